"""Warp kernels for BVH queries on a triangle mesh (launched by :mod:`geometry`).

Both kernels write Warp's raw barycentric pair ``(u, v)``; the host turns it into three
weights in the order of the face's vertices: ``(u, v, 1 - u - v)`` for ``F[face] = (i, j, k)``,
since Warp evaluates a point as ``p_i u + p_j v + p_k (1 - u - v)`` (``mesh_eval_position``).
A miss writes ``face = -1``.
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def _ray_cast(
    # Model:
    mesh_id: wp.uint64,
    # Query in:
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    max_t: float,
    both_directions: int,
    # Query out:
    face_out: wp.array(dtype=wp.int32),
    t_out: wp.array(dtype=float),
    uv_out: wp.array(dtype=wp.vec2),
):
    # directions are unit length (normalised on the host), so t is a distance. With
    # both_directions the backward hit is reported with a negative t; the nearer one wins,
    # the forward one on a tie.
    tid = wp.tid()
    o = origins[tid]
    d = directions[tid]
    face = int(-1)
    t = float(0.0)
    u = float(0.0)
    v = float(0.0)
    if wp.length_sq(d) > 0.0:
        fwd = wp.mesh_query_ray(mesh_id, o, d, max_t)
        if fwd.result:
            face = fwd.face
            t = fwd.t
            u = fwd.u
            v = fwd.v
        if both_directions != 0:
            bwd = wp.mesh_query_ray(mesh_id, o, -d, max_t)
            if bwd.result:
                if face < 0 or bwd.t < t:
                    face = bwd.face
                    t = -bwd.t
                    u = bwd.u
                    v = bwd.v
    face_out[tid] = face
    t_out[tid] = t
    uv_out[tid] = wp.vec2(u, v)


@wp.kernel
def _closest_point(
    # Model:
    mesh_id: wp.uint64,
    # Query in:
    points: wp.array(dtype=wp.vec3),
    max_dist: float,
    # Query out:
    face_out: wp.array(dtype=wp.int32),
    uv_out: wp.array(dtype=wp.vec2),
):
    tid = wp.tid()
    q = wp.mesh_query_point_no_sign(mesh_id, points[tid], max_dist)
    if q.result:
        face_out[tid] = q.face
        uv_out[tid] = wp.vec2(q.u, q.v)
    else:
        face_out[tid] = -1
        uv_out[tid] = wp.vec2(0.0, 0.0)
