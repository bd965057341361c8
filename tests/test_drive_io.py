"""Performance files (markers JSON / CSV / C3D, Live Link Face CSV, MediaPipe JSON), their writers
and the rigid head-motion removal: round trips, one-line errors for bad files, and a take moved by
random rigid motions brought back to the head's frame."""

import json
import warnings
import zlib

import numpy as np
import pytest

import facewarp as fw

RNG = np.random.default_rng(7)
NAMES = ["2.1", "8.3", "8.4", "3.7", "11.1", "9.6", "9.7", "10.9", "10.10", "v12"]


def _track(T=12, fps=30.0, names=NAMES, missing=True):
    base = RNG.normal(scale=0.05, size=(len(names), 3))
    P = base[None] + RNG.normal(scale=0.002, size=(T, len(names), 3))
    if missing:
        P[3, 1] = np.nan
        P[5, 4] = np.nan
    return fw.MarkerTrack(fps, names, P, source="test")


def _one_line_error(fn, *words):
    with pytest.raises(fw.InputError) as e:
        fn()
    msg = str(e.value)
    assert "\n" not in msg, msg
    for w in words:
        assert w in msg, msg
    return msg


# ----------------------------------------------------------------------------- markers JSON
def test_markers_json_round_trip_in_mm(tmp_path):
    tr = _track()
    p = fw.takes.save_markers_json(tr, tmp_path / "take.json", units="mm")
    data = json.loads(p.read_text())
    assert data["units"] == "mm" and data["fps"] == 30.0
    assert data["markers"]["8.3"][3] is None
    np.testing.assert_allclose(data["markers"]["2.1"][0], tr.positions[0, 0] * 1e3, rtol=1e-12)
    back = fw.load_markers(p)
    assert back.names == tr.names and back.fps == tr.fps and back.source == str(p)
    np.testing.assert_allclose(back.positions, tr.positions, rtol=1e-12, atol=1e-15)
    assert np.array_equal(back.visible(), tr.visible())


def test_markers_json_map_renames_and_drops(tmp_path):
    (tmp_path / "t.json").write_text(json.dumps({"fps": 60, "units": "m", "markers": {
        "CHIN": [[0, -0.1, 0.05], [0, -0.11, 0.05]], "LMOU": [[0.03, -0.05, 0.08], None],
        "HEAD": [[0, 0.1, 0.0], [0, 0.1, 0.0]]}}))
    (tmp_path / "map.json").write_text(json.dumps({"CHIN": "2.1", "LMOU": "8.3"}))
    tr = fw.load_markers(tmp_path / "t.json", map=tmp_path / "map.json")
    assert tr.names == ["2.1", "8.3"] and tr.fps == 60.0
    assert np.isnan(tr.positions[1, 1]).all()
    tr2 = fw.load_markers(tmp_path / "t.json", map={"CHIN": "2.1", "HEAD": "v3"})
    assert tr2.names == ["2.1", "v3"]


@pytest.mark.parametrize("content, words", [
    ("", ["file is empty"]),
    ('{"fps": 30, "units": "mm", "markers": {"2.1": [[1, 2, 3], [1, 2', ["malformed JSON"]),
    ("[1, 2]", ["expected a JSON object"]),
    ('{"fps": 30, "markers": {"2.1": [[1, 2, NaN]]}}', ["NaN is not JSON", "null"]),
    ('{"fps": 30, "markers": {"2.1": [[1, 2]]}}', ["'2.1' frame 0", "[x, y, z]"]),
    ('{"fps": 30, "markers": {"2.1": [[0, 0, 0]], "8.3": [[0, 0.1, 0], [0, 0, 0]]}}', ["'8.3' has 2 frames"]),
    ('{"fps": -1, "markers": {"2.1": [[0, 0, 0]]}}', ["fps"]),
    ('{"markers": {"2.1": [[0, 0, 0]]}}', ["no 'fps'"]),
    ('{"fps": 30, "units": "inch", "markers": {"2.1": [[0, 0, 0]]}}', ["unknown unit 'inch'"]),
    ('{"fps": 30, "markers": {"LBRO": [[0, 0, 0]]}}', ["'LBRO'", "map file"]),
    ('{"fps": 30, "markers": {"2.1": []}}', ["no frames"]),
    ('{"fps": 30, "marker": {}}', ["expected a JSON object"]),
    ('{"fps": 30, "markers": {"2.1": [null]}}', ["no marker is present"]),
    # millimetres read as metres: a 'head' 150 m wide
    ('{"fps": 30, "markers": {"2.1": [[0, -90, 50]], "11.1": [[0, 60, 40]], "3.7": [[45, 20, 30]]}}',
     ["span", "units"]),
])
def test_markers_json_bad_files(tmp_path, content, words):
    p = tmp_path / "bad.json"
    p.write_text(content)
    msg = _one_line_error(lambda: fw.load_markers(p), *words)
    assert msg.startswith(str(p)), msg


