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
