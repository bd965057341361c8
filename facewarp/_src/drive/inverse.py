"""The inverse solve: muscle activations and jaw angles per frame whose simulated face matches
target skin points, with the physics in the loop (issue 24).

Each frame is one simulated step of the :class:`~facewarp.FaceSimulator`. Its 29 controls ``u``
(27 activations in [0, 1], the jaw's opening 0..60 deg and side +-5 deg) minimise

    sum_k w_k |p_k(u) - p*_k|^2 / s^2  +  smoothness sum_k |J_k (u - u_ref)|^2 / s^2  +  effort |a|^2

(``p_k`` the simulated points, ``p*_k`` the targets, ``s`` = 1 mm; the smoothness is the motion
of all K points away from the controls' motion continued, ``u_ref = 2 u_prev - u_prev2``, so a
steady motion has no lag, noise is held and a point seen alone cannot drag the muscles it watches;
jaw angles in units of their range, so every control spans about 1) within the bounds, by
bounded Gauss-Newton on the step's linearisation ``p(u) ~ p_b + J (u - u_b)``
(:func:`scipy.optimize.lsq_linear`; 29 unknowns). ``J`` is the solver's own sensitivity
(:func:`.sensitivity.step_sensitivity`: the step's Hessian factorised once, one back-substitution
per control) mapped through the linear read-out (:class:`.sensitivity.PointReadout`). The
weights ``w_k`` are 0 for missing points (NaN) and robust otherwise (Cauchy weights, iteratively
reweighted from the residuals of no change on), so an outlier centimetres off pulls next to nothing.

``J`` is reused across frames: after every step the change the step showed updates it
(Broyden's rank-one update on the predicted vs simulated points), and it is computed afresh
every ``refresh_every`` frames or when a step's prediction misses by more than
``refresh_tolerance``. The offline mode then re-takes the frame (rolled back to its start, the
controls re-solved about the step just seen) up to ``refine`` times while the prediction missed
by more than ``refine_tolerance``; the real-time mode takes each frame once and reuses the
solver's own factorisation (the host L-BFGS's, when it has one) for the refreshes.

Noisy targets: the tracker estimates the targets' noise from how much the residuals of the points
seen in two frames running change between them (a steady offset, a point the face cannot reach or
a lag changes little; marker noise changes every frame), and with ``gain = (noise /
noise_reference)^2`` (1 to :data:`NOISE_GAIN_MAX`; the maximum until the first estimate) the
muscles' point-space smoothness is multiplied by ``gain`` and their momentum divided by
``sqrt(gain)`` (offline mode; in real time the one-iteration step's lag changes the residuals every
frame and is no noise to hold against). The jaw, seen by many points, keeps the plain smoothness
(held harder it lags a fast opening). Without this, 0.5 mm noise with 30 % of the markers missing
shook weakly seen muscles (the lip corners', the brows') by 3 to 5 mm between frames.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..core.checks import check_array, check_bool, check_choice, check_int, check_number
from ..core.errors import InputError
from .result import DriveResult
from .sensitivity import PointReadout, step_sensitivity

__all__ = ["DriveResult", "Tracker", "drive"]

MODES = ("offline", "realtime")
"""Tracker modes: ``offline`` (frames re-taken until the step matches its prediction) and
``realtime`` (one step per frame, nothing re-taken)."""

ROBUST = ("cauchy", "huber", "none")
"""Point weights of :class:`Tracker` (iteratively reweighted least squares)."""

FIRST_FRAME_REFINE = 8
"""Re-takes of a tracker's first frame at most (both modes): a take may start far from the
simulator's state (an expression held at frame 0), and the linearisation at rest reaches it in steps."""

_SCALE = 1e-3  # [m] the point residual's unit in the objective (1 mm)
_REJECT = 5.0  # Cauchy weights are cut to 0 beyond this many scales (a point 2 cm off pulls nothing at all)
NOISE_AVERAGE = 0.1
"""Weight of a frame's estimate in the running estimate of the targets' noise (:attr:`Tracker.noise`)."""

NOISE_GAIN_MAX = 6.0
"""The largest factor on the muscles' smoothness from noisy targets (:attr:`Tracker.noise_gain`;
about what 0.5 mm of marker noise gives with the default ``noise_reference``)."""

_CONTROL_SMOOTHNESS = 0.05  # weight of |u - u_prev|^2 beside the point-space smoothness (what no point sees)