def test_markers_units_disagreement_and_metres_read_as_mm(tmp_path):
    tr = _track(missing=False)
    p = fw.takes.save_markers_json(tr, tmp_path / "m.json", units="m")
    _one_line_error(lambda: fw.load_markers(p, units="mm"), "file says units 'm'")
    q = tmp_path / "m.csv"
    _write_csv(q, tr, scale=1.0)
    _one_line_error(lambda: fw.load_markers(q, units="mm"), "span only", "units")


# ----------------------------------------------------------------------------- markers CSV
def _write_csv(path, tr, *, scale=1e3, first="time"):
    head = [first] + [f"{n}_{a}" for n in tr.names for a in "xyz"]
    lines = [",".join(head)]
    for t in range(tr.frames):
        lead = f"{t / tr.fps:.9f}" if first == "time" else str(t)
        cells = ["" if not np.isfinite(v) else repr(float(v) * scale) for v in tr.positions[t].reshape(-1)]
        lines.append(",".join([lead] + cells))
    path.write_text("\n".join(lines) + "\n")


def test_markers_csv_time_and_frame_columns(tmp_path):
    tr = _track()
    _write_csv(tmp_path / "a.csv", tr)
    a = fw.load_markers(tmp_path / "a.csv", units="mm")
    assert a.names == tr.names and a.fps == pytest.approx(30.0, rel=1e-9)
    np.testing.assert_allclose(a.positions, tr.positions, rtol=1e-12, atol=1e-15)
    _write_csv(tmp_path / "b.csv", tr, first="frame")
    b = fw.load_markers(tmp_path / "b.csv", units="mm", fps=30)
    np.testing.assert_allclose(b.positions, tr.positions, rtol=1e-12, atol=1e-15)
    _one_line_error(lambda: fw.load_markers(tmp_path / "b.csv", units="mm"), "give fps")


@pytest.mark.parametrize("edit, words", [
    (lambda L: L[:1], ["a header but no frames"]),
    (lambda L: L[:4] + [L[4][:12]], ["row 5 has", "truncated"]),
    (lambda L: [L[0].replace("time", "when")] + L[1:], ["first column must be 'time'"]),
    (lambda L: [L[0].replace("2.1_y", "2.1_q")] + L[1:], ["expected 2.1_x, 2.1_y, 2.1_z"]),
    (lambda L: [L[0] + ",extra"] + [r + ",1" for r in L[1:]], ["three columns"]),
    (lambda L: L[:2] + [L[2].replace(L[2].split(",")[1], "abc", 1)] + L[3:], ["row 3", "expected a number"]),
    (lambda L: L[:2] + [L[2].replace(L[2].split(",")[1], "", 1)] + L[3:], ["some of x, y, z missing"]),
    (lambda L: L[:-1] + [L[-1].replace(L[-1].split(",")[0], "5.0", 1)], ["uneven times"]),
    (lambda L: [L[0]] + L[1:][::-1], ["do not increase"]),
    (lambda L: L[:2] + [L[2].replace(L[2].split(",")[2], "inf", 1)] + L[3:], ["finite"]),
])
def test_markers_csv_bad_files(tmp_path, edit, words):
    p = tmp_path / "bad.csv"
    _write_csv(p, _track(missing=False))
    p.write_text("\n".join(edit(p.read_text().splitlines())) + "\n")
    msg = _one_line_error(lambda: fw.load_markers(p, units="mm"), *words)
    assert msg.startswith(str(p)), msg


