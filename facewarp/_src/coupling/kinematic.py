"""The kinematic jaw as solver stages (Eq. 6.4.9): held-node targets and the carry of the
jaw regions' mass points. The MuJoCo jaw body will sit behind the same stage interface."""

from __future__ import annotations

import numpy as np

from ..core.warp import get_warp
from ..physics.model import JawNodeArrays, Model

__all__ = ["CarryStage", "JawStage"]


class _JawNodes:
    """Nodes moved by the jaw with their Eq. 6.4.9 amounts (those with amount > 0), on the device,
    with the jaw's pivot and axes."""

    def __init__(self, jaw, nodes, amounts, device, rest_positions=None):
        self._bind(JawNodeArrays(get_warp(), jaw, nodes, amounts, device, rest_positions))

    def _bind(self, arrays: JawNodeArrays) -> None:
        """Keep references to the jaw nodes' device arrays (no copy) and the kernels."""
        from ..physics import kernels_muscle as km

        self.km = km
        vars(self).update(vars(arrays))

    @classmethod
    def _of(cls, arrays: JawNodeArrays):
        st = cls.__new__(cls)
        st._bind(arrays)
        return st


class JawStage(_JawNodes):
    """Moves the targets of the jaw-carried held nodes (Eq. 6.4.9) each substep (solver stage)."""

    @classmethod
    def from_model(cls, model: Model) -> JawStage:
        """The targets of ``model.jaw`` (:meth:`~facewarp._src.physics.builder.ModelBuilder.add_jaw`)."""
        return cls._of(model.jaw.target_arrays)

    def __init__(self, jaw, nodes, amounts, rest_positions, device):
        super().__init__(jaw, nodes, amounts, device, rest_positions)

    def prepare(self, model: Model, state_in, control, dt, targets) -> None:
        """Implicit solvers: the same targets, once per step."""
        self.apply(model, state_in, control, dt, None, targets)

    def apply(self, model: Model, state_in, control, dt, forces, targets) -> None:
        if self.count == 0:
            return
        get_warp().launch(self.km._jaw_targets, dim=self.count,
                     inputs=[self.nodes, self.amounts, self.rest, self.head, self.pivot, self.u, self.v,
                             control.jaw_angles],
                     outputs=[targets], device=self.device)


class CarryStage(_JawNodes):
    """Carries the free mass points of the jaw regions with the jaw (Eq. 6.4.9; solver stage).

    Sec. 6.4.3 applies the jaw rotation to the *mass points* of the lip-corner, upper-lip,
    lower-lip and bottom-face regions with their non-uniform amount. Each substep in which the
    jaw angles changed, every carried node (and its previous position, so that no velocity is
    injected) moves by ``J(a theta) J(a theta_prev)^-1``; the skin forces then only answer the
    strain of the amount field, not the whole rigid swing. Without it the thin skin layer of a
    lower lip is dragged by the chin (amount 1) over its own inner sheet (amount ~0.5) and
    inverts at a 30 degree jaw angle. The angles the positions correspond to are State
    (``State.jaw_carry``, on the device: no host round trip), carried in place in ``state_in``
    with its positions.
    """

    @classmethod
    def from_model(cls, model: Model) -> CarryStage:
        """The carry of ``model.jaw`` (:meth:`~facewarp._src.physics.builder.ModelBuilder.add_jaw`)."""
        return cls._of(model.jaw.carry_arrays)

    def prepare(self, model: Model, state_in, control, dt, targets) -> None:
        """Implicit solvers: the same carry, once per step (by the change over the step)."""
        self.apply(model, state_in, control, dt, None, targets)

    def apply(self, model: Model, state_in, control, dt, forces, targets) -> None:
        if self.count == 0:
            return
        wp = get_warp()
        wp.launch(self.km._jaw_carry, dim=self.count,
                  inputs=[self.nodes, self.amounts, self.head, self.pivot, self.u, self.v, control.jaw_angles,
                          state_in.jaw_carry],
                  outputs=[state_in.positions, state_in.prev_positions], device=self.device)
        wp.launch(self.km._jaw_remember, dim=self.head_count, inputs=[control.jaw_angles], outputs=[state_in.jaw_carry],
                  device=self.device)
