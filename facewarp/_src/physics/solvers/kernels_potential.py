"""Warp kernels of the implicit Euler step's incremental potential: the step's start (the
dashpots' constraints, the inertial target), every term's energy and its gradient, on any device
(launched by :class:`~.incremental.IncrementalPotential`; the Hessian blocks are in
:mod:`.kernels_hessian`, the device line search in :mod:`.kernels_line_search`, the linear solve
in :mod:`.kernels_linear`).

The potential of one step (see :mod:`facewarp._src.physics.potential`, the float64 NumPy
reference of the same terms):

    Phi(x) = sum_i mu_i / 2 |x_i - z_i|^2 + sum_held k_h / 2 |x - target|^2 - f . x
           + sum_edges [k0 (C^2 / 2 + C^4 / 4) + d / (2 h) (C - C_n)^2]         (Eq. 6.4.4, 6.4.6)
           + sum_faces [k / 2 C^2 + d / (2 h) (C - C_n)^2]                             (Eq. 6.4.7)
           + sum_tets  [k / 2 C^2 + d / (2 h) (C - C_n)^2 + kappa k phi(C + 1)]        (Eq. 6.4.8)
           + sum_springs E_s(x),

with ``mu = m (1 + alpha h) / h^2``, z the inertial target, C_n the constraint at the step's
start (the strain-rate dashpots). Every element writes its energy into its own entry and its
corner gradients (``dPhi/dx``, the negative force) into its own slots, in the layout of the
explicit force slots (``Model.node_slots``), and every node sums its slots in a fixed order:
deterministic, the same sums on CPU and CUDA. Hessian blocks go to block slots and are summed
per block of a block-sparse (BSR, 3 x 3) matrix in a fixed order likewise. Fixed nodes are not
unknowns: their gradient is 0 and their rows and columns of the Hessian are the identity.
"""

from __future__ import annotations

import warp as wp

from ..volume_barrier import _R_MIN, INVERTED_ENERGY, VOLUME_BARRIER_ONSET, VOLUME_BARRIER_STIFFNESS

_BARRIER_ONSET = wp.constant(VOLUME_BARRIER_ONSET)
_BARRIER_STIFFNESS = wp.constant(VOLUME_BARRIER_STIFFNESS)
_INVERTED_ENERGY = wp.constant(INVERTED_ENERGY)
_BARRIER_R_MIN = wp.constant(_R_MIN)

@wp.func
def _outer(a: wp.vec3, b: wp.vec3):
    return wp.outer(a, b)


@wp.func
def _pick4(g0: wp.vec3, g1: wp.vec3, g2: wp.vec3, g3: wp.vec3, a: int):
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
def _deformation(xi: wp.vec3, xj: wp.vec3, xk: wp.vec3, xl: wp.vec3, rest_inverse: wp.mat33):
    return wp.matrix_from_cols(xj - xi, xk - xi, xl - xi) * rest_inverse


@wp.func
def _green(f: wp.mat33):
    return 0.5 * (wp.transpose(f) * f - wp.identity(n=3, dtype=float))


@wp.func
def _shear_e(g: wp.mat33, k: float, dmp: float, g_start: wp.mat33):
    dg = g - g_start
    return 0.5 * k * wp.ddot(g, g) + 0.5 * dmp * wp.ddot(dg, dg)


@wp.func
def _row(m: wp.mat33, r: int):
    return wp.vec3(m[r, 0], m[r, 1], m[r, 2])


# ---------------------------------------------------------------------------- step start
# The constraints of every element at the step's start (the dashpots' C_n), and the inertial
# target z = (2 x_n - x_prev + alpha h (x_n + h v_c(x_n))) / (1 + alpha h): backward Euler's
# prediction y = x_n + h v_n merged with the mass damping's alpha m / (2 h) |x - x_n - h v_c|^2.
@wp.kernel
def _edge_constraints(
    # Model:
    edge_indices: wp.array(dtype=wp.vec2i),
    edge_rest_length: wp.array(dtype=float),
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    # Out: C_n per edge
    c_out: wp.array(dtype=float),
):
    e = wp.tid()
    d = positions_in[edge_indices[e][0]] - positions_in[edge_indices[e][1]]
    c_out[e] = wp.length(d) / edge_rest_length[e] - 1.0


