"""The thesis's levels: the FDP RBF (Eq. 4.5.3) and the multi-level RBF / CSRBF (Eq. 4.5.4-4.5.7).

- :func:`fdp_level` (level 1): global RBF (Eq. 4.4.1-4.4.4) on the FDP pairs, ``f^0``.
- :func:`refinement_levels` (levels 2, 3, ...): each collects new FP pairs
  (:class:`~.fp_search.FeatureSearch`: feature mesh expansion, Sec. 4.5.1, and curvature
  search, Sec. 4.5.2). While the FP count is below ``fp_threshold`` (thesis: 500) the level
  refits the global RBF on all FPs (approach #1); above it the level adds a CSRBF offset
  ``f^k = f^(k-1) + o^k`` fitted to the residuals ``q_i - f^(k-1)(p_i)`` with support
  ``sigma^k = sigma^(k-1) / 2`` (Eq. 4.5.4-4.5.7). After each level E_d, E_m and E
  (Eq. 5.2.1-5.2.3) are computed; the levels stop at a local minimum of E (the level that
  raised E is undone, Sec. 5.2.3) or at the level limit.
- :func:`projection_stage`: each adapted vertex moves onto the scan along its normal where the
  scan lies within a small tolerance (common practice after landmark/RBF fitting, not a step
  of the thesis).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..geometry.surface import MeshQuery, vertex_normals
from .folds import FoldCheck, unfold
from .fp_search import FeatureSearch, FPSet
from .problem import AdaptOptions, LevelRecord, Problem
from .rbf import fit_csrbf, fit_rbf

__all__ = ["Displacement", "LevelsResult", "fdp_level", "projection_stage", "refinement_levels"]


class Displacement:
    """The displacement of the levels, a sum of RBF / CSRBF fields (Eq. 4.5.4):
    template points (k, 3) [m] -> displacements (k, 3) [m]. Each field's value at the template
    vertices is kept with the field (the template vertices never change)."""

    def __init__(self, TV: np.ndarray):
        self.TV = TV
        self.fields: list = []
        self._at_TV: list = []  # per field: its value at TV, or None

    def set(self, fields: list, at_TV: list | None = None) -> None:
        self.fields = list(fields)
        self._at_TV = list(at_TV) if at_TV is not None else [None] * len(fields)

    def snapshot(self) -> tuple[list, list]:
        return list(self.fields), list(self._at_TV)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        out = np.zeros_like(X)
        for k, f in enumerate(self.fields):
            if X is self.TV:
                if self._at_TV[k] is None:
                    self._at_TV[k] = f(self.TV)
                out += self._at_TV[k]
            else:
                out += f(X)
        return out

    def vertices(self) -> np.ndarray:
        """The deformed template vertices [m], shape (n, 3)."""
        return self.TV + self(self.TV)


def _fit(disp: Displacement, fps: FPSet, opts: AdaptOptions, prob: Problem, kind_rbf: bool, sigma: float):
    """Fit one level on the FP set: a global RBF on all pairs (replaces the fields), or a CSRBF
    offset on the residuals (appended). Returns (kind, sigma or None, Krylov iterations)."""
    if kind_rbf:
        disp.set([fit_rbf(fps.p, fps.q - fps.p, rho=opts.rho)])
        return "rbf", None, 0
    resid = fps.q - fps.p - disp(fps.p)
    normals = None
    if opts.quadric:
        TN = vertex_normals(prob.TV, prob.TF)
        cp = prob.tmpl_q.closest_point(fps.p)
        n = np.einsum("kc,kcd->kd", cp.bary, TN[prob.TF[cp.face]])
        normals = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    f = fit_csrbf(fps.p, resid, sigma, normals=normals, solver=opts.solver, preconditioner=opts.preconditioner)
    fields, at = disp.snapshot()
    disp.set(fields + [f], at + [None])
    return "csrbf", sigma, int(f.iterations.max())


def fdp_level(prob: Problem, opts: AdaptOptions, disp: Displacement) -> tuple[LevelRecord, np.ndarray, float]:
    """Level 1: the global RBF on the FDP pairs, ``q_i^0 = f^0(p_i^0)`` (Eq. 4.5.3, 4.4.1-4.4.4).

    Method "csrbf" fits a CSRBF with support ``sigma0`` (default a quarter of the head width)
    instead, and halves the support for the next level (Eq. 4.5.7).

    Returns:
        (record, deformed template vertices [m] (n, 3), the next CSRBF support [m] or NaN).
    """
    t0 = time.perf_counter()
    fps = FPSet()
    fps.add(prob.P_fdp, prob.Q_fdp, 0, 1e-3 * prob.W)
    sigma = 0.25 * prob.W if opts.sigma0 is None else float(opts.sigma0)
    use_rbf = opts.method != "csrbf" and len(fps) >= 4
    kind, sig_used, its = _fit(disp, fps, opts, prob, use_rbf, sigma)
    V = disp.vertices()
    rec, _ = prob.errors.record(1, kind, V, fp_count=len(fps), sigma=sig_used, iterations=its,
                                seconds=time.perf_counter() - t0)
    return rec, V, (sigma / 2.0 if kind == "csrbf" else float("nan"))


@dataclass
class LevelsResult:
    """Result of :func:`refinement_levels`.

    Attributes:
        vertices: The best level's deformed template [m], shape (n, 3), float64.
        fps: The last FP set fitted.
        records: One record per level tried (an undone level has ``accepted`` False).
        folds: The fold check against the template, and the faces already folded after level 1.
    """

    vertices: np.ndarray
    fps: FPSet
    records: list = field(default_factory=list)
    folds: FoldCheck | None = None
    folded0: np.ndarray | None = None


def refinement_levels(prob: Problem, opts: AdaptOptions, disp: Displacement, V1: np.ndarray, E1: float,
                      first_kind: str, next_sigma: float, Q_lm: dict) -> LevelsResult:
    """Levels 2.. of the multi-level scheme (Sec. 4.5.3, Eq. 4.5.4-4.5.7).

    Each level: feature mesh expansion (Sec. 4.5.1) and curvature FP search (Sec. 4.5.2) on the
    current deformed template; the scan partners of the automatic FPs are re-found by closest
    point (``correspondence="closest"``, with ``inner_iterations`` refits so that features can
    slide into place) or fixed at discovery by a ray ("ray"). The level fits a global RBF on
    all FPs while fewer than ``fp_threshold`` (approach #1), else a CSRBF offset on the
    residuals with the support halved per level (Eq. 4.5.7). A fold guard steps vertices back
    where the level would fold the template (:func:`~.folds.unfold`). A level that raises E
    (Eq. 5.2.3) is undone and ends the levels (Sec. 5.2.3).

    Args:
        prob: The problem.
        opts: The options.
        disp: The displacement after level 1 (grown in place).
        V1: Vertices after level 1 [m], shape (n, 3).
        E1: E after level 1 [m^2].
        first_kind: Kind of level 1 ("rbf" or "csrbf").
        next_sigma: CSRBF support after level 1 [m] (NaN when level 1 was a global RBF).
        Q_lm: FDP id -> calibrated scan position [m] (curvature box).
    """
    TV, TF = prob.TV, prob.TF
    t0 = time.perf_counter()
    search = FeatureSearch(prob, opts, Q_lm)
    defo_q = MeshQuery(V1, TF, device=prob.device)
    setup_seconds = time.perf_counter() - t0
    folds = FoldCheck(TV, TF)
    folded0 = folds(V1)  # folds the FDP level already made stay allowed
    best = (E1, V1.copy(), disp.snapshot())
    Vk = V1
    fps = FPSet()
    fps.add(prob.P_fdp, prob.Q_fdp, 0, search.min_sep)
    csrbf_levels = 0
    if first_kind == "csrbf":
        sigma = next_sigma
    else:
        sigma = None if opts.sigma0 is None else float(opts.sigma0)
    records: list[LevelRecord] = []
    for level in range(2, opts.levels + 2):
        t0 = time.perf_counter() - (setup_seconds if level == 2 else 0.0)
        defo_q.update(Vk)
        n_before = search.count
        new_feat = search.expand_feature_mesh(disp, defo_q)  # Sec. 4.5.1
        search.locate()
        search.update_partners(Vk)
        new_curv = search.search_curvature(level, Vk, defo_q)  # Sec. 4.5.2
        if search.count == n_before and opts.correspondence == "ray":
            break
        fps = search.fp_set()
        use_rbf = opts.method == "rbf" or (opts.method == "multilevel" and len(fps) < opts.fp_threshold
                                            and csrbf_levels == 0)
        if not use_rbf and sigma is None:
            h, _ = cKDTree(fps.p).query(fps.p, k=2)
            sigma = opts.sigma_factor * float(np.median(h[:, 1]))
        prev = disp.snapshot()
        kind, sig_used, its = _fit(disp, fps, opts, prob, use_rbf, sigma if sigma is not None else 0.0)
        # inner iterations (correspondence="closest"): re-find the partners on the level's new
        # surface and refit the level, so that features can slide into place (ICP-like)
        for _ in range(opts.inner_iterations if opts.correspondence == "closest" else 0):
            search.update_partners(disp.vertices())
            fps = search.fp_set()
            disp.set(*prev)
            kind, sig_used, its2 = _fit(disp, fps, opts, prob, use_rbf, sigma if sigma is not None else 0.0)
            its += its2
        if kind == "csrbf":
            sigma /= 2.0  # Eq. 4.5.7
            csrbf_levels += 1
        Vnew = unfold(disp.vertices(), best[1], TF, folds, folded0)  # fold guard
        rec, _ = prob.errors.record(level, kind, Vnew, fp_count=len(fps), new_feature=new_feat,
                                    new_curvature=new_curv, sigma=sig_used, iterations=its,
                                    seconds=time.perf_counter() - t0)
        if rec.E > best[0]:
            rec.accepted = False  # local minimum of E reached (Sec. 5.2.3): undo and stop
            records.append(rec)
            disp.set(*prev)
            break
        records.append(rec)
        Vk = Vnew
        best = (rec.E, Vk.copy(), disp.snapshot())
    return LevelsResult(best[1], fps, records, folds, folded0)


def projection_stage(prob: Problem, V: np.ndarray, tolerance: float | None, normal_agreement: float,
                     folds: FoldCheck, allowed: np.ndarray) -> np.ndarray:
    """Move each vertex onto the scan along its normal where the scan lies within ``tolerance``
    [m] (default 1.5 % of the head width) with a compatible normal; the fold guard then steps
    back any vertex whose move folds a face. Brings E_d near the scan's noise without moving
    vertices across holes (not a step of the thesis).

    Args:
        V: Adapted vertices [m], shape (n, 3), float64.

    Returns:
        The projected vertices [m], shape (n, 3), float64.
    """
    tol = 0.015 * prob.W if tolerance is None else float(tolerance)
    N = vertex_normals(V, prob.TF)
    h = prob.scan_q.ray_cast(V, N, tol, both_directions=True)
    ok = h.hit & (np.einsum("kd,kd->k", prob.scan_N_face[np.maximum(h.face, 0)], N) > normal_agreement)
    Vp = V.copy()
    Vp[ok] = h.points[ok]
    return unfold(Vp, V, prob.TF, folds, allowed)
