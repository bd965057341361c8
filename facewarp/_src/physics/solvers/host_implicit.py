"""The host implicit solver: a sparse factorisation of the step's Hessian on the host, L-BFGS or Newton.

:class:`SolverHostImplicit` minimises the :class:`~.incremental.IncrementalPotential` of a
backward Euler step (module doc of :mod:`.implicit`) with the potential's kernels for energy,
gradient and Hessian, and a factorisation and the (quasi-)Newton updates in NumPy / SciPy on
zero-copy views of the Warp arrays. CPU only.

Newton with a fresh sparse factorisation per iteration converges in 3-30 iterations (the
compressed lips near a buckling mode converge linearly) at 50-200 ms per factorisation: 1-4
frames/s. The default is therefore the quasi-Newton method of Liu, Bouaziz & Kavan 2017
("Quasi-Newton methods for real-time simulation of hyperelastic materials"): L-BFGS whose initial
inverse Hessian is a sparse LDL^T / LU factorisation of the PSD Hessian ``M / h^2 + K`` made at
the first step and reused, with backtracking on the energy that also rejects any step inverting
a tet. Its energy and gradient are Warp kernels (~1 ms per evaluation at level 0 on one CPU
thread), the factor's back-substitution (~1.4 ms with QDLDL) is the other half of an iteration.
A converged frame (every node within ``tolerance`` 3e-5 m of its last iterate) takes 2-7
iterations: 15-55 frames/s at level 0, every FDP within 0.03 mm of the fully converged step. The
curvature pairs carry over from step to step, and the factorisation is renewed at the current
shape only when the old one has become a poor model (the jaw turned, muscle springs switched
on): when the iterations beyond one per step since the last factorisation add up to
``refactor_after`` (20: at levels 0 and 1 a factorisation costs about as much as 20-25
iterations), or within a step that stalls for as many. The rule counts iterations, not seconds,
so a run repeats bit for bit.

Methods (``method=``):

* ``"lbfgs"`` (default): the above; host factorisation (QDLDL or CHOLMOD when installed, else
  SciPy's SuperLU; :func:`factorization_backend`). ``iterations=k`` is the interactive mode: k
  iterations per frame whatever the residual (measured lag: 0.1-0.5 mm on smile and sad at 2-3
  iterations, 1-3 mm on the lips during the jaw's 0.3 s opening of laugh and surprise, none once
  the expression is held).
* ``"newton"``: Newton with a fresh factorisation every iteration and the same line search.
"""

from __future__ import annotations

import importlib.util
import time

import numpy as np

from ...core.errors import InputError, SimulationError
from ...core.warp import get_warp
from ..model import Model
from ..state import Control, State
from .implicit import _COMMON_OPTIONS, SolverImplicit, refuse_options

__all__ = ["HOST_METHODS", "SolverHostImplicit", "factorization_backend"]

HOST_METHODS = ("lbfgs", "newton")
"""The methods of :class:`SolverHostImplicit`."""


def factorization_backend() -> str:
    """The sparse factorisation the host solver uses, the first one installed: ``"qdldl"`` (the
    QDLDL LDL^T with AMD ordering, a wheel on PyPI), ``"cholmod"`` (scikit-sparse, which needs
    SuiteSparse from the system) or ``"splu"`` (SciPy's SuperLU, always there).

    Measured on the default head's Hessian (2-core box): level 0 (7.3k unknowns) factorisation
    52 / 66 / 178 ms and back-substitution 1.4 / 1.5 / 3.4 ms (qdldl / cholmod / splu); level 1
    (28k) 457 / 541 / 560 ms and 12.7 / 11.6 / 11.1 ms."""
    if importlib.util.find_spec("qdldl") is not None:
        return "qdldl"
    if importlib.util.find_spec("sksparse") is not None:
        try:
            from sksparse.cholmod import cholesky  # noqa: F401

            return "cholmod"
        except ImportError:  # pragma: no cover - a broken install
            pass
    return "splu"


