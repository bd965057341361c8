"""The scan's colour baked into the adapted head's texture (``texture.png`` of ``facewarp adapt``).

For every texel of the head's UV layout (:mod:`~facewarp._src.template.uv`):

1. **Where on the head**: the UV triangles are rasterised (texel centres, barycentric weights),
   giving the texel's point ``p`` on the adapted surface and its interpolated normal ``n``.
2. **Where on the scan**: rays along ``+n`` and ``-n`` from ``p`` (``|t| <=``
   :data:`MAX_DISTANCE`) find the scan surface; a hit counts only where the scan's face there
   turns the same way as the head (``n_scan . n >=`` :data:`MIN_NORMAL_COSINE`), and the nearer
   of the two counting hits is taken. That keeps the lower lip's colour off the upper lip and
   the inside of a fold off its outside (the guard against crossing to the wrong sheet). Where the ray misses (a scan border, a
   narrow crease) the closest scan point within half that distance is taken, with the same
   guard.
3. **Its colour**: the scan's vertex colours interpolated with the hit's barycentric weights, or
   its texture sampled bilinearly at the hit's interpolated UV.
4. **Where the scan has nothing** (holes, the back of a face-only scan, under the chin, inside
   the lips): the head's vertices take the colour sampled the same way at their own position,
   the vertices without one are filled by a harmonic (membrane) interpolation over the head
   mesh from those with one (the smooth fill from the nearest skin), and those texels take the
   filled vertex colours.
5. **Seams**: every texel outside all charts takes the colour of the nearest texel inside one
   (a full dilation), so bilinear filtering and mip-maps at chart borders read skin, not black.

Colours stay in the scan's stored (sRGB) values; the texture is written as an 8-bit sRGB PNG,
row 0 at v = 1 (the top), as OBJ / USD / glTF viewers read it.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError

__all__ = ["MAX_DISTANCE", "MIN_NORMAL_COSINE", "BakeResult", "bake_texture", "rasterize_uv", "sample_scan_colors",
           "vertex_color_texture"]

MAX_DISTANCE = 0.005
"""Farthest a scan point may lie from the head along the normal [m] to lend it its colour."""

MIN_NORMAL_COSINE = 0.3
"""Least cosine between the scan's face normal and the head's normal for a colour sample."""


class BakeResult:
    """A baked texture.

    Attributes:
        image: The texture, shape (size, size, 3), uint8 sRGB, row 0 at v = 1.
        covered_fraction: Fraction of the head's texels (inside a chart) coloured from the scan.
        filled_fraction: Fraction of them filled from the nearest skin.
        vertex_colors: The head's per-vertex colours after the fill, shape (n, 3), float64 in [0, 1].
    """

    def __init__(self, image, covered_fraction, filled_fraction, vertex_colors):
        self.image = image
        self.covered_fraction = float(covered_fraction)
        self.filled_fraction = float(filled_fraction)
        self.vertex_colors = vertex_colors

    def to_dict(self) -> dict:
        return {"size": int(self.image.shape[0]), "covered_fraction": self.covered_fraction,
                "filled_fraction": self.filled_fraction, "max_distance_m": MAX_DISTANCE,
                "min_normal_cosine": MIN_NORMAL_COSINE}


def rasterize_uv(uv, face_uv, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The texels whose centres lie in a UV triangle.

    Args:
        uv: Texture coordinates in [0, 1]^2, shape (k, 2), float64 (v up).
        face_uv: Per triangle corner an index into ``uv``, shape (m, 3), int64.
        size: Texture side [texels].

    Returns:
        ``(texel, face, bary)``: flat texel index ``row * size + col`` (row 0 at v = 1), shape
        (q,), int64; the triangle, shape (q,), int64; barycentric weights of its corners,
        shape (q, 3), float64. A texel on a shared edge is listed once.
    """
    U = np.asarray(uv, dtype=np.float64)[np.asarray(face_uv)]  # (m, 3, 2)
    X = U[..., 0] * size - 0.5  # texel-centre coordinates: column
    Y = (1.0 - U[..., 1]) * size - 0.5  # row
    texels, faces, barys = [], [], []
    x0 = np.clip(np.floor(X.min(1)).astype(int), 0, size - 1)
    x1 = np.clip(np.ceil(X.max(1)).astype(int), 0, size - 1)
    y0 = np.clip(np.floor(Y.min(1)).astype(int), 0, size - 1)
    y1 = np.clip(np.ceil(Y.max(1)).astype(int), 0, size - 1)
    eps = -1e-9
    for f in range(len(U)):
        cols = np.arange(x0[f], x1[f] + 1)
        rows = np.arange(y0[f], y1[f] + 1)
        cc, rr = np.meshgrid(cols, rows)
        px, py = cc.ravel().astype(np.float64), rr.ravel().astype(np.float64)
        ax, bx, cx = X[f]
        ay, by, cy = Y[f]
        det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
        if abs(det) < 1e-20:
            continue
        l0 = ((by - cy) * (px - cx) + (cx - bx) * (py - cy)) / det
        l1 = ((cy - ay) * (px - cx) + (ax - cx) * (py - cy)) / det
        l2 = 1.0 - l0 - l1
        inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
        if not inside.any():
            continue
        texels.append(rr.ravel()[inside] * size + cc.ravel()[inside])
        faces.append((f, int(inside.sum())))
        barys.append(np.stack([l0[inside], l1[inside], l2[inside]], 1))
    if not texels:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    t = np.concatenate(texels)
    f = np.repeat(np.array([a for a, _ in faces], dtype=np.int64), [n for _, n in faces])
    b = np.clip(np.concatenate(barys), 0.0, 1.0)
    b /= b.sum(1, keepdims=True)
    t, first = np.unique(t, return_index=True)
    return t, f[first], b[first]


