"""`facewarp demo` (a tiny duration) and the USD animations of `simulate`: what a DCC user receives."""

from __future__ import annotations

import json

import numpy as np
import pytest

import facewarp
import usd_export
from facewarp.cli import main

pytestmark = pytest.mark.slow  # minutes on the 2-core box: the slow tier



@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--out", str(out), "--quick"]) == 0
    return out, json.loads((out / "report.json").read_text())


def test_demo_writes_everything(demo):
    out, rep = demo
    for name in ("animation.usdc", "head.xml", "report.json", "adapted_head.png", "expressions.png", "sequence.gif",
                 "scan/scan.obj", "scan/landmarks.json", "adapt/adapted.obj", "build/face_rig.npz", "build/head.xml"):
        assert (out / name).is_file(), name
    assert not [p for p in out.rglob(".*")], "temporary files left behind"
    a = rep["adaptation"]
    assert a["E_v_mm"]["median"] < 2.0 and a["distance_to_scan_mm"]["median"] < 1.0, a
    assert a["marker_count"] == 12 and a["marker_error_mm"]["median"] < 2.0
    assert rep["anatomy"]["inverted_count"] == 0 and rep["anatomy"]["muscle_count"] == 27
    s = rep["simulation"]
    assert s["frames"] == s["usd_frames"] == 7 and s["frames_per_second"] > 0
    assert rep["scan"]["units"] == "mm" and rep["timings_s"]["total"] > 0
    # 0.2 s is the whole Fig. 6.16 sequence squeezed: every expression peaks inside it
    assert rep["demo"]["sequence"] == ["smile", "laugh", "surprise", "angry", "sad"]


def test_demo_usd_is_a_clean_animation(demo):
    from pxr import Usd

    out, rep = demo
    path = out / "animation.usdc"
    assert usd_export.validate_usd(path) == []  # UsdUtils.ComplianceChecker, or UsdValidation on usd-core >= 26
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == stage.GetFramesPerSecond() == 30
    a = usd_export.read_animation(path)
    n = rep["simulation"]["frames"]
    np.testing.assert_array_equal(a["time_codes"], np.arange(n))  # one time sample per frame
    assert stage.GetStartTimeCode() == 0 and stage.GetEndTimeCode() == n - 1
    moved = np.linalg.norm(a["points"] - a["points"][0], axis=2).max(axis=1)
    assert moved[0] == 0 and moved.max() > 1e-3, moved  # the points change over time
    assert a["points"].shape[1] == len(a["rest_points"]) == 3415  # the whole head, not the simulated region
    T = a["part_transforms"]
    np.testing.assert_allclose(T["eye_L"], np.broadcast_to(np.eye(4), T["eye_L"].shape), atol=1e-12)
    assert np.abs(T["teeth_lower"] - np.eye(4)).max() > 1e-3  # the jaw opens in the laugh
    np.testing.assert_allclose(T["teeth_lower"], T["tongue"])
    assert len(a["muscles"]) == 27 and a["activations"].max() > 0


def test_demo_head_xml_and_pictures(demo):
    import mujoco
    from PIL import Image

    out, rep = demo
    m = mujoco.MjModel.from_xml_path(str(out / "head.xml"))
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "jaw_open") >= 0
    gif = Image.open(out / "sequence.gif")
    assert gif.n_frames == 4  # every other of the 7 frames
    assert gif.size[1] > 1.5 * gif.size[0]  # the whole head, crown to neck cut, from the front
    # five expressions, three per row: two bands of (front, 3/4, heat) rows of rest | peak pairs
    w, h = Image.open(out / "expressions.png").size
    assert h > w > 6 * gif.size[0], (w, h)


def test_simulate_streams_usd(demo, tmp_path, capsys):
    out, _ = demo
    build = out / "build"
    for suffix, extra in (("usda", ["--tets"]), ("usdz", [])):
        f = tmp_path / f"anim.{suffix}"
        assert main(["--json", "simulate", str(build), "--expression", "laugh", "--seconds", "0.1", "--out", str(f),
                     *extra]) == 0
        rep = json.loads(capsys.readouterr().out)
        assert rep["files"] == [str(f)] and rep["frames"] == 4
        a = usd_export.read_animation(f)
        assert len(a["time_codes"]) == 4 and usd_export.validate_usd(f) == []
        assert (a["tet_points"] is not None) == bool(extra)
    # a folder with --usd: the USD holds exactly the frames of frames.npz
    d = tmp_path / "sim"
    assert main(["simulate", str(build), "--expression", "smile", "--seconds", "0.1", "--out", str(d), "--usd"]) == 0
    z = np.load(d / "frames.npz")
    a = usd_export.read_animation(d / "animation.usdc")
    np.testing.assert_array_equal(a["points"], z["points"])
    np.testing.assert_allclose(a["times"], z["times"], atol=1e-9)


def test_interrupted_animation_leaves_nothing(demo, tmp_path):
    out, _ = demo
    sim = facewarp.FaceSimulator(facewarp.load_face_rig(out / "build"))

    def boom(s, k, t):
        if k == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        with facewarp.UsdAnimation(tmp_path / "take.usdc", sim) as usd:
            facewarp.play(sim, facewarp.timeline_for("smile"), 1.0, sinks=[usd, boom])
    assert list(tmp_path.iterdir()) == []


def test_synthetic_scan():
    scan = facewarp.synthetic_scan(1, holes=3)
    t = facewarp.default_template(0)
    rep = facewarp.geometry.mesh_report(scan.vertices, scan.faces)
    assert rep["boundary_loop_count"] == 4 + 3 and rep["non_manifold_edge_count"] == 0  # neck, mouth, eyes + holes
    assert scan.units == "mm" and scan.truth.shape == t.vertices.shape
    np.testing.assert_allclose(scan.rotation @ scan.rotation.T, np.eye(3), atol=1e-12)
    # the FDPs lie on the scanned surface (noise 0.15 mm; those on the lip and lid margins up to ~1.3 mm
    # off, where the re-tessellation cut the slit's edge)
    d = facewarp.geometry.MeshQuery(scan.vertices, scan.faces).closest_point(np.array(list(scan.landmarks.values()))).dist
    assert np.median(d) < 3e-4 and d.max() < 2e-3, d
    assert scan.proportions != facewarp.synthetic_scan(2).proportions
    with pytest.raises(facewarp.InputError, match="holes"):
        facewarp.synthetic_scan(0, holes=-1)


def test_demo_bad_inputs(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    for argv, needle in ((["demo", "--out", str(afile), "--quick"], "afile"),
                         (["demo", "--out", str(tmp_path / "d"), "--seconds", "0"], "--seconds"),
                         (["demo", "--out", str(tmp_path / "d"), "--seed", "-1"], "--seed"),
                         (["simulate", str(tmp_path), "--expression", "smile", "--out", str(tmp_path / "no" / "a.usdc")],
                          "does not exist")):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("facewarp: error:") and "\n" not in err and needle in err, err
