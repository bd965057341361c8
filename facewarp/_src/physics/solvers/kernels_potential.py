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

from ..elements import (SpringSet, barrier_d, deformation_gradient, edge_energy, face_energy,  # noqa: F401
                        green_strain, node_energy, shear_energy, spring_energy_grad, tet_constraint_at,
                        mat_columns, tet_energy, tet_strain)
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
    c_out[t] = tet_constraint_at(tet_indices, tet_rest_volume, positions_in, t)
    g_out[t] = green_strain(deformation_gradient(positions_in[tet_indices[t][0]], positions_in[tet_indices[t][1]],
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
    energy_out[e] = edge_energy(positions[edge_indices[e][0]], positions[edge_indices[e][1]], d0, k0, dmp,
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
    energy_out[t] = face_energy(xi, positions[face_indices[t][1]], positions[face_indices[t][2]], a0, face_k[t], dmp,
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
    c = tet_strain(xi, positions[tet_indices[t][1]], positions[tet_indices[t][2]], positions[tet_indices[t][3]], v0)
    c_out[t] = c  # C <= -1: inverted (the host line search rejects such a step)
    dc = c - tet_c_start[t]
    dmp = tet_damping[t] * inv_h
    e = tet_energy(c, tet_k[t], dmp, tet_c_start[t])
    s = (tet_k[t] * (c + barrier_d(c + 1.0)) + dmp * dc) / (6.0 * v0)
    gj = s * wp.cross(e2, e3)
    gk = s * wp.cross(e3, e1)
    gl = s * wp.cross(e1, e2)
    ks = tet_shear_k[t]
    ds = tet_shear_damping[t] * inv_h
    if ks > 0.0 or ds > 0.0:
        dmi = tet_rest_inverse[t]
        f = wp.matrix_from_cols(e1, e2, e3) * dmi
        g = green_strain(f)
        g0 = tet_g_start[t]
        e = e + shear_energy(g, ks, ds, g0)
        pm = f * (ks * g + ds * (g - g0)) * wp.transpose(dmi)  # columns: dE/dx_j, dE/dx_k, dE/dx_l
        pj, pk, pl = mat_columns(pm)
        gj = gj + pj
        gk = gk + pk
        gl = gl + pl
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
    energy_out[i] = node_energy(x, mu, z[i], kh, targets[i], f)
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
    e, g = spring_energy_grad(s, j, positions[s.node[j]])
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

