"""Error metrics of Sec. 5.2: E_d (Eq. 5.2.1), E_m (5.2.2), E (5.2.3), E_v."""

import numpy as np
import trimesh

from facewarp.adaptation import combined_error, distance_error, marker_error, vertex_error


def _sphere(r=0.1, sub=3):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=r)
    return np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int64)


def test_identical_meshes_have_zero_errors():
    V, F = _sphere()
    de = distance_error(V, V, F)
    assert de.value < 1e-12 and not de.hole.any()
    ev = vertex_error(V, V)
    assert ev.stats["max"] == 0.0 and ev.stats["median"] == 0.0


def test_distance_error_of_an_offset_sphere():
    V, F = _sphere(0.1, 4)
    U = V * (0.102 / 0.1)  # 2 mm outside
    de = distance_error(U, V, F)
    # point-to-triangle distance: >= 2 mm (chords lie inside the sphere), close to it
    assert 0.002 - 1e-12 <= de.stats["median"] < 0.0025
    np.testing.assert_allclose(de.value, np.mean(de.dist**2), rtol=1e-12)


def test_holes_get_weight_zero_and_regions_weights():
    V, F = _sphere(0.1, 3)
    C = V[F].mean(1)
    scan_F = F[C[:, 2] < 0.07]  # a hole at the top
    de = distance_error(V * 1.01, V, scan_F)
    assert de.hole[V[:, 2] > 0.095].all()
    assert (de.weights[de.hole] == 0).all()
    region = np.where(V[:, 0] > 0, "ears", "face")
    dr = distance_error(V * 1.01, V, F, region=region)
    np.testing.assert_allclose(dr.weights[region == "ears"], 0.2)
    assert set(dr.per_region) == {"ears", "face"}


def test_marker_and_combined_error():
    U = np.zeros((3, 3))
    W = np.array([[0.001, 0, 0], [0, 0.002, 0], [0, 0, 0]])
    np.testing.assert_allclose(marker_error(U, W), 0.001**2 + 0.002**2)
    np.testing.assert_allclose(combined_error(1.0, 2.0, alpha=1.0, beta=0.1), 1.2)


def test_vertex_error_per_region():
    V, _ = _sphere()
    U = V.copy()
    U[V[:, 0] > 0] += [0.001, 0, 0]
    region = np.where(V[:, 0] > 0, "left", "right")
    ev = vertex_error(U, V, region=region)
    np.testing.assert_allclose(ev.per_region["left"]["rms"], 0.001)
    assert ev.per_region["right"]["max"] == 0.0
