"""What every solver of the skin model shares: the stage protocol, the step contract's checks, the
kinematic targets and the NaN / inversion guard.

Contract: ``solver.step(state_in, state_out, control, dt)`` advances one step of ``dt`` [s] from
``state_in`` into ``state_out`` (different buffers). Each step the solver first lets its stages
(muscles, Eq. 6.4.1; jaw, Eq. 6.4.9; supports) act, then moves the free nodes; fixed nodes sit on
:attr:`SolverBase.targets`, held nodes are pulled to them. A guard kernel records the first step
and tet with a NaN position or an inverted tet; :meth:`SolverBase.check` (host side, between
frames) raises :class:`~facewarp.SimulationError`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ...core.errors import InputError, SimulationError
from ...core.warp import get_warp
from .. import kernels_tissue as kt
from ..model import Model
from ..state import Control, State

wp = get_warp()  # the kernels of this package import Warp already

__all__ = ["SolverBase", "SolverStage", "check_device", "check_model_devices", "check_stage_devices", "check_step_args",
           "stage_springs"]


def check_step_args(state_in: State, state_out: State, dt) -> None:
    """The checks every solver's ``step`` makes on the host (no device work).

    Raises:
        InputError: ``dt`` not a positive finite number, or ``state_in`` and ``state_out``
            the same buffers.
    """
    if isinstance(dt, bool) or not (isinstance(dt, (int, float, np.floating)) and np.isfinite(dt) and dt > 0.0):
        raise InputError(f"dt must be a positive number of seconds, got {dt!r}")
    if state_in.positions.ptr == state_out.positions.ptr:
        raise InputError("state_in and state_out must be different State buffers")


def check_device(value, device, name: str) -> None:
    """Raise :class:`InputError` if ``value`` is a Warp array on another device than ``device``
    (a CPU kernel handed a CUDA pointer, or the other way round, crashes the process).

    Args:
        value: Anything; only Warp arrays are checked.
        device: The model's device.
        name: What to name in the message (e.g. ``"stages: MuscleStage.att_node"``).
    """
    if isinstance(value, wp.array) and str(value.device) != str(device):
        raise InputError(f"{name}: a Warp array on {value.device}, but the model is on {device}; "
                         "make it with device=model.device")


def _check_fields(obj, device, name: str) -> None:
    """Every Warp array among ``obj``'s attributes on ``device`` (one level; host side)."""
    for attr, v in vars(obj).items():
        check_device(v, device, f"{name}.{attr}")


def check_model_devices(model: Model) -> None:
    """The device arrays :meth:`~facewarp._src.physics.builder.ModelBuilder.finalize` made for the
    model's parts (``MuscleArrays``, ``SupportArrays``, ``JawNodeArrays``, ``ContactArrays``) on
    the model's device; an :class:`InputError` naming the part and field otherwise."""
    for part, fields in (("muscles", ("arrays",)), ("supports", ("arrays",)), ("contact", ("arrays",)),
                         ("jaw", ("target_arrays", "carry_arrays"))):
        sub = getattr(model, part, None)
        for f in fields:
            arrays = getattr(sub, f, None) if sub is not None else None
            if arrays is not None:
                _check_fields(arrays, model.device, f"model.{part}.{f}")


def check_stage_devices(stages, device) -> None:
    """Every Warp array a stage holds (its attributes, the model's arrays it binds included) and
    every array of its ``Springs`` on ``device``; an :class:`InputError` naming the stage and field
    otherwise."""
    for st in stages:
        _check_fields(st, device, f"stages: {type(st).__name__}")
        for i, s_ in enumerate(stage_springs([st])):
            for field in ("node", "point", "stiffness", "rest_length", "axis"):
                check_device(getattr(s_, field, None), device, f"stages: {type(st).__name__}.springs[{i}].{field}")


def stage_springs(stages) -> list:
    """The :class:`~facewarp._src.physics.springs.Springs` of ``stages``, in stage order: a stage's
    ``springs`` attribute is None, one ``Springs`` or a tuple / list of them (a contact stage has
    one set per obstacle kind)."""
    out = []
    for st in stages:
        sp = getattr(st, "springs", None)
        if sp is None:
            continue
        out.extend(sp if isinstance(sp, (list, tuple)) else [sp])
    return out


