"""Error metrics of an adaptation (thesis Sec. 5.2).

- :func:`distance_error`: ``E_d = sum_i w_i dist^2(x_i, Q*) / n`` (Eq. 5.2.1), the squared
  point-to-triangle distance from each adapted vertex to the calibrated scan, with weight 0
  where a vertex finds no scan surface (holes, or farther than the threshold, by default
  1/10 of the head width as in Sec. 5.2.1) and region weights (e.g. ears 0.2).
- :func:`marker_error`: ``E_m = sum_i ||u_i - v_i||^2`` over markers that took no part in
  the training (Eq. 5.2.2).
- :func:`combined_error`: ``E = alpha E_d + beta E_m`` (Eq. 5.2.3); the thesis's tables 5.1
  and 5.2 fit ``alpha = 1, beta = 0.1``.
- :func:`vertex_error`: ``E_v``, vertex-to-vertex distances between two heads of the same
  topology (e.g. an adapted head and the truth).

Every metric can be split by a per-vertex region label array. Distances are in metres;
``E_d`` and ``E_m`` in square metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "DEFAULT_REGION_WEIGHTS",
    "REGION_GROUPS",
    "DistanceError",
    "VertexError",
    "combined_error",
    "distance_error",
    "head_width",
    "vertex_groups",
    "marker_error",
    "vertex_error",
]

DEFAULT_REGION_WEIGHTS: dict[str, float] = {"ears": 0.2, "ear": 0.2}
"""Region weights of Sec. 5.2.1 (the ears are scanned poorly)."""


def head_width(V) -> float:
    """Largest bounding-box extent of V [m] (the thesis's "max width of the head")."""
    V = np.asarray(V, dtype=np.float64)
    return float(np.ptp(V, axis=0).max()) if len(V) else 0.0


def _stats(d: np.ndarray) -> dict:
    d = d[np.isfinite(d)]
    if len(d) == 0:
        return {"count": 0, "mean": float("nan"), "median": float("nan"), "rms": float("nan"), "max": float("nan")}
    return {
        "count": int(len(d)),
        "mean": float(d.mean()),
        "median": float(np.median(d)),
        "rms": float(np.sqrt(np.mean(d * d))),
        "max": float(d.max()),
    }


def _labels(region, n: int) -> np.ndarray | None:
    if region is None:
        return None
    region = np.asarray(region)
    if region.shape != (n,):
        raise ValueError(f"region must have shape ({n},), got {region.shape}")
    return region


@dataclass
class DistanceError:
    """Result of :func:`distance_error` (Eq. 5.2.1).

    Attributes:
        value: E_d [m^2].
        dist: Point-to-surface distance of each vertex [m], shape (n,); inf where none found.
        weights: w_i used, shape (n,), float64 (0 in holes).
        hole: Vertices that found no scan surface, shape (n,), bool.
        stats: count / mean / median / rms / max of the distance [m] over vertices with w > 0.
        per_region: region label -> {"E_d": [m^2], and the distance stats [m]}.
    """

    value: float
    dist: np.ndarray
    weights: np.ndarray
    hole: np.ndarray
    stats: dict = field(default_factory=dict)
    per_region: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"E_d": self.value, **{f"dist_{k}": v for k, v in self.stats.items()}, "holes": int(self.hole.sum()), "per_region": self.per_region}


def distance_error(
    V,
    scan_V=None,
    scan_F=None,
    *,
    query=None,
    weights=None,
    region=None,
    region_weights: dict | None = None,
    max_dist: float | None = None,
    boundary_is_hole: bool = True,
    device: str = "cpu",
) -> DistanceError:
    """Distance error E_d of Eq. 5.2.1.

    ``dist(x_i, Q*)`` is the distance from vertex x_i to its closest point on the scan's
    triangles (point-to-triangle). A vertex gets weight 0 (a hole) when no scan triangle lies
    within ``max_dist``, or, with ``boundary_is_hole``, when its closest scan point lies on
    a scan boundary edge (the vertex sits over a hole or beyond the scan's border).

    Args:
        V: Adapted vertices [m], shape (n, 3), float64.
        scan_V, scan_F: The calibrated scan [m], shapes (k, 3) float64 and (l, 3) int64.
        query: Optional prebuilt :class:`geometry.MeshQuery` of the scan (then scan_V/F may be None).
        weights: Optional per-vertex weights, shape (n,); default 1.
        region: Optional per-vertex region labels, shape (n,).
        region_weights: Region label -> weight multiplier; default :data:`DEFAULT_REGION_WEIGHTS`.
        max_dist: Hole threshold [m]; default 1/10 of the head width of V (Sec. 5.2.1).
        boundary_is_hole: Treat closest points on the scan boundary as holes.
        device: Warp device for the BVH query.

    Returns:
        :class:`DistanceError`.
    """
    from ..core.checks import check_array

    check_array("V", V, shape=(None, 3))
    from ..geometry.surface import MeshQuery

    V = np.asarray(V, dtype=np.float64)
    n = len(V)
    if query is None:
        if scan_V is None or scan_F is None:
            raise ValueError("give scan_V and scan_F, or query")
        query = MeshQuery(scan_V, scan_F, device=device)
    if max_dist is None:
        max_dist = 0.1 * head_width(V)
    labels = _labels(region, n)
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64).reshape(n).copy()
    if labels is not None:
        rw = DEFAULT_REGION_WEIGHTS if region_weights is None else region_weights
        for lab, val in rw.items():
            w[labels == lab] *= val
    cp = query.closest_point(V, max_dist)
    dist = cp.dist
    hole = cp.face < 0
    if boundary_is_hole:
        hole |= _on_boundary(query, cp)
    w = np.where(hole, 0.0, w)
    d2 = np.where(hole, 0.0, dist**2)
    value = float((w * d2).sum() / max(n, 1))
    good = w > 0
    stats = _stats(np.where(good, dist, np.nan))
    per_region = {}
    if labels is not None:
        for lab in np.unique(labels):
            sel = labels == lab
            per_region[str(lab)] = {"E_d": float((w[sel] * d2[sel]).sum() / max(sel.sum(), 1)), **_stats(np.where(good[sel], dist[sel], np.nan))}
    return DistanceError(value=value, dist=dist, weights=w, hole=hole, stats=stats, per_region=per_region)