def test_markers_csv_nan_cell_is_missing(tmp_path):
    tr = _track(missing=False)
    p = tmp_path / "n.csv"
    _write_csv(p, tr)
    lines = p.read_text().splitlines()
    cells = lines[2].split(",")
    cells[1:4] = ["NaN"] * 3
    lines[2] = ",".join(cells)
    p.write_text("\n".join(lines) + "\n")
    back = fw.load_markers(p, units="mm")
    assert not back.visible()[1, 0] and back.visible()[1, 1:].all()


def test_load_markers_bad_paths_and_maps(tmp_path):
    _one_line_error(lambda: fw.load_markers(tmp_path / "nope.json"), "no such file")
    _one_line_error(lambda: fw.load_markers(tmp_path), "is a folder")
    (tmp_path / "x.trc").write_text("x")
    _one_line_error(lambda: fw.load_markers(tmp_path / "x.trc"), "unsupported marker format '.trc'")
    tr = _track(missing=False)
    p = fw.takes.save_markers_json(tr, tmp_path / "t.json")
    (tmp_path / "map.json").write_text('{"A": "2.1", "B": "2.1"}')
    _one_line_error(lambda: fw.load_markers(p, map=tmp_path / "map.json"), "both map to '2.1'")
    (tmp_path / "map.json").write_text('{"A": "12.9"}')
    _one_line_error(lambda: fw.load_markers(p, map=tmp_path / "map.json"), "'12.9' is neither")
    (tmp_path / "map.json").write_text('{"A": "2.1"}')
    _one_line_error(lambda: fw.load_markers(p, map=tmp_path / "map.json"), "none of the take's labels")
    _one_line_error(lambda: fw.load_markers(p, units="furlong"), "unknown unit")
    _one_line_error(lambda: fw.load_markers(p, fps=25), "frame rate is 30")


# ----------------------------------------------------------------------------- C3D
def test_markers_c3d_with_map(tmp_path):
    c3d = pytest.importorskip("c3d")
    tr = _track(T=6, names=["2.1", "8.3", "8.4", "11.1"], missing=False)
    w = c3d.Writer(point_rate=120.0, point_units="mm  ")
    frames = []
    for t in range(tr.frames):
        pts = np.zeros((5, 5), np.float32)
        pts[:4, :3] = tr.positions[t] * 1e3
        pts[4, :3] = [1000.0, 0.0, 0.0]  # a body marker the map leaves out
        if t == 2:
            pts[1, 3] = -1.0  # not seen in this frame
        frames.append((pts, np.zeros((0, 0), np.float32)))
    w.add_frames(frames)
    w.set_point_labels(["CHIN", "LMOU", "RMOU", "FORE", "HIP"])
    with open(tmp_path / "take.c3d", "wb") as f, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "No analog data found in file."
        w.write(f)
    (tmp_path / "map.json").write_text(json.dumps({"CHIN": "2.1", "LMOU": "8.3", "RMOU": "8.4", "FORE": "11.1"}))
    got = fw.load_markers(tmp_path / "take.c3d", map=tmp_path / "map.json")
    assert got.names == tr.names and got.fps == 120.0
    expect = tr.positions.copy()
    expect[2, 1] = np.nan
    np.testing.assert_allclose(got.positions, expect, atol=1e-6)  # float32 in the file
    _one_line_error(lambda: fw.load_markers(tmp_path / "take.c3d"), "'CHIN'", "map file")
    (tmp_path / "broken.c3d").write_bytes((tmp_path / "take.c3d").read_bytes()[:700])
    _one_line_error(lambda: fw.load_markers(tmp_path / "broken.c3d", map=tmp_path / "map.json"), "broken.c3d")


# ----------------------------------------------------------------------------- ARKit
def _arkit(T=75, fps=30.0, head=True):
    t = np.arange(T) / fps
    W = 0.5 + 0.5 * np.sin(t[:, None] * (1 + np.arange(52))[None] * 0.7)
    H = np.stack([0.2 * np.sin(t), 0.1 * np.cos(t), 0.05 * t], axis=1) if head else None
    return fw.takes.ArkitTrack(fps, W, H, source="test")


