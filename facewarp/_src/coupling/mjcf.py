"""The head as a MuJoCo model (MJCF): a cranium body and a mandible on two hinges (Sec. 6.4.3).

:func:`head_mjcf` writes, for one head (the default template, an imported or an adapted one):

- a ``cranium`` body carrying the skull, upper teeth and eyes as visual meshes;
- a ``mandible`` body at the midpoint of this head's condyles with two hinges: ``jaw_open``
  about the condyle u-axis (0..60 deg; positive opens the mouth, as in
  :class:`~facewarp._src.anatomy.jaw.JawKinematic`) and ``jaw_side`` about the vertical v-axis
  (+-5 deg); its mass and inertia come from bone density over a mandible geometry (the skull
  surface under the chin and bottom-face regions, taken as a cortical plate of
  :data:`MANDIBLE_PLATE` thickness), its visual meshes are that plate and the lower teeth;
- position actuators ``jaw_open`` and ``jaw_side`` on both hinges;
- a site :data:`HEAD_SITE` on the cranium at the head's own origin and axes: the frame the skin
  is simulated in (with ``neck=True`` the cranium body's frame sits at the neck's pivot instead).

Everything is in metres and the head's own frame (y up, +z out of the face), so gravity is
``(0, -9.81, 0)``. Meshes are written inline (``<mesh vertex=... face=...>``): the file is
self-contained and loads with ``mujoco.MjModel.from_xml_path`` and in the MuJoCo viewer.
Geoms are visual only (``contype=0 conaffinity=0``, no mass); the bodies' inertia is given
explicitly, so MuJoCo's mesh-inertia rules play no part.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from ..anatomy.jaw import JawKinematic
from ..core.errors import InputError
from ..core.fileio import atomic_write
from ..geometry.surface import face_areas, face_normals
from ..template.head import REGIONS

__all__ = [
    "BONE_DENSITY",
    "HEAD_MASS",
    "HEAD_SITE",
    "JAW_OPEN_RANGE",
    "JAW_SIDE_RANGE",
    "MANDIBLE_PLATE",
    "MandibleInertia",
    "head_mjcf",
    "mandible_geometry",
    "mandible_inertia",
    "write_head_mjcf",
]

BONE_DENSITY = 1850.0
"""Density of cortical bone [kg/m^3] (about 1.8-2.0 g/cm^3; Currey, *Bones*, 2002)."""

MANDIBLE_PLATE = 0.008
"""Thickness [m] of the bone plate that stands for the mandible under the chin and the bottom
face (the mandibular body is 8-12 mm thick; Schwartz-Dabney & Dechow 2003 give 2-4 mm of cortex
on each side of cancellous bone, so 8 mm of equivalent cortical bone is a middle value). With the
default head it gives about 0.1 kg, near a wet adult mandible."""

JAW_OPEN_RANGE = (0.0, math.radians(60.0))
"""Range of the opening hinge [rad] (Sec. 6.4.3)."""

JAW_SIDE_RANGE = (-math.radians(5.0), math.radians(5.0))
"""Range of the lateral hinge [rad] (Sec. 6.4.3)."""

MANDIBLE_REGIONS = ("chin", "bottom_face")
"""Regions whose skull surface is the mandible."""


class MandibleInertia:
    """Mass properties of the mandible plate in the head frame.

    Attributes:
        mass: [kg].
        center: Centre of mass [m], shape (3,), float64.
        inertia: Inertia tensor about the centre of mass [kg m^2], shape (3, 3), float64.
    """

    def __init__(self, mass: float, center: np.ndarray, inertia: np.ndarray):
        self.mass = float(mass)
        self.center = np.asarray(center, np.float64)
        self.inertia = np.asarray(inertia, np.float64)


def mandible_geometry(head) -> tuple[np.ndarray, np.ndarray]:
    """The mandible as the skull surface under :data:`MANDIBLE_REGIONS`.

    Args:
        head: A template-like head (``vertices``, ``faces``, ``face_region``, ``skull_vertices()``).

    Returns:
        V (k, 3) float64 [m] and F (l, 3) int64: the plate's outer surface (compact indices).
    """
    ids = [REGIONS.index(r) for r in MANDIBLE_REGIONS]
    faces = np.asarray(head.faces)[np.isin(np.asarray(head.face_region), ids)]
    if not len(faces):
        raise InputError("head: no chin or bottom-face region, so no mandible geometry")
    used, inv = np.unique(faces, return_inverse=True)
    return np.asarray(head.skull_vertices(), np.float64)[used], inv.reshape(-1, 3).astype(np.int64)


def mandible_inertia(V, F, *, thickness: float = MANDIBLE_PLATE, density: float = BONE_DENSITY) -> MandibleInertia:
    """Mass, centre and inertia of a bone plate of ``thickness`` [m] under the surface (V, F).

    Each triangle carries ``density * area * thickness`` at its centroid moved inward (against
    the outward normal) by half the thickness; the tensor sums those point masses (a plate's own
    thickness term is below 1 % here and left out).
    """
    if not (thickness > 0 and density > 0 and math.isfinite(thickness) and math.isfinite(density)):
        raise InputError(f"thickness, density: expected positive numbers, got {thickness!r}, {density!r}")
    V = np.asarray(V, np.float64)
    A = face_areas(V, F)
    c = V[F].mean(1) - 0.5 * thickness * face_normals(V, F)
    m = density * thickness * A
    mass = float(m.sum())
    com = (m[:, None] * c).sum(0) / mass
    r = c - com
    inertia = np.eye(3) * float((m * np.einsum("kd,kd->k", r, r)).sum()) - np.einsum("k,ki,kj->ij", m, r, r)
    return MandibleInertia(mass, com, inertia)


def _fmt(values) -> str:
    return " ".join(f"{v:.7g}" for v in np.asarray(values, np.float64).ravel())


def _mesh_asset(name: str, V, F) -> str:
    return f'    <mesh name={quoteattr(name)} vertex="{_fmt(V)}" face="{" ".join(map(str, np.asarray(F).ravel()))}"/>'


def _visual(name: str, mesh: str, rgba: str) -> str:
    return (f'      <geom name={quoteattr(name)} type="mesh" mesh={quoteattr(mesh)} contype="0" conaffinity="0" '
            f'density="0" group="1" rgba="{rgba}"/>')


HEAD_SITE = "head_origin"
"""Name of the cranium site at the head's coordinate origin (see the module doc); a user's own
model can carry one to tell :class:`~facewarp.MujocoJaw` where the head frame is on its body."""

HEAD_MASS = 4.5
"""Mass of the cranium body with the soft tissue on it [kg] (an adult head without the mandible
is 4-5 kg; Clauser et al. 1969)."""


def head_mjcf(head, *, jaw: JawKinematic | None = None, name: str = "facewarp_head", kp: float = 100.0,
              joint_damping: float = 0.4, neck: bool = False, neck_kp: float = 200.0) -> str:
    """MJCF text of a head's cranium and mandible (see the module docstring).

    Args:
        head: A template-like head (``vertices``, ``faces``, ``face_region``, ``condyles``,
            ``skull_vertices()``, ``landmarks()``, ``parts``).
        jaw: The jaw kinematics (pivot, u and v axes); default from the head's condyles and FDPs.
        name: Model name.
        kp: Position-actuator gain [N m / rad] of both hinges (100: the skin's resistance, about
            0.7 N m at a 0.25 rad opening of the default head, costs under 0.5 deg).
        joint_damping: Hinge damping [N m s / rad] (0.4: about critical for the default mandible
            under ``kp``, so the position control settles without ringing).
        neck: Mount the cranium on a 2-DOF neck (``neck_pan`` about y, ``neck_tilt`` about x,
            +-60 / +-40 deg) with position actuators, as an animatronic head; else the cranium
            is welded to the world.
        neck_kp: Position-actuator gain of the neck joints [N m / rad].

    Returns:
        The MJCF document as a string.
    """
    from ..core.checks import check_head_arg

    check_head_arg("head", head)
    for arg, v in (("kp", kp), ("joint_damping", joint_damping), ("neck_kp", neck_kp)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise InputError(f"{arg}: expected a non-negative number, got {v!r}")
    jaw = jaw or JawKinematic.from_landmarks(head.condyles, head.landmarks())
    pivot = np.asarray(jaw.pivot, np.float64)
    MV, MF = mandible_geometry(head)
    inert = mandible_inertia(MV, MF)
    I = inert.inertia
    parts = dict(getattr(head, "parts", {}) or {})
    assets = [_mesh_asset("skull", head.skull_vertices(), head.faces), _mesh_asset("mandible", MV - pivot, MF)]
    cranium_geoms = [_visual("skull", "skull", "0.92 0.89 0.8 1")]
    mandible_geoms = [_visual("mandible", "mandible", "0.92 0.89 0.8 1")]
    for pname, (V, F) in parts.items():
        lower = pname in ("teeth_lower", "tongue")
        assets.append(_mesh_asset(pname, (np.asarray(V) - pivot) if lower else V, F))
        rgba = "0.8 0.42 0.42 1" if pname == "tongue" else "0.97 0.96 0.93 1"
        (mandible_geoms if lower else cranium_geoms).append(_visual(pname, pname, rgba))
    lo, hi = JAW_OPEN_RANGE
    slo, shi = JAW_SIDE_RANGE
    V = np.asarray(head.vertices, np.float64)
    centre, half = 0.5 * (V.min(0) + V.max(0)), 0.5 * (V.max(0) - V.min(0))
    Ic = HEAD_MASS / 5.0 * np.array([half[1] ** 2 + half[2] ** 2, half[0] ** 2 + half[2] ** 2, half[0] ** 2 + half[1] ** 2])
    neck_at = np.array([0.0, pivot[1] - 0.04, pivot[2] - 0.03])  # near the atlanto-occipital joint
    head_body = [
        f'    <body name="cranium"{f" pos={quoteattr(_fmt(neck_at))}" if neck else ""}>',
        f'      <inertial pos="{_fmt(centre - (neck_at if neck else 0))}" mass="{HEAD_MASS:.7g}" diaginertia="{_fmt(Ic)}"/>',
    ]
    if neck:
        head_body += [
            '      <joint name="neck_pan" type="hinge" axis="0 1 0" range="-1.047 1.047" damping="2"/>',
            '      <joint name="neck_tilt" type="hinge" axis="1 0 0" range="-0.698 0.698" damping="2"/>',
            f'      <frame pos="{_fmt(-neck_at)}">',
        ]
    ind = "  " if neck else ""
    head_body += [ind + g for g in cranium_geoms] + [
        # the head's own coordinate frame (the template's origin and axes) on the cranium: the
        # pose MujocoJaw hands to the skin, wherever the body's frame sits (the neck's pivot)
        f'{ind}      <site name="{HEAD_SITE}" size="0.004" rgba="1 0.2 0.2 0"/>',
        f'{ind}      <body name="mandible" pos="{_fmt(pivot)}">',
        f'{ind}        <inertial pos="{_fmt(inert.center - pivot)}" mass="{inert.mass:.7g}" '
        f'fullinertia="{_fmt([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])}"/>',
        f'{ind}        <joint name="jaw_open" type="hinge" axis="{_fmt(jaw.u_axis)}" range="{lo:.7g} {hi:.7g}" '
        f'damping="{joint_damping:.7g}"/>',
        f'{ind}        <joint name="jaw_side" type="hinge" axis="{_fmt(jaw.v_axis)}" range="{slo:.7g} {shi:.7g}" '
        f'damping="{joint_damping:.7g}"/>',
        *[ind + "  " + g for g in mandible_geoms],
        f'{ind}      </body>',
    ]
    if neck:
        head_body.append('      </frame>')
    head_body.append('    </body>')
    actuators = [
        f'    <position name="jaw_open" joint="jaw_open" kp="{kp:.7g}" ctrlrange="{lo:.7g} {hi:.7g}"/>',
        f'    <position name="jaw_side" joint="jaw_side" kp="{kp:.7g}" ctrlrange="{slo:.7g} {shi:.7g}"/>',
    ]
    if neck:
        actuators += [
            f'    <position name="neck_pan" joint="neck_pan" kp="{neck_kp:.7g}" ctrlrange="-1.047 1.047"/>',
            f'    <position name="neck_tilt" joint="neck_tilt" kp="{neck_kp:.7g}" ctrlrange="-0.698 0.698"/>',
        ]
    return "\n".join([
        f'<mujoco model={quoteattr(name)}>',
        '  <compiler angle="radian" autolimits="true"/>',
        '  <option timestep="0.002" gravity="0 -9.81 0" integrator="implicitfast"/>',
        '  <asset>',
        *assets,
        '  </asset>',
        '  <worldbody>',
        *head_body,
        '  </worldbody>',
        '  <actuator>',
        *actuators,
        '  </actuator>',
        '</mujoco>',
        '',
    ])


def write_head_mjcf(path: str | os.PathLike, head, **kwargs) -> Path:
    """Write :func:`head_mjcf` to ``path`` (atomically). Returns the path."""
    from ..core.checks import check_head_arg, check_path

    check_path("path", path)
    check_head_arg("head", head)
    text = head_mjcf(head, **kwargs)
    with atomic_write(path, "w") as f:
        f.write(text)
    return Path(path)
