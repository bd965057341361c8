"""The incremental potential of one implicit (backward) Euler step, in NumPy (float64).

Backward Euler of ``M a = F(x) - D v`` over a step h is the minimiser of (Martin et al. 2011;
Liu, Bouaziz & Kavan 2017)

    Phi(x) = sum_i mu_i / 2 |x_i - z_i|^2                                (inertia + mass damping)
           + E_tissue(x)                                           (Eq. 6.4.4-6.4.8, Table 6.3)
           + sum_elements d / (2 h) (C(x) - C(x_n))^2                  (strain-rate dashpots)
           + sum_held k_h / 2 |x - target|^2 + sum_springs E_s(x) - f_ext . x,

with ``mu_i = m_i (1 + alpha h) / h^2`` and ``z = (y + alpha h w) / (1 + alpha h)``, where
``y = x_n + h v_n`` is the inertial prediction and ``w = x_n + h v_c`` the position the cranium's
rigid velocity v_c would carry the node to: the mass damping ``alpha m (v - v_c)`` becomes
``alpha m / (2 h) |x - w|^2``, and the two quadratics merge into one. The dashpot term's gradient
``d (C - C_n) / h grad C`` is the strain-rate damping ``d dC/dt grad C`` of the explicit model.
Fixed nodes sit on their targets and are not unknowns.

Energies per element (C dimensionless, see :mod:`.model`):

* distance (Eq. 6.4.4, 6.4.6): ``k0 (C^2 / 2 + C^4 / 4)``, C = |x_i - x_j| / D0 - 1;
* area (Eq. 6.4.7): ``k / 2 C^2``, C = A / A0 - 1;
* volume (Eq. 6.4.8): ``k / 2 C^2``, C = V / V0 - 1 (signed volume), plus the volume barrier
  ``kappa k phi(C + 1)`` below a twentieth of the rest volume (:mod:`..volume_barrier`);
* springs (:class:`~facewarp._src.physics.springs.Springs`): ``k / 2 (|p - x| - l0)^2`` (muscles,
  Eq. 6.4.1 with the fibre cosine frozen over the step) or ``k / 2 ((x - p) . a)^2`` (supports);
  one-sided (contact): ``k / 2 min(0, |x - p| - l0)^2`` (out of a ball) or
  ``k / 2 min(0, (x - p) . a)^2`` (a half-space).

Hessians are positive semi-definite approximations, as a Newton-type solver needs: exact for
the distance energy and the springs when stretched, with the negative part of the transverse
term dropped when compressed (``max(dE/dC, 0)``), and Gauss-Newton ``(k + d / h) grad C grad C^T``
for area and volume (their constraint is small: the neglected ``k C grad^2 C`` vanishes at rest).
They are assembled into a 3 x 3 block sparse matrix over the free nodes, on a pattern (diagonal
+ tet edges) and scatter map made once.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .model import Model
from .volume_barrier import INVERTED_ENERGY, VOLUME_BARRIER_STIFFNESS, barrier, barrier_d, barrier_dd

__all__ = ["StepData", "StepPotential", "deformation_gradient", "edge_energy", "edge_strain", "face_area_gradient",
           "face_energy", "face_strain", "green_strain", "node_energy", "shear_energy", "spring_energy_grad",
           "tet_edges", "tet_energy", "tet_strain", "tet_volume", "tet_volume_gradient"]


def _host(a, dtype=np.float64) -> np.ndarray:
    """A Warp array (or NumPy) as a host NumPy array of ``dtype`` (vec3 arrays become (n, 3))."""
    arr = a.numpy() if hasattr(a, "numpy") else np.asarray(a)
    return np.asarray(arr, dtype=dtype)


def _spring_tuple(t) -> tuple:
    """``(node, point, k, l0, axis, one_sided)`` of a spring tuple with or without its 6th entry."""
    return (*t[:5], bool(t[5]) if len(t) > 5 else False)


def _rows3(v: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("ij,ij->i", v, v))


class StepData:
    """What one step needs besides the positions: set by :meth:`StepPotential.begin_step`.

    Attributes:
        h: Step [s].
        z: Inertial target of every node [m], shape (n, 3).
        mu: Inertia weight ``m (1 + alpha h) / h^2`` [N/m], shape (n,).
        targets: Targets of fixed and held nodes [m], shape (n, 3).
        force: External force [N], shape (n, 3).
        edge_c, face_c, tet_c: Constraints at the step's start (for the dashpots).
        tet_g: Green strain of every tet at the step's start (the shear term's dashpot), shape
            (t, 3, 3), or None (zero).
        springs: list of ``(node (k,), point (k, 3), stiffness (k,), rest_length (k,) or None,
            axis (k, 3) or None[, one_sided bool])`` (one_sided: False when left out).
    """

    def __init__(self, h, z, mu, targets, force, edge_c, face_c, tet_c, springs, tet_g=None):
        self.h, self.z, self.mu, self.targets, self.force = h, z, mu, targets, force
        self.edge_c, self.face_c, self.tet_c, self.springs = edge_c, face_c, tet_c, springs
        self.tet_g = tet_g


class StepPotential:
    """The potential Phi of one implicit Euler step of a :class:`~facewarp._src.physics.model.Model`
    (module doc), its gradient and a PSD Hessian, in float64 on the host.

    Args:
        model: the tissue model (its arrays are read back once).

    Attributes:
        n: node count; free: (n,) bool, the unknown nodes (not fixed); free_index: (nf,) their
        indices; pattern: the block sparse pattern of the free nodes' Hessian.
    """

    def __init__(self, model: Model):
        self.model = model
        X0 = _host(model.rest_positions)
        self.rest = X0
        self.n = n = len(X0)
        self.mass = _host(model.vertex_mass)
        self.fixed = _host(model.vertex_fixed, np.int64) != 0
        self.hold = _host(model.vertex_hold_stiffness)
        self.alpha = float(model.damping_rate)
        self.E = _host(model.edge_indices, np.int64)
        self.L = _host(model.edge_rest_length)
        self.k0 = _host(model.edge_k0)
        self.de = _host(model.edge_damping)
        self.F = _host(model.face_indices, np.int64)
        self.A0 = _host(model.face_rest_area)
        self.kf = _host(model.face_k)
        self.df = _host(model.face_damping)
        self.T = _host(model.tet_indices, np.int64)
        self.V0 = _host(model.tet_rest_volume)
        self.kt = _host(model.tet_k)
        self.dt_ = _host(model.tet_damping)
        self.Dmi = _host(model.tet_rest_inverse).reshape(-1, 3, 3)
        self.ks = _host(model.tet_shear_k)
        self.ds = _host(model.tet_shear_damping)
        self.shear = bool(self.ks.any() or self.ds.any())
        self.free = ~self.fixed
        self.free_index = np.flatnonzero(self.free)
        # gradient gather: every element corner's vector adds to its node (fixed order)
        self.corner_node = np.concatenate([self.E.ravel(), self.F.ravel(), self.T.ravel()])
        self._gather = sp.csr_matrix((np.ones(len(self.corner_node)), (self.corner_node, np.arange(len(self.corner_node)))),
                                     shape=(n, len(self.corner_node)))
        self._build_pattern()

    # ------------------------------------------------------------------------------ pattern
    def _build_pattern(self):
        n, free = self.n, self.free
        nf = len(self.free_index)
        fid = np.full(n, -1, np.int64)
        fid[self.free_index] = np.arange(nf)
        self.fid = fid
        E = self.E
        pairs = np.concatenate([np.stack([np.arange(n), np.arange(n)], 1), E, E[:, ::-1]])
        ok = free[pairs[:, 0]] & free[pairs[:, 1]]
        fp = fid[pairs[ok]]
        code = np.unique(fp[:, 0] * nf + fp[:, 1])
        rows, cols = code // nf, code % nf
        self.block_code = code
        self.block_count = len(code)
        self.bsr_indices = cols.astype(np.int32)
        self.bsr_indptr = np.searchsorted(rows, np.arange(nf + 1)).astype(np.int32)
        self.nf = nf
        dump = self.block_count  # blocks touching a fixed node go here and are dropped

        def block_index(a, b):
            fa, fb = fid[a], fid[b]
            ok = (fa >= 0) & (fb >= 0)
            out = np.full(a.shape, dump, np.int64)
            out[ok] = np.searchsorted(code, fa[ok] * nf + fb[ok])
            return out

        def element_blocks(idx):
            c = idx.shape[1]
            a = np.repeat(idx[:, :, None], c, axis=2)
            b = np.repeat(idx[:, None, :], c, axis=1)
            return block_index(a, b)  # (m, c, c)

        self.blk_E = element_blocks(self.E)
        self.blk_F = element_blocks(self.F)
        self.blk_T = element_blocks(self.T)
        self.blk_diag = block_index(np.arange(n), np.arange(n))
        comp = np.arange(9)
        # flat scatter index of every (block, component) contribution, in a fixed order
        self._scatter = np.concatenate([
            (self.blk_E.reshape(-1, 1) * 9 + comp).ravel(),
            (self.blk_F.reshape(-1, 1) * 9 + comp).ravel(),
            (self.blk_T.reshape(-1, 1) * 9 + comp).ravel(),
            (self.blk_diag.reshape(-1, 1) * 9 + comp).ravel(),
        ])

    # ------------------------------------------------------------------------------ per step
    def constraints(self, X) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Relative length, area and volume change of every element at X (n, 3): (e,), (f,), (t,)."""
        E, F, T = self.E, self.F, self.T
        ce = _rows3(X[E[:, 0]] - X[E[:, 1]]) / self.L - 1.0
        cf = 0.5 * _rows3(np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])) / self.A0 - 1.0
        x0 = X[T[:, 0]]
        v = np.einsum("ij,ij->i", X[T[:, 1]] - x0, np.cross(X[T[:, 2]] - x0, X[T[:, 3]] - x0)) / 6.0
        return ce, cf, v / self.V0 - 1.0

    def green(self, X) -> np.ndarray:
        """Green strain ``(F^T F - I) / 2`` of every tet at X (n, 3), ``F = D_s D_m^-1``: (t, 3, 3)."""
        T = self.T
        Ds = np.stack([X[T[:, c]] - X[T[:, 0]] for c in (1, 2, 3)], axis=2)
        F = Ds @ self.Dmi
        return 0.5 * (np.einsum("kji,kjl->kil", F, F) - np.eye(3))

    def begin_step(self, x_n, x_prev, h: float, targets, *, force=None, springs=(), cranium_velocity=None) -> StepData:
        """The step's data: inertial target, dashpot constraints at the start, springs.

        Args:
            x_n: Positions at the step's start [m], shape (n, 3).
            x_prev: Positions one step earlier [m], shape (n, 3) (``x_n - x_prev = h v_n``).
            h: Step [s].
            targets: Targets of fixed and held nodes [m], shape (n, 3).
            force: External force [N], shape (n, 3), or None.
            springs: Tuples ``(node, point, stiffness, rest_length | None, axis | None[, one_sided])``.
            cranium_velocity: ``(v, w)``: linear [m/s] and angular [rad/s] velocity, shape (2, 3).
        """
        x_n = np.asarray(x_n, np.float64)
        y = 2.0 * x_n - np.asarray(x_prev, np.float64)
        ah = self.alpha * h
        w = x_n
        if cranium_velocity is not None:
            vc = np.asarray(cranium_velocity, np.float64).reshape(2, 3)
            if np.any(vc):
                w = x_n + h * (vc[0] + np.cross(vc[1], x_n))
        z = (y + ah * w) / (1.0 + ah)
        # fixed nodes are not unknowns: no inertia, hold or external force terms
        mu = np.where(self.free, self.mass * (1.0 + ah) / (h * h), 0.0)
        ce, cf, ct = self.constraints(x_n)
        f = np.zeros((self.n, 3)) if force is None else np.asarray(force, np.float64) * self.free[:, None]
        g = self.green(x_n) if self.shear else None
        return StepData(h, z, mu, np.asarray(targets, np.float64), f, ce, cf, ct, list(springs), tet_g=g)

    def start_positions(self, x_guess, data: StepData) -> np.ndarray:
        """``x_guess`` with the fixed nodes on their targets, float64 (n, 3)."""
        X = np.array(x_guess, dtype=np.float64)
        X[self.fixed] = data.targets[self.fixed]
        return X

    # ------------------------------------------------------------------------------ evaluation
    def _elements(self, X, data: StepData, want_grad: bool):
        """Energy and per-corner gradient vectors of the tissue terms (with dashpots)."""
        ih = 1.0 / data.h
        E, F, T = self.E, self.F, self.T
        # distance
        d = X[E[:, 0]] - X[E[:, 1]]
        l = _rows3(d)
        ce = l / self.L - 1.0
        dc = ce - data.edge_c
        e_sum = np.sum(self.k0 * ce * ce * (0.5 + 0.25 * ce * ce)) + 0.5 * ih * np.sum(self.de * dc * dc)
        # area
        xf0 = X[F[:, 0]]
        e1, e2 = X[F[:, 1]] - xf0, X[F[:, 2]] - xf0
        N = np.cross(e1, e2)
        nl = _rows3(N)
        cf = face_strain(xf0, X[F[:, 1]], X[F[:, 2]], self.A0)
        dcf = cf - data.face_c
        e_sum += 0.5 * np.sum(self.kf * cf * cf) + 0.5 * ih * np.sum(self.df * dcf * dcf)
        # volume
        xt0 = X[T[:, 0]]
        t1, t2, t3 = tet_edges(xt0, X[T[:, 1]], X[T[:, 2]], X[T[:, 3]])
        c23 = np.cross(t2, t3)
        ct = tet_volume(t1, t2, t3) / self.V0 - 1.0
        dct = ct - data.tet_c
        e_sum += 0.5 * np.sum(self.kt * ct * ct) + 0.5 * ih * np.sum(self.dt_ * dct * dct)
        e_sum += VOLUME_BARRIER_STIFFNESS * np.sum(self.kt * barrier(ct + 1.0))
        Fd = None
        if self.shear:  # the shear term (model doc): k_s / 2 |G|^2 + d_s / (2h) |G - G_n|^2
            Fd = np.stack([t1, t2, t3], axis=2) @ self.Dmi
            G = 0.5 * (np.einsum("kji,kjl->kil", Fd, Fd) - np.eye(3))
            dG = G - (0.0 if data.tet_g is None else data.tet_g)
            e_sum += 0.5 * np.sum(self.ks * np.einsum("kij,kij->k", G, G))
            e_sum += 0.5 * ih * np.sum(self.ds * np.einsum("kij,kij->k", dG, dG))
        if not want_grad:
            return e_sum, None, None
        n_e = d / np.maximum(l, 1e-300)[:, None]
        s_e = (self.k0 * (ce + ce**3) + ih * self.de * dc) / self.L
        ge = np.empty((len(E), 2, 3))
        ge[:, 0] = s_e[:, None] * n_e
        ge[:, 1] = -ge[:, 0]
        m = N / np.maximum(nl, 1e-300)[:, None]
        _, gj, gk = face_area_gradient(e1, e2, m)
        s_f = (self.kf * cf + ih * self.df * dcf) / self.A0
        gf = np.empty((len(F), 3, 3))
        gf[:, 1] = s_f[:, None] * gj
        gf[:, 2] = s_f[:, None] * gk
        gf[:, 0] = -(gf[:, 1] + gf[:, 2])
        s_t = (self.kt * (ct + VOLUME_BARRIER_STIFFNESS * barrier_d(ct + 1.0)) + ih * self.dt_ * dct) / (6.0 * self.V0)
        gt = np.empty((len(T), 4, 3))
        gt[:, 1] = s_t[:, None] * c23
        gt[:, 2] = s_t[:, None] * np.cross(t3, t1)
        gt[:, 3] = s_t[:, None] * np.cross(t1, t2)
        if self.shear:  # dE/dx_{1,2,3} = columns of F S D_m^-T, S = k_s G + d_s / h (G - G_n)
            S = self.ks[:, None, None] * G + ih * self.ds[:, None, None] * dG
            P = Fd @ S @ np.transpose(self.Dmi, (0, 2, 1))
            gt[:, 1:] += np.transpose(P, (0, 2, 1))
        gt[:, 0] = -(gt[:, 1] + gt[:, 2] + gt[:, 3])
        corners = np.concatenate([ge.reshape(-1, 3), gf.reshape(-1, 3), gt.reshape(-1, 3)])
        return e_sum, corners, (n_e, l, ce, dc, m, nl, gj, gk, cf, c23, t1, t2, t3, ct, Fd)

    def _node_terms(self, X, data: StepData, want_grad: bool):
        """Inertia, holds, springs and the external force: energy and per-node gradient."""
        dz = X - data.z
        e = 0.5 * np.sum(data.mu * np.einsum("ij,ij->i", dz, dz))
        dh = X - data.targets
        e += 0.5 * np.sum(self.hold * np.einsum("ij,ij->i", dh, dh))  # held nodes are never fixed
        e -= np.sum(data.force * X)
        G = None
        if want_grad:
            G = data.mu[:, None] * dz + self.hold[:, None] * dh - data.force
        for node, point, k, l0, axis, one in map(_spring_tuple, data.springs):
            if len(node) == 0:
                continue
            r = X[node] - point
            if axis is not None:
                s = np.einsum("ij,ij->i", r, axis)
                if one:
                    s = np.minimum(s, 0.0)
                e += 0.5 * np.sum(k * s * s)
                if want_grad:
                    g = (k * s)[:, None] * axis
            else:
                ll = _rows3(r)
                st = ll - l0
                if one:
                    st = np.minimum(st, 0.0)
                e += 0.5 * np.sum(k * st * st)
                if want_grad:
                    g = (k * st / np.maximum(ll, 1e-300))[:, None] * r
            if want_grad:
                for c in range(3):
                    G[:, c] += np.bincount(node, weights=g[:, c], minlength=self.n)
        return e, G

    def energy(self, X, data: StepData) -> float:
        """Phi(X) [J] (module doc); X (n, 3) with the fixed nodes on their targets."""
        e1, _, _ = self._elements(X, data, False)
        e2, _ = self._node_terms(X, data, False)
        return float(e1 + e2)

    def gradient(self, X, data: StepData) -> tuple[float, np.ndarray]:
        """``(Phi, dPhi/dX)``: energy [J] and gradient [N], shape (n, 3) (fixed rows included)."""
        e1, corners, _ = self._elements(X, data, True)
        e2, G = self._node_terms(X, data, True)
        G += self._gather @ corners
        return float(e1 + e2), G

    def hessian(self, X, data: StepData) -> sp.bsr_matrix:
        """PSD Hessian of Phi over the free nodes (module doc), a (3 nf, 3 nf) BSR matrix, node-major."""
        vals = self._element_hessian_values(X, data)
        diag = np.zeros((self.n, 3, 3))
        idx = np.arange(3)
        diag[:, idx, idx] = (data.mu + np.where(self.free, self.hold, 0.0))[:, None]
        for node, point, k, l0, axis, one in map(_spring_tuple, data.springs):
            if len(node) == 0:
                continue
            r = X[node] - point
            if axis is not None:
                B = k[:, None, None] * axis[:, :, None] * axis[:, None, :]
                if one:
                    B = B * (np.einsum("ij,ij->i", r, axis) < 0.0)[:, None, None]
            else:
                ll = np.maximum(_rows3(r), 1e-300)
                nn = r / ll[:, None]
                nnT = nn[:, :, None] * nn[:, None, :]
                tr = np.maximum(1.0 - l0 / ll, 0.0)
                B = k[:, None, None] * (nnT + tr[:, None, None] * (np.eye(3) - nnT))
                if one:
                    B = B * (ll < l0)[:, None, None]
            np.add.at(diag, node, B)
        w = np.concatenate([vals, diag.ravel()])
        data9 = np.bincount(self._scatter, weights=w, minlength=(self.block_count + 1) * 9)[: self.block_count * 9]
        nf3 = 3 * self.nf
        return sp.bsr_matrix((data9.reshape(-1, 3, 3), self.bsr_indices, self.bsr_indptr), shape=(nf3, nf3))

    def _element_hessian_values(self, X, data: StepData) -> np.ndarray:
        """Flattened (block-major, 9 components) element Hessian contributions, in scatter order."""
        ih = 1.0 / data.h
        _, _, aux = self._elements(X, data, True)
        n_e, l, ce, dc, m, nl, gj, gk, cf, c23, t1, t2, t3, ct, Fd = aux
        I3 = np.eye(3)
        # distance: a n n^T / L^2 + max(b, 0) / (L l) (I - n n^T), signs [[+, -], [-, +]]
        a = (self.k0 * (1.0 + 3.0 * ce * ce) + ih * self.de) / self.L**2
        b = np.maximum(self.k0 * (ce + ce**3) + ih * self.de * dc, 0.0) / (self.L * np.maximum(l, 1e-300))
        nnT = n_e[:, :, None] * n_e[:, None, :]
        Hb = a[:, None, None] * nnT + b[:, None, None] * (I3 - nnT)
        He = np.empty((len(self.E), 2, 2, 3, 3))
        He[:, 0, 0] = Hb
        He[:, 1, 1] = Hb
        He[:, 0, 1] = -Hb
        He[:, 1, 0] = -Hb
        # area: Gauss-Newton (k + d / h) / A0^2 gA gA^T
        g = np.empty((len(self.F), 3, 3))
        g[:, 1], g[:, 2] = gj, gk
        g[:, 0] = -(gj + gk)
        s = (self.kf + ih * self.df) / self.A0**2
        Hf = s[:, None, None, None, None] * g[:, :, None, :, None] * g[:, None, :, None, :]
        # volume: Gauss-Newton (k + d / h) / V0^2 gV gV^T
        gv = np.empty((len(self.T), 4, 3))
        gv[:, 1] = c23 / 6.0
        gv[:, 2] = np.cross(t3, t1) / 6.0
        gv[:, 3] = np.cross(t1, t2) / 6.0
        gv[:, 0] = -(gv[:, 1] + gv[:, 2] + gv[:, 3])
        s = (self.kt * (1.0 + VOLUME_BARRIER_STIFFNESS * barrier_dd(ct + 1.0)) + ih * self.dt_) / self.V0**2
        Ht = s[:, None, None, None, None] * gv[:, :, None, :, None] * gv[:, None, :, None, :]
        if Fd is not None:
            # shear term, Gauss-Newton: block (a, b)_cd = (k_s + d_s / h) / 2 ((F F^T)_cd (b_a . b_b) + (F b_b)_c (F b_a)_d)
            b = np.concatenate([-self.Dmi.sum(axis=1)[:, None], self.Dmi], axis=1)  # (t, 4, 3)
            fb = np.einsum("kij,kaj->kai", Fd, b)  # F b_a
            FF = np.einsum("kij,klj->kil", Fd, Fd)
            bb = np.einsum("kai,kbi->kab", b, b)
            ss = 0.5 * (self.ks + ih * self.ds)
            Ht = Ht + ss[:, None, None, None, None] * (bb[:, :, :, None, None] * FF[:, None, None]
                                                       + fb[:, None, :, :, None] * fb[:, :, None, None, :])
        return np.concatenate([He.ravel(), Hf.ravel(), Ht.ravel()])

    # ------------------------------------------------------------------------------ helpers
    def free_vector(self, G) -> np.ndarray:
        """Rows of the free nodes of an (n, 3) array, flattened node-major: (3 nf,)."""
        return np.ascontiguousarray(G[self.free_index]).ravel()

    def scatter_free(self, X, dv) -> np.ndarray:
        """``X`` with ``dv`` (3 nf,) added to the free nodes (a new array)."""
        Y = X.copy()
        Y[self.free_index] += dv.reshape(-1, 3)
        return Y


