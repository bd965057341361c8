"""Tests of the tissue model, its kernels and the Verlet reference solver (thesis Sec. 6.4, Table 6.3).

Every force is checked against the finite-difference gradient of a float64 NumPy energy
written here from the thesis equations (independent of the kernels); the solver is checked
for rest, rigid-motion invariance, damping, fixed / held nodes and the NaN / inversion guard.
Runs on every device of the ``device`` fixture (CPU always, CUDA when present).
"""

from __future__ import annotations


import numpy as np
import pytest
import warp as wp

from conftest import grid_tets
from facewarp import InputError, SimulationError
from facewarp.geometry import signed_tet_volumes as signed_volumes
from facewarp.physics import (DT_STABLE_1CM, EDGE_CROSS, EDGE_INNER, EDGE_OUTER, MaterialPhysical, ModelBuilder,
                              SolverVerlet, node_stable_dt, scale_masses, simulate, stable_dt, thesis_substep)

CM = 0.01


# ----------------------------------------------------------------------------------------
# fixtures: tiny analytic meshes


def one_tet(edge: float = CM) -> tuple[np.ndarray, np.ndarray]:
    """A regular tet with edge length ``edge`` [m], positively oriented."""
    V = np.array(
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, np.sqrt(3) / 2, 0.0], [0.5, np.sqrt(3) / 6, np.sqrt(2 / 3)]]
    )
    return V * edge, np.array([[0, 1, 2, 3]])




def slab_layers(V: np.ndarray) -> np.ndarray:
    """0 (outer) on the top face of a grid, 1 (inner) below."""
    return np.where(np.isclose(V[:, 2], V[:, 2].max()), 0, 1)


# ----------------------------------------------------------------------------------------
# NumPy oracle (float64), straight from the thesis equations


def oracle_energy(b: ModelBuilder, X: np.ndarray) -> float:
    """Total internal energy [J] of positions X (n, 3) for builder b.

    Distance: Eq. 6.4.4 with k = (1 + C^2) k0 (Eq. 6.4.6) applied as F = -k C dC/dx, whose
    potential is k0 (C^2/2 + C^4/4); area Eq. 6.4.7; volume Eq. 6.4.8; hold springs
    1/2 k_hold |x - x_rest|^2.
    """
    X = np.asarray(X, dtype=np.float64)
    e = 0.0
    i, j = b.edges.T
    c = np.linalg.norm(X[i] - X[j], axis=1) / b.edge_rest_lengths - 1.0
    e += np.sum(b.edge_k0 * (c**2 / 2 + c**4 / 4))
    f = b.faces
    area = 0.5 * np.linalg.norm(np.cross(X[f[:, 1]] - X[f[:, 0]], X[f[:, 2]] - X[f[:, 0]]), axis=1)
    c = area / b.face_rest_areas - 1.0
    e += 0.5 * np.sum(b.face_k * c**2)
    c = signed_volumes(X, b.tets) / b.tet_rest_volumes - 1.0
    e += 0.5 * np.sum(b.tet_k * c**2)
    # the shear term (physical profile, shear_modulus mu): mu V0 |G|^2, G = (F^T F - I) / 2, F = D_s D_m^-1
    R = b.vertices.astype(np.float32).astype(np.float64)
    for t, (i0, i1, i2, i3) in enumerate(b.tets):
        if b.tet_shear_k[t] > 0.0:
            Dm = np.column_stack([R[i1] - R[i0], R[i2] - R[i0], R[i3] - R[i0]])
            F = np.column_stack([X[i1] - X[i0], X[i2] - X[i0], X[i3] - X[i0]]) @ np.linalg.inv(Dm)
            G = 0.5 * (F.T @ F - np.eye(3))
            e += 0.5 * b.tet_shear_k[t] * np.sum(G * G)
    e += 0.5 * np.sum(b.hold_stiffness * np.sum((X - b.vertices) ** 2, axis=1))
    return float(e)


