"""The muscles of a head (Sec. 6.3): definitions as FDP-relative placement rules, placement,
segmentation, anchors and skin attachment, and their JSON form.

The 14 muscles of Table 6.2 (paired where anatomical) are defined as data in
``muscle_defs.json``: control points are *placement rules* relative to MPEG-4 FDPs, resolved on
any head with FDPs to skin points (face, barycentric) and displaced inward along the skin normal
(averaged over a patch as wide as the depth, :func:`depth_normals`, so the placement does not
change with the mesh resolution):

- linear muscles (1-12): a regular quadratic Bezier curve (all weights 1) through the insertion
  (depth ``2 t_skin + r``), middle (``(2 t_skin + t_skull) / 2``) and attachment
  (``t_skull - r``) control points, ``r`` the muscle radius;
- sphincters (13 orbicularis oris, 14 orbicularis oculi): a closed ring of 4 quadratic rational
  Bezier arcs (8 control points, the arcs' middle points weighted ``w``; ``w = cos 45deg`` gives
  exact circular quarters) at depth ``(2 t_skin + t_skull) / 2`` (or ``t_skin + r`` with
  ``"depth": "under_skin"``: the palpebral orbicularis oculi right under the lid skin).

Anchors (Fig. 6.3) tie the insertions of voluntary muscles to control points of a sphincter,
two-way: in the solver every member moves by the stiffness-weighted mean of the members' own
displacements (stiffness ``anchor_passive_stiffness + activation``), so an active muscle drags
the sphincter point and the passive insertions along (``kernels_muscle._muscle_anchors``).

A sphincter may mark ring points ``fixed`` (the lid corners on their palpebral ligaments), give its
ring centre as a placement rule (``center``; default the mean of its on-curve points) and contract
toward the plane through that centre that holds the chord of its two fixed points and the face's
forward axis z (``to_plane``: the lids close across the palpebral fissure instead of shrinking
toward one point), lie right under the skin (``depth``: ``under_skin``) and glide over a rigid part
(``glide_part``: the lids over the eyeball ``eye``; each point keeps its distance from the part's
centre as it contracts). A muscle's ``regions``
(Fig. 6.4: "the region the muscle is related to") limit the nodes it attaches to; region names
without a side take the muscle's side (both sides for an unpaired muscle).

Every curve is cut into ellipsoid segments of equal arc length (the zygomatic major into 5, others
in proportion to their length; :mod:`facewarp._src.anatomy.ellipsoids`), and inner-layer skin nodes
attach to them by the distance and angle rule of Fig. 6.4 (:mod:`facewarp._src.anatomy.attach`). The
curves themselves are in :mod:`facewarp._src.anatomy.bezier`.
"""

from __future__ import annotations

import enum
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..geometry.mesh import SurfacePoints, closest_surface_points
from ..geometry.surface import gaussian_sums, vertex_normals
from .attach import MuscleAttachment, attach_by_area, sheet_samples
from .bezier import arc_length_params, bezier_quadratic
from .ellipsoids import Ellipsoids, segment_ellipsoids

__all__ = [
    "DEFAULT_MUSCLE_DEFS",
    "Anchor",
    "Muscle",
    "MuscleKind",
    "MuscleSet",
    "NORMAL_FOOTPRINT",
    "build_muscles",
    "depth_normals",
    "load_muscle_defs",
    "make_linear_muscle",
    "muscles_to_json",
    "node_regions",
]


DEFAULT_MUSCLE_DEFS = Path(__file__).with_name("muscle_defs.json")
"""The shipped muscle definitions (placement rules relative to FDPs)."""


class MuscleKind(str, enum.Enum):
    LINEAR = "linear"
    SPHINCTER = "sphincter"


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
        contraction: Largest relative shortening c_max at activation 1 (used by the solver).
        saturation: beta of the activation curve ``c(a) = c_max (1 - e^(-beta a)) / (1 - e^-beta)``.
        regions: Template regions whose nodes the muscle may attach to (empty: any).
        center: Ring centre of a sphincter [m], shape (3,) (None: the mean of its on-curve points).
        fixed: Sphincter control points that do not contract (tied to bone), indices.
        center_normal: Unit normal of the plane the sphincter contracts toward, shape (3,), or None
            (toward the centre point).
        glide_center: Centre of the rigid part (an eyeball) the sphincter glides over [m], shape
            (3,), or None.
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
    saturation: float = 0.0
    regions: tuple = ()
    center: np.ndarray | None = None
    fixed: tuple = ()
    center_normal: np.ndarray | None = None
    glide_center: np.ndarray | None = None

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
    """Control points that move together (Fig. 6.3), two-way: each member moves by the
    stiffness-weighted mean of the members' own displacements (``kernels_muscle._muscle_anchors``).

    Attributes:
        name: e.g. ``"modiolus_L"``.
        members: ``(muscle name, control point index)`` pairs, the sphincter point first.
        position: Rest position [m], the mean of the members, shape (3,).
        passive: Stiffness of a member at activation 0, relative to what activation 1 adds.
    """

    name: str
    members: list[tuple[str, int]]
    position: np.ndarray
    passive: float = 0.1


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


