"""Import the ICT-FaceKit neutral head as a full facewarp :class:`Template`.

The ICT-FaceKit light model (MIT) gives a realistic head in centimetres with a fixed topology
(vertex ranges in the kit's README): face 0-9408 and head + neck 9409-11247 (the skin),
gums + tongue 14062-17038, teeth 17039-21450 (upper 17039-19246, lower 19247-21450), the left
eyeball 21451-23020 (at +x, the subject's left) and the right one 23021-24590.

Everything the pipeline needs besides the geometry is transferred from the default template
(:func:`default_template` level 0) through the adaptation (Sec. 4.3-4.5), so nothing is labelled
by hand:

1. the default template (its head FDPs) is adapted to the ICT skin, method multilevel, with
   the FDPs known on ICT: the 12 of :data:`ICT_FDP_VERTICES`, the inner lip contour 2.4-2.9
   (ICT's Multi-PIE landmarks 60-67, :data:`ICT_INNER_LIP_VERTICES`) and the lid margins
   3.1-3.4 (top and bottom of ICT's eye openings at the pupils; without them the template's
   eye openings end up about 5 mm below ICT's). The adapted template is taken in the ICT frame
   (``AdaptResult.vertices_scan_frame``, i.e. ``calibration.transform.inverse()`` applied);
2. FDPs: the known ones exactly at their ICT vertices; every other head FDP at the ICT skin
   point closest to the adapted template's FDP, made mirror-symmetric (the ICT neutral head is
   symmetric about x = 0, the adaptation not exactly) and with centre FDPs on the midline;
   pupils (3.5, 3.6) at the front-most point of the ICT eyeballs; teeth (9.8-9.11) on the
   ICT central incisors; tongue (6.1-6.4) on the tongue of the ICT gums + tongue mesh;
3. regions: each ICT face takes the region of the closest adapted-template face (by centroid),
   the faces at x < 0 then the mirrored region of their mirror face. Frontal faces are those
   of :data:`FRONTAL_REGIONS` except where no usable skin layer can be extruded: the inside of
   the closed mouth (behind the inner lip contour), the creases where the closed lips press
   together at the corners, and faces whose skin-layer tets would be flatter than 0.2 mm (the
   lid margins curling into the eye sockets, the nostril rims). Thickness per vertex is Table
   6.1 x :data:`THICKNESS_FACTOR` averaged over the regions around the vertex (as for the
   default template); skull depth is the adapted template's, interpolated at the closest point
   (averaged with the mirror image's);
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

from ..core.errors import InputError
from ..geometry.tets import tet_heights
from ..geometry.surface import vertex_normals
from ..geometry.landmarks import FDP_CATALOGUE, FDP_IDS
from ..geometry.mesh import SurfacePoints, closest_surface_points, load_mesh, mesh_report
from ..template.head import FRONTAL_REGIONS, REGIONS, THICKNESS_FACTOR, Template, _vertex_thickness, default_template
from ..template.likeness import ICT_FDP_VERTICES

__all__ = [
    "ICT_INNER_LIP_VERTICES",
    "ICT_MESH",
    "ICT_PART_RANGES",
    "ICT_SKIN_VERTICES",
    "ict_import_report",
    "import_ict",
]

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

ICT_INNER_LIP_VERTICES = {"2.4": 6207, "2.5": 5702, "2.6": 6216, "2.7": 5711, "2.8": 6470, "2.9": 5966}
"""Inner-lip FDPs -> ICT vertex: ICT's Multi-PIE 68 landmarks 60-67 (inner lip contour, kit README)."""
_INNER_LIP_LOOP = (5702, 5711, 5533, 6216, 6207, 6470, 5517, 5966)
"""The inner lip contour (Multi-PIE 60-67) in order around the closed mouth."""


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


