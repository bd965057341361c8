"""Warp kernels of the contact stage (:mod:`.contact`): surfaces that follow the skin or the jaw,
contact detection against closed surfaces (``wp.Mesh`` queries) and the one-sided spring forces
of the explicit solver. One module (Warp compiles a module at a time; the CPU compile is slow).

Contact springs (:class:`~facewarp._src.physics.model.Springs` with ``one_sided``):

* against a closed surface (the other lip's tet region, a dental arch): the node's closest
  surface point p and the outward unit direction a there give the half-space energy
  ``E = 1/2 k min(0, (x - p') . a)^2`` with ``p' = p + gap a``; the spring is armed for every
  node within ``reach`` of the surface (inside or out) and slack (stiffness 0) beyond;
* against a sphere (the eyeball): ``E = 1/2 k min(0, |x - c| - r)^2``, static; the inner lid
  sheet gliding on the eyeball has the two-sided ``E = 1/2 k (|x - c| - r)^2`` (r its rest distance);
* against a plane (a lid against the palpebral fissure, where the other lid closes to): the
  half-space energy above with a static p and a, set once by :class:`.contact.ContactStage`.

The explicit force is ``-dE/dx``: ``-k s a`` (half-space, ``s = min(0, (x - p') . a)``) and
``-k s (x - c) / |x - c|`` (sphere, ``s = min(0, |x - c| - r)``, or ``|x - c| - r`` two-sided).
"""

from __future__ import annotations

import warp as wp

from .kernels_muscle import _jaw_move


# Copy the nodes of a contact surface out of the tissue positions (the mesh's own points).
@wp.kernel
def _gather_points(
    # Model:
    nodes: wp.array(dtype=wp.int32),
    # State in:
    positions: wp.array(dtype=wp.vec3),
    # Out:
    points_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    points_out[i] = positions[nodes[i]]


# A rigid part moved by the jaw with its Eq. 6.4.9 amount (1: the lower teeth; 0: the upper
# teeth, which ride the cranium).
@wp.kernel
def _rigid_points(
    # Model:
    rest: wp.array(dtype=wp.vec3),
    amount: float,
    pivot: wp.vec3,
    u_axis: wp.vec3,
    v_axis: wp.vec3,
    # Control:
    jaw_angles: wp.array(dtype=float),
    # Out:
    points_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    points_out[i] = _jaw_move(rest[i], amount, pivot, u_axis, v_axis, jaw_angles)


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
    # State in:
    positions: wp.array(dtype=wp.vec3),
    # Out:
    point_out: wp.array(dtype=wp.vec3),
    axis_out: wp.array(dtype=wp.vec3),
    stiffness_out: wp.array(dtype=float),
):
    k = wp.tid()
    x = positions[nodes[k]]
    q = wp.mesh_query_point_sign_normal(mesh, x, reach)
    if not q.result:
        point_out[k] = x
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


# Explicit forces of one-sided half-space springs: f = -k min(0, (x - p) . a) a (the surface
# contacts and the lids' fissure planes). Every node appears once per spring set, so the set
# adds to its nodes without atomics.
@wp.kernel
def _half_space_forces(
    nodes: wp.array(dtype=wp.int32),
    point: wp.array(dtype=wp.vec3),
    axis: wp.array(dtype=wp.vec3),
    stiffness: wp.array(dtype=float),
    positions: wp.array(dtype=wp.vec3),
    forces: wp.array(dtype=wp.vec3),
):
    k = wp.tid()
    i = nodes[k]
    a = axis[k]
    s = wp.min(wp.dot(positions[i] - point[k], a), 0.0)
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
