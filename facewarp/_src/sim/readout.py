"""What a simulated face shows, as functions of a face rig and node positions (host, NumPy, SI):
the head surface, the rigid parts, the FDPs and the muscle fibres; and the controls' input forms.

:class:`~facewarp._src.sim.simulator.FaceSimulator` calls them on its current state; they take
plain arrays, so a recorded frame can be read out the same way.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..expressions import MUSCLES

__all__ = ["activation_vector", "expression_activations", "fdp_points", "head_surface", "jaw_vector",
           "muscle_curves", "parts_at", "surface_index"]


def surface_index(fr) -> tuple[np.ndarray, np.ndarray]:
    """The outer nodes on the head surface: ``(node (q,), vertex (q,))``, int64, node ``node[i]``
    lies on head vertex ``vertex[i]``."""
    sv = np.asarray(fr.surface_vertex)
    node = np.where(sv >= 0)[0]
    return node, sv[node]


def head_surface(fr, X, jaw_angles, index=None) -> np.ndarray:
    """Head vertices [m] in the head frame, shape (n, 3), float64: the simulated outer nodes
    written in, the rims of the frontal face's openings following them (``FaceRig.opening_*``),
    the rest of the head moved kinematically by the jaw (its per-vertex amount).

    Args:
        fr: The face rig.
        X: Node positions [m], shape (p, 3), head frame.
        jaw_angles: (u, v) [rad].
        index: :func:`surface_index` of ``fr`` (default: computed).
    """
    node, vertex = surface_index(fr) if index is None else index
    V = fr.head_vertices.copy()
    if fr.vertex_jaw is not None and (jaw_angles[0] or jaw_angles[1]):
        m = fr.vertex_jaw > 0
        V[m] = fr.jaw.apply(V[m], fr.vertex_jaw[m], float(jaw_angles[0]), float(jaw_angles[1]))
    V[vertex] = X[node]
    if fr.opening_vertex is not None and len(fr.opening_vertex):  # rims of openings follow the skin
        ov, w = fr.opening_vertex, fr.opening_weight
        u = np.einsum("qc,qcd->qd", w, X[fr.opening_node] - fr.nodes[fr.opening_node])
        share = w.sum(1, keepdims=True)
        V[ov] = (1.0 - share) * V[ov] + share * fr.head_vertices[ov] + u
    return V


EYES = ("eye_L", "eye_R")
"""The eyeball parts, in the order of a gaze array's rows (left at +x, right)."""


def eye_gaze_rotation(yaw: float, pitch: float) -> np.ndarray:
    """An eyeball's rotation (3, 3) float64 for a gaze ``yaw`` (about +y, > 0 towards +x) and ``pitch``
    [rad] (> 0 up) in the head frame (y up, +z forward): ``R = Ry(yaw) Rx(-pitch)``, so the rest gaze
    +z goes to (sin yaw cos pitch, sin pitch, cos yaw cos pitch)."""
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    Ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, sp], [0.0, -sp, cp]])
    return Ry @ Rx


def eye_transforms(fr, gaze) -> dict:
    """Rest-to-current rigid maps of the eyeballs turned by ``gaze`` ((2, 2) [rad], per eye of :data:`EYES`
    its yaw and pitch; None: none turned): name -> (R (3, 3), c (3,) [m]) with ``p' = R (p - c) + c``,
    ``c`` the eyeball's centre (the mean of its rest vertices, as the lid contact's sphere)."""
    out = {}
    if gaze is None:
        return out
    g = np.asarray(gaze, np.float64).reshape(2, 2)
    for e, name in enumerate(EYES):
        if name in fr.parts and (g[e, 0] or g[e, 1]):
            out[name] = (eye_gaze_rotation(g[e, 0], g[e, 1]), np.asarray(fr.parts[name][0], np.float64).mean(axis=0))
    return out


def parts_at(fr, jaw_angles, gaze=None) -> dict:
    """The rigid parts (eyes, teeth, tongue) at ``jaw_angles`` and eye ``gaze`` (:func:`eye_transforms`):
    name -> vertices [m], (k, 3), head frame."""
    out = {name: fr.part_at(name, jaw_angles) for name in fr.parts}
    for name, (R, c) in eye_transforms(fr, gaze).items():
        out[name] = (out[name] - c) @ R.T + c
    return out


