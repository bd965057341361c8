"""Physics (thesis Sec. 6.4), lower level: ModelBuilder -> Model / State / Control, solvers and their stages, the packed face rig (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.physics.builder import ModelBuilder  # noqa: F401
from ._src.physics.model import (  # noqa: F401
    Model,
    ModelContact,
    ModelJaw,
    ModelMuscles,
    ModelSupports,
)
from ._src.physics.state import Control, State  # noqa: F401
from ._src.physics.springs import Springs  # noqa: F401
from ._src.physics.tissue import EDGE_CROSS, EDGE_INNER, EDGE_OUTER, sheet_areas  # noqa: F401
from ._src.physics.stability import (  # noqa: F401
    DT_STABLE_1CM,
    MASS_SCALING_QUANTILE,
    node_stable_dt,
    scale_masses,
    stable_dt,
    thesis_substep,
)
from ._src.physics.materials import (  # noqa: F401
    MATERIALS,
    TISSUE_DENSITY,
    MaterialPhysical,
    MaterialThesis,
    TABLE_6_3,
    isotropic_moduli,
    linear_stiffness,
    material_profile,
)
from ._src.physics.potential import (  # noqa: F401
    StepData,
    StepPotential,
)
from ._src.physics.volume_barrier import (  # noqa: F401
    VOLUME_BARRIER_ONSET,
    VOLUME_BARRIER_STIFFNESS,
    VOLUME_FLOOR,
)
from ._src.physics.solvers.base import (  # noqa: F401
    SolverBase,
    SolverStage,
    check_device,
)
from ._src.physics.solvers.verlet import (  # noqa: F401
    SolverVerlet,
    simulate,
)
from ._src.physics.solvers.implicit import (  # noqa: F401
    IMPLICIT_METHODS,
    SolverImplicit,
)
from ._src.physics.solvers.incremental import IncrementalPotential  # noqa: F401
from ._src.physics.solvers.select import select_solver  # noqa: F401
from ._src.physics.solvers.host_implicit import (  # noqa: F401
    HOST_METHODS,
    SolverHostImplicit,
    factorization_backend,
)
from ._src.physics.solvers.newton_pcg import (  # noqa: F401
    SolverDeviceNewtonPCG,
    default_linear_iterations,
)
from ._src.physics.muscle_stage import (  # noqa: F401
    MuscleRig,
    MuscleStage,
    SupportStage,
    contraction_curve,
    ellipsoid_uv,
    rig_reference,
    segment_frames,
)
from ._src.physics.face_rig import node_jaw_amounts  # noqa: F401
from ._src.anatomy.rig import BONE_REGIONS, MUSCLE_STIFFNESS, face_rig_from_anatomy, muscle_rig  # noqa: F401
from ._src.physics.contact import (  # noqa: F401
    CONTACT_GAP,
    CONTACT_MODULUS,
    CONTACT_MUSCLE_RATIO,
    ContactGeometry,
    ContactStage,
    contact_crossings,
)
from ._src.anatomy.contact import (  # noqa: F401
    contact_geometry,
    lid_contact_geometry,
    lip_contact_geometry,
)
from ._src.sim.simulator import SOLVERS, save_frames_npz  # noqa: F401

__all__ = ["BONE_REGIONS", "check_device", "contact_crossings", "CONTACT_GAP", "contact_geometry",
           "CONTACT_MODULUS", "CONTACT_MUSCLE_RATIO", "ContactGeometry", "ContactStage", "contraction_curve",
           "Control", "default_linear_iterations", "DT_STABLE_1CM", "EDGE_CROSS", "EDGE_INNER", "EDGE_OUTER",
           "ellipsoid_uv", "face_rig_from_anatomy", "factorization_backend", "HOST_METHODS", "IMPLICIT_METHODS",
           "IncrementalPotential", "isotropic_moduli", "lid_contact_geometry", "linear_stiffness",
           "lip_contact_geometry", "MASS_SCALING_QUANTILE", "material_profile", "MaterialPhysical", "MATERIALS",
           "MaterialThesis", "Model", "ModelBuilder", "ModelContact", "ModelJaw", "ModelMuscles", "ModelSupports",
           "muscle_rig", "MUSCLE_STIFFNESS", "MuscleRig", "MuscleStage", "node_jaw_amounts", "node_stable_dt",
           "rig_reference", "save_frames_npz", "scale_masses", "segment_frames", "select_solver", "sheet_areas",
           "simulate", "SolverBase", "SolverDeviceNewtonPCG", "SolverHostImplicit", "SolverImplicit", "SOLVERS",
           "SolverStage", "SolverVerlet", "Springs", "stable_dt", "State", "StepData", "StepPotential",
           "SupportStage", "TABLE_6_3", "thesis_substep", "TISSUE_DENSITY", "VOLUME_BARRIER_ONSET",
           "VOLUME_BARRIER_STIFFNESS", "VOLUME_FLOOR"]
