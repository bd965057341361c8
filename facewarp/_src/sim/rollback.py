"""Frames that always finish: sub-stepping with rollback, and the volume floor.

:meth:`FaceSimulator.step` runs each frame through :func:`step_frame`: the state before the frame
is kept (every array of the State: node positions, previous positions, muscle control points, the
jaw carry's angles; the solver's targets, step counter and guard, and the L-BFGS solver's host
state), the frame is taken (:meth:`.stepper.FrameStepper.frame`), and it
is *checked*: no NaN and no inverted tet (the solver's guard), every tet above
:data:`~facewarp.physics.VOLUME_FLOOR` (2 %) of its rest volume, and, for the CPU methods of the
implicit solver, a last solve that converged. A frame that fails the check is rolled back and
taken again as 2, 4, ... up to ``2 ** FaceSimulator.max_refinement`` times its substeps, the
controls ramped linearly across them; only a frame that still fails at the bound raises
:class:`~facewarp.SimulationError` (with NaN or an inverted tet) — one that only stays below the
volume floor or short of convergence is kept and counted. A frame that passes the check first
time is exactly the frame of the plain solver: preset results do not change.

:class:`FrameStats` counts what happened (``FaceSimulator.stats``; the ``simulate`` and ``demo``
reports carry it).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from ..core.errors import SimulationError
from ..core.warp import get_warp
from ..physics.volume_barrier import VOLUME_FLOOR

__all__ = ["FrameGuard", "FrameStats", "step_frame"]

MAX_REFINEMENT = 6
"""Default bound of the retries: a failing frame is taken again with up to 2^6 = 64 times its substeps."""

# host-side state of the implicit solver's CPU methods that a failed frame must not keep
_SOLVER_HOST_STATE = ("_history", "_excess", "_solve0", "_h", "_contacts_factored", "_last_step_size",
                      "_host_total", "last_iterations")


@dataclass
class FrameStats:
    """What the frame guard saw since the last reset.

    Attributes:
        frames: Frames taken.
        substepped_frames: Frames rolled back and taken again with more substeps.
        retries: Retries in all (a frame may need several).
        max_substep_factor: The largest factor of extra substeps a frame needed (1: none).
        frames_below_floor: Frames that ended with a tet below :data:`VOLUME_FLOOR` even at the
            retry bound (kept, not failed).
        unconverged_frames: Frames whose last solve did not converge even at the retry bound.
        min_volume_ratio: The smallest V / V0 of any tet at the end of any frame.
        events: The first retries, as text (at most 20).
    """

    frames: int = 0
    substepped_frames: int = 0
    retries: int = 0
    max_substep_factor: int = 1
    frames_below_floor: int = 0
    unconverged_frames: int = 0
    min_volume_ratio: float = 1.0
    events: list = None

    def __post_init__(self):
        if self.events is None:
            self.events = []

    def as_dict(self) -> dict:
        """The stats as plain JSON-able values."""
        d = asdict(self)
        d["volume_floor"] = VOLUME_FLOOR
        return d


class FrameGuard:
    """The saved state of a frame's start and the frame's checks, for one simulator (no
    allocation per frame)."""

    def __init__(self, sim):
        wp = get_warp()
        self.sim = sim
        dev = sim.device
        self._arrays = [v for v in vars(sim.state).values() if isinstance(v, wp.array)]
        self._arrays += [sim.solver.targets, sim.solver.step_counter, sim.solver.guard]
        self._saved = [wp.empty_like(a) for a in self._arrays]
        self._ratio = wp.zeros(1, dtype=float, device=dev)
        self._ratio_host = wp.zeros(1, dtype=float, device="cpu", pinned=bool(dev.is_cuda))
        self._host_state = None

    def save(self) -> None:
        """Keep the state at the frame's start."""
        wp = get_warp()
        for a, s in zip(self._arrays, self._saved):
            wp.copy(s, a)
        solver = self.sim.solver
        self._host_state = {k: _copy_host(getattr(solver, k)) for k in _SOLVER_HOST_STATE if hasattr(solver, k)}

    def restore(self) -> None:
        """Go back to the saved frame start."""
        wp = get_warp()
        for a, s in zip(self._arrays, self._saved):
            wp.copy(a, s)
        solver = self.sim.solver
        for k, v in (self._host_state or {}).items():
            setattr(solver, k, _copy_host(v))

    def min_volume_ratio(self) -> float:
        """The smallest V / V0 over the tets of the current state (a host read)."""
        wp = get_warp()
        from . import kernels_rollback as kr

        m = self.sim.model
        self._ratio.fill_(3.0e38)
        wp.launch(kr._min_volume_ratio, dim=m.tet_count,
                  inputs=[m.tet_indices, m.tet_rest_volume, self.sim.state.positions], outputs=[self._ratio],
                  device=m.device)
        wp.copy(self._ratio_host, self._ratio)
        if m.device.is_cuda:
            wp.synchronize_stream(wp.get_stream(m.device))
        return float(self._ratio_host.numpy()[0])


