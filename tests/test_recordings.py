"""Recordings as they really are (issue 36, issue 40's drive inputs): Live Link Face takes that drop
frames and overshoot 1, both header spellings and any case; MediaPipe's 51+1 categories in every
layout exporters write, string scores, millisecond and microsecond timestamps; cuts and neutrals of
marker takes; fps bounds; truncated C3D; stable points that cannot give a head motion; the
retargeting maps against known affine faces. The takes come from ``benchmarks/_takes.py``."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

import facewarp as fw
from benchmarks import _takes


def _one_line_error(fn, *words):
    with pytest.raises(fw.InputError) as e:
        fn()
    msg = str(e.value)
    assert "\n" not in msg, msg
    for w in words:
        assert w in msg, msg
    return msg


def _curves(seed=1, seconds=3.0, fps=30.0):
    rng = np.random.default_rng(seed)
    return rng, _takes.arkit_curves(seconds, fps, rng)


# ----------------------------------------------------------------------------- Live Link Face
def test_livelink_take_dropping_frames_on_a_60_fps_timecode(tmp_path):
    rng, W = _curves()
    p = tmp_path / "take.csv"
    keep = _takes.write_livelink(p, W, 30.0, rng)
    steps = np.diff(keep)
    assert steps.max() >= 2 and steps.min() == 1  # timecode steps 2 to 8 frames at 60
    tr = fw.load_arkit(p)
    assert tr.fps == 30.0 and tr.frames == keep[-1] + 1  # the take's real length, frames at their real times
    assert tr.info["frames_filled"] == tr.frames - len(keep) > 0
    assert any("skipped" in n and "interpolated" in n for n in tr.notes), tr.notes
    np.testing.assert_allclose(tr.weights[keep], np.clip(W[keep], 0, 1), atol=2e-6)  # kept frames exact
    gap = int(np.argmax(steps > 1))  # an interpolated frame lies between its neighbours
    a, b = keep[gap], keep[gap + 1]
    lo, hi = np.minimum(tr.weights[a], tr.weights[b]), np.maximum(tr.weights[a], tr.weights[b])
    assert ((tr.weights[a + 1] >= lo - 1e-9) & (tr.weights[a + 1] <= hi + 1e-9)).all()
    assert tr.eye_rotation is None  # the generator records no gaze (all zero): the eyeLook weights say it


def test_livelink_weights_over_one_are_clamped_and_counted(tmp_path):
    rng, W = _curves()
    assert W.max() > 1.04  # EyeLookIn to 1.05
    p = tmp_path / "take.csv"
    _takes.write_livelink(p, W, 30.0, rng, drop=False)
    tr = fw.load_arkit(p)
    assert tr.weights.max() == 1.0
    over = int((W > 1.0).sum())
    assert sum(tr.info["clamped"].values()) == over and set(tr.info["clamped"]) <= {"eyeLookInLeft", "eyeLookInRight"}
    assert any("clamped" in n for n in tr.notes)
    W[5, 17] = 1.2  # jawOpen beyond the slack: an error naming row and column
    _takes.write_livelink(p, W, 30.0, rng, drop=False)
    _one_line_error(lambda: fw.load_arkit(p), "row 7", "'JawOpen'", "1.2")


@pytest.mark.parametrize("count_header, case", [("BlendShapeCount", "title"), ("BlendshapeCount", "title"),
                                                ("blendshapecount", "lower"), ("BLENDSHAPECOUNT", "upper"),
                                                ("BlendShapeCount", "camel")])
def test_livelink_header_spellings_and_case(tmp_path, count_header, case):
    rng, W = _curves(seed=2, seconds=1.5)
    p = tmp_path / "take.csv"
    _takes.write_livelink(p, W, 30.0, np.random.default_rng(5), count_header=count_header, case=case)
    ref = tmp_path / "ref.csv"
    _takes.write_livelink(ref, W, 30.0, np.random.default_rng(5))
    np.testing.assert_array_equal(fw.load_arkit(p).weights, fw.load_arkit(ref).weights)


def test_livelink_start_end_cut(tmp_path):
    rng, W = _curves(seconds=4.0)
    p = tmp_path / "take.csv"
    _takes.write_livelink(p, W, 30.0, rng, drop=False)
    full = fw.load_arkit(p)
    part = fw.load_arkit(p, start=1.0, end=2.5)
    assert part.frames == 46 and part.info["start_s"] == 1.0
    np.testing.assert_array_equal(part.weights, full.weights[30:76])
    np.testing.assert_array_equal(part.head_rotation, full.head_rotation[30:76])
    _one_line_error(lambda: fw.load_arkit(p, start=9.0), "start 9 s is beyond the take's")
    _one_line_error(lambda: fw.load_arkit(p, start=2.0, end=1.0), "end: 1 s is not after start 2 s")
    _one_line_error(lambda: fw.load_arkit(p, start=-1.0), "start")


# ----------------------------------------------------------------------------- MediaPipe
@pytest.mark.parametrize("layout", ["tasks", "js", "people", "flat", "lists"])
@pytest.mark.parametrize("strings", [False, True])
def test_mediapipe_51_plus_neutral_in_every_layout(tmp_path, layout, strings):
    rng, W = _curves(seed=3, seconds=2.0)
    W = np.clip(W, 0, 1)
    p = tmp_path / "mp.json"
    _takes.write_mediapipe(p, W, 30.0, rng, layout=layout, strings=strings)
    names = _takes.mediapipe_names()
    assert len(names) == 52 and names[0] == "_neutral" and "tongueOut" not in names
    tr = fw.load_arkit(p, fps=30.0 if layout == "lists" else None)
    assert tr.fps == 30.0 and tr.frames == len(W)  # whole-ms stamps (0, 33, 67, ...): 30 fps, not 30.303
    np.testing.assert_allclose(tr.weights, W * (np.array(fw.ARKIT_NAMES) != "tongueOut"), atol=1e-6)
    assert tr.info["missing"] == ["tongueOut"] and any("tongueOut" in n for n in tr.notes)


def test_mediapipe_microseconds_and_bounds(tmp_path):
    rng, W = _curves(seed=4, seconds=2.0)
    p = tmp_path / "mp.json"
    _takes.write_mediapipe(p, np.clip(W, 0, 1), 30.0, rng, stamps="us")
    tr = fw.load_arkit(p)  # microseconds under timestamp_ms: not a 0.03 fps take
    assert tr.fps == 30.0 and tr.info.get("timestamps_in_microseconds")
    assert any("microseconds" in n for n in tr.notes)
    frames = json.loads(p.read_text())
    slow = [dict(f, timestamp_ms=2000 * i) for i, f in enumerate(frames[:3])]  # 0.5 fps: stills, not a take
    p.write_text(json.dumps(slow))
    _one_line_error(lambda: fw.load_arkit(p), "0.5 frames/s", "outside a take's 1..1000")
    fast = [dict(f, timestamp_ms=0.1 * i) for i, f in enumerate(frames)]
    p.write_text(json.dumps(fast))
    _one_line_error(lambda: fw.load_arkit(p), "10000 frames/s")


def test_mediapipe_dropped_frames_and_faceless_frames(tmp_path):
    rng, W = _curves(seed=5, seconds=2.0)
    W = np.clip(W, 0, 1)
    p = tmp_path / "mp.json"
    keep = _takes.write_mediapipe(p, W, 30.0, rng, drop=True, no_face=3)
    tr = fw.load_arkit(p)
    assert tr.frames == keep[-1] + 1 and tr.info["frames_filled"] == tr.frames - len(keep)
    assert tr.info["frames_without_face"] == len({k for k in keep if len(W) // 2 <= k < len(W) // 2 + 3})


def test_mediapipe_score_beyond_slack_names_frame_and_category(tmp_path):
    rng, W = _curves(seed=6, seconds=1.0)
    W = np.clip(W, 0, 1)
    W[4, list(fw.ARKIT_NAMES).index("mouthSmileLeft")] = 1.3
    p = tmp_path / "mp.json"
    _takes.write_mediapipe(p, W, 30.0, rng)
    _one_line_error(lambda: fw.load_arkit(p), "frame 4", "'mouthSmileLeft'", "1.3")


def test_mediapipe_other_missing_category_is_an_error(tmp_path):
    rng, W = _curves(seed=6, seconds=1.0)
    p = tmp_path / "mp.json"
    _takes.write_mediapipe(p, np.clip(W, 0, 1), 30.0, rng)
    frames = json.loads(p.read_text())
    frames[2]["face_blendshapes"][0] = [c for c in frames[2]["face_blendshapes"][0] if c["category_name"] != "jawOpen"]
    p.write_text(json.dumps(frames))
    _one_line_error(lambda: fw.load_arkit(p), "frame 2", "no category 'jawOpen'")


# ----------------------------------------------------------------------------- marker takes
def _local_points(rng, names):
    return {n: rng.normal(scale=0.04, size=3) for n in names}


def test_marker_csv_cut_neutral_and_dropped_rows(tmp_path):
    rng = np.random.default_rng(8)
    names = list(_takes.MARKERS_41)
    rest = _local_points(rng, names)
    T = 90
    local = np.array([[rest[n] for n in names]] * T) + np.linspace(0, 1, T)[:, None, None] * 0.003
    tr, _ = _takes.marker_take(local, 30.0, rng, names=names, motion=False, dropout=0.0, noise_m=0.0)
    assert len(names) == 41
    p = tmp_path / "take.csv"
    _takes.save_take_csv(tr, p, units="cm")
    lines = p.read_text().splitlines()
    p.write_text("\n".join(lines[:20] + lines[22:]) + "\n")  # two rows lost: frames 18, 19
    got = fw.load_markers(p, units="cm")
    assert got.frames == T and got.info["frames_filled"] == 2 and got.fps == 30.0
    np.testing.assert_allclose(got.positions, tr.positions, atol=1e-6)  # a straight motion: interpolation exact
    part = fw.load_markers(p, units="cm", start=1.0, end=2.0, neutral="0:0.5")
    assert part.frames == 31
    np.testing.assert_allclose(part.positions, tr.positions[30:61], atol=1e-6)
    np.testing.assert_allclose(part.neutral, tr.positions[:16].mean(0), atol=1e-6)
    first = fw.load_markers(p, units="cm", start=1.0)
    np.testing.assert_allclose(first.neutral_points(), tr.positions[0], atol=1e-6)  # the take's own first frame
    _one_line_error(lambda: fw.load_markers(p, units="cm", neutral="a:b"), "neutral")
    _one_line_error(lambda: fw.load_markers(p, units="cm", neutral=(2.0, 1.0)), "neutral")


def test_marker_fps_bounds(tmp_path):
    p = tmp_path / "t.json"
    p.write_text(json.dumps({"fps": 1e-4, "units": "mm", "markers": {"2.1": [[0, 0, 0], [0, 1, 0]]}}))
    _one_line_error(lambda: fw.load_markers(p), "0.0001 frames/s", "outside a take's")
    with pytest.raises(fw.InputError, match="fps"):
        fw.MarkerTrack(0.03, ["2.1"], np.zeros((2, 1, 3)))


def test_truncated_c3d_is_refused(tmp_path):
    c3d = pytest.importorskip("c3d")
    T, K = 7, 41  # 656 bytes a frame: 300 bytes off the end cut into the last frame
    w = c3d.Writer(point_rate=100.0, point_units="mm  ")
    rng = np.random.default_rng(2)
    base = rng.normal(scale=40.0, size=(K, 3))
    w.add_frames([(np.c_[base + t, np.zeros((K, 2))].astype(np.float32), np.zeros((0, 0), np.float32))
                  for t in range(T)])
    w.set_point_labels(list(_takes.MARKERS_41))
    good = tmp_path / "t.c3d"
    with open(good, "wb") as f, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        w.write(f)
    assert fw.load_markers(good).frames == T
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(good.read_bytes()[:-300])
    _one_line_error(lambda: fw.load_markers(cut), "header says 7 frames", "holds 6", "truncated")


# ----------------------------------------------------------------------------- stable points
def _stable_rest(rng):
    names = list(fw.takes.STABLE_POINTS) + ["2.1", "8.3"]
    return names, {n: rng.normal(scale=0.06, size=3) for n in names}


def test_collinear_stable_points_refused():
    rng = np.random.default_rng(4)
    names, rest = _stable_rest(rng)
    three = ["11.1", "9.6", "9.7", "2.1"]
    P = np.array([[rest[n] for n in three]] * 3)
    P[:, :3] = np.array([0.0, 0.0, 0.0]) + np.linspace(0, 0.08, 3)[:, None] * np.array([1.0, 0.2, 0.1])  # a line
    tr = fw.MarkerTrack(30, three, P)
    _one_line_error(lambda: fw.takes.remove_head_motion(tr, rest), "11.1, 9.6, 9.7", "lie on a line")


def test_collapsed_stable_points_refused():
    rng = np.random.default_rng(5)
    names, rest = _stable_rest(rng)
    P = np.array([[rest[n] for n in names]] * 3)
    P[:, :10] = P[:, :10] * 1e-3  # every stable point within a millimetre: no head
    tr = fw.MarkerTrack(30, names, P)
    _one_line_error(lambda: fw.takes.remove_head_motion(tr, rest), "collapsed")


def test_mirrored_stable_points_refused():
    rng = np.random.default_rng(6)
    names, rest = _stable_rest(rng)
    P = np.array([[rest[n] for n in names]] * 4)
    P[..., 0] *= -1.0  # a left-handed capture
    tr = fw.MarkerTrack(30, names, P)
    _one_line_error(lambda: fw.takes.remove_head_motion(tr, rest), "mirrored", "left and right swapped")
    ok = fw.MarkerTrack(30, names, np.array([[rest[n] for n in names]] * 4))
    fw.takes.remove_head_motion(ok, rest)  # the same points unmirrored fit


# ----------------------------------------------------------------------------- retargeting maps
def _face(rng):
    """A face of FDPs: rest points (m) spread as on a head."""
    names = ["2.1", "2.2", "8.1", "8.2", "8.3", "8.4", "8.5", "8.6", "4.1", "4.2", "4.3", "4.4", "3.1", "3.2", "3.3",
             "3.4", "3.7", "3.8", "3.11", "3.12", "9.15", "9.3", "5.1", "5.2", *fw.takes.STABLE_POINTS]
    return names, {n: rng.uniform(-0.07, 0.07, 3) for n in names}


def test_retarget_regions():
    rng = np.random.default_rng(2)
    names, head = _face(rng)
    _, _, m = fw.takes.retarget_markers(fw.MarkerTrack(30, names, np.array([[head[n] for n in names]] * 2)), head)
    region = dict(zip(m.names, m.regions))
    assert region["8.3"] == "mouth" and region["2.2"] == "mouth" and region["2.1"] == "jaw"
    assert region["4.1"] == "brows" and region["11.1"] == "forehead" and region["10.9"] == "ears"


@pytest.mark.parametrize("method", ["affine", "fapu"])
def test_retarget_undoes_a_stretched_actor(method):
    """The actor is the head stretched (1.15 across, 0.9 up and deep), turned and moved: its
    displacements, stretched the same way, come back as the head's own."""
    rng = np.random.default_rng(9)
    names, head = _face(rng)
    Q = np.array([head[n] for n in names])
    S = np.diag([1.15, 0.9, 0.9])
    c, s = np.cos(0.3), np.sin(0.3)
    Rw = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    to_actor = lambda X: (X @ S.T) @ Rw.T + np.array([0.1, 1.6, -0.2])  # noqa: E731
    T = 5
    D = np.zeros((T, len(names), 3))  # the head's own expression: mouth and brows move, stable points do not
    mov = [i for i, n in enumerate(names) if n not in fw.takes.STABLE_POINTS]
    D[:, mov] = rng.normal(scale=0.003, size=(T, len(mov), 3)) * np.linspace(0, 1, T)[:, None, None]
    take = fw.MarkerTrack(30, names, np.array([to_actor(Q + D[t]) for t in range(T)]))
    targets, motion, m = fw.takes.retarget_markers(take, head, method=method)
    assert motion is not None and np.allclose(motion.rotation, np.eye(3), atol=1e-9)  # the actor stood still
    got = targets.positions - Q[None]
    err = np.linalg.norm(got - D, axis=2).max()
    naive = np.linalg.norm((targets.positions * 0 + (take.positions - take.positions[:1]) @ Rw) - D, axis=2).max()
    assert err < (0.1 if method == "affine" else 0.4) * naive, (err, naive)  # better than the displacements as they are
    assert method == "fapu" or err < 2e-4, err
    assert m.scale == pytest.approx(np.cbrt(1 / (1.15 * 0.81)), rel=0.15)


