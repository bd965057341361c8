"""Parametric muscles (Sec. 6.3): Bezier curves, ellipsoid segments, attachment, placement."""

from __future__ import annotations

import json

import numpy as np
import pytest

import facewarp
from facewarp import anatomy as mu
from facewarp import physics


@pytest.fixture(scope="module")
def head0():
    t = facewarp.default_template(0)
    sl = mu.build_skin_layer(t)
    return t, sl, mu.build_muscles(t, sl)


def test_rational_bezier_reproduces_circle():
    w = np.sqrt(0.5)
    r = 0.01
    ring = r * np.array([[1, 0, 0], [1, 1, 0], [0, 1, 0], [-1, 1, 0], [-1, 0, 0], [-1, -1, 0], [0, -1, 0], [1, -1, 0]])
    t = np.linspace(0, 1, 101)
    for a in range(4):
        idx = [2 * a, 2 * a + 1, (2 * a + 2) % 8]
        C = mu.bezier_quadratic(ring[idx], t, [1.0, w, 1.0])
        np.testing.assert_allclose(np.linalg.norm(C, axis=1), r, rtol=1e-12, err_msg=f"arc {a} is not on the circle")
    # the regular (non-rational) curve is not a circle
    C = mu.bezier_quadratic(ring[[0, 1, 2]], t)
    assert np.abs(np.linalg.norm(C, axis=1) - r).max() > 1e-4
    # equal arc-length pieces of a quarter circle have equal angles
    tt, length = mu.arc_length_params(ring[[0, 1, 2]], 5, [1.0, w, 1.0], samples=4096)
    np.testing.assert_allclose(length, np.pi / 2 * r, rtol=1e-6)
    ang = np.arctan2(*mu.bezier_quadratic(ring[[0, 1, 2]], tt, [1.0, w, 1.0])[:, [1, 0]].T)
    np.testing.assert_allclose(np.diff(ang), np.pi / 10, rtol=1e-4)


def test_ellipsoid_volume_preserved_when_x_radius_changes():
    radii = np.array([[0.01, 0.002, 0.002], [0.005, 0.001, 0.0015]])
    vol0 = 4 / 3 * np.pi * radii.prod(1)
    for f in (0.5, 0.8, 1.0, 1.3):
        new = mu.ellipsoid_radii_for_length(radii, radii[:, 0] * f)
        np.testing.assert_allclose(4 / 3 * np.pi * new.prod(1), vol0, rtol=1e-12)
        np.testing.assert_allclose(new[:, 0], radii[:, 0] * f)
        np.testing.assert_allclose(new[:, 1] / new[:, 2], radii[:, 1] / radii[:, 2])  # same cross-section shape
    with pytest.raises(ValueError):
        mu.ellipsoid_radii_for_length(radii, [0.0, 1.0])


def test_closest_point_on_ellipsoid():
    # sphere: distance |y| - r, parameters from the direction
    rng = np.random.default_rng(0)
    Y = rng.normal(size=(200, 3)) * 0.01
    X, d, uv = mu.closest_point_on_ellipsoid(Y, [0.004, 0.004, 0.004])
    np.testing.assert_allclose(d, np.abs(np.linalg.norm(Y, axis=1) - 0.004), atol=1e-12)
    np.testing.assert_allclose(mu.ellipsoid_points(np.zeros((200, 3)), np.tile(np.eye(3), (200, 1, 1)), np.full((200, 3), 0.004), uv), X, atol=1e-12)
    # ellipsoid: compare with a dense surface sampling
    E = np.array([0.01, 0.003, 0.002])
    u, v = np.meshgrid(np.linspace(0, np.pi, 721), np.linspace(-np.pi, np.pi, 721))
    S = np.stack([E[0] * np.cos(u), E[1] * np.sin(u) * np.cos(v), E[2] * np.sin(u) * np.sin(v)], -1).reshape(-1, 3)
    Y = rng.normal(size=(20, 3)) * [0.01, 0.005, 0.005] + [0, 0.004, 0]
    _, d, _ = mu.closest_point_on_ellipsoid(Y, E)
    brute = np.array([np.linalg.norm(S - y, axis=1).min() for y in Y])
    assert (d <= brute + 1e-12).all()
    np.testing.assert_allclose(d, brute, atol=5e-5)
    # on the x axis beyond the tip
    _, d, uv = mu.closest_point_on_ellipsoid(np.array([[0.015, 0, 0]]), E)
    np.testing.assert_allclose(d, 0.005)
    np.testing.assert_allclose(uv[0, 0], 0.0, atol=1e-6)


