"""Builder -> Model / State / Control: what is simulated, built once (thesis Sec. 6.4, Table 6.3).

:class:`ModelBuilder` collects a head's parts, computes every material-dependent number and
finalizes one :class:`Model`: :meth:`~ModelBuilder.add_tissue` (the tet mesh, below),
:meth:`~ModelBuilder.add_muscles` (Eq. 6.4.1), :meth:`~ModelBuilder.add_supports`,
:meth:`~ModelBuilder.add_jaw` (Eq. 6.4.9) and :meth:`~ModelBuilder.add_contacts`, or all of them
from a face rig with :meth:`~ModelBuilder.add_face`. The Model carries per-head ranges
(``head_*_start``), so more heads are an append. Every array a step changes is in :class:`State`
(positions, previous positions, the muscle control points, the jaw carry); the inputs are in
:class:`Control`.

The tissue: a generic tetrahedral mesh (numpy), validated, gives the
elements of the deformation model: unique tet edges (distance energy, Eq. 6.4.4 with the
nonlinear stiffness of Eq. 6.4.6), unique tet faces (area energy, Eq. 6.4.7) and the tets
themselves (volume energy, Eq. 6.4.8), with per-element stiffness, damping and per-node masses
from a material profile (:mod:`.materials`: ``thesis``, Table 6.3 as it stands, or
``physical``, the same energies from moduli in Pa and a density). :meth:`ModelBuilder.finalize`
copies everything into a read-only :class:`Model` of Warp arrays on one device;
:meth:`Model.state` and :meth:`Model.control` make the mutable buffers the solvers step
(:class:`~facewarp._src.physics.solvers.implicit.SolverImplicit`,
:class:`~facewarp._src.physics.solvers.verlet.SolverVerlet`).

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

import copy
from dataclasses import dataclass

import numpy as np

from ..core.warp import get_warp
from ..core.errors import InputError
from ..geometry.tets import TET_EDGES, TET_FACES
from .materials import (CONTACT_MODULUS, CONTACT_MUSCLE_RATIO, EDGE_DAMPING, MaterialPhysical, MaterialThesis,
                        material_profile)

__all__ = [
    "EDGE_CROSS",
    "EDGE_INNER",
    "EDGE_OUTER",
    "TABLE_6_3",
    "DT_STABLE_1CM",
    "sheet_areas",
    "thesis_substep",
    "Control",
    "Model",
    "ModelBuilder",
    "ModelContact",
    "ModelJaw",
    "ModelMuscles",
    "ModelSupports",
    "ContactArrays",
    "ContactSurface",
    "JawNodeArrays",
    "MuscleArrays",
    "SupportArrays",
    "Springs",
    "State",
    "group_indices",
    "node_jaw_amounts",
]

EDGE_OUTER = 0
"""Edge class of an edge whose two nodes are both on the outer layer (``layer == 0``)."""
EDGE_INNER = 1
"""Edge class of an edge whose two nodes are both on the inner layer (``layer == 1``)."""
EDGE_CROSS = 2
"""Edge class of an edge joining the outer and the inner layer."""

TABLE_6_3 = {
    "mass": 0.5,  # kg per node
    "damping": 0.002,  # per-substep velocity loss of the Verlet reference (dimensionless)
    "k0_outer": 15.0,  # J
    "k0_inner": 10.0,  # J
    "k0_cross": 5.0,  # J
    "k_area": 7.5,  # J
    "k_volume": 7.5,  # J
}
"""Table 6.3 of the thesis in SI as it stands (the ``thesis`` material profile)."""

_TET_EDGES, _TET_FACES = TET_EDGES, TET_FACES




_WARP = []


def _warp():
    """Warp (:func:`~facewarp._src.core.warp.get_warp`), asked once per process and kept: the
    builder and the Model make their arrays without calling back out of this module."""
    if not _WARP:
        _WARP.append(get_warp())
    return _WARP[0]


def _vertex_array(a, n: int, name: str, dtype) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim == 0:
        a = np.full(n, a)
    if a.shape != (n,):
        raise InputError(f"{name} must have shape ({n},) (one value per vertex), got {a.shape}")
    return a.astype(dtype)


def group_indices(keys, groups=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR grouping for the deterministic gathers: the entries of each group in ascending order.

    Args:
        keys: Group of each entry, shape (k,), int.
        groups: The groups to list, ascending, shape (g,) (default: the distinct keys); a group
            with no entry gets an empty range.

    Returns:
        ``(groups, start, order)``: group ``j`` owns entries ``order[start[j]:start[j + 1]]``;
        shapes (g,), (g + 1,), (k,), int64.
    """
    keys = np.asarray(keys, dtype=np.int64)
    groups = np.unique(keys) if groups is None else np.asarray(groups, dtype=np.int64)
    order = np.argsort(keys, kind="stable")
    start = np.searchsorted(keys[order], groups, side="left")
    return groups, np.r_[start, len(keys)], order


def thesis_substep(d0, mass, k0_max: float, *, safety: float = 0.5):
    """The Verlet reference substep [s] of the thesis profile's edge rule:
    ``safety * DT_STABLE_1CM * (d0 / 1 cm) * sqrt(mass / 0.5 kg) * sqrt(15 J / k0_max)``.

    ``DT_STABLE_1CM`` (0.6 ms) is the largest step found stable for a 1 cm tet with the Table 6.3
    defaults (see :mod:`facewarp._src.physics.solvers.verlet`). Scalars or arrays.
    """
    k = max(float(k0_max), 1e-30)
    return safety * DT_STABLE_1CM * (np.asarray(d0) / 0.01) * np.sqrt(np.asarray(mass) / 0.5) * np.sqrt(15.0 / k)


DT_STABLE_1CM = 0.6e-3
"""Largest Verlet step [s] found stable for a 1 cm tet with the Table 6.3 defaults: one regular
tet (all-outer or mixed layers) and a 3 x 3 x 1 slab of 1 cm Kuhn cubes, from random starts
with strains up to ~10 %, run for 1-2 s (all 20 / 5 starts bounded; at 0.8 ms a quarter to
most of the 10 %-strain starts of the mixed-layer tet invert). The linear limit 2 / omega_max
of the regular tet at rest is 1.04 ms (omega_max^2 = 3.7e6 s^-2); the stiffening of
Eq. 6.4.6 at large strain lowers it."""


def _opt(value, default):
    return default if value is None else value


def sheet_areas(V, T, layer) -> np.ndarray:
    """Each node's share of the boundary area of its own sheet [m^2], shape (n,), float64.

    The boundary faces of the tet mesh whose three nodes lie in one layer (the skin surface for
    layer 0, the inner sheet for layer 1) give a third of their area to each node; nodes on no
    such face (a side wall) get 0.
    """
    V = np.asarray(V, dtype=np.float64)
    T = np.asarray(T)
    n = len(V)
    F = np.sort(T[:, _TET_FACES].reshape(-1, 3), axis=1)
    uniq, count = np.unique(F, axis=0, return_counts=True)
    B = uniq[count == 1]
    lay = np.asarray(layer)[B]
    B = B[(lay == lay[:, :1]).all(axis=1)]
    a = 0.5 * np.linalg.norm(np.cross(V[B[:, 1]] - V[B[:, 0]], V[B[:, 2]] - V[B[:, 0]]), axis=1)
    return np.bincount(B.ravel(), weights=np.repeat(a / 3.0, 3), minlength=n)


