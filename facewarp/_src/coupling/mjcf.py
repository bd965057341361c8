"""The head as a MuJoCo model (MJCF): a cranium body and a mandible on two hinges (Sec. 6.4.3).

:func:`head_mjcf` writes, for one head (the default template, an imported or an adapted one), a
body tree that a robot model can mount:

- a ``cranium`` body carrying the skull, upper teeth and eyes (and, with ``skin=``, the skin) as
  visual meshes;
- a ``mandible`` body at the midpoint of this head's condyles with two hinges: ``jaw_open``
  about the condyle u-axis (0..60 deg; positive opens the mouth, as in
  :class:`~facewarp._src.geometry.jaw.JawKinematic`) and ``jaw_side`` about the vertical v-axis
  (+-5 deg); its mass and inertia come from bone density over a mandible geometry (the skull
  surface under the chin and bottom-face regions, taken as a cortical plate of
  :data:`MANDIBLE_PLATE` thickness), its visual meshes are that plate and the lower teeth;
- position actuators ``jaw_open`` and ``jaw_side`` on both hinges;
- a site :data:`HEAD_SITE` on the cranium at the head's own origin and axes: the frame the skin
  is simulated in (with ``neck=True`` the cranium body's frame sits at the neck's pivot instead).

The file is meant to be ``<include>``d at a host's top level (the head then sits fixed in the
world) or ``<attach>``ed / ``MjSpec.attach``ed under any body of a host: it has no ``<option>``
(the host's gravity, time step and integrator stay), no ``<compiler>`` (its two hinge ranges are
in degrees, MuJoCo's default unit; ``<attach>`` keeps them right under a host that says
``angle="radian"``; actuator ranges are radians in any case) and no joint to the world: the
cranium is fixed to whatever body holds it. Its meshes are inline (``<mesh vertex=...
face=...>``), so no ``meshdir`` is involved. ``prefix`` puts a string before every name, so two
heads fit in one model. :func:`scene_mjcf` is the standalone scene (options, floor, light,
camera) that includes it; :func:`write_head_mjcf` writes both.

Everything is in metres. The cranium body turns the head frame (y up, +z out of the face) into
the world: with ``up="z"`` (default, MuJoCo's convention) by :data:`Z_UP`, so the head stands up
and looks along +x; with ``up="y"`` not at all. Geoms are visual only (``contype=0
conaffinity=0``, no mass); the bodies' inertia is given explicitly, so MuJoCo's mesh-inertia rules
play no part.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from ..geometry.jaw import JawKinematic
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
    "SCENE_NAME",
    "UPS",
    "Z_UP",
    "head_mjcf",
    "mandible_geometry",
    "mandible_inertia",
    "scene_mjcf",
    "skin_vertex_split",
    "up_rotation",
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

SCENE_NAME = "scene.xml"
"""The standalone scene :func:`write_head_mjcf` writes beside the head file."""

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
    return " ".join(f"{v + 0.0:.7g}" for v in np.asarray(values, np.float64).ravel())  # no "-0"


def _mesh_asset(name: str, V, F, extra: str = "", *, normals=None, texcoord=None) -> str:
    more = "" if normals is None else f' normal="{_fmt(normals)}"'
    if texcoord is not None:
        more += f' texcoord="{_fmt(texcoord)}"'
    return (f'    <mesh name={quoteattr(name)}{extra} vertex="{_fmt(V)}"{more} '
            f'face="{" ".join(map(str, np.asarray(F).ravel()))}"/>')


def skin_vertex_split(F, face_uv) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The skin's mesh for MuJoCo, whose texture coordinates are per vertex: the vertices split
    where the UVs have seams.

    Args:
        F: Skin triangles (m, 3) int into n vertices. face_uv: (m, 3) int index into the UVs per corner.

    Returns:
        (faces (m, 3) int64 into n' >= n vertices, source vertex (n',) int64, UV index (n',) int64):
        vertex ``i < n`` is skin vertex ``i`` (with the UV of its first corner, in face order), the
        ones after it copies of seam vertices with their other UVs (``source[i]``), so the first n
        keep the skin's own order (:class:`~facewarp.MujocoSkin` writes the face into them and the copies).
    """
    F = np.asarray(F, np.int64)
    T = np.asarray(face_uv, np.int64)
    n = int(F.max()) + 1
    first = np.full(n, -1, np.int64)
    extra: dict = {}
    src, uvi = [], []
    out = np.empty_like(F)
    for c, (v, t) in enumerate(zip(F.ravel(), T.ravel())):
        if first[v] < 0:
            first[v] = t
            out.flat[c] = v
        elif first[v] == t:
            out.flat[c] = v
        else:
            k = extra.get((v, t))
            if k is None:
                k = extra[(v, t)] = n + len(src)
                src.append(v)
                uvi.append(t)
            out.flat[c] = k
    first[first < 0] = 0
    return out, np.r_[np.arange(n), np.asarray(src, np.int64)], np.r_[first, np.asarray(uvi, np.int64)]