def test_attachment_search_analytic():
    # one segment along x, radius 2 mm, 10 mm half-length, at the origin
    ell = mu.Ellipsoids(
        centers=np.zeros((1, 3)),
        axes=np.eye(3)[None],
        radii=np.array([[0.01, 0.002, 0.002]]),
        curve=np.zeros(1, np.int64),
        t=np.array([[0.0, 1.0]]),
    )
    X = np.array(
        [
            [0.0, 0.003, 0.0],  # 1 mm above the middle (+y): theta 0 -> attached, u = pi/2, v = 0
            [0.0, 0.0, -0.004],  # 2 mm below (-z): attached, v = -pi/2
            [0.0, 0.012, 0.0],  # 10 mm away: beyond lambda
            [0.014, 0.0, 0.0],  # 4 mm beyond the tip along the fibre: theta 90 deg
            [0.0, 0.0, 0.0],  # inside, on the axis: 2 mm from the surface
        ]
    )
    a = mu.attach_nodes(X, ell, lam=0.005, phi=np.deg2rad(60))
    assert a.nodes.tolist() == [0, 1, 4]
    np.testing.assert_allclose(a.rest_length, [0.001, 0.002, 0.002], atol=1e-9)
    np.testing.assert_allclose(a.uv[0], [np.pi / 2, 0.0], atol=1e-6)
    np.testing.assert_allclose(a.uv[1], [np.pi / 2, -np.pi / 2], atol=1e-6)
    np.testing.assert_allclose(a.angle[:2], 0.0, atol=1e-6)
    wide = mu.attach_nodes(X, ell, lam=0.005, phi=np.deg2rad(90.01))
    assert 3 in wide.nodes.tolist()
    # the surface point from (u, v) is where the connection starts
    P = mu.ellipsoid_points(ell.centers[a.segment], ell.axes[a.segment], ell.radii[a.segment], a.uv)
    np.testing.assert_allclose(np.linalg.norm(X[a.nodes] - P, axis=1), a.rest_length, atol=1e-9)
    # with inward directions -y (skin above the muscle at +y), a node below the muscle (its
    # spring would pull it up through the skin) is not attached; a rotated frame agrees
    down = np.tile([0.0, -1.0, 0.0], (len(X), 1))
    b = mu.attach_nodes(X, ell, lam=0.005, phi=np.deg2rad(60), directions=down)
    assert b.nodes.tolist() == [0]
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    ell_r = mu.Ellipsoids(centers=ell.centers, axes=(R @ ell.axes[0].T).T[None], radii=ell.radii, curve=ell.curve, t=ell.t)
    c = mu.attach_nodes(X @ R.T, ell_r, lam=0.005, phi=np.deg2rad(60), directions=down @ R.T)
    assert c.nodes.tolist() == [0]


def test_segment_ellipsoids_frame_and_taper():
    P = np.array([[[0, 0, 0], [0.02, 0.01, 0], [0.04, 0, 0]]], float)
    e = mu.segment_ellipsoids(P, np.ones((1, 3)), [5], 0.002, taper=0.5)
    assert len(e) == 5
    for k in range(5):
        np.testing.assert_allclose(e.axes[k] @ e.axes[k].T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(e.axes[k, 2], [0, 0, np.sign(e.axes[k, 2, 2])], atol=1e-12)  # y in the xy plane
        np.testing.assert_allclose(np.cross(e.axes[k, 0], e.axes[k, 1]), e.axes[k, 2], atol=1e-12)
    np.testing.assert_allclose(e.radii[[0, -1], 1], 0.001)
    np.testing.assert_allclose(e.radii[1:-1, 1], 0.002)
    ends = mu.bezier_quadratic(P[0], e.t.ravel()).reshape(-1, 2, 3)
    np.testing.assert_allclose(2 * e.radii[:, 0], 1.05 * np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1))


