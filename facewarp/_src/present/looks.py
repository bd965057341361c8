"""How a head looks: the one palette and the face groups (lips, sclera, iris, pupil, gums) that
every output uses -- the USD animation and UsdSkel rig (``usd_export``'s ``part_colors`` and
``subsets``), the glTF rig (one primitive per look) and the package's renders
(:func:`part_vertex_colors`) -- plus a framing camera for the USD files.

The groups are found on the rig's own geometry, so they follow any adapted head:

- **lips**: skin faces inside the outer lip contour (FDPs 8.1-8.10, MPEG-4) seen from the front
  (the contour's points sorted by angle about their centroid in the x-y plane), and in front of
  the contour's mean depth less :data:`LIP_DEPTH`; a head with a skin texture (baked from its scan,
  or its preview colours painted over the UVs) takes its lips from the texture instead;
- **eyes**: the gaze axis of an eyeball runs from its centre (the mean of its vertices) to its
  pupil FDP (3.5 left, 3.6 right: whichever lies on the ball), else along +z, the head frame's
  forward axis. A face whose centre lies within :func:`eye_angles`' pupil / iris half-angle of
  that axis is **Pupil** / **Iris**, the rest **Sclera**: the three partition the ball's faces;
- **teeth and gums**: a tooth row (a part named ``teeth``/``tooth`` with ``upper`` or ``lower``) is
  drawn and exported split at its gum line (:func:`tooth_mesh`): the plane across the row
  :data:`GUM_HEIGHT` from its root end (a third of the row's height at most), measured along the
  row's vertical (its vertices' axis of least spread, turned to point at the root: up, +y, for the
  upper row, down for the lower). The faces on the root side are **Gums** (pink), the rest the
  teeth (ivory). The template's rows are closed bands from the incisal edge to the root, so the
  gums are the root end of each band, labial and lingual, and follow any adapted head (the rows'
  own geometry). Only the looks are split: the simulated tooth meshes (contact, FDPs) stay as
  they are, and a split row is the same surface (its faces cut in two at the line), riding its
  part's motion (upper row: the skull, lower row: the jaw). The ICT-FaceKit's own gums are part of
  its ``tongue`` mesh (:mod:`~facewarp._src.importers.ict`) and take the tongue's colour; its tooth
  rows carry their roots (about 28 mm high), so their gum band is the 3 mm at the roots' tips;
- the **tongue** is one colour.

The names of the looks (USD ``Looks/<name>`` materials and ``GeomSubset`` s, glTF materials) are
``Lips`` (skin subset), ``Sclera``, ``Iris``, ``Pupil`` (eyeball subsets), ``Gums`` (tooth-row
subsets), and the parts' own materials ``Eye_L``, ``Eye_R`` (sclera), ``Teeth_Upper``,
``Teeth_Lower`` (ivory) and ``Tongue``.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.errors import InputError

__all__ = ["COLORS", "GUM_HEIGHT", "IRIS_DIAMETER", "LIP_DEPTH", "PUPIL_DIAMETER", "drawn_part", "eye_angles",
           "eye_looks", "gaze_axis", "gum_plane", "head_camera", "head_looks", "iris_rgb", "lip_faces", "part_kind",
           "part_looks", "part_vertex_colors", "refine_ball", "rest_fdps", "tooth_mesh"]

COLORS = {
    "skin": (0.87, 0.72, 0.62),
    "lips": (0.78, 0.47, 0.45),
    "mouth": (0.45, 0.20, 0.20),  # the lips' inner sheets (previews)
    "cavity": (0.16, 0.05, 0.05),  # the inside of the head seen through the open mouth (previews)
    "sclera": (0.94, 0.93, 0.89),  # off-white
    "iris": (0.30, 0.19, 0.08),  # brown-hazel, the commonest iris colour
    "pupil": (0.02, 0.02, 0.02),  # near-black
    "teeth": (0.95, 0.93, 0.85),  # ivory
    "gums": (0.72, 0.30, 0.33),  # gingiva: coral pink, deeper than the lips and the tongue
    "tongue": (0.76, 0.36, 0.38),  # muscle red-pink
}
"""Linear RGB (0..1) of each look, the one palette of every output."""

IRIS_DIAMETER = 11.7e-3
"""Visible iris diameter [m]: the horizontal visible iris diameter of adults is 11.7 +- 0.5 mm
(Ruefer, Schroeder, Erb, J. Cataract Refract. Surg. 31 (2005) 1150: 11.71 mm, SD 0.42, n = 689;
textbook range 11.5-12 mm)."""

PUPIL_DIAMETER = 4.0e-3
"""Pupil diameter [m]: 3-5 mm in room light (2 mm in bright light, 8 mm dark-adapted; Watson and
Yellott, J. Vision 12(10):12 (2012)); the middle of the room-light range."""

GUM_HEIGHT = 3.0e-3
"""Height of the gums drawn on a tooth row [m], from its root end toward the crown: the attached
gingiva at the incisors is about 3.5-4.5 mm wide in the upper jaw and 3.3-3.9 mm in the lower
(textbook values, Lindhe, Clinical Periodontology and Implant Dentistry); 3 mm leaves the
template's crowns (10 and 8.2 mm high) 7 and 5.2 mm of ivory."""

