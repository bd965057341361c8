"""Warp kernels of the one-Model batch (:mod:`.batch_model`): each head's smallest tet volume ratio."""

from __future__ import annotations

import warp as wp


# The smallest V / V0 over each head's tets (signed volume: <= 0 inverted; a NaN position gives
# -1e30), by atomic min per head (the order of the updates does not change a minimum:
# repeatable). ``ratio_out`` (H,) starts at a large value.
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
    x0 = positions_in[tet_indices[t][0]]
    v = wp.dot(positions_in[tet_indices[t][1]] - x0,
               wp.cross(positions_in[tet_indices[t][2]] - x0, positions_in[tet_indices[t][3]] - x0)) / 6.0
    r = v / tet_rest_volume[t]
    if wp.isnan(r) or wp.isinf(r):
        r = -1.0e30
    wp.atomic_min(ratio_out, tet_head[t], r)
