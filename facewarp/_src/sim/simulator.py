"""The face simulator: a :class:`~facewarp._src.physics.face_rig.FaceRig` on a device, stepped
by a user's loop or by an expression timeline, and the frame stream the exporters consume.

:class:`FaceSimulator` makes the Model, the solver with its muscle, support and jaw stages,
and keeps the controls (muscle activations, jaw angles); :class:`Frames` is what
:meth:`FaceSimulator.run` records.
"""

from __future__ import annotations

import io
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.checks import (check_activations, check_array, check_choice, check_int, check_jaw_angles,
                           check_positions, check_run_args, check_simulator_args, check_step_count, describe)
from ..core.errors import InputError
from ..core.limits import MAX_FPS, MAX_SECONDS
from ..core.fileio import atomic_write
from ..core.warp import get_warp
from ..expressions import MUSCLES, Timeline
from ..coupling.head_pose import HeadPose
from ..physics.face_rig import EDGE_DAMPING, FaceRig, node_jaw_amounts

__all__ = ["SOLVERS", "FaceSimulator", "Frames", "save_frames_npz"]


# ------------------------------------------------------------------------------------ frames
@dataclass
class Frames:
    """The frame stream of a simulation (what exporters consume).

    Attributes:
        times: Frame times [s], shape (f,).
        points: Head surface vertices [m], shape (f, n, 3), float32.
        faces: Head triangles, shape (m, 3).
        fdp_ids: FDP ids, shape (84,).
        fdp_points: FDP positions [m], shape (f, 84, 3).
        parts: Rigid part name -> (frames (f, k, 3), faces (l, 3)).
        muscle_names: Muscle instance names (M,).
        muscle_curves: Muscle fibre polylines [m], shape (f, M, samples, 3) (closed rings for
            sphincters repeat their first point).
        activations: Activations per frame, shape (f, M); jaw: (f, 2) [rad].
        steps_per_second: Simulated substeps per wall-clock second.
        substeps: Solver steps per frame; dt: step [s].
        frames_per_second: Frames simulated per wall-clock second (the stepping only, not the
            surface and curve read-back of each frame).
        realtime_factor: Simulated seconds per wall-clock second of stepping (1: real time).
        solver, material: The solver and material profile names.
    """

    times: np.ndarray
    points: np.ndarray
    faces: np.ndarray
    fdp_ids: np.ndarray
    fdp_points: np.ndarray
    parts: dict
    muscle_names: list
    muscle_curves: np.ndarray
    activations: np.ndarray
    jaw: np.ndarray
    steps_per_second: float = 0.0
    substeps: int = 0
    dt: float = 0.0
    frames_per_second: float = 0.0
    realtime_factor: float = 0.0
    solver: str = ""
    material: str = ""


