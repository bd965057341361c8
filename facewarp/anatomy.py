"""Anatomy (thesis Sec. 6.2-6.3, 6.4.3): skin tetrahedra, Bezier muscles, jaw kinematics (public).

- tet mesh quality: :func:`tet_volumes`, :func:`tet_dihedral_angles`, :func:`tet_mean_ratio`,
  :func:`tet_conformity`, :func:`boundary_faces`, :func:`boundary_self_intersections`,
  :func:`tet_quality`;
- the skin layer (Sec. 6.2): :func:`split_prisms` (Fig. 6.2), :func:`extrude_skin_layer`,
  :func:`build_skin_layer`, :func:`skin_layer_quality`, :class:`SkinLayer`;
- muscle fibres and segments (Sec. 6.3): :func:`bezier_quadratic`, :func:`arc_length_params`,
  :class:`Ellipsoids`, :func:`segment_ellipsoids`, :func:`ellipsoid_points`,
  :func:`closest_point_on_ellipsoid`, :func:`ellipsoid_radii_for_length`;
- skin attachment (Fig. 6.4): :func:`attach_nodes`, :class:`MuscleAttachment`, by area:
  :func:`sheet_samples`, :class:`SheetSamples`, :func:`attach_by_area`;
- the muscles of a head: :func:`load_muscle_defs`, :func:`build_muscles`, :class:`MuscleSet`,
  :class:`Muscle`, :class:`Anchor`, :func:`make_linear_muscle`, :func:`muscles_to_json`,
  :func:`node_regions` (the template regions of every skin node, Fig. 6.4's region filter),
  :func:`depth_normals` (the skin normal that places a control point at a depth);
- the whole anatomy: :func:`build_anatomy`, :func:`write_anatomy`, :func:`slab_anatomy`;
- the kinematic jaw (Sec. 6.4.3): :class:`JawKinematic`, :func:`rotate_about`;
- the lips: :func:`mouth_slit`, :func:`lip_sides`, :func:`lip_tets`, :func:`lip_crossings`,
  :func:`points_in_tets`, :func:`separate_lips`, :func:`separate_skin_lips` (lips that cross at
  rest, moved apart by ``build``).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.anatomy.tet_quality import (  # noqa: F401
    boundary_faces,
    boundary_self_intersections,
    tet_conformity,
    tet_dihedral_angles,
    tet_mean_ratio,
    tet_quality,
    tet_volumes,
)
from ._src.anatomy.extrude import (  # noqa: F401
    TET_QUALITY_FLOOR,
    split_prisms,
)
from ._src.anatomy.tissue import (  # noqa: F401
    SkinLayer,
    build_skin_layer,
    extrude_skin_layer,
    skin_layer_quality,
)
from ._src.anatomy.bezier import (  # noqa: F401
    arc_length_params,
    bezier_quadratic,
)
from ._src.anatomy.ellipsoids import (  # noqa: F401
    Ellipsoids,
    closest_point_on_ellipsoid,
    ellipsoid_points,
    ellipsoid_radii_for_length,
    segment_ellipsoids,
)
from ._src.anatomy.attach import (  # noqa: F401
    MuscleAttachment,
    SheetSamples,
    attach_by_area,
    attach_nodes,
    sheet_samples,
)
from ._src.anatomy.muscles import (  # noqa: F401
    DEFAULT_MUSCLE_DEFS,
    Anchor,
    Muscle,
    MuscleKind,
    MuscleSet,
    build_muscles,
    depth_normals,
    load_muscle_defs,
    make_linear_muscle,
    muscles_to_json,
    node_regions,
)
from ._src.anatomy.build import (  # noqa: F401
    Anatomy,
    SlabHead,
    anatomy_report,
    check_head,
    slab_anatomy,
    write_anatomy,
)
from ._src.anatomy.lips import (  # noqa: F401
    LIP_CLEARANCE,
    lip_crossings,
    lip_sides,
    lip_tets,
    mouth_slit,
    points_in_tets,
    separate_lips,
    separate_skin_lips,
)
from ._src.geometry.jaw import (  # noqa: F401
    JawKinematic,
    JAW_REGIONS,
    jaw_rotation,
    rotate_about,
)

__all__ = ["Anatomy", "anatomy_report", "Anchor", "arc_length_params", "attach_by_area", "attach_nodes",
           "bezier_quadratic", "boundary_faces", "boundary_self_intersections", "build_muscles",
           "build_skin_layer", "check_head", "closest_point_on_ellipsoid", "DEFAULT_MUSCLE_DEFS",
           "ellipsoid_points", "ellipsoid_radii_for_length", "Ellipsoids", "extrude_skin_layer", "JAW_REGIONS",
           "jaw_rotation", "JawKinematic", "LIP_CLEARANCE", "lip_crossings", "lip_sides", "lip_tets",
           "load_muscle_defs", "make_linear_muscle", "mouth_slit", "Muscle", "MuscleAttachment", "MuscleKind",
           "muscles_to_json", "MuscleSet", "node_regions", "points_in_tets", "rotate_about", "segment_ellipsoids",
           "separate_lips", "separate_skin_lips", "sheet_samples", "SheetSamples", "skin_layer_quality",
           "SkinLayer", "slab_anatomy", "SlabHead", "split_prisms", "tet_conformity", "tet_dihedral_angles",
           "tet_mean_ratio", "tet_quality", "TET_QUALITY_FLOOR", "tet_volumes", "write_anatomy"]
