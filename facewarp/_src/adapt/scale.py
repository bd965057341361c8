"""The scale of a scan from its FDPs against human proportions (``facewarp adapt --units auto``).

Three distances between FDP-derived points, none of which depends on the pose:

- **eye distance**: between the centres of the two eye fissures (midpoints of 3.7-3.11 and
  3.12-3.8), which is close to the interpupillary distance. Adults: mean 63 mm, SD 3.8 mm,
  nearly all within 52-75 mm (Dodgson 2004, "Variation and extrema of human interpupillary
  distance", Proc. SPIE 5291).
- **eye to mouth**: from the midpoint of the two eye centres to the midpoint of the lip corners
  (8.3, 8.4). Farkas (1994, "Anthropometry of the Head and Face") gives the upper face height
  n-sto as about 71 mm (women) to 77 mm (men), SD about 4 mm; the eye line lies about 8-10 mm
  below the nasion, so the eye-to-mouth distance is about 60-70 mm, 55-80 mm for nearly all adults.
- **nose length**: from the midpoint of the eye centres to the nose tip (9.3). Farkas's nasal
  length n-prn is about 47-53 mm (SD 3-4 mm); from the eye line (below the nasion, but the tip
  stands forward) the distance is about 42-50 mm, 36-58 mm for nearly all adults.

:data:`HUMAN_RANGES_M` holds those ranges. The reference values of the estimate
(:data:`REFERENCE_M`: 62.0, 67.1 and 47.7 mm, inside each range and near the adult means) are
the default template's own distances on its fine surface (level 1 and up; level 0's coarse nose
tip is 2 mm lower), so that a scan of the template's own proportions comes back at scale 1.
The estimated metres per file unit is the geometric mean over the measures found of
``reference / measured``; when the measures disagree by more than :data:`SPREAD_LIMIT` (one
FDP pair is off, e.g. a detector's miss) their median instead.

The estimate cannot be better than people differ: a person whose face is 5 % larger than
average in every direction comes back 5 % off. On the synthetic scans (proportions drawn at
half to all of two standard deviations of adult norms, every direction) the error is within 5 %
for most faces and up to about 6 % for the largest and smallest (``benchmarks/likeness.py``).

A scan given in explicit units is checked by the same measures: if the implied factor differs
from 1 by more than :data:`FAR_FACTOR` (the eyes would be below 42 or above 95 mm apart), the
units are wrong, and :func:`check_human_scale` says so in one line naming the measured eye
distance and the likely factor.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError

__all__ = ["FAR_FACTOR", "HUMAN_RANGES_M", "PLAUSIBLE_EXTENT_M", "REFERENCE_M", "SPREAD_LIMIT", "ScaleEstimate", "check_human_scale",
           "estimate_scale", "face_measures", "plausible_extent", "prescale", "reference_measures"]

HUMAN_RANGES_M: dict[str, tuple[float, float]] = {
    "eye_distance": (0.052, 0.075),
    "eye_to_mouth": (0.055, 0.080),
    "nose_length": (0.036, 0.058),
}
"""Adult ranges [m] of the measures (module docstring: Dodgson 2004; Farkas 1994)."""

FAR_FACTOR = 1.5
"""A scan whose FDPs imply a scale factor beyond this (or below its inverse) in the given units
is refused: the units are wrong (a child's eye distance, about 50 mm, is within it)."""

PLAUSIBLE_EXTENT_M = (0.12, 0.8)
"""Largest side of the scan's bounding box [m] of a plausible head, face or bust; outside it the
default units (metres) give way to ``auto``."""

_HEAD_EXTENT_M = 0.26  # a typical head-and-neck scan's largest side, for the pre-scale before detection


REFERENCE_M: dict[str, float] = {"eye_distance": 0.0620, "eye_to_mouth": 0.06715, "nose_length": 0.04767}
"""The default template's measures [m] on its fine surface (checked against level 1 in the tests)."""

SPREAD_LIMIT = 1.25
"""Largest over smallest factor above which the median replaces the geometric mean."""


def _eye_centres(lm: dict):
    if all(k in lm for k in ("3.7", "3.11", "3.12", "3.8")):
        a = 0.5 * (np.asarray(lm["3.7"], float) + np.asarray(lm["3.11"], float))
        b = 0.5 * (np.asarray(lm["3.12"], float) + np.asarray(lm["3.8"], float))
        return a, b
    if "3.5" in lm and "3.6" in lm:
        return np.asarray(lm["3.5"], float), np.asarray(lm["3.6"], float)
    return None


def face_measures(landmarks: dict) -> dict[str, float]:
    """The measures of the module docstring that ``landmarks`` allow, in the landmarks' units.

    Args:
        landmarks: FDP id -> position, shape (3,), any length unit.

    Returns:
        Measure name -> distance (same unit as the landmarks); measures lacking FDPs are left out.
    """
    out: dict[str, float] = {}
    eyes = _eye_centres(landmarks)
    if eyes is None:
        return out
    a, b = eyes
    out["eye_distance"] = float(np.linalg.norm(a - b))
    mid = 0.5 * (a + b)
    if "8.3" in landmarks and "8.4" in landmarks:
        mouth = 0.5 * (np.asarray(landmarks["8.3"], float) + np.asarray(landmarks["8.4"], float))
        out["eye_to_mouth"] = float(np.linalg.norm(mid - mouth))
    if "9.3" in landmarks:
        out["nose_length"] = float(np.linalg.norm(mid - np.asarray(landmarks["9.3"], float)))
    return out


def reference_measures() -> dict[str, float]:
    """The reference values [m] of :func:`estimate_scale` (:data:`REFERENCE_M`)."""
    return dict(REFERENCE_M)


class ScaleEstimate:
    """The scale of a scan from its FDPs.

    Attributes:
        metres_per_unit: Estimated length of one file unit [m].
        measures: Measure name -> distance in file units.
        factors: Measure name -> ``reference [m] / measured [file units]``.
        spread: Largest factor over the smallest (1 when the measures agree).
        estimator: ``"geometric mean"`` or ``"median"`` (spread above :data:`SPREAD_LIMIT`).
    """

    def __init__(self, measures: dict, factors: dict):
        self.measures = dict(measures)
        self.factors = dict(factors)
        f = np.array(list(factors.values()))
        self.spread = float(f.max() / f.min())
        self.estimator = "geometric mean" if self.spread <= SPREAD_LIMIT else "median"
        self.metres_per_unit = float(np.exp(np.mean(np.log(f))) if self.spread <= SPREAD_LIMIT else np.median(f))

    def to_dict(self) -> dict:
        return {"metres_per_unit": self.metres_per_unit, "measures_file_units": self.measures,
                "factors": self.factors, "spread": self.spread, "estimator": self.estimator,
                "reference_m": reference_measures(),
                "human_ranges_m": {k: list(v) for k, v in HUMAN_RANGES_M.items()}}


def estimate_scale(landmarks: dict, *, what: str = "landmarks") -> ScaleEstimate:
    """Metres per file unit of a scan from its FDPs (see the module docstring).

    Args:
        landmarks: FDP id -> position (3,) in the scan's file units.
        what: How to name the landmarks in an error.

    Raises:
        InputError: the eye corners (3.7, 3.11, 3.12, 3.8) or pupils (3.5, 3.6) are missing,
            or two FDPs coincide.
    """
    m = face_measures(landmarks)
    if "eye_distance" not in m:
        raise InputError(f"{what}: --units auto needs the eye corners (FDPs 3.7, 3.11, 3.12, 3.8) or the pupils "
                         "(3.5, 3.6) to measure the scale")
    if not all(v > 0 and np.isfinite(v) for v in m.values()):
        raise InputError(f"{what}: FDPs coincide, the scale cannot be measured ({m})")
    ref = reference_measures()
    return ScaleEstimate(m, {k: ref[k] / v for k, v in m.items()})


def check_human_scale(landmarks_m: dict, units: str, what: str) -> ScaleEstimate | None:
    """Refuse FDPs far outside human proportions in the given units (one line: the measured eye
    distance and the likely factor).

    Args:
        landmarks_m: FDP id -> position [m] (the file's numbers times the given unit).
        units: The unit the user gave (for the message).
        what: The scan's name (for the message).

    Returns:
        The estimate (None when the eye FDPs are missing: nothing to check).
    """
    try:
        est = estimate_scale(landmarks_m, what=what)
    except InputError:
        return None
    f = est.metres_per_unit
    if not 1.0 / FAR_FACTOR <= f <= FAR_FACTOR:
        eye = est.measures["eye_distance"]
        lo, hi = HUMAN_RANGES_M["eye_distance"]
        raise InputError(f"{what}: the FDPs put the eyes {eye * 1e3:.1f} mm apart in units {units!r} (adults: "
                         f"{lo * 1e3:.0f}-{hi * 1e3:.0f} mm): the scan looks {1 / f:.2g}x human size, likely factor "
                         f"{f:.3g} (give --units auto)")
    return est


def plausible_extent(V_m) -> bool:
    """Whether the largest side of the bounding box of V [m], shape (n, 3), is a head's."""
    e = float(np.ptp(np.asarray(V_m, float), axis=0).max())
    return PLAUSIBLE_EXTENT_M[0] <= e <= PLAUSIBLE_EXTENT_M[1]


def prescale(V) -> float:
    """A first guess of metres per unit from the bounding box alone (before the FDPs are found)."""
    e = float(np.ptp(np.asarray(V, float), axis=0).max())
    if not e > 0:
        raise InputError("scan: all vertices coincide")
    return _HEAD_EXTENT_M / e
