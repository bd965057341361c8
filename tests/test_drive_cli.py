"""`facewarp drive` end to end on a level-0 head (a few frames of a simulated smile driven back from
its markers) and its one-line errors with nothing written."""

from __future__ import annotations

import json

import numpy as np
import pytest

import facewarp as fw
from facewarp.cli import main
from conftest import fresh_build

NAMES = ["2.1", "8.3", "8.4", "8.1", "8.2", "5.1", "5.2", *fw.takes.STABLE_POINTS]


@pytest.fixture(scope="module")
def built(tmp_path_factory, default_build_dir):
    return fresh_build(tmp_path_factory, default_build_dir)


@pytest.fixture(scope="module")
def take(built, tmp_path_factory):
    """A simulated smile's markers (5 frames at 30 fps), moved by a rigid head motion."""
    sim = fw.FaceSimulator(fw.load_face_rig(built))
    frames = sim.run(fw.timeline_for("smile", attack=0.13, start=0.0), 0.13)
    tr = fw.takes.markers_from_frames(frames, NAMES)
    rng = np.random.default_rng(5)
    P = tr.positions.copy()
    for t in range(tr.frames):  # a nod and a turn, a few degrees, and a drift of a few cm
        a, b = np.radians(rng.uniform(-8, 8, size=2))
        Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
        P[t] = P[t] @ (Ry @ Rx).T + rng.uniform(-0.03, 0.03, size=3)
    moved = fw.MarkerTrack(tr.fps, tr.names, P)
    d = tmp_path_factory.mktemp("take")
    fw.takes.save_markers_json(moved, d / "take.json", units="mm")
    return d / "take.json", tr


@pytest.mark.slow
def test_drive_markers_end_to_end(built, take, tmp_path, capsys):
    path, truth = take
    out = tmp_path / "driven"
    code = main(["--json", "drive", str(built), "--markers", str(path), "--out", str(out)])
    o, err = capsys.readouterr()
    assert code == 0, err
    rep = json.loads(o)
    T = truth.frames
    assert rep["frames"] == T and rep["kind"] == "markers"
    for name in ("activations.csv", "frames.npz", "animation.usdc", "report.json", "drive.png", "activations.png"):
        assert (out / name).is_file(), name
        assert (out / name).stat().st_size < 300_000 or name in ("frames.npz", "animation.usdc"), name
    rows = (out / "activations.csv").read_text().splitlines()
    head = rows[0].split(",")
    assert head[:2] == ["frame", "time_s"] and head[-2:] == ["jaw_open_rad", "jaw_side_rad"]
    assert len(head) == 2 + 27 + 2 and len(rows) == 1 + T
    A = np.array([[float(c) for c in r.split(",")[2:-2]] for r in rows[1:]])
    assert ((A >= 0) & (A <= 1)).all()
    z = np.load(out / "frames.npz")
    assert z["fdp_points"].shape[1:] == (84, 3) and len(z["fdp_ids"]) == 84
    assert z["activations"].shape[1] == 27 and z["jaw"].shape[1] == 2
    full = json.loads((out / "report.json").read_text())
    assert len(full["error_per_frame_mm"]) == T and len(full["error_per_frame_mm"][0]) == len(NAMES)
    hm = full["head_motion"]
    assert len(hm["yaw_pitch_roll_deg"]) == T and hm["frames_held"] == 0
    assert max(hm["residual_mm"]) < 0.1  # the stable points barely move in a smile
    # the zygomatic major pulled: the smile's main muscle comes back from its markers
    zyg = [i for i, n in enumerate(rep["muscles"]) if n.startswith("zygomatic_major")]
    assert A[-1, zyg].max() > 0.1, A[-1]
    assert rep["error_mm"]["rms"] < 2.0, rep["error_mm"]
    # a USD file alone, from a CSV of the same take in metres with a frame column
    csv_path = tmp_path / "take.csv"
    P = truth.positions
    lines = ["frame," + ",".join(f"{n}_{a}" for n in NAMES for a in "xyz")]
    lines += [f"{t}," + ",".join(repr(float(v)) for v in P[t].reshape(-1)) for t in range(T)]
    csv_path.write_text("\n".join(lines) + "\n")
    usd = tmp_path / "alone.usda"
    code = main(["--json", "drive", str(built), "--markers", str(csv_path), "--fps", "30", "--out", str(usd)])
    o, err = capsys.readouterr()
    assert code == 0, err
    rep = json.loads(o)
    assert rep["files"] == [str(usd)] and usd.is_file() and rep["frames"] == T
    assert "#usda" in usd.read_text()[:20]


@pytest.mark.parametrize("case", ["empty", "truncated", "nan", "columns", "units", "vertex", "map_with_arkit",
                                  "two_inputs", "no_input", "missing", "mediapipe_csv", "arkit_empty", "arkit_columns",
                                  "mediapipe_truncated", "no_build"])
def test_drive_bad_input(built, take, tmp_path, capsys, case):
    path, _ = take
    bad = tmp_path / "bad.json"
    text = path.read_text()
    argv = None
    if case == "empty":
        bad.write_text("")
    elif case == "truncated":
        bad.write_text(text[: len(text) // 2])
    elif case == "nan":
        bad.write_text(text.replace("[", "[NaN, ", 3).replace("[NaN, [NaN, ", "[[", 1))
    elif case == "columns":
        bad = tmp_path / "bad.csv"
        bad.write_text("time,2.1_x,2.1_y\n0,1,2\n")
    elif case == "units":
        data = json.loads(text)
        data["units"] = "m"  # millimetres read as metres
        bad.write_text(json.dumps(data))
    elif case == "vertex":
        data = json.loads(text)
        data["markers"]["v999999"] = data["markers"]["2.1"]
        bad.write_text(json.dumps(data))
    elif case == "map_with_arkit":
        argv = ["drive", str(built), "--arkit", str(tmp_path / "x.csv"), "--map", str(path)]
    elif case == "two_inputs":
        argv = ["drive", str(built), "--markers", str(path), "--mediapipe", str(path)]
    elif case == "no_input":
        argv = ["drive", str(built)]
    elif case == "missing":
        bad = tmp_path / "nothing.json"
    elif case == "mediapipe_csv":
        argv = ["drive", str(built), "--mediapipe", str(tmp_path / "x.csv")]
    elif case == "arkit_empty":
        (tmp_path / "x.csv").write_text("")
        argv = ["drive", str(built), "--arkit", str(tmp_path / "x.csv")]
    elif case == "arkit_columns":
        (tmp_path / "x.csv").write_text("Timecode,BlendShapeCount,EyeBlinkLeft\n00:00:00:00.000,1,0.5\n")
        argv = ["drive", str(built), "--arkit", str(tmp_path / "x.csv")]
    elif case == "mediapipe_truncated":
        (tmp_path / "x.json").write_text('[{"timestamp_ms": 0, "face_blendshapes": [[{"category_name": "_neu')
        argv = ["drive", str(built), "--mediapipe", str(tmp_path / "x.json")]
    elif case == "no_build":
        argv = ["drive", str(tmp_path), "--markers", str(path)]
    out = tmp_path / "o"
    argv = (argv or ["drive", str(built), "--markers", str(bad)]) + ["--out", str(out)]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, (case, err)
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert err.startswith("facewarp: error: "), err
    assert not out.exists() and not list(tmp_path.glob(".o*")), list(tmp_path.iterdir())
