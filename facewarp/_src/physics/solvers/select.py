"""Which solver steps a Model: :func:`select_solver`, one function over the explicit solver classes
(no base class builds its subclass).

``select_solver(model, solver="implicit", method=None, stages=..., **options)`` returns a
:class:`~.verlet.SolverVerlet` (``solver="verlet"``) or the implicit class of ``method``:
:class:`~.host_implicit.SolverHostImplicit` (``"lbfgs"``, the CPU default, and ``"newton"``) or
:class:`~.newton_pcg.SolverDeviceNewtonPCG` (``"newton-pcg"``, the CUDA default). New frame
schemes are new classes over the same Model / State / Control and a new branch here.
"""

from __future__ import annotations

from ...core.errors import InputError
from .host_implicit import SolverHostImplicit
from .implicit import IMPLICIT_METHODS, refuse_options
from .newton_pcg import SolverDeviceNewtonPCG
from .verlet import SolverVerlet

__all__ = ["SOLVER_KINDS", "implicit_solver_class", "select_solver"]

SOLVER_KINDS = ("implicit", "verlet")
"""The kinds :func:`select_solver` makes: backward Euler (``implicit``) or the explicit Verlet reference."""


def implicit_solver_class(method: str | None, device=None) -> type:
    """The class of the implicit ``method`` (None: the default of ``device``, a Warp device:
    Newton-PCG on CUDA, L-BFGS elsewhere).

    Raises:
        InputError: an unknown method.
    """
    if method is None:
        method = "newton-pcg" if getattr(device, "is_cuda", False) else "lbfgs"
    if method not in IMPLICIT_METHODS:
        raise InputError(f"method: expected one of {', '.join(IMPLICIT_METHODS)}, got {method!r}")
    return SolverDeviceNewtonPCG if method == "newton-pcg" else SolverHostImplicit


def select_solver(model, *, solver: str = "implicit", method: str | None = None, stages=(), **options):
    """The solver of ``model`` (a :class:`~facewarp._src.physics.model.Model`).

    Args:
        model: The Model.
        solver: ``"implicit"`` (default) or ``"verlet"``.
        method: The implicit method: ``"lbfgs"``, ``"newton"`` or ``"newton-pcg"`` (default: by the
            model's device); not taken by ``"verlet"``.
        stages: The solver's stages, in step order.
        options: Further keywords of the chosen class (its doc).

    Returns:
        A :class:`~.verlet.SolverVerlet`, :class:`~.host_implicit.SolverHostImplicit` or
        :class:`~.newton_pcg.SolverDeviceNewtonPCG`.

    Raises:
        InputError: an unknown solver or method, or an option the class does not take (naming
            the class it belongs to).
    """
    if solver == "verlet":
        if method is not None or options:
            bad = "method" if method is not None else next(iter(options))
            raise InputError(f"{bad}: not an option of SolverVerlet (the explicit reference takes stages only)")
        return SolverVerlet(model, stages=stages)
    if solver != "implicit":
        raise InputError(f"solver: expected one of {', '.join(SOLVER_KINDS)}, got {solver!r}")
    cls = implicit_solver_class(method, getattr(model, "device", None))
    refuse_options(cls, options)
    return cls(model, stages=stages, method=method, **options)
