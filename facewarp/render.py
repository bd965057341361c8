"""Pictures: the headless Warp ray-cast renderer, colour maps, frame strips, anatomy and template previews (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.present.render import (  # noqa: F401
    SKIN_COLOR,
    VIEWS,
    colormap,
    render_mesh,
    render_views,
    save_png,
)
from ._src.present.strips import (  # noqa: F401
    displacement_max,
    render_strip,
)
from ._src.present.anatomy import (  # noqa: F401
    render_anatomy,
)
from ._src.present.template import (  # noqa: F401
    LIPS,
    SKIN,
    TEETH,
    TONGUE,
    colored_scene,
    render_previews,
    vermilion_weight,
)
from ._src.present.plot import (  # noqa: F401
    line_chart,
)
from ._src.present.animation import (  # noqa: F401
    FaceView,
    label_grid,
    save_gif,
)

__all__ = ["LIPS", "SKIN", "SKIN_COLOR", "TEETH", "TONGUE", "VIEWS", "FaceView", "colored_scene", "colormap",
           "displacement_max", "label_grid", "line_chart", "render_anatomy", "render_mesh", "render_previews",
           "render_strip", "render_views", "save_gif", "save_png", "vermilion_weight"]
