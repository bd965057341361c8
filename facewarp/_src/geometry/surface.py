"""Triangle-mesh geometry: normals, areas, discrete mean curvature, BVH queries.

Free functions on plain arrays with libigl letters: ``V (n, 3) float64 [m]`` vertex
positions, ``F (m, 3) int64`` triangle vertex indices (counter-clockwise seen from outside,
so that normals point out). :class:`MeshQuery` wraps a Warp BVH (``wp.Mesh``) for ray casts
and closest-point queries on CPU or CUDA.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..core.errors import InputError
from ..core.warp import get_warp

__all__ = ["winding_numbers", 
    "ClosestPoints",
    "MeshQuery",
    "RayHits",
    "boundary_edges",
    "boundary_vertices",
    "closest_point",
    "face_areas",
    "face_normals",
    "gaussian_sums",
    "mean_curvature",
    "vertex_normals",
]


# ----------------------------------------------------------------------------------------
# input normalisation


def check_cells(V, C, arity: int, letter: str) -> tuple[np.ndarray, np.ndarray]:
    """V (n, 3) float64 and cells C (k, arity) int64 indexing V, or an :class:`InputError` naming
    ``letter`` ("F" for triangles, "T" for tets) and what was expected."""
    try:
        V = np.asarray(V, dtype=np.float64)
        C = np.asarray(C)
    except (TypeError, ValueError) as e:
        raise InputError(f"V, {letter}: expected numeric arrays ({e})") from None
    if V.ndim != 2 or V.shape[1] != 3:
        raise InputError(f"V must have shape (n, 3), got {V.shape}")
    if C.ndim != 2 or C.shape[1] != arity:
        raise InputError(f"{letter} must have shape ({'m' if arity == 3 else 'k'}, {arity}), got {C.shape}")
    if C.size and not np.issubdtype(C.dtype, np.integer):
        raise InputError(f"{letter} must be an integer array, got dtype {C.dtype}")
    C = C.astype(np.int64, copy=False)
    if C.size and (C.min() < 0 or C.max() >= len(V)):
        raise InputError(f"{letter} indexes vertices {C.min()}..{C.max()}, but V has {len(V)} vertices")
    return V, C


def _check_VF(V, F) -> tuple[np.ndarray, np.ndarray]:
    return check_cells(V, F, 3, "F")


def _check_points(P, name: str) -> np.ndarray:
    try:
        P = np.asarray(P, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{name}: expected a numeric array of shape (k, 3) ({e})") from None
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(f"{name} must have shape (k, 3), got {P.shape}")
    return P


# ----------------------------------------------------------------------------------------
# normals and areas


def face_areas(V, F) -> np.ndarray:
    """Triangle areas.

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.

    Returns:
        Areas [m^2], shape (m,), float64.
    """
    V, F = _check_VF(V, F)
    c = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return 0.5 * np.linalg.norm(c, axis=1)


def face_normals(V, F) -> np.ndarray:
    """Unit triangle normals, oriented by the winding (right-hand rule).

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.

    Returns:
        Unit normals, shape (m, 3), float64 (dimensionless). Degenerate (zero-area)
        triangles get the zero vector.
    """
    V, F = _check_VF(V, F)
    c = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n = np.linalg.norm(c, axis=1, keepdims=True)
    return np.divide(c, n, out=np.zeros_like(c), where=n > 0)


def vertex_normals(V, F) -> np.ndarray:
    """Area-weighted unit vertex normals.

    Each vertex normal is the normalised sum of the un-normalised normals (twice the area
    times the unit normal) of its incident triangles.

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.

    Returns:
        Unit normals, shape (n, 3), float64 (dimensionless). Vertices in no triangle (or
        whose incident areas cancel) get the zero vector.
    """
    V, F = _check_VF(V, F)
    c = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N = np.zeros_like(V)
    for k in range(3):
        N[:, 0] += np.bincount(F[:, k], weights=c[:, 0], minlength=len(V))
        N[:, 1] += np.bincount(F[:, k], weights=c[:, 1], minlength=len(V))
        N[:, 2] += np.bincount(F[:, k], weights=c[:, 2], minlength=len(V))
    n = np.linalg.norm(N, axis=1, keepdims=True)
    return np.divide(N, n, out=np.zeros_like(N), where=n > 0)


def gaussian_sums(P, S, vectors, width, weights=None, *, reach: float = 2.5) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian-weighted sums of vectors held at sample points, around each query point: row i is
    ``sum_j w_j exp(-(|S_j - P_i| / width_i)^2) vectors_j`` over the samples within
    ``reach * width_i`` of P_i (w_j = ``weights`` or 1). The smoothing behind the skin normals
    that do not depend on the mesh resolution (muscle placement, sliding supports).

    Args:
        P: Query points [m], shape (k, 3), float.
        S: Sample points [m], shape (s, 3), float.
        vectors: Vector at each sample, shape (s, 3), float.
        width: Gaussian width [m], a scalar or shape (k,), float, > 0.
        weights: Weight of each sample (e.g. its area), shape (s,), float, or None.
        reach: Samples farther than ``reach * width`` are left out.

    Returns:
        ``(sums (k, 3) float64, counts (k,) int64)``: counts the samples within reach.
    """
    from scipy.spatial import cKDTree

    P = np.asarray(P, np.float64).reshape(-1, 3)
    S = np.asarray(S, np.float64).reshape(-1, 3)
    vectors = np.asarray(vectors, np.float64)
    width = np.broadcast_to(np.asarray(width, np.float64), (len(P),))
    out = np.zeros((len(P), 3))
    count = np.zeros(len(P), np.int64)
    tree = cKDTree(S)
    for i, near in enumerate(tree.query_ball_point(P, reach * width)):
        j = np.asarray(near, np.int64)
        g = np.exp(-((np.linalg.norm(S[j] - P[i], axis=1) / width[i]) ** 2))
        if weights is not None:
            g = weights[j] * g
        out[i] = g @ vectors[j]
        count[i] = len(j)
    return out, count


