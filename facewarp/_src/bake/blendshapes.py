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

__all__ = ["BlendshapeRig", "bake_blendshapes", "evaluate", "jaw_rotation", "static_surface", "target_weights"]


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

    @property
    def muscle_names(self) -> list:
        return [n for n in self.names if n != "jaw_open"]

    def evaluate(self, activations: dict, jaw: float = 0.0, *, inbetweens: bool = True) -> np.ndarray:
        """The linear rig's skin (n, 3) [m] (:func:`evaluate`)."""
        return evaluate(self, activations, jaw, inbetweens=inbetweens)


def jaw_rotation(axis, angle: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle`` [rad] about the unit ``axis`` (3,) (Rodrigues)."""
    k = np.asarray(axis, np.float64)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


def static_surface(sim, activations: dict, jaw: float = 0.0, *, tol: float = 5e-6, max_frames: int = 60):
    """The simulator's converged head surface [m] under constant controls, head frame.

    Resets ``sim``, sets ``activations`` (name -> 0..1) and the jaw opening ``jaw`` [rad], and steps
    until no head vertex moves more than ``tol`` [m] in a frame (or ``max_frames``).

    Returns:
        (V (n, 3) float64, frames taken).
    """
    sim.reset()
    sim.set_activations(dict(activations))
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


def bake_blendshapes(fr, *, muscles=None, inbetweens: int = 0, jaw_angle: float = 0.3, device: str = "cpu",
                     tol: float = 5e-6, max_frames: int = 60, progress=None) -> BlendshapeRig:
    """Bake a face rig's blendshape rig (see the module docstring).

    Args:
        fr: The :class:`~facewarp.FaceRig`.
        muscles: Muscle names to bake (default all of the simulator's, each side its own).
        inbetweens: In-between shapes per muscle (K >= 0) at ``k / (K + 1)``.
        jaw_angle: Opening [rad] of the jaw corrective (0 < angle <= 60 deg).
        device: Warp device.
        tol, max_frames: Convergence of each static shape (:func:`static_surface`).
        progress: Optional ``progress(done, total, name)``.
    """
    from ..sim.simulator import FaceSimulator

    if not (isinstance(inbetweens, (int, np.integer)) and not isinstance(inbetweens, bool) and 0 <= inbetweens <= 8):
        raise InputError(f"inbetweens: expected a whole number 0..8, got {inbetweens!r}")
    if not (isinstance(jaw_angle, (int, float)) and 0 < jaw_angle <= math.radians(60)):
        raise InputError(f"jaw_angle: expected an angle in (0, 1.047] rad, got {jaw_angle!r}")
    sim = FaceSimulator(fr, device=device)
    names = list(sim.muscle_names) if muscles is None else [str(m) for m in muscles]
    unknown = [m for m in names if m not in sim.muscle_names]
    if unknown or not names:
        raise InputError(f"muscles: {unknown[0] if unknown else 'none given'!r} is not a muscle of this rig; "
                         f"muscles are {', '.join(sim.muscle_names)}")
    rest, _ = static_surface(sim, {}, 0.0, tol=tol, max_frames=max_frames)
    fractions = [(k + 1) / (inbetweens + 1) for k in range(inbetweens + 1)]
    shapes, frames = {}, {}
    total = len(names) * len(fractions) + 1
    done = 0
    for m in names:
        shapes[m], frames[m] = [], []
        for f in fractions:
            V, k = static_surface(sim, {m: f}, 0.0, tol=tol, max_frames=max_frames)
            shapes[m].append((f, V - rest))
            frames[m].append(k)
            done += 1
            if progress:
                progress(done, total, m)
    pivot = np.asarray(fr.jaw_pivot, np.float64)
    axis = np.asarray(fr.jaw_u, np.float64)
    axis = axis / np.linalg.norm(axis)
    weight = np.clip(np.asarray(fr.vertex_jaw, np.float64), 0.0, 1.0) if fr.vertex_jaw is not None \
        else np.zeros(len(rest))
    V, k = static_surface(sim, {}, jaw_angle, tol=tol, max_frames=max_frames)
    # the corrective lives before skinning (as USD and glTF apply shapes): LBS(rest + C) = V, and
    # LBS is affine per vertex, p -> A_i p + b_i with A_i = w_i R + (1 - w_i) I (invertible here)
    A = weight[:, None, None] * jaw_rotation(axis, jaw_angle)[None] + (1.0 - weight)[:, None, None] * np.eye(3)[None]
    corrective = np.linalg.solve(A, (V - _lbs(rest, weight, pivot, axis, jaw_angle))[..., None])[..., 0]
    shapes["jaw_open"] = [(1.0, corrective)]
    frames["jaw_open"] = [k]
    if progress:
        progress(total, total, "jaw_open")
    parts = {n: (np.asarray(P, np.float64), np.asarray(F, np.int64)) for n, (P, F) in dict(fr.parts).items()}
    jaw_parts = tuple(n for n in parts if n in ("teeth_lower", "tongue"))
    return BlendshapeRig(rest=rest, faces=np.asarray(fr.head_faces, np.int64), names=names + ["jaw_open"],
                         shapes=shapes, jaw_pivot=pivot, jaw_axis=axis, jaw_angle=float(jaw_angle), jaw_weight=weight,
                         parts=parts, jaw_parts=jaw_parts, fps=float(sim.fps), bake_frames=frames)


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
        if name not in rig.shapes or name == "jaw_open":
            raise InputError(f"activations: {name!r} is not a muscle target of this rig")
        shape = rig.shapes[name] if inbetweens else rig.shapes[name][-1:]
        for wt, (_, D) in zip(target_weights(shape, a), shape):
            if wt:
                V = V + wt * D
    if jaw:  # shapes first, then skinning (USD's and glTF's order)
        V = V + (float(jaw) / rig.jaw_angle) * rig.shapes["jaw_open"][0][1]
        V = _lbs(V, rig.jaw_weight, rig.jaw_pivot, rig.jaw_axis, float(jaw))
    return V
