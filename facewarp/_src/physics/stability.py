"""Stable steps and mass scaling of the explicit (Verlet) reference: the step each node allows, the
contact springs a node can carry at once, and selective mass scaling. Host NumPy on a
:class:`~.builder.ModelBuilder`'s arrays (or a thesis-profile :class:`~.model.Model`); the builder
asks these of its own tissue (:meth:`~.builder.ModelBuilder.explicit_step`) without importing a solver.

Stable time step
----------------
An edge of rest length D0 acts like a spring of stiffness k0 / D0^2 on a node of mass m, so
the explicit step must stay below about 2 / omega with omega^2 ~ (sum of the node's element
stiffnesses) / m, and the limit scales with D0. For the ``thesis`` profile the measured limit
for tets with 1 cm edges is :data:`DT_STABLE_1CM` (0.6 ms; 1.04 ms is the linear limit at rest);
:func:`stable_dt` scales a safe step (by default half of it: 0.3 ms for 1 cm edges) with the
shortest edge, the lightest node and the stiffest k0. For any other material (``physical``)
:func:`node_stable_dt` bounds every node's omega^2 and damping rate by Gershgorin's theorem on the
rest stiffness and damping matrices and takes the explicit limit of damped Verlet,
``dt < (sqrt(c^2 + 4 omega^2) - c) / omega^2``.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..geometry.tets import tet_heights
from .model import Model

__all__ = ["DT_STABLE_1CM", "MASS_SCALING_QUANTILE", "contact_stiffness_bound", "explicit_step", "node_spring_stiffness",
           "node_stable_dt", "scale_masses", "stable_dt", "thesis_substep"]


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



def stable_dt(model_or_builder, *, safety: float = 0.5) -> float:
    """A safe Verlet substep [s] for a mesh.

    Thesis profile: ``safety * DT_STABLE_1CM * (shortest edge / 1 cm)``, scaled by
    ``sqrt(lightest node mass / 0.5 kg)`` and ``sqrt(15 J / largest k0)`` (it assumes the
    Table 6.3 proportions of k_area and k_volume to k0 and hold springs no stiffer than the
    default). Other profiles: the smallest of :func:`node_stable_dt`.

    Args:
        model_or_builder: a :class:`~facewarp._src.physics.builder.ModelBuilder` (numpy,
            preferred) or a :class:`Model` (thesis profile only; reads its arrays back once).
        safety: fraction of the limit, default 0.5.
    """
    if isinstance(model_or_builder, Model):
        if model_or_builder.material != "thesis":
            raise InputError("model_or_builder: stable_dt of a non-thesis Model needs its ModelBuilder")
        d0 = model_or_builder.edge_rest_length.numpy()
        mass = model_or_builder.vertex_mass.numpy()
        k0 = model_or_builder.edge_k0.numpy()
        return float(thesis_substep(d0.min(), mass.min(), float(k0.max()), safety=safety))
    b = model_or_builder
    if b.material.name == "thesis":
        return float(thesis_substep(b.edge_rest_lengths.min(), b.mass.min(), float(b.edge_k0.max()), safety=safety))
    free = ~b.fixed
    dtn = node_stable_dt(b, safety=safety)
    return float(dtn[free].min() if free.any() else dtn.min())


MASS_SCALING_QUANTILE = 0.02
"""Fraction of nodes whose own stable step may lie below the chosen substep; those nodes get
the extra mass that brings them up to it (:func:`scale_masses`)."""


def _gershgorin_rates(builder) -> tuple[np.ndarray, np.ndarray]:
    """Per node bounds of the rest stiffness and strain-rate damping rows [N/m], [N s/m].

    Each element term ``1/2 k C^2`` has the rest Hessian ``k grad C grad C^T``; the row of
    node a is bounded by ``k |g_a| sum_b |g_b|`` (Gershgorin), likewise the dashpot ``d``.
    The distance energy's stiffening (Eq. 6.4.6, 1 + 3 C^2) is left to the safety factor.
    """
    V, n = builder.vertices, builder.vertex_count
    K = np.zeros(n)
    D = np.zeros(n)

    def add(idx, g, k, d):
        norms = np.linalg.norm(g, axis=2)  # (m, c)
        tot = norms.sum(axis=1, keepdims=True)
        for c in range(idx.shape[1]):
            np.add.at(K, idx[:, c], k * norms[:, c] * tot[:, 0])
            np.add.at(D, idx[:, c], d * norms[:, c] * tot[:, 0])

    E = builder.edges
    dvec = V[E[:, 0]] - V[E[:, 1]]
    L = builder.edge_rest_lengths
    nrm = dvec / np.linalg.norm(dvec, axis=1, keepdims=True)
    add(E, np.stack([nrm, -nrm], 1) / L[:, None, None], builder.edge_k0, builder.edge_damping_coef)
    F = builder.faces
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    N = np.cross(e1, e2)
    m = N / np.linalg.norm(N, axis=1, keepdims=True)
    gj, gk = 0.5 * np.cross(e2, m), 0.5 * np.cross(m, e1)
    add(F, np.stack([-(gj + gk), gj, gk], 1) / builder.face_rest_areas[:, None, None], builder.face_k,
        builder.face_damping_coef)
    T = builder.tets
    e1, e2, e3 = (V[T[:, c]] - V[T[:, 0]] for c in (1, 2, 3))
    gj, gk, gl = np.cross(e2, e3) / 6, np.cross(e3, e1) / 6, np.cross(e1, e2) / 6
    add(T, np.stack([-(gj + gk + gl), gj, gk, gl], 1) / builder.tet_rest_volumes[:, None, None], builder.tet_k,
        builder.tet_damping_coef)
    # shear term: rest blocks (k_s / 2) ((b_a . b_b) I + b_b b_a^T), rows bounded by k_s |b_a| sum |b_b|
    Dmi = builder.tet_rest_inverse
    add(T, np.concatenate([-Dmi.sum(axis=1)[:, None], Dmi], axis=1), builder.tet_shear_k, builder.tet_shear_damping)
    return K + builder.hold_stiffness, D


def node_stable_dt(builder, *, safety: float = 0.5, extra_stiffness=None) -> np.ndarray:
    """The stable Verlet step [s] each node allows, shape (n,), float64.

    Thesis profile, two limits per node, the smaller wins:

    * edges: :func:`stable_dt`'s rule with the node's shortest incident edge and its own mass
      (an edge of rest length D0 is a spring k0 / D0^2);
    * flat tets: the volume and area energies of Eq. 6.4.7-6.4.8 have a stiffness of about
      (k_volume + k_area) / h^2 on a tet of height h (its volume over its largest face), so
      ``dt <= 0.5 h sqrt(m / (k_volume + k_area))`` (half the explicit limit 1 / omega) over the
      node's tets;

    and ``extra_stiffness`` k, the stages' springs on the node, adds k / m to the omega^2 of that
    limit (``dt / safety = 2 / omega``).

    Other profiles: ``safety`` times the damped explicit limit with Gershgorin bounds of the
    node's rest stiffness and damping rows (module doc), the hold spring and ``extra_stiffness``
    included, and the mass-proportional damping rate.

    Args:
        builder: a :class:`~facewarp._src.physics.builder.ModelBuilder`.
        safety: fraction of the limit (as :func:`stable_dt`).
        extra_stiffness: Further springs on each node [N/m] (supports, muscles, contacts: all
            that can act at once, :func:`contact_stiffness_bound`), shape (n,).
    """
    V, T, m = builder.vertices, builder.tets, builder.mass
    n = len(V)
    if builder.material.name != "thesis":
        K, D = _gershgorin_rates(builder)
        if extra_stiffness is not None:
            K = K + np.asarray(extra_stiffness, dtype=np.float64)
        w2 = K / m
        c = D / m + builder.damping_rate
        return safety * (np.sqrt(c * c + 4.0 * w2) - c) / np.maximum(w2, 1e-30)
    E, d0 = builder.edges, builder.edge_rest_lengths
    dmin = np.full(n, np.inf)
    np.minimum.at(dmin, E[:, 0], d0)
    np.minimum.at(dmin, E[:, 1], d0)
    dt = thesis_substep(dmin, m, float(builder.edge_k0.max()), safety=safety)
    h = tet_heights(V, T)
    hmin = np.full(n, np.inf)
    for i in range(4):
        np.minimum.at(hmin, T[:, i], h)
    kf = max(float(builder.tet_k.max() + builder.face_k.max()), 1e-30)
    dt = np.minimum(dt, 0.5 * hmin * np.sqrt(m / kf))
    if extra_stiffness is None:
        return dt
    # the stages' springs on the node add to its omega^2: the tissue rule's limit dt / safety is
    # 2 / omega_t, so omega^2 = (2 safety / dt)^2 + k / m and the step is safety * 2 / omega
    k = np.broadcast_to(np.asarray(extra_stiffness, dtype=np.float64), (n,))
    with np.errstate(divide="ignore"):
        dts = 2.0 * safety / np.sqrt((2.0 * safety / dt) ** 2 + k / m)
    return np.where(k > 0, dts, dt)


def contact_stiffness_bound(geometry, node_stiffness, glide_stiffness=None) -> np.ndarray:
    """The stiffest contact springs each node can carry at once [N/m], shape (n,), float64: what
    the explicit stable step must include (:func:`node_stable_dt` ``extra_stiffness``).

    Per node of :class:`~facewarp._src.physics.contact.ContactStage`'s sets (a node in several
    sums them): a lip node's spring toward the other lip counts twice (its point is on the
    other lip, detected again every substep, whose node the mirror spring pushes back: the two
    sides' relative motion has twice the stiffness), a dental arch's and an eyeball's once, a
    gliding inner lid node's glide spring and its floor once each, a lid margin's spring to the
    fissure plane once (``LID_STIFFNESS_RATIO`` times the node's; the plane does not move) and its
    tie to the partner margin twice (both margins move).

    Args:
        geometry: the :class:`~facewarp._src.physics.contact.ContactGeometry`.
        node_stiffness: each node's contact stiffness [N/m], shape (n,) (a node of a set with 0
            gets its set's median, as the stage does).
        glide_stiffness: the glide springs' stiffness [N/m], shape (n,) (default node_stiffness).
    """
    from .contact import LID_STIFFNESS_RATIO

    g = geometry
    kn = np.asarray(node_stiffness, dtype=np.float64)
    kg = kn if glide_stiffness is None else np.asarray(glide_stiffness, dtype=np.float64)
    out = np.zeros(len(kn))

    def stiff(nodes):
        k = kn[nodes]
        pos = k[k > 0]
        return np.where(k > 0, k, np.median(pos) if len(pos) else 0.0)

    def add(nodes, k):
        nodes = np.asarray(nodes, dtype=np.int64)
        if len(nodes):
            np.add.at(out, nodes, k)

    for nodes in g.lip_nodes:
        add(nodes, 2.0 * stiff(np.asarray(nodes, dtype=np.int64)))
    for t in g.teeth:
        add(t[4], stiff(np.asarray(t[4], dtype=np.int64)))
    eye = np.asarray(g.eye_nodes, dtype=np.int64)
    if len(eye):
        add(eye, stiff(eye))
        glide = np.asarray(g.eye_glide, bool)
        if len(glide) == len(eye) and glide.any():
            add(eye[glide], kg[eye[glide]] + stiff(eye)[glide])
    lid = np.asarray(g.lid_nodes, dtype=np.int64)
    if len(lid):
        add(lid, LID_STIFFNESS_RATIO * stiff(lid) + 2.0 * kg[lid])
    return out


def scale_masses(builder, *, quantile: float = MASS_SCALING_QUANTILE, safety: float = 0.5,
                 extra_stiffness=None) -> tuple[float, float]:
    """Selective mass scaling: choose the Verlet substep and add mass where a node is below it.

    The substep is the ``quantile`` of :func:`node_stable_dt` over the free nodes; a node that
    allows less (a short edge or a flat tet: on adapted heads these sit in sharp creases of the
    lips and nostrils) gets its mass raised by ``(dt / dt_node)^2``, which raises its own limit
    to dt. The change is written into ``builder.mass``; only the inertia of those few nodes
    changes, which the quasi-static expressions (slow muscle activations, damped skin) do not
    feel. ``quantile = 0`` leaves the masses alone and returns the smallest limit.

        builder: a :class:`~facewarp._src.physics.builder.ModelBuilder` (its ``mass`` is updated).
        quantile: fraction of the free nodes that may get extra mass, in [0, 0.5].
        safety: as :func:`stable_dt`.
        extra_stiffness: as :func:`node_stable_dt`.

    Returns:
        ``(dt, added)``: the substep [s] and the added mass as a fraction of the total.
    """
    if not 0.0 <= quantile <= 0.5:
        raise InputError(f"quantile must lie in [0, 0.5], got {quantile}")
    dtn = node_stable_dt(builder, safety=safety, extra_stiffness=extra_stiffness)
    free = ~builder.fixed
    if not free.any():
        return float(dtn.min()), 0.0
    dt = float(np.quantile(dtn[free], quantile)) if quantile > 0 else float(dtn[free].min())
    factor = np.where(free, np.maximum(1.0, (dt / dtn) ** 2), 1.0)
    total = float(builder.mass.sum())
    builder.mass = builder.mass * factor
    return dt, float(builder.mass.sum() / total - 1.0)


def node_spring_stiffness(builder) -> np.ndarray:
    """The springs the added stages put on each node [N/m], shape (vertex_count,), float64:
    supports, muscles and contact candidates (the explicit step's stability bound)."""
    extra = np.zeros(builder.vertex_count)
    np.add.at(extra, builder.support_nodes, np.broadcast_to(builder._support_k, (len(builder.support_nodes),)))
    if builder.muscle_rig is not None:
        np.add.at(extra, builder.muscle_rig.att_node, builder.muscle_rig.att_stiffness)
    if builder.contact_geometry is not None:  # every contact spring a node can carry at once (the lids' too)
        if isinstance(builder.contact_geometry, list):  # N faces: each head's own
            extra += np.concatenate([contact_stiffness_bound(f.contact_geometry, f.contact_stiffness,
                                                             f.glide_stiffness) for f in builder._faces])
        else:
            extra += contact_stiffness_bound(builder.contact_geometry, builder.contact_stiffness,
                                             builder.glide_stiffness)
    return extra


def explicit_step(builder, frame_dt: float, *, dt: float | None = None, substeps: int | None = None,
                  mass_scaling: bool = True) -> tuple[int, float, float]:
    """The Verlet reference's substep: selective mass scaling (the 2 % of nodes with the
    smallest own limit get the mass that lifts them to it; ``builder.mass`` changes), from the
    tissue and every spring a stage may switch on (:func:`node_spring_stiffness`). The thesis
    profile's damping rate is set by :meth:`~.builder.ModelBuilder.add_face` at the reference substep of the tissue,
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
    dt_safe, added = scale_masses(builder, quantile=MASS_SCALING_QUANTILE if mass_scaling else 0.0,
                                  extra_stiffness=node_spring_stiffness(builder))
    if substeps is None:
        substeps = int(np.ceil(frame_dt / (dt or dt_safe)))
    step = frame_dt / int(substeps)
    if step > 2.0 * dt_safe:
        raise InputError(f"substeps {substeps}: dt {step:.2e} s is above twice the stable step "
                         f"{dt_safe:.2e} s; use at least {int(np.ceil(frame_dt / (2 * dt_safe)))} substeps")
    return int(substeps), step, added
