"""The non-sliding stages (field + landing), quality figures and automatic landmarks (issue 11).

Template: the default head at level 0; scan: the same head moved by a known smooth field with a
large tangential part, subdivided (another tessellation of the same surface), posed."""

import json

import numpy as np
import pytest
import trimesh

import facewarp
from facewarp import InputError
from facewarp.geometry import Similarity
from facewarp import adapt
from facewarp.adaptation import detect_landmarks


def _field(X):
    """A smooth 3D displacement [m]: stretch and shear (up to ~1 cm over the head) and a 3 mm
    wave of 30 cm wavelength across the face (along x: tangential on the front of the face)."""
    A = np.array([[0.06, 0.02, 0.0], [0.0, -0.04, 0.03], [0.01, 0.0, 0.05]])
    wave = 0.003 * np.sin(2 * np.pi * X[:, 1] / 0.3)
    return X @ A.T + np.stack([wave, 0.0 * wave, 0.0 * wave], axis=1)


@pytest.fixture(scope="module")
def head():
    t = facewarp.default_template(0)
    tl = {k: v for k, v in t.landmarks().items() if t.fdp[k][0] == "head"}
    truth = t.vertices + _field(t.vertices)
    SV, SF = trimesh.remesh.subdivide(truth, t.faces)
    sl = {k: v + _field(v[None])[0] for k, v in tl.items()}
    return t, tl, truth, np.asarray(SV), np.asarray(SF, dtype=np.int64), sl


@pytest.fixture(scope="module")
def fitted(head):
    t, tl, truth, SV, SF, sl = head
    return adapt(t.vertices, t.faces, tl, SV, SF, sl, region=facewarp.adaptation.vertex_groups(t))


def test_tangential_shift_is_undone(head, fitted):
    t, tl, truth, SV, SF, sl = head
    ev = np.linalg.norm(fitted.vertices_scan_frame - truth, axis=1)
    assert np.median(ev) < 0.5e-3, f"E_v median {np.median(ev) * 1e3:.2f} mm"
    assert np.percentile(ev, 95) < 1.5e-3, f"E_v p95 {np.percentile(ev, 95) * 1e3:.2f} mm"
    levels_only = adapt(t.vertices, t.faces, tl, SV, SF, sl, refine="none")  # the thesis's levels slide
    e0 = np.linalg.norm(levels_only.vertices_scan_frame - truth, axis=1)
    assert np.percentile(ev, 95) < 0.5 * np.percentile(e0, 95)
    q = fitted.quality["surface"]
    assert q["folds"] == 0 and q["dihedral_ok"], q
    assert fitted.refine["field_iterations"] >= 2 and fitted.refine["field_covered_fraction"] > 0.9
    assert set(fitted.quality["distortion"]) >= {"all", "nose", "mouth", "eyes", "ears", "other"}
    assert fitted.to_dict()["quality"]["surface"]["folds"] == 0


@pytest.mark.slow
def test_rotation_invariance(head, fitted):
    t, tl, truth, SV, SF, sl = head
    c, s = np.cos(2.4), np.sin(2.4)
    axis = np.array([0.3, -0.8, 0.52]) / np.linalg.norm([0.3, -0.8, 0.52])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    pose = Similarity(1.0, np.eye(3) + s * K + (1 - c) * K @ K, [0.4, -1.2, 0.7])
    r = adapt(t.vertices, t.faces, tl, pose.apply(SV), SF, {k: pose.apply(v) for k, v in sl.items()},
              region=facewarp.adaptation.vertex_groups(t))
    back = pose.inverse().apply(r.vertices_scan_frame)
    assert np.abs(back - fitted.vertices_scan_frame).max() < 1e-4


def test_face_mask_scan_is_a_partial_fit(head):
    """A scan of the face only: the face lands, the neck and scalp follow smoothly (no fold, no tear)."""
    t, tl, truth, SV, SF, sl = head
    front = t.vertices[:, 2] > np.percentile(t.vertices[:, 2], 55)  # the front of the template
    C = SV[SF].mean(axis=1)
    keep = C[:, 2] > np.percentile(truth[front][:, 2], 5)
    F = SF[keep]
    used = np.unique(F)
    remap = np.full(len(SV), -1)
    remap[used] = np.arange(len(used))
    on_face = {k: v for k, v in sl.items() if k.split(".")[0] in ("2", "3", "8", "9")}  # what a user marks
    r = adapt(t.vertices, t.faces, tl, SV[used], remap[F], on_face, region=facewarp.adaptation.vertex_groups(t))
    assert np.isfinite(r.vertices).all()
    assert r.refine["field_covered_fraction"] < 0.8  # documented: uncovered parts have no data
    ev = np.linalg.norm(r.vertices_scan_frame - truth, axis=1)
    assert np.median(ev[front]) < 1e-3
    q = r.quality["surface"]
    assert q["folds"] == 0 and q["dihedral_ok"], q
    assert r.quality["distortion"]["all"]["stretch_p95"] < 0.15  # no torn or crumpled border


