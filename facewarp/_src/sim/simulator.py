"""The face simulator: a :class:`~facewarp._src.physics.face_rig.FaceRig` made into a Model
(:meth:`~facewarp._src.physics.builder.ModelBuilder.add_face`: what is simulated, every stiffness)
and stepped on a device by a user's loop or a timeline. What a step changes is the State's, so
:meth:`FaceSimulator.reset` is a copy of the rest State; the read-outs are functions of the rig
and the positions (:mod:`.readout`), the frame loop is :class:`.stepper.FrameStepper`'s.
"""

from __future__ import annotations

import time

import numpy as np

from ..core.checks import (check_array, check_bool, check_choice, check_device, check_int, check_mapping,
                           check_name, check_number, check_positions, check_step_count, describe)
from ..core.errors import InputError
from ..core.limits import MAX_ADVANCE_FRAMES
from ..coupling.head_pose import HeadPose
from ..expressions import Timeline
from ..physics.face_rig import FaceRig
from .frames import Frames, save_frames_npz
from .play import FrameRecorder, play
from .readout import activation_vector, fdp_points, head_surface, jaw_vector, muscle_curves, parts_at, surface_index
from .rollback import MAX_REFINEMENT, FrameGuard, FrameStats, step_frame
from .stepper import SOLVERS, FrameStepper, build_face, face_stages

__all__ = ["SOLVERS", "FaceSimulator", "Frames", "check_run_args", "check_simulator_args", "face_stages", "save_frames_npz"]


