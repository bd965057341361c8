"""usd_export: meshes and animations written with time samples and read back through pxr."""

from __future__ import annotations

import numpy as np
import pytest

import usd_export
from usd_export import AnimationWriter, UsdExportError, read_animation, validate_usd, write_meshes_usd

FORMATS = ("usda", "usdc", "usdz")


def test_time_sampled_mesh_roundtrip(tmp_path):
    from pxr import Usd, UsdGeom

    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2]])
    frames = np.stack([V + [0, 0, 0.1 * k] for k in range(3)])
    p = write_meshes_usd(tmp_path / "a.usda", {"skin": (V, F)}, frames={"skin": frames}, times=[0, 1 / 30, 2 / 30])
    stage = Usd.Stage.Open(str(p))
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Head/skin"))
    pts = np.array(mesh.GetPointsAttr().Get(2.0))
    np.testing.assert_allclose(pts[:, 2], 0.2, rtol=1e-6)
    assert list(mesh.GetFaceVertexIndicesAttr().Get()) == [0, 1, 2]
    assert not [q for q in tmp_path.iterdir() if q.name.startswith(".")]


# ----------------------------------------------------------------------------- fixtures
def octahedron(radius: float = 0.1):
    """V (6, 3), F (8, 3) counter-clockwise seen from outside."""
    V = radius * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return V, F


def single_tet():
    return np.array([[0, 1, 2, 3]]), 0.01 * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)


def rigid(angle: float, t) -> np.ndarray:
    """Rotation about Y by ``angle`` then translation ``t``, row-vector convention (p' = p @ M)."""
    c, s = np.cos(angle), np.sin(angle)
    M = np.eye(4)
    M[:3, :3] = [[c, 0, -s], [0, 1, 0], [s, 0, c]]
    M[3, :3] = t
    return M


def make_take(frames: int = 4, seed: int = 0):
    rng = np.random.default_rng(seed)
    V, F = octahedron()
    eye_V, eye_F = octahedron(0.01)
    T, nodes = single_tet()
    setup = dict(fps=24.0, faces=F, rest_points=V, uv=V[:, :2] + 0.5, parts={"eye.L": (eye_V + 0.05, eye_F),
                 "jaw": (eye_V, eye_F)}, muscles=["zygomaticus", "frontalis", "orbicularis"], muscle_samples=4,
                 tets=(T, nodes))
    take = [dict(time_s=k / 24.0, points=V * (1 + 0.1 * k) + rng.normal(0, 1e-3, V.shape),
                 part_transforms={"eye.L": rigid(0.1 * k, [0, 0.001 * k, 0]),
                                  "jaw": rigid(-0.05 * k, [0, -0.002 * k, 0])},
                 muscle_points=rng.normal(0, 0.05, (3, 4, 3)), activations=rng.uniform(0, 1, 3),
                 tet_points=nodes + rng.normal(0, 1e-4, nodes.shape)) for k in range(frames)]
    return setup, take


def write_take(path, setup, take, **kw):
    with AnimationWriter(path, **setup, **kw) as w:
        for fr in take:
            fr = dict(fr)
            w.add_frame(fr.pop("time_s"), fr.pop("points"), **fr)
    return path


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """One take written to every format: {ext: path}, plus the inputs."""
    d = tmp_path_factory.mktemp("takes")
    setup, take = make_take()
    return {ext: write_take(d / f"take.{ext}", setup, take) for ext in FORMATS}, setup, take


# ----------------------------------------------------------------------------- round trip
@pytest.mark.parametrize("ext", FORMATS)
def test_animation_roundtrip_exact(written, ext):
    paths, setup, take = written
    d = read_animation(paths[ext])
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    np.testing.assert_array_equal(d["time_codes"], np.arange(len(take)), err_msg="time code = frame index")
    np.testing.assert_allclose(d["times"], [fr["time_s"] for fr in take], rtol=1e-12)
    assert d["fps"] == 24.0 and d["up_axis"] == "Y" and d["meters_per_unit"] == 1.0
    np.testing.assert_array_equal(d["faces"], setup["faces"])
    np.testing.assert_array_equal(d["rest_points"], f32(setup["rest_points"]))
    np.testing.assert_array_equal(d["points"], f32([fr["points"] for fr in take]), err_msg="points bit-exact")
    np.testing.assert_array_equal(d["uv"], f32(setup["uv"]))
    assert d["uv_indices"] is None
    assert set(d["parts"]) == {"eye.L", "jaw"}
    for name in ("eye.L", "jaw"):
        np.testing.assert_array_equal(d["parts"][name][0], f32(setup["parts"][name][0]))
        np.testing.assert_array_equal(d["part_transforms"][name], [fr["part_transforms"][name] for fr in take])
    assert d["muscles"] == setup["muscles"]
    np.testing.assert_array_equal(d["muscle_points"], f32([fr["muscle_points"] for fr in take]))
    np.testing.assert_array_equal(d["activations"], f32([fr["activations"] for fr in take]))
    np.testing.assert_array_equal(d["tets"][0], setup["tets"][0])
    np.testing.assert_array_equal(d["tet_points"], f32([fr["tet_points"] for fr in take]))


