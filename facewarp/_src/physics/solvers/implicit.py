"""Implicit (backward) Euler solver of the skin model: the thesis's energies at frame-sized steps.

``SolverImplicit(model, stages=...).step(state_in, state_out, control, dt)`` has the contract of
:class:`~.verlet.SolverVerlet` (:mod:`.base`) and integrates the same :class:`Model` (energies of
Eq. 6.4.4-6.4.8, muscle springs of Eq. 6.4.1, holds, supports, damping): one step minimises the
incremental potential Phi of backward Euler (:mod:`facewarp._src.physics.potential`, kernels in
:mod:`.kernels_implicit`), which is stable for any step, so a 30 fps frame can be one step.

Why this method (measured on the 2-core CPU box, default head level 0: 2,448 nodes, 6,738 tets,
presets with muscles and a 30 degree jaw; ``benchmarks/solver_accuracy.py``, ``physics_steps.py``)
----------------------------------------------------------------------------------------------
The skin is a thin stiff layer driven quasi-statically: at 30 fps the mass term ``M / h^2`` is
~1e-4 of the stiffness, so a step is practically a static solve whose error modes span the whole
face. Sweep methods (Jacobi, Gauss-Seidel / VBD colour sweeps, XPBD) reduce such smooth modes by
about (edge / region)^2 per sweep and need hundreds of sweeps per frame here; so does conjugate
gradients with a block-Jacobi preconditioner inside Newton from a cold start. A global direct solve removes all modes at once. Newton with a fresh
sparse factorisation per iteration converges in 3-30 iterations (the compressed lips near a
buckling mode converge linearly) at 50-200 ms per factorisation: 1-4 frames/s. The default is
therefore the quasi-Newton method of Liu, Bouaziz & Kavan 2017 ("Quasi-Newton methods for
real-time simulation of hyperelastic materials"): L-BFGS whose initial inverse Hessian is a sparse
LDL^T / LU factorisation of the PSD Hessian ``M / h^2 + K`` made at the first step and reused,
with backtracking on the energy that also rejects any step inverting a tet. Its energy and
gradient are Warp kernels (~1 ms per evaluation at level 0 on one CPU thread), the factor's
back-substitution (~1.4 ms with QDLDL) is the other half of an iteration. A converged frame
(every node within ``tolerance`` 3e-5 m of its last iterate) takes 2-7 iterations: 15-55
frames/s at level 0, every FDP within 0.03 mm of the fully converged step. The curvature pairs
carry over from step to step, and the factorisation is renewed at the current shape only when
the old one has become a poor model (the jaw turned, muscle springs switched on): when the
iterations beyond one per step since the last factorisation add up to ``refactor_after`` (20: at
levels 0 and 1 a factorisation costs about as much as 20-25 iterations), or within a step that
stalls for as many. The rule counts iterations, not seconds, so a run repeats bit for bit.

Methods (``method=``):

* ``"lbfgs"`` (default on the CPU): the above; host factorisation (QDLDL or CHOLMOD when
  installed, else SciPy's SuperLU; :func:`factorization_backend`) on zero-copy views of the Warp
  arrays. ``iterations=k`` is the interactive mode: k iterations per frame whatever the residual
  (measured lag: 0.1-0.5 mm on smile and sad at 2-3 iterations, 1-3 mm on the lips during the
  jaw's 0.3 s opening of laugh and surprise, none once the expression is held).
* ``"newton"`` (CPU): Newton with a fresh factorisation every iteration and the same line search.
* ``"newton-pcg"`` (default on CUDA, runs on the CPU too): Newton iterations, each with a fixed
  number (``linear_iterations``, 10 up to 10,000 nodes, growing with the square root of the node
  count beyond: :func:`default_linear_iterations`) of block-Jacobi preconditioned conjugate-gradient iterations
  on the block-sparse Hessian assembled by kernels, one launch per CG iteration (the
  Chronopoulos-Gear form with the product fused into the update, kernels ``_cg_*``: about a tenth
  of ``warp.optim.linear.cg``'s launches, the same iterates), and a backtracking line search
  (t = 1, 1/2, 1/4, 1/8, all four evaluated in one pass) decided on the device.
  The Newton loop is adaptive: it runs until no free node moves more than ``tolerance`` (3e-5 m
  from the simulator) in an iteration, at most ``max_iterations`` (12), as a ``wp.capture_while``
  loop, so on CUDA a whole frame, loop included, is one CUDA graph with no host round trip
  (:meth:`SolverImplicit.step` allocates nothing on that path). With a contact stage the loop runs
  ``rounds`` (2) times, the contacts detected again between rounds: their BVH refit allocates and
  may not be inside a graph's conditional node. A line search that finds no lower energy (a
  direction from the exact Hessian that runs into a contact spring slack at x) is retried once
  with the springs within ``contact_slack`` of closing in the Hessian, and never taken as
  convergence. The first guess continues the previous step's motion (``extrapolate`` 0.5).
  Measured at level 0 against the fully converged steps (``benchmarks/solver_accuracy.py --parts
  pcg``; every FDP of the five Table 6.4 presets during attack, hold and release; on an H100):
  within 0.03-0.25 mm at 3.8-6.9 Newton iterations per frame. ``iterations=k`` gives a fixed count
  instead (the interactive mode): 3 stay within 0.32 mm, 2 and 1 miss the 0.5 mm on some presets
  (0.6 and 1.9 mm, on the CPU). A level-0 frame is launch bound (H100: 381 frames/s adaptive, 522
  with 3 iterations; ``benchmarks/physics_steps.py``): the four line-search trials are one pass
  (``_trial_energies``), every stage's springs one pooled launch (``_SpringPool``), a CG iteration
  one launch, so a Newton iteration is 36 launches where it was ~140 (179 frames/s). Before the
  exact Hessian, its retry and the extrapolated guess, the former fixed 3 x 50 missed by up to
  2.2 mm (a lid sliding over the eyeball took steps too short to follow it).

The muscle springs' fibre cosine of Eq. 6.4.1 is taken at the step's start and held over the
solve (see ``kernels_muscle._muscle_springs``): within the solve a conservative spring
``1/2 k_m w (l - l0)^2`` with an exact gradient and Hessian. The CPU methods then re-evaluate the
cosine at the solution and solve again until it no longer changes (``spring_updates``), so the
step ends at a fixed point of Eq. 6.4.1 as printed; the device method re-evaluates it before every
Newton iteration.

Contact (:mod:`facewarp._src.physics.contact`) adds one-sided springs (``Springs.one_sided``):
penalties that act only when compressed, their planes (the other lip's closest point, a dental
arch's) frozen over a solve like the fibre cosine. The CPU methods detect the contacts again at
the solution and solve again while a contact closed further by more than ``contact_tolerance``
(up to ``contact_updates`` more solves); L-BFGS renews its factorisation at the step's start when
a contact has closed since the last one (its factorised model keeps the contacts within
``contact_slack`` of closing: without the stiff contact springs it would backtrack at every
iteration). The device method re-detects before every Newton iteration, as for the muscles.
Measured at level 0 (default head, CPU L-BFGS, ``benchmarks/physics_steps.py --contact``, a
2-core box shared with other jobs, so +-30 %): the lids touch the eyeballs in most presets and
cost 1.1-2x the frame time (laugh, smile, surprise, sad, blink, squint, the Fig. 6.16 sequence);
pucker, the lips pressed together through its whole hold, 3-10x.
"""

