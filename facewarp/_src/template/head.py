"""The default template head: skin mesh, rigid parts, FDPs, regions, thickness, skull, condyles.

Everything returned here is in metres (the shape is authored in millimetres in :mod:`.shape`).
Levels share every definition: FDPs, regions and rigid parts are given in the continuous
parametrisation of the head and re-projected at each level.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import InputError
from ..geometry.surface import vertex_normals
from ..geometry.landmarks import FDP_IDS
from ..geometry.mesh import SurfacePoints, closest_surface_points
from . import shape as S
from .build import CUTS, build_raw_head
from .uv import face_uv_layout

__all__ = [
    "REGIONS",
    "FRONTAL_REGIONS",
    "REGION_THICKNESS_MM",
    "THICKNESS_FACTOR",
    "MAX_LEVEL",
    "Template",
    "default_template",
]

MM = 1e-3
MAX_LEVEL = 4

REGIONS: tuple[str, ...] = (
    "forehead",
    "eyelid_upper_L",
    "eyelid_upper_R",
    "eyelid_lower_L",
    "eyelid_lower_R",
    "cheek_L",
    "cheek_R",
    "nose",
    "upper_lip",
    "lower_lip",
    "lip_corner_L",
    "lip_corner_R",
    "chin",
    "bottom_face",
    "ear_L",
    "ear_R",
    "scalp",
    "neck",
)
"""Region names; ``_L`` is the subject's left (+x)."""

FRONTAL_REGIONS = frozenset(REGIONS[:14])
"""Regions of the frontal face, the simulation domain of Sec. 6.2."""

# Table 6.1 (Lee and Hwang 2002): forehead 0.901, eyelid 0.569, cheek 1.237, chin 0.891 mm.
# Regions the table does not list take the nearest listed tissue: lips and lip corners the
# cheek value (perioral skin is as thick as the cheek's), the nose and scalp the forehead value,
# the bottom face and neck the chin value, the ears the eyelid value (thin skin over cartilage).
_T = {"forehead": 0.901, "eyelid": 0.569, "cheek": 1.237, "chin": 0.891}
REGION_THICKNESS_MM: dict[str, float] = {
    "forehead": _T["forehead"],
    "eyelid_upper_L": _T["eyelid"],
    "eyelid_upper_R": _T["eyelid"],
    "eyelid_lower_L": _T["eyelid"],
    "eyelid_lower_R": _T["eyelid"],
    "cheek_L": _T["cheek"],
    "cheek_R": _T["cheek"],
    "nose": _T["forehead"],
    "upper_lip": _T["cheek"],
    "lower_lip": _T["cheek"],
    "lip_corner_L": _T["cheek"],
    "lip_corner_R": _T["cheek"],
    "chin": _T["chin"],
    "bottom_face": _T["chin"],
    "ear_L": _T["eyelid"],
    "ear_R": _T["eyelid"],
    "scalp": _T["forehead"],
    "neck": _T["chin"],
}

THICKNESS_FACTOR = 2.0
"""Skin thickness magnification (the thesis's 'skin thickness magnification').

Table 6.1 lists the thickness of the dermis (0.57-1.24 mm). The simulated skin layer stands for
the cutis plus the superficial subcutaneous layer above the muscles (the SMAS), which is about
twice the dermis in the face (about 2-3 mm over the cheek, 1-2 mm over the forehead and lids).
A factor 2 keeps the muscle insertion depth 2 t_skin + r_muscle of Sec. 6.3 above the bone even
over the forehead, where the whole soft tissue is only about 5.5 mm deep (De Greef et al. 2006).
"""

_EYE_R = S.EYE_RADIUS