def oracle_gradient(b: ModelBuilder, X: np.ndarray, h: float = 1e-7) -> np.ndarray:
    """Central finite-difference gradient of :func:`oracle_energy`, shape (n, 3)."""
    X = np.asarray(X, dtype=np.float64)
    G = np.zeros_like(X)
    for a in range(X.shape[0]):
        for d in range(3):
            Xp = X.copy()
            Xm = X.copy()
            Xp[a, d] += h
            Xm[a, d] -= h
            G[a, d] = (oracle_energy(b, Xp) - oracle_energy(b, Xm)) / (2 * h)
    return G


def set_state(state, X, X_prev=None):
    state.positions.assign(np.asarray(X, dtype=np.float32))
    state.prev_positions.assign(np.asarray(X if X_prev is None else X_prev, dtype=np.float32))


def kernel_forces(b: ModelBuilder, device, X, X_prev=None, dt=1e-3) -> np.ndarray:
    model = b.finalize(device)
    state = model.state()
    set_state(state, X, X_prev)
    solver = SolverVerlet(model)
    return solver.compute_forces(state, model.control(), dt).numpy().astype(np.float64)


def perturbed(V, rel: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d0 = np.linalg.norm(V[1] - V[0])
    return V + rng.normal(scale=rel * d0, size=V.shape)


# ----------------------------------------------------------------------------------------
# builder


def test_builder_derives_elements_and_table_6_3_defaults():
    V, T = one_tet()
    b = ModelBuilder(V, T, layer=[0, 0, 1, 1])
    assert b.edges.shape == (6, 2) and b.faces.shape == (4, 3)
    np.testing.assert_allclose(b.edge_rest_lengths, CM, rtol=1e-7)
    np.testing.assert_allclose(b.face_rest_areas, np.sqrt(3) / 4 * CM**2, rtol=1e-6)
    np.testing.assert_allclose(b.tet_rest_volumes, CM**3 / (6 * np.sqrt(2)), rtol=1e-6)
    cls = {tuple(e): c for e, c in zip(b.edges.tolist(), b.edge_class)}
    assert cls[(0, 1)] == EDGE_OUTER and cls[(2, 3)] == EDGE_INNER and cls[(0, 2)] == EDGE_CROSS
    k0 = {tuple(e): k for e, k in zip(b.edges.tolist(), b.edge_k0)}
    assert (k0[(0, 1)], k0[(2, 3)], k0[(1, 3)]) == (15.0, 10.0, 5.0)
    assert (b.face_k == 7.5).all() and (b.tet_k == 7.5).all()
    # Table 6.3's 0.002 per substep, as a rate over the thesis profile's Verlet substep
    assert b.damping_rate == pytest.approx(0.002 / thesis_substep(CM, 0.5, 15.0))
    assert ModelBuilder(V, T, substep=1e-4).damping_rate == pytest.approx(20.0)
    np.testing.assert_array_equal(b.mass, 0.5)


def test_builder_shares_edges_and_faces_between_tets():
    V, T = grid_tets(1, 1, 1)
    b = ModelBuilder(V, T)
    # a Kuhn cube: 12 cube edges + 6 face diagonals + 1 body diagonal; 12 boundary + 6 inner faces
    assert len(b.edges) == 19 and len(b.faces) == 18
    np.testing.assert_allclose(b.tet_rest_volumes.sum(), CM**3, rtol=1e-6)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(vertices=np.zeros((4, 2)), tets=[[0, 1, 2, 3]]), r"vertices must have shape \(n, 3\)"),
        (dict(tets=[[0, 1, 2]]), r"tets must have shape \(k, 4\)"),
        (dict(tets=[[0, 1, 2, 4]]), r"tet 0 indexes vertices \[0, 1, 2, 4\]"),
        (dict(tets=[[0, 1, 1, 3]]), r"tet 0 repeats a vertex"),
        (dict(tets=[[0, 1, 2, 3], [0, 2, 1, 3]]), r"tet 1 \[0, 2, 1, 3\] is inverted"),
        (dict(layer=[0, 1, 2, 0]), r"layer must be 0 \(outer\) or 1 \(inner\)"),
        (dict(fixed=[True, False]), r"fixed must have shape \(4,\)"),
        (dict(damping_rate=-1.0), r"damping_rate must be a finite value >= 0"),
        (dict(mass=-1.0), r"mass must be positive"),
        (dict(k0_outer=0.0, k0_inner=0.0, k0_cross=0.0, k_area=0.0, k_volume=0.0), r"no stiffness"),
        (dict(material="rubber"), r"material: expected one of"),
    ],
)
def test_builder_rejects_bad_input(kwargs, match):
    V, T = one_tet()
    args = dict(vertices=V, tets=T)
    args.update(kwargs)
    with pytest.raises(InputError, match=match):
        ModelBuilder(args.pop("vertices"), args.pop("tets"), **args)


