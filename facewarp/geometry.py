"""Meshes, surface geometry, FDP landmarks, similarity transforms and tet primitives (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.geometry.mesh import (  # noqa: F401
    MESH_SUFFIXES,
    UNITS,
    SurfacePoints,
    closest_surface_points,
    mesh_report,
    save_obj,
    unit_scale,
)
from ._src.geometry.surface import (  # noqa: F401
    ClosestPoints,
    MeshQuery,
    RayHits,
    boundary_vertices,
    closest_point,
    face_areas,
    face_normals,
    mean_curvature,
    vertex_normals,
)
from ._src.geometry.landmarks import (  # noqa: F401
    FDP,
    FDP_CATALOGUE,
    FDP_IDS,
    IBUG68_FDP_OFFSET_MM,
    IBUG68_TO_FDP,
    LANDMARK_SCHEMES,
    LANDMARK_SUFFIXES,
    fapu,
    fdp_sort_key,
    landmarks_from_scheme,
    load_landmarks,
    load_scheme_points,
    save_landmarks_json,
)
from ._src.geometry.similarity import (  # noqa: F401
    Similarity,
    fit_similarity,
    point_spread,
)
from ._src.geometry.tets import (  # noqa: F401
    signed_tet_volumes,
    tet_heights,
)

from ._src.geometry.mesh import save_glb  # noqa: F401
__all__ = ["boundary_vertices", "closest_point", "closest_surface_points", "ClosestPoints", "face_areas",
           "face_normals", "fapu", "FDP", "FDP_CATALOGUE", "FDP_IDS", "fdp_sort_key", "fit_similarity",
           "IBUG68_FDP_OFFSET_MM", "IBUG68_TO_FDP", "LANDMARK_SCHEMES", "LANDMARK_SUFFIXES",
           "landmarks_from_scheme", "load_landmarks", "load_scheme_points", "mean_curvature", "mesh_report",
           "MESH_SUFFIXES", "MeshQuery", "point_spread", "RayHits", "save_glb", "save_landmarks_json", "save_obj",
           "signed_tet_volumes", "Similarity", "SurfacePoints", "tet_heights", "unit_scale", "UNITS",
           "vertex_normals"]
