"""Extrusion of a triangle patch into a conforming tet layer (Sec. 6.2, Fig. 6.2): the prism
split and the five steps that place the inner sheets.

Every frontal-face triangle is extruded inward along its (smoothed) vertex normals by the
per-vertex skin thickness (Table 6.1 x the template's magnification; a vertex on a region boundary
carries the average, see :func:`facewarp.default_template`). The prism-like element between the
skin triangle and its inner copy is split into three tetrahedra (Fig. 6.2).

Conformity (Fig. 6.2). Neighbouring prisms share a quadrilateral side face, which each prism cuts
along one diagonal; the two must pick the same one. The rule here depends on the quad's two skin
vertices only: for a skin edge ``u < v`` (global vertex index) the diagonal always joins ``u`` on
the outer sheet to ``v`` on the inner sheet. Sorting a triangle's vertices ``a < b < c`` then gives
the staircase split ``(a, b, c, c')``, ``(a, b, b', c')``, ``(a, a', b', c')`` (primes: inner
copies), which uses exactly those diagonals, so the mesh is conforming whatever the numbering.
With more than one layer the same rule is applied between consecutive sheets.

Involute regions (lips, nose, lid margins). Extruding by the full thickness self-intersects where
the skin folds back on itself (two sheets of skin closer than twice the thickness) or curves
more tightly than the thickness (alar rim, lid margins). The thesis predefines the topology there
(Sec. 6.2); we instead clamp the extrusion depth by a *local feature size*, computed the same way
for any head, so nothing has to be redefined per head:

1. The extrusion directions are the area-weighted vertex normals of the whole head, smoothed
   over the frontal mesh (``normal_smoothing`` Jacobi sweeps), so inner nodes do not cross where
   the skin normal turns quickly, then nudged into the visibility cone of each vertex (an angle
   below about 78 deg to the normal of every triangle around it), which makes every tet positive
   at small depth: to first order in the depth a tet's volume is the triangle area times one
   vertex's (direction . triangle normal).
2. Medial-axis clamp: the inward ray from a vertex must not meet the skin within
   ``probe x depth``, and the probe point at ``probe x depth`` below it must be at least
   ``0.9 x probe x depth`` away from every skin triangle facing the other way (another sheet,
   or the far side past a focal point; the vertex's own facets never count). On a sphere of radius R this allows a
   depth up to R / probe; two sheets of skin a distance h apart each get at most
   h / (1.9 probe) (about 0.35 h with the default ``probe = 1.5``), so the two inner sheets stay
   apart. Failing vertices are shrunk by 20 % per sweep, down to ``min_fraction`` of the thickness.
3. The depth field is made 0.5-Lipschitz along edges (a vertex is at most half an edge length
   deeper than its neighbours), so the inner sheet has no steps.
4. Any tetrahedron that is still inverted or flatter than ``min_volume_ratio`` of its prism's
   share shrinks the depth of its three skin vertices (20 % per sweep); once a vertex is at the
   smallest depth, its extrusion direction and its neighbours' are averaged with their
   one-rings instead (sharp creases of the skin, e.g. the lid folds of the finer levels), and
   a still inverted tet may go down to a tenth of the smallest depth. A vertex whose triangles
   face opposite ways (the skin folded over itself) has no inward direction at all: that is an
   error in the input surface and is reported as such.
5. Where crossing directions still leave flat tets (mean ratio below
   :data:`TET_QUALITY_FLOOR`, typically in a crease an adaptation pressed into the lips or
   nostrils), the inner-sheet nodes there hill-climb: each tries a parallel copy of the skin,
   ``mean_j (P_j + X_i - X_j)``, and small steps around its place, and moves only where its worst
   tet improves (:func:`_relax_inner_sheet`).
   Flat tets matter twice: they invert first under load, and their stiff volume and area
   response sets the explicit step of the solver (:func:`facewarp.physics.node_stable_dt`).

Clamping rather than predefining the topology (the thesis's choice) keeps the build automatic
for every head with the template's topology, and leaves the tet count and the node numbering
independent of the shape (node ``l * p + i`` is always sheet ``l`` under frontal vertex ``i``),
which the transfer of the anatomy between heads (Sec. 6.6) relies on.

The steps are :func:`_extrusion_directions`, :func:`_medial_axis_clamp`, :func:`_lipschitz_depth`,
:func:`_shrink_flat_tets` and :func:`_relax_inner_sheet`, run in that order by
:func:`facewarp.anatomy.extrude_skin_layer`. The result is checked by :func:`tet_quality` (volumes, dihedral angles, conformity) and
:func:`boundary_self_intersections` (no two boundary triangles cross).
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..geometry.surface import MeshQuery, vertex_normals
from .tet_quality import _mean_ratio, tet_mean_ratio, tet_volumes

__all__ = ["TET_QUALITY_FLOOR", "split_prisms"]


# ----------------------------------------------------------------------------- prism split
# Staircase split of a prism with sorted outer vertices a < b < c and inner copies a', b', c'
# (indices 0..2 outer, 3..5 inner). Seen from outside with (a, b, c) counter-clockwise and the
# inner sheet below, these three are positively oriented (checked in tests/test_tissue.py).
_PRISM_TETS = np.array([[0, 2, 1, 5], [0, 1, 4, 5], [0, 4, 3, 5]])


def split_prisms(outer, inner, key=None) -> tuple[np.ndarray, np.ndarray]:
    """Split prisms into 3 tets each, conforming across shared quad faces (Fig. 6.2).

    Prism ``i`` has the outer triangle ``outer[i]`` (counter-clockwise seen from outside) and
    the inner triangle ``inner[i]`` (``inner[i, j]`` below ``outer[i, j]``). Its vertices are
    sorted by ``key`` of the outer vertices, a < b < c, and it is cut along the diagonals
    ``a -> b'``, ``b -> c'``, ``a -> c'``: a quad's diagonal runs from its smaller-key outer
    vertex to its larger-key inner vertex, so two prisms sharing the quad agree.

    Args:
        outer: Outer triangles, shape (m, 3), int64.
        inner: Inner triangles, shape (m, 3), int64.
        key: Sort key per vertex id used in ``outer`` (default: the ids themselves), shape
            (N,) with distinct values on every triangle.

    Returns:
        ``(T, prism)``: tets (3m, 4) int64, positively oriented for a non-degenerate prism
        whose inner sheet lies below the outer one; and the prism index of each tet (3m,).
    """
    outer = np.asarray(outer, dtype=np.int64)
    inner = np.asarray(inner, dtype=np.int64)
    if outer.ndim != 2 or outer.shape[1] != 3 or inner.shape != outer.shape:
        raise InputError(f"outer and inner must both have shape (m, 3), got {outer.shape} and {inner.shape}")
    k = outer if key is None else np.asarray(key)[outer]
    if len(outer) and ((k[:, 0] == k[:, 1]) | (k[:, 1] == k[:, 2]) | (k[:, 0] == k[:, 2])).any():
        raise InputError("key must differ between the three vertices of every triangle")
    perm = np.argsort(k, axis=1, kind="stable")
    # parity of the sorting permutation: even keeps the counter-clockwise orientation
    even = np.isin(perm[:, 0] * 9 + perm[:, 1] * 3 + perm[:, 2], [0 * 9 + 1 * 3 + 2, 1 * 9 + 2 * 3 + 0, 2 * 9 + 0 * 3 + 1])
    rows = np.arange(len(outer))[:, None]
    P = np.concatenate([outer[rows, perm], inner[rows, perm]], axis=1)  # (m, 6)
    T = P[:, _PRISM_TETS]  # (m, 3, 4)
    odd = ~even
    T[odd] = T[odd][:, :, [0, 2, 1, 3]]  # clockwise sorted triangle: swap to stay positive
    return T.reshape(-1, 4), np.repeat(np.arange(len(outer)), 3)


# ----------------------------------------------------------------------------- extrusion steps
def _vertex_adjacency(F: np.ndarray, n: int):
    from scipy.sparse import coo_matrix

    e = F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    e = np.concatenate([e, e[:, ::-1]])
    A = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    A.data[:] = 1.0
    return A


def _visible_directions(n: np.ndarray, X: np.ndarray, Fl: np.ndarray, *, min_cos: float = 0.2, iterations: int = 100) -> np.ndarray:
    """Nudge unit directions n (p, 3) until n . n_f >= min_cos for every incident triangle f.

    Each sweep moves the vertices that violate it toward the normal of their worst triangle
    (a simple max-min iteration); vertices whose triangles admit no such direction keep the
    best one found.
    """
    c = np.cross(X[Fl[:, 1]] - X[Fl[:, 0]], X[Fl[:, 2]] - X[Fl[:, 0]])
    Fn = c / np.maximum(np.linalg.norm(c, axis=1, keepdims=True), 1e-300)
    vi = Fl.ravel()
    fi = np.repeat(np.arange(len(Fl)), 3)
    n = n.copy()
    for _ in range(iterations):
        dots = np.einsum("ij,ij->i", n[vi], Fn[fi])
        worst = np.full(len(n), np.inf)
        np.minimum.at(worst, vi, dots)
        bad = worst < min_cos
        if not bad.any():
            break
        # the worst incident triangle of each bad vertex
        is_worst = bad[vi] & (dots <= worst[vi])
        w_v, w_f = vi[is_worst], fi[is_worst]
        _, first = np.unique(w_v, return_index=True)
        w_v, w_f = w_v[first], w_f[first]
        n[w_v] += 0.25 * Fn[w_f]
        n[w_v] /= np.linalg.norm(n[w_v], axis=1, keepdims=True)
    # fallback for the few left: the best of 4,000 directions (max of the min dot)
    dots = np.einsum("ij,ij->i", n[vi], Fn[fi])
    worst = np.full(len(n), np.inf)
    np.minimum.at(worst, vi, dots)
    left = np.flatnonzero(worst < min_cos)
    if len(left):
        k = np.arange(4000) + 0.5
        z = 1 - 2 * k / 4000
        r = np.sqrt(1 - z * z)
        ang = np.pi * (1 + 5**0.5) * k
        D = np.stack([r * np.cos(ang), r * np.sin(ang), z], 1)
        order = np.argsort(vi, kind="stable")
        vs, fs = vi[order], fi[order]
        starts = np.searchsorted(vs, left)
        ends = np.searchsorted(vs, left, side="right")
        for v, a, b in zip(left, starts, ends):
            score = (D @ Fn[fs[a:b]].T).min(1)
            best = int(np.argmax(score))
            if score[best] > worst[v]:
                n[v] = D[best]
    return n


def _sheets(X: np.ndarray, d: np.ndarray, u: np.ndarray, layers: int) -> np.ndarray:
    """Nodes of all sheets: sheet ``l`` at ``l / layers`` of the depth ``d`` (p,) [m] along the
    unit directions ``u`` (p, 3) below the skin points ``X`` (p, 3) [m]; shape ((layers + 1) p, 3)."""
    return np.concatenate([X + (l / layers) * d[:, None] * u for l in range(layers + 1)])


def _layer_tets(Fl: np.ndarray, p: int, layers: int) -> tuple[np.ndarray, np.ndarray]:
    """Tets of every layer (:func:`split_prisms` between consecutive sheets, keyed by the skin
    vertex so all layers cut alike) and the patch triangle of each; they depend on the numbering
    only, the depths and directions place the sheets."""
    T_list, prism_list = [], []
    for l in range(layers):
        Tl, pr = split_prisms(Fl + l * p, Fl + (l + 1) * p, key=np.tile(np.arange(p), layers + 1))
        T_list.append(Tl)
        prism_list.append(pr)
    return np.concatenate(T_list), np.concatenate(prism_list)


def _extrusion_directions(V, HF, src, Fl, A, *, normals=None, smoothing: int = 3) -> np.ndarray:
    """Step 1: outward unit directions (p, 3) of the extruded vertices ``src``: the head normals
    (of ``HF``, or ``normals`` (n, 3)), smoothed over the patch by ``smoothing`` Jacobi sweeps,
    then kept strictly on the inner side of all the vertex's patch triangles (a visibility
    cone; needed where the skin has a sharp crease or pleat)."""
    N = vertex_normals(V, HF) if normals is None else np.asarray(normals, dtype=np.float64)
    if N.shape != V.shape:
        raise InputError(f"normals: expected shape {V.shape}, got {N.shape}")
    n = N[src].copy()
    deg = np.asarray(A.sum(1)).ravel()
    for _ in range(int(smoothing)):
        n = 0.5 * n + 0.5 * (A @ n) / deg[:, None]
        n /= np.linalg.norm(n, axis=1, keepdims=True)
    return _visible_directions(n, V[src], Fl)


def _medial_axis_clamp(V, HF, X, n, d, d_min, *, probe: float, max_sweeps: int) -> np.ndarray:
    """Step 2: shrink the depths ``d`` (p,) [m] (in place, 20 % a sweep, not below ``d_min``)
    of the vertices ``X`` whose inward ray meets the skin within ``probe x depth`` or whose
    probe point lies within ``0.9 x probe x depth`` of a skin triangle facing the other way."""
    d_inward = -n
    query = MeshQuery(V, HF)
    ray_t = query.ray_cast(X + 1e-6 * d_inward, d_inward).t
    hf_n = np.cross(V[HF[:, 1]] - V[HF[:, 0]], V[HF[:, 2]] - V[HF[:, 0]])
    for _ in range(max_sweeps):
        reach = probe * d
        cp = query.closest_point(X + reach[:, None] * d_inward)
        # the closest skin is another sheet (or the far side past a focal point) when it
        # faces the other way; nearby facets of the vertex's own sheet do not count
        far = np.einsum("ij,ij->i", hf_n[np.maximum(cp.face, 0)], n) < 0
        bad = ((ray_t < reach) | ((cp.dist < 0.9 * reach) & far)) & (d > d_min)
        if not bad.any():
            break
        d[bad] = np.maximum(0.8 * d[bad], d_min[bad])
    return d


def _lipschitz_depth(X, A, d) -> np.ndarray:
    """Step 3: the depths (p,) [m] made 0.5-Lipschitz along the patch edges (a vertex at most
    half an edge length deeper than its neighbours), so the inner sheet has no steps."""
    Ae = A.tocoo()
    i, j = Ae.row, Ae.col
    elen = np.linalg.norm(X[i] - X[j], axis=1)
    for _ in range(50):
        bound = np.full(len(d), np.inf)
        np.minimum.at(bound, i, d[j] + 0.5 * elen)
        new = np.minimum(d, bound)
        if np.allclose(new, d):
            break
        d = new
    return d


def _shrink_flat_tets(X, Fl, A, T, prism, d, d_min, d_inward, layers: int, *, min_volume_ratio: float,
                      max_sweeps: int) -> tuple[np.ndarray, np.ndarray]:
    """Step 4: make the skin vertices of inverted or flat tets (volume below ``min_volume_ratio``
    of the prism's share) shallower, 20 % a sweep; at the smallest depth average their directions
    with the one-ring's instead; an inverted tet may go down to a tenth of the smallest depth.
    Returns the new depths (p,) [m] and inward directions (p, 3)."""
    p = len(X)
    area2 = np.linalg.norm(np.cross(X[Fl[:, 1]] - X[Fl[:, 0]], X[Fl[:, 2]] - X[Fl[:, 0]]), axis=1)
    P = _sheets(X, d, d_inward, layers)
    for _ in range(max_sweeps):
        vol = tet_volumes(P, T)
        ref = area2[prism] / 2 * d[Fl[prism]].mean(1) / layers / 3
        bad_t = vol < min_volume_ratio * ref
        if not bad_t.any():
            break
        verts = np.unique(Fl[prism[bad_t]])
        floor = d[verts] <= d_min[verts] * (1 + 1e-12)
        shrink = verts[~floor]
        d[shrink] = np.maximum(0.8 * d[shrink], d_min[shrink])
        # an inverted (not just flat) tet may go below the floor, to 1/10 of it: at small depth
        # the sign of each tet is that of (direction . triangle normal), kept positive above
        inv_v = np.unique(Fl[prism[vol <= 0]])
        inv_v = inv_v[d[inv_v] <= d_min[inv_v] * (1 + 1e-12)]
        d[inv_v] = np.maximum(0.8 * d[inv_v], 0.1 * d_min[inv_v])
        if floor.any():
            # at the smallest depth and still flat: the directions cross (a sharp crease of
            # the skin); average them with the one-ring's
            sel = np.zeros(p, bool)
            sel[verts[floor]] = True
            sel |= (A @ sel.astype(float)) > 0
            m = d_inward[sel] + (A[sel] @ d_inward)
            d_inward[sel] = m / np.linalg.norm(m, axis=1, keepdims=True)
            d_inward = -_visible_directions(-d_inward, X, Fl)
        P = _sheets(X, d, d_inward, layers)
    return d, d_inward


def _raise_if_inverted(P, T, prism, X, Fl, src, face_index) -> None:
    """Raise :class:`InputError` naming the first inverted tet and its patch triangle, and the
    head vertex where the skin folds over (its triangles face opposite ways, so no inward
    direction exists) when that is the cause."""
    vol = tet_volumes(P, T)
    if not (vol <= 0).any():
        return
    k = int(np.flatnonzero(vol <= 0)[0])
    f = int(prism[k])
    name = f"triangle {f} of F" if face_index is None else f"head triangle {int(np.asarray(face_index)[f])}"
    c = np.cross(X[Fl[:, 1]] - X[Fl[:, 0]], X[Fl[:, 2]] - X[Fl[:, 0]])
    folded = [int(src[v]) for v in Fl[f] if (c[(Fl == v).any(1)] @ c[f] < 0).any()]
    why = f"; the skin folds over at head vertex {folded[0]} (its triangles face opposite ways)" if folded else ""
    raise InputError(f"tet {k} (prism of {name}) is inverted after clamping the depth{why}")


TET_QUALITY_FLOOR = 0.15
"""Mean-ratio quality (:func:`tet_mean_ratio`) below which step 5 of the extrusion relaxes a
tet's inner nodes (a regular tet has 1; the prisms of a flat skin patch 0.3-0.6)."""

_STEPS = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)], float)
_STEPS /= np.linalg.norm(_STEPS, axis=1, keepdims=True)


