"""N faces in one Model: the ``backend="model"`` of :class:`~facewarp.FaceBatch`.

What it is
----------
Every head's face rig goes into one :class:`~facewarp.physics.ModelBuilder`
(:meth:`~facewarp.physics.ModelBuilder.add_faces`): one Model whose arrays hold every head's
nodes, elements, muscles, supports, jaw-moved nodes and contact, each row knowing its head (the
per-head ranges ``head_node_start``, ...; a jaw-moved row reads its head's pivot and axes and its
angles ``jaw_angles[2 h], [2 h + 1]``). One solver steps the whole Model, so each kernel launch
covers every head's elements: the frame of N heads costs about the launches of one head (the
per-head-Model backend, :class:`~facewarp.FaceBatch` with ``backend="heads"``, launches every
head's kernels one after another and is bound by launch latency on a GPU).

The Control holds every head's activations ((sum of the heads' muscle counts,), head after head)
and jaw angles ((2 N,): head h's opening and side turn at 2 h, 2 h + 1); a frame's controls go
up in one copy per ramp piece and the frame is one CUDA graph (:class:`.stepper.FrameStepper`).

Convergence and failures
------------------------
The solver's convergence test is global: the implicit step iterates until the largest step over
all heads' nodes is below the tolerance (Newton-PCG on CUDA, L-BFGS on the CPU), so a head at rest
may take the iterations a moving head needs, and its result differs from the head alone by what
the tolerance allows (the same-answer test bounds it). After the frame every head's smallest tet
volume ratio is read (one kernel, one read; a NaN counts as inverted): a frame in which any head
fails is rolled back (the whole Model) and taken again with 2, 4, ... times the substeps
(:data:`~facewarp._src.sim.rollback.MAX_REFINEMENT`); a head that still has a NaN or an inverted
tet at the bound is reported in :attr:`BatchModel.status` with its index and frozen at its last
good frame (its read-outs give that frame). It stays in the Model (its rows are still stepped):
a NaN in one head can reach the others through the global dot products of the solver, which a
per-head convergence test (not built yet) would keep apart.

What it does not do (use ``backend="heads"``): the Verlet solver, moving head poses
(:meth:`set_head_pose` other than at rest), the MuJoCo jaw, heads with different contact
surfaces (not one template) or damping rates (one material profile).
"""

from __future__ import annotations

import time

import numpy as np

from ..core.checks import check_choice
from ..core.errors import InputError, SimulationError
from ..core.warp import get_warp
from ..physics.volume_barrier import VOLUME_FLOOR
from .batch_common import _SIM_KEYS, BatchBase, _poses, activation_rows, jaw_rows, muscle_count
from .readout import activation_vector, fdp_points, head_surface, parts_at, surface_index
from .rollback import MAX_REFINEMENT, FrameGuard, FrameStats
from .simulator import FaceSimulator, check_simulator_args
from .stepper import FrameStepper, face_stages

__all__ = ["BatchModel", "model_backend_reason"]


def model_backend_reason(options: dict) -> str | None:
    """Why the options need one Model per head (``backend="heads"``), or None when one Model serves."""
    if options.get("solver", "implicit") != "implicit":
        return f"solver {options.get('solver')!r} (one Model takes the implicit solver)"
    return None