def _jaw_range() -> np.ndarray:
    from ..expressions import JAW_U_MAX, JAW_V_MAX

    return np.array([JAW_U_MAX, JAW_V_MAX])


class _Snapshot:
    """A simulator's frame start, to take a frame again (the State, the solver's targets,
    counters and host state, the simulator's controls, step count and frame stats)."""

    def __init__(self, sim):
        from ..sim.rollback import FrameGuard

        self.sim = sim
        self.guard = FrameGuard(sim)
        self.start = sim.model.state()

    def save(self) -> None:
        sim = self.sim
        self.guard.save()
        self.start.assign(sim.state)
        self.a, self.j, self.steps = sim._a.copy(), sim._j.copy(), sim._steps_taken
        self.stats = replace(sim.stats, events=list(sim.stats.events))

    def restore(self) -> None:
        sim = self.sim
        self.guard.restore()
        sim.solver.reset_guard()
        sim._a, sim._j, sim._steps_taken = self.a.copy(), self.j.copy(), self.steps
        sim.stats = replace(self.stats, events=list(self.stats.events))


@dataclass
class TrackerStats:
    """What a :class:`Tracker` did since it was made (or reset).

    Attributes:
        frames: Frames tracked.
        steps: Simulator steps taken (frames plus re-takes).
        jacobians: Sensitivities computed afresh (each: one factorisation or a reused one, 29 back-substitutions).
        broyden_updates: Rank-one updates of the sensitivity.
        refinements: Frames re-taken (offline mode).
        solve_seconds, step_seconds, jacobian_seconds: Wall time of the least-squares solves, the
            simulator steps and the sensitivities [s].
    """

    frames: int = 0
    steps: int = 0
    jacobians: int = 0
    broyden_updates: int = 0
    refinements: int = 0
    solve_seconds: float = 0.0
    step_seconds: float = 0.0
    jacobian_seconds: float = 0.0

    def as_dict(self) -> dict:
        return dict(vars(self))


