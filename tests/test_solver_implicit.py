"""The implicit solver, its potential and the material profiles (issue 10).

Small meshes only (one tet, a few Kuhn cubes): finite-difference gradients and Hessians of every
energy term of the step's potential (the float64 NumPy reference), the Warp kernels against that
reference (muscle springs included), momentum conservation, rest, step-count independence, damping
relative to the cranium, and bad parameters.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from conftest import grid_tets
from facewarp import InputError, SimulationError
from facewarp.physics import (MaterialPhysical, select_solver, MaterialThesis, ModelBuilder, SolverImplicit, SolverVerlet,
                              StepPotential, isotropic_moduli, linear_stiffness, material_profile, simulate,
                              stable_dt)

CM = 0.01


def one_tet(edge: float = CM):
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, np.sqrt(3) / 2, 0.0], [0.5, np.sqrt(3) / 6, np.sqrt(2 / 3)]])
    return V * edge, np.array([[0, 1, 2, 3]])




def layers(V):
    return np.where(np.isclose(V[:, 2], V[:, 2].max()), 0, 1)


def perturbed(V, rel, seed):
    rng = np.random.default_rng(seed)
    return V + rng.normal(scale=rel * CM, size=V.shape)


# ----------------------------------------------------------------------------------------
# materials


def test_physical_masses_and_stiffness_do_not_depend_on_the_mesh():
    mat = MaterialPhysical()
    coarse = ModelBuilder(*grid_tets(1, 1, 1, 2 * CM), material=mat)
    fine = ModelBuilder(*grid_tets(2, 2, 2, CM), material=mat)
    for b in (coarse, fine):
        assert b.mass.sum() == pytest.approx(mat.density * (2 * CM) ** 3, rel=1e-6)  # lumped: rho V
    # a uniform stretch of 5 % along x stores the same energy in both (moduli per volume share)
    def stretch_energy(b):
        X = b.vertices * [1.05, 1.0, 1.0]
        P = StepPotential(b.finalize("cpu"))
        d = P.begin_step(b.vertices, b.vertices, 1e6, b.vertices)  # h huge: no inertia, no dashpots
        return P.energy(X, d) - 0.5 * np.sum(d.mu[:, None] * (X - d.z) ** 2)

    assert stretch_energy(fine) == pytest.approx(stretch_energy(coarse), rel=1e-4)
    # the thesis profile's per-element joules stiffen as the mesh is refined
    tc = ModelBuilder(*grid_tets(1, 1, 1, 2 * CM), material="thesis")
    tf = ModelBuilder(*grid_tets(2, 2, 2, CM), material="thesis")
    assert stretch_energy(tf) > 1.9 * stretch_energy(tc)


def test_material_profiles_and_isotropic_moduli():
    E, nu = MaterialPhysical().young_poisson(0)
    assert 5e4 < E < 2e5 and 0.4 < nu < 0.5  # skin in vivo: 1e4-1e6 Pa, nearly incompressible
    # the volume term alone is a bulk modulus: lambda = K, G = 0 -> nu = 0.5
    assert isotropic_moduli(0.0, 0.0, 1e5)[1] == pytest.approx(0.5)
    # springs alone obey the Cauchy relation (lambda = G): nu = 1/4
    assert isotropic_moduli(1e5, 0.0, 0.0)[1] == pytest.approx(0.25)
    assert material_profile("thesis") == MaterialThesis()
    b = ModelBuilder(*one_tet(), material="physical")
    assert b.damping_rate == 50.0 and b.stiffness_damping == 2e-5
    np.testing.assert_allclose(b.edge_damping_coef, 2e-5 * b.edge_k0)


def _mandel(S):
    r2 = np.sqrt(2.0)
    return np.array([S[0, 0], S[1, 1], S[2, 2], r2 * S[1, 2], r2 * S[0, 2], r2 * S[0, 1]])


@pytest.mark.parametrize("material", ["physical", "thesis"])
def test_linear_stiffness_is_the_energy_of_a_small_uniform_strain(material):
    # oracle: the elements' own constraints measured on the strained positions
    V, T = grid_tets(2, 1, 1, CM)
    V = perturbed(V, 0.1, 3).astype(np.float32).astype(np.float64)  # the rest state the model measures
    b = ModelBuilder(V, T, material=material)
    rng = np.random.default_rng(5)
    for _ in range(3):
        eps = rng.normal(scale=1e-4, size=(3, 3))
        eps = 0.5 * (eps + eps.T)
        X = V @ (np.eye(3) + eps).T
        d = np.linalg.norm(X[b.edges[:, 0]] - X[b.edges[:, 1]], axis=1)
        ce = d / b.edge_rest_lengths - 1.0
        af = 0.5 * np.linalg.norm(np.cross(X[b.faces[:, 1]] - X[b.faces[:, 0]], X[b.faces[:, 2]] - X[b.faces[:, 0]]),
                                  axis=1)
        cf = af / b.face_rest_areas - 1.0
        x = X[b.tets]
        vt = np.einsum("ij,ij->i", x[:, 1] - x[:, 0], np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 0])) / 6.0
        ct = vt / b.tet_rest_volumes - 1.0
        energy = 0.5 * (np.sum(b.edge_k0 * ce**2) + np.sum(b.face_k * cf**2) + np.sum(b.tet_k * ct**2))
        C = linear_stiffness(b)
        e = _mandel(eps)
        assert 0.5 * np.sum(b.tet_rest_volumes * np.einsum("a,kab,b->k", e, C, e)) == pytest.approx(energy, rel=1e-3)


def test_linear_stiffness_over_evenly_spread_directions_is_the_isotropic_material():
    # one tet seen in many random orientations: the average tensor is lambda 1 1^T + 2 G I with the
    # Lame constants of isotropic_moduli (the module doc's even-spread assumption)
    mat = MaterialPhysical(distance_modulus=(3e5, 3e5, 3e5), area_modulus=1.5e5, volume_modulus=1.5e5)
    V, T = one_tet()
    V = perturbed(V, 0.2, 1)
    b = ModelBuilder(V, T, material=mat)
    rng = np.random.default_rng(2)
    q = rng.normal(size=(4000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    R = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                  np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                  np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], 1)
    C = np.mean([linear_stiffness(b, frames=r[None])[0] for r in R], axis=0)
    lam = 3e5 / 15 + 2 * 1.5e5 / 5 + 1.5e5
    g = (3e5 + 1.5e5) / 15
    want = 2 * g * np.eye(6)
    want[:3, :3] += lam
    np.testing.assert_allclose(C, want, atol=0.03 * want.max())
    E, nu = isotropic_moduli(3e5, 1.5e5, 1.5e5)
    assert E == pytest.approx(g * (3 * lam + 2 * g) / (lam + g)) and nu == pytest.approx(lam / (2 * (lam + g)))
    with pytest.raises(InputError, match="frames must have shape"):
        linear_stiffness(b, frames=np.eye(3))


@pytest.mark.parametrize("kwargs, match", [
    (dict(density=-1.0), "density must be finite and > 0"),
    (dict(distance_modulus=(0, 0, 0), area_modulus=0.0, volume_modulus=0.0), "no stiffness"),
    (dict(distance_modulus=(1e5, 1e5)), "distance_modulus must be 3 values"),
    (dict(damping_rate=float("nan")), "damping_rate must be finite"),
    (dict(shear_modulus=-1.0), "shear_modulus must be finite and >= 0"),
    (dict(shear_modulus=float("inf")), "shear_modulus must be finite"),
])
def test_bad_material_is_an_input_error(kwargs, match):
    with pytest.raises(InputError, match=match):
        MaterialPhysical(**kwargs)


def test_bad_step_arguments_are_input_errors():
    V, T = grid_tets(1, 1, 1)
    model = ModelBuilder(V, T, material="physical").finalize("cpu")
    solver = select_solver(model)
    a, b, c = model.state(), model.state(), model.control()
    for dt in (0.0, -1.0, float("nan")):
        with pytest.raises(InputError, match="dt must be a positive number"):
            solver.step(a, b, c, dt)
    with pytest.raises(InputError, match="different State buffers"):
        solver.step(a, a, c, 0.01)
    with pytest.raises(InputError, match="method"):
        select_solver(model, method="jacobi")
    with pytest.raises(InputError, match="tolerance"):
        select_solver(model, tolerance=-1.0)
    with pytest.raises(InputError, match="rounds"):
        select_solver(model, method="newton-pcg", rounds=0)
    with pytest.raises(InputError, match="linear_iterations"):
        select_solver(model, method="newton-pcg", linear_iterations=0)


def test_solver_implicit_makes_the_class_of_its_method_and_refuses_foreign_options():
    from facewarp.physics import SolverDeviceNewtonPCG, SolverHostImplicit

    V, T = grid_tets(1, 1, 1)
    model = ModelBuilder(V, T, material="physical").finalize("cpu")
    host, device = select_solver(model), select_solver(model, method="newton-pcg")
    assert type(host) is SolverHostImplicit and host.method == "lbfgs" and isinstance(host, SolverImplicit)
    assert type(device) is SolverDeviceNewtonPCG and device.method == "newton-pcg" and isinstance(device, SolverImplicit)
    assert select_solver(model, method="newton").method == "newton"
    # each class takes its own options only, and says whose an option is
    for cls, kw, name in ((select_solver, dict(method="newton-pcg", history=4), "history"),
                          (select_solver, dict(method="newton-pcg", spring_tolerance=1e-3), "spring_tolerance"),
                          (select_solver, dict(linear_iterations=3), "linear_iterations"),
                          (SolverHostImplicit, dict(rounds=2), "rounds"),
                          (SolverDeviceNewtonPCG, dict(backend="splu"), "backend"),
                          (select_solver, dict(tolerances=1e-3), "tolerances")):
        with pytest.raises(InputError, match=f"^{name}: not an option of") as e:
            cls(model, **kw)
        assert "\n" not in str(e.value)
    with pytest.raises(InputError, match="method"):
        SolverDeviceNewtonPCG(model, method="lbfgs")
    with pytest.raises(InputError, match="method"):
        SolverHostImplicit(model, method="newton-pcg")


def test_cg_iterations_grow_with_the_square_root_of_the_node_count():
    from facewarp.physics import default_linear_iterations

    # levels 0-3 of the default head: 10 up to 10,000 nodes, then 10 sqrt(n / 10,000)
    assert [default_linear_iterations(n) for n in (2448, 9470, 36930, 146450)] == [10, 10, 19, 38]
    V, T = grid_tets(1, 1, 1)
    model = ModelBuilder(V, T, material="physical").finalize("cpu")
    assert select_solver(model, method="newton-pcg").linear_iterations == 10
    assert select_solver(model, method="newton-pcg", linear_iterations=3).linear_iterations == 3


def test_nan_control_is_a_simulation_error_not_a_nan_frame():
    V, T = grid_tets(1, 1, 1)
    model = ModelBuilder(V, T, material="physical").finalize("cpu")
    solver = select_solver(model)
    a, b, c = model.state(), model.state(), model.control()
    f = np.zeros((len(V), 3), np.float32)
    f[0] = np.nan
    c.external_force.assign(f)
    with pytest.raises(SimulationError, match="not finite"):
        solver.step(a, b, c, 0.01)
    assert np.isfinite(b.positions.numpy()).all()


# ----------------------------------------------------------------------------------------
# the step's potential: finite differences of every term


def springs_for(V, rng):
    """A distance spring (muscle-like) and an axis spring (support-like) on a few nodes."""
    node = np.array([0, 2, 3])
    point = V[node] + rng.normal(scale=0.3 * CM, size=(3, 3))
    axis = rng.normal(size=(3, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return [(node, point, np.array([50.0, 80.0, 30.0]), np.full(3, 0.2 * CM), None),
            (node, point, np.array([40.0, 20.0, 60.0]), None, axis)]


TERMS = {
    "distance": dict(k_area=0.0, k_volume=0.0, damping_rate=0.0),
    "area": dict(k0_outer=0.0, k0_inner=0.0, k0_cross=0.0, k_volume=0.0, damping_rate=0.0),
    "volume": dict(k0_outer=0.0, k0_inner=0.0, k0_cross=0.0, k_area=0.0, damping_rate=0.0),
    "dashpots_inertia": dict(stiffness_damping=3e-3, damping_rate=7.0),
    "shear_and_its_dashpot": dict(material=MaterialPhysical(distance_modulus=(0.0, 0.0, 0.0), area_modulus=0.0,
                                                            volume_modulus=0.0, shear_modulus=3e4,
                                                            stiffness_damping=3e-3), damping_rate=0.0),
}


def potential_case(term, seed):
    V, T = one_tet()
    kw = dict(TERMS[term])
    b = ModelBuilder(V, T, layer=[0, 0, 1, 1], material=kw.pop("material", "physical"),
                     held=[False, True, False, False], **kw)
    P = StepPotential(b.finalize("cpu"))
    rng = np.random.default_rng(seed)
    Xn, Xp = perturbed(V, 0.1, seed), perturbed(V, 0.1, seed + 10)
    data = P.begin_step(Xn, Xp, 0.01, perturbed(V, 0.05, seed + 20), force=rng.normal(size=V.shape) * 1e-3,
                        springs=springs_for(V, rng), cranium_velocity=[[0.01, 0.0, 0.0], [0.0, 0.0, 0.5]])
    return P, data, perturbed(V, 0.15, seed + 30)


@pytest.mark.parametrize("term", list(TERMS))
@pytest.mark.parametrize("seed", [0, 1])
def test_potential_gradient_is_its_finite_difference(term, seed):
    P, data, X = potential_case(term, seed)
    e, G = P.gradient(X, data)
    assert e == pytest.approx(P.energy(X, data), rel=1e-12)
    h = 1e-8
    FD = np.zeros_like(X)
    for a, d in itertools.product(range(len(X)), range(3)):
        Xp, Xm = X.copy(), X.copy()
        Xp[a, d] += h
        Xm[a, d] -= h
        FD[a, d] = (P.energy(Xp, data) - P.energy(Xm, data)) / (2 * h)
    np.testing.assert_allclose(G, FD, rtol=1e-5, atol=1e-6 * np.abs(FD).max(), err_msg=f"{term} gradient")


def test_potential_hessian_is_the_finite_difference_where_exact():
    """Exact for the distance energy (stretched), springs (stretched), holds and inertia; the
    area and volume terms are Gauss-Newton, exact at rest (C = 0)."""
    V, T = one_tet()
    rng = np.random.default_rng(3)
    cases = []
    b = ModelBuilder(V, T, material="physical", k_area=0.0, k_volume=0.0, held=[0, 1, 0, 0], stiffness_damping=1e-3)
    X = V * 1.1 + rng.normal(scale=1e-4, size=V.shape)  # every edge stretched
    cases.append(("distance, holds, springs (stretched)", b, X, springs_for(V * 1.5, rng)[:1] + springs_for(V, rng)[1:]))
    b = ModelBuilder(V, T, material="physical", k0_outer=0.0, k0_inner=0.0, k0_cross=0.0)
    cases.append(("area, volume at rest", b, V.copy(), []))
    b = ModelBuilder(V, T, material=MaterialPhysical(distance_modulus=(0.0, 0.0, 0.0), area_modulus=0.0,
                                                     volume_modulus=0.0, shear_modulus=3e4))
    cases.append(("shear term at rest (Gauss-Newton)", b, V.copy(), []))
    for name, b, X, springs in cases:
        P = StepPotential(b.finalize("cpu"))
        data = P.begin_step(V, V, 0.02, V, springs=springs)
        H = P.hessian(X, data).toarray()
        h = 1e-7
        FD = np.zeros((12, 12))
        for k in range(12):
            Xp, Xm = X.copy(), X.copy()
            Xp.flat[k] += h
            Xm.flat[k] -= h
            FD[:, k] = (P.gradient(Xp, data)[1] - P.gradient(Xm, data)[1]).ravel() / (2 * h)
        np.testing.assert_allclose(H, FD, rtol=1e-4, atol=1e-5 * np.abs(FD).max(), err_msg=name)
        assert np.linalg.eigvalsh(H).min() > -1e-9 * np.abs(H).max(), f"{name}: not PSD"


@pytest.mark.parametrize("method, material", [("lbfgs", "physical"), ("newton-pcg", "physical"),
                                              ("lbfgs", MaterialPhysical(shear_modulus=3e4, stiffness_damping=1e-3))])
def test_kernels_evaluate_the_reference_potential(method, material):
    """The solver's Warp kernels (energy, gradient, Hessian) equal the float64 NumPy reference."""
    V, T = grid_tets(2, 1, 1)
    bottom = np.isclose(V[:, 2], 0.0)
    held = np.zeros(len(V), bool)
    held[[9, 11]] = True
    b = ModelBuilder(V, T, layer=layers(V), fixed=bottom, held=held, material=material)
    model = b.finalize("cpu")
    solver = select_solver(model, method=method)
    state, control = model.state(), model.control()
    Xn, Xp = perturbed(V, 0.03, 1), perturbed(V, 0.03, 2)
    Xn[bottom] = Xp[bottom] = V[bottom]
    state.positions.assign(Xn.astype(np.float32))
    state.prev_positions.assign(Xp.astype(np.float32))
    f = np.random.default_rng(4).normal(size=V.shape).astype(np.float32) * 1e-3
    control.external_force.assign(f)
    control.cranium_velocity.assign(np.array([[0.0, 0.01, 0.0], [0.2, 0.0, 0.0]], np.float32))
    X = perturbed(V, 0.05, 5)
    e, G, H = solver.potential(state, control, 0.01, X, hessian=True)
    X32 = X.astype(np.float32).astype(np.float64)
    X32[bottom] = V[bottom].astype(np.float32)
    P = StepPotential(model)
    data = P.begin_step(state.positions.numpy(), state.prev_positions.numpy(), 0.01, V, force=f,
                        cranium_velocity=control.cranium_velocity.numpy())
    e_ref, G_ref = P.gradient(X32, data)
    G_ref[bottom] = 0.0
    assert e == pytest.approx(e_ref, rel=2e-4, abs=1e-6 * np.abs(G_ref).max() * CM)
    np.testing.assert_allclose(G, G_ref, rtol=2e-3, atol=2e-3 * np.abs(G_ref).max(), err_msg="gradient")
    free = np.repeat(~bottom, 3)
    H_ref = P.hessian(X32, data).toarray()
    np.testing.assert_allclose(H.toarray()[np.ix_(free, free)], H_ref, rtol=2e-3, atol=1e-4 * np.abs(H_ref).max())


