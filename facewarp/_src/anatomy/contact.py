"""Contact geometry of a face rig (build time): the lips' surfaces and candidates, the dental arches,
the eyeballs, the fissure planes of the lids and the spheres the inner lid sheet glides on.

:func:`contact_geometry` makes the :class:`~facewarp._src.physics.contact.ContactGeometry` the
contact stage uses (:mod:`facewarp._src.physics.contact` describes the contact model); the face
rig computes it once (:func:`~facewarp._src.anatomy.rig.face_rig_from_anatomy`) and saves it
(``face_rig.npz``). :func:`lip_contact_geometry` and :func:`lid_contact_geometry` make the
lip-on-lip and lid-on-lid parts for any tet mesh.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..geometry.surface import winding_numbers
from ..geometry.tets import boundary_faces, lip_crossings, lip_tets
from ..physics.contact import CONTACT_GAP, ContactGeometry
from .lips import lip_sides

__all__ = ["EYE_NEAR_M", "GLIDE_MIN_HEIGHT_M", "GLIDE_TAPER", "LID_REACH", "TEETH_NEAR_M", "contact_geometry",
           "eyeball_sheet_nodes", "eyeball_spheres", "fissure_planes", "glide_spheres", "lid_contact_geometry",
           "lip_contact_geometry", "node_vertex"]

TEETH_NEAR_M = 1.2e-2
"""Inner-sheet nodes within this distance [m] of a dental arch at rest are its contact candidates."""


EYE_NEAR_M = 4.0e-3
"""Nodes within this distance [m] of an eyeball's sphere at rest are its contact candidates."""


LID_REACH = 2.0
"""Lid candidates lie within this many times the ring's height (its control points' largest
distance from the fissure plane) of the plane: the lids, not the brow or the cheek."""


GLIDE_TAPER = 0.15
"""Share of the corner chord at either end over which the gliding lids' meeting depth tapers to
their rest depth (:func:`glide_spheres`)."""


GLIDE_MIN_HEIGHT_M = 1.0e-3
"""A gliding node's distance [m] from its fissure plane is taken as at least this much
(:func:`glide_spheres`)."""


_LID_JAW_MAX = 0.05  # a fissure plane rides the cranium (fissure_planes)


_TEETH = ("teeth_upper", "teeth_lower")


_EYES = ("eye_L", "eye_R")


def node_vertex(fr) -> np.ndarray:
    """Head vertex every tet node lies on or under, shape (p,), int64 (-1 where unknown).

    Sheets are stored one after another (node ``l q + i`` under outer node ``i``; see
    :func:`~facewarp._src.physics.face_rig.node_jaw_amounts`)."""
    n = len(fr.nodes)
    q = int((np.asarray(fr.layer) == 0).sum())
    sv = np.asarray(fr.surface_vertex, np.int64)
    if q and n % q == 0 and (sv[:q] >= 0).all():
        return sv[np.arange(n) % q]
    return sv.copy()


def _sphere(V) -> tuple[np.ndarray, float]:
    V = np.asarray(V, np.float64)
    c = V.mean(axis=0)
    return c, float(np.linalg.norm(V - c, axis=1).mean())


def eyeball_spheres(parts) -> tuple[np.ndarray, np.ndarray]:
    """The eyeballs' spheres: centre (the mean of the part's vertices) and radius (their mean
    distance from it) of ``parts["eye_L"]`` and ``parts["eye_R"]`` where present.

    Args:
        parts: Rigid parts, ``{name: (V (n, 3) [m], F (m, 3))}``.

    Returns:
        ``(centers (e, 3) [m], radii (e,) [m])``, float64.
    """
    centers, radii = [], []
    for name in _EYES:
        if name in (parts or {}):
            c, r = _sphere(parts[name][0])
            centers.append(c)
            radii.append(r)
    return np.asarray(centers, np.float64).reshape(-1, 3), np.asarray(radii, np.float64)


