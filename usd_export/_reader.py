"""Read back what :class:`AnimationWriter` wrote, and run USD's own checks on a file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._arrays import UsdExportError
from ._pxr import Usd, UsdGeom, UsdUtils
from ._writer import FORMATS, MUSCLES, PARTS, SKIN, TISSUE, check_path


def read_animation(path) -> dict:
    """Read an animation written by :class:`AnimationWriter` (``.usda``, ``.usdc`` or ``.usdz``).

    Every animated array is sampled at the head's time codes (the frames given to ``add_frame``);
    where an attribute has no sample at such a time code USD's value resolution applies (held or
    linearly interpolated from the neighbouring samples).

    Returns:
        A dict with
        ``fps`` (float), ``time_codes`` (f,) float64, ``times`` (f,) float64 [s] (= codes / fps),
        ``up_axis`` ("Y"/"Z"), ``meters_per_unit`` (float),
        ``faces`` (m, 3) int32, ``rest_points`` (n, 3) float32, ``points`` (f, n, 3) float32,
        ``normals`` (f, n, 3) float32, ``uv`` ((n, 2) or (k, 2) float32, or None),
        ``uv_indices`` ((m, 3) int32 or None),
        ``parts`` {name: (V (k, 3) float32, F (l, 3) int32)},
        ``part_transforms`` {name: (f, 4, 4) float64} (row-vector convention, ``p' = p @ M``),
        ``muscles`` [names], ``muscle_points`` (f, M, s, 3) float32 or None,
        ``activations`` (f, M) float32 or None,
        ``tets`` (T (k, 4) int32, rest nodes (p, 3) float32) or None, ``tet_points`` (f, p, 3) float32 or None.
        With no frames written, f = 0.

    Raises:
        UsdExportError: wrong extension, or not a file in this layout.
        FileNotFoundError: no file at ``path``.
    """
    path = check_path(path, allowed=FORMATS + (".usd",))
    if not path.is_file():
        raise FileNotFoundError(f"path: no file at {str(path)!r}")
    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise UsdExportError(f"path: USD could not open {str(path)!r}")
    head = stage.GetDefaultPrim()
    skin = UsdGeom.Mesh(head.GetChild(SKIN)) if head else UsdGeom.Mesh()
    if not skin:
        raise UsdExportError(f"path: {str(path)!r} has no default prim with a '{SKIN}' mesh "
                             "(not written by AnimationWriter)")
    fps = stage.GetTimeCodesPerSecond()
    codes = np.array(skin.GetPointsAttr().GetTimeSamples(), np.float64)
    out = {"fps": fps, "time_codes": codes, "times": codes / fps, "up_axis": str(UsdGeom.GetStageUpAxis(stage)),
           "meters_per_unit": UsdGeom.GetStageMetersPerUnit(stage)}
    out.update(_read_skin(skin, codes))
    out.update(_read_parts(head.GetChild(PARTS), codes))
    out.update(_read_muscles(head.GetChild(MUSCLES), codes))
    out.update(_read_tissue(head.GetChild(TISSUE), codes))
    return out


def _samples(attr, codes: np.ndarray, shape: tuple, dtype) -> np.ndarray | None:
    if not attr or not attr.GetNumTimeSamples():
        return None
    return np.stack([np.asarray(attr.Get(c), dtype).reshape(shape) for c in codes]) if len(codes) \
        else np.zeros((0, *shape), dtype)


def _faces(mesh) -> np.ndarray:
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), np.int32)
    if counts.size and not (counts == 3).all():
        raise UsdExportError(f"{mesh.GetPath()}: expected triangles only")
    return np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), np.int32).reshape(-1, 3)


def _read_skin(skin, codes) -> dict:
    rest = np.asarray(skin.GetPointsAttr().Get(Usd.TimeCode.Default()), np.float32)
    n = len(rest)
    pv = UsdGeom.PrimvarsAPI(skin).GetPrimvar("st")
    uv = uv_indices = None
    if pv and pv.HasValue():
        uv = np.asarray(pv.Get(), np.float32)
        if pv.IsIndexed():
            uv_indices = np.asarray(pv.GetIndices(), np.int32).reshape(-1, 3)
    return {"faces": _faces(skin), "rest_points": rest,
            "points": _samples(skin.GetPointsAttr(), codes, (n, 3), np.float32),
            "normals": _samples(skin.GetNormalsAttr(), codes, (n, 3), np.float32), "uv": uv, "uv_indices": uv_indices}


def _read_parts(group, codes) -> dict:
    parts, transforms = {}, {}
    for xf_prim in (group.GetChildren() if group else []):
        # the part's Mesh prim carries its transform (an Xform over a child "Mesh" in older files)
        mesh = UsdGeom.Mesh(xf_prim) if xf_prim.IsA(UsdGeom.Mesh) else UsdGeom.Mesh(xf_prim.GetChild("Mesh"))
        if not mesh:
            continue
        name = xf_prim.GetDisplayName() or xf_prim.GetName()
        parts[name] = (np.asarray(mesh.GetPointsAttr().Get(), np.float32), _faces(mesh))
        xf = UsdGeom.Xformable(xf_prim)
        transforms[name] = np.stack([np.array(xf.GetLocalTransformation(c), np.float64) for c in codes]) \
            if len(codes) else np.zeros((0, 4, 4))
    return {"parts": parts, "part_transforms": transforms}


def _read_muscles(prim, codes) -> dict:
    curves = UsdGeom.BasisCurves(prim)
    if not curves:
        return {"muscles": [], "muscle_points": None, "activations": None}
    names = list(prim.GetAttribute("muscleNames").Get() or [])
    counts = np.asarray(curves.GetCurveVertexCountsAttr().Get(), np.int32)
    s = int(counts[0]) if counts.size else 0
    act = UsdGeom.PrimvarsAPI(curves).GetPrimvar("activation")
    return {"muscles": names, "muscle_points": _samples(curves.GetPointsAttr(), codes, (len(names), s, 3), np.float32),
            "activations": _samples(act.GetAttr() if act else None, codes, (len(names),), np.float32)}


def _read_tissue(prim, codes) -> dict:
    if not prim or not hasattr(UsdGeom, "TetMesh") or not prim.IsA(UsdGeom.TetMesh):
        return {"tets": None, "tet_points": None}
    tm = UsdGeom.TetMesh(prim)
    nodes = np.asarray(tm.GetPointsAttr().Get(Usd.TimeCode.Default()), np.float32)
    T = np.asarray(tm.GetTetVertexIndicesAttr().Get(), np.int32).reshape(-1, 4)
    return {"tets": (T, nodes), "tet_points": _samples(tm.GetPointsAttr(), codes, (len(nodes), 3), np.float32)}


def validate_usd(path) -> list[str]:
    """USD's own compliance checks on a file; returns the problems found (empty when clean).

    Uses ``UsdUtils.ComplianceChecker`` (usdchecker's rules; ARKit rules off) where the installed
    usd-core has it, else (newer usd-core, e.g. 26.11, ships ``UsdValidation`` instead) every validator
    registered with ``UsdValidation``, reporting errors and warnings. Each entry is one line.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no file at {str(path)!r}")
    if hasattr(UsdUtils, "ComplianceChecker"):  # pragma: no cover - older usd-core
        checker = UsdUtils.ComplianceChecker(arkit=False, skipARKitRootLayerCheck=False, rootPackageOnly=False,
                                             skipVariants=False, verbose=False)
        checker.CheckCompliance(str(path))
        return [f"error: {e}" for e in checker.GetErrors()] + [f"failed: {e}" for e in checker.GetFailedChecks()] \
            + [f"warning: {w}" for w in checker.GetWarnings()]
    from pxr import UsdValidation

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        return [f"error: USD could not open {str(path)!r}"]
    ctx = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    out = []
    for err in ctx.Validate(stage):
        kind = err.GetType()
        if kind in (UsdValidation.ValidationErrorType.Error, UsdValidation.ValidationErrorType.Warn):
            label = "error" if kind == UsdValidation.ValidationErrorType.Error else "warning"
            out.append(f"{label}: {err.GetIdentifier()}: {' '.join(err.GetMessage().split())}")
    return out
