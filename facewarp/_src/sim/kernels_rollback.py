"""Warp kernels of the frame guard (:mod:`.rollback`): the smallest tet volume ratio."""

from __future__ import annotations

import warp as wp


# The smallest V / V0 over all tets (signed volume: <= 0 inverted), by atomic min (the order of
# the updates does not change a minimum: repeatable; a NaN or infinite volume counts as -1e30,
# since a NaN never wins an atomic min). ``ratio_out`` starts at a large value.
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
    x0 = positions_in[tet_indices[t][0]]
    v = wp.dot(positions_in[tet_indices[t][1]] - x0,
               wp.cross(positions_in[tet_indices[t][2]] - x0, positions_in[tet_indices[t][3]] - x0)) / 6.0
    r = v / tet_rest_volume[t]
    if wp.isnan(r) or wp.isinf(r):
        r = -1.0e30
    wp.atomic_min(ratio_out, 0, r)
