"""The simulated face shown in a build's MuJoCo scene without the two-way jaw: the skin moved by
the face (:class:`~facewarp.MujocoSkin`), the mandible's hinges set to the simulator's jaw angles
and the cranium turned by a head rotation, for a passive viewer (``mujoco.viewer.launch_passive``)
or an offscreen renderer. ``facewarp live`` shows the face it drives this way; the jaw and head are
kinematic here (set, not simulated by MuJoCo).
"""

from __future__ import annotations

import contextlib

import numpy as np

from ..core.errors import InputError

__all__ = ["MujocoView"]


class MujocoView:
    """The face in the build's MuJoCo scene: the skin (:class:`~facewarp.MujocoSkin`), the
    mandible at the jaw angles, the cranium turned by the head rotation; shown in a passive
    viewer handle when given (``mujoco.viewer.launch_passive``), else kept in the model only.

    Args:
        mjcf: ``head.xml`` or ``scene.xml`` of a build (with the skin mesh).
        sim: The :class:`~facewarp.FaceSimulator`.

    Attributes:
        model, data: The ``mujoco.MjModel`` / ``MjData`` (kinematics only: never stepped).
        skin: The :class:`~facewarp.MujocoSkin`.
        cranium: The cranium body's index; handle: the viewer handle after :meth:`open` (else None).

    Raises:
        InputError: a file MuJoCo cannot load, no skin mesh or cranium in it.
    """

    def __init__(self, mjcf, sim):
        from ..coupling.mujoco import _mujoco
        from ..coupling.mujoco_skin import MujocoSkin

        mj = _mujoco()
        self.mj, self.sim = mj, sim
        try:
            self.model = mj.MjModel.from_xml_path(str(mjcf))
        except Exception as e:  # a damaged file: one line
            why = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise InputError(f"{mjcf}: MuJoCo cannot load it ({why})") from None
        self.data = mj.MjData(self.model)
        self.skin = MujocoSkin(sim, self.model)
        p = self.skin.prefix
        self.cranium = mj.mj_name2id(self.model, mj.mjtObj.mjOBJ_BODY, p + "cranium")
        if self.cranium < 0:
            raise InputError(f"{mjcf}: no body {p + 'cranium'!r}")
        self.qadr = []
        for name in ("jaw_open", "jaw_side"):
            j = mj.mj_name2id(self.model, mj.mjtObj.mjOBJ_JOINT, p + name)
            self.qadr.append(int(self.model.jnt_qposadr[j]) if j >= 0 else None)
        R0 = np.empty(9)
        mj.mju_quat2Mat(R0, np.asarray(self.model.body_quat[self.cranium], np.float64))
        self._R0 = R0.reshape(3, 3)  # the cranium's rest rotation (the head frame into MuJoCo's world)
        self.handle = None
        mj.mj_kinematics(self.model, self.data)

    def open(self) -> None:
        """Open the passive viewer window (needs a display)."""
        import mujoco.viewer

        self.handle = mujoco.viewer.launch_passive(self.model, self.data, show_left_ui=False, show_right_ui=False)

    @property
    def running(self) -> bool:
        """The window is open (True without one)."""
        return self.handle is None or bool(self.handle.is_running())

    def show(self, R=None) -> None:
        """Put the simulator's current face, jaw and the head rotation ``R`` (3, 3) (head frame;
        None: upright) into the model and onto the window."""
        mj, sim = self.mj, self.sim
        q = np.empty(4)
        mj.mju_mat2Quat(q, (self._R0 @ (np.eye(3) if R is None else np.asarray(R, np.float64))).ravel())
        jaw = sim.jaw_angles
        lock = self.handle.lock() if self.handle is not None else contextlib.nullcontext()
        with lock:
            self.model.body_quat[self.cranium] = q
            for adr, v in zip(self.qadr, jaw):
                if adr is not None:
                    self.data.qpos[adr] = float(v)
            mj.mj_kinematics(self.model, self.data)
        self.skin.update(*([self.handle] if self.handle is not None else []))
        if self.handle is not None:
            self.handle.sync()

    def close(self) -> None:
        if self.handle is not None:
            with contextlib.suppress(Exception):
                self.handle.close()
            self.handle = None
