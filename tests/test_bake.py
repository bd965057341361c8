"""Baking a scan's colour into the head's texture, and the likeness of the textured head to its scan."""

from __future__ import annotations

import json

import numpy as np
import pytest

import facewarp as fw
from facewarp.cli import main


def _grid(n=21, size=0.1, z=0.0):
    """A flat square [0, size]^2 at height z in the xy plane, normals +z, with per-vertex UV = xy / size."""
    x, y = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n))
    V = np.column_stack([x.ravel(), y.ravel(), np.full(n * n, z)])
    i = np.arange(n - 1)
    a = (i[:, None] * n + i[None, :]).ravel()
    F = np.concatenate([np.column_stack([a, a + 1, a + n + 1]), np.column_stack([a, a + n + 1, a + n])])
    return V, F


def test_rasterize_uv_covers_and_interpolates():
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    texel, face, bary = fw.adaptation.rasterize_uv(uv, np.array([[0, 1, 2]]), 64)
    assert abs(len(texel) - 0.5 * 64 * 64) < 64 + 2
    row, col = texel // 64, texel % 64
    centre = np.column_stack([(col + 0.5) / 64, 1.0 - (row + 0.5) / 64])
    np.testing.assert_allclose(bary @ uv, centre, atol=1e-9)


def test_bake_gradient_and_fill():
    """Scan 1 mm above a flat head, coloured by a gradient in x, with a hole: the texture reproduces
    the gradient, and inside the hole the harmonic fill continues it."""
    V, F = _grid()
    SV, SF = _grid(n=41, z=0.001)
    C = np.column_stack([SV[:, 0] / 0.1, np.full(len(SV), 0.5), 1.0 - SV[:, 0] / 0.1])
    hole = np.linalg.norm(SV[SF].mean(1)[:, :2] - 0.05, axis=1) < 0.015
    b = fw.adaptation.bake_texture(V, F, V[:, :2] / 0.1, F, SV, SF[~hole], colors=C, size=64)
    img = b.image.astype(float) / 255
    u = (np.arange(64) + 0.5) / 64
    np.testing.assert_allclose(img[:, :, 0], np.broadcast_to(u, (64, 64)), atol=0.02)
    np.testing.assert_allclose(img[:, :, 2], 1 - np.broadcast_to(u, (64, 64)), atol=0.02)
    assert 0.0 < b.filled_fraction < 0.3


def test_bake_keeps_off_the_wrong_sheet():
    """A sheet turned the other way 0.5 mm below the head (nearer than the right one, 1 mm above)
    lends no colour."""
    V, F = _grid()
    up, _ = _grid(n=11, z=0.001)
    down, DF = _grid(n=11, z=-0.0005)
    G = np.concatenate([DF[:, ::-1], DF + len(up)])  # the first sheet faces -z
    SV = np.concatenate([down, up])
    C = np.concatenate([np.tile([0.0, 0.0, 1.0], (len(down), 1)), np.tile([1.0, 0.0, 0.0], (len(up), 1))])
    b = fw.adaptation.bake_texture(V, F, V[:, :2] / 0.1, F, SV, G, colors=C, size=32)
    assert (b.image[..., 0] > 250).all() and (b.image[..., 2] < 5).all()


def test_bake_from_texture():
    """The scan's colour from its texture at its UVs: a texture of four quadrants."""
    V, F = _grid()
    SV, SF = _grid(n=11, z=0.0005)
    tex = np.zeros((2, 2, 3))
    tex[0, 0], tex[0, 1], tex[1, 0], tex[1, 1] = [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]  # row 0 = top
    cuv = (SV[:, :2] / 0.1)[SF]
    b = fw.adaptation.bake_texture(V, F, V[:, :2] / 0.1, F, SV, SF, texture=tex, corner_uv=cuv, size=32)
    img = b.image
    assert tuple(img[2, 2]) == (255, 0, 0) and tuple(img[2, 29]) == (0, 255, 0)
    assert tuple(img[29, 2]) == (0, 0, 255) and tuple(img[29, 29]) == (255, 255, 255)


def test_cielab_reference_values():
    lab = fw.render.srgb_to_lab(np.array([[255, 255, 255], [0, 0, 0], [255, 0, 0]], np.uint8))
    np.testing.assert_allclose(lab[0], [100, 0, 0], atol=0.01)
    np.testing.assert_allclose(lab[1], [0, 0, 0], atol=0.01)
    np.testing.assert_allclose(lab[2], [53.24, 80.09, 67.20], atol=0.05)  # sRGB red, D65


