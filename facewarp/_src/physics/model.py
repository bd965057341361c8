"""The Model: what is simulated, read only, on one device (thesis Sec. 6.4, Table 6.3).

:class:`~.builder.ModelBuilder` collects a head's parts and finalizes one :class:`Model`: the tissue
(:func:`~.tissue.tissue_elements`: edges, faces, tets with their stiffness, damping and masses) and,
per part, a dataclass of its host arrays and its device arrays (:class:`ModelMuscles`,
:class:`ModelSupports`, :class:`ModelJaw`, :class:`ModelContact`; the device arrays of a part sit
beside its stage: :class:`~.muscle_stage.MuscleArrays`, :class:`~.muscle_stage.SupportArrays`,
:class:`~.contact.ContactArrays`, and :class:`JawNodeArrays` here, the jaw's stages living in
``coupling``, a later floor). Every array a step changes is in :class:`~.state.State`; the inputs
are in :class:`~.state.Control`. The Model carries per-head ranges (``head_*_start``), so more heads
are an append.

Unit system
-----------
SI throughout: metre, kilogram, second (so newton and joule). Every energy term of Sec. 6.4.2
is ``E = 1/2 k C^2`` with a *dimensionless* constraint ``C`` (relative length, area or volume
change), so the per-element stiffness coefficients (``edge_k0``, ``face_k``, ``tet_k``) are
energies [J] (the energy of a unit relative strain); masses are [kg]. An edge of rest length
``D0`` acts like a linear spring of stiffness ``k0 / D0^2`` [N/m].

Damping (the same for every solver)
-----------------------------------
* ``damping_rate`` alpha [1/s]: Eq. 6.4.5's ``-k_damping v`` with ``k_damping = alpha m``, on the
  velocity relative to the cranium (``Control.cranium_velocity``), so a head carried at constant
  velocity is not dragged. Table 6.3's 0.002 per substep is ``alpha = 0.002 / dt``.
* per-element dashpots on the strain rate, ``F = -d dC/dt grad C`` with ``d`` [J s] per edge,
  face and tet (``edge_damping``, ``face_damping``, ``tet_damping``): Rayleigh stiffness damping
  ``d = beta k`` plus, on edges, the thesis profile's dashpot ``c`` [N s/m] along the edge
  (``d = c D0^2``). They act on deformation rates only, never on a rigid motion.

Shear term (physical profile, ``shear_modulus`` > 0; absent from Table 6.3)
--------------------------------------------------------------------------
Beside the thesis's three energies, a tet may carry ``E = 1/2 k_s |G|^2`` of its Green strain
``G = (F^T F - I) / 2``, ``F = D_s D_m^-1`` (the deformation gradient of the linear tet), with
``k_s = 2 mu V0`` [J] (Saint Venant-Kirchhoff with lambda = 0: a shear modulus mu) and the dashpot
``d_s = beta k_s`` on ``dG/dt``. Unlike the edge and face energies it is the same material for
any tet shape (:func:`~facewarp._src.physics.materials.linear_stiffness`); see
:class:`~facewarp._src.physics.materials.MaterialPhysical`.
"""


from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .arrays import head_ids, jaw_axes, warp
from .state import Control, State

__all__ = ["JawNodeArrays", "Model", "ModelContact", "ModelJaw", "ModelMuscles", "ModelSupports"]