LIP_DEPTH = 0.012
"""How far behind the lip contour's mean depth faces still count as lips [m]."""

_LIP_CONTOUR = tuple(f"8.{k}" for k in range(1, 11))
_PUPILS = ("3.5", "3.6")


def iris_rgb(iris_color=None) -> tuple:
    """The iris colour to use: ``iris_color`` (RGB (3,) in 0..1, linear) checked, or :data:`COLORS` ``["iris"]``.

    Raises:
        InputError: ``iris_color`` is not three numbers in 0..1.
    """
    if iris_color is None:
        return COLORS["iris"]
    try:
        c = np.asarray(iris_color, dtype=np.float64)
    except (TypeError, ValueError):
        c = np.zeros(0)
    if c.shape != (3,) or not np.isfinite(c).all() or (c < 0).any() or (c > 1).any():
        raise InputError(f"iris_color: expected an RGB colour of three numbers in 0..1, got {iris_color!r}")
    return tuple(float(v) for v in c)


def part_kind(name: str) -> str:
    """What a rigid part is, from its name: ``"eye"``, ``"teeth"``, ``"tongue"`` or ``"other"``."""
    low = str(name).lower()
    if "eye" in low:
        return "eye"
    if "teeth" in low or "tooth" in low:
        return "teeth"
    return "tongue" if "tongue" in low else "other"


def rest_fdps(fr) -> dict:
    """Rest positions [m] of a face rig's FDPs, on the skin and on the parts: id -> (3,) float64."""
    out = {}
    V = np.asarray(fr.head_vertices, np.float64)
    F = np.asarray(fr.head_faces)
    parts = dict(fr.parts)
    for fid, part, f, b in zip(fr.fdp_ids, fr.fdp_part, fr.fdp_face, fr.fdp_bary):
        part = str(part)
        if part == "head":
            out[str(fid)] = np.asarray(b, np.float64) @ V[F[int(f)]]
        elif part in parts:
            Vp, Fp = np.asarray(parts[part][0], np.float64), np.asarray(parts[part][1])
            out[str(fid)] = np.asarray(b, np.float64) @ Vp[Fp[int(f)]]
    return out