def _merge_rigs(faces: list, node_offsets) -> tuple:
    """The muscle rigs of several heads as one (:class:`~facewarp.MuscleRig`): rows concatenated,
    indices shifted by the heads' counts (control points, muscles and activations, curves,
    segments, anchors, nodes). Returns ``(rig or None, {"ctrl_head" (P,), "att_head" (K,),
    "att_jaw_shift" (K,)})`` (each control point's and attachment's head; the attachments' jaw
    shift, node amount less the muscle's, as one head's :class:`MuscleArrays` computes it)."""
    from .muscle_rig import MuscleRig

    rigs = [(h, f.muscle_rig, f.muscle_node_amount) for h, f in enumerate(faces) if f.muscle_rig is not None]
    if not rigs:
        return None, {}
    cols = {k: [] for k in ("names", "activation_index", "contraction", "center", "center_jaw", "ctrl_rest",
                            "ctrl_muscle", "ctrl_pivot", "ctrl_jaw", "curve_ctrl", "curve_weight", "seg_curve", "seg_t",
                            "seg_rest_radii", "anchor_ctrl", "anchor_group", "anchor_passive", "att_node", "att_seg",
                            "att_uv", "att_rest_length", "att_stiffness", "att_weight", "saturation", "center_normal",
                            "glide", "glide_center")}
    ctrl_head, att_head, shift = [], [], []
    P0 = M0 = A0 = C0 = S0 = G0 = 0
    for h, r, amount in rigs:
        P, M, C, S, K = len(r.ctrl_rest), len(r.names), len(r.curve_ctrl), len(r.seg_curve), len(r.att_node)
        cols["names"] += list(r.names)
        cols["activation_index"].append(np.asarray(r.activation_index, np.int64) + A0)
        for k in ("contraction", "center", "center_jaw", "ctrl_rest", "ctrl_jaw", "curve_weight", "seg_t",
                  "seg_rest_radii", "anchor_passive", "att_uv", "att_rest_length", "att_stiffness", "saturation",
                  "center_normal", "glide", "glide_center"):
            cols[k].append(np.asarray(getattr(r, k)))
        cols["att_weight"].append(np.asarray(r.att_weight, np.float64) if len(r.att_weight) else np.ones(K))
        cols["ctrl_muscle"].append(np.asarray(r.ctrl_muscle, np.int64) + M0)
        piv = np.asarray(r.ctrl_pivot, np.int64)
        cols["ctrl_pivot"].append(np.where(piv >= 0, piv + P0, piv))
        cols["curve_ctrl"].append(np.asarray(r.curve_ctrl, np.int64).reshape(-1, 3) + P0)
        cols["seg_curve"].append(np.asarray(r.seg_curve, np.int64) + C0)
        cols["anchor_ctrl"].append(np.asarray(r.anchor_ctrl, np.int64) + P0)
        ag = np.asarray(r.anchor_group, np.int64)
        cols["anchor_group"].append(ag + G0)
        cols["att_node"].append(np.asarray(r.att_node, np.int64) + int(node_offsets[h]))
        cols["att_seg"].append(np.asarray(r.att_seg, np.int64) + S0)
        ctrl_head.append(np.full(P, h))
        att_head.append(np.full(K, h))
        shift.append(np.asarray(amount, np.float64)[r.att_node] - r.attachment_jaw() if amount is not None and K
                     else np.zeros(K))
        P0, M0, C0, S0 = P0 + P, M0 + M, C0 + C, S0 + S
        A0 += M  # one activation per muscle (ModelBuilder.add_muscles' muscle_count)
        G0 += int(ag.max()) + 1 if len(ag) else 0
    cat = {k: (v if k == "names" else np.concatenate(v, axis=0)) for k, v in cols.items()}
    rig = MuscleRig(**cat)
    return rig, {"ctrl_head": np.concatenate(ctrl_head), "att_head": np.concatenate(att_head),
                 "att_jaw_shift": np.concatenate(shift)}


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


