"""The two lips of a skin layer: which tets are upper and lower lip, where one crosses the other,
and the build-time separation of lips that cross at rest.

The mouth is the slit of the head mesh: the boundary loop nearest the mouth centre (the mean of
FDPs 2.2 and 2.3). Its lateral extremes are the lip corners; the loop's upper chain (higher mean
y) bounds the upper lip, the other the lower lip. A head vertex belongs to the upper lip when its
geodesic distance (Dijkstra over the mesh edges) to the upper chain is within ``reach`` and
shorter by more than ``band`` than to the lower chain, and alike for the lower lip; near the
corners, where both chains are about as far, the vertices belong to neither, so the two lips'
tet regions are apart at rest by at least ``band`` along the skin. A tet is a lip's when its four
nodes are (a node takes its head vertex's side: the vertex it lies on or under).

A lip *crosses* the other where one of its nodes lies inside a tet of the other lip (an exact
point-in-tet test). Adapted heads can come out of the adaptation with the lips pressed into each
other; :func:`separate_lips` moves the offending nodes out of the other lip, to ``clearance``
outside its surface, in small steps that keep every tet valid, and reports how many it moved.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..geometry.tets import boundary_faces, lip_crossings, lip_tets, points_in_tets, signed_tet_volumes

__all__ = ["LIP_BAND", "LIP_CLEARANCE", "LIP_REACH", "lip_sides", "lip_tets", "lip_crossings", "mouth_slit",
           "points_in_tets", "separate_lips", "separate_skin_lips"]

LIP_REACH = 0.012
"""Geodesic distance [m] from the mouth slit within which the skin counts as lip (the red lip and
the skin just around it, where the lips can meet)."""
LIP_BAND = 0.002
"""Geodesic band [m] about the corners' bisector that belongs to neither lip."""
LIP_CLEARANCE = 3.0e-4
"""Distance [m] outside the other lip's surface to which :func:`separate_lips` moves a node (above
the solver's contact gap, so that a separated head starts out of contact)."""


