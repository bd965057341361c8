"""Tests of the preview renderer: small images (64 x 64) so the CPU kernel stays fast."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from PIL import Image

from facewarp import InputError
from facewarp.render import colormap, render_views, shared_hits
from facewarp import render_mesh, save_png

SIZE = 64


def unit_sphere():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    return np.asarray(sphere.vertices), np.asarray(sphere.faces)


def luminance(image):
    return image.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])


def test_front_sphere_is_a_disc_of_area_pi_r2(device):
    V, F = unit_sphere()
    margin = 0.1
    on_white = render_mesh(V, F, width=SIZE, height=SIZE, margin=margin, device=device)
    on_black = render_mesh(V, F, width=SIZE, height=SIZE, margin=margin, background=(0, 0, 0), device=device)
    # Same surface colour on both backgrounds: the difference is the background's share.
    alpha = 1.0 - (on_white.astype(np.float64) - on_black.astype(np.float64)).mean(axis=2) / 255.0
    pixel = np.ptp(V[:, :2], axis=0).max() * (1.0 + 2.0 * margin) / SIZE  # metres per pixel
    # The icosphere is inscribed in the unit sphere: its outline encloses slightly less than pi.
    outline = trimesh.creation.icosphere(subdivisions=3).vertices
    expected = np.pi * np.linalg.norm(outline[:, :2], axis=1).max() ** 2 / pixel**2
    np.testing.assert_allclose(alpha.sum(), expected, rtol=0.03, err_msg="front view of a sphere is not a pi r^2 disc")

    # Outside the disc only background.
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    radius_px = (rows + 0.5 - SIZE / 2) ** 2 + (cols + 0.5 - SIZE / 2) ** 2
    outside = radius_px > (1.0 / pixel + 1.5) ** 2
    assert np.all(on_white[outside] == 255), "pixels outside the sphere are not background"
    assert np.all(on_black[outside] == 0), "pixels outside the sphere are not background"

    # Lit from the front: the centre is brighter than the rim.
    lum = luminance(on_white)
    centre = lum[SIZE // 2 - 2 : SIZE // 2 + 2, SIZE // 2 - 2 : SIZE // 2 + 2].mean()
    rim = lum[(radius_px > (0.8 / pixel) ** 2) & (radius_px < (0.9 / pixel) ** 2)].mean()
    assert centre > rim + 20.0, f"centre luminance {centre:.1f} not above rim {rim:.1f}"


def test_views_are_not_mirrored(device):
    V, F = unit_sphere()
    centroid = V[F].mean(axis=1)
    red, blue = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    mid = SIZE // 2

    # Front: the subject's left (+x) is on the image's right, as when facing a person.
    left_red = np.where(centroid[:, 0:1] > 0.0, red, blue)
    image = render_mesh(V, F, view="front", width=SIZE, height=SIZE, face_colors=left_red, device=device)
    assert image[mid, 3 * SIZE // 4, 0] > image[mid, 3 * SIZE // 4, 2], "front view: +x is not on the right"
    assert image[mid, SIZE // 4, 2] > image[mid, SIZE // 4, 0], "front view: -x is not on the left"

    # Up is up.
    top_red = np.where(centroid[:, 1:2] > 0.0, red, blue)
    image = render_mesh(V, F, view="front", width=SIZE, height=SIZE, face_colors=top_red, device=device)
    assert image[SIZE // 4, mid, 0] > image[SIZE // 4, mid, 2], "front view: +y is not at the top"

    # Side: the camera is at +x, the face (+z) points to the image's left.
    face_red = np.where(centroid[:, 2:3] > 0.0, red, blue)
    image = render_mesh(V, F, view="side", width=SIZE, height=SIZE, face_colors=face_red, device=device)
    assert image[mid, SIZE // 4, 0] > image[mid, SIZE // 4, 2], "side view: +z is not on the left"


def test_points_and_polylines_are_hidden_behind_the_surface(device):
    V, F = unit_sphere()
    s = np.sin(np.radians(40.0))
    c = np.cos(np.radians(40.0))
    front, back = [s, 0.0, c], [-s, 0.0, -c]  # project right and left of the centre
    image = render_mesh(
        V, F, width=SIZE, height=SIZE, points=np.array([front, back]), point_color=(0.0, 1.0, 0.0),
        point_radius=2.0, device=device,
    )
    green = (image[..., 1] > 200) & (image[..., 0] < 80) & (image[..., 2] < 80)
    cols = np.nonzero(green)[1]
    assert cols.size > 0, "a visible point was not drawn"
    assert np.all(cols > SIZE // 2), "a point behind the sphere was drawn"

    t = np.linspace(0.0, 1.0, 20)[:, None]
    above = np.hstack([0 * t - 0.8, 0 * t + 0.4, 0 * t]) + t * [1.6, 0.0, 0.0]  # a chord through the sphere
    in_front = above + [0.0, -0.8, 1.0]
    image = render_mesh(
        V, F, width=SIZE, height=SIZE, polylines=[(above, (0.0, 1.0, 0.0)), (in_front, (1.0, 0.0, 1.0))],
        line_width=2.0, device=device,
    )
    assert not np.any((image[..., 1] > 200) & (image[..., 0] < 80)), "a polyline inside the sphere was drawn"
    assert np.any((image[..., 0] > 200) & (image[..., 2] > 200) & (image[..., 1] < 80)), "a polyline was not drawn"


def test_extra_meshes_and_vertex_colors(device):
    V, F = unit_sphere()
    eye = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    eye_V = np.asarray(eye.vertices) + [0.0, 0.0, 1.1]
    colors = colormap(V[:, 1], -1.0, 1.0)
    image = render_mesh(
        V, F, width=SIZE, height=SIZE, vertex_colors=colors, extra_meshes=[(eye_V, eye.faces, (0.0, 1.0, 0.0))],
        device=device,
    )
    mid = SIZE // 2
    assert image[mid, mid, 1] > 2 * image[mid, mid, 0], "the extra mesh in front is not drawn"
    top, bottom = image[SIZE // 5, mid].astype(int), image[4 * SIZE // 5, mid].astype(int)
    assert top[0] > top[2] and bottom[2] > bottom[0], "vertex colours not interpolated (turbo: red top, blue bottom)"


def test_inside_color_marks_the_inside_seen_through_a_hole(device):
    V, F = unit_sphere()
    F = F[V[F].mean(axis=1)[:, 2] < 0.6]  # a hole facing the camera: the ray at the centre meets the inside
    mid = SIZE // 2
    plain = render_mesh(V, F, width=SIZE, height=SIZE, device=device)
    inside = render_mesh(V, F, width=SIZE, height=SIZE, inside_color=(0.0, 0.0, 1.0), device=device)
    np.testing.assert_array_equal(inside[mid, mid], [0, 0, 255], err_msg="the inside is not drawn in inside_color")
    assert plain[mid, mid, 0] > plain[mid, mid, 2], "without inside_color the inside is shaded like the outside"
    ring = inside[mid, mid - int(0.9 * SIZE / 2 / 1.12)]  # outside the hole (radius 0.8), on the sphere (1.0)
    assert int(ring[0]) > int(ring[2]) + 20, f"the outside must keep its colour, got {ring}"


def test_device_matches_cpu(device):
    if device == "cpu":
        pytest.skip("compares a GPU with the CPU")
    V, F = unit_sphere()
    cpu = render_mesh(V, F, view="three_quarter", width=SIZE, height=SIZE, device="cpu").astype(int)
    gpu = render_mesh(V, F, view="three_quarter", width=SIZE, height=SIZE, device=device).astype(int)
    assert np.mean(np.abs(cpu - gpu)) < 1.0, f"{device} and CPU images differ"


def test_render_mesh_rejects_bad_input():
    V, F = unit_sphere()
    with pytest.raises(InputError, match=r"F must have shape \(m, 3\), got \(5,\)"):
        render_mesh(V, np.arange(5))
    with pytest.raises(InputError, match="F indexes vertices"):
        render_mesh(V, F + 1)
    with pytest.raises(InputError, match="view must be one of"):
        render_mesh(V, F, view="top")
    with pytest.raises(InputError, match="vertex_colors must have shape"):
        render_mesh(V, F, vertex_colors=np.zeros((3, 3)))


def test_colormap_endpoints_clamping_and_nan():
    rgb = colormap(np.array([-1.0, 0.0, 1.0, 2.0, np.nan]), 0.0, 1.0, "viridis")
    np.testing.assert_allclose(rgb[1], np.array([68, 1, 84]) / 255.0, atol=1e-12, err_msg="viridis at vmin")
    np.testing.assert_allclose(rgb[2], np.array([253, 231, 37]) / 255.0, atol=1e-12, err_msg="viridis at vmax")
    np.testing.assert_allclose(rgb[0], rgb[1], err_msg="values below vmin are not clamped")
    np.testing.assert_allclose(rgb[3], rgb[2], err_msg="values above vmax are not clamped")
    np.testing.assert_allclose(rgb[4], [0.5, 0.5, 0.5], err_msg="NaN is not grey")

    # Turbo (Du's polynomial): its constant terms at vmin, the coefficient sums (clipped) at vmax,
    # green in the middle.
    rgb = colormap(np.array([0.0, 0.5, 1.0]), 0.0, 1.0)
    np.testing.assert_allclose(rgb[0], [0.13572138, 0.09140261, 0.10667330], atol=1e-7, err_msg="turbo at vmin")
    assert rgb[1, 1] > 0.9 and rgb[1, 1] > rgb[1, 0] and rgb[1, 1] > rgb[1, 2], "turbo is not green in the middle"
    np.testing.assert_allclose(rgb[2], [0.56585921, 0.05038886, 0.0], atol=1e-7, err_msg="turbo at vmax")
    assert np.all((rgb >= 0.0) & (rgb <= 1.0))
    assert colormap(np.array([3.0]), 3.0, 3.0).shape == (1, 3)


def test_save_png_writes_atomically(tmp_path):
    image = np.zeros((SIZE, SIZE, 3), dtype=np.uint8)
    image[:, :, 0] = 200
    plain = save_png(tmp_path / "plain.png", image)
    decorated = save_png(tmp_path / "heat.png", image, title="heat map", colorbar=(0.0, 2.5, "E_d [mm]"))
    with Image.open(plain) as png:
        assert png.format == "PNG" and png.size == (SIZE, SIZE)
        np.testing.assert_array_equal(np.asarray(png.convert("RGB")), image, err_msg="pixels changed on the way")
    with Image.open(decorated) as png:
        assert png.size[0] == SIZE and png.size[1] > SIZE, "title and colour bar add bands"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["heat.png", "plain.png"], "a temporary file was left"

    with pytest.raises(InputError, match="does not exist"):
        save_png(tmp_path / "missing" / "x.png", image)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["heat.png", "plain.png"]


def test_render_views_writes_front_and_side(tmp_path):
    V, F = unit_sphere()
    paths = render_views(V, F, tmp_path / "sphere", width=32, height=32)
    assert [p.rsplit("/", 1)[-1] for p in paths] == ["sphere_front.png", "sphere_side.png"]
    for path in paths:
        with Image.open(path) as png:
            assert png.size == (32, 32)


# ------------------------------------------------------------------ whole-head pictures (issue 12)
@pytest.fixture(scope="module")
def head():
    from facewarp import default_template

    t = default_template(0)
    return t, {k: np.asarray(v) for k, v in t.landmarks().items()}


def test_face_view_draws_the_whole_head_with_a_clean_neck_cut(head):
    from facewarp.render import FaceView

    t, lm = head
    view = FaceView(t.vertices, t.faces, lm, t.parts, face_height=120)
    assert len(view.faces) == len(t.faces), "FaceView must draw the template's full mesh, not a cropped face"
    assert view.face_pixels >= 120 - 1e-9, view.face_pixels
    img = view.render(t.vertices)
    assert img.shape == (view.size, view.width, 3)
    drawn = np.any(img < 250, axis=2)
    rows = np.flatnonzero(drawn.any(axis=1))
    # crown and neck cut (y 0.134 and -0.19 m) fill the height but for the 2 % margin and 4 mm reach
    assert rows[0] <= 0.05 * view.size and rows[-1] >= 0.95 * view.size, (rows[0], rows[-1], view.size)
    # the neck cut is the template's straight ring (front view: one row), not a saw-tooth of cropped triangles
    neck = (np.abs(t.vertices[:, 0]) < 0.03) & (t.vertices[:, 1] < -0.18)
    cols = np.flatnonzero(drawn.any(axis=0))
    half = 0.03 * view.pixels_per_metre  # 3 cm either side of the midline
    mid = cols[np.abs(cols - view.width / 2) < half]
    assert neck.any() and len(mid) > 10
    lowest = np.array([np.flatnonzero(drawn[:, c])[-1] for c in mid])
    assert np.ptp(lowest) <= 1, f"the neck's lower border is ragged: rows {lowest.min()}..{lowest.max()}"


def test_face_view_eyes_have_iris_and_pupil(head):
    from facewarp.render import FaceView, view_axes

    t, lm = head
    view = FaceView(t.vertices, t.faces, lm, t.parts, face_height=200)
    img = view.render(t.vertices).astype(int)
    right, up, _ = view_axes("front")
    # the pupil: the front of the eyeball, straight ahead of its centre, projected into the image
    eye = t.parts["eye_L"][0]
    tip = eye[np.argmax(eye[:, 2])]
    x, y = view.frame_points @ right, view.frame_points @ up
    c = int(round(view.width / 2 + (tip @ right - 0.5 * (x.min() + x.max())) * view.pixels_per_metre))
    r = int(round(view.size / 2 - (tip @ up - 0.5 * (y.min() + y.max())) * view.pixels_per_metre))
    patch = img[r - 1:r + 2, c - 1:c + 2].reshape(-1, 3)
    assert patch.max() < 90, f"no dark pupil at the front of the left eye ({r}, {c}): {patch.max(0)}"


def test_preview_eyes_show_iris_and_pupil_at_the_pupil_fdps(head):
    from facewarp.render import colored_scene

    t, lm = head
    V, F, C = colored_scene(t)
    P = np.array([lm["3.5"], lm["3.6"]])  # the pupils' centres (MPEG-4 FDPs)
    lo, hi = P.min(0) - [0.02, 0.012, 0.0], P.max(0) + [0.02, 0.012, 0.0]
    lo[2], hi[2] = V[:, 2].min(), V[:, 2].max()  # the whole depth (the far plane behind the head)
    W, H = 160, 64
    img = render_mesh(V, F, view="front", width=W, height=H, vertex_colors=C, frame_points=np.array([lo, hi]),
                      margin=0.0, supersample=1).astype(int)
    size, mid = max((hi[0] - lo[0]) / W, (hi[1] - lo[1]) / H), 0.5 * (lo + hi)  # metres per pixel, centre
    for p, side in zip(P, (1.0, -1.0)):
        c, r = (int(round(v)) for v in ((p[0] - mid[0]) / size + (W - 1) / 2, -(p[1] - mid[1]) / size + (H - 1) / 2))
        pupil = img[r - 1:r + 2, c - 1:c + 2].reshape(-1, 3)
        assert pupil.max() < 60, f"no dark pupil at FDP ({r}, {c}): {pupil.max(0)}"
        ring = img[r, c + int(round(side * 4.0e-3 / size))]  # 4 mm out: the iris (11.7 mm across), brown
        assert 20 < ring[0] < 200 and ring[0] > ring[2] + 15, ring
        white = img[r, c + int(round(side * 8.5e-3 / size))]  # 8.5 mm out, towards the ear: sclera
        assert white.min() > 120 and np.ptp(white) < 20, white  # off-white (shaded: the ball turns away)


def test_preview_teeth_have_pink_gums_at_their_roots(head):
    from facewarp.render import GUMS, TEETH, FaceView, colored_scene

    t, lm = head
    V, F, C = colored_scene(t)
    parts = F[F.min(1) >= t.vertex_count]  # the rigid parts alone (the closed lips hide the teeth)
    W, H = 160, 64
    for name, root in (("teeth_upper", 1.0), ("teeth_lower", -1.0)):
        T = np.asarray(t.parts[name][0])
        lo, hi = T.min(0), T.max(0)
        lo[2], hi[2] = V[:, 2].min(), V[:, 2].max()
        img = render_mesh(V, parts, view="front", width=W, height=H, vertex_colors=C, frame_points=np.array([lo, hi]),
                          margin=0.0, supersample=1).astype(int)
        size, mid = max((hi[0] - lo[0]) / W, (hi[1] - lo[1]) / H), 0.5 * (lo + hi)

        def pixel(y):  # on the midline, at height y [m]
            return img[int(round(-(y - mid[1]) / size + (H - 1) / 2)), int(round(-mid[0] / size + (W - 1) / 2))]

        end = T[:, 1].max() if root > 0 else T[:, 1].min()
        gum = pixel(end - root * 1.5e-3)  # 1.5 mm from the root end: gums, pink
        crown = pixel(end - root * 5.0e-3)  # 5 mm from it: the crown, ivory
        assert gum[0] > 60 and gum[0] > gum[1] + 30 and gum[0] > gum[2] + 30, (name, gum)
        assert crown.min() > 100 and np.ptp(crown) < 40, (name, crown)
    view = FaceView(t.vertices, t.faces, lm, t.parts, face_height=120)
    for name in ("teeth_upper", "teeth_lower"):
        colours = {tuple(np.round(c, 6)) for c in view.part_colors[name]}
        assert colours == {tuple(np.round(GUMS, 6)), tuple(np.round(TEETH, 6))}, (name, colours)


def test_expression_sheet_pairs_rest_and_peak_and_wraps(head):
    from facewarp.render import expression_sheet

    t, lm = head
    below_mouth = t.vertices[:, 1] < lm["2.2"][1]
    moved = t.vertices.copy()
    moved[below_mouth, 1] -= 0.0052  # 5.2 mm down: the heat map's top is 6 mm
    shots = [(f"shot {i}", moved, None) for i in range(4)]
    sheet, top = expression_sheet(t.vertices, t.faces, lm, t.parts, shots, face_height=60, columns=3)
    assert top == pytest.approx(0.006)
    single, _ = expression_sheet(t.vertices, t.faces, lm, t.parts, shots[:1], face_height=60, columns=3)
    h1, w1 = single.shape[:2]
    # one block: rest | peak, three rows (front, 3/4, heat); four blocks at 3 per row: 2 x 3 blocks
    assert sheet.shape[1] > 2.9 * w1 * 0.8 and sheet.shape[0] > 1.9 * h1, (sheet.shape, single.shape)
    assert h1 > 3 * 60 * 1.5 and h1 > w1, single.shape
    # the heat row is coloured (turbo), the face rows are not
    lower = single[int(0.75 * h1):].reshape(-1, 3).astype(int)
    assert (np.abs(lower[:, 1] - lower[:, 0]) > 60).any(), "no heat map colours in the last row"
    with pytest.raises(InputError, match="shots"):
        expression_sheet(t.vertices, t.faces, lm, t.parts, [])
    with pytest.raises(InputError, match="shots\\[0\\] points"):
        expression_sheet(t.vertices, t.faces, lm, t.parts, [("x", t.vertices[:10], None)])


def test_shared_hits_give_the_same_pictures():
    """Pictures of one head from one camera with different colours inside ``shared_hits`` (one
    ray cast, the colours applied per picture) are pixel for pixel those of separate renders;
    a moved head, another view or size, points and an unlit picture too."""
    V, F = unit_sphere()
    V = V * np.array([0.08, 0.11, 0.09]) + np.random.default_rng(5).normal(0.0, 2e-3, V.shape)
    colors = [colormap(np.abs(V[:, k]) * 1e3, 0.0, 100.0) for k in range(3)]
    calls = [dict(width=80, height=64), dict(width=80, height=64), dict(width=80, height=64, points=V[::40]),
             dict(width=64, height=64, view="side"), dict(width=48, height=64, unlit=True, background=(0.2, 0.3, 0.4)),
             dict(width=80, height=64, supersample=1)]
    alone = [render_mesh(V, F, vertex_colors=c, **kw) for kw in calls for c in colors]
    with shared_hits():
        shared = [render_mesh(V, F, vertex_colors=c, **kw) for kw in calls for c in colors]
        moved = render_mesh(V + 0.01, F, vertex_colors=colors[0], **calls[0])
    for a, b in zip(alone, shared):
        assert np.array_equal(a, b)
    assert np.array_equal(moved, render_mesh(V + 0.01, F, vertex_colors=colors[0], **calls[0]))


def test_drawn_eyeball_stays_inside_its_coarse_ball():
    """The refined (round) eyeball lies inside the coarse ball the eyelids rest on: no vertex beyond
    any coarse face's plane (it bulged through the upper lids as white specks), and it is still
    round (radii within 0.5 %) and barely smaller (under 3 %)."""
    import numpy as np

    import facewarp as fw
    from facewarp.render import refine_ball

    V, F = (np.asarray(a) for a in fw.default_template(0).parts["eye_L"])
    R, RF = refine_ball(V, F)
    c = V.mean(0)
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n *= np.sign(np.einsum("fd,fd->f", V[F[:, 0]] - c, n))[:, None]  # outward
    beyond = np.einsum("kd,fd->kf", R - c, n) - np.einsum("fd,fd->f", V[F[:, 0]] - c, n)[None]
    assert beyond.max() <= 1e-9
    r = np.linalg.norm(R - c, axis=1)
    assert r.max() / r.min() < 1.005 and r.mean() > 0.97 * np.linalg.norm(V - c, axis=1).mean()
    assert len(RF) == 16 * len(F)
