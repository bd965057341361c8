"""Warp kernels of the contact stage (:mod:`.contact`): surfaces that follow the skin or the jaw,
contact detection against closed surfaces (``wp.Mesh`` queries) and the one-sided spring forces
of the explicit solver. One module (Warp compiles a module at a time; the CPU compile is slow).

Contact springs (:class:`~facewarp._src.physics.springs.Springs` with ``one_sided``):

* against a closed surface (the other lip's tet region, a dental arch): the node's closest
  surface point p and the outward unit direction a there give the half-space energy
  ``E = 1/2 k min(0, (x - p') . a)^2`` with ``p' = p + gap a``; the spring is armed for every
  node within ``reach`` of the surface (inside or out) and slack (stiffness 0) beyond;
* against a sphere (the eyeball): ``E = 1/2 k min(0, |x - c| - r)^2``, static; the inner lid
  sheet gliding on the eyeball has, on its glide sphere (c, r per node:
  :func:`.contact.glide_spheres`), the two-sided ``E = 1/2 k (|x - c| - r)^2`` and a one-sided
  floor of the same form;
* against a plane (a lid against the palpebral fissure, where the other lid closes to): the
  half-space energy above with a static p and a, set once by :class:`.contact.ContactStage`;
* lid on lid along the fissure (:func:`_lid_ties`): two-sided axis springs
  ``E = 1/2 k ((x - m) . t)^2`` whose point m is re-detected like the contacts.

The explicit force is ``-dE/dx``: ``-k s a`` (half-space, ``s = min(0, (x - p') . a)``; axis,
``s = (x - m) . t``) and ``-k s (x - c) / |x - c|`` (sphere, ``s = min(0, |x - c| - r)``, or
``|x - c| - r`` two-sided).
"""

from __future__ import annotations

import warp as wp

from .kernels_muscle import _jaw_move


