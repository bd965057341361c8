"""The adaptation problem: settings, per-level records, and the calibration stage (Sec. 4.3.2).

:class:`AdaptOptions` gathers every setting of :func:`~facewarp.adapt`;
:func:`calibration_stage` checks the inputs, maps the scan into the template's frame
(Eq. 4.3.2, 4.3.3) and returns the :class:`Problem` that the later stages share: both
meshes with their BVH queries, the FDP pairs and the error meter of Eq. 5.2.1-5.2.3.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from ..geometry.surface import MeshQuery, face_normals
from .calibrate import Calibration, calibrate
from .metrics import DistanceError, combined_error, distance_error, head_width, marker_error

__all__ = ["METHODS", "AdaptOptions", "ErrorMeter", "LevelRecord", "Problem", "calibration_stage"]

METHODS: tuple[str, ...] = ("rbf", "csrbf", "multilevel")
"""Adaptation methods: global RBF only, CSRBF only, or the thesis's combination."""

REFINE_MODES: tuple[str, ...] = ("none", "field", "field+land")
"""Non-rigid stages after the levels (:mod:`nonrigid`): none (the thesis's levels only), the
smooth field fitted to point-to-plane pairs, or the field then the landing along the normals."""


@dataclass(frozen=True)
class AdaptOptions:
    """Settings of :func:`~facewarp.adapt`; every field can also be passed to it
    as a keyword.

    Attributes:
        method: "multilevel" (global RBF below ``fp_threshold`` FPs, CSRBF above), "rbf"
            (global RBF on all FPs at every level) or "csrbf" (CSRBF at every level, from
            ``sigma0``).
        levels: Level limit (refinement levels after the FDP level).
        fp_threshold: FP count above which CSRBF levels replace the global RBF (thesis 500).
        rho: Error coefficient of the global RBF [m] (Eq. 4.4.3).
        sigma0: First CSRBF support [m]; None: a quarter of the head width for method
            "csrbf", else ``sigma_factor`` times the median FP spacing.
        sigma_factor: CSRBF support of the first CSRBF level in median FP spacings.
        coverage_points: Farthest-point samples added to the FDPs in the initial feature mesh.
        curvature_points: Curvature FPs sought at the first refinement level (doubles per level).
        correspondence: "closest" (automatic FPs re-find their scan partner by closest point
            at every level and inner iteration) or "ray" (partner fixed at discovery).
        inner_iterations: Refits of a level after re-finding the partners ("closest").
        quadric: Use the local quadric term of the CSRBF (Eq. 4.4.8-4.4.10).
        solver, preconditioner: Krylov settings of the CSRBF levels (:func:`rbf.fit_csrbf`).
        normal_agreement: Smallest cosine between template and scan normals at a pair.
        calibration_fdps: Optional FDP ids for the calibration (default: see :func:`calibrate`).
        alpha, beta: Weights of E = alpha E_d + beta E_m (Eq. 5.2.3).
        region_weights: Region label -> E_d weight (default ears 0.2, Sec. 5.2.1).
        refine: Non-rigid stages after the levels (:mod:`nonrigid`): "field+land" (a smooth
            3D field fitted to point-to-plane pairs, then smooth offsets along the normals onto
            the scan), "field", or "none" (the thesis's levels only).
        field_centers: RBF centres of the field (the FDPs and farthest-point samples).
        field_samples: About this many template vertices carry point-to-plane pairs.
        field_stiffness: Thin-plate weights of the field's stages, from stiff to soft, per
            sample and per metre of head width (dimensionless).
        field_iterations: Largest number of (closest points, solve) iterations per stage.
        field_fdp_weight: Weight of each FDP pair in the field, in point-to-plane samples
            (0: the FDPs only calibrate, e.g. for guessed landmarks).
        land_smoothing: Weight of the Dirichlet term of the landing offsets against the data
            (dimensionless; vertex areas have mean 1).
        land_iterations: Largest number of (closest points, solve) iterations of the landing.
        project: Run the final per-vertex normal projection onto the scan; None: only when
            ``refine`` is "none" (the landing stage of "field+land" replaces it).
        project_tolerance: Largest move of the projection [m]; default 1.5 % of the head width.
    """

    method: str = "multilevel"
    levels: int = 2
    fp_threshold: int = 500
    rho: float = 0.0
    sigma0: float | None = None
    sigma_factor: float = 4.0
    coverage_points: int = 150
    curvature_points: int = 60
    correspondence: str = "closest"
    inner_iterations: int = 2
    quadric: bool = False
    solver: str = "bicgstab"
    preconditioner: str = "ilu"
    normal_agreement: float = 0.3
    calibration_fdps: tuple | None = None
    alpha: float = 1.0
    beta: float = 0.1
    region_weights: dict | None = None
    refine: str = "field+land"
    field_centers: int = 150
    field_samples: int = 2000
    field_stiffness: tuple = (7e-3, 7e-4, 7e-5)
    field_iterations: int = 6
    field_fdp_weight: float = 10.0
    land_smoothing: float = 0.5
    land_iterations: int = 3
    project: bool | None = None
    project_tolerance: float | None = None

    def checked(self) -> "AdaptOptions":
        """The options with numbers normalised; raises :class:`InputError` naming a bad field."""
        if self.method not in METHODS:
            raise InputError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.refine not in REFINE_MODES:
            raise InputError(f"refine must be one of {', '.join(REFINE_MODES)}, got {self.refine!r}")
        if self.correspondence not in ("closest", "ray"):
            raise InputError(f"correspondence must be 'closest' or 'ray', got {self.correspondence!r}")
        from ..core.limits import MAX_ADAPT_LEVELS, check_count

        levels = check_count("levels", self.levels, low=0, high=MAX_ADAPT_LEVELS)
        from ..core.checks import check_int, check_number

        for name in ("coverage_points", "curvature_points", "inner_iterations", "field_iterations", "land_iterations"):
            check_int(name, getattr(self, name), low=0, high=1_000_000)
        for name in ("rho", "sigma_factor", "normal_agreement", "alpha", "beta", "land_smoothing", "field_fdp_weight"):
            check_number(name, getattr(self, name))
        if self.sigma0 is not None and not float(self.sigma0) > 0:
            raise InputError(f"sigma0 must be positive, got {self.sigma0}")
        stiff = tuple(float(s) for s in self.field_stiffness)
        if not stiff or not all(np.isfinite(s) and s > 0 for s in stiff):
            raise InputError(f"field_stiffness must be positive numbers, got {self.field_stiffness!r}")
        if int(self.field_centers) < 8 or int(self.field_samples) < 8:
            raise InputError(f"field_centers and field_samples must be >= 8, got {self.field_centers}, {self.field_samples}")
        if float(self.land_smoothing) < 0:
            raise InputError(f"land_smoothing must be >= 0, got {self.land_smoothing}")
        return dataclasses.replace(self, levels=levels, field_stiffness=stiff)

    @classmethod
    def from_keywords(cls, options: "AdaptOptions | None", settings: dict) -> "AdaptOptions":
        """``options`` (or the defaults) with the keyword ``settings`` replaced."""
        base = cls() if options is None else options
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(settings) - names)
        if unknown:
            raise InputError(f"adapt() got unknown settings {', '.join(unknown)}")
        if "calibration_fdps" in settings and settings["calibration_fdps"] is not None:
            settings = {**settings, "calibration_fdps": tuple(settings["calibration_fdps"])}
        return dataclasses.replace(base, **settings).checked()


