"""Warp kernels of the muscles (Sec. 6.3, 6.4.1) and the kinematic jaw (Sec. 6.4.3).

Per substep, quasi-statically (Sec. 6.4.4):

1. ``_muscle_controls``: every control point starts from its rest position moved by the jaw
   (Eq. 6.4.9 amount) and contracts: a linear muscle's insertion and middle point move toward
   its attachment by the fraction ``c(a)`` of their distance; a sphincter's points move toward
   the ring centre, or toward a plane through it (the lids close toward the plane of the
   palpebral fissure: the points move along its normal only); a point marked fixed (a lid corner
   on its palpebral ligament) stays. ``c(a) = c_max (1 - exp(-beta a)) / (1 - exp(-beta))`` is
   the saturating activation curve (``beta`` per muscle, 0 = linear ``c_max a``;
   :func:`_contraction`). A sphincter that glides over a rigid part (the lids over the eyeball)
   keeps each point's rest distance from the part's centre g: its straight-line target ``y``
   goes to ``g + |x - g| (y - g) / |y - g|``, so the lids slide over the eyeball, not into it.
2. ``_muscle_anchors``: anchors (Fig. 6.3) tie a sphincter control point and the insertions of
   the voluntary muscles that meet there, two-way: every member moves by the common
   displacement ``D = sum_j k_j d_j / sum_j k_j`` (``d_j`` its own contraction's displacement,
   ``k_j = k_passive + a_j`` its stiffness, rising with its activation), the equilibrium of
   springs of stiffness ``k_j`` from each member's own target to the anchor. An active muscle
   drags the sphincter and the passive muscles along; two active ones share by stiffness.
3. ``_muscle_segments``: each segment's ellipsoid is rebuilt from its (rational) quadratic Bezier
   curve: x along the chord (radius 1.05/2 of it), y perpendicular in the control-point plane,
   z = x cross y; y and z radii scale by sqrt(rx0 / rx), so the volume
   4/3 pi rx ry rz is preserved (incompressible muscle).
4. ``_muscle_forces``: each skin attachment's point on its ellipsoid is re-evaluated from its
   surface parameters (u, v) and the spring of Eq. 6.4.1,
   ``f = k_m cos(theta) (|p_m - p_s| - l0) (p_m - p_s) / |p_m - p_s|``, with theta the angle
   between the spring and the fibre, is added to the skin node. A sphincter squeezes across its
   fibres (its ring shrinks radially), so its springs take the cosine as 1.
5. ``_jaw_targets``: held / fixed nodes carried by the jaw get the jaw-rotated rest position as
   their target.
6. ``_jaw_carry`` / ``_jaw_remember``: the free nodes of the jaw regions move with the change
   of the jaw angles since the last substep (positions and previous positions alike, so no
   velocity is injected), by their Eq. 6.4.9 amount.
"""

from __future__ import annotations

import warp as wp


@wp.func
def _rotate_about(p: wp.vec3, pivot: wp.vec3, axis: wp.vec3, angle: float):
    # Rodrigues' formula about the line (pivot, axis), axis of unit length.
    q = p - pivot
    c = wp.cos(angle)
    s = wp.sin(angle)
    return pivot + q * c + wp.cross(axis, q) * s + axis * (wp.dot(q, axis) * (1.0 - c))


@wp.func
def _jaw_move(p: wp.vec3, amount: float, pivot: wp.vec3, u_axis: wp.vec3, v_axis: wp.vec3, angles: wp.array(dtype=float),
              h: int):
    # head h's jaw: its angles are angles[2 h], angles[2 h + 1] (Control.jaw_angles, (N, 2) flat)
    q = _rotate_about(p, pivot, u_axis, angles[2 * h] * amount)
    return _rotate_about(q, pivot, v_axis, angles[2 * h + 1] * amount)


