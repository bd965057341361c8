"""Template-to-scan adaptation (thesis Ch. 4-5): calibration, RBF / CSRBF, the multi-level scheme, the non-sliding field and landing stages, automatic landmarks, error and quality metrics, transfer of the template's parts onto an adapted head (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.adapt.calibrate import (  # noqa: F401
    CALIBRATION_FDPS,
    Calibration,
    Similarity,
    calibrate,
    fit_similarity,
)
from ._src.adapt.rbf import (  # noqa: F401
    CSRBFField,
    Quadrics,
    RBFField,
    fit_csrbf,
    fit_local_quadrics,
    fit_rbf,
    wendland,
)
from ._src.adapt.pipeline import (  # noqa: F401
    METHODS,
    AdaptOptions,
    AdaptResult,
    LevelRecord,
    adapt,
)
from ._src.adapt.detect import (  # noqa: F401
    DetectionResult,
    detect_landmarks,
    symmetry_plane,
)
from ._src.adapt.quality import (  # noqa: F401
    DIHEDRAL_MARGIN_DEG,
    FOLD_DEG,
    distortion,
    surface_quality,
)
from ._src.adapt.metrics import (  # noqa: F401
    DEFAULT_REGION_WEIGHTS,
    REGION_GROUPS,
    DistanceError,
    VertexError,
    combined_error,
    distance_error,
    head_width,
    vertex_groups,
    marker_error,
    vertex_error,
)
from ._src.adapt.bake import (  # noqa: F401
    BakeResult,
    bake_texture,
    rasterize_uv,
    sample_scan_colors,
    vertex_color_texture,
)
from ._src.adapt.scale import (  # noqa: F401
    REFERENCE_M as SCALE_REFERENCE_M,
    HUMAN_RANGES_M,
    ScaleEstimate,
    estimate_scale,
    face_measures,
)
from ._src.adapt.transfer import (  # noqa: F401
    EYE_FDPS,
    apply_part,
    eye_transform,
    fit_part_transform,
    load_head,
    transfer_uv,
)

__all__ = ["vertex_color_texture", "SCALE_REFERENCE_M", "BakeResult", "bake_texture", "rasterize_uv", "sample_scan_colors", "HUMAN_RANGES_M", "ScaleEstimate", "estimate_scale", "face_measures", "AdaptOptions", "AdaptResult", "DIHEDRAL_MARGIN_DEG", "DetectionResult", "FOLD_DEG", "detect_landmarks", "distortion", "surface_quality", "symmetry_plane", "CALIBRATION_FDPS", "CSRBFField", "Calibration", "DEFAULT_REGION_WEIGHTS", "DistanceError", "EYE_FDPS", "LevelRecord", "METHODS", "Quadrics", "RBFField", "REGION_GROUPS", "Similarity", "VertexError", "adapt", "apply_part", "calibrate", "combined_error", "distance_error", "eye_transform", "fit_csrbf", "fit_local_quadrics", "fit_part_transform", "fit_rbf", "fit_similarity", "head_width", "load_head", "marker_error", "transfer_uv", "vertex_error", "vertex_groups", "wendland"]