# ----------------------------------------------------------------------------------------
# the solver


@pytest.mark.parametrize("method", ["lbfgs", "newton", "newton-pcg"])
def test_rest_stays_at_rest(method):
    V, T = grid_tets(2, 2, 1)
    model = ModelBuilder(V, T, layer=layers(V), fixed=np.isclose(V[:, 2], 0.0), material="physical").finalize("cpu")
    solver = select_solver(model, method=method)
    a, b, c = model.state(), model.state(), model.control()
    for _ in range(5):
        solver.step(a, b, c, 1 / 30)
        a, b = b, a
    solver.check(a)
    np.testing.assert_allclose(a.positions.numpy(), V, atol=1e-7, err_msg="rest drifted")


def test_momentum_is_conserved_without_fixed_nodes_and_damping():
    V, T = grid_tets(2, 1, 1)
    model = ModelBuilder(V, T, layer=layers(V), material=MaterialPhysical(damping_rate=0.0, stiffness_damping=0.0),
                         ).finalize("cpu")
    solver = select_solver(model, tolerance=1e-9, max_iterations=200)
    m = model.vertex_mass.numpy().astype(np.float64)
    h = 1e-3
    a, b, c = model.state(), model.state(), model.control()
    X = perturbed(V, 0.05, 7)
    v0 = np.random.default_rng(8).normal(scale=0.02, size=V.shape)
    a.positions.assign(X.astype(np.float32))
    a.prev_positions.assign((X - h * v0).astype(np.float32))
    p0 = (m[:, None] * (a.positions.numpy() - a.prev_positions.numpy())).sum(0) / h
    for _ in range(10):
        solver.step(a, b, c, h)
        a, b = b, a
    p = (m[:, None] * (a.positions.numpy().astype(np.float64) - a.prev_positions.numpy())).sum(0) / h
    assert np.abs(p - p0).max() < 1e-3 * np.abs(m[:, None] * v0).sum(), (p, p0)
    assert np.abs(a.positions.numpy() - X).max() > 1e-4  # it moved


