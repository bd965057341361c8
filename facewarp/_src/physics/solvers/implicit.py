"""Implicit (backward) Euler solvers of the skin model: the thesis's energies at frame-sized steps.

``select_solver(model, stages=..., method=...).step(state_in, state_out, control, dt)``
(:func:`~.select.select_solver`) has the contract of :class:`~.verlet.SolverVerlet` (:mod:`.base`) and integrates the same :class:`Model`
(energies of Eq. 6.4.4-6.4.8, muscle springs of Eq. 6.4.1, holds, supports, damping): one step
minimises the incremental potential Phi of backward Euler
(:class:`~.incremental.IncrementalPotential`, kernels in :mod:`.kernels_potential` and
:mod:`.kernels_hessian`), which is stable for any step, so a 30 fps frame can be one step.

Two algorithms, one class each, sharing that potential:

* :class:`~.host_implicit.SolverHostImplicit` (``method="lbfgs"``, the default on the CPU, or
  ``"newton"``): a sparse factorisation on the host, L-BFGS with the factorised Hessian as its
  initial inverse (Liu, Bouaziz & Kavan 2017) or Newton with a fresh factorisation per iteration;
* :class:`~.newton_pcg.SolverDeviceNewtonPCG` (``method="newton-pcg"``, the default on CUDA, runs
  on the CPU too): Newton iterations with block-Jacobi preconditioned conjugate gradients and a
  line search decided on the device, a whole adaptive step one CUDA graph.

:class:`SolverImplicit` is their base (what both share: the stages, the potential, the step's
frame); :func:`~.select.select_solver` makes the class ``method`` names (default: L-BFGS on the
CPU, Newton-PCG on CUDA). Each class takes its own options; one it lacks is an
:class:`~facewarp.InputError` naming it (and the class it belongs to).

Why these methods (measured on the 2-core CPU box, default head level 0: 2,448 nodes, 6,738
tets, presets with muscles and a 30 degree jaw; ``benchmarks/solver_accuracy.py``, ``physics_steps.py``)
-------------------------------------------------------------------------------------------------
The skin is a thin stiff layer driven quasi-statically: at 30 fps the mass term ``M / h^2`` is
~1e-4 of the stiffness, so a step is practically a static solve whose error modes span the whole
face. Sweep methods (Jacobi, Gauss-Seidel / VBD colour sweeps, XPBD) reduce such smooth modes by
about (edge / region)^2 per sweep and need hundreds of sweeps per frame here; so does conjugate
gradients with a block-Jacobi preconditioner inside Newton from a cold start. A global direct
solve removes all modes at once: the host solver's factorisation (see its module doc). On a GPU
a factorisation per frame does not pay; Newton with a few CG iterations from the previous
motion's extrapolation, the exact Hessian and a device line search does (see the device
solver's module doc).

The muscle springs' fibre cosine of Eq. 6.4.1 is taken at the step's start and held over the
solve (see ``kernels_muscle._muscle_springs``): within the solve a conservative spring
``1/2 k_m w (l - l0)^2`` with an exact gradient and Hessian. The host solver then re-evaluates the
cosine at the solution and solves again until it no longer changes (``spring_updates``), so the
step ends at a fixed point of Eq. 6.4.1 as printed; the device solver re-evaluates it before
every Newton iteration.

Contact (:mod:`facewarp._src.physics.contact`) adds one-sided springs (``Springs.one_sided``):
penalties that act only when compressed, their planes (the other lip's closest point, a dental
arch's) frozen over a solve like the fibre cosine. The host solver detects the contacts again at
the solution and solves again while a contact closed further by more than ``contact_tolerance``
(up to ``contact_updates`` more solves); L-BFGS renews its factorisation at the step's start when
a contact has closed since the last one (its factorised model keeps the contacts within
``contact_slack`` of closing: without the stiff contact springs it would backtrack at every
iteration). The device solver re-detects before every Newton iteration, as for the muscles.
Measured at level 0 (default head, CPU L-BFGS, ``benchmarks/physics_steps.py --contact``, a
2-core box shared with other jobs, so +-30 %): the lids touch the eyeballs in most presets and
cost 1.1-2x the frame time (laugh, smile, surprise, sad, blink, squint, the Fig. 6.16 sequence);
pucker, the lips pressed together through its whole hold, 3-10x.
"""

from __future__ import annotations

import time

import numpy as np

from ...core.errors import InputError
from ...core.warp import get_warp
from ..model import Model
from ..state import Control, State
from . import kernels_potential as kp
from .base import SolverBase, check_step_args, stage_springs
from .incremental import IncrementalPotential

__all__ = ["IMPLICIT_METHODS", "SolverImplicit", "refuse_options"]

