"""Radial basis function displacement fields (thesis Sec. 4.4).

Both fields map template points ``p`` to displacements ``d = f(p) - p`` so that
``p + d(p_i) = q_i`` at the feature-point (FP) pairs ``(p_i, q_i)``; fitting the displacement
instead of the position is the same system (the affine part absorbs the identity).

- :func:`fit_rbf`: approach #1, global ``phi(r) = r`` with an affine term and the side
  conditions ``sum c_i = 0``, ``sum c_i p_i^T = 0`` (Eq. 4.4.1-4.4.4), dense solve, the error
  coefficient ``rho`` of Eq. 4.4.3 as a smoothing regulariser.
- :func:`fit_csrbf`: approach #2, Wendland's compactly supported
  ``phi(r) = (1 - r)_+^4 (4 r + 1)`` with support ``sigma`` and a local quadric ``g_j`` per
  centre (Eq. 4.4.5-4.4.10); the sparse system of Eq. 4.4.7 is solved by a preconditioned
  Krylov method (the thesis: preconditioned BiCG).

Inputs are plain float64 arrays in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

__all__ = [
    "CSRBFField",
    "Quadrics",
    "RBFField",
    "fit_csrbf",
    "fit_local_quadrics",
    "fit_rbf",
    "wendland",
]


def _check_pairs(P, D) -> tuple[np.ndarray, np.ndarray]:
    P = np.asarray(P, dtype=np.float64)
    D = np.asarray(D, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"P must have shape (m, 3), got {P.shape}")
    if D.shape != P.shape:
        raise ValueError(f"D must have shape {P.shape} like P, got {D.shape}")
    if not (np.isfinite(P).all() and np.isfinite(D).all()):
        raise ValueError("P and D must be finite")
    return P, D


def _check_X(X) -> np.ndarray:
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"X must have shape (k, 3), got {X.shape}")
    return X


# ----------------------------------------------------------------------------------------
# approach #1: global RBF, phi(r) = r


@dataclass
class RBFField:
    """Global RBF displacement field, Eq. 4.4.4: ``d(x) = sum_j c_j |x - p_j| + A^T [x, 1]``.

    Attributes:
        centers: Centres p_j [m], shape (m, 3), float64.
        coeffs: Coefficients c_j [dimensionless, m/m], shape (m, 3), float64.
        affine: Affine part, rows (R^T; t^T) of Eq. 4.4.2, shape (4, 3), float64.
        rho: The error coefficient used (Eq. 4.4.3) [m].
    """

    centers: np.ndarray
    coeffs: np.ndarray
    affine: np.ndarray
    rho: float = 0.0

    def __call__(self, X, *, chunk: int = 4096) -> np.ndarray:
        """Displacements at X, shape (k, 3) [m] -> (k, 3) [m]."""
        X = _check_X(X)
        out = X @ self.affine[:3] + self.affine[3]
        for s in range(0, len(X), chunk):
            Xs = X[s : s + chunk]
            out[s : s + chunk] += cdist(Xs, self.centers) @ self.coeffs  # phi(r) = r
        return out


def fit_rbf(P, D, *, rho: float = 0.0) -> RBFField:
    """Global RBF with ``phi(r) = r`` and an affine term (Eq. 4.4.1-4.4.4).

    Solves the dense symmetric system ``A* X = B`` of Eq. 4.4.3::

        [P - rho I   Q] [c]   [d]
        [Q^T         0] [a] = [0],   P_ij = |p_i - p_j|, Q = [p_i^T 1]

    ``rho >= 0`` [m] smooths: 0 interpolates the pairs exactly; larger values trade fidelity
    at the pairs for a smoother field (the thesis's remedy for noisy scans). With
    ``phi(r) = r`` the matrix ``P`` is conditionally negative definite, so ``- rho I`` is the
    regularising sign.

    Args:
        P: Centres (template FPs) [m], shape (m, 3), float64; m >= 4, not coplanar.
        D: Displacements at the centres (q_i - p_i) [m], shape (m, 3), float64.
        rho: Error coefficient [m], >= 0.

    Returns:
        :class:`RBFField`; an affine D is reproduced exactly (all c_j = 0).
    """
    P, D = _check_pairs(P, D)
    m = len(P)
    if m < 4:
        raise ValueError(f"the global RBF needs at least 4 centres, got {m}")
    if rho < 0:
        raise ValueError(f"rho must be >= 0, got {rho}")
    # centre and scale for conditioning; the affine part is mapped back afterwards
    mu = P.mean(axis=0)
    L = float(np.sqrt(((P - mu) ** 2).sum(1).mean())) or 1.0
    Pn = (P - mu) / L
    A = np.zeros((m + 4, m + 4))
    A[:m, :m] = np.linalg.norm(Pn[:, None] - Pn[None], axis=2) - (rho / L) * np.eye(m)
    A[:m, m : m + 3] = Pn
    A[:m, m + 3] = 1.0
    A[m:, :m] = A[:m, m:].T
    B = np.zeros((m + 4, 3))
    B[:m] = D
    try:
        X = scipy.linalg.solve(A, B, assume_a="sym", check_finite=False)
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        X = np.linalg.lstsq(A, B, rcond=None)[0]
    c = X[:m] / L  # phi(|x-p|/L) = |x-p| / L
    Rn = X[m : m + 3]  # acts on (x - mu) / L
    t = X[m + 3]
    affine = np.zeros((4, 3))
    affine[:3] = Rn / L
    affine[3] = t - mu @ Rn / L
    return RBFField(centers=P.copy(), coeffs=c, affine=affine, rho=float(rho))


# ----------------------------------------------------------------------------------------
# approach #2: CSRBF with local quadrics


def wendland(r) -> np.ndarray:
    """Wendland's C2 function ``phi(r) = (1 - r)_+^4 (4 r + 1)`` (Eq. 4.4.5, 4.4.6); r >= 0."""
    r = np.asarray(r, dtype=np.float64)
    t = np.clip(1.0 - r, 0.0, None)
    return t**4 * (4.0 * r + 1.0)


@dataclass
class Quadrics:
    """Local quadrics ``w = h(u, v) = A u^2 + 2 B u v + C v^2`` (Eq. 4.4.8) at m centres.

    Attributes:
        frames: Rows (u, v, w) of each local frame, w the unit normal, shape (m, 3, 3).
        abc: Coefficients (A, B, C) [1/m], shape (m, 3), float64.
    """

    frames: np.ndarray
    abc: np.ndarray

    def g(self, j: np.ndarray, X: np.ndarray, centers: np.ndarray) -> np.ndarray:
        """``g_j(x) = w - h(u, v)`` (Eq. 4.4.10) for pairs (j[k], X[k]) [m], shape (k,)."""
        local = np.einsum("kij,kj->ki", self.frames[j], X - centers[j])
        u, v, w = local[:, 0], local[:, 1], local[:, 2]
        A, B, C = self.abc[j].T
        return w - (A * u * u + 2.0 * B * u * v + C * v * v)


def _frames(normals: np.ndarray) -> np.ndarray:
    """Orthonormal rows (u, v, w) with w = normal, shape (m, 3, 3)."""
    w = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    a = np.where(np.abs(w[:, [0]]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    u = np.cross(a, w)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(w, u)
    return np.stack([u, v, w], axis=1)


def fit_local_quadrics(P, normals, sigma: float, *, pairs=None, ridge: float = 1e-8) -> Quadrics:
    """Weighted least-squares quadric at every centre (Eq. 4.4.8, 4.4.9).

    For centre p_i, in the frame (u, v, w) with w along its normal, minimise
    ``sum_j phi_sigma(|p_j - p_i|) (w_j - h(u_j, v_j))^2`` over (A, B, C), the sum over the
    other centres within the support. Fewer than 3 neighbours give a flat (zero) quadric.

    Args:
        P: Centres [m], shape (m, 3), float64.
        normals: Unit normals at the centres, shape (m, 3), float64.
        sigma: Support size [m].
        pairs: Optional (i, j, r) neighbour arrays within sigma (as computed by the caller).
        ridge: Relative Tikhonov term keeping the 3x3 normal equations regular.

    Returns:
        :class:`Quadrics`.
    """
    P = np.asarray(P, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    m = len(P)
    frames = _frames(normals)
    if pairs is None:
        tree = cKDTree(P)
        S = tree.sparse_distance_matrix(tree, sigma, output_type="coo_matrix")
        i, j, r = S.row, S.col, S.data
    else:
        i, j, r = pairs
    keep = i != j
    i, j, r = i[keep], j[keep], r[keep]
    wgt = wendland(r / sigma)
    local = np.einsum("kab,kb->ka", frames[i], P[j] - P[i])
    u, v, w = local[:, 0], local[:, 1], local[:, 2]
    M = np.stack([u * u, 2.0 * u * v, v * v], axis=1)  # (k, 3)
    # normal equations per centre: sum wgt M^T M, sum wgt M^T w
    G = np.zeros((m, 3, 3))
    b = np.zeros((m, 3))
    MM = wgt[:, None, None] * M[:, :, None] * M[:, None, :]
    np.add.at(G, i, MM)
    np.add.at(b, i, wgt[:, None] * M * w[:, None])
    count = np.bincount(i, minlength=m)
    scale = np.trace(G, axis1=1, axis2=2)[:, None, None]
    G = G + (ridge * scale + 1e-300) * np.eye(3)
    abc = np.linalg.solve(G, b[:, :, None])[:, :, 0]
    abc[count < 3] = 0.0
    return Quadrics(frames=frames, abc=abc)


@dataclass
class CSRBFField:
    """CSRBF displacement field, Eq. 4.4.5 / 4.5.5::

        d(x) = sum_j (g_j(x) n_j + c_j) phi(|x - p_j| / sigma)

    The thesis writes the quadric term as ``g_j(x) I``; for a vector field we read it as
    ``g_j(x) n_j``, the offset of x from the local quadric (Eq. 4.4.10) along the centre's
    normal, which vanishes on the local surface. ``quadrics=None`` drops the term.

    Attributes:
        centers: Centres p_j [m], shape (m, 3), float64.
        coeffs: c_j [m], shape (m, 3), float64.
        sigma: Support size [m].
        quadrics: Local quadrics or None.
        iterations: Krylov iterations per right-hand side column, shape (3,), int.
        residual: Relative residual of the solve (max over columns).
    """

    centers: np.ndarray
    coeffs: np.ndarray
    sigma: float
    quadrics: Quadrics | None = None
    iterations: np.ndarray | None = None
    residual: float = 0.0

    def __post_init__(self):
        self._tree = cKDTree(self.centers)

    def __call__(self, X) -> np.ndarray:
        """Displacements at X, shape (k, 3) [m] -> (k, 3) [m]; zero outside every support."""
        X = _check_X(X)
        out = np.zeros_like(X)
        if len(X) == 0 or len(self.centers) == 0:
            return out
        S = cKDTree(X).sparse_distance_matrix(self._tree, self.sigma, output_type="coo_matrix")
        k, j, r = S.row, S.col, S.data  # the coo output keeps exact zeros (x == p_j)
        phi = wendland(r / self.sigma)
        val = self.coeffs[j]
        if self.quadrics is not None:
            val = val + self.quadrics.g(j, X[k], self.centers)[:, None] * self.quadrics.frames[j, 2]
        contrib = phi[:, None] * val
        for d in range(3):
            out[:, d] = np.bincount(k, weights=contrib[:, d], minlength=len(X))
        return out


def _krylov(A: sp.csr_matrix, B: np.ndarray, *, solver: str, preconditioner: str, tol: float, maxiter: int):
    n = A.shape[0]
    if preconditioner == "jacobi":
        dinv = 1.0 / A.diagonal()
        M = spla.LinearOperator((n, n), matvec=lambda x: dinv * x.ravel(), rmatvec=lambda x: dinv * x.ravel())
    elif preconditioner == "ilu":
        ilu = spla.spilu(A.tocsc(), drop_tol=1e-4, fill_factor=10)
        M = spla.LinearOperator((n, n), matvec=ilu.solve, rmatvec=lambda x: ilu.solve(x, "T"))
    elif preconditioner == "none":
        M = None
    else:
        raise ValueError(f"preconditioner must be 'jacobi', 'ilu' or 'none', got {preconditioner!r}")
    fn = {"cg": spla.cg, "bicgstab": spla.bicgstab, "gmres": spla.gmres, "bicg": spla.bicg}.get(solver)
    if fn is None:
        raise ValueError(f"solver must be 'cg', 'bicg', 'bicgstab' or 'gmres', got {solver!r}")
    X = np.zeros_like(B)
    its = np.zeros(B.shape[1], dtype=np.int64)
    res = 0.0
    for c in range(B.shape[1]):
        b = B[:, c]
        nb = np.linalg.norm(b)
        if nb == 0:
            continue
        count = [0]

        def cb(_):
            count[0] += 1

        kw = dict(rtol=tol, maxiter=maxiter, M=M, callback=cb)
        if solver == "gmres":
            kw["callback_type"] = "pr_norm"
        x, info = fn(A, b, **kw)
        X[:, c] = x
        its[c] = count[0]
        res = max(res, float(np.linalg.norm(A @ x - b) / nb))
    return X, its, res


def fit_csrbf(
    P,
    D,
    sigma: float,
    *,
    normals=None,
    smoothing: float = 0.0,
    solver: str = "cg",
    preconditioner: str = "jacobi",
    tol: float = 1e-8,
    maxiter: int = 2000,
) -> CSRBFField:
    """Compactly supported RBF with local quadrics (Eq. 4.4.5-4.4.10).

    Two steps (Sec. 4.4.2): the quadrics ``g_j`` are fitted at each centre to the
    neighbouring centres (Eq. 4.4.8, 4.4.9; needs ``normals``), then the coefficients solve
    the sparse system of Eq. 4.4.7::

        sum_j c_j phi_sigma(|p_i - p_j|) = d_i - sum_j g_j(p_i) n_j phi_sigma(|p_i - p_j|)

    The Wendland matrix is symmetric positive definite, so CG with a Jacobi preconditioner
    is the default; ``solver`` picks BiCG (the thesis), BiCGSTAB or GMRES, and
    ``preconditioner`` Jacobi, ILU or none. The initial guess is c = 0 (as in the thesis).

    Args:
        P: Centres (template FPs) [m], shape (m, 3), float64.
        D: Displacements to interpolate [m], shape (m, 3), float64.
        sigma: Support size [m], > 0.
        normals: Unit template normals at the centres, shape (m, 3), or None (no quadric term).
        smoothing: Added to the diagonal (relative to phi(0) = 1); 0 interpolates.
        solver, preconditioner, tol, maxiter: Krylov settings.

    Returns:
        :class:`CSRBFField` with the iteration counts.
    """
    P, D = _check_pairs(P, D)
    sigma = float(sigma)
    if not sigma > 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    m = len(P)
    tree = cKDTree(P)
    S = tree.sparse_distance_matrix(tree, sigma, output_type="coo_matrix")
    i, j, r = S.row, S.col, S.data  # includes the diagonal (r = 0)
    phi = wendland(r / sigma)
    A = sp.csr_matrix((phi + np.where(i == j, smoothing, 0.0), (i, j)), shape=(m, m))
    rhs = D.copy()
    quadrics = None
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != P.shape:
            raise ValueError(f"normals must have shape {P.shape}, got {normals.shape}")
        quadrics = fit_local_quadrics(P, normals, sigma, pairs=(i, j, r))
        gij = quadrics.g(j, P[i], P)  # g_j(p_i)
        term = (gij * phi)[:, None] * quadrics.frames[j, 2]
        for d in range(3):
            rhs[:, d] -= np.bincount(i, weights=term[:, d], minlength=m)
    C, its, res = _krylov(A, rhs, solver=solver, preconditioner=preconditioner, tol=tol, maxiter=maxiter)
    return CSRBFField(centers=P.copy(), coeffs=C, sigma=sigma, quadrics=quadrics, iterations=its, residual=res)