def _dot(a: np.ndarray, b: np.ndarray) -> float:
    """a . b without BLAS: on a 2-core machine OpenBLAS's threaded dot wakes a second thread
    that competes with the solver for the other core (measured: 5 ms per dot of 28k entries)."""
    return float(np.einsum("i,i->", a, b))


def _factorize(A, backend: str):
    """A solve function ``b -> A^-1 b`` for the sparse SPD matrix A (scipy, any format)."""
    import scipy.sparse as sp

    A = sp.csc_matrix(A)
    if backend == "cholmod":
        from sksparse.cholmod import cholesky

        f = cholesky(A)
        return f
    if backend == "qdldl":
        import qdldl

        s = qdldl.Solver(sp.triu(A, format="csc"))
        return s.solve
    import scipy.sparse.linalg as spla

    lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True))
    return lu.solve


class SolverHostImplicit(SolverImplicit):
    """Backward Euler by a host factorisation: L-BFGS (default) or Newton (module doc). CPU only.

    :class:`~.implicit.SolverImplicit`'s ``stages``, ``tolerance``, ``max_iterations`` (default 50)
    and ``iterations`` apply too.

    Args:
        method: ``"lbfgs"`` (default) or ``"newton"``.
        extrapolate: the first guess's extrapolation (:class:`~.implicit.SolverImplicit`).
            Default 0.5 with a fixed ``iterations`` (measured on the laugh preset: the lag of the
            interactive mode during the jaw's opening drops from 2.9 to 1.9 mm at 2 iterations;
            1.0 overshoots and rings), 0 otherwise (converged L-BFGS steps gain nothing).
        history: L-BFGS memory (default 8 pairs).
        refactor_after: L-BFGS renews the factorisation at the current shape when the iterations
            beyond one per step since the last one add up to this (with a fixed ``iterations``:
            all iterations of steps whose last update was above ``tolerance``), or within a step
            after this many (default 20; 0: never renew).
        spring_updates: Stages with a ``refresh`` (the muscles' fibre cosine of Eq. 6.4.1) are
            re-evaluated at the solution and the step solved again, up to this many times, until
            no spring stiffness changes by more than ``spring_tolerance`` of the largest (default
            4; the step then ends at a fixed point of Eq. 6.4.1). With ``iterations`` (fixed
            cost) the cosine stays at the step's start (lagged one step).
        spring_tolerance: see ``spring_updates`` (default 0.01).
        backend: Sparse factorisation (default :func:`factorization_backend`).

    Attributes:
        contact_slack: One-sided (contact) springs within this distance [m] of closing are kept
            in the factorised model of L-BFGS (3e-4).
        contact_tolerance: A contact detected again at the solution that closed further by more
            than this [m] makes the solver solve again (5e-5: half the 0.1 mm below the contact
            gap that a pressed node keeps).
        contact_updates: At most this many further solves for contacts (8).
        step_bound: The line search skips, without evaluating them, the trials at which a tet
            would invert (True; the same steps up to float32 rounding, fewer evaluations; False:
            every trial evaluated).
        factorizations: Number of factorisations made so far.
        line_search_trials: Energy evaluations of the line search so far.
    """

    _OPTIONS = _COMMON_OPTIONS + ("history", "refactor_after", "spring_updates", "spring_tolerance", "backend")

    def __init__(self, model: Model, *, method: str | None = None, stages=(), tolerance: float = 1e-5,
                 max_iterations: int | None = None, iterations: int | None = None, extrapolate: float | None = None,
                 history: int = 8, refactor_after: int = 20, spring_updates: int = 4, spring_tolerance: float = 0.01,
                 backend: str | None = None, **options):
        refuse_options(type(self), options)
        method = "lbfgs" if method is None else method
        if method not in HOST_METHODS:
            raise InputError(f"method: {type(self).__name__} runs {' or '.join(HOST_METHODS)}, got {method!r}"
                             + (" (SolverDeviceNewtonPCG)" if method == "newton-pcg" else ""))
        if extrapolate is None:
            extrapolate = 0.5 if iterations is not None else 0.0
        super().__init__(model, stages=stages, tolerance=tolerance,
                         max_iterations=50 if max_iterations is None else max_iterations, iterations=iterations,
                         extrapolate=extrapolate)
        if self.device.is_cuda:
            raise InputError(f"method {method!r} factorises on the host and runs on the CPU only; "
                             "use method='newton-pcg' on CUDA")
        if not (isinstance(history, (int, np.integer)) and history >= 1):
            raise InputError(f"history: expected a whole number >= 1, got {history!r}")
        if not (isinstance(refactor_after, (int, np.integer)) and refactor_after >= 0):
            raise InputError(f"refactor_after: expected a whole number >= 0, got {refactor_after!r}")
        if not (isinstance(spring_updates, (int, np.integer)) and spring_updates >= 0):
            raise InputError(f"spring_updates: expected a whole number >= 0, got {spring_updates!r}")
        if not (np.isfinite(spring_tolerance) and spring_tolerance > 0):
            raise InputError(f"spring_tolerance: expected a positive number, got {spring_tolerance!r}")
        if backend is not None and backend not in ("cholmod", "qdldl", "splu"):
            raise InputError(f"backend: expected 'cholmod', 'qdldl' or 'splu', got {backend!r}")
        self.method = method
        self.history = int(history)
        self.refactor_after = int(refactor_after)
        self.spring_updates = int(spring_updates)
        self.spring_tolerance = float(spring_tolerance)
        self.backend = backend or factorization_backend()
        self.contact_tolerance = 5.0e-5  # [m] contact re-detection that changes less is not solved again
        self.contact_updates = 8  # further solves while a re-detected contact closed further
        self._contacts_factored = None  # the contact set of the last factorisation
        self._excess = 0  # iterations beyond one per step since the last factorisation
        self._last_step_size = 0.0
        self._inverted = False
        self._history = ([], [], [])
        self._h = None
        self._solve0 = None
        self._solve_converged = True
        self._tets = None  # the step bound's float64 arrays (positions, direction, roots)
        self.line_search_trials = 0  # energy evaluations of the line search so far
        self.step_bound = True  # the line search skips trials that would invert a tet

    # ------------------------------------------------------------------------------ evaluation
    def _host_eval(self, x64: np.ndarray, control: Control, h: float,
                   with_grad: bool = True) -> tuple[float, np.ndarray | None, float]:
        """Energy, gradient (3n,) (None without ``with_grad``: :meth:`_host_grad` then) and the
        energy's float32 rounding scale at positions x64 (n, 3); :attr:`_inverted` tells whether
        a tet is inverted there."""
        t0 = time.perf_counter()
        e, g, noise, self._inverted = self.incremental.host_eval(x64, control, h, with_grad)
        self.timings["gradient"] += time.perf_counter() - t0
        return e, g, noise

    def _host_grad(self, control: Control, h: float) -> np.ndarray:
        """The gradient at the last :meth:`_host_eval` (made without ``with_grad``)."""
        t0 = time.perf_counter()
        g = self.incremental.host_grad(control, h)
        self.timings["gradient"] += time.perf_counter() - t0
        return g

    def _host_factor(self, x64: np.ndarray, h: float):
        t0 = time.perf_counter()
        ip = self.incremental
        ip.x.numpy()[:] = x64
        ip.launch_hessian(ip.x, h, self.contact_slack if self.method == "lbfgs" else 0.0)
        self._contacts_factored = ip.contact_set(x64, self.contact_slack)
        if self.backend == "qdldl":  # QDLDL reads the upper triangle
            import qdldl

            solve = qdldl.Solver(ip.hessian_upper()).solve
        else:
            solve = _factorize(ip.hessian_matrix(), self.backend)
        self._clear_history()
        self.factorizations += 1
        self._excess = 0
        self.timings["factor"] += time.perf_counter() - t0
        return solve

    def _line_search(self, x64, d, e, g, noise, control, h):
        """Backtracking from t = 1 on the energy (Armijo, within float32 rounding), halving t,
        rejecting any step that inverts a tet; returns (t, x, e, g, noise) at the accepted point
        (t = 0: none), after at most 12 trials.

        With :attr:`step_bound`, once a trial inverts a tet, the further trials at which a tet
        would invert are skipped without an evaluation: t goes on halving to the first value below
        the first t at which a tet's volume along the direction reaches 0
        (:meth:`_first_inversion`), the skipped halvings counted as trials. The accepted step is
        the one of plain halving (up to float32 rounding at the inversion itself); on a control
        stream switching every frame half the rejected trials were such inverted ones."""
        gd = _dot(g, d)
        t, trials, root = 1.0, 12, None
        while trials > 0:
            xt = x64 + t * d.reshape(-1, 3)
            et, _, nt = self._host_eval(xt, control, h, with_grad=False)  # the gradient only if accepted
            self.line_search_trials += 1
            trials -= 1
            if et <= e + 1e-4 * t * gd + noise and not self._inverted:
                return t, xt, et, self._host_grad(control, h), nt
            t *= 0.5
            if self._inverted and self.step_bound:
                if root is None:
                    root = self._first_inversion(x64, d)
                while t >= root and trials > 0:
                    t *= 0.5
                    trials -= 1
        self._host_eval(x64, control, h)  # leave the buffers at the current point
        return 0.0, x64, e, g, noise

    def _first_inversion(self, x64: np.ndarray, d: np.ndarray) -> float:
        """The smallest t in (0, 1] at which a tet's signed volume along ``x64 + t d`` (a cubic in
        t) reaches 0, or inf: the cubic sampled at t = k / 8, the first sign change refined by
        bisection to 1e-6, float64 (a Warp kernel, ``kernels_line_search._first_inversion``;
        measured at level 0 on the shared 2-core box: 0.6 ms, the NumPy version it replaces 5.5
        ms, the same roots). x64: (n, 3) [m]; d: (3n,) [m]."""
        from . import kernels_line_search as kl

        wp = get_warp()
        if self._tets is None:
            n, dev = self.model.vertex_count, self.device
            self._tets = (wp.zeros(n, dtype=wp.vec3d, device=dev), wp.zeros(n, dtype=wp.vec3d, device=dev),
                          wp.zeros(self.model.tet_count, dtype=wp.float64, device=dev))
        xa, da, roots = self._tets
        xa.numpy()[:] = x64
        da.numpy()[:] = d.reshape(-1, 3)
        wp.launch(kl._first_inversion, dim=self.model.tet_count, inputs=[self.model.tet_indices, xa, da],
                  outputs=[roots], device=self.device)
        r = float(roots.numpy().min())
        return float("inf") if r >= 1.0e300 else r

    # ------------------------------------------------------------------------------ step
    def _solve(self, state_in: State, control: Control, h: float) -> None:
        ip = self.incremental
        if self.extrapolate > 0.0:
            self._host_eval(ip.x.numpy().astype(np.float64), control, h)
            if self._inverted:  # the extrapolated guess inverts a tet: start from x_n instead
                ip.launch_guess(state_in, 0.0)
        x64 = ip.x.numpy().astype(np.float64)
        self._solve_converged = True
        if self.method == "lbfgs" and (self._solve0 is None or self._h != h):
            self._solve0 = self._host_factor(x64, h)
            self._h = h
        total = 0
        updates = 0 if self.iterations is not None else self.spring_updates
        extra = 0 if self.iterations is not None else self.contact_updates
        for outer in range(updates + extra + 1):
            if (outer == 0 and self.method == "lbfgs" and self.refactor_after > 0
                    and self._contacts_factored is not None):
                # a contact closed since the factorisation: the factorised model lacks its stiff
                # spring, and L-BFGS would backtrack at every iteration
                cs = ip.contact_set(x64, self.contact_slack)
                if cs.shape != self._contacts_factored.shape or np.any(cs & ~self._contacts_factored):
                    self._solve0 = self._host_factor(x64, h)
            e, g, noise = self._host_eval(x64, control, h)
            if not (np.isfinite(e) and np.isfinite(g).all()):
                raise SimulationError(
                    f"step {self.step_count + 1}: the step's energy is not finite: a NaN or inf in the controls "
                    "(activations, jaw angles, external force, cranium velocity) or the state; nothing was written")
            if self.method == "newton":
                its, x64 = self._newton(x64, e, g, noise, control, h)
            else:
                its, x64 = self._lbfgs(x64, e, g, noise, control, h)
            total += its
            if outer == updates + extra or (outer >= updates and not any(s_.one_sided for s_ in ip.springs)):
                break
            springs, contacts = self._refresh_springs(x64, control)
            # the muscles' cosine is re-evaluated up to spring_updates times; a contact that
            # closed further (a crossing in the making) up to contact_updates times more
            if not ((springs and outer < updates) or contacts):
                break
        if self.method == "lbfgs" and self.refactor_after > 0:
            if self.iterations is None:
                self._excess += max(total - 1, 0)
            elif self._last_step_size > self.tolerance:
                self._excess += total
            if self._excess >= self.refactor_after:
                self._solve0 = self._host_factor(x64, h)
        ip.x.numpy()[:] = x64
        self.last_iterations = total
        # the last solve reached the tolerance (always true with a fixed iteration count)
        self.last_converged = self.iterations is not None or self._solve_converged

    def _refresh_springs(self, x64: np.ndarray, control: Control) -> tuple[bool, bool]:
        """Re-evaluate the refreshable springs at x64; whether they changed: ``(springs,
        contacts)``, a stiffness by more than ``spring_tolerance`` of the largest, and a one-sided
        (contact) spring's compression at x64 grown by more than ``contact_tolerance`` (a contact
        found, or its surface moved toward the node)."""
        if not self._refreshers:
            return False, False
        ip = self.incremental

        def snap(s):
            sp_ = s.springs
            k = sp_.stiffness.numpy().copy()
            if not s.one_sided:
                return k, None
            r = x64[s.node_host] - sp_.point.numpy()
            if sp_.axis is not None:
                c = -np.einsum("ij,ij->i", r, sp_.axis.numpy())
            else:
                c = sp_.rest_length.numpy() - np.linalg.norm(r, axis=1)
            return k, np.where(k > 0, np.maximum(c, 0.0), 0.0)

        before = [snap(s) for s in ip.springs]
        ip.x.numpy()[:] = x64
        for st in self._refreshers:
            st.refresh(self.model, ip.x, control)
        springs = contacts = False
        for s, (b, cb) in zip(ip.springs, before):
            k, c = snap(s)
            if not len(k):
                continue
            if s.one_sided:
                # only a contact that closed further matters (one that opened leaves the node a
                # little farther out, by less than the contact gap)
                contacts |= float((c - cb).max()) > max(self.tolerance, self.contact_tolerance)
            else:
                scale = max(float(np.abs(b).max()), float(np.abs(k).max()), 1e-30)
                springs |= float(np.abs(k - b).max()) / scale > self.spring_tolerance
        return springs, contacts

    def _clear_history(self) -> None:
        self._history = ([], [], [])

    def _converged(self, step: np.ndarray) -> bool:
        return self.iterations is None and float(np.abs(step).max(initial=0.0)) < self.tolerance

    def _newton(self, x64, e, g, noise, control, h) -> int:
        its = self.iterations or self.max_iterations
        for k in range(its):
            solve = self._host_factor(x64, h)
            t0 = time.perf_counter()
            d = -solve(g)
            self.timings["solve"] += time.perf_counter() - t0
            t, xn, e, g, noise = self._line_search(x64, d, e, g, noise, control, h)
            step, x64 = t * d, xn
            if t == 0.0 or self._converged(step):
                self._solve_converged = True
                return k + 1, x64
        self._solve_converged = False
        return its, x64

    def _lbfgs(self, x64, e, g, noise, control, h) -> tuple[int, np.ndarray]:
        # the curvature pairs carry over from step to step (consecutive steps have nearly the
        # same Hessian): with one or two iterations per frame, the interactive mode keeps
        # learning the soft modes the factorised Hessian misses
        S, Y, R = self._history
        its = self.iterations or self.max_iterations
        solve0 = self._solve0
        fresh = False  # solve0 was factorised at x64
        self._last_step_size = 0.0
        for k in range(its):
            if self.iterations is None and self.refactor_after > 0 and k > 0 and k % self.refactor_after == 0:
                # stalled (a large change of shape, e.g. a jump of the controls): a fresh
                # factorisation at the current shape, history cleared
                solve0 = self._solve0 = self._host_factor(x64, h)
                S, Y, R = self._history
                fresh = True
            t0 = time.perf_counter()
            q = -g
            alphas = []
            for s_, y_, rho in zip(reversed(S), reversed(Y), reversed(R)):
                a = rho * _dot(s_, q)
                alphas.append(a)
                q = q - a * y_
            r = solve0(q)
            for (s_, y_, rho), a in zip(zip(S, Y, R), reversed(alphas)):
                r = r + s_ * (a - rho * _dot(y_, r))
            d = r
            if _dot(g, d) >= 0.0:  # not a descent direction: restart from the factorised Hessian
                self._clear_history()
                S, Y, R = self._history
                d = solve0(-g)
            self.timings["solve"] += time.perf_counter() - t0
            t, xn, en, gn, nn = self._line_search(x64, d, e, g, noise, control, h)
            if t == 0.0:
                if not S:
                    if fresh:
                        self._solve_converged = True  # no lower energy from a fresh factorisation: a minimum
                        return k + 1, x64
                    # the factorisation was made at another shape: where the mesh has a soft
                    # mode there (a flap, a sliver) its direction can be metres long and no
                    # step of the line search lowers the energy; renew it here and retry once
                    # (measured on the imported ICT head: the smile's lip corner stalled at
                    # 0.7 mm of its 11 mm without this)
                    solve0 = self._solve0 = self._host_factor(x64, h)
                    S, Y, R = self._history
                    fresh = True
                    continue
                self._clear_history()  # a stale pair spoilt the direction: retry from the factorisation
                S, Y, R = self._history
                continue
            s_ = t * d
            y_ = gn - g
            sy = _dot(s_, y_)
            # keep only pairs measured above float32 rounding (a step that really lowered the energy)
            if e - en > nn and sy > 1e-12 * np.sqrt(_dot(s_, s_) * _dot(y_, y_)):
                S.append(s_)
                Y.append(y_)
                R.append(1.0 / sy)
                if len(S) > self.history:
                    S.pop(0), Y.pop(0), R.pop(0)
            x64, e, g, noise = xn, en, gn, nn
            fresh = False
            self._last_step_size = float(np.abs(s_).max(initial=0.0))
            if self._converged(s_):
                self._solve_converged = True
                return k + 1, x64
        self._solve_converged = False
        return its, x64

    def reset(self) -> None:
        """Back to the rest pose (targets, counter, guard) and to a fresh solver's step history: the
        curvature pairs and the factorisation go (a factorisation kept from a later state would
        steer the next steps' iterations, up to the tolerance, away from a fresh solver's)."""
        super().reset()
        self._clear_history()
        self._solve0 = self._h = self._contacts_factored = None
        self._excess, self._last_step_size = 0, 0.0