@pytest.mark.parametrize("fps", [30.0, 60.0, 25.0])
def test_livelink_round_trip(tmp_path, fps):
    tr = _arkit(T=int(2.5 * fps), fps=fps)
    p = fw.takes.save_livelink_csv(tr, tmp_path / "take.csv")
    head = p.read_text().splitlines()[0].split(",")
    assert head[:3] == ["Timecode", "BlendShapeCount", "EyeBlinkLeft"] and "HeadYaw" in head and "TongueOut" in head
    back = fw.load_arkit(p)
    assert back.fps == fps and back.frames == tr.frames
    np.testing.assert_allclose(back.weights, tr.weights, atol=1e-6)
    np.testing.assert_allclose(back.head_rotation, tr.head_rotation, atol=1e-6)


def test_livelink_timecode_at_60_with_30_fps_data(tmp_path):
    """A take at 30 fps whose timecode counts at 60 (frame numbers step by 2)."""
    tr = _arkit(T=70)
    p = fw.takes.save_livelink_csv(tr, tmp_path / "t.csv")
    lines = p.read_text().splitlines()
    out = [lines[0]]
    for k, line in enumerate(lines[1:]):
        s, ff = divmod(2 * k, 60)
        cells = line.split(",")
        cells[0] = f"17:02:{s:02d}:{ff:02d}.250"
        out.append(",".join(cells))
    p.write_text("\n".join(out) + "\n")
    assert fw.load_arkit(p).fps == 30.0


def test_livelink_short_take_needs_fps(tmp_path):
    tr = _arkit(T=10)
    p = fw.takes.save_livelink_csv(tr, tmp_path / "t.csv")
    _one_line_error(lambda: fw.load_arkit(p), "does not cross a whole second", "give fps")
    assert fw.load_arkit(p, fps=30).fps == 30.0


@pytest.mark.parametrize("edit, words", [
    (lambda L: [], ["file is empty"]),
    (lambda L: L[:1], ["a header but no frames"]),
    (lambda L: L[:10] + [L[10][:40]], ["row 11 has", "truncated"]),
    (lambda L: [L[0].replace("Timecode", "Time")] + L[1:], ["first column must be 'Timecode'"]),
    (lambda L: [L[0].replace("JawOpen", "JawOpn")] + L[1:], ["unknown column 'JawOpn'"]),
    (lambda L: [L[0].replace("EyeBlinkLeft", "EyeBlinkRight")] + L[1:], ["appears twice"]),
    (lambda L: L[:5] + [L[5].replace(L[5].split(",")[0], "12:99:00:00.000", 1)] + L[6:], ["row 6", "above 59"]),
    (lambda L: L[:5] + [L[5].replace(L[5].split(",")[0], "noon", 1)] + L[6:], ["row 6", "timecode 'noon'"]),
    (lambda L: L[:5] + [",".join(L[5].split(",")[:2] + ["nan"] + L[5].split(",")[3:])] + L[6:],
     ["row 6", "finite"]),
    (lambda L: L[:5] + [",".join(L[5].split(",")[:2] + ["1.7"] + L[5].split(",")[3:])] + L[6:],
     ["row 6", "outside [0, 1]"]),
    (lambda L: [L[0]] + [",".join(r.split(",")[:54] + ["57.0"] + r.split(",")[55:]) for r in L[1:]],
     ["HeadYaw", "radians"]),
])
def test_livelink_bad_files(tmp_path, edit, words):
    p = tmp_path / "bad.csv"
    fw.takes.save_livelink_csv(_arkit(), p)
    p.write_text("\n".join(edit(p.read_text().splitlines())) + "\n")
    msg = _one_line_error(lambda: fw.load_arkit(p), *words)
    assert msg.startswith(str(p)), msg


