"""A face riding a moving body: the head's pose over time and the inertial loads it causes.

The face is simulated in the frame of the cranium body (its rest shape, fixed border and held
nodes are defined there), so a head that moves rigidly does not drag its skin through the
solver's damping. What the motion does to soft tissue is kept through the fictitious forces of
the accelerating frame (Goldstein, *Classical Mechanics*, Sec. 4.10): on a node of mass ``m`` at
``x`` (body frame),

    f = -m [ R^T a + alpha x x + omega x (omega x x) ] + m (R^T g - g),

with ``R, t`` the body's orientation and position in the world, ``a = t''`` its linear
acceleration, ``omega`` and ``alpha`` its angular velocity and acceleration in the body frame,
and ``g`` gravity. The last term is the change of gravity relative to the upright head (the rest
shape already balances gravity in the neutral pose), so tilting the head lets the tissue sag the
other way. The Coriolis term ``-2 m omega x v`` needs the nodes' relative velocities, which live
on the device; it is left out (for the slow nods of a robot head, |2 omega v| is below 1 % of the
centrifugal and gravity terms). A body moving at constant velocity gives no force: the face stays
at rest in its frame.

:class:`HeadPose` keeps the last three poses, one per frame, and turns them into those
accelerations by central differences.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.errors import InputError

__all__ = ["GRAVITY", "HEAD_MOTION_LIMITS", "HeadPose", "check_pose"]

GRAVITY = np.array([0.0, -9.81, 0.0])
"""Gravity in the world frame [m/s^2] (y up, as the head's own frame)."""

HEAD_MOTION_LIMITS = {"linear_acceleration": 1000.0, "angular_velocity": 100.0, "angular_acceleration": 2.0e4}
"""The head motion a step takes [SI]: linear acceleration 1,000 m/s^2 (about 100 g, a severe
impact), angular velocity 100 rad/s (16 rev/s) and angular acceleration 20,000 rad/s^2 (sports
impacts stay below about 10,000). A pose that needs more over the coming step is refused
(:meth:`HeadPose.check_motion`): it is a jump, not a motion of a head."""


def check_pose(R, t) -> tuple[np.ndarray, np.ndarray]:
    """Validate a pose: R (3, 3) a rotation (orthonormal, det +1 within 1e-4), t (3,) [m]."""
    from ..core.checks import check_array

    R = check_array("R", R, shape=(3, 3), finite=False)
    t = check_array("t", t, shape=(3,), finite=False)
    if R.shape != (3, 3) or not np.isfinite(R).all():
        raise InputError(f"R: expected a finite (3, 3) rotation matrix, got shape {R.shape}")
    if t.shape != (3,) or not np.isfinite(t).all():
        raise InputError(f"t: expected a finite (3,) translation [m], got {t!r}")
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or abs(np.linalg.det(R) - 1.0) > 1e-4:
        raise InputError("R: not a rotation (R^T R != I or det R != 1)")
    return R, t


def _log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of R (3,) [rad]."""
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    ang = math.acos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if ang < 1e-8:
        return 0.5 * w
    return ang / (2.0 * math.sin(ang)) * w


class HeadPose:
    """Pose history of the cranium body and the inertial load per node.

    Args:
        gravity: Include the change of gravity relative to the upright head.
    """

    def __init__(self, *, gravity: bool = True):
        self.gravity = bool(gravity)
        self.reset()

    def reset(self) -> None:
        """Identity pose, at rest."""
        self.R = np.eye(3)
        self.t = np.zeros(3)
        self._hist: list[tuple[np.ndarray, np.ndarray]] = []  # poses at the ends of past frames
        self._moved = False  # a pose other than the rest pose was set since the reset

    @property
    def identity(self) -> bool:
        """Whether the head sits at the rest pose and has never moved."""
        return not self._hist and np.array_equal(self.R, np.eye(3)) and not self.t.any()

    @property
    def still(self) -> bool:
        """Whether every recorded pose and the target are the rest pose: no load at all (the
        inertial and gravity-change forces are exactly 0), so none need be computed."""
        return not self._moved

    def set(self, R, t) -> None:
        """The pose [R (3, 3), t (3,) m] at the end of the next frame."""
        self.R, self.t = check_pose(R, t)
        if self.t.any() or not np.array_equal(self.R, np.eye(3)):
            self._moved = True

    def advance(self) -> None:
        """Record the current pose as that of the frame just taken."""
        self._hist.append((self.R.copy(), self.t.copy()))
        del self._hist[:-2]

    def accelerations(self, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body-frame linear acceleration [m/s^2], angular velocity [rad/s] and angular
        acceleration [rad/s^2] over the coming frame of ``h`` [s], each (3,) float64.

        Central differences over the last two recorded poses and the target pose; a pose
        history shorter than that is padded with its oldest pose (a body that starts at rest).
        """
        hist = list(self._hist) or [(self.R, self.t)]
        while len(hist) < 2:
            hist.insert(0, hist[0])
        (R0, t0), (R1, t1), (R2, t2) = hist[-2], hist[-1], (self.R, self.t)
        a_world = (t2 - 2.0 * t1 + t0) / (h * h)
        w01 = _log(R0.T @ R1) / h  # body-frame angular velocities over the two intervals
        w12 = _log(R1.T @ R2) / h
        alpha = (w12 - w01) / h
        return R1.T @ a_world, w12, alpha

    def check_motion(self, h: float) -> None:
        """Refuse a pose that moves the head beyond :data:`HEAD_MOTION_LIMITS` over the coming
        step of ``h`` [s].

        Raises:
            InputError: naming the quantity, its value and the limit.
        """
        a, w, alpha = self.accelerations(h)
        for name, v, unit in (("linear_acceleration", np.linalg.norm(a), "m/s^2"),
                              ("angular_velocity", np.linalg.norm(w), "rad/s"),
                              ("angular_acceleration", np.linalg.norm(alpha), "rad/s^2")):
            limit = HEAD_MOTION_LIMITS[name]
            if not v <= limit:
                raise InputError(f"head pose: reaching the pose set by set_head_pose in {h:.4g} s needs a "
                                 f"{name.replace('_', ' ')} of {v:.3g} {unit}, above the limit {limit:g} {unit} "
                                 "of a moving head; move it over more steps")

    def node_forces(self, X, mass, h: float) -> np.ndarray:
        """Fictitious (and gravity-change) forces [N] on nodes X (p, 3) [m, body frame] of
        ``mass`` (p,) [kg] over the coming frame of ``h`` [s], shape (p, 3), float64."""
        X = np.asarray(X, np.float64)
        m = np.asarray(mass, np.float64)[:, None]
        a, w, alpha = self.accelerations(h)
        acc = a[None, :] + np.cross(alpha, X) + np.cross(w, np.cross(w, X))
        f = -m * acc
        if self.gravity:
            f += m * (self.R.T @ GRAVITY - GRAVITY)[None, :]
        return f

    def to_world(self, X) -> np.ndarray:
        """Body-frame points X (k, 3) [m] in the world, ``R X + t``."""
        return np.asarray(X, np.float64) @ self.R.T + self.t
