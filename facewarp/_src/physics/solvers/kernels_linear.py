"""Warp kernels of the device Newton-PCG method's linear solve (:class:`~.newton_pcg.SolverDeviceNewtonPCG`):
the Newton system's block-Jacobi preconditioner and right-hand side, and block-Jacobi
preconditioned conjugate gradients on the BSR Hessian, one launch per iteration.
"""

from __future__ import annotations

import warp as wp

# The Newton system's block-Jacobi preconditioner and right-hand side in one launch: the inverse
# of every 3 x 3 diagonal block (block index diag[i]; a singular block falls back to the
# identity) and rhs = -grad.
@wp.kernel
def _newton_system(
    # Model: (the solver's BSR pattern)
    diag: wp.array(dtype=wp.int32),
    # State in: the Hessian's block values, the gradient
    values: wp.array(dtype=wp.mat33),
    grad: wp.array(dtype=wp.vec3),
    # Out:
    inv_out: wp.array(dtype=wp.mat33),
    rhs_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    B = values[diag[i]]
    if wp.abs(wp.determinant(B)) > 1.0e-30:
        inv_out[i] = wp.inverse(B)
    else:
        inv_out[i] = wp.identity(n=3, dtype=float)
    rhs_out[i] = -grad[i]



# ------------------------------------------------------------------------------------------------
# Block-Jacobi preconditioned conjugate gradients in one launch per iteration (the device
# method's linear solve; :meth:`.newton_pcg.SolverDeviceNewtonPCG._launch_cg`). Chronopoulos & Gear's
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
def _zero_2d(
    # Out:
    a: wp.array2d(dtype=wp.float64),
):
    i, j = wp.tid()
    a[i, j] = wp.float64(0.0)


@wp.kernel
def _cg_start(
    # State in: the preconditioner, the right-hand side
    inv: wp.array(dtype=wp.mat33),
    b: wp.array(dtype=wp.vec3),
    # Out: x = 0, r = b, u = P r, p = s = 0, (r, u) into sums row 0
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
    # Model: (the BSR matrix) and the sums row
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array(dtype=wp.mat33),
    row: int,
    # State in:
    u: wp.array(dtype=wp.vec3),
    # Out:
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
    # Model: (the BSR matrix, its preconditioner) and the iteration
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array(dtype=wp.mat33),
    inv: wp.array(dtype=wp.mat33),
    it: int,
    last: int,
    # State in: the sums (also accumulated into), the scalars (row it written), r, s, w
    sums: wp.array2d(dtype=wp.float64),
    scalars: wp.array2d(dtype=wp.float64),
    r_in: wp.array(dtype=wp.vec3),
    s_in: wp.array(dtype=wp.vec3),
    w_in: wp.array(dtype=wp.vec3),
    # Out: x, p, u in place; r, s, w into the other buffers
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