def test_part_transform_moves_part_as_row_vectors(written):
    """World position of a part vertex = [p, 1] @ M (USD's row-vector convention)."""
    from pxr import Usd, UsdGeom

    paths, setup, take = written
    stage = Usd.Stage.Open(str(paths["usdc"]))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Head/Parts/Jaw"))
    M = np.array(UsdGeom.Xformable(mesh).ComputeLocalToWorldTransform(Usd.TimeCode(3)))
    p = np.append(setup["parts"]["jaw"][0][0], 1.0)
    np.testing.assert_allclose(p @ M, p @ take[3]["part_transforms"]["jaw"], atol=1e-7)
    assert M[3, 1] == pytest.approx(-0.006), "translation sits in row 3"


def test_stage_metadata_normals_extent_materials(written):
    from pxr import Usd, UsdGeom, UsdShade

    paths, setup, take = written
    stage = Usd.Stage.Open(str(paths["usda"]))
    assert stage.GetDefaultPrim().GetPath() == "/Head"
    assert stage.GetTimeCodesPerSecond() == stage.GetFramesPerSecond() == 24.0
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0.0, len(take) - 1.0)
    skin = UsdGeom.Mesh(stage.GetPrimAtPath("/Head/Skin"))
    assert skin.GetNormalsInterpolation() == "vertex" and skin.GetSubdivisionSchemeAttr().Get() == "none"
    assert list(skin.GetNormalsAttr().GetTimeSamples()) == list(range(len(take)))
    for k, fr in enumerate(take):
        P = np.asarray(fr["points"], np.float32)
        np.testing.assert_array_equal(np.array(skin.GetExtentAttr().Get(k)), [P.min(0), P.max(0)])
        N = np.array(skin.GetNormalsAttr().Get(k))
        np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, rtol=1e-6)
        assert (np.einsum("ij,ij->i", N, P - P.mean(0)) > 0).all(), "normals point outwards"
    mat, _ = UsdShade.MaterialBindingAPI(skin.GetPrim()).ComputeBoundMaterial()
    assert mat.GetPath() == "/Head/Looks/Skin"
    eye = stage.GetPrimAtPath("/Head/Parts/Eye_L")
    assert UsdShade.MaterialBindingAPI(eye).ComputeBoundMaterial()[0].GetPath() == "/Head/Looks/White"
    curves = UsdGeom.BasisCurves(stage.GetPrimAtPath("/Head/Muscles"))
    assert curves.GetTypeAttr().Get() == "linear"
    act = UsdGeom.PrimvarsAPI(curves).GetPrimvar("activation")
    assert act.GetInterpolation() == "uniform" and len(act.GetAttr().GetTimeSamples()) == len(take)
    assert stage.GetPrimAtPath("/Head/Tissue").GetTypeName() == "TetMesh"


def test_normals_are_area_weighted(tmp_path):
    """Vertex 0 is shared by a large face in the z=0 plane and a small one in the x=0 plane."""
    V = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 1], [0, -1, 0]], float)
    F = np.array([[0, 1, 2], [0, 3, 4]])  # normals +z (area 2) and +x (area 0.5)
    p = write_take(tmp_path / "n.usdc", dict(fps=30, faces=F, rest_points=V), [dict(time_s=0.0, points=V)])
    want = np.array([0.5, 0, 2]) / np.linalg.norm([0.5, 0, 2])
    np.testing.assert_allclose(read_animation(p)["normals"][0, 0], want, rtol=1e-6)