@dataclass
class Template:
    """A head with everything the pipeline needs, in metres.

    Attributes:
        vertices: Skin vertices [m], shape (n, 3), float64.
        faces: Skin triangles, shape (m, 3), int64, outward oriented.
        face_region: Index into :data:`REGIONS` per face, shape (m,), int16.
        frontal: Whether a face belongs to the frontal face (simulation domain), shape (m,), bool.
        thickness: Skin layer thickness per vertex [m] (Table 6.1 x ``thickness_factor``,
            averaged over the regions around a vertex), shape (n,), float64.
        skull_depth: Soft tissue depth from the skin to the skull along the inward normal [m],
            shape (n,), float64.
        condyles: Left (+x) and right mandibular condyle centres [m], shape (2, 3), float64.
        fdp: FDP id -> (part name, surface point) with the point as face index + barycentric.
        parts: Rigid parts, name -> (V (k, 3) [m], F (l, 3) int): eyeballs, teeth, tongue.
        level: Resolution level (0 = about 3,400 skin vertices).
        thickness_factor: Skin thickness magnification applied to Table 6.1.
        uv: Texture coordinates of the skin in [0, 1]^2, shape (k, 2), float64, or None
            (:mod:`.uv`: one low-stretch chart for the face front, a few for the rest).
        face_uv: Per skin triangle corner an index into ``uv``, shape (m, 3), int64, or None.
        texture: Path of the skin's colour texture (a PNG over ``uv``; an ``adapt`` output's
            ``texture.png`` baked from the scan), or None.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_region: np.ndarray
    frontal: np.ndarray
    thickness: np.ndarray
    skull_depth: np.ndarray
    condyles: np.ndarray
    fdp: dict[str, tuple[str, SurfacePoints]]
    parts: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    level: int = 0
    thickness_factor: float = THICKNESS_FACTOR
    uv: np.ndarray | None = None
    face_uv: np.ndarray | None = None
    texture: str | None = None

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    @property
    def face_count(self) -> int:
        return len(self.faces)

    def part_mesh(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        if name == "head":
            return self.vertices, self.faces
        return self.parts[name]

    def landmarks(self) -> dict[str, np.ndarray]:
        """FDP id -> position [m] (3,), evaluated on the current vertices and parts."""
        out = {}
        for fid, (part, sp) in self.fdp.items():
            V, F = self.part_mesh(part)
            out[fid] = sp.positions(V, F)[0]
        return out

    def skull_vertices(self) -> np.ndarray:
        """Skull surface under the skin [m], shape (n, 3): skin moved inward by ``skull_depth``."""
        return self.vertices - vertex_normals(self.vertices, self.faces) * self.skull_depth[:, None]

    def region_names(self) -> list[str]:
        return [REGIONS[i] for i in self.face_region]

    def bounding_box(self) -> np.ndarray:
        return np.stack([self.vertices.min(0), self.vertices.max(0)])


# ----------------------------------------------------------------------------- regions
def _classify_faces(V_mm: np.ndarray, F: np.ndarray, phi_v: np.ndarray) -> np.ndarray:
    c = V_mm[F].mean(1)
    x, y = c[:, 0], c[:, 1]
    # azimuth of the centroid from its vertices' azimuths (averaged on the circle)
    phi = np.arctan2(np.sin(phi_v[F]).mean(1), np.cos(phi_v[F]).mean(1))
    aphi = np.abs(np.rad2deg(phi))
    ax = np.abs(x)
    side = np.where(x >= 0, 0, 1)  # 0 = left (+x), 1 = right
    idx = {n: i for i, n in enumerate(REGIONS)}
    region = np.full(len(F), idx["scalp"], dtype=np.int16)

    neckline = np.interp(aphi, [0, 25, 60, 90, 180], [-108, -106, -90, -75, -65])
    ear_u = (np.deg2rad(aphi) - np.deg2rad(99.0)) * 75.0 / 17.5
    ear_v = (y + 5.0) / 31.5
    ear = ear_u**2 + ear_v**2 < 1.25**2
    neck = (y < neckline) & ~ear
    y_trichion = S.Y_NASION + 62.0  # tr-n forehead height (Farkas 1994)
    frontal = (aphi < 75.0) & (y <= y_trichion) & ~neck & ~ear

    def ellipse(cx, cy, rx, ry):
        return ((ax - cx) / rx) ** 2 + ((y - cy) / ry) ** 2 < 1.0

    lid = ellipse(S.X_PUPIL, S.Y_EYE, 21.0, 11.0)
    lid_up = lid & (y >= S.Y_EYE)
    lid_dn = ellipse(S.X_PUPIL, S.Y_EYE, 21.0, 9.0) & (y < S.Y_EYE)
    nose_half = np.interp(y, [S.Y_SUBNASALE - 1, S.Y_NASION - 39, S.Y_NASION], [11.0, 13.0, 10.0])
    nose = ((y >= S.Y_SUBNASALE - 1) & (y <= S.Y_NASION) & (ax < nose_half)) | ellipse(13.0, S.Y_SUBNASALE + 5, 9.0, 8.0)
    corner = ellipse(S.X_CH, S.Y_STOMION, 8.0, 8.0)
    upper = (ax < S.X_CH) & (y >= S.Y_STOMION) & (y < S.Y_SUBNASALE)
    lower = (ax < S.X_CH) & (y < S.Y_STOMION) & (y >= S.Y_STOMION - 16)
    chin = (ax < 24.0) & (y < S.Y_STOMION - 16) & (y >= S.Y_GNATHION - 15)
    forehead = y >= S.Y_EYE + 11.0
    bottom = y < S.Y_STOMION + 3.0

    f = np.full(len(F), -1, dtype=np.int16)
    order = [
        (lid_up, ("eyelid_upper_L", "eyelid_upper_R")),
        (lid_dn, ("eyelid_lower_L", "eyelid_lower_R")),
        (nose, ("nose", "nose")),
        (corner, ("lip_corner_L", "lip_corner_R")),
        (upper, ("upper_lip", "upper_lip")),
        (lower, ("lower_lip", "lower_lip")),
        (chin, ("chin", "chin")),
        (forehead, ("forehead", "forehead")),
        (bottom, ("bottom_face", "bottom_face")),
        (np.ones(len(F), bool), ("cheek_L", "cheek_R")),
    ]
    for mask, (left, right) in order:
        m = frontal & (f < 0) & mask
        f[m] = np.where(side[m] == 0, idx[left], idx[right])
    region[frontal] = f[frontal]
    region[neck] = idx["neck"]
    region[ear & (x >= 0)] = idx["ear_L"]
    region[ear & (x < 0)] = idx["ear_R"]
    return region


def _vertex_thickness(F: np.ndarray, region: np.ndarray, n: int, factor: float) -> np.ndarray:
    """Per-vertex thickness [m]: mean of the distinct regions around the vertex (Sec. 6.2)."""
    tvals = np.array([REGION_THICKNESS_MM[r] for r in REGIONS]) * MM * factor
    pairs = np.unique(np.stack([F.ravel(), np.repeat(region, 3)], 1), axis=0)
    s = np.bincount(pairs[:, 0], weights=tvals[pairs[:, 1]], minlength=n)
    c = np.bincount(pairs[:, 0], minlength=n)
    return s / np.maximum(c, 1)


# ----------------------------------------------------------------------------- rigid parts
def _icosphere(center, radius, subdivisions):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices) + center, np.asarray(m.faces, dtype=np.int64)


def _arch(y_top, y_bottom, z_front, half_width, depth, thickness, n):
    """A U-shaped dental arch (closed box swept along a half ellipse) [mm]."""
    a = np.linspace(-np.pi * 0.47, np.pi * 0.47, n)
    cx = half_width * np.sin(a)
    cz = z_front - depth + depth * np.cos(a)
    nx, nz = np.sin(a) / half_width, np.cos(a) / depth  # outward normal of the ellipse
    nn = np.hypot(nx, nz)
    nx, nz = nx / nn, nz / nn
    rings = []
    for dy, off in ((y_top, 0.0), (y_top, -thickness), (y_bottom, -thickness), (y_bottom, 0.0)):
        rings.append(np.stack([cx + off * nx, np.full(n, dy), cz + off * nz], 1))
    V = np.concatenate(rings)
    F = []
    for r in range(4):
        a0, b0 = r * n, ((r + 1) % 4) * n
        for k in range(n - 1):
            F += [(a0 + k, b0 + k, a0 + k + 1), (a0 + k + 1, b0 + k, b0 + k + 1)]
    for k, sgn in ((0, 1), (n - 1, -1)):  # end caps
        q = [k, n + k, 2 * n + k, 3 * n + k]
        F += [(q[0], q[2], q[1]), (q[0], q[3], q[2])] if sgn > 0 else [(q[0], q[1], q[2]), (q[0], q[2], q[3])]
    F = np.asarray(F, dtype=np.int64)
    # orient outward: the front-most face's normal must point +z
    nrm = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    front = np.argmax(V[F].mean(1)[:, 2])
    if nrm[front, 2] < 0:
        F = F[:, ::-1].copy()
    return V, F


def _parts_mm(head: S.HeadShape, level: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    parts = {}
    sub = min(2 + level, 5)
    parts["eye_L"] = _icosphere(head.eyes[0].center, head.eyes[0].radius, sub)
    parts["eye_R"] = _icosphere(head.eyes[1].center, head.eyes[1].radius, sub)
    # Teeth: incisal edges meet at the stomion; crowns about 10 mm high, the arch 50 mm wide
    # and 30 mm deep (adult dental arch, e.g. Bishara et al. 1997), 11 mm behind the lip surface.
    z_front = float(head.point(np.array([0.0]), np.array([S.Y_STOMION]))[0, 2]) - 11.0
    n = 12 * 2**level + 1
    parts["teeth_upper"] = _arch(S.Y_STOMION + 10.0, S.Y_STOMION + 0.8, z_front, 25.0, 30.0, 7.0, n)
    parts["teeth_lower"] = _arch(S.Y_STOMION - 0.8, S.Y_STOMION - 9.0, z_front - 1.5, 23.0, 28.0, 7.0, n)
    # Tongue: a flattened ellipsoid resting behind the lower teeth.
    Vt, Ft = _icosphere(np.zeros(3), 1.0, sub)
    Vt = Vt * np.array([20.0, 7.0, 28.0]) + np.array([0.0, S.Y_STOMION - 8.0, z_front - 30.0])
    parts["tongue"] = (Vt, Ft)
    return parts


# ----------------------------------------------------------------------------- FDPs
def _fdp_specs(head: S.HeadShape) -> dict[str, tuple[str, np.ndarray]]:
    """FDP id -> (part, target position [mm]); the surface point is the closest one on the part.

    Head points are given by lateral coordinate and height (``xy``) or azimuth and height
    (``py``); all are solved in one vectorised call (the bisection of :meth:`HeadShape.phi_at_x`
    is elementwise, so the batch gives the same points as one call per FDP, in 1/50 the time).
    """
    eye_cut, mouth_cut = CUTS

    def xy(x, y):  # resolved below, all at once
        return ("x", float(x), float(y))

    def py(phi_deg, y):
        return ("phi", float(phi_deg), float(y))

    ye, ys = S.Y_EYE, S.Y_STOMION
    up_e = lambda x: float(eye_cut.up(np.array([abs(x)]))[0])  # noqa: E731
    dn_e = lambda x: float(eye_cut.down(np.array([abs(x)]))[0])  # noqa: E731
    up_m = lambda x: float(mouth_cut.up(np.array([abs(x)]))[0])  # noqa: E731
    dn_m = lambda x: float(mouth_cut.down(np.array([abs(x)]))[0])  # noqa: E731
    xp, xch = S.X_PUPIL, S.X_CH
    x_in = xch - 1.5  # inner lip corner, just inside the cheilion
    y_tip = S.Y_NASION - 39.0
    h = {}
    # group 2: chin, inner lip, jaw
    h["2.1"] = xy(0, S.Y_GNATHION)
    h["2.2"] = xy(0, ys + up_m(0))
    h["2.3"] = xy(0, ys - dn_m(0))
    h["2.4"] = xy(x_in, ys + up_m(x_in))
    h["2.5"] = xy(-x_in, ys + up_m(x_in))
    h["2.6"] = xy(x_in / 2, ys + up_m(x_in / 2))
    h["2.7"] = xy(-x_in / 2, ys + up_m(x_in / 2))
    h["2.8"] = xy(x_in / 2, ys - dn_m(x_in / 2))
    h["2.9"] = xy(-x_in / 2, ys - dn_m(x_in / 2))
    h["2.10"] = xy(0, S.Y_GNATHION + 13)
    h["2.11"] = xy(14, S.Y_GNATHION + 8)
    h["2.12"] = xy(-14, S.Y_GNATHION + 8)
    h["2.13"] = py(80, -80)
    h["2.14"] = py(-80, -80)
    # group 3: eyes (lid margins sit on the opened cut)
    h["3.1"] = xy(xp, ye + up_e(xp))
    h["3.2"] = xy(-xp, ye + up_e(xp))
    h["3.3"] = xy(xp, ye - dn_e(xp))
    h["3.4"] = xy(-xp, ye - dn_e(xp))
    h["3.7"] = xy(S.X_EX, ye)
    h["3.8"] = xy(-S.X_EN, ye)
    h["3.9"] = xy(xp, ye - dn_e(xp) - 3.0)
    h["3.10"] = xy(-xp, ye - dn_e(xp) - 3.0)
    h["3.11"] = xy(S.X_EN, ye)
    h["3.12"] = xy(-S.X_EX, ye)
    h["3.13"] = xy(xp, ye + up_e(xp) + 4.0)
    h["3.14"] = xy(-xp, ye + up_e(xp) + 4.0)
    # group 4: eyebrows
    for (l, r), (x, y) in {("4.1", "4.2"): (18, ye + 20), ("4.3", "4.4"): (32, ye + 24), ("4.5", "4.6"): (50, ye + 18)}.items():
        h[l], h[r] = xy(x, y), xy(-x, y)
    # group 5: cheeks
    h["5.1"], h["5.2"] = xy(40, ye - 35), xy(-40, ye - 35)
    h["5.3"], h["5.4"] = xy(52, ye - 18), xy(-52, ye - 18)
    # group 7: top of the spine, projected to the nape
    h["7.1"] = py(180, -45)
    # group 8: outer lips
    h["8.1"] = xy(0, ys + 9)
    h["8.2"] = xy(0, ys - 11)
    h["8.3"], h["8.4"] = xy(xch, ys), xy(-xch, ys)
    h["8.5"], h["8.6"] = xy(xch / 2, ys + 8), xy(-xch / 2, ys + 8)
    h["8.7"], h["8.8"] = xy(xch / 2, ys - 9), xy(-xch / 2, ys - 9)
    h["8.9"], h["8.10"] = xy(-5, ys + 10), xy(5, ys + 10)
    # group 9: nose
    sn = S.Y_SUBNASALE
    h["9.1"], h["9.2"] = xy(10, sn + 3), xy(-10, sn + 3)
    h["9.3"] = xy(0, y_tip)
    h["9.4"], h["9.5"] = xy(-S.X_AL, sn + 3), xy(S.X_AL, sn + 3)
    h["9.6"], h["9.7"] = xy(-8, S.Y_NASION - 5), xy(8, S.Y_NASION - 5)
    h["9.12"] = xy(0, S.Y_NASION - 22)
    h["9.13"], h["9.14"] = xy(9, S.Y_NASION - 22), xy(-9, S.Y_NASION - 22)
    h["9.15"] = xy(0, sn + 1)
    # group 10: ears (left ear at +x, azimuth about 99 deg; sa-sba 63 mm, pra-pa 35 mm)
    for sgn, ids in ((1, ("10.1", "10.3", "10.5", "10.7", "10.9")), (-1, ("10.2", "10.4", "10.6", "10.8", "10.10"))):
        top, back, lobe, low, upc = ids
        h[top] = py(sgn * 101, 23)
        h[back] = py(sgn * 111, -4)
        h[lobe] = py(sgn * 97, -33)
        h[low] = py(sgn * 90, -28)
        h[upc] = py(sgn * 89, 17)
    # group 11: hairline and skull
    ytr = S.Y_NASION + 62.0
    h["11.1"] = xy(0, ytr)
    h["11.2"], h["11.3"] = xy(-40, ytr - 6), xy(40, ytr - 6)
    h["11.4"] = np.array([0.0, S.Y_VERTEX, float(head.axis_z(S.Y_VERTEX))])
    h["11.5"] = h["11.4"].copy()
    h["11.6"] = py(180, 35)
    _resolve_head_points(head, h)
    specs = {k: ("head", v) for k, v in h.items()}
    # internal parts: pupils on the eyeballs, teeth, tongue
    for eid, e in (("3.5", head.eyes[0]), ("3.6", head.eyes[1])):
        specs[eid] = ("eye_L" if eid == "3.5" else "eye_R", e.center + np.array([0, 0, e.radius]))
    return specs


def _resolve_head_points(head: S.HeadShape, h: dict) -> None:
    """Replace the ``("x", x, y)`` / ``("phi", deg, y)`` requests in ``h`` by surface points [mm]."""
    req = [k for k, v in h.items() if isinstance(v, tuple)]
    if not req:
        return
    kind = np.array([h[k][0] == "x" for k in req])
    a = np.array([h[k][1] for k in req])
    y = np.array([h[k][2] for k in req])
    phi = np.deg2rad(a)
    if kind.any():
        phi[kind] = head.phi_at_x(a[kind], y[kind])
    P = head.point(phi, y)
    for k, p in zip(req, P):
        h[k] = p


def _internal_specs(parts_mm) -> dict[str, tuple[str, np.ndarray]]:
    out = {}
    Vu, _ = parts_mm["teeth_upper"]
    Vl, _ = parts_mm["teeth_lower"]
    Vt, _ = parts_mm["tongue"]

    def front_mid(V, pick):
        z = V[:, 2].max()
        c = V[np.abs(V[:, 2] - z) < 1.0]
        return np.array([0.0, pick(c[:, 1]), z])

    out["9.8"] = ("teeth_upper", front_mid(Vu, np.max))
    out["9.10"] = ("teeth_upper", front_mid(Vu, np.min))
    out["9.9"] = ("teeth_lower", front_mid(Vl, np.min))
    out["9.11"] = ("teeth_lower", front_mid(Vl, np.max))
    ctr = Vt.mean(0)
    ext = Vt.max(0) - ctr
    out["6.1"] = ("tongue", ctr + np.array([0, 0, ext[2]]))
    out["6.2"] = ("tongue", ctr + np.array([0, ext[1], 0]))
    out["6.3"] = ("tongue", ctr + np.array([ext[0], 0, 0]))
    out["6.4"] = ("tongue", ctr - np.array([ext[0], 0, 0]))
    return out


# ----------------------------------------------------------------------------- disk cache
def _source_key(level: int) -> str:
    """A hash of everything the built template depends on: the source of ``template/`` and
    ``geometry/``, the NumPy version and the level."""
    import hashlib
    from pathlib import Path

    h = hashlib.sha256(f"{level} {np.__version__} 1".encode())
    root = Path(__file__).resolve().parent
    for folder in (root, root.parent / "geometry"):
        for f in sorted(folder.glob("*.py")):
            h.update(f.name.encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:20]


def _cache_file(level: int):
    """``$FACEWARP_CACHE_DIR`` (default ``~/.cache/facewarp``; ``off``: no cache) / template file."""
    import os
    from pathlib import Path

    d = os.environ.get("FACEWARP_CACHE_DIR", "")
    if d.lower() in ("off", "0", "none"):
        return None
    root = Path(d) if d else Path(os.environ.get("XDG_CACHE_HOME", "") or Path.home() / ".cache") / "facewarp"
    return root / f"template_L{level}_{_source_key(level)}.npz"


def _to_arrays(t: Template) -> dict:
    ids = list(t.fdp)
    out = {name: getattr(t, name) for name in ("vertices", "faces", "face_region", "frontal", "thickness", "skull_depth",
                                                "condyles", "uv", "face_uv")}
    out.update(level=np.int64(t.level), thickness_factor=np.float64(t.thickness_factor), fdp_ids=np.array(ids),
               fdp_part=np.array([t.fdp[k][0] for k in ids]), fdp_face=np.concatenate([t.fdp[k][1].face for k in ids]),
               fdp_bary=np.concatenate([t.fdp[k][1].bary for k in ids]), part_names=np.array(list(t.parts)))
    for k, (PV, PF) in t.parts.items():
        out[f"part_V_{k}"], out[f"part_F_{k}"] = PV, PF
    return out


def _from_arrays(z) -> Template:
    fdp = {str(k): (str(p), SurfacePoints(z["fdp_face"][i:i + 1], z["fdp_bary"][i:i + 1]))
           for i, (k, p) in enumerate(zip(z["fdp_ids"], z["fdp_part"]))}
    parts = {str(k): (z[f"part_V_{k}"], z[f"part_F_{k}"]) for k in z["part_names"]}
    return Template(vertices=z["vertices"], faces=z["faces"], face_region=z["face_region"], frontal=z["frontal"],
                    thickness=z["thickness"], skull_depth=z["skull_depth"], condyles=z["condyles"], fdp=fdp, parts=parts,
                    level=int(z["level"]), thickness_factor=float(z["thickness_factor"]), uv=z["uv"], face_uv=z["face_uv"])


@functools.lru_cache(maxsize=4)
def _build(level: int) -> Template:
    """The template of ``level``: from the disk cache when its source key matches (building
    takes ~1 s at level 0, reading it ~10 ms), else built and written there (best effort: a
    cache that cannot be written is skipped)."""
    import os

    path = _cache_file(level)
    if path is not None and path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                return _from_arrays(z)
        except (OSError, ValueError, KeyError):
            pass
    t = _build_template(level)
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
            np.savez(tmp, **_to_arrays(t))
            os.replace(tmp, path)
        except OSError:
            pass
    return t


# ----------------------------------------------------------------------------- assembly
def _build_template(level: int) -> Template:
    head = S.HeadShape()
    raw = build_raw_head(level, head)
    V_mm, F = raw.vertices, raw.faces
    region = _classify_faces(V_mm, F, raw.phi)
    frontal = np.isin(region, [REGIONS.index(r) for r in FRONTAL_REGIONS])
    thickness = _vertex_thickness(F, region, len(V_mm), THICKNESS_FACTOR)
    skull = head.skull_depth(raw.phi, raw.y) * MM
    parts_mm = _parts_mm(head, level)
    specs = _fdp_specs(head)
    specs.update(_internal_specs(parts_mm))
    parts = {k: (v * MM, f) for k, (v, f) in parts_mm.items()}
    V = V_mm * MM
    fdp = {}
    by_part: dict[str, list[str]] = {}
    for fid, (part, _) in specs.items():
        by_part.setdefault(part, []).append(fid)
    for part, ids in by_part.items():
        PV, PF = (V, F) if part == "head" else parts[part]
        P = np.array([specs[i][1] for i in ids]) * MM
        sp = closest_surface_points(PV, PF, P)
        for k, fid in enumerate(ids):
            fdp[fid] = (part, SurfacePoints(sp.face[k : k + 1], sp.bary[k : k + 1]))
    missing = set(FDP_IDS) - set(fdp)
    assert not missing, f"template lacks FDPs {sorted(missing)}"
    fdp = {k: fdp[k] for k in FDP_IDS}
    # Condyles: 10-13 mm in front of the tragion, intercondylar distance about 100 mm.
    condyles = np.array([[50.0, -8.0, 12.0], [-50.0, -8.0, 12.0]]) * MM
    layout = face_uv_layout(V, F, region, REGIONS, frontal)
    return Template(
        vertices=V,
        faces=F,
        face_region=region,
        frontal=frontal,
        thickness=thickness,
        skull_depth=skull,
        condyles=condyles,
        fdp=fdp,
        parts=parts,
        level=level,
        uv=layout.uv,
        face_uv=layout.face_uv,
    )


def default_template(level: int = 0) -> Template:
    """The default head at resolution ``level`` (0..MAX_LEVEL); level 0 has about 3,400 vertices.

    The result is cached per level; treat its arrays as read-only (copy before editing).
    """
    if not isinstance(level, (int, np.integer)) or isinstance(level, bool) or not 0 <= level <= MAX_LEVEL:
        raise InputError(f"level: expected an integer 0..{MAX_LEVEL}, got {level!r}")
    return _build(int(level))