@wp.kernel
def _face_constraints(
    # Model:
    face_indices: wp.array(dtype=wp.vec3i),
    face_rest_area: wp.array(dtype=float),
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    # Out: C_n per face
    c_out: wp.array(dtype=float),
):
    t = wp.tid()
    xi = positions_in[face_indices[t][0]]
    nn = wp.cross(positions_in[face_indices[t][1]] - xi, positions_in[face_indices[t][2]] - xi)
    c_out[t] = 0.5 * wp.length(nn) / face_rest_area[t] - 1.0


# Volume constraint of tet t at x: C = V / V0 - 1 (C <= -1: inverted).
@wp.func
def _tet_constraint(tet_indices: wp.array(dtype=wp.vec4i), tet_rest_volume: wp.array(dtype=float),
                    x: wp.array(dtype=wp.vec3), t: int):
    xi = x[tet_indices[t][0]]
    e1 = x[tet_indices[t][1]] - xi
    e2 = x[tet_indices[t][2]] - xi
    e3 = x[tet_indices[t][3]] - xi
    return wp.dot(e1, wp.cross(e2, e3)) / 6.0 / tet_rest_volume[t] - 1.0


@wp.kernel
def _tet_constraints(
    # Model:
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    tet_rest_inverse: wp.array(dtype=wp.mat33),
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    # Out: C_n and the Green strain G_n per tet
    c_out: wp.array(dtype=float),
    g_out: wp.array(dtype=wp.mat33),
):
    t = wp.tid()
    c_out[t] = _tet_constraint(tet_indices, tet_rest_volume, positions_in, t)
    g_out[t] = _green(_deformation(positions_in[tet_indices[t][0]], positions_in[tet_indices[t][1]],
                                   positions_in[tet_indices[t][2]], positions_in[tet_indices[t][3]],
                                   tet_rest_inverse[t]))