def _lid_margin_vertices(V: np.ndarray, F: np.ndarray, parts: dict) -> dict[str, int]:
    """ICT skin vertices of the lid-margin FDPs 3.1-3.4: the top and bottom of each eye opening.

    The skin ends at the lid margins (one boundary loop per eye), as in the default template
    whose 3.1-3.4 sit on its eye cut; they are taken on the loop at the pupil's x (the front-most
    point of the eyeball), nearest vertex.
    """
    from ..geometry.surface import boundary_vertices

    b = np.flatnonzero(boundary_vertices(F, len(V)))
    out = {}
    for part, (up, dn) in (("eye_L", ("3.1", "3.3")), ("eye_R", ("3.2", "3.4"))):
        E = parts[part][0]
        c, front = E.mean(0), E[np.argmax(E[:, 2])]
        near = b[(np.abs(V[b, 0] - c[0]) < 16.0 * MM) & (np.abs(V[b, 1] - c[1]) < 12.0 * MM) & (V[b, 2] > c[2])]
        if len(near) < 8:
            raise InputError(f"ICT skin: no eye opening found around the {part} eyeball")
        for fid, above in ((up, True), (dn, False)):
            half = near[(V[near, 1] > c[1]) if above else (V[near, 1] <= c[1])]
            if len(half) == 0:
                which = "upper" if above else "lower"
                raise InputError(f"ICT skin: the eye opening around {part} has no {which} lid margin")
            out[fid] = int(half[np.argmin(np.abs(V[half, 0] - front[0]))])
    return out