def _mediapipe(T=8, *, js=False, fps=30.0):
    frames = []
    for t in range(T):
        cats = [{"index": 0, "score": 0.0, "category_name": "_neutral", "display_name": ""}]
        cats += [{"index": i + 1, "score": round(0.1 + 0.8 * ((t + i) % 7) / 7, 6), "category_name": n,
                  "display_name": ""} for i, n in enumerate(fw.ARKIT_NAMES)]
        if js:
            frames.append({"timestampMs": round(1000 * t / fps),
                           "faceBlendshapes": [{"categories": [{"categoryName": c["category_name"], "score": c["score"],
                                                                "index": c["index"]} for c in cats]}]})
        else:
            frames.append({"timestamp_ms": round(1000 * t / fps), "face_blendshapes": [cats]})
    return frames


def test_mediapipe_python_and_js_layouts(tmp_path):
    for js in (False, True):
        frames = _mediapipe(js=js)
        p = tmp_path / f"mp{js}.json"
        p.write_text(json.dumps(frames if js else {"frames": frames}))
        tr = fw.load_arkit(p)
        assert tr.frames == 8 and tr.head_rotation is None
        assert tr.fps == pytest.approx(1000 / 33, rel=1e-9)  # timestamps rounded to whole ms: 0, 33, 67, ...
        i = fw.ARKIT_NAMES.index("jawOpen")
        assert tr.weights[3, i] == pytest.approx(0.1 + 0.8 * ((3 + i) % 7) / 7, abs=1e-6)


def test_mediapipe_frame_without_face_holds(tmp_path):
    frames = _mediapipe()
    frames[4]["face_blendshapes"] = []
    p = tmp_path / "mp.json"
    p.write_text(json.dumps(frames))
    tr = fw.load_arkit(p)
    np.testing.assert_array_equal(tr.weights[4], tr.weights[3])


def _scores(frame, score):
    return dict(frame, face_blendshapes=[[dict(c, score=score) for c in frame["face_blendshapes"][0]]])


@pytest.mark.parametrize("edit, words", [
    (lambda F: [], ["expected a list of frames"]),
    (lambda F: [dict(F[0], face_blendshapes=[F[0]["face_blendshapes"][0][:30]])] + F[1:], ["no category", "missing"]),
    (lambda F: [dict(F[0], face_blendshapes=[F[0]["face_blendshapes"][0] + [{"category_name": "eyeRoll", "score": 0}]])]
     + F[1:], ["unknown category 'eyeRoll'"]),
    (lambda F: F[:2] + [_scores(F[2], 1.5)] + F[3:],
     ["frame 2", "outside [0, 1]"]),
    (lambda F: F[:2] + [_scores(F[2], "x")] + F[3:],
     ["frame 2", "must be a number"]),
    (lambda F: [dict(f, face_blendshapes=[]) for f in F], ["no frame has a face"]),
    (lambda F: F[::-1], ["do not increase"]),
    (lambda F: [{k: v for k, v in f.items() if k != "timestamp_ms"} for f in F], ["give fps"]),
    (lambda F: [{"faces": 1}], ["no 'face_blendshapes'"]),
])
def test_mediapipe_bad_files(tmp_path, edit, words):
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(edit(_mediapipe())))
    msg = _one_line_error(lambda: fw.load_arkit(p), *words)
    assert msg.startswith(str(p)), msg


def test_mediapipe_truncated_and_nan(tmp_path):
    p = tmp_path / "t.json"
    p.write_text(json.dumps(_mediapipe())[:500])
    _one_line_error(lambda: fw.load_arkit(p), "malformed JSON")
    p.write_text(json.dumps(_mediapipe()).replace('"score": 0.0', '"score": NaN', 1))
    _one_line_error(lambda: fw.load_arkit(p), "NaN is not JSON")


# ----------------------------------------------------------------------------- frames -> markers
def test_markers_from_frames():
    T, n = 5, 20
    ids = np.array(fw.geometry.FDP_IDS)
    fr = fw.Frames(times=np.arange(T) / 24.0, points=RNG.normal(size=(T, n, 3)).astype(np.float32),
                   faces=np.zeros((1, 3), int), fdp_ids=ids, fdp_points=RNG.normal(size=(T, len(ids), 3)),
                   parts={}, muscle_names=[], muscle_curves=np.zeros((T, 0, 2, 3)), activations=np.zeros((T, 0)),
                   jaw=np.zeros((T, 2)))
    tr = fw.takes.markers_from_frames(fr, ["8.3", "v7", "2.1"])
    assert tr.fps == pytest.approx(24.0) and tr.names == ["8.3", "v7", "2.1"]
    np.testing.assert_array_equal(tr.positions[:, 0], fr.fdp_points[:, list(ids).index("8.3")])
    np.testing.assert_array_equal(tr.positions[:, 1], fr.points[:, 7].astype(np.float64))
    _one_line_error(lambda: fw.takes.markers_from_frames(fr, ["v20"]), "beyond the head's 20 vertices")
    _one_line_error(lambda: fw.takes.markers_from_frames(fr, ["mouth"]), "'mouth' is neither")
    _one_line_error(lambda: fw.takes.markers_from_frames("frames", ["2.1"]), "expected Frames")