class BatchModel(BatchBase):
    """The ``"model"`` backend of :class:`~facewarp.FaceBatch`: N faces in one Model stepped by one
    solver (module doc), with FaceBatch's API and arguments (less ``backend``).

    Attributes:
        model: The one :class:`~facewarp.physics.Model` of every head (its ``head_*_start`` ranges
            say whose rows are whose).
        count: Number of heads N.
        step_seconds: Wall-clock time spent in :meth:`step` [s].
        backend: ``"model"``.
    """

    backend = "model"

    def __init__(self, rigs, count: int | None = None, *, device: str = "cpu", fps: float = 30.0,
                 placements=None, streams: int = 1, **options):
        from ..physics.materials import material_profile
        from ..physics.builder import ModelBuilder
        from ..physics.solvers.select import select_solver

        rigs = self._start(rigs, count, placements, streams, options)
        why = model_backend_reason(options)
        if why is not None:
            raise InputError(f"backend: 'model' cannot step {why}; use backend='heads'")
        n = len(rigs)
        o = {k: options.get(k) for k in _SIM_KEYS}
        o["solver"] = "implicit"
        for k, v in (("material", "physical"), ("mass_scaling", True), ("contact", True)):
            o[k] = v if o[k] is None else o[k]
        for fr in {id(fr): fr for fr in rigs}.values():
            device = check_simulator_args(fr, device=device, solver="implicit", fps=fps,
                                          options={k: v for k, v in o.items() if k not in ("solver", "material")})
        self._wp = wp = get_warp()
        t0 = time.perf_counter()
        self.material = mat = material_profile(o["material"])
        builder = ModelBuilder()
        builder.add_faces(rigs, material=mat, edge_damping=o["edge_damping"], support_stiffness=o["support_stiffness"],
                          contact=o["contact"], contact_modulus=o["contact_modulus"], mass_scaling=o["mass_scaling"])
        frame_dt = 1.0 / fps
        self.substeps = int(o["substeps"] if o["substeps"] is not None else 1 if o["dt"] is None
                            else np.ceil(frame_dt / o["dt"]))
        self.dt = frame_dt / self.substeps
        self.builder, self.model = builder, builder.finalize(device)
        m = self.model
        self.device = m.device
        self.control, self.rest_state, self.state, self.scratch = m.control(), m.state(), m.state(), m.state()
        self.stages = face_stages(m)
        opts = {"tolerance": 3e-5 if o["tolerance"] is None else o["tolerance"], **(o["solver_options"] or {})}
        self.solver = select_solver(m, stages=[s for s in self.stages.values() if s is not None],
                                     method=o["method"], iterations=o["iterations"], **opts)
        from ..physics.warmup import load_kernels, solver_kernel_modules
        from . import kernels_rollback

        load_kernels(self.device, solver_kernel_modules(self.solver) + [kernels_rollback])  # compiled up front
        self.stages["muscles"].update_geometry(self.control, self.rest_state)  # rest fibres of zero control
        self.stepper = FrameStepper(self.solver, self.state, self.scratch, self.control, self.dt,
                                    chunks=FaceSimulator.CONTROL_CHUNKS)
        self.frame_guard = FrameGuard(self)
        self.max_refinement = MAX_REFINEMENT
        self.build_seconds = time.perf_counter() - t0
        self.rigs = rigs
        self._names = [fr.rig.names for fr in rigs]
        self._same_m = muscle_count(self._names)  # one muscle count: (N, M) activations checked at once
        self.count = n
        self.fps = float(fps)
        self._streams = int(streams)
        self._graphs = {}
        self._indices = {id(fr): surface_index(fr) for fr in rigs}
        self._node = np.asarray(m.head_node_start, np.int64)
        self._muscle = np.asarray(m.head_muscle_start, np.int64)
        tet_head = np.repeat(np.arange(n), np.diff(np.asarray(m.head_tet_start, np.int64)))
        self._tet_head = wp.array(tet_head.astype(np.int32), dtype=wp.int32, device=self.device)
        self._ratio = wp.zeros(n, dtype=float, device=self.device)
        self._frozen: dict[int, np.ndarray] = {}
        self._jaw_goal = np.zeros((n, 2))
        self._mujoco = None
        self.step_seconds = 0.0
        self.reset()

    # ------------------------------------------------------------------------------ controls
    @property
    def heads(self):
        raise InputError("heads: a FaceBatch of backend 'model' has no per-head simulators (one Model for all); "
                         "read positions(head) / surface(head), or use backend='heads'")

    def muscle_names(self, head: int) -> list[str]:
        """Muscle names of head ``head``, in the order of its activations."""
        return list(self.rigs[self._head(head)].rig.names)

    def activation_vector(self, head: int, activations) -> np.ndarray:
        """Head ``head``'s activations as the (M,) float32 array its rows of the Control take
        (:meth:`~facewarp.FaceSimulator.activation_vector`)."""
        return activation_vector(self.rigs[self._head(head)].rig.names, activations)

    def use_mujoco_jaws(self, mjcf) -> None:
        raise InputError("use_mujoco_jaws: the MuJoCo jaw takes one Model per head: use FaceBatch(..., backend='heads')")

    def set_activations(self, activations) -> None:
        """As :meth:`FaceBatch.set_activations <facewarp.FaceBatch.set_activations>`: (N, M) or a list of N entries."""
        self._target_a = activation_rows(activations, self._names, self._same_m)

    def set_jaw(self, angles) -> None:
        """As :meth:`FaceBatch.set_jaw <facewarp.FaceBatch.set_jaw>`: (N, 2) or (N,) openings [rad]."""
        _, self._target_j = jaw_rows(angles, self.count)

    def set_head_pose(self, R, t) -> None:
        """Only the rest pose (R = I, t = 0) in this backend: moving heads need ``backend='heads'``."""
        R, t = _poses("head pose", R, t, self.count)
        if np.abs(R - np.eye(3)).max() > 0.0 or np.abs(t).max() > 0.0:
            raise InputError("head pose: a FaceBatch of backend 'model' keeps its heads at rest (one cranium motion "
                             "per Model); moving heads: FaceBatch(..., backend='heads'); fixed places: placements")

    def reset(self, heads=None) -> None:
        """Back to rest, all heads (default) or the listed ones (their rows of the State set to rest,
        their controls to zero); a frozen head is live again."""
        wp = self._wp
        idx = self._heads_arg(heads)
        if heads is None:
            self.state.assign(self.rest_state)
            self.scratch.assign(self.rest_state)
            for a in (self.control.activations, self.control.jaw_angles, self.control.external_force):
                a.zero_()
            self.solver.reset()
            self._a = [np.zeros(len(fr.rig.names), np.float32) for fr in self.rigs]
            self._j = np.zeros((self.count, 2), np.float32)
            self._steps_taken = 0
            self.stats = FrameStats()
            self.failed: dict[int, str] = {}
            self._frozen = {}
            self.frames = 0
        else:
            m = self.model
            for i in idx:
                a, b = int(self._node[i]), int(self._node[i + 1])
                for st in (self.state, self.scratch):
                    wp.copy(st.positions, self.rest_state.positions, dest_offset=a, src_offset=a, count=b - a)
                    wp.copy(st.prev_positions, self.rest_state.prev_positions, dest_offset=a, src_offset=a,
                            count=b - a)
                    c0, c1 = int(m.head_ctrl_start[i]), int(m.head_ctrl_start[i + 1])
                    if c1 > c0:
                        wp.copy(st.muscle_ctrl, self.rest_state.muscle_ctrl, dest_offset=c0, src_offset=c0,
                                count=c1 - c0)
                    if st.jaw_carry is not None:
                        wp.copy(st.jaw_carry, self.rest_state.jaw_carry, dest_offset=2 * i, src_offset=2 * i, count=2)
                self._a[i] = np.zeros_like(self._a[i])
                self._j[i] = 0.0
                self.failed.pop(i, None)
                self._frozen.pop(i, None)
        self._target_a = [a.copy() for a in self._a]
        self._target_j = self._j.copy()
        self._jaw_goal[idx] = 0.0

    # ------------------------------------------------------------------------------ stepping
    @property
    def time(self) -> float:
        """Simulated time [s] since the last full :meth:`reset`."""
        return self._steps_taken * self.dt

    def step(self) -> None:
        """One frame (``1 / fps``) of every head, the controls set since the last step ramping
        across it: one solver over the Model (module doc: rolled back and sub-stepped when a head
        fails; a head failing at the bound is frozen and reported)."""
        t0 = time.perf_counter()
        n = self.substeps
        for i in self._frozen:  # a frozen head holds its controls: its rows change nothing it reports
            self._target_a[i], self._target_j[i] = self._a[i], self._j[i]
        a0, a1 = np.concatenate(self._a), np.concatenate(self._target_a)
        j0, j1 = self._j.reshape(-1), self._target_j.reshape(-1)
        self._frame(n, a0, a1, j0, j1)
        self._a = [a.copy() for a in self._target_a]
        self._j = self._target_j.copy()
        self._steps_taken += n
        self.frames += 1
        self.step_seconds += time.perf_counter() - t0

    def _head_ratios(self) -> np.ndarray:
        """Each head's smallest V / V0 now, (N,), float64 (one kernel, one read)."""
        wp = self._wp
        from . import kernels_rollback as kb

        m = self.model
        self._ratio.fill_(3.0e38)
        wp.launch(kb._head_min_volume_ratio, dim=m.tet_count,
                  inputs=[m.tet_indices, m.tet_rest_volume, self._tet_head, self.state.positions],
                  outputs=[self._ratio], device=self.device)
        return self._ratio.numpy().astype(np.float64)

    def _frame(self, n: int, a0, a1, j0, j1) -> None:
        guard, stats = self.frame_guard, self.stats
        guard.save()
        live = np.array([i not in self._frozen for i in range(self.count)])
        for level in range(int(self.max_refinement) + 1):
            factor = 2 ** level
            self.stepper.frame(n * factor, a0, a1, j0, j1, self.dt / factor)
            ratio = self._head_ratios()
            bad = live & ~(ratio >= VOLUME_FLOOR)
            unconverged = not getattr(self.solver, "last_converged", True)
            try:
                self.solver.check(self.state)
                guard_problem = None
            except SimulationError as e:
                guard_problem = str(e)
            if guard_problem is not None and not bad.any():
                bad = live.copy()  # the guard names no head: every live head is suspect
            if not bad.any() and not unconverged:
                break
            if level == int(self.max_refinement):
                broken = bad & ~(ratio > 0.0)  # NaN or inverted at the bound: frozen
                X = guard._saved[0].numpy().astype(np.float64)  # positions at the frame start
                for i in np.flatnonzero(broken):
                    a, b = int(self._node[i]), int(self._node[i + 1])
                    self._frozen[int(i)] = X[a:b].copy()
                    self.failed[int(i)] = (f"frame at t = {self.time + n * self.dt:.4g} s failed even as "
                                           f"{n * factor} substeps: a NaN or an inverted tet (head {int(i)})")
                if (bad & ~broken).any():
                    stats.frames_below_floor += 1
                elif unconverged:
                    stats.unconverged_frames += 1
                self.solver.reset_guard()
                break
            stats.retries += 1
            if len(stats.events) < 20:
                heads = np.flatnonzero(bad).tolist()
                stats.events.append(f"t = {self.time:.4g} s: heads {heads[:8]} failed; retried as {2 * n * factor} "
                                    "substeps")
            guard.restore()
            self.solver.reset_guard()
        stats.frames += 1
        ok = ratio[live & np.isfinite(ratio)]
        stats.min_volume_ratio = min(stats.min_volume_ratio, float(ok.min()) if len(ok) else 1.0)
        self._ratios = ratio
        if level > 0:
            stats.substepped_frames += 1
            stats.max_substep_factor = max(stats.max_substep_factor, factor)

    # ------------------------------------------------------------------------------ results
    @property
    def status(self) -> list[dict]:
        """Per head: ``head``, ``ok`` (False: frozen by a failure), ``error``, ``frames`` (frames of
        the Model), ``substepped_frames``, ``retries``, ``frames_below_floor``,
        ``unconverged_frames`` (the Model's: its frames are taken together), ``min_volume_ratio``
        (the head's own at the last frame), ``iterations`` (the Model's solver: one count for all)."""
        st = self.stats
        r = getattr(self, "_ratios", np.ones(self.count))
        it = int(getattr(self.solver, "total_iterations", 0))
        return [{"head": i, "ok": i not in self.failed, "error": self.failed.get(i), "frames": st.frames,
                 "substepped_frames": st.substepped_frames, "retries": st.retries,
                 "frames_below_floor": st.frames_below_floor, "unconverged_frames": st.unconverged_frames,
                 "min_volume_ratio": float(r[i]), "iterations": it} for i in range(self.count)]

    def _head_nodes(self, i: int) -> np.ndarray:
        if i in self._frozen:
            return self._frozen[i].copy()
        a, b = int(self._node[i]), int(self._node[i + 1])
        return self.state.positions.numpy()[a:b].astype(np.float64)

    def positions(self, head: int | None = None, *, frame: str = "head"):
        """Tet node positions [m], float64: of one head (p, 3) or of every head (a list of N arrays),
        in the head's frame (``"head"``) or the world (``"world"``: its placement applied)."""
        check_choice("frame", frame, ("head", "world"))
        if head is None:
            X = self.state.positions.numpy().astype(np.float64)
            out = [self._frozen[i].copy() if i in self._frozen else X[self._node[i]:self._node[i + 1]].copy()
                   for i in range(self.count)]
            return [self._world(i, x) for i, x in enumerate(out)] if frame == "world" else out
        i = self._head(head)
        X = self._head_nodes(i)
        return self._world(i, X) if frame == "world" else X

    def surface(self, head: int) -> np.ndarray:
        """Head vertices of head ``head`` [m], (n, 3), float64, world frame (its placement)."""
        i = self._head(head)
        fr = self.rigs[i]
        return self._world(i, head_surface(fr, self._head_nodes(i), self._j[i], self._indices[id(fr)]))

    def fdp_points(self, head: int) -> np.ndarray:
        """The FDPs of head ``head`` [m], (84, 3), float64, world frame (order ``rig.fdp_ids``)."""
        i = self._head(head)
        fr = self.rigs[i]
        V = head_surface(fr, self._head_nodes(i), self._j[i], self._indices[id(fr)])
        parts = {k: P[None] for k, P in parts_at(fr, self._j[i]).items()}
        return self._world(i, fdp_points(fr, V[None], parts)[0].astype(np.float64))
