"""Heads (thesis Ch. 3): the template's regions and files, importing ICT-FaceKit heads, UV layouts, synthetic scans and human likeness (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.template.head import FRONTAL_REGIONS, REGIONS, THICKNESS_FACTOR  # noqa: F401
from ._src.template.files import load_template_dir, save_template  # noqa: F401
from ._src.jobs.template import export_template  # noqa: F401
from ._src.importers.ict import ICT_INNER_LIP_VERTICES, ICT_PART_RANGES, ICT_SKIN_VERTICES, import_ict  # noqa: F401
from ._src.template.likeness import human_likeness, ICT_FDP_VERTICES  # noqa: F401
from ._src.template.uv import face_uv_layout, uv_distortion, UVLayout  # noqa: F401
from ._src.template.synthetic import FaceProportions, SyntheticScan  # noqa: F401
from ._src.template.ibug68 import IBUG68_TEMPLATE  # noqa: F401
__all__ = ["export_template", "face_uv_layout", "FaceProportions", "FRONTAL_REGIONS", "human_likeness",
           "IBUG68_TEMPLATE", "ICT_FDP_VERTICES", "ICT_INNER_LIP_VERTICES", "ICT_PART_RANGES", "ICT_SKIN_VERTICES",
           "import_ict", "load_template_dir", "REGIONS", "save_template", "SyntheticScan", "THICKNESS_FACTOR",
           "uv_distortion", "UVLayout"]