class SolverStage(Protocol):
    """A stage that adds forces, springs or kinematic targets each step.

    Explicit solvers (:class:`~.verlet.SolverVerlet`) call :meth:`apply` every substep: muscles
    (Eq. 6.4.1) and supports accumulate spring forces into ``forces``; the jaw (Eq. 6.4.9)
    writes the targets of the nodes it carries, and its carry stage moves the free jaw-region
    nodes kinematically, in place in ``state_in`` (both position buffers, before any force is
    computed). Implicit solvers (:class:`~.implicit.SolverImplicit`) call :meth:`prepare` once per
    step instead: the same targets and carry, and the stage's energy terms written into its
    ``springs`` (:class:`~facewarp._src.physics.springs.Springs`, a tuple of them, or None for a
    stage without any). A stage may also have ``refresh(model, positions, control)``, which the
    implicit solver calls between iterations to re-evaluate its springs at the current iterate
    (the muscles' fibre cosine, the contacts' active set). All may only launch kernels: no
    allocation, no host read.
    """

    def apply(self, model: Model, state_in: State, control: Control, dt: float, forces: object,
              targets: object) -> None:
        """Launch kernels for one explicit substep.

        Args:
            model: the tissue model.
            state_in: positions at t and t - dt (read only, except a kinematic carry).
            control: activations, jaw angles (read only).
            dt: substep [s].
            forces: forces [N] to accumulate into, shape (vertex_count,), wp.vec3; holds
                ``control.external_force`` when the stage is called.
            targets: target positions [m] of fixed / held nodes, shape (vertex_count,),
                wp.vec3; persistent between steps, rest positions initially.
        """
        ...

    def prepare(self, model: Model, state_in: State, control: Control, dt: float, targets: object) -> None:
        """Launch kernels for one implicit step: targets, carry, and fill ``springs``."""
        ...


class SolverBase:
    """Targets, step counter and guard of a solver (see the module doc).

    Attributes:
        model: the tissue model; device: its device; stages: the stages, in order.
        targets: Target position [m] of fixed / held nodes, shape (vertex_count,), wp.vec3.
        step_counter: Steps taken, on the device, shape (1,), int32.
        guard: First failing step and code ``2 tet + (0 NaN, 1 inverted)``, shape (2,), int32;
            both int32 max while nothing failed.
    """

    def __init__(self, model: Model, *, stages=()):
        if not isinstance(model, Model):
            raise InputError(f"model: expected a Model (ModelBuilder.finalize), got {type(model).__name__}")
        self.model = model
        self.device = model.device
        self.stages = list(stages)
        check_model_devices(model)
        check_stage_devices(self.stages, self.device)
        self.targets = wp.clone(model.rest_positions)
        self.step_counter = wp.zeros(1, dtype=wp.int32, device=self.device)
        self.guard = wp.array([kt.GUARD_NONE, kt.GUARD_NONE], dtype=wp.int32, device=self.device)
        # the guard comes back through pinned host memory (no allocation per check)
        self._guard_host = wp.zeros(2, dtype=wp.int32, device="cpu", pinned=bool(self.device.is_cuda))

    def _check_devices(self, state_in: State, state_out: State, control: Control) -> None:
        """The step's states and controls on the model's device (host side, no device work)."""
        for name, obj in (("state_in", state_in), ("state_out", state_out), ("control", control)):
            _check_fields(obj, self.device, name)

    def _launch_guard(self, state_out: State) -> None:
        m = self.model
        wp.launch(kt._check_tets, dim=m.tet_count, inputs=[m.tet_indices, self.step_counter, state_out.positions],
                          outputs=[self.guard], device=self.device)

    @property
    def step_count(self) -> int:
        """Steps taken so far (reads the device counter back)."""
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
        """Raise :class:`SimulationError` if a step produced a NaN or an inverted tet.

        Host side (reads the guard back): call it between frames, not inside ``step``.

        Args:
            state: the current state, used to name the offending vertex of a NaN tet.

        Raises:
            SimulationError: naming the first failing step and tet (and vertex).
        """
        wp.copy(self._guard_host, self.guard)
        if self.device.is_cuda:
            wp.synchronize_stream(wp.get_stream(self.device))
        step, code = (int(v) for v in self._guard_host.numpy())
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
        raise SimulationError(msg + "; " + self._advice())

    def _advice(self) -> str:
        return "reduce dt (see solver.stable_dt) or raise damping"
