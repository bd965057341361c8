"""Warp kernels of the skin deformation model (thesis Sec. 6.4.2, 6.4.4), launched by :mod:`solver`.

Every internal force is the negative gradient of a constraint energy ``E = 1/2 k C^2``
(Eq. 6.4.2) with a dimensionless constraint C, so ``F_i = -k C dC/dx_i`` (Eq. 6.4.3). Each
element writes the force on each of its corners into its own *slot* (no atomics); ``_gather``
then adds every node's slots in a fixed order (``Model.node_slots``), which makes a step
deterministic and the CPU and CUDA sums the same.
Units are SI (m, kg, s; stiffnesses in J, strain-rate dashpots in J s), see
:mod:`facewarp._src.physics.model`.
"""

from __future__ import annotations

import warp as wp

from .elements import face_area_gradient, finite3, mat_columns, tet_volume_gradient

GUARD_NONE = 2147483647
"""Sentinel of the guard array: no failure recorded (int32 max)."""


# Distance energy per unique tet edge (i, j), Eq. 6.4.4 with the stiffness of Eq. 6.4.6.
#   d = x_i - x_j, l = |d|, n = d / l, C = (l - D0) / D0, dC/dx_i = n / D0 = -dC/dx_j.
#   Eq. 6.4.6 makes the stiffness strain dependent, k(C) = (1 + C^2) k0, and Eq. 6.4.3 applies
#   it as F_i = -k(C) C dC/dx_i. That force is the exact negative gradient of
#       E(C) = k0 (C^2 / 2 + C^4 / 4)          (dE/dC = k0 (1 + C^2) C = k(C) C),
#   which reduces to Eq. 6.4.4's 1/2 k0 C^2 at small strain. So
#       F_i = -k0 (1 + C^2) C / D0 n,   F_j = -F_i.
#   Damping, Eq. 6.4.5 applied to the spring: a dashpot on the strain rate,
#   F_i = -d dC/dt dC/dx_i with dC/dt = (v_i - v_j) . n / D0 and v = (x - x_prev) / dt, i.e.
#   F_i = -d / D0^2 ((v_i - v_j) . n) n (d [J s] = beta k0 + c D0^2, Model.edge_damping). It acts
#   only on stretching rates, so rigid motions are not damped; d = 0 switches it off.
@wp.kernel
def _edge_forces(
    # Model:
    edge_indices: wp.array(dtype=wp.vec2i),
    edge_rest_length: wp.array(dtype=float),
    edge_k0: wp.array(dtype=float),
    edge_damping: wp.array(dtype=float),
    inv_dt: float,
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    prev_positions_in: wp.array(dtype=wp.vec3),
    # Out: corner forces, slots 2e (i) and 2e + 1 (j)
    slots_out: wp.array(dtype=wp.vec3),
):
    e = wp.tid()
    slots_out[2 * e] = wp.vec3(0.0)
    slots_out[2 * e + 1] = wp.vec3(0.0)
    i = edge_indices[e][0]
    j = edge_indices[e][1]
    xi = positions_in[i]
    xj = positions_in[j]
    d = xi - xj
    l = wp.length(d)
    if l <= 0.0:
        return
    n = d / l
    d0 = edge_rest_length[e]
    c = (l - d0) / d0
    f = -edge_k0[e] * (1.0 + c * c) * c / d0 * n
    dmp = edge_damping[e]
    if dmp > 0.0:
        vi = (xi - prev_positions_in[i]) * inv_dt
        vj = (xj - prev_positions_in[j]) * inv_dt
        f = f - dmp / (d0 * d0) * wp.dot(vi - vj, n) * n
    slots_out[2 * e] = f
    slots_out[2 * e + 1] = -f


# Area energy per unique tet face (i, j, k), Eq. 6.4.7: E = 1/2 k C^2, C = (A - A0) / A0.
#   e1 = x_j - x_i, e2 = x_k - x_i, N = e1 x e2, A = |N| / 2, m = N / |N|.
#   dA = 1/2 m . dN, and dN = de1 x e2 + e1 x de2, so with the triple product
#   m . (de1 x e2) = de1 . (e2 x m) and m . (e1 x de2) = de2 . (m x e1):
#       dA/dx_j = 1/2 e2 x m,   dA/dx_k = 1/2 m x e1,   dA/dx_i = -(dA/dx_j + dA/dx_k).
#   F_a = -(k C + d dC/dt) / A0 dA/dx_a (Eq. 6.4.3 plus the strain-rate dashpot d [J s], with
#   dC/dt = sum_a dA/dx_a . v_a / A0). A collapsed face (|N| = 0) has no direction and gets no
#   force.
@wp.kernel
def _face_forces(
    # Model:
    face_indices: wp.array(dtype=wp.vec3i),
    face_rest_area: wp.array(dtype=float),
    face_k: wp.array(dtype=float),
    face_damping: wp.array(dtype=float),
    inv_dt: float,
    slot_offset: int,
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    prev_positions_in: wp.array(dtype=wp.vec3),
    # Out: corner forces, slots offset + 3t + (0, 1, 2)
    slots_out: wp.array(dtype=wp.vec3),
):
    t = wp.tid()
    o = slot_offset + 3 * t
    slots_out[o] = wp.vec3(0.0)
    slots_out[o + 1] = wp.vec3(0.0)
    slots_out[o + 2] = wp.vec3(0.0)
    i = face_indices[t][0]
    j = face_indices[t][1]
    k = face_indices[t][2]
    xi = positions_in[i]
    e1 = positions_in[j] - xi
    e2 = positions_in[k] - xi
    nn = wp.cross(e1, e2)
    nl = wp.length(nn)
    if nl <= 0.0:
        return
    m = nn / nl
    a0 = face_rest_area[t]
    c = (0.5 * nl - a0) / a0
    gi, gj, gk = face_area_gradient(e1, e2, m)  # elements.py: dA/dx
    s = face_k[t] * c
    dmp = face_damping[t]
    if dmp > 0.0:
        vi = (xi - prev_positions_in[i]) * inv_dt
        vj = (positions_in[j] - prev_positions_in[j]) * inv_dt
        vk = (positions_in[k] - prev_positions_in[k]) * inv_dt
        s = s + dmp * (wp.dot(gi, vi) + wp.dot(gj, vj) + wp.dot(gk, vk)) / a0
    s = -s / a0
    slots_out[o] = s * gi
    slots_out[o + 1] = s * gj
    slots_out[o + 2] = s * gk


