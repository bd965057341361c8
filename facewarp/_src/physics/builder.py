"""ModelBuilder: what is simulated, collected on the host and finalized once (thesis Sec. 6.4, Table 6.3).

:class:`ModelBuilder` collects a head's parts, computes every material-dependent number and
finalizes one :class:`~.model.Model`: :meth:`~ModelBuilder.add_tissue` (the tet mesh, below),
:meth:`~ModelBuilder.add_muscles` (Eq. 6.4.1), :meth:`~ModelBuilder.add_supports`,
:meth:`~ModelBuilder.add_jaw` (Eq. 6.4.9) and :meth:`~ModelBuilder.add_contacts`, or all of them
from a face rig with :meth:`~ModelBuilder.add_face`. The Model carries per-head ranges
(``head_*_start``), so more heads are an append. Every array a step changes is in :class:`~.state.State`
(positions, previous positions, the muscle control points, the jaw carry); the inputs are in
:class:`~.state.Control`.

The tissue: a generic tetrahedral mesh (numpy), validated, gives the
elements of the deformation model (:func:`~.tissue.tissue_elements`): unique tet edges (distance energy, Eq. 6.4.4 with the
nonlinear stiffness of Eq. 6.4.6), unique tet faces (area energy, Eq. 6.4.7) and the tets
themselves (volume energy, Eq. 6.4.8), with per-element stiffness, damping and per-node masses
from a material profile (:mod:`.materials`: ``thesis``, Table 6.3 as it stands, or
``physical``, the same energies from moduli in Pa and a density). :meth:`ModelBuilder.finalize`
copies everything into a read-only :class:`~.model.Model` of Warp arrays on one device;
:meth:`~.model.Model.state` and :meth:`~.model.Model.control` make the mutable buffers the solvers step
(:class:`~facewarp._src.physics.solvers.implicit.SolverImplicit`,
:class:`~facewarp._src.physics.solvers.verlet.SolverVerlet`).

Units (SI; element stiffnesses the energies [J] of a unit relative strain), the damping and the
shear term are described once, in :mod:`.model`.
"""


from __future__ import annotations

import copy

import numpy as np

from ..core.errors import InputError
from .arrays import group_indices, warp
from .contact import ContactArrays
from .face_rig import node_jaw_amounts
from .materials import (CONTACT_MODULUS, CONTACT_MUSCLE_RATIO, EDGE_DAMPING, MaterialPhysical, MaterialThesis,
                        material_profile)
from .model import JawNodeArrays, Model, ModelContact, ModelJaw, ModelMuscles, ModelSupports
from .muscle_rig import merge_rigs
from .muscle_stage import MuscleArrays, SupportArrays
from .stability import MASS_SCALING_QUANTILE, explicit_step, node_spring_stiffness, scale_masses, thesis_substep
from .tissue import rest_geometry, tissue_elements

__all__ = ["ModelBuilder"]


def _vertex_array(a, n: int, name: str, dtype) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim == 0:
        a = np.full(n, a)
    if a.shape != (n,):
        raise InputError(f"{name} must have shape ({n},) (one value per vertex), got {a.shape}")
    return a.astype(dtype)


def _opt(value, default):
    return default if value is None else value