NORMAL_FOOTPRINT = 1.0
"""Width of the skin patch whose normal places a control point, relative to its depth: a point
``d`` below the skin lies along the area-weighted mean normal of the skin within about ``d``
(Gaussian weights ``exp(-(r / (NORMAL_FOOTPRINT d))^2)`` on the faces' areas,
:func:`depth_normals`), not along the mesh's own vertex normal. The vertex normal averages over
one ring of faces, a width that halves with each template level: on the nose and around the eyes
the level-0 and level-1 normals differed by 10-20 degrees, which moved control points 5-10 mm
deep by 1-2 mm between the levels (the nasalis 1.5, the quadratus labii superioris 1.75, the
mentalis 1.9 mm). With it the static shapes of Table 6.4's presets on the default head agree
better between levels 0 and 1 (median FDP difference, with the held rule of
``physics.face_rig``: angry 17 -> 14 %, sad 20 -> 16 %, smile 9.7, laugh 7.5 -> 6.3, surprise
8.9 -> 8.3 %; ``benchmarks/solver_accuracy.py --parts levels``). A sphincter at the
``under_skin`` depth keeps the vertex normal (it follows the skin layer, which is extruded
along the vertex normals). None: the vertex normal for every muscle."""

_SPHINCTER_CURVES = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6], [6, 7, 0]])
_LINEAR_KEYS = ("insertion", "middle", "attachment")


def _interp_vertex(values: np.ndarray, F: np.ndarray, sp: SurfacePoints) -> np.ndarray:
    return np.einsum("kc,kc...->k...", sp.bary, values[F[sp.face]])


def depth_normals(V, F, points, depth, *, footprint: float | None = None) -> np.ndarray:
    """Unit outward skin normals for control points ``depth`` below the skin points ``points``:
    the area-weighted mean of the face normals of the mesh (V, F) with Gaussian weights
    ``exp(-(r / w)^2)``, r the distance of a face's centroid from the point and
    ``w = footprint * depth`` (:data:`NORMAL_FOOTPRINT`), so the direction does not depend on
    how finely the skin is meshed.

    Args:
        V: Head vertices [m], shape (n, 3), float.
        F: Triangles, shape (m, 3), int.
        points: Skin points [m], shape (k, 3), float.
        depth: Depth of each control point below its skin point [m], shape (k,), float, > 0.
        footprint: Width relative to the depth (default :data:`NORMAL_FOOTPRINT`).

    Returns:
        Unit normals, shape (k, 3), float64.
    """
    footprint = NORMAL_FOOTPRINT if footprint is None else footprint
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    width = footprint * np.asarray(depth, dtype=np.float64).reshape(-1)
    if not (np.isfinite(width).all() and (width > 0).all()):
        raise InputError(f"depth_normals: depth * footprint must be positive lengths [m], got {width}")
    an = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # twice the area times the unit normal
    C = V[F].mean(1)
    out, count = gaussian_sums(P, C, an, width)
    for i in np.flatnonzero(count == 0):  # no face within reach: the nearest one
        j = int(np.argmin(np.linalg.norm(C - P[i], axis=1)))
        out[i] = np.exp(-((np.linalg.norm(C[j] - P[i]) / width[i]) ** 2)) * an[j]
    n = np.linalg.norm(out, axis=1, keepdims=True)
    if (n <= 0).any():
        raise InputError("depth_normals: the skin around a control point has no mean normal (faces cancel)")
    return out / n


