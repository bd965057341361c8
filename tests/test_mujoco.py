"""MuJoCo head model (head.xml): loads, mandible mass, hinge kinematics, position control."""

from __future__ import annotations

import math

import numpy as np
import pytest

import facewarp as fw
from facewarp.coupling import HeadPose, head_mjcf, mandible_geometry, mandible_inertia, write_head_mjcf

mujoco = pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def head():
    return fw.default_template(0)


@pytest.fixture(scope="module")
def model(head):
    return mujoco.MjModel.from_xml_string(head_mjcf(head))


def test_head_xml_loads_from_file(head, tmp_path):
    p = write_head_mjcf(tmp_path / "head.xml", head)
    m = mujoco.MjModel.from_xml_path(str(p))
    names = {m.body(i).name for i in range(m.nbody)}
    assert {"cranium", "mandible"} <= names
    assert {m.joint(i).name for i in range(m.njnt)} == {"jaw_open", "jaw_side"}
    assert m.nu == 2
    assert not [q for q in tmp_path.iterdir() if q.name.startswith(".")]


def test_mandible_mass_is_a_human_mandible(head, model):
    V, F = mandible_geometry(head)
    inert = mandible_inertia(V, F)
    # a wet adult mandible weighs about 0.1-0.2 kg; its centre lies below and in front of the condyles
    assert 0.05 < inert.mass < 0.3, inert.mass
    assert model.body("mandible").mass[0] == pytest.approx(inert.mass, rel=1e-5)
    jaw = fw.JawKinematic.from_landmarks(head.condyles, head.landmarks())
    assert inert.center[1] < jaw.pivot[1] and inert.center[2] > jaw.pivot[2]
    assert np.all(np.linalg.eigvalsh(inert.inertia) > 0)


@pytest.mark.parametrize("angle", [0.05, 0.3])
def test_hinge_moves_the_chin_as_the_kinematic_jaw(head, model, angle):
    d = mujoco.MjData(model)
    d.qpos[0] = angle
    mujoco.mj_kinematics(model, d)
    b = model.body("mandible").id
    jaw = fw.JawKinematic.from_landmarks(head.condyles, head.landmarks())
    chin = head.landmarks()["2.1"]
    moved = d.xmat[b].reshape(3, 3) @ (chin - jaw.pivot) + d.xpos[b]
    np.testing.assert_allclose(moved, jaw.apply(chin[None], np.ones(1), angle)[0], atol=1e-9)
    assert moved[1] < chin[1] and moved[2] < chin[2]  # down and back


def test_position_actuator_reaches_target(model):
    d = mujoco.MjData(model)
    d.ctrl[0] = 0.25
    for _ in range(1500):
        mujoco.mj_step(model, d)
    assert abs(d.qpos[0] - 0.25) < math.radians(1.0)
    assert abs(d.qvel[0]) < 1e-3


def test_neck_scene_has_pan_and_tilt(head):
    m = mujoco.MjModel.from_xml_string(head_mjcf(head, neck=True))
    assert {m.joint(i).name for i in range(m.njnt)} == {"neck_pan", "neck_tilt", "jaw_open", "jaw_side"}
    d = mujoco.MjData(m)
    d.ctrl[m.actuator("neck_pan").id] = 0.4
    for _ in range(1500):
        mujoco.mj_step(m, d)
    assert abs(d.qpos[m.joint("neck_pan").qposadr[0]] - 0.4) < math.radians(2.0)