def _boundary_loops(F) -> list[np.ndarray]:
    """Closed boundary loops of a triangle mesh, as vertex index arrays in order."""
    F = np.asarray(F, dtype=np.int64)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    key = np.sort(E, axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    B = E[cnt[inv.reshape(-1)] == 1]  # directed boundary edges
    nxt = {int(a): int(b) for a, b in B}
    loops, seen = [], set()
    for a in nxt:
        if a in seen:
            continue
        loop, v = [], a
        while v not in seen and v in nxt:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        if len(loop) >= 3:
            loops.append(np.array(loop))
    return loops


def mouth_slit(V, F, mouth_center) -> tuple[np.ndarray, np.ndarray] | None:
    """The upper and lower chain of the mouth slit, corners left out.

    Args:
        V: Head vertices [m], shape (n, 3), float. Head frame: +y up, +x the subject's left.
        F: Triangles, shape (m, 3), int.
        mouth_center: A point in the mouth [m], shape (3,) (mean of FDPs 2.2 and 2.3).

    Returns:
        ``(upper, lower)`` head vertex indices, or None when the mesh has no boundary loop within
        3 cm of ``mouth_center`` (a closed mouth: nothing to separate).
    """
    V = np.asarray(V, dtype=np.float64)
    c = np.asarray(mouth_center, dtype=np.float64).reshape(3)
    loops = _boundary_loops(F)
    if not loops:
        return None
    dist = [float(np.linalg.norm(V[lp] - c, axis=1).min()) for lp in loops]
    k = int(np.argmin(dist))
    if dist[k] > 0.03:
        return None
    loop = loops[k]
    i0, i1 = int(np.argmin(V[loop, 0])), int(np.argmax(V[loop, 0]))
    a, b = sorted((i0, i1))
    one, two = loop[a + 1 : b], np.r_[loop[b + 1 :], loop[:a]]
    if len(one) == 0 or len(two) == 0:
        return None
    return (one, two) if V[one, 1].mean() > V[two, 1].mean() else (two, one)


def lip_sides(V, F, mouth_center, *, reach: float = LIP_REACH, band: float = LIP_BAND) -> np.ndarray:
    """Side of every head vertex: +1 upper lip, -1 lower lip, 0 neither (module doc).

    Args:
        V: Head vertices [m], shape (n, 3), float.
        F: Triangles, shape (m, 3), int.
        mouth_center: A point in the mouth [m], shape (3,).
        reach: Geodesic distance [m] from the slit that counts as lip.
        band: Geodesic band [m] between the lips that is neither's.

    Returns:
        Shape (n,), int8 (all 0 when the head has no mouth slit).
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import dijkstra

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n = len(V)
    side = np.zeros(n, np.int8)
    slit = mouth_slit(V, F, mouth_center)
    if slit is None:
        return side
    E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
    w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    G = sp.coo_matrix((w, (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    du = dijkstra(G, directed=False, indices=slit[0], min_only=True, limit=reach + band)
    dl = dijkstra(G, directed=False, indices=slit[1], min_only=True, limit=reach + band)
    side[(du <= reach) & (du + band < dl)] = 1
    side[(dl <= reach) & (dl + band < du)] = -1
    return side


def separate_lips(V, T, node_side, *, movable=None, clearance: float = LIP_CLEARANCE,
                  rounds: int = 30) -> tuple[np.ndarray, dict]:
    """Move every node of one lip that lies inside (or within ``clearance`` of) the other lip out
    of it, to ``clearance`` outside the other lip's surface, keeping every tet valid.

    Each round finds the offending nodes (exact point-in-tet test, and the distance to the other
    lip's region surface for the ones just outside), and moves each to its target, the closest
    point of the other surface pushed ``clearance`` outward; a move that would leave one of the
    node's tets below a tenth of its rest volume is halved until it does not (a node that cannot
    move keeps its place). Rounds repeat while the moves change something, since moving one lip's
    surface can uncover nodes of the other.

    Args:
        V: Node positions [m], shape (p, 3), float.
        T: Tets (positive volume), shape (k, 4), int.
        node_side: +1 upper / -1 lower / 0 per node, shape (p,), int.
        movable: Nodes that may move, shape (p,), bool (default all).
        clearance: Distance [m] outside the other lip to move to.
        rounds: At most this many rounds.

    Returns:
        ``(V_new (p, 3) float64, report)``; report: ``crossing_nodes_before`` (nodes inside the
        other lip), ``crossing_nodes_after``, ``moved_nodes``, ``max_move_m``, ``rounds``.
    """
    from ..geometry.surface import closest_point

    V0 = np.asarray(V, dtype=np.float64)
    X = V0.copy()
    T = np.asarray(T, dtype=np.int64)
    side = np.asarray(node_side)
    if side.shape != (len(X),):
        raise InputError(f"node_side must have shape ({len(X)},), got {side.shape}")
    movable = np.ones(len(X), bool) if movable is None else np.asarray(movable, bool)
    vol0 = signed_tet_volumes(V0, T)
    if (vol0 <= 0).any():
        raise InputError(f"tet {int(np.argmax(vol0 <= 0))} is inverted before the lip separation")
    up, lo = lip_tets(T, side)
    before = lip_crossings(X, T, side, movable=movable)["count"]
    moved = np.zeros(len(X), bool)
    node_tets = [[] for _ in range(len(X))]
    for t, row in enumerate(T):
        for v in row:
            node_tets[v].append(t)
    r = 0
    for r in range(1, rounds + 1):
        changed = False
        for mine, other in ((1, lo), (-1, up)):
            cand = np.flatnonzero((side == mine) & movable)
            if not other.any() or len(cand) == 0:
                continue
            To = T[other]
            S = boundary_faces(To)
            cp = closest_point(X, S, X[cand], max_dist=0.01)
            inside = points_in_tets(X[cand], X, To) >= 0
            near = (cp.face >= 0) & (inside | (cp.dist < clearance * (1 - 1e-3)))
            for i in np.flatnonzero(near):
                v, p = cand[i], cp.points[i]
                d = X[v] - p
                dl = float(np.linalg.norm(d))
                if dl < 1e-12:
                    f = S[cp.face[i]]
                    nrm = np.cross(X[f[1]] - X[f[0]], X[f[2]] - X[f[0]])
                    a = nrm / max(np.linalg.norm(nrm), 1e-30)
                else:
                    a = -d / dl if inside[i] else d / dl
                step = p + clearance * a - X[v]
                tets = T[node_tets[v]]
                for _ in range(8):
                    old = X[v].copy()
                    X[v] = old + step
                    if (signed_tet_volumes(X, tets) > 0.1 * vol0[node_tets[v]]).all():
                        break
                    X[v] = old
                    step *= 0.5
                else:
                    continue
                moved[v] = True
                changed = True
        if not changed:
            break
    after = lip_crossings(X, T, side, movable=movable)["count"]
    rep = {"crossing_nodes_before": int(before), "crossing_nodes_after": int(after), "moved_nodes": int(moved.sum()),
           "max_move_m": float(np.linalg.norm(X - V0, axis=1).max(initial=0.0)), "rounds": int(r)}
    return X, rep


def separate_skin_lips(head, skin) -> dict:
    """Separate the lips of a built skin layer in place (``skin.vertices``) and report it.

    Args:
        head: The head the skin was extruded from (its mesh and ``landmarks()``: FDPs 2.2, 2.3
            give the mouth centre). A head without them (a slab) is left as it is.
        skin: The :class:`~facewarp._src.anatomy.tissue.SkinLayer` (vertices moved in place).

    Returns:
        :func:`separate_lips`'s report, with ``lip_nodes`` (nodes of either lip); all zero when
        the head has no mouth slit.
    """
    empty = {"lip_nodes": 0, "crossing_nodes_before": 0, "crossing_nodes_after": 0, "moved_nodes": 0,
             "max_move_m": 0.0, "rounds": 0}
    lm = head.landmarks() if hasattr(head, "landmarks") else {}
    if "2.2" not in lm or "2.3" not in lm:
        return empty
    mc = 0.5 * (np.asarray(lm["2.2"], np.float64) + np.asarray(lm["2.3"], np.float64))
    side_v = lip_sides(head.vertices, head.faces, mc)
    node_side = side_v[np.asarray(skin.source_vertex)]
    if not (node_side != 0).any():
        return empty
    X, rep = separate_lips(skin.vertices, skin.tets, node_side)
    skin.vertices[:] = X
    rep["lip_nodes"] = int((node_side != 0).sum())
    return rep