def test_every_muscle_on_template_level0(head0):
    t, sl, ms = head0
    names = {m.name for m in ms.muscles}
    assert len(ms.muscles) == 27  # 13 paired x 2 + orbicularis oris
    assert {m.number for m in ms.muscles} == set(range(1, 15))
    assert "orbicularis_oris" in names and "orbicularis_oculi_L" in names and "frontalis_outer_R" in names
    inner = set(sl.inner_nodes.tolist())
    for m in ms.muscles:
        assert len(m.attachment) >= 5, f"{m.name}: {len(m.attachment)} attached nodes"
        assert set(m.attachment.nodes.tolist()) <= inner
        # by area: a node part inside the band connects with that share of its area (Fig. 6.4 by area)
        w = m.attachment.weight
        assert ((w > 0) & (w <= 1)).all() and (w == 1).any(), m.name
        assert (m.attachment.rest_length < 2 * m.lam).all()
    ref = ms.by_name()["zygomatic_major_L"]
    assert len(ref.segments) == 5


def test_control_points_between_skin_and_skull(head0):
    t, _, ms = head0
    skull = t.skull_vertices()
    q_skin = facewarp.geometry.MeshQuery(t.vertices, t.faces)
    for m in ms.muscles:
        F = t.faces[m.skin_points.face]
        t_skull = np.einsum("kc,kc->k", m.skin_points.bary, t.skull_depth[F])
        assert (m.depth > 0).all() and (m.depth < t_skull).all(), m.name
        # below the skin: the nearest skin point is about the depth away, and inside the head
        d = q_skin.closest_point(m.control_points).dist
        assert (d > 0.5 * m.depth).all(), m.name
        s = m.skin_points.positions(t.vertices, t.faces)
        k = m.skin_points.positions(skull, t.faces)
        # between the skin point and the skull point under it (projection onto the segment)
        lam = np.einsum("ij,ij->i", m.control_points - s, k - s) / np.einsum("ij,ij->i", k - s, k - s)
        assert ((lam > 0) & (lam < 1)).all(), m.name


def test_mirror_symmetry_and_anchors(head0):
    _, _, ms = head0
    by = ms.by_name()
    for m in ms.muscles:
        if m.side == "L":
            r = by[m.base + "_R"]
            np.testing.assert_allclose(r.control_points * [-1, 1, 1], m.control_points, atol=1.5e-3, err_msg=m.name)
    anchors = {a.name: a for a in ms.anchors}
    assert anchors["modiolus_L"].members[0] == ("orbicularis_oris", 0)
    assert anchors["modiolus_R"].members[0] == ("orbicularis_oris", 4)
    for a in ms.anchors:
        P = np.array([by[n].control_points[i] for n, i in a.members])
        np.testing.assert_allclose(a.position, P.mean(0))
        assert np.linalg.norm(P - a.position, axis=1).max() < 0.015, a.name  # the members are close


def test_placements_reuse_and_json(head0, tmp_path):
    t, sl, ms = head0
    again = mu.build_muscles(t, sl, placements={m.name: m.skin_points for m in ms.muscles})
    for a, b in zip(ms.muscles, again.muscles):
        np.testing.assert_allclose(a.control_points, b.control_points)
        np.testing.assert_array_equal(a.attachment.nodes, b.attachment.nodes)
    # muscles_to_json is what write_anatomy writes as muscles.json
    facewarp.anatomy.write_anatomy(mu.Anatomy(head=t, skin=sl, muscles=ms, quality={}), tmp_path)
    d = json.loads((tmp_path / "muscles.json").read_text())
    assert len(d["muscles"]) == 27 and d["muscles"]["orbicularis_oris"]["kind"] == "sphincter"