IMPLICIT_METHODS = ("lbfgs", "newton", "newton-pcg")
"""The methods of :class:`SolverImplicit`: ``"lbfgs"`` and ``"newton"``
(:class:`~.host_implicit.SolverHostImplicit`), ``"newton-pcg"``
(:class:`~.newton_pcg.SolverDeviceNewtonPCG`)."""

_COMMON_OPTIONS = ("stages", "tolerance", "max_iterations", "iterations", "extrapolate")


def refuse_options(cls: type, options: dict) -> None:
    """An :class:`InputError` naming the first of ``options`` (keyword -> value) that ``cls`` (an
    implicit solver class) does not take, and the classes that do."""
    for name in options:
        if name not in cls._OPTIONS:
            owners = [c.__name__ for c in SolverImplicit.__subclasses__() if name in c._OPTIONS]
            where = f" (an option of {' and '.join(owners)})" if owners else ""
            raise InputError(f"{name}: not an option of {cls.__name__}{where}")


class SolverImplicit(SolverBase):
    """Backward Euler of the skin model, one minimisation of the step's potential per step: the base
    of the implicit solvers (module doc), made through a class of its own:
    :class:`~.host_implicit.SolverHostImplicit` (``"lbfgs"``, the CPU default, and ``"newton"``) or
    :class:`~.newton_pcg.SolverDeviceNewtonPCG` (``"newton-pcg"``, the CUDA default), or by
    :func:`~.select.select_solver` from a method name. The options every implicit solver takes are
    below; the others belong to one class (its doc).

    Args:
        model: the tissue :class:`Model`.
        stages: :class:`~.base.SolverStage` objects prepared, in order, at the start of each step.
        method: ``"lbfgs"``, ``"newton"`` or ``"newton-pcg"`` (default: by the model's device).
        tolerance: Converged when no free node moves more than this in an iteration [m]
            (default 1e-5 m = 0.01 mm). Ignored with ``iterations``.
        max_iterations: At most this many (quasi-)Newton iterations per step (default: the class's).
        iterations: A fixed count per step instead (the interactive mode: a fixed cost per
            frame, no convergence test).
        extrapolate: The first guess is ``x_n + extrapolate (x_n - x_prev)`` (the previous step's
            motion, in the jaw-carried frame, continued; a guess that inverts a tet falls back to
            x_n). Default: the class's.

    Raises:
        InputError: an unknown method, an option the method's class lacks, or a bad value.

    Attributes:
        method: the method (``"lbfgs"``, ``"newton"`` or ``"newton-pcg"``).
        incremental: the step's :class:`~.incremental.IncrementalPotential` (its iterate ``x``).
        adaptive: whether the iteration count lives on the device (the adaptive Newton-PCG loop).
        contact_slack: One-sided (contact) springs within this distance [m] of closing are kept
            in the Hessian the host L-BFGS factorises (3e-4), and in the device method's after a
            failed line search.
        last_iterations: Iterations of the last step (host; 0 before the first step; not updated
            by a replayed CUDA graph: see :attr:`total_iterations`).
        factorizations: Number of factorisations made so far (host solver; 0 on the device).
        last_converged: Whether the last step's last solve reached the tolerance (the CPU methods;
            always True with a fixed iteration count and for the device method).
        timings: Seconds spent, accumulated: ``{"prepare", "gradient", "solve", "factor"}``.
    """

    _OPTIONS: tuple = _COMMON_OPTIONS
    method: str = ""

    def __init__(self, model: Model, *, stages=(), tolerance: float = 1e-5, max_iterations: int = 50,
                 iterations: int | None = None, extrapolate: float = 0.0):
        if type(self) is SolverImplicit:
            raise InputError("SolverImplicit is the base of the implicit solvers: make one with "
                             "select_solver(model, method=...), SolverHostImplicit or SolverDeviceNewtonPCG")
        for name, val in (("tolerance", tolerance), ("extrapolate", extrapolate)):
            if not (np.isfinite(val) and val >= 0):
                raise InputError(f"{name}: expected a finite number >= 0, got {val!r}")
        if not (isinstance(max_iterations, (int, np.integer)) and max_iterations >= 1):
            raise InputError(f"max_iterations: expected a whole number >= 1, got {max_iterations!r}")
        if iterations is not None and not (isinstance(iterations, (int, np.integer)) and iterations >= 1):
            raise InputError(f"iterations: expected a whole number >= 1 or None, got {iterations!r}")
        stages = list(stages)
        refreshers = []
        for st in stages:
            if not hasattr(st, "prepare"):
                raise InputError(f"stages: {type(st).__name__} has no prepare(): it drives explicit solvers only")
            if hasattr(st, "refresh"):
                refreshers.append(st)
        # then the base (targets, guard), the springs and the potential, in one pass: what the solver
        # needs of the Model is taken here, once
        super().__init__(model, stages=stages)
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self.iterations = None if iterations is None else int(iterations)
        self.extrapolate = float(extrapolate)
        self.adaptive = False
        self.contact_slack = 3.0e-4  # [m] near-closed contacts kept in the factorised model (lbfgs)
        self._refreshers = refreshers
        self.last_iterations = 0
        self.last_converged = True  # the CPU methods: the last step's last solve reached the tolerance
        self._host_total = 0
        self.factorizations = 0
        self.timings = {"prepare": 0.0, "gradient": 0.0, "solve": 0.0, "factor": 0.0}
        self.incremental = IncrementalPotential(model, stage_springs(self.stages), self.targets)

    # ------------------------------------------------------------------------------ step
    def _begin(self, state_in: State, control: Control, h: float) -> None:
        """Stages, the dashpots' start constraints, the inertial target and the first guess."""
        for st in self.stages:
            st.prepare(self.model, state_in, control, h, self.targets)
        self.incremental.begin(state_in, control, h, self.extrapolate)

    def _solve(self, state_in: State, control: Control, h: float) -> None:
        """Minimise Phi from the first guess into :attr:`incremental` ``.x`` (the class's algorithm)."""
        raise NotImplementedError

    def _finish(self, state_in: State, state_out: State) -> None:
        wp = get_warp()
        wp.copy(state_out.prev_positions, state_in.positions)
        wp.copy(state_out.positions, self.incremental.x)
        state_out.assign_stage_data(state_in)  # what the stages carry (muscle geometry, jaw carry)
        wp.launch(kp._advance_counter, dim=1, inputs=[], outputs=[self.step_counter], device=self.device)
        self._launch_guard(state_out)

    def step(self, state_in: State, state_out: State, control: Control, dt: float) -> None:
        """Advance one step of ``dt`` [s] from ``state_in`` into ``state_out`` (different buffers).

        The device solver allocates nothing and never reads back to the host (capturable in a
        CUDA graph); the host solver reads the Warp arrays as zero-copy NumPy views.

        Raises:
            InputError: ``dt`` not a positive finite number, or the same state buffers.
        """
        check_step_args(state_in, state_out, dt)
        self._check_devices(state_in, state_out, control)
        h = float(dt)
        t0 = time.perf_counter()
        self._begin(state_in, control, h)
        self.timings["prepare"] += time.perf_counter() - t0
        self._solve(state_in, control, h)
        self._finish(state_in, state_out)
        if not self.adaptive:
            self._host_total += self.last_iterations

    @property
    def total_iterations(self) -> int:
        """(Quasi-)Newton iterations of all steps so far (counted on the host; the adaptive
        device solver counts on the device and reads it back here)."""
        return self._host_total

    def potential(self, state_in: State, control: Control, dt: float, positions=None, *, hessian: bool = False):
        """The step's potential Phi and its gradient, evaluated by the solver's kernels (host read).

        For checks and tools, not for the step itself: it runs the stages' ``prepare`` for a step
        of ``dt`` from ``state_in`` (a carry stage moves ``state_in`` as a step would).

        Args:
            state_in: the step's start (positions x_n and x_prev).
            control: the controls of the step.
            dt: step [s].
            positions: where to evaluate [m], shape (n, 3) (default: the solver's first guess).
            hessian: also return the PSD Hessian (module doc of :mod:`facewarp._src.physics.potential`).

        Returns:
            ``(Phi [J], gradient [N] (n, 3) float64)`` and, with ``hessian``, a SciPy BSR matrix
            (3n, 3n) float64 whose fixed nodes' rows and columns are the identity.
        """
        if isinstance(dt, bool) or not (isinstance(dt, (int, float, np.floating)) and np.isfinite(dt) and dt > 0.0):
            raise InputError(f"dt must be a positive number of seconds, got {dt!r}")
        h = float(dt)
        ip = self.incremental
        self._begin(state_in, control, h)
        if positions is not None:
            P = np.asarray(positions, dtype=np.float64)
            if P.shape != (self.model.vertex_count, 3) or not np.isfinite(P).all():
                raise InputError(f"positions: expected finite values of shape ({self.model.vertex_count}, 3), "
                                 f"got {P.shape}")
            fixed = self.model.vertex_fixed.numpy() != 0
            P = P.copy()
            P[fixed] = self.targets.numpy()[fixed]
            ip.x.assign(P.astype(np.float32))
        ip.launch_energy(ip.x, control, h)
        e = float(np.sum(ip.energy.numpy(), dtype=np.float64))
        g = ip.grad.numpy().astype(np.float64)
        if not hessian:
            return e, g
        ip.launch_hessian(ip.x, h)
        return e, g, ip.hessian_matrix()

    def reset(self) -> None:
        """Back to the rest pose (targets, counter, guard)."""
        super().reset()
        self.last_iterations = 0

    def _advice(self) -> str:
        return "lower the activation or jaw speed, or take smaller steps"