def node_jaw_amounts(fr) -> np.ndarray:
    """Eq. 6.4.9 jaw amount of every tet node of a face rig (:class:`~facewarp.FaceRig`), shape (p,), float64: that of the head vertex the
    node lies on or under (sheets are stored one after another, node ``l * q + i`` below outer
    node ``i``). Rigs without ``vertex_jaw`` give the held and supported nodes' amounts only."""
    n = len(fr.nodes)
    out = np.zeros(n)
    q = int((fr.layer == 0).sum())
    if fr.vertex_jaw is not None and q and n % q == 0 and (fr.surface_vertex[:q] >= 0).all():
        out = np.asarray(fr.vertex_jaw, np.float64)[fr.surface_vertex[np.arange(n) % q]]
    else:
        out[fr.jaw_nodes] = fr.jaw_amount
        out[fr.support_nodes] = fr.support_amount
    return out


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
        V = np.asarray(vertices, dtype=np.float64)
        if V.ndim != 2 or V.shape[1] != 3:
            raise InputError(f"vertices must have shape (n, 3), got {V.shape}")
        if not np.all(np.isfinite(V)):
            bad = int(np.nonzero(~np.all(np.isfinite(V), axis=1))[0][0])
            raise InputError(f"vertices must be finite, vertex {bad} is {V[bad].tolist()}")
        T = np.asarray(tets)
        if T.ndim != 2 or T.shape[1] != 4:
            raise InputError(f"tets must have shape (k, 4), got {T.shape}")
        if len(T) == 0:
            raise InputError("tets is empty: the model needs at least one tetrahedron")
        if not np.issubdtype(T.dtype, np.integer):
            raise InputError(f"tets must be an integer array, got dtype {T.dtype}")
        T = T.astype(np.int64)
        n = len(V)
        if T.min() < 0 or T.max() >= n:
            bad = int(np.nonzero((T < 0).any(axis=1) | (T >= n).any(axis=1))[0][0])
            raise InputError(f"tet {bad} indexes vertices {T[bad].tolist()}, but there are {n} vertices")
        srt = np.sort(T, axis=1)
        rep = (srt[:, 1:] == srt[:, :-1]).any(axis=1)
        if rep.any():
            bad = int(np.nonzero(rep)[0][0])
            raise InputError(f"tet {bad} repeats a vertex: {T[bad].tolist()}")

        # Rest lengths, areas and volumes are measured on the float32-rounded positions the
        # kernels see, so that the rest state is an equilibrium up to float32 arithmetic only
        # (and a tet valid here is not inverted in the kernels' eyes).
        V32 = V.astype(np.float32).astype(np.float64)
        x0, x1, x2, x3 = (V32[T[:, c]] for c in range(4))  # geometry.tets.signed_tet_volumes, the builder's own
        vol = np.einsum("ij,ij->i", x1 - x0, np.cross(x2 - x0, x3 - x0)) / 6.0
        scale = np.linalg.norm(V[T[:, 1:]] - V[T[:, :1]], axis=2).max(axis=1)
        tiny = 1e-6 * scale**3  # a regular tet has 0.118 scale^3
        inv = vol <= tiny
        if inv.any():
            bad = int(np.nonzero(inv)[0][0])
            what = "inverted" if vol[bad] < -tiny[bad] else "degenerate (zero volume)"
            raise InputError(
                f"tet {bad} {T[bad].tolist()} is {what}: signed volume {vol[bad]:.3g} m^3; "
                "expected (1/6) (x1-x0).((x2-x0)x(x3-x0)) > 0 (swap two indices to flip it)"
            )

        layer = np.zeros(n, np.int64) if layer is None else _vertex_array(layer, n, "layer", np.int64)
        if not np.isin(layer, (0, 1)).all():
            raise InputError(f"layer must be 0 (outer) or 1 (inner), got values {np.unique(layer).tolist()}")
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

        # unique edges (i < j) with their rest length D0 and class; each tet's edges and faces
        # map to the unique ones (inverse) for the volume shares
        E_all = np.sort(T[:, _TET_EDGES].reshape(-1, 2), axis=1)
        E, e_inv = np.unique(E_all, axis=0, return_inverse=True)
        D0 = np.linalg.norm(V32[E[:, 1]] - V32[E[:, 0]], axis=1)
        la, lb = layer[E[:, 0]], layer[E[:, 1]]
        edge_class = np.where(la != lb, EDGE_CROSS, np.where(la == 0, EDGE_OUTER, EDGE_INNER))
        # unique faces (sorted vertex triples: the area energy ignores the winding)
        F_all = np.sort(T[:, _TET_FACES].reshape(-1, 3), axis=1)
        Fc, f_inv = np.unique(F_all, axis=0, return_inverse=True)
        A0 = 0.5 * np.linalg.norm(np.cross(V32[Fc[:, 1]] - V32[Fc[:, 0]], V32[Fc[:, 2]] - V32[Fc[:, 0]]), axis=1)
        # volume shares: a node a quarter of each tet, an edge a sixth, a face a quarter
        v_node = np.bincount(T.ravel(), weights=np.repeat(vol / 4.0, 4), minlength=n)
        v_edge = np.bincount(e_inv.ravel(), weights=np.repeat(vol / 6.0, 6), minlength=len(E))
        v_face = np.bincount(f_inv.ravel(), weights=np.repeat(vol / 4.0, 4), minlength=len(Fc))
        area = sheet_areas(V32, T, layer)

        if physical:
            mod = np.asarray(mat.distance_modulus, dtype=np.float64)
            k0 = mod[edge_class] * v_edge
            face_k = mat.area_modulus * v_face
            tet_k = mat.volume_modulus * vol
            mass_default = mat.density * v_node
            beta = mat.stiffness_damping
            alpha = mat.damping_rate
            c_edge = 0.0
        else:
            k0 = np.array([mat.k0_outer, mat.k0_inner, mat.k0_cross], dtype=np.float64)[edge_class]
            face_k = np.full(len(Fc), mat.k_area)
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
            face_k = np.full(len(Fc), float(k_area))
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
        self.vertex_volume = v_node
        self.damping_rate = float(alpha)
        self.stiffness_damping = float(beta)
        self.edge_damping = float(c_edge)
        self.edges = E
        self.tet_edge_index = e_inv.reshape(len(T), 6)  # each tet's edges (_TET_EDGES order) in self.edges
        self.tet_face_index = f_inv.reshape(len(T), 4)  # each tet's faces (_TET_FACES order) in self.faces
        self.edge_rest_lengths = D0
        self.edge_class = edge_class
        self.edge_k0 = k0
        self.edge_damping_coef = beta * k0 + c_edge * D0**2
        self.faces = Fc
        self.face_rest_areas = A0
        self.face_k = face_k
        self.face_damping_coef = beta * face_k
        self.tet_rest_volumes = vol
        self.tet_k = tet_k
        self.tet_damping_coef = beta * tet_k
        Dm = np.stack([V32[T[:, c]] - V32[T[:, 0]] for c in (1, 2, 3)], axis=2)  # columns: rest edge vectors
        self.tet_rest_inverse = np.linalg.inv(Dm)
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
        checks (:meth:`~facewarp.MuscleRig.validate`) run in :meth:`finalize`, with its derived arrays.
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
            jaw: Anything with ``pivot``, ``u_axis``, ``v_axis`` (:class:`~facewarp.JawKinematic`).
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
            from .solvers.verlet import MASS_SCALING_QUANTILE, scale_masses

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
        n_off = np.r_[0, np.cumsum([f.vertex_count for f in faces])].astype(np.int64)
        parts = {f: [] for f in self._HEAD_FIELDS}
        shift = {"tets": "node", "edges": "node", "faces": "node", "tet_edge_index": "edge", "tet_face_index": "face"}
        ranges = {k: [0] for k in ("node", "edge", "face", "tet")}
        for f in faces:
            off = {k: int(ranges[k][-1]) for k in ranges}
            for name in self._HEAD_FIELDS:
                a = getattr(f, name)
                parts[name].append(a + off[shift[name]] if name in shift else a)
            for k, count in (("node", f.vertex_count), ("edge", len(f.edges)), ("face", len(f.faces)),
                             ("tet", len(f.tets))):
                ranges[k].append(off[k] + count)
        for name in self._HEAD_FIELDS:
            setattr(self, name, np.concatenate(parts[name], axis=0))
        for name in self._FACE_FIELDS:
            rows = []
            for h, f in enumerate(faces):
                a = getattr(f, name)
                if a is None:
                    a = np.zeros(f.vertex_count)
                rows.append(a + n_off[h] if name in self._NODE_INDEX else a)
            setattr(self, name, np.concatenate(rows, axis=0))
        self._ranges = {k: np.asarray(v, np.int64) for k, v in ranges.items()}
        self._faces = faces
        self.head_count = len(faces)
        self.jaw = [f.jaw for f in faces]
        self.contact_geometry = None if faces[0].contact_geometry is None else [f.contact_geometry for f in faces]
        self._support_k = self.support_stiffness
        self.muscle_count = int(sum(f.muscle_count for f in faces))
        self.muscle_rig, self._muscle_heads = _merge_rigs(faces, n_off)
        self.muscle_node_amount = None

    def node_spring_stiffness(self) -> np.ndarray:
        """The springs the added stages put on each node [N/m], shape (vertex_count,), float64:
        supports, muscles and contact candidates (the explicit step's stability bound)."""
        extra = np.zeros(self.vertex_count)
        np.add.at(extra, self.support_nodes, np.broadcast_to(self._support_k, (len(self.support_nodes),)))
        if self.muscle_rig is not None:
            np.add.at(extra, self.muscle_rig.att_node, self.muscle_rig.att_stiffness)
        if self.contact_geometry is not None:  # every contact spring a node can carry at once (the lids' too)
            from .solvers.verlet import contact_stiffness_bound

            if isinstance(self.contact_geometry, list):  # N faces: each head's own
                extra += np.concatenate([contact_stiffness_bound(f.contact_geometry, f.contact_stiffness,
                                                                 f.glide_stiffness) for f in self._faces])
            else:
                extra += contact_stiffness_bound(self.contact_geometry, self.contact_stiffness, self.glide_stiffness)
        return extra

    def explicit_step(self, frame_dt: float, *, dt: float | None = None, substeps: int | None = None,
                      mass_scaling: bool = True) -> tuple[int, float, float]:
        """The Verlet reference's substep: selective mass scaling (the 2 % of nodes with the
        smallest own limit get the mass that lifts them to it; ``builder.mass`` changes), from the
        tissue and every spring a stage may switch on (:meth:`node_spring_stiffness`). The thesis
        profile's damping rate is set by :meth:`add_face` at the reference substep of the tissue,
        whatever the solver's step.

        Args:
            frame_dt: Frame length [s].
            dt: Wanted substep [s] (default the stable one); substeps: per frame (overrides dt).
            mass_scaling: Scale the masses (else the smallest node limit is the step).

        Returns:
            ``(substeps, dt [s], added mass fraction)``.

        Raises:
            InputError: a substep above twice the stable one.
        """
        from .solvers.verlet import MASS_SCALING_QUANTILE, scale_masses

        self._need_tissue("explicit_step")
        dt_safe, added = scale_masses(self, quantile=MASS_SCALING_QUANTILE if mass_scaling else 0.0,
                                      extra_stiffness=self.node_spring_stiffness())
        if substeps is None:
            substeps = int(np.ceil(frame_dt / (dt or dt_safe)))
        step = frame_dt / int(substeps)
        if step > 2.0 * dt_safe:
            raise InputError(f"substeps {substeps}: dt {step:.2e} s is above twice the stable step "
                             f"{dt_safe:.2e} s; use at least {int(np.ceil(frame_dt / (2 * dt_safe)))} substeps")
        return int(substeps), step, added


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
        parts = [[getattr(self, f)] for f in self._HEAD_FIELDS] if self.head_count else [[] for _ in self._HEAD_FIELDS]
        ranges = self._head_ranges() if self.head_count else {k: [0] for k in ("node", "edge", "face", "tet")}
        n0, e0, f0, t0 = (int(ranges[k][-1]) for k in ("node", "edge", "face", "tet"))
        nb, eb, fb, tb = builder.vertex_count, len(builder.edges), len(builder.faces), len(builder.tets)
        other = builder._head_ranges()
        T = builder.tets
        for c in range(int(count)):
            V = builder.vertices @ R[c].T + t[c]
            V32 = V.astype(np.float32).astype(np.float64)
            E, Fc = builder.edges, builder.faces
            x0, x1, x2, x3 = (V32[T[:, k]] for k in range(4))
            vol = np.einsum("ij,ij->i", x1 - x0, np.cross(x2 - x0, x3 - x0)) / 6.0
            Dm = np.stack([V32[T[:, k]] - V32[T[:, 0]] for k in (1, 2, 3)], axis=2)
            geo = {"vertices": V, "edge_rest_lengths": np.linalg.norm(V32[E[:, 1]] - V32[E[:, 0]], axis=1),
                   "face_rest_areas": 0.5 * np.linalg.norm(np.cross(V32[Fc[:, 1]] - V32[Fc[:, 0]],
                                                                    V32[Fc[:, 2]] - V32[Fc[:, 0]]), axis=1),
                   "tet_rest_volumes": vol, "tet_rest_inverse": np.linalg.inv(Dm)}
            shift = {"tets": n0, "edges": n0, "faces": n0, "tet_edge_index": e0, "tet_face_index": f0}
            for lst, f in zip(parts, self._HEAD_FIELDS):
                a = geo[f] if f in geo else getattr(builder, f)
                lst.append(a + shift[f] if f in shift else a)
            for k, off in (("node", n0), ("edge", e0), ("face", f0), ("tet", t0)):
                ranges[k] = list(ranges[k]) + [int(off) + int(v) for v in other[k][1:]]
            n0, e0, f0, t0 = n0 + nb, e0 + eb, f0 + fb, t0 + tb
        for lst, f in zip(parts, self._HEAD_FIELDS):
            setattr(self, f, np.concatenate(lst, axis=0))
        if not self.head_count:
            self.material, self.damping_rate = builder.material, builder.damping_rate
            self.stiffness_damping, self.edge_damping = builder.stiffness_damping, builder.edge_damping
        self.head_count += int(count) * builder.head_count
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
            InputError: a muscle rig that fails its checks (:meth:`~facewarp.MuscleRig.validate`).
        """
        wp = _warp()
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
        """The Model's stage fields, their device arrays and per-head ranges (one head; a batch
        appends rows)."""
        rig = self.muscle_rig
        P = 0 if rig is None else len(rig.ctrl_rest)
        K = 0 if rig is None else len(rig.att_node)
        ranges = {name: np.array([0, count], np.int64) for name, count in (
            ("head_node_start", self.vertex_count), ("head_edge_start", len(self.edges)),
            ("head_face_start", len(self.faces)), ("head_tet_start", len(self.tets)),
            ("head_muscle_start", self.muscle_count), ("head_ctrl_start", P), ("head_attachment_start", K),
            ("head_support_start", len(self.support_nodes)), ("head_carry_start", len(self.carry_nodes)))}
        if self.head_count > 1:  # add_builder / replicate: tissue heads, no stage rows
            hr = self._head_ranges()
            for k in ("node", "edge", "face", "tet"):
                ranges[f"head_{k}_start"] = np.asarray(hr[k], np.int64)
            for k in ("muscle", "ctrl", "attachment", "support", "carry"):
                ranges[f"head_{k}_start"] = np.zeros(self.head_count + 1, np.int64)
        faces = getattr(self, "_faces", None)
        if faces is not None and len(faces) == self.head_count:  # add_face N times: every head's stage rows
            return self._finalize_faces(wp, dev, f32, rest, derived, ranges)
        g = self.contact_geometry
        return dict(
            head_count=self.head_count,
            **ranges,
            muscles=None if rig is None else ModelMuscles(
                rig, self.muscle_node_amount, MuscleArrays(wp, rig, self.jaw, dev, self.muscle_node_amount, *derived)),
            muscle_ctrl_rest=(f32(rig.ctrl_rest, wp.vec3) if P else wp.zeros(0, dtype=wp.vec3, device=dev)),
            supports=ModelSupports(self.support_nodes, self.support_normal, self.support_amount,
                                   self.support_stiffness,
                                   SupportArrays(wp, self.jaw, self.support_nodes, self.support_normal,
                                                 self.support_amount, self.support_stiffness, rest, dev)),
            jaw=None if self.jaw is None else ModelJaw(
                self.jaw, self.jaw_nodes, self.jaw_amount, self.carry_nodes, self.carry_amount,
                JawNodeArrays(wp, self.jaw, self.jaw_nodes, self.jaw_amount, dev, rest),
                JawNodeArrays(wp, self.jaw, self.carry_nodes, self.carry_amount, dev)),
            contact=None if g is None else ModelContact(
                g, self.contact_stiffness, self.glide_stiffness, self.vertices, self.jaw,
                ContactArrays(wp, self.vertices, self.contact_stiffness, dev, geometry=g,
                              glide_stiffness=self.glide_stiffness, jaw=self.jaw)),
        )


    def _finalize_faces(self, wp, dev, f32, rest, derived, ranges) -> dict:
        """The stage fields of a Model of N faces (:meth:`add_face` N times): every head's rows in
        one set of arrays, each row with its head (the kernels take that head's jaw and angles)."""
        faces = self._faces
        H = len(faces)
        n_off = self._head_ranges()["node"]
        for k in ("node", "edge", "face", "tet"):
            ranges[f"head_{k}_start"] = np.asarray(self._head_ranges()[k], np.int64)

        def starts(counts):
            return np.r_[0, np.cumsum(counts)].astype(np.int64)

        rig = self.muscle_rig
        ranges["head_muscle_start"] = starts([f.muscle_count for f in faces])
        ranges["head_ctrl_start"] = starts([0 if f.muscle_rig is None else len(f.muscle_rig.ctrl_rest) for f in faces])
        ranges["head_attachment_start"] = starts([0 if f.muscle_rig is None else len(f.muscle_rig.att_node)
                                                  for f in faces])
        ranges["head_support_start"] = starts([len(f.support_nodes) for f in faces])
        ranges["head_carry_start"] = starts([len(f.carry_nodes) for f in faces])
        jaws = list(self.jaw)

        def head_of(counts):
            return np.repeat(np.arange(H), counts)

        support_head = head_of([len(f.support_nodes) for f in faces])
        jaw_head = head_of([len(f.jaw_nodes) for f in faces])
        carry_head = head_of([len(f.carry_nodes) for f in faces])
        P = 0 if rig is None else len(rig.ctrl_rest)
        mh = self._muscle_heads
        has_jaw = any(j is not None for j in jaws)
        g = self.contact_geometry
        return dict(
            head_count=H,
            **ranges,
            muscles=None if rig is None else ModelMuscles(
                rig, None, MuscleArrays(wp, rig, jaws, dev, None, *derived, ctrl_head=mh["ctrl_head"],
                                        att_head=mh["att_head"], att_jaw_shift=mh["att_jaw_shift"])),
            muscle_ctrl_rest=(f32(rig.ctrl_rest, wp.vec3) if P else wp.zeros(0, dtype=wp.vec3, device=dev)),
            supports=ModelSupports(self.support_nodes, self.support_normal, self.support_amount,
                                   self.support_stiffness,
                                   SupportArrays(wp, jaws, self.support_nodes, self.support_normal,
                                                 self.support_amount, self.support_stiffness, rest, dev,
                                                 head=support_head)),
            jaw=None if not has_jaw else ModelJaw(
                jaws[0], self.jaw_nodes, self.jaw_amount, self.carry_nodes, self.carry_amount,
                JawNodeArrays(wp, jaws, self.jaw_nodes, self.jaw_amount, dev, rest, head=jaw_head),
                JawNodeArrays(wp, jaws, self.carry_nodes, self.carry_amount, dev, head=carry_head)),
            contact=None if g is None else ModelContact(
                g[0], self.contact_stiffness, self.glide_stiffness, self.vertices, jaws[0],
                ContactArrays(wp, [f.vertices for f in faces], [f.contact_stiffness for f in faces], dev,
                              geometry=list(g), glide_stiffness=[f.glide_stiffness for f in faces], jaw=jaws,
                              node_offsets=n_off[:-1])),
        )


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
        wp = _warp()
        ctrl = self.muscle_ctrl_rest
        return State(
            positions=wp.clone(self.rest_positions),
            prev_positions=wp.clone(self.rest_positions),
            muscle_ctrl=wp.clone(ctrl) if ctrl is not None else wp.zeros(0, dtype=wp.vec3, device=self.device),
            jaw_carry=wp.zeros(2 * self.head_count, dtype=float, device=self.device),
        )

    def control(self) -> Control:
        """A new :class:`Control`: no activation, jaw closed, no external force, cranium at rest."""
        wp = _warp()
        return Control(
            activations=wp.zeros(self.muscle_count, dtype=float, device=self.device),
            jaw_angles=wp.zeros(2 * self.head_count, dtype=float, device=self.device),
            external_force=wp.zeros(self.vertex_count, dtype=wp.vec3, device=self.device),
            cranium_velocity=wp.zeros(2, dtype=wp.vec3, device=self.device),
        )


@dataclass(eq=False)
class State:
    """Everything a step changes: the mass points at two consecutive steps (the velocity is their
    difference) and what the stages carry from step to step.

    The stages write their fields in place in ``state_in`` at the step's start (the muscle
    geometry of the step's controls, the jaw carry) and the solver hands them on to
    ``state_out`` (:meth:`assign_stage_data`), so two States can be swapped step by step and a
    copy of the rest State is a reset. What a stage recomputes from State and Control before
    every use (springs, ellipsoids, contact points) is scratch, not state: allocated once with
    the stage arrays of :meth:`ModelBuilder.finalize` (e.g. :class:`MuscleArrays`).
    """

    positions: object
    """Positions x(t) [m], shape (vertex_count,), wp.vec3 (float32)."""
    prev_positions: object
    """Positions x(t - dt) [m], shape (vertex_count,), wp.vec3 (float32)."""
    muscle_ctrl: object = None
    """Muscle control points after the last step's controls [m] (Eq. 6.4.1's Bezier curves,
    contracted and turned with the jaw), shape (P,), wp.vec3 (float32); None without muscles."""
    jaw_carry: object = None
    """Jaw angles [rad] the carried nodes' positions correspond to (the carry of Eq. 6.4.9 moves
    them by the change to the next step's angles), shape (2,), float32; None without a jaw."""

    def assign(self, other: State) -> None:
        """Copy ``other``'s buffers into this state's (no allocation)."""
        wp = get_warp()
        wp.copy(self.positions, other.positions)
        wp.copy(self.prev_positions, other.prev_positions)
        self.assign_stage_data(other)

    def assign_stage_data(self, other: State) -> None:
        """Copy ``other``'s stage fields (all but the positions) into this state's (no allocation)."""
        wp = get_warp()
        for a, b in ((self.muscle_ctrl, other.muscle_ctrl), (self.jaw_carry, other.jaw_carry)):
            if a is not None and b is not None and a.shape[0]:
                wp.copy(a, b)


@dataclass(frozen=True, eq=False)
class ModelMuscles:
    """The muscles of a :class:`Model` (host, NumPy, and their device arrays)."""

    rig: object
    """The :class:`~facewarp._src.physics.muscle_stage.MuscleRig` with its final ``att_stiffness`` [N/m]."""
    node_amount: np.ndarray | None
    """Jaw amount (Eq. 6.4.9) of every node, shape (vertex_count,), float64, or None."""
    arrays: MuscleArrays | None = None
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
    arrays: SupportArrays | None = None
    """The supports on the device (:class:`SupportArrays`, made by :meth:`ModelBuilder.finalize`)."""


@dataclass(frozen=True, eq=False)
class ModelJaw:
    """The kinematic jaw of a :class:`Model` (host, NumPy, and its device arrays)."""

    joint: object
    """Pivot [m] and unit axes of the jaw (``pivot``, ``u_axis``, ``v_axis``; :class:`~facewarp.JawKinematic`)."""
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
    arrays: ContactArrays | None = None
    """The contact on the device (:class:`ContactArrays`, made by :meth:`ModelBuilder.finalize`)."""


@dataclass(eq=False)
class Control:
    """What drives the face: muscle activations, jaw angles, a user force, the cranium's motion.

    The solver only reads these. Muscle and jaw stages (see
    :class:`facewarp._src.physics.solvers.verlet.SolverStage`) turn them into forces, springs
    and targets each step.
    """

    activations: object
    """Muscle activations in [0, 1], shape (muscle_count,), float32 (Table 6.4)."""
    jaw_angles: object
    """Jaw rotation [rad] about the condyle u-axis (0..60 deg) and the v-axis (+-5 deg),
    shape (2,), float32 (Sec. 6.4.3)."""
    external_force: object
    """A constant external force [N] on each node, added every step;
    shape (vertex_count,), wp.vec3 (float32). Zero by default."""
    cranium_velocity: object
    """Rigid velocity of the cranium: linear velocity [m/s] of the world origin and angular
    velocity [rad/s], shape (2,), wp.vec3 (float32). The mass-proportional damping acts on the
    node velocity relative to ``v + w x x``. Zero by default (the cranium at rest)."""


@dataclass(eq=False)
class Springs:
    """Point springs a solver stage adds to the tissue energy (muscles, supports), on the device.

    Two kinds, by whether :attr:`axis` is given:

    * distance springs ``E = 1/2 k (|p - x| - l0)^2`` (the muscle springs of Eq. 6.4.1 with the
      fibre cosine folded into ``k`` for the step);
    * axis springs ``E = 1/2 k ((x - p) . a)^2`` (a sliding support along the unit axis a).

    With :attr:`one_sided` the springs only push (contact, :mod:`facewarp._src.physics.contact`):

    * axis: ``E = 1/2 k min(0, (x - p) . a)^2``, a half-space ``(x - p) . a >= 0`` the node may
      not leave (p on the obstacle's surface, a its outward unit normal);
    * distance: ``E = 1/2 k min(0, |x - p| - l0)^2``, a ball of radius l0 about p the node may
      not enter (the eyeball).

    Both are C1 (the force vanishes continuously at the surface); their Hessian is ``k a a^T``
    (``k n n^T``, ``n = (x - p) / |x - p|``) where the spring is compressed and 0 elsewhere.

    A stage that has springs fills them in its ``prepare`` (once per implicit step); the arrays
    stay allocated, so a captured frame keeps reading the same buffers.
    """

    node: object
    """Tissue node of each spring, shape (k,), int32."""
    point: object
    """The spring's other end p [m], shape (k,), wp.vec3."""
    stiffness: object
    """Stiffness k [N/m], shape (k,), float32."""
    rest_length: object = None
    """Rest length l0 [m] of distance springs, shape (k,), float32 (None for axis springs)."""
    axis: object = None
    """Unit axis a of axis springs, shape (k,), wp.vec3 (None for distance springs)."""
    one_sided: bool = False
    """Contact springs that only push (see the class doc); a stage sets it once."""

    @property
    def count(self) -> int:
        return int(self.node.shape[0])


# ---------------------------------------------------------------------------------------- stage arrays
# What the kernel groups (stages) read and write on the device, made once by ModelBuilder.finalize
# (or by a stage's own constructor for a hand-made stage); a stage keeps references to them only.
# Each holds the model's arrays of its part and the scratch its kernels rewrite every step
# (springs, ellipsoids, contact points): recomputed from State and Control before every use.


def _jaw_axes(wp, jaw, device):
    """The jaws' pivots [m] and unit axes, one per head: three wp.array (H,) of wp.vec3 (``jaw``:
    one joint or a list of H, each with ``pivot``, ``u_axis``, ``v_axis``; None: the defaults of
    a head without a jaw)."""
    jaws = list(jaw) if isinstance(jaw, (list, tuple)) else [jaw]
    P = np.zeros((len(jaws), 3), np.float32)
    U = np.tile(np.array([1.0, 0.0, 0.0], np.float32), (len(jaws), 1))
    V = np.tile(np.array([0.0, 1.0, 0.0], np.float32), (len(jaws), 1))
    for h, j in enumerate(jaws):
        if j is not None:
            P[h], U[h], V[h] = (np.asarray(a, np.float64).astype(np.float32) for a in (j.pivot, j.u_axis, j.v_axis))
    return tuple(wp.array(a, dtype=wp.vec3, device=device) for a in (P, U, V))


def _head_ids(wp, head, count: int, device):
    """Each element's head (int32 device array (count,)); ``head`` None: all head 0."""
    h = np.zeros(count, np.int32) if head is None else np.asarray(head, np.int32).reshape(-1)
    if len(h) != count:
        raise InputError(f"head: expected {count} head indices, got {len(h)}")
    return wp.array(h, dtype=wp.int32, device=device)


class MuscleArrays:
    """The muscles on the device (:class:`~facewarp._src.physics.muscle_stage.MuscleStage`'s arrays).

    Model (read only), float32 / int32 copies of the rig's fields (:class:`~facewarp.MuscleRig`,
    same names and units): ``ctrl_rest`` (P,) vec3 [m], ``ctrl_muscle``, ``ctrl_pivot`` (P,),
    ``ctrl_jaw`` (P,), ``muscle_activation``, ``muscle_contraction``, ``muscle_saturation``,
    ``muscle_center`` (M,) vec3 [m], ``muscle_center_jaw``, ``muscle_center_normal`` (M,) vec3,
    ``muscle_glide``, ``muscle_glide_center`` (M,) vec3 [m], ``curve_ctrl`` (C,) vec3i,
    ``curve_weight`` (C,) vec3, ``curve_normal`` (C,) vec3 (rest plane normals), ``seg_curve``
    (S,), ``seg_t`` (S,) vec2, ``seg_rest_radii`` (S,) vec3 [m]; anchors grouped (``anchor_count``,
    ``anchor_start`` (A + 1,), ``anchor_ctrl``, ``anchor_passive``); attachments ``att_node``,
    ``att_seg``, ``att_uv`` (K,) vec2, ``att_rest_length`` [m], ``att_stiffness`` [N/m] (after the
    area weights), ``att_jaw_shift`` (node amount less the muscle's), ``att_across`` (K,) int32,
    grouped per node (``att_nodes_unique``, ``att_node_start``, ``att_order``); ``jaw_pivot`` [m],
    ``jaw_u``, ``jaw_v`` (wp.vec3).

    Scratch (rewritten every step): ``ctrl_jawed``, ``ctrl_contracted`` (P,) vec3 [m];
    ``seg_center`` (S,) vec3 [m], ``seg_frame`` (S,) mat33, ``seg_radii`` (S,) vec3 [m];
    ``att_point`` (K,) vec3 [m], ``spring_stiffness`` (K,) [N/m], ``att_force`` (K,) vec3 [N];
    ``springs`` (:class:`Springs` over them).
    """

    def __init__(self, wp, rig, jaw, device, node_amount, weighted_stiffness, attachment_jaw, attachment_across,
                 curve_normals, *, ctrl_head=None, att_head=None, att_jaw_shift=None):
        f32 = lambda a, dt=float: wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=dt, device=device)  # noqa: E731
        i32 = lambda a, dt=wp.int32: wp.array(np.ascontiguousarray(a, dtype=np.int32), dtype=dt, device=device)  # noqa: E731
        self.rig = rig
        self.device = device
        self.ctrl_rest = f32(rig.ctrl_rest, wp.vec3)
        self.ctrl_muscle = i32(rig.ctrl_muscle)
        self.ctrl_pivot = i32(rig.ctrl_pivot)
        self.ctrl_jaw = f32(rig.ctrl_jaw)
        self.muscle_activation = i32(rig.activation_index)
        self.muscle_contraction = f32(rig.contraction)
        self.muscle_saturation = f32(rig.saturation)
        self.muscle_center_normal = f32(rig.center_normal, wp.vec3)
        self.muscle_glide = i32(rig.glide)
        self.muscle_glide_center = f32(rig.glide_center, wp.vec3)
        self.muscle_center = f32(rig.center, wp.vec3)
        self.muscle_center_jaw = f32(rig.center_jaw)
        self.curve_ctrl = i32(rig.curve_ctrl, wp.vec3i)
        self.curve_weight = f32(rig.curve_weight, wp.vec3)
        self.curve_normal = f32(curve_normals, wp.vec3)
        self.seg_curve = i32(rig.seg_curve)
        self.seg_t = f32(rig.seg_t, wp.vec2)
        self.seg_rest_radii = f32(rig.seg_rest_radii, wp.vec3)
        groups, a_start, a_order = group_indices(rig.anchor_group)
        self.anchor_count = len(groups)
        self.anchor_start = i32(a_start)
        self.anchor_ctrl = i32(np.asarray(rig.anchor_ctrl)[a_order])
        self.anchor_passive = f32(np.asarray(rig.anchor_passive)[a_order])
        self.att_node = i32(rig.att_node)
        self.att_seg = i32(rig.att_seg)
        self.att_uv = f32(rig.att_uv, wp.vec2)
        self.att_rest_length = f32(rig.att_rest_length)
        self.att_stiffness = f32(weighted_stiffness)
        shift = np.zeros(len(rig.att_node))
        if att_jaw_shift is not None:
            shift = np.asarray(att_jaw_shift, np.float64)
        elif node_amount is not None and len(rig.att_node):
            shift = np.asarray(node_amount, np.float64)[rig.att_node] - attachment_jaw
        self.att_jaw_shift = f32(shift)
        self.ctrl_head = _head_ids(wp, ctrl_head, len(rig.ctrl_rest), device)
        self.att_head = _head_ids(wp, att_head, len(rig.att_node), device)
        self.att_across = i32(attachment_across)
        nodes_u, n_start, order = group_indices(rig.att_node)
        self.att_nodes_unique = i32(nodes_u)
        self.att_node_start = i32(n_start)
        self.att_order = i32(order)
        self.att_force = wp.zeros(len(order), dtype=wp.vec3, device=device)
        P, S, K = len(rig.ctrl_rest), len(rig.seg_curve), len(rig.att_node)
        self.ctrl_jawed = wp.zeros(P, dtype=wp.vec3, device=device)
        self.ctrl_contracted = wp.zeros(P, dtype=wp.vec3, device=device)
        self.seg_center = wp.zeros(S, dtype=wp.vec3, device=device)
        self.seg_frame = wp.zeros(S, dtype=wp.mat33, device=device)
        self.seg_radii = wp.zeros(S, dtype=wp.vec3, device=device)
        self.att_point = wp.zeros(K, dtype=wp.vec3, device=device)
        self.spring_stiffness = wp.zeros(K, dtype=float, device=device)
        self.springs = Springs(node=self.att_node, point=self.att_point, stiffness=self.spring_stiffness,
                               rest_length=self.att_rest_length)
        self.jaw_pivot, self.jaw_u, self.jaw_v = _jaw_axes(wp, jaw, device)


