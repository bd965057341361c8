"""A blendshape rig as UsdSkel: Skeleton (``root``, ``root/jaw``), SkelRoot, BlendShapes with
in-betweens, a SkelAnimation with blend-shape weights and the jaw's rotation.

Stage layout (default prim ``/Rig``, a ``SkelRoot``; metres, Y up)::

    /Rig                       SkelRoot, skel:skeleton -> /Rig/Skeleton (inherited by the meshes)
      Skeleton                 joints root, root/jaw; bind and rest transforms; skel:animationSource
        Anim                   SkelAnimation: joint root/jaw (translation, rotation per frame),
                               blendShapes, blendShapeWeights per frame (the bound clip)
        <Clip>                 further SkelAnimations (``clips``), not bound: an app binds the one
                               it plays (skel:animationSource)
      Skin                     Mesh, skinned: jointIndices / jointWeights (root, jaw; 2 per
                               vertex), skel:blendShapes, skel:blendShapeTargets; primvars:st
                               (faceVarying, indexed) and Looks/SkinTexture with a skin texture
        <shape>                BlendShape: offsets and normalOffsets (all vertices),
                               inbetweens:<name> with weights
      Parts/<Part>             Mesh, rigidly bound (constant jointIndices) to root or jaw
      Looks/...                UsdPreviewSurface materials (as the animation files)
    /Camera, /Lights           framing camera and lights (optional)
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ._arrays import UsdExportError, extent, float_array, index_array, vertex_normals
from ._pxr import Gf, Usd, UsdGeom, UsdShade, UsdSkel, Vt
from ._writer import (_SKIN_COLOR, _WHITE_COLOR, _bind_skin_texture, _camera, _lights, _material_subsets,
                      _preview_material, _uv_primvar, check_path, part_prim_name, prim_name)

__all__ = ["write_skel_rig"]



def write_skel_rig(path, *, fps: float, rest_points, faces, shapes: list, jaw_pivot, jaw_weight, parts: dict | None = None,
                   jaw_parts=(), times=None, weights=None, jaw_rotations=None, part_colors: dict | None = None,
                   subsets: dict | None = None, camera: dict | None = None, lights: bool = True, uv=None,
                   uv_indices=None, skin_texture=None, normal_offsets: dict | None = None, skin_color=None,
                   clips: dict | None = None) -> Path:
    """Write a blendshape rig as UsdSkel (``.usda`` / ``.usdc``; see the module docstring).

    Args:
        path: Output file (written beside and renamed).
        fps: Time codes per second.
        rest_points: V (n, 3) float [m]; faces: F (m, 3) int.
        shapes: [(name, offsets (n, 3), [(fraction, offsets (n, 3)), ...] in-betweens)], T shapes.
        jaw_pivot: (3,) [m]; the jaw joint's position.
        jaw_weight: (n,) float 0..1: each vertex's weight on the jaw (the rest on root).
        parts: name -> (V (k, 3), F (l, 3)) rigid parts; ``jaw_parts`` the names on the jaw joint.
        times: (f,) [s] of the animation; weights: (f, T) shape weights; jaw_rotations: (f, 4)
            unit quaternions (w, x, y, z) of the jaw joint.
        part_colors, subsets, camera, lights: as :class:`usd_export.AnimationWriter`'s.
        uv, uv_indices: The skin's texture coordinates, (k, 2) float with (m, 3) int indices per
            face corner (``primvars:st``, faceVarying), or (n, 2) per vertex.
        skin_texture: A ``.png`` / ``.jpg`` colour texture of the skin (needs ``uv``), copied beside
            the file as ``<stem>_skin.png`` and bound as ``Looks/SkinTexture`` (the lips then come
            from the texture: a ``Lips`` subset of the skin keeps the texture's material).
        normal_offsets: Optional shape name -> (n, 3) float change of the unit vertex normals of its
            full target (``normalOffsets``; in-betweens get theirs as ``[(fraction, (n, 3))]``
            under ``name + "@"``).
        skin_color: RGB (3,) in 0..1 of the skin's material (default the package palette's skin).
        clips: Optional further animations, prim name -> (times (f,) [s], weights (f, T),
            jaw_rotations (f, 4)): SkelAnimations beside ``Anim``, not bound.
    """
    path = check_path(path, allowed=(".usda", ".usdc"))
    V = float_array("rest_points", rest_points, (None, 3))
    F = index_array("faces", faces, (None, 3), upper=len(V))
    n = len(V)
    w = float_array("jaw_weight", jaw_weight, (n,))
    pivot = float_array("jaw_pivot", jaw_pivot, (3,)).astype(np.float64)
    names = [str(s[0]) for s in shapes]
    if len(set(names)) != len(names) or any(prim_name(s) != s for s in names):
        raise UsdExportError("shapes: names must be unique valid prim names")
    tex = None
    if uv is not None:
        uv = float_array("uv", uv, (None, 2))
        if uv_indices is not None:
            uv_indices = index_array("uv_indices", uv_indices, (len(F), 3), upper=len(uv))
        elif len(uv) != n:
            raise UsdExportError(f"uv: {len(uv)} coordinates for {n} vertices (give uv_indices for face-varying)")
    if skin_texture is not None:
        tex = Path(skin_texture)
        if tex.suffix.lower() not in (".png", ".jpg", ".jpeg") or not tex.is_file():
            raise UsdExportError(f"skin_texture: expected an existing .png or .jpg file, got {str(tex)!r}")
        if uv is None:
            raise UsdExportError("skin_texture: given without uv (the skin needs texture coordinates)")
    tex_name = None if tex is None else f"{path.stem}_skin{tex.suffix.lower()}"
    for cname in (clips or {}):
        if prim_name(cname) != cname or cname == "Anim":
            raise UsdExportError(f"clips: {cname!r} is not a valid prim name (or is Anim)")
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    os.unlink(tmp)
    try:
        stage = Usd.Stage.CreateNew(tmp)
        _author(stage, fps, V, F, w, pivot, shapes, names, parts or {}, tuple(jaw_parts), times, weights,
                jaw_rotations, part_colors or {}, subsets or {}, camera, lights,
                dict(uv=uv, uv_indices=uv_indices, texture=tex_name, normals=normal_offsets or {},
                     skin_color=_SKIN_COLOR if skin_color is None else tuple(float(c) for c in skin_color),
                     clips=clips or {}))
        stage.GetRootLayer().Save()
        del stage
        if tex is not None:  # the texture beside the file, under the name the material's asset path gives
            shutil.copyfile(tex, path.parent / f".{tex_name}.tmp")
            os.replace(path.parent / f".{tex_name}.tmp", path.parent / tex_name)
        shutil.move(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _author(stage, fps, V, F, w, pivot, shapes, names, parts, jaw_parts, times, weights, jaw_rotations, part_colors,
            subsets, camera, lights, skin) -> None:

    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    root = UsdSkel.Root.Define(stage, "/Rig")
    stage.SetDefaultPrim(root.GetPrim())
    skel = UsdSkel.Skeleton.Define(stage, "/Rig/Skeleton")
    skel.CreateJointsAttr(Vt.TokenArray(["root", "root/jaw"]))
    skel.CreateJointNamesAttr(Vt.TokenArray(["root", "jaw"]))
    at_pivot = Gf.Matrix4d(1.0).SetTranslate(Gf.Vec3d(*pivot))
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1.0), at_pivot]))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1.0), at_pivot]))
    UsdSkel.BindingAPI.Apply(root.GetPrim()).CreateSkeletonRel().SetTargets([skel.GetPath()])
    UsdGeom.Scope.Define(stage, "/Rig/Looks")
    skin_mat = _preview_material(stage, "/Rig/Looks/Skin", skin["skin_color"], roughness=0.55)
    # ---- skin
    mesh = UsdGeom.Mesh.Define(stage, "/Rig/Skin")
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(F), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(F.ravel()))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(V))
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(vertex_normals(V, F)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(extent(V)))
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(skin_mat)
    if skin["uv"] is not None:
        _uv_primvar(mesh, skin["uv"], skin["uv_indices"])
    if skin["texture"] is not None:
        _bind_skin_texture(stage, mesh, skin["texture"], looks="/Rig/Looks")
    bind = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    idx = np.zeros((len(V), 2), np.int32)
    idx[:, 1] = 1
    wts = np.stack([1.0 - w, w], 1).astype(np.float32)
    bind.CreateJointIndicesPrimvar(False, 2).Set(Vt.IntArray.FromNumpy(idx.ravel()))
    bind.CreateJointWeightsPrimvar(False, 2).Set(Vt.FloatArray.FromNumpy(wts.ravel()))
    bind.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))
    bind.CreateBlendShapesAttr(Vt.TokenArray(names))
    targets = []
    for name, offsets, inbetweens in shapes:
        bs = UsdSkel.BlendShape.Define(stage, f"/Rig/Skin/{name}")
        bs.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy(float_array(f"shapes[{name!r}]", offsets, (len(V), 3))))
        if name in skin["normals"]:
            bs.CreateNormalOffsetsAttr(Vt.Vec3fArray.FromNumpy(
                float_array(f"normal_offsets[{name!r}]", skin["normals"][name], (len(V), 3))))
        ib_normals = dict(skin["normals"].get(name + "@", []))
        for k, (frac, off) in enumerate(inbetweens):
            ib = bs.CreateInbetween(f"f{round(100 * frac):02d}")
            ib.SetWeight(float(frac))
            ib.SetOffsets(Vt.Vec3fArray.FromNumpy(float_array(f"shapes[{name!r}] in-between", off, (len(V), 3))))
            if frac in ib_normals:
                ib.SetNormalOffsets(Vt.Vec3fArray.FromNumpy(
                    float_array(f"normal_offsets[{name!r}] in-between", ib_normals[frac], (len(V), 3))))
        targets.append(bs.GetPath())
    bind.CreateBlendShapeTargetsRel().SetTargets(targets)
    # ---- parts, rigidly bound
    UsdGeom.Scope.Define(stage, "/Rig/Parts")
    white = _preview_material(stage, "/Rig/Looks/White", _WHITE_COLOR, roughness=0.3)
    part_paths = {}
    for pname, (P, PF) in parts.items():
        P = float_array(f"parts[{pname!r}] V", P, (None, 3))
        PF = index_array(f"parts[{pname!r}] F", PF, (None, 3), upper=len(P))
        pm = UsdGeom.Mesh.Define(stage, f"/Rig/Parts/{part_prim_name(pname)}")
        part_paths[pname] = pm.GetPath()
        pm.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(PF), 3, np.int32)))
        pm.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(PF.ravel()))
        pm.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        pm.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(P))
        pm.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(vertex_normals(P, PF)))
        pm.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        pm.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(extent(P)))
        if part_prim_name(pname) != pname:
            pm.GetPrim().SetDisplayName(str(pname))
        rgb = part_colors.get(pname)
        mat = white if rgb is None else _preview_material(stage, f"/Rig/Looks/{part_prim_name(pname)}", rgb,
                                                          roughness=0.35)
        UsdShade.MaterialBindingAPI.Apply(pm.GetPrim()).Bind(mat)
        pb = UsdSkel.BindingAPI.Apply(pm.GetPrim())
        pb.CreateJointIndicesPrimvar(True, 1).Set(Vt.IntArray([1 if pname in jaw_parts else 0]))
        pb.CreateJointWeightsPrimvar(True, 1).Set(Vt.FloatArray([1.0]))
        pb.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))
    # ---- face groups (lips, iris, pupil), the rest on the mesh's own material
    for key, groups in subsets.items():
        mpath = mesh.GetPath() if key == "Skin" else part_paths.get(key)
        if mpath is None:
            raise UsdExportError(f"subsets: unknown mesh {key!r}")
        rows = [(sub, np.sort(np.asarray(fi, np.int32)), rgb) for sub, (fi, rgb) in groups.items() if len(fi)]
        _material_subsets(stage, mpath, rows, looks="/Rig/Looks",
                          own_only=key == "Skin" and skin["texture"] is not None)
    # ---- animation: the bound clip, then any others
    anim = _skel_animation(stage, "/Rig/Skeleton/Anim", fps, pivot, names, times, weights, jaw_rotations)
    for cname, (ct, cw, cq) in skin["clips"].items():
        _skel_animation(stage, f"/Rig/Skeleton/{cname}", fps, pivot, names, ct, cw, cq, set_range=False)
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    if camera is not None:
        _camera(stage, {k: np.asarray(v, np.float64) if k != "focal_length_mm" else float(v)
                        for k, v in {"focal_length_mm": 50.0, **camera}.items()})
    if lights:
        _lights(stage, None if camera is None else {k: np.asarray(v, np.float64) for k, v in camera.items()
                                                    if k != "focal_length_mm"})


def _skel_animation(stage, path, fps, pivot, names, times, weights, jaw_rotations, *, set_range: bool = True):
    """A SkelAnimation at ``path``: the jaw joint's translation and rotation, the blend shapes' weights."""
    anim = UsdSkel.Animation.Define(stage, path)
    anim.CreateJointsAttr(Vt.TokenArray(["root/jaw"]))
    anim.CreateTranslationsAttr(Vt.Vec3fArray([Gf.Vec3f(*pivot)]))
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1.0, 1.0, 1.0)]))
    rot = anim.CreateRotationsAttr(Vt.QuatfArray([Gf.Quatf(1.0)]))
    anim.CreateBlendShapesAttr(Vt.TokenArray(names))
    bw = anim.CreateBlendShapeWeightsAttr(Vt.FloatArray(len(names)))
    if times is not None:
        t = np.asarray(times, np.float64)
        W = float_array("weights", weights, (len(t), len(names)))
        Q = float_array("jaw_rotations", jaw_rotations, (len(t), 4))
        for k, tk in enumerate(t):
            code = float(round(tk * fps, 6))
            rot.Set(Vt.QuatfArray([Gf.Quatf(float(Q[k, 0]), Gf.Vec3f(*map(float, Q[k, 1:])))]), code)
            bw.Set(Vt.FloatArray.FromNumpy(W[k]), code)
        if set_range:
            stage.SetStartTimeCode(float(round(t[0] * fps, 6)))
            stage.SetEndTimeCode(float(round(t[-1] * fps, 6)))
    return anim
