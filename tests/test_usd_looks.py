"""The head's USD looks right in a DCC tool: parts named on their Mesh prims, lips / sclera / iris /
pupil coloured by material subsets (each eyeball partitioned once, the iris and pupil about the gaze
to the pupil FDPs 3.5 / 3.6), teeth with pink gums at their roots and tongue looks, an iris colour
option, a camera that frames the head and lights; USD's checks pass."""

from __future__ import annotations

import numpy as np
import pytest

import facewarp as fw

pxr = pytest.importorskip("pxr")
import usd_export  # noqa: E402
from usd_export import AnimationWriter, UsdExportError  # noqa: E402

PART_PRIMS = {"eye_L": "Eye_L", "eye_R": "Eye_R", "teeth_upper": "Teeth_Upper", "teeth_lower": "Teeth_Lower",
              "tongue": "Tongue"}


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    rig = fw.build_face(fw.default_template(0))
    sim = fw.FaceSimulator(rig)
    path = tmp_path_factory.mktemp("looks") / "take.usdc"
    with fw.UsdAnimation(path, sim) as usd:
        usd.add(sim, 0.0)
        sim.set_jaw(0.2)
        sim.step()
        usd.add(sim, 1 / sim.fps)
    return rig, path


def test_parts_are_named_mesh_prims(take):
    from pxr import Usd, UsdGeom

    rig, path = take
    stage = Usd.Stage.Open(str(path))
    assert stage.GetPrimAtPath("/Head/Skin").IsA(UsdGeom.Mesh)
    assert set(rig.parts) == set(PART_PRIMS)
    for name, prim_name in PART_PRIMS.items():
        prim = stage.GetPrimAtPath(f"/Head/Parts/{prim_name}")
        assert prim.IsA(UsdGeom.Mesh), prim_name  # the Mesh itself carries the name (no child "Mesh")
        assert not prim.GetChildren() or all(c.IsA(UsdGeom.Subset) for c in prim.GetChildren())
    back = usd_export.read_animation(path)  # the parts' own names come back
    assert set(back["parts"]) == set(rig.parts)
    jaw_row = back["part_transforms"]["teeth_lower"][1]
    assert not np.allclose(jaw_row, np.eye(4))  # the lower teeth moved with the jaw


def test_colours_of_lips_eyes_teeth(take):
    from pxr import Usd, UsdGeom, UsdShade

    rig, path = take
    stage = Usd.Stage.Open(str(path))

    def colour(prim):
        mat = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]
        shader = UsdShade.Shader(stage.GetPrimAtPath(mat.GetPath().AppendChild("PreviewSurface")))
        return np.array(shader.GetInput("diffuseColor").Get())

    skin = stage.GetPrimAtPath("/Head/Skin")
    lips = UsdGeom.Subset(stage.GetPrimAtPath("/Head/Skin/Lips"))
    faces = np.array(lips.GetIndicesAttr().Get())
    assert 10 < len(faces) < 0.05 * len(rig.head_faces)
    # the lip faces sit around the mouth: within 35 mm of the mouth corners' midpoint
    V = np.asarray(rig.head_vertices)
    C = V[np.asarray(rig.head_faces)[faces]].mean(1)
    ids = [str(k) for k in rig.fdp_ids]
    P = fw.FaceSimulator(rig).fdp_points()
    mouth = 0.5 * (P[ids.index("8.3")] + P[ids.index("8.4")])
    assert np.linalg.norm(C - mouth, axis=1).max() < 0.035
    assert colour(lips.GetPrim())[0] < colour(skin)[0]  # redder / darker than the skin
    for side in ("Eye_L", "Eye_R"):
        iris = UsdGeom.Subset(stage.GetPrimAtPath(f"/Head/Parts/{side}/Iris"))
        pupil = UsdGeom.Subset(stage.GetPrimAtPath(f"/Head/Parts/{side}/Pupil"))
        assert len(iris.GetIndicesAttr().Get()) and len(pupil.GetIndicesAttr().Get())
        assert colour(pupil.GetPrim()).max() < 0.1 and colour(stage.GetPrimAtPath(f"/Head/Parts/{side}")).min() > 0.8
        assert colour(iris.GetPrim())[0] > colour(iris.GetPrim())[2]  # brown-hazel iris by default
    assert colour(stage.GetPrimAtPath("/Head/Parts/Tongue"))[0] > 0.6


