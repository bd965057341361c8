"""Normals, mean curvature and the Warp BVH queries against analytic values and trimesh."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from trimesh.ray.ray_triangle import RayMeshIntersector

from facewarp import InputError, geometry

# ----------------------------------------------------------------------------------------
# fixtures


def icosphere(radius=0.1, subdivisions=4):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def bumpy_sphere(seed=0):
    """A closed random-ish mesh: an icosphere with random radial noise."""
    V, F = icosphere(radius=0.1, subdivisions=3)
    rng = np.random.default_rng(seed)
    V = V * (1.0 + 0.15 * rng.uniform(-1, 1, size=(len(V), 1)))
    return V, F


def open_cylinder(radius, height, n_around=64, n_rows=41):
    """Structured-grid cylinder around z, outward-wound, open at both ends."""
    theta = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    z = np.linspace(0, height, n_rows)
    T, Z = np.meshgrid(theta, z)
    V = np.stack([radius * np.cos(T), radius * np.sin(T), Z], axis=-1).reshape(-1, 3)

    def idx(i, j):
        return i * n_around + j % n_around

    F = []
    for i in range(n_rows - 1):
        for j in range(n_around):
            a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j + 1), idx(i + 1, j)
            F += [[a, b, c], [a, c, d]]
    return V, np.array(F, np.int64)


def ray_oracle(V, F, origins, dirs):
    """First hit distance and face per ray with trimesh's float64 ray-triangle intersector."""
    m = trimesh.Trimesh(V, F, process=False)
    tri, ray, loc = RayMeshIntersector(m).intersects_id(origins, dirs, multiple_hits=True, return_locations=True)
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    t = np.full(len(origins), np.inf)
    face = np.full(len(origins), -1)
    d = np.einsum("kd,kd->k", loc - origins[ray], unit[ray])
    for r, f, dist in zip(ray, tri, d):
        if 0 <= dist < t[r]:
            t[r], face[r] = dist, f
    return t, face


# ----------------------------------------------------------------------------------------
# normals and areas


def test_face_normals_and_areas_single_triangle():
    V = np.array([[0, 0, 0], [2, 0, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2]])
    np.testing.assert_allclose(geometry.face_areas(V, F), [1.0])
    np.testing.assert_allclose(geometry.face_normals(V, F), [[0, 0, 1]])
    np.testing.assert_allclose(geometry.vertex_normals(V, F), [[0, 0, 1]] * 3)


def test_vertex_normals_sphere_point_outward():
    V, F = icosphere()
    N = geometry.vertex_normals(V, F)
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, rtol=1e-12)
    cos = np.einsum("nd,nd->n", N, V / np.linalg.norm(V, axis=1, keepdims=True))
    assert cos.min() > 0.999


def test_shape_errors():
    with pytest.raises(ValueError, match=r"V must have shape \(n, 3\)"):
        geometry.face_areas(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="F indexes vertices"):
        geometry.face_areas(np.zeros((3, 3)), np.array([[0, 1, 3]]))


# ----------------------------------------------------------------------------------------
# mean curvature


@pytest.mark.parametrize("radius", [0.02, 0.1, 3.0])
def test_mean_curvature_sphere(radius):
    V, F = icosphere(radius=radius, subdivisions=4)
    H = geometry.mean_curvature(V, F)
    assert np.isfinite(H).all()
    rel = np.abs(H * radius - 1.0)
    assert rel.max() < 0.01, f"worst vertex {rel.argmax()}: H = {H[rel.argmax()]}, expected {1 / radius}"


def test_mean_curvature_sign_flips_with_orientation():
    V, F = icosphere(radius=0.1, subdivisions=3)
    H = geometry.mean_curvature(V, F[:, ::-1])
    np.testing.assert_allclose(H, -10.0, rtol=0.01)


def test_mean_curvature_open_cylinder():
    r = 0.05
    n_rows, n_around = 41, 64
    V, F = open_cylinder(r, 0.2, n_around=n_around, n_rows=n_rows)
    H = geometry.mean_curvature(V, F).reshape(n_rows, n_around)
    assert np.isnan(H[0]).all() and np.isnan(H[-1]).all(), "boundary rows must be NaN"
    interior = H[1:-1]
    np.testing.assert_allclose(interior, 1.0 / (2.0 * r), rtol=0.01)


def test_mean_curvature_plane_is_zero():
    x, y = np.meshgrid(np.linspace(0, 1, 6), np.linspace(0, 1, 6))
    V = np.stack([x.ravel(), y.ravel(), np.zeros(36)], axis=1)
    F = []
    for i in range(5):
        for j in range(5):
            a = i * 6 + j
            F += [[a, a + 1, a + 7], [a, a + 7, a + 6]]
    H = geometry.mean_curvature(V, np.array(F))
    interior = ~geometry.boundary_vertices(np.array(F), 36)
    np.testing.assert_allclose(H[interior], 0.0, atol=1e-9)
    assert np.isnan(H[~interior]).all()


# ----------------------------------------------------------------------------------------
# Warp queries


