"""Issue 23, the solver side: any legal control stream simulates (rollback with sub-steps, the
volume floor), and the frame stats that say so. Level-0 default head, a few frames each."""

from __future__ import annotations

import numpy as np
import pytest

import facewarp as fw
from facewarp import SimulationError
from facewarp.physics import VOLUME_FLOOR, select_solver


@pytest.fixture(scope="module")
def rig(default_rig):
    return default_rig


def volume_ratios(rig, X):
    T = rig.tets
    a, b, c, d = (X[T[:, i]] for i in range(4))
    a0, b0, c0, d0 = (rig.nodes[T[:, i]] for i in range(4))
    v = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)
    v0 = np.einsum("ij,ij->i", np.cross(b0 - a0, c0 - a0), d0 - a0)
    return v / v0


def test_every_muscle_at_full_stays_above_the_volume_floor(rig):
    """Every muscle at 1.0 held tet 4814 at 3e-5 of its rest volume; the barrier keeps it above the 2 % floor."""
    sim = fw.FaceSimulator(rig)
    sim.set_activations(np.ones(len(sim.muscle_names)))
    sim.advance(8)
    r = volume_ratios(rig, sim.positions())
    assert r.min() >= VOLUME_FLOOR
    assert sim.stats.min_volume_ratio == pytest.approx(r.min(), rel=1e-3)
    assert sim.stats.frames == 8 and sim.stats.frames_below_floor == 0


def _failing_check(sim, times: int):
    """Make the solver's guard report a failure on its next ``times`` checks."""
    real = sim.solver.check
    left = [times]

    def check(state=None):
        if left[0] > 0:
            left[0] -= 1
            raise SimulationError("simulation failed at step 1: injected")
        real(state)

    sim.solver.check = check


def test_a_failing_frame_is_taken_again_as_two_substeps(rig):
    """A frame whose check fails is rolled back and taken as 2 substeps with the controls ramped:
    the same state as a simulator stepping that frame with 2 substeps from the start."""
    a = {"zygomatic_major": 0.6, "orbicularis_oris": 0.3}
    sim = fw.FaceSimulator(rig)
    _failing_check(sim, 1)
    sim.set_activations(a)
    sim.set_jaw(np.deg2rad(5.0))
    sim.step()
    ref = fw.FaceSimulator(rig, substeps=2)
    ref.set_activations(a)
    ref.set_jaw(np.deg2rad(5.0))
    ref.step()
    np.testing.assert_allclose(sim.positions(), ref.positions(), atol=1e-7)
    assert sim.stats.substepped_frames == 1 and sim.stats.retries == 1 and sim.stats.max_substep_factor == 2
    assert sim.time == pytest.approx(1 / 30)
    sim.step()  # the next frame is a plain one again
    assert sim.stats.frames == 2 and sim.stats.substepped_frames == 1


def test_a_frame_failing_at_the_bound_is_an_error_and_leaves_the_state(rig):
    sim = fw.FaceSimulator(rig)
    sim.max_refinement = 2
    sim.set_activations({"zygomatic_major": 0.5})
    sim.step()
    before = sim.positions()
    _failing_check(sim, 10)
    sim.set_activations({"zygomatic_major": 1.0})
    with pytest.raises(SimulationError, match=r"failed even as 4 substeps .*injected"):
        sim.step()
    np.testing.assert_array_equal(sim.positions(), before)
    assert sim.stats.retries == 2


def test_a_head_jump_beyond_physical_motion_is_refused(rig):
    """A single-frame jump of 1e6 m gave 0.000 mm deformation and no error."""
    sim = fw.FaceSimulator(rig)
    sim.step()
    before = sim.positions()
    sim.set_head_pose(np.eye(3), np.array([1e6, 0.0, 0.0]))
    with pytest.raises(fw.InputError, match="head pose: .*linear acceleration of 9e\\+08 m/s\\^2, above the limit 1000"):
        sim.step()
    np.testing.assert_array_equal(sim.positions(), before)
    assert sim.time == pytest.approx(1 / 30)
    # a head spinning at 5 rev/s about a tilted axis is a legal motion
    axis = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    sim.set_head_pose(np.eye(3), np.zeros(3))
    sim.step()
    for k in range(1, 4):
        ang = 2 * np.pi * 5.0 * k / 30
        sim.set_head_pose(np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K, np.zeros(3))
        sim.step()
    assert np.isfinite(sim.positions()).all()


# ----------------------------------------------------------------------------------------
# the MuJoCo jaw: its warnings reach the user (the thesis profile's stability: tests/test_mujoco.py)