# Volume energy per tet (i, j, k, l), Eq. 6.4.8: E = 1/2 k C^2, C = (V - V0) / V0 with
#   the signed volume V = 1/6 e1 . (e2 x e3), e1 = x_j - x_i, e2 = x_k - x_i, e3 = x_l - x_i.
#   V is trilinear in (e1, e2, e3), so (cyclic triple product)
#       dV/dx_j = 1/6 e2 x e3,  dV/dx_k = 1/6 e3 x e1,  dV/dx_l = 1/6 e1 x e2,
#       dV/dx_i = -(dV/dx_j + dV/dx_k + dV/dx_l).
#   F_a = -(k C + d dC/dt) / V0 dV/dx_a (Eq. 6.4.3 plus the strain-rate dashpot). The signed
#   volume keeps pushing an inverted tet back (C < -1 still points towards V0 > 0).
@wp.kernel
def _tet_forces(
    # Model:
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    tet_k: wp.array(dtype=float),
    tet_damping: wp.array(dtype=float),
    tet_rest_inverse: wp.array(dtype=wp.mat33),
    tet_shear_k: wp.array(dtype=float),
    tet_shear_damping: wp.array(dtype=float),
    inv_dt: float,
    slot_offset: int,
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    prev_positions_in: wp.array(dtype=wp.vec3),
    # Out: corner forces, slots offset + 4t + (0..3)
    slots_out: wp.array(dtype=wp.vec3),
):
    t = wp.tid()
    o = slot_offset + 4 * t
    i = tet_indices[t][0]
    j = tet_indices[t][1]
    k = tet_indices[t][2]
    l = tet_indices[t][3]
    xi = positions_in[i]
    e1 = positions_in[j] - xi
    e2 = positions_in[k] - xi
    e3 = positions_in[l] - xi
    v = wp.dot(e1, wp.cross(e2, e3)) / 6.0
    v0 = tet_rest_volume[t]
    c = (v - v0) / v0
    gi, gj, gk, gl = tet_volume_gradient(e1, e2, e3)  # elements.py: dV/dx
    s = tet_k[t] * c
    dmp = tet_damping[t]
    if dmp > 0.0:
        vi = (xi - prev_positions_in[i]) * inv_dt
        vj = (positions_in[j] - prev_positions_in[j]) * inv_dt
        vk = (positions_in[k] - prev_positions_in[k]) * inv_dt
        vl = (positions_in[l] - prev_positions_in[l]) * inv_dt
        s = s + dmp * (wp.dot(gi, vi) + wp.dot(gj, vj) + wp.dot(gk, vk) + wp.dot(gl, vl)) / v0
    s = -s / v0
    fi = s * gi
    fj = s * gj
    fk = s * gk
    fl = s * gl
    # shear term (model doc): F = D_s D_m^-1, G = (F^T F - I) / 2, S = k_s G + d_s dG/dt with
    # dG/dt = sym(F^T dF/dt); the force on corner a is -F S b_a (b_a: rows of D_m^-1, b_0 = -sum)
    ks = tet_shear_k[t]
    ds = tet_shear_damping[t]
    if ks > 0.0 or ds > 0.0:
        dmi = tet_rest_inverse[t]
        f = wp.matrix_from_cols(e1, e2, e3) * dmi
        g = 0.5 * (wp.transpose(f) * f - wp.identity(n=3, dtype=float))
        sm = ks * g
        if ds > 0.0:
            vi = (xi - prev_positions_in[i]) * inv_dt
            fd = wp.matrix_from_cols((positions_in[j] - prev_positions_in[j]) * inv_dt - vi,
                                     (positions_in[k] - prev_positions_in[k]) * inv_dt - vi,
                                     (positions_in[l] - prev_positions_in[l]) * inv_dt - vi) * dmi
            ftd = wp.transpose(f) * fd
            sm = sm + ds * 0.5 * (ftd + wp.transpose(ftd))
        pm = f * sm * wp.transpose(dmi)
        pj, pk, pl = mat_columns(pm)
        fi = fi + (pj + pk + pl)
        fj = fj - pj
        fk = fk - pk
        fl = fl - pl
    slots_out[o] = fi
    slots_out[o + 1] = fj
    slots_out[o + 2] = fk
    slots_out[o + 3] = fl


