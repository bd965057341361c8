"""``facewarp morph``: in-between heads of two heads of the same topology (thesis Ch. 7).

Two heads made from one template (the template itself, ``adapt`` outputs, template folders)
share their triangles, FDP surface points, regions and rigid parts, so any weight ``s`` in
[0, 1] gives a head: the skin vertices, skin thickness, skull depth and condyles blend
linearly, ``(1 - s) A + s B``; each rigid part moves by the interpolated similarity that takes
A's part onto B's (scale geometrically, rotation by the slerp of its axis-angle, the part's
centroid linearly), so an eyeball stays a sphere on the way. When B's part is not a similarity
image of A's (a residual over 0.1 mm), the affine map that fits it best is blended linearly
instead, which gives the blended vertices exactly when the parts are affine images.

``--steps N`` writes ``N`` in-between heads plus both ends as ``N + 2`` time samples (time code
``k`` for ``s = k / (N + 1)``) of one USD file: the head mesh with time-sampled points and the
parts as ``Xform``\\ s with time-sampled transforms, and a picture of the heads side by side
beside it. With ``build``, every head is also written as a template folder with its anatomy
rebuilt (skin layer, muscles, face rig, ``head.xml``), so each in-between head can be simulated.
"""

from __future__ import annotations

import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..adapt.transfer import load_head
from ..core.errors import InputError
from ..core.limits import MAX_FPS, MAX_MORPH_STEPS, check_memory, check_work, estimate_frames_bytes
from ..core.outputs import destination
from ..geometry.similarity import Similarity, fit_similarity
from ..present.animation import label_grid
from ..present.render import render_mesh, save_png
from ..present.template import colored_scene
from ..template.files import save_template
from .animation import check_usd_path
from .checks import check_apart, check_out_dir, make_out_dir
from .face import build_head_files

__all__ = ["PART_SIMILARITY_TOLERANCE", "blend_heads", "check_same_topology", "morph_files", "part_motion"]

PART_SIMILARITY_TOLERANCE = 1e-4
"""Largest residual [m] of a part's similarity fit for the part to be morphed rigidly."""

MAX_STEPS = MAX_MORPH_STEPS

BUILD_FOLDER_BYTES = 4_000_000
"""Disk of one in-between head of ``--build`` (its template folder and its build; measured 1.4 MB a
level-0 build folder, about 2x rounded up) [bytes]."""


def check_same_topology(a, b, names=("A", "B")) -> None:
    """Raise :class:`InputError` unless heads ``a`` and ``b`` share triangles, regions, FDP
    surface points and rigid parts (names and triangles)."""
    na, nb = names
    if a.vertices.shape != b.vertices.shape:
        raise InputError(f"{na}, {nb}: the heads have different topology ({len(a.vertices)} and {len(b.vertices)} "
                         "vertices); morph needs two heads made from one template")
    if a.faces.shape != b.faces.shape or not np.array_equal(a.faces, b.faces):
        raise InputError(f"{na}, {nb}: the heads have the same vertex count but different triangles; "
                         "morph needs two heads made from one template")
    if not np.array_equal(a.face_region, b.face_region) or not np.array_equal(a.frontal, b.frontal):
        raise InputError(f"{na}, {nb}: the heads' face regions differ")
    if set(a.fdp) != set(b.fdp) or any(a.fdp[k][0] != b.fdp[k][0] or not np.array_equal(a.fdp[k][1].face, b.fdp[k][1].face)
                                       for k in a.fdp):
        raise InputError(f"{na}, {nb}: the heads' FDPs sit on different triangles")
    if set(a.parts) != set(b.parts):
        raise InputError(f"{na}, {nb}: the heads have different rigid parts ({', '.join(sorted(a.parts))} and "
                         f"{', '.join(sorted(b.parts))})")
    for k in a.parts:
        (VA, FA), (VB, FB) = a.parts[k], b.parts[k]
        if VA.shape != VB.shape or FA.shape != FB.shape or not np.array_equal(FA, FB):
            raise InputError(f"{na}, {nb}: part {k!r} has different topology ({len(VA)} and {len(VB)} vertices)")


def _rotation_log(R: np.ndarray) -> np.ndarray:
    """Axis-angle vector of a rotation matrix (angle in [0, pi])."""
    c = float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))
    angle = math.acos(c)
    if angle < 1e-12:
        return np.zeros(3)
    if math.pi - angle < 1e-6:  # near pi: the axis from the symmetric part
        w, v = np.linalg.eigh((R + R.T) / 2.0)
        return v[:, np.argmax(w)] * angle
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2.0 * math.sin(angle))
    return axis * angle


