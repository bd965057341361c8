"""Mesh loading (own OBJ reader, trimesh for the rest), validation, report, writing."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import trimesh

from facewarp import InputError, Mesh, load_mesh
from facewarp.geometry import SurfacePoints, closest_surface_points, mesh_report, save_obj
from facewarp.geometry import save_landmarks_json
from facewarp.geometry import unit_scale

CUBE_OBJ = """\
# unit cube, quads
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
"""


def write(path, text):
    path.write_text(text)
    return path


# ----------------------------------------------------------------------------------------
# units


def test_unit_scale():
    assert unit_scale("mm") == 1e-3 and unit_scale("cm") == 1e-2 and unit_scale("m") == 1.0
    with pytest.raises(InputError, match="units: unknown unit 'inch'"):
        unit_scale("inch")


# ----------------------------------------------------------------------------------------
# OBJ reader


def test_obj_quads_fan_triangulated_in_order(tmp_path):
    m = load_mesh(write(tmp_path / "cube.obj", CUBE_OBJ), units="cm")
    assert isinstance(m, Mesh) and m.name == "cube"
    assert m.vertices.shape == (8, 3) and m.vertices.dtype == np.float64
    assert m.faces.shape == (12, 3) and m.faces.dtype == np.int64
    np.testing.assert_allclose(m.vertices[6], [0.01, 0.01, 0.01])
    np.testing.assert_array_equal(m.faces[:2], [[0, 3, 2], [0, 2, 1]])
    assert m.uv is None
    r = mesh_report(m.vertices, m.faces)
    assert r["boundary_edge_count"] == 0 and r["consistently_oriented"] and r["component_count"] == 1


def test_obj_pentagon_and_relative_indices(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0.5 1.5 0\nv 0 1 0\nf -5 -4 -3 -2 -1\nv 2 0 0\nf 2 -1 3\n"
    m = load_mesh(write(tmp_path / "p.obj", text))
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 2, 3], [0, 3, 4], [1, 5, 2]])
    # positive indices may point forward; negative ones only back
    m = load_mesh(write(tmp_path / "fwd.obj", "f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"))
    np.testing.assert_array_equal(m.faces, [[0, 1, 2]])
    with pytest.raises(InputError, match="refers to vertex -4, but there are 3 declared before it"):
        load_mesh(write(tmp_path / "neg.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n"))


def test_obj_slash_forms_and_uv(tmp_path):
    text = (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nvn 0 0 1\n"
        "f 1/1/1 2/2/1 3/3/1\nf 2/2/1 4/4/1 3/3/1\n"
    )
    m = load_mesh(write(tmp_path / "uv.obj", text))
    np.testing.assert_allclose(m.uv, [[0, 0], [1, 0], [0, 1], [1, 1]])
    # a seam: vertex 2 (1-based) has two different UVs -> no per-vertex UV
    seam = text.replace("f 2/2/1 4/4/1", "f 2/3/1 4/4/1")
    assert load_mesh(write(tmp_path / "seam.obj", seam)).uv is None
    # v//vn: no UV
    m = load_mesh(write(tmp_path / "vn.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n"))
    assert m.uv is None and m.faces.tolist() == [[0, 1, 2]]


def test_obj_keeps_vertex_order_where_trimesh_does_not(tmp_path):
    # a UV seam makes trimesh split/reorder vertices; our reader keeps the 4 v lines
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nvt 0.5 0.5\nf 1/1 2/2 3/3\nf 2/5 4/4 3/3\n"
    m = load_mesh(write(tmp_path / "order.obj", text))
    np.testing.assert_array_equal(m.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])


def test_ict_neutral_mesh(ict_dir):
    m = load_mesh(ict_dir / "generic_neutral_mesh.obj", units="cm")
    assert m.vertices.shape == (26719, 3)
    expected = np.array([4.45898, 3.4321, 8.60292]) * 1e-2
    np.testing.assert_allclose(m.vertices[3721], expected, rtol=0, atol=1e-12)
    # 26384 polygons (quads and some triangles) -> triangles
    assert m.faces.max() < 26719 and len(m.faces) >= 26384
    r = mesh_report(m.vertices, m.faces)
    assert r["vertex_count"] == 26719 and r["non_manifold_edge_count"] == 0
    # outer eye corners 8.9 cm apart (MPEG4_FDP.md)
    assert abs(np.linalg.norm(m.vertices[3721] - m.vertices[1507]) - 0.089) < 0.002


# ----------------------------------------------------------------------------------------
# other formats


@pytest.mark.parametrize("suffix", [".ply", ".stl", ".off", ".glb"])
def test_trimesh_formats(tmp_path, suffix):
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    path = tmp_path / f"box{suffix}"
    box.export(path)
    m = load_mesh(path, units="mm")
    assert len(m.faces) == 12
    np.testing.assert_allclose(m.vertices.max(axis=0) - m.vertices.min(axis=0), [1e-3, 2e-3, 3e-3], rtol=1e-6)


def test_glb_scene_is_concatenated(tmp_path):
    a = trimesh.creation.box()
    b = trimesh.creation.icosphere(subdivisions=1)
    b.apply_translation([5.0, 0, 0])
    path = tmp_path / "scene.glb"
    trimesh.Scene([a, b]).export(path)
    m = load_mesh(path)
    assert len(m.faces) == len(a.faces) + len(b.faces)
    assert mesh_report(m.vertices, m.faces)["component_count"] == 2


# ----------------------------------------------------------------------------------------
# bad input: one line, starting with the path


def assert_one_line(excinfo, path):
    msg = str(excinfo.value)
    assert "\n" not in msg and msg.startswith(str(path)), msg


def test_missing_path(tmp_path):
    p = tmp_path / "nope.obj"
    with pytest.raises(InputError, match="no such file") as e:
        load_mesh(p)
    assert_one_line(e, p)


def test_directory(tmp_path):
    p = tmp_path / "dir.obj"
    p.mkdir()
    with pytest.raises(InputError, match="is a folder") as e:
        load_mesh(p)
    assert_one_line(e, p)


@pytest.mark.parametrize("suffix", [".obj", ".ply"])
def test_empty_file(tmp_path, suffix):
    p = write(tmp_path / f"empty{suffix}", "")
    with pytest.raises(InputError, match="file is empty") as e:
        load_mesh(p)
    assert_one_line(e, p)


def test_nan_vertex(tmp_path):
    p = write(tmp_path / "nan.obj", "v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="vertex 1 has a non-finite coordinate") as e:
        load_mesh(p)
    assert_one_line(e, p)


def test_no_faces(tmp_path):
    p = write(tmp_path / "pts.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(InputError, match="no faces") as e:
        load_mesh(p)
    assert_one_line(e, p)


def test_face_index_out_of_range(tmp_path):
    p = write(tmp_path / "oob.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n")
    with pytest.raises(InputError, match="face 0 refers to vertex 4") as e:
        load_mesh(p)
    assert_one_line(e, p)
    p = write(tmp_path / "zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n")
    with pytest.raises(InputError, match="refers to vertex 0"):
        load_mesh(p)


@pytest.mark.parametrize(
    "text, match",
    [("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", "v line 2 has 2 numbers"), ("v 0 0 x\nf 1 1 1\n", "could not parse"),
     ("v 0 0 0\nv 1 0 0\nf 1 2\n", "face 0 has 2 vertices")],
)
def test_malformed_obj(tmp_path, text, match):
    p = write(tmp_path / "bad.obj", text)
    with pytest.raises(InputError, match=match) as e:
        load_mesh(p)
    assert_one_line(e, p)


def test_garbage_and_unsupported(tmp_path):
    p = write(tmp_path / "junk.ply", "this is not a ply file\n" * 5)
    with pytest.raises(InputError) as e:
        load_mesh(p)
    assert_one_line(e, p)
    p = write(tmp_path / "mesh.xyz", "1 2 3\n")
    with pytest.raises(InputError, match="unsupported mesh format '.xyz'") as e:
        load_mesh(p)
    assert_one_line(e, p)


def test_ply_out_of_range_face(tmp_path):
    p = tmp_path / "oob.ply"
    p.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n"
    )
    with pytest.raises(InputError) as e:
        load_mesh(p)
    assert_one_line(e, p)


# ----------------------------------------------------------------------------------------
# report


def test_mesh_report_open_and_defective():
    # two triangles sharing an edge (one boundary loop), plus a far, flipped, degenerate one
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [5, 5, 5], [6, 5, 5], [7, 5, 5]], float)
    F = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]])
    r = mesh_report(V, F)
    assert r["vertex_count"] == 7 and r["face_count"] == 3
    assert r["degenerate_face_count"] == 1
    assert r["boundary_edge_count"] == 4 + 3
    assert r["boundary_loop_count"] == 2
    assert r["component_count"] == 2
    assert r["non_manifold_edge_count"] == 0
    assert r["consistently_oriented"]
    assert r["bbox_min"] == [0, 0, 0] and r["bbox_max"] == [7, 5, 5]
    json.dumps(r)  # plain types

    r = mesh_report(V, np.array([[0, 1, 2], [0, 3, 2]]))  # second triangle flipped
    assert not r["consistently_oriented"]

    # three triangles on one edge: non-manifold
    V2 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    r = mesh_report(V2, np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))
    assert r["non_manifold_edge_count"] == 1


def test_mesh_report_closed_sphere_and_holes():
    m = trimesh.creation.icosphere(subdivisions=2)
    V, F = np.asarray(m.vertices), np.asarray(m.faces)
    r = mesh_report(V, F)
    assert r["boundary_edge_count"] == 0 and r["boundary_loop_count"] == 0 and r["consistently_oriented"]
    # remove two far-apart faces: two holes
    far = np.argmin(m.triangles_center @ m.triangles_center[0])
    r = mesh_report(V, np.delete(F, [0, far], axis=0))
    assert r["boundary_loop_count"] == 2 and r["boundary_edge_count"] == 6


# ----------------------------------------------------------------------------------------
# writing


def test_save_obj_roundtrip(tmp_path):
    m = trimesh.creation.icosphere(subdivisions=1, radius=0.12)
    V, F = np.asarray(m.vertices), np.asarray(m.faces, np.int64)
    uv = np.random.default_rng(0).uniform(size=(len(V), 2))
    p = tmp_path / "out.obj"
    save_obj(p, V, F, uv=uv, units="mm")
    back = load_mesh(p, units="mm")
    np.testing.assert_allclose(back.vertices, V, rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(back.faces, F)
    np.testing.assert_allclose(back.uv, uv, rtol=1e-9)
    assert [f.name for f in tmp_path.iterdir()] == ["out.obj"], "temporary file left behind"
    save_obj(p, V, F)  # overwrite, metres, no UV
    back = load_mesh(p)
    assert back.uv is None
    np.testing.assert_allclose(back.vertices, V, rtol=1e-9)


def test_writer_failing_midway_keeps_old_file(tmp_path, monkeypatch):
    # a disk error after part of the OBJ was written: the old file stays, no temporary is left
    p = tmp_path / "a.obj"
    p.write_text("old")
    V, F = np.eye(3), np.array([[0, 1, 2]])

    real_fdopen = os.fdopen

    class FailsOnSecondWrite:  # the header gets written, then the disk is full
        def __init__(self, f):
            self.f, self.writes = f, 0

        def write(self, text):
            self.writes += 1
            if self.writes > 1:
                raise OSError("disk full")
            return self.f.write(text)

        def __getattr__(self, name):
            return getattr(self.f, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return self.f.__exit__(*exc)

    with monkeypatch.context() as m:
        m.setattr(os, "fdopen", lambda *a, **k: FailsOnSecondWrite(real_fdopen(*a, **k)))
        with pytest.raises(OSError, match="disk full"):
            save_obj(p, V, F)
    assert p.read_text() == "old"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.obj"]
    save_obj(p, V, F)
    assert load_mesh(p).vertex_count == 3
    assert os.stat(p).st_mode & 0o777 == 0o666 & ~_umask()  # usual permissions, not a temp file's


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_json_writer_numpy_values_nan_and_missing_folder(tmp_path):
    p = tmp_path / "lm.json"
    save_landmarks_json(p, {"2.1": np.array([0.0, -0.1, 0.05]), "9.3": [np.float32(0.0), np.float64(0.01), 0.1]})
    assert json.loads(p.read_text()) == {"2.1": [0.0, -0.1, 0.05], "9.3": [0.0, 0.01, 0.1]}
    with pytest.raises(InputError, match="finite"):
        save_landmarks_json(p, {"2.1": [float("nan"), 0.0, 0.0]})
    assert json.loads(p.read_text())["9.3"] == [0.0, 0.01, 0.1]  # the old file is untouched
    with pytest.raises(InputError, match="does not exist"):
        save_landmarks_json(tmp_path / "missing" / "lm.json", {})
    with pytest.raises(InputError, match="does not exist"):
        save_obj(tmp_path / "missing" / "m.obj", np.eye(3), np.array([[0, 1, 2]]))


# ----------------------------------------------------------------------------------------
# surface points


def test_surface_points_roundtrip_and_follow_deformation():
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    V, F = np.asarray(m.vertices), np.asarray(m.faces, np.int64)
    P = V[:10] * 1.05 + 0.001
    sp = closest_surface_points(V, F, P)
    assert sp.face.dtype == np.int64 and sp.bary.shape == (10, 3) and len(sp) == 10
    pos = sp.positions(V, F)
    _, ref_dist, _ = trimesh.proximity.closest_point(m, P)
    np.testing.assert_allclose(np.linalg.norm(P - pos, axis=1), ref_dist, atol=1e-6)
    # the same surface points on a scaled mesh scale with it
    np.testing.assert_allclose(sp.positions(2.0 * V, F), 2.0 * pos, atol=1e-12)
    d = json.loads(json.dumps(sp.to_dict()))
    back = SurfacePoints.from_dict(d)
    np.testing.assert_array_equal(back.face, sp.face)
    np.testing.assert_array_equal(back.bary, sp.bary)


@pytest.mark.parametrize(
    "d, match",
    [({"face": [0]}, "expected an object"), ({"face": [0.5], "bary": [[1, 0, 0]]}, "integers"),
     ({"face": [0], "bary": [[1, 0]]}, "shape"), ({"face": [-1], "bary": [[1, 0, 0]]}, "negative")],
)
def test_surface_points_from_bad_dict(d, match):
    with pytest.raises(InputError, match=match):
        SurfacePoints.from_dict(d, source="lm.json")


def _trimesh_glb(V, F, uv, face_uv, texture=None) -> bytes:
    """What trimesh's exporter writes for save_glb's mesh (one vertex per (vertex, UV) pair)."""
    from PIL import Image

    pairs, inverse = np.unique(np.stack([F.ravel(), face_uv.ravel()], 1), axis=0, return_inverse=True)
    if texture is None:
        material = trimesh.visual.material.PBRMaterial(baseColorFactor=[204, 158, 133, 255])
    else:
        material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(texture), metallicFactor=0.0,
                                                       roughnessFactor=0.6)
    mesh = trimesh.Trimesh(vertices=V[pairs[:, 0]], faces=inverse.reshape(-1, 3), process=False,
                           visual=trimesh.visual.TextureVisuals(uv=uv[pairs[:, 1]], material=material))
    return mesh.export(file_type="glb")


@pytest.mark.parametrize("textured", [False, True])
def test_save_glb_writes_trimesh_bytes(tmp_path, textured):
    """save_glb writes the glTF itself (no trimesh import): byte for byte what trimesh exports."""
    import facewarp as fw

    t = fw.default_template(0)
    rng = np.random.default_rng(3)
    V = t.vertices + rng.normal(0.0, 1e-3, t.vertices.shape)
    tex = (rng.random((32, 48, 3)) * 255).astype(np.uint8) if textured else None
    fw.geometry.save_glb(tmp_path / "a.glb", V, t.faces, t.uv, t.face_uv, texture=tex)
    assert (tmp_path / "a.glb").read_bytes() == _trimesh_glb(V, t.faces, t.uv, t.face_uv, tex)
    m = load_mesh(tmp_path / "a.glb")
    assert m.corner_uv is not None and len(m.faces) == len(t.faces)


@pytest.mark.parametrize("colors", [False, True])
def test_plain_obj_reads_like_any_obj(tmp_path, colors):
    """A plain OBJ (v / f / comments; read by a fast path) gives the same arrays as the same file
    with a line that sends it through the general reader."""
    rng = np.random.default_rng(4)
    V = rng.normal(0.0, 0.1, (500, 3))
    F = rng.integers(0, 500, (900, 3))
    C = rng.random((500, 3)) if colors else None
    save_obj(tmp_path / "plain.obj", V, F, units="mm", colors=C)
    text = (tmp_path / "plain.obj").read_text()
    (tmp_path / "general.obj").write_text(text.replace("\nf ", "\no part\nf ", 1))
    a, b = load_mesh(tmp_path / "plain.obj", units="mm"), load_mesh(tmp_path / "general.obj", units="mm")
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    assert np.allclose(a.vertices, V, rtol=0, atol=1e-9) and np.array_equal(a.faces, F)
    assert (a.colors is None) == (not colors) and (b.colors is None) == (not colors)
    if colors:
        assert np.array_equal(a.colors, b.colors)
    (tmp_path / "bad.obj").write_text(text + "f 1 2 501\n")
    with pytest.raises(InputError, match="face 900 refers to vertex 501, but there are 500 in the file"):
        load_mesh(tmp_path / "bad.obj")