class Tracker:
    """Drive a simulated face from target skin points, frame by frame (the real-time loop of issue 24).

    ``tracker = fw.Tracker(sim, points)``; each ``tracker.update(targets)`` solves the frame's
    activations and jaw angles (module doc), steps ``sim`` one frame with them (it then holds
    the result: :meth:`~facewarp.FaceSimulator.surface`, :meth:`~facewarp.FaceSimulator.fdp_points`)
    and returns them. It starts from the simulator's current state (reset it first for a take
    from rest).

    Args:
        sim: A :class:`~facewarp.FaceSimulator` with the implicit solver (the sensitivities are its step's).
        points: The K point names: FDP ids (``"2.1"``) or head vertices ``"v<index>"``.
        mode: ``"offline"`` (default: frames re-taken while the prediction misses) or ``"realtime"``
            (each frame one step; with a simulator made with ``iterations=1`` the fixed-cost live loop).
        smoothness: Weight of the points' motion away from the motion continued, ``|J (u - u_ref)|^2`` over
            all K points (default 0.05; module doc), against the residuals of the present points (both in
            mm^2): a point seen alone cannot drag the muscles it watches far in one frame.
        effort: Weight of ``|a|^2`` (default 1e-3): among activations that fit equally, the smaller.
        robust: The point weights (:data:`ROBUST`): ``"cauchy"`` (default: Cauchy weights
            ``1 / (1 + (r / s)^2)`` from the residuals of no change on, 0 beyond ``5 s``, so a point centimetres
            off pulls nothing),
            ``"huber"`` (a point farther off than ``s`` pulls with a force that no longer grows) or ``"none"``.
        robust_scale: ``s`` [m] (default 1e-3: twice the noise of good markers; 1.5 times the median
            residual where that is larger, so a fast motion is not taken for outliers).
        refine: Re-takes of a frame at most (default 2 offline, 0 real-time).
        refine_tolerance: Re-take while the simulated points miss the prediction by more than
            this RMS [m] (default 2e-4).
        refresh_every: A fresh sensitivity every this many frames (default 10 offline, 60 real-time).
        refresh_tolerance: ... or when a step misses its prediction by more than this RMS [m] (default
            5e-4 offline; never in real time, where a step of one solver iteration always lags its prediction).
        momentum: The smoothness pulls towards ``u_prev + momentum (u_prev - u_prev2)`` (default 1: the
            controls' motion continued, so a steady motion has no lag and noise is held; 0: towards ``u_prev``).
        broyden: Update the sensitivity by what each step showed (default True).
        noise_reference: Target noise [m] (per axis) above which the muscles are held more firmly
            (default 2e-4 offline; 0, off, in real time, where the one-iteration step's own lag
            changes the residuals every frame; module doc).
        corrections: Iterations of a fresh sensitivity towards the exact tangent (default 1 offline,
            0 real-time; :func:`.sensitivity.step_sensitivity`).

    Attributes:
        noise: The targets' estimated noise [m] per axis (offline; module doc), 0 before two frames.
        stats: The :class:`TrackerStats`.
        last_error: (K,) float64 [m], each point's distance from its target in the last frame (NaN: missing).

    Raises:
        InputError: a bad argument (one line naming it), unknown point names (all named).
    """

    def __init__(self, sim, points, *, mode: str = "offline", smoothness: float = 0.05, effort: float = 1e-3,
                 robust: str = "cauchy", robust_scale: float = 1e-3, refine: int | None = None,
                 refine_tolerance: float = 2e-4, refresh_every: int | None = None,
                 refresh_tolerance: float | None = None,
                 corrections: int | None = None, momentum: float = 1.0, broyden: bool = True,
                 noise_reference: float | None = None):
        from ..sim.simulator import FaceSimulator

        if not isinstance(sim, FaceSimulator):
            raise InputError(f"sim: expected a facewarp FaceSimulator, got {type(sim).__name__}")
        if not hasattr(sim.solver, "incremental"):
            raise InputError(f"sim: the tracker needs the implicit solver (its step's sensitivities), "
                             f"got solver={sim.solver_name!r}")
        self.mode = check_choice("mode", mode, MODES)
        self.smoothness = check_number("smoothness", smoothness, low=0.0)
        self.effort = check_number("effort", effort, low=0.0)
        self.robust = check_choice("robust", robust, ROBUST)
        self.robust_scale = check_number("robust_scale", robust_scale, low=0.0, low_open=True)
        offline = self.mode == "offline"
        self.refine = check_int("refine", 2 if refine is None and offline else 0 if refine is None else refine,
                                low=0, high=20)
        self.refine_tolerance = check_number("refine_tolerance", refine_tolerance, low=0.0)
        self.refresh_every = check_int("refresh_every", (10 if offline else 60) if refresh_every is None
                                       else refresh_every, low=1, high=1_000_000)
        self.refresh_tolerance = ((5e-4 if offline else np.inf) if refresh_tolerance is None
                                  else check_number("refresh_tolerance", refresh_tolerance, low=0.0))
        self.momentum = check_number("momentum", momentum, low=0.0, high=1.0)
        self.broyden = check_bool("broyden", broyden)
        self.noise_reference = ((2e-4 if offline else 0.0) if noise_reference is None
                                else check_number("noise_reference", noise_reference, low=0.0))
        self.corrections = check_int("corrections", (1 if offline else 0) if corrections is None else corrections,
                                     low=0, high=10)
        self.sim = sim
        self.readout = PointReadout(sim.fr, points)
        self.names = list(self.readout.names)
        self.M = len(sim.muscle_names)
        self._scale = np.r_[np.ones(self.M), _jaw_range()]  # control units: activations 1, jaw angles their range
        self._lo = np.r_[np.zeros(self.M), 0.0, -1.0]
        self._hi = np.ones(self.M + 2)
        self._snap = _Snapshot(sim)
        self.reset_tracking()

    # ------------------------------------------------------------------------------ state
    def reset_tracking(self) -> None:
        """Forget the sensitivity and the statistics; the next :meth:`update` starts from the
        simulator's current state."""
        self._J = None  # (3K, M + 2) dp/du in control units
        self._u_older = None  # the controls a frame before the current ones
        self._last_residual = None  # (K, 3) [m] simulated minus target points a frame before (NaN: missing)
        self.noise = 0.0  # [m] the targets' estimated noise per axis (module doc)
        self._noise_frames = 0
        self._since = 0
        self._solve = None
        self.stats = TrackerStats()
        self.last_error = np.full(self.count, np.nan)

    @property
    def count(self) -> int:
        """K, the number of target points."""
        return self.readout.count

    def _controls(self) -> np.ndarray:
        sim = self.sim
        return np.r_[sim.activations, sim.jaw_angles].astype(np.float64) / self._scale

    def current_points(self) -> np.ndarray:
        """The simulated points now [m], shape (K, 3), float64, head frame."""
        return self.readout.points(self.sim.positions(), self.sim.jaw_angles)

    def _jacobian(self, start, u, X, corrections=None) -> np.ndarray:
        t0 = time.perf_counter()
        corrections = self.corrections if corrections is None else corrections
        a, j = (u * self._scale)[:self.M], (u * self._scale)[self.M:]
        solve = None
        if self.mode == "realtime":
            solve = getattr(self.sim.solver, "_solve0", None)  # the solver's own factorisation, when it has one
        dX, _ = step_sensitivity(self.sim, start, a.astype(np.float32), j.astype(np.float32), X, solve=solve,
                                  corrections=corrections)
        J = self.readout.jacobian(dX, j) * self._scale[None, :]
        self.stats.jacobians += 1
        self.stats.jacobian_seconds += time.perf_counter() - t0
        self._since = 0
        return J

    def sensitivity(self, activations, jaw) -> np.ndarray:
        """Step the simulator one frame to the controls and return how the points move per unit
        of each control at the step's solution (:func:`.sensitivity.step_sensitivity`).

        Args:
            activations: (M,) in [0, 1] (as :meth:`~facewarp.FaceSimulator.set_activations`).
            jaw: (opening, side) [rad] (as :meth:`~facewarp.FaceSimulator.set_jaw`).

        The sensitivity is taken with two corrections towards the exact tangent (:func:`.sensitivity.step_sensitivity`).

        Returns:
            (K, 3, M + 2) float64: dp/da [m per unit activation] for the M muscles, then dp/d(opening)
            and dp/d(side) [m/rad].
        """
        sim = self.sim
        a = sim.activation_vector(activations)
        j = check_array("jaw", jaw, shape=(2,))
        sim.set_jaw(float(j[0]), float(j[1]))
        self._snap.save()
        sim.set_activations(a)
        sim.step()
        u = np.r_[sim.activations, sim.jaw_angles].astype(np.float64) / self._scale
        J = self._jacobian(self._snap.start, u, sim.positions(), corrections=2) / self._scale[None, :]
        return J.reshape(self.count, 3, self.M + 2)

    # ------------------------------------------------------------------------------ the solve
    def _lsq(self, J, p_b, u_b, u_ref, targets, visible, gain=1.0) -> np.ndarray:
        """The bounded, reweighted least squares of one linearisation (module doc)."""
        from scipy.optimize import lsq_linear

        K, n = self.count, self.M + 2
        rows = np.repeat(visible, 3)
        Jv = J[rows] / _SCALE
        r0 = (p_b - targets)[visible].ravel() / _SCALE  # residual at u_b [mm]
        res0 = np.linalg.norm(r0.reshape(-1, 3), axis=1)
        # the scale: robust_scale, or 1.5 x the median residual when the face moves fast (a far point is
        # far compared with the others)
        c = max(self.robust_scale / _SCALE, 1.5 * float(np.median(res0)))
        # the first weights from the residuals of no change: a point centimetres off from the face
        # as it is (an outlier, or one the face cannot follow) starts out weak and stays so
        w = {"none": np.ones_like(res0), "huber": np.where(res0 <= c, 1.0, c / np.maximum(res0, 1e-30)),
             "cauchy": (1.0 / (1.0 + (res0 / c) ** 2)) * (res0 <= _REJECT * c)}[self.robust]
        e = np.sqrt(self.effort)
        E = np.zeros(n)
        E[:self.M] = e
        # smoothness in point space: the motion of all K points away from the motion continued, |J (u - u_ref)|^2
        # (as a 29 x 29 Cholesky factor), plus a little in control space for what no point sees
        G = self.smoothness * (J.T @ J) / _SCALE**2 + _CONTROL_SMOOTHNESS * np.eye(n)
        if gain > 1.0:  # noisy targets: the muscles held more firmly (the jaw, seen by many points, is not)
            Jm = J[:, :self.M]
            G[:self.M, :self.M] += (gain - 1.0) * self.smoothness * (Jm.T @ Jm) / _SCALE**2
        R = np.linalg.cholesky(G).T
        A_reg = np.vstack([R, np.diag(E)])
        b_reg = np.r_[R @ (u_ref - u_b), -E * u_b]  # in the increment du = u - u_b
        lo, hi = self._lo - u_b, self._hi - u_b
        lo, hi = np.minimum(lo, 0.0), np.maximum(hi, 0.0)  # u_b itself is feasible
        du = np.zeros(n)
        rounds = {"none": (), "huber": ("huber",) * 4, "cauchy": ("cauchy",) * 5}[self.robust]
        for it in range(len(rounds) + 1):
            sw = np.repeat(np.sqrt(w), 3)
            A = np.vstack([sw[:, None] * Jv, A_reg])
            b = np.r_[-sw * r0, b_reg]
            du = lsq_linear(A, b, bounds=(lo, hi), method="bvls").x
            if it == len(rounds):
                break
            res = np.linalg.norm((Jv @ du + r0).reshape(-1, 3), axis=1)
            c = max(self.robust_scale / _SCALE, 1.5 * float(np.median(res)))  # the scale follows fast motion
            if rounds[it] == "huber":
                w_new = np.where(res <= c, 1.0, c / np.maximum(res, 1e-30))
            else:  # redescending: a point far off beyond the scale stops pulling
                w_new = (1.0 / (1.0 + (res / c) ** 2)) * (res <= _REJECT * c)
            if np.abs(w_new - w).max() < 1e-3:
                break
            w = w_new
        return np.clip(u_b + du, self._lo, self._hi)

    @property
    def noise_gain(self) -> float:
        """The factor on the muscles' smoothness from the targets' estimated noise (module doc):
        ``(noise / noise_reference)^2`` within 1 and :data:`NOISE_GAIN_MAX` (the maximum before the
        first estimate; 1 with ``noise_reference=0``)."""
        if self.noise_reference <= 0.0:
            return 1.0
        if self._noise_frames == 0:
            return NOISE_GAIN_MAX
        return float(np.clip((self.noise / self.noise_reference) ** 2, 1.0, NOISE_GAIN_MAX))

    def _update_noise(self, residual) -> None:
        """Update :attr:`noise` from a frame's residuals ((K, 3) [m], simulated minus target, NaN
        where missing): the median over the points seen in this frame and the one before of how much
        their residual changed, as a per-axis standard deviation (two independent 3-D normal errors
        of per-axis sigma differ by a median 1.54 sqrt(2) sigma); a mean over the first frames, then a
        running average."""
        last, self._last_residual = self._last_residual, residual
        if last is None:
            return
        both = np.isfinite(residual).all(1) & np.isfinite(last).all(1)
        if both.sum() < 3:
            return
        change = np.linalg.norm(residual[both] - last[both], axis=1)
        sigma = float(np.median(change)) / (1.54 * np.sqrt(2.0))
        self._noise_frames += 1
        self.noise += max(NOISE_AVERAGE, 1.0 / self._noise_frames) * (sigma - self.noise)

    def _step(self, u) -> np.ndarray:
        sim = self.sim
        c = u * self._scale
        t0 = time.perf_counter()
        sim.set_activations(np.clip(c[:self.M], 0.0, 1.0).astype(np.float32))
        jmax = _jaw_range()
        sim.set_jaw(float(np.clip(c[self.M], 0.0, jmax[0])), float(np.clip(c[self.M + 1], -jmax[1], jmax[1])))
        sim.step()
        self.stats.steps += 1
        self.stats.step_seconds += time.perf_counter() - t0
        return self.current_points()

    def update(self, targets) -> tuple[np.ndarray, np.ndarray]:
        """Track one frame: solve its controls, step the simulator one frame with them.

        Args:
            targets: (K, 3) [m] the points' target positions in the head's frame (rigid head
                motion removed), NaN where a point is missing.

        Returns:
            ``(activations (M,) float32, jaw (2,) float32 [rad])`` of the frame (the simulator's
            :attr:`~facewarp.FaceSimulator.activations` and :attr:`~facewarp.FaceSimulator.jaw_angles` now).
        """
        T = check_array("targets", targets, shape=(self.count, 3), finite=False)
        if np.isinf(T).any():
            raise InputError("targets: infinite values (use NaN for a missing point)")
        visible = np.isfinite(T).all(axis=1)
        T = np.where(visible[:, None], T, 0.0)
        sim, snap = self.sim, self._snap
        u_prev = self._controls()
        p_now = self.current_points()
        snap.save()
        if self._J is None:  # the first frame: the sensitivity at the current state (at rest: an equilibrium)
            self._J = self._jacobian(snap.start, u_prev, sim.positions())
        u_b, p_b = u_prev, p_now
        # the smoothness pulls towards the motion continued (constant velocity of the controls): no lag
        # on a steady motion, and what noise would shake is held
        older = u_prev if self._u_older is None else self._u_older
        gain = self.noise_gain
        momentum = np.full(self.M + 2, self.momentum)
        momentum[:self.M] /= np.sqrt(gain)  # noise is not continued as the muscles' motion
        u_ref = np.clip(u_prev + momentum * (u_prev - older), self._lo, self._hi)
        self._u_older = u_prev
        # a take may start mid-expression: the first frame may be re-taken more often
        refine = self.refine if self.stats.frames else max(self.refine, FIRST_FRAME_REFINE)
        for attempt in range(refine + 1):
            t0 = time.perf_counter()
            u = self._lsq(self._J, p_b, u_b, u_ref, T, visible, gain) if visible.any() else u_prev.copy()
            self.stats.solve_seconds += time.perf_counter() - t0
            p = self._step(u)
            miss = p - (p_b + (self._J @ (u - u_b)).reshape(-1, 3))
            rms_miss = float(np.sqrt(np.mean(np.sum(miss**2, axis=1))))
            du = u - u_b
            if rms_miss > self.refresh_tolerance or self._since + 1 >= self.refresh_every:
                self._J = self._jacobian(snap.start, u, sim.positions())  # exact for this very step
            elif self.broyden and float(du @ du) > 1e-10:
                # Broyden: the step's own change, along the controls that moved
                self._J += np.outer(miss.ravel(), du) / float(du @ du)
                self.stats.broyden_updates += 1
            if attempt == refine or rms_miss <= self.refine_tolerance:
                break
            snap.restore()  # take the frame again, linearised about the step just seen
            self.stats.refinements += 1
            u_b, p_b = u, p
        self._since += 1
        self.stats.frames += 1
        err = np.linalg.norm(p - T, axis=1)
        self.last_error = np.where(visible, err, np.nan)
        self._update_noise(np.where(visible[:, None], p - T, np.nan))
        return sim.activations, sim.jaw_angles