def test_retarget_removes_actor_head_motion():
    rng = np.random.default_rng(10)
    names, head = _face(rng)
    Q = np.array([head[n] for n in names])
    T = 20
    R, t = _takes.head_motion(T, 30.0, rng)
    P = np.einsum("tij,kj->tki", R, Q * 1.1) + t[:, None] + np.array([0.0, 1.6, 0.0])
    targets, motion, m = fw.takes.retarget_markers(fw.MarkerTrack(30, names, P), head)
    np.testing.assert_allclose(targets.positions, np.broadcast_to(Q, P.shape), atol=1e-9)  # no expression: rest
    np.testing.assert_allclose(motion.rotation, R, atol=1e-9)


def test_retarget_needs_a_neutral_and_a_method():
    names = ["2.1", "8.3", "8.4"]
    head = {n: np.random.default_rng(1).normal(size=3) for n in names}
    take = fw.MarkerTrack(30, names, np.zeros((2, 3, 3)))
    _one_line_error(lambda: fw.takes.retarget_markers(take, head, rigid=False), "four or more points")
    _one_line_error(lambda: fw.takes.retarget_markers(take, head, method="x"), "method")
    _one_line_error(lambda: fw.takes.retarget_markers(take, {"2.1": np.zeros(3)}, rigid=False), "no point '8.3'")