class SupportArrays:
    """The sliding supports on the device (:class:`~facewarp._src.physics.muscle_stage.SupportStage`'s arrays).

    Model: ``count``; ``nodes`` (s,) int32; ``normals`` (s,) vec3 (unit rest normals); ``amounts``
    (s,) float32 (jaw amounts); ``stiffness`` (s,) float32 [N/m]; ``rest`` (vertex_count,) vec3 [m]
    (the Model's rest positions); ``pivot``, ``u``, ``v`` (wp.vec3: the jaw). Scratch: ``point``,
    ``axis`` (s,) vec3 (the step's anchors [m] and axes) and ``springs`` over them.
    """

    def __init__(self, wp, jaw, nodes, normals, amounts, stiffness, rest_positions, device, head=None):
        self.device = device
        self.count = len(nodes)
        self.head = _head_ids(wp, head, self.count, device)
        self.nodes = wp.array(np.asarray(nodes, np.int32), dtype=wp.int32, device=device)
        n = np.asarray(normals, np.float64).reshape(-1, 3)
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        self.normals = wp.array(n.astype(np.float32), dtype=wp.vec3, device=device)
        self.amounts = wp.array(np.asarray(amounts, np.float32), dtype=float, device=device)
        k = np.broadcast_to(np.asarray(stiffness, np.float64), (self.count,))
        if not (np.isfinite(k).all() and (k >= 0).all()):
            raise InputError(f"support stiffness must be finite and >= 0 [N/m], got min {k.min() if len(k) else 0}")
        self.stiffness = wp.array(k.astype(np.float32), dtype=float, device=device)
        self.rest = rest_positions
        self.pivot, self.u, self.v = _jaw_axes(wp, jaw, device)
        self.point = wp.zeros(self.count, dtype=wp.vec3, device=device)
        self.axis = wp.zeros(self.count, dtype=wp.vec3, device=device)
        self.springs = Springs(node=self.nodes, point=self.point, stiffness=self.stiffness, axis=self.axis)


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
        self.head = _head_ids(wp, None if head is None else np.asarray(head).reshape(-1)[keep], self.count, device)
        self.head_count = len(jaw) if isinstance(jaw, (list, tuple)) else 1
        self.pivot, self.u, self.v = _jaw_axes(wp, jaw, device)
        self.rest = rest_positions


