"""Warp kernels of the frame guard (:mod:`.rollback`) and the one-Model batch (:mod:`.batch_model`):
the smallest tet volume ratio, of the whole Model or of each head."""

from __future__ import annotations

import warp as wp


# A tet's V / V0 (signed volume: <= 0 inverted); a NaN or infinite volume counts as -1e30, since a
# NaN never wins an atomic min.
@wp.func
def _volume_ratio(tet_indices: wp.array(dtype=wp.vec4i), tet_rest_volume: wp.array(dtype=float),
                  positions_in: wp.array(dtype=wp.vec3), t: int):
    x0 = positions_in[tet_indices[t][0]]
    v = wp.dot(positions_in[tet_indices[t][1]] - x0,
               wp.cross(positions_in[tet_indices[t][2]] - x0, positions_in[tet_indices[t][3]] - x0)) / 6.0
    r = v / tet_rest_volume[t]
    if wp.isnan(r) or wp.isinf(r):
        r = -1.0e30
    return r


# The smallest V / V0 over all tets, by atomic min (the order of the updates does not change a
# minimum: repeatable). ``ratio_out`` (1,) starts at a large value.
@wp.kernel
def _min_volume_ratio(
    # Model:
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    # Out:
    ratio_out: wp.array(dtype=float),
):
    t = wp.tid()
    wp.atomic_min(ratio_out, 0, _volume_ratio(tet_indices, tet_rest_volume, positions_in, t))


# The smallest V / V0 over each head's tets (a Model of N faces), by atomic min per head.
# ``ratio_out`` (H,) starts at a large value.
@wp.kernel
def _head_min_volume_ratio(
    # Model:
    tet_indices: wp.array(dtype=wp.vec4i),
    tet_rest_volume: wp.array(dtype=float),
    tet_head: wp.array(dtype=wp.int32),
    # State in:
    positions_in: wp.array(dtype=wp.vec3),
    # Out:
    ratio_out: wp.array(dtype=float),
):
    t = wp.tid()
    wp.atomic_min(ratio_out, tet_head[t], _volume_ratio(tet_indices, tet_rest_volume, positions_in, t))