class FaceSimulator:
    """A simulated face: the Model of one :class:`~facewarp.FaceRig` on one device, its solver
    and State. Step it in your own loop (:meth:`set_activations`, :meth:`set_jaw`, :meth:`step`
    or :meth:`advance`, then :meth:`surface`, :meth:`positions` or :meth:`fdp`; :meth:`reset`
    goes back to rest), or play a :class:`~facewarp.Timeline` with :meth:`run`. Controls ramp
    linearly across a step in up to :attr:`CONTROL_CHUNKS` pieces (:class:`.stepper.FrameStepper`). ``stats``:
    the frames since :meth:`reset` (:class:`.rollback.FrameStats`); ``max_refinement``: retries up to 2^6 x substeps.

    Args:
        fr: The face rig (:func:`~facewarp.build_face` or :func:`~facewarp.load_face_rig`).
        device: Warp device, ``"cpu"`` or ``"cuda[:N]"``.
        solver: ``"implicit"`` (default: backward Euler, one step per frame) or ``"verlet"`` (the
            explicit reference at its stable substep); :data:`.stepper.SOLVERS`.
        material: ``"physical"`` (default), ``"thesis"`` (Table 6.3; with ``"verlet"`` the
            simulator before the implicit solver) or a material object.
        dt, substeps, fps: Substep [s] (default: implicit one per frame, Verlet its stable step),
            substeps per frame (overrides ``dt``), frames per second of :meth:`step` / :meth:`run`.
        iterations, tolerance, method, solver_options: The implicit solver's (a fixed iteration
            count per step; the convergence step [m], default 3e-5; ``"lbfgs"`` on the CPU,
            ``"newton-pcg"`` on CUDA by default; further keywords of :class:`~facewarp.physics.SolverImplicit`).
        support_stiffness, edge_damping, contact, contact_modulus, mass_scaling: As
            :meth:`~facewarp.physics.ModelBuilder.add_face` (``mass_scaling``: Verlet adds mass
            to the 2 % of nodes below the chosen substep).

    Raises:
        InputError: an unknown solver, material or method, or bad numbers.
    """

    CONTROL_CHUNKS = 16

    def __init__(self, fr: FaceRig, *, device: str = "cpu", solver: str = "implicit", material="physical",
                 dt: float | None = None, substeps: int | None = None, fps: float = 30.0,
                 iterations: int | None = None, tolerance: float | None = None, method: str | None = None,
                 solver_options: dict | None = None, support_stiffness: float | None = None,
                 edge_damping: float | None = None, mass_scaling: bool = True, contact: bool = True,
                 contact_modulus: float | None = None, _builder=None):
        device = check_simulator_args(fr, device=device, solver=solver, fps=fps, options=dict(
            dt=dt, substeps=substeps, iterations=iterations, tolerance=tolerance, method=method,
            solver_options=solver_options, support_stiffness=support_stiffness, edge_damping=edge_damping,
            mass_scaling=mass_scaling, contact=contact, contact_modulus=contact_modulus))
        b = build_face(fr, device=device, solver=solver, material=material, fps=fps, dt=dt, substeps=substeps,
                       iterations=iterations, tolerance=tolerance, method=method, solver_options=solver_options,
                       support_stiffness=support_stiffness, edge_damping=edge_damping, mass_scaling=mass_scaling,
                       contact=contact, contact_modulus=contact_modulus, builder=_builder)
        self.fr, self.fps, self.solver_name, self.material = fr, float(fps), solver, b["material"]
        self.builder, self.model, self.solver = b["builder"], b["model"], b["solver"]
        self.substeps, self.dt, self.added_mass_fraction = b["substeps"], b["dt"], b["added_mass_fraction"]
        st = b["stages"]
        self.carry, self.jaw_stage, self.support, self.muscles, self.contact = (
            st["carry"], st["jaw"], st["support"], st["muscles"], st["contact"])
        self.control, self.rest_state, self.state, self.scratch = b["control"], b["rest_state"], b["state"], b["scratch"]
        from ..physics.warmup import load_kernels, solver_kernel_modules
        from . import kernels_rollback

        # every kernel module of the run loaded (compiled side by side on a first run, said on stderr)
        load_kernels(self.model.device, solver_kernel_modules(self.solver) + [kernels_rollback])
        self.muscles.update_geometry(self.control, self.rest_state)  # the rest fibres of zero control (frame 0 of run())
        self.device, self.jaw, self.contact_geometry = self.model.device, fr.jaw, fr.contact if contact else None
        self.stepper = FrameStepper(self.solver, self.state, self.scratch, self.control, self.dt,
                                    chunks=self.CONTROL_CHUNKS)
        self.step_seconds = 0.0
        self._surface_index = surface_index(fr)
        self._pose = HeadPose()
        self.max_refinement, self.frame_guard = MAX_REFINEMENT, FrameGuard(self)
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
        """Activations as the (M,) float32 array the solver reads (:func:`.readout.activation_vector`)."""
        return activation_vector(self.fr.rig.names, activations)

    def set_activations(self, activations) -> None:
        """Set the muscle activations reached at the end of the next :meth:`step` (they ramp
        linearly from the current ones over the step). See :meth:`activation_vector`."""
        self._target_a = self.activation_vector(activations)

    def set_jaw(self, opening: float, side: float = 0.0) -> None:
        """Set the jaw angles [rad] reached at the end of the next :meth:`step`
        (:func:`.readout.jaw_vector`: ``opening`` 0..60 deg, ``side`` +-5 deg)."""
        self._target_j = jaw_vector(opening, side)

    def set_eye_gaze(self, gaze) -> None:
        """Turn the eyeballs (rigid parts about their centres) at the end of the next :meth:`step`:
        ``gaze`` (2, 2) [rad], per eye (left at +x, right) its yaw (> 0 towards +x) and pitch (> 0 up),
        each within +-90 deg (:func:`.readout.eye_gaze_rotation`). The lids rest on the eyeball's
        sphere, which turning leaves in place: the gaze changes what is drawn and the eyes' FDPs."""
        g = check_array("gaze", gaze, shape=(2, 2)).astype(np.float32)
        if np.abs(g).max() > np.pi / 2:
            raise InputError(f"gaze: eye angles lie within +-90 deg, got {np.degrees(np.abs(g).max()):.1f} deg")
        self._target_g = g

    @property
    def eye_gaze(self) -> np.ndarray:
        """The eyes' (yaw, pitch) [rad] reached by the last step, (2, 2) float32 (left, right)."""
        return getattr(self, "_g", np.zeros((2, 2), np.float32)).copy()

    def set_activation_vector(self, a) -> None:
        """Set the activations reached at the end of the next :meth:`step` from an (M,) float32 array
        already checked (:meth:`activation_vector`'s; :class:`~facewarp.FaceBatch` checks every head's at once)."""
        self._target_a = np.asarray(a, np.float32)

    def set_jaw_vector(self, j) -> None:
        """Set the jaw angles [rad] reached at the end of the next :meth:`step` from a (2,) float32 array
        already checked (:func:`.readout.jaw_vector`'s)."""
        self._target_j = np.asarray(j, np.float32)

    def set_head_pose(self, R, t) -> None:
        """Set the cranium's pose (R (3, 3) rotation, t (3,) [m]) reached at the end of the next
        step; the face, simulated in the head's frame, feels the loads of the accelerating frame
        (:class:`~facewarp.coupling.HeadPose`). :meth:`surface` and :meth:`fdp` answer in the world frame."""
        self._pose.set(R, t)

    def reset(self) -> None:
        """Back to rest: a copy of the rest State (in place: captured CUDA graphs stay valid),
        controls and head pose at zero, time 0, the solver's step history cleared."""
        self.state.assign(self.rest_state)
        self.scratch.assign(self.rest_state)
        for a in (self.control.activations, self.control.jaw_angles, self.control.external_force):
            a.zero_()
        self._pose.reset()
        self._loads_set = False
        self.solver.reset()
        self._a, self._j = np.zeros(len(self.fr.rig.names), np.float32), np.zeros(2, np.float32)
        self._target_a, self._target_j = self._a.copy(), self._j.copy()
        self._g, self._target_g = np.zeros((2, 2), np.float32), np.zeros((2, 2), np.float32)
        self._steps_taken = 0
        self.stats = FrameStats()

    # ------------------------------------------------------------------------------ stepping
    def step(self, dt: float | None = None) -> None:
        """Advance by exactly ``dt`` [s] (default one frame, ``1 / fps``), a whole number of the solver's
        steps (:attr:`dt`; another ``dt`` is refused, not rounded), the controls set since the last step
        ramping across it; a failing frame is retried with more substeps (:mod:`.rollback`). Raises InputError
        (a bad ``dt``, a head jump) or SimulationError (a NaN, an inverted tet at the retry bound)."""
        n = self.substeps if dt is None else check_step_count(dt, self.dt)
        t0 = time.perf_counter()
        self._frame_loads(n)
        step_frame(self, n, self._a, self._target_a, self._j, self._target_j)  # checked, rolled back if it fails
        self._frame_done(n)
        self.step_seconds += time.perf_counter() - t0

    def _frame_loads(self, n: int) -> None:
        """Before a frame of ``n`` substeps: the loads of the head's accelerating frame (a jump
        beyond a head's motion is an InputError, nothing changed). :class:`~facewarp.FaceBatch` shares it."""
        if self._pose.still:  # the head never left its rest pose: no load (none computed: no device read)
            if self._loads_set:
                self.control.external_force.zero_()
                self._loads_set = False
            return
        # the head rides a moving body: loads of the accelerating frame
        self._pose.check_motion(n * self.dt)
        f = self._pose.node_forces(self.positions(), self.builder.mass, n * self.dt)
        self.control.external_force.assign(f.astype(np.float32))
        self._loads_set = True

    def _frame_done(self, n: int) -> None:
        """After a frame of ``n`` substeps was taken: the controls reached, the pose and the clock advanced."""
        self._a, self._j = self._target_a.copy(), self._target_j.copy()
        self._g = getattr(self, "_target_g", self.eye_gaze).copy()
        self._pose.advance()
        self._steps_taken += n

    def advance(self, frames: int = 1) -> None:
        """Advance ``frames`` frames of ``1 / fps`` with the current controls."""
        check_int("frames", frames, low=0, high=MAX_ADVANCE_FRAMES)
        for _ in range(int(frames)):
            self.step()

    # ------------------------------------------------------------------------------ results
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

    def positions(self) -> np.ndarray:
        """Tet node positions [m], shape (p, 3), float64 (a host copy; see :attr:`positions_wp`)."""
        return self.state.positions.numpy().astype(np.float64)

    @property
    def positions_wp(self):
        """Tet node positions [m] on the device, shape (p,), ``wp.vec3`` (no copy; valid until the next step)."""
        return self.state.positions

    def surface(self, X: np.ndarray | None = None, jaw_angles=None, *, frame: str = "world") -> np.ndarray:
        """Head vertices [m], shape (n, 3), float64 (:func:`.readout.head_surface`) at node positions
        X (default the current state; head frame) and ``jaw_angles`` (default the current jaw), in
        the ``"world"`` frame (the head pose applied) or the ``"head"`` frame."""
        check_choice("frame", frame, ("world", "head"))
        X = check_positions("X", X, len(self.fr.nodes))
        jaw_angles = None if jaw_angles is None else check_array("jaw_angles", jaw_angles, shape=(2,))
        V = head_surface(self.fr, self.positions() if X is None else X, self._j if jaw_angles is None else jaw_angles,
                         self._surface_index)
        return self._pose.to_world(V) if frame == "world" else V

    def contact_crossings(self, X: np.ndarray | None = None) -> dict:
        """Crossings at node positions X (default the current state; head frame): lip nodes inside
        the other lip, nodes inside the teeth, lid nodes inside an eyeball
        (:func:`~facewarp.physics.contact_crossings`; 0 each while the contact holds)."""
        from ..physics.contact import contact_crossings

        X = check_positions("X", X, len(self.fr.nodes))
        return contact_crossings(self.fr, self.positions() if X is None else X, self._j)

    def fdp(self, fdp_id: str) -> np.ndarray:
        """Current position [m] of one FDP (e.g. ``"2.1"``, the chin), shape (3,), float64."""
        check_name("fdp_id", fdp_id)
        ids = [str(k) for k in self.fr.fdp_ids]
        if str(fdp_id) not in ids:
            raise InputError(f"fdp_id: {fdp_id!r} is not an FDP of this head")
        return self.fdp_points()[ids.index(str(fdp_id))]

    def fdp_points(self) -> np.ndarray:
        """Current positions [m] of all FDPs, shape (84, 3), float64 (order: ``rig.fdp_ids``)."""
        parts = {k: P[None] for k, P in self._parts_now(self._j).items()}
        return fdp_points(self.fr, self.surface()[None], parts)[0].astype(np.float64)

    def part_points(self, *, frame: str = "world") -> dict:
        """The rigid parts now (eyes, teeth, tongue; the lower ones turned by the jaw): name ->
        vertices [m], (k, 3), float64, in the ``"world"`` frame (as :meth:`surface`) or the ``"head"``'s."""
        return self._parts_now(self._j, frame=frame)

    def muscle_curves(self, samples: int = 24) -> np.ndarray:
        """Muscle fibre polylines at the current state [m], shape (M, samples, 3), float64, world frame."""
        check_int("samples", samples, low=2, high=10_000)
        C = self._curves(samples)
        return self._pose.to_world(C.reshape(-1, 3)).reshape(C.shape)

    def _parts_now(self, j, *, frame: str = "world") -> dict:
        out = parts_at(self.fr, j, getattr(self, "_g", None))
        return {k: self._pose.to_world(P) for k, P in out.items()} if frame == "world" else out

    def _curves(self, samples: int) -> np.ndarray:
        return muscle_curves(self.fr.rig, self.state.muscle_ctrl.numpy(), samples)

    def run(self, timeline: Timeline, seconds: float, *, progress=None, curve_samples: int = 24, jaw=None) -> Frames:
        """Simulate ``seconds`` of ``timeline`` from rest and keep every frame: :func:`~facewarp.play`
        with a :class:`~facewarp.FrameRecorder` (its ``jaw`` and ``progress``: the same)."""
        seconds = check_run_args(timeline, seconds, progress, curve_samples, fps=self.fps,
                                 vertex_count=len(self.fr.head_vertices))
        rec = FrameRecorder(curve_samples=curve_samples)
        play(self, timeline, seconds, sinks=(rec,), jaw=jaw, progress=progress)
        return rec.frames