def _sample_texture(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``img`` (h, w, 3) at ``uv`` (k, 2) (v up, wrapped into [0, 1))."""
    h, w = img.shape[:2]
    u = np.mod(uv[:, 0], 1.0) * w - 0.5
    v = (1.0 - np.mod(uv[:, 1], 1.0)) * h - 0.5
    x0 = np.floor(u).astype(int)
    y0 = np.floor(v).astype(int)
    fx = (u - x0)[:, None]
    fy = (v - y0)[:, None]
    x0c, x1c = np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1)
    y0c, y1c = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
    return ((img[y0c, x0c] * (1 - fx) + img[y0c, x1c] * fx) * (1 - fy)
            + (img[y1c, x0c] * (1 - fx) + img[y1c, x1c] * fx) * fy)


def sample_scan_colors(P, N, scan_V, scan_F, *, colors=None, texture=None, corner_uv=None, query=None,
                       max_distance: float = MAX_DISTANCE, device: str = "cpu") -> tuple[np.ndarray, np.ndarray]:
    """The scan's colour at points of the head, along their normals (steps 2-3 of the module docstring).

    Args:
        P: Points on the head [m], scan frame, shape (k, 3), float64.
        N: Unit normals of the head there, shape (k, 3), float64.
        scan_V: Scan vertices [m], shape (s, 3); scan_F: its triangles, shape (l, 3), int64.
        colors: The scan's vertex colours, shape (s, 3), in [0, 1]; or
        texture: its texture, shape (h, w, 3), in [0, 1], with ``corner_uv`` (l, 3, 2).
        query: An existing :class:`~facewarp.geometry.MeshQuery` of the scan (else one is built).
        max_distance: :data:`MAX_DISTANCE`.
        device: Warp device of the queries.

    Returns:
        (colours (k, 3) float64 in [0, 1], NaN where none; found (k,) bool).
    """
    from ..geometry.surface import MeshQuery, face_normals

    scan_F = np.asarray(scan_F, dtype=np.int64)
    if colors is None and (texture is None or corner_uv is None):
        raise InputError("scan: no colour to bake (neither vertex colours nor a texture with UVs)")
    q = query or MeshQuery(scan_V, scan_F, device=device)
    fn = face_normals(scan_V, scan_F)
    # along +n and -n separately: the nearer hit whose face turns the head's way (the nearest
    # hit may be a wrong sheet, e.g. the back of a fold, with the right one just beyond it)
    face = np.full(len(P), -1, dtype=np.int64)
    bary = np.zeros((len(P), 3))
    best = np.full(len(P), np.inf)
    for sign in (1.0, -1.0):
        h = q.ray_cast(P, sign * N, max_distance)
        good = h.hit.copy()
        good[good] = np.einsum("kd,kd->k", fn[h.face[good]], N[good]) >= MIN_NORMAL_COSINE
        good &= np.abs(h.t) < best
        face[good], bary[good], best[good] = h.face[good], h.bary[good], np.abs(h.t[good])
    ok = face >= 0
    miss = np.flatnonzero(~ok)
    if len(miss):
        cp = q.closest_point(P[miss], 0.5 * max_distance)
        good = cp.face >= 0
        good[good] = np.einsum("kd,kd->k", fn[cp.face[good]], N[miss][good]) >= MIN_NORMAL_COSINE
        face = face.copy()
        bary = bary.copy()
        face[miss[good]] = cp.face[good]
        bary[miss[good]] = cp.bary[good]
        ok[miss[good]] = True
    out = np.full((len(P), 3), np.nan)
    idx = np.flatnonzero(ok)
    if len(idx):
        f, b = face[idx], bary[idx]
        if colors is not None:
            out[idx] = np.einsum("kc,kcd->kd", b, np.asarray(colors, np.float64)[scan_F[f]])
        else:
            uvs = np.einsum("kc,kcd->kd", b, np.asarray(corner_uv, np.float64)[f])
            out[idx] = _sample_texture(np.asarray(texture, np.float64), uvs)
    return np.clip(out, 0.0, 1.0), ok


def _harmonic_fill(F: np.ndarray, n: int, C: np.ndarray, known: np.ndarray, default) -> np.ndarray:
    """Per-vertex colours C (n, 3) with the unknown vertices solved from the graph Laplacian
    (uniform weights) with the known ones fixed: a smooth fill from the nearest known colours."""
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.csgraph import connected_components
    from scipy.sparse.linalg import spsolve

    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    L = diags(np.asarray(A.sum(1)).ravel()) - A
    out = C.copy()
    unknown = np.flatnonzero(~known)
    if not len(unknown):
        return out
    if not known.any():
        out[:] = default
        return out
    # components with no known vertex take the default colour
    _, lab = connected_components(A, directed=False)
    has = np.zeros(lab.max() + 1, bool)
    has[lab[known]] = True
    lonely = ~has[lab] & ~known
    out[lonely] = default
    solve = np.flatnonzero(~known & ~lonely)
    if len(solve):
        kn = np.flatnonzero(known | lonely)
        L = L.tocsr()
        Luu = L[solve][:, solve].tocsc()
        rhs = -(L[solve][:, kn] @ out[kn])
        out[solve] = np.asarray(spsolve(Luu, rhs)).reshape(len(solve), 3)
    return np.clip(out, 0.0, 1.0)


def bake_texture(V, F, uv, face_uv, scan_V, scan_F, *, colors=None, texture=None, corner_uv=None, size: int = 2048,
                 default_color=(0.80, 0.62, 0.52), device: str = "cpu") -> BakeResult:
    """Bake a scan's colour into a texture over the head's UVs (see the module docstring).

    Args:
        V: The adapted head's vertices [m] in the scan's frame, shape (n, 3), float64.
        F: Its triangles, shape (m, 3), int64.
        uv, face_uv: Its UV layout: (k, 2) float64 in [0, 1]^2 and per-corner indices (m, 3) int64.
        scan_V, scan_F: The scan [m], shapes (s, 3) and (l, 3).
        colors: The scan's vertex colours (s, 3) in [0, 1]; or
        texture: its texture (h, w, 3) in [0, 1] with ``corner_uv`` (l, 3, 2).
        size: Texture side [texels].
        default_color: sRGB colour where the scan has no colour at all.
        device: Warp device of the queries.

    Returns:
        The :class:`BakeResult`.
    """
    from scipy.ndimage import distance_transform_edt

    from ..geometry.surface import MeshQuery, vertex_normals

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    scan_V = np.asarray(scan_V, dtype=np.float64)
    scan_F = np.asarray(scan_F, dtype=np.int64)
    q = MeshQuery(scan_V, scan_F, device=device)
    look = {"colors": colors, "texture": texture, "corner_uv": corner_uv}
    VN = vertex_normals(V, F)
    # per-vertex colours and the harmonic fill where the scan has none
    vc, vok = sample_scan_colors(V, VN, scan_V, scan_F, query=q, device=device, **look)
    vc = _harmonic_fill(F, len(V), np.nan_to_num(vc), vok, np.asarray(default_color, float))
    # texels
    texel, face, bary = rasterize_uv(uv, face_uv, size)
    P = np.einsum("kc,kcd->kd", bary, V[F[face]])
    N = np.einsum("kc,kcd->kd", bary, VN[F[face]])
    N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
    tc, tok = sample_scan_colors(P, N, scan_V, scan_F, query=q, device=device, **look)
    fill = np.einsum("kc,kcd->kd", bary, vc[F[face]])
    tc = np.where(tok[:, None], tc, fill)
    img = np.zeros((size * size, 3), dtype=np.uint8)
    inside = np.zeros(size * size, bool)
    img[texel] = np.clip(np.rint(tc * 255.0), 0, 255).astype(np.uint8)
    inside[texel] = True
    if not inside.all():
        _, (ri, ci) = distance_transform_edt(~inside.reshape(size, size), return_indices=True)
        out = np.flatnonzero(~inside)
        img[out] = img[ri.ravel()[out] * size + ci.ravel()[out]]
    image = img.reshape(size, size, 3)
    n_in = max(len(texel), 1)
    return BakeResult(image, tok.sum() / n_in, 1.0 - tok.sum() / n_in, vc)


def vertex_color_texture(F, uv, face_uv, vertex_colors, *, size: int = 1024) -> np.ndarray:
    """A texture painted from per-vertex colours over a UV layout (a head without a scan colour:
    its preview skin and lip colours), seams dilated as in :func:`bake_texture`.

    Args:
        F: Triangles, shape (m, 3), int64.
        uv, face_uv: The UV layout: (k, 2) float64 and per-corner indices (m, 3) int64.
        vertex_colors: sRGB per vertex, shape (n, 3), float in [0, 1].
        size: Texture side [texels].

    Returns:
        The texture, shape (size, size, 3), uint8, row 0 at v = 1.
    """
    from scipy.ndimage import distance_transform_edt

    F = np.asarray(F, dtype=np.int64)
    C = np.asarray(vertex_colors, dtype=np.float64)
    texel, face, bary = rasterize_uv(uv, face_uv, size)
    img = np.zeros((size * size, 3), dtype=np.uint8)
    inside = np.zeros(size * size, bool)
    img[texel] = np.clip(np.rint(np.einsum("kc,kcd->kd", bary, C[F[face]]) * 255.0), 0, 255).astype(np.uint8)
    inside[texel] = True
    if not inside.all():
        _, (ri, ci) = distance_transform_edt(~inside.reshape(size, size), return_indices=True)
        out = np.flatnonzero(~inside)
        img[out] = img[ri.ravel()[out] * size + ci.ravel()[out]]
    return img.reshape(size, size, 3)
