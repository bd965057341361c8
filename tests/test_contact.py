"""Contact (issue 12): one-sided springs in the step's potential and the solvers' kernels, lips
that may touch but not cross, lids outside the eyeball, the build's lip separation.

Small fixtures (one tet, two boxes of Kuhn cubes) except the last test, which plays the laugh
preset on the default head at level 0 for one second.
"""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import grid_tets
from facewarp.anatomy import lip_crossings, separate_lips
from facewarp.geometry import signed_tet_volumes
from facewarp.physics import (ContactStage, ModelBuilder, SolverVerlet, Springs, StepPotential, select_solver,
                              lip_contact_geometry)

CM = 0.01


def one_tet():
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, np.sqrt(3) / 2, 0.0], [0.5, np.sqrt(3) / 6, np.sqrt(2 / 3)]])
    return V * CM, np.array([[0, 1, 2, 3]])


def one_sided_springs(X):
    """On nodes 0..3 at X: two compressed and two slack of each kind (away from the kink)."""
    node = np.arange(4)
    axis = np.array([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
    off = np.array([0.2, -0.3, 0.25, -0.1]) * CM  # (x - p) . a: < 0 compressed, > 0 slack
    p_axis = X[node] - off[:, None] * axis
    centre = X[node] + np.array([[0.1, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, 0.1], [0.1, 0.1, 0.0]]) * CM
    dist = np.linalg.norm(X[node] - centre, axis=1)
    radius = dist + np.array([0.05, -0.05, 0.04, -0.02]) * CM  # radius > distance: inside the ball
    return [(node, centre, np.array([300.0, 500.0, 200.0, 400.0]), radius, None, True),
            (node, p_axis, np.array([250.0, 150.0, 350.0, 450.0]), None, axis, True)]


def _fd(P, data, X, h=1e-8):
    FD = np.zeros_like(X)
    FH = np.zeros((X.size, X.size))
    for k, (a, d) in enumerate(itertools.product(range(len(X)), range(3))):
        Xp, Xm = X.copy(), X.copy()
        Xp[a, d] += h
        Xm[a, d] -= h
        FD[a, d] = (P.energy(Xp, data) - P.energy(Xm, data)) / (2 * h)
        FH[:, k] = (P.gradient(Xp, data)[1] - P.gradient(Xm, data)[1]).ravel() / (2 * h)
    return FD, FH


def test_one_sided_springs_gradient_and_hessian_are_the_finite_differences():
    V, T = one_tet()
    # distance energy only, every edge stretched: its Hessian is exact there
    b = ModelBuilder(V, T, material="physical", k_area=0.0, k_volume=0.0, damping_rate=0.0, stiffness_damping=0.0)
    P = StepPotential(b.finalize("cpu"))
    X = V * 1.1 + np.random.default_rng(0).normal(scale=1e-5, size=V.shape)
    ball, half_space = one_sided_springs(X)
    data = P.begin_step(V, V, 0.01, V, springs=[ball, half_space])
    e, G = P.gradient(X, data)
    FD, FH = _fd(P, data, X)
    np.testing.assert_allclose(G, FD, rtol=1e-5, atol=1e-6 * np.abs(FD).max(), err_msg="gradient")
    # half-space springs: the Hessian is exact (k a a^T compressed, 0 slack)
    data = P.begin_step(V, V, 0.01, V, springs=[half_space])
    H = P.hessian(X, data).toarray()
    _, FH = _fd(P, data, X)
    np.testing.assert_allclose(H, FH, rtol=1e-4, atol=1e-5 * np.abs(FH).max(), err_msg="half-space Hessian")
    # ball springs: exact along the normal; the compressed spring's negative transverse term is
    # dropped (PSD), and a slack one adds nothing
    data = P.begin_step(V, V, 0.01, V, springs=[ball])
    data_none = P.begin_step(V, V, 0.01, V)
    H = P.hessian(X, data).toarray() - P.hessian(X, data_none).toarray()
    _, FH = _fd(P, data, X)
    _, FH0 = _fd(P, data_none, X)
    FH = FH - FH0
    node, c, k, r = ball[:4]
    for i in range(4):
        nrm = (X[i] - c[i]) / np.linalg.norm(X[i] - c[i])
        blk, fblk = H[3 * i:3 * i + 3, 3 * i:3 * i + 3], FH[3 * i:3 * i + 3, 3 * i:3 * i + 3]
        assert nrm @ blk @ nrm == pytest.approx(nrm @ fblk @ nrm, rel=1e-4, abs=1e-6 * k[i]), f"node {i}"
        inside = np.linalg.norm(X[i] - c[i]) < r[i]
        assert (nrm @ blk @ nrm > 0.5 * k[i]) == inside, f"node {i}: compressed {inside}"
    assert np.linalg.eigvalsh(P.hessian(X, data).toarray()).min() > -1e-9 * np.abs(H).max()


class _Springs:
    """A stage with fixed springs (a test double of a contact stage)."""

    def __init__(self, springs):
        self.springs = springs

    def prepare(self, model, state_in, control, dt, targets):
        pass


@pytest.mark.slow
@pytest.mark.parametrize("method", ["lbfgs", "newton-pcg"])
def test_kernels_evaluate_one_sided_springs_like_the_reference(method):
    import warp as wp

    V, T = grid_tets(2, 1, 1)
    model = ModelBuilder(V, T, material="physical").finalize("cpu")
    X = V + np.random.default_rng(2).normal(scale=5e-4, size=V.shape)
    ref = one_sided_springs(X)
    sets = []
    for node, p, k, r, a, _ in ref:
        dev = model.device  # the model's device, not Warp's default (cuda:0 on a GPU machine)
        sets.append(Springs(node=wp.array(node.astype(np.int32), dtype=wp.int32, device=dev),
                            point=wp.array(p.astype(np.float32), dtype=wp.vec3, device=dev),
                            stiffness=wp.array(k.astype(np.float32), dtype=float, device=dev),
                            rest_length=None if r is None else wp.array(r.astype(np.float32), dtype=float, device=dev),
                            axis=None if a is None else wp.array(a.astype(np.float32), dtype=wp.vec3, device=dev),
                            one_sided=True))
    solver = select_solver(model, method=method, stages=[_Springs(tuple(sets))])
    state, control = model.state(), model.control()
    e, G, H = solver.potential(state, control, 0.01, X, hessian=True)
    P = StepPotential(model)
    data = P.begin_step(V, V, 0.01, V, springs=ref)
    X32 = X.astype(np.float32).astype(np.float64)
    e_ref, G_ref = P.gradient(X32, data)
    assert e == pytest.approx(e_ref, rel=1e-4)
    np.testing.assert_allclose(G, G_ref, rtol=2e-3, atol=2e-3 * np.abs(G_ref).max(), err_msg="gradient")
    np.testing.assert_allclose(H.toarray(), P.hessian(X32, data).toarray(), rtol=2e-3, atol=1e-4 * abs(H).max())


def eyeball_case(material="physical"):
    """A 3 x 3 x 1 slab of 1 cm cubes whose middle bottom node sits on an eyeball (r = 1.2 cm)
    below it, the slab's rim fixed, pushed down by 2 N on the middle top node."""
    V, T = grid_tets(3, 3, 1)
    rim = (np.isclose(V[:, 0], 0) | np.isclose(V[:, 0], 3 * CM) | np.isclose(V[:, 1], 0) | np.isclose(V[:, 1], 3 * CM))
    model = ModelBuilder(V, T, fixed=rim, material=material).finalize("cpu")
    mid = np.flatnonzero(~rim & np.isclose(V[:, 2], 0))
    centre = np.array([1.5 * CM, 1.5 * CM, -1.2 * CM - 1e-4])
    return V, model, mid, centre


def _settle(model, stages, f, steps, method="lbfgs"):
    """Node positions [m], shape (p, 3), float64, after ``steps`` implicit steps of 1/30 s under
    the constant external force ``f`` (p, 3) [N], checked for NaN and inverted tets.
    ``"newton-pcg"``: the device method at a fixed 2 Newton x 25 CG iterations (its launches are
    slow on the CPU); ``"newton-pcg-adaptive"``: the device method as by default."""
    opts = dict(iterations=2, linear_iterations=25) if method == "newton-pcg" else {}
    solver = select_solver(model, method=method.removesuffix("-adaptive"), stages=stages, **opts)
    a, b, c = model.state(), model.state(), model.control()
    c.external_force.assign(f)
    for _ in range(steps):
        solver.step(a, b, c, 1 / 30)
        a, b = b, a
    solver.check(a)
    return a.positions.numpy().astype(np.float64)


@pytest.mark.parametrize("method", ["lbfgs", "newton-pcg", "newton-pcg-adaptive"])
def test_a_lid_pushed_into_the_eyeball_is_pushed_out(method):
    """One-sided ball springs (the eyeball's) hold the free bottom nodes outside the ball that
    a downward force drives them into without the springs."""
    import warp as wp

    V, model, mid, centre = eyeball_case()
    top = np.flatnonzero(np.isclose(V[:, 2], CM) & np.isin(np.arange(len(V)), mid + 16))
    f = np.zeros((len(V), 3), np.float32)
    f[top, 2] = -2.0
    r = 1.2 * CM
    depth = {}
    for contact in (False, True):
        stages = []
        if contact:
            dev = model.device
            stages = [_Springs(Springs(node=wp.array(mid.astype(np.int32), dtype=wp.int32, device=dev),
                                       point=wp.array(np.tile(centre, (len(mid), 1)).astype(np.float32), dtype=wp.vec3,
                                                      device=dev),
                                       stiffness=wp.full(len(mid), 2e4, dtype=float, device=dev),
                                       rest_length=wp.full(len(mid), r, dtype=float, device=dev), one_sided=True))]
        X = _settle(model, stages, f, 8 if method == "newton-pcg" else 15, method)
        depth[contact] = float((r - np.linalg.norm(X[mid] - centre, axis=1)).max())
    assert depth[False] > 5e-4, f"the force should drive the slab 0.5 mm into the ball, got {depth[False]:.2e} m"
    assert depth[True] < 1e-4, f"the contact should hold within 0.1 mm, got {depth[True]:.2e} m"


def two_slabs(gap=1e-3):
    """Two 3 x 3 x 1 boxes of 5 mm cubes, one above the other ``gap`` apart: the lower (side -1)
    with its bottom fixed, the upper (side +1) with its top fixed."""
    h = 0.005
    V, T = grid_tets(3, 3, 1, h)
    V2 = V + [0.27 * h, 0.13 * h, h + gap]  # shifted sideways: no node on a face of the other box
    VV = np.concatenate([V, V2])
    TT = np.concatenate([T, T + len(V)])
    side = np.r_[np.full(len(V), -1), np.full(len(V), 1)].astype(np.int8)
    fixed = np.r_[np.isclose(V[:, 2], 0), np.isclose(V2[:, 2], 2 * h + gap)]
    return VV, TT, side, fixed


def test_two_sheets_pressed_together_touch_but_do_not_cross():
    VV, TT, side, fixed = two_slabs()
    model = ModelBuilder(VV, TT, fixed=fixed, material="physical").finalize("cpu")
    upper_bottom = np.flatnonzero((side == 1) & ~fixed)
    f = np.zeros((len(VV), 3), np.float32)
    f[upper_bottom, 2] = -0.4  # 1.6 N down on the upper slab's free sheet
    g = lip_contact_geometry(VV, TT, side, fixed=fixed)
    assert [len(n) for n in g.lip_nodes] == [16, 16] and g.excluded["lip_lip"] == 0

    class Rig:
        nodes = VV

    crossing = {}
    for contact in (False, True):
        stages = [ContactStage(Rig(), np.full(len(VV), 5e4), "cpu", geometry=g)] if contact else []
        X = _settle(model, stages, f, 10)
        crossing[contact] = lip_crossings(X, TT, side)["count"]
        if contact:
            over = upper_bottom[(VV[upper_bottom, :2] < 0.014).all(axis=1)]  # above the lower box
            gap_now = X[over, 2].min() - X[side == -1, 2].max()
            assert -1e-4 < gap_now < 1e-3, f"the sheets should touch (within the contact gap), gap {gap_now:.2e} m"
    assert crossing[False] > 0, "without contact the force should push one sheet through the other"
    assert crossing[True] == 0


def test_crossing_sheets_are_pushed_apart_by_the_verlet_forces():
    """The explicit path: contact forces on nodes of one sheet inside the other point out of it."""
    VV, TT, side, fixed = two_slabs()
    model = ModelBuilder(VV, TT, fixed=fixed, material="physical").finalize("cpu")
    g = lip_contact_geometry(VV, TT, side, fixed=fixed)

    class Rig:
        nodes = VV

    stage = ContactStage(Rig(), np.full(len(VV), 5e4), "cpu", geometry=g)
    solver = SolverVerlet(model, stages=[stage])
    state, control = model.state(), model.control()
    X = VV.copy()
    moved = (side == 1) & ~fixed
    X[moved, 2] -= 1.5e-3  # the upper slab's free sheet 0.5 mm into the lower one
    state.positions.assign(X.astype(np.float32))
    state.prev_positions.assign(X.astype(np.float32))
    F = solver.compute_forces(state, control, 1e-4).numpy()
    solver_plain = SolverVerlet(model)
    F0 = solver_plain.compute_forces(state, control, 1e-4).numpy()
    inside = lip_crossings(X, TT, side)["nodes"]  # each sheet's nodes inside the other box
    up, lo = inside[side[inside] == 1], inside[side[inside] == -1]
    assert len(up) >= 4 and len(lo) >= 4
    dF = F[:, 2] - F0[:, 2]
    assert (dF[up] > 0).all(), "contact forces push the upper sheet up, out of the lower"
    assert (dF[lo] < 0).all(), "and the lower sheet down, out of the upper"


def test_build_separation_moves_crossing_lips_apart_and_keeps_tets_valid():
    VV, TT, side, fixed = two_slabs(gap=-1.5e-3)  # the upper box 1.5 mm into the lower one
    before = lip_crossings(VV, TT, side)["count"]
    assert before >= 8
    X, rep = separate_lips(VV, TT, side, movable=~fixed)
    assert rep["crossing_nodes_before"] == before and rep["crossing_nodes_after"] == 0
    assert rep["moved_nodes"] > 0 and lip_crossings(X, TT, side)["count"] == 0
    assert signed_tet_volumes(X, TT).min() > 0
    np.testing.assert_array_equal(X[fixed], VV[fixed])
    assert rep["max_move_m"] < 3e-3  # minimal: about the overlap and the clearance


@pytest.fixture(scope="module")
def default_rig():
    import facewarp
    from facewarp import build_anatomy
    from facewarp.physics import face_rig_from_anatomy

    an = build_anatomy(facewarp.default_template(0), check_intersections=False)
    return an, face_rig_from_anatomy(an)


@pytest.mark.slow
def test_lips_pushed_into_the_teeth_stay_outside(default_rig):
    """The inner sheet of the lips and cheeks near the teeth, pushed toward the nearest dental
    arch by 6 N a node, crosses into it without contact (6 nodes, 0.27 mm deep on the default
    head; 5 N no longer reaches the teeth since partly attached nodes over bone are held) and
    stays outside with it (a spring of ~3e4 N/m 0.25 mm out holds up to ~7 N)."""
    from facewarp import FaceSimulator
    from facewarp.physics import contact_geometry
    from facewarp.geometry import closest_point

    _, fr = default_rig
    g = contact_geometry(fr)
    nodes = np.concatenate([t[4] for t in g.teeth])
    assert len(nodes) > 20
    TV, TF = fr.parts["teeth_upper"]
    V2, F2 = fr.parts["teeth_lower"]
    TV, TF = np.concatenate([TV, V2]), np.concatenate([TF, F2 + len(TV)])
    cp = closest_point(TV, TF, fr.nodes[nodes])
    f = np.zeros((len(fr.nodes), 3), np.float32)
    f[nodes] = 6.0 * (cp.points - fr.nodes[nodes]) / cp.dist[:, None]
    inside = {}
    for contact in (False, True):
        sim = FaceSimulator(fr, contact=contact)
        # the solver itself (FaceSimulator.step owns the external force: the head pose's loads)
        sim.control.external_force.assign(f)
        a, b = sim.state, sim.scratch
        for _ in range(8):
            sim.solver.step(a, b, sim.control, sim.dt)
            a, b = b, a
        sim.solver.check(a)
        inside[contact] = sim.contact_crossings(a.positions.numpy().astype(np.float64))["lip_teeth"]
    assert inside[False] > 0, "the force should push the lips into the teeth"
    assert inside[True] == 0


def test_laugh_on_the_default_head_has_no_crossings(default_rig):
    from facewarp import FaceSimulator
    from facewarp.expressions import timeline_from_spec

    an, fr = default_rig
    sep = an.quality["lip_separation"]  # what `facewarp build` reports
    assert sep["lip_nodes"] > 0 and sep["crossing_nodes_before"] == 0 and sep["crossing_nodes_after"] == 0
    sim = FaceSimulator(fr)
    assert sim.contact is not None and sim.contact.counts["lip_lip"] > 0
    tl = timeline_from_spec("laugh", 1.0).for_head(fr)
    sim.reset()
    worst = {}
    for k in range(1, 31):
        e = tl.sample(k / 30)
        sim.set_activations(e)
        sim.set_jaw(e.jaw_u, e.jaw_v)
        sim.step()
        if k % 5 == 0:
            for key, v in sim.contact_crossings().items():
                worst[key] = max(worst.get(key, 0), v)
    assert worst["lip_lip"] == 0 and worst["lip_teeth"] == 0, worst
    assert worst["lid_eye_depth_m"] < 1e-4, worst


def two_lids(gap=1.5e-3, h=0.005):
    """Two 3 x 1 x 1 boxes of 5 mm cubes, the lower (side -1) with its bottom fixed, the upper
    (side +1) ``gap`` above it with its top fixed and one box deeper (y): closing, they do not
    run into each other but slide past, as the lids did. Returns the nodes, tets, the fixed
    nodes and the fissure plane between them (point, normal, corners, ring height)."""
    V, T = grid_tets(3, 1, 1, h)
    V2 = V + [0.0, h + 5e-4, h + gap]
    VV, TT = np.concatenate([V, V2]), np.concatenate([T, T + len(V)])
    fixed = np.r_[np.isclose(V[:, 2], 0), np.isclose(V2[:, 2], 2 * h + gap)]
    c = np.array([1.5 * h, h + 2.5e-4, h + 0.5 * gap])
    corners = np.array([[-1e-3, c[1], c[2]], [3 * h + 1e-3, c[1], c[2]]])
    return VV, TT, fixed, (c[None], np.array([[0.0, 0.0, 1.0]]), corners[None], np.array([h]))


@pytest.mark.parametrize("method", ["lbfgs", "newton-pcg"])
def test_lids_closing_past_each_other_stop_at_the_fissure_plane(method):
    """Pushed toward each other by 0.6 N a node, the free sheets of two lids slide 3.5 mm past
    the fissure plane without contact; with it every lid node stays on its side of the plane
    and the two sheets close to it (0.11 mm: the springs' gap / 2, less their compression)."""
    from facewarp.physics import contact_crossings, lid_contact_geometry

    VV, TT, fixed, plane = two_lids()
    g = lid_contact_geometry(VV, *plane, fixed=fixed)
    upper, lower = g.lid_nodes[g.lid_side > 0], g.lid_nodes[g.lid_side < 0]
    assert len(upper) == len(lower) == 8 and g.excluded["lid_lid"] == 0
    model = ModelBuilder(VV, TT, fixed=fixed, material="physical").finalize("cpu")
    f = np.zeros((len(VV), 3), np.float32)
    f[upper, 2], f[lower, 2] = -0.6, 0.6
    rig = SimpleNamespace(nodes=VV, tets=TT, fixed=fixed)
    crossed = {}
    for contact in (False, True):
        stages = [ContactStage(rig, np.full(len(VV), 5e4), "cpu", geometry=g)] if contact else []
        X = _settle(model, stages, f, 8 if method == "newton-pcg" else 12, method)
        crossed[contact] = contact_crossings(rig, X, geometry=g)
        if contact:
            z0 = plane[0][0, 2]
            assert X[upper, 2].min() - z0 < 2.5e-4 and z0 - X[lower, 2].max() < 2.5e-4, "the sheets close to the plane"
    assert crossed[False]["lid_lid"] >= 8 and crossed[False]["lid_lid_depth_m"] > 1e-3, crossed[False]
    assert crossed[True]["lid_lid"] == 0, crossed[True]


def test_a_lid_node_across_the_fissure_plane_is_pushed_back_by_the_verlet_forces():
    from facewarp.physics import lid_contact_geometry

    VV, TT, fixed, plane = two_lids()
    g = lid_contact_geometry(VV, *plane, fixed=fixed)
    model = ModelBuilder(VV, TT, fixed=fixed, material="physical").finalize("cpu")

    class Rig:
        nodes = VV

    stage = ContactStage(Rig(), np.full(len(VV), 5e4), "cpu", geometry=g)
    assert stage.counts["lid_lid"] == 16
    X = VV.copy()
    upper = g.lid_nodes[g.lid_side > 0]
    X[upper, 2] -= 1e-3  # the upper lid's free sheet 0.25 mm across the plane
    state, control = model.state(), model.control()
    state.positions.assign(X.astype(np.float32))
    state.prev_positions.assign(X.astype(np.float32))
    dF = (SolverVerlet(model, stages=[stage]).compute_forces(state, control, 1e-4).numpy()
          - SolverVerlet(model).compute_forces(state, control, 1e-4).numpy())[:, 2]
    z0 = plane[0][0, 2]
    across = g.lid_nodes[g.lid_side * (X[g.lid_nodes, 2] - z0) < 1.25e-4]  # past the springs' plane (gap / 2)
    np.testing.assert_array_equal(np.sort(across), np.sort(upper))
    np.testing.assert_array_less(0.0, dF[upper], err_msg="the upper lid is pushed back up")
    others = np.setdiff1d(np.arange(len(VV)), upper)
    np.testing.assert_array_equal(dF[others], 0.0)


def test_the_default_head_keeps_both_lids_of_each_eye_to_their_side(default_rig):
    """The orbicularis oculi of each eye closes toward a fissure plane; the contact finds the
    lids on both sides of it (none across at rest)."""
    from facewarp.physics import contact_crossings, contact_geometry

    _, fr = default_rig
    g = contact_geometry(fr)
    assert g.lid_planes.shape == (2, 2, 3)
    for j in range(2):
        side = g.lid_side[g.lid_plane == j]
        assert (side > 0).sum() >= 10 and (side < 0).sum() >= 10, np.bincount(side + 1)
    rest = contact_crossings(fr, geometry=g)
    assert rest["lid_lid"] == 0 and rest["lid_lid_depth_m"] == 0.0


@pytest.mark.slow
def test_a_gliding_lid_node_is_held_on_its_sphere_by_the_verlet_forces():
    """The inner lid sheet over the eyeball glides on it: a gliding node lifted off its sphere
    (its rest distance from the centre) is pulled back with the glide stiffness, one pushed in
    is pushed out by that, its one-sided contact and its floor on the sphere (the contact's
    stiffness); a node with contact only is free to lift."""
    from facewarp.physics import ContactGeometry

    V, model, mid, centre = eyeball_case()
    r = 1.2 * CM
    glide = np.array([True, True, False, False])
    g = ContactGeometry(np.zeros(len(V), np.int8), [], [], [], centre[None], np.array([r]), mid,
                        np.zeros(len(mid), np.int64), {}, eye_glide=glide)

    class Rig:
        nodes = V

    k, kg = 5e4, 2e3
    stage = ContactStage(Rig(), np.full(len(V), k), "cpu", geometry=g, glide_stiffness=np.full(len(V), kg))
    assert stage.counts["lid_eye"] == 4 and stage.counts["lid_glide"] == 2
    from facewarp import InputError

    for bad in (np.full(len(V) + 1, kg), np.full(len(V), -kg), np.full(len(V), np.nan)):
        with pytest.raises(InputError, match="glide_stiffness"):
            ContactStage(Rig(), np.full(len(V), k), "cpu", geometry=g, glide_stiffness=bad)
    d0 = np.linalg.norm(V[mid] - centre, axis=1)
    n = (V[mid] - centre) / d0[:, None]
    move = np.array([5e-4, -3e-4, 5e-4, -3e-4])  # out, in, out, in (radially) [m]
    X = V.copy()
    X[mid] += move[:, None] * n
    state, control = model.state(), model.control()
    state.positions.assign(X.astype(np.float32))
    state.prev_positions.assign(X.astype(np.float32))
    dF = (SolverVerlet(model, stages=[stage]).compute_forces(state, control, 1e-4).numpy()
          - SolverVerlet(model).compute_forces(state, control, 1e-4).numpy())
    # reference: -kg s n (gliding, two-sided, s = move), -k min(0, |x - c| - r_c) n (contact;
    # r_c: the rest distance less EYE_REST_SLACK_M 5e-5 m, or r + gap 2.5e-4 m) and, gliding,
    # -k min(0, s + 5e-5) n (the floor: its sphere less EYE_REST_SLACK_M)
    r_c = np.minimum(r + 2.5e-4, d0 - 5e-5)
    f = -(glide * (kg * move + k * np.minimum(move + 5e-5, 0.0)) + k * np.minimum(d0 + move - r_c, 0.0))[:, None] * n
    np.testing.assert_allclose(dF[mid], f, rtol=1e-3, atol=1e-6, err_msg="sphere forces")
    np.testing.assert_array_equal(np.delete(dF, mid, axis=0), 0.0)
    assert (np.einsum("ij,ij->i", dF[mid[:2]], n[:2]) * move[:2] < 0).all()  # back onto the sphere
    assert np.abs(dF[mid[2]]).max() == 0.0  # contact only: lifting off is free


@pytest.mark.slow
def test_the_lids_inner_sheet_over_the_eyeballs_glides_on_them(default_rig):
    """The default head's inner lid sheet over each eyeball has no planar sliding support (a plane
    tangent at rest pushed the closing lid medially and held it off the ball) but glides on the
    eyeball: it is in the contact stage's two-sided sphere springs."""
    from facewarp import FaceSimulator
    from facewarp.physics import contact_geometry

    _, fr = default_rig
    g = contact_geometry(fr)
    nodes = g.eye_nodes[g.eye_glide]
    assert len(nodes) >= 20 and (np.asarray(fr.layer)[nodes] != 0).all(), len(nodes)
    assert not np.isin(nodes, fr.support_nodes).any()
    assert np.bincount(g.eye_of_node[g.eye_glide], minlength=2).min() >= 10  # both eyes
    sim = FaceSimulator(fr)
    assert sim.contact.counts["lid_glide"] == len(nodes)


def test_the_gliding_lids_close_onto_the_eyeball_surface(default_rig):
    """Each gliding inner lid node keeps to its own sphere: through its rest position, centred on
    the line through the eyeball's centre along its fissure plane's normal, and meeting that plane
    where the eyeball's sphere of radius R + gap does (the middle of the fissure: the upper and
    lower lids close at one depth, whatever their depths at rest; 0.4 mm outside and 0.9 mm inside
    the ball on ICT identity 007)."""
    from facewarp.physics import CONTACT_GAP, contact_geometry

    _, fr = default_rig
    g = contact_geometry(fr)
    X = np.asarray(fr.nodes, np.float64)
    mine = np.flatnonzero(g.eye_glide)
    o, R = g.eye_centers[g.eye_of_node[mine]], g.eye_radii[g.eye_of_node[mine]]
    c, rho = g.glide_centers[mine], g.glide_radii[mine]
    np.testing.assert_allclose(np.linalg.norm(X[g.eye_nodes[mine]] - c, axis=1), rho, atol=1e-9, err_msg="through x0")
    checked = 0
    for j, (p, n) in enumerate(g.lid_planes):
        eye = np.argmin(np.linalg.norm(g.eye_centers - p, axis=1))
        on = g.eye_of_node[mine] == eye
        shift = c[on] - o[on]
        np.testing.assert_allclose(shift - np.outer(shift @ n, n), 0.0, atol=1e-12, err_msg="centre on the normal")
        # on the plane: the circle's foot q and radius give |x - o|^2 = |q - o|^2 + rho_c^2
        h = (p - c[on]) @ n
        q = c[on] + np.outer(h, n)
        meet = np.sqrt(np.linalg.norm(q - o[on], axis=1) ** 2 + rho[on] ** 2 - h**2)
        x0 = X[g.eye_nodes[mine][on]]
        tangent = g.lid_tangent[g.lid_plane == j][0]
        middle = (np.abs((x0 - p) @ tangent) < 5e-3) & (np.abs((x0 - p) @ n) > 1e-3)
        assert middle.sum() >= 4, middle.sum()
        np.testing.assert_allclose(meet[middle], R[on][middle] + CONTACT_GAP, atol=1e-7, err_msg="at R + gap")
        checked += middle.sum()
    assert checked >= 8


def test_closing_lid_margins_are_tied_along_the_fissure_by_the_verlet_forces():
    """Lid margins near the fissure plane are drawn toward their partners along the fissure (the
    corner chord, x here): at rest, within reach, nothing; closed to the plane with the upper
    lid shifted 0.4 mm along x, each node is pulled back by its glide stiffness times its half of
    the shift; across the chord and on other nodes, nothing."""
    from facewarp.physics import lid_contact_geometry

    VV, TT, fixed, plane = two_lids()
    g = lid_contact_geometry(VV, *plane, fixed=fixed)
    upper, lower = g.lid_nodes[g.lid_side > 0], g.lid_nodes[g.lid_side < 0]
    np.testing.assert_allclose(g.lid_tangent, np.tile([1.0, 0.0, 0.0], (16, 1)))
    partner = g.lid_nodes[g.lid_partner]
    np.testing.assert_allclose(VV[partner, 0], VV[g.lid_nodes, 0])  # the same place along the fissure
    model = ModelBuilder(VV, TT, fixed=fixed, material="physical").finalize("cpu")
    kg = 2e3

    class Rig:
        nodes = VV

    stage = ContactStage(Rig(), np.full(len(VV), 5e4), "cpu", geometry=g, glide_stiffness=np.full(len(VV), kg))
    assert stage.counts["lid_tie"] == 16

    def forces(X):
        state, control = model.state(), model.control()
        state.positions.assign(X.astype(np.float32))
        state.prev_positions.assign(X.astype(np.float32))
        return (SolverVerlet(model, stages=[stage]).compute_forces(state, control, 1e-4).numpy()
                - SolverVerlet(model).compute_forces(state, control, 1e-4).numpy())

    np.testing.assert_array_equal(forces(VV), 0.0)  # 0.625 mm from their springs: tied, at their rest offset
    X = VV.copy()
    z0 = plane[0][0, 2]
    X[upper, 2] += z0 + 1e-4 - VV[upper, 2]  # both lids 0.1 mm from the plane (touching)
    X[lower, 2] += z0 - 1e-4 - VV[lower, 2]
    X[upper, 0] += 4e-4
    dF = forces(X)
    np.testing.assert_allclose(dF[upper, 0], -kg * 2e-4, rtol=1e-3, err_msg="upper lid pulled back along x")
    np.testing.assert_allclose(dF[lower, 0], kg * 2e-4, rtol=1e-3, err_msg="lower lid drawn along")
    np.testing.assert_allclose(dF[g.lid_nodes][:, 1], 0.0, atol=1e-9)
    others = np.setdiff1d(np.arange(len(VV)), g.lid_nodes)
    np.testing.assert_array_equal(dF[others], 0.0)
