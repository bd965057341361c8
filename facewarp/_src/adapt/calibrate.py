"""Range data calibration: a similarity transform from the scan into the template frame.

Thesis Sec. 4.3.2. Every scan vertex ``q`` is mapped by (Eq. 4.3.2, 4.3.3)::

    q* = S R (q - q_c) + p_c

with a uniform scale ``S = s I``, a rotation ``R``, the scan's rotation centre ``q_c`` and the
template's ``p_c``. The thesis builds ``q_c``/``p_c`` from 8 FDPs (Eq. 4.3.4: 2.1, 11.1, 3.7,
3.12, 8.3, 8.4, 10.9, 10.10) and ``R`` from three axis angles. Real scans often miss the
hairline (11.1) and the ear points (10.9, 10.10), so here the same map is found by least
squares (Umeyama 1991) from any >= 4 non-coplanar FDPs shared by scan and template: the
centres ``q_c``, ``p_c`` become the FDP centroids, ``s`` and ``R`` minimise
``sum_i ||s R (q_i - q_c) + p_c - p_i||^2``. With the 8 thesis points present this is the
least-squares version of Eq. 4.3.4 (the same points, every axis used at once).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.errors import InputError
from ..geometry.similarity import Similarity, point_spread, fit_similarity

__all__ = [
    "CALIBRATION_FDPS",
    "Calibration",
    "Similarity",
    "calibrate",
    "fit_similarity",
]

CALIBRATION_FDPS: tuple[str, ...] = ("2.1", "11.1", "3.7", "3.12", "8.3", "8.4", "10.9", "10.10")
"""The thesis's calibration FDPs (Sec. 4.3.2, Eq. 4.3.4)."""

COPLANAR_RATIO = 1e-3
"""Point sets whose smallest/largest spread (singular values of the centred points) is below
this are called coplanar."""


@dataclass
class Calibration:
    """Result of :func:`calibrate`.

    Attributes:
        transform: Scan frame -> template frame (Eq. 4.3.3).
        fdps_used: FDP ids used for the fit, numerically sorted.
        thesis_set: Whether the points came from :data:`CALIBRATION_FDPS` (else all shared FDPs).
        rms_residual: RMS distance [template units] between mapped scan FDPs and template FDPs.
        residuals: FDP id -> residual distance [template units].
    """

    transform: Similarity
    fdps_used: tuple[str, ...]
    thesis_set: bool
    rms_residual: float
    residuals: dict[str, float]

    def to_dict(self) -> dict:
        return {
            "transform": self.transform.to_dict(),
            "fdps_used": list(self.fdps_used),
            "thesis_set": self.thesis_set,
            "rms_residual": self.rms_residual,
            "residuals": dict(self.residuals),
        }


def _sort_ids(ids) -> list[str]:
    def key(i):
        try:
            g, k = str(i).split(".")
            return (0, int(g), int(k), "")
        except ValueError:
            return (1, 0, 0, str(i))

    return sorted(ids, key=key)


def calibrate(
    scan_landmarks: dict[str, np.ndarray],
    template_landmarks: dict[str, np.ndarray],
    *,
    fdps=None,
    with_scale: bool = True,
) -> Calibration:
    """Similarity from the scan's frame into the template's, from shared FDPs (Sec. 4.3.2).

    Point choice: the shared FDPs among :data:`CALIBRATION_FDPS` when at least 4 of them are
    shared and not coplanar; else every shared FDP. ``fdps`` overrides the choice.

    Args:
        scan_landmarks: FDP id -> scan position, shape (3,), in the scan's frame and units.
        template_landmarks: FDP id -> template position [m], shape (3,).
        fdps: Optional explicit FDP ids to use.
        with_scale: Fit the scale (else a rigid transform).

    Returns:
        :class:`Calibration`.

    Raises:
        InputError: Fewer than 4 usable shared FDPs, or the shared FDPs are coplanar.
    """
    from ..core.checks import check_landmark_dict

    check_landmark_dict("scan_landmarks", scan_landmarks)
    check_landmark_dict("template_landmarks", template_landmarks)
    shared = [k for k in scan_landmarks if k in template_landmarks]
    if fdps is not None:
        missing = [k for k in fdps if k not in scan_landmarks or k not in template_landmarks]
        if missing:
            raise InputError(f"calibration FDPs {', '.join(missing)} are not in both the scan and the template landmarks")
        candidates = [list(fdps)]
    else:
        thesis = [k for k in CALIBRATION_FDPS if k in shared]
        candidates = [thesis, shared] if len(thesis) >= 4 else [shared]
    chosen = None
    for ids in candidates:
        if len(ids) < 4:
            continue
        Q = np.array([np.asarray(scan_landmarks[k], dtype=np.float64).reshape(3) for k in ids])
        P = np.array([np.asarray(template_landmarks[k], dtype=np.float64).reshape(3) for k in ids])
        if not (np.isfinite(Q).all() and np.isfinite(P).all()):
            raise InputError("calibration: a landmark position is not finite")
        sq, sp = point_spread(Q), point_spread(P)
        if sq[0] <= 0 or sp[0] <= 0 or sq[2] < COPLANAR_RATIO * sq[0] or sp[2] < COPLANAR_RATIO * sp[0]:
            continue
        chosen = (ids, Q, P)
        break
    if chosen is None:
        n = max(len(c) for c in candidates) if candidates else 0
        if n < 4:
            raise InputError(
                f"calibration needs at least 4 FDPs shared by scan and template, got {n}"
                + (f" ({', '.join(_sort_ids(shared))})" if shared else "")
            )
        raise InputError(f"calibration FDPs are coplanar ({', '.join(_sort_ids(candidates[-1]))}): add a point off their plane")
    ids, Q, P = chosen
    T = fit_similarity(Q, P, with_scale=with_scale)
    r = np.linalg.norm(T.apply(Q) - P, axis=1)
    order = _sort_ids(ids)
    res = {k: float(r[ids.index(k)]) for k in order}
    return Calibration(
        transform=T,
        fdps_used=tuple(order),
        thesis_set=fdps is None and ids is candidates[0] and len(candidates) == 2,
        rms_residual=float(np.sqrt(np.mean(r**2))),
        residuals=res,
    )