@pytest.mark.parametrize("ext", FORMATS)
def test_usd_checks_report_nothing(written, ext):
    assert validate_usd(written[0][ext]) == []


def test_face_varying_uv_and_no_frames(tmp_path):
    V, F = octahedron()
    uv = np.random.default_rng(1).uniform(0, 1, (24, 2))
    p = tmp_path / "still.usdz"
    AnimationWriter(p, fps=30, faces=F, rest_points=V, uv=uv, uv_indices=np.arange(24).reshape(8, 3)).close()
    d = read_animation(p)
    assert d["points"] is None and d["time_codes"].shape == (0,)
    np.testing.assert_array_equal(d["uv"], uv.astype(np.float32))
    np.testing.assert_array_equal(d["uv_indices"], np.arange(24).reshape(8, 3))
    assert validate_usd(p) == []


@pytest.mark.parametrize("ext", ["usdc", "usda"])
def test_many_flushes_stay_exact(tmp_path, ext):
    """flush_bytes=1 appends every frame to the working file (the long-take path)."""
    setup, take = make_take(frames=80, seed=2)
    d = read_animation(write_take(tmp_path / f"long.{ext}", setup, take, flush_bytes=1))
    np.testing.assert_array_equal(d["points"], np.asarray([fr["points"] for fr in take], np.float32))
    np.testing.assert_array_equal(d["time_codes"], np.arange(80))
    assert [q.name for q in tmp_path.iterdir()] == [f"long.{ext}"]


# ----------------------------------------------------------------------------- atomic writes
@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
@pytest.mark.parametrize("ext", FORMATS)
def test_exception_leaves_no_file(tmp_path, ext, exc):
    setup, take = make_take(frames=3)
    with pytest.raises(exc):
        with AnimationWriter(tmp_path / f"take.{ext}", **setup, flush_bytes=1) as w:
            for fr in take:
                fr = dict(fr)
                w.add_frame(fr.pop("time_s"), fr.pop("points"), **fr)
            raise exc("stop")
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_existing_file(tmp_path):
    V, F = octahedron()
    p = tmp_path / "take.usdc"
    p.write_bytes(b"previous take")
    with pytest.raises(UsdExportError, match="points: expected shape"):
        with AnimationWriter(p, fps=30, faces=F, rest_points=V) as w:
            w.add_frame(0.0, V[:5])
    assert [q.name for q in tmp_path.iterdir()] == ["take.usdc"] and p.read_bytes() == b"previous take"