def _visual(name: str, mesh: str, rgba: str, group: int = 1) -> str:
    return (f'      <geom name={quoteattr(name)} type="mesh" mesh={quoteattr(mesh)} contype="0" conaffinity="0" '
            f'density="0" group="{group}" rgba="{rgba}"/>')


HEAD_SITE = "head_origin"
"""Name of the cranium site at the head's coordinate origin (see the module doc), before any
prefix; a user's own model can carry one to tell :class:`~facewarp.MujocoJaw` where the head
frame is on its body."""

HEAD_MASS = 4.5
"""Mass of the cranium body with the soft tissue on it [kg] (an adult head without the mandible
is 4-5 kg; Clauser et al. 1969)."""

UPS = ("z", "y")
"""The world's up axis a head file can be written for: ``"z"`` (MuJoCo's convention, the default)
or ``"y"`` (the head's own frame)."""

Z_UP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
"""The head frame (y up, +z out of the face, +x the head's left) in a Z-up world where the head
looks along +x (x forward, y left, z up, as REP 103): ``x_world = Z_UP @ x_head``, shape (3, 3)."""

Z_UP_QUAT = "0.5 0.5 0.5 0.5"
""":data:`Z_UP` as an MJCF quaternion (w x y z): 120 deg about (1, 1, 1)."""

SKIN_RGBA = (0.87, 0.72, 0.62, 1.0)
"""Colour of the skin mesh in head.xml without a texture (RGBA, 0..1): the palette's skin
(``present.looks.COLORS``)."""

_NAME_OK = re.compile(r"[A-Za-z0-9_.:/-]*\Z")


def up_rotation(up: str) -> np.ndarray:
    """The fixed rotation (3, 3) from the head's own frame (y up) to a world with ``up`` ("z": :data:`Z_UP`;
    "y": the identity)."""
    if up not in UPS:
        raise InputError(f"up: expected one of {', '.join(UPS)}, got {up!r}")
    return Z_UP.copy() if up == "z" else np.eye(3)


def head_mjcf_options(up: str, prefix: str) -> None:
    """Check :func:`head_mjcf`'s ``up`` and ``prefix`` (an :class:`InputError` naming the bad one)."""
    up_rotation(up)
    if not (isinstance(prefix, str) and _NAME_OK.match(prefix)):
        raise InputError(f"prefix: expected letters, digits and _ . : / - only, got {prefix!r}")


def _deg(values) -> str:
    """Angles [rad] as MJCF degrees (MuJoCo's default unit: head.xml sets no <compiler>)."""
    return _fmt(np.degrees(np.asarray(values, np.float64)))


