"""Rigid head motion out of a marker take: per frame a similarity fit (Umeyama; the FDP
calibration's Eq. 4.3.3, :func:`~facewarp.geometry.fit_similarity`) of the take's *stable points* to the
same points on the head at rest, and the inverse of that fit applied to every point of the frame.
The muscles move the rest of the face; what is left is the expression in the head's own frame.

Stable points (:data:`STABLE_POINTS`, MPEG-4 FDPs that sit on skin over bone and that no muscle of
the model moves much): the forehead at the hairline (11.1, 11.2, 11.3), the nose bridge (9.6, 9.7
upper edge of the nose bone, 9.12 its middle lower edge) and the ear roots (10.9, 10.10 upper and
10.7, 10.8 lower contact of ear and face). Brows, eye corners, cheeks and anything on the lips or
jaw move with the expression and are left out. A stable point that still moves with the face in
a frame (the nose bridge under a strong brow, a slipped marker) is dropped from that frame's fit
(:data:`OUTLIER_FLOOR_M`). A take may name its own stable set (``points=``), e.g. head-band
markers given as ``v<index>`` vertices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.checks import check_bool, describe
from ..core.errors import InputError
from ..geometry.similarity import fit_similarity, point_spread
from .tracks import MarkerTrack

__all__ = ["OUTLIER_FLOOR_M", "STABLE_POINTS", "HeadMotion", "remove_head_motion"]

STABLE_POINTS = ("11.1", "11.2", "11.3", "9.6", "9.7", "9.12", "10.9", "10.10", "10.7", "10.8")
"""FDPs that move with the skull only: forehead (hairline), nose bridge, ear roots."""

OUTLIER_FLOOR_M = 0.5e-3
"""A stable point whose distance after a frame's fit exceeds both this [m] and three times the
median distance is left out and the fit made again (twice at most, three points kept): skin over
the nose bone follows a strong brow a millimetre or so, and one marker may slip."""

MIN_SPREAD_M = 0.01
"""The stable points present in a frame must spread at least this far [m] in two directions (a
plane's worth: the second singular value of the centred points), else the frame's fit is not
trusted and the previous frame's pose is kept."""


@dataclass
class HeadMotion:
    """The head's pose in each frame of a take: ``data = scale * rotation @ rest + translation``.

    Attributes:
        rotation: (T, 3, 3) float64, proper rotations.
        translation: (T, 3) float64 [m].
        scale: (T,) float64 (1 for a rigid fit; else the take's size over the head's).
        residual: (T,) float64 [m], RMS distance of the stable points the fit kept (NaN where held).
        used: (T,) int64, how many stable points each frame's fit kept (0 where held; fewer than
            present where some moved with the face, :data:`OUTLIER_FLOOR_M`).
        held: (T,) bool, frames with fewer than three well spread stable points, which keep the
            pose of the frame before (the first good frame's for the frames before it).
        points: The stable point names the fit looked for.
    """

    rotation: np.ndarray
    translation: np.ndarray
    scale: np.ndarray
    residual: np.ndarray
    used: np.ndarray
    held: np.ndarray
    points: tuple

    @property
    def frames(self) -> int:
        return int(len(self.scale))

    def angles(self) -> np.ndarray:
        """(T, 3) float64 [rad]: yaw (about y), pitch (about x), roll (about z) of ``R = Ry Rx Rz``."""
        R = self.rotation
        pitch = np.arcsin(np.clip(-R[:, 1, 2], -1.0, 1.0))
        yaw = np.arctan2(R[:, 0, 2], R[:, 2, 2])
        roll = np.arctan2(R[:, 1, 0], R[:, 1, 1])
        return np.stack([yaw, pitch, roll], axis=1)

    def to_dict(self) -> dict:
        """A report: the fitted points, frames held, and per frame angles [deg], translation [mm],
        scale and residual [mm]."""
        return {
            "stable_points": list(self.points), "frames_held": int(self.held.sum()),
            "residual_mm_max": float(np.nanmax(self.residual) * 1e3) if (~self.held).any() else None,
            "yaw_pitch_roll_deg": np.round(np.degrees(self.angles()), 3).tolist(),
            "translation_mm": np.round(self.translation * 1e3, 3).tolist(),
            "scale": np.round(self.scale, 6).tolist(),
            "residual_mm": [None if h else round(float(r) * 1e3, 4) for r, h in zip(self.residual, self.held)],
            "points_used": self.used.tolist(),
        }


def remove_head_motion(track: MarkerTrack, rest, *, points=None, scale: bool = True) -> tuple[MarkerTrack, HeadMotion]:
    """The take in the head's own frame and the head's pose per frame.

    Args:
        track: The take (:class:`~facewarp.MarkerTrack`), in metres.
        rest: The head at rest: a mapping from point name to position [m], shape (3,), holding at
            least the stable points the take has (e.g. ``dict(zip(fr.fdp_ids, sim.fdp_points()))``).
        points: The stable point names (default :data:`STABLE_POINTS`).
        scale: Fit a uniform scale too (default): a take of a larger or smaller face comes out at
            this head's size. False: a rigid fit.

    Returns:
        ``(track in the head's frame, HeadMotion)``; the new track's positions are
        ``R^T (p - t) / s`` per frame, its source the old one's.

    Raises:
        InputError: no frame has three stable points present and spread over a plane.
    """
    if not isinstance(track, MarkerTrack):
        raise InputError(f"track: expected a MarkerTrack, got {describe(track)}")
    scale = check_bool("scale", scale)
    if not hasattr(rest, "items"):
        raise InputError(f"rest: expected a mapping from point names to positions, got {describe(rest)}")
    points = tuple(STABLE_POINTS if points is None else (str(p) for p in points))
    cols = [track.names.index(p) for p in points if p in track.names and p in rest]
    if len(cols) < 3:
        raise InputError(f"{track.source or 'track'}: removing head motion needs three or more of the stable points "
                         f"{', '.join(points)} in the take, it has {len(cols)}")
    Q = np.array([np.asarray(rest[track.names[c]], dtype=np.float64).reshape(3) for c in cols])
    P = track.positions
    T = track.frames
    R = np.tile(np.eye(3), (T, 1, 1))
    t = np.zeros((T, 3))
    s = np.ones(T)
    res = np.full(T, np.nan)
    used = np.zeros(T, dtype=np.int64)
    held = np.ones(T, dtype=bool)
    for f in range(T):
        X = P[f, cols]
        ok = np.isfinite(X).all(axis=1)
        if ok.sum() < 3 or point_spread(Q[ok])[1] < MIN_SPREAD_M:
            continue
        keep = np.nonzero(ok)[0]
        S = fit_similarity(Q[keep], X[keep], with_scale=scale)
        for _ in range(2):  # leave out the points that moved with the face (OUTLIER_FLOOR_M), fit again
            d = np.linalg.norm(S.apply(Q[keep]) - X[keep], axis=1)
            out = d > max(OUTLIER_FLOOR_M, 3.0 * float(np.median(d)))
            if not out.any() or len(keep) - out.sum() < 3 or point_spread(Q[keep[~out]])[1] < MIN_SPREAD_M:
                break
            keep = keep[~out]
            S = fit_similarity(Q[keep], X[keep], with_scale=scale)
        R[f], t[f], s[f] = S.rotation, S.translation, S.scale
        res[f] = float(np.sqrt(np.mean(np.sum((S.apply(Q[keep]) - X[keep]) ** 2, axis=1))))
        used[f] = len(keep)
        held[f] = False
    if held.all():
        raise InputError(f"{track.source or 'track'}: no frame has three stable points ({', '.join(points)}) present "
                         f"and spread over {MIN_SPREAD_M * 1e3:g} mm")
    first = int(np.argmax(~held))
    for f in range(T):  # held frames keep the pose before them (the first good one at the start)
        if held[f]:
            g = f - 1 if f > first else first
            R[f], t[f], s[f] = R[g], t[g], s[g]
    local = np.einsum("tji,tkj->tki", R, P - t[:, None, :]) / s[:, None, None]
    out = MarkerTrack(track.fps, list(track.names), local, source=track.source)
    return out, HeadMotion(R, t, s, res, used, held, points)