def test_damping_acts_on_velocity_relative_to_the_cranium():
    """A free body carried at the cranium's velocity keeps it; a body moving against a still cranium slows."""
    V, T = grid_tets(1, 1, 1)
    model = ModelBuilder(V, T, material=MaterialPhysical(damping_rate=30.0)).finalize("cpu")
    u = np.array([0.05, -0.02, 0.01], np.float32)
    h = 1 / 30
    for cranium, expect_kept in ((u, True), (np.zeros(3, np.float32), False)):
        for solver in (select_solver(model, tolerance=1e-9), SolverVerlet(model)):
            a, b, c = model.state(), model.state(), model.control()
            c.cranium_velocity.assign(np.array([cranium, [0, 0, 0]], np.float32))
            dt = h if isinstance(solver, SolverImplicit) else 1e-4
            a.prev_positions.assign((V - dt * u).astype(np.float32))
            for _ in range(5):
                solver.step(a, b, c, dt)
                a, b = b, a
            v = (a.positions.numpy() - a.prev_positions.numpy()).mean(0) / dt
            if expect_kept:
                np.testing.assert_allclose(v, u, rtol=1e-3, atol=1e-5, err_msg=type(solver).__name__)
            else:
                assert np.linalg.norm(v) < 0.99 * np.linalg.norm(u), type(solver).__name__


