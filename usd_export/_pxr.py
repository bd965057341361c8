"""The one place that imports ``pxr`` (usd-core), with an install hint when it is missing."""

from __future__ import annotations

try:
    from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdLux, UsdShade, UsdSkel, UsdUtils, Vt
except ImportError:  # pragma: no cover - depends on the environment
    raise ImportError("usd_export needs the package usd-core: pip install usd-core") from None

__all__ = ["Gf", "Kind", "Sdf", "Usd", "UsdGeom", "UsdLux", "UsdShade", "UsdSkel", "UsdUtils", "Vt", "usd_version"]


def usd_version() -> str:
    """Version of the loaded USD library, e.g. ``"0.26.11"``."""
    return ".".join(str(v) for v in Usd.GetVersion())
