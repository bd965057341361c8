"""Template-to-scan adaptation: calibration, the thesis's multi-level RBF/CSRBF scheme (Sec. 4.5),
then a regularised non-rigid stage.

:func:`adapt` runs these stages (template and scan in metres), each a function of its module:

1. :func:`~.problem.calibration_stage` (Sec. 4.3.2): input checks; a least-squares similarity
   takes the scan into the template's frame from >= 4 shared FDPs; everything below runs in
   that frame.
2. :func:`~.levels.fdp_level` (level 1): global RBF (Eq. 4.4.1-4.4.4) on the FDP pairs,
   ``f^0`` (Eq. 4.5.3).
3. :func:`~.levels.refinement_levels` (levels 2..): feature mesh expansion (Sec. 4.5.1) and
   curvature FP search (Sec. 4.5.2, :mod:`fp_search`), a global RBF or CSRBF offset per level
   (Eq. 4.5.4-4.5.7), a fold guard (:mod:`folds`), E (Eq. 5.2.3) per level, stop at its local
   minimum.
4. :func:`~.nonrigid.field_stage` and :func:`~.nonrigid.land_stage` (``refine="field+land"``,
   the default; not in the thesis): a smooth 3D field fitted to point-to-plane pairs over the
   whole template, then smooth offsets along the normals onto the scan, so that vertices do
   not slide along the scan (:mod:`nonrigid` cites its sources).
5. :func:`~.levels.projection_stage` (with ``refine="none"``): each vertex onto the scan along
   its normal within a small tolerance.
6. :func:`~.folds.relax_squeezed`: squeezed triangles relaxed tangentially on the scan.
7. :mod:`quality`: folds, dihedral angles, curvature difference and template distortion per
   region, figures that need no truth.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from .calibrate import Calibration
from .folds import relax_squeezed, unfold
from .levels import Displacement, fdp_level, projection_stage, refinement_levels
from .problem import METHODS, AdaptOptions, LevelRecord, calibration_stage

__all__ = ["METHODS", "AdaptOptions", "AdaptResult", "LevelRecord", "adapt"]


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
        options: The :class:`AdaptOptions` used.
        refine: Figures of the non-rigid stages (iterations, convergence, covered fraction).
        quality: Figures that need no truth (:mod:`quality`): "surface" (folds, dihedral angles
            and mean-curvature difference to the scan per region) and "distortion" (edge
            stretch and angle change of the template per region, a correspondence measure).
        vertex_curvature_diff: ``|H_adapted - H_scan|`` per vertex [1/m], shape (n,), NaN off the scan.
        vertex_stretch: Mean ``|log(l / l0)|`` of each vertex's edges, shape (n,), dimensionless.
        template_vertices: The template's vertices [m], shape (n, 3), float64.
        vertex_distance: Distance of each adapted vertex to the calibrated scan [m] (template
            frame), shape (n,), inf where no scan surface lies within 1/10 of the head width.
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
    options: AdaptOptions | None = None
    refine: dict = field(default_factory=dict)
    quality: dict = field(default_factory=dict)
    vertex_curvature_diff: np.ndarray | None = None
    vertex_stretch: np.ndarray | None = None
    template_vertices: np.ndarray | None = None
    vertex_distance: np.ndarray | None = None

    def to_dict(self) -> dict:
        return {
            "method": self.method,
            "seconds": self.seconds,
            "calibration": self.calibration.to_dict(),
            "levels": [r.to_dict() for r in self.levels],
            "fp_count": int(len(self.fp_template)),
            "per_region": self.per_region,
            **({"options": dataclasses.asdict(self.options)} if self.options is not None else {}),
            **({"refine": self.refine} if self.refine else {}),
            **({"quality": self.quality} if self.quality else {}),
        }



def adapt(
    template_V,
    template_F,
    template_landmarks: dict[str, np.ndarray],
    scan_V,
    scan_F,
    scan_landmarks: dict[str, np.ndarray],
    *,
    options: AdaptOptions | None = None,
    markers: tuple[dict, dict] | None = None,
    region=None,
    device: str = "cpu",
    **settings,
) -> AdaptResult:
    """Adapt a template head to a scan (thesis Sec. 4.3-4.5, then non-rigid stages that do not slide).

    Args:
        template_V: Template vertices [m], shape (n, 3), float64.
        template_F: Template triangles, shape (m, 3), int64, outward oriented.
        template_landmarks: FDP id -> template position [m], shape (3,).
        scan_V: Scan vertices [m] in the scan's own frame, shape (k, 3), float64.
        scan_F: Scan triangles, shape (l, 3), int64, outward oriented.
        scan_landmarks: FDP id -> scan position [m], scan frame, shape (3,).
        options: An :class:`AdaptOptions` (default: its defaults).
        markers: Optional ``(template_markers, scan_markers)``, id -> position [m] (scan
            markers in the scan frame), not used for training; they give E_m (Eq. 5.2.2).
        region: Optional per-template-vertex region labels, shape (n,), for E_d weights and
            per-region stats.
        device: Warp device of the BVH queries.
        **settings: Any :class:`AdaptOptions` field by name (``method="rbf"``, ``levels=5``,
            ...), replacing that field of ``options``.

    Returns:
        :class:`AdaptResult`.

    Raises:
        InputError: A bad setting, an empty scan, too few / coplanar shared FDPs, a calibration
            scale that suggests mismatched units, or an FDP far off its surface.
    """
    from .threads import single_blas_thread

    with single_blas_thread():  # small dense algebra: OpenBLAS's threads only cost on a busy machine
        return _adapt(template_V, template_F, template_landmarks, scan_V, scan_F, scan_landmarks, options=options,
                      markers=markers, region=region, device=device, settings=settings)


def _adapt(template_V, template_F, template_landmarks, scan_V, scan_F, scan_landmarks, *, options, markers, region,
           device, settings) -> AdaptResult:
    """:func:`adapt`'s body (one BLAS thread)."""
    t_start = time.perf_counter()
    opts = AdaptOptions.from_keywords(options, settings)
    # 1. calibration (Sec. 4.3.2)
    t0 = time.perf_counter()
    prob = calibration_stage(template_V, template_F, template_landmarks, scan_V, scan_F, scan_landmarks, opts,
                             markers=markers, region=region, device=device)
    TV, TF = prob.TV, prob.TF
    T = prob.calibration.transform
    Q_lm = {k: T.apply(np.asarray(v, dtype=np.float64).reshape(3)) for k, v in scan_landmarks.items()}
    rec, de = prob.errors.record(0, "none", TV, seconds=time.perf_counter() - t0)
    records: list[LevelRecord] = [rec]
    # 2. level 1: the FDP pairs (Eq. 4.5.3)
    disp = Displacement(TV)
    rec, V1, next_sigma = fdp_level(prob, opts, disp)
    records.append(rec)
    # 3. levels 2..: feature points and RBF / CSRBF levels (Eq. 4.5.4-4.5.7)
    lv = refinement_levels(prob, opts, disp, V1, rec.E, rec.kind, next_sigma, Q_lm)
    records += lv.records
    Vk = lv.vertices
    fps = lv.fps
    refine_info: dict = {}
    # 4. the smooth field and the landing along the normals (not in the thesis; nonrigid.py)
    if opts.refine in ("field", "field+land"):
        from .nonrigid import field_stage

        t0 = time.perf_counter()
        Vk, info = field_stage(prob, opts, Vk)
        refine_info.update(info)

        rec, de = prob.errors.record(records[-1].level + 1, "field", Vk, fp_count=len(fps),
                                     iterations=int(info["field_iterations"]), seconds=time.perf_counter() - t0)
        records.append(rec)
    if opts.refine == "field+land":
        from .nonrigid import land_stage

        t0 = time.perf_counter()
        V_field = Vk
        Vk, info = land_stage(prob, opts, Vk)
        Vk = unfold(Vk, V_field, TF, lv.folds, lv.folded0)  # fold guard (folds.py)
        refine_info.update(info)
        rec, de = prob.errors.record(records[-1].level + 1, "land", Vk, fp_count=len(fps),
                                     iterations=int(info["land_iterations"]), seconds=time.perf_counter() - t0)
        records.append(rec)
    # 5. projection onto the scan along the vertex normals (common practice)
    if opts.project or (opts.project is None and opts.refine == "none"):
        t0 = time.perf_counter()
        Vk = projection_stage(prob, Vk, opts.project_tolerance, opts.normal_agreement, lv.folds, lv.folded0)
        rec, de = prob.errors.record(records[-1].level + 1, "projection", Vk, fp_count=len(fps),
                                     seconds=time.perf_counter() - t0)
        records.append(rec)
    # 6. squeezed triangles: relax toward the neighbours' mean in the tangent plane, on the scan
    t0 = time.perf_counter()
    Vr = relax_squeezed(Vk, TF, prob.scan_q, lv.folds, lv.folded0, prob.reject)
    if Vr is not Vk:
        Vk = Vr
        rec, de = prob.errors.record(records[-1].level + 1, "relax", Vk, fp_count=len(fps),
                                     seconds=time.perf_counter() - t0)
        records.append(rec)
    if records[-1].kind in ("none", "rbf", "csrbf", "field") or not records[-1].accepted:
        de, _, _ = prob.errors(Vk)
    per_region = de.per_region if region is not None else {}
    # 7. quality figures that need no truth (quality.py)
    from .quality import distortion, surface_quality

    surf, dH = surface_quality(Vk, TV, TF, scan_V=prob.Q, scan_F=prob.SF, scan_query=prob.scan_q, region=region,
                               scan_curvature=prob.scan_curvature())
    dist, stretch = distortion(Vk, TV, TF, region=region)
    return AdaptResult(
        vertices=Vk,
        vertices_scan_frame=T.inverse().apply(Vk),
        calibration=prob.calibration,
        levels=records,
        fp_template=fps.p,
        fp_scan=fps.q,
        fp_source=fps.src,
        method=opts.method,
        seconds=time.perf_counter() - t_start,
        per_region=per_region,
        options=opts,
        refine=refine_info,
        quality={"surface": surf, "distortion": dist},
        vertex_curvature_diff=dH,
        vertex_stretch=stretch,
        template_vertices=TV,
        vertex_distance=de.dist,
    )
