"""Global RBF (Eq. 4.4.1-4.4.4) and CSRBF with local quadrics (Eq. 4.4.5-4.4.10)."""

import numpy as np
import pytest

from facewarp.adaptation import fit_csrbf, fit_local_quadrics, fit_rbf, wendland


def _points(n, seed=0):
    return np.random.default_rng(seed).uniform(-0.1, 0.1, size=(n, 3))


def test_global_rbf_reproduces_affine_map_exactly():
    P = _points(30)
    M = np.array([[0.1, 0.02, 0.0], [-0.03, 0.05, 0.01], [0.0, 0.04, -0.02]])
    t = np.array([0.01, -0.02, 0.005])
    f = fit_rbf(P, P @ M.T + t)
    X = _points(200, seed=1)
    np.testing.assert_allclose(f(X), X @ M.T + t, atol=1e-12, err_msg="affine map not reproduced")
    np.testing.assert_allclose(f.coeffs, 0.0, atol=1e-12)


def test_global_rbf_interpolates_and_rho_smooths():
    P = _points(40)
    D = np.random.default_rng(2).normal(scale=0.005, size=P.shape)
    np.testing.assert_allclose(fit_rbf(P, D)(P), D, atol=1e-12)
    smooth = fit_rbf(P, D, rho=0.05)
    assert np.abs(smooth(P) - D).max() > 1e-4  # Eq. 4.4.3: rho trades fidelity for smoothness
    # side conditions: sum c = 0, sum c p^T = 0
    np.testing.assert_allclose(smooth.coeffs.sum(0), 0.0, atol=1e-10)
    np.testing.assert_allclose(P.T @ smooth.coeffs, 0.0, atol=1e-10)


def test_wendland():
    np.testing.assert_allclose(wendland([0.0, 0.5, 1.0, 2.0]), [1.0, 0.5**4 * 3.0, 0.0, 0.0])


@pytest.mark.parametrize("solver,preconditioner", [("cg", "jacobi"), ("bicgstab", "ilu"), ("gmres", "ilu"), ("bicg", "jacobi")])
def test_csrbf_interpolates_its_pairs(solver, preconditioner):
    P = _points(300)
    D = np.sin(P * 30.0) * 0.003
    f = fit_csrbf(P, D, 0.06, solver=solver, preconditioner=preconditioner, tol=1e-12)
    assert f.iterations.max() > 0 and f.residual < 1e-9
    np.testing.assert_allclose(f(P), D, atol=1e-9, err_msg=f"{solver}/{preconditioner}")
    # compact support: nothing farther than sigma from every centre
    np.testing.assert_allclose(f(np.array([[1.0, 1.0, 1.0]])), 0.0)


def test_csrbf_with_quadrics_interpolates():
    rng = np.random.default_rng(5)
    d = rng.normal(size=(400, 3))
    P = 0.1 * d / np.linalg.norm(d, axis=1, keepdims=True)
    N = P / 0.1
    D = 0.002 * N * P[:, [2]] / 0.1
    f = fit_csrbf(P, D, 0.05, normals=N, tol=1e-12)
    assert f.quadrics is not None
    np.testing.assert_allclose(f(P), D, atol=1e-8)


def test_quadric_fit_recovers_sphere_curvature():
    r = 0.08
    rng = np.random.default_rng(6)
    d = rng.normal(size=(3000, 3))
    P = r * d / np.linalg.norm(d, axis=1, keepdims=True)
    q = fit_local_quadrics(P, P / r, 0.02)
    A, B, C = q.abc.T
    # w = A u^2 + 2 B u v + C v^2 with w outward: a sphere has A = C = -1/(2r), B = 0
    np.testing.assert_allclose(A, -1 / (2 * r), rtol=0.02)
    np.testing.assert_allclose(C, -1 / (2 * r), rtol=0.02)
    np.testing.assert_allclose(B, 0.0, atol=0.02 / (2 * r))
    np.testing.assert_allclose(np.median(-(A + C)), 1 / r, rtol=0.01, err_msg="mean curvature 1/r")
