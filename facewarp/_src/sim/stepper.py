"""Frames of substeps with ramped controls: the host side of stepping a Model.

:class:`FrameStepper` owns what a frame needs beyond the Model, the State and the solver: the
pinned host buffer the controls go up through, the control ramp and the CUDA graphs it replays.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..core.warp import get_warp

__all__ = ["SOLVERS", "FrameStepper", "build_face", "face_stages"]

SOLVERS = ("implicit", "verlet")
"""Solvers of :class:`FaceSimulator`: ``implicit`` (backward Euler, a few steps per frame; the
default) and ``verlet`` (the explicit reference, hundreds of substeps per frame)."""


def face_stages(model) -> dict:
    """The kernel groups of a face Model, in step order: ``carry``, ``jaw``, ``support``,
    ``muscles`` (Eq. 6.4.9, supports, Eq. 6.4.1) and ``contact`` (None without it); each keeps
    references to the arrays the Model's ``finalize`` made."""
    from ..coupling.kinematic import CarryStage, JawStage
    from ..physics.contact import ContactStage
    from ..physics.muscle_stage import MuscleStage, SupportStage

    return {"carry": CarryStage.from_model(model), "jaw": JawStage.from_model(model),
            "support": SupportStage.from_model(model), "muscles": MuscleStage.from_model(model),
            "contact": ContactStage.from_model(model) if model.contact is not None else None}


def build_face(fr, *, device, solver: str, material, fps: float, dt=None, substeps=None, iterations=None,
               tolerance=None, method=None, solver_options=None, support_stiffness=None, edge_damping=None,
               mass_scaling: bool = True, contact: bool = True, contact_modulus=None, builder=None) -> dict:
    """A face rig made into a simulation, one way down (the arguments checked by the simulator first): one
    :class:`~facewarp._src.physics.builder.ModelBuilder` (``add_face``: every stiffness), its
    ``finalize`` (every device array of what is simulated, the rest State and the Control), the
    stages (:func:`face_stages`: kernel groups on the Model's arrays) and the solver (the Verlet
    reference, or the implicit solver of ``method`` (:func:`~facewarp._src.physics.solvers.select.select_solver`) with
    ``tolerance`` default 3e-5 m and ``solver_options`` its further keywords). The arguments are
    :class:`~facewarp.FaceSimulator`'s.

    Frame timing: the implicit solver one step per frame (or ``substeps``, or as many as ``dt``
    needs), the Verlet reference its stable step
    (:meth:`~facewarp._src.physics.builder.ModelBuilder.explicit_step`, which may scale masses).

    ``builder``: a :class:`~facewarp._src.physics.builder.ModelBuilder` already made by ``add_face``
    of ``fr`` with these arguments, shared (read only) by the heads of a
    :class:`~facewarp.FaceBatch` that play one rig (the implicit solver only: the Verlet
    reference scales the builder's masses); default a new one.

    Returns:
        A dict: ``material``, ``builder``, ``model``, ``substeps``, ``dt`` [s],
        ``added_mass_fraction``, ``control``, ``rest_state``, ``state``, ``scratch``, ``stages``
        (:func:`face_stages`'s dict) and ``solver``.

    Raises:
        InputError: an unknown solver, material or method, or bad numbers.
    """
    from ..physics.materials import material_profile
    from ..physics.builder import ModelBuilder
    from ..physics.solvers.select import select_solver

    mat = material_profile(material)
    if builder is None or solver == "verlet":
        builder = ModelBuilder()
        builder.add_face(fr, material=mat, edge_damping=edge_damping, support_stiffness=support_stiffness,
                         contact=contact, contact_modulus=contact_modulus, mass_scaling=mass_scaling)
    frame_dt = 1.0 / fps
    if solver == "verlet":
        n, step, added = builder.explicit_step(frame_dt, dt=dt, substeps=substeps, mass_scaling=mass_scaling)
    else:
        n = int(substeps if substeps is not None else 1 if dt is None else np.ceil(frame_dt / dt))
        step, added = frame_dt / n, 0.0
    model = builder.finalize(device)
    out = {"material": mat, "builder": builder, "model": model, "substeps": n, "dt": step,
           "added_mass_fraction": added, "control": model.control(), "rest_state": model.state(),
           "state": model.state(), "scratch": model.state()}
    stages = out["stages"] = face_stages(model)
    listed = []
    for st in stages.values():
        if st is not None:
            listed.append(st)
    if solver == "verlet":
        out["solver"] = select_solver(model, solver="verlet", stages=listed)
    else:
        opts = {"tolerance": 3e-5 if tolerance is None else tolerance, **(solver_options or {})}
        out["solver"] = select_solver(model, stages=listed, method=method, iterations=iterations, **opts)
    return out


