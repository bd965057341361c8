"""Parametric muscles: Bezier fibres, ellipsoid segments, anchors and skin attachment (Sec. 6.3).

The 14 muscles of Table 6.2 (paired where anatomical) are defined as data in
``muscle_defs.json``: control points are *placement rules* relative to MPEG-4 FDPs, resolved on
any head with FDPs to skin points (face, barycentric) and displaced inward along the skin normal:

- linear muscles (1-12): a regular quadratic Bezier curve (all weights 1) through the insertion
  (depth ``2 t_skin + r``), middle (``(2 t_skin + t_skull) / 2``) and attachment
  (``t_skull - r``) control points, ``r`` the muscle radius;
- sphincters (13 orbicularis oris, 14 orbicularis oculi): a closed ring of 4 quadratic rational
  Bezier arcs (8 control points, the arcs' middle points weighted ``w``; ``w = cos 45deg`` gives
  exact circular quarters) at depth ``(2 t_skin + t_skull) / 2``.

Anchors (Fig. 6.3) tie the insertions of voluntary muscles to control points of a sphincter:
the anchor is the mean of its member control points, so the sphincter follows the linear muscles.

Every curve is cut into segments of equal arc length (the zygomatic major into 5, others in
proportion to their length) and each segment is an ellipsoid: x along the chord (half-length
``1.05 x chord / 2``), y perpendicular to x in the plane of the curve's control points,
``z = x cross y``; y and z radii ``r = 2 d_m``, tapered at the two end segments of a linear muscle.
An ellipsoid keeps its volume when its x radius changes (:func:`ellipsoid_radii_for_length`).

Skin attachment (Fig. 6.4): an inner-layer node connects to the muscle when the distance to the
nearest ellipsoid surface point is below ``lambda`` and the angle ``theta`` between the
connection and the fibre's cross-section plane is below ``phi``. ``theta`` is measured from the
plane normal to the fibre (0 for a node right above the fibre, 90deg for one beyond its end), so a
wide ``phi`` (frontalis) takes nodes far along the ends and a narrow one (depressor anguli oris)
only nodes over the muscle body. The attachment point is stored by its ellipsoid surface
parameters ``(u, v)``: ``u`` the polar angle from +x, ``v`` the azimuth from +y toward +z.
"""

from __future__ import annotations

import enum
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..geometry.surface import vertex_normals
from ..geometry.mesh import SurfacePoints, closest_surface_points

__all__ = [
    "DEFAULT_MUSCLE_DEFS",
    "Anchor",
    "Ellipsoids",
    "Muscle",
    "MuscleAttachment",
    "MuscleKind",
    "MuscleSet",
    "arc_length_params",
    "attach_nodes",
    "bezier_quadratic",
    "build_muscles",
    "closest_point_on_ellipsoid",
    "ellipsoid_points",
    "ellipsoid_radii_for_length",
    "load_muscle_defs",
    "make_linear_muscle",
    "muscles_to_json",
    "segment_ellipsoids",
]

DEFAULT_MUSCLE_DEFS = Path(__file__).with_name("muscle_defs.json")
"""The shipped muscle definitions (placement rules relative to FDPs)."""


class MuscleKind(str, enum.Enum):
    LINEAR = "linear"
    SPHINCTER = "sphincter"


# ----------------------------------------------------------------------------- Bezier curves
def bezier_quadratic(P, t, weights=None) -> np.ndarray:
    """Points of a (rational) quadratic Bezier curve.

    ``C(t) = sum_i B_i(t) w_i P_i / sum_i B_i(t) w_i`` with the Bernstein polynomials
    ``B = ((1 - t)^2, 2 t (1 - t), t^2)``; all weights 1 is the regular curve of a linear muscle.

    Args:
        P: Control points [m], shape (3, 3) float64.
        t: Parameters in [0, 1], shape (k,).
        weights: Weights, shape (3,), positive (default ones).

    Returns:
        Curve points [m], shape (k, 3), float64.
    """
    P = np.asarray(P, dtype=np.float64)
    if P.shape != (3, 3):
        raise ValueError(f"P must have shape (3, 3), got {P.shape}")
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    w = np.ones(3) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (3,) or (w <= 0).any():
        raise ValueError(f"weights must be 3 positive numbers, got {w}")
    B = np.stack([(1 - t) ** 2, 2 * t * (1 - t), t**2], 1) * w
    return (B @ P) / B.sum(1, keepdims=True)