@dataclass(frozen=True, eq=False)
class Model:
    """Read-only tissue model on one device (made by :meth:`ModelBuilder.finalize`).

    Units: SI (m, kg, s); stiffnesses of the relative-strain energies in J, strain-rate dashpots
    in J s (see the module doc). Arrays are Warp arrays on :attr:`device`; solvers never write them.
    """

    device: object
    """The Warp device holding every array."""
    vertex_count: int
    """Number of mass points n."""
    edge_count: int
    """Number of unique tet edges."""
    face_count: int
    """Number of unique tet faces."""
    tet_count: int
    """Number of tets k."""
    muscle_count: int
    """Number of muscle activations in :class:`Control`."""

    rest_positions: object
    """Rest positions [m], shape (vertex_count,), wp.vec3 (float32)."""
    vertex_mass: object
    """Node mass [kg], shape (vertex_count,), float32."""
    vertex_inv_mass: object
    """Inverse node mass [1/kg], 0 for fixed nodes, shape (vertex_count,), float32."""
    vertex_layer: object
    """Layer, 0 outer / 1 inner, shape (vertex_count,), int32."""
    vertex_fixed: object
    """1 where the node is pinned to its target, else 0; shape (vertex_count,), int32."""
    vertex_hold_stiffness: object
    """Stiffness [N/m] of the spring pulling a held node to its target, 0 for free nodes;
    shape (vertex_count,), float32."""

    edge_indices: object
    """Unique tet edges (i, j), i < j; shape (edge_count,), wp.vec2i (int32)."""
    edge_rest_length: object
    """Rest length D0 [m] (Eq. 6.4.4), shape (edge_count,), float32."""
    edge_k0: object
    """Basic distance stiffness k0 [J] (Eq. 6.4.6), shape (edge_count,), float32."""
    edge_damping: object
    """Dashpot on the edge's strain rate [J s], ``F = -d dC/dt grad C``, shape (edge_count,), float32."""
    edge_class: object
    """EDGE_OUTER / EDGE_INNER / EDGE_CROSS, shape (edge_count,), int32."""

    face_indices: object
    """Unique tet faces (i, j, k), sorted; shape (face_count,), wp.vec3i (int32)."""
    face_rest_area: object
    """Rest area A0 [m^2] (Eq. 6.4.7), shape (face_count,), float32."""
    face_k: object
    """Area stiffness [J] (Eq. 6.4.7), shape (face_count,), float32."""
    face_damping: object
    """Dashpot on the face's area strain rate [J s], shape (face_count,), float32."""

    tet_indices: object
    """Tets (i, j, k, l) with positive signed volume; shape (tet_count,), wp.vec4i (int32)."""
    tet_rest_volume: object
    """Rest signed volume V0 [m^3] (Eq. 6.4.8), > 0; shape (tet_count,), float32."""
    tet_k: object
    """Volume stiffness [J] (Eq. 6.4.8), shape (tet_count,), float32."""
    tet_damping: object
    """Dashpot on the tet's volume strain rate [J s], shape (tet_count,), float32."""
    tet_rest_inverse: object
    """Inverse of the rest edge matrix D_m = [x1 - x0, x2 - x0, x3 - x0] [1/m], shape (tet_count,),
    wp.mat33 (float32): F = D_s D_m^-1 (the shear term, module doc)."""
    tet_shear_k: object
    """Shear term stiffness k_s = 2 mu V0 [J] (module doc; 0: no shear term), shape (tet_count,), float32."""
    tet_shear_damping: object
    """Dashpot on the Green strain rate [J s], shape (tet_count,), float32."""

    slot_count: int
    """Number of per-element force slots: 2 per edge, 3 per face, 4 per tet (edges first)."""
    node_slot_start: object
    """CSR start of each node's slots in :attr:`node_slots`, shape (vertex_count + 1,), int32."""
    node_slots: object
    """Force slots of each node, ascending, shape (slot_count,), int32. The elements write their
    corner forces into their own slots and each node sums its slots in this fixed order, so the
    forces are bit-for-bit reproducible run to run and the same sums on CPU and CUDA (atomic
    adds would add in whatever order threads arrive)."""

    damping_rate: float
    """Mass-proportional damping alpha [1/s] on the velocity relative to the cranium (Eq. 6.4.5)."""
    material: str
    """Name of the material profile the model was built with."""

    head_count: int = 1
    """Number of heads (one per :meth:`ModelBuilder.add_tissue`; a batch appends heads)."""
    head_node_start: np.ndarray = None
    """Each head's first node and the end, shape (head_count + 1,), int64 (host); alike the
    ``head_edge_start``, ``head_face_start``, ``head_tet_start``, ``head_muscle_start`` (activations),
    ``head_ctrl_start`` (muscle control points), ``head_attachment_start`` (muscle springs),
    ``head_support_start`` and ``head_carry_start`` (jaw-carried nodes) ranges."""
    head_edge_start: np.ndarray = None
    head_face_start: np.ndarray = None
    head_tet_start: np.ndarray = None
    head_muscle_start: np.ndarray = None
    head_ctrl_start: np.ndarray = None
    head_attachment_start: np.ndarray = None
    head_support_start: np.ndarray = None
    head_carry_start: np.ndarray = None
    muscles: ModelMuscles | None = None
    """The muscles (:meth:`ModelBuilder.add_muscles`), or None."""
    muscle_ctrl_rest: object = None
    """Rest positions of the muscle control points [m], shape (P,), wp.vec3 (the State's start)."""
    supports: ModelSupports | None = None
    """The sliding supports (:meth:`ModelBuilder.add_supports`)."""
    jaw: ModelJaw | None = None
    """The kinematic jaw (:meth:`ModelBuilder.add_jaw`), or None."""
    contact: ModelContact | None = None
    """The contact (:meth:`ModelBuilder.add_contacts`), or None."""

    def state(self) -> State:
        """A new :class:`State` at rest: positions = previous positions = rest positions, the
        muscle control points at rest, the jaw carried to (0, 0)."""
        wp = warp()
        ctrl = self.muscle_ctrl_rest
        return State(
            positions=wp.clone(self.rest_positions),
            prev_positions=wp.clone(self.rest_positions),
            muscle_ctrl=wp.clone(ctrl) if ctrl is not None else wp.zeros(0, dtype=wp.vec3, device=self.device),
            jaw_carry=wp.zeros(2 * self.head_count, dtype=float, device=self.device),
        )

    def control(self) -> Control:
        """A new :class:`Control`: no activation, jaw closed, no external force, cranium at rest."""
        wp = warp()
        return Control(
            activations=wp.zeros(self.muscle_count, dtype=float, device=self.device),
            jaw_angles=wp.zeros(2 * self.head_count, dtype=float, device=self.device),
            external_force=wp.zeros(self.vertex_count, dtype=wp.vec3, device=self.device),
            cranium_velocity=wp.zeros(2, dtype=wp.vec3, device=self.device),
        )


