"""The per-head backend of :class:`~facewarp.FaceBatch` (``backend="heads"``): a Model, State and solver
per head (a :class:`~facewarp.FaceSimulator` each), every head's frame in one CUDA graph; the module
doc of :mod:`.batch` says how."""

from __future__ import annotations

import time

import numpy as np

from ..core.checks import check_choice
from ..core.errors import InputError, SimulationError
from ..core.warp import get_warp
from ..physics.volume_barrier import VOLUME_FLOOR
from .batch_common import BatchBase, _poses, activation_rows, jaw_rows, muscle_count
from .rollback import _SOLVER_HOST_STATE, _copy_host, step_frame
from .simulator import FaceSimulator

__all__ = ["BatchHeads"]


class BatchHeads(BatchBase):
    """The ``"heads"`` backend of :class:`~facewarp.FaceBatch`: a :class:`~facewarp.FaceSimulator` per head
    (:mod:`.batch` module doc); the arguments are FaceBatch's (less ``backend``).

    Attributes:
        heads: The heads' :class:`~facewarp.FaceSimulator` objects (read them, do not step them
            alone while they are in the batch).
        count: Number of heads N.
        step_seconds: Wall-clock time spent in :meth:`step` [s].
    """

    backend = "heads"

    def __init__(self, rigs, count: int | None = None, *, device: str = "cpu", fps: float = 30.0,
                 placements=None, streams: int = 1, **options):
        rigs = self._start(rigs, count, placements, streams, options)
        n = len(rigs)
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
        """As :meth:`FaceBatch.use_mujoco_jaws <facewarp.FaceBatch.use_mujoco_jaws>` (its doc)."""
        from ..coupling.drivers import MujocoJawDriver

        paths = list(mjcf) if isinstance(mjcf, (list, tuple)) else [mjcf] * self.count
        if len(paths) != self.count:
            raise InputError(f"mjcf: expected one head.xml or {self.count} (one per head), got {len(paths)}")
        self._mujoco = [MujocoJawDriver(h, p) for h, p in zip(self.heads, paths)]
        self._mjcf = paths

    def set_activations(self, activations) -> None:
        """As :meth:`FaceBatch.set_activations <facewarp.FaceBatch.set_activations>` (its doc)."""
        for h, a in zip(self.heads, activation_rows(activations, self._names, self._same_m)):
            h.set_activation_vector(a)

    def set_jaw(self, angles) -> None:
        """As :meth:`FaceBatch.set_jaw <facewarp.FaceBatch.set_jaw>` (its doc)."""
        goal, J = jaw_rows(angles, self.count)
        for h, j in zip(self.heads, J):
            h.set_jaw_vector(j)
        self._jaw_goal[:] = goal  # MuJoCo's targets, as given

    def set_head_pose(self, R, t) -> None:
        """As :meth:`FaceBatch.set_head_pose <facewarp.FaceBatch.set_head_pose>` (its doc)."""
        R, t = _poses("head pose", R, t, self.count)
        for h, r, x in zip(self.heads, R, t):
            h.set_head_pose(r, x)

    def reset(self, heads=None) -> None:
        """As :meth:`FaceBatch.reset <facewarp.FaceBatch.reset>` (its doc)."""
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

    def step(self) -> None:
        """As :meth:`FaceBatch.step <facewarp.FaceBatch.step>` (its doc)."""
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
        """As :meth:`FaceBatch.positions <facewarp.FaceBatch.positions>` (its doc)."""
        check_choice("frame", frame, ("head", "world"))
        if head is None:
            return [self.positions(i, frame=frame) for i in range(self.count)]
        i = self._head(head)
        X = self.heads[i].positions()
        return self._world(i, self.heads[i]._pose.to_world(X)) if frame == "world" else X

    def surface(self, head: int) -> np.ndarray:
        """As :meth:`FaceBatch.surface <facewarp.FaceBatch.surface>` (its doc)."""
        i = self._head(head)
        return self._world(i, self.heads[i].surface())

    def fdp_points(self, head: int) -> np.ndarray:
        """As :meth:`FaceBatch.fdp_points <facewarp.FaceBatch.fdp_points>` (its doc)."""
        i = self._head(head)
        return self._world(i, self.heads[i].fdp_points())

