"""The simulated face: Table 6.4 presets move the FDPs the right way; rest stays at rest."""

from __future__ import annotations

import numpy as np
import pytest

from facewarp import default_template
from facewarp._src.anatomy.build import build_anatomy
from facewarp._src.expressions import Expression, Segment, Timeline, timeline_for
from facewarp._src.sim.face import FaceSimulator, face_rig_from_anatomy, load_face_rig, save_face_rig

SECONDS = 0.4


@pytest.fixture(scope="module")
def rig():
    a = build_anatomy(default_template(0), check_intersections=False)
    return face_rig_from_anatomy(a)


def motion(rig, timeline, seconds=SECONDS):
    frames = FaceSimulator(rig, fps=30).run(timeline, seconds)
    ids = list(map(str, frames.fdp_ids))
    d = frames.fdp_points[-1] - frames.fdp_points[0]
    assert np.isfinite(frames.points).all()
    return {k: d[i] for i, k in enumerate(ids)}, frames


def preset(name):
    return timeline_for(name, attack=0.15, hold=1.0, release=0.1, start=0.02)


def test_face_rig_roundtrip(rig, tmp_path):
    p = save_face_rig(tmp_path / "face_rig.npz", rig)
    r2 = load_face_rig(p)
    np.testing.assert_array_equal(r2.tets, rig.tets)
    np.testing.assert_allclose(r2.rig.ctrl_rest, rig.rig.ctrl_rest)
    assert r2.rig.names == rig.rig.names and set(r2.parts) == set(rig.parts)
    assert rig.fixed.any() and rig.held.any() and len(rig.support_nodes) and len(rig.jaw_nodes)


def test_rest_stays_at_rest(rig):
    d, frames = motion(rig, Timeline([]), 0.1)
    assert np.abs(frames.points - frames.points[0]).max() < 1e-6


def test_smile_raises_lip_corners_outward(rig):
    d, _ = motion(rig, preset("smile"))
    assert d["8.3"][1] > 1e-3 and d["8.4"][1] > 1e-3  # up (+y) by more than a millimetre
    assert d["8.3"][0] > 2e-4 and d["8.4"][0] < -2e-4  # outward: left corner +x, right corner -x


def test_sad_lowers_lip_corners(rig):
    d, _ = motion(rig, preset("sad"))
    assert d["8.3"][1] < -2e-4 and d["8.4"][1] < -2e-4


def test_surprise_raises_brows(rig):
    d, _ = motion(rig, preset("surprise"))
    for k in ("4.1", "4.2", "4.3", "4.4", "4.5", "4.6"):
        assert d[k][1] > 0, (k, d[k])
    assert d["4.3"][1] > 1e-3


def test_angry_pulls_inner_brows_in_and_down(rig):
    d, _ = motion(rig, preset("angry"))
    assert d["4.1"][0] < -2e-4 and d["4.2"][0] > 2e-4  # toward the midline x = 0
    assert d["4.1"][1] < 0 and d["4.2"][1] < 0


def test_jaw_moves_chin_down_and_back(rig):
    jaw = Timeline([Segment(Expression("jaw", {}, np.deg2rad(15.0)), 0.02, 0.15, 1.0, 0.1)])
    d, frames = motion(rig, jaw)
    assert d["2.1"][1] < -5e-3 and d["2.1"][2] < 0
    # the lower teeth follow the jaw, the eyes do not
    t_low = frames.parts["teeth_lower"][0]
    assert np.abs(t_low[-1] - t_low[0]).max() > 5e-3
    assert np.abs(frames.parts["eye_L"][0][-1] - frames.parts["eye_L"][0][0]).max() == 0


def _laugh_steps(rig, device, steps=1000, chunks=10):
    """``steps`` substeps of the laugh preset (muscles and jaw) ramped in over ``chunks``."""
    from facewarp._src.expressions import preset as table_preset
    from facewarp._src.sim.face import _activation_vector

    sim = FaceSimulator(rig, device=device)
    e = table_preset("laugh")
    a = _activation_vector(rig.rig.names, e)
    for k in range(1, chunks + 1):
        sim.control.activations.assign(a * (k / chunks))
        sim.control.jaw_angles.assign(np.array([e.jaw_u * k / chunks, 0.0], np.float32))
        sim.advance(steps // chunks)
    sim.solver.check(sim.state)
    return sim.state.positions.numpy().astype(np.float64)


def test_steps_are_deterministic(rig):
    # elements write their own force slots and nodes add them in a fixed order: no atomics
    a, b = _laugh_steps(rig, "cpu", 200), _laugh_steps(rig, "cpu", 200)
    assert np.array_equal(a, b)


def test_cpu_and_cuda_agree_after_1000_steps(rig):
    from conftest import warp_devices

    if "cuda:0" not in warp_devices():
        pytest.skip("compares a GPU with the CPU")
    x_cpu, x_gpu = _laugh_steps(rig, "cpu"), _laugh_steps(rig, "cuda:0")
    moved = np.linalg.norm(x_cpu - rig.nodes, axis=1).max()
    diff = np.linalg.norm(x_cpu - x_gpu, axis=1).max()
    assert moved > 1e-3 and diff <= 1e-4 * moved, (diff, moved)