def eyeball_sheet_nodes(V, parts) -> np.ndarray:
    """Nodes within ``EYE_NEAR_M`` of an eyeball's sphere (:func:`eyeball_spheres`) at rest.

    Their deeper surface is the eyeball: ``face_rig`` gives the inner-sheet ones among them no
    planar sliding support, and :class:`ContactStage` holds those on their sphere about the
    eyeball's centre instead (module doc).

    Args:
        V: Rest node positions [m], shape (p, 3), float.
        parts: Rigid parts, ``{name: (V (n, 3) [m], F (m, 3))}``.

    Returns:
        Shape (p,), bool.
    """
    X = np.asarray(V, np.float64).reshape(-1, 3)
    centers, radii = eyeball_spheres(parts)
    if len(centers) == 0:
        return np.zeros(len(X), bool)
    D = np.linalg.norm(X[:, None] - centers[None], axis=2) - radii[None]
    return D.min(axis=1) < EYE_NEAR_M


def glide_spheres(V, nodes, eye_of_node, eye_centers, eye_radii, planes, corners, *,
                  gap: float = CONTACT_GAP) -> tuple[np.ndarray, np.ndarray]:
    """The sphere each gliding inner lid node keeps to: through its rest position, and meeting
    the fissure plane of its eye on the eyeball's surface (``gap`` outside it).

    A sphere about the eyeball's centre o through the node's rest position x0 (radius
    ``r0 = |x0 - o|``) keeps the node at its rest depth as the lid slides over the ball, and the
    two lids of an adapted head do not lie at one depth: at identity 007's left lid margins the
    inner sheet lies 0.9 mm inside the ball's sphere (lower) and 0.4 mm outside it (upper) at
    rest, and the closed margins stayed 1.2 mm apart front to back. Each node instead gets the
    sphere about ``o + s n`` (n the unit normal of its eye's fissure plane, through the point p)
    through x0: on the plane it is the sphere
    about o of radius ``R_m``, ``R_m^2 = r0^2 - 2 s (x0 - p) . n``, so with
    ``s = (r0^2 - R_m^2) / (2 (x0 - p) . n)`` the node reaches the plane at ``|x - o| = R_m``.
    ``R_m = r0 + w (R + gap - r0)``: w is 1 along the middle of the fissure, tapering to 0 over
    ``GLIDE_TAPER`` of the corner chord at either end (the lids are closed at the corners), and
    the node's distance from the plane is taken as at least ``GLIDE_MIN_HEIGHT_M`` (a node next
    to the plane barely moves; its sphere stays near the concentric one).

    Args:
        V: Rest node positions [m], shape (p, 3), float.
        nodes: The gliding nodes, shape (c,), int.
        eye_of_node: Their eyeball (index into ``eye_centers``), shape (c,), int.
        eye_centers, eye_radii: The eyeballs' spheres [m], shapes (e, 3), (e,), float.
        planes: The fissure planes, (point [m], unit normal) each, shape (l, 2, 3), float.
        corners: Each plane's two fixed ring corners [m], shape (l, 2, 3), float.
        gap: The contact gap [m].

    Returns:
        ``(centres (c, 3) [m], radii (c,) [m])``, float64; a node whose eyeball has no fissure
        plane within twice its radius keeps the concentric sphere.
    """
    X = np.asarray(V, np.float64)[np.asarray(nodes, np.int64)]
    which = np.asarray(eye_of_node, np.int64)
    O, R = np.asarray(eye_centers, np.float64).reshape(-1, 3), np.asarray(eye_radii, np.float64).reshape(-1)
    Pl, K = np.asarray(planes, np.float64).reshape(-1, 2, 3), np.asarray(corners, np.float64).reshape(-1, 2, 3)
    if len(Pl) != len(K):
        raise InputError(f"planes, corners: expected one corner pair per plane, got {len(Pl)} and {len(K)}")
    o = O[which]
    centers, radii = o.copy(), np.linalg.norm(X - o, axis=1)
    for e in range(len(O)):
        if len(Pl) == 0:
            break
        j = int(np.argmin(np.linalg.norm(Pl[:, 0] - O[e], axis=1)))
        if np.linalg.norm(Pl[j, 0] - O[e]) > 2.0 * R[e]:
            continue
        mine = which == e
        p, n, (a, b) = Pl[j, 0], Pl[j, 1], K[j]
        t = (X[mine] - a) @ (b - a) / float((b - a) @ (b - a))
        w = np.clip(np.minimum(t, 1.0 - t) / GLIDE_TAPER, 0.0, 1.0)
        r0 = radii[mine]
        rm = r0 + w * (R[e] + gap - r0)
        h = (X[mine] - p) @ n
        h = np.where(h < 0.0, -1.0, 1.0) * np.maximum(np.abs(h), GLIDE_MIN_HEIGHT_M)
        s = (r0**2 - rm**2) / (2.0 * h)
        centers[mine] = O[e] + s[:, None] * n
        radii[mine] = np.linalg.norm(X[mine] - centers[mine], axis=1)
    return centers, radii


