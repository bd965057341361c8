"""A blendshape rig baked from the physics: what a game engine or a DCC tool can drive itself.

Each target is a converged static shape of the simulated face (:func:`static_surface`: the
simulator stepped with constant controls until no head vertex moves more than ``tol`` in a
frame): every muscle alone at full activation, and, with ``inbetweens=K``, at the fractions
``k / (K + 1)`` too (the response is nonlinear: contact, the lips' sliding, the strain-stiffening
material). Offsets are taken in the head frame.

The jaw is a joint, not a shape: the joint ``jaw`` turns about the condyle axis (the rig's
``jaw_u`` through ``jaw_pivot``); the lower teeth and tongue ride it rigidly, the skin by linear
blend skinning with the per-vertex jaw amount of Eq. 6.4.9 (``FaceRig.vertex_jaw``) as its
weight, and what the soft tissue does beyond that rigid turn at the baked opening ``jaw_angle``
is a corrective shape ``jaw_open`` driven by ``angle / jaw_angle`` (in the bind pose, solved
through the per-vertex skinning matrix so that it lands the baked opening exactly).

**ARKit shapes** (``shapes="arkit"`` or ``"both"``, with the head's
:class:`~facewarp.takes.ArkitTable`): each of the 52 ARKit-named shapes the table solved is the converged
face of its row's activations and jaw (opening, side), baked like the jaw corrective: in the bind
pose, through the skinning of its own opening, so that ``LBS_jaw(rest + D_i)`` at the opening
``jaw_i`` lands the converged face exactly. A frame of ARKit weights ``w`` is then
``LBS_jaw(rest + sum_i w_i D_i)`` at the opening ``clip(sum_i w_i jaw_i, 0, 60 deg)`` (the jaw
joint's rotation; :func:`evaluate_arkit`), as an engine plays it. Shapes the table left at zero
(out of the muscle model's reach, or no data) are left out of the rig and listed in
``BlendshapeRig.left_out`` with the reason.

The linear rig (:func:`evaluate`) is ``LBS_jaw(rest + sum_m shape_m(a_m) + (angle / jaw_angle)
corrective)``: shapes first, then skinning, as USD and glTF apply them; a muscle's shape is
piecewise linear in its weight through the in-betweens (USD's in-between rule: from 0 to the
first in-between, between consecutive ones, up to full).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import InputError

__all__ = ["RIG_FILE", "RIG_SHAPE_SETS", "BlendshapeRig", "bake_blendshapes", "evaluate", "evaluate_arkit",
           "jaw_rotation", "load_rig", "normal_offsets", "save_rig", "static_surface", "target_weights"]

RIG_FILE = "rig.npz"
"""The baked rig's own file in a ``facewarp rig --out DIR`` folder (:func:`save_rig`), read back by
:func:`load_rig` (to put a driven take on the rig without baking again)."""
_RIG_VERSION = 1

RIG_SHAPE_SETS = ("muscles", "arkit", "both")
"""The shape sets a rig bakes: each muscle alone (and the jaw corrective), the ARKit-named shapes, or both."""


@dataclass
class BlendshapeRig:
    """A baked rig (see the module docstring). Lengths in metres, head frame (y up, +z forward).

    Attributes:
        rest: Skin rest vertices [m], shape (n, 3), float64.
        faces: Skin triangles, shape (m, 3), int64.
        names: Target names (muscles, then ``jaw_open``), length T.
        shapes: name -> list of (fraction, offsets (n, 3) float64 [m]) sorted by fraction, the last
            at 1.0 (earlier ones are in-betweens).
        jaw_pivot: Joint position [m], shape (3,), float64.
        jaw_axis: Unit opening axis, shape (3,), float64 (positive angles open the mouth).
        jaw_angle: The opening [rad] the corrective ``jaw_open`` was baked at.
        jaw_weight: Skin vertices' weight on the jaw joint, shape (n,), float64 in 0..1.
        parts: name -> (V (k, 3) [m], F (l, 3) int): eyes, teeth, tongue at rest.
        jaw_parts: The parts that ride the jaw joint.
        fps: Frames per second of the demo animation.
        bake_frames: Frames each static shape took to converge, name -> list per fraction.
        arkit_jaw: ARKit name -> the jaw opening [rad] of its shape (the ARKit shapes baked, in
            :data:`~facewarp.ARKIT_NAMES` order).
        left_out: ARKit name -> why it is not in the rig (out of the muscle model's reach, no data).
        uv: The skin's texture coordinates, (k, 2) float64, or None.
        face_uv: (m, 3) int64 index into ``uv`` per face corner, or None.
        texture: The skin's colour texture (a PNG / JPEG path), or None.
        bake_seconds: Wall-clock seconds of the bake (static shapes).
    """

    rest: np.ndarray
    faces: np.ndarray
    names: list
    shapes: dict
    jaw_pivot: np.ndarray
    jaw_axis: np.ndarray
    jaw_angle: float
    jaw_weight: np.ndarray
    parts: dict
    jaw_parts: tuple
    fps: float = 30.0
    bake_frames: dict = field(default_factory=dict)
    arkit_jaw: dict = field(default_factory=dict)
    left_out: dict = field(default_factory=dict)
    uv: np.ndarray | None = None
    face_uv: np.ndarray | None = None
    texture: str | None = None
    bake_seconds: float = 0.0

    @property
    def muscle_names(self) -> list:
        """The muscles baked (each its own shape)."""
        return [n for n in self.names if n != "jaw_open" and n not in self.arkit_jaw]

    @property
    def arkit_names(self) -> list:
        """The ARKit shapes baked."""
        return [n for n in self.names if n in self.arkit_jaw]

    def largest_motion(self, name: str) -> float:
        """The largest vertex motion [m] of a shape's full target on the face (its ARKit opening or,
        for ``jaw_open``, the baked opening, applied through the joint)."""
        D = self.shapes[name][-1][1]
        if name in self.arkit_jaw or name == "jaw_open":
            ang = self.arkit_jaw.get(name, self.jaw_angle)
            V = _lbs(self.rest + D, self.jaw_weight, self.jaw_pivot, self.jaw_axis, ang)
        else:
            V = self.rest + D
        return float(np.linalg.norm(V - self.rest, axis=1).max())

    def evaluate(self, activations: dict, jaw: float = 0.0, *, inbetweens: bool = True) -> np.ndarray:
        """The linear rig's skin (n, 3) [m] (:func:`evaluate`)."""
        return evaluate(self, activations, jaw, inbetweens=inbetweens)

    def evaluate_arkit(self, weights: dict) -> np.ndarray:
        """The linear rig's skin (n, 3) [m] at ARKit weights (:func:`evaluate_arkit`)."""
        return evaluate_arkit(self, weights)

    def arkit_opening(self, weights: dict) -> float:
        """The jaw opening [rad] of ARKit weights ``weights`` (name -> 0..1): ``clip(sum w_i jaw_i, 0, 60 deg)``."""
        from ..expressions import JAW_U_MAX

        return float(np.clip(sum(float(w) * self.arkit_jaw.get(n, 0.0) for n, w in weights.items()), 0.0, JAW_U_MAX))