def boundary_edges(F) -> np.ndarray:
    """Edges used by exactly one triangle, shape (b, 2), int64, each as (i, j) with i < j.

    Args:
        F: Triangles, shape (m, 3), int64.
    """
    F = np.asarray(F, dtype=np.int64)
    if F.size == 0:
        return np.zeros((0, 2), np.int64)
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    n = int(F.max()) + 1
    key, counts = np.unique(E[:, 0] * n + E[:, 1], return_counts=True)  # 1-D keys: fast unique
    key = key[counts == 1]
    return np.stack([key // n, key % n], axis=1)


def boundary_vertices(F, vertex_count: int) -> np.ndarray:
    """Mask of vertices on a boundary edge (an edge used by exactly one triangle).

    Args:
        F: Triangles, shape (m, 3), int64.
        vertex_count: Number of vertices n.

    Returns:
        Mask, shape (n,), bool.
    """
    mask = np.zeros(vertex_count, dtype=bool)
    mask[boundary_edges(F).ravel()] = True
    return mask


# ----------------------------------------------------------------------------------------
# mean curvature (Meyer et al. 2002)


def mean_curvature(V, F) -> np.ndarray:
    """Discrete mean curvature at each vertex (Meyer et al. 2002; thesis Eq. 4.5.1, 4.5.2).

    The mean curvature normal operator (Eq. 4.5.1) is::

        K(x_i) = 1 / (2 A_mixed) * sum_j (cot a_ij + cot b_ij) (x_i - x_j)

    where ``a_ij`` and ``b_ij`` are the angles opposite edge ``ij`` in its two triangles and
    ``A_mixed`` (Eq. 4.5.2, Fig. 4.6) sums, over the triangles around ``x_i``, the Voronoi
    area of ``x_i`` in a non-obtuse triangle, ``area / 2`` when the triangle is obtuse at
    ``x_i`` and ``area / 4`` when it is obtuse at another corner. ``kappa_H = |K| / 2``.

    Sign: positive where the surface is convex, i.e. where the Laplace-Beltrami of the
    position, ``-K``, points against the outward vertex normal (:func:`vertex_normals`; the
    faces must be wound counter-clockwise seen from outside). A sphere of radius r gives
    ``+1/r``, a cylinder ``+1/(2 r)``.

    Boundary vertices (on an edge used by a single triangle) and vertices with zero mixed
    area (in no triangle, or only in degenerate ones) get NaN: the operator is undefined
    there. Degenerate triangles (zero area) contribute nothing.

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.

    Returns:
        Mean curvature kappa_H [1/m], shape (n,), float64; NaN on boundary vertices.
    """
    V, F = _check_VF(V, F)
    n = len(V)
    P = V[F]  # (m, 3 corners, 3)
    # edge opposite corner c goes from corner c+1 to corner c+2
    e = np.stack([P[:, 2] - P[:, 1], P[:, 0] - P[:, 2], P[:, 1] - P[:, 0]], axis=1)  # (m, 3, 3)
    sq = np.einsum("fcd,fcd->fc", e, e)  # squared length of the edge opposite each corner
    cross = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    area = 0.5 * double_area
    ok = double_area > 0.0
    # cot at corner c = dot(a, b) / |a x b| with a, b the edges leaving corner c
    cot = np.zeros((len(F), 3))
    for c in range(3):
        a = P[:, (c + 1) % 3] - P[:, c]
        b = P[:, (c + 2) % 3] - P[:, c]
        cot[:, c] = np.divide(np.einsum("fd,fd->f", a, b), double_area, out=np.zeros(len(F)), where=ok)

    # K: corner c's cotangent weights edge (c+1, c+2)
    K = np.zeros((n, 3))
    for c in range(3):
        i = F[:, (c + 1) % 3]
        j = F[:, (c + 2) % 3]
        w = cot[:, c][:, None] * (V[i] - V[j])
        for d in range(3):
            K[:, d] += np.bincount(i, weights=w[:, d], minlength=n)
            K[:, d] -= np.bincount(j, weights=w[:, d], minlength=n)

    # A_mixed (Meyer Fig. 4): obtuse test from the cosine sign, i.e. the cotangent's sign
    obtuse = cot < 0.0  # (m, 3)
    any_obtuse = obtuse.any(axis=1)
    A = np.zeros(n)
    for c in range(3):
        cj, ck = (c + 1) % 3, (c + 2) % 3
        # Voronoi area of corner c: edges (c, cj) and (c, ck) are opposite corners ck and cj
        voronoi = (sq[:, ck] * cot[:, ck] + sq[:, cj] * cot[:, cj]) / 8.0
        a_c = np.where(any_obtuse, np.where(obtuse[:, c], area / 2.0, area / 4.0), voronoi)
        a_c = np.where(ok, a_c, 0.0)
        A += np.bincount(F[:, c], weights=a_c, minlength=n)

    with np.errstate(divide="ignore", invalid="ignore"):
        K = K / (2.0 * A[:, None])
    H = 0.5 * np.linalg.norm(K, axis=1)
    N = vertex_normals(V, F)
    # K points along the outward normal where convex; -K (the Laplacian) points against it
    H = np.where(np.einsum("nd,nd->n", K, N) >= 0.0, H, -H)
    H[~(A > 0.0)] = np.nan
    H[boundary_vertices(F, n)] = np.nan
    return H


# ----------------------------------------------------------------------------------------
# Warp BVH queries



class RayHits(NamedTuple):
    """Result of :meth:`MeshQuery.ray_cast`, one row per ray (k rays)."""

    hit: np.ndarray
    """Whether the ray hit within ``max_dist``, shape (k,), bool."""
    t: np.ndarray
    """Signed distance [m] along the unit direction to the hit (negative: behind the
    origin, only with ``both_directions``); ``inf`` on a miss. Shape (k,), float64."""
    face: np.ndarray
    """Index of the hit triangle, -1 on a miss. Shape (k,), int64."""
    bary: np.ndarray
    """Barycentric weights of the hit for ``F[face]``'s three vertices, in that order,
    summing to 1; NaN on a miss. Shape (k, 3), float64."""
    points: np.ndarray
    """Hit positions [m], ``bary @ V[F[face]]``; NaN on a miss. Shape (k, 3), float64."""


class ClosestPoints(NamedTuple):
    """Result of :meth:`MeshQuery.closest_point`, one row per query point (k points)."""

    face: np.ndarray
    """Index of the closest triangle, -1 when none lies within ``max_dist``. Shape (k,), int64."""
    bary: np.ndarray
    """Barycentric weights of the closest point for ``F[face]``'s three vertices, in that
    order, summing to 1; NaN when not found. Shape (k, 3), float64."""
    points: np.ndarray
    """Closest surface positions [m], ``bary @ V[F[face]]``; NaN when not found.
    Shape (k, 3), float64."""
    dist: np.ndarray
    """Distance [m] from the query point to ``points``; ``inf`` when not found.
    Shape (k,), float64."""


def _max_query_dist(max_dist: float) -> float:
    max_dist = float(max_dist)
    if not max_dist > 0.0:
        raise ValueError(f"max_dist must be positive, got {max_dist}")
    return min(max_dist, 1.0e30)  # float32 in the kernel


class MeshQuery:
    """Ray casts and closest-point queries on a triangle mesh, through a Warp BVH.

    Warp stores positions as float32; results are returned as float64 numpy arrays, with
    surface points evaluated in float64 from the returned face and barycentric weights.
    Warp skips (nearly) degenerate triangles in closest-point queries.

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64; m >= 1.
        device: Warp device to build the BVH and run the queries on ("cpu", "cuda:0", ...).

    Attributes:
        vertex_count: n.
        face_count: m.
        device: The Warp device.
        mesh: The ``wp.Mesh`` (points float32 [m], indices int32).
    """

    def __init__(self, V, F, *, device: str = "cpu"):
        V, F = _check_VF(V, F)
        if len(F) == 0:
            raise ValueError("F must contain at least one triangle")
        wp = get_warp()
        self.device = wp.get_device(device)
        self.vertex_count = len(V)
        self.face_count = len(F)
        self._V = V.copy()
        self._F = F.copy()
        self._points = wp.array(V.astype(np.float32), dtype=wp.vec3, device=self.device)
        self._indices = wp.array(F.astype(np.int32).ravel(), dtype=wp.int32, device=self.device)
        self.mesh = wp.Mesh(points=self._points, indices=self._indices)

    def update(self, V) -> None:
        """Move the vertices (same topology) and refit the BVH.

        Args:
            V: New vertex positions [m], shape (n, 3), float64, n = :attr:`vertex_count`.
        """
        from ..core.errors import InputError

        V = np.asarray(V, dtype=np.float64)
        if V.shape != (self.vertex_count, 3):
            raise InputError(f"V: expected shape ({self.vertex_count}, 3) for this mesh, got {V.shape}")
        wp = get_warp()
        self._V = V.copy()
        self._points.assign(wp.array(V.astype(np.float32), dtype=wp.vec3, device=self.device))
        self.mesh.refit()

    def _finish(self, face: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        face = face.astype(np.int64)
        found = face >= 0
        bary = np.full((len(face), 3), np.nan)
        u = uv[found, 0].astype(np.float64)
        v = uv[found, 1].astype(np.float64)
        b = np.stack([u, v, 1.0 - u - v], axis=1)
        b = np.clip(b, 0.0, 1.0)
        b /= b.sum(axis=1, keepdims=True)
        bary[found] = b
        points = np.full((len(face), 3), np.nan)
        points[found] = np.einsum("kc,kcd->kd", b, self._V[self._F[face[found]]])
        return face, bary, points

    def ray_cast(self, origins, dirs, max_dist: float = np.inf, *, both_directions: bool = False) -> RayHits:
        """Nearest intersection of each ray with the mesh.

        Args:
            origins: Ray origins [m], shape (k, 3), float64.
            dirs: Ray directions, shape (k, 3), float64; any non-zero length (normalised
                here). A zero direction is a miss.
            max_dist: Largest accepted distance [m] from the origin.
            both_directions: Also cast along ``-dirs`` and keep the nearer hit, reported
                with a negative ``t``.

        Returns:
            :class:`RayHits` ``(hit, t, face, bary, points)``.
        """
        origins = _check_points(origins, "origins")
        dirs = _check_points(dirs, "dirs")
        if origins.shape != dirs.shape:
            raise ValueError(f"origins and dirs must have the same shape, got {origins.shape} and {dirs.shape}")
        max_t = _max_query_dist(max_dist)
        k = len(origins)
        if k == 0:
            return RayHits(np.zeros(0, bool), np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
        length = np.linalg.norm(dirs, axis=1, keepdims=True)
        unit = np.divide(dirs, length, out=np.zeros_like(dirs), where=length > 0)

        wp = get_warp()
        from . import kernels_geometry as kg

        face_out = wp.empty(k, dtype=wp.int32, device=self.device)
        t_out = wp.empty(k, dtype=wp.float32, device=self.device)
        uv_out = wp.empty(k, dtype=wp.vec2, device=self.device)
        wp.launch(
            kg._ray_cast,
            dim=k,
            inputs=[
                self.mesh.id,
                wp.array(origins.astype(np.float32), dtype=wp.vec3, device=self.device),
                wp.array(unit.astype(np.float32), dtype=wp.vec3, device=self.device),
                max_t,
                int(bool(both_directions)),
            ],
            outputs=[face_out, t_out, uv_out],
            device=self.device,
        )
        face, bary, points = self._finish(face_out.numpy(), uv_out.numpy())
        hit = face >= 0
        t = np.where(hit, t_out.numpy().astype(np.float64), np.inf)
        return RayHits(hit, t, face, bary, points)

    def closest_point(self, P, max_dist: float = np.inf) -> ClosestPoints:
        """Closest point on the mesh to each query point.

        Args:
            P: Query points [m], shape (k, 3), float64.
            max_dist: Only faces strictly closer than this [m] are considered.

        Returns:
            :class:`ClosestPoints` ``(face, bary, points, dist)``.
        """
        P = _check_points(P, "P")
        max_d = _max_query_dist(max_dist)
        k = len(P)
        if k == 0:
            return ClosestPoints(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))

        wp = get_warp()
        from . import kernels_geometry as kg

        face_out = wp.empty(k, dtype=wp.int32, device=self.device)
        uv_out = wp.empty(k, dtype=wp.vec2, device=self.device)
        wp.launch(
            kg._closest_point,
            dim=k,
            inputs=[self.mesh.id, wp.array(P.astype(np.float32), dtype=wp.vec3, device=self.device), max_d],
            outputs=[face_out, uv_out],
            device=self.device,
        )
        face, bary, points = self._finish(face_out.numpy(), uv_out.numpy())
        dist = np.where(face >= 0, np.linalg.norm(P - points, axis=1), np.inf)
        return ClosestPoints(face, bary, points, dist)


def closest_point(V, F, P, *, max_dist: float = np.inf, device: str = "cpu") -> ClosestPoints:
    """Closest point on the mesh (V, F) to each point of P; builds a :class:`MeshQuery`.

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.
        P: Query points [m], shape (k, 3), float64.
        max_dist: Only faces strictly closer than this [m] are considered.
        device: Warp device.

    Returns:
        :class:`ClosestPoints` ``(face, bary, points, dist)``.
    """
    return MeshQuery(V, F, device=device).closest_point(P, max_dist)


def winding_numbers(V, F, P) -> np.ndarray:
    """Generalised winding number of the closed, outward surface (V, F) at each point of P
    (Van Oosterom and Strackee's solid angle per triangle): ~1 inside, ~0 outside; shape (k,)."""
    P = np.asarray(P, np.float64).reshape(-1, 3)
    A = np.asarray(V, np.float64)[np.asarray(F)]  # (m, 3, 3)
    out = np.zeros(len(P))
    for s in range(0, len(P), 256):
        R = A[None] - P[s : s + 256, None, None]  # (k, m, 3, 3)
        a, b, c = R[..., 0, :], R[..., 1, :], R[..., 2, :]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("kmi,kmi->km", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("kmi,kmi->km", a, b) * lc + np.einsum("kmi,kmi->km", b, c) * la
               + np.einsum("kmi,kmi->km", c, a) * lb)
        out[s : s + 256] = np.arctan2(det, den).sum(axis=1) / (2.0 * np.pi)
    return out
