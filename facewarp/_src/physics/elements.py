"""The element library: one ``@wp.func`` per element quantity of the skin model (thesis Sec. 6.4),
its derivation written once above it. Every kernel file calls these instead of writing the maths
again: the Verlet forces (:mod:`.kernels_tissue`), the implicit step's energy, gradient and Hessian
(:mod:`.solvers.kernels_potential`, :mod:`.solvers.kernels_hessian`), the device line search
(:mod:`.solvers.kernels_line_search`), and the guards. :mod:`.potential` is the float64 NumPy oracle
of the same quantities under the same names (``tests/test_elements.py`` pairs them on random elements).

Notation: a tet (x0, x1, x2, x3) has edge vectors e_a = x_a - x0 (a = 1, 2, 3); a face (x0, x1, x2)
e1 = x1 - x0, e2 = x2 - x0; C is a dimensionless constraint (relative length, area or volume change);
energies are [J], positions [m].
"""

from __future__ import annotations

import warp as wp

from .volume_barrier import _R_MIN, INVERTED_ENERGY, VOLUME_BARRIER_ONSET, VOLUME_BARRIER_STIFFNESS

_BARRIER_ONSET = wp.constant(VOLUME_BARRIER_ONSET)
_BARRIER_STIFFNESS = wp.constant(VOLUME_BARRIER_STIFFNESS)
_INVERTED_ENERGY = wp.constant(INVERTED_ENERGY)
_BARRIER_R_MIN = wp.constant(_R_MIN)

@wp.func
def outer(a: wp.vec3, b: wp.vec3):
    return wp.outer(a, b)


@wp.func
def pick4(g0: wp.vec3, g1: wp.vec3, g2: wp.vec3, g3: wp.vec3, a: int):
    if a == 0:
        return g0
    if a == 1:
        return g1
    if a == 2:
        return g2
    return g3


# Shear term (model doc, "Shear term"): F = D_s D_m^-1, G = (F^T F - I) / 2,
# E = k_s / 2 |G|^2 + d_s / (2h) |G - G_n|^2, dE/dx_a = F S b_a with S = k_s G + d_s / h (G - G_n) and
# b_a the gradient of corner a's shape function (rows of D_m^-1; b_0 = -(b_1 + b_2 + b_3)).
@wp.func
def deformation_gradient(xi: wp.vec3, xj: wp.vec3, xk: wp.vec3, xl: wp.vec3, rest_inverse: wp.mat33):
    return wp.matrix_from_cols(xj - xi, xk - xi, xl - xi) * rest_inverse


@wp.func
def green_strain(f: wp.mat33):
    return 0.5 * (wp.transpose(f) * f - wp.identity(n=3, dtype=float))


@wp.func
def shear_energy(g: wp.mat33, k: float, dmp: float, g_start: wp.mat33):
    dg = g - g_start
    return 0.5 * k * wp.ddot(g, g) + 0.5 * dmp * wp.ddot(dg, dg)


@wp.func
def mat_row(m: wp.mat33, r: int):
    return wp.vec3(m[r, 0], m[r, 1], m[r, 2])




@wp.func
def finite3(x: wp.vec3) -> bool:
    """Whether every component of ``x`` is finite."""
    return wp.isfinite(x[0]) and wp.isfinite(x[1]) and wp.isfinite(x[2])


# Tet edge vectors from corner 0: e_a = x_a - x0.
@wp.func
def tet_edges(x0: wp.vec3, x1: wp.vec3, x2: wp.vec3, x3: wp.vec3):
    return x1 - x0, x2 - x0, x3 - x0


# Signed tet volume and its gradient. V = 1/6 e1 . (e2 x e3) is trilinear in (e1, e2, e3), so
# (cyclic triple product) dV/dx1 = 1/6 e2 x e3, dV/dx2 = 1/6 e3 x e1, dV/dx3 = 1/6 e1 x e2 and
# dV/dx0 = -(dV/dx1 + dV/dx2 + dV/dx3) (a translation leaves V unchanged).
@wp.func
def tet_volume(e1: wp.vec3, e2: wp.vec3, e3: wp.vec3):
    return wp.dot(e1, wp.cross(e2, e3)) / 6.0


