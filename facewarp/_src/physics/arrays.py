"""Device-array helpers shared by the Model's parts: Warp asked once, CSR groupings, per-element head
indices and the jaws' axes (:mod:`.builder`'s ``finalize`` and the stage arrays beside their stages:
:class:`~.muscle_stage.MuscleArrays`, :class:`~.muscle_stage.SupportArrays`, :class:`~.model.JawNodeArrays`,
:class:`~.contact.ContactArrays`)."""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..core.warp import get_warp

__all__ = ["group_indices", "head_ids", "jaw_axes", "warp"]

_WARP = []


def warp():
    """Warp (:func:`~facewarp._src.core.warp.get_warp`), asked once per process and kept: the
    builder and the Model make their arrays without calling back out of the physics package."""
    if not _WARP:
        _WARP.append(get_warp())
    return _WARP[0]


def group_indices(keys, groups=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR grouping for the deterministic gathers: the entries of each group in ascending order.

    Args:
        keys: Group of each entry, shape (k,), int.
        groups: The groups to list, ascending, shape (g,) (default: the distinct keys); a group
            with no entry gets an empty range.

    Returns:
        ``(groups, start, order)``: group ``j`` owns entries ``order[start[j]:start[j + 1]]``;
        shapes (g,), (g + 1,), (k,), int64.
    """
    keys = np.asarray(keys, dtype=np.int64)
    groups = np.unique(keys) if groups is None else np.asarray(groups, dtype=np.int64)
    order = np.argsort(keys, kind="stable")
    start = np.searchsorted(keys[order], groups, side="left")
    return groups, np.r_[start, len(keys)], order


def jaw_axes(wp, jaw, device):
    """The jaws' pivots [m] and unit axes, one per head: three wp.array (H,) of wp.vec3 (``jaw``:
    one joint or a list of H, each with ``pivot``, ``u_axis``, ``v_axis``; None: the defaults of
    a head without a jaw)."""
    jaws = list(jaw) if isinstance(jaw, (list, tuple)) else [jaw]
    P = np.zeros((len(jaws), 3), np.float32)
    U = np.tile(np.array([1.0, 0.0, 0.0], np.float32), (len(jaws), 1))
    V = np.tile(np.array([0.0, 1.0, 0.0], np.float32), (len(jaws), 1))
    for h, j in enumerate(jaws):
        if j is not None:
            P[h], U[h], V[h] = (np.asarray(a, np.float64).astype(np.float32) for a in (j.pivot, j.u_axis, j.v_axis))
    return tuple(wp.array(a, dtype=wp.vec3, device=device) for a in (P, U, V))


def head_ids(wp, head, count: int, device):
    """Each element's head (int32 device array (count,)); ``head`` None: all head 0."""
    h = np.zeros(count, np.int32) if head is None else np.asarray(head, np.int32).reshape(-1)
    if len(h) != count:
        raise InputError(f"head: expected {count} head indices, got {len(h)}")
    return wp.array(h, dtype=wp.int32, device=device)

