"""Adaptation (Sec. 4.5) on an ellipsoid template and a deformed, re-tessellated, posed scan;
rigid parts (Eq. 6.6.1-6.6.4) and UV transfer (Sec. 6.5)."""

import numpy as np
import pytest
import trimesh

from facewarp import InputError
from facewarp.geometry import Similarity
from facewarp import adapt
from facewarp.adaptation import eye_transform, fit_part_transform, transfer_uv

DIRS = {
    "2.1": (0, -0.9, 0.45), "3.7": (0.55, 0.25, 0.8), "3.12": (-0.55, 0.25, 0.8), "3.11": (0.2, 0.25, 0.95),
    "3.8": (-0.2, 0.25, 0.95), "8.3": (0.3, -0.45, 0.85), "8.4": (-0.3, -0.45, 0.85), "9.3": (0, 0, 1),
    "8.1": (0, -0.35, 0.94), "8.2": (0, -0.55, 0.83), "3.13": (0.38, 0.32, 0.87), "3.9": (0.38, 0.18, 0.9),
}  # fmt: skip
RT = np.array([0.08, 0.11, 0.10])  # template ellipsoid radii [m]
RS = np.array([0.085, 0.104, 0.108])  # scan ellipsoid radii [m]


def _ellipsoid(radii, sub):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=1.0)
    return np.asarray(m.vertices) * radii, np.asarray(m.faces, dtype=np.int64)


def _on(radii, d):
    d = np.asarray(d, float)
    return d / np.sqrt(((d / radii) ** 2).sum())


@pytest.fixture(scope="module")
def case():
    TV, TF = _ellipsoid(RT, 3)
    SV, SF = _ellipsoid(RS, 4)  # another tessellation
    tl = {k: _on(RT, d) for k, d in DIRS.items()}
    sl = {k: v * RS / RT for k, v in tl.items()}  # the true map is x -> x * RS / RT
    c, s = np.cos(0.4), np.sin(0.4)
    pose = Similarity(1.0, [[c, 0, s], [0, 1, 0], [-s, 0, c]], [0.3, -0.1, 0.05])
    truth = pose.apply(TV * RS / RT)
    return TV, TF, tl, pose.apply(SV), SF, {k: pose.apply(v) for k, v in sl.items()}, truth


# The thesis's levels alone (refine="none"): CSRBF alone has no affine term: from 12 FDPs it
# cannot carry the ellipsoid's stretch to the sides (Sec. 4.5.4: the global RBF suits the
# sparse first levels), so it slides more. With the default field + landing stages every
# method lands within a millimetre.
@pytest.mark.parametrize("method,refine,tol", [("multilevel", "none", 1e-3), ("rbf", "none", 1e-3), ("csrbf", "none", 15e-3),
                                               ("multilevel", "field+land", 1e-3), ("csrbf", "field+land", 1e-3)])
def test_adapts_ellipsoid_to_posed_scan(case, method, refine, tol):
    TV, TF, tl, SV, SF, sl, truth = case
    r = adapt(TV, TF, tl, SV, SF, sl, method=method, levels=2, coverage_points=20, refine=refine)
    ev = np.linalg.norm(r.vertices_scan_frame - truth, axis=1)
    assert np.median(ev) < tol, f"{method}: E_v median {np.median(ev) * 1e3:.2f} mm"
    assert r.levels[-1].E_d < (0.01 if method != "csrbf" or refine != "none" else 0.6) * r.levels[0].E_d
    kinds = [lv.kind for lv in r.levels]
    assert kinds[0] == "none"
    assert {"projection"} <= set(kinds) if refine == "none" else {"field", "land"} <= set(kinds)
    assert set(r.calibration.fdps_used) == {"2.1", "3.7", "3.12", "8.3", "8.4"}
    assert r.vertices.shape == TV.shape
    assert r.quality["surface"]["folds"] == 0


def test_bad_inputs(case):
    TV, TF, tl, SV, SF, sl, _ = case
    few = {k: sl[k] for k in ("2.1", "3.7", "3.12")}
    with pytest.raises(InputError, match="at least 4"):
        adapt(TV, TF, tl, SV, SF, few)
    with pytest.raises(InputError, match="empty"):
        adapt(TV, TF, tl, np.zeros((0, 3)), np.zeros((0, 3), np.int64), sl)
    with pytest.raises(InputError, match="units"):
        adapt(TV, TF, tl, SV * 1000, SF, {k: v * 1000 for k, v in sl.items()})
    off = dict(sl)
    off["9.3"] = sl["9.3"] + np.array([0.0, 0.0, 0.2])
    with pytest.raises(InputError, match="off the scan"):
        adapt(TV, TF, tl, SV, SF, off, calibration_fdps=["2.1", "3.7", "3.12", "8.3", "8.4"])
    with pytest.raises(InputError, match="method"):
        adapt(TV, TF, tl, SV, SF, sl, method="nope")
    with pytest.raises(InputError, match="unknown settings"):
        adapt(TV, TF, tl, SV, SF, sl, levle=2)
    with pytest.raises(InputError, match="refine"):
        adapt(TV, TF, tl, SV, SF, sl, refine="arap")


def test_eye_follows_its_fdps():
    tl = {k: _on(RT, d) for k, d in DIRS.items()}
    c, s = np.cos(0.3), np.sin(0.3)
    T = Similarity(1.1, [[c, -s, 0], [s, c, 0], [0, 0, 1]], [0.01, 0.02, -0.01])
    al = {k: T.apply(v) for k, v in tl.items()}
    center = np.array([0.035, 0.025, 0.06])
    E = eye_transform(tl, al, center, side="left")  # Eq. 6.6.1-6.6.4
    np.testing.assert_allclose(E.matrix(), T.matrix(), atol=1e-12)
    P = fit_part_transform(tl, al, ["3.7", "3.11", "3.13", "3.9"])
    np.testing.assert_allclose(P.apply(center), T.apply(center), atol=1e-12)
    with pytest.raises(InputError):
        eye_transform(tl, al, center, side="right")


def test_uv_transfer():
    V, F = _ellipsoid(RT, 2)
    uv = V[:, :2] * 3.0
    np.testing.assert_allclose(transfer_uv(V * 1.001, V, F, uv), uv, atol=1e-4)
