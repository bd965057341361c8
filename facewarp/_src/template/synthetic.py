"""A synthetic range scan made from the default head: another face, scanned (for ``facewarp demo``).

The other face is the default template deformed by a smooth map ``D`` of the head frame whose
parts are named anthropometric changes, drawn from a seed (:class:`FaceProportions`):

1. anisotropic scale about the head's centre: head width (x), height (y), depth (z);
2. a longer or shorter lower face: every point below the subnasale (FDP 9.15) moves down by up to
   ``lower_face`` with a smoothstep over 40 mm, so the mouth, chin and jaw drop together;
3. Gaussian bumps at named FDPs: the nose tip (9.3) forward, the chin (2.1) forward or back, the
   cheekbones (5.3 / 5.4) and the jaw angles (2.13 / 2.14) outward, the brow ridge (4.3 / 4.4)
   forward; each bump is ``a exp(-|x - c|^2 / (2 s^2))`` along its direction, with ``|a| / s``
   below 0.3, so ``D`` stays smooth and one-to-one.

The scan of that face is what a structured-light scanner gives: the level-1 surface of the
template deformed by ``D`` and re-tessellated by edge collapse (libigl ``decimate``: no scan
vertex sits at a template vertex), Gaussian noise along the vertex normals, holes (discs cut out
of the frontal face away from the FDPs), a random rigid pose, and millimetres in the files. Its
FDPs are the template's, moved by ``D`` and the pose; a few of them are kept apart as markers
(the marker error E_m of Sec. 5.2). Because ``D`` is known, the true position of every template
vertex on the scan is known too (:attr:`SyntheticScan.truth`), so the adaptation's vertex error
E_v can be measured exactly.

The scan has colour, as a photogrammetry or structured-light scan with a colour camera does:
per-vertex sRGB values (:func:`skin_color`) of a procedural face drawn from the seed: one of
four skin tones with a little low-frequency variation and a blush on the cheeks, darker
eyebrows along the brow FDPs, lips between the mouth's FDPs, and hair above a hairline. The
colour is a function of the point on the *template* (before ``D``), so it sits on the features
wherever ``D`` moves them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ..core.errors import InputError
from ..geometry.surface import vertex_normals
from .head import FRONTAL_REGIONS, REGIONS, Template, default_template

__all__ = ["FaceProportions", "SCAN_LANDMARKS", "SCAN_MARKERS", "SKIN_TONES", "SyntheticScan", "skin_color",
           "synthetic_scan"]

SKIN_TONES = ((0.88, 0.71, 0.60), (0.80, 0.60, 0.47), (0.64, 0.45, 0.33), (0.45, 0.31, 0.22))
"""sRGB skin tones of the synthetic faces, light to dark (one is drawn per seed)."""

_BROW = (0.23, 0.16, 0.11)  # sRGB of brows and hair (dark brown)
_LIP = (0.92, 0.66, 0.66)  # lip colour: a factor on the skin tone
_BLUSH = (1.0, 0.92, 0.92)  # cheek blush: a factor on the skin colour


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _polyline_distance(P2, Q2):
    """Distance of 2D points P2 (k, 2) to the polyline Q2 (q, 2) and the arc parameter in [0, 1]."""
    best = np.full(len(P2), np.inf)
    s_best = np.zeros(len(P2))
    seg = np.linalg.norm(np.diff(Q2, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
    for i in range(len(Q2) - 1):
        a, b = Q2[i], Q2[i + 1]
        t = np.clip(((P2 - a) @ (b - a)) / max(float((b - a) @ (b - a)), 1e-30), 0.0, 1.0)
        d = np.linalg.norm(P2 - (a + t[:, None] * (b - a)), axis=1)
        better = d < best
        best[better] = d[better]
        s_best[better] = (cum[i] + t * (cum[i + 1] - cum[i]))[better]
    return best, s_best


def skin_color(P, landmarks: dict, seed: int = 0) -> np.ndarray:
    """The synthetic face's colour at points of the default template's head (see the module docstring).

    Args:
        P: Points on (or near) the template's skin, template frame [m], shape (k, 3), float.
        landmarks: The template's FDP id -> position [m] (brows 4.1-4.6, lips 8.1-8.4, eyes 3.7/3.12).
        seed: Picks the skin tone and the variation.

    Returns:
        sRGB colours in [0, 1], shape (k, 3), float64.
    """
    P = np.asarray(P, dtype=np.float64)
    lm = {k: np.asarray(v, dtype=np.float64) for k, v in landmarks.items()}
    rng = np.random.default_rng([int(seed), 7])
    tone = np.array(SKIN_TONES[int(rng.integers(len(SKIN_TONES)))])
    x, y, z = P[:, 0], P[:, 1], P[:, 2]
    # low-frequency variation: three plane waves of 4-9 cm wavelength, +-4 % lightness, a little redness
    var = np.zeros(len(P))
    for _ in range(3):
        k = rng.normal(size=3)
        k *= 2 * np.pi / rng.uniform(0.04, 0.09) / np.linalg.norm(k)
        var += np.sin(P @ k + rng.uniform(0, 2 * np.pi)) / 3.0
    C = tone[None, :] * (1.0 + 0.04 * var[:, None])
    C[:, 0] *= 1.0 + 0.015 * var
    front = _smoothstep((z - (lm["3.7"][2] - 0.03)) / 0.01)  # the face front, not the back of the head
    # blush on the cheeks
    for c in ("5.3", "5.4"):
        if c in lm:
            w = np.exp(-np.sum((P - lm[c] + [0, 0.008, 0]) ** 2, axis=1) / (2 * 0.016**2)) * front
            C = C * (1.0 - w[:, None] * (1.0 - np.array(_BLUSH)))
    # brows: 4.1 (inner), 4.3 (top), 4.5 (outer) per side, 3.5 mm half width tapering outward
    brow = np.zeros(len(P))
    for ids in (("4.1", "4.3", "4.5"), ("4.2", "4.4", "4.6")):
        Q = np.array([lm[k] for k in ids])
        d, s = _polyline_distance(P[:, :2], Q[:, :2])
        half = 0.0042 * (1.0 - 0.45 * s)
        brow = np.maximum(brow, _smoothstep((half - d) / 0.0015 + 0.5))
    brow *= front
    C = C * (1 - 0.85 * brow[:, None]) + np.array(_BROW) * 0.85 * brow[:, None]
    # lips: between the outer lip contours through 8.1 (top), 8.2 (bottom) and the corners 8.3 / 8.4
    xc = 0.5 * abs(lm["8.3"][0] - lm["8.4"][0])
    y_st = 0.5 * (lm["8.3"][1] + lm["8.4"][1])
    r = np.clip(1.0 - (x / xc) ** 2, 0.0, None) ** 0.6
    y_up = y_st + (lm["8.1"][1] - y_st) * r
    y_dn = y_st - (y_st - lm["8.2"][1]) * r
    inside = np.minimum(y_up - y, y - y_dn)
    lip = _smoothstep(inside / 0.0012 + 0.5) * (np.abs(x) < xc) * front
    lip_col = np.array(_LIP) * tone
    C = C * (1 - lip[:, None]) + lip_col * lip[:, None]
    # hair: above a hairline at the trichion (62 mm above the nasion) in front, lower toward the back
    c = 0.5 * (lm["3.7"] + lm["3.12"])
    az = np.arctan2(x - c[0], z - (c[2] - 0.09))  # azimuth about a vertical axis in the head
    y_tr = c[1] + 0.072
    y_hair = y_tr - 0.11 * ((1 - np.cos(az)) / 2) ** 1.2
    hair = _smoothstep((y - y_hair) / 0.008 + 0.5)
    C = C * (1 - hair[:, None]) + np.array(_BROW) * (1.0 + 0.15 * var[:, None]) * hair[:, None]
    return np.clip(C, 0.0, 1.0)


SCAN_LANDMARKS = (
    "2.1", "2.2", "2.3", "2.10", "2.13", "2.14", "3.7", "3.8", "3.11", "3.12", "4.1", "4.2", "4.5", "4.6",
    "5.3", "5.4", "8.1", "8.2", "8.3", "8.4", "9.3", "9.4", "9.5", "9.15", "10.9", "10.10", "11.1", "11.4",
)
"""FDPs given with the scan, as a user would pick them (28: eyes, brows, nose, lips, chin, jaw, ears, head)."""

SCAN_MARKERS = ("3.13", "3.14", "4.3", "4.4", "5.1", "5.2", "8.5", "8.6", "8.7", "8.8", "9.6", "9.7")
"""FDPs held out of the adaptation and used as markers for E_m (Sec. 5.2)."""

# (name, FDP ids, direction per FDP (unit, template frame), sigma [m]) of the bump fields
_BUMPS = (
    ("nose", ("9.3",), ((0.0, 0.0, 1.0),), 0.014),
    ("chin", ("2.1",), ((0.0, -0.3, 0.95),), 0.018),
    ("cheek", ("5.3", "5.4"), ((1.0, 0.0, 0.3), (-1.0, 0.0, 0.3)), 0.022),
    ("jaw", ("2.13", "2.14"), ((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0)), 0.025),
    ("brow", ("4.3", "4.4"), ((0.0, 0.2, 1.0), (0.0, 0.2, 1.0)), 0.016),
)
_LOWER_FACE_RAMP = 0.040  # [m] below the subnasale over which the lower-face shift ramps in


@dataclass(frozen=True)
class FaceProportions:
    """How the synthetic face differs from the default head.

    Attributes:
        width, height, depth: Scale factors of the head along x, y, z (about its centre).
        lower_face: Extra length of the face below the subnasale [m] (negative: shorter).
        nose, chin, cheek, jaw, brow: Amplitudes [m] of the bumps at the nose tip (forward), the
            chin (forward), the cheekbones (outward), the jaw angles (outward) and the brow
            ridge (forward); negative values go the other way.
    """

    width: float = 1.0
    height: float = 1.0
    depth: float = 1.0
    lower_face: float = 0.0
    nose: float = 0.0
    chin: float = 0.0
    cheek: float = 0.0
    jaw: float = 0.0
    brow: float = 0.0

    @classmethod
    def random(cls, seed: int = 0) -> FaceProportions:
        """Proportions drawn from ``seed``: each change between half and all of its range
        (about two standard deviations of adult norms, Farkas 1994), with a random sign."""
        rng = np.random.default_rng(seed)

        def draw(limit):
            return float(rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 1.0) * limit)

        return cls(width=1.0 + draw(0.06), height=1.0 + draw(0.04), depth=1.0 + draw(0.05),
                   lower_face=draw(0.007), nose=draw(0.004), chin=draw(0.004), cheek=draw(0.004),
                   jaw=draw(0.005), brow=draw(0.0025))

    def to_dict(self) -> dict:
        """The fields (lengths in metres)."""
        return asdict(self)


def deform(P, proportions: FaceProportions, landmarks: dict, center) -> np.ndarray:
    """The smooth map ``D`` of the module docstring applied to points P (k, 3) [m] (template frame).

    Args:
        P: Points [m], shape (k, 3), float.
        proportions: The changes.
        landmarks: Template FDP id -> position [m] (bump centres, the subnasale height).
        center: Centre of the anisotropic scale [m], shape (3,).

    Returns:
        Moved points [m], shape (k, 3), float64.
    """
    P = np.asarray(P, dtype=np.float64)
    p = proportions
    c = np.asarray(center, dtype=np.float64)
    out = c + (P - c) * np.array([p.width, p.height, p.depth])
    s = np.clip((landmarks["9.15"][1] - P[:, 1]) / _LOWER_FACE_RAMP, 0.0, 1.0)
    out[:, 1] -= p.lower_face * s * s * (3.0 - 2.0 * s)
    for name, ids, dirs, sigma in _BUMPS:
        a = getattr(p, name)
        if a == 0.0:
            continue
        for fid, d in zip(ids, dirs):
            d = np.asarray(d) / np.linalg.norm(d)
            w = np.exp(-np.sum((P - landmarks[fid]) ** 2, axis=1) / (2.0 * sigma**2))
            out += a * w[:, None] * d
    return out


@dataclass
class SyntheticScan:
    """A scan-like mesh of another face with its FDPs (see the module docstring).

    Attributes:
        vertices: Scan vertices [m] in the scan's frame, shape (k, 3), float64 (write them in
            ``units``).
        faces: Scan triangles, shape (l, 3), int64.
        landmarks: FDP id -> position [m] in the scan's frame, shape (3,) (:data:`SCAN_LANDMARKS`).
        markers: FDP id -> position [m] in the scan's frame, held out (:data:`SCAN_MARKERS`).
        truth: Where each vertex of the level-``level`` template lies on the scanned face [m],
            scan frame, shape (n, 3), float64 (``D`` and the pose applied to the template).
        rotation, translation: The pose, scan = R @ x + t, shapes (3, 3) and (3,) [m].
        proportions: How the face differs from the template.
        units: Unit of the scan's files ("mm").
        seed: The seed it was made from.
        level: Template level of :attr:`truth`.
        colors: Per-vertex colour of the scan, shape (k, 3), float64 sRGB in [0, 1]
            (:func:`skin_color`), or None.
    """

    vertices: np.ndarray
    faces: np.ndarray
    landmarks: dict
    markers: dict
    truth: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    proportions: FaceProportions
    units: str = "mm"
    seed: int = 0
    level: int = 0
    colors: np.ndarray | None = None


def _random_rotation(rng, max_angle: float) -> np.ndarray:
    """A rotation (3, 3) about a uniformly random axis by an angle uniform in [-max_angle, max_angle]."""
    from scipy.spatial.transform import Rotation

    axis = rng.normal(size=3)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * rng.uniform(-max_angle, max_angle)).as_matrix()


def _holes(V, F, centres, radius) -> tuple[np.ndarray, np.ndarray]:
    """V, F without the faces whose centroid lies within ``radius`` of a centre, unused vertices dropped."""
    C = V[F].mean(axis=1)
    keep = np.ones(len(F), dtype=bool)
    for c in centres:
        keep &= np.linalg.norm(C - c, axis=1) > radius
    F = F[keep]
    used = np.unique(F)
    remap = np.full(len(V), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


def _hole_centres(rng, V, frontal_vertices, avoid, count, clearance) -> list:
    centres: list = []
    candidates = rng.permutation(frontal_vertices)
    for i in candidates:
        if len(centres) == count:
            break
        c = V[i]
        if np.linalg.norm(avoid - c, axis=1).min() > clearance and all(np.linalg.norm(c - q) > 3 * clearance for q in centres):
            centres.append(c)
    return centres


def synthetic_scan(seed: int = 0, *, level: int = 0, proportions: FaceProportions | None = None, faces: int = 20000,
                   noise: float = 0.00015, holes: int = 4, hole_radius: float = 0.006,
                   max_rotation: float = math.radians(25.0), max_translation: float = 0.2) -> SyntheticScan:
    """Make a scan of another face (see the module docstring).

    Args:
        seed: Seed of the proportions (unless given), the noise, holes and pose.
        level: Template level whose vertices :attr:`SyntheticScan.truth` gives (the level the
            scan will be adapted with), 0..4.
        proportions: The face's changes; default :meth:`FaceProportions.random` of ``seed``.
        faces: Triangles of the scan after re-tessellation (>= 1000).
        noise: Standard deviation of the noise along the normals [m] (>= 0).
        holes: Number of holes cut into the frontal face (>= 0).
        hole_radius: Radius of each hole [m] (> 0).
        max_rotation: Largest angle of the random pose [rad] (>= 0).
        max_translation: Largest offset of the random pose along each axis [m] (>= 0).

    Returns:
        The :class:`SyntheticScan`.

    Raises:
        InputError: an argument out of its range (naming it).
    """
    import igl

    checks = (("faces", faces, 1000), ("holes", holes, 0))
    for name, v, lo in checks:
        if not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= lo):
            raise InputError(f"{name}: expected a whole number >= {lo}, got {v!r}")
    for name, v, positive in (("noise", noise, False), ("hole_radius", hole_radius, True),
                              ("max_rotation", max_rotation, False), ("max_translation", max_translation, False)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and (v > 0 if positive else v >= 0)):
            raise InputError(f"{name}: expected a finite number {'> 0' if positive else '>= 0'}, got {v!r}")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool):
        raise InputError(f"seed: expected a whole number, got {seed!r}")
    props = proportions or FaceProportions.random(int(seed))
    rng = np.random.default_rng([int(seed), 1])
    fine: Template = default_template(1)  # the surface that is scanned (its own tessellation is replaced)
    target: Template = default_template(level)
    lm = target.landmarks()
    center = 0.5 * (target.vertices.min(0) + target.vertices.max(0))

    V = deform(fine.vertices, props, lm, center)
    F = np.asarray(fine.faces, dtype=np.int64)
    frontal_ids = [REGIONS.index(r) for r in FRONTAL_REGIONS]
    frontal_v = np.unique(F[np.isin(fine.face_region, frontal_ids)])
    res = igl.decimate(V, F, int(faces))
    SV = np.asarray(res[0], dtype=np.float64)
    SF = np.asarray(res[1], dtype=np.int64)
    SV = SV + vertex_normals(SV, SF) * rng.normal(scale=noise, size=(len(SV), 1))
    fdp_head = {k: v for k, v in fine.landmarks().items() if fine.fdp[k][0] == "head"}  # on the scanned surface
    moved = dict(zip(fdp_head, deform(np.array(list(fdp_head.values())), props, lm, center)))
    centres = _hole_centres(rng, V, frontal_v, np.array(list(moved.values())), holes, 2.0 * hole_radius + 0.004)
    SV, SF = _holes(SV, SF, centres, hole_radius)

    R = _random_rotation(rng, float(max_rotation))
    t = rng.uniform(-max_translation, max_translation, size=3)

    def pose(X):
        return np.asarray(X) @ R.T + t

    truth = pose(deform(target.vertices, props, lm, center))
    # colour: each scan vertex's point on the deformed surface, taken back to the template
    from ..geometry.surface import closest_point

    cp = closest_point(V, F, SV)
    on_template = np.einsum("kc,kcd->kd", cp.bary, fine.vertices[F[cp.face]])
    colors = skin_color(on_template, fine.landmarks(), int(seed))
    return SyntheticScan(vertices=pose(SV), faces=SF, colors=colors,
                         landmarks={k: pose(moved[k]) for k in SCAN_LANDMARKS},
                         markers={k: pose(moved[k]) for k in SCAN_MARKERS},
                         truth=truth, rotation=R, translation=t, proportions=props, seed=int(seed),
                         level=int(target.level))
