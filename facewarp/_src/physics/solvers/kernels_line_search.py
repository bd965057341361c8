"""Warp kernels of the device Newton-PCG method's iterate (:class:`~.newton_pcg.SolverDeviceNewtonPCG`):
the first guess's fallback, the deterministic energy sums, the line search (every trial's energy
in one pass, the step's choice and the step) and the adaptive Newton loop's condition, all decided
on the device so that a whole step can be one CUDA graph.

The trial energies evaluate the terms of :mod:`.kernels_potential` (the same ``wp.func``s, so a
trial sums as the energy kernels do); the model's element arrays reach them grouped by element
kind in the structs below, built once per solver (:class:`~.incremental.IncrementalPotential`).
"""

from __future__ import annotations

import warp as wp

from ..elements import (SpringSet, deformation_gradient, edge_energy, face_energy, green_strain, node_energy,
                        shear_energy, spring_energy_grad, tet_constraint_at, tet_energy, tet_strain)


# ---------------------------------------------------------------------------- the model's terms, grouped
@wp.struct
class EdgeTerms:
    """Distance terms (Eq. 6.4.4, 6.4.6): the Model's edge arrays."""

    indices: wp.array(dtype=wp.vec2i)
    rest_length: wp.array(dtype=float)
    k0: wp.array(dtype=float)
    damping: wp.array(dtype=float)


@wp.struct
class FaceTerms:
    """Area terms (Eq. 6.4.7): the Model's face arrays."""

    indices: wp.array(dtype=wp.vec3i)
    rest_area: wp.array(dtype=float)
    k: wp.array(dtype=float)
    damping: wp.array(dtype=float)


@wp.struct
class TetTerms:
    """Volume terms (Eq. 6.4.8) and the shear term: the Model's tet arrays."""

    indices: wp.array(dtype=wp.vec4i)
    rest_volume: wp.array(dtype=float)
    k: wp.array(dtype=float)
    damping: wp.array(dtype=float)
    rest_inverse: wp.array(dtype=wp.mat33)
    shear_k: wp.array(dtype=float)
    shear_damping: wp.array(dtype=float)


@wp.struct
class NodeTerms:
    """Inertia and hold terms: the Model's node arrays."""

    mass: wp.array(dtype=float)
    fixed: wp.array(dtype=wp.int32)
    hold_stiffness: wp.array(dtype=float)


@wp.struct
class SpringPool:
    """Every stage's springs as one pool (:class:`~.incremental._SpringPool`): pooled spring k is
    spring ``local[k]`` of set ``set_index[k]``."""

    sets: wp.array(dtype=SpringSet)
    set_index: wp.array(dtype=wp.int32)
    local: wp.array(dtype=wp.int32)


# ---------------------------------------------------------------------------- first guess
# The device method's first guess falls back to x_n (free nodes) when the extrapolated one
# inverts a tet (the host methods do the same on the host): _guess_inverted flags it,
# _guess_fallback undoes the extrapolation.
@wp.kernel
def _guess_inverted(
    # Model:
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    # State in: the first guess
    x: wp.array(dtype=wp.vec3),
    # Out: 1 when a tet is inverted (set to 0 before)
    flag: wp.array(dtype=wp.int32),
):
    t = wp.tid()
    if tet_constraint_at(tet_indices, tet_rest_volume, x, t) <= -1.0:  # the line search's test
        flag[0] = 1


