"""Quality of an adapted head that needs no ground truth: correspondence and surface figures.

Not in the thesis (its E_d, Eq. 5.2.1, measures only the distance to the scan, which is small
even when the vertices slid along the scan or the surface crumpled). Per region of the
template (and over the whole head):

- correspondence (:func:`distortion`): how much the adaptation stretched the template's edges
  (``|log(l_adapted / l_template)|``, in the template frame, so the calibration's scale is
  already out) and changed its triangles' angles. A template vertex that slid along the scan
  drags its triangles with it, so sliding shows up as stretch and shear;
- surface (:func:`surface_quality`): folds (faces whose normal turned more than 75 degrees from
  the same face of the calibrated template), the largest dihedral angle between neighbouring
  faces against the template's own largest in the same region (a crease the template lacks
  is a crumple), and the RMS difference of mean curvature (Meyer et al. 2002, Eq. 4.5.1-4.5.2)
  between the adapted surface and the scan, sampled at the template's vertices (the scan's
  curvature on a lightly smoothed copy, as in Sec. 4.5.2, so that scanner noise does not
  count). The curvature difference of the detailed regions is compared with that of the
  template's smooth regions (label ``smooth_label``, "other" in :func:`metrics.vertex_groups`).

Thresholds (issue 11): no fold; dihedral at most 15 degrees above the template's maximum in
the region; curvature difference of every region at most that of the smooth regions.
"""

from __future__ import annotations

import numpy as np

from ..geometry.surface import MeshQuery, face_normals, mean_curvature

__all__ = ["DIHEDRAL_MARGIN_DEG", "FOLD_DEG", "distortion", "surface_quality"]

FOLD_DEG = 75.0
"""A face whose normal turned more than this from the calibrated template's is a fold."""

DIHEDRAL_MARGIN_DEG = 15.0
"""Largest allowed excess of a region's maximum dihedral angle over the template's own."""