# ---------------------------------------------------------------------------------------- elements
# The float64 oracle of the element library (facewarp._src.physics.elements), under its names and
# vectorised over elements: rows (m, 3) of positions or edge vectors, (m,) of rest measures and
# coefficients. tests/test_elements.py pairs each with its wp.func.
def tet_edges(x0, x1, x2, x3) -> tuple:
    """Edge vectors from corner 0 [m], three (m, 3)."""
    return x1 - x0, x2 - x0, x3 - x0


def tet_volume(e1, e2, e3) -> np.ndarray:
    """Signed volume [m^3] 1/6 e1 . (e2 x e3), (m,)."""
    return np.einsum("ij,ij->i", e1, np.cross(e2, e3)) / 6.0


def tet_volume_gradient(e1, e2, e3) -> tuple:
    """dV/dx_a [m^2] of the four corners, four (m, 3)."""
    g1, g2, g3 = np.cross(e2, e3) / 6.0, np.cross(e3, e1) / 6.0, np.cross(e1, e2) / 6.0
    return -(g1 + g2 + g3), g1, g2, g3


def face_area_gradient(e1, e2, m) -> tuple:
    """dA/dx_a [m] of the three corners for the unit normal m, three (m, 3)."""
    g1, g2 = 0.5 * np.cross(e2, m), 0.5 * np.cross(m, e1)
    return -(g1 + g2), g1, g2


