"""Expressions (thesis Sec. 6.5): timeline segments, blends, sequence files and jaw helpers (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.expressions import blend, jaw_angle_for_drop, load_sequence, Segment, timeline_from_spec  # noqa: F401
from ._src.expressions import jaw_lever  # noqa: F401
from ._src.expressions import expression_from_activations  # noqa: F401
from ._src.expressions import REFERENCE_JAW_LEVER  # noqa: F401
__all__ = ["blend", "expression_from_activations", "jaw_angle_for_drop", "jaw_lever", "load_sequence",
           "REFERENCE_JAW_LEVER", "Segment", "timeline_from_spec"]