# ---------------------------------------------------------------------------------------- drive
def drive(sim, track, *, table=None, sinks=(), progress=None, mode: str = "offline", head_poses=None,
          unreachable_limit: float = 2e-3, **options) -> DriveResult:
    """Solve a performance's activations and jaw per frame and play them on ``sim`` (module doc).

    The simulator is reset to rest, then each frame ``k`` of the track is one step of ``1 / fps``
    (:meth:`Tracker.update`); the sinks see frame ``k`` at ``t = k / fps`` like :func:`~facewarp.play`'s
    (a :class:`~facewarp.FrameRecorder` keeps the frames, a :class:`~facewarp.UsdAnimation` streams them).

    Args:
        sim: The :class:`~facewarp.FaceSimulator` (implicit solver), at the track's frame rate.
        track: A :class:`~facewarp.MarkerTrack` (points in the head's frame, NaN where missing).
        table: For an :class:`~facewarp.takes.ArkitTrack`: the head's :class:`~facewarp.takes.ArkitTable`
            (:func:`~facewarp.arkit_table`); the track is then played through it
            (:func:`.arkit.drive_arkit`: ``refine=True`` tracks each frame towards its blended
            target FDPs, the other keywords as here; the head rotation drives the head pose).
        sinks: :class:`~facewarp.takes.Sink` objects or callables ``f(sim, k, t)``, called after each frame.
        progress: Optional ``progress(k, frame_count)`` after each frame.
        mode: ``"offline"`` or ``"realtime"`` (:class:`Tracker`).
        head_poses: Optional (T, 4, 4) rigid poses removed from the targets, kept in the result.
        unreachable_limit: A frame whose point is farther than this [m] from its target is noted (default 2 mm).
        **options: Further keywords of :class:`Tracker` (``smoothness``, ``effort``, ``robust``, ...).

    Returns:
        The :class:`DriveResult`.

    Raises:
        InputError: a bad argument, a track at another frame rate than ``sim``, unknown point names.
    """
    from ..sim.play import PlayStats, _as_sink
    from ..sim.simulator import FaceSimulator
    from .tracks import ArkitTrack, MarkerTrack

    if not isinstance(sim, FaceSimulator):
        raise InputError(f"sim: expected a facewarp FaceSimulator, got {type(sim).__name__}")
    if isinstance(track, ArkitTrack):
        from .arkit import check_table, drive_arkit

        if head_poses is not None:
            raise InputError("head_poses: not for an ArkitTrack (its head_rotation drives the head pose)")
        refine = options.pop("refine", False)
        if not isinstance(refine, (bool, np.bool_)):
            raise InputError(f"refine: expected True or False, got {refine!r}")
        if options and not refine:
            raise InputError(f"{sorted(options)[0]}: a Tracker option, only with refine=True")
        check_table(sim, table)
        tracker = Tracker(sim, table.fdp_ids, mode=mode, **options) if refine else None
        return drive_arkit(sim, track, table, sinks=sinks, progress=progress, tracker=tracker,
                           unreachable_limit=unreachable_limit)
    if not isinstance(track, MarkerTrack):
        raise InputError(f"track: expected a facewarp MarkerTrack, got {type(track).__name__}")
    if table is not None:
        raise InputError("table: only for an ArkitTrack")
    if abs(track.fps - sim.fps) > 1e-6 * sim.fps:
        raise InputError(f"track: {track.fps:g} frames/s, but the simulator runs at {sim.fps:g}: "
                         f"make the FaceSimulator with fps={track.fps:g}")
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a callable progress(k, frame_count), got {type(progress).__name__}")
    unreachable_limit = check_number("unreachable_limit", unreachable_limit, low=0.0, low_open=True)
    nf = track.frames
    if head_poses is not None:
        head_poses = check_array("head_poses", head_poses, shape=(nf, 4, 4))
    sinks = [_as_sink(s) for s in sinks]
    tracker = Tracker(sim, track.names, mode=mode, **options)
    sim.reset()
    tracker.reset_tracking()
    for s in sinks:
        s.start(sim, nf)
    K, M = tracker.count, tracker.M
    acts = np.zeros((nf, M), np.float32)
    jaw = np.zeros((nf, 2), np.float32)
    err = np.full((nf, K), np.nan)
    t0 = time.perf_counter()
    stepping = 0.0
    for k in range(nf):
        s0 = time.perf_counter()
        acts[k], jaw[k] = tracker.update(track.positions[k])
        stepping += time.perf_counter() - s0
        err[k] = tracker.last_error
        for s in sinks:
            s.frame(sim, k, k / track.fps)
        if progress:
            progress(k, nf)
    wall = time.perf_counter() - t0
    stepping = max(stepping, 1e-9)
    with np.errstate(invalid="ignore"):
        present = np.isfinite(err)
        rms = np.sqrt(np.where(present.any(1), np.nansum(err**2, 1) / np.maximum(present.sum(1), 1), np.nan))
    notes = []
    never = [n for n, seen in zip(track.names, present.any(0)) if not seen]
    if never:
        notes.append(f"never present: {', '.join(never)}")
    bad = np.where(np.nan_to_num(err, nan=0.0) > unreachable_limit)
    if len(bad[0]):
        for i in np.unique(bad[1]):
            fr_k = bad[0][bad[1] == i]
            notes.append(f"point {track.names[i]}: {len(fr_k)} frame(s) off by more than "
                         f"{unreachable_limit * 1e3:g} mm (worst {np.nanmax(err[:, i]) * 1e3:.2f} mm at frame "
                         f"{int(np.nanargmax(err[:, i]))})")
    stats = PlayStats(frames=nf, seconds=nf / track.fps, wall_s=wall, simulation_wall_s=stepping,
                      frames_per_second=nf / stepping, steps_per_second=tracker.stats.steps * sim.substeps / stepping,
                      realtime_factor=nf / track.fps / stepping, substeps=int(sim.substeps), dt_s=float(sim.dt),
                      device=str(sim.device), jaw="tracker", frame_stats=sim.stats.as_dict(), mujoco_events=[])
    for s in sinks:
        s.finish(sim, stats)
    return DriveResult(fps=track.fps, names=list(track.names), muscle_names=list(sim.muscle_names),
                       activations=acts, jaw=jaw, error=err, rms=rms, unreachable=notes, seconds=stepping,
                       frames_per_second=nf / stepping, mode=tracker.mode, stats=tracker.stats.as_dict(),
                       head_poses=head_poses)