def test_eyes_are_sclera_iris_pupil_once_about_the_gaze(take):
    from pxr import Usd, UsdGeom, UsdShade

    rig, path = take
    stage = Usd.Stage.Open(str(path))
    ids = [str(k) for k in rig.fdp_ids]
    P = fw.FaceSimulator(rig).fdp_points()  # at rest
    for part, prim_name, pupil_fdp in (("eye_L", "Eye_L", "3.5"), ("eye_R", "Eye_R", "3.6")):
        V, F = (np.asarray(a) for a in rig.parts[part])
        prim = stage.GetPrimAtPath(f"/Head/Parts/{prim_name}")
        subsets = {s.GetPrim().GetName(): np.array(s.GetIndicesAttr().Get())
                   for s in UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()}
        assert set(subsets) == {"Sclera", "Iris", "Pupil"}, subsets.keys()
        assert UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsetsFamilyType() == UsdGeom.Tokens.partition
        every = np.sort(np.concatenate(list(subsets.values())))
        np.testing.assert_array_equal(every, np.arange(len(F)), err_msg=f"{part}: faces not covered exactly once")
        for name, idx in subsets.items():
            sub = UsdGeom.Subset(stage.GetPrimAtPath(f"/Head/Parts/{prim_name}/{name}"))
            mat = UsdShade.MaterialBindingAPI(sub.GetPrim()).GetDirectBinding().GetMaterial()
            assert mat.GetPath() == f"/Head/Looks/{name}" and len(idx), (part, name)
        c = V.mean(0)
        R = np.linalg.norm(V - c, axis=1).mean()
        gaze = (P[ids.index(pupil_fdp)] - c) / np.linalg.norm(P[ids.index(pupil_fdp)] - c)
        D = V[F].mean(1) - c
        angle = np.degrees(np.arccos(np.clip(D @ gaze / np.linalg.norm(D, axis=1), -1, 1)))
        iris_half = np.degrees(np.arcsin(0.5 * 11.7e-3 / R))  # a human iris ~11.7 mm across
        assert angle[subsets["Iris"]].max() <= iris_half + 1e-6
        assert angle[subsets["Sclera"]].min() > iris_half
        assert angle[subsets["Pupil"]].max() < angle[subsets["Iris"]].max()
        assert angle.argmin() in subsets["Pupil"]
    for look in ("Sclera", "Iris", "Pupil", "Teeth_Upper", "Teeth_Lower", "Gums", "Tongue"):
        assert stage.GetPrimAtPath(f"/Head/Looks/{look}").IsA(UsdShade.Material), look
    for teeth in ("Teeth_Upper", "Teeth_Lower"):
        mat = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(f"/Head/Parts/{teeth}")).ComputeBoundMaterial()[0]
        assert mat.GetPath() == f"/Head/Looks/{teeth}"
        rgb = np.array(UsdShade.Shader(stage.GetPrimAtPath(f"{mat.GetPath()}/PreviewSurface"))
                       .GetInput("diffuseColor").Get())
        assert rgb.min() > 0.8 and rgb[2] < rgb[0]  # ivory


def test_teeth_have_pink_gums_at_their_roots(take):
    from pxr import Usd, UsdGeom, UsdShade

    rig, path = take
    stage = Usd.Stage.Open(str(path))
    gums = UsdShade.Shader(stage.GetPrimAtPath("/Head/Looks/Gums/PreviewSurface"))
    rgb = np.array(gums.GetInput("diffuseColor").Get())
    assert rgb[0] > 0.5 and rgb[0] > rgb[1] + 0.2 and rgb[0] > rgb[2] + 0.2, rgb  # pink, not ivory
    for part, prim_name, root in (("teeth_upper", "Teeth_Upper", 1.0), ("teeth_lower", "Teeth_Lower", -1.0)):
        prim = stage.GetPrimAtPath(f"/Head/Parts/{prim_name}")
        mesh = UsdGeom.Mesh(prim)
        P = np.array(mesh.GetPointsAttr().Get(), np.float64)
        F = np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
        subsets = {s.GetPrim().GetName(): np.array(s.GetIndicesAttr().Get())
                   for s in UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()}
        assert set(subsets) == {"Gums", "Rest"}, subsets.keys()  # Rest: the teeth, on the part's own look
        for name, look in (("Gums", "Gums"), ("Rest", prim_name)):
            sub = UsdGeom.Subset(stage.GetPrimAtPath(f"/Head/Parts/{prim_name}/{name}"))
            mat = UsdShade.MaterialBindingAPI(sub.GetPrim()).GetDirectBinding().GetMaterial()
            assert mat.GetPath() == f"/Head/Looks/{look}", (prim_name, name)
        every = np.sort(np.concatenate(list(subsets.values())))
        np.testing.assert_array_equal(every, np.arange(len(F)))
        # the written row is the rig's own surface (split at the gum line only for the looks)
        V0, F0 = np.asarray(rig.parts[part][0], np.float64), np.asarray(rig.parts[part][1])

        def area(V, F):
            return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()

        np.testing.assert_allclose(area(P, F), area(V0, F0), rtol=1e-5)
        np.testing.assert_allclose([P.min(0), P.max(0)], [V0.min(0), V0.max(0)], atol=1e-6)
        # the gums: the faces within 3 mm of the root end (top of the upper row, bottom of the lower),
        # the front (labial) side included; the teeth: the rest, on the crown side
        h = root * P[F].mean(1)[:, 1]
        end = root * (V0[:, 1].max() if root > 0 else V0[:, 1].min())
        gum = np.zeros(len(F), bool)
        gum[subsets["Gums"]] = True
        assert gum.any() and (~gum).any()
        assert (h[gum] > end - 3.0e-3).all() and (h[~gum] < end - 1.0e-3).all()
        front = P[F].mean(1)[:, 2] > V0[:, 2].max() - 1.0e-3
        assert (gum & front).any() and (~gum & front).any()


