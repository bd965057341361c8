"""Static/simple multi-mesh writer kept for the CLI; animations go through :class:`AnimationWriter`."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from ._arrays import UsdExportError
from ._pxr import Gf, Usd, UsdGeom, Vt
from ._writer import prim_name as _prim_name


def write_meshes_usd(path, meshes: dict, *, frames: dict | None = None, times=None, fps: float = 30.0) -> Path:
    """Write triangle meshes to a USD file (``.usda`` text or ``.usd``/``.usdc`` binary).

    Every mesh is a deformable ``/Head/<name>`` with optional time-sampled points and one extent
    covering all frames. For a head with rigid parts, muscles, normals and per-frame extents,
    streamed with bounded memory, use :class:`usd_export.AnimationWriter`.

    Args:
        path: Output file; written to a temporary file beside it and renamed.
        meshes: name -> (V (n, 3) float [m], F (m, 3) int).
        frames: Optional name -> (frames, n, 3) float [m] vertex positions over time.
        times: (frames,) float [s], required with ``frames``.
        fps: Time codes per second of the stage.
    """
    path = Path(path)
    if frames and times is None:
        raise UsdExportError("times: required when frames are given")
    suffix = path.suffix if path.suffix in (".usda", ".usd", ".usdc") else ".usda"
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    os.close(fd)
    os.unlink(tmp)
    try:
        stage = Usd.Stage.CreateNew(tmp)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        root = UsdGeom.Xform.Define(stage, "/Head")
        stage.SetDefaultPrim(root.GetPrim())
        stage.SetTimeCodesPerSecond(fps)
        codes = None
        if frames:
            codes = np.rint(np.asarray(times, float) * fps).astype(int)
            stage.SetStartTimeCode(float(codes[0]))
            stage.SetEndTimeCode(float(codes[-1]))
        for name, (V, F) in meshes.items():
            V = np.asarray(V, np.float32)
            F = np.asarray(F, np.int32)
            mesh = UsdGeom.Mesh.Define(stage, f"/Head/{_prim_name(name)}")
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(F), 3, np.int32)))
            mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(F.ravel()))
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            pts = mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(V))
            if frames and name in frames:
                seq = np.asarray(frames[name], np.float32)
                for c, P in zip(codes, seq):
                    pts.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(P)), float(c))
                lo, hi = seq.reshape(-1, 3).min(0), seq.reshape(-1, 3).max(0)
            else:
                lo, hi = V.min(0), V.max(0)
            mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
        stage.GetRootLayer().Save()
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def write_crowd_stage(path, heads: list) -> Path:
    """One stage of many animated heads: ``/Crowd/<name>`` per head, an Xform placed by its
    transform and referencing the head's own file (its default prim), so the heads' samples stay in
    their files. The stage's up axis, unit and time range are those of the first head's file.

    Args:
        path: ``.usda`` or ``.usdc`` file; written to a temporary file beside it and renamed.
        heads: ``[(name, file, M), ...]``: the prim name, the head's USD file (referenced by its
            path relative to ``path``'s folder when it lies below it) and its placement, a 4 x 4
            matrix in USD's row-vector convention (``p' = p @ M``, translation in ``M[3, :3]``).

    Raises:
        UsdExportError: no heads, a missing head file, a bad matrix or path.
    """
    path = Path(path)
    if path.suffix not in (".usda", ".usdc"):
        raise UsdExportError(f"{path}: expected a .usda or .usdc file")
    if not heads:
        raise UsdExportError("heads: expected at least one head")
    first = None
    for name, file, M in heads:
        if not Path(file).is_file():
            raise UsdExportError(f"{file}: no such USD file")
        M = np.asarray(M, np.float64)
        if M.shape != (4, 4) or not np.isfinite(M).all() or np.abs(M[:3, 3]).max() > 0 or M[3, 3] != 1.0:
            raise UsdExportError(f"{name}: expected a finite 4 x 4 row-vector matrix with last column (0, 0, 0, 1)")
        if first is None:
            first = Usd.Stage.Open(str(file))
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    os.unlink(tmp)
    try:
        stage = Usd.Stage.CreateNew(tmp)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.GetStageUpAxis(first))
        UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.GetStageMetersPerUnit(first))
        stage.SetTimeCodesPerSecond(first.GetTimeCodesPerSecond())
        stage.SetFramesPerSecond(first.GetFramesPerSecond())
        stage.SetStartTimeCode(first.GetStartTimeCode())
        stage.SetEndTimeCode(first.GetEndTimeCode())
        root = UsdGeom.Xform.Define(stage, "/Crowd")
        stage.SetDefaultPrim(root.GetPrim())
        for name, file, M in heads:
            x = UsdGeom.Xform.Define(stage, f"/Crowd/{_prim_name(name)}")
            x.AddTransformOp().Set(Gf.Matrix4d(*np.asarray(M, np.float64).ravel().tolist()))
            f = Path(file).resolve()
            try:
                ref = "./" + f.relative_to(path.parent.resolve()).as_posix()
            except ValueError:
                ref = str(f)
            x.GetPrim().GetReferences().AddReference(ref)
        stage.GetRootLayer().Save()
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