# ----------------------------------------------------------------------------- left and right
@pytest.mark.slow
def test_mouth_left_and_jaw_left_move_to_the_faces_own_left(tmp_path):
    """Live Link's MouthLeft / JawLeft are the face's own left (as its EyeBlinkLeft): through the
    head's ARKit table, the simulated mouth corners and chin move towards the face's left."""
    rig = fw.build_face(fw.default_template(0))
    sim = fw.FaceSimulator(rig)
    table = fw.arkit_table(sim, source="shipped", solve=["mouthLeft", "jawLeft", "mouthRight", "jawRight"])
    ids = [str(i) for i in rig.fdp_ids]
    rest = sim.fdp_points()
    left = np.sign(rest[ids.index("8.3"), 0] - rest[ids.index("8.4"), 0])  # the face's own left along x
    for shape, point in (("mouthLeft", "8.3"), ("jawLeft", "2.1"), ("mouthRight", "8.4"), ("jawRight", "2.1")):
        W = np.zeros((8, 52))
        W[1:, list(fw.ARKIT_NAMES).index(shape)] = 1.0
        rec = fw.FrameRecorder()
        res = fw.drive(fw.FaceSimulator(rig), fw.takes.ArkitTrack(30.0, W), table=table, sinks=[rec])
        dx = (rec.frames.fdp_points[-1, ids.index(point), 0] - rest[ids.index(point), 0]) * left
        want = 1.0 if shape.endswith("Left") else -1.0
        assert dx * want > 3e-4, (shape, dx, res.unreachable)