def test_bad_definitions(tmp_path, head0):
    t, _, _ = head0
    p = tmp_path / "defs.json"
    p.write_text("{}")
    with pytest.raises(facewarp.InputError):
        mu.load_muscle_defs(p)
    defs = mu.load_muscle_defs()
    defs["muscles"][0]["points"]["insertion"]["fdp"] = "99.1"
    with pytest.raises(facewarp.InputError, match="99.1"):
        mu.build_muscles(t, defs=defs)


def test_build_and_write_anatomy(tmp_path):
    import dataclasses

    from facewarp import build_anatomy
    from facewarp.anatomy import write_anatomy

    t = facewarp.default_template(0)
    a = build_anatomy(t)
    q = a.quality
    assert q["inverted_count"] == 0 and q["conforming"] and q["boundary_intersection_count"] == 0
    assert q["min_attached_nodes"] >= 5 and q["muscle_count"] == 27
    paths = write_anatomy(a, tmp_path / "anat")
    assert {p.name for p in paths} == {"tets.npz", "muscles.json", "anatomy.json"}
    # the picture (anatomy.png of `facewarp build`) is rendered separately
    img = facewarp.render.render_anatomy(a, size=64)
    assert img.shape == (64, 64, 3) and img.dtype == np.uint8 and img.std() > 0
    z = np.load(tmp_path / "anat" / "tets.npz")
    assert z["vertices"].shape == (q["vertex_count"], 3) and z["tets"].shape == (q["tet_count"], 4)
    assert z["layer"].shape == z["surface_vertex"].shape == (q["vertex_count"],)
    assert set(np.unique(z["layer"]).tolist()) == {0, 1}
    assert (z["surface_vertex"][z["layer"] == 1] == -1).all()
    # a head whose per-vertex data does not match its mesh is refused
    bad = dataclasses.replace(t, thickness=t.thickness[:-5])
    with pytest.raises(facewarp.InputError, match="thickness"):
        build_anatomy(bad)


def test_slab_scene():
    a = mu.slab_anatomy(cells=20, size=0.02, muscle_length=0.012)
    q = a.quality
    assert q["tet_count"] == 3 * 2 * 20 * 20 and q["inverted_count"] == 0 and q["conforming"]
    m = a.muscles.muscles[0]
    assert len(m.segments) == 5 and len(m.attachment) > 5
    # attached nodes are inner-layer nodes near the muscle's line (y = 0)
    X = a.skin.vertices[m.attachment.nodes]
    assert (a.skin.layer[m.attachment.nodes] == 1).all()
    assert np.abs(X[:, 1]).max() < m.lam + m.radius
    # a straight fibre has no control-point plane: the solver must frame its segments the same
    # way, or the springs would pull at rest (each attachment point (u, v) on the wrong side)
    rig = physics.muscle_rig(a.muscles)
    _, pts = physics.rig_reference(rig, np.zeros(1))
    np.testing.assert_allclose(np.linalg.norm(pts - a.skin.vertices[rig.att_node], axis=1), rig.att_rest_length,
                               atol=1e-9, err_msg="slab springs not at rest length")


