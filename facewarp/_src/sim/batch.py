"""Many heads stepped together: :class:`FaceBatch`, N personalized faces, one step for all.

What a head is
--------------
Each head is a :class:`~facewarp.FaceSimulator` of its own rig (its rest shape, material and
muscle rig): its own :class:`~facewarp.physics.Model`, State, Control and solver, made by the
same code path as a single head (:func:`.stepper.build_face`; heads that play one rig share its
:class:`~facewarp.physics.ModelBuilder`, so the per-head cost of a replicated rig is the
``finalize`` and the solver's buffers, not the builder's geometry). Different topologies need
nothing special: a head's arrays index its own nodes.

One step for all
----------------
:meth:`FaceBatch.step` takes one frame of every live head. The controls of all heads live in
one device array (each head's ``Control.activations`` and ``jaw_angles`` are views into it), so
a frame's controls go up in one copy per ramp piece; on CUDA the frame of every head — the
start-of-frame save of the rollback (:mod:`.rollback`), the solver's substeps (the adaptive
Newton-PCG loop of each head a conditional graph node) and the end-of-frame checks — is one
captured CUDA graph, replayed every frame, and the checks come back in one read. On the CPU the
heads run one after another through the same calls. A level-0 head's kernels are small (a few
thousand threads each), so one graph of N heads runs them one after another; with ``streams=K``
the heads are split into K groups, each group's frame its own graph on its own stream, launched
side by side after the controls' upload and joined before the checks are read, so K heads'
kernels share the GPU at a time. Each head converges on its own: its own
solver decides its iteration count (the Newton-PCG loop on CUDA stops per head on its own
residual; the CPU L-BFGS factorises and iterates per head), so a head at rest costs few
iterations whatever the others do.

A head that fails
-----------------
After the frame the checks of every head are read (NaN or inverted tet: the solver's guard;
every tet above :data:`~facewarp.physics.VOLUME_FLOOR` of its rest volume; the CPU solve
converged). A head that fails is rolled back to its frame start and taken again alone with
sub-stepping (:func:`.rollback.step_frame`, exactly the single-head path); one that still fails
at the bound (a NaN or an inverted tet) is *frozen*: kept at its last good frame, reported in
:attr:`FaceBatch.status` with its index and the error, and skipped by later steps; the other
heads go on untouched (no array is shared between heads but read-only model data).

Where the heads are
-------------------
Every head is simulated in its own head frame, as a single head is: the physics does not
depend on where the head stands. A head's *placement* (``placements``: rotation and translation,
fixed) and its *head pose* (:meth:`FaceBatch.set_head_pose`: moving, its accelerations load the
tissue as :meth:`~facewarp.FaceSimulator.set_head_pose` does) are applied at read-out:
:meth:`FaceBatch.surface` and :meth:`FaceBatch.fdp_points` answer in the world frame,
``x_world = R_place (R_pose x + t_pose) + t_place``.

The jaws
--------
The kinematic jaw (Eq. 6.4.9) of every head is its Control's ``jaw_angles`` (:meth:`FaceBatch.set_jaw`),
stepped inside the batched frame. The MuJoCo jaw (:meth:`FaceBatch.use_mujoco_jaws`) is one CPU
MuJoCo model per head (the ``head.xml`` of its build), stepped in a loop around the batched skin
step: before it, each head's MuJoCo angles and head pose are set on its skin; after it, the skin's
torque on the hinge is read back (a host read of the jaw nodes per head) and MuJoCo takes its
steps to the frame's end. Its cost grows with N on the host whatever the device
(``benchmarks/batch.py --mujoco`` measures it); MuJoCo Warp (``mujoco-warp``, one Model with
``nworld`` worlds on the GPU) would keep it on the device and is not used yet.
"""

from __future__ import annotations

import time

import numpy as np

from ..core.checks import check_array, check_choice, check_int, describe
from ..core.errors import InputError, SimulationError
from ..core.warp import get_warp
from ..physics.face_rig import FaceRig
from ..physics.volume_barrier import VOLUME_FLOOR
from .readout import activation_vector, jaw_vector
from .rollback import _SOLVER_HOST_STATE, _copy_host, step_frame
from .simulator import FaceSimulator