@wp.kernel
def _guess_fallback(
    # Model:
    vertex_fixed: wp.array(dtype=wp.int32),
    # State in: the flag of _guess_inverted, x_n
    flag: wp.array(dtype=wp.int32),
    positions_in: wp.array(dtype=wp.vec3),
    # Out: the first guess, replaced in place
    x_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    if flag[0] != 0 and vertex_fixed[i] == 0:
        x_out[i] = positions_in[i]


# ---------------------------------------------------------------------------- reductions
# Deterministic sums of the rows of an energy array (the energy at x: one row; the line search's
# trials: one row each): each thread adds a fixed chunk of a row in order (float64), then one
# thread per row adds the chunks in order and writes total_out[first_slot + j]. No atomics: the
# same sum on every run and device. The solver takes chunks of about sqrt(n) entries, so neither
# pass has a long serial chain (measured on an H100 at level 2: threads striding over the whole
# array, 512 of them, took 10x as long as contiguous chunks: every load a cache miss).
@wp.kernel
def _chunk_sums_rows(
    # Model:
    chunk: int,
    # State in: rows of per-term energies
    values: wp.array2d(dtype=float),
    # Out: per-chunk sums
    partial_out: wp.array2d(dtype=wp.float64),
):
    j, c = wp.tid()
    n = values.shape[1]
    s = wp.float64(0.0)
    for i in range(c * chunk, wp.min((c + 1) * chunk, n)):
        s = s + wp.float64(values[j, i])
    partial_out[j, c] = s


@wp.kernel
def _final_sums_rows(
    # Model:
    first_slot: int,
    # State in: per-chunk sums
    partial: wp.array2d(dtype=wp.float64),
    # Out: one total per row
    total_out: wp.array(dtype=wp.float64),
):
    j = wp.tid()
    s = wp.float64(0.0)
    for i in range(partial.shape[1]):
        s = s + partial[j, i]
    total_out[first_slot + j] = s


# ---------------------------------------------------------------------------- line search
# A trial position: x_i + t d_i on a free node (the arithmetic of _take_step, so the step taken
# is the trial evaluated), x_i on a fixed one.
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
    # Model:
    edges: EdgeTerms,
    faces: FaceTerms,
    tets: TetTerms,
    nodes: NodeTerms,
    springs: SpringPool,
    mass_scale: float,
    inv_h: float,
    # State in: the step's start (C_n per edge, face, tet; G_n per tet), the inertial target,
    # the targets, the external force (a control), the iterate x and the Newton direction d
    edge_c_start: wp.array(dtype=float),
    face_c_start: wp.array(dtype=float),
    tet_c_start: wp.array(dtype=float),
    tet_g_start: wp.array(dtype=wp.mat33),
    z: wp.array(dtype=wp.vec3),
    targets: wp.array(dtype=wp.vec3),
    external_force: wp.array(dtype=wp.vec3),
    x: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    # Out: energy per trial (rows) and term (columns)
    energy_out: wp.array2d(dtype=float),
):
    i = wp.tid()
    trials = energy_out.shape[0]
    ne = edges.indices.shape[0]
    nf = faces.indices.shape[0]
    nt = tets.indices.shape[0]
    nv = nodes.mass.shape[0]
    fixed = nodes.fixed
    t = float(1.0)
    if i < ne:
        a = edges.indices[i][0]
        b = edges.indices[i][1]
        dmp = edges.damping[i] * inv_h
        for j in range(trials):
            energy_out[j, i] = edge_energy(_trial_x(x, d, fixed, a, t), _trial_x(x, d, fixed, b, t),
                                       edges.rest_length[i], edges.k0[i], dmp, edge_c_start[i])
            t = t * 0.5
    elif i < ne + nf:
        f = i - ne
        a = faces.indices[f][0]
        b = faces.indices[f][1]
        fc = faces.indices[f][2]
        dmp = faces.damping[f] * inv_h
        for j in range(trials):
            energy_out[j, i] = face_energy(_trial_x(x, d, fixed, a, t), _trial_x(x, d, fixed, b, t),
                                       _trial_x(x, d, fixed, fc, t), faces.rest_area[f], faces.k[f], dmp,
                                       face_c_start[f])
            t = t * 0.5
    elif i < ne + nf + nt:
        q = i - ne - nf
        tet = tets.indices[q]
        dmp = tets.damping[q] * inv_h
        ks = tets.shear_k[q]
        ds = tets.shear_damping[q] * inv_h
        for j in range(trials):
            xa = _trial_x(x, d, fixed, tet[0], t)
            xb = _trial_x(x, d, fixed, tet[1], t)
            xc = _trial_x(x, d, fixed, tet[2], t)
            xd = _trial_x(x, d, fixed, tet[3], t)
            c = tet_strain(xa, xb, xc, xd, tets.rest_volume[q])
            e = tet_energy(c, tets.k[q], dmp, tet_c_start[q])
            if ks > 0.0 or ds > 0.0:
                e = e + shear_energy(green_strain(deformation_gradient(xa, xb, xc, xd, tets.rest_inverse[q])), ks, ds, tet_g_start[q])
            if c <= -1.0:
                e = 1.0e30
            energy_out[j, i] = e
            t = t * 0.5
    elif i < ne + nf + nt + nv:
        v = i - ne - nf - nt
        for j in range(trials):
            e = float(0.0)
            if fixed[v] == 0:
                e = node_energy(_trial_x(x, d, fixed, v, t), nodes.mass[v] * mass_scale, z[v],
                            nodes.hold_stiffness[v], targets[v], external_force[v])
            energy_out[j, i] = e
            t = t * 0.5
    else:
        k = i - ne - nf - nt - nv
        s = springs.sets[springs.set_index[k]]
        l = springs.local[k]
        for j in range(trials):
            e, g = spring_energy_grad(s, l, _trial_x(x, d, fixed, s.node[l], t))
            energy_out[j, i] = e
            t = t * 0.5


_FEASIBLE = wp.constant(wp.float64(1.0e29))  # below it no trial inverted a tet (INVERTED_ENERGY 1e30)