def test_flat_color_difference_is_the_distance_to_the_mean_lab():
    """Half the pixels one colour, half another: the best flat colour sits midway in CIELAB, so every
    pixel is half the two colours' Delta E from it; a colour off the middle scores worse."""
    img = np.zeros((4, 4, 3), np.uint8)
    img[:2], img[2:] = (200, 150, 130), (120, 80, 70)
    mask = np.ones((4, 4), bool)
    mask[0, 0] = mask[3, 3] = False  # one pixel off each half: still balanced
    a, b = fw.render.srgb_to_lab(img[1, 1]), fw.render.srgb_to_lab(img[2, 2])
    r = fw.render.flat_color_difference(img, mask)
    np.testing.assert_allclose(r["delta_e_mean"], 0.5 * np.linalg.norm(a - b), rtol=1e-9, err_msg=str(r))
    np.testing.assert_allclose(r["lab"], 0.5 * (a + b), rtol=1e-9)
    assert r["pixels"] == 14 and r["lightness_correlation"] == 0.0
    # one of the two colours ties on the mean (half the pixels at 0, half at the full distance:
    # equal up to rounding) and is worse at the 95th percentile; a grey off the line between them
    # is worse on the mean too
    end = fw.render.color_difference(np.broadcast_to(img[1, 1], img.shape).copy(), img, mask)
    np.testing.assert_allclose(end["delta_e_mean"], r["delta_e_mean"], rtol=1e-9, err_msg=str((end, r)))
    assert end["delta_e_p95"] > r["delta_e_p95"] + 1.0, (end, r)
    grey = fw.render.color_difference(np.full(img.shape, 160, np.uint8), img, mask)
    assert grey["delta_e_mean"] > r["delta_e_mean"] + 1.0, (grey, r)


@pytest.mark.slow
def test_adapt_bakes_a_likeness(tmp_path, capsys):
    """The synthetic scan with its colour: adapt writes texture.png and adapted.mtl, and the textured
    head's renders match the scan's (front, three-quarter) within Delta E 4, L* correlation >= 0.6,
    clearly ahead of one flat colour."""
    scan = fw.synthetic_scan(3)
    d = tmp_path / "scan"
    d.mkdir()
    fw.geometry.save_obj(d / "scan.obj", scan.vertices * 1e3, scan.faces, colors=scan.colors)
    (d / "lm.json").write_text(json.dumps({k: (np.asarray(v) * 1e3).tolist() for k, v in scan.landmarks.items()}))
    out = tmp_path / "ad"
    code = main(["adapt", str(d / "scan.obj"), "--landmarks", str(d / "lm.json"), "--units", "mm", "--out", str(out),
                 "--levels", "1", "--texture-size", "512"])
    o, err = capsys.readouterr()
    assert code == 0, err
    assert "texture: the scan's colour baked" in o
    rep = json.loads((out / "report.json").read_text())
    assert rep["texture"]["size"] == 512 and rep["texture"]["covered_fraction"] > 0.95
    # adapt's own likeness check (no truth: the scan moved into the template frame by the calibration)
    own = rep["likeness"]["mean"]
    assert own["delta_e_mean"]["textured"] < 4.0 and own["lightness_correlation"]["textured"] >= 0.6, own
    assert (out / "likeness.png").is_file() and "likeness: head vs scan" in o
    assert "map_Kd texture.png" in (out / "adapted.mtl").read_text()
    from PIL import Image

    tex = np.asarray(Image.open(out / "texture.png"))
    assert tex.shape == (512, 512, 3)
    m = fw.load_mesh(out / "adapted.obj")  # the texture follows the OBJ through its MTL
    assert m.texture is not None and m.corner_uv is not None
    t = fw.default_template(0)
    a = fw.load_mesh(out / "adapted_scan_frame.obj", units="mm")

    def to_template(X):
        return (X - scan.translation) @ scan.rotation

    res = fw.render.likeness_views(to_template(a.vertices), t.faces, tex, t.uv[t.face_uv], t.frontal,
                                   to_template(scan.vertices), scan.faces, scan_colors=scan.colors, size=160)
    mean = res["mean"]
    assert mean["delta_e_mean"]["textured"] < 4.0, mean
    assert mean["lightness_correlation"]["textured"] >= 0.6, mean
    assert mean["delta_e_mean"]["textured"] < 0.5 * mean["delta_e_mean"]["flat"], mean
    g = fw.load_mesh(out / "adapted.glb")  # glTF: the same head (split at the seams, welded on reading)
    assert g.texture is not None and g.texture.shape == (512, 512, 3) and g.corner_uv is not None
    assert g.face_count == t.face_count and g.vertex_count == t.vertex_count
    # the adapted head folder carries the texture into the build
    head = fw.load_head(out)
    assert head.texture is not None and head.texture.endswith("texture.png")
    # ... and the build into the simulation's USD: the skin bound to its texture, beside the file
    assert main(["build", str(out), "--out", str(tmp_path / "b")]) == 0
    assert (tmp_path / "b" / "texture.png").is_file()
    assert fw.load_face_rig(tmp_path / "b").skin_texture.endswith("texture.png")
    usd = tmp_path / "smile.usda"
    assert main(["simulate", str(tmp_path / "b"), "--expression", "smile", "--seconds", "0.1", "--fps", "10",
                 "--out", str(usd), "--jaw", "kinematic"]) == 0
    capsys.readouterr()
    text = usd.read_text()
    assert "UsdUVTexture" in text and "@./smile_skin.png@" in text
    assert (tmp_path / "smile_skin.png").read_bytes() == (out / "texture.png").read_bytes()


