"""The jaw as a MuJoCo hinge body, two-way coupled to the simulated skin (Sec. 6.4.3).

Hinge coupling and frames
-------------------------
:class:`MujocoJaw` attaches a :class:`~facewarp.FaceSimulator` to a user's ``MjModel`` /
``MjData`` by body and joint names (those of :func:`~facewarp._src.coupling.mjcf.head_mjcf`:
bodies ``cranium`` and ``mandible``, hinges ``jaw_open`` about the condyle u-axis and
``jaw_side`` about the v-axis, all after a name prefix that it finds itself when the model holds
one head, or is told). The face is simulated in the head's own frame (y up), with gravity along
its world's -y; a MuJoCo world has its own up (Z-up by convention). The coupler maps MuJoCo's
world into the simulator's by a fixed rotation ``C`` (:attr:`MujocoJaw.up_rotation`,
``x_mujoco = C x_sim``) with ``C e_y`` MuJoCo's up (from the model's gravity): for a Z-up world
``C`` is :data:`~facewarp._src.coupling.mjcf.Z_UP`, the turn ``head_mjcf(up="z")`` gives the
cranium, so an upright head at the origin has the identity pose in the simulator. Data are
exchanged once per frame, not per substep:

1. MuJoCo -> skin: the hinge angles become the skin's jaw angles (:meth:`FaceSimulator.set_jaw`):
   the held inner nodes of the jaw regions, the carried mass points, the muscle control points
   and anchors follow the mandible with their Eq. 6.4.9 amounts, through the stiff hold springs
   of the held nodes (the skin can resist). The cranium's head-frame pose, mapped by ``C^T``,
   becomes the head pose (:meth:`FaceSimulator.set_head_pose`), so the face rides the body.
2. skin -> MuJoCo: the hold springs' reaction on the mandible, ``k_i (x_i - T_i)`` at the targets
   ``T_i``, projected on each hinge's motion ``dT_i/dtheta = a_i (axis x (T_i - pivot))``, is the
   skin's generalised force on that hinge. It is passed with its linearisation about the current
   angle: the joint's spring reference is set to the current angle, its stiffness to the skin's
   (the secant of the force over the last frames, clipped to what MuJoCo's explicit spring can
   take at its time step), and the rest goes to ``qfrc_applied``. MuJoCo then steps the frame with
   a spring that answers the mandible's motion inside the frame, which keeps the exchange stable
   at the frame's step.

A skin much stiffer than MuJoCo's explicit spring can take (the thesis profile's hold springs:
its upper-bound stiffness ``sum k a^2 |axis x r|^2`` above :data:`STIFF_SKIN_RATIO` times the
limit) would throw the mandible: the skin's torque (28 N m in the thesis smile) acts for a
whole frame against only the clipped spring and the jaw's actuator. There the coupling passes
MuJoCo the stiffness it can take and scales the skin's torque by the same factor (the skin's
stiffness estimate over the limit): the jaw's static equilibrium under the skin is kept, its
motion toward it is slower. After every MuJoCo step the coupling reads MuJoCo's warning
counters (``data.warning``): an unstable step (NaN / huge accelerations, which MuJoCo answers by
resetting its state) raises :class:`~facewarp.SimulationError`, other warnings are kept in
:attr:`MujocoJaw.events`; MuJoCo's own warning text goes through :func:`mujoco_warnings` (no
``MUJOCO_LOG.TXT`` in the user's folder).

What is conserved and what is approximated: the force pair between skin and mandible is equal
and opposite at the frame boundaries (the torque applied to MuJoCo is exactly the reaction of
the springs the skin feels at that instant); inside a frame the skin's answer is the linear
spring above, and the skin sees the angle at the frame's end (a one-frame lag). The kinematic
carry of the jaw regions' free mass points (Sec. 6.4.3) moves them without a reaction, as in the
thesis; only held nodes push back. Energy is not exactly conserved across the exchange: the lag
and the clipped stiffness make the coupling slightly dissipative, never energy-producing.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.errors import InputError, SimulationError
from .mjcf import HEAD_SITE, Z_UP

__all__ = ["STIFF_SKIN_RATIO", "MujocoJaw", "mujoco_warnings"]

STIFF_SKIN_RATIO = 10.0
"""A skin whose upper-bound hinge stiffness exceeds this many times what MuJoCo's step takes gets
the scaled (equilibrium-keeping) coupling of the module doc."""

_UNSTABLE = ("mjWARN_BADQACC", "mjWARN_BADQVEL", "mjWARN_BADQPOS")
_messages: list[str] = []


def _collect_warning(text) -> None:
    _messages.append(str(text).strip())
    del _messages[:-20]


def mujoco_warnings() -> list[str]:
    """The last MuJoCo warning texts (at most 20) since the coupling was first made; MuJoCo's
    default handler would append them to ``MUJOCO_LOG.TXT`` in the current folder."""
    return list(_messages)


def _mujoco():
    try:
        import mujoco
    except ImportError:  # pragma: no cover - depends on the environment
        raise InputError("the MuJoCo coupling needs the package mujoco: pip install mujoco") from None
    if mujoco.get_mju_user_warning() is None:  # MuJoCo's default writes MUJOCO_LOG.TXT into the cwd
        mujoco.set_mju_user_warning(_collect_warning)
    return mujoco


def _world_rotation(model, up: str | None) -> np.ndarray:
    """The rotation C (3, 3) from the simulator's world (y up) to the MuJoCo world (see the module doc)."""
    if up is not None:
        if up not in ("z", "y"):
            raise InputError(f"up: expected 'z', 'y' or None (from the model's gravity), got {up!r}")
        return Z_UP.copy() if up == "z" else np.eye(3)
    g = np.asarray(model.opt.gravity, np.float64)
    if np.linalg.norm(g) < 1e-9:  # no gravity: MuJoCo's convention
        return Z_UP.copy()
    u = -g / np.linalg.norm(g)
    if u[1] > 1.0 - 1e-9:
        return np.eye(3)
    # the shortest turn from +z to this up, after Z_UP (exactly Z_UP for a Z-up world)
    w = np.cross([0.0, 0.0, 1.0], u)
    s, c = np.linalg.norm(w), u[2]
    if s < 1e-12:
        R = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        k = w / s
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R = np.eye(3) + s * K + (1 - c) * K @ K
    return R @ Z_UP


