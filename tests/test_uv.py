"""UV layout of the template (one low-stretch face chart, a few others), carried to files and USD."""

import numpy as np
import pytest

import facewarp as fw


def _corner_areas(uv, face_uv):
    U = uv[face_uv]
    e1, e2 = U[:, 1] - U[:, 0], U[:, 2] - U[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


@pytest.mark.parametrize("level", [0, 1])
def test_template_uv_layout(level):
    t = fw.default_template(level)
    assert t.uv is not None and t.face_uv.shape == t.faces.shape
    assert t.uv.min() >= 0.0 and t.uv.max() <= 1.0
    a = _corner_areas(t.uv, t.face_uv)
    assert (a > 0).all(), f"{int((a <= 0).sum())} UV triangles flipped or degenerate"
    # no two charts overlap: the summed UV area equals the area of the union (rasterised)
    assert a.sum() < 1.0
    # seams: vertices on a chart border carry more than one UV, the others one
    per_vertex = {}
    for f, fu in zip(t.faces.ravel(), t.face_uv.ravel()):
        per_vertex.setdefault(int(f), set()).add(int(fu))
    assert max(len(s) for s in per_vertex.values()) >= 2
    assert len(t.uv) < 1.3 * t.vertex_count


def _overlapping_texels(uv, face_uv, size=512):
    U = uv[face_uv]
    X, Y = U[..., 0] * size - 0.5, (1 - U[..., 1]) * size - 0.5
    count = np.zeros(size * size, int)
    for f in range(len(U)):
        cc, rr = np.meshgrid(np.arange(int(X[f].min()), int(np.ceil(X[f].max())) + 1),
                             np.arange(int(Y[f].min()), int(np.ceil(Y[f].max())) + 1))
        px, py = cc.ravel(), rr.ravel()
        (ax, bx, cx), (ay, by, cy) = X[f], Y[f]
        det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
        l0 = ((by - cy) * (px - cx) + (cx - bx) * (py - cy)) / det
        l1 = ((cy - ay) * (px - cx) + (ax - cx) * (py - cy)) / det
        inside = (l0 > 1e-6) & (l1 > 1e-6) & (1 - l0 - l1 > 1e-6)
        np.add.at(count, py[inside] * size + px[inside], 1)
    return int((count > 1).sum())


@pytest.mark.parametrize("level", [0, 1])
def test_charts_do_not_overlap(level):
    """No texel lies in two UV triangles (the two sides of the mouth slit stay apart)."""
    t = fw.default_template(level)
    assert _overlapping_texels(t.uv, t.face_uv) == 0


def test_face_chart_is_low_stretch():
    t = fw.default_template(0)
    d = fw.heads.uv_distortion(t.vertices, t.faces, t.uv, t.face_uv, t.frontal)
    assert d["flipped"] == 0
    assert d["angle"]["mean"] < 1.15, d  # near conformal
    assert d["area"]["mean_abs_log"] < 0.12, d  # and near equal-area (ARAP)


def test_uv_distortion_analytic():
    # a planar square mapped by a uniform scale: no distortion; stretched along u by 2: s1/s2 = 2
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    d = fw.heads.uv_distortion(V, F, V[:, :2] * 0.3, F)
    assert d["angle"]["max"] == pytest.approx(1.0) and d["area"]["mean_abs_log"] == pytest.approx(0.0, abs=1e-12)
    d = fw.heads.uv_distortion(V, F, V[:, :2] * [2.0, 1.0], F)
    assert d["angle"]["mean"] == pytest.approx(2.0)


def test_obj_with_seams_round_trip(tmp_path):
    t = fw.default_template(0)
    p = tmp_path / "head.obj"
    fw.geometry.save_obj(p, t.vertices, t.faces, uv=t.uv, face_uv=t.face_uv)
    m = fw.load_mesh(p)
    np.testing.assert_array_equal(m.faces, t.faces)
    np.testing.assert_allclose(m.corner_uv, t.uv[t.face_uv], atol=1e-9)
    assert m.uv is None  # seams: no single UV per vertex


def test_template_folder_and_adapted_head_keep_uv(tmp_path):
    t = fw.default_template(0)
    fw.heads.save_template(t, tmp_path / "t")
    back = fw.heads.load_template_dir(tmp_path / "t")
    np.testing.assert_allclose(back.uv, t.uv)
    np.testing.assert_array_equal(back.face_uv, t.face_uv)
    head = fw.load_head(tmp_path / "t")
    assert head.uv is not None


def test_vertex_colours_and_texture_read(tmp_path):
    from PIL import Image

    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2]])
    C = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    fw.geometry.save_obj(tmp_path / "c.obj", V, F, colors=C)
    m = fw.load_mesh(tmp_path / "c.obj")
    np.testing.assert_allclose(m.colors, C) and np.testing.assert_allclose(m.vertices, V)
    img = np.zeros((4, 4, 3), np.uint8)
    img[0, :, 0] = 255  # top row red
    Image.fromarray(img).save(tmp_path / "tex.png")
    (tmp_path / "t.mtl").write_text("newmtl skin\nKd 1 1 1\nmap_Kd tex.png\n")
    fw.geometry.save_obj(tmp_path / "t.obj", V, F, uv=V[:, :2], face_uv=F, mtl="t.mtl")
    m = fw.load_mesh(tmp_path / "t.obj")
    assert m.texture.shape == (4, 4, 3) and m.texture[0, 0, 0] == 1.0 and m.has_color


