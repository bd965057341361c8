"""MuJoCo head model (head.xml): loads, mandible mass, hinge kinematics, position control."""

from __future__ import annotations

import math
import os
import sys

import numpy as np
import pytest

import facewarp as fw
from facewarp.coupling import Z_UP, HeadPose, mandible_geometry, mandible_inertia, scene_mjcf, write_head_mjcf
from facewarp import head_mjcf

if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
    # headless: MuJoCo's offscreen renderer through EGL or OSMesa, where the library is there
    # (MUJOCO_GL is read when mujoco is first imported)
    import ctypes.util

    for _gl, _lib in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(_lib):
            os.environ.setdefault("MUJOCO_GL", _gl)
            break
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
    scene = mujoco.MjModel.from_xml_path(str(tmp_path / "scene.xml"))  # the standalone scene beside it
    np.testing.assert_allclose(scene.opt.gravity, [0, 0, -9.81])
    assert scene.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert "floor" in {scene.geom(i).name for i in range(scene.ngeom)}


def test_mandible_mass_is_a_human_mandible(head, model):
    V, F = mandible_geometry(head)
    inert = mandible_inertia(V, F)
    # a wet adult mandible weighs about 0.1-0.2 kg; its centre lies below and in front of the condyles
    assert 0.05 < inert.mass < 0.3, inert.mass
    assert model.body("mandible").mass[0] == pytest.approx(inert.mass, rel=1e-5)
    jaw = fw.anatomy.JawKinematic.from_landmarks(head.condyles, head.landmarks())
    assert inert.center[1] < jaw.pivot[1] and inert.center[2] > jaw.pivot[2]
    assert np.all(np.linalg.eigvalsh(inert.inertia) > 0)


@pytest.mark.parametrize("angle", [0.05, 0.3])
def test_hinge_moves_the_chin_as_the_kinematic_jaw(head, model, angle):
    d = mujoco.MjData(model)
    d.qpos[0] = angle
    mujoco.mj_kinematics(model, d)
    b = model.body("mandible").id
    jaw = fw.anatomy.JawKinematic.from_landmarks(head.condyles, head.landmarks())
    chin = head.landmarks()["2.1"]
    moved = d.xmat[b].reshape(3, 3) @ (chin - jaw.pivot) + d.xpos[b]  # Z-up world: the head frame turned by Z_UP
    np.testing.assert_allclose(moved, Z_UP @ jaw.apply(chin[None], np.ones(1), angle)[0], atol=1e-9)
    moved = Z_UP.T @ moved
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
    pivot = Z_UP.T @ d.xpos[m.body("cranium").id]  # the neck joint's position (fixed in the world), sim frame
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


def test_thesis_material_with_the_two_way_jaw_is_stable(head, rig, tmp_path, monkeypatch):
    """The thesis profile's skin (0.5 kg nodes, 6e6 N/m holds) threw the mandible off in two
    frames (a 240 N m torque, MuJoCo resetting its state); with the scaled stiff-skin coupling
    every profile couples (issue 23): no MuJoCo warning, the jaw within its range, near closed."""
    monkeypatch.chdir(tmp_path)
    sim = fw.FaceSimulator(rig, material="thesis")
    m = mujoco.MjModel.from_xml_string(head_mjcf(head))
    d = mujoco.MjData(m)
    jaw = fw.MujocoJaw(sim, m, d)
    tl = fw.timeline_for("smile").for_head(rig)
    for k in range(1, 10):
        sim.set_activations(tl.sample(k / 30))
        jaw.step()
        a = jaw.angles()
        assert abs(a[0]) < 0.02 and abs(a[1]) < np.deg2rad(5.0), (k, a)
    assert [w.number for w in d.warning] == [0] * len(d.warning)
    assert not jaw.events
    assert not list(tmp_path.iterdir())  # no MUJOCO_LOG.TXT


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


# ------------------------------------------------------------------------ head.xml on a robot
HOST = """<mujoco model="host">
  <compiler angle="radian"/>
  <option timestep="0.005" gravity="0 0 -3" integrator="RK4"/>
  {assets}
  <worldbody>
    <body name="robot" pos="0 0 1">
      <freejoint/>
      <geom name="skull" type="box" size="0.1 0.1 0.1"/>
      {mount}
    </body>
  </worldbody>
</mujoco>"""