class ContactSurface:
    """Candidate nodes against one closed surface: its ``wp.Mesh`` and the nodes' springs (contact scratch).

    With several heads the surface of every head is one mesh: head h's points are moved by its
    query shift ``head_shift[h]`` (``kernels_contact._gather_points``), so a node (moved by its
    head's shift for the query) finds only its own head's surface; head 0's shift is 0."""

    def __init__(self, wp, nodes, k, surface_points, faces, device, reach, gap, *, follows=None, rigid=None,
                 node_head=None, point_head=None, head_shift=None):
        self.count = len(nodes)
        self.reach, self.gap = float(reach), float(gap)
        self.follows = follows  # node indices the surface points are (a lip), or None
        self.rigid = rigid  # (rest points, jaw amount per point) of a rigid part, or None
        self.nodes = wp.array(np.asarray(nodes, np.int32), dtype=wp.int32, device=device)
        self.k = wp.array(np.asarray(k, np.float32), dtype=float, device=device)
        npt = len(surface_points)
        ph = np.zeros(npt, np.int32) if point_head is None else np.asarray(point_head, np.int32)
        shift = np.zeros((1, 3), np.float64) if head_shift is None else np.asarray(head_shift, np.float64)
        self.node_head = _head_ids(wp, node_head, self.count, device)
        self.point_head = _head_ids(wp, ph, npt, device)
        self.head_shift = wp.array(shift.astype(np.float32), dtype=wp.vec3, device=device)
        P = np.asarray(surface_points, np.float32)
        if head_shift is not None and np.any(shift):  # the points in the query space (as the kernels move them)
            P = (P + shift.astype(np.float32)[ph]).astype(np.float32)
        self.points = wp.array(P, dtype=wp.vec3, device=device)
        if rigid is not None:
            self.rest = wp.array(np.asarray(rigid[0], np.float32), dtype=wp.vec3, device=device)
            amt = np.broadcast_to(np.asarray(rigid[1], np.float64), (npt,))
            self.amount = float(np.abs(amt).max(initial=0.0))  # 0: the part never moves
            self.amounts = wp.array(amt.astype(np.float32), dtype=float, device=device)
        if follows is not None:
            self.follow = wp.array(np.asarray(follows, np.int32), dtype=wp.int32, device=device)
        self.mesh = wp.Mesh(points=self.points, indices=wp.array(np.asarray(faces, np.int32).ravel(), dtype=wp.int32,
                                                                   device=device))
        self.springs = Springs(node=self.nodes, point=wp.zeros(self.count, dtype=wp.vec3, device=device),
                               stiffness=wp.zeros(self.count, dtype=float, device=device),
                               axis=wp.zeros(self.count, dtype=wp.vec3, device=device), one_sided=True)