def loaded_slab(material="physical"):
    """A 3 x 2 x 1 slab, bottom fixed, two top corners held, the top pushed up and sideways."""
    V, T = grid_tets(3, 2, 1)
    bottom = np.isclose(V[:, 2], 0.0)
    held = np.zeros(len(V), bool)
    held[[12, 15]] = True
    b = ModelBuilder(V, T, layer=layers(V), fixed=bottom, held=held, material=material)
    f = np.zeros((len(V), 3), np.float32)
    f[~bottom] = [0.4, 0.0, 1.0]
    return V, b, f * (20.0 if material == "thesis" else 1e-2)


#: The physical profile with the shear term in place of the distance and area energies (MaterialPhysical.shear_modulus).
WITH_SHEAR = MaterialPhysical(distance_modulus=(0.0, 0.0, 0.0), area_modulus=0.0, shear_modulus=1e4)


@pytest.mark.parametrize("material", ["physical", WITH_SHEAR], ids=["physical", "with_shear"])
def test_static_shape_independent_of_steps_per_frame_and_equal_to_verlet(material):
    V, b, f = loaded_slab(material)
    model = b.finalize("cpu")
    frame = 1 / 30
    shapes = []
    for steps in (1, 2, 4, 8):
        solver = select_solver(model, tolerance=1e-9)
        a, s, c = model.state(), model.state(), model.control()
        c.external_force.assign(f)
        for _ in range(6 * steps):
            solver.step(a, s, c, frame / steps)
            a, s = s, a
        shapes.append(a.positions.numpy().astype(np.float64))
    moved = np.abs(shapes[0] - V).max()
    assert moved > 1e-4
    for k, X in zip((2, 4, 8), shapes[1:]):
        np.testing.assert_allclose(X, shapes[0], atol=1e-3 * moved, err_msg=f"{k} steps per frame")
    # the Verlet reference run to rest
    ref = model.state()
    c = model.control()
    c.external_force.assign(f)
    simulate(model, ref, c, stable_dt(b), 500, frames=8)
    np.testing.assert_allclose(ref.positions.numpy(), shapes[0], atol=5e-3 * moved, err_msg="Verlet at rest")