@wp.func
def _contraction(a: float, c_max: float, beta: float):
    # Saturating activation curve: c(a) = c_max (1 - e^(-beta a)) / (1 - e^(-beta)), a clamped to
    # [0, 1]; c(0) = 0, c(1) = c_max, slope c_max beta / (1 - e^-beta) at 0; beta -> 0 is linear.
    x = wp.clamp(a, 0.0, 1.0)
    if beta < 1.0e-4:
        return c_max * x
    return c_max * (1.0 - wp.exp(-beta * x)) / (1.0 - wp.exp(-beta))


@wp.kernel
def _muscle_controls(
    # Model:
    ctrl_rest: wp.array(dtype=wp.vec3),
    ctrl_muscle: wp.array(dtype=wp.int32),
    ctrl_pivot: wp.array(dtype=wp.int32),
    ctrl_jaw: wp.array(dtype=float),
    muscle_activation: wp.array(dtype=wp.int32),
    muscle_contraction: wp.array(dtype=float),
    muscle_saturation: wp.array(dtype=float),
    muscle_center: wp.array(dtype=wp.vec3),
    muscle_center_jaw: wp.array(dtype=float),
    muscle_center_normal: wp.array(dtype=wp.vec3),
    muscle_glide: wp.array(dtype=wp.int32),
    muscle_glide_center: wp.array(dtype=wp.vec3),
    ctrl_head: wp.array(dtype=wp.int32),
    jaw_pivot: wp.array(dtype=wp.vec3),
    jaw_u: wp.array(dtype=wp.vec3),
    jaw_v: wp.array(dtype=wp.vec3),
    # Control:
    activations: wp.array(dtype=float),
    jaw_angles: wp.array(dtype=float),
    # Out:
    ctrl_jawed: wp.array(dtype=wp.vec3),
    ctrl_out: wp.array(dtype=wp.vec3),
):
    p = wp.tid()
    m = ctrl_muscle[p]
    h = ctrl_head[p]
    pv = jaw_pivot[h]
    ju = jaw_u[h]
    jv = jaw_v[h]
    x = _jaw_move(ctrl_rest[p], ctrl_jaw[p], pv, ju, jv, jaw_angles, h)
    ctrl_jawed[p] = x
    a = _contraction(activations[muscle_activation[m]], muscle_contraction[m], muscle_saturation[m])
    piv = ctrl_pivot[p]
    if piv == -2:  # attachment on the bone (or a sphincter point on a ligament): does not contract
        ctrl_out[p] = x
        return
    if piv == -1:  # sphincter: toward the (jaw-moved) ring centre, or its plane (unit normal n)
        target = _jaw_move(muscle_center[m], muscle_center_jaw[m], pv, ju, jv, jaw_angles, h)
        n = muscle_center_normal[m]
        if wp.length(n) > 0.0:
            n = _jaw_move(n, muscle_center_jaw[m], wp.vec3(0.0), ju, jv, jaw_angles, h)
            target = x - n * wp.dot(x - target, n)
    else:
        target = _jaw_move(ctrl_rest[piv], ctrl_jaw[piv], pv, ju, jv, jaw_angles, h)
    y = x + a * (target - x)
    if muscle_glide[m] != 0:  # on the sphere about g through x (g on the cranium: no jaw)
        g = muscle_glide_center[m]
        q = y - g
        lq = wp.length(q)
        if lq > 1.0e-9:
            y = g + q * (wp.length(x - g) / lq)
    ctrl_out[p] = y


