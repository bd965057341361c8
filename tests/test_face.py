"""The simulated face: Table 6.4 presets move the FDPs the right way; rest stays at rest.

Run with the default solver (implicit, one step per 30 fps frame) and material (physical); one
test runs the Verlet reference with the thesis profile (the simulator's behaviour before the
implicit solver)."""

from __future__ import annotations

import numpy as np
import pytest

from facewarp import (Expression, FaceSimulator, InputError, Segment, Timeline, build_face, default_template,
                      load_face_rig, preset as table_preset, save_face_rig, timeline_for)

SECONDS = 0.4


@pytest.fixture(scope="module")
def rig():
    return build_face(default_template(0))


def motion(rig, timeline, seconds=SECONDS, **kw):
    frames = FaceSimulator(rig, fps=30, **kw).run(timeline, seconds)
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


def test_first_frame_draws_the_rest_fibres(rig):
    """Frame 0 of a run holds the muscles' rest curves (not zeros), for viewers and USD."""
    _, frames = motion(rig, preset("smile"), seconds=2 / 30)
    C = frames.muscle_curves
    head = np.asarray(rig.head_vertices)
    lo, hi = head.min(0) - 0.01, head.max(0) + 0.01
    assert ((C[0] >= lo) & (C[0] <= hi)).all()  # every fibre point of frame 0 lies in the head's box
    assert np.abs(C[1] - C[0]).max() < 0.01  # one frame into the attack: the fibres barely moved


def test_part_points_follow_jaw_and_head_pose(rig):
    """Rigid parts now: the lower teeth turn with the jaw, the upper ones stay; the world frame
    adds the head pose (as surface() does)."""
    sim = FaceSimulator(rig, fps=30)
    rest = sim.part_points()
    sim.set_jaw(0.2)
    sim.set_head_pose(np.eye(3), [0.0, 0.01, 0.0])
    sim.step()
    moved, head = sim.part_points(), sim.part_points(frame="head")
    assert np.abs(head["teeth_lower"] - rest["teeth_lower"]).max() > 5e-3
    np.testing.assert_allclose(head["teeth_upper"], rest["teeth_upper"], atol=1e-12)
    np.testing.assert_allclose(moved["teeth_upper"] - head["teeth_upper"], [[0.0, 0.01, 0.0]] * len(head["teeth_upper"]),
                               atol=1e-9)


@pytest.mark.parametrize("solver, material", [("implicit", "physical"), ("implicit", "thesis"), ("verlet", "thesis")])
def test_smile_raises_lip_corners_outward(rig, solver, material):
    seconds = SECONDS if solver == "implicit" else 0.2  # Verlet: ~2,200 substeps per frame (thesis)
    d, frames = motion(rig, preset("smile"), seconds, solver=solver, material=material)
    assert d["8.3"][1] > 1e-3 and d["8.4"][1] > 1e-3  # up (+y) by more than a millimetre
    assert d["8.3"][0] > 2e-4 and d["8.4"][0] < -2e-4  # outward: left corner +x, right corner -x
    assert frames.frames_per_second > 0 and frames.solver == solver and frames.material == material


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


def _laugh_frames(rig, device, frames=6, **kw):
    """The laugh preset (muscles and jaw) ramped in over ``frames`` frames of the user loop."""
    sim = FaceSimulator(rig, device=device, **kw)
    e = table_preset("laugh")
    for k in range(1, frames + 1):
        sim.set_activations({m: v * k / frames for m, v in e.activations.items()})
        sim.set_jaw(e.jaw_u * k / frames)
        sim.step()
    return sim.positions()


def test_steps_are_deterministic(rig):
    # elements write their own slots and nodes add them in a fixed order (no atomics), and the
    # solver's choices count iterations, not seconds
    a, b = _laugh_frames(rig, "cpu"), _laugh_frames(rig, "cpu")
    assert np.array_equal(a, b)


def test_user_loop_rejects_bad_controls(rig):
    sim = FaceSimulator(rig)
    with pytest.raises(InputError, match="activations"):
        sim.set_activations({"zygomatic_major": float("nan")})
    with pytest.raises(InputError, match="dt"):
        sim.step(0.0)
    with pytest.raises(InputError, match="solver"):
        FaceSimulator(rig, solver="euler")
    with pytest.raises(InputError, match="material"):
        FaceSimulator(rig, material="rubber")


def test_cpu_and_cuda_agree_adaptive(rig):
    from conftest import warp_devices

    if "cuda:0" not in warp_devices():
        pytest.skip("compares a GPU with the CPU")
    # the default device method (adaptive Newton count in a CUDA graph's conditional node) agrees
    # with the CPU's within its convergence tolerance (3e-5 m per iteration)
    x_cpu = _laugh_frames(rig, "cpu", method="newton-pcg")
    x_gpu = _laugh_frames(rig, "cuda:0", method="newton-pcg")
    assert np.linalg.norm(x_cpu - x_gpu, axis=1).max() <= 1e-4


@pytest.mark.parametrize("material", ["physical", "with_shear"])
def test_cpu_and_cuda_agree(rig, material):
    from conftest import warp_devices
    from facewarp.physics import MaterialPhysical

    if "cuda:0" not in warp_devices():
        pytest.skip("compares a GPU with the CPU")
    if material == "with_shear":  # the optional shear term in place of the distance and area energies
        material = MaterialPhysical(distance_modulus=(0.0, 0.0, 0.0), area_modulus=0.0, shear_modulus=3e4)
    # the same solver method on both (newton-pcg, the CUDA default, runs on the CPU too), at a
    # fixed Newton count: the adaptive count may stop one iteration apart on the two (its CG sums
    # use atomics on the GPU), which moves nodes by up to its tolerance
    x_cpu = _laugh_frames(rig, "cpu", method="newton-pcg", iterations=3, material=material)
    x_gpu = _laugh_frames(rig, "cuda:0", method="newton-pcg", iterations=3, material=material)
    moved = np.linalg.norm(x_cpu - rig.nodes, axis=1).max()
    diff = np.linalg.norm(x_cpu - x_gpu, axis=1).max()
    assert moved > 1e-3 and diff <= 1e-4 * moved, (diff, moved)