def test_builder_rejects_degenerate_tet():
    V, T = one_tet()
    V[3, 2] = 0.0
    with pytest.raises(InputError, match=r"tet 0 .* degenerate"):
        ModelBuilder(V, T)


def test_finalize_model_state_control(device):
    V, T = grid_tets(2, 1, 1)
    model = ModelBuilder(V, T, layer=slab_layers(V), muscle_count=14).finalize(device)
    assert model.vertex_count == len(V) and model.tet_count == len(T)
    np.testing.assert_allclose(model.rest_positions.numpy(), V, atol=1e-9)
    state = model.state()
    np.testing.assert_array_equal(state.positions.numpy(), state.prev_positions.numpy())
    control = model.control()
    assert control.activations.shape == (14,) and control.jaw_angles.shape == (2,)
    assert control.external_force.shape == (len(V),)
    with pytest.raises(Exception):
        model.damping_rate = 1.0  # frozen


# ----------------------------------------------------------------------------------------
# forces = -gradient of the energies (Eq. 6.4.2-6.4.8)


TERMS = {
    "distance": dict(k_area=0.0, k_volume=0.0),
    "area": dict(k0_outer=0.0, k0_inner=0.0, k0_cross=0.0, k_volume=0.0),
    "volume": dict(k0_outer=0.0, k0_inner=0.0, k0_cross=0.0, k_area=0.0),
    "all": dict(),
    "shear": dict(material=MaterialPhysical(distance_modulus=(0.0, 0.0, 0.0), area_modulus=0.0, volume_modulus=0.0,
                                            shear_modulus=1e6)),
    "physical_with_shear": dict(material=MaterialPhysical(distance_modulus=(3e6, 2e6, 1e6), area_modulus=1.5e6,
                                                          volume_modulus=1.5e6, shear_modulus=3e6)),
}


@pytest.mark.parametrize("term", list(TERMS))
@pytest.mark.parametrize("seed", [0, 1])
def test_force_is_negative_energy_gradient(device, term, seed):
    V, T = one_tet()
    b = ModelBuilder(V, T, layer=[0, 0, 1, 1], **TERMS[term])
    X = perturbed(V, 0.15, seed)  # strains of ~10-30 %: the nonlinear stiffness matters
    assert signed_volumes(X, T)[0] > 0
    F = kernel_forces(b, device, X.astype(np.float32).astype(np.float64))
    G = oracle_gradient(b, X.astype(np.float32).astype(np.float64))
    scale = np.abs(G).max()
    assert scale > 1.0, "perturbation too small to test anything"
    np.testing.assert_allclose(F, -G, rtol=1e-3, atol=2e-4 * scale, err_msg=f"{term} force != -dE/dx")


def test_force_gradient_on_shared_elements(device):
    # a 2-cube slab with mixed layers: edges and faces shared between tets accumulate
    V, T = grid_tets(2, 1, 1)
    b = ModelBuilder(V, T, layer=slab_layers(V))
    X = perturbed(V, 0.05, 3)
    X = X.astype(np.float32).astype(np.float64)
    assert (signed_volumes(X, T) > 0).all()
    F = kernel_forces(b, device, X)
    G = oracle_gradient(b, X)
    np.testing.assert_allclose(F, -G, rtol=1e-3, atol=2e-4 * np.abs(G).max(), err_msg="mesh force != -dE/dx")