@dataclass(frozen=True, eq=False)
class ModelMuscles:
    """The muscles of a :class:`Model` (host, NumPy, and their device arrays)."""

    rig: object
    """The :class:`~facewarp._src.physics.muscle_stage.MuscleRig` with its final ``att_stiffness`` [N/m]."""
    node_amount: np.ndarray | None
    """Jaw amount (Eq. 6.4.9) of every node, shape (vertex_count,), float64, or None."""
    arrays: object = None
    """The muscles on the device (:class:`MuscleArrays`, made by :meth:`ModelBuilder.finalize`)."""


@dataclass(frozen=True, eq=False)
class ModelSupports:
    """The sliding supports of a :class:`Model` (host, NumPy, and their device arrays)."""

    nodes: np.ndarray
    """Supported nodes, shape (s,), int64."""
    normals: np.ndarray
    """Their rest normals, shape (s, 3), float64."""
    amounts: np.ndarray
    """Their jaw amounts, shape (s,), float64."""
    stiffness: np.ndarray
    """Spring stiffness [N/m], shape (s,), float64."""
    arrays: object = None
    """The supports on the device (:class:`SupportArrays`, made by :meth:`ModelBuilder.finalize`)."""


@dataclass(frozen=True, eq=False)
class ModelJaw:
    """The kinematic jaw of a :class:`Model` (host, NumPy, and its device arrays)."""

    joint: object
    """Pivot [m] and unit axes of the jaw (``pivot``, ``u_axis``, ``v_axis``; :class:`~facewarp.anatomy.JawKinematic`)."""
    nodes: np.ndarray
    """Fixed / held nodes whose targets turn with the jaw, shape (j,), int64."""
    amounts: np.ndarray
    """Their amounts, shape (j,), float64."""
    carry_nodes: np.ndarray
    """Free nodes carried with the jaw, shape (c,), int64."""
    carry_amounts: np.ndarray
    """Their amounts, shape (c,), float64."""
    target_arrays: JawNodeArrays | None = None
    """The jaw-moved fixed / held nodes on the device (:class:`JawNodeArrays`, by :meth:`ModelBuilder.finalize`)."""
    carry_arrays: JawNodeArrays | None = None
    """The carried free nodes on the device (:class:`JawNodeArrays`, by :meth:`ModelBuilder.finalize`)."""


@dataclass(frozen=True, eq=False)
class ModelContact:
    """The contact of a :class:`Model` (host, NumPy, and its device arrays)."""

    geometry: object
    """The :class:`~facewarp._src.physics.contact.ContactGeometry` (made at build time)."""
    node_stiffness: np.ndarray
    """Contact spring stiffness of every node [N/m], shape (vertex_count,), float64."""
    glide_stiffness: np.ndarray
    """Stiffness of the gliding lid sheet and the lid ties [N/m], shape (vertex_count,), float64."""
    nodes: np.ndarray
    """Rest positions [m], shape (vertex_count, 3), float64 (the contact stage's rest frame)."""
    jaw: object
    """The jaw joint (the lower teeth turn with it), or None."""
    arrays: object = None
    """The contact on the device (:class:`ContactArrays`, made by :meth:`ModelBuilder.finalize`)."""



class JawNodeArrays:
    """Nodes moved by the jaw with their Eq. 6.4.9 amounts (those > 0), on the device
    (:mod:`facewarp._src.coupling.kinematic`'s stages): ``count``; ``nodes`` (j,) int32;
    ``amounts`` (j,) float32; ``pivot``, ``u``, ``v`` (wp.vec3: the jaw); ``rest`` (vertex_count,)
    vec3 [m] (the Model's rest positions, or None for the carry)."""

    def __init__(self, wp, jaw, nodes, amounts, device, rest_positions=None, head=None):
        self.device = device
        keep = np.asarray(amounts) > 0
        self.count = int(keep.sum())
        self.nodes = wp.array(np.asarray(nodes)[keep].astype(np.int32), dtype=wp.int32, device=device)
        self.amounts = wp.array(np.asarray(amounts)[keep].astype(np.float32), dtype=float, device=device)
        self.head = head_ids(wp, None if head is None else np.asarray(head).reshape(-1)[keep], self.count, device)
        self.head_count = len(jaw) if isinstance(jaw, (list, tuple)) else 1
        self.pivot, self.u, self.v = jaw_axes(wp, jaw, device)
        self.rest = rest_positions