def _edges_faces(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interior edges' two faces, shape (e, 2), and every unique edge, shape (u, 2)."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    fid = np.tile(np.arange(len(F)), 3)
    key = np.sort(E, axis=1)
    n = int(F.max()) + 1
    k1 = key[:, 0] * n + key[:, 1]
    order = np.argsort(k1, kind="stable")
    ks, fs = k1[order], fid[order]
    same = ks[1:] == ks[:-1]
    pairs = np.stack([fs[:-1][same], fs[1:][same]], 1)
    uk = np.unique(k1)
    return pairs, np.stack([uk // n, uk % n], 1)


def _inputs(V, V0, F, region) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(V, V0, F, per-vertex labels as str; "all" without regions)."""
    V = np.asarray(V, dtype=np.float64)
    V0 = np.asarray(V0, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    lab = np.full(len(V), "all") if region is None else np.asarray(region).astype(str)
    return V, V0, F, lab


def _pct(x: np.ndarray, q: float) -> float:
    return float(np.percentile(x, q)) if len(x) else float("nan")


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x))) if len(x) else float("nan")


def _angles(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    P = V[F]
    out = np.zeros((len(F), 3))
    for c in range(3):
        a = P[:, (c + 1) % 3] - P[:, c]
        b = P[:, (c + 2) % 3] - P[:, c]
        cosv = np.einsum("kd,kd->k", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
        out[:, c] = np.arccos(np.clip(cosv, -1.0, 1.0))
    return out


def distortion(V, V0, F, *, region=None) -> tuple[dict, np.ndarray]:
    """Edge-length and angle distortion of the adapted template (a correspondence measure).

    Args:
        V: Adapted vertices [m], template frame, shape (n, 3), float64.
        V0: Template vertices [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.
        region: Optional per-vertex region labels, shape (n,) (an edge or face takes the label
            of its first vertex).

    Returns:
        (per-region dict (and "all"): ``stretch_rms`` and ``stretch_p95`` of
        ``|log(l / l0)|`` (dimensionless; 0.1 is about 10 %), ``angle_change_rms_deg`` and
        ``angle_change_p95_deg``; per-vertex mean ``|log(l / l0)|`` of its edges, shape (n,)).
    """
    V, V0, F, lab = _inputs(V, V0, F, region)
    n = len(V)
    _, E = _edges_faces(F)
    l0 = np.linalg.norm(V0[E[:, 0]] - V0[E[:, 1]], axis=1)
    l1 = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    s = np.abs(np.log(np.maximum(l1, 1e-300) / np.maximum(l0, 1e-300)))
    da = np.degrees(np.abs(_angles(V, F) - _angles(V0, F))).ravel()
    per_vertex = np.bincount(E.ravel(), weights=np.repeat(s, 2), minlength=n) / np.maximum(np.bincount(E.ravel(), minlength=n), 1)
    out = {}
    groups = ["all"] + sorted(set(lab.tolist()) - {"all"})
    for g in groups:
        se = np.ones(len(E), bool) if g == "all" else lab[E[:, 0]] == g
        sf = np.ones(len(F), bool) if g == "all" else lab[F[:, 0]] == g
        a = da.reshape(-1, 3)[sf].ravel()
        out[g] = {"stretch_rms": _rms(s[se]), "stretch_p95": _pct(s[se], 95), "angle_change_rms_deg": _rms(a),
                  "angle_change_p95_deg": _pct(a, 95)}
    return out, per_vertex


def _dihedral(V: np.ndarray, F: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    n = face_normals(V, F)
    return np.degrees(np.arccos(np.clip(np.einsum("kd,kd->k", n[pairs[:, 0]], n[pairs[:, 1]]), -1.0, 1.0)))


def surface_quality(V, V0, F, *, scan_V=None, scan_F=None, scan_query: MeshQuery | None = None, region=None,
                    smooth_label: str = "other", scan_smooth_steps: int = 3, max_dist: float | None = None,
                    scan_curvature=None) -> tuple[dict, np.ndarray]:
    """Folds, dihedral angles and mean-curvature difference to the scan, per region.

    Args:
        V: Adapted vertices [m], template frame, shape (n, 3), float64.
        V0: Template vertices [m] (the calibrated template), shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.
        scan_V, scan_F: The calibrated scan [m] (template frame), or None to skip the curvature.
        scan_query: Optional prebuilt query of (scan_V, scan_F).
        region: Optional per-vertex labels, shape (n,); a face takes its first vertex's label.
        smooth_label: The label of the template's smooth regions (the curvature reference).
        scan_smooth_steps: Uniform smoothing steps of the scan before its curvature.
        max_dist: Vertices farther than this from the scan [m] take no part in the curvature
            figures (default 2 % of the head's size).
        scan_curvature: Optional precomputed mean curvature of the smoothed scan [1/m], (k,).

    Returns:
        (dict with "regions": label -> {faces, folds, dihedral_max_deg,
        template_dihedral_max_deg, dihedral_ok, curvature_rms_diff_per_m, vertices_on_scan}
        plus "all"; "folds", "dihedral_ok", "curvature_limit_per_m" (the smooth regions' RMS
        difference), "curvature_ok" (None without a smooth region or scan); per-vertex
        ``|H_adapted - H_scan|`` [1/m], shape (n,), NaN off the scan).
    """
    from .fp_search import uniform_smooth

    V, V0, F, lab = _inputs(V, V0, F, region)
    n = len(V)
    pairs, _ = _edges_faces(F)
    turn = np.degrees(np.arccos(np.clip(np.einsum("kd,kd->k", face_normals(V, F), face_normals(V0, F)), -1.0, 1.0)))
    fold = turn > FOLD_DEG
    dih = _dihedral(V, F, pairs)
    dih0 = _dihedral(V0, F, pairs)
    dH = np.full(n, np.nan)
    if scan_V is not None and scan_F is not None:
        SV = np.asarray(scan_V, dtype=np.float64)
        SF = np.asarray(scan_F, dtype=np.int64)
        q = scan_query if scan_query is not None else MeshQuery(SV, SF)
        Hs = (np.asarray(scan_curvature, dtype=np.float64) if scan_curvature is not None
              else mean_curvature(uniform_smooth(SV, SF, scan_smooth_steps), SF))
        Ha = mean_curvature(V, F)
        lim = 0.02 * float(np.ptp(V, axis=0).max()) if max_dist is None else float(max_dist)
        cp = q.closest_point(V, lim)
        ok = cp.face >= 0
        h = np.einsum("kc,kc->k", np.nan_to_num(cp.bary[ok]), Hs[SF[cp.face[ok]]])
        dH[np.flatnonzero(ok)] = np.abs(Ha[ok] - h)
    regions = {}
    groups = ["all"] + sorted(set(lab.tolist()) - {"all"})
    for g in groups:
        sf = np.ones(len(F), bool) if g == "all" else lab[F[:, 0]] == g
        sp = sf[pairs[:, 0]]
        sv = np.ones(n, bool) if g == "all" else lab == g
        dv = dH[sv]
        dv = dv[np.isfinite(dv)]
        dmax = float(dih[sp].max()) if sp.any() else float("nan")
        dmax0 = float(dih0[sp].max()) if sp.any() else float("nan")
        regions[g] = {"faces": int(sf.sum()), "folds": int(fold[sf].sum()), "dihedral_max_deg": dmax,
                      "template_dihedral_max_deg": dmax0,
                      "dihedral_ok": bool(not sp.any() or dmax <= dmax0 + DIHEDRAL_MARGIN_DEG),
                      "curvature_rms_diff_per_m": _rms(dv), "vertices_on_scan": int(len(dv))}
    limit = regions.get(smooth_label, {}).get("curvature_rms_diff_per_m") if smooth_label in regions else None
    curv_ok = None
    if limit is not None and np.isfinite(limit):
        curv_ok = {g: bool(not np.isfinite(r["curvature_rms_diff_per_m"]) or r["curvature_rms_diff_per_m"] <= limit)
                   for g, r in regions.items() if g != "all"}
    out = {"folds": int(fold.sum()), "fold_threshold_deg": FOLD_DEG,
           "dihedral_ok": all(r["dihedral_ok"] for g, r in regions.items() if g != "all"),
           "dihedral_margin_deg": DIHEDRAL_MARGIN_DEG, "curvature_limit_per_m": limit, "curvature_ok": curv_ok,
           "regions": regions}
    return out, dH