def _contact_head(g, X, kn, kg, gap, *, lips, teeth, eyes, lids, ties) -> dict:
    """One head's contact on the host (float64, its own node indices): the surfaces' candidates,
    the eyeball, glide, floor, lid and tie springs (:class:`ContactArrays`)."""
    from . import contact as C

    def stiff(nodes):
        k = kn[nodes]
        pos = k[k > 0]
        return np.where(k > 0, k, np.median(pos) if len(pos) else 0.0)

    out = {"surfaces": []}
    if lips:
        for S, nodes in zip(g.lip_faces, g.lip_nodes):
            if len(S) == 0 or len(nodes) == 0:
                continue
            used, local = np.unique(S, return_inverse=True)
            out["surfaces"].append(dict(kind="lip", nodes=np.asarray(nodes, np.int64), k=stiff(nodes), points=X[used],
                                        faces=local.reshape(-1, 3), reach=C.LIP_REACH_M, follows=used))
    if teeth:
        for name, TV, TF, amount, nodes in g.teeth:
            if len(nodes):
                out["surfaces"].append(dict(kind=f"teeth:{name}", nodes=np.asarray(nodes, np.int64), k=stiff(nodes),
                                            points=np.asarray(TV, np.float64), faces=np.asarray(TF),
                                            reach=C.TEETH_REACH_M, amount=float(amount)))
    glide = np.asarray(g.eye_glide, bool)
    if len(glide) != len(g.eye_nodes):
        glide = np.zeros(len(g.eye_nodes), bool)
    en = np.asarray(g.eye_nodes, np.int64)
    d_rest = np.linalg.norm(X[en] - g.eye_centers[g.eye_of_node], axis=1) if len(en) else np.zeros(0)
    if eyes and len(en):
        # a node inside the ball (or within the gap) at rest gets its rest distance less
        # C.EYE_REST_SLACK_M: no force at rest, and it may not sink deeper
        r = np.minimum(g.eye_radii[g.eye_of_node] + gap, d_rest - C.EYE_REST_SLACK_M)
        out["eye"] = (en, g.eye_centers[g.eye_of_node], stiff(en), r)
    if eyes and glide.any():
        # the inner lid sheet glides on the eyeball: on its glide sphere (glide_spheres; about
        # the eyeball's centre through its rest position where none is given), two-sided at
        # the sliding support's stiffness, and it may not sink below that sphere (one-sided at
        # its contact stiffness, C.EYE_REST_SLACK_M short of it); the contact above keeps it out
        # of the ball
        if len(g.glide_centers) == len(en) and len(g.glide_radii) == len(en):
            gc, gr = np.asarray(g.glide_centers, np.float64), np.asarray(g.glide_radii, np.float64)
        else:
            gc, gr = g.eye_centers[g.eye_of_node], d_rest
        out["glide"] = (en[glide], gc[glide], kg[en[glide]], gr[glide])
        out["floor"] = (en[glide], gc[glide], stiff(en)[glide], (gr - C.EYE_REST_SLACK_M)[glide])
    if lids and len(g.lid_nodes):
        ln = np.asarray(g.lid_nodes, np.int64)
        c, n = g.lid_planes[g.lid_plane, 0], g.lid_planes[g.lid_plane, 1]
        a = g.lid_side[:, None] * n  # toward the node's own side
        # the plane gap / 2 short of the fissure plane (the two margins stop gap apart; a
        # node nearer at rest, with a geometry made for a smaller gap, keeps its rest distance)
        r = np.minimum(0.5 * gap, np.einsum("ij,ij->i", X[ln] - c, a))
        out["lid"] = (ln, c + r[:, None] * a, C.LID_STIFFNESS_RATIO * stiff(ln), a)
        partner = np.asarray(g.lid_partner, np.int64)
        if ties and len(partner) == len(ln) and len(g.lid_tangent) == len(ln) and (partner >= 0).any():
            # margins that close meet point to point along the fissure (kernels_contact._lid_ties),
            # held as firmly as the inner sheet on its support (the glide stiffness: the
            # contact's stiffness there stalled the CPU L-BFGS on the level-1 head)
            mate = np.maximum(partner, 0)
            off = 0.5 * (X[ln] - X[ln[mate]])
            above = np.einsum("ij,ij->i", X[ln] - c, a) - r  # from the node's spring plane at rest
            out["ties"] = (partner, above + above[mate], off, kg[ln], np.asarray(g.lid_tangent, np.float64))
    return out


