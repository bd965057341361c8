"""Feature-point (FP) search of the refinement levels (thesis Sec. 4.5.1, 4.5.2).

- Feature mesh expansion (Sec. 4.5.1): every feature triangle is split at its barycentre; a
  ray from the barycentre along the triangle normal hits the deformed template (giving the
  template point p through the hit's face and barycentric weights) and the scan (giving q).
  The initial feature mesh triangulates the FDPs that lie on the skin plus a few
  farthest-point samples of the template (whose scan partners come from a ray along the
  deformed template's normal): the thesis has up to 84 FDPs over the whole head, a scan may
  carry a dozen on the face, and a feature mesh must cover the head (Sec. 4.5.2's own
  remark). The triangulation is a spherical Delaunay (convex hull of the directions from the
  head centre), so it wraps around the head.
- Curvature-based FP search (Sec. 4.5.2): vertices of the scan with the largest Meyer mean
  curvature (Eq. 4.5.1, 4.5.2; computed on a lightly smoothed copy so that scanner noise does
  not win) inside a bounding box from the outer eye corners across and from the top of the
  head to the bottom of the mouth; a ray along the scan vertex normal finds the template point.

Ray hits farther than 1/10 of the head width are rejected (Sec. 5.2.1), as are hits whose
template and scan normals disagree.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

from ..geometry.surface import MeshQuery, boundary_vertices, face_normals, mean_curvature, vertex_normals
from .metrics import _on_boundary

__all__ = ["FPSet", "FeatureSearch"]


def farthest_points(V: np.ndarray, seeds: np.ndarray, count: int) -> np.ndarray:
    """Farthest-point sampling of ``count`` vertices of V [m], shape (n, 3), starting from the
    points ``seeds`` [m], shape (s, 3); returns vertex indices, shape (count,), int64."""
    d = np.full(len(V), np.inf)
    for s in seeds:
        d = np.minimum(d, np.linalg.norm(V - s, axis=1))
    out = []
    for _ in range(count):
        i = int(np.argmax(d))
        out.append(i)
        d = np.minimum(d, np.linalg.norm(V - V[i], axis=1))
    return np.asarray(out, dtype=np.int64)


def sphere_triangulation(P: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Delaunay triangulation on the sphere of directions of P [m], shape (k, 3), around
    ``center`` (their convex hull), oriented outward; shape (t, 3), int64."""
    D = P - center
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    hull = ConvexHull(D)
    T = hull.simplices.astype(np.int64)
    n = np.cross(D[T[:, 1]] - D[T[:, 0]], D[T[:, 2]] - D[T[:, 0]])
    flip = np.einsum("kd,kd->k", n, D[T].mean(1)) < 0
    T[flip] = T[flip][:, ::-1]
    return T


def uniform_smooth(V: np.ndarray, F: np.ndarray, steps: int) -> np.ndarray:
    """``steps`` rounds of half-step uniform Laplacian smoothing of V [m], boundary fixed."""
    import scipy.sparse as sp

    n = len(V)
    i = np.concatenate([F[:, 0], F[:, 1], F[:, 2], F[:, 1], F[:, 2], F[:, 0]])
    j = np.concatenate([F[:, 1], F[:, 2], F[:, 0], F[:, 0], F[:, 1], F[:, 2]])
    A = sp.csr_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    A.data[:] = 1.0
    deg = np.asarray(A.sum(1)).ravel()
    deg[deg == 0] = 1.0
    W = sp.diags(1.0 / deg) @ A
    bnd = boundary_vertices(F, n)
    X = V.copy()
    for _ in range(steps):
        Y = 0.5 * X + 0.5 * (W @ X)
        Y[bnd] = X[bnd]
        X = Y
    return X


def thin(P: np.ndarray, count: int, spacing: float) -> np.ndarray:
    """Greedy selection, in the given order, of up to ``count`` points of P [m] at least
    ``spacing`` [m] apart; returns their indices, int64."""
    if len(P) == 0 or count <= 0:
        return np.zeros(0, dtype=np.int64)
    tree = cKDTree(P)
    blocked = np.zeros(len(P), dtype=bool)
    out = []
    for i in range(len(P)):
        if blocked[i]:
            continue
        out.append(i)
        if len(out) >= count:
            break
        blocked[tree.query_ball_point(P[i], spacing)] = True
    return np.asarray(out, dtype=np.int64)