def _on_boundary(query, cp, tol: float = 1e-4) -> np.ndarray:
    """Whether each closest point (:class:`ClosestPoints` of ``query``) lies on a boundary edge
    of the queried mesh, shape (k,), bool. The mesh's boundary edge keys are kept on the query
    object (its faces never change)."""
    from ..geometry.surface import boundary_edges

    F = query._F
    n = query.vertex_count
    keys = getattr(query, "_facewarp_boundary_keys", None)
    if keys is None:
        be = boundary_edges(F)
        keys = np.sort(be[:, 0] * n + be[:, 1])
        query._facewarp_boundary_keys = keys
    out = np.zeros(len(cp.face), dtype=bool)
    found = np.flatnonzero(cp.face >= 0)
    if len(keys) == 0 or len(found) == 0:
        return out
    b = cp.bary[found]
    tri = F[cp.face[found]]
    for c in range(3):  # bary[c] ~ 0: the point is on the edge opposite corner c
        on = b[:, c] < tol
        if not on.any():
            continue
        a = tri[on, (c + 1) % 3]
        bb = tri[on, (c + 2) % 3]
        key = np.minimum(a, bb) * n + np.maximum(a, bb)
        pos = np.minimum(np.searchsorted(keys, key), len(keys) - 1)
        out[found[on]] |= keys[pos] == key
    return out


def marker_error(U, V) -> float:
    """Marker error E_m = sum_i ||u_i - v_i||^2 (Eq. 5.2.2) [m^2].

    Args:
        U: Markers on the adapted template [m], shape (m, 3), float64.
        V: The corresponding markers on the scan [m], shape (m, 3), float64.
    """
    U = np.asarray(U, dtype=np.float64).reshape(-1, 3)
    V = np.asarray(V, dtype=np.float64).reshape(-1, 3)
    if U.shape != V.shape:
        raise ValueError(f"U and V must have the same shape, got {U.shape} and {V.shape}")
    return float(((U - V) ** 2).sum())


def combined_error(E_d: float, E_m: float, *, alpha: float = 1.0, beta: float = 0.1) -> float:
    """E = alpha E_d + beta E_m (Eq. 5.2.3); the thesis's tables fit alpha = 1, beta = 0.1."""
    return float(alpha * E_d + beta * E_m)


@dataclass
class VertexError:
    """Result of :func:`vertex_error`.

    Attributes:
        dist: Per-vertex distance [m], shape (n,), float64.
        stats: count / mean / median / rms / max [m] over the selected vertices.
        per_region: region label -> the same stats [m].
    """

    dist: np.ndarray
    stats: dict
    per_region: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {**self.stats, "per_region": self.per_region}


def vertex_error(V1, V2, *, mask=None, region=None) -> VertexError:
    """Vertex-to-vertex error E_v between two heads with the same topology.

    Args:
        V1, V2: Vertex positions [m], shape (n, 3), float64.
        mask: Optional vertices to include in the stats, shape (n,) bool or an index array.
        region: Optional per-vertex region labels, shape (n,).

    Returns:
        :class:`VertexError`.
    """
    from ..core.checks import check_array

    check_array("V1", V1, shape=(None, 3))
    check_array("V2", V2, shape=(None, 3))
    V1 = np.asarray(V1, dtype=np.float64)
    V2 = np.asarray(V2, dtype=np.float64)
    if V1.shape != V2.shape or V1.ndim != 2 or V1.shape[1] != 3:
        raise ValueError(f"V1 and V2 must have the same shape (n, 3), got {V1.shape} and {V2.shape}")
    n = len(V1)
    d = np.linalg.norm(V1 - V2, axis=1)
    sel = np.ones(n, dtype=bool)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.dtype == bool:
            if mask.shape != (n,):
                raise ValueError(f"mask must have shape ({n},), got {mask.shape}")
            sel = mask
        else:
            sel = np.zeros(n, dtype=bool)
            sel[mask] = True
    labels = _labels(region, n)
    per_region = {}
    if labels is not None:
        for lab in np.unique(labels[sel]):
            per_region[str(lab)] = _stats(d[sel & (labels == lab)])
    return VertexError(dist=d, stats=_stats(d[sel]), per_region=per_region)


# Per-region error groups (Sec. 5.2): template regions -> eyes, nose, mouth, ears.
REGION_GROUPS = {
    "eyes": ("eyelid_upper_L", "eyelid_upper_R", "eyelid_lower_L", "eyelid_lower_R"),
    "nose": ("nose",),
    "mouth": ("upper_lip", "lower_lip", "lip_corner_L", "lip_corner_R"),
    "ears": ("ear_L", "ear_R"),
}
"""Report groups of template regions (group name -> region names) for the per-region errors."""


def vertex_groups(template) -> np.ndarray:
    """Per-vertex group label (eyes / nose / mouth / ears / other) of a template with regions."""
    from ..template import REGIONS

    lab = np.full(template.vertex_count, "other", dtype=object)
    for group, names in REGION_GROUPS.items():
        ids = [REGIONS.index(n) for n in names]
        lab[np.unique(template.faces[np.isin(template.face_region, ids)])] = group
    return lab.astype(str)