def test_a_zygomatic_pull_with_the_mujoco_jaw_runs(rig):
    """The issue's case: zygomatic_major 0.9 over 0.2 s with the MuJoCo jaw inverted tet 1814 at
    step 5 (the jaw carry flattened a tet that the muscles had already pressed to 5e-4 of its volume)."""
    mujoco = pytest.importorskip("mujoco")
    sim = fw.FaceSimulator(rig)
    model = mujoco.MjModel.from_xml_string(fw.head_mjcf(fw.default_template(0)))
    jaw = fw.MujocoJaw(sim, model, mujoco.MjData(model))
    tl = fw.expressions.timeline_from_spec("zygomatic_major=0.9", 0.2).for_head(rig)
    for k in range(1, 7):
        sim.set_activations(tl.sample(k / 30))
        jaw.step()
        assert volume_ratios(rig, sim.positions()).min() >= VOLUME_FLOOR
    st = sim.stats.as_dict()
    assert st["frames"] == 6 and st["min_volume_ratio"] >= VOLUME_FLOOR


def test_an_unstable_mujoco_step_is_an_error(rig, tmp_path, monkeypatch):
    mujoco = pytest.importorskip("mujoco")
    from facewarp.coupling import mujoco_warnings

    monkeypatch.chdir(tmp_path)
    sim = fw.FaceSimulator(rig)
    model = mujoco.MjModel.from_xml_string(fw.head_mjcf(fw.default_template(0)))
    data = mujoco.MjData(model)
    jaw = fw.MujocoJaw(sim, model, data)
    jaw.step()
    data.qvel[0] = 1e11  # beyond MuJoCo's limit: it warns (BADQVEL) and resets its state
    with pytest.raises(SimulationError, match="MuJoCo jaw went unstable .*mjWARN_BADQVEL"):
        jaw.step()
    assert any("qvel" in m.lower() or "QVEL" in m for m in mujoco_warnings())
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


# ----------------------------------------------------------------------------------------
# devices: every array a stage, Springs or solver receives is on the model's device


def test_an_array_on_another_device_is_an_input_error():
    import warp as wp

    from facewarp.physics import check_device

    check_device(wp.zeros(3, dtype=float, device="cpu"), "cpu", "x")  # the same device: fine
    check_device(np.zeros(3), "cuda:0", "x")  # not a Warp array: not checked
    with pytest.raises(fw.InputError, match=r"stages: Foo.springs\[0\].node: a Warp array on cpu, but the model is on cuda:0"):
        check_device(wp.zeros(3, dtype=wp.int32, device="cpu"), "cuda:0", "stages: Foo.springs[0].node")


@pytest.mark.skipif("not __import__('warp').is_cuda_available()", reason="needs a CUDA device")
def test_springs_on_cuda_for_a_cpu_model_are_refused():
    """On a GPU machine Warp's default device is cuda:0: Springs made without device= for a CPU
    model crashed the process (CPU kernels reading CUDA pointers)."""
    import warp as wp

    from conftest import grid_tets
    from facewarp.physics import ModelBuilder, Springs

    V, T = grid_tets(2, 1, 1)
    model = ModelBuilder(V, T, material="physical").finalize("cpu")
    sp = Springs(node=wp.array([0, 1], dtype=wp.int32, device="cuda:0"),
                 point=wp.zeros(2, dtype=wp.vec3, device="cuda:0"), stiffness=wp.ones(2, dtype=float, device="cuda:0"),
                 rest_length=wp.zeros(2, dtype=float, device="cuda:0"))

    class Stage:
        springs = sp

        def prepare(self, *args):
            pass

    with pytest.raises(fw.InputError, match="springs\\[0\\].node: a Warp array on cuda:0, but the model is on cpu"):
        select_solver(model, stages=[Stage()])
    cuda_state = ModelBuilder(V, T, material="physical").finalize("cuda:0").state()
    solver = select_solver(model)
    with pytest.raises(fw.InputError, match="state_in.positions: a Warp array on cuda:0"):
        solver.step(cuda_state, model.state(), model.control(), 0.01)


def test_play_reports_the_frame_stats(rig):
    """The frame stats reach the reports (:func:`facewarp.play` backs ``simulate`` and the demo)."""
    sim = fw.FaceSimulator(rig)
    rep = fw.play(sim, fw.timeline_for("smile"), 0.1).to_dict()
    st = rep["frame_stats"]
    assert st["frames"] == 3 and st["substepped_frames"] == 0 and st["volume_floor"] == VOLUME_FLOOR
    assert 0.0 < st["min_volume_ratio"] <= 1.0 and rep["mujoco_events"] == []