def test_include_leaves_the_hosts_options(head, tmp_path):
    """<include> at the host's top level: the host keeps its gravity, integrator, time step and
    angle unit; a prefixed head beside a host geom named like one of its own compiles."""
    write_head_mjcf(tmp_path / "head.xml", head, prefix="h_")
    host = HOST.format(assets='<include file="head.xml"/>', mount="")
    (tmp_path / "host.xml").write_text(host)
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "host.xml"))
    np.testing.assert_allclose(m.opt.gravity, [0, 0, -3])
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 and m.opt.timestep == 0.005
    assert {"h_cranium", "h_mandible", "robot"} <= {m.body(i).name for i in range(m.nbody)}
    assert m.body("h_cranium").parentid[0] == 0  # included at the top level: in the world
    # with the host's angle="radian" an included head reads its degree ranges as radians: the
    # file says so, and <attach> (below) keeps them right
    assert m.jnt_range[m.joint("h_jaw_open").id][1] == pytest.approx(60.0)


def test_attach_under_a_body_keeps_units_and_options(head, tmp_path):
    write_head_mjcf(tmp_path / "head.xml", head, scene=False)
    host = HOST.format(assets='<asset><model name="head" file="head.xml"/></asset>',
                       mount='<attach model="head" body="cranium" prefix="a_"/>')
    (tmp_path / "host.xml").write_text(host)
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "host.xml"))
    np.testing.assert_allclose(m.opt.gravity, [0, 0, -3])
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    assert m.body("a_cranium").parentid[0] == m.body("robot").id  # mounted on the robot body
    np.testing.assert_allclose(m.jnt_range[m.joint("a_jaw_open").id], [0.0, math.radians(60)], atol=1e-9)
    np.testing.assert_allclose(m.jnt_range[m.joint("a_jaw_side").id], [-math.radians(5), math.radians(5)], atol=1e-9)


def test_spec_attach_two_prefixed_heads(head, rig):
    """MjSpec.attach of two heads (prefixes a_ and b_) onto two bodies of a host compiles, and
    MujocoJaw finds each head by its prefix (and asks for one when there are two)."""
    host = mujoco.MjSpec.from_string(HOST.format(assets="", mount=""))
    for i, p in enumerate(("a_", "b_")):
        body = host.body("robot").add_body(name=f"mount{i}", pos=[0.0, 0.3 * i, 0.2])
        child = mujoco.MjSpec.from_string(head_mjcf(head, prefix=p))
        body.add_frame().attach_body(child.body(p + "cranium"), "robot/", "")
    m = host.compile()
    d = mujoco.MjData(m)
    np.testing.assert_allclose(m.opt.gravity, [0, 0, -3])
    assert {"robot/a_mandible", "robot/b_mandible"} <= {m.body(i).name for i in range(m.nbody)}
    assert m.nu == 4
    sim = fw.FaceSimulator(rig)
    with pytest.raises(fw.InputError, match="prefix"):
        fw.MujocoJaw(sim, m, d)
    cpl = fw.MujocoJaw(sim, m, d, prefix="robot/b_")
    assert cpl.mandible == m.body("robot/b_mandible").id
    np.testing.assert_allclose(cpl.up_rotation, Z_UP)


def _chin_path(head, rig, tmp_path, **kw):
    write_head_mjcf(tmp_path / "head.xml", head, **kw)
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "scene.xml"))
    d = mujoco.MjData(m)
    sim = fw.FaceSimulator(rig)
    cpl = fw.MujocoJaw(sim, m, d)  # the prefix found, up from the scene's gravity
    d.ctrl[m.actuator(kw.get("prefix", "") + "jaw_open").id] = 0.25
    path = []
    for _ in range(15):
        cpl.step()
        path.append(sim.fdp("2.1"))
    return np.array(path), cpl


def test_prefixed_z_up_head_opens_the_jaw_as_the_y_up_head(head, rig, tmp_path):
    (tmp_path / "y").mkdir()
    (tmp_path / "z").mkdir()
    old, cy = _chin_path(head, rig, tmp_path / "y", up="y")
    new, cz = _chin_path(head, rig, tmp_path / "z", prefix="robot1/")
    np.testing.assert_allclose(cy.up_rotation, np.eye(3))
    np.testing.assert_allclose(cz.up_rotation, Z_UP)
    assert cz.prefix == "robot1/"
    assert old[-1, 1] < old[0, 1] - 5e-3  # the chin went down
    assert np.linalg.norm(new - old, axis=1).max() < 0.5e-3, np.linalg.norm(new - old, axis=1).max()


def test_bad_up_and_prefix_are_input_errors(head):
    with pytest.raises(fw.InputError, match="up"):
        head_mjcf(head, up="x")
    with pytest.raises(fw.InputError, match="prefix"):
        head_mjcf(head, prefix='a"b')
    with pytest.raises(fw.InputError, match="up"):
        scene_mjcf(up="-z")