@wp.func
def tet_volume_gradient(e1: wp.vec3, e2: wp.vec3, e3: wp.vec3):
    g1 = wp.cross(e2, e3) / 6.0
    g2 = wp.cross(e3, e1) / 6.0
    g3 = wp.cross(e1, e2) / 6.0
    return -(g1 + g2 + g3), g1, g2, g3


# Face area and its gradient. N = e1 x e2, A = |N| / 2, m = N / |N|; dA = 1/2 m . dN with
# dN = de1 x e2 + e1 x de2, so by the triple product m . (de1 x e2) = de1 . (e2 x m) and
# m . (e1 x de2) = de2 . (m x e1): dA/dx1 = 1/2 e2 x m, dA/dx2 = 1/2 m x e1,
# dA/dx0 = -(dA/dx1 + dA/dx2). ``m`` is the unit normal (the caller handles |N| = 0: no direction).
@wp.func
def face_area_gradient(e1: wp.vec3, e2: wp.vec3, m: wp.vec3):
    g1 = 0.5 * wp.cross(e2, m)
    g2 = 0.5 * wp.cross(m, e1)
    return -(g1 + g2), g1, g2


# Edge strain C = |xi - xj| / D0 - 1 (Eq. 6.4.4's relative length change).
@wp.func
def edge_strain(xi: wp.vec3, xj: wp.vec3, d0: float):
    return wp.length(xi - xj) / d0 - 1.0


# Face strain C = A / A0 - 1 (Eq. 6.4.7).
@wp.func
def face_strain(xi: wp.vec3, xj: wp.vec3, xk: wp.vec3, a0: float):
    return 0.5 * wp.length(wp.cross(xj - xi, xk - xi)) / a0 - 1.0


# The columns of a 3 x 3 matrix (the shear term's corner gradients: P D_m^-T has dE/dx_a in column a).
@wp.func
def mat_columns(m: wp.mat33):
    return wp.vec3(m[0, 0], m[1, 0], m[2, 0]), wp.vec3(m[0, 1], m[1, 1], m[2, 1]), wp.vec3(m[0, 2], m[1, 2], m[2, 2])


# Volume constraint of tet t at x: C = V / V0 - 1 (C <= -1: inverted).
@wp.func
def tet_constraint_at(tet_indices: wp.array(dtype=wp.vec4i), tet_rest_volume: wp.array(dtype=float),
                    x: wp.array(dtype=wp.vec3), t: int):
    xi = x[tet_indices[t][0]]
    e1 = x[tet_indices[t][1]] - xi
    e2 = x[tet_indices[t][2]] - xi
    e3 = x[tet_indices[t][3]] - xi
    return wp.dot(e1, wp.cross(e2, e3)) / 6.0 / tet_rest_volume[t] - 1.0


# One definition of every term's energy, shared by the energy kernels and the device line
# search's trial kernel (so a trial at t = 0 would sum to the same total, bit for bit).
@wp.func
def edge_energy(xi: wp.vec3, xj: wp.vec3, d0: float, k0: float, dmp: float, c_start: float):
    c = wp.length(xi - xj) / d0 - 1.0
    dc = c - c_start
    return k0 * c * c * (0.5 + 0.25 * c * c) + 0.5 * dmp * dc * dc


@wp.func
def face_energy(xi: wp.vec3, xj: wp.vec3, xk: wp.vec3, a0: float, k: float, dmp: float, c_start: float):
    c = 0.5 * wp.length(wp.cross(xj - xi, xk - xi)) / a0 - 1.0
    dc = c - c_start
    return 0.5 * k * c * c + 0.5 * dmp * dc * dc