def lip_contact_geometry(V, T, node_side, *, fixed=None, gap: float = CONTACT_GAP) -> ContactGeometry:
    """The lip-on-lip part of :func:`contact_geometry` for any tet mesh with two marked regions.

    Args:
        V: Rest node positions [m], shape (p, 3), float.
        T: Tets, shape (k, 4), int.
        node_side: +1 / -1 for the nodes of the two regions (upper, lower lip), 0 elsewhere,
            shape (p,), int; a region's tets are those whose four nodes are on its side.
        fixed: Nodes that do not move (no candidates), shape (p,), bool.
        gap: The contact gap [m] (candidates closer than ``2 gap`` at rest are left out).

    Returns:
        A :class:`ContactGeometry` without teeth and eyes.
    """
    from ..geometry.surface import closest_point

    X = np.asarray(V, np.float64)
    T = np.asarray(T, np.int64)
    side = np.asarray(node_side, np.int8)
    if side.shape != (len(X),):
        raise InputError(f"node_side: expected shape ({len(X)},), got {side.shape}")
    free = np.ones(len(X), bool) if fixed is None else ~np.asarray(fixed, bool)
    up, lo = lip_tets(T, side)
    excluded = {"lip_lip": 0, "lip_teeth": 0, "lid_eye_inside_at_rest": 0, "lid_lid": 0}
    lip_faces, lip_nodes = [], []
    crossing = lip_crossings(X, T, side)["nodes"]
    for region, mine in ((up, -1), (lo, 1)):  # the lower lip's nodes against the upper lip, and back
        S = boundary_faces(T[region]) if region.any() else np.zeros((0, 3), np.int64)
        cand = np.flatnonzero((side == mine) & free)
        if len(S) and len(cand):
            d = closest_point(X, S, X[cand], max_dist=1.0).dist
            bad = (d < 2.0 * gap) | np.isin(cand, crossing)
            excluded["lip_lip"] += int(bad.sum())
            cand = cand[~bad]
        else:
            cand = np.zeros(0, np.int64)
        lip_faces.append(S)
        lip_nodes.append(cand)
    return ContactGeometry(side, lip_faces, lip_nodes, [], np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64),
                           np.zeros(0, np.int64), excluded)