# ------------------------------------------------------------------------ the skin inside MuJoCo
def _skin_model(head, rig, **kw):
    m = mujoco.MjModel.from_xml_string(head_mjcf(head, jaw=rig.jaw, skin=(rig.head_vertices, rig.head_faces), **kw))
    return m, mujoco.MjData(m)


def test_skin_mesh_follows_the_face(head, rig):
    """After a jaw opening, a smile and a turn of the neck, the skin geom's vertices in MuJoCo's
    world are the simulator's head-frame surface on the cranium's head frame (float32 storage)."""
    m, d = _skin_model(head, rig, prefix="h_", neck=True)
    sim = fw.FaceSimulator(rig)
    jaw = fw.MujocoJaw(sim, m, d)
    skin = fw.MujocoSkin(sim, m)
    assert skin.prefix == "h_"
    assert m.geom_group[m.geom("h_skull").id] == 3  # bones hidden under the skin by default
    d.ctrl[m.actuator("h_jaw_open").id] = 0.2
    d.ctrl[m.actuator("h_neck_pan").id] = 0.3
    sim.set_activations({"zygomatic_major": 1.0})
    for _ in range(6):
        jaw.step()
    skin.update()
    mujoco.mj_kinematics(m, d)
    g = m.geom("h_skin").id
    i = skin.mesh_id
    Vm = m.mesh_vert[m.mesh_vertadr[i]: m.mesh_vertadr[i] + m.mesh_vertnum[i]].astype(np.float64)
    world = Vm @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
    site = m.site("h_head_origin").id  # the head frame now (the simulator's pose lags MuJoCo's by the frame's step)
    expected = sim.surface(frame="head") @ d.site_xmat[site].reshape(3, 3).T + d.site_xpos[site]
    moved = np.linalg.norm(sim.surface(frame="head") - rig.head_vertices, axis=1).max()
    assert moved > 5e-3  # the face did move
    np.testing.assert_allclose(world, expected, atol=2e-6)
    np.testing.assert_allclose(skin.vertices(), sim.surface(frame="head"), atol=2e-6)


def test_skin_errors(head, rig):
    m, _ = mujoco.MjModel.from_xml_string(head_mjcf(head)), None
    with pytest.raises(fw.InputError, match="skin"):
        fw.MujocoSkin(fw.FaceSimulator(rig), m)  # no skin mesh in the model
    other = fw.default_template(1)
    m2 = mujoco.MjModel.from_xml_string(head_mjcf(other, skin=(other.vertices, other.faces)))
    with pytest.raises(fw.InputError, match="vertices"):
        fw.MujocoSkin(fw.FaceSimulator(rig), m2)
    with pytest.raises(fw.InputError, match="skin"):
        head_mjcf(head, skin=(rig.head_vertices, rig.head_faces + 10**6))


def test_renderer_shows_the_updated_skin(head, rig):
    """mjr_uploadMesh through MujocoSkin.update(renderer) draws what a renderer made after the
    change draws (its context uploads the model's meshes as they are), and differs from the rest."""
    m, d = _skin_model(head, rig)
    try:
        r = mujoco.Renderer(m, 96, 96)
    except Exception as e:  # no GL here (MUJOCO_GL=egl or osmesa needs libEGL / libOSMesa)
        pytest.skip(f"no offscreen OpenGL: {e}")
    sim = fw.FaceSimulator(rig)
    jaw = fw.MujocoJaw(sim, m, d)
    skin = fw.MujocoSkin(sim, m)
    cam = mujoco.MjvCamera()
    cam.lookat[:] = [0.0, 0.0, -0.04]
    cam.distance, cam.azimuth, cam.elevation = 0.3, 180.0, 0.0  # in front of the face (it looks along +x)
    mujoco.mj_forward(m, d)
    r.update_scene(d, camera=cam)
    rest = r.render().copy()
    d.ctrl[m.actuator("jaw_open").id] = 0.3
    sim.set_activations({"zygomatic_major": 1.0})
    for _ in range(6):
        jaw.step()
    skin.update(r)
    r.update_scene(d, camera=cam)
    moved = r.render().copy()
    fresh = mujoco.Renderer(m, 96, 96)
    fresh.update_scene(d, camera=cam)
    np.testing.assert_array_equal(moved, fresh.render())
    assert np.abs(moved.astype(int) - rest).max() > 50
    assert skin.updates == 1 and skin.update_seconds["upload"] > 0


@pytest.mark.parametrize("gravity, up", [((0, 0, -9.81), (0, 0, 1)), ((0, -9.81, 0), (0, 1, 0)),
                                         ((-3.0, 0, -4.0), (0.6, 0, 0.8)), ((0, 0, 0), (0, 0, 1))])
