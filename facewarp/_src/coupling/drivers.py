"""Jaw drivers: what advances a simulator one frame toward an expression's jaw angles.

:func:`~facewarp.play` hands each frame's expression to a driver, after it has set the
activations; the driver sets the jaw and steps the simulator. :class:`KinematicJawDriver` imposes
the angles (Eq. 6.4.9); :class:`MujocoJawDriver` makes them the actuator targets of the MuJoCo
hinge body of ``head.xml`` and steps skin and body together (:class:`~facewarp.MujocoJaw`).
"""

from __future__ import annotations

from pathlib import Path

from ..core.errors import InputError

__all__ = ["JAWS", "KinematicJawDriver", "MujocoJawDriver", "jaw_driver", "load_mjcf"]

JAWS = ("kinematic", "mujoco")
"""How the jaw is driven: the kinematic jaw of Eq. 6.4.9 (angles set per frame) or the MuJoCo
hinge body of ``head.xml`` (angles as actuator targets, two-way coupled)."""


class KinematicJawDriver:
    """The jaw angles set directly each frame (Eq. 6.4.9), then one simulator step.

    Args:
        sim: The :class:`~facewarp.FaceSimulator`.
    """

    name = "kinematic"

    def __init__(self, sim):
        self.sim = sim

    def step(self, expr) -> None:
        """Set the jaw to ``expr.jaw_u``, ``expr.jaw_v`` [rad] and step one frame."""
        self.sim.set_jaw(expr.jaw_u, expr.jaw_v)
        self.sim.step()


def load_mjcf(mjcf):
    """The ``mujoco.MjModel`` of a head's ``head.xml`` (or the ``scene.xml`` beside it, which
    includes it with the options); a missing or broken file is one :class:`InputError` line naming
    it (MuJoCo's parse errors span several lines)."""
    from .mjcf import SCENE_NAME
    from .mujoco import _mujoco

    mj = _mujoco()
    if mjcf is None or not Path(mjcf).is_file():
        raise InputError(f"jaw: the MuJoCo jaw needs the head's head.xml, not found at {mjcf}")
    scene = Path(mjcf).with_name(SCENE_NAME)  # the head file's options (gravity, integrator) live there
    model = None
    for path in (Path(mjcf), scene) if scene.is_file() else (Path(mjcf),):  # the head first: its errors name it
        try:
            model = mj.MjModel.from_xml_path(str(path))
        except Exception as e:  # MuJoCo's parse errors are multi-line ValueErrors
            raise InputError(f"{path}: not a valid MuJoCo model ({' '.join(str(e).split())})") from None
    return model


class MujocoJawDriver:
    """The jaw as the MuJoCo hinge body of ``head.xml``: the expression's angles are the actuator
    targets (``jaw_open``, ``jaw_side``), :class:`~facewarp.MujocoJaw` steps skin and body together.

    Args:
        sim: The :class:`~facewarp.FaceSimulator`.
        mjcf: The head's ``head.xml`` (:func:`~facewarp.coupling.write_head_mjcf`, written by ``facewarp build``).

    Raises:
        InputError: no ``head.xml`` at ``mjcf``, or no ``mujoco`` package.
    """

    name = "mujoco"

    def __init__(self, sim, mjcf):
        from .mujoco import MujocoJaw, _mujoco

        mj = _mujoco()
        self.model = load_mjcf(mjcf)
        self.data = mj.MjData(self.model)
        self.coupler = MujocoJaw(sim, self.model, self.data)
        p = self.coupler.prefix
        self.act = [mj.mj_name2id(self.model, mj.mjtObj.mjOBJ_ACTUATOR, p + n) for n in ("jaw_open", "jaw_side")]

    def step(self, expr) -> None:
        """Set the actuator targets to ``expr.jaw_u``, ``expr.jaw_v`` [rad] and step skin and body one frame."""
        for i, target in zip(self.act, (expr.jaw_u, expr.jaw_v)):
            if i >= 0:
                self.data.ctrl[i] = target
        self.coupler.step()


def jaw_driver(sim, jaw: str = "kinematic", *, mjcf=None):
    """The driver of ``sim`` named ``jaw`` (one of :data:`JAWS`; ``mjcf``: the head's ``head.xml``
    for ``"mujoco"``).

    Raises:
        InputError: an unknown name, or the MuJoCo jaw without its ``head.xml``.
    """
    if jaw == "kinematic":
        return KinematicJawDriver(sim)
    if jaw == "mujoco":
        return MujocoJawDriver(sim, mjcf)
    raise InputError(f"jaw: expected one of {', '.join(JAWS)}, got {jaw!r}")
