"""Import the ICT-FaceKit neutral head as a full facewarp :class:`Template`.

The ICT-FaceKit light model (MIT) gives a realistic head in centimetres with a fixed topology
(vertex ranges in the kit's README): face 0-9408 and head + neck 9409-11247 (the skin),
gums + tongue 14062-17038, teeth 17039-21450 (upper 17039-19246, lower 19247-21450), the left
eyeball 21451-23020 (at +x, the subject's left) and the right one 23021-24590.

Everything the pipeline needs besides the geometry is transferred from the default template
(:func:`default_template` level 0) through the adaptation (Sec. 4.3-4.5), so nothing is labelled
by hand:

1. the default template (its head FDPs) is adapted to the ICT skin with the 12 FDPs both
   heads have (:data:`ICT_FDP_VERTICES`), method multilevel; the adapted template is taken in
   the ICT frame (``AdaptResult.vertices_scan_frame``, i.e. ``calibration.transform.inverse()``
   applied to the adapted template);
2. FDPs: the 12 known ones exactly at their ICT vertices; every other head FDP at the ICT skin
   point closest to the adapted template's FDP; pupils (3.5, 3.6) at the front-most point of
   the ICT eyeballs; teeth (9.8-9.11) on the ICT central incisors; tongue (6.1-6.4) on the
   tongue of the ICT gums + tongue mesh;
3. regions: each ICT face takes the region of the closest adapted-template face (by centroid);
   frontal faces are those of :data:`FRONTAL_REGIONS`; thickness per vertex is Table 6.1 x
   :data:`THICKNESS_FACTOR` averaged over the regions around the vertex (as for the default
   template); skull depth is the adapted template's, interpolated at the closest point;
4. condyles: the default template's, mapped by the least-squares similarity of the shared FDPs
   (template -> ICT);
5. rigid parts (``eye_L``, ``eye_R``, ``teeth_upper``, ``teeth_lower``, ``tongue``) are the ICT
   meshes of those ranges (the ``tongue`` part is the whole gums + tongue mesh).

The result has ``level = -1`` (not one of the default template's levels).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import face_normals
from ..landmarks import FDP_IDS
from ..mesh import SurfacePoints, closest_surface_points, load_mesh, mesh_report
from .head import FRONTAL_REGIONS, REGIONS, THICKNESS_FACTOR, Template, _vertex_thickness, default_template
from .likeness import ICT_FDP_VERTICES

__all__ = ["ICT_MESH", "ICT_SKIN_VERTICES", "ICT_PART_RANGES", "import_ict", "ict_import_report"]

ICT_MESH = "generic_neutral_mesh.obj"
ICT_SKIN_VERTICES = 11248
"""Vertices 0..11247: face (0-9408) and head + neck (9409-11247)."""

ICT_PART_RANGES: dict[str, tuple[int, int]] = {
    "eye_L": (21451, 23021),  # ICT "Eyeball left" lies at +x (the subject's left)
    "eye_R": (23021, 24591),
    "teeth_upper": (17039, 19247),
    "teeth_lower": (19247, 21451),
    "tongue": (14062, 17039),  # gums and tongue (one connected mesh in the kit)
}
"""Part name -> [start, stop) ICT vertex range."""

_UPPER_CENTRAL_INCISORS = (18067, 18219)
_LOWER_CENTRAL_INCISORS = (20263, 20435)
_ICT_VERTEX_COUNT = 24591  # the last range above must exist

MM = 1e-3
# Crown heights above the incisal edges (the default template's arches: 9.2 and 8.2 mm;
# adult central incisors: upper about 10.5 mm, lower about 9 mm). The ICT teeth carry their
# roots, so "top of upper teeth" (9.8) and "bottom of lower teeth" (9.9) are taken at the crown
# height above / below the incisal edge on the labial surface, not at the root apex.
_UPPER_CROWN = 10.0 * MM
_LOWER_CROWN = 9.0 * MM
_GUM_CLEARANCE = 5.0 * MM  # gums + tongue vertices farther than this from the teeth: not gums
_MIDLINE = 3.0 * MM
_INNER_UPPER_LIP = ("2.6", "2.7")
_INNER_LOWER_LIP = ("2.8", "2.9")


def _load_ict(ict_dir) -> tuple[np.ndarray, np.ndarray]:
    """The ICT neutral mesh in metres (vertex order kept). Raises a one-line InputError."""
    d = Path(ict_dir)
    if not d.is_dir():
        raise InputError(f"{d}: not an ICT-FaceKit folder (no such directory)")
    path = d / ICT_MESH
    if not path.is_file():
        raise InputError(f"{d}: not an ICT-FaceKit folder ({ICT_MESH} is missing)")
    m = load_mesh(path, units="cm")
    if len(m.vertices) < _ICT_VERTEX_COUNT:
        raise InputError(f"{path}: {len(m.vertices)} vertices, expected the ICT-FaceKit topology (26719 vertices)")
    return m.vertices, m.faces


def _sub_mesh(V, F, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [start, stop) and the faces lying entirely within them, re-indexed."""
    f = F[((F >= start) & (F < stop)).all(1)] - start
    return np.ascontiguousarray(V[start:stop], dtype=np.float64), np.ascontiguousarray(f, dtype=np.int64)


