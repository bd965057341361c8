"""A baked blendshape rig as glTF 2.0 binary (``.glb``): morph targets, a jaw joint, an animation.

Layout (metres, Y up, the face looking along +z, as glTF wants):

- scene roots ``Rig`` (with the joint ``root``) and ``Skin`` (the skinned mesh); ``root`` has
  the child joint ``jaw`` at the condyle pivot; the eyes and upper teeth hang under ``root``, the
  lower teeth and tongue under ``jaw`` (rigid, as in the head);
- mesh ``Skin``: POSITION, NORMAL, JOINTS_0 / WEIGHTS_0 (root, jaw: the Eq. 6.4.9 jaw amount),
  one primitive per material (skin, lips) sharing those attributes; one morph target per baked
  shape, named in ``mesh.extras.targetNames``: a muscle's full shape under its name, its
  in-betweens as ``NAME@0.50`` (the fraction), and the jaw corrective ``jaw_open``;
- skin ``Skin`` with joints ``root``, ``jaw`` and their inverse bind matrices;
- with the skin's UVs (``BlendshapeRig.uv``): TEXCOORD_0 (v flipped: glTF's v points down), the
  skin's vertices split where the UVs have seams (every attribute and morph target follows), and
  the build's texture embedded as the skin material's base colour (PNG / JPEG); the lips are then
  the texture's own (no Lips primitive);
- each morph target carries POSITION and NORMAL deltas (:func:`~facewarp._src.bake.blendshapes.normal_offsets`);
- animations (clips): ``sequence`` (the Fig. 6.16 muscle sequence) and any others given, each the
  jaw node's rotation and the Skin node's morph weights per frame; a clip of ARKit weights sets the
  ARKit targets by name and the jaw to :meth:`BlendshapeRig.arkit_opening`.

Colours come from the one palette, ``present.looks.COLORS`` (as the USD files).

**In-between weight mapping.** glTF morph targets are linear, so an in-between is its own
target: a muscle at weight ``w`` with in-betweens at fractions ``f_1 < ... < f_K < 1`` sets, for
``f_i <= w <= f_{i+1}`` (``f_0 = 0``, ``f_{K+1} = 1``), target ``f_{i+1}`` to
``t = (w - f_i) / (f_{i+1} - f_i)`` and target ``f_i`` to ``1 - t`` (all others 0): the shape is
piecewise linear through the baked shapes (:func:`~facewarp._src.bake.blendshapes.target_weights`,
USD's in-between rule). The ``jaw_open`` corrective's weight is the jaw angle over the baked
opening (``BlendshapeRig.jaw_angle``).
"""

from __future__ import annotations

import json
import math
import struct

import numpy as np

from ..core.fileio import atomic_write
from .blendshapes import BlendshapeRig, target_weights

__all__ = ["clip_arrays", "frame_weights", "skin_vertices", "target_list", "write_glb"]

_FLOAT, _UBYTE, _USHORT, _UINT = 5126, 5121, 5123, 5125
_ARRAY, _ELEMENTS = 34962, 34963


def target_list(rig: BlendshapeRig) -> list[tuple[str, str, int]]:
    """(target name, shape name, index in the shape's list) of every morph target, in order."""
    out = []
    for name in rig.names:
        shape = rig.shapes[name]
        for i, (f, _) in enumerate(shape):
            out.append((name if i == len(shape) - 1 else f"{name}@{f:.2f}", name, i))
    return out


def frame_weights(rig: BlendshapeRig, activations: dict, jaw: float, arkit: dict | None = None) -> np.ndarray:
    """Morph weights (targets,) of one frame: muscle weights through :func:`target_weights`, the
    jaw corrective at ``jaw / rig.jaw_angle``, ARKit weights (``arkit``: name -> 0..1) as they are."""
    out = []
    arkit = arkit or {}
    for name in rig.names:
        if name == "jaw_open":
            out.append(float(jaw) / rig.jaw_angle)
        elif name in rig.arkit_jaw:
            out.append(float(arkit.get(name, 0.0)))
        else:
            out.extend(target_weights(rig.shapes[name], float(activations.get(name, 0.0))))
    return np.asarray(out, np.float32)


