"""The default template head, authored in code (shape, meshing, FDPs, regions, anatomy refs)."""

from .head import FRONTAL_REGIONS, MAX_LEVEL, REGION_THICKNESS_MM, REGIONS, THICKNESS_FACTOR, Template, default_template

__all__ = [
    "FRONTAL_REGIONS",
    "MAX_LEVEL",
    "REGIONS",
    "REGION_THICKNESS_MM",
    "THICKNESS_FACTOR",
    "Template",
    "default_template",
]