# Backtracking on the device: trials t = 1, 1/2, ..., 2^-(trials-1) have energies totals[1..trials]; take the
# first that does not raise the energy above totals[0] (within float32 rounding), else the
# lowest if it is below, else no move (t = 0).
@wp.kernel
def _select_step(
    # Model:
    trials: int,
    # State in: the energy at x (totals[0]) and at the trials
    totals: wp.array(dtype=wp.float64),
    # Out: the step length t
    t_out: wp.array(dtype=float),
):
    e0 = totals[0]
    tol = wp.float64(1.0e-6) * wp.abs(e0) + wp.float64(1.0e-20)
    t = float(1.0)
    best = int(-1)
    # a trial that inverts a tet sums to >= 1e30: never taken, even when the iterate's own energy is
    # that large (a tet inverted at x: then any trial inverting none is the improvement)
    for j in range(trials):
        if best < 0 and totals[1 + j] < _FEASIBLE and totals[1 + j] <= e0 + tol:
            best = j
    if best < 0:
        lowest = e0
        for j in range(trials):
            if totals[1 + j] < _FEASIBLE and totals[1 + j] < lowest:
                lowest = totals[1 + j]
                best = j
    if best < 0:
        t_out[0] = 0.0
    else:
        for j in range(best):
            t = t * 0.5
        t_out[0] = t


# The line search's step: x += t d on the free nodes, and the largest step (t |d_i|) and
# direction (|d_i|) of a free node for the convergence test (largest reset by _newton_continue).
@wp.kernel
def _take_step(
    # Model:
    vertex_fixed: wp.array(dtype=wp.int32),
    # State in: the direction d and step length t
    d: wp.array(dtype=wp.vec3),
    t: wp.array(dtype=float),
    # Out: the iterate x (in place), the largest step and direction
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
    # Out: the loop's counter, largest step, condition and Hessian slack, reset
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
    # Model: (the solver's options)
    tolerance: float,
    max_iterations: int,
    contact_slack: float,
    # State in: the step length of this iteration
    t: wp.array(dtype=float),
    # Out: the loop's counter, largest step, condition, total count and Hessian slack, in place
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


# ---------------------------------------------------------------------------- the host line search's step bound
_NO_ROOT = wp.constant(wp.float64(1.0e300))  # a tet whose volume stays positive on (0, 1]


@wp.func
def _cubic(c0: wp.float64, c1: wp.float64, c2: wp.float64, c3: wp.float64, t: wp.float64):
    return c0 + t * (c1 + t * (c2 + t * c3))


# The host L-BFGS line search's step bound (SolverHostImplicit._first_inversion), float64: per tet,
# the signed volume along x + t d is a cubic in t; the first t in (0, 1] where it reaches 0 (sampled
# at t = k / 8, the first sign change refined by 17 bisections: 1/8 / 2^17 < 1e-6), or _NO_ROOT.
@wp.kernel
def _first_inversion(
    # Model:
    tet_indices: wp.array(dtype=wp.vec4i),
    # State in: the iterate and the direction, float64
    x: wp.array(dtype=wp.vec3d),
    d: wp.array(dtype=wp.vec3d),
    # Out: each tet's first root (or _NO_ROOT)
    root_out: wp.array(dtype=wp.float64),
):
    t = wp.tid()
    idx = tet_indices[t]
    p0 = x[idx[0]]
    q0 = d[idx[0]]
    e1 = x[idx[1]] - p0
    e2 = x[idx[2]] - p0
    e3 = x[idx[3]] - p0
    f1 = d[idx[1]] - q0
    f2 = d[idx[2]] - q0
    f3 = d[idx[3]] - q0
    c0 = wp.dot(e1, wp.cross(e2, e3))
    c1 = wp.dot(f1, wp.cross(e2, e3)) + wp.dot(e1, wp.cross(f2, e3)) + wp.dot(e1, wp.cross(e2, f3))
    c2 = wp.dot(f1, wp.cross(f2, e3)) + wp.dot(f1, wp.cross(e2, f3)) + wp.dot(e1, wp.cross(f2, f3))
    c3 = wp.dot(f1, wp.cross(f2, f3))
    root = _NO_ROOT
    if c0 > wp.float64(0.0):
        lo = wp.float64(0.0)
        hi = wp.float64(-1.0)
        for k in range(1, 9):
            g = wp.float64(k) / wp.float64(8.0)
            if hi < wp.float64(0.0):
                if _cubic(c0, c1, c2, c3, g) <= wp.float64(0.0):
                    hi = g
                else:
                    lo = g
        if hi > wp.float64(0.0):
            for _ in range(17):
                mid = wp.float64(0.5) * (lo + hi)
                if _cubic(c0, c1, c2, c3, mid) > wp.float64(0.0):
                    lo = mid
                else:
                    hi = mid
            root = hi
    root_out[t] = root
