"""What both backends of :class:`~facewarp.FaceBatch` share: the options, the rig list, poses and
activation rows checked, and :class:`BatchBase` (head indices, placements, streams, advance)."""

from __future__ import annotations

import numpy as np

from ..core.checks import check_array, check_int, describe
from ..core.errors import InputError
from ..physics.face_rig import FaceRig
from .readout import activation_vector, jaw_vector

__all__ = ["BACKENDS", "MAX_BATCH_HEADS", "BatchBase", "activation_rows", "jaw_rows", "muscle_count"]

BACKENDS = ("auto", "model", "heads")
"""How :class:`FaceBatch` holds its heads: ``"model"`` (N faces in one Model, one solver:
:mod:`.batch_model`), ``"heads"`` (a Model, State and solver per head, all in one CUDA graph) or
``"auto"`` (default: ``"model"`` on CUDA with the implicit solver, else ``"heads"``)."""

MAX_BATCH_HEADS = 100_000
"""Largest number of heads of one :class:`FaceBatch`."""

_SIM_KEYS = ("solver", "material", "dt", "substeps", "iterations", "tolerance", "method", "solver_options",
             "support_stiffness", "edge_damping", "mass_scaling", "contact", "contact_modulus")


def _rig_list(rigs, count) -> list:
    if isinstance(rigs, FaceRig):
        n = 1 if count is None else check_int("count", count, low=1, high=MAX_BATCH_HEADS)
        rigs = [rigs] * int(n)
        _check_batch_memory(rigs, "count")
        return rigs
    if isinstance(rigs, (str, bytes)) or not hasattr(rigs, "__len__"):
        raise InputError(f"rigs: expected a FaceRig or a list of FaceRigs, got {describe(rigs)}")
    rigs = list(rigs)
    if not rigs:
        raise InputError("rigs: expected at least one FaceRig, got an empty list")
    for i, fr in enumerate(rigs):
        if not isinstance(fr, FaceRig):
            raise InputError(f"rigs[{i}]: expected a FaceRig (build_face or load_face_rig), got {describe(fr)}")
    if len(rigs) > MAX_BATCH_HEADS:
        raise InputError(f"rigs: at most {MAX_BATCH_HEADS} heads, got {len(rigs)}")
    if count is not None:
        check_int("count", count, low=1, high=MAX_BATCH_HEADS)
        if int(count) != len(rigs):
            raise InputError(f"count: {count} heads asked for with {len(rigs)} rigs (give one rig to replicate, "
                             "or leave count out)")
    _check_batch_memory(rigs, "rigs")
    return rigs


def _check_batch_memory(rigs: list, what: str) -> None:
    """Refuse a batch whose heads would not fit in this machine's memory, before any is made
    (:func:`~facewarp._src.core.limits.estimate_batch_bytes`: a level-0 head about 18.8 MB more)."""
    from collections import Counter

    from ..core.limits import check_memory, estimate_batch_bytes

    count = Counter(id(fr) for fr in rigs)
    distinct = {id(fr): fr for fr in rigs}
    need = sum(estimate_batch_bytes(len(fr.nodes), len(fr.tets), count[k]) for k, fr in distinct.items())
    check_memory(need, f"{what}: {len(rigs)} heads")


def _poses(name: str, R, t, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (n, 3, 3) and translations (n, 3) from one pose or one per head, checked."""
    try:
        R = np.asarray(R, dtype=np.float64) if R is not None else np.eye(3)
    except (TypeError, ValueError):
        raise InputError(f"{name}: rotations must be numbers, shape (3, 3) or ({n}, 3, 3), got {describe(R)}") from None
    try:
        t = np.asarray(t, dtype=np.float64) if t is not None else np.zeros(3)
    except (TypeError, ValueError):
        raise InputError(f"{name}: translations must be numbers [m], shape (3,) or ({n}, 3), got {describe(t)}") from None
    if R.shape == (3, 3):
        R = np.broadcast_to(R, (n, 3, 3))
    if t.shape == (3,):
        t = np.broadcast_to(t, (n, 3))
    if R.shape != (n, 3, 3):
        raise InputError(f"{name}: rotations must have shape (3, 3) or ({n}, 3, 3), got {R.shape}")
    if t.shape != (n, 3):
        raise InputError(f"{name}: translations must have shape (3,) or ({n}, 3) [m], got {t.shape}")
    if not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise InputError(f"{name}: rotations and translations must be finite")
    err = np.abs(np.einsum("nij,nkj->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = np.flatnonzero((err > 1e-6) | (det < 0))
    if len(bad):
        raise InputError(f"{name}: rotation of head {int(bad[0])} is not a rotation (R R^T = I, det R = +1)")
    return R.copy(), t.copy()


def activation_rows(activations, names: list, same_m: int | None) -> list:
    """Every head's activations checked: ``activations`` an array (N, M) in [0, 1] (heads of one
    muscle count ``same_m``: checked at once, no per-head host work) or a list of N entries, each
    what :meth:`~facewarp.FaceSimulator.set_activations` takes; ``names`` the N heads' muscle names,
    ``same_m`` their one muscle count (None: the counts differ; :func:`muscle_count`).
    Returns N float32 vectors (M_i,). Raises :class:`InputError` naming the head and the muscle."""
    n = len(names)
    if isinstance(activations, np.ndarray):
        if activations.ndim != 2 or activations.shape[0] != n:
            raise InputError(f"activations: expected shape ({n}, M), got {activations.shape}")
        if same_m is not None and activations.shape[1] == same_m:
            a = np.asarray(activations, np.float64)
            bad = np.argwhere(~np.isfinite(a) | (a < 0.0) | (a > 1.0))
            if len(bad):
                i, k = (int(v) for v in bad[0])
                raise InputError(f"activations of head {i}: {names[i][k]} is {a[i, k]!r}, expected a value in [0, 1]")
            return list(a.astype(np.float32))
        rows = list(activations)
    elif isinstance(activations, (list, tuple)):
        if len(activations) != n:
            raise InputError(f"activations: expected {n} entries (one per head), got {len(activations)}")
        rows = list(activations)
    else:
        raise InputError(f"activations: expected an array ({n}, M) or a list of {n} entries, got {describe(activations)}")
    targets = []
    for i, a in enumerate(rows):
        try:
            targets.append(activation_vector(names[i], a))
        except InputError as e:
            raise InputError(f"activations of head {i}: {e}") from None
    return targets


def jaw_rows(angles, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Every head's jaw angles checked: ``angles`` (N, 2) (opening, side [rad]) or (N,) openings.
    Returns ``(as given (N, 2) float64, the targets (N, 2) float32)`` (:func:`.readout.jaw_vector`'s
    conversion, all at once when every head is in range). Raises :class:`InputError` naming the head."""
    a = check_array("angles", angles, shape=(count,)) if np.ndim(angles) == 1 else check_array(
        "angles", angles, shape=(count, 2))
    a = np.asarray(a, np.float64).reshape(count, -1)
    if a.shape[1] == 1:
        a = np.concatenate([a, np.zeros_like(a)], axis=1)
    from ..expressions import JAW_U_MAX, JAW_V_MAX

    ok = (a[:, 0] >= -1e-9) & (a[:, 0] <= JAW_U_MAX + 1e-9) & (np.abs(a[:, 1]) <= JAW_V_MAX + 1e-9)
    if ok.all():  # every head in range: jaw_vector's conversion for all at once (row by row below otherwise)
        return a, np.stack([np.maximum(a[:, 0], 0.0), a[:, 1]], 1).astype(np.float32)
    out = np.zeros((count, 2), np.float32)
    for i in range(count):
        try:
            out[i] = jaw_vector(float(a[i, 0]), float(a[i, 1]))
        except InputError as e:
            raise InputError(f"angles of head {i}: {e}") from None
    return a, out