@wp.kernel
def _muscle_anchors(
    # Model (anchor k owns the members anchor_ctrl[start[k]] .. anchor_ctrl[start[k+1]-1]):
    start: wp.array(dtype=wp.int32),
    anchor_ctrl: wp.array(dtype=wp.int32),
    anchor_passive: wp.array(dtype=float),
    ctrl_muscle: wp.array(dtype=wp.int32),
    muscle_activation: wp.array(dtype=wp.int32),
    # Control:
    activations: wp.array(dtype=float),
    # In:
    ctrl_jawed: wp.array(dtype=wp.vec3),
    ctrl_contracted: wp.array(dtype=wp.vec3),
    # Out (the members only; a control point belongs to at most one anchor):
    ctrl_out: wp.array(dtype=wp.vec3),
):
    # Fig. 6.3, two-way: members j with own displacements d_j and stiffnesses k_j are tied by
    # springs to one anchor displacement D; the springs' equilibrium minimises
    # sum_j k_j |D - d_j|^2, so D = sum_j k_j d_j / sum_j k_j, and every member moves by D.
    k = wp.tid()
    d = wp.vec3(0.0)
    wsum = float(0.0)
    for j in range(start[k], start[k + 1]):
        p = anchor_ctrl[j]
        w = anchor_passive[j] + wp.clamp(activations[muscle_activation[ctrl_muscle[p]]], 0.0, 1.0)
        d = d + w * (ctrl_contracted[p] - ctrl_jawed[p])
        wsum = wsum + w
    d = d / wp.max(wsum, 1.0e-12)
    for j in range(start[k], start[k + 1]):
        p = anchor_ctrl[j]
        ctrl_out[p] = ctrl_jawed[p] + d


@wp.func
def _bezier(c0: wp.vec3, c1: wp.vec3, c2: wp.vec3, w: wp.vec3, t: float):
    # Rational quadratic Bezier (weights 1, w1, 1 give circular arcs; all 1 is regular).
    b0 = (1.0 - t) * (1.0 - t) * w[0]
    b1 = 2.0 * t * (1.0 - t) * w[1]
    b2 = t * t * w[2]
    return (c0 * b0 + c1 * b1 + c2 * b2) / (b0 + b1 + b2)


@wp.kernel
def _muscle_segments(
    # Model:
    curve_ctrl: wp.array(dtype=wp.vec3i),
    curve_weight: wp.array(dtype=wp.vec3),
    curve_normal_rest: wp.array(dtype=wp.vec3),
    seg_curve: wp.array(dtype=wp.int32),
    seg_t: wp.array(dtype=wp.vec2),
    seg_rest_radii: wp.array(dtype=wp.vec3),
    # In:
    ctrl: wp.array(dtype=wp.vec3),
    # Out:
    seg_center: wp.array(dtype=wp.vec3),
    seg_frame: wp.array(dtype=wp.mat33),
    seg_radii: wp.array(dtype=wp.vec3),
):
    s = wp.tid()
    c = seg_curve[s]
    idx = curve_ctrl[c]
    c0 = ctrl[idx[0]]
    c1 = ctrl[idx[1]]
    c2 = ctrl[idx[2]]
    w = curve_weight[c]
    a = _bezier(c0, c1, c2, w, seg_t[s][0])
    b = _bezier(c0, c1, c2, w, seg_t[s][1])
    chord = b - a
    length = wp.length(chord)
    x = chord / wp.max(length, 1.0e-12)
    n = wp.cross(c1 - c0, c2 - c0)
    if wp.length(n) < 1.0e-12 * (wp.length(c1 - c0) * wp.length(c2 - c0) + 1.0e-30):
        n = curve_normal_rest[c]  # straight curve: keep the rest plane
    n = wp.normalize(n)
    y = wp.cross(n, x)
    y = wp.normalize(y)
    z = wp.cross(x, y)
    rx = 0.525 * length
    r0 = seg_rest_radii[s]
    scale = wp.sqrt(r0[0] / wp.max(rx, 1.0e-12))
    seg_center[s] = 0.5 * (a + b)
    seg_frame[s] = wp.matrix_from_cols(x, y, z)
    seg_radii[s] = wp.vec3(rx, r0[1] * scale, r0[2] * scale)


@wp.func
def _ellipsoid_point(center: wp.vec3, frame: wp.mat33, radii: wp.vec3, u: float, v: float):
    # u in [0, pi] runs along the fibre (x), v in [0, 2 pi) around it.
    local = wp.vec3(radii[0] * wp.cos(u), radii[1] * wp.sin(u) * wp.cos(v), radii[2] * wp.sin(u) * wp.sin(v))
    return center + frame * local


