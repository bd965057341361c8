"""The UV layout of the template: a low-stretch chart for the face front, a few for the rest.

Charts (by the template's regions, so every level gets the same charts):

- ``face``: the frontal face (the simulation domain, :data:`~.head.FRONTAL_REGIONS`), with the
  eye and mouth openings as holes; a least-squares conformal map (LSCM, Levy et al. 2002,
  libigl ``lscm``) with two pins on the outer boundary at the chart's widest points, refined
  by an as-rigid-as-possible parametrisation (ARAP, Liu et al. 2008, libigl ``arap_solve``),
  which trades a little angle distortion for much less area distortion. ARAP runs with the
  chart's holes filled by fans (so the sides of the mouth slit cannot slide over each other)
  and is kept only if no triangle flips and the chart's boundary does not cross itself. It gets
  :data:`FACE_DENSITY` x the texel density of the other charts, because that is where the
  person is recognised.
- ``ear_L``, ``ear_R``: each ear (LSCM + ARAP).
- ``side_L``, ``side_R``: the rest of the head (scalp, neck), split at the midline (x = 0) into
  two discs, each by LSCM + ARAP.

Each chart is scaled to its 3D area (times its density), turned to its smallest bounding box,
and the charts are packed in shelves into the unit square with a gutter of
:data:`GUTTER` so texture filtering and the bake's dilation do not bleed between charts.
UVs are per corner: ``uv`` (k, 2) with ``face_uv`` (m, 3) indices into it, as OBJ ``f v/vt``
and USD's indexed faceVarying ``primvars:st`` store them; vertices on a chart seam get one UV
per chart.

The stretch of a layout is measured by :func:`uv_distortion`: per triangle the singular
values ``s1 >= s2`` of the map from the 3D triangle to its UV triangle (after one global
scale of the chart), the area distortion ``s1 s2`` and the angle distortion (conformal
factor) ``s1 / s2``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FACE_DENSITY", "GUTTER", "UVLayout", "face_uv_layout", "uv_distortion"]

FACE_DENSITY = 2.0
"""Texels per metre of the face chart over those of the other charts (per axis)."""

UPRIGHT = ("face", "ear_L", "ear_R")
"""Charts turned so the head's up is the texture's up (the others turn to their smallest box)."""

ARAP_ITERATIONS = 10
"""As-rigid-as-possible iterations after the conformal map of each chart."""

GUTTER = 0.012
"""Empty margin around each chart, as a fraction of the texture side."""


class UVLayout:
    """Per-corner texture coordinates of a triangle mesh.

    Attributes:
        uv: Texture coordinates in [0, 1]^2, shape (k, 2), float64 (v up, as in OBJ and USD).
        face_uv: Per triangle corner an index into ``uv``, shape (m, 3), int64.
        chart: Chart index of every triangle, shape (m,), int64.
        chart_names: Name of every chart.
    """

    def __init__(self, uv, face_uv, chart, chart_names):
        self.uv = np.asarray(uv, dtype=np.float64)
        self.face_uv = np.asarray(face_uv, dtype=np.int64)
        self.chart = np.asarray(chart, dtype=np.int64)
        self.chart_names = list(chart_names)

    def corner_uv(self) -> np.ndarray:
        """UV of every triangle corner, shape (m, 3, 2), float64."""
        return self.uv[self.face_uv]


def _chart_lscm(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """LSCM + ARAP of one chart (triangles F over vertices V): (local vertex ids (k,), UV (k, 2))."""
    import igl

    ids, inv = np.unique(F, return_inverse=True)
    lf = inv.reshape(-1, 3).astype(np.int64)
    lv = np.ascontiguousarray(V[ids], dtype=np.float64)
    n_real = len(ids)
    lf_real = lf
    loop = igl.boundary_loop(lf)
    # pins: the two boundary vertices farthest apart, at their 3D distance along the u axis
    B = lv[loop]
    c = B.mean(0)
    a = loop[int(np.argmax(np.linalg.norm(B - c, axis=1)))]
    b = loop[int(np.argmax(np.linalg.norm(B - lv[a], axis=1)))]
    d = float(np.linalg.norm(lv[a] - lv[b]))
    res = igl.lscm(lv, lf, np.array([a, b], dtype=np.int64), np.array([[0.0, 0.0], [d, 0.0]]))
    uv = np.asarray(res[0] if isinstance(res, tuple) else res, dtype=np.float64)
    # ARAP (Liu et al. 2008, libigl arap_solve) from the conformal start: trades a little angle
    # distortion for much less area distortion (the nose and lids are no longer squeezed);
    # kept only where it flips no triangle and its boundary does not cross itself (no overlap)
    a3 = _areas3(lv, lf).sum()
    uv = uv * np.sqrt(a3 / max(abs(_areas2(uv, lf).sum()), 1e-300))
    # ARAP runs on the chart with its holes filled (the fill's centre starts at its loop's mean UV)
    lv, lf = _fill_holes(lv, lf)
    start = np.concatenate([uv, np.zeros((len(lv) - n_real, 2))])
    for c in range(n_real, len(lv)):
        ring = np.unique(lf[(lf == c).any(1)])
        ring = ring[ring != c]
        start[c] = start[ring].mean(0)
    try:
        data = igl.ARAPData()
        data.max_iter = ARAP_ITERATIONS
        pin = np.array([0], dtype=np.int32)
        igl.arap_precomputation(lv, lf, 2, pin, data)
        refined = np.asarray(igl.arap_solve(start[pin].copy(), data, start.copy()), dtype=np.float64)
        s0 = np.sign(_areas2(start, lf_real))
        if (refined.shape == start.shape and np.isfinite(refined).all()
                and (np.sign(_areas2(refined, lf_real)) == s0).all() and not _boundary_crosses(refined, lf_real)):
            uv = refined
    except (RuntimeError, AttributeError, TypeError):  # libigl cannot (or this libigl has no ARAP): conformal map
        pass
    # one orientation for every chart: UV triangles counter-clockwise like the outward faces
    uv, lf = uv[:n_real].copy(), lf_real
    e1 = uv[lf[:, 1]] - uv[lf[:, 0]]
    e2 = uv[lf[:, 2]] - uv[lf[:, 0]]
    if np.sum(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) < 0:
        uv[:, 1] = -uv[:, 1]
    return ids, uv


def _boundary_crosses(uv: np.ndarray, F: np.ndarray) -> bool:
    """Whether two boundary edges of the chart (triangles F) cross in UV: with no flipped
    triangle, the only way a chart can overlap itself."""
    d = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    key = np.sort(d, axis=1)
    _, inv, cnt = np.unique(key[:, 0] * (F.max() + 1) + key[:, 1], return_inverse=True, return_counts=True)
    e = d[cnt[inv.ravel()] == 1]
    if len(e) < 4:
        return False
    A, B = uv[e[:, 0]], uv[e[:, 1]]
    lo, hi = np.minimum(A, B), np.maximum(A, B)
    for i in range(len(e)):
        cand = np.flatnonzero((lo[:, 0] <= hi[i, 0]) & (hi[:, 0] >= lo[i, 0]) & (lo[:, 1] <= hi[i, 1])
                              & (hi[:, 1] >= lo[i, 1]))
        cand = cand[(cand > i) & ~np.isin(e[cand], e[i]).any(1)]  # not itself, not sharing a vertex
        if not len(cand):
            continue
        p, r = A[i], B[i] - A[i]
        q, sv = A[cand], B[cand] - A[cand]
        den = r[0] * sv[:, 1] - r[1] * sv[:, 0]
        ok = np.abs(den) > 1e-300
        t = ((q[:, 0] - p[0]) * sv[:, 1] - (q[:, 1] - p[1]) * sv[:, 0]) / np.where(ok, den, 1.0)
        u = ((q[:, 0] - p[0]) * r[1] - (q[:, 1] - p[1]) * r[0]) / np.where(ok, den, 1.0)
        if (ok & (t > 0) & (t < 1) & (u > 0) & (u < 1)).any():
            return True
    return False


def _fill_holes(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """V, F with every boundary loop but the longest closed by a fan to a new centre vertex.

    The chart is parametrised with its holes (eyes, the mouth slit) filled, so the two sides of
    a narrow opening cannot slide over each other in UV (ARAP keeps the fill triangles unflipped
    as it does the others); the fill is dropped afterwards (the new vertices come last)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    d = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    key = np.sort(d, axis=1)
    _, inv, cnt = np.unique(key[:, 0] * len(V) + key[:, 1], return_inverse=True, return_counts=True)
    b = d[cnt[inv.ravel()] == 1]  # directed boundary edges, as their faces list them
    if not len(b):
        return V, F
    verts, local = np.unique(b, return_inverse=True)
    local = local.reshape(-1, 2)
    g = coo_matrix((np.ones(len(b)), (local[:, 0], local[:, 1])), shape=(len(verts), len(verts)))
    nc, lab = connected_components(g, directed=False)
    edge_loop = lab[local[:, 0]]
    length = np.bincount(edge_loop, weights=np.linalg.norm(V[b[:, 0]] - V[b[:, 1]], axis=1), minlength=nc)
    outer = int(np.argmax(length))
    newV, newF = [V], [F]
    n = len(V)
    for k in range(nc):
        if k == outer:
            continue
        e = b[edge_loop == k]
        c = n + len(newV) - 1
        newV.append(V[np.unique(e)].mean(0, keepdims=True))
        newF.append(np.column_stack([e[:, 1], e[:, 0], np.full(len(e), c)]))
    return np.concatenate(newV), np.concatenate(newF)


