"""Template-to-scan adaptation: calibration, then a multi-level RBF/CSRBF scheme (Sec. 4.5).

Pipeline of :func:`adapt` (template and scan in metres):

1. Calibration (Sec. 4.3.2, :mod:`calibrate`): a least-squares similarity takes the scan
   into the template's frame from >= 4 shared FDPs; everything below runs in that frame.
2. Level 1: global RBF (Eq. 4.4.1-4.4.4) on the FDP pairs, ``f^0`` (Eq. 4.5.3).
3. Each further level k collects new feature-point (FP) pairs:

   - feature mesh expansion (Sec. 4.5.1): every feature triangle is split at its barycentre;
     a ray from the barycentre along the triangle normal hits the deformed template (giving
     the template point p through the hit's face and barycentric weights) and the scan
     (giving q). The initial feature mesh triangulates the FDPs that lie on the skin plus a
     few farthest-point samples of the template (whose scan partners come from a ray along
     the deformed template's normal): the thesis has up to 84 FDPs over the whole head, a
     scan may carry a dozen on the face, and a feature mesh must cover the head (Sec.
     4.5.2's own remark). The triangulation is a spherical Delaunay (convex hull of the
     directions from the head centre), so it wraps around the head;
   - curvature-based FP search (Sec. 4.5.2): vertices of the scan with the largest Meyer
     mean curvature (Eq. 4.5.1, 4.5.2; computed on a lightly smoothed copy so that scanner
     noise does not win) inside a bounding box from the outer eye corners across and from the
     top of the head to the bottom of the mouth; a ray along the scan vertex normal finds
     the template point.

   Ray hits farther than 1/10 of the head width are rejected (Sec. 5.2.1), as are hits
   whose template and scan normals disagree. While the FP count is below ``fp_threshold``
   (thesis: 500) the level refits the global RBF on all FPs (approach #1); above it the
   level adds a CSRBF offset ``f^k = f^(k-1) + o^k`` fitted to the residuals
   ``q_i - f^(k-1)(p_i)`` with support ``sigma^k = sigma^(k-1) / 2`` (Eq. 4.5.4-4.5.7).
4. After each level E_d, E_m and E (Eq. 5.2.1-5.2.3) are computed; the adaptation stops at
   a local minimum of E (the level that raised E is undone) or at the level limit.
5. Optionally (on by default) a final step moves each adapted vertex onto the scan along its
   normal when the scan lies within a small tolerance. This is common practice after
   landmark/RBF fitting (not a step of the thesis); it brings E_d near the scan's noise
   without moving vertices across holes, and is reported as its own level record.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .calibrate import Calibration, calibrate
from ..core.errors import InputError
from ..geometry.surface import MeshQuery, boundary_vertices, face_normals, mean_curvature, vertex_normals
from .metrics import _on_boundary, combined_error, distance_error, head_width, marker_error
from .rbf import fit_csrbf, fit_rbf

__all__ = ["METHODS", "AdaptResult", "LevelRecord", "adapt"]

METHODS: tuple[str, ...] = ("rbf", "csrbf", "multilevel")
"""Adaptation methods: global RBF only, CSRBF only, or the thesis's combination."""


@dataclass
class LevelRecord:
    """One level of the adaptation.

    Attributes:
        level: 0 = calibrated template before any deformation, 1 = FDP RBF, ...
        kind: "none", "rbf", "csrbf" or "projection".
        fp_count: FP pairs in use after this level.
        new_feature: New FPs from the feature mesh at this level.
        new_curvature: New FPs from the curvature search at this level.
        sigma: CSRBF support [m], or None for a global RBF level.
        iterations: Krylov iterations (max over x, y, z) of a CSRBF level, else 0.
        E_d: Distance error [m^2] (Eq. 5.2.1).
        E_m: Marker error [m^2] (Eq. 5.2.2); 0 without markers.
        E: Combined error [m^2] (Eq. 5.2.3).
        rms_dist: RMS vertex-to-scan distance [m] over vertices that found the scan.
        seconds: Wall time of this level [s].
        accepted: False when the level raised E and was undone.
    """

    level: int
    kind: str
    fp_count: int
    new_feature: int
    new_curvature: int
    sigma: float | None
    iterations: int
    E_d: float
    E_m: float
    E: float
    rms_dist: float
    seconds: float
    accepted: bool = True

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class AdaptResult:
    """Result of :func:`adapt`.

    Attributes:
        vertices: Adapted template vertices in the template frame [m], shape (n, 3), float64.
        vertices_scan_frame: The same in the scan's frame [m], shape (n, 3), float64.
        calibration: The scan -> template :class:`Calibration` (FDPs used, residuals).
        levels: Per-level records, in order.
        fp_template: Final FP positions on the template [m], shape (k, 3), float64.
        fp_scan: Their partners on the calibrated scan [m], shape (k, 3), float64.
        fp_source: Where each FP came from: 0 FDP, 1 coverage sample, 2 feature mesh,
            3 curvature search; shape (k,), int8.
        method: The method used.
        seconds: Total wall time [s].
        per_region: Region label -> distance stats of the final head (when regions were given).
    """

    vertices: np.ndarray
    vertices_scan_frame: np.ndarray
    calibration: Calibration
    levels: list[LevelRecord]
    fp_template: np.ndarray
    fp_scan: np.ndarray
    fp_source: np.ndarray
    method: str
    seconds: float
    per_region: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "method": self.method,
            "seconds": self.seconds,
            "calibration": self.calibration.to_dict(),
            "levels": [r.to_dict() for r in self.levels],
            "fp_count": int(len(self.fp_template)),
            "per_region": self.per_region,
        }