def fdp_points(fr, points, parts) -> np.ndarray:
    """FDP positions [m] of frames, shape (f, 84, 3), float32 (order ``fr.fdp_ids``).

    Args:
        points: Head vertices per frame [m], shape (f, n, 3).
        parts: Rigid part name -> vertices per frame [m], shape (f, k, 3).
    """
    out = np.zeros((len(points), len(fr.fdp_ids), 3), np.float32)
    for i, (part, f, b) in enumerate(zip(fr.fdp_part, fr.fdp_face, fr.fdp_bary)):
        if part == "head":
            out[:, i] = np.einsum("k,fkd->fd", b, points[:, fr.head_faces[f]])
        else:
            V = parts[str(part)]
            out[:, i] = np.einsum("k,fkd->fd", b, V[:, fr.parts[str(part)][1][f]])
    return out


def muscle_curves(rig, ctrl, samples: int) -> np.ndarray:
    """Muscle fibre polylines [m], shape (M, samples, 3), float64: each muscle's Bezier curves
    (Eq. 6.4.1's fibres) at control points ``ctrl`` (P, 3), sampled evenly along the chain."""
    from ..physics.muscle_stage import _bezier_np

    ctrl = np.asarray(ctrl, np.float64)
    out = np.zeros((len(rig.names), samples, 3))
    curve_m = rig.ctrl_muscle[rig.curve_ctrl[:, 0]]
    for m in range(len(rig.names)):
        cs = np.where(curve_m == m)[0]
        per = max(2, samples // len(cs))
        seq = [_bezier_np(ctrl[rig.curve_ctrl[c]][None], rig.curve_weight[c][None], np.linspace(0, 1, per)) for c in cs]
        P = np.concatenate(seq)
        out[m] = P[np.linspace(0, len(P) - 1, samples).round().astype(int)]
    return out


def _unit_value(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a number in [0, 1], got {value!r}") from None
    if not (np.isfinite(v) and 0.0 <= v <= 1.0):
        raise InputError(f"{name}: expected a value in [0, 1], got {value!r}")
    return v


def expression_activations(names: list[str], expr) -> np.ndarray:
    """An :class:`~facewarp.Expression`'s activation of each muscle instance (``_L`` / ``_R``
    sides), shape (M,), float32."""
    out = np.zeros(len(names), np.float32)
    for i, n in enumerate(names):
        side = n[-1] if n.endswith(("_L", "_R")) else None
        base = n[:-2] if side else n
        out[i] = expr.activation(base, side) if base in MUSCLES else 0.0
    return out


def activation_vector(names: list[str], activations) -> np.ndarray:
    """Activations as the (M,) float32 array the solver reads.

    Args:
        names: Muscle instance names (M,).
        activations: An :class:`~facewarp.Expression`, a dict muscle name -> value in [0, 1]
            (an instance name such as ``"zygomatic_major_L"``, or a Table 6.2 name such as
            ``"zygomatic_major"`` for both sides; missing muscles are 0), or an array (M,)
            in ``names`` order.

    Raises:
        InputError: unknown muscle, wrong length, or a value outside [0, 1] (NaN included).
    """
    from ..core.checks import check_activations

    activations = check_activations(activations, len(names))
    if hasattr(activations, "activation") and hasattr(activations, "jaw_u"):
        return expression_activations(names, activations)
    if isinstance(activations, dict):
        from ..expressions import muscle_instances

        out = np.zeros(len(names), np.float32)
        for key, value in activations.items():
            hit = set(muscle_instances(key, names, what="activations"))
            out[[i for i, n in enumerate(names) if n in hit]] = _unit_value(f"activations[{key!r}]", value)
        return out
    a = np.asarray(activations, dtype=np.float64)
    if a.shape != (len(names),):
        raise InputError(f"activations: expected a dict or an array of shape ({len(names)},), got shape {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a) | (a < 0.0) | (a > 1.0))
    if len(bad):
        raise InputError(f"activations: {names[bad[0]]} is {a[bad[0]]!r}, expected a value in [0, 1]")
    return a.astype(np.float32)


def jaw_vector(opening: float, side: float = 0.0) -> np.ndarray:
    """Jaw angles [rad] as the (2,) float32 array the solver reads: ``opening`` about the condyle
    u-axis (Sec. 6.4.3, 0..60 deg), ``side`` about the vertical v-axis (+-5 deg).

    Raises:
        InputError: a non-finite angle or one outside its range.
    """
    from ..expressions import JAW_U_MAX, JAW_V_MAX

    from ..core.checks import check_jaw_angles

    u, v = check_jaw_angles(opening, side)
    if not (np.isfinite(u) and -1e-9 <= u <= JAW_U_MAX + 1e-9):
        raise InputError(f"jaw opening: expected 0..{JAW_U_MAX:.4f} rad (0..60 deg), got {opening!r}")
    if not (np.isfinite(v) and abs(v) <= JAW_V_MAX + 1e-9):
        raise InputError(f"jaw side: expected within +-{JAW_V_MAX:.4f} rad (+-5 deg), got {side!r}")
    return np.array([max(u, 0.0), v], np.float32)
