"""Quality measures of tetrahedral meshes (Sec. 6.2): volumes, dihedral angles, mean ratio,
conformity, boundary triangles and boundary self-intersections, and the report that combines them.

Free functions on plain arrays (``V (n, 3) float64``, ``T (k, 4) int64``); the skin layer's
report (:func:`facewarp.anatomy.skin_layer_quality`) adds the expected boundary count of the slab.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..geometry.surface import check_cells
from ..geometry.tets import TET_EDGES, TET_FACES, boundary_faces, signed_tet_volumes

__all__ = [
    "boundary_faces",
    "boundary_self_intersections",
    "tet_conformity",
    "tet_dihedral_angles",
    "tet_mean_ratio",
    "tet_quality",
    "tet_volumes",
]


def _check_VT(V, T) -> tuple[np.ndarray, np.ndarray]:
    return check_cells(V, T, 4, "T")


def tet_volumes(V, T) -> np.ndarray:
    """Signed tetrahedron volumes ``det[b - a, c - a, d - a] / 6``; positive = valid orientation.

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        T: Tetrahedra, shape (k, 4), int64.

    Returns:
        Signed volumes [m^3], shape (k,), float64.
    """
    return signed_tet_volumes(*_check_VT(V, T))


_TET_FACES, _TET_EDGES = TET_FACES, TET_EDGES


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