def test_iris_colour_option(tmp_path):
    from pxr import Usd, UsdShade

    sim = fw.FaceSimulator(fw.build_face(fw.default_template(0)))
    with fw.UsdAnimation(tmp_path / "blue.usda", sim, iris_color=(0.1, 0.3, 0.5)) as usd:
        usd.add(sim, 0.0)
    stage = Usd.Stage.Open(str(tmp_path / "blue.usda"))
    shader = UsdShade.Shader(stage.GetPrimAtPath("/Head/Looks/Iris/PreviewSurface"))
    np.testing.assert_allclose(shader.GetInput("diffuseColor").Get(), (0.1, 0.3, 0.5), atol=1e-6)
    with pytest.raises(fw.InputError, match="iris_color"):
        fw.UsdAnimation(tmp_path / "bad.usda", sim, iris_color=(1.5, 0, 0))
    assert not (tmp_path / "bad.usda").exists()


def test_camera_frames_the_head_and_checks_pass(take):
    from pxr import Gf, Usd, UsdGeom

    rig, path = take
    stage = Usd.Stage.Open(str(path))
    cam = UsdGeom.Camera(stage.GetPrimAtPath("/Camera"))
    frustum = cam.GetCamera(Usd.TimeCode(0)).frustum
    V = np.asarray(rig.head_vertices)
    box = Gf.BBox3d(Gf.Range3d(Gf.Vec3d(*V.min(0)), Gf.Vec3d(*V.max(0))))
    assert frustum.Intersects(box)
    M = frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix()
    for corner in (V.min(0), V.max(0), V[np.argmax(V[:, 1])], V[np.argmin(V[:, 1])]):
        p = M.Transform(Gf.Vec3d(*corner))
        assert abs(p[0]) < 1 and abs(p[1]) < 1, corner  # inside the picture
    assert stage.GetPrimAtPath("/Lights/Key") and stage.GetPrimAtPath("/Lights/Fill")
    assert usd_export.validate_usd(path) == []


def test_looks_arguments_are_checked(tmp_path):
    V = 0.1 * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    base = dict(fps=30, faces=F, rest_points=V, parts={"eye": (V, F)})
    for kw, needle in [
        (dict(part_colors={"nose": (1, 0, 0)}), "unknown part"),
        (dict(part_colors={"eye": (2, 0, 0)}), "0..1"),
        (dict(subsets={"Skin": {"Lips": ([0, 99], (1, 0, 0))}}), "indices"),
        (dict(subsets={"Skin": {"A": ([0], (1, 0, 0)), "B": ([0], (0, 1, 0))}}), "overlap"),
        (dict(subsets={"Skin": {"A": ([0], (1, 0, 0))}, "eye": {"A": ([1], (0, 1, 0))}}), "two colours"),
        (dict(subsets={"Nose": {"A": ([0], (1, 0, 0))}}), "unknown mesh"),
        (dict(camera={"position": (0, 0, 1), "target": (0, 0, 1), "up": (0, 1, 0)}), "camera"),
        (dict(camera={"position": (0, 0, 1)}), "camera"),
    ]:
        with pytest.raises(UsdExportError, match=needle):
            AnimationWriter(tmp_path / "x.usda", **base, **kw)
    assert not list(tmp_path.iterdir())  # nothing left behind
