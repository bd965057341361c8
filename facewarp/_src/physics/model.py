"""Builder -> Model / State / Control for the skin tissue (thesis Sec. 6.4, Table 6.3).

:class:`ModelBuilder` takes a generic tetrahedral mesh (numpy), validates it and derives the
elements of the deformation model: unique tet edges (distance energy, Eq. 6.4.4 with the
nonlinear stiffness of Eq. 6.4.6), unique tet faces (area energy, Eq. 6.4.7) and the tets
themselves (volume energy, Eq. 6.4.8). :meth:`ModelBuilder.finalize` copies everything into a
read-only :class:`Model` of Warp arrays on one device; :meth:`Model.state` and
:meth:`Model.control` make the mutable buffers that :class:`~facewarp._src.solver.SolverVerlet`
steps.

Unit system
-----------
SI throughout: metre, kilogram, second (so newton and joule). Every energy term of Sec. 6.4.2
is ``E = 1/2 k C^2`` with a *dimensionless* constraint ``C`` (relative length, area or volume
change), so the stiffness coefficients ``k0``, ``k_area`` and ``k_volume`` are energies [J] (the
energy of a unit relative strain); masses are [kg]. Table 6.3's numbers are used as they stand
in this system: node mass 0.5 kg, k0 15 / 10 / 5 J (outer / inner / cross-layer edges),
k_area = k_volume = 7.5 J. Only the ratio k / m sets the motion (15 J / 0.5 kg = 30 J/kg,
of the order of Young's modulus over density of skin, ~1e5 Pa / 1e3 kg m^-3 = 100 J/kg), so
time scales are plausible; absolute force magnitudes are those of a 0.5 kg node, i.e. the
numbers are best read as a consistent *model* unit system, not measured tissue forces.

Because the constraints are relative, an edge of rest length ``D0`` acts like a linear spring
of stiffness ``k0 / D0^2`` [N/m]: finer meshes are stiffer and need smaller steps (the stable
step scales with ``D0``; see :mod:`facewarp._src.solver`).

The damping of Table 6.3 (``k_damping`` 0.002) is the *per-substep* velocity loss of the
damped Verlet step ``x' = x + (1 - damping) (x - x_prev) + dt^2 f / m`` (dimensionless), which
is Eq. 6.4.5's ``-k_damping v`` term with ``k_damping = damping m / dt`` [kg/s]. An optional
dashpot along each edge (``edge_damping`` [N s/m], default 0) damps relative velocity only,
so it never slows a rigid motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.warp import get_warp
from ..core.errors import InputError
from ..geometry.tets import signed_tet_volumes

__all__ = [
    "EDGE_CROSS",
    "EDGE_INNER",
    "EDGE_OUTER",
    "TABLE_6_3",
    "Control",
    "Model",
    "ModelBuilder",
    "State",
]

EDGE_OUTER = 0
"""Edge class of an edge whose two nodes are both on the outer layer (``layer == 0``)."""
EDGE_INNER = 1
"""Edge class of an edge whose two nodes are both on the inner layer (``layer == 1``)."""
EDGE_CROSS = 2
"""Edge class of an edge joining the outer and the inner layer."""

TABLE_6_3 = {
    "mass": 0.5,  # kg per node
    "damping": 0.002,  # per-substep velocity loss (dimensionless)
    "k0_outer": 15.0,  # J
    "k0_inner": 10.0,  # J
    "k0_cross": 5.0,  # J
    "k_area": 7.5,  # J
    "k_volume": 7.5,  # J
}
"""Table 6.3 of the thesis in the SI model unit system of this module (see the module doc)."""

_TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])




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


class ModelBuilder:
    """Validates a tet mesh and derives the elements of the deformation model (Sec. 6.4).

    Args:
        vertices: Rest positions [m], shape (n, 3), float.
        tets: Tetrahedra, shape (k, 4), int; each must have positive signed volume
            ``(1/6) (x1 - x0) . ((x2 - x0) x (x3 - x0))`` (see :func:`facewarp._src.geometry.tets.signed_tet_volumes`).
        layer: Layer of each vertex, shape (n,), int: 0 outer (skin surface), 1 inner.
            Sets the edge class and so ``k0`` (Table 6.3). Default: all outer.
        fixed: Nodes pinned to their target (the rest position unless a solver stage moves
            it), shape (n,), bool. Default: none.
        held: Nodes pulled to their target by a spring of ``hold_stiffness``, shape (n,),
            bool. Default: none.
        mass: Node mass [kg], scalar or shape (n,). Default 0.5 (Table 6.3).
        damping: Per-substep velocity loss of the damped Verlet step, dimensionless in
            [0, 1). Default 0.002 (Table 6.3 ``k_damping``; see the module doc).
        edge_damping: Dashpot along each edge on the relative velocity [N s/m] (Eq. 6.4.5
            applied per spring). Default 0.
        k0_outer, k0_inner, k0_cross: Basic distance stiffness k0 [J] of Eq. 6.4.6 for
            outer-outer, inner-inner and cross-layer edges. Default 15, 10, 5 (Table 6.3).
        k_area: Area stiffness [J] of Eq. 6.4.7. Default 7.5 (Table 6.3).
        k_volume: Volume stiffness [J] of Eq. 6.4.8. Default 7.5 (Table 6.3).
        hold_stiffness: Spring stiffness [N/m] pulling each ``held`` node to its target.
            Default (None): four times the 98th percentile of the rest edge springs,
            ``4 k0 / D0^2`` (6e5 N/m for 1 cm outer edges), stiff against the tissue yet within
            the stable step of :func:`facewarp._src.solver.stable_dt`. The percentile keeps a
            few very short edges (a crease of an adapted head) from stiffening every hold;
            :func:`facewarp._src.solver.scale_masses` takes care of those edges' own nodes.
        muscle_count: Number of muscle activations in :class:`Control`. Default 0.

    Raises:
        InputError: on bad shapes, indices out of range, repeated vertices in a tet, an
            inverted or degenerate tet (naming its index), or bad coefficients.

    Attributes (numpy, float64 / int64; ``finalize`` copies them as float32 / int32):
        vertices (n, 3) [m], tets (k, 4), layer (n,), fixed (n,) bool, held (n,) bool (never
        also fixed), mass (n,) [kg], hold_stiffness (n,) [N/m] (0 where not held);
        edges (e, 2) unique, i < j; edge_rest_lengths (e,) [m]; edge_class (e,) EDGE_*;
        edge_k0 (e,) [J]; faces (f, 3) unique, sorted; face_rest_areas (f,) [m^2];
        tet_rest_volumes (k,) [m^3]; damping, edge_damping [N s/m], k_area [J],
        k_volume [J], muscle_count.
    """

    def __init__(
        self,
        vertices,
        tets,
        *,
        layer=None,
        fixed=None,
        held=None,
        mass=TABLE_6_3["mass"],
        damping: float = TABLE_6_3["damping"],
        edge_damping: float = 0.0,
        k0_outer: float = TABLE_6_3["k0_outer"],
        k0_inner: float = TABLE_6_3["k0_inner"],
        k0_cross: float = TABLE_6_3["k0_cross"],
        k_area: float = TABLE_6_3["k_area"],
        k_volume: float = TABLE_6_3["k_volume"],
        hold_stiffness: float | None = None,
        muscle_count: int = 0,
    ):
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
        vol = signed_tet_volumes(V32, T)
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
        mass = _vertex_array(mass, n, "mass", np.float64)
        if not (np.isfinite(mass).all() and (mass > 0).all()):
            raise InputError(f"mass must be positive and finite [kg], got min {mass.min()}")
        if not 0.0 <= damping < 1.0:
            raise InputError(f"damping must lie in [0, 1) (per-substep velocity loss), got {damping}")
        for name, val in (
            ("edge_damping", edge_damping),
            ("k0_outer", k0_outer),
            ("k0_inner", k0_inner),
            ("k0_cross", k0_cross),
            ("k_area", k_area),
            ("k_volume", k_volume),
        ):
            if not (np.isfinite(val) and val >= 0.0):
                raise InputError(f"{name} must be a finite value >= 0, got {val}")
        if int(muscle_count) < 0:
            raise InputError(f"muscle_count must be >= 0, got {muscle_count}")

        # unique edges (i < j) with their rest length D0 and class
        E = np.sort(T[:, _TET_EDGES].reshape(-1, 2), axis=1)
        E = np.unique(E, axis=0)
        D0 = np.linalg.norm(V32[E[:, 1]] - V32[E[:, 0]], axis=1)
        la, lb = layer[E[:, 0]], layer[E[:, 1]]
        edge_class = np.where(la != lb, EDGE_CROSS, np.where(la == 0, EDGE_OUTER, EDGE_INNER))
        k0 = np.array([k0_outer, k0_inner, k0_cross])[edge_class]

        # unique faces (sorted vertex triples: the area energy ignores the winding)
        Fc = np.sort(T[:, _TET_FACES].reshape(-1, 3), axis=1)
        Fc = np.unique(Fc, axis=0)
        A0 = 0.5 * np.linalg.norm(np.cross(V32[Fc[:, 1]] - V32[Fc[:, 0]], V32[Fc[:, 2]] - V32[Fc[:, 0]]), axis=1)

        if hold_stiffness is None:
            hold_stiffness = 4.0 * float(np.quantile(k0 / D0**2, 0.98))
        if not (np.isfinite(hold_stiffness) and hold_stiffness >= 0.0):
            raise InputError(f"hold_stiffness must be a finite value >= 0 [N/m], got {hold_stiffness}")

        self.vertices = V
        self.tets = T
        self.layer = layer
        self.fixed = fixed
        self.held = held & ~fixed
        self.mass = mass
        self.damping = float(damping)
        self.edge_damping = float(edge_damping)
        self.edges = E
        self.edge_rest_lengths = D0
        self.edge_class = edge_class
        self.edge_k0 = k0
        self.faces = Fc
        self.face_rest_areas = A0
        self.tet_rest_volumes = vol
        self.k_area = float(k_area)
        self.k_volume = float(k_volume)
        self.hold_stiffness = np.where(self.held, float(hold_stiffness), 0.0)
        self.muscle_count = int(muscle_count)

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    def finalize(self, device=None) -> Model:
        """Copy the model onto ``device`` (a Warp device or its name; None: Warp's default).

        Returns:
            A read-only :class:`Model` of Warp arrays (float32 / int32) on that device.
        """
        wp = get_warp()
        dev = wp.get_device(device)

        def f32(a, dtype=float):
            return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=dtype, device=dev)

        def i32(a, dtype=wp.int32):
            return wp.array(np.ascontiguousarray(a, dtype=np.int32), dtype=dtype, device=dev)

        inv_mass = np.where(self.fixed, 0.0, 1.0 / self.mass)
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
            rest_positions=f32(self.vertices, wp.vec3),
            vertex_mass=f32(self.mass),
            vertex_inv_mass=f32(inv_mass),
            vertex_layer=i32(self.layer),
            vertex_fixed=i32(self.fixed),
            vertex_hold_stiffness=f32(self.hold_stiffness),
            edge_indices=i32(self.edges, wp.vec2i),
            edge_rest_length=f32(self.edge_rest_lengths),
            edge_k0=f32(self.edge_k0),
            edge_class=i32(self.edge_class),
            face_indices=i32(self.faces, wp.vec3i),
            face_rest_area=f32(self.face_rest_areas),
            tet_indices=i32(self.tets, wp.vec4i),
            tet_rest_volume=f32(self.tet_rest_volumes),
            slot_count=len(slot_node),
            node_slot_start=i32(start),
            node_slots=i32(order),
            k_area=self.k_area,
            k_volume=self.k_volume,
            damping=self.damping,
            edge_damping=self.edge_damping,
        )


@dataclass(frozen=True, eq=False)
class Model:
    """Read-only tissue model on one device (made by :meth:`ModelBuilder.finalize`).

    Units: SI (m, kg, s); stiffnesses of the relative-strain energies in J (see the module
    doc). Arrays are Warp arrays on :attr:`device`; the solver never writes them.
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
    """Node mass [kg], shape (vertex_count,), float32 (Table 6.3: 0.5)."""
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
    """Basic distance stiffness k0 [J] (Eq. 6.4.6, Table 6.3 by edge class),
    shape (edge_count,), float32."""
    edge_class: object
    """EDGE_OUTER / EDGE_INNER / EDGE_CROSS, shape (edge_count,), int32."""

    face_indices: object
    """Unique tet faces (i, j, k), sorted; shape (face_count,), wp.vec3i (int32)."""
    face_rest_area: object
    """Rest area A0 [m^2] (Eq. 6.4.7), shape (face_count,), float32."""

    tet_indices: object
    """Tets (i, j, k, l) with positive signed volume; shape (tet_count,), wp.vec4i (int32)."""
    tet_rest_volume: object
    """Rest signed volume V0 [m^3] (Eq. 6.4.8), > 0; shape (tet_count,), float32."""

    slot_count: int
    """Number of per-element force slots: 2 per edge, 3 per face, 4 per tet (edges first)."""
    node_slot_start: object
    """CSR start of each node's slots in :attr:`node_slots`, shape (vertex_count + 1,), int32."""
    node_slots: object
    """Force slots of each node, ascending, shape (slot_count,), int32. The elements write their
    corner forces into their own slots and each node sums its slots in this fixed order, so the
    forces are bit-for-bit reproducible run to run and the same sums on CPU and CUDA (atomic
    adds would add in whatever order threads arrive)."""

    k_area: float
    """Area stiffness [J] (Eq. 6.4.7, Table 6.3: 7.5)."""
    k_volume: float
    """Volume stiffness [J] (Eq. 6.4.8, Table 6.3: 7.5)."""
    damping: float
    """Per-substep velocity loss of the damped Verlet step (Eq. 6.4.10), dimensionless
    (Table 6.3 k_damping: 0.002)."""
    edge_damping: float
    """Dashpot coefficient along each edge on the relative velocity [N s/m] (Eq. 6.4.5)."""

    def state(self) -> State:
        """A new :class:`State` at rest: positions = previous positions = rest positions."""
        wp = get_warp()
        return State(
            positions=wp.clone(self.rest_positions),
            prev_positions=wp.clone(self.rest_positions),
        )

    def control(self) -> Control:
        """A new :class:`Control`: no activation, jaw closed, no external force."""
        wp = get_warp()
        return Control(
            activations=wp.zeros(self.muscle_count, dtype=float, device=self.device),
            jaw_angles=wp.zeros(2, dtype=float, device=self.device),
            external_force=wp.zeros(self.vertex_count, dtype=wp.vec3, device=self.device),
        )


@dataclass(eq=False)
class State:
    """Positions of the mass points at two consecutive substeps (Verlet, Eq. 6.4.10)."""

    positions: object
    """Positions x(t) [m], shape (vertex_count,), wp.vec3 (float32)."""
    prev_positions: object
    """Positions x(t - dt) [m], shape (vertex_count,), wp.vec3 (float32)."""

    def assign(self, other: State) -> None:
        """Copy ``other``'s buffers into this state's (no allocation)."""
        wp = get_warp()
        wp.copy(self.positions, other.positions)
        wp.copy(self.prev_positions, other.prev_positions)


@dataclass(eq=False)
class Control:
    """What drives the face: muscle activations, jaw angles, and a user force.

    The solver only reads these. Muscle and jaw stages (see
    :class:`facewarp._src.solver.SolverStage`) turn them into forces and targets each substep.
    """

    activations: object
    """Muscle activations in [0, 1], shape (muscle_count,), float32 (Table 6.4)."""
    jaw_angles: object
    """Jaw rotation [rad] about the condyle u-axis (0..60 deg) and the v-axis (+-5 deg),
    shape (2,), float32 (Sec. 6.4.3)."""
    external_force: object
    """A constant external force [N] on each node, added every substep;
    shape (vertex_count,), wp.vec3 (float32). Zero by default."""