def _vertex_point(F: np.ndarray, vertex: int) -> SurfacePoints:
    """A surface point exactly at ``vertex``: a face containing it, barycentric one-hot."""
    rows, cols = np.nonzero(F == vertex)
    if len(rows) == 0:
        raise InputError(f"ICT vertex {vertex} is on no skin face")
    bary = np.zeros((1, 3))
    bary[0, cols[0]] = 1.0
    return SurfacePoints(np.array([rows[0]]), bary)


def _closest(V, F, P, device) -> list[SurfacePoints]:
    sp = closest_surface_points(V, F, np.atleast_2d(P), device=device)
    return [SurfacePoints(sp.face[k : k + 1], sp.bary[k : k + 1]) for k in range(len(sp))]


def _internal_fdps(V_all: np.ndarray, parts: dict, device: str) -> dict[str, tuple[str, SurfacePoints]]:
    """Pupils, teeth and tongue FDPs on the ICT parts."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    out = {}
    # pupils: front-most point of each eyeball (the cornea apex; the eyes look along +z)
    for fid, part in (("3.5", "eye_L"), ("3.6", "eye_R")):
        PV, PF = parts[part]
        out[fid] = (part, _closest(PV, PF, PV[np.argmax(PV[:, 2])], device)[0])

    # teeth: the central incisors' incisal edges; crown top / bottom on the labial surface
    def edge(rng, pick):
        P = V_all[rng[0] : rng[1]]
        y = pick(P[:, 1])
        near = P[np.abs(P[:, 1] - y) < 0.5 * MM]
        return np.array([0.0, y, near[:, 2].mean()]), P

    def labial(P, y):
        band = P[np.abs(P[:, 1] - y) < 1.0 * MM]
        return np.array([0.0, y, band[:, 2].max()])

    up_edge, Pu = edge(_UPPER_CENTRAL_INCISORS, np.min)
    lo_edge, Pl = edge(_LOWER_CENTRAL_INCISORS, np.max)
    tu, tl = parts["teeth_upper"], parts["teeth_lower"]
    sp_u = _closest(*tu, np.stack([labial(Pu, up_edge[1] + _UPPER_CROWN), up_edge]), device)
    sp_l = _closest(*tl, np.stack([labial(Pl, lo_edge[1] - _LOWER_CROWN), lo_edge]), device)
    out["9.8"], out["9.10"] = ("teeth_upper", sp_u[0]), ("teeth_upper", sp_u[1])
    out["9.9"], out["9.11"] = ("teeth_lower", sp_l[0]), ("teeth_lower", sp_l[1])

    # tongue: the largest connected piece of the gums + tongue mesh left after removing the
    # vertices near the teeth (the gums); it holds the tongue and the floor of the mouth.
    GV, GF = parts["tongue"]
    teeth = np.concatenate([tu[0], tl[0]])
    d, _ = cKDTree(teeth).query(GV)
    keep = d > _GUM_CLEARANCE
    kf = GF[keep[GF].all(1)]
    nG = len(GV)
    A = sp.coo_matrix((np.ones(kf.size), (kf.ravel(), np.roll(kf, 1, 1).ravel())), shape=(nG, nG))
    _, lab = connected_components(A, directed=False)
    lab = np.where(keep, lab, -1)
    sizes = np.bincount(lab[keep])
    idx = np.flatnonzero(lab == np.argmax(sizes))
    mid = idx[np.abs(GV[idx, 0]) < _MIDLINE]
    if len(idx) < 50 or len(mid) == 0:
        raise InputError("ICT gums + tongue: could not find the tongue (too few vertices away from the teeth)")
    # tip: front-most on the midline; centre: top of the midline at the mean depth;
    # borders: the widest points of the upper half (the tongue, not the floor of the mouth)
    tip = mid[np.argmax(GV[mid, 2])]
    zc = GV[idx, 2].mean()
    body = mid[np.abs(GV[mid, 2] - zc) < 5.0 * MM]
    top = (body if len(body) else mid)[np.argmax(GV[body if len(body) else mid, 1])]
    upper = idx[GV[idx, 1] > np.median(GV[idx, 1])]
    left, right = upper[np.argmax(GV[upper, 0])], upper[np.argmin(GV[upper, 0])]
    sps = _closest(GV, GF, GV[[tip, top, left, right]], device)
    for fid, sp in zip(("6.1", "6.2", "6.3", "6.4"), sps):
        out[fid] = ("tongue", sp)
    return out


def import_ict(ict_dir: str | os.PathLike, *, levels: int = 3, device: str = "cpu", report: dict | None = None) -> Template:
    """The ICT-FaceKit neutral head as a :class:`Template` (level -1), everything in metres.

    Args:
        ict_dir: The ICT-FaceKit folder holding ``generic_neutral_mesh.obj``.
        levels: Adaptation levels of the default template onto the ICT skin.
        device: Warp device of the closest-point queries.
        report: Optional dict filled with diagnostics (adaptation residuals, mesh report).

    Raises:
        InputError: A missing folder or mesh, or a mesh without the ICT topology.
    """
    from ..adapt import adapt
    from ..adapt_io import _vertex_groups
    from ..calibrate import fit_similarity
    from ..geometry import closest_point

    V_all, F_all = _load_ict(ict_dir)
    n = ICT_SKIN_VERTICES
    V, F = _sub_mesh(V_all, F_all, 0, n)
    if len(np.unique(F)) != n:
        raise InputError(f"{ict_dir}: the ICT skin (vertices 0-{n - 1}) has unreferenced vertices; not the ICT topology")
    rep = mesh_report(V, F)

    # 1. adapt the default template to the ICT skin
    t = default_template(0)
    tlm = {k: v for k, v in t.landmarks().items() if t.fdp[k][0] == "head"}
    ict_lm = {k: V[i] for k, i in ICT_FDP_VERTICES.items() if k in tlm}
    res = adapt(t.vertices, t.faces, tlm, V, F, ict_lm, method="multilevel", levels=levels,
                region=_vertex_groups(t), device=device)
    AV = res.vertices_scan_frame  # = calibration.transform.inverse().apply(res.vertices)
    adapted_lm = {k: sp.positions(AV, t.faces)[0] for k, (part, sp) in t.fdp.items() if part == "head"}

    # 2. FDPs
    fdp: dict[str, tuple[str, SurfacePoints]] = {}
    for k, i in ICT_FDP_VERTICES.items():
        fdp[k] = ("head", _vertex_point(F, i))
    # inner-lip midpoints: the ICT mouth is closed, so the plain closest point may fall on the
    # other lip; the upper ones go onto faces looking down, the lower ones onto faces looking up
    fn = face_normals(V, F)
    for ids, side in ((_INNER_UPPER_LIP, fn[:, 1] < 0), (_INNER_LOWER_LIP, fn[:, 1] > 0)):
        sub = np.flatnonzero(side)
        for k, sp in zip(ids, _closest(V, F[sub], np.array([adapted_lm[k] for k in ids]), device)):
            fdp[k] = ("head", SurfacePoints(sub[sp.face], sp.bary))
    rest = [k for k in adapted_lm if k not in fdp]
    for k, sp in zip(rest, _closest(V, F, np.array([adapted_lm[k] for k in rest]), device)):
        fdp[k] = ("head", sp)
    parts = {name: _sub_mesh(V_all, F_all, a, b) for name, (a, b) in ICT_PART_RANGES.items()}
    fdp.update(_internal_fdps(V_all, parts, device))
    missing = set(FDP_IDS) - set(fdp)
    if missing:  # the default template has every FDP; this would be a bug here
        raise AssertionError(f"ICT import lacks FDPs {sorted(missing)}")
    fdp = {k: fdp[k] for k in FDP_IDS}

    # 3. regions, thickness, skull depth
    cp = closest_point(AV, t.faces, V[F].mean(1), device=device)
    region = np.asarray(t.face_region)[cp.face].astype(np.int16)
    frontal = np.isin(region, [REGIONS.index(r) for r in FRONTAL_REGIONS])
    thickness = _vertex_thickness(F, region, n, THICKNESS_FACTOR)
    cv = closest_point(AV, t.faces, V, device=device)
    skull = np.einsum("kc,kc->k", cv.bary, np.asarray(t.skull_depth)[t.faces[cv.face]])

    # 4. condyles: least-squares similarity template -> ICT on the shared FDPs
    ids = list(ict_lm)
    sim = fit_similarity(np.array([tlm[k] for k in ids]), np.array([ict_lm[k] for k in ids]))
    condyles = sim.apply(np.asarray(t.condyles))

    if report is not None:
        inv = res.calibration.transform.inverse()
        report.update({
            "skin_mesh": rep,
            "adapt_seconds": res.seconds,
            "calibration_scale": float(res.calibration.transform.scale),
            "fdp_residual_adapted_m": {k: float(np.linalg.norm(adapted_lm[k] - ict_lm[k])) for k in ids},
            "frame_check_m": float(np.abs(inv.apply(res.vertices) - AV).max()),
            "region_distance_m": {"median": float(np.median(cp.dist)), "max": float(cp.dist.max())},
            "skin_to_adapted_m": {"median": float(np.median(cv.dist)), "p95": float(np.percentile(cv.dist, 95)),
                                  "max": float(cv.dist.max())},
            "condyle_similarity_scale": float(sim.scale),
        })

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
        level=-1,
        thickness_factor=THICKNESS_FACTOR,
    )


def ict_import_report(t: Template) -> dict:
    """A few counts of an imported head (JSON-ready)."""
    counts = np.bincount(t.face_region, minlength=len(REGIONS))
    return {
        "vertex_count": t.vertex_count,
        "face_count": t.face_count,
        "frontal_face_count": int(t.frontal.sum()),
        "fdp_count": len(t.fdp),
        "regions": {r: int(c) for r, c in zip(REGIONS, counts)},
        "parts": {k: len(v[0]) for k, v in t.parts.items()},
    }
