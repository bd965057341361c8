"""Automatic FDP landmarks on a scan in any pose: a geometric detector (no learned model).

Not in the thesis (whose FDPs are picked by hand, Sec. 4.3.1). :func:`detect_landmarks` finds the
template's FDPs on a scan in four steps:

1. symmetry plane of the scan: the plane through the centroid whose mirror image of the scan
   lies closest to the scan (a search over directions on a hemisphere, then refined by mirror
   pairs, as in the planar-reflective-symmetry transform of Podolak et al. 2006); the template's
   own plane is found the same way;
2. coarse pose: every proper rotation that maps the scan's plane onto the template's (both
   normal signs, 12 turns about the normal, two starting centres: the template's head centroid
   and its face centroid, so that a scan of the face alone starts in front), each refined by a
   trimmed similarity ICP of the scan onto the template (Besl & McKay 1992; Chetverikov et al.
   2002's trimming, so scan parts the template lacks and template parts the scan lacks do not
   pull; Umeyama 1991 for each step); the pose with the smallest trimmed residual of the scan
   onto the template plus the template's face (vertices near its FDPs) onto the scan wins (a
   head is round: only the face tells its front and its up);
3. non-rigid fit: the template is adapted to the scan from that pose by
   :func:`~facewarp.adapt` with the FDPs of the pose as calibration only (their
   weight in the field stage 0): the smooth field fitted to point-to-plane pairs
   (:mod:`nonrigid`) carries the template's shape, and with it its FDPs, onto the scan;
4. FDPs: each template FDP's surface point on the adapted template, moved to its closest scan
   point; the nose tip (9.3) is refined to the most protruding scan point near it along the
   face's forward direction, the curvature extreme of Sec. 4.5.2 that it is by definition.

Confidence per FDP (0..1): ``exp(-(d / 2 mm)^2)`` of the distance ``d`` from the adapted FDP to
the scan, times the fraction of template vertices within 5 % of the head size of the FDP that found a scan
partner (0 over a hole or beyond the scan's border), times the pose's score ``exp(-(s / (4 % of
the head size))^2)`` of its trimmed residual ``s`` (scan onto template plus face onto scan).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..core.errors import InputError
from ..geometry.similarity import Similarity, fit_similarity
from ..geometry.surface import MeshQuery, vertex_normals

__all__ = ["DetectionResult", "detect_landmarks", "symmetry_plane"]


def _fibonacci_hemisphere(count: int) -> np.ndarray:
    i = np.arange(count) + 0.5
    z = i / count  # upper hemisphere: z in (0, 1]
    phi = np.pi * (1.0 + 5.0**0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _sample(V: np.ndarray, count: int, rng) -> np.ndarray:
    return V if len(V) <= count else V[rng.choice(len(V), count, replace=False)]


def symmetry_plane(V, *, samples: int = 1500, directions: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
    """The plane of (approximate) mirror symmetry of a point set.

    Args:
        V: Points [m], shape (n, 3), float64 (e.g. a scan's vertices).
        samples: Points used.
        directions: Candidate normals on the hemisphere.
        seed: Seed of the sampling.

    Returns:
        (unit normal (3,), a point on the plane (3,) [m], RMS distance of the mirrored samples
        to the set [m]).
    """
    rng = np.random.default_rng(seed)
    P = _sample(np.asarray(V, dtype=np.float64), samples, rng)
    tree = cKDTree(P)
    c = P.mean(axis=0)
    D = _fibonacci_hemisphere(directions)

    def cost(n, c0):
        M = P - 2.0 * ((P - c0) @ n)[:, None] * n
        d, _ = tree.query(M)
        return float(np.sqrt(np.mean(np.minimum(d, np.percentile(d, 80)) ** 2)))

    costs = np.array([cost(n, c) for n in D])
    best = []
    for k in np.argsort(costs)[:4]:  # refine the best few by mirror pairs
        n, c0 = D[k].copy(), c.copy()
        for _ in range(15):
            M = P - 2.0 * ((P - c0) @ n)[:, None] * n
            d, j = tree.query(M)
            keep = d <= np.percentile(d, 80)
            Q = P[j[keep]]  # partner of each mirrored point: P[keep] should mirror onto Q
            dv = P[keep] - Q
            s = np.sign(dv @ n)
            s[s == 0] = 1.0
            n_new = (dv * s[:, None]).sum(axis=0)
            if np.linalg.norm(n_new) == 0:
                break
            n = n_new / np.linalg.norm(n_new)
            c0 = 0.5 * (P[keep] + Q).mean(axis=0)
        best.append((cost(n, c0), n, c0))
    e, n, c0 = min(best, key=lambda b: b[0])
    return n, c0, e


def _rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A rotation taking unit vector a onto unit vector b."""
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        if c > 0:
            return np.eye(3)
        p = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
        return _rotation_about(np.cross(a, p), np.pi)
    return _rotation_about(v, np.arctan2(np.linalg.norm(v), c))


def _trimmed_icp(S: np.ndarray, tree: cKDTree, TP: np.ndarray, T0: Similarity, iterations: int,
                 keep: float = 0.7) -> tuple[Similarity, float]:
    """Similarity ICP of points S onto the template points TP (KD-tree ``tree``), keeping the
    closest ``keep`` fraction of pairs each step; returns (transform, trimmed RMS / scale)."""
    T = T0
    err = np.inf
    for _ in range(iterations):
        X = T.apply(S)
        d, j = tree.query(X)
        lim = np.percentile(d, 100 * keep)
        m = d <= lim
        T = fit_similarity(S[m], TP[j[m]], with_scale=True)
        err = float(np.sqrt(np.mean(d[m] ** 2)))
    return T, err / max(T.scale, 1e-12)


class DetectionResult(dict):
    """FDP id -> scan position [m], shape (3,); with ``confidence`` (FDP id -> 0..1), ``pose`` (the
    coarse scan -> template :class:`Similarity`) and ``info`` (diagnostics)."""

    confidence: dict
    pose: Similarity
    info: dict


def detect_landmarks(V, F, *, template=None, fdps=None, device: str = "cpu", seed: int = 0
                     ) -> tuple[dict, dict]:
    """Find the template's FDPs on a scan in any pose (see the module docstring).

    Args:
        V: Scan vertices [m], shape (k, 3), float64, any pose (units must be metres: convert first).
        F: Scan triangles, shape (l, 3), int64.
        template: ``(V_t, F_t, landmarks)`` of the template in metres, or None for
            :func:`~facewarp.default_template` level 0 and its head FDPs.
        fdps: FDP ids to report (default: every template FDP found on the scan).
        device: Warp device of the BVH queries.
        seed: Seed of the point sampling.

    Returns:
        (FDP id -> scan position [m] (3,), FDP id -> confidence in [0, 1]). The returned
        position dict is a :class:`DetectionResult` that also carries ``pose`` and ``info``.

    Raises:
        InputError: An empty or malformed scan, or a scan far from head-sized in metres.
    """
    from .pipeline import adapt

    SV = np.asarray(V, dtype=np.float64)
    SF = np.asarray(F)
    if SV.ndim != 2 or SV.shape[1] != 3 or len(SV) < 10 or SF.ndim != 2 or SF.shape[1] != 3 or len(SF) < 10:
        raise InputError(f"scan is empty or malformed: vertices {SV.shape}, faces {SF.shape}")
    SF = SF.astype(np.int64)
    if template is None:
        from ..template import default_template

        t = default_template(0)
        TV, TF = t.vertices, t.faces
        tlm = {k: v for k, v in t.landmarks().items() if t.fdp[k][0] == "head"}
        face_center = TV[np.unique(TF[t.frontal])].mean(axis=0)
    else:
        TV, TF, tlm = template
        TV = np.asarray(TV, dtype=np.float64)
        TF = np.asarray(TF, dtype=np.int64)
        tlm = {k: np.asarray(v, dtype=np.float64).reshape(3) for k, v in tlm.items()}
        P = np.array(list(tlm.values()))
        face_center = P.mean(axis=0)  # the FDPs sit on the face
    size_s = float(np.ptp(SV, axis=0).max())
    size_t = float(np.ptp(TV, axis=0).max())
    if not 0.05 * size_t < size_s < 5.0 * size_t:
        raise InputError(f"scan spans {size_s:.3g} m, a head spans about {size_t:.2g} m: give the scan in metres "
                         "(its units are probably wrong)")
    rng = np.random.default_rng(seed)
    # 1. symmetry planes
    n_s, c_s, sym_err = symmetry_plane(SV, seed=seed)
    n_t, c_t, _ = symmetry_plane(TV, seed=seed)
    # 2. coarse pose: rotations mapping the scan's plane onto the template's, trimmed ICP each;
    # scored by the trimmed scan -> template residual plus that of the template's face
    # (vertices near its FDPs) -> scan, so that a pose matching the head's round back but not
    # the face loses
    S = _sample(SV, 1200, rng)
    tree = cKDTree(TV)
    stree = cKDTree(_sample(SV, 20000, rng))
    P_lm = np.array(list(tlm.values()))
    face_pts = TV[np.unique(np.concatenate(tree.query_ball_point(P_lm, 0.12 * size_t)))]
    face_pts = _sample(face_pts, 800, rng)

    def score(T: Similarity, e: float) -> float:
        d, _ = stree.query(T.inverse().apply(face_pts))
        d = np.sort(d)[: int(0.9 * len(d))] * T.scale  # template units
        return e + float(np.sqrt(np.mean(d * d)))

    cands = []
    for sign in (1.0, -1.0):
        R0 = _align(sign * n_s, n_t)
        for k in range(12):
            R = _rotation_about(n_t, 2 * np.pi * k / 12) @ R0
            for centre in (TV.mean(axis=0), face_center):
                t0 = centre - R @ S.mean(axis=0)
                T, e = _trimmed_icp(S, tree, TV, Similarity(1.0, R, t0), 8)
                cands.append((score(T, e), T))
    cands.sort(key=lambda c: c[0])
    refined = []
    for _, T0 in cands[:6]:
        T, e = _trimmed_icp(S, tree, TV, T0, 25)
        refined.append((score(T, e), T, e))
    sc_best, T, e = min(refined, key=lambda c: c[0])
    pose_score = float(np.exp(-((sc_best / (0.04 * size_t)) ** 2)))
    # 3. non-rigid fit from the pose; the pose's FDPs calibrate only
    Tinv = T.inverse()
    scan_q = MeshQuery(SV, SF, device=device)
    guess = {}
    for k, p in tlm.items():
        cp = scan_q.closest_point(Tinv.apply(p[None]))
        guess[k] = cp.points[0]
    res = adapt(TV, TF, tlm, SV, SF, guess, levels=0, refine="field", field_fdp_weight=0.0, device=device)
    # 4. template FDPs on the adapted surface -> closest scan points
    tq = MeshQuery(TV, TF, device=device)
    ids = [k for k in tlm if fdps is None or k in fdps]
    P = np.array([tlm[k] for k in ids])
    cp = tq.closest_point(P)
    A = np.einsum("kc,kcd->kd", cp.bary, res.vertices_scan_frame[TF[cp.face]])
    sc = scan_q.closest_point(A, 0.05 * size_s)
    out = DetectionResult()
    conf = {}
    Avert = res.vertices_scan_frame
    # coverage: template vertices near each FDP that found a scan partner
    near = cKDTree(TV).query_ball_point(P, 0.05 * size_t)
    vcp = scan_q.closest_point(Avert, 0.01 * size_s)
    covered = vcp.face >= 0
    N_t = vertex_normals(res.vertices_scan_frame, TF)
    for i, k in enumerate(ids):
        if sc.face[i] < 0:
            continue
        q = sc.points[i]
        if k == "9.3":  # nose tip: the most protruding scan point nearby along the face's front
            fwd = N_t[TF[cp.face[i]]].mean(axis=0)
            fwd /= max(np.linalg.norm(fwd), 1e-12)
            idx = cKDTree(SV).query_ball_point(q, 0.03 * size_t)
            if idx:
                j = np.asarray(idx)
                q = SV[j[np.argmax(SV[j] @ fwd)]]
        d = float(np.linalg.norm(q - A[i]))
        cov = float(covered[near[i]].mean()) if len(near[i]) else 0.0
        out[k] = q
        conf[k] = float(np.exp(-((d / 0.002) ** 2)) * cov * pose_score)
    out.confidence = conf
    out.pose = T
    out.info = {"symmetry_rms_m": sym_err, "pose_trimmed_rms_m": e, "pose_face_score_m": sc_best, "pose_score": pose_score,
                "fit_seconds": res.seconds}
    return out, conf
