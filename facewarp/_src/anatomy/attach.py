"""Skin attachment of a muscle (Fig. 6.4, 6.5): which inner-layer nodes connect to which segment.

An inner-layer point connects to the muscle when the distance to the nearest ellipsoid surface
point is below ``lambda`` and the angle ``theta`` between the connection and the fibre's
cross-section plane is below ``phi``. ``theta`` is measured from the plane normal to the fibre (0
for a node right above the fibre, 90deg for one beyond its end), so a wide ``phi`` (frontalis)
takes nodes far along the ends and a narrow one (depressor anguli oris) only nodes over the muscle
body. The attachment point is stored by its ellipsoid surface parameters ``(u, v)``
(:func:`facewarp.anatomy.ellipsoid_points`).

:func:`attach_nodes` applies the rule to the nodes themselves. :func:`attach_by_area` applies it
to the inner sheet's area: each node gets the share of its part of the sheet (its corner of
every triangle around it, sampled by :func:`sheet_samples`) that passes the rule as its
attachment ``weight``. On a coarse mesh a node half inside the band then pulls with half its
area instead of all or nothing, so a muscle pulls on the same area of skin at every mesh level.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .ellipsoids import Ellipsoids, closest_point_on_ellipsoid

__all__ = ["MuscleAttachment", "SheetSamples", "attach_by_area", "attach_nodes", "sheet_samples"]


@dataclass
class MuscleAttachment:
    """Skin nodes connected to a muscle (Fig. 6.4, 6.5).

    Attributes:
        nodes: Tet-mesh node indices (inner layer), shape (a,), int64.
        segment: Ellipsoid each node connects to, shape (a,), int64.
        uv: Surface parameters (u, v) [rad] of the attachment point, shape (a, 2), float64.
        rest_length: Rest length l0 of the connection [m], shape (a,), float64.
        angle: theta [rad] of each connection (see the module docstring), shape (a,).
        weight: Share of the node's sheet area that lies within the rule, in (0, 1], shape (a,)
            (all 1 from :func:`attach_nodes`); it scales the node's spring stiffness.
    """

    nodes: np.ndarray
    segment: np.ndarray
    uv: np.ndarray
    rest_length: np.ndarray
    angle: np.ndarray
    weight: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self):
        if len(self.weight) != len(self.nodes):
            self.weight = np.ones(len(self.nodes))

    def __len__(self) -> int:
        return len(self.nodes)


def _nearest(P, ell: Ellipsoids, D=None):
    """Nearest surface point of the muscle to each point P (k, 3) over all segments: segment,
    (u, v), distance, theta [rad], whether the muscle lies deeper than the point along the
    inward directions D (k, 3) (all True without D) and the nearest point itself [m] (k, 3)."""
    best_d = np.full(len(P), np.inf)
    best_s = np.zeros(len(P), np.int64)
    best_uv = np.zeros((len(P), 2))
    best_sin = np.zeros(len(P))
    best_deeper = np.ones(len(P), bool)
    best_p = np.zeros((len(P), 3))
    for k in range(len(ell)):
        Y = (P - ell.centers[k]) @ ell.axes[k].T  # local coordinates
        Xl, d, uv = closest_point_on_ellipsoid(Y, ell.radii[k])
        conn = Y - Xl
        n = np.linalg.norm(conn, axis=1)
        sin_t = np.divide(np.abs(conn[:, 0]), n, out=np.zeros_like(n), where=n > 0)
        better = d < best_d
        best_d[better] = d[better]
        best_s[better] = k
        best_uv[better] = uv[better]
        best_sin[better] = sin_t[better]
        best_p[better] = ell.centers[k] + Xl[better] @ ell.axes[k]
        if D is not None:
            deeper = np.einsum("ij,ij->i", conn @ ell.axes[k], D) < 0  # world x - p against inward
            best_deeper[better] = deeper[better]
    return best_s, best_uv, best_d, np.arcsin(np.clip(best_sin, 0.0, 1.0)), best_deeper, best_p


def _under_sheet(p, samples: "SheetSamples", tree) -> np.ndarray:
    """Whether each muscle point p (k, 3) [m] lies under the sheet where it is: deeper than the
    sheet's sample nearest to it, along that sample's inward direction, shape (k,) bool."""
    _, j = tree.query(p)
    return np.einsum("ij,ij->i", p - samples.points[j], samples.direction[j]) > 0.0


def _empty() -> MuscleAttachment:
    z = np.zeros(0)
    return MuscleAttachment(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)), z, z, z)


def attach_nodes(X, ell: Ellipsoids, lam: float, phi: float, *, candidates=None, directions=None) -> MuscleAttachment:
    """Connect nodes to a muscle's ellipsoids (Fig. 6.4).

    For each node x: the nearest surface point p over all segments; x connects when
    ``|x - p| < lam`` and ``theta < phi``, theta the angle between ``x - p`` and the plane
    normal to the segment's fibre axis. With ``directions``, x must also lie on the skin side
    of the muscle, ``(p - x) . direction > 0``: on a head whose skin is thinner than the muscle
    depth (the lips of an adapted scan) part of a muscle can lie in or above the skin layer, and
    a spring from there would pull its inner node out through the skin.

    Args:
        X: Node positions [m], shape (p, 3).
        ell: The muscle's segments.
        lam: Distance threshold lambda [m].
        phi: Angle threshold [rad].
        candidates: Node indices to test (default all).
        directions: Unit inward (skin to deep) direction of every node, shape (p, 3).

    Returns:
        :class:`MuscleAttachment` with indices into X (weights 1).
    """
    X = np.asarray(X, dtype=np.float64)
    idx = np.arange(len(X)) if candidates is None else np.asarray(candidates, dtype=np.int64)
    if len(idx) == 0 or len(ell) == 0:
        return _empty()
    D = None if directions is None else np.asarray(directions, dtype=np.float64)[idx]
    s, uv, d, theta, deeper, _ = _nearest(X[idx], ell, D)
    ok = (d < lam) & (theta < phi) & deeper
    return MuscleAttachment(idx[ok], s[ok], uv[ok], d[ok], theta[ok])


@dataclass
class SheetSamples:
    """Points sampling a sheet of nodes by area: each triangle cut into n^2 equal sub-triangles
    whose centroids belong to the triangle corner of largest barycentric weight (the centre one
    of n = 3 to all three, a third each).

    Attributes:
        points: Sample positions [m], shape (s, 3).
        node: Node each sample's area belongs to, shape (s,), int64.
        area: Area of the sample assigned to that node [m^2], shape (s,).
        direction: Unit inward direction at the sample (its corner node's), shape (s, 3).
        face: Sheet triangle of each sample, shape (s,), int64.
    """

    points: np.ndarray
    node: np.ndarray
    area: np.ndarray
    direction: np.ndarray
    face: np.ndarray

    def node_area(self, count: int) -> np.ndarray:
        """Sheet area [m^2] of every node, shape (count,)."""
        return np.bincount(self.node, weights=self.area, minlength=count)


def sheet_samples(X, F, directions, *, n: int = 3) -> SheetSamples:
    """Area samples of the triangles F (m, 3) over the nodes X (p, 3) (:class:`SheetSamples`);
    ``directions`` (p, 3) the nodes' unit inward directions."""
    X = np.asarray(X, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    D = np.asarray(directions, dtype=np.float64)
    bary = []
    for i in range(n):
        for j in range(n - i):
            tris = [((i, j), (i + 1, j), (i, j + 1))]  # upright sub-triangle
            if i + j <= n - 2:
                tris.append(((i + 1, j), (i, j + 1), (i + 1, j + 1)))  # the inverted one beside it
            for t in tris:
                gx, gy = np.mean(t, axis=0)
                bary.append([1.0 - (gx + gy) / n, gx / n, gy / n])
    B = np.array(bary)  # (n^2, 3)
    top = B.max(1, keepdims=True)
    W = (np.abs(B - top) < 1e-9).astype(float)
    W /= W.sum(1, keepdims=True)  # share of each sub-triangle per corner (ties split)
    tri = X[F]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    P = np.einsum("sc,mcx->msx", B, tri)  # (m, n^2, 3)
    m, k = len(F), len(B)
    pts, node, ar, dirs, face = [], [], [], [], []
    for c in range(3):
        sel = W[:, c] > 0
        pts.append(P[:, sel].reshape(-1, 3))
        node.append(np.repeat(F[:, c], sel.sum()))
        ar.append((area[:, None] / k * W[sel, c][None, :]).reshape(-1))
        dirs.append(np.repeat(D[F[:, c]], sel.sum(), axis=0))
        face.append(np.repeat(np.arange(m), sel.sum()))
    return SheetSamples(np.concatenate(pts), np.concatenate(node), np.concatenate(ar), np.concatenate(dirs),
                        np.concatenate(face))


def attach_by_area(X, ell: Ellipsoids, lam: float, phi: float, samples: SheetSamples, *, sample_mask=None,
                   directions=None, min_weight: float = 0.05) -> MuscleAttachment:
    """Fig. 6.4 over the sheet's area: a node's weight is the share of its sheet area
    (:class:`SheetSamples`) whose points pass the distance and angle rule of :func:`attach_nodes`,
    the skin-side rule (and ``sample_mask``, e.g. the muscle's regions); nodes with a weight of
    at least ``min_weight`` connect, each by its own nearest surface point.

    The skin-side rule is taken where the muscle is: a sample (or node) connects only when its
    nearest muscle point lies under the sheet there (deeper than the sheet sample nearest to that
    point, along its inward direction), so no spring pulls its node out through the skin where
    a muscle runs in or above the skin layer. (:func:`attach_nodes` compares the muscle point
    with the node's own tangent plane instead; on a curved sheet that rejects a node beside a
    muscle that runs under the sheet: in the fold of the upper lid the orbicularis oculi's ring
    2-3 mm below a node lies "above" the node's plane, and the level-0 default head lost the
    medial half of its upper lid's row of attachments, so the ring pulled the lid down on its
    lateral half only and sheared it 2.6 mm medially.)

    Args:
        X: Node positions [m], shape (p, 3).
        ell: The muscle's segments.
        lam: Distance threshold lambda [m].
        phi: Angle threshold [rad].
        samples: The sheet's area samples.
        sample_mask: Samples that may pass at all, shape (s,), bool (default all).
        directions: Unit inward direction of every node, shape (p, 3): with it the skin-side
            rule applies to the node itself too (its nearest muscle point under the sheet).
        min_weight: Smallest weight that connects a node.

    Returns:
        :class:`MuscleAttachment` with indices into X and the weights.
    """
    X = np.asarray(X, dtype=np.float64)
    if len(ell) == 0 or len(samples.points) == 0:
        return _empty()
    from scipy.spatial import cKDTree

    reach = ell.radii.max(1) + lam
    tree = cKDTree(samples.points)
    cand = set()
    for c, rr in zip(ell.centers, reach):
        cand.update(tree.query_ball_point(c, rr))
    cand = np.array(sorted(cand), dtype=np.int64)
    if sample_mask is not None and len(cand):
        cand = cand[np.asarray(sample_mask, bool)[cand]]
    if len(cand) == 0:
        return _empty()
    _, _, d, theta, _, p = _nearest(samples.points[cand], ell)
    ok = cand[(d < lam) & (theta < phi) & _under_sheet(p, samples, tree)]
    total = samples.node_area(len(X))
    inside = np.bincount(samples.node[ok], weights=samples.area[ok], minlength=len(X))
    w = np.divide(inside, total, out=np.zeros(len(X)), where=total > 0)
    idx = np.flatnonzero(w >= min_weight)
    if len(idx) == 0:
        return _empty()
    s, uv, dn, th, _, p = _nearest(X[idx], ell)
    keep = _under_sheet(p, samples, tree) if directions is not None else np.ones(len(idx), bool)
    return MuscleAttachment(idx[keep], s[keep], uv[keep], dn[keep], th[keep], np.minimum(w[idx][keep], 1.0))
