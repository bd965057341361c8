"""A regularised non-rigid ICP after the thesis's levels: vertices land on the scan without sliding.

Not a step of the thesis. The multi-level RBF (Sec. 4.5) fits dense FP pairs whose scan
partners are closest points; nothing in it penalises a vertex sliding *along* the scan, so
away from the FDPs the template's vertices drift tangentially (the surface lands, the
correspondence does not). This stage keeps the RBF result as its starting point and
minimises, over the template vertices ``x_i`` (template frame, metres)::

    E(X) = sum_i a_i (n_i . (x_i - c_i))^2                            data: point-to-plane
         + lambda sum_(i,j) w_ij |(x_i - x_j) - R_i (p_i - p_j)|^2     as-rigid-as-possible
         + mu sum_l |sum_c b_lc x_(f_l c) - q_l|^2                      FDPs (barycentric)

- data: ``c_i`` is the closest point of ``x_i`` on the scan and ``n_i`` the scan's normal
  there (point-to-plane, Chen & Medioni 1992); a pair counts only if it is closer than a
  threshold, not on the scan's border (holes, the edge of a partial scan) and its normal is
  compatible with the deformed template's (angle below 60 degrees), as in Amberg et al. 2007
  (optimal step non-rigid ICP). ``a_i`` is the vertex's area share (mean 1), so the data term
  is a surface integral;
- regulariser: the as-rigid-as-possible energy of Sorkine & Alexa 2007 with the rest shape the
  calibrated template ``p`` and clamped cotangent weights ``w_ij``; it penalises stretch and
  shear of the template's triangles, i.e. exactly the tangential sliding, while bending and
  local rotation (which a different face needs) cost nothing;
- FDPs: each shared FDP as a barycentric point of the template pulled to its scan position.

Minimised by alternation (Sorkine & Alexa's local/global steps): closest points and rotations
``R_i`` (SVD of the 3x3 covariance per vertex) with X fixed, then X by one sparse solve. The
point-to-plane term is linearised per iteration as a point target in the tangent plane of the
scan point, ``c~_i = x_i + n_i n_i^T (c_i - x_i)``, which keeps the system matrix
``lambda L_w + diag(a) + mu B^T B`` the same for the three coordinates and for every
iteration of a stiffness stage: one sparse LU per stage (scipy SuperLU). Like Amberg et al.,
the stiffness ``lambda`` falls in stages (``AdaptOptions.refine_stiffness``). A stage ends when
the correspondences converge: the RMS change of the vertices and of their scan partners
between iterations below 1e-4 of the head width (not only when E_d stops falling).

Vertices without a valid scan partner (holes, parts a partial scan does not cover: neck,
scalp) have no data term and follow their neighbours as rigidly as possible.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..geometry.surface import face_normals, vertex_normals
from .metrics import _on_boundary

__all__ = ["arap_stage", "cotan_edge_weights", "field_stage", "vertex_areas"]

NORMAL_COS = 0.5
"""Smallest cosine between the scan normal and the deformed template normal at a pair (60 deg)."""

CONVERGED = 1e-4
"""A stiffness stage stops when the RMS change of vertices and partners is below this times the head width."""


def unique_edges(F: np.ndarray) -> np.ndarray:
    """Undirected edges of the triangles F, each once, shape (e, 2), int64 (i < j)."""
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    return np.unique(E, axis=0)


def cotan_edge_weights(V: np.ndarray, F: np.ndarray, *, floor: float = 1e-2) -> tuple[np.ndarray, np.ndarray]:
    """Cotangent weights ``w_ij = (cot a_ij + cot b_ij) / 2`` of each edge (Pinkall & Polthier
    1993), clamped below at ``floor`` times their mean so that obtuse pairs stay positive.

    Args:
        V: Vertices [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.

    Returns:
        (edges (e, 2) int64 with i < j, weights (e,) float64, dimensionless).
    """
    P = V[F]
    dbl = np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
    dbl = np.maximum(dbl, 1e-300)
    keys, vals = [], []
    for c in range(3):
        a = P[:, (c + 1) % 3] - P[:, c]
        b = P[:, (c + 2) % 3] - P[:, c]
        cot = np.einsum("fd,fd->f", a, b) / dbl
        keys.append(np.sort(F[:, [(c + 1) % 3, (c + 2) % 3]], axis=1))
        vals.append(0.5 * cot)
    K = np.concatenate(keys)
    w = np.concatenate(vals)
    E, inv = np.unique(K, axis=0, return_inverse=True)
    W = np.bincount(inv.ravel(), weights=w, minlength=len(E))
    W = np.maximum(W, floor * max(float(np.mean(np.abs(W))), 1e-12))
    return E, W


def vertex_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Barycentric vertex areas (a third of each incident triangle) [m^2], shape (n,)."""
    A = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    return np.bincount(F.ravel(), weights=np.repeat(A / 3.0, 3), minlength=len(V))


def _laplacian(n: int, E: np.ndarray, w: np.ndarray) -> sp.csr_matrix:
    i, j = E[:, 0], E[:, 1]
    L = sp.coo_matrix((np.concatenate([-w, -w]), (np.concatenate([i, j]), np.concatenate([j, i]))), shape=(n, n)).tocsr()
    return L + sp.diags(np.bincount(np.concatenate([i, j]), weights=np.concatenate([w, w]), minlength=n))


def _rotations(P: np.ndarray, X: np.ndarray, E: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Best rotation per vertex (Sorkine & Alexa 2007, Eq. 6): R_i = V U^T from the SVD of
    S_i = sum_j w_ij (p_i - p_j)(x_i - x_j)^T, det fixed to +1; shape (n, 3, 3)."""
    n = len(P)
    e0 = P[E[:, 0]] - P[E[:, 1]]
    e1 = X[E[:, 0]] - X[E[:, 1]]
    outer = (w[:, None, None] * e0[:, :, None] * e1[:, None, :]).reshape(-1, 9)
    S = np.zeros((n, 9))
    for k in range(9):
        S[:, k] = np.bincount(E[:, 0], weights=outer[:, k], minlength=n) + np.bincount(E[:, 1], weights=outer[:, k], minlength=n)
    U, _, Vt = np.linalg.svd(S.reshape(n, 3, 3))
    R = np.einsum("nji,nkj->nik", Vt, U)  # V U^T
    bad = np.linalg.det(R) < 0
    if bad.any():
        U[bad, :, 2] *= -1.0
        R[bad] = np.einsum("nji,nkj->nik", Vt[bad], U[bad])
    return R


def _arap_rhs(P: np.ndarray, R: np.ndarray, E: np.ndarray, w: np.ndarray) -> np.ndarray:
    """b_i = sum_j w_ij / 2 (R_i + R_j)(p_i - p_j) (Sorkine & Alexa 2007, Eq. 9), shape (n, 3)."""
    n = len(P)
    e0 = P[E[:, 0]] - P[E[:, 1]]
    v = 0.5 * w[:, None] * np.einsum("kab,kb->ka", R[E[:, 0]] + R[E[:, 1]], e0)
    b = np.zeros((n, 3))
    for d in range(3):
        b[:, d] = np.bincount(E[:, 0], weights=v[:, d], minlength=n) - np.bincount(E[:, 1], weights=v[:, d], minlength=n)
    return b


def _partners(prob, X: np.ndarray, max_dist: float):
    """Closest scan points of X with their scan normals, and which pairs are valid."""
    cp = prob.scan_q.closest_point(X, max_dist)
    ok = cp.face >= 0
    face = np.maximum(cp.face, 0)
    ns = prob.scan_N_face[face]
    nx = vertex_normals(X, prob.TF)
    ok &= np.einsum("kd,kd->k", ns, nx) > NORMAL_COS
    ok &= ~_on_boundary(prob.scan_q, cp)
    C = np.where(ok[:, None], cp.points, X)
    return C, ns, ok


def _voxel_sample(V: np.ndarray, count: int) -> np.ndarray:
    """About ``count`` vertices of V [m], (n, 3), one per occupied cell of a cubic grid whose
    cell size is set from the bounding box; returns sorted indices, int64."""
    if len(V) <= count:
        return np.arange(len(V))
    ext = np.ptp(V, axis=0)
    h = float(np.sqrt((ext[0] * ext[1] + ext[1] * ext[2] + ext[0] * ext[2]) * 2.0 / 3.0 / count))
    for _ in range(8):  # adjust the cell to land near count
        key = np.floor((V - V.min(0)) / h).astype(np.int64)
        _, first = np.unique(key, axis=0, return_index=True)
        if 0.8 * count <= len(first) <= 1.25 * count:
            break
        h *= float(np.sqrt(len(first) / count))
    return np.sort(first)


def field_stage(prob, opts, X0: np.ndarray) -> tuple[np.ndarray, dict]:
    """A smooth 3D displacement field fitted to point-to-plane pairs (see the module docstring).

    The field is the thesis's global RBF (Eq. 4.4.1-4.4.4, ``phi(r) = r`` with an affine part)
    on ``field_centers`` centres (the FDPs and farthest-point samples of the template), but
    fitted by regularised least squares to point-to-plane pairs instead of interpolating
    point pairs::

        min  sum_i (n_i . (p_i + d(p_i) - c_i))^2 + mu sum_l |p_l + d(p_l) - q_l|^2 + gamma c^T (-Phi) c

    subject to Eq. 4.4.2's side conditions (``sum c_j = 0, sum c_j p_j^T = 0``, here by a
    null-space basis). ``-c^T Phi c`` is the thin-plate (Duchon) energy of the field in 3D
    (Carr et al. 2001), so among the fields that put the template on the scan's tangent planes
    the smoothest wins, and an affine map costs nothing. The data pairs are about
    ``field_samples`` template vertices spread over the whole template (every part the scan
    covers takes part), their closest scan points with compatible normals. ``gamma`` falls
    per ``field_stiffness`` stage; each stage iterates (closest points, solve) until the
    vertices and their partners stop moving (RMS change below 1e-4 of the head width).

    Args:
        prob: The :class:`~.problem.Problem`.
        opts: The :class:`~.problem.AdaptOptions`.
        X0: The levels' result [m], shape (n, 3), float64: only its closest points seed the
            first iteration; the field is measured from the template, so tangential drift of
            the seed is not kept.

    Returns:
        (vertices [m] (n, 3) float64, info dict).
    """
    from scipy.linalg import cho_factor, cho_solve, null_space
    from scipy.spatial.distance import cdist

    from .fp_search import farthest_points

    TV, TF = prob.TV, prob.TF
    n = len(TV)
    W = prob.W
    m = int(opts.field_centers)
    P_c = np.concatenate([prob.P_fdp, TV[farthest_points(TV, prob.P_fdp, max(m - len(prob.P_fdp), 4))]])
    m = len(P_c)
    Pt = np.column_stack([P_c, np.ones(m)])
    Z = null_space(Pt.T)  # (m, m - 4): coefficient vectors that meet Eq. 4.4.2's side conditions
    k = Z.shape[1] + 4
    Rg = -(Z.T @ cdist(P_c, P_c) @ Z)  # thin-plate energy, positive definite on the null space
    Rg = 0.5 * (Rg + Rg.T)

    def basis(X):
        return np.column_stack([cdist(X, P_c) @ Z, X, np.ones(len(X))])

    G_all = basis(TV)
    D = _voxel_sample(TV, int(opts.field_samples))
    G_D = G_all[D]
    G_f = basis(prob.P_fdp)
    N_ref = len(D)
    mu = 10.0
    M_fdp = mu * (G_f.T @ G_f)
    b_fdp = mu * (G_f.T @ (prob.Q_fdp - prob.P_fdp))
    max_dist = 0.05 * W
    tol = CONVERGED * W
    X = np.asarray(X0, dtype=np.float64).copy()
    U = None
    per_stage, total = [], 0
    dx = dc = float("nan")
    C_prev = None
    ok = np.zeros(len(D), bool)
    for s in opts.field_stiffness:
        gamma = float(s) * N_ref * W
        its = 0
        for its in range(1, int(opts.field_iterations) + 1):
            cp = prob.scan_q.closest_point(X[D], max_dist)
            ok = cp.face >= 0
            ns = prob.scan_N_face[np.maximum(cp.face, 0)]
            nx = vertex_normals(X, TF)[D]
            ok &= np.einsum("kd,kd->k", ns, nx) > NORMAL_COS
            ok &= ~_on_boundary(prob.scan_q, cp)
            C = np.where(ok[:, None], cp.points, X[D])
            r = np.where(ok, np.einsum("kd,kd->k", ns, C - TV[D]), 0.0)
            w = ok.astype(np.float64)
            M = np.zeros((3 * k, 3 * k))
            b = np.zeros(3 * k)
            for a in range(3):
                sa = slice(a * k, (a + 1) * k)
                b[sa] = G_D.T @ (w * ns[:, a] * r) + b_fdp[:, a]
                for c in range(a, 3):
                    sc = slice(c * k, (c + 1) * k)
                    blk = G_D.T @ ((w * ns[:, a] * ns[:, c])[:, None] * G_D)
                    M[sa, sc] = blk
                    if c != a:
                        M[sc, sa] = blk.T
                M[sa, sa] += M_fdp
                M[a * k:a * k + k - 4, a * k:a * k + k - 4] += gamma * Rg
            U = cho_solve(cho_factor(M), b).reshape(3, k).T
            Xn = TV + G_all @ U
            dx = float(np.sqrt(np.mean(np.sum((Xn - X) ** 2, axis=1))))
            dc = float(np.sqrt(np.mean(np.sum((C - C_prev) ** 2, axis=1)))) if C_prev is not None else float("inf")
            X, C_prev = Xn, C
            total += 1
            if dx < tol and dc < tol:  # the correspondences converged
                break
        per_stage.append(its)
    return X, {"field_iterations": total, "field_per_stage": per_stage, "field_centers": m, "field_samples": int(len(D)),
               "field_last_vertex_change_m": dx, "field_last_partner_change_m": dc,
               "field_covered_fraction": float(ok.mean()) if len(ok) else 0.0}


def arap_stage(prob, opts, X0: np.ndarray) -> tuple[np.ndarray, dict]:
    """The ARAP-regularised non-rigid ICP (see the module docstring), seeded by X0.

    Args:
        prob: The :class:`~.problem.Problem` (calibrated scan, template, FDP pairs).
        opts: The :class:`~.problem.AdaptOptions` (``refine_stiffness``, ``refine_iterations``).
        X0: The levels' result [m], shape (n, 3), float64.

    Returns:
        (vertices [m] (n, 3) float64, info dict: iterations, per-stage iterations, the RMS
        vertex / partner change at the end [m], covered vertex fraction).
    """
    TV, TF = prob.TV, prob.TF
    n = len(TV)
    E, w = cotan_edge_weights(TV, TF)
    L = _laplacian(n, E, w)
    area = vertex_areas(TV, TF)
    area = area / max(float(area[area > 0].mean()), 1e-300)
    # FDPs as barycentric rows of B
    cp = prob.tmpl_q.closest_point(prob.P_fdp)
    rows = np.repeat(np.arange(len(cp.face)), 3)
    B = sp.csr_matrix((cp.bary.ravel(), (rows, TF[cp.face].ravel())), shape=(len(cp.face), n))
    mu = 10.0 * float(np.mean(area[TF[cp.face].ravel()])) if len(cp.face) else 0.0
    BtB = (B.T @ B).tocsr() * mu
    BtQ = mu * (B.T @ prob.Q_fdp)
    max_dist = 0.05 * prob.W
    tol = CONVERGED * prob.W
    X = np.asarray(X0, dtype=np.float64).copy()
    its_per_stage = []
    total = 0
    stiff = tuple(opts.refine_stiffness)
    per_stage = max(1, int(np.ceil(opts.refine_iterations / len(stiff))))
    C_prev = None
    dx = dc = float("nan")
    ok = np.zeros(n, bool)
    for lam in stiff:
        C, ns, ok = _partners(prob, X, max_dist)
        a = np.where(ok, area, 0.0)
        A = (lam * L + sp.diags(a) + BtB).tocsc()
        lu = spla.splu(A, permc_spec="MMD_AT_PLUS_A")
        its = 0
        for its in range(1, per_stage + 1):
            if its > 1:
                C, ns, ok_now = _partners(prob, X, max_dist)
                ok_now &= ok  # the stage's matrix fixes which vertices have data
                C = np.where(ok_now[:, None], C, X)
            else:
                ok_now = ok
            R = _rotations(TV, X, E, w)
            # point-to-plane as a point target in the scan's tangent plane
            Ct = X + np.einsum("kd,kd->k", ns, C - X)[:, None] * ns
            Ct = np.where(ok_now[:, None], Ct, X)
            rhs = lam * _arap_rhs(TV, R, E, w) + a[:, None] * Ct + BtQ
            Xn = np.column_stack([lu.solve(rhs[:, d]) for d in range(3)])
            dx = float(np.sqrt(np.mean(np.sum((Xn - X) ** 2, axis=1))))
            dc = float(np.sqrt(np.mean(np.sum((C[ok_now] - C_prev[ok_now]) ** 2, axis=1)))) if C_prev is not None and ok_now.any() else float("inf")
            X = Xn
            C_prev = C
            total += 1
            if dx < tol and dc < tol:  # correspondences converged
                break
        its_per_stage.append(its)
    return X, {"iterations": total, "per_stage": its_per_stage, "stiffness": list(stiff),
               "last_vertex_change_m": dx, "last_partner_change_m": dc, "covered_fraction": float(ok.mean())}
