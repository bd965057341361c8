"""Warp kernels of the implicit Euler step's PSD Hessian: every element's, node's and spring's
3 x 3 blocks written into block slots and summed per block of a block-sparse (BSR) matrix in a
fixed order (launched by :class:`~.incremental.IncrementalPotential`; the energies and gradients
are in :mod:`.kernels_potential`, whose module doc states the potential).
"""

from __future__ import annotations

import warp as wp

from ..elements import SpringSet, barrier_dd, face_area_gradient, mat_row, outer, pick4, tet_volume_gradient

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
    # Model:
    edge_indices: wp.array(dtype=wp.vec2i),
    edge_rest_length: wp.array(dtype=float),
    edge_k0: wp.array(dtype=float),
    edge_damping: wp.array(dtype=float),
    inv_h: float,
    # State in: C_n (step start), the iterate x
    edge_c_start: wp.array(dtype=float),
    positions: wp.array(dtype=wp.vec3),
    # Out: block slots (ii, ij, ji, jj) x edge count, from 0
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
    nn = outer(n, n)
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
    # Model:
    face_indices: wp.array(dtype=wp.vec3i),
    face_rest_area: wp.array(dtype=float),
    face_k: wp.array(dtype=float),
    face_damping: wp.array(dtype=float),
    inv_h: float,
    block_offset: int,
    # State in: the iterate x
    positions: wp.array(dtype=wp.vec3),
    # Out: block slots offset + p * face count + t, corner pairs p = 0..8
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
    g0 = wp.vec3(0.0)
    g1 = wp.vec3(0.0)
    g2 = wp.vec3(0.0)
    if nl > 0.0:
        g0, g1, g2 = face_area_gradient(e1, e2, nn / nl)  # elements.py: dA/dx
    a0 = face_rest_area[t]
    s = (face_k[t] + face_damping[t] * inv_h) / (a0 * a0)
    blocks_out[o] = s * outer(g0, g0)
    blocks_out[o + nf] = s * outer(g0, g1)
    blocks_out[o + 2 * nf] = s * outer(g0, g2)
    blocks_out[o + 3 * nf] = s * outer(g1, g0)
    blocks_out[o + 4 * nf] = s * outer(g1, g1)
    blocks_out[o + 5 * nf] = s * outer(g1, g2)
    blocks_out[o + 6 * nf] = s * outer(g2, g0)
    blocks_out[o + 7 * nf] = s * outer(g2, g1)
    blocks_out[o + 8 * nf] = s * outer(g2, g2)


@wp.kernel
def _tet_hessian(
    # Model:
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    tet_k: wp.array(dtype=float),
    tet_damping: wp.array(dtype=float),
    tet_rest_inverse: wp.array(dtype=wp.mat33),
    tet_shear_k: wp.array(dtype=float),
    tet_shear_damping: wp.array(dtype=float),
    inv_h: float,
    block_offset: int,
    # State in: the iterate x
    positions: wp.array(dtype=wp.vec3),
    # Out: block slots offset + p * tet count + t, corner pairs p = 0..15
    blocks_out: wp.array(dtype=wp.mat33),
):
    t = wp.tid()
    nt = tet_indices.shape[0]
    o = block_offset + t
    xi = positions[tet_indices[t][0]]
    e1 = positions[tet_indices[t][1]] - xi
    e2 = positions[tet_indices[t][2]] - xi
    e3 = positions[tet_indices[t][3]] - xi
    g0, g1, g2, g3 = tet_volume_gradient(e1, e2, e3)  # elements.py: dV/dx
    v0 = tet_rest_volume[t]
    r = wp.dot(e1, wp.cross(e2, e3)) / 6.0 / v0  # the volume ratio (the barrier's Gauss-Newton term)
    s = (tet_k[t] * (1.0 + barrier_dd(r)) + tet_damping[t] * inv_h) / (v0 * v0)
    # shear term, Gauss-Newton: (k_s + d_s / h) dG/dx_a : dG/dx_b, block (c, d) =
    # (k_s + d_s / h) / 2 ((F F^T)_cd (b_a . b_b) + (F b_b)_c (F b_a)_d)
    ss = 0.5 * (tet_shear_k[t] + tet_shear_damping[t] * inv_h)
    if ss > 0.0:
        dmi = tet_rest_inverse[t]
        f = wp.matrix_from_cols(e1, e2, e3) * dmi
        ff = f * wp.transpose(f)
        b1 = mat_row(dmi, 0)
        b2 = mat_row(dmi, 1)
        b3 = mat_row(dmi, 2)
        b0 = -(b1 + b2 + b3)
        for a in range(4):
            ga = pick4(g0, g1, g2, g3, a)
            ba = pick4(b0, b1, b2, b3, a)
            for b in range(4):
                bb = pick4(b0, b1, b2, b3, b)
                blocks_out[o + (4 * a + b) * nt] = s * outer(ga, pick4(g0, g1, g2, g3, b)) + ss * (
                    wp.dot(ba, bb) * ff + outer(f * bb, f * ba))
    else:
        for a in range(4):
            ga = pick4(g0, g1, g2, g3, a)
            for b in range(4):
                blocks_out[o + (4 * a + b) * nt] = s * outer(ga, pick4(g0, g1, g2, g3, b))


# Diagonal blocks of every node: (mu + k_h) I; fixed nodes: the identity (their DOFs are not
# unknowns; the right-hand side there is 0).
@wp.kernel
def _node_hessian(
    # Model:
    vertex_mass: wp.array(dtype=float),
    vertex_hold_stiffness: wp.array(dtype=float),
    mass_scale: float,
    block_offset: int,
    # Out: block slot offset + i per node
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
    # Model: (the stages' springs, read in place)
    springs: wp.array(dtype=SpringSet),
    spring_set: wp.array(dtype=wp.int32),
    spring_local: wp.array(dtype=wp.int32),
    block_offset: int,
    # State in: the Hessian slack [m] (one element), the iterate x
    slack: wp.array(dtype=float),
    positions: wp.array(dtype=wp.vec3),
    # Out: block slot offset + k per pooled spring
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
        H = kj * outer(a, a)
        gap = wp.dot(r, a)
    else:
        l = wp.length(r)
        H = kj * wp.identity(n=3, dtype=float)
        if l > 0.0:
            n = r / l
            nn = outer(n, n)
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
    # Model: (the solver's BSR pattern)
    start: wp.array(dtype=wp.int32),
    order: wp.array(dtype=wp.int32),
    block_row: wp.array(dtype=wp.int32),
    block_col: wp.array(dtype=wp.int32),
    vertex_fixed: wp.array(dtype=wp.int32),
    # State in: block slots
    blocks: wp.array(dtype=wp.mat33),
    # Out: the BSR matrix's block values
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