def test_muscle_rig_matches_segments(head0):
    t, sl, ms = head0
    jaw = mu.JawKinematic.from_landmarks(t.condyles, t.landmarks())
    rig = physics.muscle_rig(ms, jaw=jaw, head=t)
    assert rig.muscle_count == 27 and len(rig.ctrl_rest) == 12 * 2 * 3 + 8 + 2 * 8
    c, f, r = physics.segment_frames(rig, rig.ctrl_rest)
    C = np.concatenate([m.segments.centers for m in ms.muscles])
    A = np.concatenate([m.segments.axes for m in ms.muscles])
    R = np.concatenate([m.segments.radii for m in ms.muscles])
    np.testing.assert_allclose(c, C, atol=1e-12, err_msg="segment centres differ from the solver's")
    np.testing.assert_allclose(np.swapaxes(f, 1, 2), A, atol=1e-9, err_msg="segment frames differ from the solver's")
    np.testing.assert_allclose(r, R, rtol=1e-9)
    # at rest the attachment points sit at the recorded rest length from their nodes
    _, pts = physics.rig_reference(rig, np.zeros(27))
    d = np.linalg.norm(pts - sl.vertices[rig.att_node], axis=1)
    np.testing.assert_allclose(d, rig.att_rest_length, atol=1e-9)
    # the orbicularis oris corners follow the jaw by about a third, the forehead not at all
    names = rig.names
    i = names.index("frontalis_major_L")
    assert (rig.ctrl_jaw[rig.ctrl_muscle == i] == 0).all()
    # two-way anchors: the modiolus ties 1 + 4 members per side, the upper lip 1 + 2
    assert len(rig.anchor_ctrl) == 2 * 5 + 2 * 3 and len(np.unique(rig.anchor_group)) == 4
    assert rig.anchor_passive.min() > 0


def test_transfer_to_a_reshaped_head(head0):
    # Sec. 6.6: same topology, another shape -> tets re-extruded, muscles reuse their skin points
    import dataclasses

    t, _, ms = head0
    V = t.vertices * [1.06, 0.95, 1.03]
    V = V + 0.002 * np.sin(V[:, [1]] * 40.0) * [1.0, 0.0, 0.0]
    t2 = dataclasses.replace(t, vertices=V)
    a = facewarp.build_anatomy(t2, placements={m.name: m.skin_points for m in ms.muscles}, check_intersections=False)
    assert a.quality["inverted_count"] == 0 and a.quality["conforming"]
    assert a.quality["min_attached_nodes"] >= 5
    for m0, m1 in zip(ms.muscles, a.muscles.muscles):
        np.testing.assert_array_equal(m0.skin_points.face, m1.skin_points.face)


def test_region_filter(head0):
    """Fig. 6.4: a muscle attaches only the sheet area of its own regions: no node without a face
    there; the lid-closing orbicularis oculi takes lid area only, the frontalis only forehead."""
    t, sl, ms = head0
    R = mu.node_regions(t, sl)
    REGIONS = facewarp.heads.REGIONS
    assert R.shape == (len(sl.vertices), len(REGIONS))
    np.testing.assert_allclose(R.sum(1), 1.0)

    def outside(m, nodes):  # nodes with no face in the muscle's regions
        return int((R[nodes][:, [REGIONS.index(r) for r in m.regions]].sum(1) == 0).sum())

    for m in ms.muscles:
        assert m.regions and outside(m, m.attachment.nodes) == 0, m.name
    by = ms.by_name()
    for side in ("L", "R"):
        assert set(by[f"orbicularis_oculi_{side}"].regions) == {f"eyelid_upper_{side}", f"eyelid_lower_{side}"}
        assert len(by[f"orbicularis_oculi_{side}"].attachment) >= 8
    assert set(by["orbicularis_oris"].regions) == {"upper_lip", "lower_lip", "lip_corner_L", "lip_corner_R"}
    # without the regions the same muscles reach beyond them (the frontalis into the lids and the
    # scalp, the orbicularis oculi into the brow and cheek)
    defs = mu.load_muscle_defs()
    for m in defs["muscles"]:
        m.pop("regions", None)
    wide = mu.build_muscles(t, sl, defs=defs).by_name()
    for name in ("frontalis_major_L", "orbicularis_oculi_L", "orbicularis_oculi_R", "corrugator_L"):
        # the weights count the area in the band: 68.6 -> 65.9, 13.0 -> 10.1, 12.7 -> 10.1, 10.4 -> 8.8
        assert wide[name].attachment.weight.sum() > by[name].attachment.weight.sum() + 1.0, name
    assert outside(by["orbicularis_oculi_L"], wide["orbicularis_oculi_L"].attachment.nodes) >= 2
    with pytest.raises(facewarp.InputError, match="unknown region"):
        defs["muscles"][0]["regions"] = ["elbow"]
        mu.build_muscles(t, sl, defs=defs)