def _areas3(V, F):
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)


def _areas2(U, F):
    e1 = U[F[:, 1]] - U[F[:, 0]]
    e2 = U[F[:, 2]] - U[F[:, 0]]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def _upright(uv: np.ndarray, height: np.ndarray) -> np.ndarray:
    """``uv`` (k, 2) turned so that the 3D height (world y of its vertices, (k,)) grows along +v,
    moved to the origin: the face reads upright in the texture."""
    A = np.column_stack([uv - uv.mean(0), np.ones(len(uv))])
    g = np.linalg.lstsq(A, height, rcond=None)[0][:2]  # gradient of the height in the chart
    ang = np.arctan2(g[0], g[1])  # rotate g onto +v
    c, s = np.cos(ang), np.sin(ang)
    r = uv @ np.array([[c, -s], [s, c]]).T
    return r - r.min(0)


def _min_box(uv: np.ndarray) -> np.ndarray:
    """``uv`` rotated so its bounding box is smallest (over 90 trial angles), moved to the origin."""
    best, best_area = uv, np.inf
    for ang in np.linspace(0.0, np.pi / 2, 90, endpoint=False):
        c, s = np.cos(ang), np.sin(ang)
        r = uv @ np.array([[c, -s], [s, c]])
        ext = np.ptp(r, axis=0)
        if ext[0] * ext[1] < best_area:
            best, best_area = r, ext[0] * ext[1]
    if np.ptp(best[:, 1]) > np.ptp(best[:, 0]):  # lying: wider than tall packs better in shelves
        best = best[:, ::-1] * np.array([1.0, -1.0])
    return best - best.min(0)