def _rotation_exp(w: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.eye(3)
    k = w / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


class _PartMotion:
    """How one rigid part goes from A to B: an interpolated similarity or a blended affine map."""

    def __init__(self, VA: np.ndarray, VB: np.ndarray):
        VA, VB = np.asarray(VA, np.float64), np.asarray(VB, np.float64)
        self.center_a, self.center_b = VA.mean(0), VB.mean(0)
        sim = fit_similarity(VA, VB)
        self.residual = float(np.linalg.norm(sim.apply(VA) - VB, axis=1).max())
        self.rigid = self.residual <= PART_SIMILARITY_TOLERANCE
        self.scale, self.log_rotation = sim.scale, _rotation_log(sim.rotation)
        if not self.rigid:  # least-squares affine map, row-vector form [V 1] @ A = VB
            H = np.hstack([VA, np.ones((len(VA), 1))])
            self.affine = np.linalg.lstsq(H, VB, rcond=None)[0]  # (4, 3)
            self.residual = float(np.linalg.norm(H @ self.affine - VB, axis=1).max())

    def matrix(self, s: float) -> np.ndarray:
        """Rest (A) to weight-``s`` transform, 4x4 row-vector convention (``p' = p @ M``)."""
        M = np.eye(4)
        if self.rigid:
            sim = Similarity(self.scale**s, _rotation_exp(s * self.log_rotation), np.zeros(3))
            c = (1.0 - s) * self.center_a + s * self.center_b
            L = sim.scale * sim.rotation
            M[:3, :3] = L.T
            M[3, :3] = c - L @ self.center_a
        else:
            M[:3, :3] = (1.0 - s) * np.eye(3) + s * self.affine[:3]
            M[3, :3] = s * self.affine[3]
        return M


def part_motion(a, b) -> dict:
    """Part name -> motion object (``matrix(s)``, ``rigid``, ``residual`` [m]) from head ``a`` to ``b``."""
    return {k: _PartMotion(a.parts[k][0], b.parts[k][0]) for k in a.parts}


def blend_heads(a, b, s: float, motions: dict | None = None):
    """The head at weight ``s`` between ``a`` (0) and ``b`` (1), a :class:`~facewarp.Template`
    (see the module docstring); ``a`` and ``b`` must pass :func:`check_same_topology`."""
    motions = motions or part_motion(a, b)
    parts = {}
    for k, (V, F) in a.parts.items():
        M = motions[k].matrix(s)
        parts[k] = (np.asarray(V, np.float64) @ M[:3, :3] + M[3, :3], F)
    mix = lambda x, y: (1.0 - s) * np.asarray(x, np.float64) + s * np.asarray(y, np.float64)  # noqa: E731
    return replace(a, vertices=mix(a.vertices, b.vertices), thickness=mix(a.thickness, b.thickness),
                   skull_depth=mix(a.skull_depth, b.skull_depth), condyles=mix(a.condyles, b.condyles), parts=parts)


def _strip(heads: list, weights: list, path: Path, *, device: str, size: int = 300) -> None:
    pick = np.unique(np.linspace(0, len(heads) - 1, min(len(heads), 7)).round().astype(int))
    row = []
    for i in pick:
        V, F, C = colored_scene(heads[i])
        row.append(render_mesh(V, F, view="three_quarter", width=size, height=size, vertex_colors=C, device=device))
    grid = label_grid([row], column_labels=[f"s = {weights[i]:.2f}" for i in pick])
    save_png(path, grid, title="morph: A (s = 0) to B (s = 1)")


def morph_files(head_a, head_b, out, *, steps: int = 8, fps: float = 30.0, build=None, device: str = "cpu",
                progress=None) -> dict:
    """Write the morph of ``head_a`` into ``head_b`` (see the module docstring); returns a report.

    Args:
        head_a, head_b: Heads as :func:`~facewarp.load_head` takes them (template folders,
            ``adapt`` outputs, ``"default[:LEVEL]"``), of the same topology.
        out: The USD file (``.usda``, ``.usdc``, ``.usdz``); a picture ``<stem>.png`` is written
            beside it.
        steps: In-between heads (>= 1); the file has ``steps + 2`` time samples.
        fps: Time codes per second of the file.
        build: Optional folder: every head as a template folder ``head_KK`` with its anatomy
            in ``head_KK/build`` (simulate it with ``facewarp simulate head_KK/build``).
        device: Warp device for the pictures.
        progress: Optional ``progress(message)``.

    Raises:
        InputError: a missing head, heads of different topology, a bad path or number.
    """
    from .animation import load_usd_export

    ue = load_usd_export()
    AnimationWriter, UsdExportError = ue.AnimationWriter, ue.UsdExportError

    step = progress or (lambda msg: None)
    if not (isinstance(steps, (int, np.integer)) and not isinstance(steps, bool) and 1 <= steps <= MAX_STEPS):
        raise InputError(f"steps: expected a whole number 1..{MAX_STEPS}, got {steps!r}")
    if not (isinstance(fps, (int, float, np.integer, np.floating)) and not isinstance(fps, bool)
            and math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise InputError(f"fps: expected a finite number > 0 and <= {MAX_FPS:g}, got {fps!r}")
    for name, h in (("head_a", head_a), ("head_b", head_b)):
        if not isinstance(h, (str, os.PathLike)) and not hasattr(h, "vertices"):
            raise InputError(f"{name}: expected a head folder, 'default[:LEVEL]' or a Template, got {type(h).__name__}")
    if not isinstance(out, (str, os.PathLike)) or not str(out).strip():
        raise InputError(f"out: expected a .usda, .usdc or .usdz file path, got {out!r}")
    path = check_usd_path(out)
    if build is not None:
        if not isinstance(build, (str, os.PathLike)) or not str(build).strip():
            raise InputError(f"build: expected a folder path, got {build!r}")
        build = check_out_dir(build)
    inputs = [(n, h) for n, h in (("A", head_a), ("B", head_b))
              if isinstance(h, (str, os.PathLike)) and not str(h).startswith("default")]
    outputs = [("out", path, "file"), ("out", path.with_suffix(".png"), "file")]
    if build is not None:
        outputs.append(("build", build, "dir"))
        real_out, real_build = (Path(destination(p)).resolve() for p in (path, build))
        if real_build in real_out.parents:
            raise InputError(f"out {out}: lies inside --build {build}, whose head_KK folders it would sit among; "
                             "choose outputs apart")
        check_work(f"steps: {steps + 2} heads built", head_frames=0, vertex_count=1, device=str(device),
                   disk_bytes=(steps + 2) * BUILD_FOLDER_BYTES, folder=destination(build))
    check_apart(outputs, inputs)
    step("loading heads")
    a, b = load_head(head_a), load_head(head_b)
    check_same_topology(a, b, names=(str(head_a), str(head_b)))
    check_memory(estimate_frames_bytes(steps + 2, 4 * len(a.vertices)),
                 f"steps: {steps + 2} heads of {len(a.vertices)} vertices")
    motions = part_motion(a, b)
    weights = [k / (steps + 1) for k in range(steps + 2)]
    heads = [blend_heads(a, b, s, motions) for s in weights]
    step("writing USD")
    try:
        look = {} if a.uv is None else {"uv": a.uv, "uv_indices": a.face_uv}
        with AnimationWriter(path, fps=fps, faces=a.faces, rest_points=a.vertices, parts=dict(a.parts), **look) as w:
            for k, (s, h) in enumerate(zip(weights, heads)):
                w.add_frame(k / fps, h.vertices, part_transforms={n: m.matrix(s) for n, m in motions.items()})
    except UsdExportError as e:
        raise InputError(str(e)) from None
    picture = path.with_suffix(".png")
    step("picture")
    _strip(heads, weights, picture, device=device)
    report = {
        "a": str(head_a), "b": str(head_b), "steps": int(steps), "samples": len(weights), "fps": float(fps),
        "weights": weights, "vertex_count": int(len(a.vertices)),
        "max_vertex_distance_mm": float(np.linalg.norm(b.vertices - a.vertices, axis=1).max() * 1e3),
        "parts": {k: {"rigid": m.rigid, "fit_residual_mm": m.residual * 1e3} for k, m in motions.items()},
        "files": [str(path), str(picture)],
    }
    if build is not None:
        make_out_dir(build)
        report["heads"] = []
        for k, h in enumerate(heads):
            step(f"anatomy {k + 1}/{len(heads)}")
            folder = build / f"head_{k:02d}"
            save_template(h, folder)
            q = build_head_files(h, folder / "build", device=device)
            report["heads"].append({"weight": weights[k], "folder": str(folder), "build": str(folder / "build"),
                                    **{key: q.get(key) for key in ("tet_count", "inverted_count", "min_dihedral_deg",
                                                                   "conforming", "muscle_count")}})
    return report