def test_edge_damping_opposes_stretch_rate(device):
    # Eq. 6.4.5 per spring: two nodes separating along their edge are pulled together by c v
    V, T = one_tet()
    c, dt = 3.0, 1e-3
    b = ModelBuilder(V, T, edge_damping=c, k0_outer=1e-9, k0_inner=0.0, k0_cross=0.0, k_area=0.0, k_volume=0.0)
    prev = V.copy()
    prev[1, 0] -= 1e-5  # node 1 moves +x at 1 cm/s, along edge (0, 1)
    F = kernel_forces(b, device, V, prev, dt=dt)
    v = 1e-5 / dt
    expect = np.zeros_like(V)
    # edge (0,1): relative velocity v along x -> -c v x on node 1, +c v x on node 0
    expect[1] += [-c * v, 0, 0]
    expect[0] += [c * v, 0, 0]
    # edges (1,2) and (1,3): component of the velocity along each unit edge
    for k in (2, 3):
        n = (V[1] - V[k]) / np.linalg.norm(V[1] - V[k])
        f = -c * v * n[0] * n
        expect[1] += f
        expect[k] -= f
    np.testing.assert_allclose(F, expect, atol=1e-4 * c * v, err_msg="edge dashpot")


# ----------------------------------------------------------------------------------------
# invariances


def random_rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return q if np.linalg.det(q) > 0 else -q


def test_rigid_motion_produces_no_internal_force(device):
    V, T = grid_tets(2, 2, 1)
    b = ModelBuilder(V, T, layer=slab_layers(V), edge_damping=5.0)
    R = random_rotation(7)
    X = V @ R.T + np.array([0.03, -0.02, 0.05])
    F = kernel_forces(b, device, X)
    # one unit of strain on a 1 cm edge gives k0 / D0 = 1500 N; float32 leaves ~1e-7 strain
    np.testing.assert_allclose(F, 0.0, atol=1e-5 * 15.0 / CM, err_msg="rotated rest state has internal forces")
    # a rigid translation velocity is not damped by the edge dashpots either
    F = kernel_forces(b, device, X, X - np.array([1e-4, 2e-4, -1e-4]))
    np.testing.assert_allclose(F, 0.0, atol=1e-5 * 15.0 / CM, err_msg="translating body has internal forces")


def test_shear_term_is_rigid_motion_invariant_and_damps_its_strain_rate(device):
    V, T = grid_tets(2, 1, 1)
    b = ModelBuilder(V, T, layer=slab_layers(V), material=MaterialPhysical(
        distance_modulus=(0.0, 0.0, 0.0), area_modulus=0.0, volume_modulus=0.0, shear_modulus=1e5,
        stiffness_damping=1e-3))
    R = random_rotation(3)
    X = V @ R.T + np.array([0.01, 0.02, -0.03])
    dt = 1e-3
    # rotated rest state, moving rigidly (translation plus a small rotation per step): no force
    R2 = random_rotation(4)
    w = 1e-4 * (R2 - R2.T)
    prev = (X - 0.01) @ (np.eye(3) - w).T + 0.01 - np.array([1e-5, 0.0, 2e-5])
    F = kernel_forces(b, device, X, prev, dt=dt)
    k_s = b.tet_shear_k.max()
    assert np.abs(F).max() < 1e-4 * k_s / CM
    # a pure stretch rate: the dashpot beta k_s dG/dt equals the finite difference of the elastic force
    S = np.diag([1.0, -0.5, 0.3]) * 1e-3
    X = V
    prev = V - V @ S.T  # velocity (S / dt) x at rest: dG/dt = S / dt
    F_damp = kernel_forces(b, device, X, prev, dt=dt)
    F_el = kernel_forces(b, device, V + (V @ S.T), dt=dt)  # elastic force of the strain S (small)
    beta = 1e-3
    np.testing.assert_allclose(F_damp, beta / dt * F_el, rtol=2e-2, atol=2e-3 * np.abs(F_el).max() * beta / dt)