def muscle_count(names: list) -> int | None:
    """The one muscle count of heads with these muscle names, or None when the counts differ."""
    ms = {len(m) for m in names}
    return ms.pop() if len(ms) == 1 else None



class BatchBase:
    """What both backends of :class:`~facewarp.FaceBatch` share: the arguments checked, the head
    indices, the placements, the stream count and the frame loop over :meth:`step` (the backends
    define ``step``, ``count`` and ``failed``)."""

    def _start(self, rigs, count, placements, streams, options: dict) -> list:
        """FaceBatch's arguments checked (options, rigs, streams, placements); returns the rig list."""
        bad = sorted(set(options) - set(_SIM_KEYS))
        if bad:
            raise InputError(f"{bad[0]}: not an option of FaceBatch (options: {', '.join(_SIM_KEYS)})")
        rigs = _rig_list(rigs, count)
        check_int("streams", streams, low=1, high=1024)
        n = len(rigs)
        if placements is None:
            self._place_R, self._place_t = np.broadcast_to(np.eye(3), (n, 3, 3)).copy(), np.zeros((n, 3))
        else:
            if not (isinstance(placements, (tuple, list)) and len(placements) == 2):
                raise InputError(f"placements: expected (R, t), got {describe(placements)}")
            self._place_R, self._place_t = _poses("placements", placements[0], placements[1], n)
        return rigs

    @property
    def streams(self) -> int:
        """CUDA streams the heads' frames are spread over (module doc; 1: one graph for all; the CPU ignores it)."""
        return self._streams

    @streams.setter
    def streams(self, value: int) -> None:
        self._streams = int(check_int("streams", value, low=1, high=1024))
        self._graphs = {}

    # ------------------------------------------------------------------------------ controls
    def _heads_arg(self, heads) -> list[int]:
        if heads is None:
            return list(range(self.count))
        if isinstance(heads, (int, np.integer)) and not isinstance(heads, bool):
            heads = [heads]
        try:
            idx = [int(h) for h in heads]
        except (TypeError, ValueError):
            raise InputError(f"heads: expected head indices, got {describe(heads)}") from None
        for h in idx:
            if not 0 <= h < self.count:
                raise InputError(f"heads: head {h} is not in 0..{self.count - 1}")
        return idx

    def _head(self, head) -> int:
        if isinstance(head, bool) or not isinstance(head, (int, np.integer)) or not 0 <= head < self.count:
            raise InputError(f"head: expected a head index 0..{self.count - 1}, got {head!r}")
        return int(head)


    # ------------------------------------------------------------------------------ stepping
    @property
    def live(self) -> list[int]:
        """Heads that step (not frozen by a failure), ascending."""
        return [i for i in range(self.count) if i not in self.failed]


    def advance(self, frames: int = 1) -> None:
        """Advance ``frames`` frames with the current controls."""
        check_int("frames", frames, low=0, high=1_000_000)
        for _ in range(int(frames)):
            self.step()


    def _world(self, i: int, X: np.ndarray) -> np.ndarray:
        return X @ self._place_R[i].T + self._place_t[i]

    @property
    def placements(self) -> tuple[np.ndarray, np.ndarray]:
        """The heads' placements: rotations (N, 3, 3) and translations (N, 3) [m]."""
        return self._place_R.copy(), self._place_t.copy()