def test_head_frame_on_a_neck_is_the_template_frame(head, rig):
    """On a neck the cranium body's frame sits at the neck pivot; the coupler hands the skin the
    head_origin site's pose, which is the identity at zero neck angles and turns about the pivot."""
    m = mujoco.MjModel.from_xml_string(head_mjcf(head, neck=True))
    d = mujoco.MjData(m)
    coupler = fw.MujocoJaw(fw.FaceSimulator(rig), m, d)
    mujoco.mj_kinematics(m, d)
    R, t = coupler.head_pose()
    np.testing.assert_allclose(R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(t, 0.0, atol=1e-12)
    d.qpos[m.joint("neck_tilt").qposadr[0]] = 0.3
    mujoco.mj_kinematics(m, d)
    R, t = coupler.head_pose()
    pivot = d.xpos[m.body("cranium").id]  # the neck joint's position (fixed in the world)
    np.testing.assert_allclose(R @ pivot + t, pivot, atol=1e-9)  # a rotation about the pivot
    assert math.isclose(math.degrees(math.acos((np.trace(R) - 1) / 2)), math.degrees(0.3), abs_tol=1e-6)


def test_bad_gains_are_input_errors(head):
    with pytest.raises(fw.InputError, match="kp"):
        head_mjcf(head, kp=float("nan"))


def test_head_pose_inertial_forces():
    hp = HeadPose(gravity=False)
    X = np.array([[0.0, 0.0, 0.1], [0.05, 0.0, 0.0]])
    m = np.ones(2)
    h = 1 / 30
    # constant velocity: no force
    for k in range(3):
        hp.set(np.eye(3), np.array([0.01 * k, 0, 0]))
        hp.advance()
    hp.set(np.eye(3), np.array([0.03, 0, 0]))
    np.testing.assert_allclose(hp.node_forces(X, m, h), 0.0, atol=1e-9)
    # constant acceleration a: force -m a
    hp.reset()
    a = 2.0
    for k in range(3):
        hp.set(np.eye(3), np.array([0.5 * a * (k * h) ** 2, 0, 0]))
        hp.advance()
    hp.set(np.eye(3), np.array([0.5 * a * (3 * h) ** 2, 0, 0]))
    np.testing.assert_allclose(hp.node_forces(X, m, h), [[-a, 0, 0], [-a, 0, 0]], atol=1e-9)
    # tilting the head by 90 deg about z turns gravity: change = R^T g - g
    hp = HeadPose(gravity=True)
    R = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    hp._hist = [(R, np.zeros(3))] * 2
    hp.set(R, np.zeros(3))
    f = hp.node_forces(X[:1], m[:1], h)[0]
    np.testing.assert_allclose(f, R.T @ [0, -9.81, 0] - np.array([0, -9.81, 0]), atol=1e-9)
    with pytest.raises(fw.InputError, match="rotation"):
        hp.set(np.eye(3) * 2, np.zeros(3))


# ------------------------------------------------------------------------ skin coupled to MuJoCo
@pytest.fixture(scope="module")
def rig(head):
    return fw.build_face(head)


def _coupled(head, rig, **kw):
    sim = fw.FaceSimulator(rig)
    m = mujoco.MjModel.from_xml_string(head_mjcf(head, **kw))
    d = mujoco.MjData(m)
    return sim, m, d, fw.MujocoJaw(sim, m, d)


def test_thesis_material_with_the_two_way_jaw_is_refused(head, rig):
    """The thesis profile's skin (0.5 kg nodes, 6e6 N/m holds) threw the mandible off in two
    frames (a 240 N m torque): refused in one line; one-way coupling stays allowed."""
    sim = fw.FaceSimulator(rig, material="thesis")
    m = mujoco.MjModel.from_xml_string(head_mjcf(head))
    d = mujoco.MjData(m)
    with pytest.raises(fw.InputError, match="kinematic jaw") as e:
        fw.MujocoJaw(sim, m, d)
    assert "\n" not in str(e.value)
    fw.MujocoJaw(sim, m, d, two_way=False)


def test_skin_resists_a_constant_torque(head, rig):
    """Under the same constant torque the jaw opens less with the skin attached."""
    torque = 0.5  # N m about the opening hinge
    opened = {}
    for skin in (False, True):
        sim, m, d, cpl = _coupled(head, rig, kp=0.0)
        b = m.body("mandible").id
        u = np.asarray(rig.jaw_u)
        for _ in range(30):  # 1 s
            d.xfrc_applied[b, 3:] = torque * u
            if skin:
                cpl.step()
            else:
                for _ in range(round(1 / 30 / m.opt.timestep)):
                    d.xfrc_applied[b, 3:] = torque * u
                    mujoco.mj_step(m, d)
        opened[skin] = float(d.qpos[0])
    assert 0.0 < opened[True] < opened[False] - math.radians(2.0), opened


def test_position_target_reached_with_skin(head, rig):
    sim, m, d, cpl = _coupled(head, rig)
    chin0 = sim.fdp("2.1").copy()
    d.ctrl[0] = 0.25
    for _ in range(30):
        cpl.step()
    assert abs(d.qpos[0] - 0.25) < math.radians(1.0), d.qpos[0]
    assert cpl.torque[0] < 0.0  # the skin pulls the jaw closed
    chin = sim.fdp("2.1")
    assert chin[1] < chin0[1] - 5e-3 and chin[2] < chin0[2] - 5e-3  # down and back
    cpl.detach()
    assert m.jnt_stiffness[0] == 0.0 and d.qfrc_applied[0] == 0.0


def test_mujoco_and_kinematic_jaw_agree_at_small_angles(head, rig):
    sim, m, d, cpl = _coupled(head, rig)
    d.ctrl[0] = math.radians(5.0)
    for _ in range(20):
        cpl.step()
    angle = float(d.qpos[0])
    kin = fw.FaceSimulator(rig)
    kin.set_jaw(angle)
    kin.advance(3)
    assert np.linalg.norm(sim.fdp("2.1") - kin.fdp("2.1")) < 0.5e-3


def test_head_moving_at_constant_velocity_leaves_face_undeformed(rig):
    sim = fw.FaceSimulator(rig)
    rest = sim.positions()
    v = np.array([0.3, -0.1, 0.2])  # m/s
    for k in range(1, 11):
        sim.set_head_pose(np.eye(3), v * k / sim.fps)
        sim.step()
    assert np.abs(sim.positions() - rest).max() < 1e-4
    np.testing.assert_allclose(sim.fdp("2.1"), sim.fdp_points()[list(map(str, rig.fdp_ids)).index("2.1")])
    # world frame: the chin moved with the head
    sim2 = fw.FaceSimulator(rig)
    np.testing.assert_allclose(sim.fdp("2.1") - sim2.fdp("2.1"), v * 10 / sim.fps, atol=1e-4)


def test_accelerating_head_deforms_the_face(rig):
    sim = fw.FaceSimulator(rig)
    rest = sim.positions()
    for k in range(1, 11):  # 5 m/s^2 forward
        sim.set_head_pose(np.eye(3), np.array([0.0, 0.0, 0.5 * 5.0 * (k / sim.fps) ** 2]))
        sim.step()
    assert np.abs(sim.positions() - rest).max() > 1e-5
    with pytest.raises(fw.InputError, match="rotation"):
        sim.set_head_pose(np.ones((3, 3)), np.zeros(3))
