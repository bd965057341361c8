"""The 68-point landmark scheme on the default template: where each of its points lies on the head.

A scan that comes with the common 68-point scheme (iBUG 300-W / Multi-PIE order) gives, besides
the 13 points that are FDPs (:data:`~facewarp._src.geometry.landmarks.IBUG68_TO_FDP`), 55 more:
the jaw line, the brows, the nose bridge and the nostrils, the lids, the lips. They pin the rim
of the face (jaw angle, temples) and the features where the 12 or so FDPs of a scan leave the
skin free to slide along the surface. To use them the template needs its own place for each.

:data:`IBUG68_TEMPLATE` is that place on the default template (level 0 rest positions, metres,
the template's frame). It was found on ICT-FaceKit's neutral head, which publishes its 68 points
as vertices (vertex_indices.json, idx_to_landmark_verts; ICT-FaceKit is MIT licensed,
Copyright (c) 2020 USC Institute for Creative Technologies): the default template adapted to that
head with the head's 12 FDPs (:func:`ibug68_template_points`), each ICT point's closest point on the
adapted surface taken back to the template's rest shape by its triangle and barycentric
coordinates. The ICT points lie within 1 mm of the adapted surface but at the lids and the inner
lips (up to 2.8 mm: the template's eye and mouth openings are not ICT's).
"""

from __future__ import annotations

import numpy as np

__all__ = ["IBUG68_KEY", "IBUG68_TEMPLATE", "ibug68_template_points"]

IBUG68_KEY = "ibug68.{}"
"""Landmark id of a 68-point scheme's point N (0-based) that is not an FDP, in the adaptation."""

# 68 x [x, y, z] in mm (the default template's level-0 frame); from ibug68_template_points()
_TABLE_MM = [
    [-74.44, 17.45, 30.03], [-72.82, -6.44, 31.03], [-68.45, -27.19, 36.33], [-61.51, -46.73, 41.76],
    [-52.91, -69.75, 49.65], [-42.14, -88.51, 60.33], [-30.16, -93.23, 73.71], [-14.82, -94.30, 87.45],
    [0.02, -98.02, 87.40], [14.69, -94.32, 87.55], [29.97, -93.27, 73.95], [41.99, -88.47, 60.67],
    [52.78, -70.01, 49.85], [61.22, -47.59, 41.79], [68.20, -28.07, 36.40], [72.72, -7.05, 31.27],
    [74.39, 17.12, 30.29], [-58.79, 32.95, 74.22], [-48.55, 40.41, 84.83], [-36.66, 42.76, 93.59],
    [-22.70, 41.46, 100.18], [-10.78, 38.02, 102.98], [11.30, 37.86, 102.97], [22.86, 41.05, 100.19],
    [36.28, 42.19, 93.93], [48.18, 39.79, 85.28], [58.57, 32.44, 74.54], [-0.10, 15.29, 100.96],
    [0.00, 1.83, 107.35], [0.16, -7.44, 114.44], [0.23, -17.33, 121.40], [-12.66, -32.00, 102.58],
    [-5.25, -31.14, 104.95], [0.00, -31.49, 105.61], [5.25, -31.17, 104.92], [12.67, -32.08, 102.61],
    [-45.28, 12.60, 81.87], [-39.32, 18.26, 90.71], [-26.55, 18.64, 93.80], [-17.00, 11.48, 91.06],
    [-24.75, 8.15, 92.54], [-40.46, 7.93, 90.61], [17.05, 11.38, 91.04], [26.47, 18.30, 94.01],
    [38.32, 18.62, 91.52], [45.35, 12.41, 81.78], [40.28, 7.74, 90.67], [24.84, 8.13, 92.61],
    [-27.07, -54.26, 98.71], [-17.43, -47.81, 106.91], [-6.91, -45.09, 108.70], [0.04, -45.68, 109.51],
    [6.99, -45.13, 108.72], [17.45, -47.84, 106.91], [27.05, -54.23, 98.72], [19.61, -60.55, 105.00],
    [10.80, -63.64, 108.63], [-0.02, -64.53, 110.10], [-10.83, -63.63, 108.62], [-19.63, -60.59, 104.97],
    [-25.25, -54.14, 100.15], [-11.41, -53.46, 108.17], [-0.00, -53.40, 109.94], [11.41, -53.46, 108.17],
    [25.29, -54.13, 100.12], [12.29, -54.53, 107.72], [0.03, -54.60, 109.86], [-12.17, -54.53, 107.76],
]

IBUG68_TEMPLATE: np.ndarray = np.array(_TABLE_MM, dtype=np.float64) * 1e-3
"""Place of each point of the 68-point scheme on the default template [m], shape (68, 3), float64."""
IBUG68_TEMPLATE.setflags(write=False)


def ibug68_template_points(template, ict_vertices: np.ndarray, ict_faces: np.ndarray, ict_indices, *,
                           device: str = "cpu") -> tuple[np.ndarray, np.ndarray]:
    """The 68-point scheme's places on template from a head that has them as vertices.

    Args:
        template: A :class:`~facewarp.Template` (its head FDPs must include ICT's 12).
        ict_vertices: The ICT-FaceKit neutral head [m], shape (11248, 3), float64.
        ict_faces: Its triangles, shape (m, 3), int64.
        ict_indices: The 68 landmark vertex indices (ICT's idx_to_landmark_verts).
        device: Warp device of the closest-point queries.

    Returns:
        (points on the template's rest shape [m] (68, 3), distance of each ICT point to the adapted
        template surface [m] (68,)).
    """
    from ..adapt.pipeline import adapt
    from ..geometry.surface import MeshQuery
    from .likeness import ICT_FDP_VERTICES

    V = np.asarray(ict_vertices, dtype=np.float64)
    tl = template.landmarks()
    res = adapt(template.vertices, template.faces, {k: tl[k] for k in ICT_FDP_VERTICES}, V, ict_faces,
                {k: V[i] for k, i in ICT_FDP_VERTICES.items()}, device=device)
    cp = MeshQuery(res.vertices_scan_frame, template.faces, device=device).closest_point(V[np.asarray(ict_indices)])
    P = np.einsum("kj,kjd->kd", cp.bary, np.asarray(template.vertices)[np.asarray(template.faces)[cp.face]])
    return P, cp.dist