# Copy the nodes of a contact surface out of the tissue positions (the mesh's own points), each
# moved by its head's query shift (one mesh holds the surface of every head of a Model, each head
# shifted to its own cell of the query space so that a head's nodes find only its own surface;
# head 0's shift is 0: a one-head Model queries in place).
@wp.kernel
def _gather_points(
    # Model:
    nodes: wp.array(dtype=wp.int32),
    point_head: wp.array(dtype=wp.int32),
    head_shift: wp.array(dtype=wp.vec3),
    # State in:
    positions: wp.array(dtype=wp.vec3),
    # Out:
    points_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    points_out[i] = positions[nodes[i]] + head_shift[point_head[i]]


# A rigid part moved by the jaw with its Eq. 6.4.9 amount (1: the lower teeth; 0: the upper
# teeth, which ride the cranium).
@wp.kernel
def _rigid_points(
    # Model:
    rest: wp.array(dtype=wp.vec3),
    amount: wp.array(dtype=float),
    point_head: wp.array(dtype=wp.int32),
    head_shift: wp.array(dtype=wp.vec3),
    pivot: wp.array(dtype=wp.vec3),
    u_axis: wp.array(dtype=wp.vec3),
    v_axis: wp.array(dtype=wp.vec3),
    # Control:
    jaw_angles: wp.array(dtype=float),
    # Out:
    points_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    h = point_head[i]
    points_out[i] = _jaw_move(rest[i], amount[i], pivot[h], u_axis[h], v_axis[h], jaw_angles, h) + head_shift[h]


# Contact of each node with one closed, outward-oriented surface: the closest point p within
# `reach` and the side (the angle-weighted pseudo-normal, which is cheap; the winding number
# was measured 30 times slower on the CPU for the same crossings); the outward direction is
# a = (x - p) / |x - p| outside and (p - x) / |x - p| inside (the face normal when x is on the
# surface), d its signed distance (negative inside). The half-space spring (q, a) is armed with
# the node's stiffness, q = p + gap a: the node may come to `gap` of the surface. Against a
# surface that itself comes to meet the node (the other lip, `mutual` = 1), a node outside it by
# less than 2 gap gets the plane halfway instead, q = p + (d + gap) / 2 a: two lips in contact
# are held at their mid-plane, which stays where it is when the contacts are detected again at
# the solution (with the full plane each lip is pushed to where the other was, and back, at
# every detection). A node inside always gets the full plane. Nodes with no surface within reach
# get a slack spring (stiffness 0).
@wp.kernel
def _surface_contacts(
    # Model:
    mesh: wp.uint64,
    reach: float,
    gap: float,
    mutual: int,
    nodes: wp.array(dtype=wp.int32),
    node_stiffness: wp.array(dtype=float),
    node_head: wp.array(dtype=wp.int32),
    head_shift: wp.array(dtype=wp.vec3),
    # State in:
    positions: wp.array(dtype=wp.vec3),
    # Out:
    point_out: wp.array(dtype=wp.vec3),
    axis_out: wp.array(dtype=wp.vec3),
    stiffness_out: wp.array(dtype=float),
):
    k = wp.tid()
    x0 = positions[nodes[k]]
    shift = head_shift[node_head[k]]
    x = x0 + shift  # in the query space (see _gather_points)
    q = wp.mesh_query_point_sign_normal(mesh, x, reach)
    if not q.result:
        point_out[k] = x0
        axis_out[k] = wp.vec3(0.0, 0.0, 1.0)
        stiffness_out[k] = 0.0
        return
    p = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
    d = x - p
    l = wp.length(d)
    a = wp.mesh_eval_face_normal(mesh, q.face)
    inside = q.sign < 0.0
    if l > 1.0e-7:
        a = d / l
        if inside:
            a = -a
    p = p - shift  # back to the head's own frame
    if mutual != 0 and not inside and l < 2.0 * gap:
        point_out[k] = p + 0.5 * (l + gap) * a
    else:
        point_out[k] = p + gap * a
    axis_out[k] = a
    stiffness_out[k] = node_stiffness[k]


# Signed distance of each node to a closed surface within `reach` (negative inside; `reach` when
# no surface is that close): the counter of :func:`contact.contact_crossings`.
@wp.kernel
def _signed_distance(
    mesh: wp.uint64,
    reach: float,
    points: wp.array(dtype=wp.vec3),
    dist_out: wp.array(dtype=float),
):
    k = wp.tid()
    x = points[k]
    q = wp.mesh_query_point_sign_normal(mesh, x, reach)
    if not q.result:
        dist_out[k] = reach
        return
    dist_out[k] = q.sign * wp.length(x - wp.mesh_eval_position(mesh, q.face, q.u, q.v))


# Explicit forces of half-space springs: f = -k s a, s = min(0, (x - p) . a) one-sided (the surface
# contacts and the lids' fissure planes), s = (x - p) . a two-sided (the lid ties). Every node
# appears once per spring set, so the set adds to its nodes without atomics.
@wp.kernel
def _half_space_forces(
    nodes: wp.array(dtype=wp.int32),
    point: wp.array(dtype=wp.vec3),
    axis: wp.array(dtype=wp.vec3),
    stiffness: wp.array(dtype=float),
    one_sided: int,
    positions: wp.array(dtype=wp.vec3),
    forces: wp.array(dtype=wp.vec3),
):
    k = wp.tid()
    i = nodes[k]
    a = axis[k]
    s = wp.dot(positions[i] - point[k], a)
    if one_sided != 0:
        s = wp.min(s, 0.0)
    forces[i] = forces[i] - stiffness[k] * s * a


# Explicit forces of sphere springs: f = -k s (x - c) / |x - c|, s = min(0, |x - c| - r) one-sided
# (out of the eyeball), s = |x - c| - r two-sided (the inner lid sheet gliding on it).
@wp.kernel
def _sphere_forces(
    nodes: wp.array(dtype=wp.int32),
    center: wp.array(dtype=wp.vec3),
    radius: wp.array(dtype=float),
    stiffness: wp.array(dtype=float),
    one_sided: int,
    positions: wp.array(dtype=wp.vec3),
    forces: wp.array(dtype=wp.vec3),
):
    k = wp.tid()
    i = nodes[k]
    r = positions[i] - center[k]
    l = wp.length(r)
    s = l - radius[k]
    if one_sided != 0:
        s = wp.min(s, 0.0)
    if l > 0.0:
        forces[i] = forces[i] - stiffness[k] * s / l * r


# Lid margins that close meet point to point: a lid node k and its partner j across the fissure
# (the other lid's node nearest to it along the plane at rest), both within `reach` of their
# half-space springs at the fissure plane (the margins closing or closed), are drawn together
# along the fissure's tangent t (the corner chord in the plane): each gets the two-sided axis
# spring E = 1/2 k ((x_k - m_k) . t)^2 about m_k = (x_k + x_j) / 2 + s offset_k, offset_k =
# (X_k - X_j) / 2 at rest and s = d / d_rest (clamped to [0, 1]) the pair's distance across the
# plane (d: the sum of the two nodes' distances from their springs' planes) over its rest value.
# So (x_k - x_j) . t shrinks with the opening: the rest offset at rest (no force there), 0 where
# the margins touch. m_k is taken at the positions of the last detection (as the lips'
# mid-plane); a pair not both that near gets stiffness 0.
@wp.kernel
def _lid_ties(
    # Model:
    nodes: wp.array(dtype=wp.int32),
    partner: wp.array(dtype=wp.int32),
    rest_offset: wp.array(dtype=wp.vec3),
    rest_distance: wp.array(dtype=float),
    plane_point: wp.array(dtype=wp.vec3),
    plane_axis: wp.array(dtype=wp.vec3),
    reach: float,
    node_stiffness: wp.array(dtype=float),
    # State in:
    positions: wp.array(dtype=wp.vec3),
    # Out:
    point_out: wp.array(dtype=wp.vec3),
    stiffness_out: wp.array(dtype=float),
):
    k = wp.tid()
    x = positions[nodes[k]]
    j = partner[k]
    point_out[k] = x
    stiffness_out[k] = 0.0
    if j < 0:
        return
    y = positions[nodes[j]]
    dx = wp.dot(x - plane_point[k], plane_axis[k])
    dy = wp.dot(y - plane_point[j], plane_axis[j])
    if dx < reach and dy < reach:
        s = wp.clamp((dx + dy) / wp.max(rest_distance[k], 1.0e-9), 0.0, 1.0)
        point_out[k] = 0.5 * (x + y) + s * rest_offset[k]
        stiffness_out[k] = node_stiffness[k]