def test_bad_inputs_name_the_argument(head):
    t, tl, truth, SV, SF, sl = head
    with pytest.raises(InputError, match="at least 4"):
        adapt(t.vertices, t.faces, tl, SV, SF, {k: sl[k] for k in ("2.1", "3.7", "3.12")})
    with pytest.raises(InputError, match="empty"):
        adapt(t.vertices, t.faces, tl, np.zeros((0, 3)), np.zeros((0, 3), np.int64), sl)
    with pytest.raises(InputError, match="units"):
        adapt(t.vertices, t.faces, tl, SV * 1000.0, SF, {k: v * 1000.0 for k, v in sl.items()})
    off = dict(sl)
    off["9.3"] = sl["9.3"] + np.array([0.0, 0.0, 0.08])
    with pytest.raises(InputError, match="off the scan"):
        adapt(t.vertices, t.faces, tl, SV, SF, off, calibration_fdps=["2.1", "3.7", "3.12", "8.3", "8.4"])
    with pytest.raises(InputError, match="field_stiffness"):
        adapt(t.vertices, t.faces, tl, SV, SF, sl, field_stiffness=(-1.0,))
    with pytest.raises(InputError, match="empty"):
        detect_landmarks(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    with pytest.raises(InputError, match="metres"):
        detect_landmarks(SV * 1000.0, SF)


@pytest.mark.slow
def test_detects_fdps_in_any_pose(head):
    t, tl, truth, SV, SF, sl = head
    c, s = np.cos(-2.0), np.sin(-2.0)
    pose = Similarity(1.1, [[1, 0, 0], [0, c, -s], [0, s, c]], [0.2, 0.1, -0.3])
    lm, conf = detect_landmarks(pose.apply(SV), SF)
    ids = [k for k in ("2.1", "3.7", "3.8", "3.11", "3.12", "8.1", "8.2", "8.3", "8.4", "9.3", "2.2", "2.3") if k in lm]
    err = [np.linalg.norm(lm[k] - pose.apply(sl[k])) for k in ids]
    assert len(ids) >= 10
    assert np.median(err) < 3e-3, dict(zip(ids, np.round(np.array(err) * 1e3, 1)))
    assert all(0.0 <= conf[k] <= 1.0 for k in conf)


@pytest.mark.slow
def test_cli_detects_then_adapts_without_landmarks(head, tmp_path, capsys):
    """`facewarp landmarks detect` writes loadable landmarks with confidences; `facewarp adapt` without
    --landmarks finds them itself and writes the quality pictures."""
    from facewarp.geometry import load_landmarks, save_obj
    from facewarp.cli import main

    t, tl, truth, SV, SF, sl = head
    c, s = np.cos(1.1), np.sin(1.1)
    pose = Similarity(1000.0, [[c, 0, s], [0, 1, 0], [-s, 0, c]], [10.0, -20.0, 5.0])  # metres -> posed mm
    save_obj(tmp_path / "scan.obj", pose.apply(SV) * 1e-3, SF, units="mm")
    assert main(["landmarks", "detect", str(tmp_path / "scan.obj"), "--units", "mm", "--out", str(tmp_path / "lm.json")]) == 0
    lm = load_landmarks(tmp_path / "lm.json", units="mm")
    conf = json.loads((tmp_path / "lm_confidence.json").read_text())["confidence"]
    err = [np.linalg.norm(lm[k] * 1e3 - pose.apply(sl[k])) for k in ("3.7", "3.12", "8.3", "8.4", "9.3", "2.1")]
    assert np.median(err) < 3.0, err  # mm
    assert set(conf) == set(lm) and all(0.0 <= v <= 1.0 for v in conf.values())
    out = tmp_path / "ad"
    assert main(["adapt", str(tmp_path / "scan.obj"), "--units", "mm", "--out", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert "detected_landmarks" in rep and rep["quality"]["surface"]["folds"] == 0
    for f in ("detected_landmarks.json", "quality_heatmap.png", "distortion_heatmap.png", "error_heatmap.png"):
        assert (out / f).is_file(), f
    capsys.readouterr()
