"""Volumetric skin layer: frontal-face triangles extruded inward into conforming tetrahedra (Sec. 6.2).

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
   response sets the explicit step of the solver (:func:`facewarp._src.solver.node_stable_dt`).

Clamping rather than predefining the topology (the thesis's choice) keeps the build automatic
for every head with the template's topology, and leaves the tet count and the node numbering
independent of the shape (node ``l * p + i`` is always sheet ``l`` under frontal vertex ``i``),
which the transfer of the anatomy between heads (Sec. 6.6) relies on.

The result is checked by :func:`tet_quality` (volumes, dihedral angles, conformity) and
:func:`boundary_self_intersections` (no two boundary triangles cross).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from ..geometry.tets import signed_tet_volumes
from ..geometry.surface import MeshQuery, vertex_normals

__all__ = [
    "SkinLayer",
    "boundary_faces",
    "boundary_self_intersections",
    "extrude_skin_layer",
    "split_prisms",
    "tet_conformity",
    "tet_dihedral_angles",
    "tet_mean_ratio",
    "tet_quality",
    "tet_volumes",
    "build_skin_layer",
    "skin_layer_quality",
]


@dataclass
class SkinLayer:
    """The tetrahedral skin layer of Sec. 6.2.

    Node ``k`` lies on sheet ``layer[k]`` (0 = the skin surface, ``layer_count`` = the inner
    sheet the muscles attach to) below head vertex ``source_vertex[k]``.

    Attributes:
        vertices: Node positions [m], shape (n, 3), float64.
        tets: Tetrahedra, shape (k, 4), int64, positively oriented
            (``det[b - a, c - a, d - a] > 0``, see :func:`tet_volumes`).
        layer: Sheet of each node, 0 outer (skin) ... ``layer_count`` inner, shape (n,), int32.
        surface_vertex: Head-mesh vertex a node coincides with (outer sheet), else -1,
            shape (n,), int64.
        source_vertex: Head-mesh vertex each node was extruded from, shape (n,), int64.
        depth: Distance [m] of each node below its skin vertex along ``direction``, shape (n,).
        direction: Unit inward extrusion direction of each node, shape (n, 3), float64.
        tet_face: Head-mesh triangle whose prism each tet belongs to, shape (k,), int64.
        skin_faces: The extruded head triangles (outer sheet), indices into ``vertices``,
            shape (m, 3), int64, outward oriented.
        layer_count: Number of tet layers between the outer and the inner sheet (>= 1).
        thickness: Requested skin thickness [m] of each node's source vertex, shape (n,).
    """

    vertices: np.ndarray
    tets: np.ndarray
    layer: np.ndarray
    surface_vertex: np.ndarray
    source_vertex: np.ndarray
    depth: np.ndarray
    direction: np.ndarray
    tet_face: np.ndarray
    skin_faces: np.ndarray
    layer_count: int
    thickness: np.ndarray

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    @property
    def tet_count(self) -> int:
        return len(self.tets)

    @property
    def inner_nodes(self) -> np.ndarray:
        """Indices of the inner-sheet nodes (the ones muscles attach to), shape (p,), int64."""
        return np.flatnonzero(self.layer == self.layer_count)

    @property
    def clamped_fraction(self) -> float:
        """Fraction of inner nodes whose depth was clamped below the requested thickness."""
        inner = self.inner_nodes
        return float(np.mean(self.depth[inner] < self.thickness[inner] * (1 - 1e-9))) if len(inner) else 0.0


# ----------------------------------------------------------------------------- tet measures
def _check_VT(V, T) -> tuple[np.ndarray, np.ndarray]:
    V = np.asarray(V, dtype=np.float64)
    T = np.asarray(T)
    if V.ndim != 2 or V.shape[1] != 3:
        raise InputError(f"V must have shape (n, 3), got {V.shape}")
    if T.ndim != 2 or T.shape[1] != 4:
        raise InputError(f"T must have shape (k, 4), got {T.shape}")
    if T.size and not np.issubdtype(T.dtype, np.integer):
        raise InputError(f"T must be an integer array, got dtype {T.dtype}")
    T = T.astype(np.int64, copy=False)
    if T.size and (T.min() < 0 or T.max() >= len(V)):
        raise InputError(f"T indexes vertices {T.min()}..{T.max()}, but V has {len(V)} vertices")
    return V, T


def tet_volumes(V, T) -> np.ndarray:
    """Signed tetrahedron volumes ``det[b - a, c - a, d - a] / 6``; positive = valid orientation.

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        T: Tetrahedra, shape (k, 4), int64.

    Returns:
        Signed volumes [m^3], shape (k,), float64.
    """
    return signed_tet_volumes(*_check_VT(V, T))


_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])  # face k opposite vertex k, outward
_TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


def tet_dihedral_angles(V, T) -> np.ndarray:
    """The six interior dihedral angles of every tetrahedron.

    The angle at edge (i, j) lies between the two faces containing it, i.e. the faces opposite
    the other two vertices k, l: ``pi - angle(n_k, n_l)`` with outward unit normals n.

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        T: Tetrahedra, shape (k, 4), int64.

    Returns:
        Angles [rad], shape (k, 6), in the edge order (01, 02, 03, 12, 13, 23); NaN for a
        degenerate face.
    """
    V, T = _check_VT(V, T)
    P = V[T]  # (k, 4, 3)
    sign = np.sign(tet_volumes(V, T))[:, None, None]
    sign[sign == 0] = 1.0
    N = np.empty((len(T), 4, 3))
    for k, (i, j, l) in enumerate(_TET_FACES):
        N[:, k] = np.cross(P[:, j] - P[:, i], P[:, l] - P[:, i])
    N *= sign  # outward for either orientation
    with np.errstate(invalid="ignore", divide="ignore"):
        N /= np.linalg.norm(N, axis=2, keepdims=True)
    out = np.empty((len(T), 6))
    for e, (i, j) in enumerate(_TET_EDGES):
        k, l = sorted(set(range(4)) - {i, j})
        cosang = np.clip(np.einsum("ij,ij->i", N[:, k], N[:, l]), -1.0, 1.0)
        out[:, e] = np.pi - np.arccos(cosang)
    return out


def _sorted_faces(T: np.ndarray) -> np.ndarray:
    return np.sort(T[:, _TET_FACES].reshape(-1, 3), axis=1)


def tet_conformity(T) -> dict:
    """Face sharing counts of a tet mesh.

    A conforming mesh has every triangle shared by at most two tets; its boundary triangles
    (shared by one) must then be exactly the triangles of the domain's boundary, which the
    caller compares (see :func:`tet_quality`'s ``expected_boundary_face_count``).

    Args:
        T: Tetrahedra, shape (k, 4), int64.

    Returns:
        ``{"face_count", "interior_face_count", "boundary_face_count", "max_face_share",
        "duplicate_tet_count"}``.
    """
    T = np.asarray(T, dtype=np.int64)
    if T.ndim != 2 or T.shape[1] != 4:
        raise InputError(f"T must have shape (k, 4), got {T.shape}")
    if len(T) == 0:
        return {"face_count": 0, "interior_face_count": 0, "boundary_face_count": 0, "max_face_share": 0, "duplicate_tet_count": 0}
    _, counts = np.unique(_sorted_faces(T), axis=0, return_counts=True)
    dup = len(T) - len(np.unique(np.sort(T, axis=1), axis=0))
    return {
        "face_count": int(len(counts)),
        "interior_face_count": int((counts == 2).sum()),
        "boundary_face_count": int((counts == 1).sum()),
        "max_face_share": int(counts.max()),
        "duplicate_tet_count": int(dup),
    }


def boundary_faces(T) -> np.ndarray:
    """Triangles used by exactly one tet, oriented outward.

    Args:
        T: Tetrahedra, shape (k, 4), int64, positively oriented.

    Returns:
        Boundary triangles, shape (b, 3), int64.
    """
    T = np.asarray(T, dtype=np.int64)
    Fall = T[:, _TET_FACES].reshape(-1, 3)
    key = np.sort(Fall, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return Fall[counts[inv.reshape(-1)] == 1]


def boundary_self_intersections(V, T, *, chunk: int = 200_000) -> int:
    """Number of (edge, triangle) crossings among the boundary triangles of a tet mesh.

    Two boundary triangles that share no vertex intersect (in general position) exactly when
    an edge of one crosses the other; 0 means the tet mesh has no intersecting elements
    (interior overlaps would need the boundary to cross itself or a tet to be inverted).

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        T: Tetrahedra, shape (k, 4), int64.
        chunk: Candidate pairs tested per batch (memory bound).

    Returns:
        Count of crossing (boundary edge, boundary triangle) pairs.
    """
    from scipy.spatial import cKDTree

    V, T = _check_VT(V, T)
    B = boundary_faces(T)
    if len(B) == 0:
        return 0
    E = np.unique(np.sort(B[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    C = V[B].mean(1)
    R = np.linalg.norm(V[B] - C[:, None], axis=2).max(1)
    M = 0.5 * (V[E[:, 0]] + V[E[:, 1]])
    half = 0.5 * np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1)
    tree = cKDTree(C)
    lists = tree.query_ball_point(M, half + R.max() * (1 + 1e-9))
    ei = np.repeat(np.arange(len(E)), [len(x) for x in lists])
    fi = np.fromiter((f for x in lists for f in x), dtype=np.int64, count=len(ei))
    # drop pairs sharing a vertex
    share = (B[fi] == E[ei, 0:1]).any(1) | (B[fi] == E[ei, 1:2]).any(1)
    ei, fi = ei[~share], fi[~share]
    total = 0
    for s in range(0, len(ei), chunk):
        e, f = ei[s : s + chunk], fi[s : s + chunk]
        p, q = V[E[e, 0]], V[E[e, 1]]
        a, b, c = V[B[f, 0]], V[B[f, 1]], V[B[f, 2]]
        # Moller-Trumbore on the segment p + t (q - p), t in [0, 1]
        d = q - p
        e1, e2 = b - a, c - a
        h = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, h)
        ok = np.abs(det) > 1e-30
        inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
        sv = p - a
        u = inv * np.einsum("ij,ij->i", sv, h)
        qv = np.cross(sv, e1)
        v = inv * np.einsum("ij,ij->i", d, qv)
        t = inv * np.einsum("ij,ij->i", e2, qv)
        eps = 1e-9
        hit = ok & (u > eps) & (v > eps) & (u + v < 1 - eps) & (t > eps) & (t < 1 - eps)
        total += int(hit.sum())
    return total


def tet_quality(V, T, *, expected_boundary_face_count: int | None = None, check_intersections: bool = False) -> dict:
    """Quality report of a tet mesh (Sec. 6.2): volumes, dihedral angles, inversions, conformity.

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        T: Tetrahedra, shape (k, 4), int64.
        expected_boundary_face_count: Triangles of the domain boundary; when given,
            ``conforming`` also requires the boundary triangle count to match it (a split that
            disagrees on a shared quad leaves extra boundary triangles inside the domain).
        check_intersections: Also count boundary self-intersections
            (:func:`boundary_self_intersections`).

    Returns:
        JSON-ready dict: ``vertex_count``, ``tet_count``, ``min_volume_m3``, ``max_volume_m3``,
        ``inverted_count`` (volume <= 0), ``min_dihedral_deg``, ``max_dihedral_deg``,
        the :func:`tet_conformity` counts, ``conforming`` and optionally
        ``boundary_intersection_count``.
    """
    V, T = _check_VT(V, T)
    vol = tet_volumes(V, T)
    dih = np.rad2deg(tet_dihedral_angles(V, T)) if len(T) else np.zeros((0, 6))
    conf = tet_conformity(T)
    conforming = conf["max_face_share"] <= 2 and conf["duplicate_tet_count"] == 0
    if expected_boundary_face_count is not None:
        conforming = conforming and conf["boundary_face_count"] == int(expected_boundary_face_count)
    rep = {
        "vertex_count": int(len(V)),
        "tet_count": int(len(T)),
        "min_volume_m3": float(vol.min()) if len(T) else 0.0,
        "max_volume_m3": float(vol.max()) if len(T) else 0.0,
        "inverted_count": int((vol <= 0).sum()),
        "min_dihedral_deg": float(np.nanmin(dih)) if len(T) else 0.0,
        "max_dihedral_deg": float(np.nanmax(dih)) if len(T) else 0.0,
        **conf,
        "conforming": bool(conforming),
    }
    if expected_boundary_face_count is not None:
        rep["expected_boundary_face_count"] = int(expected_boundary_face_count)
    if check_intersections:
        rep["boundary_intersection_count"] = boundary_self_intersections(V, T)
    return rep


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
        raise ValueError(f"outer and inner must both have shape (m, 3), got {outer.shape} and {inner.shape}")
    k = outer if key is None else np.asarray(key)[outer]
    if len(outer) and ((k[:, 0] == k[:, 1]) | (k[:, 1] == k[:, 2]) | (k[:, 0] == k[:, 2])).any():
        raise ValueError("key must differ between the three vertices of every triangle")
    perm = np.argsort(k, axis=1, kind="stable")
    # parity of the sorting permutation: even keeps the counter-clockwise orientation
    even = np.isin(perm[:, 0] * 9 + perm[:, 1] * 3 + perm[:, 2], [0 * 9 + 1 * 3 + 2, 1 * 9 + 2 * 3 + 0, 2 * 9 + 0 * 3 + 1])
    rows = np.arange(len(outer))[:, None]
    P = np.concatenate([outer[rows, perm], inner[rows, perm]], axis=1)  # (m, 6)
    T = P[:, _PRISM_TETS]  # (m, 3, 4)
    odd = ~even
    T[odd] = T[odd][:, :, [0, 2, 1, 3]]  # clockwise sorted triangle: swap to stay positive
    return T.reshape(-1, 4), np.repeat(np.arange(len(outer)), 3)


# ----------------------------------------------------------------------------- extrusion
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


TET_QUALITY_FLOOR = 0.15
"""Mean-ratio quality (:func:`tet_mean_ratio`) below which step 5 of the extrusion relaxes a
tet's inner nodes (a regular tet has 1; the prisms of a flat skin patch 0.3-0.6)."""


def tet_mean_ratio(V, T) -> np.ndarray:
    """Mean-ratio quality ``12 (3 |vol|)^(2/3) / sum(edge^2)`` of each tet: 1 for a regular
    tet, toward 0 for a flat one (sliver, cap, needle, wedge), scale invariant.

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        T: Tetrahedra, shape (k, 4), int64.

    Returns:
        Quality, shape (k,), float64, in [0, 1]; negative for an inverted tet.
    """
    V, T = _check_VT(V, T)
    return _mean_ratio(V[T])


def _mean_ratio(Q: np.ndarray) -> np.ndarray:
    """:func:`tet_mean_ratio` of tets given by their corners, shape (k, 4, 3)."""
    vol = np.einsum("ij,ij->i", np.cross(Q[:, 1] - Q[:, 0], Q[:, 2] - Q[:, 0]), Q[:, 3] - Q[:, 0]) / 6.0
    e2 = sum(np.sum((Q[:, j] - Q[:, i]) ** 2, axis=1) for i, j in _TET_EDGES)
    return np.sign(vol) * 12.0 * np.cbrt(3.0 * np.abs(vol)) ** 2 / np.maximum(e2, 1e-300)


_STEPS = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)], float)
_STEPS /= np.linalg.norm(_STEPS, axis=1, keepdims=True)