@pytest.mark.parametrize("material", ["physical", WITH_SHEAR], ids=["physical", "with_shear"])
def test_newton_pcg_reaches_the_direct_solution(material):
    V, b, f = loaded_slab(material)
    model = b.finalize("cpu")
    out = {}
    counts = []
    for label, method, kw in (("lbfgs", "lbfgs", dict(tolerance=1e-9)),
                              ("fixed", "newton-pcg", dict(iterations=4, linear_iterations=100)),
                              ("adaptive", "newton-pcg", dict(tolerance=1e-7, linear_iterations=100))):
        solver = select_solver(model, method=method, **kw)
        a, s, c = model.state(), model.state(), model.control()
        c.external_force.assign(f)
        for _ in range(3):
            solver.step(a, s, c, 1 / 30)
            a, s = s, a
            counts.append((label, solver.last_iterations))
        out[label] = a.positions.numpy().astype(np.float64)
    moved = np.abs(out["lbfgs"] - V).max()
    np.testing.assert_allclose(out["fixed"], out["lbfgs"], atol=2e-3 * moved)
    # the adaptive count (the default) iterates until the step is below its tolerance: more
    # iterations on the first step (the load applied at once) than once the slab has settled
    np.testing.assert_allclose(out["adaptive"], out["lbfgs"], atol=2e-3 * moved)
    adaptive = [n for label, n in counts if label == "adaptive"]
    assert adaptive[0] > 2 and adaptive[0] <= solver.max_iterations, counts
    assert solver.total_iterations == sum(adaptive)


