"""Anatomy (thesis Sec. 6.2-6.3, 6.4.3): skin tetrahedra, Bezier muscles, jaw kinematics (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.anatomy.tissue import (  # noqa: F401
    SkinLayer,
    boundary_faces,
    boundary_self_intersections,
    extrude_skin_layer,
    split_prisms,
    tet_conformity,
    tet_dihedral_angles,
    tet_mean_ratio,
    tet_quality,
    tet_volumes,
    build_skin_layer,
    skin_layer_quality,
)
from ._src.anatomy.muscles import (  # noqa: F401
    DEFAULT_MUSCLE_DEFS,
    Anchor,
    Ellipsoids,
    Muscle,
    MuscleAttachment,
    MuscleKind,
    MuscleSet,
    arc_length_params,
    attach_nodes,
    bezier_quadratic,
    build_muscles,
    closest_point_on_ellipsoid,
    ellipsoid_points,
    ellipsoid_radii_for_length,
    load_muscle_defs,
    make_linear_muscle,
    muscles_to_json,
    segment_ellipsoids,
)
from ._src.anatomy.build import (  # noqa: F401
    Anatomy,
    SlabHead,
    anatomy_report,
    build_anatomy,
    check_head,
    slab_anatomy,
    write_anatomy,
)
from ._src.anatomy.jaw import (  # noqa: F401
    JawKinematic,
    JAW_REGIONS,
    jaw_rotation,
    rotate_about,
)

__all__ = ["Anatomy", "Anchor", "DEFAULT_MUSCLE_DEFS", "Ellipsoids", "JAW_REGIONS", "JawKinematic", "Muscle", "MuscleAttachment", "MuscleKind", "MuscleSet", "SkinLayer", "SlabHead", "anatomy_report", "arc_length_params", "attach_nodes", "bezier_quadratic", "boundary_faces", "boundary_self_intersections", "build_anatomy", "build_muscles", "build_skin_layer", "check_head", "closest_point_on_ellipsoid", "ellipsoid_points", "ellipsoid_radii_for_length", "extrude_skin_layer", "jaw_rotation", "load_muscle_defs", "make_linear_muscle", "muscles_to_json", "rotate_about", "segment_ellipsoids", "skin_layer_quality", "slab_anatomy", "split_prisms", "tet_conformity", "tet_dihedral_angles", "tet_mean_ratio", "tet_quality", "tet_volumes", "write_anatomy"]
