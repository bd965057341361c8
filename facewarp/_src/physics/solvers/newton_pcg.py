"""The device implicit solver: Newton iterations with preconditioned conjugate gradients, all on the device.

:class:`SolverDeviceNewtonPCG` minimises the :class:`~.incremental.IncrementalPotential` of a
backward Euler step (module doc of :mod:`.implicit`) by Newton iterations, each with a fixed
number (``linear_iterations``, 10 up to 10,000 nodes, growing with the square root of the node
count beyond: :func:`default_linear_iterations`) of block-Jacobi preconditioned conjugate-gradient
iterations on the block-sparse Hessian assembled by kernels, one launch per CG iteration (the
Chronopoulos-Gear form with the product fused into the update, :mod:`.kernels_linear`: about a
tenth of ``warp.optim.linear.cg``'s launches, the same iterates), and a backtracking line search
(t = 1, 1/2, ..., 1/128, all eight evaluated in one pass; a trial inverting a tet is never taken)
decided on the device (:mod:`.kernels_line_search`). The default on CUDA; it runs on the CPU too.

The Newton loop is adaptive: it runs until no free node moves more than ``tolerance`` (3e-5 m
from the simulator) in an iteration, at most ``max_iterations`` (12), as a ``wp.capture_while``
loop, so on CUDA a whole frame, loop included, is one CUDA graph with no host round trip
(:meth:`~.implicit.SolverImplicit.step` allocates nothing on this path). With a contact stage the
loop runs ``rounds`` (2) times, the contacts detected again between rounds: their BVH refit
allocates and may not be inside a graph's conditional node. A line search that finds no lower
energy (a direction from the exact Hessian that runs into a contact spring slack at x) is retried
once with the springs within ``contact_slack`` of closing in the Hessian, and never taken as
convergence. The first guess continues the previous step's motion (``extrapolate`` 0.5).

Measured at level 0 against the fully converged steps (``benchmarks/solver_accuracy.py --parts
pcg``; every FDP of the five Table 6.4 presets during attack, hold and release; on an H100):
within 0.03-0.25 mm at 3.8-6.9 Newton iterations per frame. ``iterations=k`` gives a fixed count
instead (the interactive mode): 3 stay within 0.32 mm, 2 and 1 miss the 0.5 mm on some presets
(0.6 and 1.9 mm, on the CPU). A level-0 frame is launch bound (H100: 381 frames/s adaptive, 522
with 3 iterations; ``benchmarks/physics_steps.py``): the line-search trials are one pass
(``_trial_energies``), every stage's springs one pooled launch (``_SpringPool``), a CG iteration
one launch, so a Newton iteration is 36 launches where it was ~140 (179 frames/s). Before the
exact Hessian, its retry and the extrapolated guess, the former fixed 3 x 50 missed by up to
2.2 mm (a lid sliding over the eyeball took steps too short to follow it).
"""

from __future__ import annotations

import numpy as np

from ...core.errors import InputError, SimulationError
from ...core.warp import get_warp
from ..model import Model
from ..state import Control, State
from . import kernels_line_search as kl
from . import kernels_linear as kli
from .implicit import _COMMON_OPTIONS, SolverImplicit, refuse_options

__all__ = ["SolverDeviceNewtonPCG", "default_linear_iterations"]

_LINE_SEARCH_TRIALS = 8  # device line search: t = 1, 1/2, ..., 1/128


def default_linear_iterations(node_count: int) -> int:
    """Conjugate-gradient iterations per Newton iteration of :class:`SolverDeviceNewtonPCG` for a
    mesh of ``node_count`` nodes: 10 up to 10,000 nodes, then ``10 sqrt(node_count / 10,000)`` rounded.

    The skin is a sheet: each level halves the edge length h and quarters the node count, the
    Hessian's condition number grows as h^-2, and the CG iterations that reach a given reduction as
    its square root, h^-1 ~ sqrt(node_count). Levels 0-3 of the default head (2,448 / 9,470 /
    36,930 / 146,450 nodes) get 10 / 10 / 19 / 38.
    """
    n = int(node_count)
    return 10 if n <= 10_000 else int(round(10.0 * np.sqrt(n / 10_000.0)))