def _pack(charts: list[np.ndarray], gutter: float) -> list[np.ndarray]:
    """Shelf packing of charts (each (k, 2) from the origin, same unit) into the unit square."""
    ext = [np.ptp(c, axis=0) for c in charts]
    order = sorted(range(len(charts)), key=lambda i: -ext[i][1])

    def layout(width):
        x = y = shelf_h = 0.0
        pos = {}
        for i in order:
            w, h = ext[i]
            if x > 0 and x + w > width:
                y += shelf_h + gutter
                x, shelf_h = 0.0, 0.0
            pos[i] = (x, y)
            x += w + gutter
            shelf_h = max(shelf_h, h)
        return pos, y + shelf_h

    # search the shelf width that makes the packing closest to a square
    total = sum(e[0] * e[1] for e in ext)
    best = None
    for width in np.sqrt(total) * np.linspace(0.9, 2.5, 60):
        width = max(width, max(e[0] for e in ext))
        pos, height = layout(width)
        used_w = max(pos[i][0] + ext[i][0] for i in pos)
        side = max(used_w, height)
        if best is None or side < best[0]:
            best = (side, pos)
    side, pos = best
    s = (1.0 - 2.0 * gutter) / side
    return [gutter + (c + np.asarray(pos[i])) * s for i, c in enumerate(charts)]