@dataclass
class LevelRecord:
    """One stage or level of the adaptation.

    Attributes:
        level: 0 = calibrated template before any deformation, 1 = FDP RBF, ...
        kind: "none", "rbf", "csrbf", "field", "land", "projection" or "relax".
        fp_count: FP pairs in use after this level.
        new_feature: New FPs from the feature mesh at this level.
        new_curvature: New FPs from the curvature search at this level.
        sigma: CSRBF support [m], or None for a global RBF level.
        iterations: Krylov iterations (max over x, y, z) of a CSRBF level, (closest points,
            solve) iterations of a field or landing stage, else 0.
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


class ErrorMeter:
    """E_d, E_m and E of a deformed template (Eq. 5.2.1-5.2.3), with the problem's scan,
    markers and region weights."""

    def __init__(self, problem: "Problem", *, region, region_weights, markers_face, markers_bary, markers_scan,
                 alpha: float, beta: float):
        self.p = problem
        self.region = region
        self.region_weights = region_weights
        self.mk_face, self.mk_bary, self.mk_scan = markers_face, markers_bary, markers_scan
        self.alpha, self.beta = alpha, beta

    def __call__(self, V: np.ndarray) -> tuple[DistanceError, float, float]:
        """(E_d result, E_m [m^2], E [m^2]) of the template deformed to V [m], shape (n, 3)."""
        de = distance_error(V, query=self.p.scan_q, region=self.region, region_weights=self.region_weights,
                            max_dist=self.p.reject)
        em = 0.0
        if self.mk_face is not None:
            U = np.einsum("kc,kcd->kd", self.mk_bary, V[self.p.TF[self.mk_face]])
            em = marker_error(U, self.mk_scan)
        return de, em, combined_error(de.value, em, alpha=self.alpha, beta=self.beta)

    def record(self, level: int, kind: str, V: np.ndarray, *, fp_count: int = 0, new_feature: int = 0,
               new_curvature: int = 0, sigma: float | None = None, iterations: int = 0, seconds: float = 0.0
               ) -> tuple[LevelRecord, DistanceError]:
        de, em, E = self(V)
        return LevelRecord(level, kind, fp_count, new_feature, new_curvature, sigma, iterations, de.value, em, E,
                           de.stats["rms"], seconds), de


@dataclass
class Problem:
    """What every stage after the calibration shares (template frame, metres).

    Attributes:
        TV: Template vertices [m], shape (n, 3), float64.
        TF: Template triangles, shape (m, 3), int64.
        Q: Calibrated scan vertices [m], shape (k, 3), float64.
        SF: Scan triangles, shape (l, 3), int64.
        calibration: The scan -> template :class:`Calibration`.
        scan_q, tmpl_q: BVH queries of the calibrated scan and of the template.
        scan_N_face: Unit face normals of the calibrated scan, shape (l, 3), float64.
        W: Head width of the template [m].
        reject: Largest pair distance [m], 1/10 of the head width (Sec. 5.2.1).
        fdp_ids: The FDP ids shared by template and scan, in the order of P_fdp / Q_fdp.
        P_fdp: Template FDPs [m], shape (f, 3), float64.
        Q_fdp: Calibrated scan FDPs [m], shape (f, 3), float64.
        fdp_skin_dist: Distance of each template FDP to the template surface [m], shape (f,).
        device: Warp device of the BVH queries.
    """

    TV: np.ndarray
    TF: np.ndarray
    Q: np.ndarray
    SF: np.ndarray
    calibration: Calibration
    scan_q: MeshQuery
    tmpl_q: MeshQuery
    scan_N_face: np.ndarray
    W: float
    reject: float
    fdp_ids: list
    P_fdp: np.ndarray
    Q_fdp: np.ndarray
    fdp_skin_dist: np.ndarray
    device: str
    errors: ErrorMeter | None = None
    _scan_H: np.ndarray | None = None

    def scan_curvature(self) -> np.ndarray:
        """Meyer mean curvature (Eq. 4.5.1, 4.5.2) of the calibrated scan after 3 rounds of
        uniform smoothing (so that scanner noise does not win) [1/m], shape (k,); NaN on its
        border. Computed once."""
        if self._scan_H is None:
            from ..geometry.surface import mean_curvature
            from .fp_search import uniform_smooth

            self._scan_H = mean_curvature(uniform_smooth(self.Q, self.SF, 3), self.SF)
        return self._scan_H


def _mesh_arrays(V, F, what: str) -> tuple[np.ndarray, np.ndarray]:
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0 or F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
        raise InputError(f"{what} is empty or malformed: vertices {V.shape}, faces {F.shape}")
    if not np.issubdtype(F.dtype, np.integer) or F.min() < 0 or F.max() >= len(V):
        raise InputError(f"{what} faces must index its {len(V)} vertices")
    if not np.isfinite(V).all():
        raise InputError(f"{what} vertices must be finite")
    return V, F.astype(np.int64)


def calibration_stage(template_V, template_F, template_landmarks: dict, scan_V, scan_F, scan_landmarks: dict,
                      opts: AdaptOptions, *, markers=None, region=None, device: str = "cpu") -> Problem:
    """Input checks and range-data calibration (Sec. 4.3.2, Eq. 4.3.2-4.3.4).

    The scan is mapped into the template's frame by the least-squares similarity of the shared
    FDPs (:func:`calibrate`); FDPs farther than 1/10 of the head width from their surface are
    errors (Sec. 5.2.1's threshold).

    Args:
        template_V, template_F: Template [m], shapes (n, 3) float64 and (m, 3) int64.
        template_landmarks: FDP id -> template position [m], shape (3,).
        scan_V, scan_F: Scan [m] in its own frame, shapes (k, 3) float64 and (l, 3) int64.
        scan_landmarks: FDP id -> scan position [m], scan frame, shape (3,).
        opts: Checked :class:`AdaptOptions`.
        markers: Optional ``(template_markers, scan_markers)`` for E_m (Eq. 5.2.2).
        region: Optional per-template-vertex region labels, shape (n,).
        device: Warp device of the BVH queries.

    Raises:
        InputError: An empty or malformed mesh, too few / coplanar FDPs, a scale that
            suggests mismatched units, or an FDP far off its surface.
    """
    TV, TF = _mesh_arrays(template_V, template_F, "template")
    SV, SF = _mesh_arrays(scan_V, scan_F, "scan")
    cal = calibrate(scan_landmarks, template_landmarks, fdps=opts.calibration_fdps)
    T = cal.transform
    if not 0.2 < T.scale < 5.0:
        raise InputError(
            f"calibration scale {T.scale:.3g} between scan and template: the units probably do not match "
            "(check the scan's and the template's units)"
        )
    W = head_width(TV)
    reject = 0.1 * W  # Sec. 5.2.1: 1/10 of the head width
    Q = T.apply(SV)
    scan_q = MeshQuery(Q, SF, device=device)
    tmpl_q = MeshQuery(TV, TF, device=device)
    shared = [k for k in template_landmarks if k in scan_landmarks]
    P_fdp = np.array([np.asarray(template_landmarks[k], dtype=np.float64).reshape(3) for k in shared])
    Q_fdp = T.apply(np.array([np.asarray(scan_landmarks[k], dtype=np.float64).reshape(3) for k in shared]))
    d_scan = scan_q.closest_point(Q_fdp).dist
    far = d_scan > reject
    if far.any():
        k = int(np.flatnonzero(far)[0])
        raise InputError(f"scan FDP {shared[k]} is {d_scan[k] * 1e3:.1f} mm off the scan surface "
                         "(more than 1/10 of the head width)")
    d_tmpl = tmpl_q.closest_point(P_fdp)
    far = d_tmpl.dist > reject
    if far.any():
        k = int(np.flatnonzero(far)[0])
        raise InputError(f"template FDP {shared[k]} is {d_tmpl.dist[k] * 1e3:.1f} mm off the template surface")
    prob = Problem(TV, TF, Q, SF, cal, scan_q, tmpl_q, face_normals(Q, SF), W, reject, shared, P_fdp, Q_fdp,
                   d_tmpl.dist, str(device))
    # markers (E_m, Eq. 5.2.2): template markers ride on the template surface
    mk_face = mk_bary = mk_scan = None
    if markers is not None:
        tm, sm = markers
        ids = [k for k in tm if k in sm]
        if ids:
            cp = tmpl_q.closest_point(np.array([np.asarray(tm[k], dtype=np.float64).reshape(3) for k in ids]))
            mk_face, mk_bary = cp.face, cp.bary
            mk_scan = T.apply(np.array([np.asarray(sm[k], dtype=np.float64).reshape(3) for k in ids]))
    if region is not None:
        region = np.asarray(region)
        if region.shape != (len(TV),):
            raise InputError(f"region must have one label per template vertex ({len(TV)}), got shape {region.shape}")
    prob.errors = ErrorMeter(prob, region=region, region_weights=opts.region_weights, markers_face=mk_face,
                             markers_bary=mk_bary, markers_scan=mk_scan, alpha=opts.alpha, beta=opts.beta)
    return prob
