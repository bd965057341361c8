"""Template-to-scan adaptation (thesis Ch. 4-5): calibration, RBF / CSRBF, the multi-level scheme, the non-sliding field and landing stages, automatic landmarks, error and quality metrics, transfer of the template's parts onto an adapted head (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.adapt.calibrate import CALIBRATION_FDPS, Calibration, calibrate  # noqa: F401
from ._src.adapt.rbf import (  # noqa: F401
    CSRBFField,
    Quadrics,
    RBFField,
    fit_csrbf,
    fit_local_quadrics,
    fit_rbf,
    wendland,
)
from ._src.adapt.pipeline import METHODS, LevelRecord  # noqa: F401
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
from ._src.adapt.transfer import EYE_FDPS, apply_part, eye_transform, fit_part_transform, transfer_uv  # noqa: F401

__all__ = ["apply_part", "bake_texture", "BakeResult", "calibrate", "Calibration", "CALIBRATION_FDPS",
           "combined_error", "CSRBFField", "DEFAULT_REGION_WEIGHTS", "detect_landmarks", "DetectionResult",
           "DIHEDRAL_MARGIN_DEG", "distance_error", "DistanceError", "distortion", "estimate_scale", "EYE_FDPS",
           "eye_transform", "face_measures", "fit_csrbf", "fit_local_quadrics", "fit_part_transform", "fit_rbf",
           "FOLD_DEG", "head_width", "HUMAN_RANGES_M", "LevelRecord", "marker_error", "METHODS", "Quadrics",
           "rasterize_uv", "RBFField", "REGION_GROUPS", "sample_scan_colors", "SCALE_REFERENCE_M", "ScaleEstimate",
           "surface_quality", "symmetry_plane", "transfer_uv", "vertex_color_texture", "vertex_error",
           "vertex_groups", "VertexError", "wendland"]
