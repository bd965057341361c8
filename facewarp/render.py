"""Pictures: the headless Warp ray-cast renderer, colour maps, frame strips, anatomy and template previews (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.present.render import SKIN_COLOR, VIEWS, colormap, render_views, shared_hits, view_axes  # noqa: F401
from ._src.present.compare import (  # noqa: F401
    color_difference,
    flat_color_difference,
    likeness_views,
    srgb_to_lab,
)
from ._src.present.strips import (  # noqa: F401
    displacement_max,
    expression_sheet,
    frames_sheet,
    render_strip,
    sheet_font_size,
)
from ._src.present.anatomy import (  # noqa: F401
    render_anatomy,
)
from ._src.present.template import (  # noqa: F401
    CAVITY,
    GUMS,
    LIPS,
    MOUTH,
    SKIN,
    TEETH,
    TONGUE,
    colored_scene,
    head_colors,
    part_colors,
    render_previews,
    vermilion_weight,
)
from ._src.present.plot import (  # noqa: F401
    line_chart,
)
from ._src.present.looks import (  # noqa: F401
    COLORS,
    refine_ball,
)
from ._src.present.animation import (  # noqa: F401
    FACE_HEIGHT,
    FaceView,
    label_grid,
    save_gif,
)

__all__ = ["CAVITY", "color_difference", "colored_scene", "colormap", "COLORS", "displacement_max",
           "expression_sheet", "FACE_HEIGHT", "FaceView", "flat_color_difference", "frames_sheet", "GUMS",
           "head_colors", "label_grid", "likeness_views", "line_chart", "LIPS", "MOUTH", "part_colors",
           "refine_ball", "render_anatomy", "render_previews", "render_strip", "render_views", "save_gif",
           "shared_hits", "sheet_font_size", "SKIN", "SKIN_COLOR", "srgb_to_lab", "TEETH", "TONGUE",
           "vermilion_weight", "view_axes", "VIEWS"]