def _query_shifts(points: list, reach: float) -> np.ndarray:
    """Each head's shift into its own cell of the contact query space [m], (H, 3), float64:
    head h at cell (i, j, k) of a cube grid (head 0 at the origin, unshifted), the cells wider
    than every head's contact points and twice the reach, so no head's query reaches another's."""
    H = len(points)
    if H == 1:
        return np.zeros((1, 3))
    allp = np.concatenate([np.asarray(p, np.float64).reshape(-1, 3) for p in points if len(p)] or [np.zeros((1, 3))])
    lo, hi = allp.min(0), allp.max(0)
    cell = float((hi - lo).max()) + 2.0 * reach + 0.01
    side = int(np.ceil(H ** (1.0 / 3.0) - 1e-9))
    h = np.arange(H)
    return np.stack([h % side, (h // side) % side, h // (side * side)], 1) * cell


class ContactArrays:
    """The contact on the device (:class:`~facewarp._src.physics.contact.ContactStage`'s arrays;
    the arguments are the stage's, with ``nodes`` the rest positions [m], (p, 3), and ``jaw`` the
    joint the lower teeth turn with, or None). Several heads: ``nodes``, ``node_stiffness``,
    ``geometry``, ``glide_stiffness`` and ``jaw`` lists of one per head, ``node_offsets`` (H,)
    each head's first node in the Model (the heads' surfaces must be alike: the same lips and
    teeth in the same order, e.g. heads of one template).

    Model: ``geometry`` (the :class:`~facewarp._src.physics.contact.ContactGeometry`; the first
    head's), ``pivot``, ``u``, ``v`` (wp.array (H,) of wp.vec3: the jaws); per obstacle surface a
    :class:`ContactSurface` in ``surfaces`` (its candidate nodes, stiffness [N/m], points [m] and
    ``wp.Mesh``, every head's in one); counts ``eye_count``, ``glide_count``, ``lid_count``,
    ``tie_count``; the lid ties' ``tie_rest`` [m], ``tie_partner``, ``tie_offset`` [m],
    ``tie_stiffness`` [N/m]. The spring sets (``eye_springs``, ``glide_springs``,
    ``floor_springs``, ``lid_springs``, ``tie_springs``; all in ``springs``): fixed nodes and
    stiffness, their points, axes and stiffness the detection's scratch.
    """

    def __init__(self, wp, nodes, node_stiffness, device, *, gap=None, lips=True, teeth=True, eyes=True, lids=True,
                 ties=True, geometry=None, glide_stiffness=None, jaw=None, node_offsets=None):
        from . import contact as C

        gap = C.CONTACT_GAP if gap is None else gap
        self.device = device
        if not (np.isfinite(gap) and gap >= 0.0):
            raise InputError(f"gap: expected a finite distance >= 0 [m], got {gap!r}")
        multi = isinstance(geometry, (list, tuple))
        geos = list(geometry) if multi else [geometry]
        H = len(geos)
        Xs = list(nodes) if multi else [nodes]
        kns = list(node_stiffness) if multi else [node_stiffness]
        kgs = list(glide_stiffness) if multi else [glide_stiffness]
        jaws = list(jaw) if multi else [jaw]
        offs = np.zeros(1, np.int64) if node_offsets is None else np.asarray(node_offsets, np.int64)
        heads, seen = [], {}
        for h in range(H):
            key = (id(geos[h]), id(Xs[h]), id(kns[h]), id(kgs[h]))  # heads of one rig: computed once
            if key in seen:
                heads.append(seen[key])
                continue
            X = np.asarray(Xs[h], np.float64)
            kn = np.asarray(kns[h], np.float64)
            if kn.shape != (len(X),) or not (np.isfinite(kn).all() and (kn >= 0).all()):
                raise InputError(f"node_stiffness: expected finite values >= 0 of shape ({len(X)},) [N/m]")
            kg = kn if kgs[h] is None else np.asarray(kgs[h], np.float64)
            if kg.shape != (len(X),) or not (np.isfinite(kg).all() and (kg >= 0).all()):
                raise InputError(f"glide_stiffness: expected finite values >= 0 of shape ({len(X)},) [N/m]")
            heads.append(_contact_head(geos[h], X, kn, kg, gap, lips=lips, teeth=teeth, eyes=eyes, lids=lids,
                                       ties=ties))
            seen[key] = heads[-1]
        g = geos[0]
        self.geometry = g
        self.geometries = geos
        self.pivot, self.u, self.v = _jaw_axes(wp, jaws if multi else jaw, device)

        # the surfaces: the k-th of every head in one mesh (the heads shifted apart for the queries)
        kinds = [tuple(s["kind"] for s in hd["surfaces"]) for hd in heads]
        if any(k != kinds[0] for k in kinds):
            bad = next(h for h, k in enumerate(kinds) if k != kinds[0])
            raise InputError(f"contact of head {bad}: its lip and teeth surfaces {list(kinds[bad])} differ from head "
                             f"0's {list(kinds[0])}; heads of one Model need alike contact surfaces")
        reach = max([s["reach"] for hd in heads for s in hd["surfaces"]] or [0.0])
        shift = _query_shifts([np.concatenate([s["points"] for s in hd["surfaces"]] or [np.zeros((0, 3))])
                               for hd in heads], reach)
        self.head_shift = shift
        self.surfaces: list[ContactSurface] = []
        for j in range(len(kinds[0])):
            parts = [hd["surfaces"][j] for hd in heads]
            s0 = parts[0]
            pts, fcs, nds, ks, nh, ph, fol, amt = [], [], [], [], [], [], [], []
            p0 = 0
            for h, s in enumerate(parts):
                npt = len(s["points"])
                pts.append(s["points"])
                fcs.append(np.asarray(s["faces"], np.int64) + p0)
                nds.append(s["nodes"] + offs[h])
                ks.append(s["k"])
                nh.append(np.full(len(s["nodes"]), h))
                ph.append(np.full(npt, h))
                if s0["kind"] == "lip":
                    fol.append(s["follows"] + offs[h])
                else:
                    amt.append(np.full(npt, s["amount"]))
                p0 += npt
            cat = np.concatenate
            lip = s0["kind"] == "lip"
            self.surfaces.append(ContactSurface(
                wp, cat(nds), cat(ks), cat(pts), cat(fcs), device, s0["reach"], gap,
                follows=cat(fol) if lip else None, rigid=None if lip else (cat(pts), cat(amt)),
                node_head=cat(nh), point_head=cat(ph), head_shift=shift))
        sets = [s.springs for s in self.surfaces]

        def gather(key, n_items):
            """The heads' rows of one set, node indices shifted; None when no head has it."""
            rows = [(h, hd[key]) for h, hd in enumerate(heads) if key in hd]
            if not rows:
                return None
            out = []
            for i in range(n_items):
                out.append(np.concatenate([r[i] + (offs[h] if i == 0 else 0) for h, r in rows]))
            return out

        def sphere_set(parts, one_sided):
            en, c, k, r = parts
            return Springs(node=wp.array(en.astype(np.int32), dtype=wp.int32, device=device),
                           point=wp.array(c.astype(np.float32), dtype=wp.vec3, device=device),
                           stiffness=wp.array(k.astype(np.float32), dtype=float, device=device),
                           rest_length=wp.array(r.astype(np.float32), dtype=float, device=device),
                           one_sided=one_sided)

        eye, glide, floor = gather("eye", 4), gather("glide", 4), gather("floor", 4)
        self.eye_count = 0 if eye is None else len(eye[0])
        self.glide_count = 0 if glide is None else len(glide[0])
        if self.eye_count:
            self.eye_springs = sphere_set(eye, True)
            sets.append(self.eye_springs)
        if self.glide_count:
            self.glide_springs = sphere_set(glide, False)
            self.floor_springs = sphere_set(floor, True)
            sets += [self.glide_springs, self.floor_springs]
        lid = gather("lid", 4)
        self.lid_count = 0 if lid is None else len(lid[0])
        self.tie_count = 0
        if self.lid_count:
            ln, point, k, a = lid
            self.lid_springs = Springs(
                node=wp.array(ln.astype(np.int32), dtype=wp.int32, device=device),
                point=wp.array(point.astype(np.float32), dtype=wp.vec3, device=device),
                stiffness=wp.array(k.astype(np.float32), dtype=float, device=device),
                axis=wp.array(a.astype(np.float32), dtype=wp.vec3, device=device), one_sided=True)
            sets.append(self.lid_springs)
            if any("ties" in hd for hd in heads):
                # every head's lid rows, its partners shifted by its first lid row (none: no partner)
                partner, rest, off, kt, tan = [], [], [], [], []
                l0 = 0
                for hd in heads:
                    if "lid" not in hd:
                        continue
                    m = len(hd["lid"][0])
                    if "ties" in hd:
                        p, r, o, k_, t = hd["ties"]
                        partner.append(np.where(p >= 0, p + l0, -1))
                        rest += [r]
                        off += [o]
                        kt += [k_]
                        tan += [t]
                    else:
                        partner.append(np.full(m, -1))
                        rest += [np.zeros(m)]
                        off += [np.zeros((m, 3))]
                        kt += [np.zeros(m)]
                        tan += [np.zeros((m, 3))]
                    l0 += m
                cat = np.concatenate
                self.tie_count = self.lid_count
                self.tie_rest = wp.array(cat(rest).astype(np.float32), dtype=float, device=device)
                self.tie_partner = wp.array(cat(partner).astype(np.int32), dtype=wp.int32, device=device)
                self.tie_offset = wp.array(cat(off).astype(np.float32), dtype=wp.vec3, device=device)
                self.tie_stiffness = wp.array(cat(kt).astype(np.float32), dtype=float, device=device)
                self.tie_springs = Springs(
                    node=self.lid_springs.node, point=wp.zeros(self.lid_count, dtype=wp.vec3, device=device),
                    stiffness=wp.zeros(self.lid_count, dtype=float, device=device),
                    axis=wp.array(cat(tan).astype(np.float32), dtype=wp.vec3, device=device))
                sets.append(self.tie_springs)
        self.springs = tuple(sets)
