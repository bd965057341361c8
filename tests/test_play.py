"""One playback path (issue 22): ``facewarp.play`` with sinks, typed timelines, the module path of
``facewarp simulate`` up to the first kernel launch."""

from __future__ import annotations

import numpy as np
import pytest

import facewarp as fw
from module_trace import entry_counts, module_entries

SECONDS = 0.1  # 4 frames at 30 fps


@pytest.fixture(scope="module")
def rig(default_rig):
    return default_rig


@pytest.fixture(scope="module")
def sim(rig):
    return fw.FaceSimulator(rig, device="cpu")


class _Log(fw.takes.Sink):
    def __init__(self):
        self.calls = []

    def start(self, sim, frame_count):
        self.calls.append(("start", frame_count))

    def frame(self, sim, k, t):
        self.calls.append(("frame", k, t))

    def finish(self, sim, stats):
        self.calls.append(("finish", stats.frames))


def test_recorder_matches_a_user_loop(rig):
    # the oracle: the same frames stepped by hand through the public methods (fresh simulators:
    # the comparison does not lean on reset)
    tl = fw.timeline_for("laugh", attack=0.05, start=0.0)
    rec, log = fw.FrameRecorder(), _Log()
    seen = []
    stats = fw.play(fw.FaceSimulator(rig), tl, SECONDS, sinks=[rec, log, lambda s, k, t: seen.append(k)])
    frames = rec.frames
    assert stats.frames == 4 == len(frames.times) and seen == [0, 1, 2, 3]
    assert log.calls[0] == ("start", 4) and log.calls[-1] == ("finish", 4)
    assert [c[1] for c in log.calls[1:-1]] == [0, 1, 2, 3]
    head = tl.for_head(rig)
    sim = fw.FaceSimulator(rig)
    np.testing.assert_array_equal(frames.points[0], sim.surface().astype(np.float32), err_msg="frame 0 is the rest")
    for k in range(1, 4):
        e = head.sample(k / sim.fps)
        sim.set_activations(e)
        sim.set_jaw(e.jaw_u, e.jaw_v)
        sim.step()
        np.testing.assert_array_equal(frames.points[k], sim.surface().astype(np.float32), err_msg=f"frame {k}")
        np.testing.assert_array_equal(frames.activations[k], sim.activations)
        np.testing.assert_array_equal(frames.jaw[k], sim.jaw_angles)
    assert frames.jaw[-1, 0] > 0  # the laugh's chin drop, converted for this head
    # FaceSimulator.run is play with a FrameRecorder
    again = fw.FaceSimulator(rig).run(tl, SECONDS)
    np.testing.assert_array_equal(again.points, frames.points)
    np.testing.assert_array_equal(again.fdp_points, frames.fdp_points)
    np.testing.assert_array_equal(again.muscle_curves, frames.muscle_curves)


def test_usd_is_a_sink(rig, tmp_path):
    pytest.importorskip("pxr")
    sim = fw.FaceSimulator(rig)
    with fw.UsdAnimation(tmp_path / "take.usda", sim) as usd:
        stats = fw.play(sim, fw.timeline_for("smile", start=0.0), SECONDS, sinks=[usd])
        assert usd.frame_count == stats.frames == 4
    assert (tmp_path / "take.usda").is_file()


def test_timeline_converted_once(rig):
    tl = fw.expressions.timeline_from_spec("laugh", 1.0)
    assert tl.lever is None
    head = tl.for_head(rig)
    assert head.lever == pytest.approx(fw.expressions.jaw_lever(rig)) and head.for_head(rig) is head
    assert head.segments[0].expression.jaw_u == pytest.approx(0.022 / fw.expressions.jaw_lever(rig))
    smile = fw.timeline_for("smile")  # no chin drop: nothing to convert
    assert smile.for_head(rig) is smile
    other = head.for_head(0.2)  # another head: converted again from the chin drop
    assert other.lever == 0.2 and other.segments[0].expression.jaw_u == pytest.approx(0.022 / 0.2)


def test_held_is_the_spec_envelope():
    e = fw.expressions.expression_from_activations("zygomatic_major=0.5,jaw_drop_mm=8")
    assert fw.Timeline.held(e, 2.0) == fw.expressions.timeline_from_spec("zygomatic_major=0.5,jaw_drop_mm=8", 2.0)
    assert fw.Timeline.held(fw.preset("smile"), 0.4) == fw.expressions.timeline_from_spec("smile", 0.4)
    with pytest.raises(fw.InputError, match="Expression"):
        fw.Timeline.held("smile", 1.0)
    with pytest.raises(fw.InputError, match="seconds"):
        fw.Timeline.held(e, 0.0)


@pytest.mark.parametrize("args, msg", [
    (("smile", 1.0), "timeline"),
    ((fw.timeline_for("smile"), 0.0), "seconds"),
    ((fw.timeline_for("smile"), float("nan")), "seconds"),
])
def test_play_rejects_bad_input(sim, args, msg):
    with pytest.raises(fw.InputError, match=msg):
        fw.play(sim, *args)


def test_play_rejects_bad_sink(sim):
    with pytest.raises(fw.InputError, match="sinks"):
        fw.play(sim, fw.timeline_for("smile"), SECONDS, sinks=[3])


@pytest.fixture(scope="module")
def simulate_path(tmp_path_factory):
    """The facewarp modules ``facewarp simulate`` enters from ``simulate_files`` to the first kernel launch."""
    from facewarp.cli import main

    tmp = tmp_path_factory.mktemp("path")
    assert main(["--json", "build", "default:0", "--out", str(tmp / "b")]) == 0
    return module_entries(lambda: main(["--json", "simulate", str(tmp / "b"), "--expression", "smile", "--seconds",
                                        str(SECONDS), "--jaw", "kinematic", "--out", str(tmp / "o")]))


def test_simulate_jobs_side_enters_once(simulate_path):
    # the job checks, loads the head once and builds one simulator; the CLI built the timeline
    counts = entry_counts(simulate_path)
    assert simulate_path[0] == "jobs.face"
    for m in ("jobs.face", "jobs.checks", "expressions", "sim.play", "coupling.drivers"):
        assert counts.get(m, 0) <= 1, f"{m} entered {counts.get(m)} times: " + " -> ".join(simulate_path)


def test_simulate_enters_no_module_more_than_twice(simulate_path):
    # issue 22: following the head from simulate_files to the first kernel launch. Since issue 35 the
    # physics package is Newton's files (builder, model, state, springs, arrays, stage arrays): finalize
    # walks many small files and dataclass constructors, so the package counts as one stage here
    # (consecutive physics modules one entry): the rig loaded, the Model built, the stages, the solver
    outside = [m for m in simulate_path if not m.startswith("physics.")]
    counts = entry_counts(outside)
    assert max(counts.values()) <= 2, f"{counts}: " + " -> ".join(simulate_path)
    stages = [m.split(".")[0] if m.startswith("physics.") else m for m in simulate_path]
    stages = [m for k, m in enumerate(stages) if k == 0 or stages[k - 1] != m]
    assert stages.count("physics") <= 5, " -> ".join(stages)  # measured 5 after the split (core.warp asked inside finalize)