def _xforms(xforms, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (count, 3, 3) and translations (count, 3) [m] of :meth:`ModelBuilder.replicate`'s ``xforms``."""
    R, t = np.broadcast_to(np.eye(3), (count, 3, 3)).copy(), np.zeros((count, 3))
    if xforms is None:
        return R, t
    items = list(xforms) if not isinstance(xforms, np.ndarray) else list(xforms)
    if len(items) != count:
        raise InputError(f"xforms: expected {count} transforms (one per copy), got {len(items)}")
    for i, x in enumerate(items):
        if isinstance(x, (tuple, list)) and len(x) == 2:
            r, tt = np.asarray(x[0], np.float64), np.asarray(x[1], np.float64)
        else:
            m = np.asarray(x, np.float64)
            if m.shape != (4, 4):
                raise InputError(f"xforms[{i}]: expected (R, t) or a 4 x 4 transform, got shape {m.shape}")
            r, tt = m[:3, :3], m[:3, 3]
        if r.shape != (3, 3) or tt.shape != (3,) or not (np.isfinite(r).all() and np.isfinite(tt).all()):
            raise InputError(f"xforms[{i}]: expected a finite rotation (3, 3) and translation (3,)")
        if np.abs(r @ r.T - np.eye(3)).max() > 1e-6 or np.linalg.det(r) < 0:
            raise InputError(f"xforms[{i}]: not a rotation (R R^T = I, det R = +1)")
        R[i], t[i] = r, tt
    return R, t


class ModelBuilder:
    """Collects what is simulated and finalizes the :class:`Model` (module doc).

    ``ModelBuilder()`` starts empty (then :meth:`add_face`, or :meth:`add_tissue` and the other
    ``add_*``); ``ModelBuilder(vertices, tets, **tissue)`` calls :meth:`add_tissue` at once. The
    tissue validates a tet mesh and derives the elements of the deformation model (Sec. 6.4).

    The arguments are those of :meth:`add_tissue` (``muscle_count``: the constructor's).

    Args:
        vertices: Rest positions [m], shape (n, 3), float.
        tets: Tetrahedra, shape (k, 4), int; each must have positive signed volume
            ``(1/6) (x1 - x0) . ((x2 - x0) x (x3 - x0))`` (see :func:`facewarp.geometry.signed_tet_volumes`).
        layer: Layer of each vertex, shape (n,), int: 0 outer (skin surface), 1 inner.
            Sets the edge class and so ``k0`` (Table 6.3). Default: all outer.
        fixed: Nodes pinned to their target (the rest position unless a solver stage moves
            it), shape (n,), bool. Default: none.
        held: Nodes pulled to their target by a spring of ``hold_stiffness``, shape (n,),
            bool. Default: none.
        material: ``"thesis"`` (default: Table 6.3 as it stands), ``"physical"`` or a
            :class:`~facewarp._src.physics.materials.MaterialThesis` /
            :class:`~facewarp._src.physics.materials.MaterialPhysical`. The keywords below
            override single values of the profile.
        mass: Node mass [kg], scalar or shape (n,). Default: the profile's (thesis 0.5 kg;
            physical: density times a quarter of each incident tet's volume).
        damping_rate: Mass-proportional damping alpha [1/s] on the velocity relative to the
            cranium. Default: physical 50; thesis Table 6.3's 0.002 per substep of ``substep``.
        substep: The Verlet reference substep [s] that turns the thesis profile's per-substep
            damping into a rate. Default: :func:`thesis_substep` of the mesh (the shortest edge,
            the lightest node, the stiffest k0).
        stiffness_damping: Rayleigh stiffness damping beta [s]: every element gets a dashpot
            ``beta k`` on its strain rate. Default: physical 2e-5, thesis 0.
        edge_damping: Dashpot along each edge on the relative velocity [N s/m] (Eq. 6.4.5 per
            spring). Default: the thesis profile's ``edge_damping`` (0; the face simulator's
            thesis profile uses 500), physical 0.
        k0_outer, k0_inner, k0_cross: Basic distance stiffness k0 [J] of Eq. 6.4.6 for
            outer-outer, inner-inner and cross-layer edges, the same for every edge of a class
            (thesis profile: 15, 10, 5). With the physical profile they come from its moduli.
        k_area: Area stiffness [J] of every face (Eq. 6.4.7; thesis 7.5).
        k_volume: Volume stiffness [J] of every tet (Eq. 6.4.8; thesis 7.5).
        hold_stiffness: Spring stiffness [N/m] pulling each ``held`` node to its target.
            Default (None): thesis: four times the 98th percentile of the rest edge springs,
            ``4 k0 / D0^2`` (6e5 N/m for 1 cm outer edges), stiff against the tissue; a few very
            short edges (a crease of an adapted head) do not stiffen every hold. Physical:
            ``hold_modulus`` [N/m^3] times the node's sheet area (:func:`sheet_areas`).
        muscle_count: Number of muscle activations in :class:`Control` (default 0; :meth:`add_muscles`
            sets it to the rig's muscles).

    Raises:
        InputError: on bad shapes, indices out of range, repeated vertices in a tet, an
            inverted or degenerate tet (naming its index), or bad coefficients (negative or
            non-finite values, a material with no stiffness at all).

    Attributes (numpy, float64 / int64; ``finalize`` copies them as float32 / int32):
        vertices (n, 3) [m], tets (k, 4), layer (n,), fixed (n,) bool, held (n,) bool (never
        also fixed), mass (n,) [kg], hold_stiffness (n,) [N/m] (0 where not held),
        vertex_area (n,) [m^2] (:func:`sheet_areas`), vertex_volume (n,) [m^3] (a quarter of
        each incident tet); edges (e, 2) unique, i < j; edge_rest_lengths (e,) [m];
        edge_class (e,) EDGE_*; edge_k0 (e,) [J]; edge_damping_coef (e,) [J s];
        faces (f, 3) unique, sorted; face_rest_areas (f,) [m^2]; face_k (f,) [J];
        face_damping_coef (f,) [J s]; tet_rest_volumes (k,) [m^3]; tet_k (k,) [J];
        tet_damping_coef (k,) [J s]; tet_rest_inverse (k, 3, 3) [1/m]; tet_shear_k (k,) [J];
        tet_shear_damping (k,) [J s] (the shear term, module doc); tet_edge_index (k, 6), tet_face_index
        (k, 4): each tet's edges and faces as rows of ``edges`` / ``faces``; damping_rate [1/s]; stiffness_damping [s];
        edge_damping [N s/m]; material (the profile); muscle_count; head_count. The other
        ``add_*`` set ``muscle_rig``, ``muscle_node_amount``; ``support_nodes``, ``support_normal``,
        ``support_amount``, ``support_stiffness`` (s,) [N/m]; ``jaw``, ``jaw_nodes``, ``jaw_amount``,
        ``carry_nodes``, ``carry_amount``; ``contact_geometry``, ``contact_stiffness`` and
        ``glide_stiffness`` (n,) [N/m].
    """

    def __init__(self, vertices=None, tets=None, *, muscle_count: int = 0, **tissue):
        if isinstance(muscle_count, bool) or not isinstance(muscle_count, (int, np.integer)) or muscle_count < 0:
            raise InputError(f"muscle_count must be a whole number >= 0, got {muscle_count}")
        self.head_count = 0
        self.muscle_count = int(muscle_count)
        self.muscle_rig = None
        self.muscle_node_amount = None
        self.support_nodes = np.zeros(0, np.int64)
        self.support_normal = np.zeros((0, 3))
        self.support_amount = np.zeros(0)
        self.support_stiffness = np.zeros(0)
        self._support_k = 0.0
        self._support_given = False
        self.jaw = None
        self.jaw_nodes = np.zeros(0, np.int64)
        self.jaw_amount = np.zeros(0)
        self.carry_nodes = np.zeros(0, np.int64)
        self.carry_amount = np.zeros(0)
        self.contact_geometry = None
        self.contact_stiffness = None
        self.glide_stiffness = None
        if vertices is not None or tets is not None:
            self.add_tissue(vertices, tets, **tissue)
        elif tissue:
            raise InputError(f"{', '.join(sorted(tissue))}: tissue keywords need the vertices and tets")

    def add_tissue(
        self,
        vertices,
        tets,
        *,
        layer=None,
        fixed=None,
        held=None,
        material=None,
        mass=None,
        damping_rate: float | None = None,
        substep: float | None = None,
        stiffness_damping: float | None = None,
        edge_damping: float | None = None,
        k0_outer: float | None = None,
        k0_inner: float | None = None,
        k0_cross: float | None = None,
        k_area: float | None = None,
        k_volume: float | None = None,
        hold_stiffness: float | None = None,
    ) -> None:
        """The skin tissue of one head: the tet mesh, its boundary conditions and its material
        (the class doc lists the arguments and the attributes it sets).

        Raises:
            InputError: as the class doc, or a second head (more heads: :meth:`add_builder`).
        """
        if self.head_count:
            raise InputError("add_tissue: this builder has its head already (one head per builder; append more heads with add_builder)")
        mat = material if isinstance(material, (MaterialThesis, MaterialPhysical)) else material_profile(
            "thesis" if material is None else material)
        physical = isinstance(mat, MaterialPhysical)
        el = tissue_elements(vertices, tets, layer)  # validated; rest measures on the float32 positions
        V, T, layer = el.vertices, el.tets, el.layer
        n = len(V)
        fixed = np.zeros(n, bool) if fixed is None else _vertex_array(fixed, n, "fixed", bool)
        held = np.zeros(n, bool) if held is None else _vertex_array(held, n, "held", bool)
        for name, val in (("damping_rate", damping_rate), ("substep", substep),
                          ("stiffness_damping", stiffness_damping), ("edge_damping", edge_damping),
                          ("k0_outer", k0_outer), ("k0_inner", k0_inner), ("k0_cross", k0_cross),
                          ("k_area", k_area), ("k_volume", k_volume)):
            if val is not None and not (np.isfinite(val) and val >= 0.0):
                raise InputError(f"{name} must be a finite value >= 0, got {val}")
        if substep is not None and substep <= 0.0:
            raise InputError(f"substep must be > 0 [s], got {substep}")
        edge_class, D0, vol, area = el.edge_class, el.edge_rest_lengths, el.tet_rest_volumes, el.vertex_area
        nF = len(el.faces)

        if physical:
            mod = np.asarray(mat.distance_modulus, dtype=np.float64)
            k0 = mod[edge_class] * el.edge_volume
            face_k = mat.area_modulus * el.face_volume
            tet_k = mat.volume_modulus * vol
            mass_default = mat.density * el.vertex_volume
            beta = mat.stiffness_damping
            alpha = mat.damping_rate
            c_edge = 0.0
        else:
            k0 = np.array([mat.k0_outer, mat.k0_inner, mat.k0_cross], dtype=np.float64)[edge_class]
            face_k = np.full(nF, mat.k_area)
            tet_k = np.full(len(T), mat.k_volume)
            mass_default = np.full(n, mat.mass)
            beta = 0.0
            alpha = None  # the per-substep damping, converted below
            c_edge = mat.edge_damping
        if k0_outer is not None or k0_inner is not None or k0_cross is not None:
            cls_k = [k0_outer, k0_inner, k0_cross]
            for c in range(3):
                if cls_k[c] is not None:
                    k0 = np.where(edge_class == c, float(cls_k[c]), k0)
        if k_area is not None:
            face_k = np.full(nF, float(k_area))
        if k_volume is not None:
            tet_k = np.full(len(T), float(k_volume))
        mass = mass_default if mass is None else _vertex_array(mass, n, "mass", np.float64)
        if not (np.isfinite(mass).all() and (mass > 0).all()):
            raise InputError(f"mass must be positive and finite [kg], got min {mass.min()}")
        shear = float(mat.shear_modulus) if physical else 0.0
        if k0.max(initial=0.0) + face_k.max(initial=0.0) + tet_k.max(initial=0.0) + shear <= 0.0:
            raise InputError("the material has no stiffness: k0, k_area and k_volume are all 0")
        beta = _opt(stiffness_damping, beta)
        c_edge = _opt(edge_damping, c_edge)
        if damping_rate is not None:
            alpha = float(damping_rate)
        elif alpha is None:
            dt_ref = substep if substep is not None else float(thesis_substep(D0.min(), mass.min(), k0.max()))
            alpha = mat.damping / dt_ref

        if hold_stiffness is None:
            if physical:
                hold = mat.hold_modulus * area
            else:
                hold = np.full(n, 4.0 * float(np.quantile(k0 / D0**2, 0.98)))
        else:
            if not (np.isfinite(hold_stiffness) and hold_stiffness >= 0.0):
                raise InputError(f"hold_stiffness must be a finite value >= 0 [N/m], got {hold_stiffness}")
            hold = np.full(n, float(hold_stiffness))

        self.material = mat
        self.vertices = V
        self.tets = T
        self.layer = layer
        self.fixed = fixed
        self.held = held & ~fixed
        self.mass = mass
        self.vertex_area = area
        self.vertex_volume = el.vertex_volume
        self.damping_rate = float(alpha)
        self.stiffness_damping = float(beta)
        self.edge_damping = float(c_edge)
        self.edges = el.edges
        self.tet_edge_index = el.tet_edge_index  # each tet's edges (TET_EDGES order) in self.edges
        self.tet_face_index = el.tet_face_index  # each tet's faces (TET_FACES order) in self.faces
        self.edge_rest_lengths = D0
        self.edge_class = edge_class
        self.edge_k0 = k0
        self.edge_damping_coef = beta * k0 + c_edge * D0**2
        self.faces = el.faces
        self.face_rest_areas = el.face_rest_areas
        self.face_k = face_k
        self.face_damping_coef = beta * face_k
        self.tet_rest_volumes = vol
        self.tet_k = tet_k
        self.tet_damping_coef = beta * tet_k
        self.tet_rest_inverse = el.tet_rest_inverse
        self.tet_shear_k = 2.0 * shear * vol
        self.tet_shear_damping = beta * self.tet_shear_k
        self.hold_stiffness = np.where(self.held, hold, 0.0)
        self.head_count = 1

    def _need_tissue(self, what: str) -> None:
        if not self.head_count:
            raise InputError(f"{what}: add the tissue first (add_tissue or add_face)")

    def _node_index(self, nodes, name: str) -> np.ndarray:
        idx = np.asarray(nodes, dtype=np.int64).reshape(-1)
        if len(idx) and (idx.min() < 0 or idx.max() >= self.vertex_count):
            raise InputError(f"{name}: node indices must lie in 0..{self.vertex_count - 1}")
        return idx

    def add_muscles(self, rig, *, node_amount=None) -> None:
        """The muscles of Eq. 6.4.1 (:class:`~facewarp._src.physics.muscle_stage.MuscleRig`), with
        their spring stiffness from the material: physical ``muscle_modulus`` times the node's sheet
        area, thesis its ``muscle_stiffness`` (when set; else the rig's own), shared equally by the
        springs on a node (the stage then splits it by the area weights).

        Args:
            rig: The packed muscles (``att_node`` index this builder's nodes).
            node_amount: Jaw amount (Eq. 6.4.9) of every node, shape (vertex_count,), float: each
                spring's muscle end turns with the jaw by its node's amount (default: the muscle's).

        Sets ``muscle_rig`` (the rig with the final ``att_stiffness`` [N/m]), ``muscle_node_amount``
        and ``muscle_count`` (the activations in :class:`Control`: one per muscle). The rig's own
        checks (:meth:`~facewarp.physics.MuscleRig.validate`) run in :meth:`finalize`, with its derived arrays.
        """
        self._need_tissue("add_muscles")
        n, mat = self.vertex_count, self.material
        att = self._node_index(rig.att_node, "rig.att_node")
        per_node = np.bincount(att, minlength=n)
        if isinstance(mat, MaterialPhysical) or mat.muscle_stiffness is not None:
            rig = copy.copy(rig)  # the rig with the builder's stiffness (finalize validates it)
            rig.att_stiffness = (mat.muscle_modulus * self.vertex_area[att] if isinstance(mat, MaterialPhysical)
                                 else mat.muscle_stiffness) / np.maximum(per_node[att], 1)
        if node_amount is not None:
            node_amount = _vertex_array(node_amount, n, "node_amount", np.float64)
        self.muscle_rig = rig
        self.muscle_node_amount = node_amount
        self.muscle_count = len(rig.names)

    def add_supports(self, nodes, normals, amounts, *, stiffness=None) -> None:
        """Sliding supports of inner-sheet nodes along their rest normal, moved with the jaw
        (:class:`~facewarp._src.physics.muscle_stage.SupportStage`).

        Args:
            nodes: Supported nodes, shape (s,), int.
            normals: Their unit rest normals, shape (s, 3), float.
            amounts: Their jaw amounts (Eq. 6.4.9), shape (s,), float.
            stiffness: Spring stiffness [N/m], scalar or shape (s,) (default: physical
                ``support_modulus`` times the node's sheet area; thesis the largest hold stiffness).
        """
        self._need_tissue("add_supports")
        nodes = self._node_index(nodes, "support nodes")
        if stiffness is None:
            if isinstance(self.material, MaterialPhysical):
                k = self.material.support_modulus * self.vertex_area[nodes]
            else:
                k = float(self.hold_stiffness.max()) if self.held.any() else 0.0
        else:
            k = stiffness
        self.support_nodes = nodes
        self.support_normal = np.asarray(normals, np.float64).reshape(-1, 3)
        self.support_amount = np.asarray(amounts, np.float64).reshape(-1)
        self._support_k = k
        self._support_given = stiffness is not None
        self.support_stiffness = np.broadcast_to(np.asarray(k, np.float64), (len(nodes),)).copy()
        if not (np.isfinite(self.support_stiffness).all() and (self.support_stiffness >= 0).all()):
            raise InputError(f"support stiffness must be finite and >= 0 [N/m], got {stiffness!r}")

    def add_jaw(self, jaw, nodes, amounts, *, node_amount=None) -> None:
        """The kinematic jaw (Eq. 6.4.9): the targets of the fixed / held nodes it carries, and the
        carry of the free nodes with a jaw amount (``coupling.kinematic``).

        Args:
            jaw: Anything with ``pivot``, ``u_axis``, ``v_axis`` (:class:`~facewarp.anatomy.JawKinematic`).
            nodes: Fixed / held nodes whose targets turn with the jaw, shape (j,), int.
            amounts: Their amounts, shape (j,), float.
            node_amount: Amount of every node, shape (vertex_count,) (default: none carried).
        """
        self._need_tissue("add_jaw")
        self.jaw = jaw
        self.jaw_nodes = self._node_index(nodes, "jaw nodes")
        self.jaw_amount = np.asarray(amounts, np.float64).reshape(-1)
        if node_amount is not None:
            a = _vertex_array(node_amount, self.vertex_count, "node_amount", np.float64)
            self.carry_nodes = np.flatnonzero((a > 0) & ~self.fixed)
            self.carry_amount = a[self.carry_nodes]

    def add_contacts(self, geometry, *, modulus: float | None = None) -> None:
        """Lip, teeth, eyeball and lid contact (:class:`~facewarp._src.physics.contact.ContactStage`)
        with its stiffness; add the muscles and supports first.

        A node's contact spring holds against the tissue (physical ``modulus`` times its sheet area,
        default ``CONTACT_MODULUS``; thesis its hold stiffness) and against its own muscle springs
        (``CONTACT_MUSCLE_RATIO`` times them). The inner lid sheet gliding on the eyeball and the
        lid ties get the sliding support's stiffness.

        Args:
            geometry: The rig's :class:`~facewarp._src.physics.contact.ContactGeometry`.
            modulus: Contact stiffness per unit sheet area [N/m^3], > 0 (physical profile).
        """
        self._need_tissue("add_contacts")
        if modulus is not None and not (isinstance(modulus, (int, float)) and np.isfinite(modulus) and modulus > 0):
            raise InputError(f"contact_modulus: expected a positive number [N/m^3], got {modulus!r}")
        n, mat = self.vertex_count, self.material
        physical = isinstance(mat, MaterialPhysical)
        rig = self.muscle_rig
        k_muscle = (np.bincount(rig.att_node, weights=rig.att_stiffness, minlength=n) if rig is not None
                    else np.zeros(n))
        if physical:
            k_contact = float(modulus or CONTACT_MODULUS) * self.vertex_area
        else:
            k_contact = np.full(n, float(self.hold_stiffness.max()) if self.held.any() else 0.0)
        self.contact_stiffness = k_contact + CONTACT_MUSCLE_RATIO * k_muscle
        k_s = self._support_k
        self.glide_stiffness = (mat.support_modulus * self.vertex_area if physical and not self._support_given
                                else np.full(n, float(np.median(k_s)) if np.size(k_s) else 0.0))
        self.contact_geometry = geometry

    def add_face(self, fr, *, material=None, edge_damping: float | None = None, support_stiffness=None,
                 contact: bool = True, contact_modulus: float | None = None, mass_scaling: bool = True) -> None:
        """One face rig (:class:`~facewarp._src.physics.face_rig.FaceRig`): its tissue, muscles,
        supports, jaw and contact, every stiffness from ``material``.

        Args:
            fr: The face rig (``facewarp build``, :func:`~facewarp.build_face`).
            material: ``"physical"`` (default), ``"thesis"`` or a material object.
            edge_damping: Edge dashpot [N s/m] (default: thesis :data:`EDGE_DAMPING`, physical 0).
            support_stiffness: Sliding-support stiffness [N/m] (default: from the material).
            contact: Add the contact (the rig's ``contact`` geometry, made at build time).
            contact_modulus: As :meth:`add_contacts`.
            mass_scaling: The thesis profile's damping rate is Table 6.3's 0.002 per substep of
                the Verlet reference with (True) or without selective mass scaling
                (:meth:`explicit_step` sets it from the step the explicit solver takes).

        Called again on a builder that has a face, it appends another head (its own rest shape,
        material, muscles, jaw, supports and contact) to the same Model (:meth:`add_faces`): one
        Model of N faces, each kernel launch covering every head's elements.

        Raises:
            InputError: bad values, or ``contact`` with a rig that has no contact geometry; a
                further face whose damping rate differs from the first's, or one added to a
                builder of tissue-only heads.
        """
        if self.head_count:
            sub = ModelBuilder()
            sub.add_face(fr, material=material, edge_damping=edge_damping, support_stiffness=support_stiffness,
                         contact=contact, contact_modulus=contact_modulus, mass_scaling=mass_scaling)
            self._append_faces([sub])
            return
        mat = material if isinstance(material, (MaterialThesis, MaterialPhysical)) else material_profile(
            "physical" if material is None else material)
        physical = isinstance(mat, MaterialPhysical)
        if edge_damping is None:
            edge_damping = 0.0 if physical else EDGE_DAMPING
        if contact and getattr(fr, "contact", None) is None:
            raise InputError("fr: the face rig has no contact geometry (make it with facewarp.build_face, or "
                             "rebuild an older build with `facewarp build`); or pass contact=False")
        self.add_tissue(fr.nodes, fr.tets, layer=fr.layer, fixed=fr.fixed, held=fr.held, material=mat,
                        edge_damping=edge_damping)
        node_jaw = node_jaw_amounts(fr)
        self.add_muscles(fr.rig, node_amount=node_jaw)
        self.add_supports(fr.support_nodes, fr.support_normal, fr.support_amount, stiffness=support_stiffness)
        self.add_jaw(fr.jaw, fr.jaw_nodes, fr.jaw_amount, node_amount=node_jaw)
        if contact:
            self.add_contacts(fr.contact, modulus=contact_modulus)
        if not physical:  # Table 6.3's per-substep damping as a rate, at the reference's substep
            ref = copy.copy(self)  # the tissue alone: no springs, the masses not scaled
            ref.mass = self.mass.copy()
            dt_ref, _ = scale_masses(ref, quantile=MASS_SCALING_QUANTILE if mass_scaling else 0.0)
            self.damping_rate = mat.damping / dt_ref

    _FACE_FIELDS = ("support_nodes", "support_normal", "support_amount", "support_stiffness", "jaw_nodes",
                    "jaw_amount", "carry_nodes", "carry_amount", "contact_stiffness", "glide_stiffness")
    _NODE_INDEX = ("support_nodes", "jaw_nodes", "carry_nodes")

    def add_faces(self, rigs, **options) -> None:
        """:meth:`add_face` of every rig in ``rigs`` (a list of face rigs; ``options`` are
        :meth:`add_face`'s keywords, the same for all), appended in one concatenation; a rig that
        appears more than once is built once (its heads share the host geometry)."""
        rigs = list(rigs)
        if not rigs:
            return
        if not self.head_count:
            self.add_face(rigs[0], **options)
            rigs = rigs[1:]
        built: dict[int, ModelBuilder] = {}
        subs = []
        for fr in rigs:
            if id(fr) not in built:
                sub = ModelBuilder()
                sub.add_face(fr, **options)
                built[id(fr)] = sub
            subs.append(built[id(fr)])
        self._append_faces(subs)

    def _append_faces(self, subs: list) -> None:
        """Append the one face of each builder in ``subs`` (made by :meth:`add_face`) as further
        heads: every array concatenated, node / element / muscle indices shifted by the counts
        before it (the per-head ranges of :class:`Model`); the per-head parts kept in ``_faces``
        for :meth:`finalize` (each head's jaw, muscle rig and contact geometry)."""
        if not subs:
            return
        faces = getattr(self, "_faces", None)
        if faces is None:
            if self.head_count != 1 or not self._has_stages():
                raise InputError("add_face: this builder's heads are tissue only (add_tissue / replicate); add faces "
                                 "to an empty builder or to one made by add_face")
            faces = [copy.copy(self)]
        for k, sub in enumerate(subs):
            h = len(faces) + k
            if sub.head_count != 1 or getattr(sub, "_faces", None) is not None:
                raise InputError(f"add_face: head {h}: expected a builder of one face")
            if not np.isclose(sub.damping_rate, faces[0].damping_rate, rtol=1e-6):
                raise InputError(f"add_face: head {h}'s damping rate {sub.damping_rate:g} 1/s differs from head "
                                 f"0's {faces[0].damping_rate:g} 1/s (one rate per Model: use one material profile)")
            if (sub.contact_geometry is None) != (faces[0].contact_geometry is None):
                raise InputError(f"add_face: head {h} {'has no' if sub.contact_geometry is None else 'has'} "
                                 "contact, head 0 the other way (one Model: all heads with contact or none)")
        faces = faces + list(subs)
        self._concatenate([(f, None) for f in faces])
        n_off = self._ranges["node"]
        for name in self._FACE_FIELDS:
            rows = []
            for h, f in enumerate(faces):
                a = getattr(f, name)
                if a is None:
                    a = np.zeros(f.vertex_count)
                rows.append(a + n_off[h] if name in self._NODE_INDEX else a)
            setattr(self, name, np.concatenate(rows, axis=0))
        self._faces = faces
        self.head_count = len(faces)
        self.jaw = [f.jaw for f in faces]
        self.contact_geometry = None if faces[0].contact_geometry is None else [f.contact_geometry for f in faces]
        self._support_k = self.support_stiffness
        self.muscle_count = int(sum(f.muscle_count for f in faces))
        self.muscle_rig, self._muscle_heads = merge_rigs(
            [(f.muscle_rig, f.muscle_node_amount) for f in faces], n_off)
        self.muscle_node_amount = None

    def node_spring_stiffness(self) -> np.ndarray:
        """The springs the added stages put on each node [N/m], (vertex_count,), float64
        (:func:`~.stability.node_spring_stiffness`)."""
        return node_spring_stiffness(self)

    def explicit_step(self, frame_dt: float, *, dt: float | None = None, substeps: int | None = None,
                      mass_scaling: bool = True) -> tuple[int, float, float]:
        """The Verlet reference's ``(substeps, dt [s], added mass fraction)`` for frames of ``frame_dt`` [s],
        the masses scaled (:func:`~.stability.explicit_step`, its arguments)."""
        self._need_tissue("explicit_step")
        return explicit_step(self, frame_dt, dt=dt, substeps=substeps, mass_scaling=mass_scaling)

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    # ------------------------------------------------------------------------------ more heads
    _HEAD_FIELDS = ("vertices", "tets", "layer", "fixed", "held", "mass", "vertex_area", "vertex_volume",
                    "hold_stiffness", "edges", "tet_edge_index", "tet_face_index", "edge_rest_lengths", "edge_class",
                    "edge_k0", "edge_damping_coef", "faces", "face_rest_areas", "face_k", "face_damping_coef",
                    "tet_rest_volumes", "tet_k", "tet_damping_coef", "tet_rest_inverse", "tet_shear_k",
                    "tet_shear_damping")

    def _has_stages(self) -> bool:
        return bool(self.muscle_rig is not None or len(self.support_nodes) or self.jaw is not None
                    or self.contact_geometry is not None or len(self.carry_nodes))

    def add_builder(self, other: ModelBuilder, xform=None) -> None:
        """Append the heads of ``other`` (after Newton's ``ModelBuilder.add_builder``): its nodes,
        elements and materials, every index shifted by this builder's counts, its rest shape placed
        by ``xform``; the per-head ranges of the finalized :class:`Model` (``head_node_start``, ...)
        say which rows are whose. Rest lengths, areas, volumes and rest inverses are measured again
        on the placed (float32) positions, so each head's rest state stays an equilibrium.

        What is appended today is the tissue (tet mesh, material, fixed and held nodes): one Model of N
        tissues is stepped by one solver. Heads with muscles, supports, a jaw or contact are refused:
        their stages take one jaw per Model; step such heads together with :class:`~facewarp.FaceBatch`
        (one Model per head, one graph per frame).

        Args:
            other: A builder with at least one head (``add_tissue``, or an earlier ``add_builder``).
            xform: Where the appended heads go: ``(R, t)`` (a rotation (3, 3) and a translation (3,)
                [m]) or a 4 x 4 rigid transform; ``x -> R x + t``. Default: as they are.

        Raises:
            InputError: ``other`` not a builder or without a head, heads with stages, another
                damping rate, or a bad ``xform``.
        """
        self.replicate(other, 1, xforms=None if xform is None else [xform])

    def replicate(self, builder: ModelBuilder, count: int, xforms=None) -> None:
        """Append ``count`` copies of ``builder``'s heads (:meth:`add_builder`), copy ``i`` placed by
        ``xforms[i]`` (a list of ``(R, t)`` or 4 x 4 transforms, or an array (count, 4, 4); default all
        in place). One concatenation for all copies.

        Raises:
            InputError: as :meth:`add_builder`, or a bad ``count`` / ``xforms``.
        """
        if not isinstance(builder, ModelBuilder):
            raise InputError(f"builder: expected a ModelBuilder, got {type(builder).__name__}")
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or not 1 <= count <= 1_000_000:
            raise InputError(f"count: expected a whole number 1..1000000, got {count!r}")
        if not builder.head_count:
            raise InputError("builder: it has no head yet (add_tissue or add_face first)")
        if builder._has_stages() or self._has_stages():
            raise InputError("add_builder: heads with muscles, supports, a jaw or contact cannot share one Model yet "
                             "(their stages take one jaw per Model); step them together with facewarp.FaceBatch")
        if self.head_count and not np.isclose(self.damping_rate, builder.damping_rate, rtol=1e-6):
            raise InputError(f"add_builder: damping rate {builder.damping_rate:g} 1/s differs from this model's "
                             f"{self.damping_rate:g} 1/s (one rate per Model)")
        R, t = _xforms(xforms, int(count))
        pieces = [(self, None)] if self.head_count else []
        for c in range(int(count)):  # each copy placed, its rest measures taken again on the placed positions
            V = builder.vertices @ R[c].T + t[c]
            pieces.append((builder, {"vertices": V, **rest_geometry(V, builder.tets, builder.edges, builder.faces)}))
        self._concatenate(pieces)
        if not self.head_count:
            self.material, self.damping_rate = builder.material, builder.damping_rate
            self.stiffness_damping, self.edge_damping = builder.stiffness_damping, builder.edge_damping
        self.head_count += int(count) * builder.head_count

    _INDEX_SHIFT = {"tets": "node", "edges": "node", "faces": "node", "tet_edge_index": "edge", "tet_face_index": "face"}

    def _concatenate(self, pieces: list) -> None:
        """The one concatenation of heads (:meth:`add_face` again, :meth:`add_faces`, :meth:`add_builder`,
        :meth:`replicate`): every tissue array (``_HEAD_FIELDS``) of the ``pieces`` in order, node and
        element indices shifted by the counts before them, and the per-head ranges (a piece of several
        heads brings its own).

        Args:
            pieces: ``[(builder, overrides or None)]``: a builder with heads, and arrays that replace
                its own (a placed copy's ``vertices`` and rest measures).
        """
        parts = {f: [] for f in self._HEAD_FIELDS}
        ranges = {k: [0] for k in ("node", "edge", "face", "tet")}
        for src, geo in pieces:
            off = {k: int(ranges[k][-1]) for k in ranges}
            for name in self._HEAD_FIELDS:
                a = geo[name] if geo is not None and name in geo else getattr(src, name)
                parts[name].append(a + off[self._INDEX_SHIFT[name]] if name in self._INDEX_SHIFT else a)
            own = src._head_ranges()
            for k in ranges:
                ranges[k] += [off[k] + int(v) for v in own[k][1:]]
        for name in self._HEAD_FIELDS:
            setattr(self, name, np.concatenate(parts[name], axis=0))
        self._ranges = {k: np.asarray(v, np.int64) for k, v in ranges.items()}

    def _head_ranges(self) -> dict:
        """Each head's first node, edge, face and tet and the ends (host, int64)."""
        r = getattr(self, "_ranges", None)
        if r is not None and int(r["node"][-1]) == self.vertex_count:
            return r
        return {"node": np.array([0, self.vertex_count]), "edge": np.array([0, len(self.edges)]),
                "face": np.array([0, len(self.faces)]), "tet": np.array([0, len(self.tets)])}

    def finalize(self, device=None) -> Model:
        """Copy the model onto ``device`` (a Warp device or its name; None: Warp's default): every
        device array of what is simulated, made here in one place: the tissue, and the stages'
        (:class:`MuscleArrays`, :class:`SupportArrays`, :class:`JawNodeArrays`,
        :class:`ContactArrays`, with the scratch their kernels rewrite each step). A stage's
        ``from_model`` keeps references to them; the solver reads the Model's fields.

        Returns:
            A read-only :class:`Model` of Warp arrays (float32 / int32) on that device.

        Raises:
            InputError: a muscle rig that fails its checks (:meth:`~facewarp.physics.MuscleRig.validate`).
        """
        wp = warp()
        rig = self.muscle_rig
        if rig is not None:  # the rig checked and its derived arrays, at once (Eq. 6.4.1, Fig. 6.4)
            rig.validate()
            derived = (rig.weighted_stiffness(), rig.attachment_jaw(), rig.attachment_across(), rig.curve_normals())
        dev = wp.get_device(device)

        def f32(a, dtype=float):
            return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=dtype, device=dev)

        def i32(a, dtype=wp.int32):
            return wp.array(np.ascontiguousarray(a, dtype=np.int32), dtype=dtype, device=dev)

        inv_mass = np.where(self.fixed, 0.0, 1.0 / self.mass)
        rest = f32(self.vertices, wp.vec3)
        # force slots: edge e -> 2e (i), 2e+1 (j); face f -> 2E + 3f + (0, 1, 2); tet t -> 2E + 3F + 4t + (0..3)
        slot_node = np.concatenate([self.edges.ravel(), self.faces.ravel(), self.tets.ravel()])
        _, start, order = group_indices(slot_node, np.arange(len(self.vertices)))
        return Model(
            device=dev,
            vertex_count=len(self.vertices),
            edge_count=len(self.edges),
            face_count=len(self.faces),
            tet_count=len(self.tets),
            muscle_count=self.muscle_count,
            rest_positions=rest,
            vertex_mass=f32(self.mass),
            vertex_inv_mass=f32(inv_mass),
            vertex_layer=i32(self.layer),
            vertex_fixed=i32(self.fixed),
            vertex_hold_stiffness=f32(self.hold_stiffness),
            edge_indices=i32(self.edges, wp.vec2i),
            edge_rest_length=f32(self.edge_rest_lengths),
            edge_k0=f32(self.edge_k0),
            edge_damping=f32(self.edge_damping_coef),
            edge_class=i32(self.edge_class),
            face_indices=i32(self.faces, wp.vec3i),
            face_rest_area=f32(self.face_rest_areas),
            face_k=f32(self.face_k),
            face_damping=f32(self.face_damping_coef),
            tet_indices=i32(self.tets, wp.vec4i),
            tet_rest_volume=f32(self.tet_rest_volumes),
            tet_k=f32(self.tet_k),
            tet_damping=f32(self.tet_damping_coef),
            tet_rest_inverse=f32(self.tet_rest_inverse, wp.mat33),
            tet_shear_k=f32(self.tet_shear_k),
            tet_shear_damping=f32(self.tet_shear_damping),
            slot_count=len(slot_node),
            node_slot_start=i32(start),
            node_slots=i32(order),
            damping_rate=self.damping_rate,
            material=self.material.name,
            **self._finalize_stages(wp, dev, f32, rest, derived if rig is not None else None),
        )

    def _finalize_stages(self, wp, dev, f32, rest, derived) -> dict:
        """The Model's stage fields, their device arrays and per-head ranges: every head's rows in one
        set of arrays, each row with its head (the kernels take that head's jaw and angles). The heads
        are the faces of :meth:`add_face` (one or many; a single head is one face of its own), or
        tissue-only heads (:meth:`replicate`) with no stage rows."""
        faces = getattr(self, "_faces", None)
        if faces is None or len(faces) != self.head_count:
            faces = [self] if self.head_count == 1 else None  # None: tissue-only heads
        H = self.head_count
        hr = self._head_ranges()

        def count(fn):
            return [fn(f) for f in faces] if faces is not None else [0] * H

        def starts(counts):
            return np.r_[0, np.cumsum(counts)].astype(np.int64)

        def head_of(counts):
            return np.repeat(np.arange(H), counts)

        ranges = {f"head_{k}_start": np.asarray(hr[k], np.int64) for k in ("node", "edge", "face", "tet")}
        ranges["head_muscle_start"] = starts(count(lambda f: f.muscle_count))
        ranges["head_ctrl_start"] = starts(count(lambda f: 0 if f.muscle_rig is None else len(f.muscle_rig.ctrl_rest)))
        ranges["head_attachment_start"] = starts(count(lambda f: 0 if f.muscle_rig is None else len(f.muscle_rig.att_node)))
        support_counts, carry_counts = count(lambda f: len(f.support_nodes)), count(lambda f: len(f.carry_nodes))
        ranges["head_support_start"] = starts(support_counts)
        ranges["head_carry_start"] = starts(carry_counts)
        jaws = [f.jaw for f in faces] if faces is not None else [None] * H
        rig = self.muscle_rig
        P = 0 if rig is None else len(rig.ctrl_rest)
        mh = getattr(self, "_muscle_heads", None) if H > 1 else None  # N faces: each row's head (_merge_rigs)
        g = self.contact_geometry
        geos = g if isinstance(g, list) else [g]
        return dict(
            head_count=H,
            **ranges,
            muscles=None if rig is None else ModelMuscles(
                rig, self.muscle_node_amount, MuscleArrays(wp, rig, jaws, dev, self.muscle_node_amount, *derived,
                                                           **(mh or {}))),
            muscle_ctrl_rest=(f32(rig.ctrl_rest, wp.vec3) if P else wp.zeros(0, dtype=wp.vec3, device=dev)),
            supports=ModelSupports(self.support_nodes, self.support_normal, self.support_amount,
                                   self.support_stiffness,
                                   SupportArrays(wp, jaws, self.support_nodes, self.support_normal,
                                                 self.support_amount, self.support_stiffness, rest, dev,
                                                 head=head_of(support_counts))),
            jaw=None if all(j is None for j in jaws) else ModelJaw(
                jaws[0], self.jaw_nodes, self.jaw_amount, self.carry_nodes, self.carry_amount,
                JawNodeArrays(wp, jaws, self.jaw_nodes, self.jaw_amount, dev, rest,
                              head=head_of(count(lambda f: len(f.jaw_nodes)))),
                JawNodeArrays(wp, jaws, self.carry_nodes, self.carry_amount, dev, head=head_of(carry_counts))),
            contact=None if g is None else ModelContact(
                geos[0], self.contact_stiffness, self.glide_stiffness, self.vertices, jaws[0],
                ContactArrays(wp, [f.vertices for f in faces], [f.contact_stiffness for f in faces], dev,
                              geometry=list(geos), glide_stiffness=[f.glide_stiffness for f in faces], jaw=jaws,
                              node_offsets=hr["node"][:-1])),
        )