# Each node adds its slots, in a fixed order, to the forces of the stages (deterministic, no
# atomics): node[k] takes slots[order[start[k]]] .. slots[order[start[k + 1] - 1]]. The solver
# gathers the element slots of every node (Model.node_slots); the muscle stage gathers the springs
# of its attached nodes.
@wp.kernel
def _gather(
    node: wp.array(dtype=wp.int32),
    start: wp.array(dtype=wp.int32),
    order: wp.array(dtype=wp.int32),
    slots: wp.array(dtype=wp.vec3),
    # In / out:
    forces: wp.array(dtype=wp.vec3),
):
    k = wp.tid()
    f = wp.vec3(0.0)
    for s in range(start[k], start[k + 1]):
        f = f + slots[order[s]]
    i = node[k]
    forces[i] = forces[i] + f


# Start of a substep: forces = the user's constant external force (Control.external_force);
# muscle / jaw stages and the internal-force kernels then accumulate on top.
@wp.kernel
def _init_forces(
    # Control:
    external_force: wp.array(dtype=wp.vec3),
    # Forces out:
    forces_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    forces_out[i] = external_force[i]


# Damped Verlet step, Eq. 6.4.10: x(t + dt) = 2 x(t) - x(t - dt) + dt^2 F / m, with Eq. 6.4.5's
# mass-proportional damping F_d = -alpha m (v - v_c) on the velocity v = (x - x_prev) / dt
# relative to the cranium's rigid velocity v_c = v_lin + w x x:
#   x' = x + (1 - alpha dt) (x - x_prev) + alpha dt^2 v_c + dt^2 F / m
# (Table 6.3's 0.002 per substep is alpha dt = 0.002). Held nodes feel a spring to their target,
# F += -k_hold (x - target) (energy 1/2 k_hold |x - target|^2); fixed nodes are placed on their
# target. Thread 0 also advances the device step counter used by the guard.
@wp.kernel
def _integrate_verlet(
    # Model:
    vertex_inv_mass: wp.array(dtype=float),
    vertex_fixed: wp.array(dtype=wp.int32),
    vertex_hold_stiffness: wp.array(dtype=float),
    damping_rate: float,
    dt: float,
    # Control:
    cranium_velocity: wp.array(dtype=wp.vec3),
    # Solver:
    forces: wp.array(dtype=wp.vec3),
    targets: wp.array(dtype=wp.vec3),
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    prev_positions_in: wp.array(dtype=wp.vec3),
    # State out:
    positions_out: wp.array(dtype=wp.vec3),
    prev_positions_out: wp.array(dtype=wp.vec3),
    step_counter_out: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    if i == 0:
        step_counter_out[0] = step_counter_out[0] + 1
    x = positions_in[i]
    target = targets[i]
    if vertex_fixed[i] != 0:
        x_new = target
    else:
        f = forces[i] - vertex_hold_stiffness[i] * (x - target)
        ad = damping_rate * dt
        vc = cranium_velocity[0] + wp.cross(cranium_velocity[1], x)
        x_new = x + (1.0 - ad) * (x - prev_positions_in[i]) + (ad * dt) * vc + (dt * dt * vertex_inv_mass[i]) * f
    positions_out[i] = x_new
    prev_positions_out[i] = x


# NaN / inversion guard (no host read): a tet with a non-finite node position, or with signed
# volume <= 0 (its rest volume is > 0), is a failure. The first failing substep is kept in
# guard[0] and the smallest code 2 tet + (0: NaN, 1: inverted) of that substep in guard[1];
# later substeps leave both alone (guard[0] < step).
@wp.kernel
def _check_tets(
    # Model:
    tet_indices: wp.array(dtype=wp.vec4i),
    step_counter: wp.array(dtype=wp.int32),
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    # Guard out:
    guard_out: wp.array(dtype=wp.int32),
):
    t = wp.tid()
    s = step_counter[0]
    if guard_out[0] < s:
        return
    x0 = positions_in[tet_indices[t][0]]
    x1 = positions_in[tet_indices[t][1]]
    x2 = positions_in[tet_indices[t][2]]
    x3 = positions_in[tet_indices[t][3]]
    code = int(-1)
    if not (finite3(x0) and finite3(x1) and finite3(x2) and finite3(x3)):
        code = 2 * t
    else:
        v = wp.dot(x1 - x0, wp.cross(x2 - x0, x3 - x0))
        if not (v > 0.0):
            code = 2 * t + 1
    if code >= 0:
        wp.atomic_min(guard_out, 0, s)
        wp.atomic_min(guard_out, 1, code)