def test_attach_by_area_is_mesh_independent():
    """Fig. 6.4 by area: the area of a sheet a muscle pulls on (node areas times their weights)
    stays the same when the sheet is refined; attaching whole nodes by the nodes' own positions
    changes it with the mesh."""
    mus = mu.make_linear_muscle("m", [[-0.02, 0.0, -0.004], [0.0, 0.0005, -0.004], [0.02, 0.0, -0.004]],
                                radius=0.0015, lam=0.005, phi=np.deg2rad(60), segments=5)
    area, whole = [], []
    for n in (9, 36):  # 5 mm and 1.25 mm cells over 4 x 4 cm
        g = np.linspace(-0.02, 0.02, n + 1)
        X = np.array([[x, y, 0.0] for y in g for x in g])
        q = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
        F = np.concatenate([np.stack([q[:-1, :-1], q[:-1, 1:], q[1:, 1:]], -1).reshape(-1, 3),
                            np.stack([q[:-1, :-1], q[1:, 1:], q[1:, :-1]], -1).reshape(-1, 3)])
        down = np.tile([0.0, 0.0, -1.0], (len(X), 1))
        S = mu.sheet_samples(X, F, down)
        np.testing.assert_allclose(S.node_area(len(X)).sum(), 0.04 ** 2, rtol=1e-12)
        a = mu.attach_by_area(X, mus.segments, mus.lam, mus.phi, S, directions=down)
        area.append(float((S.node_area(len(X))[a.nodes] * a.weight).sum()))
        b = mu.attach_nodes(X, mus.segments, mus.lam, mus.phi, directions=down)
        whole.append(float(S.node_area(len(X))[b.nodes].sum()))
        assert ((a.weight > 0) & (a.weight <= 1)).all()
    assert abs(area[1] / area[0] - 1) < 0.05, area
    assert abs(whole[1] / whole[0] - 1) > 2 * abs(area[1] / area[0] - 1), (whole, area)


def test_depth_normals_do_not_depend_on_the_mesh():
    """The direction that places a control point d below the skin is the skin's normal averaged
    over about d: on a wavy sheet meshed at 5 and 1.25 mm it turns by 1.5 degrees (and on a plane it is the
    plane's normal); the vertex normal turns by 4.7."""
    from facewarp.geometry import vertex_normals

    def sheet(n):
        g = np.linspace(-0.03, 0.03, n + 1)
        X = np.array([[x, y, 0.004 * np.cos(2 * np.pi * x / 0.03)] for y in g for x in g])
        q = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
        F = np.concatenate([np.stack([q[:-1, :-1], q[:-1, 1:], q[1:, 1:]], -1).reshape(-1, 3),
                            np.stack([q[:-1, :-1], q[1:, 1:], q[1:, :-1]], -1).reshape(-1, 3)])
        return X, F

    P = np.array([[0.005, 0.0], [0.01, 0.005], [-0.005, 0.01]])  # nodes of both meshes
    depth = np.full(len(P), 0.006)
    out, vn = [], []
    for n in (12, 48):  # 5 and 1.25 mm
        X, F = sheet(n)
        i = np.argmin(np.linalg.norm(X[:, None, :2] - P[None], axis=2), axis=0)
        out.append(mu.depth_normals(X, F, X[i], depth))
        vn.append(vertex_normals(X, F)[i])
    ang = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", out[0], out[1]), -1, 1)))
    ang_v = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", vn[0], vn[1]), -1, 1)))
    assert ang.max() < 2.0 and ang_v.max() > 2.5 * ang.max(), (ang, ang_v)  # 1.5 and 4.7 deg
    flat = mu.depth_normals(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 2]]),
                            np.array([[0.2, 0.2, 0.0]]), [0.5])
    np.testing.assert_allclose(flat, [[0.0, 0.0, 1.0]], atol=1e-12)
    with pytest.raises(facewarp.InputError):
        mu.depth_normals(X, F, X[:1], [0.0])