# ------------------------------------------------------------------------------ checks of the arguments
def check_simulator_args(fr, *, device, solver: str, fps, options: dict) -> str:
    """The arguments of :class:`FaceSimulator` (see its docstring): the rig, ``device``, ``solver``
    (one of :data:`SOLVERS`), ``fps`` and ``options`` (its other keywords by name: ``dt``,
    ``substeps``, ``iterations``, ``tolerance``, ``method``, ``solver_options``, ``support_stiffness``,
    ``edge_damping``, ``mass_scaling``, ``contact``, ``contact_modulus``; absent ones as None /
    their defaults); returns the device name. Sizes are bounded by :mod:`facewarp._src.core.limits`."""
    from ..core.limits import MAX_FPS, MAX_SUBSTEPS

    o = {"mass_scaling": True, "contact": True, **options}
    if not all(hasattr(fr, k) for k in ("nodes", "tets", "rig", "head_vertices")):
        raise InputError(f"fr: expected a FaceRig (build_face or load_face_rig), got {describe(fr)}")
    device = check_device(device)
    check_choice("solver", solver, SOLVERS)
    check_number("dt", o.get("dt"), low=0.0, low_open=True, high=1.0, allow_none=True)
    check_int("substeps", o.get("substeps"), low=1, high=MAX_SUBSTEPS, allow_none=True)
    check_number("fps", fps, low=0.0, low_open=True, high=MAX_FPS)
    check_int("iterations", o.get("iterations"), low=1, high=100_000, allow_none=True)
    check_number("tolerance", o.get("tolerance"), low=0.0, low_open=True, allow_none=True)
    method = o.get("method")
    if method is not None and not isinstance(method, str):
        raise InputError(f"method: expected a method name or None, got {describe(method)}")
    if o.get("solver_options") is not None:
        opts = check_mapping("solver_options", o["solver_options"])
        bad = [k for k in opts if not isinstance(k, str)]
        if bad:
            raise InputError(f"solver_options: keys must be option names, got {bad[0]!r}")
    check_number("support_stiffness", o.get("support_stiffness"), low=0.0, allow_none=True)
    check_number("edge_damping", o.get("edge_damping"), low=0.0, allow_none=True)
    check_bool("mass_scaling", o["mass_scaling"])
    check_bool("contact", o["contact"])
    check_number("contact_modulus", o.get("contact_modulus"), low=0.0, low_open=True, allow_none=True)
    return device


def check_run_args(timeline, seconds, progress, curve_samples, *, fps: float, vertex_count: int) -> float:
    """The arguments of :meth:`~facewarp.FaceSimulator.run`; the memory of the kept frames is
    checked against the machine's. Returns ``seconds`` as a float."""
    from ..core.limits import MAX_SECONDS, check_memory, estimate_frames_bytes

    if not (hasattr(timeline, "sample") and hasattr(timeline, "for_head")):
        raise InputError(f"timeline: expected a Timeline (preset(...), load_sequence(...)), got {describe(timeline)}")
    seconds = check_number("seconds", seconds, low=0.0, low_open=True, high=MAX_SECONDS)
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a function progress(k, frame_count) or None, got {describe(progress)}")
    check_int("curve_samples", curve_samples, low=2, high=10_000)
    frames = round(seconds * fps) + 1
    check_memory(estimate_frames_bytes(frames, vertex_count) + frames * curve_samples * 12 * 64,
                 f"seconds: {frames} frames of {vertex_count} vertices")
    return seconds
