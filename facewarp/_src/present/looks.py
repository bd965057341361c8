"""How a head looks in a DCC tool: part colours, coloured face groups (lips, iris, pupil) and a
framing camera, for the USD writer (``usd_export.AnimationWriter``'s ``part_colors``,
``subsets``, ``camera`` and ``lights``).

The groups are found on the rig's own geometry, so they follow any adapted head:

- **lips**: skin faces inside the outer lip contour (FDPs 8.1-8.10, MPEG-4) seen from the front
  (the contour's points sorted by angle about their centroid in the x-y plane), and in front of
  the contour's mean depth less :data:`LIP_DEPTH`;
- **iris / pupil**: eye faces whose direction from the eyeball's centre is within
  :data:`IRIS_ANGLE` / :data:`PUPIL_ANGLE` of the gaze (+z, the head frame's forward axis); the
  rest of the eye is sclera;
- **teeth** are one colour: the template's tooth rows are single bands of faces from crown to
  root, with no faces of their own for gums.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["COLORS", "IRIS_ANGLE", "LIP_DEPTH", "PUPIL_ANGLE", "head_camera", "head_looks", "lip_faces"]

COLORS = {
    "skin": (0.80, 0.58, 0.48),
    "lips": (0.70, 0.34, 0.35),
    "sclera": (0.94, 0.93, 0.89),
    "iris": (0.24, 0.40, 0.55),
    "pupil": (0.02, 0.02, 0.02),
    "teeth": (0.95, 0.93, 0.85),
    "tongue": (0.76, 0.36, 0.38),
}
"""Linear RGB (0..1) of each look."""

IRIS_ANGLE = math.radians(30.0)
"""Half-angle of the iris seen from the eyeball's centre [rad] (an iris about 12 mm across on a
24 mm eyeball: asin(6 / 12) = 30 deg)."""

PUPIL_ANGLE = math.radians(12.0)
"""Half-angle of the pupil [rad] (about 4-5 mm across in room light)."""

LIP_DEPTH = 0.012
"""How far behind the lip contour's mean depth faces still count as lips [m]."""

_LIP_CONTOUR = tuple(f"8.{k}" for k in range(1, 11))


def _rest_fdps(fr) -> dict:
    """Rest positions [m] of the FDPs on the skin: id -> (3,) float64."""
    out = {}
    V = np.asarray(fr.head_vertices, np.float64)
    F = np.asarray(fr.head_faces)
    for fid, part, f, b in zip(fr.fdp_ids, fr.fdp_part, fr.fdp_face, fr.fdp_bary):
        if str(part) == "head":
            out[str(fid)] = np.asarray(b, np.float64) @ V[F[int(f)]]
    return out


def _inside(P: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Points P (k, 2) inside the closed polygon poly (n, 2) (even-odd rule), shape (k,) bool."""
    x, y = P[:, 0:1], P[:, 1:2]
    x0, y0 = poly[:, 0][None], poly[:, 1][None]
    x1, y1 = np.roll(poly[:, 0], -1)[None], np.roll(poly[:, 1], -1)[None]
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (crosses & (x < xc)).sum(1) % 2 == 1


def lip_faces(fr) -> np.ndarray:
    """Indices of the skin faces that are lips (see the module docstring), shape (k,), int64."""
    fdp = _rest_fdps(fr)
    pts = np.array([fdp[i] for i in _LIP_CONTOUR if i in fdp])
    if len(pts) < 4:
        return np.zeros(0, np.int64)
    c = pts.mean(0)
    order = np.argsort(np.arctan2(pts[:, 1] - c[1], pts[:, 0] - c[0]))
    poly = pts[order, :2]
    V = np.asarray(fr.head_vertices, np.float64)
    C = V[np.asarray(fr.head_faces)].mean(1)
    ok = _inside(C[:, :2], poly) & (C[:, 2] > c[2] - LIP_DEPTH)
    return np.flatnonzero(ok)


def head_looks(fr) -> dict:
    """Part colours and face groups of a face rig's head for ``usd_export.AnimationWriter``.

    Args:
        fr: A :class:`~facewarp.FaceRig` (head vertices and faces, FDPs, ``parts``).

    Returns:
        ``{"part_colors": {part: RGB}, "subsets": {"Skin" or part: {name: (faces (k,) int64, RGB)}}}``.
    """
    part_colors, subsets = {}, {}
    lips = lip_faces(fr)
    if len(lips):
        subsets["Skin"] = {"Lips": (lips, COLORS["lips"])}
    for name, (V, F) in dict(fr.parts).items():
        V, F = np.asarray(V, np.float64), np.asarray(F)
        low = str(name).lower()
        C = V[F].mean(1)
        if "eye" in low:
            part_colors[name] = COLORS["sclera"]
            d = C - V.mean(0)
            cos = d[:, 2] / np.maximum(np.linalg.norm(d, axis=1), 1e-12)
            pupil = np.flatnonzero(cos >= math.cos(PUPIL_ANGLE))
            iris = np.flatnonzero((cos >= math.cos(IRIS_ANGLE)) & (cos < math.cos(PUPIL_ANGLE)))
            subsets[name] = {"Iris": (iris, COLORS["iris"]), "Pupil": (pupil, COLORS["pupil"])}
        elif "teeth" in low or "tooth" in low:
            part_colors[name] = COLORS["teeth"]
        elif "tongue" in low:
            part_colors[name] = COLORS["tongue"]
    return {"part_colors": part_colors, "subsets": subsets}


def head_camera(fr, *, focal_length_mm: float = 50.0, vertical_aperture_mm: float = 15.2908,
                margin: float = 1.15) -> dict:
    """A camera in front of the head (+z, the face's side) that frames its whole height.

    Args:
        fr: The face rig (its rest head vertices [m]).
        focal_length_mm: Lens; with USD's default vertical aperture (15.2908 mm) 50 mm sees 17.4 deg.
        vertical_aperture_mm: The camera's vertical aperture [mm].
        margin: Room around the head (1.15: 15 %).

    Returns:
        ``{"position", "target", "up"}`` (3,) float64 [m] and ``"focal_length_mm"``.
    """
    V = np.asarray(fr.head_vertices, np.float64)
    lo, hi = V.min(0), V.max(0)
    target = 0.5 * (lo + hi)
    half = 0.5 * margin * max(hi[1] - lo[1], hi[0] - lo[0])
    dist = half * focal_length_mm / (0.5 * vertical_aperture_mm) + hi[2] - target[2]
    return {"position": target + np.array([0.0, 0.0, dist]), "target": target, "up": np.array([0.0, 1.0, 0.0]),
            "focal_length_mm": float(focal_length_mm)}
