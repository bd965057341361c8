"""Skin layer tetrahedralisation (Sec. 6.2): prism split, conformity, quality on the template."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import facewarp
from facewarp import anatomy as ts


def grid_sheet(n: int = 4, size: float = 0.01, *, bump: float = 0.0):
    """An n x n vertex grid in the z = 0 plane (normals +z), split into 2 (n-1)^2 triangles."""
    x, y = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n), indexing="ij")
    z = bump * np.sin(np.pi * x / size) * np.sin(np.pi * y / size)
    V = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    F = []
    for i, j in itertools.product(range(n - 1), range(n - 1)):
        a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
        F += [(a, b, c), (a, c, d)] if (i + j) % 2 == 0 else [(a, b, d), (b, c, d)]
    return V, np.asarray(F, dtype=np.int64)


def test_single_prism_split_is_positive_for_every_vertex_order():
    # A right prism (outer z = 0, inner z = -1) with its outer triangle counter-clockwise from
    # +z; every relabelling of its vertices must give three positive tets filling it.
    V0 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    for perm in itertools.permutations(range(3)):
        for rot in range(3):
            tri = np.roll(np.array([0, 1, 2]), rot)  # same orientation, other start
            key = np.array(perm)
            V = np.concatenate([V0, V0 - [0, 0, 1]])
            T, prism = ts.split_prisms(tri[None], tri[None] + 3, key=np.concatenate([key, key]))
            vol = ts.tet_volumes(V, T)
            assert (vol > 0).all(), (perm, rot, vol)
            np.testing.assert_allclose(vol.sum(), 0.5, err_msg="three tets must fill the prism")
            assert prism.tolist() == [0, 0, 0]


def test_prism_split_conformity_on_4x4_sheet():
    V, F = grid_sheet(4)
    thickness = np.full(len(V), 0.002)
    for seed in range(5):  # any global numbering: relabel the sheet's vertices randomly
        rng = np.random.default_rng(seed)
        p = rng.permutation(len(V))
        inv = np.argsort(p)
        sl = ts.extrude_skin_layer(V[p], inv[F], thickness, probe=0.0)
        rep = ts.skin_layer_quality(sl, check_intersections=True)
        assert rep["tet_count"] == 3 * len(F)
        assert rep["inverted_count"] == 0
        assert rep["max_face_share"] == 2
        # 18 outer + 18 inner + 2 per boundary edge (12 of them)
        assert rep["boundary_face_count"] == rep["expected_boundary_face_count"] == 2 * 18 + 2 * 12
        assert rep["conforming"], rep
        assert rep["boundary_intersection_count"] == 0
        np.testing.assert_allclose(ts.tet_volumes(sl.vertices, sl.tets).sum(), 0.01**2 * 0.002, rtol=1e-9)


def test_conformity_detects_mismatched_diagonals():
    # Two prisms sharing the quad (1, 2, 5', 4'): split each with its own local order, so the
    # shared quad is cut along different diagonals -> extra boundary triangles inside.
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    V = np.concatenate([V, V - [0, 0, 1]])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    good, _ = ts.split_prisms(F, F + 4)
    bad1, _ = ts.split_prisms(F[:1], F[:1] + 4, key=np.array([0, 1, 2, 3, 0, 1, 2, 3]))
    bad2, _ = ts.split_prisms(F[1:], F[1:] + 4, key=np.array([0, 3, 1, 2, 0, 3, 1, 2]))
    expected = 2 * 2 + 2 * 4
    assert ts.tet_quality(V, good, expected_boundary_face_count=expected)["conforming"]
    rep = ts.tet_quality(V, np.concatenate([bad1, bad2]), expected_boundary_face_count=expected)
    assert not rep["conforming"] and rep["boundary_face_count"] == expected + 4


def test_multi_layer_sheet():
    V, F = grid_sheet(5, bump=0.002)
    sl = ts.extrude_skin_layer(V, F, np.full(len(V), 0.003), layers=3)
    rep = ts.skin_layer_quality(sl)
    assert rep["tet_count"] == 3 * 3 * len(F)
    assert rep["inverted_count"] == 0 and rep["conforming"], rep
    assert sorted(set(sl.layer.tolist())) == [0, 1, 2, 3]
    assert (sl.surface_vertex[sl.layer == 0] == np.arange(len(V))).all()
    assert (sl.surface_vertex[sl.layer > 0] == -1).all()
    np.testing.assert_array_equal(sl.inner_nodes, np.flatnonzero(sl.layer == 3))


def test_dihedral_angles_of_regular_tet():
    V = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    T = np.array([[0, 1, 2, 3]])
    if ts.tet_volumes(V, T)[0] < 0:
        T = T[:, [0, 2, 1, 3]]
    np.testing.assert_allclose(ts.tet_dihedral_angles(V, T), np.arccos(1 / 3), err_msg="regular tet")
    np.testing.assert_allclose(ts.tet_volumes(V, T), 8 / 3)


def test_medial_clamp_keeps_two_close_sheets_apart():
    # Two parallel sheets 3 mm apart facing each other (an involute fold, like two lips): the
    # naive 2.5 mm extrusion would cross; the clamp keeps both inner sheets apart.
    V, F = grid_sheet(6, 0.02)
    V2 = V * 0.8 + [0.002, 0.002, 0.0]  # a smaller sheet, so the slabs' sides do not coincide
    V2[:, 2] = -0.003
    Vall = np.concatenate([V2, V])
    Fall = np.concatenate([F[:, ::-1], F + len(V)])  # outward normals point away from the gap
    thickness = np.full(len(Vall), 0.0025)
    naive = ts.extrude_skin_layer(Vall, Fall, thickness, probe=0.0, min_volume_ratio=0.0)
    assert ts.boundary_self_intersections(naive.vertices, naive.tets) > 0
    sl = ts.extrude_skin_layer(Vall, Fall, thickness)
    rep = ts.skin_layer_quality(sl, check_intersections=True)
    assert rep["boundary_intersection_count"] == 0 and rep["inverted_count"] == 0 and rep["conforming"]
    lower = sl.inner_nodes[sl.source_vertex[sl.inner_nodes] < len(V2)]
    assert sl.depth[lower].max() < 0.0015  # at most about 0.35 x the 3 mm gap


def test_bad_inputs():
    V, F = grid_sheet(3)
    with pytest.raises(facewarp.InputError):
        ts.extrude_skin_layer(V, F, np.ones(len(V) - 1))
    with pytest.raises(facewarp.InputError):
        ts.extrude_skin_layer(V, F, np.zeros(len(V)))
    with pytest.raises(facewarp.InputError):
        ts.extrude_skin_layer(V, F, np.ones(len(V)), layers=0)
    with pytest.raises(ValueError):
        ts.tet_volumes(V, F)


@pytest.mark.parametrize("level", [0, 1])
def test_template_skin_layer(level):
    t = facewarp.default_template(level)
    sl = ts.build_skin_layer(t)
    rep = ts.skin_layer_quality(sl, check_intersections=level == 0)
    assert rep["inverted_count"] == 0, rep
    assert rep["conforming"], rep
    assert rep["tet_count"] == 3 * int(t.frontal.sum())
    assert rep["min_volume_m3"] > 0 and rep["min_dihedral_deg"] > 1.0
    if level == 0:
        assert rep["boundary_intersection_count"] == 0
    # every frontal vertex appears once per sheet; tets map back to frontal faces
    assert t.frontal[sl.tet_face].all()
    outer = sl.layer == 0
    np.testing.assert_allclose(sl.vertices[outer], t.vertices[sl.surface_vertex[outer]])
    inner = sl.inner_nodes
    assert (sl.depth[inner] <= t.thickness[sl.source_vertex[inner]] + 1e-12).all()


def test_template_two_layers():
    t = facewarp.default_template(0)
    sl = ts.build_skin_layer(t, layers=2)
    rep = ts.skin_layer_quality(sl)
    assert rep["tet_count"] == 2 * 3 * int(t.frontal.sum())
    assert rep["inverted_count"] == 0 and rep["conforming"], rep
    assert sorted(set(sl.layer.tolist())) == [0, 1, 2]
    mid = sl.layer == 1
    np.testing.assert_allclose(sl.depth[mid], 0.5 * sl.depth[sl.layer == 2])


def test_tet_mean_ratio_regular_flat_inverted():
    V = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    T = np.array([[0, 1, 2, 3]])
    if ts.tet_volumes(V, T)[0] < 0:
        T = T[:, [0, 2, 1, 3]]
    assert ts.tet_mean_ratio(V, T)[0] == pytest.approx(1.0)
    flat = V.copy()
    flat[3] = 0.5 * (flat[0] + flat[1]) + 1e-3 * (flat[3] - flat[0])
    assert 0 < ts.tet_mean_ratio(flat, T)[0] < 0.05
    assert ts.tet_mean_ratio(V, T[:, [0, 2, 1, 3]])[0] == pytest.approx(-1.0)
    assert ts.tet_mean_ratio(2.5 * V, T)[0] == pytest.approx(1.0)  # scale invariant