def jaw_rotation(axis, angle: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle`` [rad] about the unit ``axis`` (3,) (Rodrigues)."""
    k = np.asarray(axis, np.float64)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


def static_surface(sim, activations: dict, jaw: float = 0.0, *, tol: float = 5e-6, max_frames: int = 60):
    """The simulator's converged head surface [m] under constant controls, head frame.

    Resets ``sim``, sets ``activations`` (name -> 0..1) and the jaw ``jaw`` [rad] (the opening, or
    (opening, side)), and steps until no head vertex moves more than ``tol`` [m] in a frame (or
    ``max_frames``).

    Returns:
        (V (n, 3) float64, frames taken).
    """
    sim.reset()
    sim.set_activations(dict(activations))
    if np.ndim(jaw):
        sim.set_jaw(float(jaw[0]), float(jaw[1]))
    else:
        sim.set_jaw(float(jaw))
    prev = sim.surface(frame="head")
    for k in range(1, int(max_frames) + 1):
        sim.step()
        V = sim.surface(frame="head")
        if k >= 2 and np.abs(V - prev).max() < tol:
            return V, k
        prev = V
    return prev, int(max_frames)


def _lbs(rig_rest, weight, pivot, axis, angle: float) -> np.ndarray:
    """Linear blend skinning of the rest points on the jaw joint: w R(p - c) + c + (1 - w) p."""
    R = jaw_rotation(axis, angle)
    turned = (rig_rest - pivot) @ R.T + pivot
    return weight[:, None] * turned + (1.0 - weight[:, None]) * rig_rest


def _check_table(table, sim):
    """The ARKit table's rows, checked against the simulator: (activations (52, M), jaw (52, 2), solved, reasons)."""
    for attr in ("names", "muscle_names", "activations", "jaw", "solved"):
        if not hasattr(table, attr):
            raise InputError(f"arkit: expected an ArkitTable, got {type(table).__name__}")
    if list(table.muscle_names) != list(sim.muscle_names):
        raise InputError("arkit: the table was built for another head (its muscles are not this rig's)")
    return (np.asarray(table.activations, np.float64), np.asarray(table.jaw, np.float64),
            np.asarray(table.solved, bool), dict(getattr(table, "reasons", {}) or {}))


def bake_blendshapes(fr, *, muscles=None, inbetweens: int = 0, jaw_angle: float = 0.3, shapes: str = "muscles",
                     arkit=None, device: str = "cpu", tol: float = 5e-6, max_frames: int = 60,
                     progress=None) -> BlendshapeRig:
    """Bake a face rig's blendshape rig (see the module docstring), every shape set from one simulator.

    Args:
        fr: The :class:`~facewarp.FaceRig`.
        muscles: Muscle names to bake (default all of the simulator's, each side its own); names
            must not repeat.
        inbetweens: In-between shapes per muscle (K >= 0) at ``k / (K + 1)``.
        jaw_angle: Opening [rad] of the jaw corrective (0 < angle <= 60 deg).
        shapes: ``"muscles"`` (each muscle alone and the jaw corrective), ``"arkit"`` (the ARKit
            shapes of ``arkit``) or ``"both"`` (:data:`RIG_SHAPE_SETS`).
        arkit: The head's :class:`~facewarp.takes.ArkitTable` (:func:`~facewarp.arkit_table`); needed for
            the ARKit shapes.
        device: Warp device.
        tol, max_frames: Convergence of each static shape (:func:`static_surface`).
        progress: Optional ``progress(done, total, name)``.
    """
    import time

    from ..sim.simulator import FaceSimulator

    t_start = time.perf_counter()
    if shapes not in RIG_SHAPE_SETS:
        raise InputError(f"shapes: expected one of {', '.join(RIG_SHAPE_SETS)}, got {shapes!r}")
    if not (isinstance(inbetweens, (int, np.integer)) and not isinstance(inbetweens, bool) and 0 <= inbetweens <= 8):
        raise InputError(f"inbetweens: expected a whole number 0..8, got {inbetweens!r}")
    if not (isinstance(jaw_angle, (int, float)) and 0 < jaw_angle <= math.radians(60)):
        raise InputError(f"jaw_angle: expected an angle in (0, 1.047] rad, got {jaw_angle!r}")
    if shapes != "muscles" and arkit is None:
        raise InputError(f"arkit: shapes={shapes!r} needs the head's ARKit table (facewarp.arkit_table)")
    sim = FaceSimulator(fr, device=device)
    with_muscles = shapes in ("muscles", "both")
    names = []
    if with_muscles:
        names = list(sim.muscle_names) if muscles is None else [str(m) for m in muscles]
        unknown = [m for m in names if m not in sim.muscle_names]
        if unknown or not names:
            raise InputError(f"muscles: {unknown[0] if unknown else 'none given'!r} is not a muscle of this rig; "
                             f"muscles are {', '.join(sim.muscle_names)}")
        twice = sorted({m for m in names if names.count(m) > 1})
        if twice:
            raise InputError(f"muscles: {', '.join(twice)} given twice (each muscle is one shape)")
    rows = None if arkit is None or shapes == "muscles" else _check_table(arkit, sim)
    left_out = {}
    arkit_rows = []
    if rows is not None:
        A, J, solved, reasons = rows
        for i, n in enumerate(arkit.names):
            if solved[i] and (A[i].any() or J[i].any()):
                arkit_rows.append((str(n), i))
            else:
                left_out[str(n)] = reasons.get(n, "no muscle or jaw motion reaches it (its table row is zero)")
    fractions = [(k + 1) / (inbetweens + 1) for k in range(inbetweens + 1)]
    total = len(names) * len(fractions) + (1 if with_muscles else 0) + len(arkit_rows) + 1
    done = 0

    def tick(name):
        nonlocal done
        done += 1
        if progress:
            progress(done, total, name)

    rest, _ = static_surface(sim, {}, 0.0, tol=tol, max_frames=max_frames)
    tick("rest")
    pivot = np.asarray(fr.jaw_pivot, np.float64)
    axis = np.asarray(fr.jaw_u, np.float64)
    axis = axis / np.linalg.norm(axis)
    weight = np.clip(np.asarray(fr.vertex_jaw, np.float64), 0.0, 1.0) if fr.vertex_jaw is not None \
        else np.zeros(len(rest))

    def bind_pose(V, angle):
        # shapes live before skinning (as USD and glTF apply them): LBS(rest + D) = V at ``angle``, and
        # LBS is affine per vertex, p -> A_i p + b_i with A_i = w_i R + (1 - w_i) I (invertible here)
        if not angle:
            return V - rest
        A_ = weight[:, None, None] * jaw_rotation(axis, angle)[None] \
            + (1.0 - weight)[:, None, None] * np.eye(3)[None]
        return np.linalg.solve(A_, (V - _lbs(rest, weight, pivot, axis, angle))[..., None])[..., 0]

    out, frames, arkit_jaw = {}, {}, {}
    for m in names:
        out[m], frames[m] = [], []
        for f in fractions:
            V, k = static_surface(sim, {m: f}, 0.0, tol=tol, max_frames=max_frames)
            out[m].append((f, V - rest))
            frames[m].append(k)
            tick(m)
    if with_muscles:
        V, k = static_surface(sim, {}, jaw_angle, tol=tol, max_frames=max_frames)
        out["jaw_open"] = [(1.0, bind_pose(V, jaw_angle))]
        frames["jaw_open"] = [k]
        names = names + ["jaw_open"]
        tick("jaw_open")
    if arkit_rows:
        A, J = rows[0], rows[1]
        muscle_list = list(sim.muscle_names)
        for n, i in arkit_rows:
            acts = {muscle_list[m]: float(A[i, m]) for m in np.flatnonzero(A[i] > 0)}
            opening = float(max(J[i, 0], 0.0))
            V, k = static_surface(sim, acts, (opening, float(J[i, 1])), tol=tol, max_frames=max_frames)
            out[n] = [(1.0, bind_pose(V, opening))]
            frames[n] = [k]
            arkit_jaw[n] = opening
            names.append(n)
            tick(n)
    parts = {n: (np.asarray(P, np.float64), np.asarray(F, np.int64)) for n, (P, F) in dict(fr.parts).items()}
    jaw_parts = tuple(n for n in parts if n in ("teeth_lower", "tongue"))
    uv = getattr(fr, "head_uv", None)
    face_uv = getattr(fr, "head_face_uv", None)
    texture = getattr(fr, "skin_texture", None)
    return BlendshapeRig(rest=rest, faces=np.asarray(fr.head_faces, np.int64), names=names,
                         shapes=out, jaw_pivot=pivot, jaw_axis=axis, jaw_angle=float(jaw_angle), jaw_weight=weight,
                         parts=parts, jaw_parts=jaw_parts, fps=float(sim.fps), bake_frames=frames,
                         arkit_jaw=arkit_jaw, left_out=left_out,
                         uv=None if uv is None else np.asarray(uv, np.float64),
                         face_uv=None if uv is None or face_uv is None else np.asarray(face_uv, np.int64),
                         texture=str(texture) if texture else None, bake_seconds=time.perf_counter() - t_start)


def normal_offsets(rig: BlendshapeRig, offsets) -> np.ndarray:
    """The change of the skin's unit vertex normals (n, 3) a target's offsets (n, 3) [m] make in the
    bind pose: ``normals(rest + offsets) - normals(rest)`` (area-weighted; the morph targets' NORMAL
    deltas in glTF, ``normalOffsets`` in UsdSkel)."""
    from ..geometry.surface import vertex_normals

    return vertex_normals(rig.rest + np.asarray(offsets, np.float64), rig.faces) - vertex_normals(rig.rest, rig.faces)


def target_weights(shape: list, w: float) -> list:
    """Weights of a shape's targets (in-betweens, then full) at the shape weight ``w`` (0..1):
    piecewise linear through the fractions (USD's in-between rule; the glTF weight mapping)."""
    fr = [f for f, _ in shape]
    out = [0.0] * len(fr)
    w = float(np.clip(w, 0.0, 1.0))
    prev = 0.0
    for i, f in enumerate(fr):
        if w <= f + 1e-12:
            t = (w - prev) / (f - prev)
            out[i] = t
            if i > 0:
                out[i - 1] = 1.0 - t
            return out
        prev = f
    out[-1] = 1.0
    return out


def evaluate(rig: BlendshapeRig, activations: dict, jaw: float = 0.0, *, inbetweens: bool = True) -> np.ndarray:
    """The linear rig's skin [m] (n, 3) at muscle weights ``activations`` (name -> 0..1) and
    opening ``jaw`` [rad]; ``inbetweens=False`` uses only each muscle's full shape (linear in w)."""
    V = rig.rest.copy()
    for name, a in activations.items():
        if name not in rig.shapes or name == "jaw_open" or name in rig.arkit_jaw:
            raise InputError(f"activations: {name!r} is not a muscle target of this rig")
        shape = rig.shapes[name] if inbetweens else rig.shapes[name][-1:]
        for wt, (_, D) in zip(target_weights(shape, a), shape):
            if wt:
                V = V + wt * D
    if jaw:  # shapes first, then skinning (USD's and glTF's order)
        V = V + (float(jaw) / rig.jaw_angle) * rig.shapes["jaw_open"][0][1]
        V = _lbs(V, rig.jaw_weight, rig.jaw_pivot, rig.jaw_axis, float(jaw))
    return V


def evaluate_arkit(rig: BlendshapeRig, weights: dict) -> np.ndarray:
    """The linear rig's skin [m] (n, 3) at ARKit weights ``weights`` (ARKit name -> 0..1; names left
    out of the rig count as 0): ``LBS_jaw(rest + sum_i w_i D_i)`` at the opening
    :meth:`BlendshapeRig.arkit_opening` (see the module docstring)."""
    V = rig.rest.copy()
    for name, w in weights.items():
        if name in rig.arkit_jaw:
            if w:
                V = V + float(w) * rig.shapes[name][0][1]
        elif name not in rig.left_out:
            raise InputError(f"weights: {name!r} is not an ARKit shape of this rig")
    angle = rig.arkit_opening({n: w for n, w in weights.items() if n in rig.arkit_jaw})
    return _lbs(V, rig.jaw_weight, rig.jaw_pivot, rig.jaw_axis, angle) if angle else V


def save_rig(path, rig: BlendshapeRig, *, texture_name=None) -> None:
    """Write ``rig`` to ``path`` (``.npz``, atomically): every array and name, and the texture's path
    (``texture_name``: a file beside ``path`` to name instead, read back relative to the file)."""
    import json
    import os
    from pathlib import Path

    path = Path(path)
    arrays = {"rest": rig.rest, "faces": rig.faces, "jaw_pivot": rig.jaw_pivot, "jaw_axis": rig.jaw_axis,
              "jaw_weight": rig.jaw_weight}
    meta = {"version": _RIG_VERSION, "names": list(rig.names), "jaw_angle": rig.jaw_angle, "fps": rig.fps,
            "jaw_parts": list(rig.jaw_parts), "bake_frames": rig.bake_frames, "arkit_jaw": rig.arkit_jaw,
            "left_out": rig.left_out, "bake_seconds": rig.bake_seconds,
            "texture": Path(texture_name).name if texture_name else rig.texture,
            "shapes": {n: [f for f, _ in rig.shapes[n]] for n in rig.names}, "parts": list(rig.parts)}
    for n in rig.names:
        for i, (_, D) in enumerate(rig.shapes[n]):
            arrays[f"shape:{n}:{i}"] = D
    for n, (P, F) in rig.parts.items():
        arrays[f"part:{n}:V"], arrays[f"part:{n}:F"] = P, F
    if rig.uv is not None:
        arrays["uv"] = rig.uv
        if rig.face_uv is not None:
            arrays["face_uv"] = rig.face_uv
    tmp = path.with_name(f".{path.name}.tmp.npz")
    try:
        np.savez_compressed(tmp, meta=np.array(json.dumps(meta)), **arrays)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def load_rig(path) -> BlendshapeRig:
    """Read a rig written by :func:`save_rig` (a file, or a folder holding :data:`RIG_FILE`).

    Raises:
        InputError: no such file, or not a facewarp rig (one line naming it).
    """
    import json
    from pathlib import Path

    path = Path(path)
    if path.is_dir():
        path = path / RIG_FILE
    if not path.is_file():
        raise InputError(f"{path}: not found (expected a `facewarp rig --out DIR` folder holding {RIG_FILE})")
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if meta.get("version") != _RIG_VERSION:
                raise InputError(f"{path}: rig version {meta.get('version')}, this facewarp reads {_RIG_VERSION}")
            shapes = {n: [(float(f), z[f"shape:{n}:{i}"].astype(np.float64)) for i, f in enumerate(fs)]
                      for n, fs in meta["shapes"].items()}
            parts = {n: (z[f"part:{n}:V"].astype(np.float64), z[f"part:{n}:F"].astype(np.int64)) for n in meta["parts"]}
            return BlendshapeRig(
                rest=z["rest"].astype(np.float64), faces=z["faces"].astype(np.int64), names=list(meta["names"]),
                shapes=shapes, jaw_pivot=z["jaw_pivot"].astype(np.float64), jaw_axis=z["jaw_axis"].astype(np.float64),
                jaw_angle=float(meta["jaw_angle"]), jaw_weight=z["jaw_weight"].astype(np.float64), parts=parts,
                jaw_parts=tuple(meta["jaw_parts"]), fps=float(meta["fps"]), bake_frames=meta["bake_frames"],
                arkit_jaw={k: float(v) for k, v in meta["arkit_jaw"].items()}, left_out=meta["left_out"],
                uv=z["uv"].astype(np.float64) if "uv" in z else None,
                face_uv=z["face_uv"].astype(np.int64) if "face_uv" in z else None,
                texture=None if not meta["texture"] else str(path.parent / meta["texture"]),
                bake_seconds=float(meta["bake_seconds"]))
    except InputError:
        raise
    except Exception as e:  # a damaged or foreign file: one line
        raise InputError(f"{path}: not a facewarp rig ({type(e).__name__}: {e})") from None