def test_rest_state_stays_at_rest(device):
    V, T = grid_tets(2, 2, 1)
    model = ModelBuilder(V, T, layer=slab_layers(V)).finalize(device)
    state = model.state()
    simulate(model, state, model.control(), 4e-4, 50, frames=4)
    # float32 round-off leaves forces of ~1e-4 N (strain ~1e-7): a jitter well below 1e-7 m
    np.testing.assert_allclose(state.positions.numpy(), V, atol=1e-7, err_msg="rest state drifted")


# ----------------------------------------------------------------------------------------
# integration


def total_energy(b, state, dt) -> float:
    """Potential (oracle) + kinetic energy with the Verlet velocity (x - x_prev) / dt."""
    X = state.positions.numpy().astype(np.float64)
    P = state.prev_positions.numpy().astype(np.float64)
    v = (X - P) / dt
    return oracle_energy(b, X) + 0.5 * float(np.sum(b.mass[:, None] * v * v))


@pytest.mark.parametrize(
    "kwargs",
    [dict(), dict(damping_rate=0.0, edge_damping=20.0)],
    ids=["verlet_damping", "edge_damping"],
)
def test_energy_decays_with_damping(device, kwargs):
    V, T = grid_tets(2, 1, 1)
    b = ModelBuilder(V, T, layer=slab_layers(V), **kwargs)
    model = b.finalize(device)
    dt = 4e-4
    state = model.state()
    set_state(state, perturbed(V, 0.05, 11))
    solver = SolverVerlet(model)
    energies = [total_energy(b, state, dt)]
    for _ in range(10):
        simulate(model, state, model.control(), dt, 100, solver=solver)
        energies.append(total_energy(b, state, dt))
    e = np.array(energies)
    assert e[-1] < 0.5 * e[0], f"energy did not decay: {e}"
    assert np.all(e[1:] <= e[:-1] * 1.05), f"energy grew: {e}"


def test_energy_is_conserved_without_damping(device):
    # the forces are conservative: undamped Verlet keeps the energy within a few per cent
    V, T = grid_tets(2, 1, 1)
    b = ModelBuilder(V, T, layer=slab_layers(V), damping_rate=0.0)
    model = b.finalize(device)
    dt = 1e-4
    state = model.state()
    set_state(state, perturbed(V, 0.02, 5))
    solver = SolverVerlet(model)
    e0 = total_energy(b, state, dt)
    energies = []
    for _ in range(5):
        simulate(model, state, model.control(), dt, 200, solver=solver)
        energies.append(total_energy(b, state, dt))
    np.testing.assert_allclose(energies, e0, rtol=0.05, err_msg="undamped energy drifted")


def test_simulate_matches_manual_steps_with_odd_substeps(device):
    V, T = grid_tets(1, 1, 1)
    model = ModelBuilder(V, T).finalize(device)
    X = perturbed(V, 0.05, 2)
    a, b1, b2 = model.state(), model.state(), model.state()
    set_state(a, X)
    set_state(b1, X)
    simulate(model, a, model.control(), 5e-4, 3, frames=2)
    solver = SolverVerlet(model)
    c = model.control()
    for k in range(6):
        src, dst = (b1, b2) if k % 2 == 0 else (b2, b1)
        solver.step(src, dst, c, 5e-4)
    # six manual steps end in b1
    np.testing.assert_allclose(a.positions.numpy(), b1.positions.numpy(), atol=1e-9)
    np.testing.assert_allclose(a.prev_positions.numpy(), b1.prev_positions.numpy(), atol=1e-9)
    assert solver.step_count == 6