@wp.func
def tet_strain(xi: wp.vec3, xj: wp.vec3, xk: wp.vec3, xl: wp.vec3, v0: float):
    return wp.dot(xj - xi, wp.cross(xk - xi, xl - xi)) / 6.0 / v0 - 1.0


# The volume barrier kappa phi(r), r = C + 1 (module doc of facewarp._src.physics.volume_barrier):
# phi = -(r - r_b)^2 ln(r / r_b) below r_b, 0 above; phi' and phi'' for the gradient and the
# Gauss-Newton Hessian (derivatives at r_min where r <= 0).
@wp.func
def barrier_d(r: float):
    if r >= _BARRIER_ONSET:
        return 0.0
    rc = wp.max(r, _BARRIER_R_MIN)
    s = rc - _BARRIER_ONSET
    return _BARRIER_STIFFNESS * (-2.0 * s * wp.log(rc / _BARRIER_ONSET) - s * s / rc)


@wp.func
def barrier_dd(r: float):
    if r >= _BARRIER_ONSET:
        return 0.0
    rc = wp.max(r, _BARRIER_R_MIN)
    s = rc - _BARRIER_ONSET
    return _BARRIER_STIFFNESS * (-2.0 * wp.log(rc / _BARRIER_ONSET) - 4.0 * s / rc + s * s / (rc * rc))


@wp.func
def tet_energy(c: float, k: float, dmp: float, c_start: float):
    dc = c - c_start
    e = 0.5 * k * c * c + 0.5 * dmp * dc * dc
    r = c + 1.0
    if r < _BARRIER_ONSET:
        if r <= 0.0:
            return _INVERTED_ENERGY
        s = r - _BARRIER_ONSET
        e = e - _BARRIER_STIFFNESS * k * s * s * wp.log(r / _BARRIER_ONSET)
    return e


@wp.func
def node_energy(x: wp.vec3, mu: float, z: wp.vec3, kh: float, target: wp.vec3, f: wp.vec3):
    dz = x - z
    dh = x - target
    return 0.5 * mu * wp.dot(dz, dz) + 0.5 * kh * wp.dot(dh, dh) - wp.dot(f, x)


# Every stage's springs in one launch: a SpringSet per stage set (its arrays, read in place, so the
# stages keep filling their own buffers), spring k of the pool being spring spring_local[k] of set
# spring_set[k]. Unused arrays (rest_length of axis springs, axis of distance springs) are dummies.
@wp.struct
class SpringSet:
    node: wp.array(dtype=wp.int32)
    point: wp.array(dtype=wp.vec3)
    stiffness: wp.array(dtype=float)
    rest_length: wp.array(dtype=float)
    axis: wp.array(dtype=wp.vec3)
    is_axis: int
    one_sided: int


# Distance springs (muscles): E = k/2 (|p - x| - l0)^2, dE/dx = k (l - l0) (x - p) / l.
# One-sided (contact, pushing out of the ball of radius l0 about p): the same with
# s = min(0, l - l0), E = k/2 s^2, dE/dx = k s (x - p) / l.
# Axis springs (sliding supports): E = k/2 ((x - p) . a)^2, dE/dx = k ((x - p) . a) a.
# One-sided (contact, the half-space (x - p) . a >= 0): s = min(0, (x - p) . a), E = k/2 s^2,
# dE/dx = k s a.
@wp.func
def spring_energy_grad(s: SpringSet, k: int, x: wp.vec3):
    r = x - s.point[k]
    g = wp.vec3(0.0)
    st = float(0.0)
    if s.is_axis != 0:
        a = s.axis[k]
        st = wp.dot(r, a)
        if s.one_sided != 0:
            st = wp.min(st, 0.0)
        g = s.stiffness[k] * st * a
    else:
        l = wp.length(r)
        st = l - s.rest_length[k]
        if s.one_sided != 0:
            st = wp.min(st, 0.0)
        if l > 0.0:
            g = s.stiffness[k] * st / l * r
    return 0.5 * s.stiffness[k] * st * st, g