def _copy_host(v):
    if isinstance(v, tuple):
        return tuple(_copy_host(x) for x in v)
    if isinstance(v, list):
        return list(v)
    return v


def step_frame(sim, n: int, a0, a1, j0, j1) -> None:
    """Take one frame of ``n`` substeps of ``sim.dt`` with rollback (the module doc).

    Args:
        sim: The :class:`~facewarp.FaceSimulator` (its ``frame_guard``, ``stats``, ``solver``,
            ``stepper``, ``max_refinement``).
        n: Substeps of the frame.
        a0, a1, j0, j1: The activations (M,) and jaw angles (2,) [rad] at the frame's start and
            end, float32 (ramped across the substeps, :meth:`.stepper.FrameStepper.frame`).

    Raises:
        SimulationError: a NaN or an inverted tet even with ``2 ** max_refinement`` times the substeps.
    """
    guard, stats, solver = sim.frame_guard, sim.stats, sim.solver
    guard.save()
    bound = int(sim.max_refinement)
    for level in range(bound + 1):
        factor = 2 ** level
        problem = None
        try:
            sim.stepper.frame(n * factor, a0, a1, j0, j1, sim.dt / factor)
            solver.check(sim.state)
        except SimulationError as e:
            problem = str(e)
        ratio = None
        if problem is None:
            ratio = guard.min_volume_ratio()
            if not ratio > -1.0e29:  # the volume kernel's mark of a non-finite position
                problem = "a NaN or non-finite node position"
            elif not ratio >= VOLUME_FLOOR:
                problem = f"a tet at {ratio:.3g} of its rest volume (floor {VOLUME_FLOOR:g})"
            elif not getattr(solver, "last_converged", True):
                problem = "the step's solve did not converge"
        if problem is None or (level == bound and ratio is not None and ratio > 0.0):
            if problem is not None:  # kept at the bound: below the floor or not converged, reported
                if ratio < VOLUME_FLOOR:
                    stats.frames_below_floor += 1
                else:
                    stats.unconverged_frames += 1
            stats.frames += 1
            stats.min_volume_ratio = min(stats.min_volume_ratio, ratio)
            if level > 0:
                stats.substepped_frames += 1
                stats.max_substep_factor = max(stats.max_substep_factor, factor)
            return
        if level == bound:
            guard.restore()
            raise SimulationError(
                f"frame at t = {sim.time + n * sim.dt:.4g} s failed even as {n * factor} substeps "
                f"({factor} times {n}): {problem}")
        stats.retries += 1
        if len(stats.events) < 20:
            stats.events.append(f"t = {sim.time + n * sim.dt:.4g} s: {problem}; retried as {n * factor * 2} substeps")
        guard.restore()
        solver.reset_guard()