def _find_prefix(mj, model, mandible: str, open_joint: str) -> str:
    """The one prefix p with a body ``p + mandible`` and a joint ``p + open_joint`` in the model."""
    found = []
    for b in range(model.nbody):
        name = model.body(b).name
        if name.endswith(mandible):
            p = name[: len(name) - len(mandible)]
            if mj.mj_name2id(model, mj.mjtObj.mjOBJ_JOINT, p + open_joint) >= 0:
                found.append(p)
    if not found:
        raise InputError(f"mandible: no body named {mandible!r} (after any prefix) with a joint {open_joint!r} "
                         "in the MuJoCo model")
    if len(found) > 1:
        raise InputError(f"prefix: the MuJoCo model holds {len(found)} heads (prefixes "
                         f"{', '.join(repr(p) for p in found)}); pass prefix= to pick one")
    return found[0]


class MujocoJaw:
    """Couples a face simulator to a MuJoCo model's mandible (see the module docstring).

    Args:
        sim: The :class:`~facewarp.FaceSimulator` of the head.
        model: The ``mujoco.MjModel``.
        data: Its ``mujoco.MjData``.
        prefix: Put before every name below (``head_mjcf(prefix=...)``, or ``<attach prefix>``);
            None (default): the one prefix under which the model has the mandible body and the
            opening hinge ("" for a head without one); several heads need it given.
        mandible: Name of the mandible body.
        cranium: Name of the cranium body (the head pose); None keeps the head still. The head
            frame is the pose of the cranium's site ``head_site`` where the body has one (the
            head's origin and axes; :func:`~facewarp.head_mjcf` writes it), else the body's frame.
        head_site: Name of that site (default ``"head_origin"``).
        open_joint, side_joint: Names of the hinges (``side_joint`` may be None).
        two_way: Apply the skin's reaction to MuJoCo (False: MuJoCo drives the skin only).
        up: The MuJoCo world's up axis, ``"z"`` or ``"y"``; None (default): opposite the
            model's gravity (Z-up without gravity). Sets :attr:`up_rotation`.

    Attributes:
        up_rotation: C (3, 3): ``x_mujoco = C x_sim`` for points of the simulator's world frame
            (:meth:`FaceSimulator.surface`, :meth:`FaceSimulator.fdp`).
        prefix: The name prefix in use.

    Raises:
        InputError: a body or joint name not in the model, a joint that is not a hinge, or
            several heads and no prefix.
        SimulationError: (from :meth:`step`) MuJoCo went unstable (its NaN / huge-value warnings).

    Every material profile couples (the thesis profile's stiff holds through the scaled coupling
    of the module doc); MuJoCo's other warnings are kept in ``events`` (text).
    """

    def __init__(self, sim, model, data, *, prefix: str | None = None, mandible: str = "mandible",
                 cranium: str | None = "cranium", open_joint: str = "jaw_open", side_joint: str | None = "jaw_side",
                 two_way: bool = True, head_site: str = HEAD_SITE, up: str | None = None):
        mj = _mujoco()
        self.mj = mj
        self.sim, self.model, self.data = sim, model, data
        self.two_way = bool(two_way)
        if prefix is None:
            prefix = _find_prefix(mj, model, mandible, open_joint)
        elif not isinstance(prefix, str):
            raise InputError(f"prefix: expected a string, got {prefix!r}")
        self.prefix = prefix
        self.up_rotation = _world_rotation(model, up)

        def body(name):
            i = mj.mj_name2id(model, mj.mjtObj.mjOBJ_BODY, name)
            if i < 0:
                raise InputError(f"mandible/cranium: no body named {name!r} in the MuJoCo model")
            return i

        def hinge(name):
            j = mj.mj_name2id(model, mj.mjtObj.mjOBJ_JOINT, name)
            if j < 0:
                raise InputError(f"joint: no joint named {name!r} in the MuJoCo model")
            if model.jnt_type[j] != mj.mjtJoint.mjJNT_HINGE:
                raise InputError(f"joint {name!r}: expected a hinge")
            return j

        self.mandible = body(prefix + mandible)
        self.cranium = body(prefix + cranium) if cranium is not None else None
        self.site = -1  # the head frame's site on the cranium body, if it has one
        if self.cranium is not None:
            site = mj.mj_name2id(model, mj.mjtObj.mjOBJ_SITE, prefix + head_site)
            if site >= 0 and int(model.site_bodyid[site]) == self.cranium:
                self.site = site
        self.joints = [hinge(prefix + open_joint)] + ([hinge(prefix + side_joint)] if side_joint is not None else [])
        self.qadr = [int(model.jnt_qposadr[j]) for j in self.joints]
        self.dadr = [int(model.jnt_dofadr[j]) for j in self.joints]
        self.frame_dt = 1.0 / sim.fps
        self._clock = 0.0  # frame time simulated; MuJoCo steps until its time catches up
        self._elapsed = 0.0
        fr = sim.fr
        self.pivot = np.asarray(fr.jaw_pivot, np.float64)
        self.axes = [np.asarray(fr.jaw_u, np.float64), np.asarray(fr.jaw_v, np.float64)][: len(self.joints)]
        self.nodes = np.asarray(fr.jaw_nodes, np.int64)
        self.amount = np.asarray(fr.jaw_amount, np.float64)
        self.k_hold = sim.hold_stiffness()[self.nodes]
        self.rest = np.asarray(fr.nodes, np.float64)[self.nodes]
        # the stiffest spring MuJoCo's explicit passive force takes at its step, per hinge
        # (1 / dof_invweight0 is the joint's effective inertia at the reference pose)
        self._k_max = [0.5 * (2.0 / float(model.opt.timestep)) ** 2 / max(float(model.dof_invweight0[d]), 1e-12)
                       for d in self.dadr]
        self._stiff0 = [float(model.jnt_stiffness[j]) for j in self.joints]
        self._ref0 = [float(model.qpos_spring[a]) for a in self.qadr]
        self._last = None  # (angles, generalised forces) of the previous frame
        self.torque = np.zeros(len(self.joints))
        self.stiffness = np.zeros(len(self.joints))
        self.events: list[str] = []  # MuJoCo warnings (not instabilities, which raise) as text
        self._k_true = None  # the stiff skin's stiffness estimate [N m / rad] per hinge
        self._warned = np.zeros(len(mj.mjtWarning.__members__) - 1, np.int64)

    # ---------------------------------------------------------------------------------------
    def angles(self) -> np.ndarray:
        """Current hinge angles [rad], (open, side)."""
        a = [float(self.data.qpos[q]) for q in self.qadr]
        return np.array(a + [0.0] * (2 - len(a)))

    def skin_forces(self, angles) -> tuple[np.ndarray, np.ndarray]:
        """The skin's generalised force on each hinge [N m] at the simulator's current state,
        and its upper-bound stiffness ``sum k a^2 |axis x r|^2`` [N m / rad], each (hinges,)."""
        jaw = self.sim.jaw
        T = jaw.apply(self.rest, self.amount, float(angles[0]), float(angles[1]))
        X = self.sim.positions()[self.nodes]
        f_mandible = self.k_hold[:, None] * (X - T)  # the springs pull the mandible toward the skin
        tau, k = [], []
        for ax in self.axes:  # small angles: the v rotation's effect on the u axis is neglected
            lever = self.amount[:, None] * np.cross(ax, T - self.pivot)
            tau.append(float(np.einsum("kd,kd->", f_mandible, lever)))
            k.append(float((self.k_hold * np.einsum("kd,kd->k", lever, lever)).sum()))
        return np.array(tau), np.array(k)

    def head_pose(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The head frame's pose (R (3, 3), t (3,) [m]) in the simulator's world, as handed to
        :meth:`FaceSimulator.set_head_pose`: ``x_sim = R x_head + t``, which is ``C^T`` of the
        MuJoCo world pose (:attr:`up_rotation`); None without a cranium."""
        if self.cranium is None:
            return None
        if self.site >= 0:
            R, t = self.data.site_xmat[self.site].reshape(3, 3), self.data.site_xpos[self.site]
        else:
            R, t = self.data.xmat[self.cranium].reshape(3, 3), self.data.xpos[self.cranium]
        C = self.up_rotation
        return C.T @ R, C.T @ t

    def to_mujoco(self, X) -> np.ndarray:
        """Points X (k, 3) [m] of the simulator's world (:meth:`FaceSimulator.surface`, ``fdp``)
        in the MuJoCo world, ``C X``, shape (k, 3), float64."""
        return np.asarray(X, np.float64) @ self.up_rotation.T

    def exchange(self) -> None:
        """Skin side of one frame: take the MuJoCo angles and head pose, step the skin, and hand
        MuJoCo the skin's torque with its linearisation (no MuJoCo step)."""
        ang = self.exchange_begin()
        self.sim.step()
        self.exchange_end(ang)

    def exchange_begin(self) -> np.ndarray:
        """The first half of :meth:`exchange`: MuJoCo's angles and head pose set on the simulator
        (not stepped); returns the angles [rad] (open, side). :class:`~facewarp.FaceBatch`'s MuJoCo
        jaws step every head's skin together between the halves."""
        mj = self.mj
        mj.mj_kinematics(self.model, self.data)
        pose = self.head_pose()
        if pose is not None:
            self.sim.set_head_pose(*pose)
        ang = self.angles()
        self.sim.set_jaw(min(max(ang[0], 0.0), math.radians(60.0)), float(np.clip(ang[1], -math.radians(5), math.radians(5))))
        return ang

    def exchange_end(self, ang) -> None:
        """The second half of :meth:`exchange`, after the skin stepped at angles ``ang``: the
        skin's torque and its linearisation handed to MuJoCo."""
        tau, k_bound = self.skin_forces(ang)
        k = self.stiffness.copy()  # keep the last estimate while the jaw does not move
        if self._last is not None:
            dq = ang[: len(self.joints)] - self._last[0]
            dt = tau - self._last[1]
            moved = np.abs(dq) > 1e-5
            with np.errstate(divide="ignore", invalid="ignore"):
                k = np.where(moved, np.clip(-dt / np.where(moved, dq, 1.0), 0.0, k_bound), k)
        self._last = (ang[: len(self.joints)].copy(), tau.copy())
        k, applied = self._linearisation(k, k_bound, tau)
        self.torque, self.stiffness = tau, k
        if self.two_way:
            for i, (j, q, d) in enumerate(zip(self.joints, self.qadr, self.dadr)):
                self.model.jnt_stiffness[j] = self._stiff0[i] + k[i]
                self.model.qpos_spring[q] = ang[i]
                # the joint's own spring keeps its reference: -(s0 + k)(q - ang) = -s0 (q - r0)
                # - k (q - ang) - s0 (r0 - ang), so the last term is given back here
                self.data.qfrc_applied[d] = applied[i] + self._stiff0[i] * (self._ref0[i] - ang[i])

    def _linearisation(self, k: np.ndarray, k_bound: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The stiffness and torque handed to MuJoCo per hinge from the secant stiffness ``k``,
        the upper bound ``k_bound`` and the skin's torque ``tau`` (module doc): ``k`` clipped to
        MuJoCo's limit and ``tau`` as is, or for a stiff skin the limit and ``tau`` scaled by the
        limit over the skin's stiffness estimate (the same static equilibrium)."""
        k_max = np.asarray(self._k_max)
        stiff = k_bound > STIFF_SKIN_RATIO * k_max
        if not stiff.any():
            return np.minimum(k, k_max), tau
        if self._k_true is None:
            self._k_true = np.asarray(k_bound, np.float64).copy()
        self._k_true = np.where(k > k_max, k, self._k_true)  # a measured secant above the limit
        scale = np.where(stiff, np.minimum(1.0, k_max / np.maximum(self._k_true, 1e-30)), 1.0)
        return np.where(stiff, k_max, np.minimum(k, k_max)), tau * scale

    def _check_warnings(self) -> None:
        """Read MuJoCo's warning counters after a step: an instability raises, others are kept."""
        mj = self.mj
        counts = np.array([self.data.warning[i].number for i in range(len(self._warned))], np.int64)
        new = np.flatnonzero(counts > self._warned)
        self._warned = counts
        for i in new:
            name = mj.mjtWarning(i).name
            text = f"MuJoCo {name} at t = {self.data.time:.4f} s" + (f": {_messages[-1]}" if _messages else "")
            if name in _UNSTABLE:
                raise SimulationError(f"the MuJoCo jaw went unstable ({text}); MuJoCo reset its state. "
                                      "Lower the jaw actuator's gain or the skin stiffness, or use the kinematic jaw")
            self.events.append(text)

    def step(self) -> None:
        """One frame: :meth:`exchange`, then MuJoCo steps until its clock reaches the frame's end
        (the frame need not be a whole number of MuJoCo steps; the remainder carries over)."""
        self.exchange()
        self.mujoco_frame()

    def mujoco_frame(self) -> None:
        """MuJoCo's part of :meth:`step`: its steps until its clock reaches the frame's end."""
        self._clock += self.frame_dt
        h = float(self.model.opt.timestep)
        while self._elapsed + 0.5 * h < self._clock:
            self.mj.mj_step(self.model, self.data)
            self._check_warnings()
            self._elapsed += h

    def detach(self) -> None:
        """Give the model back its own joint stiffness and spring references, no applied force."""
        for i, (j, q, d) in enumerate(zip(self.joints, self.qadr, self.dadr)):
            self.model.jnt_stiffness[j] = self._stiff0[i]
            self.model.qpos_spring[q] = self._ref0[i]
            self.data.qfrc_applied[d] = 0.0
