"""Muscle and jaw stages: kernels against the NumPy reference, incompressibility, rest state."""

from __future__ import annotations

import numpy as np
import pytest

import facewarp
from facewarp.anatomy import JawKinematic
from facewarp.anatomy import bezier_quadratic, ellipsoid_points
from facewarp.coupling import CarryStage, JawStage
from facewarp.physics import (    ModelBuilder,
    MuscleRig,
    MuscleStage,
    SolverVerlet,
    contraction_curve,
    ellipsoid_uv,
    rig_reference,
    segment_frames,
    select_solver)

S2 = np.sqrt(0.5)


def muscle_builder(V, T, layer, rig):
    """A builder of the slab with the muscles of ``rig`` (their control points are State)."""
    b = ModelBuilder(V, T, layer=layer)
    b.add_muscles(rig)
    return b


def slab(n=4, h=0.01):
    """A 2-layer slab of tets (n x n cells, h spacing) with outer layer on top (z = 0)."""
    g = np.stack(np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij"), -1).reshape(-1, 2) * h
    top = np.c_[g, np.zeros(len(g))]
    bot = np.c_[g, np.full(len(g), -h)]
    V = np.concatenate([top, bot])
    m = (n + 1) ** 2
    T = []
    for i in range(n):
        for j in range(n):
            a, b, c, d = i * (n + 1) + j, (i + 1) * (n + 1) + j, (i + 1) * (n + 1) + j + 1, i * (n + 1) + j + 1
            cube = [a, b, c, d, a + m, b + m, c + m, d + m]
            for t in ([0, 1, 3, 4], [1, 2, 3, 6], [1, 3, 4, 6], [3, 4, 6, 7], [1, 4, 5, 6]):
                T.append([cube[k] for k in t])
    T = np.array(T)
    vol = np.einsum("ij,ij->i", V[T[:, 1]] - V[T[:, 0]], np.cross(V[T[:, 2]] - V[T[:, 0]], V[T[:, 3]] - V[T[:, 0]]))
    T[vol < 0] = T[vol < 0][:, [0, 2, 1, 3]]
    layer = np.r_[np.zeros(m, int), np.ones(m, int)]
    return V, T, layer


def ellipsoid_point(center, frame, radii, uv):
    """Points on ellipsoids with frames whose columns are the axes (as segment_frames gives)."""
    return ellipsoid_points(center, np.transpose(frame, (0, 2, 1)), radii, uv)


def small_rig(nodes, node_pos):
    """One linear muscle along +x below the slab and a circular sphincter (4 rational arcs)."""
    r = 0.012
    c = np.array([0.02, 0.02, -0.02])
    lin = np.array([[0.005, 0.02, -0.018], [0.02, 0.021, -0.019], [0.045, 0.02, -0.02]])
    ring = np.array([c + r * np.array([np.cos(a), np.sin(a), 0]) * (1 if k % 2 == 0 else 1 / S2)
                     for k, a in enumerate(np.arange(8) * np.pi / 4)])
    ctrl = np.concatenate([lin, ring])
    rig = MuscleRig(
        names=["linear", "ring"], activation_index=np.array([0, 1]), contraction=np.array([0.3, 0.2]),
        center=np.array([[0, 0, 0], c]), center_jaw=np.zeros(2),
        ctrl_rest=ctrl, ctrl_muscle=np.array([0, 0, 0] + [1] * 8), ctrl_pivot=np.array([2, 2, -2] + [-1] * 8),
        ctrl_jaw=np.zeros(11),
        curve_ctrl=np.array([[0, 1, 2]] + [[3 + 2 * k, 3 + 2 * k + 1, 3 + (2 * k + 2) % 8] for k in range(4)]),
        curve_weight=np.array([[1, 1, 1]] + [[1, S2, 1]] * 4, float),
        seg_curve=np.array([0, 0, 0, 1, 2, 3, 4]),
        seg_t=np.array([[0, 1 / 3], [1 / 3, 2 / 3], [2 / 3, 1], [0, 1], [0, 1], [0, 1], [0, 1]], float),
        seg_rest_radii=np.zeros((7, 3)),
        anchor_ctrl=np.array([3, 0]), anchor_group=np.array([0, 0]), anchor_passive=np.array([0.1, 0.1]),
    )
    c0, f0, r0 = segment_frames(rig, rig.ctrl_rest)
    rig.seg_rest_radii = np.c_[r0[:, 0], np.full(7, 0.003), np.full(7, 0.003)]
    c0, f0, r0 = segment_frames(rig, rig.ctrl_rest)
    seg = np.argmin(np.linalg.norm(node_pos[:, None] - c0[None], axis=-1), axis=1)
    uv = ellipsoid_uv(c0[seg], f0[seg], r0[seg], node_pos)
    pm = ellipsoid_point(c0[seg], f0[seg], r0[seg], uv)
    rig.att_node, rig.att_seg, rig.att_uv = np.asarray(nodes), seg, uv
    rig.att_rest_length = np.linalg.norm(pm - node_pos, axis=1)
    rig.att_stiffness = np.full(len(nodes), 2e3)
    return rig


def test_rational_bezier_ring_is_a_circle():
    V, T, layer = slab()
    rig = small_rig([0], V[:1])
    t = np.linspace(0, 1, 11)
    for k in range(1, 5):
        pts = bezier_quadratic(rig.ctrl_rest[rig.curve_ctrl[k]], t, rig.curve_weight[k])
        np.testing.assert_allclose(np.linalg.norm(pts - rig.center[1], axis=1), 0.012, rtol=1e-12)


def test_kernels_match_reference(device):
    V, T, layer = slab()
    inner = np.where(layer == 1)[0]
    rig = small_rig(inner, V[inner])
    b = muscle_builder(V, T, layer, rig)
    model = b.finalize(device)
    jaw = JawKinematic(np.array([0.02, 0.05, 0.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
                       np.array([[0.03, 0, 0], [0.01, 0, 0]]), np.array([0.02, 0, 0]))
    rig.ctrl_jaw = np.linspace(0, 1, 11)
    rig.saturation = np.array([2.0, 0.5])  # the saturating activation curve, both muscles
    stage = MuscleStage(rig, jaw, model.device)
    control = model.control()
    acts, angles = np.array([0.8, 0.5]), np.array([0.3, 0.05])
    control.activations.assign(acts.astype(np.float32))
    control.jaw_angles.assign(angles.astype(np.float32))
    state = model.state()
    stage.update_geometry(control, state)
    ctrl_ref, _ = rig_reference(rig, acts, jaw, angles)
    np.testing.assert_allclose(state.muscle_ctrl.numpy(), ctrl_ref, atol=2e-6, err_msg="control points")
    c, f, r = segment_frames(rig, ctrl_ref)
    np.testing.assert_allclose(stage.seg_radii.numpy(), r, rtol=1e-4, err_msg="radii")
    np.testing.assert_allclose(stage.seg_center.numpy(), c, atol=2e-6, err_msg="centres")
    # incompressible: every segment keeps its ellipsoid volume
    r_rest = rig.seg_rest_radii
    np.testing.assert_allclose(np.prod(r, 1), np.prod(r_rest, 1), rtol=1e-6)
    assert (r[:3, 0] < r_rest[:3, 0]).all() and (r[:3, 1] > r_rest[:3, 1]).all()


def test_rest_has_no_muscle_force_and_contraction_pulls(device):
    V, T, layer = slab()
    inner = np.where(layer == 1)[0]
    rig = small_rig(inner, V[inner])
    model = muscle_builder(V, T, layer, rig).finalize(device)
    stage = MuscleStage(rig, None, model.device)
    solver = SolverVerlet(model, stages=[stage])
    state, control = model.state(), model.control()
    f = solver.compute_forces(state, control, 1e-4).numpy()
    assert np.abs(f).max() < 1e-3, "muscle springs at rest must be relaxed"
    control.activations.assign(np.array([1.0, 0.0], np.float32))
    f = solver.compute_forces(state, control, 1e-4).numpy()
    # the linear muscle shortens toward its attachment at +x: attached nodes are pulled to +x
    assert f[inner, 0].sum() > 0


def test_jaw_stage_moves_targets(device):
    V, T, layer = slab()
    model = ModelBuilder(V, T, layer=layer, fixed=np.r_[np.zeros(25, bool), np.ones(25, bool)]).finalize(device)
    jaw = JawKinematic(np.array([0.0, 0.0, 0.05]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
                       np.array([[0.03, 0, 0], [0.01, 0, 0]]), np.array([0.02, 0, 0]))
    nodes = np.arange(25, 50)
    stage = JawStage(jaw, nodes, np.ones(25), model.rest_positions, model.device)
    solver = SolverVerlet(model, stages=[stage])
    state, out, control = model.state(), model.state(), model.control()
    control.jaw_angles.assign(np.array([0.2, 0.0], np.float32))
    solver.step(state, out, control, 1e-5)
    np.testing.assert_allclose(out.positions.numpy()[nodes], jaw.apply(V[nodes], np.ones(25), 0.2), atol=1e-6)


def test_carry_stage_moves_nodes_rigidly_without_velocity(device):
    V, T, layer = slab()
    model = ModelBuilder(V, T, layer=layer).finalize(device)
    jaw = JawKinematic(np.array([0.0, 0.0, 0.05]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
                       np.array([[0.03, 0, 0], [0.01, 0, 0]]), np.array([0.02, 0, 0]))
    nodes = np.arange(len(V))
    stage = CarryStage(jaw, nodes, np.ones(len(V)), model.device)
    solver = SolverVerlet(model, stages=[stage])
    state, out, control = model.state(), model.state(), model.control()
    control.jaw_angles.assign(np.array([0.2, 0.03], np.float32))
    f = solver.compute_forces(state, control, 1e-5).numpy()  # carries state in place, then forces
    target = jaw.apply(V, np.ones(len(V)), 0.2, 0.03)
    np.testing.assert_allclose(state.positions.numpy(), target, atol=2e-6)
    np.testing.assert_allclose(state.prev_positions.numpy(), target, atol=2e-6)  # no velocity injected
    assert np.abs(f).max() < 1e-2, "a rigid carry strains nothing"
    solver.step(state, out, control, 1e-5)  # same angles: no further carry, the slab stays put
    np.testing.assert_allclose(out.positions.numpy(), target, atol=2e-6)
    np.testing.assert_array_equal(state.jaw_carry.numpy(), np.array([0.2, 0.03], np.float32))  # the angles the positions are at
    np.testing.assert_array_equal(out.jaw_carry.numpy(), np.array([0.2, 0.03], np.float32))  # handed on to the step's end State


def test_jaw_alone_strains_no_muscle_spring(device):
    # each spring's muscle end turns with its node's jaw amount: a jaw rotation of the whole rig
    # (nodes carried by their amounts, muscles by theirs) leaves the springs at rest length
    V, T, layer = slab()
    inner = np.where(layer == 1)[0]
    rig = small_rig(inner, V[inner])
    rig.ctrl_jaw = np.full(11, 0.5)
    rig.center_jaw = np.full(2, 0.5)
    node_amount = np.linspace(0.2, 0.9, len(V))
    model = muscle_builder(V, T, layer, rig).finalize(device)
    jaw = JawKinematic(np.array([0.02, 0.05, 0.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
                       np.array([[0.03, 0, 0], [0.01, 0, 0]]), np.array([0.02, 0, 0]))
    np.testing.assert_allclose(rig.attachment_jaw(), 0.5)
    stage = MuscleStage(rig, jaw, model.device, node_amount=node_amount)
    solver = SolverVerlet(model, stages=[stage])
    state, control = model.state(), model.control()
    control.jaw_angles.assign(np.array([0.4, 0.0], np.float32))
    X = jaw.apply(V, node_amount, 0.4, 0.0)
    state.positions.assign(X.astype(np.float32))
    state.prev_positions.assign(X.astype(np.float32))
    solver.forces.zero_()
    stage.apply(model, state, control, 1e-5, solver.forces, solver.targets)
    f = np.abs(solver.forces.numpy()).max()
    # without the shift the same pose pulls the nodes hard
    stage0 = MuscleStage(rig, jaw, model.device)
    solver.forces.zero_()
    stage0.apply(model, state, control, 1e-5, solver.forces, solver.targets)
    f0 = np.abs(solver.forces.numpy()).max()
    assert f < 0.02 * f0 and f0 > 1.0, (f, f0)


def contracted_stage(device, activation=0.9):
    """The slab with its inner sheet attached to the small rig, the linear muscle contracted."""
    V, T, layer = slab()
    inner = np.where(layer == 1)[0]
    rig = small_rig(inner, V[inner])
    model = muscle_builder(V, T, layer, rig).finalize(device)
    stage = MuscleStage(rig, None, model.device)
    control = model.control()
    control.activations.assign(np.array([activation, 0.3], np.float32))
    return V, rig, model, stage, control


def test_muscle_force_is_eq_6_4_1(device):
    """Each spring pulls its node with k_m |cos theta| (|p_m - p_s| - l0) toward p_m (Eq. 6.4.1)."""
    V, rig, model, stage, control = contracted_stage(device)
    solver = SolverVerlet(model, stages=[stage])
    state = model.state()
    X = V + np.random.default_rng(3).normal(scale=2e-4, size=V.shape)  # strained: l != l0, theta arbitrary
    state.positions.assign(X.astype(np.float32))
    state.prev_positions.assign(X.astype(np.float32))
    solver.forces.zero_()
    stage.apply(model, state, control, 1e-5, solver.forces, solver.targets)
    F = solver.forces.numpy().astype(np.float64)
    # reference from the stage's own muscle geometry (checked against NumPy in test_kernels_match_reference)
    pm = stage.att_point.numpy().astype(np.float64)
    fibre = stage.seg_frame.numpy().astype(np.float64)[rig.att_seg][:, :, 0]
    d = pm - X.astype(np.float32).astype(np.float64)[rig.att_node]
    length = np.linalg.norm(d, axis=1)
    n = d / length[:, None]
    cos = np.abs(np.einsum("ij,ij->i", n, fibre))
    across = rig.attachment_across() == 1  # a sphincter's springs pull across its fibre: w = 1
    assert across.any() and (~across).any()
    w = np.where(across, 1.0, cos)
    f = (rig.att_stiffness * w * (length - rig.att_rest_length))[:, None] * n
    expect = np.zeros_like(F)
    np.add.at(expect, rig.att_node, f)
    assert np.abs(expect).max() > 1e-2, "the contraction must strain the springs"
    np.testing.assert_allclose(F, expect, atol=1e-4 * np.abs(expect).max(), err_msg="Eq. 6.4.1")
    # a spring along the fibre gets |cos| = 1, one across it 0: spot-check the extremes exist
    assert cos[~across].max() > 0.5 and cos[~across].min() < 0.2


def test_implicit_muscle_energy_gradient_is_the_eq_6_4_1_force(device):
    """At the step's start the muscle springs' energy 1/2 k_m w (l - l0)^2 (w = |cos theta| frozen
    over the step) has exactly the gradient -F of Eq. 6.4.1; away from it, its gradient is the
    finite difference of its energy."""
    V, rig, model, stage, control = contracted_stage(device)
    state = model.state()
    X = V + np.random.default_rng(4).normal(scale=2e-4, size=V.shape)
    state.positions.assign(X.astype(np.float32))
    state.prev_positions.assign(X.astype(np.float32))
    implicit = select_solver(model, stages=[stage])
    verlet = SolverVerlet(model, stages=[stage])
    stage.prepare(model, state, control, 1.0, verlet.targets)
    verlet.forces.zero_()
    stage.apply(model, state, control, 1.0, verlet.forces, verlet.targets)
    F = verlet.forces.numpy().astype(np.float64)
    # the muscle part of the implicit gradient: the potential with and without the muscles
    e1, g1 = implicit.potential(state, control, 1.0, X)
    e0, g0 = select_solver(model).potential(state, control, 1.0, X)
    np.testing.assert_allclose(g1 - g0, -F, atol=2e-3 * np.abs(F).max(), err_msg="muscle gradient != -Eq. 6.4.1")
    # finite differences of the frozen-cosine energy around X (the cosine stays that of X)
    rng = np.random.default_rng(5)
    D = rng.normal(size=V.shape) * 1e-6
    ep, _ = implicit.potential(state, control, 1.0, X + D)
    em, _ = implicit.potential(state, control, 1.0, X - D)
    ep0, _ = select_solver(model).potential(state, control, 1.0, X + D)
    em0, _ = select_solver(model).potential(state, control, 1.0, X - D)
    fd = ((ep - ep0) - (em - em0)) / 2.0
    np.testing.assert_allclose(fd, np.sum((g1 - g0) * D), rtol=2e-2)


def test_contraction_curve_saturates():
    a = np.linspace(0.0, 1.0, 11)
    c = contraction_curve(a, 0.5, 2.0)
    assert c[0] == 0.0 and c[-1] == pytest.approx(0.5)
    np.testing.assert_allclose(c, 0.5 * (1 - np.exp(-2 * a)) / (1 - np.exp(-2.0)), rtol=1e-12)
    assert (np.diff(c, 2) < 0).all(), "saturating: concave"
    assert c[5] == pytest.approx(0.5 * 0.731, rel=1e-3)  # half the activation, 73 % of the contraction
    np.testing.assert_allclose(contraction_curve(a, 0.5, 0.0), 0.5 * a, rtol=1e-12)  # beta 0: linear
    np.testing.assert_allclose(contraction_curve([-1.0, 2.0], 0.5, 2.0), [0.0, 0.5])  # clamped to [0, 1]


def _moved(stage, control, acts, state):
    control.activations.assign(np.asarray(acts, np.float32))
    stage.update_geometry(control, state)
    return state.muscle_ctrl.numpy().astype(np.float64) - stage.rig.ctrl_rest


def test_two_way_anchor(device):
    """Fig. 6.3 two-way: the linear insertion (control point 0) and the ring point 3 it is anchored
    to move by the same displacement, the stiffness-weighted mean of their own ones
    (k = passive + activation): the active member drags the passive one, not a diluted mean."""
    _, rig, model, stage, control = contracted_stage(device)  # _moved sets the activations
    state = model.state()
    lin = np.ones(len(rig.ctrl_rest), bool)
    for acts in ([1.0, 0.0], [0.0, 1.0], [0.6, 0.3]):
        d = _moved(stage, control, acts, state)
        free = rig_reference(rig, acts)[0] - rig.ctrl_rest
        # each member's own displacement, without the anchor
        loose = MuscleRig(**{**rig.__dict__, "anchor_ctrl": np.zeros(0, int), "anchor_group": np.zeros(0, int),
                             "anchor_passive": np.zeros(0)})
        own = rig_reference(loose, acts)[0] - rig.ctrl_rest
        k = 0.1 + np.array([acts[0], acts[1]])  # members: ring point 3 (muscle 1), insertion 0 (muscle 0)
        D = (k[1] * own[3] + k[0] * own[0]) / k.sum()
        np.testing.assert_allclose(d[[0, 3]], [D, D], atol=2e-7, err_msg=f"anchor members, activations {acts}")
        np.testing.assert_allclose(d, free, atol=2e-7, err_msg="kernel against the NumPy reference")
        others = lin.copy()
        others[[0, 3]] = False
        np.testing.assert_allclose(d[others], own[others], atol=2e-7, err_msg="non-members follow their own muscle")
    d = _moved(stage, control, [1.0, 0.0], state)
    assert np.linalg.norm(d[3]) > 0.9 * np.linalg.norm(
        rig_reference(rig, [1.0, 0.0])[0][0] - rig.ctrl_rest[0]) > 1e-3  # the ring point follows (1.1 / 1.2)
    # members keep their rest offset: pulled together, not averaged into one point
    X = state.muscle_ctrl.numpy().astype(np.float64)
    np.testing.assert_allclose(X[3] - X[0], rig.ctrl_rest[3] - rig.ctrl_rest[0], atol=2e-7)


def test_sphincter_to_plane_keeps_fixed_points(device):
    """A ring with two fixed points contracting toward a plane through its centre (the lids
    closing toward the palpebral fissure): the points move along the plane's normal only, by the
    contraction fraction of their distance to it (past it for a fraction above 1)."""
    V, T, layer = slab()
    inner = np.where(layer == 1)[0]
    rig = small_rig(inner, V[inner])
    rig.ctrl_pivot[[3, 7]] = -2  # ring points 0 and 4: fixed
    rig.center_normal = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    model = muscle_builder(V, T, layer, rig).finalize(device)
    control = model.control()
    ring = np.arange(3, 11)
    for c_max in (1.0, 1.6):
        rig.contraction = np.array([0.3, c_max])
        stage = MuscleStage(rig, None, model.device)
        acts = [0.0, 1.0]
        d = _moved(stage, control, acts, model.state())
        X = rig.ctrl_rest + d
        np.testing.assert_allclose(X, rig_reference(rig, acts)[0], atol=2e-7, err_msg="kernel against NumPy")
        np.testing.assert_allclose(d[[3, 7]], 0.0, atol=1e-8, err_msg="fixed points")
        np.testing.assert_allclose(d[ring][:, [0, 2]], 0.0, atol=1e-7, err_msg="along the normal only")
        free = np.setdiff1d(ring, [3, 7])
        y0 = rig.center[1, 1]
        np.testing.assert_allclose(X[free, 1] - y0, (1 - c_max) * (rig.ctrl_rest[free, 1] - y0), atol=2e-7,
                                   err_msg="the fraction c of the way to the plane")


def test_area_weights_split_a_nodes_stiffness():
    """Fig. 6.4 by area: a node's stiffness (shared equally by its attachments when given) is split
    by the attachments' area weights, and a node only partly inside a band keeps that share."""
    V, T, layer = slab()
    rig = small_rig([25, 25, 26], V[[25, 25, 26]])
    rig.att_stiffness = np.array([5.0, 5.0, 10.0])  # node 25: 10 N/m shared by two muscles; node 26: 10
    rig.att_weight = np.array([0.5, 1.0, 0.25])
    rig.validate()
    np.testing.assert_allclose(rig.weighted_stiffness(), [10 * 0.5 / 1.5, 10 * 1.0 / 1.5, 10 * 0.25])
    rig.att_weight = np.array([0.5, 1.2, 0.25])
    with pytest.raises(facewarp.InputError, match="att_weight"):
        rig.validate()


def test_sphincter_glides_over_a_sphere(device):
    """A ring gliding over a rigid part (the lids over the eyeball): each contracting point keeps
    its rest distance from the part's centre; the kernel matches the NumPy reference."""
    V, T, layer = slab()
    inner = np.where(layer == 1)[0]
    rig = small_rig(inner, V[inner])
    g = rig.center[1] + np.array([0.0, 0.0, -0.015])
    rig.glide, rig.glide_center = np.array([0, 1]), np.array([[0.0, 0.0, 0.0], g])
    model = muscle_builder(V, T, layer, rig).finalize(device)
    stage = MuscleStage(rig, None, model.device)
    acts = [0.0, 1.0]
    X = rig.ctrl_rest + _moved(stage, model.control(), acts, model.state())
    np.testing.assert_allclose(X, rig_reference(rig, acts)[0], atol=2e-7, err_msg="kernel against NumPy")
    ring = np.arange(4, 11)  # the ring but point 3, which the anchor ties to the linear insertion
    r = lambda P: np.linalg.norm(P - g, axis=1)  # noqa: E731
    np.testing.assert_allclose(r(X[ring]), r(rig.ctrl_rest[ring]), rtol=1e-5, err_msg="distance from the centre")
    assert np.linalg.norm(X[ring] - rig.ctrl_rest[ring], axis=1).min() > 1e-3  # and yet they moved
