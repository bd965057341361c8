"""The incremental potential of one backward Euler step, on the device: what every implicit solver
of the skin model minimises (:class:`~.host_implicit.SolverHostImplicit`,
:class:`~.newton_pcg.SolverDeviceNewtonPCG`).

    Phi(x) = sum_i mu_i / 2 |x_i - z_i|^2 + holds + element energies (Eq. 6.4.4-6.4.8) + springs

(the terms in :mod:`.kernels_potential`'s module doc; the float64 NumPy reference of the same
terms is :mod:`facewarp._src.physics.potential`). :class:`IncrementalPotential` owns the arrays of
one step (the dashpots' start constraints, the inertial target z, the iterate x, per-term
energies, the gradient, Hessian block slots and the BSR pattern they sum into), the stages'
springs as one pool, and launches the energy / gradient and Gauss-Newton Hessian kernels
(:mod:`.kernels_potential`, :mod:`.kernels_hessian`). Its host evaluation (energy, gradient and
whether a tet inverted, at float64 positions) serves the host solver's line search and every
solver's :meth:`~.implicit.SolverImplicit.potential`.
"""

from __future__ import annotations

import numpy as np

from ...core.warp import get_warp
from ..model import Model
from ..state import Control, State
from . import kernels_hessian as kh
from . import kernels_line_search as kl
from . import kernels_potential as kp

__all__ = ["IncrementalPotential"]

wp = get_warp()  # the kernel modules above import Warp already


_PATTERNS: dict = {}
_PATTERN_CACHE = 8


def _block_pattern(code, n: int):
    """The Hessian's block pattern of the block codes ``row * n + col`` (k,), int64: the distinct
    blocks ascending (b,) and each block's slots grouped (start (b + 1,), order (k,)). Heads of one
    topology (:class:`~facewarp.FaceBatch`) have the same codes: the last few patterns are kept,
    known by the codes' hash (the sort is most of a head's set-up)."""
    import hashlib

    key = (n, len(code), hashlib.blake2b(np.ascontiguousarray(code).tobytes(), digest_size=16).digest())
    hit = _PATTERNS.get(key)
    if hit is None:
        uniq, inv = np.unique(code, return_inverse=True)
        _, start, order = _group_indices(inv, np.arange(len(uniq)))
        hit = (uniq, start, order)
        if len(_PATTERNS) >= _PATTERN_CACHE:
            _PATTERNS.pop(next(iter(_PATTERNS)))
        _PATTERNS[key] = hit
    return hit


def _group_indices(keys, groups=None):
    """:func:`~facewarp._src.physics.arrays.group_indices` (the same CSR grouping), here so that the
    solver's construction reads the Model without calling back into it."""
    keys = np.asarray(keys, dtype=np.int64)
    groups = np.unique(keys) if groups is None else np.asarray(groups, dtype=np.int64)
    order = np.argsort(keys, kind="stable")
    start = np.searchsorted(keys[order], groups, side="left")
    return groups, np.r_[start, len(keys)], order


class _SpringSet:
    """One stage's springs (host side: the contact and fibre-cosine tests of the host solver)."""

    def __init__(self, springs):
        self.springs = springs
        self.node_host = springs.node.numpy().astype(np.int64)
        self.count = len(self.node_host)
        self.axis = springs.axis is not None
        self.one_sided = int(bool(getattr(springs, "one_sided", False)))


class _SpringPool:
    """Every stage's springs as one pool of ``count`` springs, evaluated in one launch per pass:
    a :class:`~.kernels_potential.SpringSet` per set (the stage's own arrays, read in place), the
    set and local index of every pooled spring, its gradient entries and their fixed-order gather
    per node (deterministic sums)."""

    def __init__(self, sets: list, device):
        dummy_f = wp.zeros(1, dtype=float, device=device)
        dummy_v = wp.zeros(1, dtype=wp.vec3, device=device)
        descs = []
        for s in sets:
            sp = s.springs
            d = kp.SpringSet()
            d.node, d.point, d.stiffness = sp.node, sp.point, sp.stiffness
            d.rest_length = dummy_f if sp.rest_length is None else sp.rest_length
            d.axis = dummy_v if sp.axis is None else sp.axis
            d.is_axis, d.one_sided = int(s.axis), s.one_sided
            descs.append(d)
        self._dummies = (dummy_f, dummy_v)
        counts = [s.count for s in sets]
        self.count = int(sum(counts))
        i32 = lambda a: wp.array(np.ascontiguousarray(a, np.int32), dtype=wp.int32, device=device)  # noqa: E731
        self.sets = wp.array(descs, dtype=kp.SpringSet, device=device) if descs else None
        self.set_index = i32(np.repeat(np.arange(len(sets)), counts))
        self.local = i32(np.concatenate([np.arange(c) for c in counts]) if sets else np.zeros(0))
        node = np.concatenate([s.node_host for s in sets]) if sets else np.zeros(0, np.int64)
        nodes_u, start, order = _group_indices(node)
        self.group_nodes, self.group_start, self.group_order = i32(nodes_u), i32(start), i32(order)
        self.grad = wp.zeros(self.count, dtype=wp.vec3, device=device)