def arc_length_params(P, count: int, weights=None, *, samples: int = 512) -> tuple[np.ndarray, float]:
    """Parameters cutting a quadratic Bezier curve into ``count`` pieces of equal arc length.

    Args:
        P: Control points [m], shape (3, 3).
        count: Number of pieces (>= 1).
        weights: Rational weights, shape (3,) (default ones).
        samples: Polyline samples used to measure the arc length.

    Returns:
        ``(t, length)``: parameters shape (count + 1,) from 0 to 1, and the curve length [m].
    """
    ts = np.linspace(0.0, 1.0, samples + 1)
    C = bezier_quadratic(P, ts, weights)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(C, axis=0), axis=1))])
    length = float(s[-1])
    t = np.interp(np.linspace(0.0, length, int(count) + 1), s, ts)
    t[0], t[-1] = 0.0, 1.0
    return t, length


# ----------------------------------------------------------------------------- ellipsoids
@dataclass
class Ellipsoids:
    """Muscle segments (one ellipsoid each).

    Attributes:
        centers: Centres [m], shape (s, 3), float64.
        axes: Unit axes as rows (x along the fibre chord, y in the control-point plane,
            z = x cross y), shape (s, 3, 3), float64.
        radii: Semi-axis lengths (x, y, z) [m], shape (s, 3), float64.
        curve: Index of the Bezier curve (arc) each segment lies on, shape (s,), int64.
        t: Curve parameters of each segment's two ends, shape (s, 2), float64.
    """

    centers: np.ndarray
    axes: np.ndarray
    radii: np.ndarray
    curve: np.ndarray
    t: np.ndarray

    def __len__(self) -> int:
        return len(self.centers)

    @property
    def volumes(self) -> np.ndarray:
        """Volumes 4/3 pi a b c [m^3], shape (s,)."""
        return 4.0 / 3.0 * np.pi * np.prod(self.radii, axis=1)


def ellipsoid_radii_for_length(radii, x_radius) -> np.ndarray:
    """Radii of a segment whose x radius becomes ``x_radius``, keeping its volume (Sec. 6.4.1).

    Muscle is incompressible: ``a b c`` is constant, and the cross-section scales uniformly,
    so ``b' = b sqrt(a / a')`` and ``c' = c sqrt(a / a')``.

    Args:
        radii: Rest radii (a, b, c) [m], shape (s, 3).
        x_radius: New x radii a' [m], shape (s,), > 0.

    Returns:
        New radii [m], shape (s, 3).
    """
    radii = np.asarray(radii, dtype=np.float64).reshape(-1, 3)
    a1 = np.asarray(x_radius, dtype=np.float64).reshape(-1)
    if (a1 <= 0).any():
        raise ValueError("x_radius must be > 0")
    f = np.sqrt(radii[:, 0] / a1)
    return np.stack([a1, radii[:, 1] * f, radii[:, 2] * f], 1)


def ellipsoid_points(centers, axes, radii, uv) -> np.ndarray:
    """Surface points at parameters (u, v): local ``(a cos u, b sin u cos v, c sin u sin v)``.

    Args:
        centers: (k, 3) [m]; axes: (k, 3, 3) unit rows; radii: (k, 3) [m]; uv: (k, 2) [rad].

    Returns:
        Points [m], shape (k, 3).
    """
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    u, v = uv[:, 0], uv[:, 1]
    radii = np.asarray(radii, dtype=np.float64).reshape(-1, 3)
    loc = np.stack([radii[:, 0] * np.cos(u), radii[:, 1] * np.sin(u) * np.cos(v), radii[:, 2] * np.sin(u) * np.sin(v)], 1)
    return np.asarray(centers) + np.einsum("kj,kji->ki", loc, np.asarray(axes))