def _unit_value(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a number in [0, 1], got {value!r}") from None
    if not (np.isfinite(v) and 0.0 <= v <= 1.0):
        raise InputError(f"{name}: expected a value in [0, 1], got {value!r}")
    return v


def _activation_vector(names: list[str], expr) -> np.ndarray:
    out = np.zeros(len(names), np.float32)
    for i, n in enumerate(names):
        side = n[-1] if n.endswith(("_L", "_R")) else None
        base = n[:-2] if side else n
        out[i] = expr.activation(base, side) if base in MUSCLES else 0.0
    return out


MAX_ADVANCE_FRAMES = int(MAX_SECONDS * MAX_FPS)
"""Most frames one :meth:`FaceSimulator.advance` takes (an hour at the highest frame rate)."""

SOLVERS = ("implicit", "verlet")
"""Solvers of :class:`FaceSimulator`: ``implicit`` (backward Euler, a few steps per frame; the
default) and ``verlet`` (the explicit reference, hundreds of substeps per frame)."""


class FaceSimulator:
    """A simulated face: Model + solver + muscle, support and jaw stages for one
    :class:`~facewarp.FaceRig` on one device.

    Step it in your own loop (:meth:`set_activations`, :meth:`set_jaw`, :meth:`step` or
    :meth:`advance`, then :meth:`surface`, :meth:`positions` or :meth:`fdp`; :meth:`reset`
    goes back to rest), or play a :class:`~facewarp.Timeline` with :meth:`run`. Controls
    change once per step and ramp linearly across it in up to :attr:`CONTROL_CHUNKS` pieces,
    each a run of substeps with no host round trip inside (a replayed CUDA graph on the GPU).

    Args:
        fr: The face rig (:func:`~facewarp.build_face` or :func:`~facewarp.load_face_rig`).
        device: Warp device, ``"cpu"`` or ``"cuda[:N]"``.
        solver: ``"implicit"`` (default: backward Euler, stable at one step per frame;
            :class:`~facewarp.physics.SolverImplicit`) or ``"verlet"`` (the explicit reference,
            :class:`~facewarp.physics.SolverVerlet`, at its stable substep).
        material: ``"physical"`` (default: tissue density, moduli in Pa, damping rates in 1/s)
            or ``"thesis"`` (Table 6.3 as it stands), or a material object
            (:mod:`facewarp.physics` ``MaterialPhysical`` / ``MaterialThesis``).
            ``solver="verlet", material="thesis"`` is the simulator before the implicit solver.
        dt: Substep [s]; default: implicit one step per frame, Verlet its stable step.
        substeps: Substeps (steps) per frame (overrides ``dt``).
        fps: Frames per second of :meth:`step` / :meth:`run`.
        iterations: Implicit solver: a fixed iteration count per step (the interactive mode: a
            fixed cost per frame) instead of iterating to ``tolerance``.
        tolerance: Implicit solver: converged when no node moves more than this in an iteration
            [m] (default 3e-5).
        method: Implicit solver method (default: ``"lbfgs"`` on the CPU, ``"newton-pcg"`` on CUDA).
        solver_options: Further keyword arguments of :class:`~facewarp.physics.SolverImplicit`
            (e.g. ``max_iterations``, ``spring_tolerance``, ``linear_iterations``).
        support_stiffness: Sliding-support stiffness [N/m] of every supported node (default:
            physical ``support_modulus`` times the node's area; thesis the hold stiffness).
        edge_damping: Edge dashpot [N s/m] (default: thesis 500, physical 0).
        mass_scaling: Verlet: add mass to the 2 % of nodes below the chosen substep.
        contact: Keep the lips from crossing each other, lips and cheeks outside the teeth and
            the lids outside the eyeballs (:class:`~facewarp.physics.ContactStage`; default True).
        contact_modulus: Contact stiffness per unit sheet area [N/m^3] (default
            ``CONTACT_MODULUS``, 2e9, with the physical material; the thesis profile uses its hold
            stiffness), plus ``CONTACT_MUSCLE_RATIO`` (50) times the node's muscle springs.

    Raises:
        InputError: an unknown solver, material or method, or bad numbers.
    """

    CONTROL_CHUNKS = 16

    def __init__(self, fr: FaceRig, *, device: str = "cpu", solver: str = "implicit", material="physical",
                 dt: float | None = None, substeps: int | None = None, fps: float = 30.0,
                 iterations: int | None = None, tolerance: float | None = None, method: str | None = None,
                 solver_options: dict | None = None, support_stiffness: float | None = None, edge_damping: float | None = None,
                 mass_scaling: bool = True, contact: bool = True, contact_modulus: float | None = None):
        device = check_simulator_args(fr, device=device, solver=solver, solvers=SOLVERS, dt=dt, substeps=substeps,
                                      fps=fps, iterations=iterations, tolerance=tolerance, method=method,
                                      solver_options=solver_options, support_stiffness=support_stiffness,
                                      edge_damping=edge_damping, mass_scaling=mass_scaling, contact=contact,
                                      contact_modulus=contact_modulus)
        wp = get_warp()
        from dataclasses import replace

        from ..coupling.kinematic import CarryStage, JawStage
        from ..physics.contact import CONTACT_MODULUS, CONTACT_MUSCLE_RATIO, ContactStage, contact_geometry
        from ..physics.materials import MaterialPhysical, material_profile
        from ..physics.model import ModelBuilder
        from ..physics.muscle_stage import MuscleStage, SupportStage
        from ..physics.solvers.implicit import SolverImplicit
        from ..physics.solvers.verlet import MASS_SCALING_QUANTILE, SolverVerlet, scale_masses

        if solver not in SOLVERS:
            raise InputError(f"solver: expected one of {', '.join(SOLVERS)}, got {solver!r}")
        mat = material_profile(material)
        physical = isinstance(mat, MaterialPhysical)
        if not (isinstance(fps, (int, float)) and np.isfinite(fps) and fps > 0):
            raise InputError(f"fps: expected a positive number, got {fps!r}")
        if substeps is not None and not (isinstance(substeps, (int, np.integer)) and substeps >= 1):
            raise InputError(f"substeps: expected a whole number >= 1, got {substeps!r}")
        if dt is not None and not (isinstance(dt, (int, float)) and np.isfinite(dt) and dt > 0):
            raise InputError(f"dt: expected a positive number of seconds, got {dt!r}")
        self.fr = fr
        self.fps = float(fps)
        self.solver_name = solver
        self.material = mat
        if edge_damping is None:
            edge_damping = 0.0 if physical else EDGE_DAMPING
        builder = ModelBuilder(fr.nodes, fr.tets, layer=fr.layer, fixed=fr.fixed, held=fr.held, material=mat,
                               muscle_count=len(fr.rig.names), edge_damping=edge_damping)
        # springs of the stages, per node: sliding supports and muscles (physical: per unit area)
        rig = fr.rig
        if physical:
            k_support = mat.support_modulus * builder.vertex_area[fr.support_nodes]
            per_node = np.bincount(rig.att_node, minlength=len(fr.nodes))
            att_k = mat.muscle_modulus * builder.vertex_area[rig.att_node] / np.maximum(per_node[rig.att_node], 1)
            rig = replace(rig, att_stiffness=att_k)
        else:
            k_support = float(builder.hold_stiffness.max()) if fr.held.any() else 0.0
            if mat.muscle_stiffness is not None:
                per_node = np.bincount(rig.att_node, minlength=len(fr.nodes))
                rig = replace(rig, att_stiffness=mat.muscle_stiffness / np.maximum(per_node[rig.att_node], 1))
        if support_stiffness is not None:
            k_support = support_stiffness
        extra = np.zeros(len(fr.nodes))
        np.add.at(extra, fr.support_nodes, np.broadcast_to(k_support, (len(fr.support_nodes),)))
        np.add.at(extra, rig.att_node, rig.att_stiffness)
        # contact springs (one-sided, on the lips, the cheeks near the teeth and the lids)
        self.contact_geometry = None
        if contact:
            if contact_modulus is not None and not (isinstance(contact_modulus, (int, float))
                                                    and np.isfinite(contact_modulus) and contact_modulus > 0):
                raise InputError(f"contact_modulus: expected a positive number [N/m^3], got {contact_modulus!r}")
            # a node's contact spring holds against the tissue (per area, or the thesis profile's
            # hold stiffness) and against its own muscle springs (CONTACT_MUSCLE_RATIO times them)
            k_muscle = np.bincount(rig.att_node, weights=rig.att_stiffness, minlength=len(fr.nodes))
            if physical:
                k_contact = float(contact_modulus or CONTACT_MODULUS) * builder.vertex_area
            else:
                k_contact = np.full(len(fr.nodes), float(builder.hold_stiffness.max()) if fr.held.any() else 0.0)
            k_contact = k_contact + CONTACT_MUSCLE_RATIO * k_muscle
            self.contact_geometry = contact_geometry(fr)
            g = self.contact_geometry
            cand = np.unique(np.concatenate([*g.lip_nodes, *[t[4] for t in g.teeth], g.eye_nodes]).astype(np.int64))
            extra[cand] += k_contact[cand]
        # the Verlet reference substep (selective mass scaling: the 2 % of nodes with the smallest
        # own limit, short edges and flat tets in creases of adapted heads, get the mass that lifts
        # them to it); the thesis profile's per-substep damping is a rate of 0.002 / that step
        frame_dt = 1.0 / self.fps
        self.added_mass_fraction = 0.0
        if solver == "verlet":
            dt_safe, self.added_mass_fraction = scale_masses(
                builder, quantile=MASS_SCALING_QUANTILE if mass_scaling else 0.0, extra_stiffness=extra)
            if substeps is None:
                substeps = int(np.ceil(frame_dt / (dt or dt_safe)))
            self.substeps = int(substeps)
            self.dt = frame_dt / self.substeps
            if self.dt > 2.0 * dt_safe:
                raise InputError(f"substeps {substeps}: dt {self.dt:.2e} s is above twice the stable step "
                                 f"{dt_safe:.2e} s; use at least {int(np.ceil(frame_dt / (2 * dt_safe)))} substeps")
            if not physical:
                builder.damping_rate = mat.damping / self.dt
        else:
            if substeps is None:
                substeps = 1 if dt is None else int(np.ceil(frame_dt / dt))
            self.substeps = int(substeps)
            self.dt = frame_dt / self.substeps
            if not physical:
                ref = ModelBuilder(fr.nodes, fr.tets, layer=fr.layer, fixed=fr.fixed, held=fr.held, material=mat)
                dt_ref, _ = scale_masses(ref, quantile=MASS_SCALING_QUANTILE if mass_scaling else 0.0)
                builder.damping_rate = mat.damping / dt_ref
        self.builder = builder
        self.model = builder.finalize(device)
        self.device = self.model.device
        self.jaw = fr.jaw
        self.jaw_stage = JawStage(self.jaw, fr.jaw_nodes, fr.jaw_amount, self.model.rest_positions, self.device)
        self.support = SupportStage(self.jaw, fr.support_nodes, fr.support_normal, fr.support_amount, k_support,
                                    self.model.rest_positions, self.device)
        node_jaw = node_jaw_amounts(fr)
        self.muscles = MuscleStage(rig, self.jaw, self.device, node_amount=node_jaw)
        carried = np.flatnonzero((node_jaw > 0) & ~fr.fixed)
        self.carry = CarryStage(self.jaw, carried, node_jaw[carried], self.device)
        stages = [self.carry, self.jaw_stage, self.support, self.muscles]
        self.contact = None
        if contact:
            # the inner lid sheet gliding on the eyeball has the sliding support's stiffness
            k_glide = (mat.support_modulus * builder.vertex_area if physical and support_stiffness is None
                       else np.full(len(fr.nodes), float(np.median(k_support)) if np.size(k_support) else 0.0))
            self.contact = ContactStage(fr, k_contact, self.device, geometry=self.contact_geometry,
                                        glide_stiffness=k_glide)
            stages.append(self.contact)
        if solver == "verlet":
            self.solver = SolverVerlet(self.model, stages=stages)
        else:
            opts = {"tolerance": 3e-5 if tolerance is None else tolerance, **(solver_options or {})}
            self.solver = SolverImplicit(self.model, stages=stages, method=method, iterations=iterations, **opts)
        self.state = self.model.state()
        self.scratch = self.model.state()
        self.control = self.model.control()
        # the controls go up through pinned host memory: an asynchronous copy, no allocation (one
        # row per control chunk, so no chunk's values are overwritten before its copy has run)
        na = int(self.control.activations.shape[0])
        self._control_host = wp.zeros(self.CONTROL_CHUNKS * (na + 2), dtype=float, device="cpu",
                                      pinned=bool(self.device.is_cuda))
        # a frame is one replayed CUDA graph; the adaptive device solver's Newton loop is a
        # conditional graph node (CUDA 12.4+): without one, the frames run launch by launch
        self.use_graph = bool(self.device.is_cuda) and (
            not getattr(self.solver, "adaptive", False) or wp.is_conditional_graph_supported())
        self._graphs: dict[int, object] = {}
        self._wp = wp
        self.step_seconds = 0.0
        # head surface <- outer nodes
        sv = fr.surface_vertex
        self.node_of_vertex = np.where(sv >= 0)[0]
        self.vertex_of_node = sv[self.node_of_vertex]
        self._pose = HeadPose()
        self.reset()

    # ------------------------------------------------------------------------------ controls
    @property
    def muscle_names(self) -> list[str]:
        """Muscle instance names, in the order of :meth:`set_activations` arrays (M,)."""
        return list(self.fr.rig.names)

    @property
    def time(self) -> float:
        """Simulated time [s] since the last :meth:`reset`."""
        return self._steps_taken * self.dt

    def activation_vector(self, activations) -> np.ndarray:
        """Activations as the (M,) float32 array the solver reads.

        Args:
            activations: An :class:`~facewarp.Expression`, a dict muscle name -> value in [0, 1]
                (an instance name such as ``"zygomatic_major_L"``, or a Table 6.2 name such as
                ``"zygomatic_major"`` for both sides; missing muscles are 0), or an array (M,)
                in :attr:`muscle_names` order.

        Raises:
            InputError: unknown muscle, wrong length, or a value outside [0, 1] (NaN included).
        """
        names = self.fr.rig.names
        activations = check_activations(activations, len(names))
        if hasattr(activations, "activation") and hasattr(activations, "jaw_u"):
            return _activation_vector(names, activations)
        if isinstance(activations, dict):
            out = np.zeros(len(names), np.float32)
            for key, value in activations.items():
                hit = [i for i, n in enumerate(names) if n == key or (n.endswith(("_L", "_R")) and n[:-2] == key)]
                if not hit:
                    raise InputError(f"activations: unknown muscle {key!r} (known: {', '.join(sorted(set(names)))})")
                v = _unit_value(f"activations[{key!r}]", value)
                out[hit] = v
            return out
        a = np.asarray(activations, dtype=np.float64)
        if a.shape != (len(names),):
            raise InputError(f"activations: expected a dict or an array of shape ({len(names)},), got shape {a.shape}")
        bad = np.flatnonzero(~np.isfinite(a) | (a < 0.0) | (a > 1.0))
        if len(bad):
            raise InputError(f"activations: {names[bad[0]]} is {a[bad[0]]!r}, expected a value in [0, 1]")
        return a.astype(np.float32)

    def set_activations(self, activations) -> None:
        """Set the muscle activations reached at the end of the next :meth:`step` (they ramp
        linearly from the current ones over the step). See :meth:`activation_vector`."""
        self._target_a = self.activation_vector(activations)

    def set_jaw(self, opening: float, side: float = 0.0) -> None:
        """Set the jaw angles [rad] reached at the end of the next :meth:`step`.

        Args:
            opening: Rotation about the condyle u-axis (Sec. 6.4.3), 0..60 deg in radians.
            side: Rotation about the vertical v-axis, within +-5 deg in radians.

        Raises:
            InputError: a non-finite angle or one outside its range.
        """
        from ..expressions import JAW_U_MAX, JAW_V_MAX

        u, v = check_jaw_angles(opening, side)
        if not (np.isfinite(u) and -1e-9 <= u <= JAW_U_MAX + 1e-9):
            raise InputError(f"jaw opening: expected 0..{JAW_U_MAX:.4f} rad (0..60 deg), got {opening!r}")
        if not (np.isfinite(v) and abs(v) <= JAW_V_MAX + 1e-9):
            raise InputError(f"jaw side: expected within +-{JAW_V_MAX:.4f} rad (+-5 deg), got {side!r}")
        self._target_j = np.array([max(u, 0.0), v], np.float32)

    def reset(self) -> None:
        """Back to rest: positions, velocities, activations and jaw at zero, time 0."""
        for s in (self.state, self.scratch):  # in place: captured CUDA graphs stay valid
            s.positions.assign(self.model.rest_positions)
            s.prev_positions.assign(self.model.rest_positions)
        self.control.activations.zero_()
        self.control.jaw_angles.zero_()
        self.control.external_force.zero_()
        self._pose.reset()
        self.carry.reset()
        self.solver.reset()
        self._a = np.zeros(len(self.fr.rig.names), np.float32)
        self._j = np.zeros(2, np.float32)
        self._target_a, self._target_j = self._a.copy(), self._j.copy()
        self._steps_taken = 0
        self.muscles.update_geometry(self.control)  # the rest fibres (frame 0 of run() draws them)

    # ------------------------------------------------------------------------------ stepping
    def step(self, dt: float | None = None) -> None:
        """Advance by exactly ``dt`` [s] (default one frame, ``1 / fps``), in whole substeps.

        ``dt`` must be a whole number of the solver's steps (:attr:`dt`, ``1 / (fps *
        substeps)``): ``step(0.001)`` on a 30 fps, one-substep simulator is refused rather than
        rounded to a frame, so that :attr:`time` always advances by what was asked. Make the
        simulator with ``substeps=`` or ``dt=`` for finer steps.

        The controls set since the last step ramp linearly from their old to their new
        values across the step (a jump would jolt the held nodes). Raises
        :class:`~facewarp.SimulationError` if a substep produced a NaN or an inverted tet.

        Raises:
            InputError: ``dt`` not a positive finite number, or not a whole number of solver steps.
        """
        n = self.substeps if dt is None else check_step_count(dt, self.dt)
        t0 = time.perf_counter()
        if not self._pose.identity:  # the head rides a moving body: loads of the accelerating frame
            f = self._pose.node_forces(self.positions(), self.builder.mass, n * self.dt)
            self.control.external_force.assign(f.astype(np.float32))
        chunks = max(1, min(n, self.CONTROL_CHUNKS))
        bounds = np.linspace(0, n, chunks + 1).round().astype(int)
        a0, j0 = self._a, self._j
        wp, host, na = self._wp, self._control_host.numpy(), len(a0)
        for c in range(chunks):
            w = (c + 1) / chunks
            o = c * (na + 2)
            host[o:o + na] = (1 - w) * a0 + w * self._target_a
            host[o + na:o + na + 2] = (1 - w) * j0 + w * self._target_j
            if na:
                wp.copy(self.control.activations, self._control_host, src_offset=o, count=na)
            wp.copy(self.control.jaw_angles, self._control_host, src_offset=o + na, count=2)
            self._run_substeps(int(bounds[c + 1] - bounds[c]))
        self._a, self._j = self._target_a.copy(), self._target_j.copy()
        self._pose.advance()
        self._steps_taken += n
        self.solver.check(self.state)  # a host read: also waits for the device
        self.step_seconds += time.perf_counter() - t0

    def set_head_pose(self, R, t) -> None:
        """Set the cranium body's pose in the world, reached at the end of the next step.

        The face is simulated in the head's own frame: the fixed border, held nodes and rigid
        parts stay put there, so a head moving rigidly does not drag its skin; the motion acts
        through the loads of the accelerating frame (linear and angular acceleration,
        centrifugal, and the change of gravity; :class:`~facewarp.HeadPose`). :meth:`surface`,
        :meth:`fdp` and :meth:`fdp_points` answer in the world frame (``R x + t``);
        :meth:`positions` stays in the head frame.

        Args:
            R: Rotation, shape (3, 3), float (orthonormal, det +1).
            t: Translation [m], shape (3,).

        Raises:
            InputError: R not a rotation, or non-finite values.
        """
        self._pose.set(R, t)

    @property
    def head_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The current head pose (R (3, 3), t (3,) [m]) set by :meth:`set_head_pose`."""
        return self._pose.R.copy(), self._pose.t.copy()

    @property
    def activations(self) -> np.ndarray:
        """Activations reached by the last step, shape (M,), float32 (:attr:`muscle_names` order)."""
        return self._a.copy()

    @property
    def jaw_angles(self) -> np.ndarray:
        """Jaw angles reached by the last step [rad], (opening, side), float32."""
        return self._j.copy()

    def hold_stiffness(self) -> np.ndarray:
        """Stiffness of each node's hold spring [N/m], shape (p,), float64 (0 for free nodes)."""
        return np.asarray(self.builder.hold_stiffness, np.float64).copy()

    def muscle_curves(self, samples: int = 24) -> np.ndarray:
        """Muscle fibre polylines at the current state [m], shape (M, samples, 3), float64, in
        the world frame."""
        check_int("samples", samples, low=2, high=10_000)
        C = self._curves(samples)
        return self._pose.to_world(C.reshape(-1, 3)).reshape(C.shape)

    def advance(self, frames: int = 1) -> None:
        """Advance ``frames`` frames of ``1 / fps`` with the current controls."""
        check_int("frames", frames, low=0, high=MAX_ADVANCE_FRAMES)
        for _ in range(int(frames)):
            self.step()

    def _run_substeps(self, n: int) -> None:
        """``n`` substeps with the current control; on CUDA a replayed graph (one per n)."""
        if n <= 0:
            return
        if not self.use_graph:
            self._substeps(n)
            return
        g = self._graphs.get(n)
        if g is None:
            with self._wp.ScopedCapture(device=self.device) as cap:
                self._substeps(n)
            g = self._graphs[n] = cap.graph
        self._wp.capture_launch(g)

    def _substeps(self, n: int) -> None:
        for s in range(n):
            src, dst = (self.state, self.scratch) if s % 2 == 0 else (self.scratch, self.state)
            self.solver.step(src, dst, self.control, self.dt)
        if n % 2 == 1:
            self.state.assign(self.scratch)

    # ------------------------------------------------------------------------------ results
    def positions(self) -> np.ndarray:
        """Tet node positions [m], shape (p, 3), float64 (a host copy; see :attr:`positions_wp`)."""
        return self.state.positions.numpy().astype(np.float64)

    @property
    def positions_wp(self):
        """Tet node positions [m] on the device, shape (p,), ``wp.vec3`` (no copy; valid until
        the next step)."""
        return self.state.positions

    def surface(self, X: np.ndarray | None = None, jaw_angles=None, *, frame: str = "world") -> np.ndarray:
        """Head vertices [m], shape (n, 3), float64: the simulated outer nodes written in, the
        rims of the frontal face's openings following them (``FaceRig.opening_*``), the rest of
        the head moved kinematically by the jaw (its per-vertex amount).

        Args:
            X: Node positions (p, 3) [m], head frame; default the current state.
            jaw_angles: (u, v) [rad]; default the current jaw.
            frame: ``"world"`` (the head pose of :meth:`set_head_pose` applied; the same as
                ``"head"`` while the head has not moved) or ``"head"``.
        """
        check_choice("frame", frame, ("world", "head"))
        X = check_positions("X", X, len(self.fr.nodes))
        jaw_angles = None if jaw_angles is None else check_array("jaw_angles", jaw_angles, shape=(2,))
        fr = self.fr
        X = self.positions() if X is None else X
        ja = self._j if jaw_angles is None else jaw_angles
        V = fr.head_vertices.copy()
        if fr.vertex_jaw is not None and (ja[0] or ja[1]):
            m = fr.vertex_jaw > 0
            V[m] = self.jaw.apply(V[m], fr.vertex_jaw[m], float(ja[0]), float(ja[1]))
        V[self.vertex_of_node] = X[self.node_of_vertex]
        if fr.opening_vertex is not None and len(fr.opening_vertex):  # rims of openings follow the skin
            ov, w = fr.opening_vertex, fr.opening_weight
            u = np.einsum("qc,qcd->qd", w, X[fr.opening_node] - fr.nodes[fr.opening_node])
            share = w.sum(1, keepdims=True)
            V[ov] = (1.0 - share) * V[ov] + share * fr.head_vertices[ov] + u
        return self._pose.to_world(V) if frame == "world" else V

    def contact_crossings(self, X: np.ndarray | None = None) -> dict:
        """Crossings at node positions X (default the current state; head frame): lip nodes inside
        the other lip, nodes inside the teeth, lid nodes inside an eyeball
        (:func:`~facewarp.physics.contact_crossings`; 0 each while the contact holds)."""
        from ..physics.contact import contact_crossings, contact_geometry

        if self.contact_geometry is None:
            self.contact_geometry = contact_geometry(self.fr)
        X = check_positions("X", X, len(self.fr.nodes))
        return contact_crossings(self.fr, self.positions() if X is None else X, self._j,
                                 geometry=self.contact_geometry)

    def fdp(self, fdp_id: str) -> np.ndarray:
        """Current position [m] of one FDP (e.g. ``"2.1"``, the chin), shape (3,), float64."""
        if not isinstance(fdp_id, str):
            raise InputError(f"fdp_id: expected an FDP id such as '2.1', got {describe(fdp_id)}")
        ids = [str(k) for k in self.fr.fdp_ids]
        if str(fdp_id) not in ids:
            raise InputError(f"fdp_id: {fdp_id!r} is not an FDP of this head")
        return self.fdp_points()[ids.index(str(fdp_id))]

    def fdp_points(self) -> np.ndarray:
        """Current positions [m] of all FDPs, shape (84, 3), float64 (order: ``rig.fdp_ids``)."""
        V = self.surface()
        parts = self._parts_now(self._j)
        return self._fdp_points(V[None], {k: P[None] for k, P in parts.items()})[0].astype(np.float64)

    def part_points(self, *, frame: str = "world") -> dict:
        """The rigid parts now (eyes, teeth, tongue): name -> vertices [m], shape (k, 3), float64;
        the lower teeth and tongue turned by the current jaw, ``frame="world"`` with the head pose
        applied (as :meth:`surface`), ``"head"`` without it."""
        return self._parts_now(self._j, frame=frame)

    def _parts_now(self, j, *, frame: str = "world") -> dict:
        out = {name: self.fr.part_at(name, j) for name in self.fr.parts}
        return {k: self._pose.to_world(P) for k, P in out.items()} if frame == "world" else out

    def run(self, timeline: Timeline, seconds: float, *, progress=None, curve_samples: int = 24, jaw=None) -> Frames:
        """Simulate ``seconds`` of ``timeline`` from rest (it calls :meth:`reset`); one frame
        every 1/fps s, frame 0 at rest.

        Args:
            jaw: None (the kinematic jaw: the timeline's angles), or a driver with
                ``step(expression)`` that sets the jaw and steps this simulator one frame (the MuJoCo
                jaw of ``facewarp simulate --jaw mujoco``).
        """
        seconds = check_run_args(timeline, seconds, progress, curve_samples, fps=self.fps,
                                 vertex_count=len(self.fr.head_vertices))
        fr = self.fr
        timeline = timeline.for_head(fr)  # chin drops -> this head's jaw angles (idempotent)
        self.reset()
        nf = int(round(seconds * self.fps)) + 1
        times = np.arange(nf) / self.fps
        names = fr.rig.names
        pts = np.zeros((nf, len(fr.head_vertices), 3), np.float32)
        acts = np.zeros((nf, len(names)), np.float32)
        jaws = np.zeros((nf, 2), np.float32)
        curves = np.zeros((nf, len(names), curve_samples, 3), np.float32)
        parts_frames = {k: np.zeros((nf, len(V), 3), np.float32) for k, (V, _) in fr.parts.items()}
        t0 = time.perf_counter()
        step0 = self.step_seconds
        e0 = timeline.sample(0.0)
        self._a = self._target_a = _activation_vector(names, e0)
        self._j = self._target_j = np.array([e0.jaw_u, e0.jaw_v], np.float32)
        for k, t in enumerate(times):
            if k > 0:
                e = timeline.sample(float(t))
                self._target_a = _activation_vector(names, e)
                self._target_j = np.array([e.jaw_u, e.jaw_v], np.float32)
                if jaw is None:
                    self.step()
                else:  # e.g. the MuJoCo jaw: it sets the angles it reached and steps
                    jaw.step(e)
            pts[k] = self.surface()
            acts[k], jaws[k] = self._a, self._j
            curves[k] = self._curves(curve_samples)
            for name, P in self._parts_now(self._j).items():
                parts_frames[name][k] = P
            if progress:
                progress(k, nf)
        wall = time.perf_counter() - t0
        stepping = max(self.step_seconds - step0, 1e-9)
        fdp = self._fdp_points(pts, parts_frames)
        return Frames(times, pts, fr.head_faces, fr.fdp_ids, fdp,
                      {k: (v, fr.parts[k][1]) for k, v in parts_frames.items()}, list(names), curves, acts, jaws,
                      self._steps_taken / max(wall, 1e-9), self.substeps, self.dt,
                      frames_per_second=(nf - 1) / stepping, realtime_factor=(nf - 1) / self.fps / stepping,
                      solver=self.solver_name, material=self.material.name)

    def _curves(self, samples: int) -> np.ndarray:
        from ..physics.muscle_stage import _bezier_np

        rig = self.fr.rig
        ctrl = self.muscles.ctrl.numpy().astype(np.float64)
        out = np.zeros((len(rig.names), samples, 3))
        curve_m = rig.ctrl_muscle[rig.curve_ctrl[:, 0]]
        for m in range(len(rig.names)):
            cs = np.where(curve_m == m)[0]
            per = max(2, samples // len(cs))
            seq = [_bezier_np(ctrl[rig.curve_ctrl[c]][None], rig.curve_weight[c][None], np.linspace(0, 1, per)) for c in cs]
            P = np.concatenate(seq)
            idx = np.linspace(0, len(P) - 1, samples).round().astype(int)
            out[m] = P[idx]
        return out

    def _fdp_points(self, pts, parts_frames) -> np.ndarray:
        fr = self.fr
        out = np.zeros((len(pts), len(fr.fdp_ids), 3), np.float32)
        for i, (part, f, b) in enumerate(zip(fr.fdp_part, fr.fdp_face, fr.fdp_bary)):
            if part == "head":
                tri = fr.head_faces[f]
                out[:, i] = np.einsum("k,fkd->fd", b, pts[:, tri])
            else:
                V = parts_frames[str(part)]
                tri = fr.parts[str(part)][1][f]
                out[:, i] = np.einsum("k,fkd->fd", b, V[:, tri])
        return out


def save_frames_npz(path, frames: Frames) -> Path:
    """``frames.npz``: points (f, n, 3) [m], times (f,), fdp_ids (84,), fdp_points (f, 84, 3), faces,
    activations (f, M), muscle_names (M,), jaw (f, 2) [rad], muscle_curves (f, M, s, 3)."""
    from ..core.checks import check_has, check_path

    check_path("path", path)
    check_has("frames", frames, ("points", "times", "fdp_points"), "Frames (FaceSimulator.run)")
    buf = io.BytesIO()
    np.savez_compressed(buf, points=frames.points, times=frames.times, fdp_ids=frames.fdp_ids,
                        fdp_points=frames.fdp_points, faces=frames.faces, activations=frames.activations,
                        muscle_names=np.array(frames.muscle_names), jaw=frames.jaw, muscle_curves=frames.muscle_curves)
    with atomic_write(path, "wb", encoding=None) as f:
        f.write(buf.getvalue())
    return Path(path)