def test_interactive_mode_runs_a_fixed_iteration_count():
    V, b, f = loaded_slab()
    model = b.finalize("cpu")
    solver = select_solver(model, iterations=2)
    a, s, c = model.state(), model.state(), model.control()
    c.external_force.assign(f)
    for _ in range(4):
        solver.step(a, s, c, 1 / 30)
        a, s = s, a
        assert solver.last_iterations == 2
    solver.check(a)


# ----------------------------------------------------------------------------------------
# the volume barrier (issue 23): a floor under every tet's volume


def flattened_tet(ratio: float):
    """The regular tet with its apex lowered to ``ratio`` of the rest volume (and nudged sideways)."""
    V, T = one_tet()
    X = V.copy()
    X[3, 2] *= ratio
    X[3, 0] += 0.1 * CM
    return V, T, X


@pytest.mark.parametrize("ratio", [0.01, 0.04])
def test_volume_barrier_gradient_and_kernels_match_the_reference(ratio):
    """Below the onset the barrier is in the potential: its gradient is the finite difference of
    the energy, its Gauss-Newton block is PSD, and the Warp kernels equal the NumPy reference."""
    from facewarp.physics import VOLUME_BARRIER_ONSET, VOLUME_BARRIER_STIFFNESS

    def barrier(r):  # the module doc's phi (IPC's barrier), below the onset
        return -(r - VOLUME_BARRIER_ONSET) ** 2 * np.log(r / VOLUME_BARRIER_ONSET)

    V, T, X = flattened_tet(ratio)
    b = ModelBuilder(V, T, material="physical", k0_outer=0.0, k0_inner=0.0, k0_cross=0.0, k_area=0.0,
                     damping_rate=0.0)
    model = b.finalize("cpu")
    P = StepPotential(model)
    data = P.begin_step(V, V, 0.01, V)
    e, G = P.gradient(X, data)
    assert ratio < VOLUME_BARRIER_ONSET
    k = float(model.tet_k.numpy()[0])
    r = np.dot(X[1] - X[0], np.cross(X[2] - X[0], X[3] - X[0])) / 6 / model.tet_rest_volume.numpy()[0]
    assert e > 0.5 * k * (r - 1) ** 2 + VOLUME_BARRIER_STIFFNESS * k * barrier(r) * (1 - 1e-6) > 0.5 * k * (r - 1) ** 2
    h = 1e-9
    FD = np.zeros_like(X)
    for a, d in itertools.product(range(4), range(3)):
        Xp, Xm = X.copy(), X.copy()
        Xp[a, d] += h
        Xm[a, d] -= h
        FD[a, d] = (P.energy(Xp, data) - P.energy(Xm, data)) / (2 * h)
    np.testing.assert_allclose(G, FD, rtol=1e-5, atol=1e-6 * np.abs(FD).max(), err_msg="barrier gradient")
    H = P.hessian(X, data).toarray()
    assert np.linalg.eigvalsh(H).min() > -1e-9 * np.abs(H).max()
    solver = select_solver(model)
    state, control = model.state(), model.control()
    state.positions.assign(V.astype(np.float32))
    state.prev_positions.assign(V.astype(np.float32))
    e_k, G_k, H_k = solver.potential(state, control, 0.01, X, hessian=True)
    X32 = X.astype(np.float32).astype(np.float64)
    e_ref, G_ref = P.gradient(X32, data)
    assert e_k == pytest.approx(e_ref, rel=1e-3)
    np.testing.assert_allclose(G_k, G_ref, rtol=2e-3, atol=2e-3 * np.abs(G_ref).max(), err_msg="kernel gradient")
    np.testing.assert_allclose(H_k.toarray(), P.hessian(X32, data).toarray(), rtol=2e-3,
                               atol=1e-4 * np.abs(H_k.toarray()).max(), err_msg="kernel Hessian")


