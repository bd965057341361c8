"""Tetrahedron primitives shared by the anatomy and the physics: volumes, the corner tables, the
boundary, point location and the lip crossing count (one helper each)."""

from __future__ import annotations

import numpy as np

__all__ = ["TET_EDGES", "TET_FACES", "boundary_faces", "lip_crossings", "lip_tets", "points_in_tets",
           "signed_tet_volumes", "tet_heights"]

TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
"""The six edges of a tet (i, j) as corner indices, shape (6, 2)."""
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
"""The four faces of a positively oriented tet, face k opposite corner k, outward, shape (4, 3)."""


def signed_tet_volumes(V, T) -> np.ndarray:
    """Signed tet volumes ``(1/6) (x1 - x0) . ((x2 - x0) x (x3 - x0))`` (the V of Eq. 6.4.8).

    Args:
        V: Vertex positions [m], shape (n, 3), float.
        T: Tets, shape (k, 4), int (not checked; see :func:`facewarp.anatomy.tet_volumes`).

    Returns:
        Signed volumes [m^3], shape (k,), float64; positive for a correctly oriented tet.
    """
    V = np.asarray(V, dtype=np.float64)
    T = np.asarray(T)
    x0, x1, x2, x3 = (V[T[:, c]] for c in range(4))
    return np.einsum("ij,ij->i", x1 - x0, np.cross(x2 - x0, x3 - x0)) / 6.0


def tet_heights(V, T) -> np.ndarray:
    """Smallest height of each tet, ``3 |vol| / (largest face area)`` [m], shape (k,), float64."""
    V = np.asarray(V, dtype=np.float64)
    T = np.asarray(T)
    a, b, c, d = (V[T[:, i]] for i in range(4))
    vol = np.abs(signed_tet_volumes(V, T))
    areas = [0.5 * np.linalg.norm(np.cross(q - p, r - p), axis=1) for p, q, r in ((a, b, c), (a, b, d), (a, c, d), (b, c, d))]
    return 3.0 * vol / np.maximum(np.max(areas, axis=0), 1e-30)


def boundary_faces(T) -> np.ndarray:
    """Triangles used by exactly one tet, oriented outward.

    Args:
        T: Tetrahedra, shape (k, 4), int64, positively oriented.

    Returns:
        Boundary triangles, shape (b, 3), int64.
    """
    T = np.asarray(T, dtype=np.int64)
    Fall = T[:, TET_FACES].reshape(-1, 3)
    key = np.sort(Fall, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return Fall[counts[inv.reshape(-1)] == 1]


def lip_tets(T, node_side) -> tuple[np.ndarray, np.ndarray]:
    """Tets of the upper and of the lower lip: those whose four nodes are on that side.

    Args:
        T: Tets, shape (k, 4), int.
        node_side: Side of every node (+1 upper, -1 lower, 0 neither), shape (p,), int.

    Returns:
        ``(upper, lower)``: boolean masks, shape (k,) each.
    """
    s = np.asarray(node_side)[np.asarray(T)]
    return (s == 1).all(axis=1), (s == -1).all(axis=1)


def points_in_tets(P, V, T, *, eps: float = 1e-9) -> np.ndarray:
    """Index of a tet of (V, T) containing each point (barycentric weights all > ``eps``), or -1.

    Args:
        P: Points [m], shape (k, 3), float.
        V: Vertices [m], shape (n, 3), float.
        T: Tets, shape (t, 4), int.

    Returns:
        Shape (k,), int64.
    """
    from scipy.spatial import cKDTree

    P = np.asarray(P, dtype=np.float64).reshape(-1, 3)
    V = np.asarray(V, dtype=np.float64)
    T = np.asarray(T, dtype=np.int64).reshape(-1, 4)
    out = np.full(len(P), -1, np.int64)
    if len(P) == 0 or len(T) == 0:
        return out
    X = V[T]
    C = X.mean(axis=1)
    R = np.linalg.norm(X - C[:, None], axis=2).max(axis=1)
    lists = cKDTree(C).query_ball_point(P, R.max() * (1 + 1e-9))
    pi = np.repeat(np.arange(len(P)), [len(x) for x in lists])
    ti = np.fromiter((t for x in lists for t in x), dtype=np.int64, count=len(pi))
    if len(pi) == 0:
        return out
    A = np.transpose(X[ti, 1:] - X[ti, :1], (0, 2, 1))  # columns x1-x0, x2-x0, x3-x0
    ok = np.abs(np.linalg.det(A)) > 1e-30
    lam = np.zeros((len(pi), 3))
    lam[ok] = np.linalg.solve(A[ok], (P[pi] - X[ti, 0])[ok][..., None])[..., 0]
    hit = ok & (lam > eps).all(axis=1) & (lam.sum(axis=1) < 1 - eps)
    out[pi[hit]] = ti[hit]
    return out


def lip_crossings(V, T, node_side, *, movable=None) -> dict:
    """Nodes of each lip inside a tet of the other lip, and how deep.

    Args:
        V: Node positions [m], shape (p, 3), float.
        T: Tets, shape (k, 4), int.
        node_side: +1 upper / -1 lower / 0 per node, shape (p,), int.
        movable: Only these nodes count, shape (p,), bool (default all).

    Returns:
        ``{"nodes": (c,) int64 crossing nodes, "depth": (c,) float64 distance [m] to the other
        lip's surface, "count": c}``.
    """
    from .surface import closest_point

    V = np.asarray(V, dtype=np.float64)
    side = np.asarray(node_side)
    up, lo = lip_tets(T, side)
    movable = np.ones(len(V), bool) if movable is None else np.asarray(movable, bool)
    nodes, depth = [], []
    for mine, other in ((1, lo), (-1, up)):
        cand = np.flatnonzero((side == mine) & movable)
        if not other.any() or len(cand) == 0:
            continue
        hit = cand[points_in_tets(V[cand], V, np.asarray(T)[other]) >= 0]
        if len(hit):
            S = boundary_faces(np.asarray(T)[other])
            nodes.append(hit)
            depth.append(closest_point(V, S, V[hit]).dist)
    nodes = np.concatenate(nodes) if nodes else np.zeros(0, np.int64)
    depth = np.concatenate(depth) if depth else np.zeros(0)
    return {"nodes": nodes, "depth": depth, "count": int(len(nodes))}