def build_muscles(template, skin_layer=None, *, defs=None, placements=None) -> MuscleSet:
    """Place the muscles on a head and attach them to its skin layer (Sec. 6.3).

    Args:
        template: A head with ``vertices``, ``faces``, ``thickness``, ``skull_depth`` and
            ``landmarks()`` (a :class:`facewarp.Template`).
        skin_layer: The head's :class:`~facewarp.anatomy.SkinLayer`; without it no nodes
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
    muscles = _place_muscles(template, defs, placements or {})
    by = {m.name: m for m in muscles}
    _segment_muscles(muscles, by, dflt)
    anchors = _anchor_muscles(defs, by)
    if skin_layer is not None:
        _attach_muscles(muscles, skin_layer, template)
    return MuscleSet(muscles=muscles, anchors=anchors, defaults=dict(dflt))


def _place_muscles(template, defs: dict, placements: dict) -> list[Muscle]:
    """Step 1 of :func:`build_muscles`: every muscle instance with its skin points and control
    points (the FDP rules resolved on the head, or the given ``placements``)."""
    dflt = defs.get("defaults", {})
    mirror = defs.get("mirror_fdp", {})
    V = np.asarray(template.vertices, dtype=np.float64)
    F = np.asarray(template.faces, dtype=np.int64)
    N = vertex_normals(V, F)
    lm = template.landmarks()

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
                # Sec. 6.3's ring depth; "under_skin": right below the skin layer (t_skin + r), as
                # the palpebral orbicularis oculi lies under the thin lid skin on the tarsal plates
                # (the thesis depth would put it inside the eyeball)
                rule = m.get("depth", "thesis")
                if rule not in ("thesis", "under_skin"):
                    raise InputError(f"muscle {name}: depth must be 'thesis' or 'under_skin', got {rule!r}")
                depth = 0.5 * (2 * t_skin + t_skull) if rule == "thesis" else t_skin + r
                sw = float(dflt.get("sphincter_weight", np.sqrt(0.5)))
                w = np.array([1.0, sw] * 4)
                curves = _SPHINCTER_CURVES.copy()
            if NORMAL_FOOTPRINT is not None and (kind is MuscleKind.LINEAR or rule == "thesis"):
                # (a ring right under the skin, "under_skin", follows the skin layer's own
                # extrusion along the vertex normals)
                n = depth_normals(V, F, skin, depth)
            center = None
            if kind is not MuscleKind.LINEAR and "center" in m:
                # the rule's point itself (it may lie in an opening, the palpebral fissure), moved
                # inward by the ring's mean depth along the ring's mean skin normal
                crule = _mirror_rule(m["center"], mirror) if side == "R" else m["center"]
                cn = n.mean(0)
                cn = cn / np.linalg.norm(cn)
                center = _rule_target(crule, lm, f"muscle {name} center") - float(depth.mean()) * cn
            center_normal = None
            if kind is not MuscleKind.LINEAR and m.get("to_plane", False):
                fixed = [int(k) for k in m.get("fixed", [])]
                if len(fixed) < 2:
                    raise InputError(f"muscle {name}: to_plane needs 2 fixed control points (the chord), got {fixed}")
                cp = skin - depth[:, None] * n
                chord = cp[fixed[1]] - cp[fixed[0]]
                cn = np.cross(chord, [0.0, 0.0, 1.0])  # the plane of the chord and the face's forward z
                center_normal = cn / np.linalg.norm(cn)
            glide_center = None
            if kind is not MuscleKind.LINEAR and "glide_part" in m:
                part = m["glide_part"] + (f"_{side}" if side else "")
                parts = getattr(template, "parts", None) or {}
                if part in parts:  # a head without that part: the ring moves in straight lines
                    PV = np.asarray(parts[part][0], dtype=np.float64)
                    glide_center = 0.5 * (PV.min(0) + PV.max(0))
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
                    saturation=float(m.get("saturation", dflt.get("saturation", 0.0))),
                    regions=_side_regions(m.get("regions", []), side, f"muscle {name}"),
                    center=center,
                    center_normal=center_normal,
                    glide_center=glide_center,
                    fixed=tuple(int(k) for k in m.get("fixed", [])),
                )
            )
    return muscles


def _side_regions(names, side: str, where: str) -> tuple:
    """Template regions of a muscle: a name without a side takes the muscle's side (both sides
    for an unpaired muscle); a side-specific name is mirrored for the right side."""
    from ..template import REGIONS

    out = []
    for r in names:
        if side == "R" and r.endswith("_L"):
            r = r[:-2] + "_R"
        if r in REGIONS:
            out.append(r)
        elif side and f"{r}_{side}" in REGIONS:
            out.append(f"{r}_{side}")
        elif not side and f"{r}_L" in REGIONS:
            out += [f"{r}_L", f"{r}_R"]
        else:
            raise InputError(f"{where}: unknown region {r!r} (known: {', '.join(REGIONS)})")
    return tuple(out)


def node_regions(template, skin_layer) -> np.ndarray:
    """How much of every skin node lies in each template region: the share of the faces around
    the head vertex the node was extruded from that belong to the region, shape (n, R) float64
    (R = len(REGIONS); rows sum to 1). (The attachments themselves count the sheet area of a
    muscle's regions by triangle, :func:`~facewarp._src.anatomy.attach.attach_by_area`.)"""
    from ..template import REGIONS

    F = np.asarray(template.faces, dtype=np.int64)
    fr = np.asarray(template.face_region, dtype=np.int64)
    vr = np.zeros((len(template.vertices), len(REGIONS)))
    np.add.at(vr, (F.ravel(), np.repeat(fr, 3)), 1.0)
    vr /= np.maximum(vr.sum(1, keepdims=True), 1.0)
    return vr[np.asarray(skin_layer.source_vertex)]


def _segment_muscles(muscles: list[Muscle], by: dict[str, Muscle], dflt: dict) -> None:
    """Step 2: the ellipsoid segments of every muscle; the reference muscle gets
    ``reference_segments``, the others in proportion to their length (at least 2 for a linear
    muscle)."""
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


def _anchor_muscles(defs: dict, by: dict[str, Muscle]) -> list[Anchor]:
    """Step 3: the anchors of Fig. 6.3 (a sphincter control point and the insertions it follows)."""
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
            passive = float(a.get("passive_stiffness", defs.get("defaults", {}).get("anchor_passive_stiffness", 0.1)))
            if not (np.isfinite(passive) and passive > 0):
                raise InputError(f"anchor {a['name']}: passive_stiffness must be > 0, got {passive!r}")
            anchors.append(Anchor(name=a["name"] + (f"_{side}" if side else ""), members=members, position=pos,
                                  passive=passive))
    return anchors


def _attach_muscles(muscles: list[Muscle], skin_layer, template=None) -> None:
    """Step 4: attach the inner-sheet nodes of ``skin_layer`` to each muscle by the share of their
    sheet area within Fig. 6.4's rule (:func:`~facewarp._src.anatomy.attach.attach_by_area`):
    only area on the skin side of the muscle and, with the ``template`` (its ``face_region`` and
    ``frontal``), only area of the muscle's own regions counts."""
    from ..template import REGIONS

    X = skin_layer.vertices
    p = int((np.asarray(skin_layer.layer) == 0).sum())
    Fi = np.asarray(skin_layer.skin_faces) + skin_layer.layer_count * p  # the inner sheet's triangles
    samples = sheet_samples(X, Fi, skin_layer.direction)
    region = None
    if template is not None and getattr(template, "face_region", None) is not None:
        fidx = np.flatnonzero(np.asarray(template.frontal, dtype=bool))
        if len(fidx) == len(Fi):  # skin face j was extruded from frontal face j
            region = np.asarray(template.face_region)[fidx][samples.face]
    for mu in muscles:
        mask = None
        if region is not None and mu.regions:
            mask = np.isin(region, [REGIONS.index(r) for r in mu.regions])
        mu.attachment = attach_by_area(X, mu.segments, mu.lam, mu.phi, samples, sample_mask=mask,
                                       directions=skin_layer.direction)


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

    For scenes that are not heads (e.g. the slab of :func:`facewarp.anatomy.slab_anatomy`).

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
            "saturation": m.saturation,
            "regions": list(m.regions),
            "fixed": list(m.fixed),
            "center": m.center,
            "center_normal": m.center_normal,
            "glide_center": m.glide_center,

            "segments": None
            if e is None
            else {"centers": e.centers, "axes": e.axes, "radii": e.radii, "curve": e.curve, "t": e.t},
            "attachment": None
            if a is None
            else {"nodes": a.nodes, "segment": a.segment, "uv": a.uv, "rest_length": a.rest_length, "weight": a.weight},
        }
    for an in ms.anchors:
        out["anchors"][an.name] = {"members": [list(x) for x in an.members], "position": an.position,
                                   "passive_stiffness": an.passive}
    return out