# ----------------------------------------------------------------------------- input checks
def test_bad_extension(tmp_path):
    V, F = octahedron()
    with pytest.raises(UsdExportError, match=r"'.*take\.obj'.*expected one of .usda, .usdc, .usdz") as e:
        AnimationWriter(tmp_path / "take.obj", fps=30, faces=F, rest_points=V)
    assert isinstance(e.value, ValueError) and "\n" not in str(e.value)
    with pytest.raises(UsdExportError, match="expected one of"):
        read_animation(tmp_path / "take.abc")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("call, message", [
    (lambda w, V: w.add_frame(0.0, V[:5]), r"points: expected shape \(6, 3\), got \(5, 3\)"),
    (lambda w, V: w.add_frame(0.0, V * np.nan), r"points: expected finite float32 values"),
    (lambda w, V: w.add_frame(0.0, V.astype(complex)), r"points: expected a real float array, got dtype complex128"),
    (lambda w, V: (w.add_frame(0.1, V), w.add_frame(0.1, V)), r"time_s: expected a time after the previous frame's"),
    (lambda w, V: w.add_frame(float("inf"), V), r"time_s: expected a finite time"),
    (lambda w, V: w.add_frame(0.0, V, part_transforms={"nose": np.eye(4)}), r"part_transforms: unknown part 'nose'"),
    (lambda w, V: w.add_frame(0.0, V, part_transforms={"jaw": rigid(0.1, [0, 1, 0]).T}),
     r"part_transforms\['jaw'\]: last column must be \(0, 0, 0, 1\).*transpose"),
    (lambda w, V: w.add_frame(0.0, V, muscle_points=np.zeros((2, 4, 3))),
     r"muscle_points: expected shape \(3, 4, 3\), got \(2, 4, 3\)"),
    (lambda w, V: w.add_frame(0.0, V, activations=np.zeros(4)), r"activations: expected shape \(3,\), got \(4,\)"),
    (lambda w, V: w.add_frame(0.0, V, tet_points=np.zeros((5, 3))), r"tet_points: expected shape \(4, 3\)"),
])
def test_add_frame_checks(tmp_path, call, message):
    setup, _ = make_take()
    with pytest.raises(UsdExportError, match=message) as e:
        with AnimationWriter(tmp_path / "x.usdc", **setup) as w:
            call(w, setup["rest_points"])
    assert "\n" not in str(e.value)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("change, message", [
    (dict(faces=np.array([[0, 1, 6]])), r"faces: expected indices in \[0, 6\), got \[0, 1, 6\] at row 0"),
    (dict(faces=np.zeros((2, 3), float)), r"faces: expected an integer array, got dtype float64"),
    (dict(fps=0), r"fps: expected a positive finite number"),
    (dict(uv=np.zeros((5, 2))), r"uv: expected shape \(6, 2\), got \(5, 2\)"),
    (dict(muscle_samples=1), r"muscle_samples: expected an integer >= 2"),
    (dict(muscles=["a", "a", "b"]), r"muscles: duplicate name 'a'"),
    (dict(tets=(np.array([[0, 1, 2, 9]]), np.zeros((4, 3)))), r"tets T: expected indices in \[0, 4\)"),
    (dict(parts={"eye.L": (np.zeros((3, 3)), [[0, 1, 2]]), "eye_L": (np.zeros((3, 3)), [[0, 1, 2]])}),
     r"parts: names 'eye.L' and 'eye_L' map to the same prim name 'Eye_L'"),
    (dict(up_axis="X"), r"up_axis: expected 'Y' or 'Z'"),
    (dict(tets=(np.array([[0, 2, 1, 3]]), single_tet()[1])), r"tets T: tet 0 \[0, 2, 1, 3\] is inverted at rest"),
])
def test_constructor_checks(tmp_path, change, message):
    setup, _ = make_take()
    with pytest.raises(UsdExportError, match=message):
        AnimationWriter(tmp_path / "x.usda", **{**setup, **change})
    assert list(tmp_path.iterdir()) == []


def test_public_names():
    assert set(usd_export.__all__) == {"AnimationWriter", "UsdExportError", "part_prim_name", "read_animation",
                                       "validate_usd", "write_crowd_stage", "write_meshes_usd", "write_skel_rig"}
    assert issubclass(UsdExportError, ValueError)


def test_textured_skin_subsets_show_the_texture(tmp_path):
    """With a skin texture the skin's subsets (the lips) are bound to the texture's material, so an
    importer that makes a material slot per subset (Blender) shows the texture there too; without
    one they keep their tint. The texture's asset path is relative and the file lies beside the USD,
    read at ``primvars:st`` (what Blender's USD importer follows to an Image Texture node)."""
    from PIL import Image
    from pxr import Usd, UsdGeom, UsdShade

    V = 0.1 * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    uv = 0.5 + 0.5 * V[:, :2] / 0.1
    Image.fromarray(np.full((4, 4, 3), 180, np.uint8)).save(tmp_path / "tex.png")
    looks = dict(subsets={"Skin": {"Lips": ([0, 1], (0.7, 0.3, 0.3))}})
    for textured in (True, False):
        p = tmp_path / f"h{int(textured)}.usda"
        kw = dict(uv=uv, skin_texture=tmp_path / "tex.png") if textured else {}
        with AnimationWriter(p, fps=30, faces=F, rest_points=V, **looks, **kw) as w:
            w.add_frame(0.0, V)
        assert validate_usd(p) == []
        stage = Usd.Stage.Open(str(p))
        lips = stage.GetPrimAtPath("/Head/Skin/Lips")
        assert list(UsdGeom.Subset(lips).GetIndicesAttr().Get()) == [0, 1]
        bound = {UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(f"/Head/Skin/{n}")).ComputeBoundMaterial()[0]
                 .GetPath().name for n in ("Lips", "Rest")}
        assert bound == ({"SkinTexture"} if textured else {"Lips", "Skin"}), bound
        if textured:
            tex = UsdShade.Shader(stage.GetPrimAtPath("/Head/Looks/SkinTexture/DiffuseTexture"))
            asset = tex.GetInput("file").Get()
            assert asset.path == "./h1_skin.png" and (tmp_path / "h1_skin.png").is_file()
            assert UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Head/Skin")).GetPrimvar("st").IsDefined()