def test_world_rotation_puts_the_face_up_against_gravity(head, rig, gravity, up):
    m = mujoco.MjModel.from_xml_string(head_mjcf(head))
    m.opt.gravity[:] = gravity
    cpl = fw.MujocoJaw(fw.FaceSimulator(rig), m, mujoco.MjData(m))
    C = cpl.up_rotation
    np.testing.assert_allclose(C.T @ C, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(C[:, 1], up, atol=1e-12)  # the face's up is the world's up
    np.testing.assert_allclose(cpl.to_mujoco(np.eye(3)), C.T, atol=1e-12)


def test_textured_skin_moves_whole_and_shows_the_texture(head, rig, tmp_path):
    """head.xml with the skin's texture: the mesh is split at the UV seams (the face's vertices
    first), MujocoSkin writes every copy with its vertex's position and smooth normal, and an
    unlit render shows, at each visible vertex, the texture's colour at that vertex's own UV."""
    from PIL import Image

    from facewarp.coupling import skin_vertex_split
    from facewarp.geometry import vertex_normals

    uv, face_uv = rig.head_uv, rig.head_face_uv
    assert uv is not None
    tex = np.zeros((64, 64, 3), np.uint8)  # red grows with u, green with v (v up: row 0 is v = 1)
    tex[..., 0] = np.linspace(0, 255, 64)[None, :]
    tex[..., 1] = np.linspace(255, 0, 64)[:, None]
    Image.fromarray(tex).save(tmp_path / "skin.png")
    write_head_mjcf(tmp_path / "head.xml", head, jaw=rig.jaw, skin=(rig.head_vertices, rig.head_faces, uv, face_uv),
                    skin_texture="skin.png")
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "scene.xml"))
    d = mujoco.MjData(m)
    F2, src, uvi = skin_vertex_split(rig.head_faces, face_uv)
    n = len(rig.head_vertices)
    assert len(src) > n and (src[:n] == np.arange(n)).all()
    np.testing.assert_array_equal(src[F2], rig.head_faces)  # the same triangles
    np.testing.assert_array_equal(uvi[F2], face_uv)  # each corner keeps its UV
    sim = fw.FaceSimulator(rig)
    skin = fw.MujocoSkin(sim, m)
    i = skin.mesh_id
    assert m.mesh_vertnum[i] == len(src)
    sl = slice(int(m.mesh_vertadr[i]), int(m.mesh_vertadr[i] + m.mesh_vertnum[i]))
    sim.set_activations({"zygomatic_major": 1.0})
    sim.set_jaw(0.2)
    for _ in range(4):
        sim.step()
    skin.update()
    Vm = m.mesh_vert[sl].astype(np.float64)
    np.testing.assert_array_equal(Vm, Vm[src])  # the seam copies sit on their vertices
    np.testing.assert_allclose(skin.vertices(), sim.surface(frame="head"), atol=2e-6)
    nl = slice(int(m.mesh_normaladr[i]), int(m.mesh_normaladr[i] + m.mesh_normalnum[i]))
    np.testing.assert_allclose(m.mesh_normal[nl], vertex_normals(Vm[:n], rig.head_faces)[src], atol=1e-5)
    try:
        r = mujoco.Renderer(m, 160, 160)
    except Exception as e:
        pytest.skip(f"no offscreen OpenGL: {e}")
    mujoco.mj_forward(m, d)
    mat = m.material("skin").id
    m.mat_emission[mat], m.mat_specular[mat] = 1.0, 0.0
    m.light_active[:] = 0
    m.vis.headlight.active = 0
    r.update_scene(d, camera=0)
    img = r.render().astype(np.float64)
    r.enable_depth_rendering()
    depth = r.render()
    g = m.geom("skin").id
    Vw = Vm @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
    R, c = d.cam_xmat[0].reshape(3, 3), d.cam_xpos[0]
    P = (Vw - c) @ R
    z = -P[:, 2]
    f = 80 / np.tan(np.radians(m.cam_fovy[0]) / 2)
    px, py = np.round(80 + f * P[:, 0] / z - 0.5).astype(int), np.round(80 - f * P[:, 1] / z - 0.5).astype(int)
    ok = (px >= 0) & (px < 160) & (py >= 0) & (py < 160)
    ok[ok] = np.abs(depth[py[ok], px[ok]] - z[ok]) < 1e-3
    assert ok.sum() > 200
    want = np.asarray(uv, np.float64)[uvi[ok]] * 255.0  # red = u, green = v
    got = img[py[ok], px[ok], :2]
    err = np.abs(got - want)
    assert np.median(err) < 8 and np.percentile(err, 90) < 25, (np.median(err), np.percentile(err, 90))