def edge_strain(xi, xj, d0) -> np.ndarray:
    """C = |xi - xj| / D0 - 1, (m,)."""
    return _rows3(xi - xj) / d0 - 1.0


def face_strain(xi, xj, xk, a0) -> np.ndarray:
    """C = A / A0 - 1, (m,)."""
    return 0.5 * _rows3(np.cross(xj - xi, xk - xi)) / a0 - 1.0


def tet_strain(xi, xj, xk, xl, v0) -> np.ndarray:
    """C = V / V0 - 1, (m,)."""
    return tet_volume(*tet_edges(xi, xj, xk, xl)) / v0 - 1.0


def deformation_gradient(xi, xj, xk, xl, rest_inverse) -> np.ndarray:
    """F = D_s D_m^-1, (m, 3, 3)."""
    return np.stack(tet_edges(xi, xj, xk, xl), axis=2) @ rest_inverse


def green_strain(F) -> np.ndarray:
    """G = (F^T F - I) / 2, (m, 3, 3)."""
    return 0.5 * (np.einsum("kji,kjl->kil", F, F) - np.eye(3))


def shear_energy(G, k, dmp, G_start) -> np.ndarray:
    """k / 2 |G|^2 + dmp / 2 |G - G_n|^2 [J], (m,)."""
    dG = G - G_start
    return 0.5 * k * np.einsum("kij,kij->k", G, G) + 0.5 * dmp * np.einsum("kij,kij->k", dG, dG)