def test_barycentric_order_matches_faces(device):
    # hit point (0.2, 0.3) in the triangle (0,0,0), (1,0,0), (0,1,0): weights (0.5, 0.2, 0.3)
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], float)
    for F in (np.array([[0, 1, 2]]), np.array([[1, 2, 0]]), np.array([[2, 0, 1]])):
        q = geometry.MeshQuery(V, F, device=device)
        expected = np.array([0.5, 0.2, 0.3])[F[0]]  # weights in F's vertex order
        hits = q.ray_cast(np.array([[0.2, 0.3, 1.0]]), np.array([[0.0, 0.0, -2.0]]))
        assert hits.hit[0] and hits.face[0] == 0
        np.testing.assert_allclose(hits.t, [1.0], atol=1e-6)
        np.testing.assert_allclose(hits.bary[0], expected, atol=1e-6, err_msg=f"F = {F[0]}")
        np.testing.assert_allclose(hits.points[0], [0.2, 0.3, 0.0], atol=1e-6)
        cp = q.closest_point(np.array([[0.2, 0.3, -0.7]]))
        np.testing.assert_allclose(cp.bary[0], expected, atol=1e-6, err_msg=f"F = {F[0]}")
        np.testing.assert_allclose(cp.dist, [0.7], atol=1e-6)


@pytest.mark.parametrize("mesh", ["icosphere", "bumpy"])
def test_closest_point_vs_trimesh(device, mesh):
    V, F = icosphere(subdivisions=3) if mesh == "icosphere" else bumpy_sphere()
    rng = np.random.default_rng(1)
    P = rng.normal(size=(300, 3)) * 0.1
    res = geometry.MeshQuery(V, F, device=device).closest_point(P)
    ref_points, ref_dist, _ = trimesh.proximity.closest_point(trimesh.Trimesh(V, F, process=False), P)
    assert (res.face >= 0).all()
    np.testing.assert_allclose(res.dist, ref_dist, atol=1e-6, err_msg="distance")
    # a point on the surface at the oracle's minimum distance is a closest point (there can be
    # several equidistant ones on the bumpy mesh, so the points themselves may differ)
    np.testing.assert_allclose(np.linalg.norm(P - res.points, axis=1), res.dist, atol=1e-12)
    unique = np.linalg.norm(res.points - ref_points, axis=1) < 2e-5
    assert unique.mean() > 0.95, "closest points disagree beyond ties"
    np.testing.assert_allclose(res.bary.sum(axis=1), 1.0, atol=1e-12)
    assert (res.bary >= 0).all()
    np.testing.assert_allclose(np.einsum("kc,kcd->kd", res.bary, V[F[res.face]]), res.points, atol=1e-12)


def test_closest_point_max_dist(device):
    V, F = icosphere(radius=0.1, subdivisions=2)
    P = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 0.105]])
    res = geometry.closest_point(V, F, P, max_dist=0.05, device=device)
    assert res.face[0] == -1 and np.isinf(res.dist[0]) and np.isnan(res.points[0]).all()
    assert res.face[1] >= 0 and abs(res.dist[1] - 0.005) < 1e-3


@pytest.mark.parametrize("mesh", ["icosphere", "bumpy"])
def test_ray_cast_vs_trimesh(device, mesh):
    V, F = icosphere(subdivisions=3) if mesh == "icosphere" else bumpy_sphere()
    rng = np.random.default_rng(2)
    origins = rng.normal(size=(200, 3)) * 0.3
    dirs = -origins + rng.normal(size=(200, 3)) * 0.1  # most rays aim at the mesh
    dirs[:20] = origins[:20]  # some aim away: miss (or hit from inside)
    res = geometry.MeshQuery(V, F, device=device).ray_cast(origins, dirs)
    t_ref, face_ref = ray_oracle(V, F, origins, dirs)
    np.testing.assert_array_equal(res.hit, np.isfinite(t_ref), err_msg="hit/miss")
    np.testing.assert_allclose(res.t[res.hit], t_ref[res.hit], atol=1e-6, err_msg="hit distance")
    agree = (res.face == face_ref)[res.hit]
    assert agree.mean() > 0.97, "hit faces disagree (beyond edge ties)"
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    on_ray = origins + res.t[:, None] * unit
    np.testing.assert_allclose(res.points[res.hit], on_ray[res.hit], atol=1e-6, err_msg="point on ray")
    assert np.isnan(res.points[~res.hit]).all() and (res.face[~res.hit] == -1).all()


def test_ray_cast_both_directions_and_max_dist(device):
    V, F = icosphere(radius=0.1, subdivisions=3)
    q = geometry.MeshQuery(V, F, device=device)
    origins = np.array([[0.0, 0.0, 0.2], [0.0, 0.0, 0.2], [0.0, 0.0, 0.5]])
    dirs = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    one = q.ray_cast(origins, dirs)
    np.testing.assert_array_equal(one.hit, [False, True, True])
    both = q.ray_cast(origins, dirs, both_directions=True)
    np.testing.assert_array_equal(both.hit, [True, True, True])
    np.testing.assert_allclose(both.t, [-0.1, 0.1, 0.4], atol=2e-3)  # polyhedron inside the sphere
    np.testing.assert_allclose(both.points[0], both.points[1], atol=1e-6)
    short = q.ray_cast(origins, dirs, 0.2, both_directions=True)
    np.testing.assert_array_equal(short.hit, [True, True, False])


def test_update_refits(device):
    V, F = icosphere(radius=0.1, subdivisions=2)
    q = geometry.MeshQuery(V, F, device=device)
    ray = (np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, -1.0]]))
    t0 = q.ray_cast(*ray).t[0]
    q.update(V * 2.0 + np.array([0.0, 0.0, 0.1]))
    t1 = q.ray_cast(*ray).t[0]
    np.testing.assert_allclose(t1, t0 - 0.1 - (1.0 - t0), atol=1e-5)
    with pytest.raises(InputError, match="expected shape"):
        q.update(V[:-1])