def _relax_inner_sheet(X, Fl, d, d_inward, sheets, T, prism, A, *, d_max, sweeps: int):
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
    P = sheets(d, d_inward)
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
        Pn = sheets(dn, un)
        qn = tet_mean_ratio(Pn, T)
        # undo a move that left any of its tets below the worst quality the node had before
        floor_t = np.where(keep, old_min, np.inf)[Fl[prism]].min(1)
        worse = (qn < q) & (qn < floor_t)
        back = np.unique(Fl[prism[worse]])
        dn[back], un[back] = d[back], d_inward[back]
        d, d_inward = dn, un
        P = sheets(d, d_inward)
    return d, d_inward


def extrude_skin_layer(
    V,
    F,
    thickness,
    *,
    normals=None,
    layers: int = 1,
    head_faces=None,
    normal_smoothing: int = 3,
    probe: float = 1.5,
    min_fraction: float = 0.2,
    min_volume_ratio: float = 0.02,
    max_sweeps: int = 60,
    relax_sweeps: int = 30,
    face_index=None,
) -> SkinLayer:
    """Extrude a triangle patch inward into a conforming tet layer (Sec. 6.2, Fig. 6.2).

    Args:
        V: Head vertex positions [m], shape (n, 3), float64.
        F: The triangles to extrude (e.g. the frontal face), shape (m, 3), int64, outward
            oriented, indices into V.
        thickness: Requested skin thickness [m] per head vertex, shape (n,), float64, > 0 on
            the vertices of F.
        normals: Outward unit vertex normals, shape (n, 3) (default: area-weighted normals of
            ``head_faces`` or of F).
        layers: Number of tet layers (>= 1); sheet ``l`` lies at ``l / layers`` of the depth.
        head_faces: All head triangles, shape (M, 3); used for the normals and for the
            local-feature-size clamp (default: F only).
        normal_smoothing: Jacobi sweeps averaging each extrusion direction with its neighbours.
        probe: Medial-axis clamp factor (see the module docstring); 0 turns the clamp off.
        min_fraction: Smallest depth as a fraction of the thickness.
        min_volume_ratio: A tet smaller than this fraction of its prism's volume / 3 makes its
            skin vertices shallower.
        max_sweeps: Sweeps of the clamp loops.
        relax_sweeps: Sweeps of the inner-sheet relaxation (step 5 of the module docstring);
            0 turns it off.
        face_index: Names of F's rows in error messages (e.g. their head triangle indices).

    Returns:
        :class:`SkinLayer`; node ``l * p + i`` is sheet ``l`` below the i-th extruded vertex
        (ascending head index).

    Raises:
        InputError: Bad shapes, non-positive thickness on the patch, or a tet that is still
            inverted after the clamp (named by its triangle of F). This happens where the skin
            itself is folded over (a vertex whose incident triangles face opposite ways, so
            no inward direction exists).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    if V.ndim != 2 or V.shape[1] != 3:
        raise InputError(f"V: expected shape (n, 3), got {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or (F.size and not np.issubdtype(F.dtype, np.integer)):
        raise InputError(f"F: expected an integer array of shape (m, 3), got {F.shape} {F.dtype}")
    F = F.astype(np.int64)
    if len(F) == 0:
        raise InputError("F: no triangles to extrude")
    if F.min() < 0 or F.max() >= len(V):
        raise InputError(f"F indexes vertices {F.min()}..{F.max()}, but V has {len(V)} vertices")
    thickness = np.asarray(thickness, dtype=np.float64)
    if thickness.shape != (len(V),):
        raise InputError(f"thickness: expected shape ({len(V)},), got {thickness.shape}")
    layers = int(layers)
    if layers < 1:
        raise InputError(f"layers: expected >= 1, got {layers}")
    HF = F if head_faces is None else np.asarray(head_faces, dtype=np.int64)
    src = np.unique(F)
    if not (np.isfinite(thickness[src]).all() and (thickness[src] > 0).all()):
        raise InputError("thickness: must be finite and > 0 on every extruded vertex")
    p = len(src)
    local = np.full(len(V), -1, dtype=np.int64)
    local[src] = np.arange(p)
    Fl = local[F]

    # 1. extrusion directions: head normals, smoothed over the patch
    N = vertex_normals(V, HF) if normals is None else np.asarray(normals, dtype=np.float64)
    if N.shape != V.shape:
        raise InputError(f"normals: expected shape {V.shape}, got {N.shape}")
    n = N[src].copy()
    A = _vertex_adjacency(Fl, p)
    deg = np.asarray(A.sum(1)).ravel()
    for _ in range(int(normal_smoothing)):
        n = 0.5 * n + 0.5 * (A @ n) / deg[:, None]
        n /= np.linalg.norm(n, axis=1, keepdims=True)
    # keep every direction strictly on the inner side of all the vertex's patch triangles
    # (a visibility cone): needed where the skin has a sharp crease or pleat
    X = V[src]
    n = _visible_directions(n, X, Fl)
    d_inward = -n
    t = thickness[src]
    d = t.copy()
    d_min = min_fraction * t

    # 2. medial-axis clamp against the whole head
    if probe > 0:
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

    # 3. 0.5-Lipschitz depth along edges
    Ae = A.tocoo()
    i, j = Ae.row, Ae.col
    elen = np.linalg.norm(X[i] - X[j], axis=1)
    for _ in range(50):
        bound = np.full(p, np.inf)
        np.minimum.at(bound, i, d[j] + 0.5 * elen)
        new = np.minimum(d, bound)
        if np.allclose(new, d):
            break
        d = new

    # 4. build, and shrink around inverted / flat tets
    # the tets depend on the numbering only; the depths and directions place the sheets
    T_list, prism_list = [], []
    for l in range(layers):
        Tl, pr = split_prisms(Fl + l * p, Fl + (l + 1) * p, key=np.tile(np.arange(p), layers + 1))
        T_list.append(Tl)
        prism_list.append(pr)
    T, prism = np.concatenate(T_list), np.concatenate(prism_list)

    def sheets(d, u=None):
        u = d_inward if u is None else u
        return np.concatenate([X + (l / layers) * d[:, None] * u for l in range(layers + 1)])

    area2 = np.linalg.norm(np.cross(X[Fl[:, 1]] - X[Fl[:, 0]], X[Fl[:, 2]] - X[Fl[:, 0]]), axis=1)
    P = sheets(d)
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
        P = sheets(d)

    # 5. flat tets left by crossing directions (creases of adapted heads): the inner sheet is
    # relaxed toward a parallel copy of the skin, one node at a time where that helps
    if relax_sweeps > 0:
        d, d_inward = _relax_inner_sheet(X, Fl, d, d_inward, sheets, T, prism, A, d_max=t, sweeps=relax_sweeps)
        P = sheets(d, d_inward)
    vol = tet_volumes(P, T)
    if (vol <= 0).any():
        k = int(np.flatnonzero(vol <= 0)[0])
        f = int(prism[k])
        name = f"triangle {f} of F" if face_index is None else f"head triangle {int(np.asarray(face_index)[f])}"
        # is there an inward direction at all? (a vertex whose triangles face opposite ways)
        c = np.cross(X[Fl[:, 1]] - X[Fl[:, 0]], X[Fl[:, 2]] - X[Fl[:, 0]])
        folded = [int(src[v]) for v in Fl[f] if (c[(Fl == v).any(1)] @ c[f] < 0).any()]
        why = f"; the skin folds over at head vertex {folded[0]} (its triangles face opposite ways)" if folded else ""
        raise InputError(f"tet {k} (prism of {name}) is inverted after clamping the depth{why}")

    layer = np.repeat(np.arange(layers + 1, dtype=np.int32), p)
    surface_vertex = np.full(len(P), -1, dtype=np.int64)
    surface_vertex[:p] = src
    return SkinLayer(
        vertices=P,
        tets=T,
        layer=layer,
        surface_vertex=surface_vertex,
        source_vertex=np.tile(src, layers + 1),
        depth=np.concatenate([(l / layers) * d for l in range(layers + 1)]),
        direction=np.tile(d_inward, (layers + 1, 1)),
        tet_face=prism,
        skin_faces=Fl,
        layer_count=layers,
        thickness=np.tile(t, layers + 1),
    )


def build_skin_layer(template, *, layers: int = 1, **kwargs) -> SkinLayer:
    """The skin layer of a template (or any head with its data): its frontal faces extruded.

    Args:
        template: A :class:`facewarp.Template` (``vertices``, ``faces``, ``frontal``,
            ``thickness``).
        layers: Number of tet layers.
        **kwargs: Passed to :func:`extrude_skin_layer`.

    Returns:
        :class:`SkinLayer` with ``tet_face`` as indices into ``template.faces``.
    """
    V, F = np.asarray(template.vertices), np.asarray(template.faces)
    frontal = np.asarray(template.frontal, dtype=bool)
    if frontal.shape != (len(F),):
        raise InputError(f"frontal: expected shape ({len(F)},), got {frontal.shape}")
    fidx = np.flatnonzero(frontal)
    sl = extrude_skin_layer(V, F[fidx], template.thickness, layers=layers, head_faces=F, face_index=fidx, **kwargs)
    sl.tet_face = fidx[sl.tet_face]
    return sl


def skin_layer_quality(sl: SkinLayer, *, check_intersections: bool = False) -> dict:
    """:func:`tet_quality` of a skin layer, with the expected boundary count of the slab.

    The boundary of the extruded slab is the outer and inner sheets (m triangles each) plus
    two triangles per patch-boundary edge per layer.
    """
    F = sl.skin_faces
    e = np.sort(F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, c = np.unique(e, axis=0, return_counts=True)
    expected = 2 * len(F) + 2 * sl.layer_count * int((c == 1).sum())
    rep = tet_quality(sl.vertices, sl.tets, expected_boundary_face_count=expected, check_intersections=check_intersections)
    inner = sl.inner_nodes
    rep["layer_count"] = sl.layer_count
    rep["clamped_fraction"] = sl.clamped_fraction
    rep["min_depth_m"] = float(sl.depth[inner].min())
    rep["max_depth_m"] = float(sl.depth[inner].max())
    return rep