# ----------------------------------------------------------------------------------------
# helpers


def _fps(V: np.ndarray, seeds: np.ndarray, count: int) -> np.ndarray:
    """Farthest-point sampling of ``count`` vertices of V, starting from the points ``seeds``."""
    d = np.full(len(V), np.inf)
    for s in seeds:
        d = np.minimum(d, np.linalg.norm(V - s, axis=1))
    out = []
    for _ in range(count):
        i = int(np.argmax(d))
        out.append(i)
        d = np.minimum(d, np.linalg.norm(V - V[i], axis=1))
    return np.asarray(out, dtype=np.int64)


def _sphere_triangulation(P: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Delaunay triangulation on the sphere of directions around ``center`` (convex hull)."""
    from scipy.spatial import ConvexHull

    D = P - center
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    hull = ConvexHull(D)
    T = hull.simplices.astype(np.int64)
    # orient outward (normal away from the centre)
    n = np.cross(D[T[:, 1]] - D[T[:, 0]], D[T[:, 2]] - D[T[:, 0]])
    flip = np.einsum("kd,kd->k", n, D[T].mean(1)) < 0
    T[flip] = T[flip][:, ::-1]
    return T


def _uniform_smooth(V: np.ndarray, F: np.ndarray, steps: int) -> np.ndarray:
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


class _FPSet:
    """Feature-point pairs (template point p, calibrated scan point q)."""

    def __init__(self):
        self.p = np.zeros((0, 3))
        self.q = np.zeros((0, 3))
        self.src = np.zeros(0, dtype=np.int8)

    def add(self, p, q, src: int, min_dist: float) -> np.ndarray:
        """Add pairs whose p is farther than min_dist from every existing p; returns kept mask."""
        from scipy.spatial import cKDTree

        p = np.asarray(p).reshape(-1, 3)
        q = np.asarray(q).reshape(-1, 3)
        keep = np.ones(len(p), dtype=bool)
        if len(self.p) and len(p):
            d, _ = cKDTree(self.p).query(p)
            keep &= d > min_dist
        # among themselves
        if keep.sum() > 1:
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


# ----------------------------------------------------------------------------------------
# main entry


def adapt(
    template_V,
    template_F,
    template_landmarks: dict[str, np.ndarray],
    scan_V,
    scan_F,
    scan_landmarks: dict[str, np.ndarray],
    *,
    method: str = "multilevel",
    levels: int = 3,
    markers: tuple[dict, dict] | None = None,
    region=None,
    region_weights: dict | None = None,
    fp_threshold: int = 500,
    rho: float = 0.0,
    sigma0: float | None = None,
    coverage_points: int = 150,
    curvature_points: int = 60,
    project: bool = True,
    project_tolerance: float | None = None,
    normal_agreement: float = 0.3,
    calibration_fdps=None,
    alpha: float = 1.0,
    beta: float = 0.1,
    solver: str = "bicgstab",
    preconditioner: str = "ilu",
    correspondence: str = "closest",
    quadric: bool = False,
    inner_iterations: int = 2,
    sigma_factor: float = 4.0,
    device: str = "cpu",
) -> AdaptResult:
    """Adapt a template head to a scan (thesis Sec. 4.3-4.5).

    Args:
        template_V: Template vertices [m], shape (n, 3), float64.
        template_F: Template triangles, shape (m, 3), int64, outward oriented.
        template_landmarks: FDP id -> template position [m], shape (3,).
        scan_V: Scan vertices [m] in the scan's own frame, shape (k, 3), float64.
        scan_F: Scan triangles, shape (l, 3), int64, outward oriented.
        scan_landmarks: FDP id -> scan position [m], scan frame, shape (3,).
        method: "multilevel" (global RBF below ``fp_threshold`` FPs, CSRBF above), "rbf"
            (global RBF on all FPs at every level) or "csrbf" (CSRBF at every level, from
            ``sigma0``).
        levels: Level limit (levels after the FDP level).
        markers: Optional ``(template_markers, scan_markers)``, id -> position [m] (scan
            markers in the scan frame), not used for training; they give E_m (Eq. 5.2.2).
        region: Optional per-template-vertex region labels, shape (n,), for E_d weights and
            per-region stats.
        region_weights: Region label -> E_d weight (default ears 0.2).
        fp_threshold: FP count above which CSRBF levels replace the global RBF (thesis 500).
        rho: Error coefficient of the global RBF [m] (Eq. 4.4.3).
        sigma0: First CSRBF support [m]; default a quarter of the head width.
        coverage_points: Farthest-point samples added to the FDPs in the initial feature mesh.
        curvature_points: Curvature FPs sought at the first refinement level (doubles per level).
        project: Run the final normal projection onto the scan.
        project_tolerance: Largest move of the projection [m]; default 1.5 % of the head width.
        normal_agreement: Smallest cosine between template and scan normals at a ray hit.
        calibration_fdps: Optional FDP ids for the calibration (default: see :func:`calibrate`).
        alpha, beta: Weights of E = alpha E_d + beta E_m (Eq. 5.2.3).
        solver, preconditioner: Krylov settings of the CSRBF levels (:func:`rbf.fit_csrbf`).
        device: Warp device of the BVH queries.

    Returns:
        :class:`AdaptResult`.

    Raises:
        InputError: Bad method, an empty scan, too few / coplanar shared FDPs, a calibration
            scale that suggests mismatched units, or an FDP far off its surface.
    """
    t_start = time.perf_counter()
    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    TV = np.asarray(template_V, dtype=np.float64)
    TF = np.asarray(template_F, dtype=np.int64)
    SV = np.asarray(scan_V, dtype=np.float64)
    SF = np.asarray(scan_F, dtype=np.int64)
    if SV.ndim != 2 or SV.shape[1] != 3 or len(SV) == 0 or SF.ndim != 2 or SF.shape[1] != 3 or len(SF) == 0:
        raise InputError(f"scan is empty or malformed: vertices {SV.shape}, faces {SF.shape}")
    if TV.ndim != 2 or TV.shape[1] != 3 or len(TF) == 0:
        raise InputError(f"template is empty or malformed: vertices {TV.shape}, faces {TF.shape}")
    levels = int(levels)
    if levels < 0:
        raise InputError(f"levels must be >= 0, got {levels}")

    # -- 1. calibration (Sec. 4.3.2)
    cal = calibrate(scan_landmarks, template_landmarks, fdps=calibration_fdps)
    T = cal.transform
    if not 0.2 < T.scale < 5.0:
        raise InputError(
            f"calibration scale {T.scale:.3g} between scan and template: the units probably do not match (check the scan's and the template's units)"
        )
    W = head_width(TV)
    reject = 0.1 * W  # Sec. 5.2.1: 1/10 of the head width
    Q = T.apply(SV)
    scan_q = MeshQuery(Q, SF, device=device)
    tmpl_q = MeshQuery(TV, TF, device=device)
    scan_N_face = face_normals(Q, SF)

    shared = [k for k in template_landmarks if k in scan_landmarks]
    P_fdp = np.array([np.asarray(template_landmarks[k], dtype=np.float64).reshape(3) for k in shared])
    Q_fdp = T.apply(np.array([np.asarray(scan_landmarks[k], dtype=np.float64).reshape(3) for k in shared]))
    d_scan = scan_q.closest_point(Q_fdp).dist
    far = d_scan > reject
    if far.any():
        k = int(np.flatnonzero(far)[0])
        raise InputError(f"scan FDP {shared[k]} is {d_scan[k] * 1e3:.1f} mm off the scan surface (more than 1/10 of the head width)")
    d_tmpl = tmpl_q.closest_point(P_fdp)
    far = d_tmpl.dist > reject
    if far.any():
        k = int(np.flatnonzero(far)[0])
        raise InputError(f"template FDP {shared[k]} is {d_tmpl.dist[k] * 1e3:.1f} mm off the template surface")

    # markers (E_m, Eq. 5.2.2): template markers ride on the template surface
    mk_face = mk_bary = mk_scan = None
    if markers is not None:
        tm, sm = markers
        ids = [k for k in tm if k in sm]
        if ids:
            cp = tmpl_q.closest_point(np.array([np.asarray(tm[k], dtype=np.float64).reshape(3) for k in ids]))
            mk_face, mk_bary = cp.face, cp.bary
            mk_scan = T.apply(np.array([np.asarray(sm[k], dtype=np.float64).reshape(3) for k in ids]))

    def errors(V):
        de = distance_error(V, query=scan_q, region=region, region_weights=region_weights, max_dist=reject)
        em = 0.0
        if mk_face is not None:
            U = np.einsum("kc,kcd->kd", mk_bary, V[TF[mk_face]])
            em = marker_error(U, mk_scan)
        return de, em, combined_error(de.value, em, alpha=alpha, beta=beta)

    records: list[LevelRecord] = []
    t0 = time.perf_counter()
    de, em, E = errors(TV)
    records.append(LevelRecord(0, "none", 0, 0, 0, None, 0, de.value, em, E, de.stats["rms"], time.perf_counter() - t0))

    # -- 2. level 1: the FDP pairs
    t0 = time.perf_counter()
    fps = _FPSet()
    min_sep = 1e-3 * W
    fps.add(P_fdp, Q_fdp, 0, min_sep)
    sigma = 0.25 * W if sigma0 is None else float(sigma0)  # level 1 of method "csrbf"
    fields = []  # the displacement is the sum of these fields

    at_TV: dict = {}  # id(field) -> (field, its value at the template vertices)

    def displacement(X):
        out = np.zeros_like(X)
        for f in fields:
            if X is TV:
                hit = at_TV.get(id(f))
                if hit is None or hit[0] is not f:
                    hit = at_TV[id(f)] = (f, f(TV))
                out += hit[1]
            else:
                out += f(X)
        return out

    def fit_level(kind_rbf: bool, sig: float):
        nonlocal fields
        if kind_rbf:
            fields = [fit_rbf(fps.p, fps.q - fps.p, rho=rho)]
            return "rbf", None, 0
        resid = fps.q - fps.p - displacement(fps.p)
        normals = tmpl_normals_at(fps.p) if quadric else None
        f = fit_csrbf(fps.p, resid, sig, normals=normals, solver=solver, preconditioner=preconditioner)
        fields = fields + [f]
        return "csrbf", sig, int(f.iterations.max())

    TN = vertex_normals(TV, TF)

    def tmpl_normals_at(P):
        cp = tmpl_q.closest_point(P)
        n = np.einsum("kc,kcd->kd", cp.bary, TN[TF[cp.face]])
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    use_rbf0 = method != "csrbf" and len(fps) >= 4
    kind, sig_used, its = fit_level(use_rbf0, sigma)
    if kind == "csrbf":
        sigma /= 2.0  # Eq. 4.5.7
    Vk = TV + displacement(TV)
    de, em, E = errors(Vk)
    records.append(LevelRecord(1, kind, len(fps), 0, 0, sig_used, its, de.value, em, E, de.stats["rms"], time.perf_counter() - t0))

    # -- 3. initial feature mesh: FDPs on the skin + coverage samples (template points)
    t0 = time.perf_counter()
    defo_q = MeshQuery(Vk, TF, device=device)
    on_skin = d_tmpl.dist < 0.02 * W
    cov = _fps(TV, P_fdp[on_skin], int(coverage_points)) if coverage_points > 0 else np.zeros(0, np.int64)
    fm_p = np.concatenate([P_fdp[on_skin], TV[cov]])  # feature mesh vertices on the template
    center = TV.mean(axis=0)
    fm_T = _sphere_triangulation(fm_p, center) if len(fm_p) >= 4 else np.zeros((0, 3), np.int64)
    # automatic FPs: template point p (fixed) and its scan partner q (re-found each level
    # with correspondence="closest", fixed at discovery with "ray")
    auto_p = TV[cov].copy()
    auto_q = np.full_like(auto_p, np.nan)
    auto_src = np.full(len(auto_p), 1, dtype=np.int8)
    setup_seconds = time.perf_counter() - t0

    # curvature candidates on the scan (Sec. 4.5.2), computed once
    curv_idx, curv_order = _curvature_candidates(Q, SF, template_landmarks, scan_landmarks, T)
    curv_sorted = curv_idx[curv_order]  # scan vertices by decreasing |kappa_H|
    curv_taken = np.zeros(len(curv_sorted), dtype=bool)
    curv_p = np.zeros((0, 3))
    curv_q = np.zeros((0, 3))

    def partners(Pt, Pd, Nd, q_old):
        """Scan partners of template points Pt deformed to Pd with normals Nd."""
        if correspondence == "ray":
            q = q_old.copy()
            todo = np.flatnonzero(~np.isfinite(q_old[:, 0]))
            if len(todo):
                h = scan_q.ray_cast(Pd[todo], Nd[todo], reject, both_directions=True)
                ok = h.hit & (np.einsum("kd,kd->k", scan_N_face[np.maximum(h.face, 0)], Nd[todo]) > normal_agreement)
                q[todo[ok]] = h.points[ok]
            return q
        cp = scan_q.closest_point(Pd, reject)
        q = np.full_like(Pd, np.nan)
        ok = cp.face >= 0
        ok[ok] &= np.einsum("kd,kd->k", scan_N_face[cp.face[ok]], Nd[ok]) > normal_agreement
        ok &= ~_on_boundary(scan_q, cp)
        q[ok] = cp.points[ok]
        return q

    n0_template = _FoldCheck(TV, TF)
    folded0 = n0_template(Vk)  # folds the FDP level already made stay allowed
    best = (E, Vk.copy(), list(fields), len(fps))
    n_curv = int(curvature_points)
    csrbf_levels = 0
    sigma = None
    if records[-1].kind == "csrbf":
        sigma = float(records[-1].sigma) / 2.0  # Eq. 4.5.7
    elif sigma0 is not None:
        sigma = float(sigma0)
    for level in range(2, levels + 2):
        t0 = time.perf_counter() - (setup_seconds if level == 2 else 0.0)
        Nk = vertex_normals(Vk, TF)
        defo_q.update(Vk)
        n_before = len(auto_p) + len(curv_p)
        # 3a. feature mesh expansion (Sec. 4.5.1): rays from the barycentres of the deformed
        # feature triangles along their normals hit the deformed template (-> p)
        new_feat = 0
        if len(fm_T):
            fm_d = fm_p + displacement(fm_p)
            A, B, C = fm_d[fm_T[:, 0]], fm_d[fm_T[:, 1]], fm_d[fm_T[:, 2]]
            o = (A + B + C) / 3.0
            n = np.cross(B - A, C - A)
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
            ht = defo_q.ray_cast(o, n, reject, both_directions=True)
            f_t = np.maximum(ht.face, 0)
            p_new = np.einsum("kc,kcd->kd", np.nan_to_num(ht.bary), TV[TF[f_t]])
            ok = ht.hit.copy()
            if ok.any():  # not on top of an existing FP
                from scipy.spatial import cKDTree

                allp = np.concatenate([fps.p, auto_p, curv_p])
                dmin, _ = cKDTree(allp).query(p_new[ok])
                ok[np.flatnonzero(ok)[dmin <= min_sep]] = False
            new_feat = int(ok.sum())
            base = len(fm_p)
            fm_p = np.concatenate([fm_p, p_new[ok]])
            tk = fm_T[ok]
            c = base + np.arange(len(tk))
            fm_T = np.concatenate(
                [np.stack([tk[:, 0], tk[:, 1], c], 1), np.stack([tk[:, 1], tk[:, 2], c], 1), np.stack([tk[:, 2], tk[:, 0], c], 1)]
            )
            auto_p = np.concatenate([auto_p, p_new[ok]])
            auto_q = np.concatenate([auto_q, np.full((new_feat, 3), np.nan)])
            auto_src = np.concatenate([auto_src, np.full(new_feat, 2, dtype=np.int8)])
        # scan partners of the automatic FPs
        auto_cp = tmpl_q.closest_point(auto_p)
        auto_d = np.einsum("kc,kcd->kd", auto_cp.bary, Vk[TF[auto_cp.face]])
        auto_n = face_normals(Vk, TF[auto_cp.face])
        auto_q = partners(auto_p, auto_d, auto_n, auto_q)
        # 3b. curvature-based FP search (Sec. 4.5.2): scan vertex -> ray along its normal
        new_curv = 0
        if n_curv > 0 and len(curv_sorted):
            avail = np.flatnonzero(~curv_taken)
            spacing = 0.02 * W / 2 ** (level - 2)
            chosen = avail[_thin(Q[curv_sorted[avail]], n_curv, spacing)]
            curv_taken[chosen] = True
            vi = curv_sorted[chosen]
            SN = vertex_normals(Q, SF)[vi]
            ht = defo_q.ray_cast(Q[vi], SN, reject, both_directions=True)
            f_t = np.maximum(ht.face, 0)
            ok = ht.hit & (np.einsum("kd,kd->k", face_normals(Vk, TF[f_t]), SN) > normal_agreement)
            p_new = np.einsum("kc,kcd->kd", np.nan_to_num(ht.bary), TV[TF[f_t]])
            curv_p = np.concatenate([curv_p, p_new[ok]])
            curv_q = np.concatenate([curv_q, Q[vi[ok]]])
            new_curv = int(ok.sum())
            n_curv *= 2
        if len(auto_p) + len(curv_p) == n_before and correspondence == "ray":
            break
        # this level's FP set: FDPs + automatic FPs with a partner + curvature FPs
        good = np.isfinite(auto_q[:, 0])
        fps = _FPSet()
        fps.add(P_fdp, Q_fdp, 0, min_sep)
        fps.add(curv_p, curv_q, 3, min_sep)
        for src in (1, 2):
            sel = good & (auto_src == src)
            fps.add(auto_p[sel], auto_q[sel], src, min_sep)
        # 3c. fit this level (Eq. 4.5.4-4.5.7)
        use_rbf = method == "rbf" or (method == "multilevel" and len(fps) < fp_threshold and csrbf_levels == 0)
        if not use_rbf and sigma is None:
            from scipy.spatial import cKDTree

            h, _ = cKDTree(fps.p).query(fps.p, k=2)
            sigma = sigma_factor * float(np.median(h[:, 1]))
        prev_fields = list(fields)
        kind, sig_used, its = fit_level(use_rbf, sigma if sigma is not None else 0.0)
        # inner iterations (correspondence="closest"): re-find the partners on the level's
        # new surface and refit the level, so that features can slide into place (ICP-like)
        for _ in range(inner_iterations if correspondence == "closest" else 0):
            Vi = TV + displacement(TV)
            auto_d = np.einsum("kc,kcd->kd", auto_cp.bary, Vi[TF[auto_cp.face]])
            auto_n = face_normals(Vi, TF[auto_cp.face])
            auto_q = partners(auto_p, auto_d, auto_n, auto_q)
            good = np.isfinite(auto_q[:, 0])
            fps = _FPSet()
            fps.add(P_fdp, Q_fdp, 0, min_sep)
            fps.add(curv_p, curv_q, 3, min_sep)
            for src in (1, 2):
                sel = good & (auto_src == src)
                fps.add(auto_p[sel], auto_q[sel], src, min_sep)
            fields = list(prev_fields)
            kind, sig_used, its2 = fit_level(use_rbf, sigma if sigma is not None else 0.0)
            its += its2
        if kind == "csrbf":
            sigma /= 2.0  # Eq. 4.5.7
            csrbf_levels += 1
        Vnew = TV + displacement(TV)
        # fold guard: where the dense FPs of this level would fold the template's triangles,
        # the vertices step back toward the previous level's shape
        Vnew = _unfold(Vnew, best[1], TF, n0_template, folded0)
        de, em, E = errors(Vnew)
        rec = LevelRecord(level, kind, len(fps), new_feat, new_curv, sig_used, its, de.value, em, E, de.stats["rms"], time.perf_counter() - t0)
        if E > best[0]:
            rec.accepted = False  # local minimum of E reached (Sec. 5.2.3): undo and stop
            records.append(rec)
            fields = prev_fields
            break
        records.append(rec)
        Vk = Vnew
        best = (E, Vk.copy(), list(fields), len(fps))

    Vk = best[1]

    # -- 5. projection onto the scan along the vertex normals (common practice, see module doc)
    if project:
        t0 = time.perf_counter()
        tol = 0.015 * W if project_tolerance is None else float(project_tolerance)
        Nk = vertex_normals(Vk, TF)
        h = scan_q.ray_cast(Vk, Nk, tol, both_directions=True)
        ok = h.hit & (np.einsum("kd,kd->k", scan_N_face[np.maximum(h.face, 0)], Nk) > normal_agreement)
        Vp = Vk.copy()
        Vp[ok] = h.points[ok]
        Vp = _unfold(Vp, Vk, TF, n0_template, folded0)
        de, em, E = errors(Vp)
        records.append(LevelRecord(records[-1].level + 1, "projection", len(fps), 0, 0, None, 0, de.value, em, E, de.stats["rms"], time.perf_counter() - t0))
        Vk = Vp

    # -- 6. squeezed triangles: where the adapted surface squeezed a triangle flat (e.g. closed lips
    # pressing the template's mouth corner), its vertices relax toward their neighbours' mean in
    # the tangent plane and are put back on the scan; a flat triangle would make a flat tet
    Vr = _relax_squeezed(Vk, TF, scan_q, n0_template, folded0, reject)
    if Vr is not Vk:
        Vk = Vr
        de, em, E = errors(Vk)
        records.append(LevelRecord(records[-1].level + 1, "relax", len(fps), 0, 0, None, 0, de.value, em, E, de.stats["rms"], 0.0))

    per_region = de.per_region if region is not None else {}
    Tinv = T.inverse()
    return AdaptResult(
        vertices=Vk,
        vertices_scan_frame=Tinv.apply(Vk),
        calibration=cal,
        levels=records,
        fp_template=fps.p,
        fp_scan=fps.q,
        fp_source=fps.src,
        method=method,
        seconds=time.perf_counter() - t_start,
        per_region=per_region,
    )


class _FoldCheck:
    """Folds of a deformed template: faces turned by more than 75 degrees from their template
    normal, and pairs of neighbouring faces whose normals turned more than 100 degrees apart
    (a crease sharper than 80 degrees) where the template had none. Such creases leave no
    inward direction from which a skin layer can be extruded (Sec. 6.2)."""

    TURN_COS = 0.26  # cos 75 deg
    CREASE_COS = -0.17  # cos 100 deg

    def __init__(self, V0: np.ndarray, F: np.ndarray):
        self.F = F
        self.V0 = V0
        self.n0 = self._normals(V0)
        E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        fid = np.tile(np.arange(len(F)), 3)
        key = np.sort(E, axis=1)
        order = np.lexsort((key[:, 1], key[:, 0]))
        ks, fs = key[order], fid[order]
        same = np.all(ks[1:] == ks[:-1], axis=1)
        self.pairs = np.stack([fs[:-1][same], fs[1:][same]], 1)
        self.dot0 = np.einsum("kd,kd->k", self.n0[self.pairs[:, 0]], self.n0[self.pairs[:, 1]])

    def _normals(self, V):
        n = np.cross(V[self.F[:, 1]] - V[self.F[:, 0]], V[self.F[:, 2]] - V[self.F[:, 0]])
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    def __call__(self, V: np.ndarray) -> np.ndarray:
        n = self._normals(V)
        bad = np.einsum("kd,kd->k", n, self.n0) <= self.TURN_COS
        d = np.einsum("kd,kd->k", n[self.pairs[:, 0]], n[self.pairs[:, 1]])
        crease = (d < self.CREASE_COS) & (self.dot0 >= self.CREASE_COS)
        bad[self.pairs[crease].ravel()] = True
        return bad


def _unfold(V: np.ndarray, V_safe: np.ndarray, F: np.ndarray, folds: _FoldCheck, allowed: np.ndarray, *, rounds: int = 20) -> np.ndarray:
    """Move the vertices of newly folded faces back toward ``V_safe`` (halving their step each
    round) until no face folds that did not fold in ``V_safe``; returns the repaired vertices."""
    V = V.copy()
    for _ in range(rounds):
        bad = folds(V) & ~allowed
        if not bad.any():
            break
        idx = np.unique(F[bad])
        V[idx] = 0.5 * (V[idx] + V_safe[idx])
    bad = folds(V) & ~allowed
    if bad.any():
        idx = np.unique(F[bad])
        V[idx] = V_safe[idx]
    return V


TRI_QUALITY_FLOOR = 0.3
"""A triangle whose quality ``4 sqrt(3) area / sum(edge^2)`` (1 equilateral, 0 flat) is below this
and below half its template quality is *squeezed* (e.g. a 150-degree cap, or a 10-degree needle)."""


def _tri_quality(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    return _tri_quality_points(V[F])


def _relax_squeezed(V, F, scan_q, folds: _FoldCheck, allowed, reject, *, rounds: int = 60):
    """Tangential relaxation of squeezed triangles (see :data:`TRI_QUALITY_FLOOR`), on the scan.

    Where the adapted surface squeezed triangles flat (closed lips pressing the template's mouth
    corner, a crease of the nostril), their vertices and those vertices' neighbours step halfway
    to their neighbours' mean in the tangent plane and are put back on the scan (closest point).
    A step is kept only if it raises the smallest quality of the vertex's triangles, and a
    round's steps are undone on any triangle they made worse than both its old quality and the
    floor, so the relaxation never trades one flat triangle for another. A flat triangle makes a
    flat tet in the skin layer (Sec. 6.2), and a flat tet sets the solver's step (Sec. 6.4.4).
    """
    q0 = _tri_quality(folds.V0, F)
    target = np.minimum(TRI_QUALITY_FLOOR, 0.5 * q0)
    if not (_tri_quality(V, F) < target).any():
        return V
    n = len(V)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    E = np.concatenate([E, E[:, ::-1]])
    deg = np.bincount(E[:, 0], minlength=n)
    vf = np.repeat(np.arange(len(F)), 3)  # vertex -> face incidence, as pairs
    vv = F.ravel()
    W = V.copy()
    for _ in range(rounds):
        q = _tri_quality(W, F)
        bad = q < target
        if not bad.any():
            break
        act = np.zeros(n, bool)
        act[F[bad].ravel()] = True
        act[E[act[E[:, 0]], 1]] = True  # and their one-ring
        idx = np.flatnonzero(act)
        mean = np.zeros_like(W)
        np.add.at(mean, E[:, 0], W[E[:, 1]])
        mean = mean / np.maximum(deg, 1)[:, None]
        N = vertex_normals(W, F)[idx]
        step = mean[idx] - W[idx]
        step -= np.einsum("kd,kd->k", step, N)[:, None] * N  # stay in the tangent plane
        C = W.copy()
        C[idx] += 0.5 * step
        cp = scan_q.closest_point(C[idx], reject)
        ok = cp.face >= 0
        C[idx[ok]] = cp.points[ok]
        # keep a vertex's step if, with its neighbours where they were, its worst triangle improves
        old_min = np.full(n, np.inf)
        np.minimum.at(old_min, vv, q[vf])
        new_min = np.full(n, np.inf)
        PW = W[F]
        for k in range(3):  # move one corner at a time
            P = PW.copy()
            P[:, k] = C[F[:, k]]
            qk = _tri_quality_points(P)
            np.minimum.at(new_min, F[:, k], qk)
        keep = act & (new_min > old_min)
        if not keep.any():
            break
        Wn = W.copy()
        Wn[keep] = C[keep]
        qn = _tri_quality(Wn, F)
        worse = (qn < q) & (qn < target)
        Wn[F[worse].ravel()] = W[F[worse].ravel()]
        if np.array_equal(Wn, W):
            break
        W = Wn
    return _unfold(W, V, F, folds, allowed)


def _tri_quality_points(P: np.ndarray) -> np.ndarray:
    e2 = (np.linalg.norm(P - np.roll(P, 1, axis=1), axis=2) ** 2).sum(1)
    A = 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
    return 4.0 * np.sqrt(3.0) * A / np.maximum(e2, 1e-300)






def _thin(P: np.ndarray, count: int, spacing: float) -> np.ndarray:
    """Greedy selection, in the given order, of up to ``count`` points at least ``spacing`` apart."""
    from scipy.spatial import cKDTree

    if len(P) == 0 or count <= 0:
        return np.zeros(0, dtype=np.int64)
    tree = cKDTree(P)
    taken = np.zeros(len(P), dtype=bool)
    blocked = np.zeros(len(P), dtype=bool)
    out = []
    for i in range(len(P)):
        if blocked[i]:
            continue
        out.append(i)
        taken[i] = True
        if len(out) >= count:
            break
        blocked[tree.query_ball_point(P[i], spacing)] = True
    return np.asarray(out, dtype=np.int64)


def _curvature_candidates(Q, SF, template_landmarks, scan_landmarks, T):
    """Scan vertices in the eyes..mouth box, sorted by decreasing |mean curvature| (Sec. 4.5.2).

    Returns (vertex indices in the box, an ordering of them by decreasing |kappa_H|).
    """
    lm = {k: T.apply(np.asarray(v, dtype=np.float64).reshape(3)) for k, v in scan_landmarks.items()}
    xs = [lm[k][0] for k in ("3.7", "3.12", "3.8", "3.11") if k in lm]
    ys = [lm[k][1] for k in ("8.2", "2.3", "8.3", "8.4", "2.2", "8.1") if k in lm]
    if len(xs) < 2 or not ys:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    x0, x1 = min(xs), max(xs)
    y0 = min(ys)
    inside = (Q[:, 0] >= x0) & (Q[:, 0] <= x1) & (Q[:, 1] >= y0)
    # only vertices on the front (facing +z in the template frame) of the head
    if not inside.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    Qs = _uniform_smooth(Q, SF, 3)
    H = mean_curvature(Qs, SF)
    N = vertex_normals(Q, SF)
    inside &= np.isfinite(H) & (N[:, 2] > 0.0)
    idx = np.flatnonzero(inside)
    order = np.argsort(-np.abs(H[idx]), kind="stable")
    return idx, order