def test_a_crushed_tet_stays_above_the_volume_floor():
    """A force of 5 k (k: the tet's volume stiffness [J] over its height) on the apex of a tet whose
    base is fixed: without the barrier the volume term alone (at most k / height) cannot stop it and
    the tet would invert; with it the tet settles above the documented floor."""
    from facewarp.physics import VOLUME_FLOOR

    V, T = one_tet()
    fixed = np.array([True, True, True, False])
    b = ModelBuilder(V, T, material="physical", fixed=fixed, k0_outer=0.0, k0_inner=0.0, k0_cross=0.0, k_area=0.0)
    model = b.finalize("cpu")
    k = float(model.tet_k.numpy()[0])
    height = V[3, 2]
    solver = select_solver(model)
    a, c, control = model.state(), model.state(), model.control()
    f = np.zeros((4, 3), np.float32)
    f[3, 2] = -5.0 * k / height
    control.external_force.assign(f)
    for _ in range(40):
        solver.step(a, c, control, 1 / 30)
        a, c = c, a
    solver.check(a)
    X = a.positions.numpy().astype(np.float64)
    r = np.dot(X[1] - X[0], np.cross(X[2] - X[0], X[3] - X[0])) / 6 / model.tet_rest_volume.numpy()[0]
    assert VOLUME_FLOOR < r < 0.05, r


