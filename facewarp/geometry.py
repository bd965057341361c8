"""Meshes, surface geometry, FDP landmarks, similarity transforms and tet primitives (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.geometry.mesh import (  # noqa: F401
    MESH_SUFFIXES,
    UNITS,
    Mesh,
    SurfacePoints,
    closest_surface_points,
    load_mesh,
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

__all__ = ["ClosestPoints", "FDP", "FDP_CATALOGUE", "FDP_IDS", "IBUG68_FDP_OFFSET_MM", "IBUG68_TO_FDP", "LANDMARK_SCHEMES", "LANDMARK_SUFFIXES", "MESH_SUFFIXES", "Mesh", "MeshQuery", "RayHits", "Similarity", "SurfacePoints", "UNITS", "boundary_vertices", "closest_point", "closest_surface_points", "face_areas", "face_normals", "fapu", "fdp_sort_key", "fit_similarity", "landmarks_from_scheme", "load_landmarks", "load_scheme_points", "load_mesh", "mean_curvature", "mesh_report", "point_spread", "save_landmarks_json", "save_obj", "signed_tet_volumes", "tet_heights", "unit_scale", "vertex_normals"]
