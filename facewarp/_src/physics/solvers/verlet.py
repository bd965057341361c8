"""Verlet solver of the skin deformation model (thesis Sec. 6.4.2, 6.4.4, Eq. 6.4.10).

``SolverVerlet(model).step(state_in, state_out, control, dt)`` advances one substep. It
allocates nothing and never reads back to the host, so a frame of substeps can be recorded
once with ``wp.ScopedCapture`` and replayed (:func:`simulate` does this on CUDA).

One substep:

1. ``forces = control.external_force``;
2. each :class:`SolverStage` (muscles, Eq. 6.4.1; jaw, Eq. 6.4.9 — later stages) accumulates
   its forces into ``solver.forces`` and may move kinematic ``solver.targets``;
3. distance, area and volume forces (Eq. 6.4.4-6.4.8) are accumulated;
4. damped Verlet (Eq. 6.4.10) writes ``state_out``; fixed nodes sit on their target, held
   nodes feel a spring to it;
5. a guard kernel records the first substep and tet with a NaN position or an inverted tet;
   :meth:`SolverVerlet.check` (host side, between frames) raises :class:`SimulationError`.

Stable time step
----------------
An edge of rest length D0 acts like a spring of stiffness k0 / D0^2 on a node of mass m, so
the explicit step must stay below about 2 / omega with omega^2 ~ (sum of the node's element
stiffnesses) / m, and the limit scales with D0. With the Table 6.3 defaults (SI model units,
see :mod:`facewarp._src.model`) the measured limit for tets with 1 cm edges is
:data:`DT_STABLE_1CM` (0.6 ms; 1.04 ms is the linear limit at rest); :func:`stable_dt`
scales a safe step (by default half of it: 0.3 ms for 1 cm edges) with the shortest edge, the
lightest node and the stiffest k0.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ...core.warp import get_warp
from .. import kernels_tissue as kt
from ...core.errors import SimulationError
from ...geometry.tets import tet_heights
from ..model import Control, Model, State

__all__ = ["DT_STABLE_1CM", "MASS_SCALING_QUANTILE", "SolverStage", "SolverVerlet", "node_stable_dt", "scale_masses",
           "simulate", "stable_dt"]

DT_STABLE_1CM = 0.6e-3
"""Largest step [s] found stable for a 1 cm tet with the Table 6.3 defaults: one regular
tet (all-outer or mixed layers) and a 3 x 3 x 1 slab of 1 cm Kuhn cubes, from random starts
with strains up to ~10 %, run for 1-2 s (all 20 / 5 starts bounded; at 0.8 ms a quarter to
most of the 10 %-strain starts of the mixed-layer tet invert). The linear limit 2 / omega_max
of the regular tet at rest is 1.04 ms (omega_max^2 = 3.7e6 s^-2); the stiffening of
Eq. 6.4.6 at large strain lowers it. See ``tests/test_solver.py::test_stable_dt_one_centimetre_tet``."""


def stable_dt(model_or_builder, *, safety: float = 0.5) -> float:
    """A safe substep [s] for a mesh: ``safety * DT_STABLE_1CM * (shortest edge / 1 cm)``,
    scaled by ``sqrt(lightest node mass / 0.5 kg)`` and ``sqrt(15 J / largest k0)``.

    Assumes the Table 6.3 proportions of k_area and k_volume to k0 and hold springs no
    stiffer than the default; check larger steps with :meth:`SolverVerlet.check`.

    Args:
        model_or_builder: a :class:`~facewarp._src.model.ModelBuilder` (numpy, preferred) or
            a :class:`Model` (reads its arrays back to the host once).
        safety: fraction of the measured single-tet limit, default 0.5.
    """
    if isinstance(model_or_builder, Model):
        d0 = model_or_builder.edge_rest_length.numpy()
        mass = model_or_builder.vertex_mass.numpy()
        k0 = model_or_builder.edge_k0.numpy()
    else:
        d0 = model_or_builder.edge_rest_lengths
        mass = model_or_builder.mass
        k0 = model_or_builder.edge_k0
    return float(_edge_dt(d0.min(), mass.min(), float(k0.max()), safety))


def _edge_dt(d0, mass, k0_max: float, safety: float):
    """The edge rule of :func:`stable_dt`: ``safety * DT_STABLE_1CM`` scaled by edge length,
    node mass and the stiffest k0 (scalars or arrays)."""
    k = max(k0_max, 1e-30)
    return safety * DT_STABLE_1CM * (d0 / 0.01) * np.sqrt(mass / 0.5) * np.sqrt(15.0 / k)


MASS_SCALING_QUANTILE = 0.02
"""Fraction of nodes whose own stable step may lie below the chosen substep; those nodes get
the extra mass that brings them up to it (:func:`scale_masses`)."""


def node_stable_dt(builder, *, safety: float = 0.5) -> np.ndarray:
    """The stable step [s] each node allows, shape (n,), float64.

    Two limits per node, the smaller wins:

    * edges: :func:`stable_dt`'s rule with the node's shortest incident edge and its own mass
      (an edge of rest length D0 is a spring k0 / D0^2);
    * flat tets: the volume and area energies of Eq. 6.4.7-6.4.8 have a stiffness of about
      (k_volume + k_area) / h^2 on a tet of height h (its volume over its largest face), so
      ``dt <= 0.5 h sqrt(m / (k_volume + k_area))`` (half the explicit limit 1 / omega) over the
      node's tets.

    Args:
        builder: a :class:`~facewarp._src.model.ModelBuilder`.
        safety: fraction of the measured single-tet limit (as :func:`stable_dt`).
    """
    V, T, m = builder.vertices, builder.tets, builder.mass
    n = len(V)
    E, d0 = builder.edges, builder.edge_rest_lengths
    dmin = np.full(n, np.inf)
    np.minimum.at(dmin, E[:, 0], d0)
    np.minimum.at(dmin, E[:, 1], d0)
    dt = _edge_dt(dmin, m, float(builder.edge_k0.max()), safety)
    h = tet_heights(V, T)
    hmin = np.full(n, np.inf)
    for i in range(4):
        np.minimum.at(hmin, T[:, i], h)
    kf = max(builder.k_volume + builder.k_area, 1e-30)
    return np.minimum(dt, 0.5 * hmin * np.sqrt(m / kf))


def scale_masses(builder, *, quantile: float = MASS_SCALING_QUANTILE, safety: float = 0.5) -> tuple[float, float]:
    """Selective mass scaling: choose the substep and add mass where a node is below it.

    The substep is the ``quantile`` of :func:`node_stable_dt` over the free nodes; a node that
    allows less (a short edge or a flat tet: on adapted heads these sit in sharp creases of the
    lips and nostrils) gets its mass raised by ``(dt / dt_node)^2``, which raises its own limit
    to dt. The change is written into ``builder.mass``; only the inertia of those few nodes
    changes, which the quasi-static expressions (slow muscle activations, damped skin) do not
    feel. ``quantile = 0`` leaves the masses alone and returns the smallest limit.

    Args:
        builder: a :class:`~facewarp._src.model.ModelBuilder` (its ``mass`` is updated).
        quantile: fraction of the free nodes that may get extra mass, in [0, 0.5].
        safety: as :func:`stable_dt`.

    Returns:
        ``(dt, added)``: the substep [s] and the added mass as a fraction of the total.
    """
    if not 0.0 <= quantile <= 0.5:
        raise ValueError(f"quantile must lie in [0, 0.5], got {quantile}")
    dtn = node_stable_dt(builder, safety=safety)
    free = ~builder.fixed
    if not free.any():
        return float(dtn.min()), 0.0
    dt = float(np.quantile(dtn[free], quantile)) if quantile > 0 else float(dtn[free].min())
    factor = np.where(free, np.maximum(1.0, (dt / dtn) ** 2), 1.0)
    total = float(builder.mass.sum())
    builder.mass = builder.mass * factor
    return dt, float(builder.mass.sum() / total - 1.0)


class SolverStage(Protocol):
    """A stage that adds external forces or moves kinematic targets each substep.

    Muscles (Eq. 6.4.1) accumulate spring forces into ``forces``; the jaw (Eq. 6.4.9) writes
    the targets of the nodes it carries (fixed nodes are placed on their target, held nodes
    are pulled to it), and its carry stage moves the free jaw-region nodes kinematically, in
    place in ``state_in`` (both position buffers, before any force is computed). ``apply`` may
    only launch kernels: no allocation, no host read.
    """

    def apply(
        self,
        model: Model,
        state_in: State,
        control: Control,
        dt: float,
        forces: object,
        targets: object,
    ) -> None:
        """Launch kernels for one substep.

        Args:
            model: the tissue model.
            state_in: positions at t and t - dt (read only, except a kinematic carry).
            control: activations, jaw angles (read only).
            dt: substep [s].
            forces: forces [N] to accumulate into (wp.atomic_add), shape (vertex_count,),
                wp.vec3; holds ``control.external_force`` when the stage is called.
            targets: target positions [m] of fixed / held nodes, shape (vertex_count,),
                wp.vec3; persistent between substeps, rest positions initially.
        """
        ...


class SolverVerlet:
    """Damped Verlet integration of the tissue model (Eq. 6.4.10) on ``model.device``.

    Args:
        model: the tissue :class:`Model`.
        stages: :class:`SolverStage` objects applied, in order, at the start of each substep.

    Attributes:
        forces: Per-node force [N] of the current substep, shape (vertex_count,), wp.vec3.
        targets: Target position [m] of fixed / held nodes, shape (vertex_count,), wp.vec3.
        step_counter: Substeps taken, on the device, shape (1,), int32.
        guard: First failing substep and code ``2 tet + (0 NaN, 1 inverted)``, shape (2,),
            int32; both int32 max while nothing failed.
    """

    def __init__(self, model: Model, *, stages=()):
        wp = get_warp()
        self.model = model
        self.device = model.device
        self.stages = list(stages)
        n = model.vertex_count
        self.forces = wp.zeros(n, dtype=wp.vec3, device=self.device)
        self.slots = wp.zeros(model.slot_count, dtype=wp.vec3, device=self.device)
        self.nodes = wp.array(np.arange(n, dtype=np.int32), dtype=wp.int32, device=self.device)
        self.targets = wp.clone(model.rest_positions)
        self.step_counter = wp.zeros(1, dtype=wp.int32, device=self.device)
        self.guard = wp.array([kt.GUARD_NONE, kt.GUARD_NONE], dtype=wp.int32, device=self.device)

    # ------------------------------------------------------------------------------------
    # device work (no allocation, no host read)

    def compute_forces(self, state_in: State, control: Control, dt: float):
        """Total force [N] on each node at ``state_in`` (external, stages, Eq. 6.4.4-6.4.8),
        written into and returned as :attr:`forces`. Hold springs are added by the
        integrator, not here."""
        wp = get_warp()
        m = self.model
        wp.launch(
            kt._init_forces,
            dim=m.vertex_count,
            inputs=[control.external_force],
            outputs=[self.forces],
            device=self.device,
        )
        for stage in self.stages:
            stage.apply(m, state_in, control, dt, self.forces, self.targets)
        wp.launch(
            kt._edge_forces,
            dim=m.edge_count,
            inputs=[
                m.edge_indices,
                m.edge_rest_length,
                m.edge_k0,
                m.edge_damping,
                1.0 / dt,
                state_in.positions,
                state_in.prev_positions,
            ],
            outputs=[self.slots],
            device=self.device,
        )
        # area / volume slots stay zero (as allocated) when their stiffness is 0
        if m.k_area > 0.0:
            wp.launch(
                kt._face_forces,
                dim=m.face_count,
                inputs=[m.face_indices, m.face_rest_area, m.k_area, 2 * m.edge_count, state_in.positions],
                outputs=[self.slots],
                device=self.device,
            )
        if m.k_volume > 0.0:
            wp.launch(
                kt._tet_forces,
                dim=m.tet_count,
                inputs=[m.tet_indices, m.tet_rest_volume, m.k_volume, 2 * m.edge_count + 3 * m.face_count,
                        state_in.positions],
                outputs=[self.slots],
                device=self.device,
            )
        wp.launch(kt._gather, dim=m.vertex_count, inputs=[self.nodes, m.node_slot_start, m.node_slots, self.slots],
                  outputs=[self.forces], device=self.device)
        return self.forces

    def step(self, state_in: State, state_out: State, control: Control, dt: float) -> None:
        """Advance one substep of ``dt`` [s] from ``state_in`` into ``state_out``.

        ``state_in`` and ``state_out`` must be different buffers. Allocates nothing and does
        not synchronise, so it can be captured in a CUDA graph.
        """
        if state_in.positions.ptr == state_out.positions.ptr:
            raise ValueError("state_in and state_out must be different State buffers")
        wp = get_warp()
        m = self.model
        self.compute_forces(state_in, control, dt)
        wp.launch(
            kt._integrate_verlet,
            dim=m.vertex_count,
            inputs=[
                m.vertex_inv_mass,
                m.vertex_fixed,
                m.vertex_hold_stiffness,
                m.damping,
                dt,
                self.forces,
                self.targets,
                state_in.positions,
                state_in.prev_positions,
            ],
            outputs=[state_out.positions, state_out.prev_positions, self.step_counter],
            device=self.device,
        )
        wp.launch(
            kt._check_tets,
            dim=m.tet_count,
            inputs=[m.tet_indices, self.step_counter, state_out.positions],
            outputs=[self.guard],
            device=self.device,
        )

    # ------------------------------------------------------------------------------------
    # host side

    @property
    def step_count(self) -> int:
        """Substeps taken so far (reads the device counter back)."""
        return int(self.step_counter.numpy()[0])

    def reset(self) -> None:
        """Back to the rest pose: targets at rest, step counter 0, guard cleared (no allocation)."""
        self.targets.assign(self.model.rest_positions)
        self.step_counter.zero_()
        self.reset_guard()

    def reset_guard(self) -> None:
        """Forget a recorded failure (host side)."""
        self.guard.assign(np.array([kt.GUARD_NONE, kt.GUARD_NONE], dtype=np.int32))

    def check(self, state: State | None = None) -> None:
        """Raise :class:`SimulationError` if a substep produced a NaN or an inverted tet.

        Host side (reads the guard back): call it between frames, not inside ``step``.

        Args:
            state: the current state, used to name the offending vertex of a NaN tet and
                the current volume of an inverted one (optional).

        Raises:
            SimulationError: naming the first failing substep and tet (and vertex).
        """
        step, code = (int(v) for v in self.guard.numpy())
        if step == kt.GUARD_NONE:
            return
        tet, kind = divmod(code, 2)
        idx = self.model.tet_indices.numpy()[tet].tolist()
        where = f"simulation failed at step {step}: tet {tet} (vertices {idx})"
        if kind == 0:
            msg = f"{where} has a non-finite (NaN/inf) node position"
            if state is not None:
                x = state.positions.numpy()[idx]
                bad = [v for v, row in zip(idx, x) if not np.all(np.isfinite(row))]
                if bad:
                    msg += f" (now non-finite: vertices {bad})"
        else:
            v0 = float(self.model.tet_rest_volume.numpy()[tet])
            msg = f"{where} is inverted (signed volume <= 0, rest volume {v0:.3g} m^3)"
        raise SimulationError(msg + "; reduce dt (see solver.stable_dt) or raise damping")


def simulate(
    model: Model,
    state: State,
    control: Control,
    dt: float,
    substeps: int,
    *,
    frames: int = 1,
    solver: SolverVerlet | None = None,
    use_graph: bool | None = None,
    check: bool = True,
) -> State:
    """Run ``frames`` frames of ``substeps`` Verlet substeps of ``dt`` [s], in place.

    On CUDA (``use_graph`` None or True) one frame of substeps is recorded once with
    ``wp.ScopedCapture`` and replayed for every frame; on CPU the substeps are launched
    directly. ``state`` holds the result after every frame (an odd substep count ends with a
    copy from the scratch buffer, inside the frame).

    Args:
        model: the tissue model.
        state: the state to advance (updated in place and returned).
        control: activations, jaw angles, external force.
        dt: substep [s].
        substeps: substeps per frame, >= 1.
        frames: frames to run, default 1.
        solver: a solver to reuse (its stages, targets and guard); default a new one.
        use_graph: record a CUDA graph; default: when the device is CUDA.
        check: call :meth:`SolverVerlet.check` after every frame (a host sync).

    Raises:
        SimulationError: if ``check`` and a substep produced a NaN or an inverted tet.
    """
    wp = get_warp()
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    if dt <= 0.0:
        raise ValueError(f"dt must be > 0, got {dt}")
    solver = solver or SolverVerlet(model)
    scratch = model.state()
    device = model.device
    if use_graph is None:
        use_graph = device.is_cuda
    if use_graph and not device.is_cuda:
        raise ValueError(f"use_graph needs a CUDA device, the model is on {device}")

    def frame():
        for s in range(substeps):
            src, dst = (state, scratch) if s % 2 == 0 else (scratch, state)
            solver.step(src, dst, control, dt)
        if substeps % 2 == 1:
            state.assign(scratch)

    graph = None
    if use_graph:
        with wp.ScopedCapture(device=device) as capture:
            frame()
        graph = capture.graph
    for _ in range(frames):
        if graph is not None:
            wp.capture_launch(graph)
        else:
            frame()
        if check:
            solver.check(state)
    return state