# ----------------------------------------------------------------------------- rigid head motion
def _random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _head_points(rng):
    names = list(fw.takes.STABLE_POINTS) + ["2.1", "8.3", "8.4", "3.7", "4.1", "v42"]
    rest = {n: rng.normal(scale=0.06, size=3) for n in names}
    return names, rest


@pytest.mark.parametrize("scale", [True, False])
def test_rigid_motion_removed(scale):
    rng = np.random.default_rng(11)
    names, rest = _head_points(rng)
    stable = [names.index(n) for n in fw.takes.STABLE_POINTS]
    T = 20
    local = np.array([[rest[n] for n in names]] * T)
    moving = [i for i in range(len(names)) if i not in stable]
    local[:, moving] += rng.normal(scale=0.004, size=(T, len(moving), 3))  # the expression
    Rs = np.array([_random_rotation(rng) for _ in range(T)])
    ts = rng.normal(scale=0.3, size=(T, 3))
    ss = rng.uniform(0.8, 1.25, size=T) if scale else np.ones(T)
    world = ss[:, None, None] * np.einsum("tij,tkj->tki", Rs, local) + ts[:, None]
    world[4, stable[:8]] = np.nan  # a frame with too few stable points: held
    world[7, [stable[0], moving[0]]] = np.nan  # a frame with some missing
    tr = fw.MarkerTrack(30, names, world, source="moved")
    back, motion = fw.takes.remove_head_motion(tr, rest, scale=scale)
    ok = [f for f in range(T) if f != 4]
    vis = np.isfinite(world[ok]).all(axis=2)
    np.testing.assert_allclose(back.positions[ok][vis], local[ok][vis], atol=1e-6)
    np.testing.assert_allclose(motion.rotation[ok], Rs[ok], atol=1e-9)
    np.testing.assert_allclose(motion.translation[ok], ts[ok], atol=1e-9)
    np.testing.assert_allclose(motion.scale[ok], ss[ok], atol=1e-9)
    assert motion.held.tolist() == [f == 4 for f in range(T)]
    assert motion.used[7] == len(stable) - 1 and motion.used[4] == 0
    np.testing.assert_array_equal(motion.rotation[4], motion.rotation[3])
    assert np.nanmax(motion.residual) < 1e-9
    rep = motion.to_dict()
    assert rep["frames_held"] == 1 and len(rep["yaw_pitch_roll_deg"]) == T
    json.dumps(rep)


def test_rigid_fit_leaves_out_a_stable_point_that_moved():
    """One stable point off by 4 mm in a frame (a slipped marker): the fit drops it and the rest
    come back exactly."""
    rng = np.random.default_rng(12)
    names, rest = _head_points(rng)
    local = np.array([[rest[n] for n in names]] * 3)
    slip = names.index("9.7")
    local[1, slip] += [0.0, 0.004, 0.0]
    R = _random_rotation(rng)
    world = local @ R.T + [0.1, -0.2, 0.05]
    back, motion = fw.takes.remove_head_motion(fw.MarkerTrack(30, names, world), rest)
    np.testing.assert_allclose(back.positions, local, atol=1e-9)
    assert motion.used.tolist() == [10, 9, 10] and motion.residual[1] < 1e-9