__all__ = ["BACKENDS", "MAX_BATCH_HEADS", "FaceBatch"]

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
    (:func:`~facewarp._src.core.limits.estimate_batch_bytes`)."""
    from ..core.limits import check_memory, estimate_batch_bytes

    from collections import Counter

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


def muscle_count(names: list) -> int | None:
    """The one muscle count of heads with these muscle names, or None when the counts differ."""
    ms = {len(m) for m in names}
    return ms.pop() if len(ms) == 1 else None


class FaceBatch:
    """N simulated faces, each its own person, stepped together (module doc).

    Args:
        rigs: One :class:`~facewarp.FaceRig` (replicated ``count`` times) or a list of them (one
            per head, any mix of identities and topologies).
        count: Number of heads with one rig (default 1); with a list, None or its length.
        device: Warp device, ``"cpu"`` or ``"cuda[:N]"``, for every head.
        fps: Frames per second of :meth:`step`.
        placements: Each head's fixed place in the world: ``(R, t)`` with R (3, 3) or (N, 3, 3)
            rotations and t (3,) or (N, 3) translations [m] (default: all at the origin).
        streams: CUDA only: the heads split into this many groups, each group's frame one graph
            on its own stream, the groups run side by side (default 1: one graph for all heads;
            module doc). The CPU ignores it.
        backend: :data:`BACKENDS`: ``"model"`` (every head in one Model, one solver; the fast path on
            a GPU: :class:`~facewarp._src.sim.batch_model.FaceBatchModel`), ``"heads"`` (one
            :class:`~facewarp.FaceSimulator` per head: any solver, moving head poses, the MuJoCo
            jaw, per-head convergence) or ``"auto"`` (default: ``"model"`` on CUDA with the
            implicit solver, else ``"heads"``).
        **options: :class:`~facewarp.FaceSimulator`'s keywords (``solver``, ``material``, ``dt``,
            ``substeps``, ``iterations``, ``tolerance``, ``method``, ``solver_options``,
            ``support_stiffness``, ``edge_damping``, ``mass_scaling``, ``contact``,
            ``contact_modulus``), the same for every head.

    Attributes:
        heads: The heads' :class:`~facewarp.FaceSimulator` objects (read them, do not step them
            alone while they are in the batch).
        count: Number of heads N.
        step_seconds: Wall-clock time spent in :meth:`step` [s].

    Raises:
        InputError: bad rigs, count, placements or simulator options.
    """

    backend = "heads"

    def __new__(cls, *args, backend: str = "auto", **kwargs):
        # backend dispatch (batch_model.py): "model" = N faces in one Model; "heads" = a Model per head
        check_choice("backend", backend, BACKENDS)
        if cls is FaceBatch:
            from .batch_model import FaceBatchModel, model_backend_reason

            dev = str(kwargs.get("device", "cpu"))
            auto = dev.startswith("cuda") and model_backend_reason(kwargs) is None
            if backend == "model" or (backend == "auto" and auto):
                return super().__new__(FaceBatchModel)
        return super().__new__(cls)

    def __init__(self, rigs, count: int | None = None, *, device: str = "cpu", fps: float = 30.0,
                 placements=None, streams: int = 1, backend: str = "auto", **options):
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
        shared = options.get("solver", "implicit") == "implicit"
        builders: dict[int, object] = {}
        self.heads: list[FaceSimulator] = []
        for fr in rigs:
            sim = FaceSimulator(fr, device=device, fps=fps, _builder=builders.get(id(fr)), **options)
            if shared:
                builders.setdefault(id(fr), sim.builder)
            self.heads.append(sim)
        self.count = n
        self.fps = float(fps)
        self.device = self.heads[0].device
        self._wp = wp = get_warp()
        # every head's activations and jaw angles are views of one device array: one upload per ramp piece
        sizes = [int(h.control.activations.shape[0]) + 2 for h in self.heads]
        self._ctrl_start = np.r_[0, np.cumsum(sizes)].astype(np.int64)
        total = int(self._ctrl_start[-1])
        self._ctrl = wp.zeros(total, dtype=float, device=self.device)
        self._chunks = FaceSimulator.CONTROL_CHUNKS
        self._ctrl_host = wp.zeros(self._chunks * total, dtype=float, device="cpu", pinned=bool(self.device.is_cuda))
        for i, h in enumerate(self.heads):
            o, m = int(self._ctrl_start[i]), sizes[i] - 2
            h.control.activations = self._ctrl[o:o + m]
            h.control.jaw_angles = self._ctrl[o + m:o + m + 2]
        # the end-of-frame checks of every head land in two device arrays, read back at once
        self._guard_all = wp.zeros(2 * n, dtype=wp.int32, device=self.device)
        self._ratio_all = wp.zeros(n, dtype=float, device=self.device)
        from . import kernels_rollback as kr

        wp.load_module(kr, device=self.device)  # its kernel is captured in the frame's graph: loaded before
        self._graphs: dict[tuple, list] = {}
        self._use_graph = all(h.stepper.use_graph for h in self.heads)
        self._host_keys = [[k for k in _SOLVER_HOST_STATE if hasattr(h.solver, k)] for h in self.heads]
        self._names = [h.fr.rig.names for h in self.heads]
        self._same_m = muscle_count(self._names)  # one muscle count: (N, M) activations checked at once
        self._stream_pool: list = []
        self.streams = streams
        self.step_seconds = 0.0
        self._mujoco = None
        self._jaw_goal = np.zeros((n, 2))
        self.reset()

    def use_mujoco_jaws(self, mjcf) -> None:
        """Drive every head's jaw by the MuJoCo hinge body of its ``head.xml`` (written by ``facewarp
        build``), two-way coupled as :class:`~facewarp.coupling.MujocoJawDriver` does for one head:
        :meth:`set_jaw`'s angles become the actuator targets, MuJoCo's angles and head pose go onto
        the skin before each batched step and the skin's torque back after it. One CPU MuJoCo model
        per head, stepped in a loop (module doc).

        Args:
            mjcf: One ``head.xml`` path for every head, or a list of N (one per head).

        Raises:
            InputError: a missing or broken file, a list of the wrong length, or no ``mujoco``.
        """
        from ..coupling.drivers import MujocoJawDriver

        paths = list(mjcf) if isinstance(mjcf, (list, tuple)) else [mjcf] * self.count
        if len(paths) != self.count:
            raise InputError(f"mjcf: expected one head.xml or {self.count} (one per head), got {len(paths)}")
        self._mujoco = [MujocoJawDriver(h, p) for h, p in zip(self.heads, paths)]
        self._mjcf = paths

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

    def set_activations(self, activations) -> None:
        """Set every head's muscle activations reached at the end of the next :meth:`step` (they
        ramp linearly over it from the current ones).

        Args:
            activations: An array (N, M) in [0, 1] (M the heads' muscle count, the order of
                ``heads[i].muscle_names``; heads with different rigs: a list instead), or a list of N
                entries, each what :meth:`~facewarp.FaceSimulator.set_activations` takes (a dict
                name -> value, an :class:`~facewarp.Expression`, an (M,) array).
        """
        for h, a in zip(self.heads, activation_rows(activations, self._names, self._same_m)):
            h._target_a = a

    def set_jaw(self, angles) -> None:
        """Set every head's jaw angles [rad] reached at the end of the next :meth:`step`.

        Args:
            angles: (N, 2) (opening 0..60 deg, side +-5 deg in radians, as
                :meth:`~facewarp.FaceSimulator.set_jaw`), or (N,) openings with no side turn.
        """
        a = check_array("angles", angles, shape=(self.count,)) if np.ndim(angles) == 1 else check_array(
            "angles", angles, shape=(self.count, 2))
        a = np.asarray(a, np.float64).reshape(self.count, -1)
        if a.shape[1] == 1:
            a = np.concatenate([a, np.zeros_like(a)], axis=1)
        from ..expressions import JAW_U_MAX, JAW_V_MAX

        ok = (a[:, 0] >= -1e-9) & (a[:, 0] <= JAW_U_MAX + 1e-9) & (np.abs(a[:, 1]) <= JAW_V_MAX + 1e-9)
        if ok.all():  # every head in range: jaw_vector's conversion for all at once (row by row below otherwise)
            J32 = np.stack([np.maximum(a[:, 0], 0.0), a[:, 1]], 1).astype(np.float32)
            for i, h in enumerate(self.heads):
                h._target_j = J32[i]
            self._jaw_goal[:] = a
            return
        targets = []
        for i in range(self.count):
            try:
                targets.append(jaw_vector(float(a[i, 0]), float(a[i, 1]) if a.shape[1] > 1 else 0.0))
            except InputError as e:
                raise InputError(f"angles of head {i}: {e}") from None
        for i, (h, j) in enumerate(zip(self.heads, targets)):
            h._target_j = j
            self._jaw_goal[i] = (a[i, 0], a[i, 1] if a.shape[1] > 1 else 0.0)  # MuJoCo's targets, as given

    def set_head_pose(self, R, t) -> None:
        """Set every head's pose (in its placement) reached at the end of the next :meth:`step`:
        R (3, 3) or (N, 3, 3) rotations, t (3,) or (N, 3) translations [m]. As
        :meth:`~facewarp.FaceSimulator.set_head_pose`: the head, simulated in its own frame,
        feels the loads of the accelerating frame."""
        R, t = _poses("head pose", R, t, self.count)
        for h, r, x in zip(self.heads, R, t):
            h.set_head_pose(r, x)

    def reset(self, heads=None) -> None:
        """Back to rest, all heads (default) or the listed ones: each head's
        :meth:`~facewarp.FaceSimulator.reset` (and its MuJoCo jaw's model made again); a frozen
        head is live again."""
        idx = self._heads_arg(heads)
        for i in idx:
            self.heads[i].reset()
            self._jaw_goal[i] = 0.0
        if getattr(self, "_mujoco", None) is not None:  # MuJoCo from its initial state too
            from ..coupling.drivers import MujocoJawDriver

            for i in idx:
                self._mujoco[i] = MujocoJawDriver(self.heads[i], self._mjcf[i])
        if heads is None:
            self.failed: dict[int, str] = {}
            self.frames = 0
        else:
            for i in idx:
                self.failed.pop(i, None)

    # ------------------------------------------------------------------------------ stepping
    @property
    def live(self) -> list[int]:
        """Heads that step (not frozen by a failure), ascending."""
        return [i for i in range(self.count) if i not in self.failed]

    def step(self) -> None:
        """One frame (``1 / fps``) of every live head, the controls set since the last step
        ramping across it (module doc: one CUDA graph on CUDA; a failing head is rolled back,
        taken again alone with more substeps, and frozen if it still fails).

        Raises:
            InputError: a head pose jump beyond a head's motion (nothing changed).
        """
        t0 = time.perf_counter()
        live = self.live
        angles = {}
        if self._mujoco is not None:  # MuJoCo's angles and head poses onto the skins (one CPU MuJoCo per head)
            for i in live:
                d = self._mujoco[i]
                for a, target in zip(d.act, self._jaw_goal[i]):
                    if a >= 0:
                        d.data.ctrl[a] = target
                angles[i] = d.coupler.exchange_begin()
        for i in live:
            self.heads[i]._frame_loads(self.heads[i].substeps)
        same = len({self.heads[i].substeps for i in live}) == 1 and len({self.heads[i].dt for i in live}) == 1
        if live and same:
            problems = self._frame_together(live)
        else:
            problems = {i: "" for i in live}  # heads with different substeps: each alone
        for i in live:
            h = self.heads[i]
            n = h.substeps
            if i in problems:
                try:
                    if problems[i]:  # rolled back; taken again alone, sub-stepped
                        h.frame_guard.restore()
                        h.solver.reset_guard()
                    step_frame(h, n, h._a, h._target_a, h._j, h._target_j)
                except SimulationError as e:
                    self.failed[i] = str(e)
                    continue
            else:
                st = h.stats
                st.frames += 1
                st.min_volume_ratio = min(st.min_volume_ratio, self._ratios[i])
            h._frame_done(n)
        if self._mujoco is not None:  # the skins' torques to MuJoCo, then MuJoCo's frame, head by head
            for i in live:
                if i in self.failed:
                    continue
                try:
                    self._mujoco[i].coupler.exchange_end(angles[i])
                    self._mujoco[i].coupler.mujoco_frame()
                except SimulationError as e:
                    self.failed[i] = str(e)
        self.frames += 1
        self.step_seconds += time.perf_counter() - t0

    def advance(self, frames: int = 1) -> None:
        """Advance ``frames`` frames with the current controls."""
        check_int("frames", frames, low=0, high=1_000_000)
        for _ in range(int(frames)):
            self.step()

    def _frame_together(self, live: list[int]) -> dict:
        """The frame of the heads ``live`` (same substeps) together; returns {head: problem} of
        those whose checks failed (rolled back by the caller)."""
        wp = self._wp
        h0 = self.heads[live[0]]
        n, dt = h0.substeps, h0.dt
        chunks = max(1, min(n, self._chunks))
        bounds = np.linspace(0, n, chunks + 1).round().astype(int)
        total = int(self._ctrl_start[-1])
        host = self._ctrl_host.numpy().reshape(self._chunks, total)
        for c in range(chunks):
            w = (c + 1) / chunks
            for i in live:
                h, o = self.heads[i], int(self._ctrl_start[i])
                m = len(h._a)
                host[c, o:o + m] = (1 - w) * h._a + w * h._target_a
                host[c, o + m:o + m + 2] = (1 - w) * h._j + w * h._target_j
        for i in live:  # the host part of the rollback's save (the CPU solvers' history), before the frame
            g, solver = self.heads[i].frame_guard, self.heads[i].solver
            g._host_state = {k: _copy_host(getattr(solver, k)) for k in self._host_keys[i]}
        groups = [g.tolist() for g in np.array_split(np.asarray(live), min(self._streams, len(live)))]
        key = (tuple(live), n, dt, len(groups))
        self._raised: dict[int, str] = {}  # before a capture: _piece reads it
        if self._use_graph and key not in self._graphs:
            while len(self._stream_pool) < len(groups) - 1:
                self._stream_pool.append(wp.Stream(self.device))
            streams = [wp.get_stream(self.device)] + self._stream_pool[:len(groups) - 1]
            graphs = []
            for c in range(chunks):  # per ramp piece, one graph per group of heads, each on its stream
                row = []
                for g, st in zip(groups, streams):
                    with wp.ScopedStream(st), wp.ScopedCapture(device=self.device) as cap:
                        self._piece(g, c, chunks, int(bounds[c + 1] - bounds[c]), dt)
                    row.append((cap.graph, st))
                graphs.append(row)
            self._graphs[key] = graphs
        for c in range(chunks):
            wp.copy(self._ctrl, self._ctrl_host, src_offset=c * total, count=total)
            if self._use_graph:
                row = self._graphs[key][c]
                if len(row) == 1:
                    wp.capture_launch(row[0][0], stream=row[0][1])
                else:  # fork after the upload, the groups side by side, join before the checks are read
                    main = wp.get_stream(self.device)
                    ev = main.record_event()
                    for graph, st in row[1:]:
                        st.wait_event(ev)
                        wp.capture_launch(graph, stream=st)
                    wp.capture_launch(row[0][0], stream=main)
                    for _, st in row[1:]:
                        main.wait_stream(st)
            else:
                self._piece(live, c, chunks, int(bounds[c + 1] - bounds[c]), dt)
        guard = self._guard_all.numpy().reshape(-1, 2)  # one read of every head's checks
        ratio = self._ratio_all.numpy()
        self._ratios = ratio
        from ..physics import kernels_tissue as kt

        problems = dict(self._raised)
        for i in live:
            h = self.heads[i]
            if i in problems:
                continue
            if int(guard[i, 0]) != kt.GUARD_NONE:
                problems[i] = "a NaN or an inverted tet"
            elif not ratio[i] > -1.0e29:  # the volume kernel's mark of a non-finite position
                problems[i] = "a NaN or non-finite position"
            elif not ratio[i] >= VOLUME_FLOOR:
                problems[i] = f"a tet at {ratio[i]:.3g} of its rest volume"
            elif not getattr(h.solver, "last_converged", True):
                problems[i] = "the step's solve did not converge"
        return problems

    def _piece(self, live: list[int], c: int, chunks: int, steps: int, dt: float) -> None:
        """Ramp piece ``c``: the saves at the first, the substeps of every head, the checks at the last."""
        wp = self._wp
        from . import kernels_rollback as kr

        for i in live:
            h = self.heads[i]
            if c == 0:  # the rollback's frame start (FrameGuard.save's device part)
                for a, s in zip(h.frame_guard._arrays, h.frame_guard._saved):
                    wp.copy(s, a)
            if i in self._raised:
                continue
            try:
                h.stepper._substeps(steps, dt)
            except SimulationError as e:  # a host-side solver's (CPU) own check: this head only
                self._raised[i] = str(e)
                continue
            if c == chunks - 1:
                m = h.model
                wp.copy(self._guard_all, h.solver.guard, dest_offset=2 * i, count=2)
                ratio = self._ratio_all[i:i + 1]
                ratio.fill_(3.0e38)
                wp.launch(kr._min_volume_ratio, dim=m.tet_count,
                          inputs=[m.tet_indices, m.tet_rest_volume, h.state.positions], outputs=[ratio],
                          device=m.device)

    # ------------------------------------------------------------------------------ results
    @property
    def status(self) -> list[dict]:
        """Per head: ``head`` (index), ``ok`` (False: frozen by a failure), ``error`` (the
        failure, or None), ``frames`` (frames taken), ``substepped_frames``, ``retries``,
        ``frames_below_floor``, ``unconverged_frames``, ``min_volume_ratio``
        (:class:`~facewarp._src.sim.rollback.FrameStats`), ``iterations`` (the head's own solver
        iterations since its reset: each head converges on its own; a device read per head on CUDA)."""
        out = []
        for i, h in enumerate(self.heads):
            st = h.stats
            out.append({"head": i, "ok": i not in self.failed, "error": self.failed.get(i),
                        "frames": st.frames, "substepped_frames": st.substepped_frames, "retries": st.retries,
                        "frames_below_floor": st.frames_below_floor, "unconverged_frames": st.unconverged_frames,
                        "min_volume_ratio": float(st.min_volume_ratio),
                        "iterations": int(getattr(h.solver, "total_iterations", 0))})
        return out

    def positions(self, head: int | None = None, *, frame: str = "head"):
        """Tet node positions [m], float64: of one head (p, 3), or of every head (a list of N
        arrays (p_i, 3)); in the head's own frame (``"head"``, default: what a
        :class:`~facewarp.FaceSimulator` of the rig gives alone) or the ``"world"`` frame
        (placement and head pose applied)."""
        check_choice("frame", frame, ("head", "world"))
        if head is None:
            return [self.positions(i, frame=frame) for i in range(self.count)]
        i = self._head(head)
        X = self.heads[i].positions()
        return self._world(i, self.heads[i]._pose.to_world(X)) if frame == "world" else X

    def surface(self, head: int) -> np.ndarray:
        """Head vertices of head ``head`` [m], (n, 3), float64, world frame (module doc)."""
        i = self._head(head)
        return self._world(i, self.heads[i].surface())

    def fdp_points(self, head: int) -> np.ndarray:
        """The FDPs of head ``head`` [m], (84, 3), float64, world frame (order ``rig.fdp_ids``)."""
        i = self._head(head)
        return self._world(i, self.heads[i].fdp_points())

    def _world(self, i: int, X: np.ndarray) -> np.ndarray:
        return X @ self._place_R[i].T + self._place_t[i]

    @property
    def placements(self) -> tuple[np.ndarray, np.ndarray]:
        """The heads' placements: rotations (N, 3, 3) and translations (N, 3) [m]."""
        return self._place_R.copy(), self._place_t.copy()
