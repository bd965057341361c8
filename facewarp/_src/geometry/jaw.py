"""Jaw kinematics (Sec. 6.4.3, Eq. 6.4.9) behind a small interface.

The mandible rotates about the u-axis through the two condyles (mouth opening, 0..60 deg) and
about the vertical v-axis through their midpoint (+-5 deg). Points of the jaw-influenced regions
(lip corners, upper lip, lower lip, bottom face, and the chin, which sits on the mandible) follow
with a per-point *amount* in [0, 1] of the jaw rotation.

Eq. 6.4.9 as printed, ``theta(x) = theta/3 + 2 theta/3 sqrt(|x - x_c| / |x_lc - x_c|)``, gives the
full rotation at the lip corners and a third at the middle, while the text says the opposite
("the points in the middle of the lower lip are rotated by the same amount as the jaw rotation
... the corners of the mouth are rotated by one third"). We follow the text, with the square-root
curve of the equation, measuring ``|x - x_c|`` along the u-axis from the face's midline:

- lower lip: ``amount = 1 - 2/3 sqrt(r)``, ``r = min(1, |x_u| / |x_lc,u|)`` (1 in the middle, 1/3
  at the corners);
- lip corners: 1/3; upper lip: ``sqrt(r) / 3`` (its corners are pulled down with the jaw, its
  middle stays with the maxilla);
- chin and bottom face: the lower-lip amount blended to 1 (rigid with the mandible) over
  ``blend_depth`` below the mouth line.

The interface (:class:`JawKinematic`) gives the amounts once at build time and the pivot and axes
that the solver's kernels use every substep; a MuJoCo hinge body can later provide the same
angles (``Control.jaw``) without changing the solver.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["JawKinematic", "JAW_REGIONS", "jaw_rotation", "rotate_about"]

JAW_REGIONS = ("lip_corner_L", "lip_corner_R", "upper_lip", "lower_lip", "bottom_face", "chin")
"""Template regions whose points follow the jaw rotation with a per-point amount in [0, 1]: the lip
corners (1/3), the upper lip (its corners pulled down, its middle staying), the lower lip (1 in the
middle, 1/3 at the corners), the bottom face and the chin (blended to rigid with the mandible)."""


def rotate_about(P, pivot, axis, angle):
    """Rotate points P (k, 3) [m] about the line through ``pivot`` along unit ``axis`` by
    ``angle`` (scalar or (k,)) [rad] (Rodrigues)."""
    P = np.asarray(P, dtype=np.float64) - pivot
    a = np.asarray(angle, dtype=np.float64).reshape(-1, 1)
    k = np.asarray(axis, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    return pivot + P * c + np.cross(k, P) * s + np.outer(P @ k, k) * (1 - c)


def jaw_rotation(P, amount, pivot, u_axis, v_axis, theta_u, theta_v):
    """Positions of P (k, 3) [m] after the jaw rotation with per-point ``amount`` (k,)."""
    Q = rotate_about(P, pivot, u_axis, theta_u * amount)
    return rotate_about(Q, pivot, v_axis, theta_v * amount)


@dataclass
class JawKinematic:
    """The kinematic jaw of Sec. 6.4.3.

    Attributes:
        pivot: Midpoint of the condyles [m], shape (3,).
        u_axis: Unit axis through the condyles, from the right (-x) to the left (+x) condyle.
            A positive angle opens the mouth (the chin moves down and back).
        v_axis: Unit vertical axis (perpendicular to u, in the plane of u and +y).
        lip_corners: Left and right lip corners (FDP 8.3, 8.4) [m], shape (2, 3).
        mouth_y: Height of the mouth line [m] (mean of 2.2 and 2.3) in the head frame.
        blend_depth: Distance below the mouth line over which the bottom face becomes rigid
            with the mandible [m].
    """

    pivot: np.ndarray
    u_axis: np.ndarray
    v_axis: np.ndarray
    lip_corners: np.ndarray
    mouth_center: np.ndarray
    blend_depth: float = 0.015

    @classmethod
    def from_landmarks(cls, condyles, landmarks, *, blend_depth: float = 0.015) -> JawKinematic:
        """Build from condyles (2, 3) [m] (left, right) and FDP positions (8.3, 8.4, 2.2, 2.3)."""
        condyles = np.asarray(condyles, dtype=np.float64)
        pivot = condyles.mean(0)
        u = condyles[0] - condyles[1]
        u /= np.linalg.norm(u)
        # A positive rotation about +x (right-hand rule) takes a point below and in front of
        # the condyles down and back: positive angles open the mouth.
        v = np.array([0.0, 1.0, 0.0]) - u * u[1]
        v /= np.linalg.norm(v)
        lc = np.stack([landmarks["8.3"], landmarks["8.4"]])
        mc = 0.5 * (np.asarray(landmarks["2.2"]) + np.asarray(landmarks["2.3"]))
        return cls(pivot, u, v, lc, mc, blend_depth)

    def amounts(self, P, region_names) -> np.ndarray:
        """Rotation amount in [0, 1] of points P (k, 3) [m] with region names (k,) (Eq. 6.4.9)."""
        P = np.asarray(P, dtype=np.float64)
        names = np.asarray(region_names)
        half = 0.5 * abs(float((self.lip_corners[0] - self.lip_corners[1]) @ self.u_axis))
        r = np.minimum(1.0, np.abs((P - self.mouth_center) @ self.u_axis) / half)
        lower = 1.0 - (2.0 / 3.0) * np.sqrt(r)
        below = np.clip((self.mouth_center[1] - P[:, 1]) / self.blend_depth, 0.0, 1.0)
        below = below * below * (3 - 2 * below)
        out = np.zeros(len(P))
        out = np.where(names == "lower_lip", lower, out)
        out = np.where(np.isin(names, ["lip_corner_L", "lip_corner_R"]), 1.0 / 3.0, out)
        out = np.where(names == "upper_lip", np.sqrt(r) / 3.0, out)
        rigid = lower + (1.0 - lower) * below
        out = np.where(np.isin(names, ["bottom_face", "chin"]), rigid, out)
        return out

    def apply(self, P, amount, theta_u: float, theta_v: float = 0.0) -> np.ndarray:
        """NumPy reference of the jaw motion (the solver does the same in a kernel)."""
        return jaw_rotation(P, amount, self.pivot, self.u_axis, self.v_axis, theta_u, theta_v)