def head_mjcf(head, *, jaw: JawKinematic | None = None, name: str = "facewarp_head", kp: float = 100.0,
              joint_damping: float = 0.4, neck: bool = False, neck_kp: float = 200.0, up: str = "z",
              prefix: str = "", skin=None, skin_texture=None, iris_color=None) -> str:
    """MJCF text of a head's cranium and mandible as a body tree (see the module docstring).

    Args:
        head: A template-like head (``vertices``, ``faces``, ``face_region``, ``condyles``,
            ``skull_vertices()``, ``landmarks()``, ``parts``).
        jaw: The jaw kinematics (pivot, u and v axes); default from the head's condyles and FDPs.
        name: Model name.
        kp: Position-actuator gain [N m / rad] of both hinges (100: the skin's resistance, about
            0.7 N m at a 0.25 rad opening of the default head, costs under 0.5 deg).
        joint_damping: Hinge damping [N m s / rad] (0.4: about critical for the default mandible
            under ``kp``, so the position control settles without ringing).
        neck: Mount the cranium on a 2-DOF neck (``neck_pan`` about the head's up axis,
            ``neck_tilt`` about its left-right axis, +-60 / +-40 deg) with position actuators, as
            an animatronic head; else the cranium has no joint (fixed to its parent body).
        neck_kp: Position-actuator gain of the neck joints [N m / rad].
        up: ``"z"`` (default): the cranium body turns the head into MuJoCo's Z-up world, looking
            along +x (:data:`Z_UP`); ``"y"``: the head's own frame (y up, looking along +z).
        prefix: Put before every name (bodies, joints, geoms, meshes, site, actuators), so that
            two heads fit in one model; letters, digits and ``_ . : / -``.
        skin: The skin as a mesh geom ``skin`` on the cranium: ``(V (n, 3) [m], F (m, 3) int)`` in
            the head frame (``FaceRig.head_vertices``, ``FaceRig.head_faces``), or None for none.
            :class:`~facewarp.MujocoSkin` moves its vertices with the simulated face. With a skin
            the skull and mandible geoms go to geom group 3 (hidden by default in MuJoCo's
            renderer and viewer; the viewer's group toggles show them). Smooth (area-weighted)
            vertex normals are written with it. ``(V, F, uv (k, 2), face_uv (m, 3))`` adds its
            texture coordinates (the vertices split at the UV seams, :func:`skin_vertex_split`);
            with ``skin_texture`` and without them the head's own (``head.uv``, ``head.face_uv``)
            are taken when ``F`` is the head's faces.
        skin_texture: The skin's colour texture (PNG), the ``file`` of a ``<texture>`` as written
            (a name relative to the model file, such as ``texture.png`` beside head.xml), bound to
            the skin through a material; needs the texture coordinates. None: the palette's skin colour.
        iris_color: Optional iris RGB (3,) in 0..1; each eyeball is drawn as its sclera, iris and
            pupil (``present.looks.eye_looks``), three visual geoms.

    Returns:
        The MJCF document as a string.
    """
    from ..core.checks import check_head_arg

    check_head_arg("head", head)
    for arg, v in (("kp", kp), ("joint_damping", joint_damping), ("neck_kp", neck_kp)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise InputError(f"{arg}: expected a non-negative number, got {v!r}")
    head_mjcf_options(up, prefix)
    C = up_rotation(up)
    n = (lambda s: quoteattr(prefix + s))
    jaw = jaw or JawKinematic.from_landmarks(head.condyles, head.landmarks())
    pivot = np.asarray(jaw.pivot, np.float64)
    MV, MF = mandible_geometry(head)
    inert = mandible_inertia(MV, MF)
    I = inert.inertia
    parts = dict(getattr(head, "parts", {}) or {})
    assets = [_mesh_asset(prefix + "skull", head.skull_vertices(), head.faces),
              _mesh_asset(prefix + "mandible", MV - pivot, MF)]
    # under a skin the bones go to geom group 3: hidden by MuJoCo's renderer and viewer by default
    # (the skin lies a few mm over them and they would show through where it is thin)
    bone = 1 if skin is None else 3
    cranium_geoms = [_visual(prefix + "skull", prefix + "skull", "0.92 0.89 0.8 1", bone)]
    mandible_geoms = [_visual(prefix + "mandible", prefix + "mandible", "0.92 0.89 0.8 1", bone)]
    from ..geometry.surface import vertex_normals
    from ..present.looks import COLORS, eye_looks, part_kind

    fdps = None
    try:
        fdps = {str(k): np.asarray(v, np.float64) for k, v in head.landmarks().items()}
    except Exception:  # a head without FDPs: the gaze along +z
        fdps = None
    materials = []
    for pname, (V, F) in parts.items():
        lower = pname in ("teeth_lower", "tongue")
        PV = (np.asarray(V, np.float64) - pivot) if lower else np.asarray(V, np.float64)
        PF = np.asarray(F, np.int64)
        rgba = "0.8 0.42 0.42 1" if pname == "tongue" else "0.97 0.96 0.93 1"
        geoms = mandible_geoms if lower else cranium_geoms
        if part_kind(pname) == "eye":
            # the ball as its sclera, iris and pupil: three meshes of its faces, each its own colour
            for look, (faces, rgb) in eye_looks(np.asarray(V, np.float64), PF, fdps, iris_color=iris_color).items():
                if not len(faces):
                    continue
                sub = PF[faces]
                used, inv = np.unique(sub, return_inverse=True)
                mname = prefix + pname + ("" if look == "Sclera" else "_" + look.lower())
                assets.append(_mesh_asset(mname, PV[used], inv.reshape(-1, 3), extra=' inertia="shell"',
                                          normals=vertex_normals(PV, PF)[used]))
                geoms.append(_visual(mname, mname, _fmt([*rgb, 1.0])))
            continue
        assets.append(_mesh_asset(prefix + pname, PV, PF, normals=vertex_normals(PV, PF)))
        geoms.append(_visual(prefix + pname, prefix + pname, rgba))
    if skin is not None:
        SV, SF, uv, face_uv = _check_skin(skin)
        if uv is None and skin_texture is not None and getattr(head, "uv", None) is not None \
                and getattr(head, "face_uv", None) is not None \
                and np.shape(head.face_uv) == SF.shape and np.array_equal(np.asarray(head.faces), SF):
            uv, face_uv = np.asarray(head.uv, np.float64), np.asarray(head.face_uv, np.int64)
        N = vertex_normals(SV, SF)
        if uv is not None:
            MF, src, uvi = skin_vertex_split(SF, face_uv)
            tc = uv[uvi].copy()
            tc[:, 1] = 1.0 - tc[:, 1]  # MuJoCo's texture rows run top to bottom, v up: flip as its OBJ reader does
            mesh = _mesh_asset(prefix + "skin", SV[src], MF, extra=' inertia="shell"', normals=N[src], texcoord=tc)
        else:
            mesh = _mesh_asset(prefix + "skin", SV, SF, extra=' inertia="shell"', normals=N)
        # shell inertia: the skin is an open surface (no volume); the geom has no mass anyway
        assets.append(mesh)
        # skin is not a mirror: a faint, broad highlight (MuJoCo's default material shines like plastic)
        if skin_texture is not None:
            if uv is None:
                raise InputError("skin_texture: the skin has no texture coordinates (give skin=(V, F, uv, face_uv))")
            assets.append(f'    <texture name={n("skin")} type="2d" file={quoteattr(str(skin_texture))}/>')
            materials.append(f'    <material name={n("skin")} texture={n("skin")} specular="0.15" shininess="0.2" '
                             f'reflectance="0"/>')
        else:
            materials.append(f'    <material name={n("skin")} rgba="{_fmt(SKIN_RGBA)}" specular="0.15" '
                             f'shininess="0.2" reflectance="0"/>')
        cranium_geoms.append(f'      <geom name={n("skin")} type="mesh" mesh={n("skin")} material={n("skin")} '
                             'contype="0" conaffinity="0" density="0" group="1"/>')
    assets += materials
    lo, hi = JAW_OPEN_RANGE
    slo, shi = JAW_SIDE_RANGE
    V = np.asarray(head.vertices, np.float64)
    centre, half = 0.5 * (V.min(0) + V.max(0)), 0.5 * (V.max(0) - V.min(0))
    Ic = HEAD_MASS / 5.0 * np.array([half[1] ** 2 + half[2] ** 2, half[0] ** 2 + half[2] ** 2, half[0] ** 2 + half[1] ** 2])
    neck_at = np.array([0.0, pivot[1] - 0.04, pivot[2] - 0.03])  # near the atlanto-occipital joint
    body_at = C @ neck_at if neck else np.zeros(3)
    frame = "" if up == "y" else f' quat="{Z_UP_QUAT}"'
    head_body = [
        f'    <body name={n("cranium")}{f" pos={quoteattr(_fmt(body_at))}" if neck else ""}{frame}>',
        f'      <inertial pos="{_fmt(centre - (neck_at if neck else 0))}" mass="{HEAD_MASS:.7g}" diaginertia="{_fmt(Ic)}"/>',
    ]
    if neck:
        head_body += [
            f'      <joint name={n("neck_pan")} type="hinge" axis="0 1 0" range="-60 60" damping="2"/>',
            f'      <joint name={n("neck_tilt")} type="hinge" axis="1 0 0" range="-40 40" damping="2"/>',
            f'      <frame pos="{_fmt(-neck_at)}">',
        ]
    ind = "  " if neck else ""
    head_body += [ind + g for g in cranium_geoms] + [
        # the head's own coordinate frame (the template's origin and axes) on the cranium: the
        # pose MujocoJaw hands to the skin, wherever the body's frame sits (the neck's pivot)
        f'{ind}      <site name={n(HEAD_SITE)} size="0.004" rgba="1 0.2 0.2 0"/>',
        f'{ind}      <body name={n("mandible")} pos="{_fmt(pivot)}">',
        f'{ind}        <inertial pos="{_fmt(inert.center - pivot)}" mass="{inert.mass:.7g}" '
        f'fullinertia="{_fmt([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])}"/>',
        f'{ind}        <joint name={n("jaw_open")} type="hinge" axis="{_fmt(jaw.u_axis)}" range="{_deg([lo, hi])}" '
        f'damping="{joint_damping:.7g}"/>',
        f'{ind}        <joint name={n("jaw_side")} type="hinge" axis="{_fmt(jaw.v_axis)}" range="{_deg([slo, shi])}" '
        f'damping="{joint_damping:.7g}"/>',
        *[ind + "  " + g for g in mandible_geoms],
        f'{ind}      </body>',
    ]
    if neck:
        head_body.append('      </frame>')
    head_body.append('    </body>')
    # actuator ctrlrange is not an angle attribute in MJCF: radians whatever the compiler says
    actuators = [
        f'    <position name={n("jaw_open")} joint={n("jaw_open")} kp="{kp:.7g}" ctrlrange="{lo:.7g} {hi:.7g}"/>',
        f'    <position name={n("jaw_side")} joint={n("jaw_side")} kp="{kp:.7g}" ctrlrange="{slo:.7g} {shi:.7g}"/>',
    ]
    if neck:
        actuators += [
            f'    <position name={n("neck_pan")} joint={n("neck_pan")} kp="{neck_kp:.7g}" ctrlrange="-1.047198 1.047198"/>',
            f'    <position name={n("neck_tilt")} joint={n("neck_tilt")} kp="{neck_kp:.7g}" ctrlrange="-0.6981317 0.6981317"/>',
        ]
    return "\n".join([
        f'<mujoco model={quoteattr(name)}>',
        '  <!-- a body tree to <include> or <attach>: no <option>, no <compiler> (angles in degrees, '
        'MuJoCo\'s default; meshes inline); scene.xml beside it adds a floor, a light and the options -->',
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


def _check_skin(skin) -> tuple:
    uv = face_uv = None
    try:
        if len(skin) == 4:
            SV, SF, uv, face_uv = skin
        else:
            SV, SF = skin
        SV = np.asarray(SV, np.float64)
        SF = np.asarray(SF)
    except (TypeError, ValueError):
        raise InputError("skin: expected (V (n, 3) [m], F (m, 3) int) or (V, F, uv (k, 2), face_uv (m, 3))") from None
    if uv is not None:
        uv, face_uv = np.asarray(uv, np.float64), np.asarray(face_uv)
        if uv.ndim != 2 or uv.shape[1] != 2 or not np.isfinite(uv).all() or face_uv.shape != np.shape(SF) \
                or face_uv.dtype.kind not in "iu" or face_uv.min() < 0 or face_uv.max() >= len(uv):
            raise InputError(f"skin: uv must be finite (k, 2) and face_uv (m, 3) indices into it, got {uv.shape}, "
                             f"{face_uv.shape}")
    if SV.ndim != 2 or SV.shape[1] != 3 or not len(SV) or not np.isfinite(SV).all():
        raise InputError(f"skin: V must be finite with shape (n, 3), got {SV.shape}")
    if SF.ndim != 2 or SF.shape[1] != 3 or not len(SF) or SF.dtype.kind not in "iu" or SF.min() < 0 or SF.max() >= len(SV):
        raise InputError(f"skin: F must be (m, 3) indices into V, got shape {SF.shape}")
    return SV, SF, uv, face_uv


def scene_mjcf(head_file: str = "head.xml", *, up: str = "z", head=None, name: str = "facewarp_scene",
               timestep: float = 0.002) -> str:
    """MJCF text of a standalone scene that ``<include>``s ``head_file``: the options (time step,
    gravity along -``up``, the implicit-fast integrator), a floor under the head, a light and a
    camera on the face.

    Args:
        head_file: Path of the head file as the scene refers to it (relative to the scene's folder).
        up: The up axis the head file was written for (:data:`UPS`).
        head: The head (its vertices place the floor under the chin); None: 0.25 m below the origin.
        name: Model name.
        timestep: MuJoCo's time step [s].
    """
    C = up_rotation(up)
    if not (isinstance(timestep, (int, float)) and math.isfinite(timestep) and timestep > 0):
        raise InputError(f"timestep: expected a positive number, got {timestep!r}")
    if head is not None:
        W = np.asarray(head.vertices, np.float64) @ C.T
        floor = float((W @ C[:, 1]).min()) - 0.02
    else:
        floor = -0.25
    g = -9.81 * C[:, 1]
    upv, fwd = C[:, 1], C[:, 2]
    floor_pos = floor * upv
    floor_quat = "1 0 0 0" if up == "z" else "0.7071068 -0.7071068 0 0"  # the plane's normal along up
    cam = 0.55 * fwd + 0.02 * upv
    light = 0.6 * fwd + 0.8 * upv
    return "\n".join([
        f'<mujoco model={quoteattr(name)}>',
        f'  <option timestep="{timestep:.7g}" gravity="{_fmt(g)}" integrator="implicitfast"/>',
        '  <visual><global offwidth="1280" offheight="960"/><quality shadowsize="4096"/></visual>',
        f'  <include file={quoteattr(str(head_file))}/>',
        '  <asset>',
        '    <texture name="floor_grid" type="2d" builtin="checker" rgb1="0.32 0.34 0.37" rgb2="0.26 0.28 0.3" '
        'width="256" height="256"/>',
        '    <material name="floor_grid" texture="floor_grid" texrepeat="8 8" reflectance="0.1"/>',
        '  </asset>',
        '  <worldbody>',
        f'    <light name="key" pos="{_fmt(light)}" dir="{_fmt(-light / np.linalg.norm(light))}" diffuse="0.8 0.8 0.8" '
        'castshadow="false"/>',  # shadow maps speckle the face (acne at the chin)
        # a fill from the camera's side: the face's front lit as the skin texture shows it (the key alone and
        # the headlight left it about 10 L* darker than its texture)
        f'    <light name="fill" pos="{_fmt(cam)}" dir="{_fmt(-fwd)}" diffuse="0.5 0.5 0.5" specular="0 0 0" '
        'castshadow="false"/>',
        f'    <geom name="floor" type="plane" size="1 1 0.05" pos="{_fmt(floor_pos)}" quat="{floor_quat}" '
        'material="floor_grid" contype="1" conaffinity="1"/>',
        f'    <camera name="face" pos="{_fmt(cam)}" xyaxes="{_fmt(C[:, 0])} {_fmt(upv)}"/>',
        '  </worldbody>',
        '</mujoco>',
        '',
    ])


def write_head_mjcf(path: str | os.PathLike, head, *, scene: bool = True, **kwargs) -> Path:
    """Write :func:`head_mjcf` to ``path`` and, with ``scene``, :func:`scene_mjcf` to ``scene.xml``
    beside it (atomically). Returns the head file's path."""
    from ..core.checks import check_head_arg, check_path

    check_path("path", path)
    check_head_arg("head", head)
    path = Path(path)
    text = head_mjcf(head, **kwargs)
    scene_text = scene_mjcf(path.name, up=kwargs.get("up", "z"), head=head) if scene else None
    with atomic_write(path, "w") as f:
        f.write(text)
    if scene_text is not None:
        with atomic_write(path.with_name(SCENE_NAME), "w") as f:
            f.write(scene_text)
    return path