@wp.kernel
def _inertial_target(
    # Model:
    damping_rate: float,
    h: float,
    # State in: (the cranium's linear and angular velocity: a control)
    cranium_velocity: wp.array(dtype=wp.vec3),
    positions_in: wp.array(dtype=wp.vec3),
    prev_positions_in: wp.array(dtype=wp.vec3),
    # Out:
    z_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    x = positions_in[i]
    ah = damping_rate * h
    w = x + h * (cranium_velocity[0] + wp.cross(cranium_velocity[1], x))
    z_out[i] = (2.0 * x - prev_positions_in[i] + ah * w) / (1.0 + ah)


# Start of a step: fixed nodes on their targets, free nodes at x_n + (x_n - x_prev) * extrapolate
# (the previous motion continued: a good first guess of a slowly changing quasi-static shape).
@wp.kernel
def _initial_guess(
    # Model:
    vertex_fixed: wp.array(dtype=wp.int32),
    extrapolate: float,
    # State in: the targets, x_n, x_prev
    targets: wp.array(dtype=wp.vec3),
    positions_in: wp.array(dtype=wp.vec3),
    prev_positions_in: wp.array(dtype=wp.vec3),
    # Out: the first guess
    x_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    if vertex_fixed[i] != 0:
        x_out[i] = targets[i]
    else:
        x = positions_in[i]
        x_out[i] = x + extrapolate * (x - prev_positions_in[i])


# ---------------------------------------------------------------------------- element energies
# One definition of every term's energy, shared by the energy kernels and the device line
# search's trial kernel (so a trial at t = 0 would sum to the same total, bit for bit).
@wp.func
def _edge_e(xi: wp.vec3, xj: wp.vec3, d0: float, k0: float, dmp: float, c_start: float):
    c = wp.length(xi - xj) / d0 - 1.0
    dc = c - c_start
    return k0 * c * c * (0.5 + 0.25 * c * c) + 0.5 * dmp * dc * dc


@wp.func
def _face_e(xi: wp.vec3, xj: wp.vec3, xk: wp.vec3, a0: float, k: float, dmp: float, c_start: float):
    c = 0.5 * wp.length(wp.cross(xj - xi, xk - xi)) / a0 - 1.0
    dc = c - c_start
    return 0.5 * k * c * c + 0.5 * dmp * dc * dc


@wp.func
def _tet_c(xi: wp.vec3, xj: wp.vec3, xk: wp.vec3, xl: wp.vec3, v0: float):
    return wp.dot(xj - xi, wp.cross(xk - xi, xl - xi)) / 6.0 / v0 - 1.0


# The volume barrier kappa phi(r), r = C + 1 (module doc of facewarp._src.physics.volume_barrier):
# phi = -(r - r_b)^2 ln(r / r_b) below r_b, 0 above; phi' and phi'' for the gradient and the
# Gauss-Newton Hessian (derivatives at r_min where r <= 0).
@wp.func
def _barrier_d(r: float):
    if r >= _BARRIER_ONSET:
        return 0.0
    rc = wp.max(r, _BARRIER_R_MIN)
    s = rc - _BARRIER_ONSET
    return _BARRIER_STIFFNESS * (-2.0 * s * wp.log(rc / _BARRIER_ONSET) - s * s / rc)


@wp.func
def _barrier_dd(r: float):
    if r >= _BARRIER_ONSET:
        return 0.0
    rc = wp.max(r, _BARRIER_R_MIN)
    s = rc - _BARRIER_ONSET
    return _BARRIER_STIFFNESS * (-2.0 * wp.log(rc / _BARRIER_ONSET) - 4.0 * s / rc + s * s / (rc * rc))


@wp.func
def _tet_e(c: float, k: float, dmp: float, c_start: float):
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
def _node_e(x: wp.vec3, mu: float, z: wp.vec3, kh: float, target: wp.vec3, f: wp.vec3):
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
def _spring_e_grad(s: SpringSet, k: int, x: wp.vec3):
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


# ---------------------------------------------------------------------------- energy, gradient
# Distance (Eq. 6.4.4 with k(C) of Eq. 6.4.6): E = k0 (C^2/2 + C^4/4) + d/(2h) (C - C_n)^2,
# dE/dC = k0 (C + C^3) + d/h (C - C_n), dC/dx_i = n / D0 = -dC/dx_j.
@wp.kernel
def _edge_energy(
    # Model:
    edge_indices: wp.array(dtype=wp.vec2i),
    edge_rest_length: wp.array(dtype=float),
    edge_k0: wp.array(dtype=float),
    edge_damping: wp.array(dtype=float),
    inv_h: float,
    # State in: C_n (step start), the iterate x
    edge_c_start: wp.array(dtype=float),
    positions: wp.array(dtype=wp.vec3),
    # Out: energy per edge, gradient slots 2e (i) and 2e + 1 (j)
    energy_out: wp.array(dtype=float),
    slots_out: wp.array(dtype=wp.vec3),
):
    e = wp.tid()
    d = positions[edge_indices[e][0]] - positions[edge_indices[e][1]]
    l = wp.length(d)
    d0 = edge_rest_length[e]
    c = l / d0 - 1.0
    dc = c - edge_c_start[e]
    k0 = edge_k0[e]
    dmp = edge_damping[e] * inv_h
    energy_out[e] = _edge_e(positions[edge_indices[e][0]], positions[edge_indices[e][1]], d0, k0, dmp,
                            edge_c_start[e])
    g = wp.vec3(0.0)
    if l > 0.0:
        g = (k0 * (c + c * c * c) + dmp * dc) / (d0 * l) * d
    slots_out[2 * e] = g
    slots_out[2 * e + 1] = -g


# Area (Eq. 6.4.7): E = k/2 C^2 + d/(2h) (C - C_n)^2, grad = (k C + d/h (C - C_n)) / A0 dA/dx
# (dA/dx as in kernels_tissue._face_forces).
@wp.kernel
def _face_energy(
    # Model:
    face_indices: wp.array(dtype=wp.vec3i),
    face_rest_area: wp.array(dtype=float),
    face_k: wp.array(dtype=float),
    face_damping: wp.array(dtype=float),
    inv_h: float,
    slot_offset: int,
    # State in: C_n (step start), the iterate x
    face_c_start: wp.array(dtype=float),
    positions: wp.array(dtype=wp.vec3),
    # Out: energy per face, gradient slots offset + 3t + (0, 1, 2)
    energy_out: wp.array(dtype=float),
    slots_out: wp.array(dtype=wp.vec3),
):
    t = wp.tid()
    o = slot_offset + 3 * t
    xi = positions[face_indices[t][0]]
    e1 = positions[face_indices[t][1]] - xi
    e2 = positions[face_indices[t][2]] - xi
    nn = wp.cross(e1, e2)
    nl = wp.length(nn)
    a0 = face_rest_area[t]
    c = 0.5 * nl / a0 - 1.0
    dc = c - face_c_start[t]
    dmp = face_damping[t] * inv_h
    energy_out[t] = _face_e(xi, positions[face_indices[t][1]], positions[face_indices[t][2]], a0, face_k[t], dmp,
                            face_c_start[t])
    gj = wp.vec3(0.0)
    gk = wp.vec3(0.0)
    if nl > 0.0:
        m = nn / nl
        s = 0.5 * (face_k[t] * c + dmp * dc) / a0
        gj = s * wp.cross(e2, m)
        gk = s * wp.cross(m, e1)
    slots_out[o] = -(gj + gk)
    slots_out[o + 1] = gj
    slots_out[o + 2] = gk


# Volume (Eq. 6.4.8): E = k/2 C^2 + d/(2h) (C - C_n)^2, grad = (k C + d/h (C - C_n)) / V0 dV/dx.
@wp.kernel
def _tet_energy(
    # Model:
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    tet_k: wp.array(dtype=float),
    tet_damping: wp.array(dtype=float),
    tet_rest_inverse: wp.array(dtype=wp.mat33),
    tet_shear_k: wp.array(dtype=float),
    tet_shear_damping: wp.array(dtype=float),
    inv_h: float,
    slot_offset: int,
    # State in: C_n and G_n (step start), the iterate x
    tet_c_start: wp.array(dtype=float),
    tet_g_start: wp.array(dtype=wp.mat33),
    positions: wp.array(dtype=wp.vec3),
    # Out: energy per tet, gradient slots offset + 4t + (0..3), C at x
    energy_out: wp.array(dtype=float),
    slots_out: wp.array(dtype=wp.vec3),
    c_out: wp.array(dtype=float),
):
    t = wp.tid()
    o = slot_offset + 4 * t
    xi = positions[tet_indices[t][0]]
    e1 = positions[tet_indices[t][1]] - xi
    e2 = positions[tet_indices[t][2]] - xi
    e3 = positions[tet_indices[t][3]] - xi
    v0 = tet_rest_volume[t]
    c = _tet_c(xi, positions[tet_indices[t][1]], positions[tet_indices[t][2]], positions[tet_indices[t][3]], v0)
    c_out[t] = c  # C <= -1: inverted (the host line search rejects such a step)
    dc = c - tet_c_start[t]
    dmp = tet_damping[t] * inv_h
    e = _tet_e(c, tet_k[t], dmp, tet_c_start[t])
    s = (tet_k[t] * (c + _barrier_d(c + 1.0)) + dmp * dc) / (6.0 * v0)
    gj = s * wp.cross(e2, e3)
    gk = s * wp.cross(e3, e1)
    gl = s * wp.cross(e1, e2)
    ks = tet_shear_k[t]
    ds = tet_shear_damping[t] * inv_h
    if ks > 0.0 or ds > 0.0:
        dmi = tet_rest_inverse[t]
        f = wp.matrix_from_cols(e1, e2, e3) * dmi
        g = _green(f)
        g0 = tet_g_start[t]
        e = e + _shear_e(g, ks, ds, g0)
        pm = f * (ks * g + ds * (g - g0)) * wp.transpose(dmi)  # columns: dE/dx_j, dE/dx_k, dE/dx_l
        gj = gj + wp.vec3(pm[0, 0], pm[1, 0], pm[2, 0])
        gk = gk + wp.vec3(pm[0, 1], pm[1, 1], pm[2, 1])
        gl = gl + wp.vec3(pm[0, 2], pm[1, 2], pm[2, 2])
    energy_out[t] = e
    slots_out[o] = -(gj + gk + gl)
    slots_out[o + 1] = gj
    slots_out[o + 2] = gk
    slots_out[o + 3] = gl


# Per node: inertia mu/2 |x - z|^2 (mu = m (1 + alpha h) / h^2), hold k_h/2 |x - target|^2 and
# the external force -f . x; the gradient starts here (element and spring slots are gathered on
# top). Fixed nodes contribute nothing.
@wp.kernel
def _node_energy(
    # Model:
    vertex_mass: wp.array(dtype=float),
    vertex_fixed: wp.array(dtype=wp.int32),
    vertex_hold_stiffness: wp.array(dtype=float),
    mass_scale: float,
    # State in: the inertial target, the fixed / held nodes' targets, the external force (a
    # control), the iterate x
    z: wp.array(dtype=wp.vec3),
    targets: wp.array(dtype=wp.vec3),
    external_force: wp.array(dtype=wp.vec3),
    positions: wp.array(dtype=wp.vec3),
    # Out: energy per node, the gradient's node terms
    energy_out: wp.array(dtype=float),
    grad_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    if vertex_fixed[i] != 0:
        energy_out[i] = 0.0
        grad_out[i] = wp.vec3(0.0)
        return
    x = positions[i]
    mu = vertex_mass[i] * mass_scale
    dz = x - z[i]
    kh = vertex_hold_stiffness[i]
    dh = x - targets[i]
    f = external_force[i]
    energy_out[i] = _node_e(x, mu, z[i], kh, targets[i], f)
    grad_out[i] = mu * dz + kh * dh - f


# Every spring of every stage: energy and gradient (one entry each; gathered per node by _gather_free).
@wp.kernel
def _spring_energy(
    # Model: (the stages' springs, read in place)
    springs: wp.array(dtype=SpringSet),
    spring_set: wp.array(dtype=wp.int32),
    spring_local: wp.array(dtype=wp.int32),
    # State in: the iterate x
    positions: wp.array(dtype=wp.vec3),
    # Out: energy and gradient per pooled spring
    energy_out: wp.array(dtype=float),
    grad_out: wp.array(dtype=wp.vec3),
):
    k = wp.tid()
    s = springs[spring_set[k]]
    j = spring_local[k]
    e, g = _spring_e_grad(s, j, positions[s.node[j]])
    energy_out[k] = e
    grad_out[k] = g


# Gather per node for springs whose nodes may repeat: node[k] takes slots order[start[k]] ..
# (the same fixed-order sum as kernels_tissue._gather, but skipping fixed nodes).
@wp.kernel
def _gather_free(
    # Model:
    node: wp.array(dtype=wp.int32),
    start: wp.array(dtype=wp.int32),
    order: wp.array(dtype=wp.int32),
    vertex_fixed: wp.array(dtype=wp.int32),
    # State in: gradient slots
    slots: wp.array(dtype=wp.vec3),
    # Out: per-node sums, added in place
    forces: wp.array(dtype=wp.vec3),
):
    k = wp.tid()
    i = node[k]
    if vertex_fixed[i] != 0:
        return
    f = wp.vec3(0.0)
    for s in range(start[k], start[k + 1]):
        f = f + slots[order[s]]
    forces[i] = forces[i] + f


# ---------------------------------------------------------------------------- step end
@wp.kernel
def _advance_counter(
    # Out:
    counter: wp.array(dtype=wp.int32),
):
    counter[0] = counter[0] + 1

