"""Frames of substeps with ramped controls: the host side of stepping a Model.

:class:`FrameStepper` owns what a frame needs beyond the Model, the State and the solver: the
pinned host buffer the controls go up through, the control ramp and the CUDA graphs it replays.
"""

from __future__ import annotations

import numpy as np

from ..core.warp import get_warp

__all__ = ["FrameStepper"]


class FrameStepper:
    """Runs substeps of a solver on a State, swapping it with a scratch State, with the controls
    ramped linearly from their old to their new values in up to ``chunks`` pieces.

    Each piece is a run of substeps with no host round trip inside: on CUDA a replayed graph
    (one per substep count; the adaptive device solver's Newton loop is a conditional graph node,
    CUDA 12.4+: without one, the frames run launch by launch). The controls go up through pinned
    host memory, one row per piece, so no piece's values are overwritten before its copy has run.

    Args:
        solver: Anything with ``step(state_in, state_out, control, dt)``.
        state, scratch: The State stepped and its partner (both stay where they are: graphs
            captured on them stay valid).
        control: The :class:`~facewarp._src.physics.model.Control` the solver reads.
        dt: Substep [s].
        chunks: Largest number of ramp pieces per frame.
    """

    def __init__(self, solver, state, scratch, control, dt: float, *, chunks: int = 16):
        wp = get_warp()
        self.solver, self.state, self.scratch, self.control, self.dt = solver, state, scratch, control, float(dt)
        self.device = state.positions.device
        self.chunks = int(chunks)
        self.na = int(control.activations.shape[0])
        self.host = wp.zeros(self.chunks * (self.na + 2), dtype=float, device="cpu", pinned=bool(self.device.is_cuda))
        self.use_graph = bool(self.device.is_cuda) and (
            not getattr(solver, "adaptive", False) or wp.is_conditional_graph_supported())
        self.graphs: dict[int, object] = {}

    def frame(self, n: int, a0, a1, j0, j1) -> None:
        """``n`` substeps with activations ramping from ``a0`` to ``a1`` (M,) and jaw angles from
        ``j0`` to ``j1`` (2,) [rad], float32."""
        wp = get_warp()
        chunks = max(1, min(n, self.chunks))
        bounds = np.linspace(0, n, chunks + 1).round().astype(int)
        host, na = self.host.numpy(), self.na
        for c in range(chunks):
            w, o = (c + 1) / chunks, c * (na + 2)
            host[o:o + na] = (1 - w) * a0 + w * a1
            host[o + na:o + na + 2] = (1 - w) * j0 + w * j1
            if na:
                wp.copy(self.control.activations, self.host, src_offset=o, count=na)
            wp.copy(self.control.jaw_angles, self.host, src_offset=o + na, count=2)
            self.substeps(int(bounds[c + 1] - bounds[c]))

    def substeps(self, n: int) -> None:
        """``n`` substeps with the current control (a replayed graph on CUDA)."""
        wp = get_warp()
        if n <= 0:
            return
        if self.use_graph and n not in self.graphs:
            with wp.ScopedCapture(device=self.device) as cap:
                self._substeps(n)
            self.graphs[n] = cap.graph
        if self.use_graph:
            wp.capture_launch(self.graphs[n])
        else:
            self._substeps(n)

    def _substeps(self, n: int) -> None:
        for s in range(n):
            src, dst = (self.state, self.scratch) if s % 2 == 0 else (self.scratch, self.state)
            self.solver.step(src, dst, self.control, self.dt)
        if n % 2 == 1:
            self.state.assign(self.scratch)