class SolverDeviceNewtonPCG(SolverImplicit):
    """Backward Euler by Newton-PCG on the model's device (module doc); ``method="newton-pcg"``.

    :class:`~.implicit.SolverImplicit`'s ``stages``, ``tolerance`` and ``iterations`` apply too.

    Args:
        method: ``"newton-pcg"`` or None.
        max_iterations: At most this many Newton iterations per round of the adaptive loop
            (default 12: a bounded frame time; the thesis profile's stiff layer otherwise took up
            to 100 iterations in frames of the laugh's hold, the lip contacts chattering).
        extrapolate: the first guess's extrapolation (default 0.5: with the adaptive loop 1.0 took
            as many iterations).
        linear_iterations: Conjugate-gradient iterations per Newton iteration (default
            :func:`default_linear_iterations` of the node count: 10 up to 10,000 nodes, levels 0
            and 1. Measured per frame against the converged steps, every FDP of the five Table 6.4
            presets at level 0: 10 gave the errors of 20 (and 20 those of 50 and 200) at about 0.3
            more Newton iterations per frame; on an H100 at level 0, 3 Newton iterations, a frame
            took a quarter less time than with 20. At level 2 (36,930 nodes) 10 left the adaptive
            loop at its cap, 22.5 Newton iterations per frame of the laugh's attack on the CPU;
            20 took 6.6 and 40 took 7.9).
        rounds: With a contact stage the adaptive Newton loop runs this many times per step, the
            contacts detected again before each (default 2: solve, detect at the solution, solve
            again); the fibre cosine is refreshed after every iteration. No rounds with a fixed
            ``iterations``.

    Attributes:
        contact_slack: After a line search that found no lower energy, one-sided (contact)
            springs within this distance [m] of closing enter the next iteration's Hessian
            (3e-4). Otherwise the Newton model is the exact Hessian: with the slack springs in it,
            a lid sliding over the eyeball within 0.3 mm of it took steps too short to follow (its
            FDP 3.13 lagged 1.7 mm behind the converged solution in the sad preset's attack;
            0.15 mm without).
        A: The Hessian as a ``warp.sparse`` BSR matrix (its values are summed in place each
            Newton iteration; users and tests can multiply with it, ``bsr_mv``).
    """

    _OPTIONS = _COMMON_OPTIONS + ("linear_iterations", "rounds")
    method = "newton-pcg"

    def __init__(self, model: Model, *, method: str | None = None, stages=(), tolerance: float = 1e-5,
                 max_iterations: int = 12, iterations: int | None = None, extrapolate: float = 0.5,
                 linear_iterations: int | None = None, rounds: int = 2, **options):
        refuse_options(type(self), options)
        if method not in (None, "newton-pcg"):
            raise InputError(f"method: {type(self).__name__} runs 'newton-pcg', got {method!r}"
                             " (SolverHostImplicit runs 'lbfgs' and 'newton')")
        super().__init__(model, stages=stages, tolerance=tolerance, max_iterations=max_iterations,
                         iterations=iterations, extrapolate=extrapolate)
        if linear_iterations is None:  # a Model of N heads: its Hessian is N blocks, each conditioned as its head
            starts = getattr(model, "head_node_start", None)
            largest = int(np.diff(np.asarray(starts)).max()) if starts is not None and len(starts) > 1 else 0
            linear_iterations = default_linear_iterations(largest or model.vertex_count)
        if not (isinstance(linear_iterations, (int, np.integer)) and linear_iterations >= 1):
            raise InputError(f"linear_iterations: expected a whole number >= 1, got {linear_iterations!r}")
        if not (isinstance(rounds, (int, np.integer)) and rounds >= 1):
            raise InputError(f"rounds: expected a whole number >= 1, got {rounds!r}")
        self.linear_iterations = int(linear_iterations)
        self.rounds = int(rounds)
        self.adaptive = self.iterations is None
        # the Newton loop (a conditional graph node) may not allocate: the stages whose refresh
        # does (the contact BVH refit) are refreshed between its rounds instead
        self._round_refreshers = [st for st in self._refreshers if getattr(st, "allocates_on_refresh", False)]
        self._loop_refreshers = [st for st in self._refreshers if st not in self._round_refreshers]
        self._build_buffers()

    def _build_buffers(self):
        import warp.sparse as wsp

        wp = get_warp()
        ip = self.incremental
        dev, n = self.device, self.model.vertex_count
        A = wsp.bsr_zeros(n, n, block_type=wp.mat33, device=dev)
        rows = np.repeat(np.arange(n), np.diff(ip.bsr_offsets)).astype(np.int32)
        wsp.bsr_set_from_triplets(A, wp.array(rows, dtype=wp.int32, device=dev),
                                  wp.array(ip.bsr_columns, dtype=wp.int32, device=dev),
                                  wp.array(np.tile(np.eye(3, dtype=np.float32), (ip.block_count, 1, 1)),
                                           dtype=wp.mat33, device=dev), prune_numerical_zeros=False)
        if not (np.array_equal(A.offsets.numpy()[: n + 1], ip.bsr_offsets)
                and np.array_equal(A.columns.numpy()[: ip.block_count], ip.bsr_columns)):
            raise RuntimeError("warp.sparse ordered the Hessian blocks differently from the solver's pattern")
        self.A = A
        ip.use_block_values(A.values)  # the gather writes straight into the matrix
        self.inv_diag = wp.zeros(n, dtype=wp.mat33, device=dev)
        self.rhs = wp.zeros(n, dtype=wp.vec3, device=dev)
        self.direction = wp.zeros(n, dtype=wp.vec3, device=dev)
        vec = lambda: wp.zeros(n, dtype=wp.vec3, device=dev)  # noqa: E731
        self._cg_buffers = ((vec(), vec(), vec()), (vec(), vec(), vec()), vec(), vec())  # (r, s, w) x 2, u, p
        self._cg_sums = wp.zeros((2 * self.linear_iterations + 2, kli.CG_SLOTS), dtype=wp.float64, device=dev)
        self._cg_scalars = wp.zeros((self.linear_iterations, 3), dtype=wp.float64, device=dev)
        self.t_step = wp.zeros(1, dtype=float, device=dev)
        self._newton_count = wp.zeros(1, dtype=wp.int32, device=dev)
        self._newton_cond = wp.zeros(1, dtype=wp.int32, device=dev)
        self._largest_step = wp.zeros(2, dtype=float, device=dev)  # (max t |d_i|, max |d_i|) [m]
        self._newton_total = wp.zeros(1, dtype=wp.int64, device=dev)
        self._slack = wp.zeros(1, dtype=float, device=dev)  # the Hessian slack [m], changed on the device
        self._guess_flag = wp.zeros(1, dtype=wp.int32, device=dev)  # the extrapolated guess inverts a tet
        # deterministic sums of the energy row and the line search's trials (rows t = 2^-j), in
        # the energy array's layout: chunks of about sqrt(entries)
        size = int(ip.energy.shape[0])
        self._chunk = max(32, int(np.ceil(np.sqrt(size))))  # entries per partial sum
        self._chunks = max(1, -(-size // self._chunk))
        self._energy_row = ip.energy.reshape((1, size))  # a view: summed as one row
        self.partial = wp.zeros((1, self._chunks), dtype=wp.float64, device=dev)
        self.totals = wp.zeros(1 + _LINE_SEARCH_TRIALS, dtype=wp.float64, device=dev)
        self.trial_energy = wp.zeros((_LINE_SEARCH_TRIALS, size), dtype=float, device=dev)
        self.trial_partial = wp.zeros((_LINE_SEARCH_TRIALS, self._chunks), dtype=wp.float64, device=dev)

    # ------------------------------------------------------------------------------ device work
    def _begin(self, state_in: State, control: Control, h: float) -> None:
        super()._begin(state_in, control, h)
        if self.extrapolate > 0.0:  # the extrapolated guess falls back to x_n where it inverts a tet
            wp = get_warp()
            m, x = self.model, self.incremental.x
            self._guess_flag.zero_()
            wp.launch(kl._guess_inverted, dim=m.tet_count, inputs=[m.tet_indices, m.tet_rest_volume, x],
                      outputs=[self._guess_flag], device=self.device)
            wp.launch(kl._guess_fallback, dim=m.vertex_count, inputs=[m.vertex_fixed, self._guess_flag,
                                                                      state_in.positions],
                      outputs=[x], device=self.device)

    def _launch_sums(self, values, partial, first_slot: int) -> None:
        """Each row of ``values`` (rows, energy entries) summed deterministically into
        ``totals[first_slot + row]``, through ``partial`` (rows, chunks)."""
        wp = get_warp()
        wp.launch(kl._chunk_sums_rows, dim=partial.shape, inputs=[self._chunk, values], outputs=[partial],
                  device=self.device)
        wp.launch(kl._final_sums_rows, dim=partial.shape[0], inputs=[first_slot, partial], outputs=[self.totals],
                  device=self.device)

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
        wp.launch(kli._zero_2d, dim=sums.shape, inputs=[], outputs=[sums], device=dev)  # (a kernel node)
        wp.launch(kli._cg_start, dim=n, inputs=[inv, self.rhs], outputs=[x, r0, u, p, s0, sums], device=dev)
        wp.launch(kli._cg_matvec, dim=n, inputs=[A.offsets, A.columns, A.values, 1, u], outputs=[w0, sums], device=dev)
        bufs = ((r0, s0, w0), (r1, s1, w1))
        for k in range(self.linear_iterations):
            (ri, si, wi), (ro, so, wo) = bufs[k % 2], bufs[(k + 1) % 2]
            wp.launch(kli._cg_iteration, dim=n,
                      inputs=[A.offsets, A.columns, A.values, inv, k, int(k == self.linear_iterations - 1), sums,
                              scalars, ri, si, wi],
                      outputs=[x, p, u, ro, so, wo], device=dev)

    # ------------------------------------------------------------------------------ step
    def _solve(self, state_in: State, control: Control, h: float) -> None:
        wp = get_warp()
        x = self.incremental.x
        if not self.adaptive:
            self._launch_newton_start()
            for it in range(self.iterations):
                if it > 0:
                    for st in self._refreshers:  # the fibre cosine and the contacts at the current iterate
                        st.refresh(self.model, x, control)
                self._iteration(control, h)
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
                    st.refresh(self.model, x, control)
            self._launch_newton_start()
            wp.capture_while(self._newton_cond, self._adaptive_iteration, control=control, h=h)
            if not capturing:
                count += int(self._newton_count.numpy()[0])
        if not capturing:
            self.last_iterations = count

    @property
    def total_iterations(self) -> int:
        """Newton iterations of all steps so far (a device read with the adaptive loop, whose count
        lives on the device; a fixed count is counted on the host, so steps replayed from a CUDA
        graph are not)."""
        return self._host_total + (int(self._newton_total.numpy()[0]) if self.adaptive else 0)

    def _launch_newton_start(self) -> None:
        get_warp().launch(kl._newton_start, dim=1, inputs=[],
                          outputs=[self._newton_count, self._largest_step, self._newton_cond, self._slack],
                          device=self.device)

    def _adaptive_iteration(self, control: Control, h: float) -> None:
        """One Newton iteration, its convergence test, then the fibre cosine at the new iterate
        (the loop's body; measured: with the cosine held over a round instead, laugh took 10.3
        iterations per frame instead of 6.6, and frames of its hold up to 70)."""
        self._iteration(control, h)
        self._launch_continue()
        for st in self._loop_refreshers:  # for the next iteration (after the last one: spent, it is cheap)
            st.refresh(self.model, self.incremental.x, control)

    def _launch_continue(self) -> None:
        """The loop's condition and the next iteration's Hessian slack (from the step's size)."""
        get_warp().launch(kl._newton_continue, dim=1,
                          inputs=[self.tolerance, self.max_iterations, self.contact_slack, self.t_step],
                          outputs=[self._newton_count, self._largest_step, self._newton_cond, self._newton_total,
                                   self._slack],
                          device=self.device)

    def _iteration(self, control: Control, h: float) -> None:
        """One Newton iteration at the iterate x: Hessian and gradient, CG, line search on the device.

        The line search evaluates its eight trials in one pass (:func:`~.kernels_line_search._trial_energies`:
        every element, node and spring at every trial), every stage's springs are one pool and
        a CG iteration is one launch: 36 launches per Newton iteration, where a launch per trial,
        per spring set and per CG phase took ~140 (the level-0 frame is launch bound)."""
        wp = get_warp()
        ip = self.incremental
        m, dev, n, x = self.model, self.device, self.model.vertex_count, ip.x
        ip.launch_energy(x, control, h)
        self._launch_sums(self._energy_row, self.partial, 0)
        ip.launch_hessian(x, h, self._slack)  # 0 (exact) unless the last line search failed
        wp.launch(kli._newton_system, dim=n, inputs=[ip.diag_block, ip.block_values, ip.grad],
                  outputs=[self.inv_diag, self.rhs], device=dev)
        self._launch_cg()
        wp.launch(kl._trial_energies, dim=ip.energy.shape[0],
                  inputs=[ip.edge_terms, ip.face_terms, ip.tet_terms, ip.node_terms, ip.spring_terms,
                          ip.mass_scale(h), 1.0 / h, ip.c_edge, ip.c_face, ip.c_tet, ip.g_tet, ip.z, self.targets,
                          control.external_force, x, self.direction],
                  outputs=[self.trial_energy], device=dev)
        self._launch_sums(self.trial_energy, self.trial_partial, 1)
        wp.launch(kl._select_step, dim=1, inputs=[_LINE_SEARCH_TRIALS, self.totals], outputs=[self.t_step],
                  device=dev)
        wp.launch(kl._take_step, dim=n, inputs=[m.vertex_fixed, self.direction, self.t_step],
                  outputs=[x, self._largest_step], device=dev)