def closest_point_on_ellipsoid(Y, radii, *, iterations: int = 80) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest surface point of axis-aligned ellipsoids to points given in their local frames.

    The closest point is ``x_i = e_i^2 y_i / (s + e_i^2)`` where s solves
    ``F(s) = sum_i (e_i y_i / (s + e_i^2))^2 - 1 = 0`` on ``s > -min e_i^2`` (F decreases
    there; s > 0 outside, s < 0 inside); solved by bisection (Eberly, "Distance from a point to
    an ellipse, an ellipsoid, or a hyperellipsoid").

    Args:
        Y: Points in the local frames [m], shape (k, 3).
        radii: Semi-axes (a, b, c) [m], shape (k, 3) or (3,).
        iterations: Bisection steps.

    Returns:
        ``(X, dist, uv)``: closest points (local) shape (k, 3); unsigned distances [m] (k,);
        surface parameters (u, v) [rad] (k, 2).
    """
    Y = np.asarray(Y, dtype=np.float64).reshape(-1, 3)
    E = np.broadcast_to(np.asarray(radii, dtype=np.float64), Y.shape)
    e2 = E * E
    emin2 = e2.min(1)
    ey = np.abs(E * Y)
    lo = -emin2 + 1e-30 * np.maximum(emin2, 1e-300)
    hi = np.maximum(np.linalg.norm(ey, axis=1), emin2)  # F(hi) <= 0
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        Fm = ((ey / (mid[:, None] + e2)) ** 2).sum(1) - 1.0
        pos = Fm > 0
        lo = np.where(pos, mid, lo)
        hi = np.where(pos, hi, mid)
    s = 0.5 * (lo + hi)
    X = e2 * Y / (s[:, None] + e2)
    # Degenerate inside case (Eberly): the root sits at s = -min e^2 when the point lies (nearly)
    # in the plane of the smallest axis; then the other coordinates follow from s = -e_min^2
    # and the smallest-axis coordinate from the ellipsoid equation.
    kmin = np.argmin(e2, axis=1)
    rows = np.arange(len(Y))
    gap = s + emin2
    deg = gap <= 1e-9 * emin2
    if deg.any():
        r, km = rows[deg], kmin[deg]
        den = e2[deg] - emin2[deg][:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            Xd = np.where(den > 0, e2[deg] * Y[deg] / np.where(den > 0, den, 1.0), 0.0)
        Xd[np.arange(len(r)), km] = 0.0
        rest = np.clip(1.0 - ((Xd / E[deg]) ** 2).sum(1), 0.0, None)
        sgn = np.where(Y[r, km] < 0, -1.0, 1.0)
        Xd[np.arange(len(r)), km] = sgn * E[r, km] * np.sqrt(rest)
        X[deg] = Xd
    # put X exactly on the surface (bisection residue)
    X /= np.sqrt(((X / E) ** 2).sum(1))[:, None]
    dist = np.linalg.norm(Y - X, axis=1)
    q = X / E
    u = np.arccos(np.clip(q[:, 0], -1.0, 1.0))
    v = np.arctan2(q[:, 2], q[:, 1])
    return X, dist, np.stack([u, v], 1)


def segment_ellipsoids(curves, weights, counts, radius: float, *, taper=None, chord_scale: float = 1.05) -> Ellipsoids:
    """Cut Bezier curves into equal-arc-length segments, one ellipsoid each (Sec. 6.3).

    Args:
        curves: Control points of each curve [m], shape (q, 3, 3).
        weights: Rational weights, shape (q, 3).
        counts: Segments per curve, shape (q,), >= 1.
        radius: y and z radius r = 2 d_m [m].
        taper: Radius factor of the first and last segment overall (None: no taper).
        chord_scale: x length / chord (1.05: 5 % longer, so neighbours overlap).

    Returns:
        :class:`Ellipsoids`.
    """
    C, A, R, cur, T = [], [], [], [], []
    for qi, (P, w, n) in enumerate(zip(np.asarray(curves, float), np.asarray(weights, float), counts)):
        t, _ = arc_length_params(P, int(n), w)
        pts = bezier_quadratic(P, t, w)
        plane = np.cross(P[1] - P[0], P[2] - P[0])
        for k in range(int(n)):
            a, b = pts[k], pts[k + 1]
            chord = b - a
            L = float(np.linalg.norm(chord))
            if L <= 0:
                raise InputError(f"curve {qi} has a zero-length segment {k}")
            x = chord / L
            y = np.cross(plane, x)
            if np.linalg.norm(y) < 1e-9 * max(np.linalg.norm(plane), 1e-30) or np.linalg.norm(plane) < 1e-20:
                # straight fibre: any perpendicular
                y = np.cross(x, [0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.cross(x, [1.0, 0.0, 0.0])
            y /= np.linalg.norm(y)
            z = np.cross(x, y)
            C.append(0.5 * (a + b))
            A.append(np.stack([x, y, z]))
            R.append([0.5 * chord_scale * L, radius, radius])
            cur.append(qi)
            T.append([t[k], t[k + 1]])
    R = np.asarray(R)
    if taper is not None and len(R):
        R[0, 1:] *= taper
        R[-1, 1:] *= taper
    return Ellipsoids(np.asarray(C), np.asarray(A), R, np.asarray(cur, dtype=np.int64), np.asarray(T))


# ----------------------------------------------------------------------------- attachment
@dataclass
class MuscleAttachment:
    """Skin nodes connected to a muscle (Fig. 6.4, 6.5).

    Attributes:
        nodes: Tet-mesh node indices (inner layer), shape (a,), int64.
        segment: Ellipsoid each node connects to, shape (a,), int64.
        uv: Surface parameters (u, v) [rad] of the attachment point, shape (a, 2), float64.
        rest_length: Rest length l0 of the connection [m], shape (a,), float64.
        angle: theta [rad] of each connection (see the module docstring), shape (a,).
    """

    nodes: np.ndarray
    segment: np.ndarray
    uv: np.ndarray
    rest_length: np.ndarray
    angle: np.ndarray

    def __len__(self) -> int:
        return len(self.nodes)


def attach_nodes(X, ell: Ellipsoids, lam: float, phi: float, *, candidates=None, directions=None) -> MuscleAttachment:
    """Connect nodes to a muscle's ellipsoids (Fig. 6.4).

    For each node x: the nearest surface point p over all segments; x connects when
    ``|x - p| < lam`` and ``theta < phi``, theta the angle between ``x - p`` and the plane
    normal to the segment's fibre axis. With ``directions``, x must also lie on the skin side
    of the muscle, ``(p - x) . direction > 0``: on a head whose skin is thinner than the muscle
    depth (the lips of an adapted scan) part of a muscle can lie in or above the skin layer, and
    a spring from there would pull its inner node out through the skin.

    Args:
        X: Node positions [m], shape (p, 3).
        ell: The muscle's segments.
        lam: Distance threshold lambda [m].
        phi: Angle threshold [rad].
        candidates: Node indices to test (default all).
        directions: Unit inward (skin to deep) direction of every node, shape (p, 3).

    Returns:
        :class:`MuscleAttachment` with indices into X.
    """
    X = np.asarray(X, dtype=np.float64)
    idx = np.arange(len(X)) if candidates is None else np.asarray(candidates, dtype=np.int64)
    s = len(ell)
    if len(idx) == 0 or s == 0:
        z = np.zeros(0)
        return MuscleAttachment(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)), z, z)
    P = X[idx]
    best_d = np.full(len(idx), np.inf)
    best_s = np.zeros(len(idx), np.int64)
    best_uv = np.zeros((len(idx), 2))
    best_sin = np.zeros(len(idx))
    best_deeper = np.ones(len(idx), bool)
    D = None if directions is None else np.asarray(directions, dtype=np.float64)[idx]
    for k in range(s):
        Y = (P - ell.centers[k]) @ ell.axes[k].T  # local coordinates
        Xl, d, uv = closest_point_on_ellipsoid(Y, ell.radii[k])
        conn = Y - Xl
        n = np.linalg.norm(conn, axis=1)
        sin_t = np.divide(np.abs(conn[:, 0]), n, out=np.zeros_like(n), where=n > 0)
        better = d < best_d
        best_d[better] = d[better]
        best_s[better] = k
        best_uv[better] = uv[better]
        best_sin[better] = sin_t[better]
        if D is not None:
            deeper = np.einsum("ij,ij->i", conn @ ell.axes[k], D) < 0  # world x - p against inward
            best_deeper[better] = deeper[better]
    theta = np.arcsin(np.clip(best_sin, 0.0, 1.0))
    ok = (best_d < lam) & (theta < phi) & best_deeper
    return MuscleAttachment(idx[ok], best_s[ok], best_uv[ok], best_d[ok], theta[ok])


# ----------------------------------------------------------------------------- definitions
def load_muscle_defs(path=None) -> dict:
    """Read muscle definitions (default: the shipped ``muscle_defs.json``).

    Raises:
        InputError: Unreadable file, wrong format tag, or a muscle missing its fields.
    """
    path = Path(path) if path is not None else DEFAULT_MUSCLE_DEFS
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(f"{path}: cannot read muscle definitions ({e})") from None
    if not isinstance(d, dict) or d.get("format") != "facewarp.muscles/1":
        raise InputError(f"{path}: expected format 'facewarp.muscles/1'")
    for m in d.get("muscles", []):
        for key in ("name", "number", "kind", "points"):
            if key not in m:
                raise InputError(f"{path}: muscle {m.get('name', '?')} lacks '{key}'")
        if m["kind"] == "linear" and set(m["points"]) != {"insertion", "middle", "attachment"}:
            raise InputError(f"{path}: linear muscle {m['name']} needs insertion, middle, attachment")
        if m["kind"] == "sphincter" and len(m["points"]) != 8:
            raise InputError(f"{path}: sphincter {m['name']} needs 8 control points, got {len(m['points'])}")
    return d


def _mirror_rule(rule: dict, mirror: dict[str, str]) -> dict:
    both = {**mirror, **{v: k for k, v in mirror.items()}}
    if "between" in rule:
        return {**rule, "between": [_mirror_rule(r, mirror) for r in rule["between"]]}
    out = dict(rule)
    out["fdp"] = both.get(rule["fdp"], rule["fdp"])
    if "y_from" in rule:
        out["y_from"] = both.get(rule["y_from"], rule["y_from"])
    off = list(rule.get("offset_m", [0.0, 0.0, 0.0]))
    out["offset_m"] = [-off[0], off[1], off[2]]
    return out


def _rule_target(rule: dict, lm: dict[str, np.ndarray], where: str) -> np.ndarray:
    if "between" in rule:
        a, b = rule["between"]
        t = float(rule.get("t", 0.5))
        return (1 - t) * _rule_target(a, lm, where) + t * _rule_target(b, lm, where)
    fid = rule.get("fdp")
    if fid not in lm:
        raise InputError(f"{where}: FDP {fid!r} is not on this head")
    p = np.array(lm[fid], dtype=np.float64)
    if "y_from" in rule:
        if rule["y_from"] not in lm:
            raise InputError(f"{where}: FDP {rule['y_from']!r} is not on this head")
        p[1] = lm[rule["y_from"]][1]
    return p + np.asarray(rule.get("offset_m", [0.0, 0.0, 0.0]), dtype=np.float64)


# ----------------------------------------------------------------------------- muscles
@dataclass
class Muscle:
    """One muscle of Table 6.2 on one side.

    Attributes:
        name: Unique name, e.g. ``"zygomatic_major_L"`` (``_L`` = subject's left, +x).
        base: Name without the side, e.g. ``"zygomatic_major"``.
        number: Table 6.2 number (1..14).
        side: ``"L"``, ``"R"`` or ``""`` (unpaired).
        kind: :class:`MuscleKind`.
        skin_points: The control points' skin points on the head, (c,) surface points.
        depth: Inward displacement of each control point [m], shape (c,).
        control_points: Control points [m], shape (c, 3) (c = 3 linear, 8 sphincter).
        weights: Rational weights per control point, shape (c,).
        curves: Control-point indices of each quadratic arc, shape (q, 3), int64.
        radius: y/z radius r = 2 d_m [m].
        lam: Attachment distance lambda [m].
        phi: Attachment angle phi [rad].
        segments: The ellipsoids.
        attachment: Attached inner-layer nodes (filled by :func:`build_muscles`).
        contraction: Largest relative shortening at activation 1 (used by the solver).
    """

    name: str
    base: str
    number: int
    side: str
    kind: MuscleKind
    skin_points: SurfacePoints
    depth: np.ndarray
    control_points: np.ndarray
    weights: np.ndarray
    curves: np.ndarray
    radius: float
    lam: float
    phi: float
    segments: Ellipsoids | None = None
    attachment: MuscleAttachment | None = None
    contraction: float = 0.3

    def curve_points(self, samples: int = 32) -> np.ndarray:
        """The fibre as a polyline [m], shape (q * samples + 1, 3) (closed for a sphincter)."""
        out = []
        for q, c in enumerate(self.curves):
            t = np.linspace(0, 1, samples + 1)[: -1 if q < len(self.curves) - 1 else None]
            out.append(bezier_quadratic(self.control_points[c], t, self.weights[c]))
        return np.concatenate(out)

    def length(self) -> float:
        return float(sum(arc_length_params(self.control_points[c], 1, self.weights[c])[1] for c in self.curves))


@dataclass
class Anchor:
    """Control points that move together (Fig. 6.3): the anchor is their mean.

    Attributes:
        name: e.g. ``"modiolus_L"``.
        members: ``(muscle name, control point index)`` pairs.
        position: Rest position [m], the mean of the members, shape (3,).
    """

    name: str
    members: list[tuple[str, int]]
    position: np.ndarray


@dataclass
class MuscleSet:
    """All muscles of a head, with their anchors.

    Attributes:
        muscles: In definition order, left before right.
        anchors: The anchors.
        defaults: The definitions' defaults (radius, lambda, phi, segmentation).
    """

    muscles: list[Muscle]
    anchors: list[Anchor] = field(default_factory=list)
    defaults: dict = field(default_factory=dict)

    def by_name(self) -> dict[str, Muscle]:
        return {m.name: m for m in self.muscles}


_SPHINCTER_CURVES = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6], [6, 7, 0]])
_LINEAR_KEYS = ("insertion", "middle", "attachment")


def _interp_vertex(values: np.ndarray, F: np.ndarray, sp: SurfacePoints) -> np.ndarray:
    return np.einsum("kc,kc...->k...", sp.bary, values[F[sp.face]])


def build_muscles(template, skin_layer=None, *, defs=None, placements=None) -> MuscleSet:
    """Place the muscles on a head and attach them to its skin layer (Sec. 6.3).

    Args:
        template: A head with ``vertices``, ``faces``, ``thickness``, ``skull_depth`` and
            ``landmarks()`` (a :class:`facewarp.Template`).
        skin_layer: The head's :class:`~facewarp._src.tissue.SkinLayer`; without it no nodes
            are attached.
        defs: Muscle definitions (default :func:`load_muscle_defs`).
        placements: Optional muscle name -> :class:`SurfacePoints` of its control points'
            skin points (e.g. from an earlier build on a head of the same topology); muscles not
            listed are placed by their FDP rules.

    Returns:
        :class:`MuscleSet`.

    Raises:
        InputError: A rule names an FDP the head lacks, or a control point does not lie between
            the skin and the skull (depth <= 0 or >= the skull depth).
    """
    defs = load_muscle_defs() if defs is None else defs
    dflt = defs.get("defaults", {})
    mirror = defs.get("mirror_fdp", {})
    V = np.asarray(template.vertices, dtype=np.float64)
    F = np.asarray(template.faces, dtype=np.int64)
    N = vertex_normals(V, F)
    lm = template.landmarks()
    placements = placements or {}

    # 1. control points
    muscles: list[Muscle] = []
    for m in defs["muscles"]:
        sides = ("L", "R") if m.get("paired", False) else ("",)
        kind = MuscleKind(m["kind"])
        r = float(m.get("radius_m", dflt.get("radius_m", 0.0015)))
        for side in sides:
            name = m["name"] + (f"_{side}" if side else "")
            rules = [m["points"][k] for k in _LINEAR_KEYS] if kind is MuscleKind.LINEAR else list(m["points"])
            if side == "R":
                rules = [_mirror_rule(rr, mirror) for rr in rules]
            if name in placements:
                sp = placements[name]
            else:
                P = np.array([_rule_target(rr, lm, f"muscle {name}") for rr in rules])
                sp = closest_surface_points(V, F, P)
            skin = sp.positions(V, F)
            n = _interp_vertex(N, F, sp)
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            t_skin = _interp_vertex(np.asarray(template.thickness, float), F, sp)
            t_skull = _interp_vertex(np.asarray(template.skull_depth, float), F, sp)
            if kind is MuscleKind.LINEAR:
                depth = np.array([2 * t_skin[0] + r, 0.5 * (2 * t_skin[1] + t_skull[1]), t_skull[2] - r])
                w = np.ones(3)
                curves = np.array([[0, 1, 2]])
            else:
                depth = 0.5 * (2 * t_skin + t_skull)
                sw = float(dflt.get("sphincter_weight", np.sqrt(0.5)))
                w = np.array([1.0, sw] * 4)
                curves = _SPHINCTER_CURVES.copy()
            if (depth <= 0).any() or (depth >= t_skull).any():
                k = int(np.flatnonzero((depth <= 0) | (depth >= t_skull))[0])
                raise InputError(
                    f"muscle {name}: control point {k} depth {depth[k] * 1e3:.2f} mm is not between the skin and the "
                    f"skull ({t_skull[k] * 1e3:.2f} mm deep there)"
                )
            muscles.append(
                Muscle(
                    name=name,
                    base=m["name"],
                    number=int(m["number"]),
                    side=side,
                    kind=kind,
                    skin_points=sp,
                    depth=depth,
                    control_points=skin - depth[:, None] * n,
                    weights=w,
                    curves=curves,
                    radius=r,
                    lam=float(m.get("lambda_m", dflt.get("lambda_m", 0.006))),
                    phi=np.deg2rad(float(m.get("phi_deg", dflt.get("phi_deg", 60.0)))),
                    contraction=float(
                        m.get(
                            "contraction",
                            dflt.get("contraction", 0.3)
                            if kind is MuscleKind.LINEAR
                            else dflt.get("sphincter_contraction", 0.2),
                        )
                    ),
                )
            )
    by = {m.name: m for m in muscles}

    # 2. segments: the reference muscle gets reference_segments, others in proportion
    ref_name = dflt.get("reference_muscle", "zygomatic_major_L")
    ref_n = int(dflt.get("reference_segments", 5))
    if ref_name not in by:
        raise InputError(f"muscle definitions: reference muscle {ref_name!r} is not defined")
    ref_len = by[ref_name].length()
    taper = float(dflt.get("end_taper", 0.5))
    chord_scale = float(dflt.get("chord_scale", 1.05))
    for mu in muscles:
        counts = []
        for c in mu.curves:
            L = arc_length_params(mu.control_points[c], 1, mu.weights[c])[1]
            counts.append(max(2 if mu.kind is MuscleKind.LINEAR else 1, int(round(ref_n * L / ref_len))))
        mu.segments = segment_ellipsoids(
            mu.control_points[mu.curves],
            mu.weights[mu.curves],
            counts,
            mu.radius,
            taper=taper if mu.kind is MuscleKind.LINEAR else None,
            chord_scale=chord_scale,
        )

    # 3. anchors (Fig. 6.3)
    anchors = []
    for a in defs.get("anchors", []):
        sides = ("L", "R") if a.get("paired", False) else ("",)
        for side in sides:
            sph = by.get(a["sphincter"]) or by.get(f"{a['sphincter']}_{side}")
            if sph is None:
                raise InputError(f"anchor {a['name']}: sphincter {a['sphincter']!r} is not defined")
            ctrl = int(a["control"])
            if side == "R" and not sph.side:
                ctrl = (4 - ctrl) % 8  # mirror across the midline: angle k 45deg -> 180deg - k 45deg
            members = [(sph.name, ctrl)]
            for ins in a["insertions"]:
                nm = f"{ins}_{side}" if side else ins
                if nm not in by:
                    raise InputError(f"anchor {a['name']}: muscle {nm!r} is not defined")
                members.append((nm, 0))
            pos = np.mean([by[n].control_points[i] for n, i in members], axis=0)
            anchors.append(Anchor(name=a["name"] + (f"_{side}" if side else ""), members=members, position=pos))

    # 4. attachment (Fig. 6.4)
    if skin_layer is not None:
        from scipy.spatial import cKDTree

        inner = skin_layer.inner_nodes
        tree = cKDTree(skin_layer.vertices[inner])
        for mu in muscles:
            e = mu.segments
            reach = e.radii.max(1) + mu.lam
            cand = set()
            for c, rr in zip(e.centers, reach):
                cand.update(tree.query_ball_point(c, rr))
            cand = inner[np.array(sorted(cand), dtype=np.int64)] if cand else np.zeros(0, np.int64)
            mu.attachment = attach_nodes(skin_layer.vertices, e, mu.lam, mu.phi, candidates=cand,
                                         directions=skin_layer.direction)
    return MuscleSet(muscles=muscles, anchors=anchors, defaults=dict(dflt))


def make_linear_muscle(
    name: str,
    control_points,
    *,
    radius: float,
    lam: float,
    phi: float,
    segments: int = 5,
    taper: float | None = 0.5,
    skin_points: SurfacePoints | None = None,
    depth=None,
    number: int = 0,
) -> Muscle:
    """A linear muscle from explicit control points (insertion, middle, attachment), segmented.

    For scenes that are not heads (e.g. the slab of :func:`facewarp._src.anatomy.slab_anatomy`).

    Args:
        name: Muscle name.
        control_points: Insertion, middle, attachment [m], shape (3, 3).
        radius: y/z radius r [m].
        lam: Attachment distance lambda [m].
        phi: Attachment angle phi [rad].
        segments: Number of ellipsoids.
        taper: End-segment radius factor (None: none).
        skin_points: Skin points above the control points (optional).
        depth: Depth of each control point [m], shape (3,) (optional, informative).
        number: Table 6.2 number (0 when not one of them).
    """
    P = np.asarray(control_points, dtype=np.float64)
    if P.shape != (3, 3):
        raise InputError(f"control_points: expected shape (3, 3), got {P.shape}")
    mu = Muscle(
        name=name,
        base=name,
        number=int(number),
        side="",
        kind=MuscleKind.LINEAR,
        skin_points=skin_points if skin_points is not None else SurfacePoints(np.zeros(0, np.int64), np.zeros((0, 3))),
        depth=np.zeros(3) if depth is None else np.asarray(depth, dtype=np.float64),
        control_points=P,
        weights=np.ones(3),
        curves=np.array([[0, 1, 2]]),
        radius=float(radius),
        lam=float(lam),
        phi=float(phi),
    )
    mu.segments = segment_ellipsoids(P[None], np.ones((1, 3)), [int(segments)], float(radius), taper=taper)
    return mu


def muscles_to_json(ms: MuscleSet) -> dict:
    """JSON-ready description: per muscle its control points, segments and attached nodes."""
    out = {"units": "m", "muscles": {}, "anchors": {}}
    for m in ms.muscles:
        e = m.segments
        a = m.attachment
        out["muscles"][m.name] = {
            "number": m.number,
            "base": m.base,
            "side": m.side,
            "kind": m.kind.value,
            "control_points": m.control_points,
            "weights": m.weights,
            "curves": m.curves,
            "depth": m.depth,
            "skin_points": m.skin_points.to_dict(),
            "radius": m.radius,
            "lambda": m.lam,
            "phi_deg": float(np.rad2deg(m.phi)),
            "length": m.length(),
            "contraction": m.contraction,
            "segments": None
            if e is None
            else {"centers": e.centers, "axes": e.axes, "radii": e.radii, "curve": e.curve, "t": e.t},
            "attachment": None
            if a is None
            else {"nodes": a.nodes, "segment": a.segment, "uv": a.uv, "rest_length": a.rest_length},
        }
    for an in ms.anchors:
        out["anchors"][an.name] = {"members": [list(x) for x in an.members], "position": an.position}
    return out
