"""The simulated face: Table 6.4 presets move the FDPs the right way; rest stays at rest.

Run with the default solver (implicit, one step per 30 fps frame) and material (physical); one
test runs the Verlet reference with the thesis profile (the simulator's behaviour before the
implicit solver)."""

from __future__ import annotations

import numpy as np
import pytest

from facewarp import (    Expression,
    FaceSimulator,
    InputError,
    Timeline,
    build_face,
    default_template,
    load_face_rig,
    preset as table_preset,
    save_face_rig,
    timeline_for)
from facewarp.expressions import Segment

SECONDS = 0.4


@pytest.fixture(scope="module")
def rig(default_rig):
    return default_rig


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
    np.testing.assert_array_equal(r2.head_face_uv, rig.head_face_uv)  # the skin's UVs ride along
    assert rig.fixed.any() and rig.held.any() and len(rig.support_nodes) and len(rig.jaw_nodes)
    # the contact geometry is built once and saved with the rig
    g, g2 = rig.contact, r2.contact
    for name in ("node_side", "eye_nodes", "eye_centers", "lid_nodes", "lid_partner", "glide_radii"):
        np.testing.assert_array_equal(getattr(g2, name), getattr(g, name), err_msg=name)
    assert [len(n) for n in g2.lip_nodes] == [len(n) for n in g.lip_nodes] and g2.excluded == g.excluded
    assert [t[0] for t in g2.teeth] == [t[0] for t in g.teeth]
    np.testing.assert_array_equal(g2.teeth[0][4], g.teeth[0][4])


def test_old_face_rig_without_contact_asks_for_a_rebuild(rig, tmp_path):
    p = save_face_rig(tmp_path / "face_rig.npz", rig)
    with np.load(p) as z:
        old = {k: z[k] for k in z.files if not k.startswith("contact_")}
    np.savez(tmp_path / "old.npz", **old)
    with pytest.raises(InputError, match="rebuild it with `facewarp build`") as e:
        load_face_rig(tmp_path / "old.npz")
    assert "\n" not in str(e.value)


@pytest.mark.slow
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


@pytest.mark.slow
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


def _drive(sim, steps=4):
    for k in range(steps):
        sim.set_activations({"zygomatic_major": 0.2 * k, "orbicularis_oris": 0.1 * k, "frontalis_major": 0.15 * k})
        sim.set_jaw(np.deg2rad(4.0 * k))
        sim.step()
    return sim.positions(), sim.state.muscle_ctrl.numpy(), sim.state.jaw_carry.numpy(), sim.fdp_points()


def test_reset_is_a_fresh_simulator(rig):
    # reset() copies the rest State (and zeroes the controls): after any sequence of steps,
    # controls and head poses the next run is bit for bit a fresh simulator's
    used = FaceSimulator(rig)
    used.run(timeline_for("smile"), 0.5)  # the CPU solver refactorises on the way (a later Hessian)
    _drive(used, 6)
    used.set_head_pose(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), np.array([0.0, 0.01, 0.0]))
    used.set_activations({"orbicularis_oculi": 1.0})
    used.step()
    used.reset()
    again, fresh = _drive(used), _drive(FaceSimulator(rig))
    for name, a, b in zip(("positions", "muscle_ctrl", "jaw_carry", "fdp"), again, fresh):
        np.testing.assert_array_equal(a, b, err_msg=name)


def test_two_states_stepped_alternately_equal_one(rig):
    # solver.step(state_in, state_out, control, dt): every per-step array is in the State, so
    # swapping two States step by step gives the same as stepping one State and copying back
    out = []
    for swap in (True, False):
        sim = FaceSimulator(rig)
        a, b = sim.model.state(), sim.model.state()
        for k in range(5):
            sim.control.activations.assign(np.full(len(sim.muscle_names), 0.15 * k, np.float32))
            sim.control.jaw_angles.assign(np.array([np.deg2rad(3.0 * k), 0.0], np.float32))
            sim.solver.step(a, b, sim.control, sim.dt)
            if swap:
                a, b = b, a
            else:
                a.assign(b)
        out.append([x.numpy() for x in (a.positions, a.prev_positions, a.muscle_ctrl, a.jaw_carry)])
    assert np.abs(out[0][0] - rig.nodes).max() > 1e-4, "the controls must move the face"
    for name, x, y in zip(("positions", "prev_positions", "muscle_ctrl", "jaw_carry"), *out):
        np.testing.assert_array_equal(x, y, err_msg=name)


def test_builder_add_face_makes_the_whole_model(rig):
    from facewarp.physics import CONTACT_MODULUS, ModelBuilder

    with pytest.raises(InputError, match="add the tissue first"):
        ModelBuilder().add_muscles(rig.rig)
    b = ModelBuilder()
    b.add_face(rig, material="physical")
    with pytest.raises(InputError, match="one head per builder"):
        b.add_tissue(rig.nodes, rig.tets)
    m = b.finalize("cpu")
    n, M = len(rig.nodes), len(rig.rig.names)
    assert m.head_count == 1 and m.head_node_start.tolist() == [0, n] and m.head_tet_start.tolist() == [0, len(rig.tets)]
    assert m.head_muscle_start.tolist() == [0, M] and m.control().activations.shape == (M,)
    # every material-dependent stiffness is the builder's: physical muscles, supports and contact per sheet area
    area = b.vertex_area
    k = m.muscles.rig.att_stiffness
    per_node = np.bincount(rig.rig.att_node, minlength=n)[rig.rig.att_node]
    np.testing.assert_allclose(k * per_node, b.material.muscle_modulus * area[rig.rig.att_node], rtol=1e-12)
    np.testing.assert_allclose(m.supports.stiffness, b.material.support_modulus * area[rig.support_nodes], rtol=1e-12)
    assert m.contact is not None and m.contact.geometry is rig.contact
    np.testing.assert_array_less(CONTACT_MODULUS * area - 1e-9, m.contact.node_stiffness)
    # the State starts at rest with the muscles' rest control points
    s = m.state()
    np.testing.assert_array_equal(s.muscle_ctrl.numpy(), rig.rig.ctrl_rest.astype(np.float32))
    np.testing.assert_array_equal(s.jaw_carry.numpy(), np.zeros(2, np.float32))