def _relax_inner_sheet(X, Fl, d, d_inward, layers, T, prism, A, *, d_max, sweeps: int):
    """Step 5 of :func:`extrude_skin_layer`: a hill climb of the inner-sheet nodes under tets of
    mean ratio below :data:`TET_QUALITY_FLOOR` (and of their inner neighbours).

    Each node tries a parallel copy of the skin, ``mean_j (P_j + X_i - X_j)`` over its
    neighbours j, and 26 steps of its own radius (a quarter of its depth at first, halved when
    nothing helps) and takes the candidate that most raises the worst quality of its tets
    (neighbours where they were). Candidates must stay on the inner side of the skin (within
    60 deg of the node's old direction) and no deeper than the requested thickness. Only nodes
    whose gain beats all their neighbours' move in a round, so no tet has two moving corners;
    a move is undone if any of its tets (intermediate sheets included) ends below the worst
    quality the node had before."""
    p = len(X)
    Ac = A.tocoo()
    ii, jj = Ac.row, Ac.col
    deg = np.bincount(ii, minlength=p).astype(float)
    P = _sheets(X, d, d_inward, layers)
    inner_of = np.full(len(P), -1)
    inner_of[len(P) - p:] = np.arange(p)  # the inner sheet is the last block of nodes
    radius = 0.25 * d.copy()

    def node_min_quality(C, act):
        """Worst quality of each active node's tets with only that node at C (others at P)."""
        off = C - X
        dc = np.linalg.norm(off, axis=1)
        dir_c = off / np.maximum(dc, 1e-300)[:, None]
        ok = act & (np.einsum("ij,ij->i", dir_c, d_inward) > 0.5) & (dc <= d_max) & (dc > 0)
        out = np.full(p, np.inf)
        for k in range(4):
            own = inner_of[T[:, k]]
            sel = np.flatnonzero((own >= 0) & ok[np.maximum(own, 0)])
            if not len(sel):
                continue
            v = own[sel]
            Q = P[T[sel]]
            frac = np.linalg.norm(Q[:, k] - X[v], axis=1) / np.maximum(d[v], 1e-300)  # the node's sheet
            Q[:, k] = X[v] + (frac * dc[v])[:, None] * dir_c[v]
            np.minimum.at(out, v, _mean_ratio(Q))
        out[~ok] = -np.inf
        return out, dc, dir_c

    for _ in range(sweeps):
        Pin = X + d[:, None] * d_inward
        q = tet_mean_ratio(P, T)
        bad = q < TET_QUALITY_FLOOR
        if not bad.any():
            break
        act = np.zeros(p, bool)
        act[np.unique(Fl[prism[bad]])] = True
        act[jj[act[ii]]] = True
        old_min = np.full(p, np.inf)
        for k in range(4):
            own = inner_of[T[:, k]]
            sel = np.flatnonzero(own >= 0)
            np.minimum.at(old_min, own[sel], q[sel])
        parallel = np.zeros((p, 3))
        np.add.at(parallel, ii, Pin[jj] + X[ii] - X[jj])
        parallel /= np.maximum(deg, 1)[:, None]
        best, best_d, best_u = old_min.copy(), d.copy(), d_inward.copy()
        for C in [parallel] + [Pin + radius[:, None] * s for s in _STEPS]:
            m, dc, uc = node_min_quality(C, act)
            better = m > best
            best[better], best_d[better], best_u[better] = m[better], dc[better], uc[better]
        gain = np.where(act & (best > old_min), best - old_min, 0.0)
        radius[act & (gain == 0)] *= 0.5
        # move an independent set: a node whose gain beats all its neighbours' (no tet then has two
        # moving nodes, so each node's judged quality is exactly what it gets)
        nb_max = np.zeros(p)
        np.maximum.at(nb_max, ii, gain[jj])
        keep = (gain > 0) & (gain > nb_max)
        if not keep.any():
            if (radius[act] < 1e-3 * d[act]).all():
                break
            continue
        dn, un = d.copy(), d_inward.copy()
        dn[keep], un[keep] = best_d[keep], best_u[keep]
        Pn = _sheets(X, dn, un, layers)
        qn = tet_mean_ratio(Pn, T)
        # undo a move that left any of its tets below the worst quality the node had before
        floor_t = np.where(keep, old_min, np.inf)[Fl[prism]].min(1)
        worse = (qn < q) & (qn < floor_t)
        back = np.unique(Fl[prism[worse]])
        dn[back], un[back] = d[back], d_inward[back]
        d, d_inward = dn, un
        P = _sheets(X, d, d_inward, layers)
    return d, d_inward