from __future__ import annotations

import importlib.util
import time

import numpy as np

from ...core.errors import InputError, SimulationError
from ...core.warp import get_warp
from ..model import Control, Model, State, group_indices
from . import kernels_implicit as ki
from .base import SolverBase, check_step_args, stage_springs

__all__ = ["IMPLICIT_METHODS", "SolverImplicit", "default_linear_iterations", "factorization_backend"]

IMPLICIT_METHODS = ("lbfgs", "newton", "newton-pcg")
"""The methods of :class:`SolverImplicit` (see the module doc)."""

_LINE_SEARCH_TRIALS = 4  # device line search: t = 1, 1/2, 1/4, 1/8


def factorization_backend() -> str:
    """The sparse factorisation the CPU methods use, the first one installed: ``"qdldl"`` (the
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


def default_linear_iterations(node_count: int) -> int:
    """Conjugate-gradient iterations per Newton iteration of ``"newton-pcg"`` for a mesh of
    ``node_count`` nodes: 10 up to 10,000 nodes, then ``10 sqrt(node_count / 10,000)`` rounded.

    The skin is a sheet: each level halves the edge length h and quarters the node count, the
    Hessian's condition number grows as h^-2, and the CG iterations that reach a given reduction as
    its square root, h^-1 ~ sqrt(node_count). Levels 0-3 of the default head (2,448 / 9,470 /
    36,930 / 146,450 nodes) get 10 / 10 / 19 / 38.
    """
    n = int(node_count)
    return 10 if n <= 10_000 else int(round(10.0 * np.sqrt(n / 10_000.0)))


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


class _SpringSet:
    """One stage's springs (host side: the contact and fibre-cosine tests of the CPU methods)."""

    def __init__(self, springs):
        self.springs = springs
        self.node_host = springs.node.numpy().astype(np.int64)
        self.count = len(self.node_host)
        self.axis = springs.axis is not None
        self.one_sided = int(bool(getattr(springs, "one_sided", False)))


class _SpringPool:
    """Every stage's springs as one pool of ``count`` springs, evaluated in one launch per pass:
    a :class:`~.kernels_implicit.SpringSet` per set (the stage's own arrays, read in place), the
    set and local index of every pooled spring, its gradient entries and their fixed-order gather
    per node (deterministic sums)."""

    def __init__(self, sets: list, device):
        wp = get_warp()
        dummy_f = wp.zeros(1, dtype=float, device=device)
        dummy_v = wp.zeros(1, dtype=wp.vec3, device=device)
        descs = []
        for s in sets:
            sp = s.springs
            d = ki.SpringSet()
            d.node, d.point, d.stiffness = sp.node, sp.point, sp.stiffness
            d.rest_length = dummy_f if sp.rest_length is None else sp.rest_length
            d.axis = dummy_v if sp.axis is None else sp.axis
            d.is_axis, d.one_sided = int(s.axis), s.one_sided
            descs.append(d)
        self._dummies = (dummy_f, dummy_v)
        counts = [s.count for s in sets]
        self.count = int(sum(counts))
        i32 = lambda a: wp.array(np.ascontiguousarray(a, np.int32), dtype=wp.int32, device=device)  # noqa: E731
        self.sets = wp.array(descs, dtype=ki.SpringSet, device=device) if descs else None
        self.set_index = i32(np.repeat(np.arange(len(sets)), counts))
        self.local = i32(np.concatenate([np.arange(c) for c in counts]) if sets else np.zeros(0))
        node = np.concatenate([s.node_host for s in sets]) if sets else np.zeros(0, np.int64)
        nodes_u, start, order = group_indices(node)
        self.group_nodes, self.group_start, self.group_order = i32(nodes_u), i32(start), i32(order)
        self.grad = wp.zeros(self.count, dtype=wp.vec3, device=device)