def clip_arrays(rig: BlendshapeRig, frames: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A clip's arrays: times (f,) [s], morph weights (f, targets) float32, jaw openings (f,) [rad].

    ``frames``: [(time [s], {muscle: weight}, jaw [rad])] (muscle frames), or [(time [s], {ARKit
    name: weight})] (ARKit frames: the jaw is :meth:`BlendshapeRig.arkit_opening`)."""
    t, W, J = [], [], []
    for f in frames:
        if len(f) == 2:
            w = {n: v for n, v in f[1].items() if n in rig.arkit_jaw}
            jaw = rig.arkit_opening(w)
            W.append(frame_weights(rig, {}, 0.0, w))
        else:
            jaw = float(f[2])
            W.append(frame_weights(rig, f[1], jaw))
        t.append(float(f[0]))
        J.append(jaw)
    return np.asarray(t, np.float64), np.asarray(W, np.float32).reshape(len(t), -1), np.asarray(J, np.float64)


def _quat_xyzw(axis, angle: float) -> list:
    s = math.sin(0.5 * angle)
    return [float(axis[0] * s), float(axis[1] * s), float(axis[2] * s), math.cos(0.5 * angle)]


class _Buffer:
    def __init__(self):
        self.data = bytearray()
        self.views, self.accessors = [], []

    def add(self, array: np.ndarray, ctype: int, kind: str, *, target: int | None = None, minmax: bool = False) -> int:
        a = np.ascontiguousarray(array)
        while len(self.data) % 4:
            self.data.append(0)
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": a.nbytes}
        if target is not None:
            view["target"] = target
        self.data += a.tobytes()
        self.views.append(view)
        count = a.shape[0]
        acc = {"bufferView": len(self.views) - 1, "componentType": ctype, "count": int(count), "type": kind}
        if minmax:
            flat = a.reshape(count, -1)
            acc["min"] = [float(v) for v in flat.min(0)]
            acc["max"] = [float(v) for v in flat.max(0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def add_bytes(self, data: bytes) -> int:
        """A buffer view of raw bytes (an image); returns the view's index."""
        while len(self.data) % 4:
            self.data.append(0)
        self.views.append({"buffer": 0, "byteOffset": len(self.data), "byteLength": len(data)})
        self.data += data
        return len(self.views) - 1


def part_prim_name(name: str) -> str:
    """A part's object name, as in the USD (``usd_export.part_prim_name``: ``eye_L`` -> ``Eye_L``)."""
    s = "".join(c if (c.isascii() and c.isalnum()) or c == "_" else "_" for c in str(name))
    s = s if s and not s[0].isdigit() else f"_{s}"
    return "_".join(w[:1].upper() + w[1:] for w in s.split("_"))


def _normals(V, F) -> np.ndarray:
    N = np.zeros_like(V)
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    for c in range(3):
        np.add.at(N, F[:, c], fn)
    n = np.linalg.norm(N, axis=1, keepdims=True)
    return np.where(n > 0, N / np.maximum(n, 1e-30), np.array([0.0, 0.0, 1.0]))


def skin_vertices(rig: BlendshapeRig) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The glTF skin's vertices: (source skin vertex (k,) int64, faces (m, 3) into them, UVs (k, 2)
    or None). Without UVs the skin's own; with them one vertex per distinct (vertex, UV) corner
    pair (the vertices split at the UV seams)."""
    if rig.uv is None or rig.face_uv is None:
        return np.arange(len(rig.rest)), rig.faces, None
    pairs, inverse = np.unique(np.stack([rig.faces.ravel(), rig.face_uv.ravel()], 1), axis=0, return_inverse=True)
    return pairs[:, 0], inverse.reshape(-1, 3), rig.uv[pairs[:, 1]]


def write_glb(path, rig: BlendshapeRig, *, frames: list | None = None, looks: dict | None = None,
              clips: dict | None = None) -> None:
    """Write ``rig`` as ``.glb`` (see the module docstring).

    Args:
        path: Output file (written atomically).
        rig: The baked rig.
        frames: Optional animation ``sequence``: a list of (time [s], activations {muscle: 0..1}, jaw [rad]).
        looks: Optional ``present.looks.head_looks`` output (part colours, skin / eye / gum subsets
            and the part meshes they index: the tooth rows split at their gum lines).
        clips: Optional further animations, name -> frames (:func:`clip_arrays`: muscle frames or
            ARKit frames).
    """
    from ..geometry.surface import vertex_normals
    from .blendshapes import normal_offsets

    looks = looks or {"part_colors": {}, "subsets": {}}
    buf = _Buffer()
    materials, mat_index = [], {}
    images, textures = [], []

    def material(name, rgb, rough=0.5, texture=None):
        if name not in mat_index:
            mat_index[name] = len(materials)
            pbr = {"baseColorFactor": [float(rgb[0]), float(rgb[1]), float(rgb[2]), 1.0], "metallicFactor": 0.0,
                   "roughnessFactor": rough}
            if texture is not None:
                pbr["baseColorFactor"] = [1.0, 1.0, 1.0, 1.0]
                pbr["baseColorTexture"] = {"index": texture}
            materials.append({"name": name, "pbrMetallicRoughness": pbr, "doubleSided": True})
        return mat_index[name]

    from ..present.looks import COLORS

    def primitives(attrs, F, groups, base_name, base_rgb, targets=None, texture=None):
        """One primitive per material: the faces of each group, then the rest."""
        used = np.zeros(len(F), bool)
        prims = []
        for gname, (idx, rgb) in groups.items():
            idx = np.asarray(idx, np.int64)
            if not len(idx):
                continue
            used[idx] = True
            prims.append((gname, rgb, F[idx]))
        rest = F[~used]
        if len(rest):
            prims.insert(0, (base_name, base_rgb, rest))
        out = []
        for gname, rgb, faces in prims:
            p = {"attributes": attrs, "indices": buf.add(faces.astype(np.uint32).ravel(), _UINT, "SCALAR",
                                                         target=_ELEMENTS),
                 "material": material(gname, rgb, texture=texture if gname == base_name else None)}
            if targets:
                p["targets"] = targets
            out.append(p)
        return out

    # ---- skin mesh: attributes, skin weights, morph targets
    src, SF, tc = skin_vertices(rig)
    V = rig.rest[src].astype(np.float32)
    n = len(V)
    attrs = {"POSITION": buf.add(V, _FLOAT, "VEC3", target=_ARRAY, minmax=True),
             "NORMAL": buf.add(vertex_normals(rig.rest, rig.faces)[src].astype(np.float32), _FLOAT, "VEC3",
                               target=_ARRAY)}
    texture = None
    if tc is not None:
        flipped = np.array(tc, np.float64)
        flipped[:, 1] = 1.0 - flipped[:, 1]
        attrs["TEXCOORD_0"] = buf.add(flipped.astype(np.float32), _FLOAT, "VEC2", target=_ARRAY)
        if rig.texture:
            from pathlib import Path

            data = Path(rig.texture).read_bytes()
            mime = "image/png" if data[:8] == b"\x89PNG\r\n\x1a\n" else "image/jpeg"
            view = buf.add_bytes(data)
            images.append({"name": "skin", "bufferView": view, "mimeType": mime})
            textures.append({"source": len(images) - 1})
            texture = len(textures) - 1
    # joint 0 root, 1 jaw; a vertex wholly on one joint lists only it (unused slots: joint 0, weight 0)
    w = rig.jaw_weight[src].astype(np.float32)
    joints = np.zeros((n, 4), np.uint8)
    weights = np.zeros((n, 4), np.float32)
    weights[:, 0] = 1.0 - w
    both = (w > 0) & (w < 1)
    joints[both, 1], weights[both, 1] = 1, w[both]
    full = w >= 1
    joints[full, 0], weights[full, 0] = 1, 1.0
    attrs["JOINTS_0"] = buf.add(joints, _UBYTE, "VEC4", target=_ARRAY)
    attrs["WEIGHTS_0"] = buf.add(weights, _FLOAT, "VEC4", target=_ARRAY)
    tlist = target_list(rig)
    targets = []
    for _, s_, i in tlist:
        D = rig.shapes[s_][i][1]
        targets.append({"POSITION": buf.add(D[src].astype(np.float32), _FLOAT, "VEC3", target=_ARRAY, minmax=True),
                        "NORMAL": buf.add(normal_offsets(rig, D)[src].astype(np.float32), _FLOAT, "VEC3",
                                          target=_ARRAY)})
    skin_groups = {} if texture is not None else \
        {k.capitalize(): v for k, v in looks.get("subsets", {}).get("Skin", {}).items()}
    meshes = [{"name": "Skin", "primitives": primitives(attrs, SF, skin_groups, "Skin", COLORS["skin"], targets,
                                                        texture=texture),
               "weights": [0.0] * len(tlist), "extras": {"targetNames": [t for t, _, _ in tlist]}}]
    # ---- nodes
    pivot = [float(v) for v in rig.jaw_pivot]
    nodes = [{"name": "Rig", "children": [1]},
             {"name": "root", "children": [2]},
             {"name": "jaw", "translation": pivot, "children": []},
             {"name": "Skin", "mesh": 0, "skin": 0}]
    for pname, (P, F) in rig.parts.items():
        P, F = looks.get("parts", {}).get(pname, (P, F))
        P, F = np.asarray(P, np.float64), np.asarray(F, np.int64)
        on_jaw = pname in rig.jaw_parts
        pattrs = {"POSITION": buf.add(P.astype(np.float32), _FLOAT, "VEC3", target=_ARRAY, minmax=True),
                  "NORMAL": buf.add(_normals(P, F).astype(np.float32), _FLOAT, "VEC3", target=_ARRAY)}
        base = looks.get("part_colors", {}).get(pname, COLORS["teeth"])
        mesh = {"name": part_prim_name(pname), "primitives": primitives(
            pattrs, F, looks.get("subsets", {}).get(pname, {}), part_prim_name(pname), base)}
        meshes.append(mesh)
        node = {"name": part_prim_name(pname), "mesh": len(meshes) - 1}
        if on_jaw:
            node["translation"] = [-v for v in pivot]  # part vertices are in the head frame
        nodes.append(node)
        (nodes[2] if on_jaw else nodes[1])["children"].append(len(nodes) - 1)
    if not nodes[2]["children"]:
        del nodes[2]["children"]
    ibm = np.zeros((2, 16), np.float32)
    ibm[0] = np.eye(4, dtype=np.float32).T.ravel()
    M = np.eye(4, dtype=np.float32)
    M[:3, 3] = -np.asarray(pivot, np.float32)
    ibm[1] = M.T.ravel()  # column-major
    skins = [{"name": "Skin", "joints": [1, 2], "skeleton": 1, "inverseBindMatrices": buf.add(ibm, _FLOAT, "MAT4")}]
    doc = {"asset": {"version": "2.0", "generator": "facewarp rig (physics-baked blendshapes)"},
           "scene": 0, "scenes": [{"name": "Rig", "nodes": [0, 3]}], "nodes": nodes, "meshes": meshes,
           "skins": skins, "materials": materials}
    if images:
        doc["images"], doc["textures"] = images, textures
    all_clips = ({"sequence": frames} if frames else {}) | dict(clips or {})
    for cname, cframes in all_clips.items():
        if not cframes:
            continue
        t, mw, jaw = clip_arrays(rig, cframes)
        rot = np.asarray([_quat_xyzw(rig.jaw_axis, a) for a in jaw], np.float32)
        tin = buf.add(t.astype(np.float32), _FLOAT, "SCALAR", minmax=True)
        doc.setdefault("animations", []).append({"name": str(cname), "samplers": [
            {"input": tin, "output": buf.add(rot, _FLOAT, "VEC4"), "interpolation": "LINEAR"},
            {"input": tin, "output": buf.add(mw.ravel(), _FLOAT, "SCALAR"), "interpolation": "LINEAR"}],
            "channels": [{"sampler": 0, "target": {"node": 2, "path": "rotation"}},
                         {"sampler": 1, "target": {"node": 3, "path": "weights"}}]})
    while len(buf.data) % 4:
        buf.data.append(0)
    doc["buffers"] = [{"byteLength": len(buf.data)}]
    doc["bufferViews"], doc["accessors"] = buf.views, buf.accessors
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    total = 12 + 8 + len(js) + 8 + len(buf.data)
    with atomic_write(path, "wb") as f:
        f.write(struct.pack("<4sII", b"glTF", 2, total))
        f.write(struct.pack("<I4s", len(js), b"JSON") + js)
        f.write(struct.pack("<I4s", len(buf.data), b"BIN\x00") + bytes(buf.data))