def test_usd_skin_texture(tmp_path):
    from PIL import Image
    from pxr import Usd, UsdShade

    from usd_export import AnimationWriter, validate_usd

    t = fw.default_template(0)
    Image.fromarray(np.full((8, 8, 3), 200, np.uint8)).save(tmp_path / "texture.png")
    for ext in (".usda", ".usdz"):
        p = tmp_path / f"head{ext}"
        with AnimationWriter(p, fps=30, faces=t.faces, rest_points=t.vertices, uv=t.uv, uv_indices=t.face_uv,
                             skin_texture=tmp_path / "texture.png") as w:
            w.add_frame(0.0, t.vertices)
        assert validate_usd(p) == []
        stage = Usd.Stage.Open(str(p))
        skin = stage.GetPrimAtPath("/Head/Skin")
        mat = UsdShade.MaterialBindingAPI(skin).ComputeBoundMaterial()[0]
        assert mat.GetPath().name == "SkinTexture"
        tex = UsdShade.Shader(stage.GetPrimAtPath("/Head/Looks/SkinTexture/DiffuseTexture"))
        asset = tex.GetInput("file").Get()
        assert asset.path == "./head_skin.png"
        if ext == ".usda":
            assert (tmp_path / "head_skin.png").is_file() and asset.resolvedPath
        else:
            import zipfile

            assert "head_skin.png" in zipfile.ZipFile(p).namelist()
        st = skin.GetAttribute("primvars:st")
        assert st.GetMetadata("interpolation") == "faceVarying"


def test_ply_vertex_colours_read(tmp_path):
    import trimesh

    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    C = np.array([[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255]], np.uint8)
    trimesh.Trimesh(V, [[0, 1, 2]], vertex_colors=C, process=False).export(tmp_path / "c.ply")
    m = fw.load_mesh(tmp_path / "c.ply")
    np.testing.assert_allclose(m.colors, C[:, :3] / 255.0)
    assert m.has_color


def test_stl_is_welded(tmp_path):
    """An STL (three vertices per triangle) reads as one connected surface."""
    import trimesh

    t = fw.default_template(0)
    trimesh.Trimesh(t.vertices, t.faces, process=False).export(tmp_path / "h.stl")
    m = fw.load_mesh(tmp_path / "h.stl")
    assert m.vertex_count == t.vertex_count and fw.geometry.mesh_report(m.vertices, m.faces)["boundary_loop_count"] == 4