def test_last_converged_tells_a_solve_cut_short():
    """``last_converged`` (the rollback's check): False when the iteration bound cut the solve
    short of its tolerance, True when it converged or ran a fixed iteration count."""
    V, b, f = loaded_slab()
    model = b.finalize("cpu")
    for kw, want in (({"max_iterations": 1, "tolerance": 1e-12}, False), ({}, True), ({"iterations": 1}, True)):
        solver = select_solver(model, **kw)
        a, s, c = model.state(), model.state(), model.control()
        c.external_force.assign(f)
        solver.step(a, s, c, 1 / 30)
        assert solver.last_converged is want, kw


def _crushed_tet_run(step_bound: bool):
    """The crushed tet of the test above (5 k on the apex), 40 steps; (positions, solver)."""
    V, T = one_tet()
    fixed = np.array([True, True, True, False])
    b = ModelBuilder(V, T, material="physical", fixed=fixed, k0_outer=0.0, k0_inner=0.0, k0_cross=0.0, k_area=0.0)
    model = b.finalize("cpu")
    k = float(model.tet_k.numpy()[0])
    solver = select_solver(model)
    solver.step_bound = step_bound
    a, c, control = model.state(), model.state(), model.control()
    f = np.zeros((4, 3), np.float32)
    f[3, 2] = -5.0 * k / V[3, 2]
    control.external_force.assign(f)
    for _ in range(40):
        solver.step(a, c, control, 1 / 30)
        a, c = c, a
    return a.positions.numpy().copy(), solver


def test_line_search_skips_inverting_trials_and_takes_the_same_steps():
    """The host line search's ``step_bound``: the trials at which the tet would invert are skipped
    without an evaluation, and the steps are those of plain halving (positions bit for bit); the
    Hessian's upper triangle for QDLDL is scipy's triu of the full matrix, entry for entry."""
    import scipy.sparse as sp

    X_on, on = _crushed_tet_run(True)
    X_off, off = _crushed_tet_run(False)
    np.testing.assert_array_equal(X_on, X_off)
    assert on.line_search_trials < off.line_search_trials, (on.line_search_trials, off.line_search_trials)
    ip = on.incremental
    ip.launch_hessian(ip.x, 1 / 30, 0.0)
    U, ref = ip.hessian_upper(), sp.triu(sp.csc_matrix(ip.hessian_matrix()), format="csc")
    for name in ("indptr", "indices", "data"):
        np.testing.assert_array_equal(getattr(U, name), getattr(ref, name), err_msg=name)