@wp.func
def _attachment_point(
    k: int,
    att_seg: wp.array(dtype=wp.int32),
    att_uv: wp.array(dtype=wp.vec2),
    att_jaw_shift: wp.array(dtype=float),
    att_head: wp.array(dtype=wp.int32),
    jaw_pivot: wp.array(dtype=wp.vec3),
    jaw_u: wp.array(dtype=wp.vec3),
    jaw_v: wp.array(dtype=wp.vec3),
    jaw_angles: wp.array(dtype=float),
    seg_center: wp.array(dtype=wp.vec3),
    seg_frame: wp.array(dtype=wp.mat33),
    seg_radii: wp.array(dtype=wp.vec3),
):
    # The attachment's point p_m on its (current) ellipsoid, from its surface parameters (u, v).
    s = att_seg[k]
    pm = _ellipsoid_point(seg_center[s], seg_frame[s], seg_radii[s], att_uv[k][0], att_uv[k][1])
    # the muscle point turned with the jaw by the muscle's amount there; the node by its own:
    # the difference (a_node - a_muscle) theta is turned in, so the jaw alone strains no spring
    shift = att_jaw_shift[k]
    if shift != 0.0:
        h = att_head[k]
        pm = _jaw_move(pm, shift, jaw_pivot[h], jaw_u[h], jaw_v[h], jaw_angles, h)
    return pm


@wp.func
def _fibre_cosine(pm: wp.vec3, x: wp.vec3, frame: wp.mat33, across: int):
    # |cos theta| of Eq. 6.4.1: the angle between the spring (x -> p_m) and the fibre (the
    # segment's x axis); 0 for a spring of zero length; 1 for a sphincter's spring (across != 0)
    if across != 0:
        return 1.0
    d = pm - x
    length = wp.length(d)
    if length <= 1.0e-12:
        return 0.0
    fibre = wp.vec3(frame[0, 0], frame[1, 0], frame[2, 0])
    return wp.abs(wp.dot(d / length, fibre))


@wp.kernel
def _muscle_forces(
    # Model:
    att_node: wp.array(dtype=wp.int32),
    att_seg: wp.array(dtype=wp.int32),
    att_uv: wp.array(dtype=wp.vec2),
    att_rest_length: wp.array(dtype=float),
    att_stiffness: wp.array(dtype=float),
    att_jaw_shift: wp.array(dtype=float),
    att_across: wp.array(dtype=wp.int32),
    att_head: wp.array(dtype=wp.int32),
    jaw_pivot: wp.array(dtype=wp.vec3),
    jaw_u: wp.array(dtype=wp.vec3),
    jaw_v: wp.array(dtype=wp.vec3),
    # Control:
    jaw_angles: wp.array(dtype=float),
    # In:
    seg_center: wp.array(dtype=wp.vec3),
    seg_frame: wp.array(dtype=wp.mat33),
    seg_radii: wp.array(dtype=wp.vec3),
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    # Out:
    att_point_out: wp.array(dtype=wp.vec3),
    att_force_out: wp.array(dtype=wp.vec3),
):
    k = wp.tid()
    att_force_out[k] = wp.vec3(0.0)
    pm = _attachment_point(k, att_seg, att_uv, att_jaw_shift, att_head, jaw_pivot, jaw_u, jaw_v, jaw_angles, seg_center,
                           seg_frame, seg_radii)
    att_point_out[k] = pm
    i = att_node[k]
    d = pm - positions_in[i]
    length = wp.length(d)
    if length <= 1.0e-12:
        return
    n = d / length
    cos_theta = _fibre_cosine(pm, positions_in[i], seg_frame[att_seg[k]], att_across[k])
    # Eq. 6.4.1: spring toward the muscle, scaled by the cosine of the spring-fibre angle.
    att_force_out[k] = att_stiffness[k] * cos_theta * (length - att_rest_length[k]) * n