def curvature_candidates(Q: np.ndarray, SF: np.ndarray, Q_lm: dict, H: np.ndarray | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Scan vertices in the eyes..mouth box, and their order by decreasing |kappa_H| (Sec. 4.5.2).

    Args:
        Q: Calibrated scan vertices [m], shape (k, 3), float64 (template frame: y up, z front).
        SF: Scan triangles, shape (l, 3), int64.
        Q_lm: FDP id -> calibrated scan position [m], shape (3,).
        H: Optional precomputed mean curvature of the smoothed scan [1/m], shape (k,).

    Returns:
        (vertex indices in the box, an ordering of them by decreasing Meyer |kappa_H|
        (Eq. 4.5.1, 4.5.2) on a lightly smoothed copy), both int64.
    """
    xs = [Q_lm[k][0] for k in ("3.7", "3.12", "3.8", "3.11") if k in Q_lm]
    ys = [Q_lm[k][1] for k in ("8.2", "2.3", "8.3", "8.4", "2.2", "8.1") if k in Q_lm]
    if len(xs) < 2 or not ys:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    x0, x1 = min(xs), max(xs)
    y0 = min(ys)
    inside = (Q[:, 0] >= x0) & (Q[:, 0] <= x1) & (Q[:, 1] >= y0)
    if not inside.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if H is None:
        H = mean_curvature(uniform_smooth(Q, SF, 3), SF)
    N = vertex_normals(Q, SF)
    inside &= np.isfinite(H) & (N[:, 2] > 0.0)  # only the front (facing +z in the template frame)
    idx = np.flatnonzero(inside)
    order = np.argsort(-np.abs(H[idx]), kind="stable")
    return idx, order


class FPSet:
    """Feature-point pairs: template points ``p`` [m] (k, 3), calibrated scan points ``q`` [m]
    (k, 3), and ``src`` (k,) int8: 0 FDP, 1 coverage sample, 2 feature mesh, 3 curvature."""

    def __init__(self):
        self.p = np.zeros((0, 3))
        self.q = np.zeros((0, 3))
        self.src = np.zeros(0, dtype=np.int8)

    def add(self, p, q, src: int, min_dist: float) -> np.ndarray:
        """Add pairs whose p is farther than min_dist from every existing p; returns the kept mask."""
        p = np.asarray(p).reshape(-1, 3)
        q = np.asarray(q).reshape(-1, 3)
        keep = np.ones(len(p), dtype=bool)
        if len(self.p) and len(p):
            d, _ = cKDTree(self.p).query(p)
            keep &= d > min_dist
        if keep.sum() > 1:  # among themselves
            idx = np.flatnonzero(keep)
            pairs = cKDTree(p[idx]).query_pairs(min_dist, output_type="ndarray")
            if len(pairs):
                keep[idx[np.unique(pairs[:, 1])]] = False
        self.p = np.concatenate([self.p, p[keep]])
        self.q = np.concatenate([self.q, q[keep]])
        self.src = np.concatenate([self.src, np.full(keep.sum(), src, dtype=np.int8)])
        return keep

    def __len__(self):
        return len(self.p)


class FeatureSearch:
    """The growing FP sets of the refinement levels: the feature mesh (Sec. 4.5.1), its
    automatic FPs with their scan partners, and the curvature FPs (Sec. 4.5.2).

    Args:
        prob: The :class:`~.problem.Problem`.
        opts: The :class:`~.problem.AdaptOptions`.
        Q_lm: FDP id -> calibrated scan position [m] (for the curvature box).
    """

    def __init__(self, prob, opts, Q_lm: dict):
        self.prob = prob
        self.opts = opts
        TV, W = prob.TV, prob.W
        self.min_sep = 1e-3 * W
        on_skin = prob.fdp_skin_dist < 0.02 * W
        n_cov = int(opts.coverage_points)
        cov = farthest_points(TV, prob.P_fdp[on_skin], n_cov) if n_cov > 0 else np.zeros(0, np.int64)
        self.fm_p = np.concatenate([prob.P_fdp[on_skin], TV[cov]])  # feature mesh vertices on the template
        self.fm_T = (sphere_triangulation(self.fm_p, TV.mean(axis=0)) if len(self.fm_p) >= 4
                     else np.zeros((0, 3), np.int64))
        # automatic FPs: template point p (fixed) and its scan partner q (re-found each level
        # with correspondence="closest", fixed at discovery with "ray")
        self.auto_p = TV[cov].copy()
        self.auto_q = np.full_like(self.auto_p, np.nan)
        self.auto_src = np.full(len(self.auto_p), 1, dtype=np.int8)
        self.auto_cp = None
        # curvature candidates on the scan (Sec. 4.5.2), computed once
        idx, order = curvature_candidates(prob.Q, prob.SF, Q_lm, prob.scan_curvature())
        self.curv_sorted = idx[order]  # scan vertices by decreasing |kappa_H|
        self.curv_taken = np.zeros(len(self.curv_sorted), dtype=bool)
        self.curv_p = np.zeros((0, 3))
        self.curv_q = np.zeros((0, 3))
        self.n_curv = int(opts.curvature_points)

    @property
    def count(self) -> int:
        """Automatic plus curvature FPs found so far."""
        return len(self.auto_p) + len(self.curv_p)

    def expand_feature_mesh(self, displacement, defo_q: MeshQuery) -> int:
        """Sec. 4.5.1: split each feature triangle at its barycentre, found on the deformed
        template by a ray along the deformed feature triangle's normal; returns the new FP count.

        Args:
            displacement: The current displacement field, template points (k, 3) [m] -> (k, 3) [m].
            defo_q: BVH query of the currently deformed template.
        """
        if not len(self.fm_T):
            return 0
        prob = self.prob
        TV, TF = prob.TV, prob.TF
        fm_d = self.fm_p + displacement(self.fm_p)
        A, B, C = fm_d[self.fm_T[:, 0]], fm_d[self.fm_T[:, 1]], fm_d[self.fm_T[:, 2]]
        o = (A + B + C) / 3.0
        n = np.cross(B - A, C - A)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        ht = defo_q.ray_cast(o, n, prob.reject, both_directions=True)
        f_t = np.maximum(ht.face, 0)
        p_new = np.einsum("kc,kcd->kd", np.nan_to_num(ht.bary), TV[TF[f_t]])
        ok = ht.hit.copy()
        if ok.any():  # not on top of an existing FP
            allp = np.concatenate([prob.P_fdp, self.auto_p, self.curv_p])
            dmin, _ = cKDTree(allp).query(p_new[ok])
            ok[np.flatnonzero(ok)[dmin <= self.min_sep]] = False
        new = int(ok.sum())
        base = len(self.fm_p)
        self.fm_p = np.concatenate([self.fm_p, p_new[ok]])
        tk = self.fm_T[ok]
        c = base + np.arange(len(tk))
        self.fm_T = np.concatenate(
            [np.stack([tk[:, 0], tk[:, 1], c], 1), np.stack([tk[:, 1], tk[:, 2], c], 1), np.stack([tk[:, 2], tk[:, 0], c], 1)]
        )
        self.auto_p = np.concatenate([self.auto_p, p_new[ok]])
        self.auto_q = np.concatenate([self.auto_q, np.full((new, 3), np.nan)])
        self.auto_src = np.concatenate([self.auto_src, np.full(new, 2, dtype=np.int8)])
        return new

    def locate(self) -> None:
        """Find the automatic FPs on the template (face and barycentric weights), once per level."""
        self.auto_cp = self.prob.tmpl_q.closest_point(self.auto_p)

    def update_partners(self, V: np.ndarray) -> None:
        """Scan partners of the automatic FPs on the template deformed to V [m], shape (n, 3)."""
        prob, cp = self.prob, self.auto_cp
        Pd = np.einsum("kc,kcd->kd", cp.bary, V[prob.TF[cp.face]])
        Nd = face_normals(V, prob.TF[cp.face])
        if self.opts.correspondence == "ray":
            q = self.auto_q.copy()
            todo = np.flatnonzero(~np.isfinite(q[:, 0]))
            if len(todo):
                h = prob.scan_q.ray_cast(Pd[todo], Nd[todo], prob.reject, both_directions=True)
                ok = h.hit & (np.einsum("kd,kd->k", prob.scan_N_face[np.maximum(h.face, 0)], Nd[todo])
                              > self.opts.normal_agreement)
                q[todo[ok]] = h.points[ok]
            self.auto_q = q
            return
        cp2 = prob.scan_q.closest_point(Pd, prob.reject)
        q = np.full_like(Pd, np.nan)
        ok = cp2.face >= 0
        ok[ok] &= np.einsum("kd,kd->k", prob.scan_N_face[cp2.face[ok]], Nd[ok]) > self.opts.normal_agreement
        ok &= ~_on_boundary(prob.scan_q, cp2)
        q[ok] = cp2.points[ok]
        self.auto_q = q

    def search_curvature(self, level: int, V: np.ndarray, defo_q: MeshQuery) -> int:
        """Sec. 4.5.2: the next highest-curvature scan vertices (thinned to a spacing that halves
        per level) cast a ray along their normal onto the template deformed to V; returns the
        new FP count. The count sought doubles per level."""
        if self.n_curv <= 0 or not len(self.curv_sorted):
            return 0
        prob = self.prob
        TV, TF, Q = prob.TV, prob.TF, prob.Q
        avail = np.flatnonzero(~self.curv_taken)
        spacing = 0.02 * prob.W / 2 ** (level - 2)
        chosen = avail[thin(Q[self.curv_sorted[avail]], self.n_curv, spacing)]
        self.curv_taken[chosen] = True
        vi = self.curv_sorted[chosen]
        SN = vertex_normals(Q, prob.SF)[vi]
        ht = defo_q.ray_cast(Q[vi], SN, prob.reject, both_directions=True)
        f_t = np.maximum(ht.face, 0)
        ok = ht.hit & (np.einsum("kd,kd->k", face_normals(V, TF[f_t]), SN) > self.opts.normal_agreement)
        p_new = np.einsum("kc,kcd->kd", np.nan_to_num(ht.bary), TV[TF[f_t]])
        self.curv_p = np.concatenate([self.curv_p, p_new[ok]])
        self.curv_q = np.concatenate([self.curv_q, Q[vi[ok]]])
        self.n_curv *= 2
        return int(ok.sum())

    def fp_set(self) -> FPSet:
        """This level's FP set: FDPs, curvature FPs, then automatic FPs with a partner."""
        fps = FPSet()
        fps.add(self.prob.P_fdp, self.prob.Q_fdp, 0, self.min_sep)
        fps.add(self.curv_p, self.curv_q, 3, self.min_sep)
        good = np.isfinite(self.auto_q[:, 0])
        for src in (1, 2):
            sel = good & (self.auto_src == src)
            fps.add(self.auto_p[sel], self.auto_q[sel], src, self.min_sep)
        return fps