class _Launch:
    """A plain launch with fixed arguments (the CUDA path of the recorded ones: graph capture
    records plain launches)."""

    def __init__(self, kernel, dim, inputs, outputs, device):
        self.args = (kernel,)
        self.kw = dict(dim=dim, inputs=inputs, outputs=outputs, device=device)

    def launch(self) -> None:
        wp.launch(*self.args, **self.kw)


class IncrementalPotential:
    """Phi of one backward Euler step of ``model`` with the stages' ``springs``, on the model's device.

    Args:
        model: the tissue :class:`Model`.
        springs: the stages' :class:`~facewarp._src.physics.springs.Springs` (empty sets dropped).
        targets: the solver's targets of fixed / held nodes [m], shape (vertex_count,), wp.vec3
            (read, not copied).

    Attributes:
        springs: the non-empty spring sets (host views: nodes, kind).
        pool: every spring set as one pool (one launch per pass).
        x: The iterate [m], shape (vertex_count,), wp.vec3.
        z: The inertial target [m] of the step, shape (vertex_count,), wp.vec3.
        grad: dPhi/dx [N] at the last :meth:`launch_energy`, shape (vertex_count,), wp.vec3.
        energy: Per-term energies [J]: edges, faces, tets, nodes, then the pooled springs,
            shape (term_count,), float32.
        c_edge, c_face, c_tet: Constraints at the step's start (the dashpots' C_n), float32.
        g_tet: Green strain at the step's start, shape (tet_count,), wp.mat33.
        c_tet: Volume constraints at the last :meth:`launch_energy` (C <= -1: inverted).
        block_values: The Hessian's BSR block values, shape (block_count,), wp.mat33 (a solver may
            point it at its own matrix's values, :meth:`use_block_values`).
        block_count, bsr_offsets, bsr_columns, diag_block: the BSR pattern (host, int32).
    """

    def __init__(self, model: Model, springs, targets):
        m, dev, n = model, model.device, model.vertex_count
        self.model = model
        self.device = dev
        self.targets = targets
        self.springs = [_SpringSet(sp_) for sp_ in springs if sp_.node.shape[0] > 0]
        self.pool = _SpringPool(self.springs, dev)
        self._energy_cmd_cache = {}  # (x, external force, h) -> the recorded launches of launch_energy
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
        sizes = [m.edge_count, m.face_count, m.tet_count, n, self.pool.count]
        off = np.r_[0, np.cumsum(sizes)]
        self.energy = wp.zeros(int(off[-1]), dtype=float, device=dev)
        self._e_views = [self.energy[int(off[i]):int(off[i + 1])] if sizes[i] else None for i in range(len(sizes))]
        self._build_blocks()
        self._build_terms()

    # ------------------------------------------------------------------------------ Hessian pattern
    def _build_blocks(self):
        """Block slots of every element, node and spring, and the BSR pattern they sum into."""
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
        self._block_offsets = np.cumsum([0, 4 * len(E), 9 * len(F), 16 * len(T), n, self.pool.count])
        code = rows * n + cols
        uniq, start, order = _block_pattern(code, n)
        nb = len(uniq)
        brow, bcol = uniq // n, uniq % n
        self.block_count = nb
        self.bsr_offsets = np.searchsorted(brow, np.arange(n + 1)).astype(np.int32)
        self.bsr_columns = bcol.astype(np.int32)
        i32 = lambda a: wp.array(np.ascontiguousarray(a, np.int32), dtype=wp.int32, device=dev)  # noqa: E731
        self.block_slots = wp.zeros(len(code), dtype=wp.mat33, device=dev)
        self.block_start = i32(start)
        self.block_order = i32(order)
        self.block_row = i32(brow)
        self.block_col = i32(bcol)
        self.diag_block = i32(np.searchsorted(uniq, np.arange(n) * n + np.arange(n)))
        self.block_values = wp.zeros(nb, dtype=wp.mat33, device=dev)

    def use_block_values(self, values) -> None:
        """Sum the Hessian into ``values`` (shape (block_count,), wp.mat33: e.g. a
        ``warp.sparse`` matrix's values with this pattern) instead of the own array."""
        self.block_values = values

    def _build_terms(self):
        """The model's arrays grouped per term kind, for the one-pass trial energies."""
        m, pool = self.model, self.pool
        self.edge_terms = kl.EdgeTerms()
        self.edge_terms.indices, self.edge_terms.rest_length = m.edge_indices, m.edge_rest_length
        self.edge_terms.k0, self.edge_terms.damping = m.edge_k0, m.edge_damping
        self.face_terms = kl.FaceTerms()
        self.face_terms.indices, self.face_terms.rest_area = m.face_indices, m.face_rest_area
        self.face_terms.k, self.face_terms.damping = m.face_k, m.face_damping
        t = self.tet_terms = kl.TetTerms()
        t.indices, t.rest_volume, t.k, t.damping = m.tet_indices, m.tet_rest_volume, m.tet_k, m.tet_damping
        t.rest_inverse, t.shear_k, t.shear_damping = m.tet_rest_inverse, m.tet_shear_k, m.tet_shear_damping
        self.node_terms = kl.NodeTerms()
        self.node_terms.mass, self.node_terms.fixed = m.vertex_mass, m.vertex_fixed
        self.node_terms.hold_stiffness = m.vertex_hold_stiffness
        self.spring_terms = kl.SpringPool()
        if pool.sets is not None:
            self.spring_terms.sets = pool.sets
        self.spring_terms.set_index, self.spring_terms.local = pool.set_index, pool.local

    # ------------------------------------------------------------------------------ device work
    def begin(self, state_in: State, control: Control, h: float, extrapolate: float) -> None:
        """The dashpots' start constraints, the inertial target and the first guess of a step of
        ``h`` [s] from ``state_in`` (the stages must have prepared the step already)."""
        m, dev = self.model, self.device
        x = state_in.positions
        wp.launch(kp._edge_constraints, dim=m.edge_count, inputs=[m.edge_indices, m.edge_rest_length, x],
                  outputs=[self.c_edge], device=dev)
        wp.launch(kp._face_constraints, dim=m.face_count, inputs=[m.face_indices, m.face_rest_area, x],
                  outputs=[self.c_face], device=dev)
        wp.launch(kp._tet_constraints, dim=m.tet_count,
                  inputs=[m.tet_indices, m.tet_rest_volume, m.tet_rest_inverse, x],
                  outputs=[self.c_tet, self.g_tet], device=dev)
        wp.launch(kp._inertial_target, dim=m.vertex_count,
                  inputs=[m.damping_rate, h, control.cranium_velocity, x, state_in.prev_positions],
                  outputs=[self.z], device=dev)
        self.launch_guess(state_in, extrapolate)

    def launch_guess(self, state_in: State, extrapolate: float) -> None:
        """:attr:`x` = the first guess: fixed nodes on their targets, free ones at
        ``x_n + extrapolate (x_n - x_prev)``."""
        m = self.model
        get_warp().launch(kp._initial_guess, dim=m.vertex_count,
                          inputs=[m.vertex_fixed, extrapolate, self.targets, state_in.positions,
                                  state_in.prev_positions],
                          outputs=[self.x], device=self.device)

    def mass_scale(self, h: float) -> float:
        """mu / m = (1 + alpha h) / h^2 [1/s^2] of a step of ``h`` [s]."""
        return (1.0 + self.model.damping_rate * h) / (h * h)

    def launch_energy(self, x, control: Control, h: float, with_grad: bool = True) -> None:
        """Per-term energies into :attr:`energy` and the gradient into :attr:`grad` at x
        (``with_grad`` False: the per-element gradient entries are written but not gathered into
        :attr:`grad`; :meth:`launch_gather` does that later).

        On the CPU the launches are recorded once per ``(x, control, h)`` and replayed
        (``wp.launch(..., record_cmd=True)``): the host solver evaluates the energy ~300 times a
        frame on a stream switching every frame, and Warp's argument packing took ~40 % of the
        launches' time at level 0 (cProfile of 10 such frames: 2.3 of 5.5 s)."""
        energy, gather = self._energy_commands(x, control, h)
        for cmd in energy:
            cmd.launch()
        if with_grad:
            for cmd in gather:
                cmd.launch()

    def launch_gather(self, x, control: Control, h: float) -> None:
        """Gather the gradient entries of the last :meth:`launch_energy` at the same arguments
        into :attr:`grad` (its ``with_grad`` part)."""
        for cmd in self._energy_commands(x, control, h)[1]:
            cmd.launch()

    def _energy_commands(self, x, control: Control, h: float):
        """The launches of :meth:`launch_energy`: ``(energy, gather)`` lists of Warp launches,
        recorded at the first call with these arrays and step (CUDA: plain launches, the same
        kernels, so that graph capture is unchanged)."""
        key = (x.ptr, control.external_force.ptr, float(h))
        cache = self._energy_cmd_cache
        hit = cache.get(key)
        if hit is None:
            if len(cache) >= 8:
                cache.clear()
            hit = self._record_energy(x, control, h)
            cache[key] = hit
        return hit

    def _record_energy(self, x, control: Control, h: float):
        m, dev = self.model, self.device
        rec = not dev.is_cuda
        ih = 1.0 / h
        ee, ef, et, en = self._e_views[:4]
        pool = self.pool
        specs = [
            (kp._edge_energy, m.edge_count,
             [m.edge_indices, m.edge_rest_length, m.edge_k0, m.edge_damping, ih, self.c_edge, x], [ee, self.slots]),
            (kp._face_energy, m.face_count,
             [m.face_indices, m.face_rest_area, m.face_k, m.face_damping, ih, 2 * m.edge_count, self.c_face, x],
             [ef, self.slots]),
            (kp._tet_energy, m.tet_count,
             [m.tet_indices, m.tet_rest_volume, m.tet_k, m.tet_damping, m.tet_rest_inverse, m.tet_shear_k,
              m.tet_shear_damping, ih, 2 * m.edge_count + 3 * m.face_count, self.c_tet, self.g_tet, x],
             [et, self.slots, self.c_tet_trial]),
            (kp._node_energy, m.vertex_count,
             [m.vertex_mass, m.vertex_fixed, m.vertex_hold_stiffness, self.mass_scale(h), self.z, self.targets,
              control.external_force, x],
             [en, self.grad]),
        ]
        if pool.count:
            specs.append((kp._spring_energy, pool.count, [pool.sets, pool.set_index, pool.local, x],
                          [self._e_views[4], pool.grad]))
        gathers = [(kp._gather_free, m.vertex_count,
                    [self.nodes, m.node_slot_start, m.node_slots, m.vertex_fixed, self.slots], [self.grad])]
        if pool.count:
            gathers.append((kp._gather_free, len(pool.group_nodes),
                            [pool.group_nodes, pool.group_start, pool.group_order, m.vertex_fixed, pool.grad],
                            [self.grad]))

        def make(spec):
            kernel, dim, inputs, outputs = spec
            if rec:
                return wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=dev, record_cmd=True)
            return _Launch(kernel, dim, inputs, outputs, dev)

        return [make(sp_) for sp_ in specs], [make(sp_) for sp_ in gathers]

    def launch_hessian(self, x, h: float, slack=None) -> None:
        """PSD Hessian blocks at x summed into :attr:`block_values` (fixed rows / columns: identity);
        ``slack`` [m]: one-sided springs slack by less than this keep their block (the factorised
        model of the host L-BFGS), 0 for the exact Hessian; a host number or a one-element device
        array (the device method's, changed on the device)."""
        m, dev = self.model, self.device
        if not isinstance(slack, wp.array):  # a host number: into the host slack array
            self._host_slack.fill_(float(slack or 0.0))
            slack = self._host_slack
        ih = 1.0 / h
        o = self._block_offsets
        wp.launch(kh._edge_hessian, dim=m.edge_count,
                  inputs=[m.edge_indices, m.edge_rest_length, m.edge_k0, m.edge_damping, ih, self.c_edge, x],
                  outputs=[self.block_slots], device=dev)
        wp.launch(kh._face_hessian, dim=m.face_count,
                  inputs=[m.face_indices, m.face_rest_area, m.face_k, m.face_damping, ih, int(o[1]), x],
                  outputs=[self.block_slots], device=dev)
        wp.launch(kh._tet_hessian, dim=m.tet_count,
                  inputs=[m.tet_indices, m.tet_rest_volume, m.tet_k, m.tet_damping, m.tet_rest_inverse,
                          m.tet_shear_k, m.tet_shear_damping, ih, int(o[2]), x],
                  outputs=[self.block_slots], device=dev)
        wp.launch(kh._node_hessian, dim=m.vertex_count,
                  inputs=[m.vertex_mass, m.vertex_hold_stiffness, self.mass_scale(h), int(o[3])],
                  outputs=[self.block_slots], device=dev)
        pool = self.pool
        if pool.count:
            wp.launch(kh._spring_hessian, dim=pool.count,
                      inputs=[pool.sets, pool.set_index, pool.local, int(o[4]), slack, x],
                      outputs=[self.block_slots], device=dev)
        wp.launch(kh._gather_blocks, dim=self.block_count,
                  inputs=[self.block_start, self.block_order, self.block_row, self.block_col, m.vertex_fixed,
                          self.block_slots],
                  outputs=[self.block_values], device=dev)

    # ------------------------------------------------------------------------------ host side
    def host_eval(self, x64: np.ndarray, control: Control, h: float,
                  with_grad: bool = True) -> tuple[float, np.ndarray | None, float, bool]:
        """Phi [J], its gradient [N] (3n,) float64, the energy's float32 rounding scale [J] and
        whether a tet is inverted, at positions ``x64`` [m] (n, 3) (written into :attr:`x`).
        ``with_grad`` False: the gradient is None (not gathered; :meth:`host_grad` gathers it
        afterwards, the same values)."""
        self.x.numpy()[:] = x64
        self.launch_energy(self.x, control, h, with_grad=with_grad)
        e = self.energy.numpy()
        g = self.grad.numpy().astype(np.float64).ravel() if with_grad else None
        total = float(np.sum(e, dtype=np.float64))
        noise = 4.0 * 1.2e-7 * float(np.sum(np.abs(e), dtype=np.float64)) + 1e-30
        return total, g, noise, bool(self.c_tet_trial.numpy().min() <= -1.0)

    def host_grad(self, control: Control, h: float) -> np.ndarray:
        """The gradient [N] (3n,) float64 of the last :meth:`host_eval` made with ``with_grad``
        False (same control and step)."""
        self.launch_gather(self.x, control, h)
        return self.grad.numpy().astype(np.float64).ravel()

    def hessian_matrix(self):
        """:attr:`block_values` as a SciPy BSR matrix (3n, 3n), float64 (host read)."""
        import scipy.sparse as sp

        n = self.model.vertex_count
        return sp.bsr_matrix((self.block_values.numpy().astype(np.float64), self.bsr_columns, self.bsr_offsets),
                             shape=(3 * n, 3 * n))

    def hessian_upper(self):
        """The upper triangle of :attr:`block_values`' matrix as a SciPy CSC matrix (3n, 3n),
        float64 (host read), with the same entries (explicit zeros included) and order as
        ``scipy.sparse.triu(hessian_matrix(), format="csc")``, gathered by an index map made at
        the first call (about 1 ms at level 0 instead of 10 for the conversion)."""
        import scipy.sparse as sp

        if getattr(self, "_upper_map", None) is None:
            n = self.model.vertex_count
            marker = np.arange(1, 9 * self.block_count + 1, dtype=np.float64).reshape(-1, 3, 3)
            A = sp.bsr_matrix((marker, self.bsr_columns, self.bsr_offsets), shape=(3 * n, 3 * n))
            U = sp.triu(sp.csc_matrix(A), format="csc")
            self._upper_map = (U.data.astype(np.int64) - 1, U.indices.copy(), U.indptr.copy(), U.shape)
        take, indices, indptr, shape = self._upper_map
        values = self.block_values.numpy().reshape(-1).astype(np.float64)[take]
        return sp.csc_matrix((values, indices, indptr), shape=shape)

    def contact_set(self, x64: np.ndarray, slack: float) -> np.ndarray:
        """The contact active set: which one-sided springs are compressed or within ``slack`` [m]
        of it at x64, all sets concatenated, shape (total,), bool."""
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
            out.append((sp_.stiffness.numpy() > 0) & (gap < slack))
        return np.concatenate(out)