# The muscle springs as energy terms for an implicit step (Eq. 6.4.1 made conservative):
#   E_k = 1/2 k_m w_k (|p_m - x| - l0)^2,   w_k = |cos theta| evaluated once per step at the
# step's start positions and held over the step. Within a step this is an energy with the exact
# gradient -k_m w (|p_m - x| - l0) (p_m - x) / |p_m - x| (Eq. 6.4.1 with the frozen cosine) and a
# Hessian, so the step is a minimisation; at rest (and for the Verlet reference, which takes w at
# every substep) the force is Eq. 6.4.1 exactly. (An energy with |cos theta| inside would add a
# force ~ 1/2 k_m (l - l0)^2 / l along the fibre, which dominates where the spring is nearly
# perpendicular to the fibre, as most attachments are at rest.)
@wp.kernel
def _muscle_springs(
    # Model:
    att_node: wp.array(dtype=wp.int32),
    att_seg: wp.array(dtype=wp.int32),
    att_uv: wp.array(dtype=wp.vec2),
    att_stiffness: wp.array(dtype=float),
    att_jaw_shift: wp.array(dtype=float),
    att_across: wp.array(dtype=wp.int32),
    att_head: wp.array(dtype=wp.int32),
    jaw_pivot: wp.array(dtype=wp.vec3),
    jaw_u: wp.array(dtype=wp.vec3),
    jaw_v: wp.array(dtype=wp.vec3),
    # Control:
    jaw_angles: wp.array(dtype=float),
    # In:
    seg_center: wp.array(dtype=wp.vec3),
    seg_frame: wp.array(dtype=wp.mat33),
    seg_radii: wp.array(dtype=wp.vec3),
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    # Out: spring anchor point and effective stiffness k_m w
    att_point_out: wp.array(dtype=wp.vec3),
    spring_stiffness_out: wp.array(dtype=float),
):
    k = wp.tid()
    pm = _attachment_point(k, att_seg, att_uv, att_jaw_shift, att_head, jaw_pivot, jaw_u, jaw_v, jaw_angles, seg_center,
                           seg_frame, seg_radii)
    att_point_out[k] = pm
    spring_stiffness_out[k] = att_stiffness[k] * _fibre_cosine(pm, positions_in[att_node[k]], seg_frame[att_seg[k]],
                                                               att_across[k])


@wp.kernel
def _jaw_targets(
    # Model:
    jaw_node: wp.array(dtype=wp.int32),
    jaw_amount: wp.array(dtype=float),
    rest_positions: wp.array(dtype=wp.vec3),
    jaw_head: wp.array(dtype=wp.int32),
    jaw_pivot: wp.array(dtype=wp.vec3),
    jaw_u: wp.array(dtype=wp.vec3),
    jaw_v: wp.array(dtype=wp.vec3),
    # Control:
    jaw_angles: wp.array(dtype=float),
    # Out:
    targets_out: wp.array(dtype=wp.vec3),
):
    k = wp.tid()
    i = jaw_node[k]
    h = jaw_head[k]
    targets_out[i] = _jaw_move(rest_positions[i], jaw_amount[k], jaw_pivot[h], jaw_u[h], jaw_v[h], jaw_angles, h)


# Sliding support of the inner sheet: the skin glides over the deeper tissue but does not sink
# into it. A spring acts only along the node's rest normal n (carried by the jaw like the rest
# position p0): F = -k_s ((x - p0) . n) n, the gradient of 1/2 k_s ((x - p0) . n)^2. Each
# supported node appears once, so the atomic add is deterministic.
@wp.kernel
def _support_forces(
    # Model:
    support_node: wp.array(dtype=wp.int32),
    support_normal: wp.array(dtype=wp.vec3),
    support_jaw: wp.array(dtype=float),
    support_stiffness: wp.array(dtype=float),
    rest_positions: wp.array(dtype=wp.vec3),
    support_head: wp.array(dtype=wp.int32),
    jaw_pivot: wp.array(dtype=wp.vec3),
    jaw_u: wp.array(dtype=wp.vec3),
    jaw_v: wp.array(dtype=wp.vec3),
    # Control:
    jaw_angles: wp.array(dtype=float),
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    # Out (accumulated):
    forces_out: wp.array(dtype=wp.vec3),
):
    k = wp.tid()
    i = support_node[k]
    a = support_jaw[k]
    h = support_head[k]
    p0 = _jaw_move(rest_positions[i], a, jaw_pivot[h], jaw_u[h], jaw_v[h], jaw_angles, h)
    n = _jaw_move(support_normal[k], a, wp.vec3(0.0), jaw_u[h], jaw_v[h], jaw_angles, h)
    wp.atomic_add(forces_out, i, -support_stiffness[k] * wp.dot(positions_in[i] - p0, n) * n)