def edge_energy(xi, xj, d0, k0, dmp, c_start) -> np.ndarray:
    """k0 (C^2 / 2 + C^4 / 4) + dmp / 2 (C - C_n)^2 [J] (Eq. 6.4.4, 6.4.6), (m,)."""
    c = edge_strain(xi, xj, d0)
    return k0 * c * c * (0.5 + 0.25 * c * c) + 0.5 * dmp * (c - c_start) ** 2


def face_energy(xi, xj, xk, a0, k, dmp, c_start) -> np.ndarray:
    """k / 2 C^2 + dmp / 2 (C - C_n)^2 [J] (Eq. 6.4.7), (m,)."""
    c = face_strain(xi, xj, xk, a0)
    return 0.5 * k * c * c + 0.5 * dmp * (c - c_start) ** 2


def tet_energy(c, k, dmp, c_start) -> np.ndarray:
    """k / 2 C^2 + dmp / 2 (C - C_n)^2 + kappa k phi(C + 1) [J] (Eq. 6.4.8 and the volume barrier), (m,)."""
    quad = 0.5 * k * c * c + 0.5 * dmp * (c - c_start) ** 2
    return np.where(c + 1.0 <= 0.0, INVERTED_ENERGY, quad + VOLUME_BARRIER_STIFFNESS * k * barrier(c + 1.0))


def node_energy(x, mu, z, kh, target, f) -> np.ndarray:
    """mu / 2 |x - z|^2 + kh / 2 |x - target|^2 - f . x [J], (m,)."""
    dz, dh = x - z, x - target
    return 0.5 * mu * np.einsum("ij,ij->i", dz, dz) + 0.5 * kh * np.einsum("ij,ij->i", dh, dh) - np.einsum("ij,ij->i", f, x)


def spring_energy_grad(x, point, stiffness, rest_length=None, axis=None, one_sided=False) -> tuple:
    """A spring set's energy [J] (m,) and gradient [N] (m, 3) (:class:`~.springs.Springs`: distance
    springs with ``rest_length``, axis springs with ``axis``; ``one_sided`` only push)."""
    r = x - point
    if axis is not None:
        s = np.einsum("ij,ij->i", r, axis)
        if one_sided:
            s = np.minimum(s, 0.0)
        return 0.5 * stiffness * s * s, (stiffness * s)[:, None] * axis
    l = _rows3(r)
    s = l - rest_length
    if one_sided:
        s = np.minimum(s, 0.0)
    return 0.5 * stiffness * s * s, (stiffness * s / np.maximum(l, 1e-300))[:, None] * r