def test_fixed_nodes_do_not_move_and_held_nodes_resist(device):
    V, T = grid_tets(2, 2, 1)
    bottom = np.isclose(V[:, 2], 0.0)
    top = ~bottom
    held = np.zeros(len(V), bool)
    held[[9, 11]] = True  # two top corners
    b = ModelBuilder(V, T, layer=slab_layers(V), fixed=bottom, held=held)
    assert b.hold_stiffness[9] == pytest.approx(4 * 15.0 / CM**2, rel=1e-5)
    model = b.finalize(device)
    control = model.control()
    force = np.zeros((len(V), 3), np.float32)
    force[top] = [0.0, 0.0, 20.0]  # pull the top up: 20 N per node
    control.external_force.assign(force)
    # from a perturbed start the fixed nodes sit exactly on their rest positions
    state = model.state()
    set_state(state, perturbed(V, 0.05, 4))
    simulate(model, state, control, 4e-4, 100, frames=5)
    P = state.positions.numpy()
    np.testing.assert_array_equal(P[bottom], V[bottom].astype(np.float32), err_msg="fixed nodes moved")
    # from rest the top rises; held nodes much less than without their springs (2 s: settled)
    rises = []
    for m in (model, ModelBuilder(V, T, layer=slab_layers(V), fixed=bottom).finalize(device)):
        state = m.state()
        simulate(m, state, control, 4e-4, 100, frames=50)
        P = state.positions.numpy()
        np.testing.assert_array_equal(P[bottom], V[bottom].astype(np.float32), err_msg="fixed nodes moved")
        rises.append(P[:, 2] - V[:, 2])
    free = top & ~held
    assert (rises[0][free] > 1e-5).all(), f"free nodes did not follow the force: {rises[0][free]}"
    assert (rises[0][held] < 0.5 * rises[1][held]).all(), f"held nodes don't resist: {rises[0][held]}, {rises[1][held]}"
    # the fixed nodes follow their targets (the hook a jaw stage uses)
    solver = SolverVerlet(model)
    targets = V.copy()
    targets[bottom] += [0.0, 0.0, -0.002]
    solver.targets.assign(targets.astype(np.float32))
    control.external_force.zero_()
    simulate(model, state, control, 4e-4, 100, frames=5, solver=solver)
    P = state.positions.numpy()
    np.testing.assert_allclose(P[bottom], targets[bottom], atol=1e-7, err_msg="fixed nodes ignore targets")