# The sliding support as energy terms for an implicit step: the anchor p0 and unit axis n of
# each supported node (jaw-moved); E = 1/2 k_s ((x - p0) . n)^2.
@wp.kernel
def _support_springs(
    # Model:
    support_node: wp.array(dtype=wp.int32),
    support_normal: wp.array(dtype=wp.vec3),
    support_jaw: wp.array(dtype=float),
    rest_positions: wp.array(dtype=wp.vec3),
    support_head: wp.array(dtype=wp.int32),
    jaw_pivot: wp.array(dtype=wp.vec3),
    jaw_u: wp.array(dtype=wp.vec3),
    jaw_v: wp.array(dtype=wp.vec3),
    # Control:
    jaw_angles: wp.array(dtype=float),
    # Out:
    point_out: wp.array(dtype=wp.vec3),
    axis_out: wp.array(dtype=wp.vec3),
):
    k = wp.tid()
    i = support_node[k]
    a = support_jaw[k]
    h = support_head[k]
    point_out[k] = _jaw_move(rest_positions[i], a, jaw_pivot[h], jaw_u[h], jaw_v[h], jaw_angles, h)
    axis_out[k] = _jaw_move(support_normal[k], a, wp.vec3(0.0), jaw_u[h], jaw_v[h], jaw_angles, h)


@wp.func
def _jaw_unmove(p: wp.vec3, amount: float, pivot: wp.vec3, u_axis: wp.vec3, v_axis: wp.vec3, angles: wp.array(dtype=float),
                h: int):
    # inverse of _jaw_move: undo the v rotation, then the u rotation
    q = _rotate_about(p, pivot, v_axis, -angles[2 * h + 1] * amount)
    return _rotate_about(q, pivot, u_axis, -angles[2 * h] * amount)


@wp.kernel
def _jaw_carry(
    # Model:
    carry_node: wp.array(dtype=wp.int32),
    carry_jaw: wp.array(dtype=float),
    carry_head: wp.array(dtype=wp.int32),
    jaw_pivot: wp.array(dtype=wp.vec3),
    jaw_u: wp.array(dtype=wp.vec3),
    jaw_v: wp.array(dtype=wp.vec3),
    # Control:
    jaw_angles: wp.array(dtype=float),
    # Stage state (angles of the last substep):
    jaw_prev: wp.array(dtype=float),
    # State in (moved in place):
    positions: wp.array(dtype=wp.vec3),
    prev_positions: wp.array(dtype=wp.vec3),
):
    # Eq. 6.4.9 applied to the mass points: x <- J(a theta) J(a theta_prev)^-1 x (head h's jaw)
    k = wp.tid()
    h = carry_head[k]
    if jaw_angles[2 * h] == jaw_prev[2 * h] and jaw_angles[2 * h + 1] == jaw_prev[2 * h + 1]:
        return
    i = carry_node[k]
    a = carry_jaw[k]
    pv = jaw_pivot[h]
    ju = jaw_u[h]
    jv = jaw_v[h]
    x = _jaw_unmove(positions[i], a, pv, ju, jv, jaw_prev, h)
    positions[i] = _jaw_move(x, a, pv, ju, jv, jaw_angles, h)
    y = _jaw_unmove(prev_positions[i], a, pv, ju, jv, jaw_prev, h)
    prev_positions[i] = _jaw_move(y, a, pv, ju, jv, jaw_angles, h)


@wp.kernel
def _jaw_remember(jaw_angles: wp.array(dtype=float), jaw_prev: wp.array(dtype=float)):
    # one thread per head
    h = wp.tid()
    jaw_prev[2 * h] = jaw_angles[2 * h]
    jaw_prev[2 * h + 1] = jaw_angles[2 * h + 1]
