"""What a step changes (:class:`State`) and what drives it (:class:`Control`); made by
:meth:`~.model.Model.state` and :meth:`~.model.Model.control`."""

from __future__ import annotations

from dataclasses import dataclass

from ..core.warp import get_warp

__all__ = ["Control", "State"]


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