def _textured_scan(scan, size=512):
    """The synthetic scan with its colour moved into a texture over a cylindrical UV map
    (per-corner UVs, unwrapped at the back seam): what a photogrammetry scan looks like."""
    V = (scan.vertices - scan.translation) @ scan.rotation  # template frame: y up, z front
    c = V.mean(0)
    u = (np.arctan2(V[:, 0] - c[0], V[:, 2] - c[2]) / (2 * np.pi) + 0.5) * 0.98 + 0.01
    v = (V[:, 1] - V[:, 1].min()) / np.ptp(V[:, 1]) * 0.98 + 0.01
    U = np.stack([u, v], 1)[scan.faces]  # (m, 3, 2)
    wrap = np.ptp(U[..., 0], axis=1) > 0.5  # triangles across the back seam
    U[wrap, :, 0] = np.where(U[wrap, :, 0] < 0.5, U[wrap, :, 0] + 0.98, U[wrap, :, 0])
    keep = ~wrap | (U[..., 0].max(1) <= 1.0)
    uv = U.reshape(-1, 2)
    face_uv = np.arange(len(uv)).reshape(-1, 3)
    tex = fw.adaptation.vertex_color_texture(scan.faces, uv, face_uv, scan.colors, size=size)
    return uv, face_uv, tex, keep


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["obj", "glb"])
def test_adapt_bakes_from_a_textured_scan(tmp_path, capsys, fmt):
    """OBJ + MTL + PNG, or GLB with a base-colour texture: the colour comes from the texture."""
    from PIL import Image

    scan = fw.synthetic_scan(1)
    uv, face_uv, tex, keep = _textured_scan(scan)
    d = tmp_path / "scan"
    d.mkdir()
    F = scan.faces[keep]
    if fmt == "obj":
        Image.fromarray(tex).save(d / "scan.png")
        (d / "scan.mtl").write_text("newmtl skin\nKd 1 1 1\nmap_Kd scan.png\n")
        fw.geometry.save_obj(d / "scan.obj", scan.vertices * 1e3, F, uv=uv, face_uv=face_uv[keep], mtl="scan.mtl")
    else:
        fw.geometry.save_glb(d / "scan.glb", scan.vertices * 1e3, F, uv, face_uv[keep], texture=tex)
    m = fw.load_mesh(d / f"scan.{fmt}")
    assert m.texture is not None and m.corner_uv is not None and m.colors is None
    (d / "lm.json").write_text(json.dumps({k: (np.asarray(v) * 1e3).tolist() for k, v in scan.landmarks.items()}))
    out = tmp_path / "ad"
    assert main(["adapt", str(d / f"scan.{fmt}"), "--landmarks", str(d / "lm.json"), "--units", "mm",
                 "--out", str(out), "--levels", "1", "--texture-size", "512"]) == 0
    capsys.readouterr()
    t = fw.default_template(0)
    a = fw.load_mesh(out / "adapted_scan_frame.obj", units="mm")
    baked = np.asarray(Image.open(out / "texture.png"))

    def to_template(X):
        return (X - scan.translation) @ scan.rotation

    res = fw.render.likeness_views(to_template(a.vertices), t.faces, baked, t.uv[t.face_uv], t.frontal,
                                   to_template(scan.vertices), scan.faces, scan_colors=scan.colors, size=160)
    mean = res["mean"]
    assert mean["delta_e_mean"]["textured"] < 4.0 and mean["lightness_correlation"]["textured"] >= 0.6, mean


def test_render_samples_the_texture():
    """A square facing the camera with a texture red on the left (u < 0.5), green on the right:
    the unlit render shows the two halves."""
    V = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float) * 0.05
    F = np.array([[0, 1, 2], [0, 2, 3]])
    uv = (V[:, :2] / 0.1 + 0.5)
    tex = np.zeros((8, 8, 3), np.uint8)
    tex[:, :4] = [255, 0, 0]
    tex[:, 4:] = [0, 255, 0]
    img = fw.render_mesh(V, F, view="front", width=64, height=64, texture=(tex, uv[F]), unlit=True, margin=0.0,
                         supersample=1)
    assert tuple(img[32, 5]) == (255, 0, 0) and tuple(img[32, 58]) == (0, 255, 0)
    with pytest.raises(fw.InputError, match="corner_uv"):
        fw.render_mesh(V, F, texture=(tex, uv))