def _components(F: np.ndarray, tri: np.ndarray, n: int) -> np.ndarray:
    """Component label of each triangle ``tri`` (connected through shared edges), shape (len(tri),)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    E = np.sort(np.stack([F[tri][:, [0, 1]], F[tri][:, [1, 2]], F[tri][:, [2, 0]]], 1).reshape(-1, 2), axis=1)
    _, inv = np.unique(E[:, 0] * n + E[:, 1], return_inverse=True)
    owner = np.repeat(np.arange(len(tri)), 3)
    g = coo_matrix((np.ones(len(owner)), (owner, inv.ravel())), shape=(len(tri), inv.max() + 1)).tocsr()
    return connected_components(g @ g.T, directed=False)[1]


ISLAND = 0.02
"""A connected piece of a chart with fewer than this fraction of its triangles joins the chart
that holds most of the triangles around it."""


def _absorb_islands(F: np.ndarray, chart: np.ndarray, n: int) -> np.ndarray:
    chart = chart.copy()
    for _ in range(3):
        changed = False
        for k in np.unique(chart):
            tri = np.flatnonzero(chart == k)
            lab = _components(F, tri, n)
            sizes = np.bincount(lab)
            for c in np.flatnonzero(sizes < ISLAND * len(tri)):
                t = tri[lab == c]
                near = np.flatnonzero(np.isin(F, F[t]).any(1) & (chart != k))
                if len(near):
                    chart[t] = np.bincount(chart[near]).argmax()
                    changed = True
        if not changed:
            break
    return chart


def face_uv_layout(V, F, face_region, region_names, frontal) -> UVLayout:
    """The UV layout of a head (see the module docstring).

    Args:
        V: Vertices [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.
        face_region: Region index per triangle, shape (m,), int.
        region_names: Names of the regions (``ear_L``/``ear_R`` become their own charts).
        frontal: Whether a triangle is on the frontal face, shape (m,), bool.

    Returns:
        The :class:`UVLayout`.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    names = list(region_names)
    region = np.asarray(face_region)
    x = V[F].mean(1)[:, 0]
    chart = np.where(np.asarray(frontal, bool), 0, np.where(x >= 0, 3, 4))
    for k, ear in ((1, "ear_L"), (2, "ear_R")):
        if ear in names:
            chart[region == names.index(ear)] = k
    chart_names = ["face", "ear_L", "ear_R", "side_L", "side_R"]
    chart = _absorb_islands(F, chart, len(V))
    # split any chart that is not connected into its components (e.g. a stray triangle)
    pieces: list[tuple[str, np.ndarray]] = []
    for k, name in enumerate(chart_names):
        tri = np.flatnonzero(chart == k)
        if not len(tri):
            continue
        lab = _components(F, tri, len(V))
        sizes = np.bincount(lab)
        for c in np.argsort(-sizes):
            pieces.append((name if c == np.argmax(sizes) else f"{name}_{int(c)}", tri[lab == c]))
    uv_charts, vid_charts = [], []
    for name, tri in pieces:
        ids, uv = _chart_lscm(V, F[tri])
        a3 = _areas3(V, F[tri]).sum()
        lf = np.searchsorted(ids, F[tri])
        a2 = abs(_areas2(uv, lf).sum())
        uv = uv * np.sqrt(a3 / max(a2, 1e-300)) * (FACE_DENSITY if name == "face" else 1.0)
        uv_charts.append(_upright(uv, V[ids, 1]) if name in UPRIGHT else _min_box(uv))
        vid_charts.append(ids)
    packed = _pack(uv_charts, GUTTER)
    uv_all, face_uv = [], np.zeros_like(F)
    tri_chart = np.zeros(len(F), dtype=np.int64)
    offset = 0
    for c, ((name, tri), ids, uv) in enumerate(zip(pieces, vid_charts, packed)):
        face_uv[tri] = offset + np.searchsorted(ids, F[tri])
        tri_chart[tri] = c
        uv_all.append(uv)
        offset += len(ids)
    return UVLayout(np.concatenate(uv_all), face_uv, tri_chart, [p[0] for p in pieces])


def uv_distortion(V, F, uv, face_uv, mask=None) -> dict:
    """Stretch of a UV map over the triangles ``mask`` (default all), after one global scale.

    Args:
        V: Vertices [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.
        uv: Texture coordinates, shape (k, 2), float64.
        face_uv: Per corner an index into ``uv``, shape (m, 3), int64.
        mask: Triangles to measure, shape (m,), bool.

    Returns:
        A dict: ``area`` (the area ratio ``s1 s2`` normalised so that the area-weighted mean is 1:
        ``mean_abs_log`` (area-weighted mean of ``|ln s1 s2|``), ``p95``, ``min``, ``max``),
        ``angle`` (the conformal factor ``s1 / s2``: area-weighted mean, p95, max), ``flipped``
        (triangles whose UV orientation is reversed) and ``triangles``.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    U = np.asarray(uv, dtype=np.float64)[np.asarray(face_uv)]
    if mask is not None:
        F, U = F[mask], U[mask]
    P = V[F]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    # local orthonormal frame of each 3D triangle
    x = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    n = np.cross(e1, e2)
    A3 = 0.5 * np.linalg.norm(n, axis=1)
    y = np.cross(n / (2 * A3[:, None]), x)
    S = np.stack([np.stack([np.einsum("kd,kd->k", e1, x), np.einsum("kd,kd->k", e1, y)], 1),
                  np.stack([np.einsum("kd,kd->k", e2, x), np.einsum("kd,kd->k", e2, y)], 1)], 2)  # (m, 2, 2) cols
    T = np.stack([U[:, 1] - U[:, 0], U[:, 2] - U[:, 0]], 2)  # (m, 2, 2), columns = uv edges
    J = T @ np.linalg.inv(S)  # 3D-tangent -> uv
    det = np.linalg.det(J)
    sv = np.linalg.svd(J, compute_uv=False)
    w = A3 / A3.sum()
    area = sv[:, 0] * sv[:, 1]
    area = area / np.sum(w * area)
    angle = sv[:, 0] / np.maximum(sv[:, 1], 1e-300)
    la = np.abs(np.log(np.maximum(area, 1e-300)))
    return {
        "triangles": int(len(F)),
        "flipped": int((det <= 0).sum()),
        "area": {"mean_abs_log": float(np.sum(w * la)), "p95": float(np.percentile(area, 95)),
                 "p05": float(np.percentile(area, 5)), "min": float(area.min()), "max": float(area.max())},
        "angle": {"mean": float(np.sum(w * angle)), "p95": float(np.percentile(angle, 95)), "max": float(angle.max())},
    }