def gaze_axis(V, fdps: dict | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre, gaze axis and radius of an eyeball.

    Args:
        V: The eyeball's vertices [m], shape (k, 3), float (a closed ball-like mesh).
        fdps: Optional FDP id -> rest position (3,) [m]; the pupil FDP (3.5 or 3.6) that lies on
            the ball (within half a radius of its surface) gives the gaze.

    Returns:
        centre (3,) float64 [m] (the vertices' mean), unit gaze axis (3,) float64 (centre to the
        pupil FDP, else +z, the head's forward axis) and the mean radius [m].
    """
    V = np.asarray(V, np.float64)
    c = V.mean(0)
    R = float(np.linalg.norm(V - c, axis=1).mean())
    axis, best = np.array([0.0, 0.0, 1.0]), math.inf
    for pid in _PUPILS:
        p = None if fdps is None else fdps.get(pid)
        if p is None:
            continue
        d = np.asarray(p, np.float64) - c
        r = float(np.linalg.norm(d))
        if abs(r - R) < 0.5 * R and r < best:
            axis, best = d / r, r
    return c, axis, R


def eye_angles(radius: float) -> tuple[float, float]:
    """Half-angles [rad] of the pupil and the iris seen from the centre of an eyeball of ``radius`` [m]:
    ``asin(d / 2 / radius)`` for :data:`PUPIL_DIAMETER` and :data:`IRIS_DIAMETER` (9.6 and 29.2 deg
    on a 24 mm ball)."""
    r = max(float(radius), 1e-9)
    return (math.asin(min(1.0, 0.5 * PUPIL_DIAMETER / r)), math.asin(min(1.0, 0.5 * IRIS_DIAMETER / r)))


def _gaze_angles(P: np.ndarray, c: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Angles [rad] between the gaze axis ``a`` (3,) and the directions from the centre ``c`` (3,)
    to the points ``P`` (k, 3) [m], shape (k,)."""
    D = P - c
    return np.arccos(np.clip(D @ a / np.maximum(np.linalg.norm(D, axis=1), 1e-30), -1.0, 1.0))


def _part_rgb(kind: str) -> tuple:
    """A part's own colour by :func:`part_kind`: sclera for an eyeball, the tongue's, else the teeth's (ivory)."""
    return COLORS["sclera" if kind == "eye" else "tongue" if kind == "tongue" else "teeth"]


def _axis_faces(V: np.ndarray, F: np.ndarray, c: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Faces F (m, 3) of V (k, 3) that the ray from c along a passes through (edges and corners
    included), shape (m,) bool."""
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = B - A, C - A
    h = np.cross(a, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > 1e-30
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = c - A
    u = inv * np.einsum("ij,ij->i", s, h)
    q = np.cross(s, e1)
    v = inv * (q @ a)
    t = inv * np.einsum("ij,ij->i", e2, q)
    tol = 1e-6
    return ok & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol) & (t > 0)


def eye_looks(V, F, fdps: dict | None = None, *, iris_color=None) -> dict:
    """The faces of an eyeball's sclera, iris and pupil (see the module docstring).

    Args:
        V: The eyeball's rest vertices [m], shape (k, 3), float. F: Its triangles, shape (m, 3), int.
        fdps: Optional FDP id -> rest position (3,) [m] for the gaze (:func:`gaze_axis`).
        iris_color: Optional iris RGB (3,) in 0..1 (default :data:`COLORS` ``["iris"]``).

    Returns:
        ``{"Sclera": (faces, RGB), "Iris": (faces, RGB), "Pupil": (faces, RGB)}``, faces (j,) int64:
        each face of the ball in exactly one. A face is pupil if its centre lies within the pupil's
        half-angle of the gaze axis or the axis passes through it (a coarse ball still gets a pupil),
        else iris within the iris' half-angle, else sclera.
    """
    V, F = np.asarray(V, np.float64), np.asarray(F, np.int64)
    c, a, R = gaze_axis(V, fdps)
    pupil_half, iris_half = eye_angles(R)
    ang = _gaze_angles(V[F].mean(1), c, a)
    pupil = (ang <= pupil_half) | _axis_faces(V, F, c, a)
    iris = ~pupil & (ang <= iris_half)
    return {"Sclera": (np.flatnonzero(~pupil & ~iris), COLORS["sclera"]),
            "Iris": (np.flatnonzero(iris), iris_rgb(iris_color)),
            "Pupil": (np.flatnonzero(pupil), COLORS["pupil"])}


def gum_plane(name: str, V) -> tuple[np.ndarray, float] | None:
    """The gum line of a tooth row (see the module docstring), or None for any other part.

    Args:
        name: The part's name: a tooth row has ``teeth`` or ``tooth`` and ``upper`` or ``lower`` in it.
        V: The row's rest vertices [m], shape (k, 3), float.

    Returns:
        (unit axis (3,) float64 pointing from the crowns to the roots, level [m]): a point ``p`` is
        on the gums' side where ``p @ axis > level``. The axis is the vertices' direction of least
        spread (the row's height; +-y, the head's vertical, if that direction is more than 45 deg
        from it), the level :data:`GUM_HEIGHT` (at most a third of the row's height) below the
        root end.
    """
    low = str(name).lower()
    if part_kind(name) != "teeth" or ("upper" in low) == ("lower" in low):
        return None
    V = np.asarray(V, np.float64)
    if len(V) < 4:
        return None
    X = V - V.mean(0)
    a = np.linalg.eigh(X.T @ X)[1][:, 0]
    if abs(a[1]) < math.sqrt(0.5):
        a = np.array([0.0, 1.0, 0.0])
    a = a * (1.0 if "upper" in low else -1.0) * math.copysign(1.0, a[1])
    h = V @ a
    return a, float(h.max() - min(GUM_HEIGHT, np.ptp(h) / 3.0))


def _edge_points(V: np.ndarray, d: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Where the edges (i, j) (each (k,) int) cross the level d = 0, (k, 3) [m]; computed from the
    lower index, so both triangles of an edge get the very same point."""
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    t = d[lo] / (d[lo] - d[hi])
    return V[lo] + t[:, None] * (V[hi] - V[lo])


def _welded(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A triangle soup T (m, 3, 3) [m] as vertices (k, 3) and faces (m, 3) int64, equal corners merged."""
    if not len(T):
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    V, inv = np.unique(T.reshape(-1, 3), axis=0, return_inverse=True)
    return V, inv.reshape(-1, 3).astype(np.int64)


def tooth_mesh(name: str, V, F) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A part's mesh for the looks: a tooth row split at its gum line, any other part as it is.

    Each triangle that the gum line (:func:`gum_plane`) crosses is cut in three, so every face lies
    on one side; the two sides are separate pieces (the vertices on the line doubled), so per-vertex
    colours stay sharp at the line. The surface is the same: only the drawing is split.

    Args:
        name: The part's name. V: Its rest vertices [m], shape (k, 3), float. F: Its triangles, shape (m, 3), int.

    Returns:
        Vertices (k', 3) float64 [m], triangles (m', 3) int64 (the teeth's, then the gums') and the
        gum faces (g,) int64 (none for a part that is not a tooth row).
    """
    V, F = np.asarray(V, np.float64), np.asarray(F, np.int64)
    plane = gum_plane(name, V)
    if plane is None:
        return V, F, np.zeros(0, np.int64)
    a, level = plane
    d = V @ a - level
    g = d[F] > 0
    n = g.sum(1)
    sides = [[V[F[n == 0]]], [V[F[n == 3]]]]  # triangle soups (m, 3, 3): teeth, gums
    mixed = (n == 1) | (n == 2)
    if mixed.any():
        Fm, gm = F[mixed], g[mixed]
        lone_gum = n[mixed] == 1
        k = np.where(lone_gum, np.argmax(gm, 1), np.argmin(gm, 1))  # the vertex alone on its side
        R = np.take_along_axis(Fm, (k[:, None] + np.arange(3)) % 3, 1)  # rolled: the lone vertex first
        A, B, C = V[R[:, 0]], V[R[:, 1]], V[R[:, 2]]
        pab, pac = _edge_points(V, d, R[:, 0], R[:, 1]), _edge_points(V, d, R[:, 0], R[:, 2])
        lone = np.stack([A, pab, pac], 1)
        rest = np.concatenate([np.stack([pab, B, C], 1), np.stack([pab, C, pac], 1)])
        rest_gum = np.concatenate([~lone_gum, ~lone_gum])
        sides[0] += [lone[~lone_gum], rest[~rest_gum]]
        sides[1] += [lone[lone_gum], rest[rest_gum]]
    pieces = []
    for soup in sides:
        T = np.concatenate(soup)
        area = np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
        pieces.append(_welded(T[area > 1e-18]))
    (Vt, Ft), (Vg, Fg) = pieces
    return (np.concatenate([Vt, Vg]), np.concatenate([Ft, Fg + len(Vt)]),
            np.arange(len(Ft), len(Ft) + len(Fg), dtype=np.int64))


def part_looks(name: str, V, F, fdps: dict | None = None, *,
               iris_color=None) -> tuple[tuple, dict, tuple[np.ndarray, np.ndarray]]:
    """A rigid part's own colour, its coloured face groups and the mesh they index.

    Args:
        name: The part's name (:func:`part_kind`). V (k, 3) [m], F (m, 3) int: its rest mesh.
        fdps, iris_color: As :func:`eye_looks`'s.

    Returns:
        (RGB of the part, {look name: (faces (j,) int64, RGB)}, (V' (k', 3) float64 [m], F' (m', 3)
        int64)): an eyeball is sclera with the groups of :func:`eye_looks` on its own mesh; a tooth
        row ivory with ``Gums`` on its :func:`tooth_mesh`; any other part ivory, the tongue
        red-pink, no groups, its own mesh.
    """
    kind = part_kind(name)
    if kind == "eye":
        V, F = np.asarray(V, np.float64), np.asarray(F, np.int64)
        return _part_rgb(kind), eye_looks(V, F, fdps, iris_color=iris_color), (V, F)
    Vt, Ft, gums = tooth_mesh(name, V, F)
    return _part_rgb(kind), ({"Gums": (gums, COLORS["gums"])} if len(gums) else {}), (Vt, Ft)


def part_vertex_colors(name: str, V, fdps: dict | None = None, *, iris_color=None, ball=None,
                       faces=None) -> np.ndarray:
    """Per-vertex colours of a rigid part for the renders, (k, 3) float64 in 0..1 (linear RGB).

    The same looks as :func:`part_looks`, by vertex: on an eyeball a vertex within the pupil's /
    iris' half-angle of the gaze axis is pupil / iris (and the vertex nearest the axis is pupil
    always), so draw a refined ball for a round iris. On a tooth row (drawn as its
    :func:`tooth_mesh`) a vertex of a face on the gums' side of the gum line is gums; without
    ``faces``, a vertex beyond the line.

    Args:
        name: The part's name. V: Its vertices [m], shape (k, 3), float.
        fdps, iris_color: As :func:`eye_looks`'s.
        ball: Optional rest vertices (j, 3) [m] of the part that V draws (V a :func:`drawn_part`
            of them): an eyeball's centre and gaze, a tooth row's gum line (default V's own).
        faces: Optional triangles (m, 3) int of V (a tooth row's :func:`tooth_mesh`).
    """
    V = np.asarray(V, np.float64)
    kind = part_kind(name)
    out = np.tile(np.asarray(_part_rgb(kind)), (len(V), 1))
    if kind == "teeth":
        plane = gum_plane(name, V if ball is None else ball)
        if plane is not None:
            a, level = plane
            if faces is None:
                gum = V @ a > level
            else:
                F = np.asarray(faces, np.int64)
                gum = np.zeros(len(V), bool)
                gum[F[V[F].mean(1) @ a > level].ravel()] = True
            out[gum] = COLORS["gums"]
        return out
    if kind != "eye":
        return out
    c, a, R = gaze_axis(V if ball is None else ball, fdps)
    pupil_half, iris_half = eye_angles(R)
    ang = _gaze_angles(V, c, a)
    pupil = (ang <= pupil_half) | (ang <= ang.min())
    out[~pupil & (ang <= iris_half)] = iris_rgb(iris_color)
    out[pupil] = COLORS["pupil"]
    return out


def _inside(P: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Points P (k, 2) inside the closed polygon poly (n, 2) (even-odd rule), shape (k,) bool."""
    x, y = P[:, 0:1], P[:, 1:2]
    x0, y0 = poly[:, 0][None], poly[:, 1][None]
    x1, y1 = np.roll(poly[:, 0], -1)[None], np.roll(poly[:, 1], -1)[None]
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (crosses & (x < xc)).sum(1) % 2 == 1


def lip_faces(fr) -> np.ndarray:
    """Indices of the skin faces that are lips (see the module docstring), shape (k,), int64."""
    fdp = rest_fdps(fr)
    pts = np.array([fdp[i] for i in _LIP_CONTOUR if i in fdp])
    if len(pts) < 4:
        return np.zeros(0, np.int64)
    c = pts.mean(0)
    order = np.argsort(np.arctan2(pts[:, 1] - c[1], pts[:, 0] - c[0]))
    poly = pts[order, :2]
    V = np.asarray(fr.head_vertices, np.float64)
    C = V[np.asarray(fr.head_faces)].mean(1)
    ok = _inside(C[:, :2], poly) & (C[:, 2] > c[2] - LIP_DEPTH)
    return np.flatnonzero(ok)


def refine_ball(V: np.ndarray, F: np.ndarray, levels: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A ball-like closed mesh (an eyeball) refined ``levels`` times for drawing: every triangle
    split into four, each new vertex pushed out from the centre to the mean radius of its edge's
    ends (so an iris 12 mm across is drawn round, not as a blur over 3 mm triangles).

    Args:
        V: Vertices [m], shape (k, 3), float. F: Triangles, shape (l, 3), int.

    The round ball is then scaled about its centre onto the coarse mesh's inscribed sphere (the
    least distance of its faces' planes from the centre): a sphere through the coarse vertices bulges
    out of the coarse faces by up to the facets' sagitta (~0.2 mm on the template's eyes), through
    the eyelid skin that rests on them (white specks on the upper lids); inside, it never shows
    through.

    Returns:
        Refined vertices (k', 3) [m] and triangles (4**levels * l, 3).
    """
    c = V.mean(0)
    V0, F0 = V, F
    for _ in range(levels):
        E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        edges, inverse = np.unique(E, axis=0, return_inverse=True)
        a, b = V[edges[:, 0]] - c, V[edges[:, 1]] - c
        m = a + b
        r = 0.5 * (np.linalg.norm(a, axis=1) + np.linalg.norm(b, axis=1))
        mid = c + m / np.maximum(np.linalg.norm(m, axis=1), 1e-12)[:, None] * r[:, None]
        e = len(V) + inverse.reshape(3, -1).T  # new vertex of the edges (01, 12, 20) of each triangle
        V = np.concatenate([V, mid])
        F = np.concatenate([np.stack([F[:, 0], e[:, 0], e[:, 2]], 1), np.stack([F[:, 1], e[:, 1], e[:, 0]], 1),
                            np.stack([F[:, 2], e[:, 2], e[:, 1]], 1), e])
    if levels:
        n = np.cross(V0[F0[:, 1]] - V0[F0[:, 0]], V0[F0[:, 2]] - V0[F0[:, 0]])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        inscribed = np.abs(np.einsum("fd,fd->f", V0[F0[:, 0]] - c, n)).min()
        reach = np.linalg.norm(V - c, axis=1).max()
        if 0 < inscribed < reach:
            V = c + (V - c) * (inscribed / reach)
    return V, F


def drawn_part(name: str, V, F) -> tuple[np.ndarray, np.ndarray]:
    """The mesh a renderer draws for a rigid part: an eyeball :func:`refine_ball`-ed (a round iris),
    a tooth row split at its gum line (:func:`tooth_mesh`), any other part as it is.
    V (k, 3) [m], F (l, 3) int -> (V', F')."""
    if part_kind(name) == "eye":
        return refine_ball(np.asarray(V, np.float64), np.asarray(F))
    if gum_plane(name, V) is not None:
        return tooth_mesh(name, V, F)[:2]
    return V, F


def head_looks(fr, *, iris_color=None) -> dict:
    """Part colours and face groups of a face rig's head for ``usd_export``'s writers and the glTF rig.

    Args:
        fr: A :class:`~facewarp.FaceRig` (head vertices and faces, FDPs, ``parts``, ``skin_texture``).
        iris_color: Optional iris RGB (3,) in 0..1, linear (default :data:`COLORS` ``["iris"]``, brown-hazel).

    Returns:
        ``{"part_colors": {part: RGB}, "subsets": {"Skin" or part: {name: (faces (k,) int64, RGB)}},
        "parts": {part: (V (k, 3) float64 [m], F (l, 3) int64)}}``: ``Lips`` on the skin (only
        without a skin texture, which carries the lips itself), ``Sclera``, ``Iris`` and ``Pupil`` on
        each eyeball (a partition of its faces), ``Gums`` on each tooth row; ``parts`` are the rest
        meshes to write, which the part subsets index: the rig's own, but the tooth rows split at
        their gum lines (:func:`tooth_mesh`; the same surfaces, riding the same part motions).

    Raises:
        InputError: a bad ``iris_color``.
    """
    iris_rgb(iris_color)
    part_colors, subsets, meshes = {}, {}, {}
    fdps = rest_fdps(fr)
    lips = np.zeros(0, np.int64) if getattr(fr, "skin_texture", None) else lip_faces(fr)
    if len(lips):
        subsets["Skin"] = {"Lips": (lips, COLORS["lips"])}
    for name, (V, F) in dict(fr.parts).items():
        part_colors[name], groups, meshes[name] = part_looks(name, V, F, fdps, iris_color=iris_color)
        if groups:
            subsets[name] = groups
    return {"part_colors": part_colors, "subsets": subsets, "parts": meshes}


def head_camera(fr, *, focal_length_mm: float = 50.0, vertical_aperture_mm: float = 15.2908,
                margin: float = 1.15) -> dict:
    """A camera in front of the head (+z, the face's side) that frames its whole height.

    Args:
        fr: The face rig (its rest head vertices [m]).
        focal_length_mm: Lens; with USD's default vertical aperture (15.2908 mm) 50 mm sees 17.4 deg.
        vertical_aperture_mm: The camera's vertical aperture [mm].
        margin: Room around the head (1.15: 15 %).

    Returns:
        ``{"position", "target", "up"}`` (3,) float64 [m] and ``"focal_length_mm"``.
    """
    V = np.asarray(fr.head_vertices, np.float64)
    lo, hi = V.min(0), V.max(0)
    target = 0.5 * (lo + hi)
    half = 0.5 * margin * max(hi[1] - lo[1], hi[0] - lo[0])
    dist = half * focal_length_mm / (0.5 * vertical_aperture_mm) + hi[2] - target[2]
    return {"position": target + np.array([0.0, 0.0, dist]), "target": target, "up": np.array([0.0, 1.0, 0.0]),
            "focal_length_mm": float(focal_length_mm)}
