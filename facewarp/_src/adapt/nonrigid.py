"""Non-rigid stages after the thesis's levels: vertices land on the scan without sliding.

Not steps of the thesis. The multi-level RBF (Sec. 4.5) interpolates dense FP pairs whose scan
partners are closest points; nothing in it penalises a vertex sliding *along* the scan, so away
from the FDPs the template's vertices drift tangentially: the surface lands, the correspondence
does not (on random unseen faces, E_v RMS 3-10 mm with distance-to-scan 0). Two stages follow
the levels (``AdaptOptions.refine = "field+land"``):

1. :func:`field_stage`: one smooth 3D displacement field, the thesis's own global RBF
   (``phi(r) = r`` with an affine part, Eq. 4.4.1-4.4.4), fitted by regularised least squares
   to *point-to-plane* pairs (Chen & Medioni 1992) over the whole template instead of
   interpolating point pairs: a pair constrains only the distance along the scan's normal, the
   tangential part comes from the smoothest field (its thin-plate energy in 3D, Duchon 1977,
   Carr et al. 2001) that puts the template on the scan's tangent planes and its FDPs on
   theirs. The closest points are re-found each iteration with normal compatibility and border
   rejection (as in Amberg et al. 2007's optimal-step non-rigid ICP) and the stiffness falls in
   stages; a stage ends when the correspondences converge (the RMS change of the vertices and
   of their scan partners below 1e-4 of the head width), not only when E_d stops falling.
2. :func:`land_stage`: the field's surface moved along its own normals by a smooth offset field
   (point-to-plane data + a cotangent Dirichlet term) onto the scan: detail the field cannot
   carry, no tangential motion at all, no per-vertex copy of scanner noise.

Vertices without a valid scan partner (holes, parts a partial scan does not cover: neck,
scalp) have no data term: the field extrapolates smoothly into them and the landing offsets
extend harmonically.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..geometry.surface import vertex_normals
from .metrics import _on_boundary

__all__ = ["cotan_edge_weights", "field_stage", "land_stage", "vertex_areas"]

NORMAL_COS = 0.5
"""Smallest cosine between the scan normal and the deformed template normal at a pair (60 deg)."""

CONVERGED = 1e-4
"""A stage stops when the RMS change of vertices and partners is below this times the head width."""


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
    """The weighted graph Laplacian L (n, n): (L x)_i = sum_j w_ij (x_i - x_j) over the edges E (e, 2)."""
    i, j = E[:, 0], E[:, 1]
    L = sp.coo_matrix((np.concatenate([-w, -w]), (np.concatenate([i, j]), np.concatenate([j, i]))), shape=(n, n)).tocsr()
    return L + sp.diags(np.bincount(np.concatenate([i, j]), weights=np.concatenate([w, w]), minlength=n))


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
    from scipy.linalg.blas import dsyrk as syrk
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
    mu = float(opts.field_fdp_weight)
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
            # point-to-plane rows n_i^T (G_i u_x, G_i u_y, G_i u_z) of the paired samples: B (pairs, 3k);
            # the normal matrix B^T B by one symmetric rank-k update (BLAS syrk: half a product's work)
            G_ok = G_D[ok]
            B = np.concatenate([ns[ok, a, None] * G_ok for a in range(3)], axis=1)
            M = syrk(1.0, B, trans=1, lower=0) if len(B) else np.zeros((3 * k, 3 * k))
            M = np.triu(M) + np.triu(M, 1).T
            b = (B.T @ r[ok]) if len(B) else np.zeros(3 * k)
            for a in range(3):
                sa = slice(a * k, (a + 1) * k)
                b[sa] += b_fdp[:, a]
                M[sa, sa] += M_fdp
                M[a * k:a * k + k - 4, a * k:a * k + k - 4] += gamma * Rg
            M[np.diag_indices_from(M)] += 1e-9 * float(np.mean(np.diag(M))) + 1e-300  # keeps an unconstrained direction finite
            try:
                U = cho_solve(cho_factor(M), b).reshape(3, k).T
            except np.linalg.LinAlgError:
                U = np.linalg.lstsq(M, b, rcond=None)[0].reshape(3, k).T
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


def land_stage(prob, opts, Y: np.ndarray) -> tuple[np.ndarray, dict]:
    """Land the field's result on the scan by smooth offsets along its normals (no sliding).

    Each vertex moves only along its normal ``N_i`` (of the field's surface Y):
    ``x_i = y_i + t_i N_i``, with the scalar offsets minimising::

        sum_i a_i (n_i . (y_i + t_i N_i - c_i))^2 + lambda sum_(i,j) w_ij (t_i - t_j)^2

    (point-to-plane data to the closest scan point ``c_i`` with scan normal ``n_i``, and the
    cotangent Dirichlet energy of the offset field, Pinkall & Polthier 1993). As no vertex moves
    tangentially, the field's correspondence is kept; the Dirichlet term spreads the offsets
    smoothly, so scanner noise is not copied vertex by vertex and vertices without a scan
    partner (holes, parts a partial scan lacks) follow their neighbours (a harmonic extension).
    A sparse SPD solve per iteration (closest points, solve) until the offsets converge.

    Args:
        prob: The :class:`~.problem.Problem`.
        opts: The :class:`~.problem.AdaptOptions` (``land_smoothing`` is lambda, ``land_iterations``).
        Y: The field's result [m], shape (n, 3), float64.

    Returns:
        (vertices [m] (n, 3) float64, info dict).
    """
    TV, TF = prob.TV, prob.TF
    n = len(TV)
    E, w = cotan_edge_weights(Y, TF)
    L = _laplacian(n, E, w)
    area = vertex_areas(Y, TF)
    area = area / max(float(area[area > 0].mean()), 1e-300)
    N = vertex_normals(Y, TF)
    lam = float(opts.land_smoothing)
    max_dist = 0.02 * prob.W
    t = np.zeros(n)
    its = 0
    dt = float("nan")
    ok = np.zeros(n, bool)
    for its in range(1, int(opts.land_iterations) + 1):
        X = Y + t[:, None] * N
        cp = prob.scan_q.closest_point(X, max_dist)
        ok = cp.face >= 0
        ns = prob.scan_N_face[np.maximum(cp.face, 0)]
        ok &= np.einsum("kd,kd->k", ns, N) > NORMAL_COS
        ok &= ~_on_boundary(prob.scan_q, cp)
        g = np.where(ok, np.einsum("kd,kd->k", ns, N), 0.0)  # d(residual)/dt
        r = np.where(ok, np.einsum("kd,kd->k", ns, np.where(ok[:, None], cp.points, 0.0) - Y), 0.0)
        A = (sp.diags(area * g * g + 1e-9) + lam * L).tocsc()
        tn = spla.spsolve(A, area * g * r)
        dt = float(np.sqrt(np.mean((tn - t) ** 2)))
        t = tn
        if dt < CONVERGED * prob.W:
            break
    X = Y + t[:, None] * N
    return X, {"land_iterations": its, "land_last_change_m": dt, "land_covered_fraction": float(ok.mean()),
               "land_offset_rms_m": float(np.sqrt(np.mean(t * t)))}
