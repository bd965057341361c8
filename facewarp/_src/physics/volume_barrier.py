"""The volume barrier of the implicit step: a floor under every tet's volume.

The volume term of Eq. 6.4.8, ``k / 2 C^2`` with ``C = V / V0 - 1``, stays finite when a tet
flattens (``k / 2`` at V = 0), so muscles strong enough (every muscle at 1.0 on the default head)
hold a tet at a few 1e-5 of its rest volume, where the next jaw carry or control change inverts
it. The implicit solver's potential therefore adds, per tet, the barrier of IPC (Li et al. 2020)
on the volume ratio ``r = V / V0 = C + 1``:

    B(r) = kappa k phi(r),   phi(r) = -(r - r_b)^2 ln(r / r_b) for 0 < r < r_b, 0 for r >= r_b,

which is C2 at ``r_b`` (value, slope and curvature 0 there), convex, and infinite at r = 0: no
step of the line search inverts a tet, and a tet pushed by a force F (in units of k over its
height) settles where ``kappa phi'(r) = -F``: about 3.7 % of its rest volume for F = k, 2 % for
F = 10 k. With ``r_b`` = :data:`VOLUME_BARRIER_ONSET` (0.05) the barrier is zero for every tet above
a twentieth of its rest volume (the presets stay above a fifth: their results do not change);
``kappa`` = :data:`VOLUME_BARRIER_STIFFNESS` (100). :data:`VOLUME_FLOOR` (2 %) is the documented
floor: :class:`~facewarp.FaceSimulator` retries a frame that ends below it with sub-steps and
counts frames that stay below it (``FaceSimulator.stats``). The onset is low on purpose: a barrier
that starts at a tenth kept lips pushed against the teeth by 6 N a node from flattening their tets
and slid one 14 mm around the lower arch into it (``tests/test_contact.py``). The Verlet reference
(explicit) has no barrier.

Derivatives (``s = r - r_b``): ``phi' = -2 s ln(r / r_b) - s^2 / r``,
``phi'' = -2 ln(r / r_b) - 4 s / r + s^2 / r^2`` (>= 0 on (0, r_b)). The gradient is
``kappa k phi'(r) / V0 dV/dx`` and the Hessian block Gauss-Newton ``kappa k phi''(r) / V0^2 dV/dx
dV/dx^T`` (the volume term's own form). At r <= 0 the energy is :data:`INVERTED_ENERGY` and the
derivatives are taken at ``r = 1e-6``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["VOLUME_BARRIER_ONSET", "VOLUME_BARRIER_STIFFNESS", "INVERTED_ENERGY", "VOLUME_FLOOR", "barrier", "barrier_d",
           "barrier_dd"]

VOLUME_BARRIER_ONSET = 0.05
"""Volume ratio V / V0 below which the barrier acts (r_b)."""
VOLUME_BARRIER_STIFFNESS = 100.0
"""kappa: the barrier in units of the tet's volume stiffness ``tet_k`` [J]."""
VOLUME_FLOOR = 0.02
"""Documented floor on V / V0 (2 %): frames ending below it are retried with sub-steps and reported."""
INVERTED_ENERGY = 1.0e30
"""Energy [J] of an inverted tet (never accepted by a line search)."""
_R_MIN = 1.0e-6


def barrier(r) -> np.ndarray:
    """phi(r) of the module doc (float64; ``INVERTED_ENERGY`` where r <= 0), r: volume ratios (t,)."""
    r = np.asarray(r, np.float64)
    rc = np.clip(r, _R_MIN, VOLUME_BARRIER_ONSET)
    s = rc - VOLUME_BARRIER_ONSET
    out = -s * s * np.log(rc / VOLUME_BARRIER_ONSET)
    return np.where(r <= 0.0, INVERTED_ENERGY, out)


def barrier_d(r) -> np.ndarray:
    """phi'(r) (0 above the onset), shape of r, float64."""
    rc = np.clip(np.asarray(r, np.float64), _R_MIN, VOLUME_BARRIER_ONSET)
    s = rc - VOLUME_BARRIER_ONSET
    return -2.0 * s * np.log(rc / VOLUME_BARRIER_ONSET) - s * s / rc


def barrier_dd(r) -> np.ndarray:
    """phi''(r) (0 above the onset), shape of r, float64."""
    rc = np.clip(np.asarray(r, np.float64), _R_MIN, VOLUME_BARRIER_ONSET)
    s = rc - VOLUME_BARRIER_ONSET
    return -2.0 * np.log(rc / VOLUME_BARRIER_ONSET) - 4.0 * s / rc + s * s / (rc * rc)