class FrameStepper:
    """Runs substeps of a solver on a State, swapping it with a scratch State, with the controls
    ramped linearly from their old to their new values in up to ``chunks`` pieces.

    Each piece is a run of substeps with no host round trip inside: on CUDA a replayed graph
    (one per substep count and substep length; the adaptive device solver's Newton loop is a conditional graph node,
    CUDA 12.4+: without one, the frames run launch by launch). The controls go up through pinned
    host memory, one row per piece, so no piece's values are overwritten before its copy has run.

    Args:
        solver: Anything with ``step(state_in, state_out, control, dt)``.
        state, scratch: The State stepped and its partner (both stay where they are: graphs
            captured on them stay valid).
        control: The :class:`~facewarp._src.physics.state.Control` the solver reads.
        dt: Substep [s].
        chunks: Largest number of ramp pieces per frame.
    """

    def __init__(self, solver, state, scratch, control, dt: float, *, chunks: int = 16):
        wp = get_warp()
        self.solver, self.state, self.scratch, self.control, self.dt = solver, state, scratch, control, float(dt)
        self.device = state.positions.device
        self.chunks = int(chunks)
        self.na = int(control.activations.shape[0])
        self.nj = int(control.jaw_angles.shape[0])  # 2 per head
        self.host = wp.zeros(self.chunks * (self.na + self.nj), dtype=float, device="cpu",
                             pinned=bool(self.device.is_cuda))
        self.use_graph = bool(self.device.is_cuda) and (
            not getattr(solver, "adaptive", False) or wp.is_conditional_graph_supported())
        self.graphs: dict[tuple, object] = {}

    def frame(self, n: int, a0, a1, j0, j1, h: float | None = None) -> None:
        """``n`` substeps of ``h`` [s] (default :attr:`dt`; the rollback's retries take shorter
        ones) with activations ramping from ``a0`` to ``a1`` (M,) and jaw angles from ``j0`` to
        ``j1`` (2,) [rad] (a Model of N heads: (N * M,) and (2 N,), head after head), float32."""
        wp = get_warp()
        chunks = max(1, min(n, self.chunks))
        bounds = np.linspace(0, n, chunks + 1).round().astype(int)
        host, na, nj = self.host.numpy(), self.na, self.nj
        for c in range(chunks):
            w, o = (c + 1) / chunks, c * (na + nj)
            host[o:o + na] = (1 - w) * a0 + w * a1
            host[o + na:o + na + nj] = (1 - w) * j0 + w * j1
            if na:
                wp.copy(self.control.activations, self.host, src_offset=o, count=na)
            wp.copy(self.control.jaw_angles, self.host, src_offset=o + na, count=nj)
            self.substeps(int(bounds[c + 1] - bounds[c]), h)

    def substeps(self, n: int, h: float | None = None) -> None:
        """``n`` substeps of ``h`` [s] (default :attr:`dt`) with the current control (a replayed
        graph on CUDA, one per ``(n, h)``)."""
        wp = get_warp()
        if n <= 0:
            return
        h = self.dt if h is None else float(h)
        key = (n, h)
        if self.use_graph and key not in self.graphs:
            with wp.ScopedCapture(device=self.device) as cap:
                self._substeps(n, h)
            self.graphs[key] = cap.graph
        if self.use_graph:
            wp.capture_launch(self.graphs[key])
        else:
            self._substeps(n, h)

    def _substeps(self, n: int, h: float) -> None:
        for s in range(n):
            src, dst = (self.state, self.scratch) if s % 2 == 0 else (self.scratch, self.state)
            self.solver.step(src, dst, self.control, h)
        if n % 2 == 1:
            self.state.assign(self.scratch)