def _mouth_interior(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Faces of the ICT skin behind the lip contact line (inside the closed mouth), mask (m,).

    The ICT mouth is closed and its skin runs on past the lips' contact into the mouth, where it
    folds back on itself at the lip corners (no inward direction exists there, so no skin layer
    can be extruded). The default template's mouth is cut open at the inner lip contour; here
    the skin is cut along ICT's inner lip contour (shortest edge paths through Multi-PIE 60-67)
    and the side holding the mouth's boundary loop is the interior.
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components, dijkstra

    from ..geometry.surface import boundary_vertices

    n = len(V)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    Es = np.sort(E, axis=1)
    Eu, inv = np.unique(Es, axis=0, return_inverse=True)
    w = np.linalg.norm(V[Eu[:, 0]] - V[Eu[:, 1]], axis=1)
    G = sp.coo_matrix((np.r_[w, w], (np.r_[Eu[:, 0], Eu[:, 1]], np.r_[Eu[:, 1], Eu[:, 0]])), shape=(n, n)).tocsr()
    loop = list(_INNER_LIP_LOOP) + [_INNER_LIP_LOOP[0]]
    _, pred = dijkstra(G, indices=loop[:-1], return_predecessors=True)
    cut = set()
    for k, (a, b) in enumerate(zip(loop[:-1], loop[1:])):
        v = b
        while v != a:
            u = pred[k, v]
            if u < 0:
                raise InputError("ICT skin: the inner lip contour is not connected; not the ICT topology")
            cut.add((min(u, v), max(u, v)))
            v = u
    m = len(F)
    edge_id = inv.reshape(-1)  # edge of (face k mod m, side k // m)
    face_of = np.tile(np.arange(m), 3)
    is_cut = np.array([tuple(e) in cut for e in Eu.tolist()])
    order = np.argsort(edge_id, kind="stable")
    e_sorted, f_sorted = edge_id[order], face_of[order]
    pair = np.flatnonzero((e_sorted[1:] == e_sorted[:-1]) & ~is_cut[e_sorted[1:]])
    A = sp.coo_matrix((np.ones(len(pair)), (f_sorted[pair], f_sorted[pair + 1])), shape=(m, m))
    nc, lab = connected_components(A, directed=False)
    if nc != 2:
        raise InputError(f"ICT skin: cutting along the inner lip contour gives {nc} pieces, expected 2")
    small = int(np.argmin(np.bincount(lab)))
    inside = lab == small
    bv = boundary_vertices(F, n)
    if not bv[F[inside]].any():
        raise InputError("ICT skin: the mouth interior has no boundary loop; not the ICT topology")
    return inside


def _crease_faces(V: np.ndarray, F: np.ndarray, frontal: np.ndarray, *, min_cos: float = 0.0,
                  rounds: int = 10) -> np.ndarray:
    """Frontal faces around creases where the skin folds back on itself, mask (m,).

    A vertex whose frontal triangles face opposite ways (two normals more than 90 degrees
    apart) has no usable inward direction, so the skin layer cannot be extruded there. In the
    closed ICT mouth this happens where the lips are pressed together at the corners, between
    the inner and the outer lip corners. Those triangles are removed from the frontal face,
    repeatedly, until no such vertex is left. (At 120 degrees the folds left at the lip corners
    extrude into tets of ~0.05 mm^3 that a smile flattens before full activation; the line
    search then stalls there: lip corner 8.6 mm instead of 11.4 at zygomatic major 1.0.)
    """
    from ..geometry.surface import face_normals

    N = face_normals(V, F)
    keep = frontal.copy()
    for _ in range(rounds):
        idx = np.flatnonzero(keep)
        vf = np.stack([F[idx].ravel(), np.repeat(idx, 3)], 1)
        vf = vf[np.argsort(vf[:, 0], kind="stable")]
        starts = np.flatnonzero(np.r_[True, vf[1:, 0] != vf[:-1, 0]])
        bad_faces = []
        for a, b in zip(starts, np.r_[starts[1:], len(vf)]):
            fs = vf[a:b, 1]
            if len(fs) > 1:
                n = N[fs]
                if (n @ n.T).min() < min_cos:
                    bad_faces.append(fs)
        if not bad_faces:
            break
        keep[np.concatenate(bad_faces)] = False
    return frontal & ~keep


def _loose_faces(F: np.ndarray, frontal: np.ndarray) -> np.ndarray:
    """Frontal faces that hang on the rest by a vertex or not at all, mask (m,).

    Removing creases and thin faces can leave single triangles touching the frontal face at one
    vertex only (bow-tie vertices at the lip corners, lid corners and nostrils) or not at all.
    Extruded, such a triangle is a prism joined to the skin layer along the one edge under that
    vertex (a hinge) or nowhere: a motion that costs no elastic energy, which makes the implicit
    solver's factorised Hessian near-singular (its steps reach metres and every line search
    fails, so the face barely follows the muscles). Kept are the largest edge-connected
    component and, at each vertex, the largest fan of triangles joined through edges at that
    vertex; repeated until nothing changes.
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    keep = frontal.copy()
    n = int(F.max()) + 1
    while keep.any():
        idx = np.flatnonzero(keep)
        Ff = F[idx]
        m = len(idx)
        # half-edge 3 f + e runs from corner 3 f + e to corner 3 f + (e + 1) % 3
        a, b = Ff.ravel(), Ff[:, [1, 2, 0]].ravel()
        key = np.minimum(a, b) * n + np.maximum(a, b)
        o = np.argsort(key, kind="stable")
        pair = np.flatnonzero(key[o][1:] == key[o][:-1])
        h1, h2 = o[pair], o[pair + 1]  # half-edges of two faces on one edge
        faces = sp.coo_matrix((np.ones(len(h1)), (h1 // 3, h2 // 3)), shape=(m, m))
        _, comp = connected_components(faces, directed=False)
        loose = comp != np.argmax(np.bincount(comp))
        # corners of one vertex joined across a shared edge (both ends of the edge)
        nxt = lambda h: 3 * (h // 3) + (h % 3 + 1) % 3  # noqa: E731
        same = a[h1] == a[h2]
        c1 = np.concatenate([h1, nxt(h1)])
        c2 = np.concatenate([np.where(same, h2, nxt(h2)), np.where(same, nxt(h2), h2)])
        _, fan = connected_components(sp.coo_matrix((np.ones(len(c1)), (c1, c2)), shape=(3 * m, 3 * m)),
                                      directed=False)
        vf, size = np.unique(np.stack([a, fan], 1), axis=0, return_counts=True)  # (vertex, fan) pairs
        order = np.lexsort((-size, vf[:, 0]))  # by vertex, its largest fan first
        first = order[np.r_[True, vf[order[1:], 0] != vf[order[:-1], 0]]]
        big = np.full(n, -1, np.int64)
        big[vf[first, 0]] = vf[first, 1]
        loose[np.flatnonzero(fan != big[a]) // 3] = True
        if not loose.any():
            break
        keep[idx[loose]] = False
    return frontal & ~keep


_MIRROR = np.array([-1.0, 1.0, 1.0])


def _symmetrized(adapted: dict[str, np.ndarray], template: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """FDP positions made mirror-symmetric about x = 0 (the ICT neutral head is symmetric).

    The adaptation is not exactly symmetric (its feature points are sampled one at a time), so
    left and right FDPs would differ by a few millimetres: each left / right pair is replaced
    by the mean of one and the mirror image of the other, centre FDPs get x = 0. Partners are
    the FDPs of the other side nearest to each other's mirror image on the default template.
    """
    out = dict(adapted)
    rights = [k for k in template if FDP_CATALOGUE[k].side == "right"]
    for k in template:
        side = FDP_CATALOGUE[k].side
        if side == "center":
            out[k] = adapted[k] * np.array([0.0, 1.0, 1.0])
        elif side == "left" and rights:
            r = min(rights, key=lambda j: np.linalg.norm(template[j] - template[k] * _MIRROR))
            if np.linalg.norm(template[r] - template[k] * _MIRROR) < 2.0 * MM:
                out[k] = 0.5 * (adapted[k] + adapted[r] * _MIRROR)
                out[r] = out[k] * _MIRROR
    return out


def _symmetric_regions(V: np.ndarray, F: np.ndarray, region: np.ndarray, device: str) -> np.ndarray:
    """Regions made mirror-symmetric: faces at x < 0 take the mirrored label of their mirror face."""
    from ..geometry.surface import closest_point

    swap = np.array([REGIONS.index(r[:-1] + ("R" if r.endswith("_L") else "L")) if r[-2:] in ("_L", "_R") else i
                     for i, r in enumerate(REGIONS)])
    C = V[F].mean(1)
    right = np.flatnonzero(C[:, 0] < 0)
    mirror = closest_point(V, F, C[right] * _MIRROR, device=device).face
    out = region.copy()
    out[right] = swap[region[mirror]]
    return out.astype(np.int16)


def _midline_points(V: np.ndarray, F: np.ndarray, P: np.ndarray) -> list[SurfacePoints]:
    """The closest points of P on the skin's midline (the edges with both ends at x = 0).

    The closest skin point of a centre FDP may slide off the midline on a narrow ridge (the
    nose); the ICT mesh has its midline as edges at x = 0 exactly, so centre FDPs are put there.
    """
    on = np.abs(V[:, 0]) < 1e-9
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    face_of = np.tile(np.arange(len(F)), 3)
    col = np.repeat([0, 1, 2], len(F))
    mid = np.flatnonzero(on[E].all(1))
    if len(mid) == 0:
        raise InputError("ICT skin: no midline edges at x = 0; not the ICT topology")
    A, B = V[E[mid, 0]], V[E[mid, 1]]
    D = B - A
    out = []
    for p in np.atleast_2d(P):
        s = np.clip(np.einsum("ij,ij->i", p - A, D) / np.maximum(np.einsum("ij,ij->i", D, D), 1e-30), 0.0, 1.0)
        k = int(np.argmin(np.linalg.norm(A + s[:, None] * D - p, axis=1)))
        e = mid[k]
        bary = np.zeros((1, 3))
        bary[0, col[e]] = 1.0 - s[k]
        bary[0, (col[e] + 1) % 3] = s[k]
        out.append(SurfacePoints(np.array([face_of[e]]), bary))
    return out


_MIN_TET_HEIGHT = 0.2 * MM


def _thin_faces(V: np.ndarray, F: np.ndarray, frontal: np.ndarray, thickness: np.ndarray, *,
                rounds: int = 8) -> np.ndarray:
    """Frontal faces whose skin-layer tets come out flatter than :data:`_MIN_TET_HEIGHT`, mask (m,).

    Where the ICT skin curls round a thin edge (the lid margins run on into the eye sockets,
    where the default template's lids end at its eye cut; the nostril rims) the skin layer's
    depth is clamped to a fraction of a millimetre, and its tets get as flat as 5 um. The flattest tet sets the stable
    time step of the simulation (``solver.node_stable_dt``), so those faces are left out of the frontal
    face, repeatedly until every tet is at least :data:`_MIN_TET_HEIGHT` high (the default
    template's flattest is about 0.35 mm).
    """
    from types import SimpleNamespace

    from ..anatomy.tissue import build_skin_layer

    keep = frontal.copy()
    for _ in range(rounds):
        sl = build_skin_layer(SimpleNamespace(vertices=V, faces=F, frontal=keep, thickness=thickness))
        bad = np.unique(sl.tet_face[tet_heights(sl.vertices, sl.tets) < _MIN_TET_HEIGHT])
        if not len(bad):
            break
        keep[bad] = False
    return frontal & ~keep


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
    body = body if len(body) else mid
    # the piece also holds the palate above the tongue: keep the surface looking up (the mesh's
    # orientation sign is fixed by the tip, whose normal must look forward)
    N = vertex_normals(GV, GF)
    sgn = 1.0 if N[tip, 2] >= 0 else -1.0
    up = body[sgn * N[body, 1] > 0.5]
    top = (up if len(up) else body)[np.argmax(GV[up if len(up) else body, 1])]
    upper = idx[GV[idx, 1] > np.median(GV[idx, 1])]
    left, right = upper[np.argmax(GV[upper, 0])], upper[np.argmin(GV[upper, 0])]
    sps = _closest(GV, GF, GV[[tip, top, left, right]], device)
    for fid, sp in zip(("6.1", "6.2", "6.3", "6.4"), sps):
        out[fid] = ("tongue", sp)
    return out


def import_ict(ict_dir: str | os.PathLike, *, levels: int = 3, device: str = "cpu",
               report: dict | None = None) -> Template:
    """The ICT-FaceKit neutral head as a :class:`Template` (level -1), everything in metres.

    Args:
        ict_dir: The ICT-FaceKit folder holding ``generic_neutral_mesh.obj``.
        levels: Adaptation levels of the default template onto the ICT skin.
        device: Warp device of the closest-point queries.
        report: Optional dict filled with diagnostics (adaptation residuals, mesh report).

    Raises:
        InputError: A missing folder or mesh, or a mesh without the ICT topology.
    """
    from ..adapt.pipeline import adapt
    from ..adapt.metrics import vertex_groups
    from ..adapt.calibrate import fit_similarity
    from ..geometry.surface import closest_point

    V_all, F_all = _load_ict(ict_dir)
    n = ICT_SKIN_VERTICES
    V, F = _sub_mesh(V_all, F_all, 0, n)
    if len(np.unique(F)) != n:
        raise InputError(f"{ict_dir}: the ICT skin (vertices 0-{n - 1}) has unreferenced vertices; "
                         "not the ICT topology")
    rep = mesh_report(V, F)

    parts = {name: _sub_mesh(V_all, F_all, a, b) for name, (a, b) in ICT_PART_RANGES.items()}

    # 1. adapt the default template to the ICT skin on the FDPs known on ICT
    t = default_template(0)
    tlm = {k: v for k, v in t.landmarks().items() if t.fdp[k][0] == "head"}
    exact = {**ICT_FDP_VERTICES, **ICT_INNER_LIP_VERTICES, **_lid_margin_vertices(V, F, parts)}
    ict_lm = {k: V[i] for k, i in exact.items() if k in tlm}
    res = adapt(t.vertices, t.faces, tlm, V, F, ict_lm, method="multilevel", levels=levels,
                region=vertex_groups(t), device=device)
    AV = res.vertices_scan_frame  # = calibration.transform.inverse().apply(res.vertices)
    adapted_lm = {k: sp.positions(AV, t.faces)[0] for k, (part, sp) in t.fdp.items() if part == "head"}

    # 2. FDPs
    fdp: dict[str, tuple[str, SurfacePoints]] = {}
    for k, i in exact.items():
        fdp[k] = ("head", _vertex_point(F, i))
    rest = [k for k in adapted_lm if k not in fdp]
    sym_lm = _symmetrized(adapted_lm, tlm)
    for k, sp in zip(rest, _closest(V, F, np.array([sym_lm[k] for k in rest]), device)):
        fdp[k] = ("head", sp)
    centre = [k for k in rest if FDP_CATALOGUE[k].side == "center"]
    for k, sp in zip(centre, _midline_points(V, F, np.array([sym_lm[k] for k in centre]))):
        fdp[k] = ("head", sp)
    fdp.update(_internal_fdps(V_all, parts, device))
    missing = set(FDP_IDS) - set(fdp)
    if missing:  # the default template has every FDP; this would be a bug here
        raise AssertionError(f"ICT import lacks FDPs {sorted(missing)}")
    fdp = {k: fdp[k] for k in FDP_IDS}

    # 3. regions, thickness, skull depth
    cp = closest_point(AV, t.faces, V[F].mean(1), device=device)
    region = np.asarray(t.face_region)[cp.face].astype(np.int16)
    region = _symmetric_regions(V, F, region, device)
    frontal = np.isin(region, [REGIONS.index(r) for r in FRONTAL_REGIONS])
    inside = _mouth_interior(V, F)
    frontal[inside] = False  # the inner lips behind the closed mouth's contact line
    creased = _crease_faces(V, F, frontal)
    frontal[creased] = False  # the lips pressed together at the corners
    thickness = _vertex_thickness(F, region, n, THICKNESS_FACTOR)
    while True:
        frontal[_loose_faces(F, frontal)] = False  # triangles left hanging by a vertex
        thin = _thin_faces(V, F, frontal, thickness)
        if not thin.any():
            break
        frontal[thin] = False  # the lid margins curling into the eye sockets, the nostril rims
    cv = closest_point(AV, t.faces, V, device=device)
    skull = np.einsum("kc,kc->k", cv.bary, np.asarray(t.skull_depth)[t.faces[cv.face]])
    mv = closest_point(AV, t.faces, V * _MIRROR, device=device)  # the mirror image's depth
    skull = 0.5 * (skull + np.einsum("kc,kc->k", mv.bary, np.asarray(t.skull_depth)[t.faces[mv.face]]))

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


