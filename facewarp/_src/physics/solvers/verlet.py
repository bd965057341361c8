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

Stable time step: :mod:`..stability` (:func:`~..stability.stable_dt`, :func:`~..stability.node_stable_dt`,
selective mass scaling), re-exported here.
"""

from __future__ import annotations

import numpy as np

from ...core.warp import get_warp
from .. import kernels_tissue as kt
from ...core.errors import InputError
from ..model import Model
from ..state import Control, State
from ..stability import (DT_STABLE_1CM, MASS_SCALING_QUANTILE, contact_stiffness_bound,  # noqa: F401 (re-exported)
                         node_stable_dt, scale_masses, stable_dt)
from .base import SolverBase, SolverStage, check_step_args  # noqa: F401 (re-exported)

__all__ = ["DT_STABLE_1CM", "MASS_SCALING_QUANTILE", "SolverStage", "SolverVerlet", "check_step_args",
           "contact_stiffness_bound", "node_stable_dt", "scale_masses", "simulate", "stable_dt"]

class SolverVerlet(SolverBase):
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
        super().__init__(model, stages=stages)
        n = model.vertex_count
        self.forces = wp.zeros(n, dtype=wp.vec3, device=self.device)
        self.slots = wp.zeros(model.slot_count, dtype=wp.vec3, device=self.device)
        self.nodes = wp.array(np.arange(n, dtype=np.int32), dtype=wp.int32, device=self.device)

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
            inputs=[m.edge_indices, m.edge_rest_length, m.edge_k0, m.edge_damping, 1.0 / dt,
                    state_in.positions, state_in.prev_positions],
            outputs=[self.slots],
            device=self.device,
        )
        wp.launch(
            kt._face_forces,
            dim=m.face_count,
            inputs=[m.face_indices, m.face_rest_area, m.face_k, m.face_damping, 1.0 / dt, 2 * m.edge_count,
                    state_in.positions, state_in.prev_positions],
            outputs=[self.slots],
            device=self.device,
        )
        wp.launch(
            kt._tet_forces,
            dim=m.tet_count,
            inputs=[m.tet_indices, m.tet_rest_volume, m.tet_k, m.tet_damping, m.tet_rest_inverse, m.tet_shear_k,
                    m.tet_shear_damping, 1.0 / dt, 2 * m.edge_count + 3 * m.face_count, state_in.positions,
                    state_in.prev_positions],
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
        check_step_args(state_in, state_out, dt)
        self._check_devices(state_in, state_out, control)
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
                m.damping_rate,
                dt,
                control.cranium_velocity,
                self.forces,
                self.targets,
                state_in.positions,
                state_in.prev_positions,
            ],
            outputs=[state_out.positions, state_out.prev_positions, self.step_counter],
            device=self.device,
        )
        state_out.assign_stage_data(state_in)  # what the stages carry (muscle geometry, jaw carry)
        self._launch_guard(state_out)


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
        raise InputError(f"substeps must be >= 1, got {substeps}")
    if not (np.isfinite(dt) and dt > 0.0):
        raise InputError(f"dt must be a positive number of seconds, got {dt!r}")
    solver = solver or SolverVerlet(model)
    scratch = model.state()
    device = model.device
    if use_graph is None:
        use_graph = device.is_cuda
    if use_graph and not device.is_cuda:
        raise InputError(f"use_graph needs a CUDA device, the model is on {device}")

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