def fissure_planes(fr) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The planes the lid-closing sphincters close toward (the orbicularis oculi's palpebral
    fissure): every sphincter of ``fr.rig`` with a ``center_normal`` (``to_plane``), two fixed
    control points (its corners on the palpebral ligaments) and a centre that rides the cranium
    (a jaw amount below 5 %; the lids' is ~1 %, interpolated from the regions around them): the
    plane stays where it is at rest.

    Returns:
        ``(point (l, 3) [m], unit normal (l, 3), corners (l, 2, 3) [m], height (l,) [m])``: the
        ring centre, the plane's normal, the fixed corners and the ring's height (its control
        points' largest distance from the plane), float64; l = 0 for a rig without such a ring.
    """
    rig = getattr(fr, "rig", None)
    out = ([], [], [], [])
    if rig is not None and len(getattr(rig, "center_normal", ())):
        N = np.asarray(rig.center_normal, np.float64)
        ctrl_m, piv = np.asarray(rig.ctrl_muscle), np.asarray(rig.ctrl_pivot)
        P = np.asarray(rig.ctrl_rest, np.float64)
        for m in np.flatnonzero(np.linalg.norm(N, axis=1) > 0.5):
            ctrl = np.flatnonzero(ctrl_m == m)
            corners = ctrl[piv[ctrl] == -2]
            if len(corners) != 2 or float(np.asarray(rig.center_jaw)[m]) > _LID_JAW_MAX:
                continue
            c, n = np.asarray(rig.center[m], np.float64), N[m] / np.linalg.norm(N[m])
            for a, v in zip(out, (c, n, P[corners], float(np.abs((P[ctrl] - c) @ n).max()))):
                a.append(v)
    return (np.asarray(out[0], np.float64).reshape(-1, 3), np.asarray(out[1], np.float64).reshape(-1, 3),
            np.asarray(out[2], np.float64).reshape(-1, 2, 3), np.asarray(out[3], np.float64))


def lid_contact_geometry(V, point, normal, corners, height, *, fixed=None, gap: float = CONTACT_GAP) -> ContactGeometry:
    """The lid-on-lid part of :func:`contact_geometry`: the nodes kept to their side of each
    fissure plane (:func:`fissure_planes` gives the planes of a face rig).

    A node is a lid node of a plane when it is free, lies between the plane's corners (its
    projection on the corner chord strictly inside it), within ``LID_REACH`` times ``height`` of
    the plane and within half the chord of the ring centre across it (the lids, not the back of
    the head); its side is the side it lies on at rest. Nodes within ``2 gap`` of the plane at
    rest (where the lids join at the corners) are left out, as the lips' candidates that touch at
    rest: no side to keep, and a spring there would be near-closed from the start (the CPU
    L-BFGS keeps near-closed contacts in its factorised model); they are counted in
    ``excluded["lid_lid"]``.

    Args:
        V: Rest node positions [m], shape (p, 3), float.
        point: A point of each plane [m] (the ring centre), shape (l, 3), float.
        normal: Each plane's unit normal, shape (l, 3), float.
        corners: The ring's two fixed corners [m], shape (l, 2, 3), float.
        height: The ring's height [m], shape (l,), float.
        fixed: Nodes that do not move (no candidates), shape (p,), bool.
        gap: The contact gap [m].

    Returns:
        A :class:`ContactGeometry` with only the lid fields filled.
    """
    X = np.asarray(V, np.float64)
    C, N = np.asarray(point, np.float64).reshape(-1, 3), np.asarray(normal, np.float64).reshape(-1, 3)
    K, H = np.asarray(corners, np.float64).reshape(-1, 2, 3), np.asarray(height, np.float64).reshape(-1)
    if not (len(C) == len(N) == len(K) == len(H)):
        raise InputError(f"lid planes: expected l points, normals, corner pairs and heights, got shapes "
                         f"{C.shape}, {N.shape}, {K.shape}, {H.shape}")
    if not (np.isfinite(C).all() and np.isfinite(K).all() and (H > 0).all()
            and np.allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-6)):
        raise InputError("lid planes: expected finite points and corners, unit normals and heights > 0 [m]")
    free = np.ones(len(X), bool) if fixed is None else ~np.asarray(fixed, bool)  # a node on one plane only
    nodes, plane, side, tangent, partner, on_plane, count = [], [], [], [], [], 0, 0
    for j, (c, n, (a, b), h) in enumerate(zip(C, N, K, H)):
        chord = b - a
        length = float(np.linalg.norm(chord))
        e = chord / length
        t = (X - a) @ e / length
        d = (X - c) @ n
        across = np.abs((X - c) @ np.cross(n, e))
        cand = free & (t > 0.0) & (t < 1.0) & (np.abs(d) <= LID_REACH * h) & (across <= 0.5 * length)
        flat = cand & (np.abs(d) < 2.0 * gap)
        on_plane += int(flat.sum())
        k = np.flatnonzero(cand & ~flat)
        free[cand] = False
        nodes.append(k)
        plane.append(np.full(len(k), j, np.int64))
        sd = np.sign(d[k]).astype(np.int8)
        side.append(sd)
        f = chord - n * float(chord @ n)
        tangent.append(np.tile(f / np.linalg.norm(f), (len(k), 1)))
        # the partner: the other lid's node nearest along the plane at rest
        Y = X[k] - np.outer(d[k], n)
        mine = np.full(len(k), -1, np.int64)
        for s in (-1, 1):
            me, other = np.flatnonzero(sd == s), np.flatnonzero(sd == -s)
            if len(me) and len(other):
                mine[me] = count + other[np.argmin(np.linalg.norm(Y[me][:, None] - Y[other][None], axis=2), axis=1)]
        partner.append(mine)
        count += len(k)
    g = ContactGeometry(np.zeros(len(X), np.int8), [], [], [], np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64),
                        np.zeros(0, np.int64), {"lip_lip": 0, "lip_teeth": 0, "lid_eye_inside_at_rest": 0,
                                                "lid_lid": on_plane})
    g.lid_planes = np.stack([C, N], axis=1)
    if nodes:
        g.lid_nodes, g.lid_plane, g.lid_side = np.concatenate(nodes), np.concatenate(plane), np.concatenate(side)
        g.lid_tangent, g.lid_partner = np.concatenate(tangent).reshape(-1, 3), np.concatenate(partner)
    return g


def contact_geometry(fr, *, gap: float = CONTACT_GAP) -> ContactGeometry:
    """The lips, teeth and eyeballs of a face rig and the candidate nodes of each contact.

    Candidates that already touch or cross at rest (within ``2 gap`` of the other surface, or
    inside it) are left out and counted in ``excluded``: a spring there would push the rest
    shape away from rest. ``facewarp build`` separates crossing lips (:mod:`.lips`).
    """
    from ..geometry.surface import closest_point

    X = np.asarray(fr.nodes, np.float64)
    free = ~np.asarray(fr.fixed, bool)
    nv = node_vertex(fr)
    side = lip_sides(fr.head_vertices, fr.head_faces, fr.mouth_center)[np.maximum(nv, 0)]
    side[nv < 0] = 0
    g = lip_contact_geometry(X, fr.tets, side, fixed=fr.fixed, gap=gap)
    excluded, lip_faces, lip_nodes = g.excluded, g.lip_faces, g.lip_nodes
    inner = (np.asarray(fr.layer) != 0) & free & ~np.asarray(fr.held, bool)
    teeth = []
    for name in _TEETH:
        if name not in fr.parts:
            continue
        TV, TF = (np.asarray(a) for a in fr.parts[name])
        cand = np.flatnonzero(inner)
        cp = closest_point(TV, TF, X[cand], max_dist=TEETH_NEAR_M)
        near = cp.face >= 0
        cand, dist = cand[near], cp.dist[near]
        bad = (dist < 2.0 * gap) | (winding_numbers(TV, TF, X[cand]) > 0.5)
        excluded["lip_teeth"] += int(bad.sum())
        teeth.append((name, TV.astype(np.float64), TF.astype(np.int64), float(fr.part_jaw.get(name, 0.0)), cand[~bad]))
    centers, radii = eyeball_spheres(fr.parts)
    eye_nodes, eye_of = np.zeros(0, np.int64), np.zeros(0, np.int64)
    if len(centers):
        D = np.linalg.norm(X[:, None] - centers[None], axis=2) - radii[None]
        which = np.argmin(D, axis=1)
        dmin = D[np.arange(len(X)), which]
        # a node already inside the ball at rest (an inner lid sheet extruded into the eyeball)
        # keeps its rest distance as its radius: it may not sink deeper (ContactStage)
        eye_nodes = np.flatnonzero(free & (dmin < EYE_NEAR_M))
        eye_of = which[eye_nodes]
        excluded["lid_eye_inside_at_rest"] = int((dmin[eye_nodes] < 0.0).sum())
    # the inner lid sheet over the eyeball without a planar support glides on the eyeball (a rig
    # built before, with planar supports there, keeps them and gets one-sided contact only)
    glide = np.zeros(len(eye_nodes), bool)
    if getattr(fr, "support_nodes", None) is not None:
        supported = np.zeros(len(X), bool)
        supported[np.asarray(fr.support_nodes, np.int64)] = True
        glide = ((np.asarray(fr.layer) != 0) & ~np.asarray(fr.held, bool) & ~supported)[eye_nodes]
    planes = fissure_planes(fr)
    lids = lid_contact_geometry(X, *planes, fixed=fr.fixed, gap=gap)
    excluded["lid_lid"] = lids.excluded["lid_lid"]
    # the gliding lids close onto the eyeball's surface, whatever their depth at rest
    gc, gr = glide_spheres(X, eye_nodes, eye_of, centers, radii, lids.lid_planes, planes[2], gap=gap)
    return ContactGeometry(side, lip_faces, lip_nodes, teeth, centers, radii, eye_nodes, eye_of, excluded,
                           lids.lid_planes, lids.lid_nodes, lids.lid_plane, lids.lid_side, glide, lids.lid_tangent,
                           lids.lid_partner, gc, gr)
