"""Physics (thesis Sec. 6.4), lower level: ModelBuilder -> Model / State / Control, solvers and their stages, the packed face rig (public).

Re-exports of ``facewarp._src``; see each name's docstring for shapes and units."""

from __future__ import annotations

from ._src.physics.model import (  # noqa: F401
    EDGE_CROSS,
    EDGE_INNER,
    EDGE_OUTER,
    TABLE_6_3,
    Control,
    Model,
    ModelBuilder,
    State,
)
from ._src.physics.solvers.verlet import (  # noqa: F401
    DT_STABLE_1CM,
    MASS_SCALING_QUANTILE,
    SolverStage,
    SolverVerlet,
    node_stable_dt,
    scale_masses,
    simulate,
    stable_dt,
)
from ._src.physics.muscle_stage import (  # noqa: F401
    MuscleRig,
    MuscleStage,
    SupportStage,
    ellipsoid_uv,
    rig_reference,
    segment_frames,
)
from ._src.physics.face_rig import (  # noqa: F401
    BONE_REGIONS,
    MUSCLE_STIFFNESS,
    FaceRig,
    build_face,
    face_rig_from_anatomy,
    load_face_rig,
    muscle_rig,
    node_jaw_amounts,
    save_face_rig,
)
from ._src.coupling.kinematic import (  # noqa: F401
    CarryStage,
    JawStage,
)
from ._src.sim.simulator import (  # noqa: F401
    FaceSimulator,
    Frames,
    save_frames_npz,
)

__all__ = ["BONE_REGIONS", "CarryStage", "Control", "DT_STABLE_1CM", "EDGE_CROSS", "EDGE_INNER", "EDGE_OUTER", "FaceRig", "FaceSimulator", "Frames", "JawStage", "MASS_SCALING_QUANTILE", "MUSCLE_STIFFNESS", "Model", "ModelBuilder", "MuscleRig", "MuscleStage", "SolverStage", "SolverVerlet", "State", "SupportStage", "TABLE_6_3", "build_face", "ellipsoid_uv", "face_rig_from_anatomy", "load_face_rig", "muscle_rig", "node_jaw_amounts", "node_stable_dt", "rig_reference", "save_face_rig", "save_frames_npz", "scale_masses", "segment_frames", "simulate", "stable_dt"]