class SolverImplicit(SolverBase):
    """Backward Euler of the skin model, one minimisation of the step's potential per step.

    Args:
        model: the tissue :class:`Model`.
        stages: :class:`~.base.SolverStage` objects prepared, in order, at the start of each step.
        method: ``"lbfgs"`` (CPU default), ``"newton"`` (CPU) or ``"newton-pcg"`` (CUDA
            default); see the module doc.
        tolerance: Converged when no free node moves more than this in an iteration [m]
            (default 1e-5 m = 0.01 mm). Ignored with ``iterations``.
        max_iterations: At most this many (quasi-)Newton iterations per step (default 50), per
            round with the adaptive ``"newton-pcg"`` (default 12 there: a bounded frame time; the
            thesis profile's stiff layer otherwise took up to 100 iterations in frames of the
            laugh's hold, the lip contacts chattering).
        iterations: A fixed count per step instead (the interactive mode: a fixed cost per
            frame, no convergence test; ``"newton-pcg"``: also no rounds).
        history: L-BFGS memory (default 8 pairs).
        extrapolate: The first guess is ``x_n + extrapolate (x_n - x_prev)`` (the previous step's
            motion, in the jaw-carried frame, continued; a guess that inverts a tet falls back to
            x_n). Default: 0.5 with a fixed ``iterations`` (measured on the laugh preset: the
            lag of the interactive mode during the jaw's opening drops from 2.9 to 1.9 mm at 2
            iterations; 1.0 overshoots and rings) and with ``"newton-pcg"`` (its adaptive loop:
            1.0 took as many iterations), 0 otherwise (converged L-BFGS steps gain nothing).
        linear_iterations: Conjugate-gradient iterations per Newton iteration (``"newton-pcg"``;
            default :func:`default_linear_iterations` of the node count: 10 up to 10,000 nodes,
            levels 0 and 1. Measured per frame against the converged steps, every FDP of the five
            Table 6.4 presets at level 0: 10 gave the errors of 20 (and 20 those of 50 and 200) at
            about 0.3 more Newton iterations per frame; on an H100 at level 0, 3 Newton iterations,
            a frame took a quarter less time than with 20. At level 2 (36,930 nodes) 10 left the
            adaptive loop at its cap, 22.5 Newton iterations per frame of the laugh's attack on the
            CPU; 20 took 6.6 and 40 took 7.9).
        refactor_after: ``"lbfgs"`` renews the factorisation at the current shape when the
            iterations beyond one per step since the last one add up to this (with a fixed
            ``iterations``: all iterations of steps whose last update was above ``tolerance``),
            or within a step after this many (default 20; 0: never renew).
        spring_updates: Stages with a ``refresh`` (the muscles' fibre cosine of Eq. 6.4.1) are
            re-evaluated at the solution and the step solved again, up to this many times, until
            no spring stiffness changes by more than ``spring_tolerance`` of the largest (default
            4; the step then ends at a fixed point of Eq. 6.4.1). With ``iterations`` (fixed
            cost) the cosine stays at the step's start (lagged one step).
        spring_tolerance: see ``spring_updates`` (default 0.01).
        backend: Sparse factorisation for the CPU methods (default :func:`factorization_backend`).
        rounds: The adaptive ``"newton-pcg"`` with a contact stage: the Newton loop runs this many
            times per step, the contacts detected again before each (default 2: solve, detect at
            the solution, solve again); the fibre cosine is refreshed after every iteration.

    Attributes:
        contact_slack: One-sided (contact) springs within this distance [m] of closing are kept
            in the factorised model of L-BFGS (3e-4). The device method's Newton model is the exact
            Hessian: with the slack springs in it, a lid sliding over the eyeball within 0.3 mm of
            it took steps too short to follow (its FDP 3.13 lagged 1.7 mm behind the converged
            solution in the sad preset's attack; 0.15 mm without).
        contact_tolerance: A contact detected again at the solution that closed further by more
            than this [m] makes the CPU methods solve again (5e-5: half the 0.1 mm below the
            contact gap that a pressed node keeps).
        contact_updates: At most this many further solves for contacts (8).
        last_iterations: Iterations of the last step (host; 0 before the first step; not updated
            by a replayed CUDA graph: see :attr:`total_iterations`).
        factorizations: Number of factorisations made so far (CPU methods).
        timings: Seconds spent, accumulated: ``{"prepare", "gradient", "solve", "factor"}``.
    """

    def __init__(self, model: Model, *, stages=(), method: str | None = None, tolerance: float = 1e-5,
                 max_iterations: int | None = None, iterations: int | None = None, history: int = 8,
                 extrapolate: float | None = None, linear_iterations: int | None = None, refactor_after: int = 20,
                 spring_updates: int = 4, spring_tolerance: float = 0.01, backend: str | None = None,
                 rounds: int = 2):
        super().__init__(model, stages=stages)
        wp = get_warp()
        if method is None:
            method = "newton-pcg" if self.device.is_cuda else "lbfgs"
        if method not in IMPLICIT_METHODS:
            raise InputError(f"method: expected one of {', '.join(IMPLICIT_METHODS)}, got {method!r}")
        if method != "newton-pcg" and self.device.is_cuda:
            raise InputError(f"method {method!r} factorises on the host and runs on the CPU only; "
                             "use method='newton-pcg' on CUDA")
        if max_iterations is None:
            max_iterations = 12 if method == "newton-pcg" else 50
        if extrapolate is None:
            extrapolate = 0.5 if iterations is not None or method == "newton-pcg" else 0.0
        if linear_iterations is None:
            linear_iterations = default_linear_iterations(model.vertex_count)
        for name, val in (("tolerance", tolerance), ("extrapolate", extrapolate)):
            if not (np.isfinite(val) and val >= 0):
                raise InputError(f"{name}: expected a finite number >= 0, got {val!r}")
        for name, val in (("max_iterations", max_iterations), ("history", history),
                          ("linear_iterations", linear_iterations)):
            if not (isinstance(val, (int, np.integer)) and val >= 1):
                raise InputError(f"{name}: expected a whole number >= 1, got {val!r}")
        if not (isinstance(refactor_after, (int, np.integer)) and refactor_after >= 0):
            raise InputError(f"refactor_after: expected a whole number >= 0, got {refactor_after!r}")
        if not (isinstance(rounds, (int, np.integer)) and rounds >= 1):
            raise InputError(f"rounds: expected a whole number >= 1, got {rounds!r}")
        if not (isinstance(spring_updates, (int, np.integer)) and spring_updates >= 0):
            raise InputError(f"spring_updates: expected a whole number >= 0, got {spring_updates!r}")
        if not (np.isfinite(spring_tolerance) and spring_tolerance > 0):
            raise InputError(f"spring_tolerance: expected a positive number, got {spring_tolerance!r}")
        if iterations is not None and not (isinstance(iterations, (int, np.integer)) and iterations >= 1):
            raise InputError(f"iterations: expected a whole number >= 1 or None, got {iterations!r}")
        if backend is not None and backend not in ("cholmod", "qdldl", "splu"):
            raise InputError(f"backend: expected 'cholmod', 'qdldl' or 'splu', got {backend!r}")
        for st in self.stages:
            if not hasattr(st, "prepare"):
                raise InputError(f"stages: {type(st).__name__} has no prepare(): it drives explicit solvers only")
        self.method = method
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self.iterations = None if iterations is None else int(iterations)
        self.adaptive = method == "newton-pcg" and self.iterations is None
        self.history = int(history)
        self.extrapolate = float(extrapolate)
        self.linear_iterations = int(linear_iterations)
        self.refactor_after = int(refactor_after)
        self._excess = 0  # iterations beyond one per step since the last factorisation
        self.contact_slack = 3.0e-4  # [m] near-closed contacts kept in the factorised model (lbfgs)
        self.contact_tolerance = 5.0e-5  # [m] contact re-detection that changes less is not solved again
        self.contact_updates = 8  # further solves while a re-detected contact closed further
        self._contacts_factored = None  # the contact set of the last factorisation
        self.spring_updates = int(spring_updates)
        self.spring_tolerance = float(spring_tolerance)
        self._refreshers = [st for st in self.stages if hasattr(st, "refresh")]
        # the device method's Newton loop (a conditional graph node) may not allocate: the stages
        # whose refresh does (the contact BVH refit) are refreshed between its rounds instead
        self._round_refreshers = [st for st in self._refreshers if getattr(st, "allocates_on_refresh", False)]
        self._loop_refreshers = [st for st in self._refreshers if st not in self._round_refreshers]
        self.rounds = int(rounds)
        self.backend = backend or factorization_backend()
        self.last_iterations = 0
        self._host_total = 0
        self._last_step_size = 0.0
        self._inverted = False
        self._history = ([], [], [])
        self.factorizations = 0
        self.timings = {"prepare": 0.0, "gradient": 0.0, "solve": 0.0, "factor": 0.0}

        m, dev, n = model, self.device, model.vertex_count
        self.springs = [_SpringSet(sp_) for sp_ in stage_springs(self.stages) if sp_.count > 0]
        self._pool = _SpringPool(self.springs, dev)
        self.x = wp.zeros(n, dtype=wp.vec3, device=dev)
        self.z = wp.zeros(n, dtype=wp.vec3, device=dev)
        self.grad = wp.zeros(n, dtype=wp.vec3, device=dev)
        self.slots = wp.zeros(m.slot_count, dtype=wp.vec3, device=dev)
        self.c_edge = wp.zeros(m.edge_count, dtype=float, device=dev)
        self.c_face = wp.zeros(m.face_count, dtype=float, device=dev)
        self.c_tet = wp.zeros(m.tet_count, dtype=float, device=dev)
        self.c_tet_trial = wp.zeros(m.tet_count, dtype=float, device=dev)
        self.g_tet = wp.zeros(m.tet_count, dtype=wp.mat33, device=dev)  # Green strain at the step's start
        self.nodes = wp.array(np.arange(n, dtype=np.int32), dtype=wp.int32, device=dev)
        self._host_slack = wp.zeros(1, dtype=float, device=dev)
        # one energy array: edges, faces, tets, nodes, then the pooled springs
        sizes = [m.edge_count, m.face_count, m.tet_count, n, self._pool.count]
        off = np.r_[0, np.cumsum(sizes)]
        self.energy = wp.zeros(int(off[-1]), dtype=float, device=dev)
        self._e_views = [self.energy[int(off[i]):int(off[i + 1])] if sizes[i] else None for i in range(len(sizes))]
        self._chunk = max(32, int(np.ceil(np.sqrt(off[-1]))))  # entries per partial sum
        self._chunks = max(1, -(-int(off[-1]) // self._chunk))
        self._energy_row = self.energy.reshape((1, self.energy.shape[0]))  # a view: summed as one row
        self.partial = wp.zeros((1, self._chunks), dtype=wp.float64, device=dev)
        self.totals = wp.zeros(1 + _LINE_SEARCH_TRIALS, dtype=wp.float64, device=dev)
        self._h = None
        self._solve0 = None
        self._blocks_ready = False
        self._build_blocks()
        if method == "newton-pcg":
            self._build_pcg()

    # ------------------------------------------------------------------------------ Hessian pattern
    def _build_blocks(self):
        """Block slots of every element, node and spring, and the BSR pattern they sum into."""
        wp = get_warp()
        m, dev, n = self.model, self.device, self.model.vertex_count
        E = m.edge_indices.numpy().astype(np.int64)
        F = m.face_indices.numpy().astype(np.int64)
        T = m.tet_indices.numpy().astype(np.int64)

        def pairs(idx):  # block slot p * count + t: corner pair p = a * c + b of element t (pair-major:
            c = idx.shape[1]  # a warp's threads write neighbouring blocks, coalesced)
            r = np.repeat(idx[:, :, None], c, axis=2).reshape(len(idx), c * c)
            cc = np.repeat(idx[:, None, :], c, axis=1).reshape(len(idx), c * c)
            return r.T.reshape(-1), cc.T.reshape(-1)

        rows, cols = zip(*[pairs(E), pairs(F), pairs(T), (np.arange(n), np.arange(n))]
                         + [(s.node_host, s.node_host) for s in self.springs])
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        self._block_offsets = np.cumsum([0, 4 * len(E), 9 * len(F), 16 * len(T), n, self._pool.count])
        code = rows * n + cols
        uniq, inv = np.unique(code, return_inverse=True)
        nb = len(uniq)
        _, start, order = group_indices(inv, np.arange(nb))
        brow, bcol = uniq // n, uniq % n
        self.block_count = nb
        self._bsr_offsets = np.searchsorted(brow, np.arange(n + 1)).astype(np.int32)
        self._bsr_columns = bcol.astype(np.int32)
        self._diag_block = np.searchsorted(uniq, np.arange(n) * n + np.arange(n)).astype(np.int32)
        i32 = lambda a: wp.array(np.ascontiguousarray(a, np.int32), dtype=wp.int32, device=dev)  # noqa: E731
        self.block_slots = wp.zeros(len(code), dtype=wp.mat33, device=dev)
        self.block_start = i32(start)
        self.block_order = i32(order)
        self.block_row = i32(brow)
        self.block_col = i32(bcol)
        self.diag_block = i32(self._diag_block)
        self.block_values = wp.zeros(nb, dtype=wp.mat33, device=dev)
        self._blocks_ready = True

    def _build_pcg(self):
        import warp.sparse as wsp

        wp = get_warp()
        dev, n = self.device, self.model.vertex_count
        A = wsp.bsr_zeros(n, n, block_type=wp.mat33, device=dev)
        rows = np.repeat(np.arange(n), np.diff(self._bsr_offsets)).astype(np.int32)
        wsp.bsr_set_from_triplets(A, wp.array(rows, dtype=wp.int32, device=dev),
                                  wp.array(self._bsr_columns, dtype=wp.int32, device=dev),
                                  wp.array(np.tile(np.eye(3, dtype=np.float32), (self.block_count, 1, 1)),
                                           dtype=wp.mat33, device=dev), prune_numerical_zeros=False)
        if not (np.array_equal(A.offsets.numpy()[: n + 1], self._bsr_offsets)
                and np.array_equal(A.columns.numpy()[: self.block_count], self._bsr_columns)):
            raise RuntimeError("warp.sparse ordered the Hessian blocks differently from the solver's pattern")
        self.A = A  # a warp.sparse matrix: users and tests can multiply with it (bsr_mv)
        self.block_values = A.values  # the gather writes straight into the matrix
        self.inv_diag = wp.zeros(n, dtype=wp.mat33, device=dev)
        self.rhs = wp.zeros(n, dtype=wp.vec3, device=dev)
        self.direction = wp.zeros(n, dtype=wp.vec3, device=dev)
        vec = lambda: wp.zeros(n, dtype=wp.vec3, device=dev)  # noqa: E731
        self._cg_buffers = ((vec(), vec(), vec()), (vec(), vec(), vec()), vec(), vec())  # (r, s, w) x 2, u, p
        self._cg_sums = wp.zeros((2 * self.linear_iterations + 2, ki.CG_SLOTS), dtype=wp.float64, device=dev)
        self._cg_scalars = wp.zeros((self.linear_iterations, 3), dtype=wp.float64, device=dev)
        self.t_step = wp.zeros(1, dtype=float, device=dev)
        self._newton_count = wp.zeros(1, dtype=wp.int32, device=dev)
        self._newton_cond = wp.zeros(1, dtype=wp.int32, device=dev)
        self._largest_step = wp.zeros(2, dtype=float, device=dev)  # (max t |d_i|, max |d_i|) [m]
        self._newton_total = wp.zeros(1, dtype=wp.int64, device=dev)
        self._slack = wp.zeros(1, dtype=float, device=dev)  # the device method's Hessian slack [m]
        self._guess_flag = wp.zeros(1, dtype=wp.int32, device=dev)  # the extrapolated guess inverts a tet
        # the line search's trial energies (row j: t = 2^-j), in the energy array's layout
        self.trial_energy = wp.zeros((_LINE_SEARCH_TRIALS, self.energy.shape[0]), dtype=float, device=dev)
        self.trial_partial = wp.zeros((_LINE_SEARCH_TRIALS, self._chunks), dtype=wp.float64, device=dev)

    def _launch_cg(self) -> None:
        """:attr:`direction` = A^-1 :attr:`rhs` by ``linear_iterations`` block-Jacobi preconditioned
        CG iterations from 0, one launch each after a start and a first product (kernels
        ``_cg_*``, Chronopoulos-Gear form, the product fused with the update).

        Measured against ``warp.optim.linear.cg`` (~10 launches and a conditional graph node per
        iteration) on the same systems: the same iterates up to float32 rounding."""
        wp = get_warp()
        dev, n, A = self.device, self.model.vertex_count, self.A
        (r0, s0, w0), (r1, s1, w1), u, p = self._cg_buffers
        sums, scalars, inv, x = self._cg_sums, self._cg_scalars, self.inv_diag, self.direction
        wp.launch(ki._zero_2d, dim=sums.shape, inputs=[], outputs=[sums], device=dev)  # (a kernel node)
        wp.launch(ki._cg_start, dim=n, inputs=[inv, self.rhs], outputs=[x, r0, u, p, s0, sums], device=dev)
        wp.launch(ki._cg_matvec, dim=n, inputs=[A.offsets, A.columns, A.values, u, 1], outputs=[w0, sums], device=dev)
        bufs = ((r0, s0, w0), (r1, s1, w1))
        for k in range(self.linear_iterations):
            (ri, si, wi), (ro, so, wo) = bufs[k % 2], bufs[(k + 1) % 2]
            wp.launch(ki._cg_iteration, dim=n,
                      inputs=[A.offsets, A.columns, A.values, inv, k, int(k == self.linear_iterations - 1), sums,
                              scalars, ri, si, wi],
                      outputs=[x, p, u, ro, so, wo], device=dev)

    # ------------------------------------------------------------------------------ device work
    def _begin(self, state_in: State, control: Control, h: float) -> None:
        """Stages, the dashpots' start constraints, the inertial target and the first guess."""
        wp = get_warp()
        m, dev = self.model, self.device
        for st in self.stages:
            st.prepare(m, state_in, control, h, self.targets)
        x = state_in.positions
        wp.launch(ki._edge_constraints, dim=m.edge_count, inputs=[m.edge_indices, m.edge_rest_length, x],
                  outputs=[self.c_edge], device=dev)
        wp.launch(ki._face_constraints, dim=m.face_count, inputs=[m.face_indices, m.face_rest_area, x],
                  outputs=[self.c_face], device=dev)
        wp.launch(ki._tet_constraints, dim=m.tet_count, inputs=[m.tet_indices, m.tet_rest_volume, m.tet_rest_inverse, x],
                  outputs=[self.c_tet, self.g_tet], device=dev)
        wp.launch(ki._inertial_target, dim=m.vertex_count,
                  inputs=[m.damping_rate, h, control.cranium_velocity, x, state_in.prev_positions],
                  outputs=[self.z], device=dev)
        wp.launch(ki._initial_guess, dim=m.vertex_count,
                  inputs=[m.vertex_fixed, self.extrapolate, self.targets, x, state_in.prev_positions],
                  outputs=[self.x], device=dev)
        if self.method == "newton-pcg" and self.extrapolate > 0.0:  # (the host methods check on the host)
            self._guess_flag.zero_()
            wp.launch(ki._guess_inverted, dim=m.tet_count, inputs=[m.tet_indices, m.tet_rest_volume, self.x],
                      outputs=[self._guess_flag], device=dev)
            wp.launch(ki._guess_fallback, dim=m.vertex_count, inputs=[self._guess_flag, m.vertex_fixed, x],
                      outputs=[self.x], device=dev)

    def _mass_scale(self, h: float) -> float:
        return (1.0 + self.model.damping_rate * h) / (h * h)

    def _launch_energy(self, x, control: Control, h: float, with_grad: bool = True) -> None:
        """Per-element energies into :attr:`energy` and the gradient into :attr:`grad` at x."""
        wp = get_warp()
        m, dev = self.model, self.device
        ih = 1.0 / h
        ee, ef, et, en = self._e_views[:4]
        wp.launch(ki._edge_energy, dim=m.edge_count,
                  inputs=[m.edge_indices, m.edge_rest_length, m.edge_k0, m.edge_damping, self.c_edge, ih, x],
                  outputs=[ee, self.slots], device=dev)
        wp.launch(ki._face_energy, dim=m.face_count,
                  inputs=[m.face_indices, m.face_rest_area, m.face_k, m.face_damping, self.c_face, ih,
                          2 * m.edge_count, x],
                  outputs=[ef, self.slots], device=dev)
        wp.launch(ki._tet_energy, dim=m.tet_count,
                  inputs=[m.tet_indices, m.tet_rest_volume, m.tet_k, m.tet_damping, self.c_tet,
                          m.tet_rest_inverse, m.tet_shear_k, m.tet_shear_damping, self.g_tet, ih,
                          2 * m.edge_count + 3 * m.face_count, x],
                  outputs=[et, self.slots, self.c_tet_trial], device=dev)
        wp.launch(ki._node_energy, dim=m.vertex_count,
                  inputs=[m.vertex_mass, m.vertex_fixed, m.vertex_hold_stiffness, self._mass_scale(h), self.z,
                          self.targets, control.external_force, x],
                  outputs=[en, self.grad], device=dev)
        pool = self._pool
        if pool.count:
            wp.launch(ki._spring_energy, dim=pool.count, inputs=[pool.sets, pool.set_index, pool.local, x],
                      outputs=[self._e_views[4], pool.grad], device=dev)
        if not with_grad:
            return
        wp.launch(ki._gather_free, dim=m.vertex_count,
                  inputs=[self.nodes, m.node_slot_start, m.node_slots, m.vertex_fixed, self.slots],
                  outputs=[self.grad], device=dev)
        if pool.count:
            wp.launch(ki._gather_free, dim=len(pool.group_nodes),
                      inputs=[pool.group_nodes, pool.group_start, pool.group_order, m.vertex_fixed, pool.grad],
                      outputs=[self.grad], device=dev)

    def _launch_sums(self, values, partial, first_slot: int) -> None:
        """Each row of ``values`` (rows, energy entries) summed deterministically into
        ``totals[first_slot + row]``, through ``partial`` (rows, chunks)."""
        wp = get_warp()
        wp.launch(ki._chunk_sums_rows, dim=partial.shape, inputs=[values, self._chunk], outputs=[partial],
                  device=self.device)
        wp.launch(ki._final_sums_rows, dim=partial.shape[0], inputs=[partial, first_slot], outputs=[self.totals],
                  device=self.device)

    def _launch_hessian(self, x, h: float, slack=None) -> None:
        """PSD Hessian blocks at x summed into :attr:`block_values` (fixed rows / columns: identity);
        ``slack`` [m]: one-sided springs slack by less than this keep their block (the factorised
        model of the CPU L-BFGS), 0 for the exact Hessian."""
        wp = get_warp()
        m, dev = self.model, self.device
        if not isinstance(slack, wp.array):  # a host number: into the host slack array
            self._host_slack.fill_(float(slack or 0.0))
            slack = self._host_slack
        ih = 1.0 / h
        o = self._block_offsets
        wp.launch(ki._edge_hessian, dim=m.edge_count,
                  inputs=[m.edge_indices, m.edge_rest_length, m.edge_k0, m.edge_damping, self.c_edge, ih, x],
                  outputs=[self.block_slots], device=dev)
        wp.launch(ki._face_hessian, dim=m.face_count,
                  inputs=[m.face_indices, m.face_rest_area, m.face_k, m.face_damping, ih, int(o[1]), x],
                  outputs=[self.block_slots], device=dev)
        wp.launch(ki._tet_hessian, dim=m.tet_count,
                  inputs=[m.tet_indices, m.tet_rest_volume, m.tet_k, m.tet_damping, m.tet_rest_inverse,
                          m.tet_shear_k, m.tet_shear_damping, ih, int(o[2]), x],
                  outputs=[self.block_slots], device=dev)
        wp.launch(ki._node_hessian, dim=m.vertex_count,
                  inputs=[m.vertex_mass, m.vertex_hold_stiffness, self._mass_scale(h), int(o[3])],
                  outputs=[self.block_slots], device=dev)
        pool = self._pool
        if pool.count:
            wp.launch(ki._spring_hessian, dim=pool.count,
                      inputs=[pool.sets, pool.set_index, pool.local, slack, int(o[4]), x],
                      outputs=[self.block_slots], device=dev)
        wp.launch(ki._gather_blocks, dim=self.block_count,
                  inputs=[self.block_start, self.block_order, self.block_row, self.block_col, m.vertex_fixed,
                          self.block_slots],
                  outputs=[self.block_values], device=dev)

    def _finish(self, state_in: State, state_out: State) -> None:
        wp = get_warp()
        wp.copy(state_out.prev_positions, state_in.positions)
        wp.copy(state_out.positions, self.x)
        state_out.assign_stage_data(state_in)  # what the stages carry (muscle geometry, jaw carry)
        wp.launch(ki._advance_counter, dim=1, inputs=[], outputs=[self.step_counter], device=self.device)
        self._launch_guard(state_out)

    # ------------------------------------------------------------------------------ step
    def step(self, state_in: State, state_out: State, control: Control, dt: float) -> None:
        """Advance one step of ``dt`` [s] from ``state_in`` into ``state_out`` (different buffers).

        ``"newton-pcg"`` allocates nothing and never reads back to the host (capturable in a
        CUDA graph); the CPU methods read the Warp arrays as zero-copy NumPy views.

        Raises:
            InputError: ``dt`` not a positive finite number, or the same state buffers.
        """
        check_step_args(state_in, state_out, dt)
        h = float(dt)
        t0 = time.perf_counter()
        self._begin(state_in, control, h)
        self.timings["prepare"] += time.perf_counter() - t0
        if self.method == "newton-pcg":
            self._step_pcg(control, h)
        else:
            self._step_host(state_in, control, h)
        self._finish(state_in, state_out)
        if not self.adaptive:
            self._host_total += self.last_iterations

    @property
    def total_iterations(self) -> int:
        """(Quasi-)Newton iterations of all steps so far (a device read with the adaptive
        ``newton-pcg``, whose count lives on the device; a fixed count is counted on the host,
        so steps replayed from a CUDA graph are not)."""
        return self._host_total + (int(self._newton_total.numpy()[0]) if self.adaptive else 0)

    # ------------------------------------------------------------------------------ device method
    def _step_pcg(self, control: Control, h: float) -> None:
        wp = get_warp()
        if not self.adaptive:
            self._launch_newton_start()
            for it in range(self.iterations):
                if it > 0:
                    for st in self._refreshers:  # the fibre cosine and the contacts at the current iterate
                        st.refresh(self.model, self.x, control)
                self._pcg_iteration(control, h)
                self._launch_continue()  # (its slack rule; the count is fixed)
            self.last_iterations = self.iterations
            return
        capturing = self.device.is_cuda and self.device.is_capturing
        if capturing and not wp.is_conditional_graph_supported():
            raise SimulationError("the adaptive newton-pcg needs CUDA 12.4+ (conditional graph nodes) to run in a "
                                  "CUDA graph; pass iterations=k for a fixed count")
        count = 0
        for r in range(self.rounds if self._round_refreshers else 1):
            if r > 0:  # the contacts detected again at this round's start (outside the loop: it allocates)
                for st in self._round_refreshers:
                    st.refresh(self.model, self.x, control)
            self._launch_newton_start()
            wp.capture_while(self._newton_cond, self._pcg_adaptive_iteration, control=control, h=h)
            if not capturing:
                count += int(self._newton_count.numpy()[0])
        if not capturing:
            self.last_iterations = count

    def _launch_newton_start(self) -> None:
        get_warp().launch(ki._newton_start, dim=1, inputs=[],
                          outputs=[self._newton_count, self._largest_step, self._newton_cond, self._slack],
                          device=self.device)

    def _pcg_adaptive_iteration(self, control: Control, h: float) -> None:
        """One Newton iteration, its convergence test, then the fibre cosine at the new iterate
        (the loop's body; measured: with the cosine held over a round instead, laugh took 10.3
        iterations per frame instead of 6.6, and frames of its hold up to 70)."""
        self._pcg_iteration(control, h)
        self._launch_continue()
        for st in self._loop_refreshers:  # for the next iteration (after the last one: spent, it is cheap)
            st.refresh(self.model, self.x, control)

    def _launch_continue(self) -> None:
        """The loop's condition and the next iteration's Hessian slack (from the step's size)."""
        wp = get_warp()
        wp.launch(ki._newton_continue, dim=1, inputs=[self.tolerance, self.max_iterations, self.contact_slack, self.t_step],
                  outputs=[self._newton_count, self._largest_step, self._newton_cond, self._newton_total, self._slack],
                  device=self.device)

    def _pcg_iteration(self, control: Control, h: float) -> None:
        """One Newton iteration at :attr:`x`: Hessian and gradient, CG, line search on the device.

        The line search evaluates its four trials in one pass (:func:`~.kernels_implicit._trial_energies`:
        every element, node and spring at every trial), every stage's springs are one pool and
        a CG iteration is one launch: 36 launches per Newton iteration, where a launch per trial,
        per spring set and per CG phase took ~140 (the level-0 frame is launch bound)."""
        wp = get_warp()
        m, dev, n, pool = self.model, self.device, self.model.vertex_count, self._pool
        self._launch_energy(self.x, control, h)
        self._launch_sums(self._energy_row, self.partial, 0)
        self._launch_hessian(self.x, h, self._slack)  # 0 (exact) unless the last line search failed
        wp.launch(ki._newton_system, dim=n, inputs=[self.diag_block, self.block_values, self.grad],
                  outputs=[self.inv_diag, self.rhs], device=dev)
        self._launch_cg()
        wp.launch(ki._trial_energies, dim=self.energy.shape[0],
                  inputs=[m.edge_indices, m.edge_rest_length, m.edge_k0, m.edge_damping, self.c_edge,
                          m.face_indices, m.face_rest_area, m.face_k, m.face_damping, self.c_face,
                          m.tet_indices, m.tet_rest_volume, m.tet_k, m.tet_damping, self.c_tet,
                          m.tet_rest_inverse, m.tet_shear_k, m.tet_shear_damping, self.g_tet,
                          m.vertex_mass, m.vertex_fixed, m.vertex_hold_stiffness, self._mass_scale(h), self.z,
                          self.targets, control.external_force, pool.sets, pool.set_index, pool.local,
                          1.0 / h, self.x, self.direction],
                  outputs=[self.trial_energy], device=dev)
        self._launch_sums(self.trial_energy, self.trial_partial, 1)
        wp.launch(ki._select_step, dim=1, inputs=[self.totals, _LINE_SEARCH_TRIALS], outputs=[self.t_step],
                  device=dev)
        wp.launch(ki._take_step, dim=n, inputs=[m.vertex_fixed, self.direction, self.t_step],
                  outputs=[self.x, self._largest_step], device=dev)

    # ------------------------------------------------------------------------------ host methods
    def _host_eval(self, x64: np.ndarray, control: Control, h: float) -> tuple[float, np.ndarray, float]:
        """Energy, gradient (3n,) and the energy's float32 rounding scale at positions x64 (n, 3);
        :attr:`_inverted` tells whether a tet is inverted there."""
        t0 = time.perf_counter()
        self.x.numpy()[:] = x64
        self._launch_energy(self.x, control, h)
        e = self.energy.numpy()
        g = self.grad.numpy().astype(np.float64).ravel()
        total = float(np.sum(e, dtype=np.float64))
        noise = 4.0 * 1.2e-7 * float(np.sum(np.abs(e), dtype=np.float64)) + 1e-30
        self._inverted = bool(self.c_tet_trial.numpy().min() <= -1.0)
        self.timings["gradient"] += time.perf_counter() - t0
        return total, g, noise

    def _host_factor(self, x64: np.ndarray, h: float):
        import scipy.sparse as sp

        t0 = time.perf_counter()
        self.x.numpy()[:] = x64
        self._launch_hessian(self.x, h, self.contact_slack if self.method == "lbfgs" else 0.0)
        self._contacts_factored = self._contact_set(x64)
        n = self.model.vertex_count
        vals = self.block_values.numpy().astype(np.float64)
        A = sp.bsr_matrix((vals, self._bsr_columns, self._bsr_offsets), shape=(3 * n, 3 * n))
        solve = _factorize(A, self.backend)
        self._clear_history()
        self.factorizations += 1
        self._excess = 0
        self.timings["factor"] += time.perf_counter() - t0
        return solve

    def _line_search(self, x64, d, e, g, noise, control, h):
        """Backtracking from t = 1 on the energy (Armijo, within float32 rounding), rejecting any
        step that inverts a tet; returns (t, x, e, g, noise) at the accepted point (t = 0: none)."""
        gd = _dot(g, d)
        t = 1.0
        for _ in range(12):
            xt = x64 + t * d.reshape(-1, 3)
            et, gt, nt = self._host_eval(xt, control, h)
            if et <= e + 1e-4 * t * gd + noise and not self._inverted:
                return t, xt, et, gt, nt
            t *= 0.5
        self._host_eval(x64, control, h)  # leave the buffers at the current point
        return 0.0, x64, e, g, noise

    def _step_host(self, state_in: State, control: Control, h: float) -> None:
        if self.extrapolate > 0.0:
            self._host_eval(self.x.numpy().astype(np.float64), control, h)
            if self._inverted:  # the extrapolated guess inverts a tet: start from x_n instead
                get_warp().launch(ki._initial_guess, dim=self.model.vertex_count,
                                  inputs=[self.model.vertex_fixed, 0.0, self.targets, state_in.positions,
                                          state_in.prev_positions],
                                  outputs=[self.x], device=self.device)
        x64 = self.x.numpy().astype(np.float64)
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
                cs = self._contact_set(x64)
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
            if outer == updates + extra or (outer >= updates and not any(s_.one_sided for s_ in self.springs)):
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
        self.x.numpy()[:] = x64
        self.last_iterations = total

    def _contact_set(self, x64: np.ndarray) -> np.ndarray:
        """Which one-sided springs are compressed or within :attr:`contact_slack` of it at x64,
        all sets concatenated, shape (total,), bool."""
        out = [np.zeros(0, bool)]
        for s in self.springs:
            if not s.one_sided:
                continue
            sp_ = s.springs
            r = x64[s.node_host] - sp_.point.numpy()
            if sp_.axis is not None:
                gap = np.einsum("ij,ij->i", r, sp_.axis.numpy())
            else:
                gap = np.linalg.norm(r, axis=1) - sp_.rest_length.numpy()
            out.append((sp_.stiffness.numpy() > 0) & (gap < self.contact_slack))
        return np.concatenate(out)

    def _refresh_springs(self, x64: np.ndarray, control: Control) -> tuple[bool, bool]:
        """Re-evaluate the refreshable springs at x64; whether they changed: ``(springs,
        contacts)``, a stiffness by more than ``spring_tolerance`` of the largest, and a one-sided
        (contact) spring's compression at x64 grown by more than ``contact_tolerance`` (a contact
        found, or its surface moved toward the node)."""
        if not self._refreshers:
            return False, False

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

        before = [snap(s) for s in self.springs]
        self.x.numpy()[:] = x64
        for st in self._refreshers:
            st.refresh(self.model, self.x, control)
        springs = contacts = False
        for s, (b, cb) in zip(self.springs, before):
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
                return k + 1, x64
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
                return k + 1, x64
        return its, x64

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
        import scipy.sparse as sp

        if isinstance(dt, bool) or not (isinstance(dt, (int, float, np.floating)) and np.isfinite(dt) and dt > 0.0):
            raise InputError(f"dt must be a positive number of seconds, got {dt!r}")
        h = float(dt)
        self._begin(state_in, control, h)
        if positions is not None:
            P = np.asarray(positions, dtype=np.float64)
            if P.shape != (self.model.vertex_count, 3) or not np.isfinite(P).all():
                raise InputError(f"positions: expected finite values of shape ({self.model.vertex_count}, 3), got {P.shape}")
            fixed = self.model.vertex_fixed.numpy() != 0
            P = P.copy()
            P[fixed] = self.targets.numpy()[fixed]
            self.x.assign(P.astype(np.float32))
        self._launch_energy(self.x, control, h)
        e = float(np.sum(self.energy.numpy(), dtype=np.float64))
        g = self.grad.numpy().astype(np.float64)
        if not hessian:
            return e, g
        self._launch_hessian(self.x, h)
        n = self.model.vertex_count
        H = sp.bsr_matrix((self.block_values.numpy().astype(np.float64), self._bsr_columns, self._bsr_offsets),
                          shape=(3 * n, 3 * n))
        return e, g, H

    def reset(self) -> None:
        """Back to the rest pose (targets, counter, guard) and to a fresh solver's step history: the
        curvature pairs and the factorisation go (a factorisation kept from a later state would
        steer the next steps' iterations, up to the tolerance, away from a fresh solver's)."""
        super().reset()
        self.last_iterations = 0
        self._clear_history()
        self._solve0 = self._h = self._contacts_factored = None
        self._excess, self._last_step_size = 0, 0.0

    def _advice(self) -> str:
        return "lower the activation or jaw speed, or take smaller steps"