@wp.kernel
def _add_force(force: wp.array(dtype=wp.vec3), forces_out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    wp.atomic_add(forces_out, i, force[i])


class ConstantForceStage:
    """A stand-in for the muscle stage: adds a fixed force each substep and moves targets."""

    def __init__(self, force, targets):
        self.force = force
        self.new_targets = targets
        self.calls = 0

    def apply(self, model, state_in, control, dt, forces, targets):
        self.calls += 1
        wp.launch(_add_force, dim=model.vertex_count, inputs=[self.force], outputs=[forces], device=model.device)
        wp.copy(targets, self.new_targets)


def test_solver_stage_hook_adds_forces_and_moves_targets(device):
    V, T = grid_tets(2, 1, 1)
    bottom = np.isclose(V[:, 2], 0.0)
    model = ModelBuilder(V, T, fixed=bottom).finalize(device)
    force = np.zeros((len(V), 3), np.float32)
    force[~bottom] = [5.0, 0.0, 10.0]
    # reference: the same force through Control.external_force
    ref = model.state()
    control = model.control()
    control.external_force.assign(force)
    simulate(model, ref, control, 4e-4, 50, frames=2)
    # through a stage
    targets = V.astype(np.float32)
    stage = ConstantForceStage(
        wp.array(force, dtype=wp.vec3, device=model.device), wp.array(targets, dtype=wp.vec3, device=model.device)
    )
    state = model.state()
    simulate(model, state, model.control(), 4e-4, 50, frames=2, solver=SolverVerlet(model, stages=[stage]))
    assert stage.calls == 100 or model.device.is_cuda  # a CUDA graph records the frame once
    np.testing.assert_allclose(state.positions.numpy(), ref.positions.numpy(), atol=1e-9)
    # moving the targets moves the fixed nodes
    targets[bottom] += [0.0, 0.001, 0.0]
    stage.new_targets.assign(targets)
    simulate(model, state, model.control(), 4e-4, 3, solver=SolverVerlet(model, stages=[stage]))
    np.testing.assert_allclose(state.positions.numpy()[bottom], targets[bottom], atol=1e-9)


# ----------------------------------------------------------------------------------------
# guard and stability


def two_tets():
    V, T = one_tet()
    V2 = np.concatenate([V, V + [0.05, 0.0, 0.0]])
    return V2, np.array([[0, 1, 2, 3], [4, 5, 6, 7]])


def test_guard_names_nan_vertex_step_and_tet(device):
    V, T = two_tets()
    model = ModelBuilder(V, T).finalize(device)
    solver = SolverVerlet(model)
    a, b = model.state(), model.state()
    control = model.control()
    solver.step(a, b, control, 1e-4)
    solver.step(b, a, control, 1e-4)
    solver.check(a)  # fine so far
    X = a.positions.numpy().copy()
    X[6] = np.nan
    a.positions.assign(X)
    solver.step(a, b, control, 1e-4)
    msg = r"step 3: tet 1 \(vertices \[4, 5, 6, 7\]\).*non-finite.*vertices \[.*6.*\]"
    with pytest.raises(SimulationError, match=msg):
        solver.check(b)
    solver.step(b, a, control, 1e-4)  # the NaN spreads; the guard keeps the first step
    with pytest.raises(SimulationError, match=r"step 3: tet 1 "):
        solver.check(a)
    solver.reset_guard()
    X[6] = V[6]
    a.positions.assign(X)
    a.prev_positions.assign(X)
    solver.step(a, b, control, 1e-4)
    solver.check(b)


def test_guard_names_inverted_tet(device):
    V, T = two_tets()
    model = ModelBuilder(V, T).finalize(device)
    state = model.state()
    X = V.copy()
    X[7, 2] = -0.5 * CM  # push the apex of tet 1 through its base
    set_state(state, X)
    with pytest.raises(SimulationError, match=r"step 1: tet 1 .*inverted"):
        simulate(model, state, model.control(), 1e-5, 1)


def test_stable_dt_one_centimetre_tet(device):
    """DT_STABLE_1CM keeps a 1 cm tet with ~10 % strains bounded for 2 s; 2 ms blows up.

    The linear limit 2 / omega_max of one regular 1 cm tet with the Table 6.3 defaults is
    1.04 ms (omega_max^2 = 3.7e6 s^-2 from the Hessian); the stiffening of Eq. 6.4.6 at 10 %
    strain lowers it (at 0.8 ms most mixed-layer starts invert).
    """
    V, T = one_tet()
    b = ModelBuilder(V, T, layer=[0, 0, 1, 1])
    model = b.finalize(device)
    for seed in range(4):
        state = model.state()
        set_state(state, perturbed(V, 0.1, seed))
        simulate(model, state, model.control(), DT_STABLE_1CM, 250, frames=int(2.0 / DT_STABLE_1CM / 250))
        X = state.positions.numpy()
        strain = np.abs(np.linalg.norm(X[b.edges[:, 0]] - X[b.edges[:, 1]], axis=1) / b.edge_rest_lengths - 1)
        assert strain.max() < 0.3, f"seed {seed}: strain {strain.max()} after 2 s at dt {DT_STABLE_1CM}"
    state = model.state()
    set_state(state, perturbed(V, 0.1, 0))
    with pytest.raises(SimulationError):
        simulate(model, state, model.control(), 2.0e-3, 100, frames=10)
    assert stable_dt(b) == pytest.approx(0.5 * DT_STABLE_1CM)
    assert stable_dt(ModelBuilder(V * 0.5, T)) == pytest.approx(0.25 * DT_STABLE_1CM)


def test_node_stable_dt_and_selective_mass_scaling():
    V, T = grid_tets(4, 4, 1)
    V = V.copy()
    # flatten one interior top node toward its bottom neighbour: one short edge, flat tets
    top = np.flatnonzero(np.isclose(V[:, 2], CM) & np.isclose(V[:, 0], 2 * CM) & np.isclose(V[:, 1], 2 * CM))[0]
    V[top, 2] = 0.1 * CM
    b = ModelBuilder(V, T)
    dtn = node_stable_dt(b)
    assert dtn.argmin() == top or np.isclose(V[dtn.argmin(), 0], 2 * CM)
    b_ref = ModelBuilder(*grid_tets(4, 4, 1))
    assert node_stable_dt(b_ref).min() == pytest.approx(stable_dt(b_ref), rel=0.3)  # both the edge rule
    m0 = b.mass.copy()
    dt, added = scale_masses(b, quantile=0.1)
    assert dt == pytest.approx(np.quantile(dtn, 0.1))
    scaled = b.mass > m0
    assert scaled.any() and (dtn[scaled] < dt).all() and not scaled[dtn >= dt].any()
    # every node now allows dt, and the added mass is what the scaled nodes needed
    assert node_stable_dt(b).min() == pytest.approx(dt, rel=1e-9)
    assert added == pytest.approx(b.mass.sum() / m0.sum() - 1)
    b2 = ModelBuilder(V, T)
    dt0, added0 = scale_masses(b2, quantile=0.0)
    assert added0 == 0.0 and dt0 == pytest.approx(dtn.min())


@wp.kernel
def _spring_to_rest(k: wp.array(dtype=float), rest: wp.array(dtype=wp.vec3), x: wp.array(dtype=wp.vec3),
                    forces_out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    forces_out[i] = forces_out[i] - k[i] * (x[i] - rest[i])


class SpringStage:
    """A stand-in for a stiff stage spring (a contact, a muscle): each node pulled to its rest position."""

    def __init__(self, k, rest, device):
        self.k = wp.array(np.asarray(k, np.float32), dtype=float, device=device)
        self.rest = wp.array(np.asarray(rest, np.float32), dtype=wp.vec3, device=device)

    def apply(self, model, state_in, control, dt, forces, targets):
        wp.launch(_spring_to_rest, dim=model.vertex_count, inputs=[self.k, self.rest, state_in.positions],
                  outputs=[forces], device=model.device)


def test_thesis_stable_step_counts_the_stage_springs():
    """A stage spring four times past the tissue rule's step (omega dt = 4 > 2) blows Verlet up at
    the tissue step; with it in ``extra_stiffness`` the thesis rule gives the damped-spring step
    ``safety * 2 / sqrt((2 safety / dt_t)^2 + k / m)`` and the run stays at rest."""
    V, T = grid_tets(2, 2, 1)
    bottom = np.isclose(V[:, 2], 0.0)
    b = ModelBuilder(V, T, fixed=bottom, material="thesis")
    dt_t = node_stable_dt(b)
    k = np.where(bottom, 0.0, 16.0 * b.mass / dt_t.min() ** 2)
    dt_k = node_stable_dt(b, extra_stiffness=k)
    expect = np.where(k > 0, 1.0 / np.sqrt((1.0 / dt_t) ** 2 + k / b.mass), dt_t)  # safety 0.5
    np.testing.assert_allclose(dt_k, expect, rtol=1e-12)
    assert dt_k[~bottom].max() < 0.5 * dt_t.min()
    model = b.finalize("cpu")
    stage = SpringStage(k, V, "cpu")
    X = perturbed(V, 0.01, seed=3)
    X[bottom] = V[bottom]
    out = {}
    for label, dt in (("tissue", dt_t.min()), ("with springs", dt_k.min())):
        state = model.state()
        set_state(state, X, X)
        try:
            simulate(model, state, model.control(), float(dt), 200, solver=SolverVerlet(model, stages=[stage]))
            out[label] = float(np.abs(state.positions.numpy() - V).max())
        except SimulationError:
            out[label] = np.inf
    assert out["tissue"] > 1e-2 and out["with springs"] < 1e-3, out