def test_rigid_angles_of_known_rotations():
    a = np.deg2rad([20.0, -10.0, 5.0])  # yaw (y), pitch (x), roll (z)
    cy, sy, cp, sp, cr, sr = np.cos(a[0]), np.sin(a[0]), np.cos(a[1]), np.sin(a[1]), np.cos(a[2]), np.sin(a[2])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    Rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    m = fw.takes.HeadMotion(np.array([Ry @ Rx @ Rz]), np.zeros((1, 3)), np.ones(1), np.zeros(1), np.ones(1, int),
                      np.zeros(1, bool), fw.takes.STABLE_POINTS)
    np.testing.assert_allclose(m.angles()[0], a, atol=1e-12)


def test_rigid_needs_stable_points():
    rng = np.random.default_rng(3)
    names, rest = _head_points(rng)
    keep = ["2.1", "8.3", "11.1", "9.6"]
    tr = fw.MarkerTrack(30, keep, np.array([[rest[n] for n in keep]] * 3))
    _one_line_error(lambda: fw.takes.remove_head_motion(tr, rest), "needs three or more of the stable points", "it has 2")
    _one_line_error(lambda: fw.takes.remove_head_motion("x", rest), "expected a MarkerTrack")
    full = fw.MarkerTrack(30, names, np.array([[rest[n] for n in names]] * 2))
    same, m = fw.takes.remove_head_motion(full, rest)
    np.testing.assert_allclose(same.positions, full.positions, atol=1e-12)
    # a custom stable set, all in one spot: too little spread in every frame
    tight = {n: np.array([0.0, 0.0, 0.001 * i]) for i, n in enumerate(names)}
    tr2 = fw.MarkerTrack(30, names, np.array([[tight[n] for n in names]] * 2))
    _one_line_error(lambda: fw.takes.remove_head_motion(tr2, tight, points=names[:4]), "no frame has three stable points")


# ----------------------------------------------------------------------------- random damage
DAMAGED_FILES = 40


def _damaged(data: bytes, rng) -> bytes:
    kind = rng.integers(4)
    i = int(rng.integers(1, len(data)))
    if kind == 0:
        return data[:i]  # truncated
    if kind == 1:
        return data[:i] + data[i + int(rng.integers(1, 40)):]  # a piece cut out
    if kind == 2:
        return data[:i] + bytes([int(rng.integers(32, 127))]) + data[i + 1:]  # one character changed
    return data[:i] + b",nan" + data[i:]  # a stray cell


@pytest.mark.parametrize("fmt", ["markers_json", "markers_csv", "livelink", "mediapipe", "c3d"])
def test_damaged_files_load_or_fail_in_one_line(tmp_path, fmt):
    """Valid files damaged at random: each loads, or fails with one InputError line naming it."""
    rng = np.random.default_rng(zlib.crc32(fmt.encode()))
    src = tmp_path / "src"
    src.mkdir()
    if fmt == "markers_json":
        good = fw.takes.save_markers_json(_track(T=6), src / "t.json")
        load = fw.load_markers
    elif fmt == "markers_csv":
        good = src / "t.csv"
        _write_csv(good, _track(T=6))
        load = lambda p: fw.load_markers(p, units="mm")  # noqa: E731
    elif fmt == "livelink":
        good = fw.takes.save_livelink_csv(_arkit(T=40), src / "t.csv")
        load = fw.load_arkit
    elif fmt == "mediapipe":
        good = src / "t.json"
        good.write_text(json.dumps(_mediapipe(T=3)))
        load = fw.load_arkit
    else:
        c3d = pytest.importorskip("c3d")
        tr = _track(T=4, names=["2.1", "8.3", "8.4"], missing=False)
        w = c3d.Writer(point_rate=60.0)
        w.add_frames([(np.c_[tr.positions[t] * 1e3, np.zeros((3, 2))].astype(np.float32), np.zeros((0, 0)))
                      for t in range(4)])
        w.set_point_labels(["2.1", "8.3", "8.4"])
        good = src / "t.c3d"
        with open(good, "wb") as f, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            w.write(f)
        load = fw.load_markers
    data = good.read_bytes()
    load(good)
    for n in range(DAMAGED_FILES):
        p = tmp_path / f"d{n}{good.suffix}"
        p.write_bytes(_damaged(data, rng))
        try:
            load(p)
        except fw.InputError as e:
            assert "\n" not in str(e) and str(e).startswith(str(p)), str(e)
