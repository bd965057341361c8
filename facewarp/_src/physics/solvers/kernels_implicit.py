"""Warp kernels of the implicit Euler step (:mod:`.implicit`): the incremental potential, its
gradient and its PSD Hessian blocks, on any device.

The potential of one step (see :mod:`facewarp._src.physics.potential`, the float64 NumPy
reference of the same terms):

    Phi(x) = sum_i mu_i / 2 |x_i - z_i|^2 + sum_held k_h / 2 |x - target|^2 - f . x
           + sum_edges [k0 (C^2 / 2 + C^4 / 4) + d / (2 h) (C - C_n)^2]         (Eq. 6.4.4, 6.4.6)
           + sum_faces [k / 2 C^2 + d / (2 h) (C - C_n)^2]                             (Eq. 6.4.7)
           + sum_tets  [k / 2 C^2 + d / (2 h) (C - C_n)^2]                             (Eq. 6.4.8)
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
    edge_indices: wp.array(dtype=wp.vec2i),
    edge_rest_length: wp.array(dtype=float),
    positions: wp.array(dtype=wp.vec3),
    c_out: wp.array(dtype=float),
):
    e = wp.tid()
    d = positions[edge_indices[e][0]] - positions[edge_indices[e][1]]
    c_out[e] = wp.length(d) / edge_rest_length[e] - 1.0


@wp.kernel
def _face_constraints(
    face_indices: wp.array(dtype=wp.vec3i),
    face_rest_area: wp.array(dtype=float),
    positions: wp.array(dtype=wp.vec3),
    c_out: wp.array(dtype=float),
):
    t = wp.tid()
    xi = positions[face_indices[t][0]]
    nn = wp.cross(positions[face_indices[t][1]] - xi, positions[face_indices[t][2]] - xi)
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
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    tet_rest_inverse: wp.array(dtype=wp.mat33),
    positions: wp.array(dtype=wp.vec3),
    c_out: wp.array(dtype=float),
    g_out: wp.array(dtype=wp.mat33),
):
    t = wp.tid()
    c_out[t] = _tet_constraint(tet_indices, tet_rest_volume, positions, t)
    g_out[t] = _green(_deformation(positions[tet_indices[t][0]], positions[tet_indices[t][1]],
                                   positions[tet_indices[t][2]], positions[tet_indices[t][3]], tet_rest_inverse[t]))


@wp.kernel
def _inertial_target(
    damping_rate: float,
    h: float,
    cranium_velocity: wp.array(dtype=wp.vec3),
    positions: wp.array(dtype=wp.vec3),
    prev_positions: wp.array(dtype=wp.vec3),
    z_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    x = positions[i]
    ah = damping_rate * h
    w = x + h * (cranium_velocity[0] + wp.cross(cranium_velocity[1], x))
    z_out[i] = (2.0 * x - prev_positions[i] + ah * w) / (1.0 + ah)


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


@wp.func
def _tet_e(c: float, k: float, dmp: float, c_start: float):
    dc = c - c_start
    return 0.5 * k * c * c + 0.5 * dmp * dc * dc


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
    edge_indices: wp.array(dtype=wp.vec2i),
    edge_rest_length: wp.array(dtype=float),
    edge_k0: wp.array(dtype=float),
    edge_damping: wp.array(dtype=float),
    edge_c_start: wp.array(dtype=float),
    inv_h: float,
    positions: wp.array(dtype=wp.vec3),
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
    face_indices: wp.array(dtype=wp.vec3i),
    face_rest_area: wp.array(dtype=float),
    face_k: wp.array(dtype=float),
    face_damping: wp.array(dtype=float),
    face_c_start: wp.array(dtype=float),
    inv_h: float,
    slot_offset: int,
    positions: wp.array(dtype=wp.vec3),
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
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    tet_k: wp.array(dtype=float),
    tet_damping: wp.array(dtype=float),
    tet_c_start: wp.array(dtype=float),
    tet_rest_inverse: wp.array(dtype=wp.mat33),
    tet_shear_k: wp.array(dtype=float),
    tet_shear_damping: wp.array(dtype=float),
    tet_g_start: wp.array(dtype=wp.mat33),
    inv_h: float,
    slot_offset: int,
    positions: wp.array(dtype=wp.vec3),
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
    s = (tet_k[t] * c + dmp * dc) / (6.0 * v0)
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
    vertex_mass: wp.array(dtype=float),
    vertex_fixed: wp.array(dtype=wp.int32),
    vertex_hold_stiffness: wp.array(dtype=float),
    mass_scale: float,
    z: wp.array(dtype=wp.vec3),
    targets: wp.array(dtype=wp.vec3),
    external_force: wp.array(dtype=wp.vec3),
    positions: wp.array(dtype=wp.vec3),
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
    springs: wp.array(dtype=SpringSet),
    spring_set: wp.array(dtype=wp.int32),
    spring_local: wp.array(dtype=wp.int32),
    positions: wp.array(dtype=wp.vec3),
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
    node: wp.array(dtype=wp.int32),
    start: wp.array(dtype=wp.int32),
    order: wp.array(dtype=wp.int32),
    vertex_fixed: wp.array(dtype=wp.int32),
    slots: wp.array(dtype=wp.vec3),
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


@wp.kernel
def _zero_fixed(vertex_fixed: wp.array(dtype=wp.int32), v: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    if vertex_fixed[i] != 0:
        v[i] = wp.vec3(0.0)


# ---------------------------------------------------------------------------- Hessian blocks
# PSD Hessian blocks (the same approximations as potential.StepPotential.hessian):
#   distance: a n n^T + b (I - n n^T) with a = (k0 (1 + 3 C^2) + d/h) / D0^2 and
#             b = max(dE/dC, 0) / (D0 l) (the transverse term dropped when compressed);
#             blocks (i,i) = (j,j) = H, (i,j) = (j,i) = -H;
#   area, volume: Gauss-Newton (k + d/h) g_a g_b^T with g = grad C (the neglected k C grad^2 C
#             vanishes at rest);
# each written into the element's block slots: edges 4 (ii, ij, ji, jj), faces 9, tets 16, corner
# pair (a, b) -> p = a * c + b, pair-major: slot offset + p * count + element (neighbouring threads
# write neighbouring blocks: coalesced).
@wp.kernel
def _edge_hessian(
    edge_indices: wp.array(dtype=wp.vec2i),
    edge_rest_length: wp.array(dtype=float),
    edge_k0: wp.array(dtype=float),
    edge_damping: wp.array(dtype=float),
    edge_c_start: wp.array(dtype=float),
    inv_h: float,
    positions: wp.array(dtype=wp.vec3),
    blocks_out: wp.array(dtype=wp.mat33),
):
    e = wp.tid()
    d = positions[edge_indices[e][0]] - positions[edge_indices[e][1]]
    l = wp.length(d)
    d0 = edge_rest_length[e]
    c = l / d0 - 1.0
    k0 = edge_k0[e]
    dmp = edge_damping[e] * inv_h
    n = wp.vec3(0.0)
    if l > 0.0:
        n = d / l
    nn = _outer(n, n)
    a = (k0 * (1.0 + 3.0 * c * c) + dmp) / (d0 * d0)
    b = float(0.0)
    if l > 0.0:
        b = wp.max(k0 * (c + c * c * c) + dmp * (c - edge_c_start[e]), 0.0) / (d0 * l)
    H = a * nn + b * (wp.identity(n=3, dtype=float) - nn)
    ne = edge_indices.shape[0]
    blocks_out[e] = H
    blocks_out[ne + e] = -H
    blocks_out[2 * ne + e] = -H
    blocks_out[3 * ne + e] = H


@wp.kernel
def _face_hessian(
    face_indices: wp.array(dtype=wp.vec3i),
    face_rest_area: wp.array(dtype=float),
    face_k: wp.array(dtype=float),
    face_damping: wp.array(dtype=float),
    inv_h: float,
    block_offset: int,
    positions: wp.array(dtype=wp.vec3),
    blocks_out: wp.array(dtype=wp.mat33),
):
    t = wp.tid()
    nf = face_indices.shape[0]
    o = block_offset + t
    xi = positions[face_indices[t][0]]
    e1 = positions[face_indices[t][1]] - xi
    e2 = positions[face_indices[t][2]] - xi
    nn = wp.cross(e1, e2)
    nl = wp.length(nn)
    g1 = wp.vec3(0.0)
    g2 = wp.vec3(0.0)
    if nl > 0.0:
        m = nn / nl
        g1 = 0.5 * wp.cross(e2, m)
        g2 = 0.5 * wp.cross(m, e1)
    g0 = -(g1 + g2)
    a0 = face_rest_area[t]
    s = (face_k[t] + face_damping[t] * inv_h) / (a0 * a0)
    blocks_out[o] = s * _outer(g0, g0)
    blocks_out[o + nf] = s * _outer(g0, g1)
    blocks_out[o + 2 * nf] = s * _outer(g0, g2)
    blocks_out[o + 3 * nf] = s * _outer(g1, g0)
    blocks_out[o + 4 * nf] = s * _outer(g1, g1)
    blocks_out[o + 5 * nf] = s * _outer(g1, g2)
    blocks_out[o + 6 * nf] = s * _outer(g2, g0)
    blocks_out[o + 7 * nf] = s * _outer(g2, g1)
    blocks_out[o + 8 * nf] = s * _outer(g2, g2)


@wp.kernel
def _tet_hessian(
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    tet_k: wp.array(dtype=float),
    tet_damping: wp.array(dtype=float),
    tet_rest_inverse: wp.array(dtype=wp.mat33),
    tet_shear_k: wp.array(dtype=float),
    tet_shear_damping: wp.array(dtype=float),
    inv_h: float,
    block_offset: int,
    positions: wp.array(dtype=wp.vec3),
    blocks_out: wp.array(dtype=wp.mat33),
):
    t = wp.tid()
    nt = tet_indices.shape[0]
    o = block_offset + t
    xi = positions[tet_indices[t][0]]
    e1 = positions[tet_indices[t][1]] - xi
    e2 = positions[tet_indices[t][2]] - xi
    e3 = positions[tet_indices[t][3]] - xi
    g1 = wp.cross(e2, e3) / 6.0
    g2 = wp.cross(e3, e1) / 6.0
    g3 = wp.cross(e1, e2) / 6.0
    g0 = -(g1 + g2 + g3)
    v0 = tet_rest_volume[t]
    s = (tet_k[t] + tet_damping[t] * inv_h) / (v0 * v0)
    # shear term, Gauss-Newton: (k_s + d_s / h) dG/dx_a : dG/dx_b, block (c, d) =
    # (k_s + d_s / h) / 2 ((F F^T)_cd (b_a . b_b) + (F b_b)_c (F b_a)_d)
    ss = 0.5 * (tet_shear_k[t] + tet_shear_damping[t] * inv_h)
    if ss > 0.0:
        dmi = tet_rest_inverse[t]
        f = wp.matrix_from_cols(e1, e2, e3) * dmi
        ff = f * wp.transpose(f)
        b1 = _row(dmi, 0)
        b2 = _row(dmi, 1)
        b3 = _row(dmi, 2)
        b0 = -(b1 + b2 + b3)
        for a in range(4):
            ga = _pick4(g0, g1, g2, g3, a)
            ba = _pick4(b0, b1, b2, b3, a)
            for b in range(4):
                bb = _pick4(b0, b1, b2, b3, b)
                blocks_out[o + (4 * a + b) * nt] = s * _outer(ga, _pick4(g0, g1, g2, g3, b)) + ss * (
                    wp.dot(ba, bb) * ff + _outer(f * bb, f * ba))
    else:
        for a in range(4):
            ga = _pick4(g0, g1, g2, g3, a)
            for b in range(4):
                blocks_out[o + (4 * a + b) * nt] = s * _outer(ga, _pick4(g0, g1, g2, g3, b))


# Diagonal blocks of every node: (mu + k_h) I; fixed nodes: the identity (their DOFs are not
# unknowns; the right-hand side there is 0).
@wp.kernel
def _node_hessian(
    vertex_mass: wp.array(dtype=float),
    vertex_hold_stiffness: wp.array(dtype=float),
    mass_scale: float,
    block_offset: int,
    blocks_out: wp.array(dtype=wp.mat33),
):
    i = wp.tid()
    s = vertex_mass[i] * mass_scale + vertex_hold_stiffness[i]
    blocks_out[block_offset + i] = s * wp.identity(n=3, dtype=float)


# Springs: distance k (n n^T + max(1 - l0/l, 0) (I - n n^T)); axis k a a^T. One-sided springs:
# k n n^T (distance; the transverse term k (1 - l0/l) < 0 of a compressed spring dropped) and
# k a a^T (axis) where the spring is compressed, 0 where it is slack. ``slack`` > 0 [m] keeps the
# block also for springs slack by less than that (the CPU L-BFGS's factorised model: a contact
# about to close is in the preconditioner; the device method after a failed line search); the
# exact Hessian has slack = 0. ``slack`` is a one-element array so the device can change it.
@wp.kernel
def _spring_hessian(
    springs: wp.array(dtype=SpringSet),
    spring_set: wp.array(dtype=wp.int32),
    spring_local: wp.array(dtype=wp.int32),
    slack: wp.array(dtype=float),
    block_offset: int,
    positions: wp.array(dtype=wp.vec3),
    blocks_out: wp.array(dtype=wp.mat33),
):
    k = wp.tid()
    s = springs[spring_set[k]]
    j = spring_local[k]
    r = positions[s.node[j]] - s.point[j]
    kj = s.stiffness[j]
    H = wp.mat33(0.0)
    gap = float(0.0)  # how far a one-sided spring is from closing [m]
    if s.is_axis != 0:
        a = s.axis[j]
        H = kj * _outer(a, a)
        gap = wp.dot(r, a)
    else:
        l = wp.length(r)
        H = kj * wp.identity(n=3, dtype=float)
        if l > 0.0:
            n = r / l
            nn = _outer(n, n)
            H = kj * (nn + wp.max(1.0 - s.rest_length[j] / l, 0.0) * (wp.identity(n=3, dtype=float) - nn))
            if s.one_sided != 0:
                H = kj * nn
        gap = l - s.rest_length[j]
    if s.one_sided != 0 and gap >= slack[0]:
        H = wp.mat33(0.0)
    blocks_out[block_offset + k] = H


# Every BSR block sums its block slots in a fixed order; a block in a fixed node's row or column
# is the identity on the diagonal and 0 elsewhere.
@wp.kernel
def _gather_blocks(
    start: wp.array(dtype=wp.int32),
    order: wp.array(dtype=wp.int32),
    block_row: wp.array(dtype=wp.int32),
    block_col: wp.array(dtype=wp.int32),
    vertex_fixed: wp.array(dtype=wp.int32),
    blocks: wp.array(dtype=wp.mat33),
    values_out: wp.array(dtype=wp.mat33),
):
    b = wp.tid()
    r = block_row[b]
    c = block_col[b]
    if vertex_fixed[r] != 0 or vertex_fixed[c] != 0:
        if r == c:
            values_out[b] = wp.identity(n=3, dtype=float)
        else:
            values_out[b] = wp.mat33(0.0)
        return
    H = wp.mat33(0.0)
    for s in range(start[b], start[b + 1]):
        H = H + blocks[order[s]]
    values_out[b] = H


# ---------------------------------------------------------------------------- vector updates
# Start of a step: fixed nodes on their targets, free nodes at x_n + (x_n - x_prev) * extrapolate
# (the previous motion continued: a good first guess of a slowly changing quasi-static shape).
@wp.kernel
def _initial_guess(
    vertex_fixed: wp.array(dtype=wp.int32),
    extrapolate: float,
    targets: wp.array(dtype=wp.vec3),
    positions: wp.array(dtype=wp.vec3),
    prev_positions: wp.array(dtype=wp.vec3),
    x_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    if vertex_fixed[i] != 0:
        x_out[i] = targets[i]
    else:
        x = positions[i]
        x_out[i] = x + extrapolate * (x - prev_positions[i])


# The device method's first guess falls back to x_n (free nodes) when the extrapolated one
# inverts a tet (the host methods do the same on the host): _guess_inverted flags it,
# _guess_fallback undoes the extrapolation.
@wp.kernel
def _guess_inverted(
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    flag: wp.array(dtype=wp.int32),
):
    t = wp.tid()
    if _tet_constraint(tet_indices, tet_rest_volume, x, t) <= -1.0:  # the line search's test
        flag[0] = 1


@wp.kernel
def _guess_fallback(
    flag: wp.array(dtype=wp.int32),
    vertex_fixed: wp.array(dtype=wp.int32),
    positions: wp.array(dtype=wp.vec3),
    x_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    if flag[0] != 0 and vertex_fixed[i] == 0:
        x_out[i] = positions[i]


# ---------------------------------------------------------------------------- reductions
# Deterministic sums of the rows of an energy array (the energy at x: one row; the line search's
# trials: one row each): each thread adds a fixed chunk of a row in order (float64), then one
# thread per row adds the chunks in order and writes total_out[first_slot + j]. No atomics: the
# same sum on every run and device. The solver takes chunks of about sqrt(n) entries, so neither
# pass has a long serial chain (measured on an H100 at level 2: threads striding over the whole
# array, 512 of them, took 10x as long as contiguous chunks: every load a cache miss).
@wp.kernel
def _chunk_sums_rows(values: wp.array2d(dtype=float), chunk: int, partial_out: wp.array2d(dtype=wp.float64)):
    j, c = wp.tid()
    n = values.shape[1]
    s = wp.float64(0.0)
    for i in range(c * chunk, wp.min((c + 1) * chunk, n)):
        s = s + wp.float64(values[j, i])
    partial_out[j, c] = s


@wp.kernel
def _final_sums_rows(partial: wp.array2d(dtype=wp.float64), first_slot: int, total_out: wp.array(dtype=wp.float64)):
    j = wp.tid()
    s = wp.float64(0.0)
    for i in range(partial.shape[1]):
        s = s + partial[j, i]
    total_out[first_slot + j] = s


# ---------------------------------------------------------------------------- device line search
# A trial position: x_i + t d_i on a free node (the arithmetic of _axpy_free / _take_step, so the
# step taken is the trial evaluated), x_i on a fixed one.
@wp.func
def _trial_x(x: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3), vertex_fixed: wp.array(dtype=wp.int32),
             i: int, t: float):
    if vertex_fixed[i] != 0:
        return x[i]
    return x[i] + t * d[i]


# The energies of every line-search trial t_j = 2^-j (row j of energy_out) in one pass: entry i is
# an edge, face, tet, node or spring in the layout of the solver's energy array (i < E edges, then
# F faces, T tets, N nodes, the pooled springs), the same terms as the energy kernels. A trial that
# inverts a tet (C <= -1) gets energy 1e30 in that tet's entry: never accepted, as the host line
# search rejects inverting steps.
@wp.kernel
def _trial_energies(
    edge_indices: wp.array(dtype=wp.vec2i),
    edge_rest_length: wp.array(dtype=float),
    edge_k0: wp.array(dtype=float),
    edge_damping: wp.array(dtype=float),
    edge_c_start: wp.array(dtype=float),
    face_indices: wp.array(dtype=wp.vec3i),
    face_rest_area: wp.array(dtype=float),
    face_k: wp.array(dtype=float),
    face_damping: wp.array(dtype=float),
    face_c_start: wp.array(dtype=float),
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    tet_k: wp.array(dtype=float),
    tet_damping: wp.array(dtype=float),
    tet_c_start: wp.array(dtype=float),
    tet_rest_inverse: wp.array(dtype=wp.mat33),
    tet_shear_k: wp.array(dtype=float),
    tet_shear_damping: wp.array(dtype=float),
    tet_g_start: wp.array(dtype=wp.mat33),
    vertex_mass: wp.array(dtype=float),
    vertex_fixed: wp.array(dtype=wp.int32),
    vertex_hold_stiffness: wp.array(dtype=float),
    mass_scale: float,
    z: wp.array(dtype=wp.vec3),
    targets: wp.array(dtype=wp.vec3),
    external_force: wp.array(dtype=wp.vec3),
    springs: wp.array(dtype=SpringSet),
    spring_set: wp.array(dtype=wp.int32),
    spring_local: wp.array(dtype=wp.int32),
    inv_h: float,
    x: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    energy_out: wp.array2d(dtype=float),
):
    i = wp.tid()
    trials = energy_out.shape[0]
    ne = edge_indices.shape[0]
    nf = face_indices.shape[0]
    nt = tet_indices.shape[0]
    nv = vertex_mass.shape[0]
    t = float(1.0)
    if i < ne:
        a = edge_indices[i][0]
        b = edge_indices[i][1]
        dmp = edge_damping[i] * inv_h
        for j in range(trials):
            energy_out[j, i] = _edge_e(_trial_x(x, d, vertex_fixed, a, t), _trial_x(x, d, vertex_fixed, b, t),
                                       edge_rest_length[i], edge_k0[i], dmp, edge_c_start[i])
            t = t * 0.5
    elif i < ne + nf:
        f = i - ne
        a = face_indices[f][0]
        b = face_indices[f][1]
        fc = face_indices[f][2]
        dmp = face_damping[f] * inv_h
        for j in range(trials):
            energy_out[j, i] = _face_e(_trial_x(x, d, vertex_fixed, a, t), _trial_x(x, d, vertex_fixed, b, t),
                                       _trial_x(x, d, vertex_fixed, fc, t), face_rest_area[f], face_k[f], dmp,
                                       face_c_start[f])
            t = t * 0.5
    elif i < ne + nf + nt:
        q = i - ne - nf
        tet = tet_indices[q]
        dmp = tet_damping[q] * inv_h
        ks = tet_shear_k[q]
        ds = tet_shear_damping[q] * inv_h
        for j in range(trials):
            xa = _trial_x(x, d, vertex_fixed, tet[0], t)
            xb = _trial_x(x, d, vertex_fixed, tet[1], t)
            xc = _trial_x(x, d, vertex_fixed, tet[2], t)
            xd = _trial_x(x, d, vertex_fixed, tet[3], t)
            c = _tet_c(xa, xb, xc, xd, tet_rest_volume[q])
            e = _tet_e(c, tet_k[q], dmp, tet_c_start[q])
            if ks > 0.0 or ds > 0.0:
                e = e + _shear_e(_green(_deformation(xa, xb, xc, xd, tet_rest_inverse[q])), ks, ds, tet_g_start[q])
            if c <= -1.0:
                e = 1.0e30
            energy_out[j, i] = e
            t = t * 0.5
    elif i < ne + nf + nt + nv:
        v = i - ne - nf - nt
        for j in range(trials):
            e = float(0.0)
            if vertex_fixed[v] == 0:
                e = _node_e(_trial_x(x, d, vertex_fixed, v, t), vertex_mass[v] * mass_scale, z[v],
                            vertex_hold_stiffness[v], targets[v], external_force[v])
            energy_out[j, i] = e
            t = t * 0.5
    else:
        k = i - ne - nf - nt - nv
        s = springs[spring_set[k]]
        l = spring_local[k]
        for j in range(trials):
            e, g = _spring_e_grad(s, l, _trial_x(x, d, vertex_fixed, s.node[l], t))
            energy_out[j, i] = e
            t = t * 0.5


# Backtracking on the device: trials t = 1, 1/2, 1/4, 1/8 have energies totals[1..4]; take the
# first that does not raise the energy above totals[0] (within float32 rounding), else the
# lowest if it is below, else no move (t = 0).
@wp.kernel
def _select_step(totals: wp.array(dtype=wp.float64), trials: int, t_out: wp.array(dtype=float)):
    e0 = totals[0]
    tol = wp.float64(1.0e-6) * wp.abs(e0) + wp.float64(1.0e-20)
    t = float(1.0)
    best = int(-1)
    for j in range(trials):
        if best < 0 and totals[1 + j] <= e0 + tol:
            best = j
    if best < 0:
        lowest = e0
        for j in range(trials):
            if totals[1 + j] < lowest:
                lowest = totals[1 + j]
                best = j
    if best < 0:
        t_out[0] = 0.0
    else:
        for j in range(best):
            t = t * 0.5
        t_out[0] = t


# The Newton system's block-Jacobi preconditioner and right-hand side in one launch: the inverse
# of every 3 x 3 diagonal block (block index diag[i]; a singular block falls back to the
# identity) and rhs = -grad.
@wp.kernel
def _newton_system(diag: wp.array(dtype=wp.int32), values: wp.array(dtype=wp.mat33), grad: wp.array(dtype=wp.vec3),
                   inv_out: wp.array(dtype=wp.mat33), rhs_out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    B = values[diag[i]]
    if wp.abs(wp.determinant(B)) > 1.0e-30:
        inv_out[i] = wp.inverse(B)
    else:
        inv_out[i] = wp.identity(n=3, dtype=float)
    rhs_out[i] = -grad[i]


@wp.kernel
def _advance_counter(counter: wp.array(dtype=wp.int32)):
    counter[0] = counter[0] + 1


# ------------------------------------------------------------------------------------------------
# Block-Jacobi preconditioned conjugate gradients in one launch per iteration (the device
# method's linear solve; :meth:`.implicit.SolverImplicit._launch_cg`). Chronopoulos & Gear's
# formulation ("s-step iterative methods for symmetric linear systems", J. Comput. Appl. Math. 25,
# 1989) computes both inner products of an iteration, (r, u) and (A u, u) with u = P r, in the same
# phase, and carries s = A p by recurrence, so an iteration is one vector update and one
# matrix-vector product, each also adding its inner product into CG_SLOTS partial sums (float64
# atomics spread over slots so that no single address takes every thread's add); _cg_iteration
# fuses the two into one launch (see there). Each launch recomputes alpha and beta from the sums
# (every thread the same arithmetic); thread 0 also records them. The iteration count is fixed
# (no host round trip: capturable in a CUDA graph); a breakdown or a residual below 1e-12 of the
# first one freezes the remaining iterations.
CG_SLOTS = 32


@wp.func
def _slot_total(sums: wp.array2d(dtype=wp.float64), row: int):
    s = wp.float64(0.0)
    for k in range(CG_SLOTS):
        s += sums[row, k]
    return s


@wp.kernel
def _zero_2d(a: wp.array2d(dtype=wp.float64)):
    i, j = wp.tid()
    a[i, j] = wp.float64(0.0)


@wp.kernel
def _cg_start(
    inv: wp.array(dtype=wp.mat33),
    b: wp.array(dtype=wp.vec3),
    x_out: wp.array(dtype=wp.vec3),
    r: wp.array(dtype=wp.vec3),
    u: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=wp.vec3),
    s: wp.array(dtype=wp.vec3),
    sums: wp.array2d(dtype=wp.float64),
):
    i = wp.tid()
    ri = b[i]
    ui = inv[i] * ri
    r[i] = ri
    u[i] = ui
    x_out[i] = wp.vec3(0.0)
    p[i] = wp.vec3(0.0)
    s[i] = wp.vec3(0.0)
    wp.atomic_add(sums, 0, i % CG_SLOTS, wp.float64(wp.dot(ri, ui)))


# w = A u (A block-sparse, rows offsets[i]..offsets[i+1]) and (w, u) into sums[row].
@wp.kernel
def _cg_matvec(
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array(dtype=wp.mat33),
    u: wp.array(dtype=wp.vec3),
    row: int,
    w: wp.array(dtype=wp.vec3),
    sums: wp.array2d(dtype=wp.float64),
):
    i = wp.tid()
    acc = wp.vec3(0.0)
    for k in range(offsets[i], offsets[i + 1]):
        acc += values[k] * u[columns[k]]
    w[i] = acc
    wp.atomic_add(sums, row, i % CG_SLOTS, wp.float64(wp.dot(acc, u[i])))


# alpha_k, beta_k of iteration k from sums rows 2k = (r_k, u_k) and 2k + 1 = (A u_k, u_k), and whether
# the iteration is active (not after a breakdown or a residual below 1e-12 of the first).
@wp.func
def _cg_coefficients(sums: wp.array2d(dtype=wp.float64), scalars: wp.array2d(dtype=wp.float64), it: int):
    gamma = _slot_total(sums, 2 * it)
    delta = _slot_total(sums, 2 * it + 1)
    alpha = wp.float64(0.0)
    beta = wp.float64(0.0)
    den = wp.float64(0.0)
    active = int(1)
    if it > 0:
        if scalars[it - 1, 2] == wp.float64(0.0):
            active = 0
    if active == 1:
        if it > 0:
            if gamma <= wp.float64(1.0e-12) * scalars[0, 1]:
                active = 0
    if active == 1:
        if it == 0:
            den = delta
        else:
            beta = gamma / scalars[it - 1, 1]
            den = delta - beta * gamma / scalars[it - 1, 0]
        if gamma > wp.float64(0.0) and den > wp.float64(0.0):
            alpha = gamma / den
        else:
            active = 0
    return alpha, beta, gamma, active


# One whole CG iteration k in one launch. Its vector update p = u + beta p, s = w + beta s,
# x += alpha p, r -= alpha s, u = P r only needs a node's own entries, and so does the next
# product's u at a neighbour j: u_j = P_j (r_j - alpha (w_j + beta s_j)) from the iteration's
# input. So each thread updates its node and also forms A u for its row from its neighbours'
# inputs (recomputed, not read back: r, s, w are double-buffered, *_in read, *_out written; x, p
# and u are only ever read by their own thread). (r, u) goes into sums row 2k + 2 and (A u, u)
# into row 2k + 3; the last iteration (``last``) skips the product. scalars[k] = (alpha_k,
# gamma_k, active).
@wp.kernel
def _cg_iteration(
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array(dtype=wp.mat33),
    inv: wp.array(dtype=wp.mat33),
    it: int,
    last: int,
    sums: wp.array2d(dtype=wp.float64),
    scalars: wp.array2d(dtype=wp.float64),
    r_in: wp.array(dtype=wp.vec3),
    s_in: wp.array(dtype=wp.vec3),
    w_in: wp.array(dtype=wp.vec3),
    x: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=wp.vec3),
    u: wp.array(dtype=wp.vec3),
    r_out: wp.array(dtype=wp.vec3),
    s_out: wp.array(dtype=wp.vec3),
    w_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    alpha, beta, gamma, active = _cg_coefficients(sums, scalars, it)
    if i == 0:
        scalars[it, 0] = alpha
        scalars[it, 1] = gamma
        scalars[it, 2] = wp.float64(active)
    if active == 0:
        return
    a = float(alpha)
    bt = float(beta)
    pi = u[i] + bt * p[i]
    si = w_in[i] + bt * s_in[i]
    p[i] = pi
    x[i] = x[i] + a * pi
    ri = r_in[i] - a * si
    ui = inv[i] * ri
    r_out[i] = ri
    s_out[i] = si
    u[i] = ui
    wp.atomic_add(sums, 2 * it + 2, i % CG_SLOTS, wp.float64(wp.dot(ri, ui)))
    if last != 0:
        return
    acc = wp.vec3(0.0)
    for k in range(offsets[i], offsets[i + 1]):
        j = columns[k]
        acc += values[k] * (inv[j] * (r_in[j] - a * (w_in[j] + bt * s_in[j])))
    w_out[i] = acc
    wp.atomic_add(sums, 2 * it + 3, i % CG_SLOTS, wp.float64(wp.dot(acc, ui)))


# The line search's step: x += t d on the free nodes, and the largest step (t |d_i|) and
# direction (|d_i|) of a free node for the convergence test (largest reset by _newton_continue).
@wp.kernel
def _take_step(
    vertex_fixed: wp.array(dtype=wp.int32),
    d: wp.array(dtype=wp.vec3),
    t: wp.array(dtype=float),
    x: wp.array(dtype=wp.vec3),
    largest: wp.array(dtype=float),
):
    i = wp.tid()
    if vertex_fixed[i] == 0:
        x[i] = x[i] + t[0] * d[i]
        wp.atomic_max(largest, 0, t[0] * wp.length(d[i]))
        wp.atomic_max(largest, 1, wp.length(d[i]))


# Convergence of the device method's adaptive Newton loop: from the largest step of a free node
# this iteration (t * |d_i|, _take_step), the loop's condition (continue while above tolerance, at
# most max_iterations), decided on the device so the loop can be a conditional node of a CUDA graph.
@wp.kernel
def _newton_start(
    counter: wp.array(dtype=wp.int32),
    largest: wp.array(dtype=float),
    cond: wp.array(dtype=wp.int32),
    slack: wp.array(dtype=float),
):
    counter[0] = 0
    largest[0] = 0.0
    largest[1] = 0.0
    cond[0] = 1
    slack[0] = 0.0


# After an iteration (largest = (max t |d_i|, max |d_i|) over free nodes): a line search that found
# no lower energy along a direction longer than the tolerance (t = 0; a direction from the exact
# Hessian ran into a contact spring that was slack at x) is retried once with the springs within
# ``contact_slack`` of closing in the Hessian; it is never taken as convergence.
@wp.kernel
def _newton_continue(
    tolerance: float,
    max_iterations: int,
    contact_slack: float,
    t: wp.array(dtype=float),
    counter: wp.array(dtype=wp.int32),
    largest: wp.array(dtype=float),
    cond: wp.array(dtype=wp.int32),
    total: wp.array(dtype=wp.int64),
    slack: wp.array(dtype=float),
):
    k = counter[0] + 1
    counter[0] = k
    total[0] = total[0] + wp.int64(1)
    go = int(0)
    if t[0] == 0.0 and slack[0] == 0.0 and largest[1] > tolerance:
        slack[0] = contact_slack
        if k < max_iterations:
            go = 1
    else:
        slack[0] = 0.0
        if k < max_iterations and largest[0] > tolerance:
            go = 1
    cond[0] = go
    largest[0] = 0.0
    largest[1] = 0.0
