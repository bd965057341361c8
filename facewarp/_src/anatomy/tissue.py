"""The volumetric skin layer of Sec. 6.2: the frontal face extruded inward into conforming tetrahedra.

Every frontal-face triangle is extruded inward along its (smoothed) vertex normals by the
per-vertex skin thickness (Table 6.1 x the template's magnification; a vertex on a region boundary
carries the average, see :func:`facewarp.default_template`). The prism-like element between the
skin triangle and its inner copy is split into three tetrahedra (Fig. 6.2). How the split stays
conforming and how the depth is clamped in the involute lips, nose and lid margins is told in
:mod:`facewarp._src.anatomy.extrude`; the measures that check the result are in
:mod:`facewarp._src.anatomy.tet_quality`.

Node ``l * p + i`` is always sheet ``l`` under frontal vertex ``i``, whatever the shape, which the
transfer of the anatomy between heads (Sec. 6.6) relies on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from .extrude import (_extrusion_directions, _layer_tets, _lipschitz_depth, _medial_axis_clamp, _raise_if_inverted,
                      _relax_inner_sheet, _sheets, _shrink_flat_tets, _vertex_adjacency)
from .tet_quality import tet_quality

__all__ = ["SkinLayer", "build_skin_layer", "extrude_skin_layer", "skin_layer_quality"]


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
        probe: Medial-axis clamp factor (step 2 in :mod:`facewarp._src.anatomy.extrude`); 0 turns the clamp off.
        min_fraction: Smallest depth as a fraction of the thickness.
        min_volume_ratio: A tet smaller than this fraction of its prism's volume / 3 makes its
            skin vertices shallower.
        max_sweeps: Sweeps of the clamp loops.
        relax_sweeps: Sweeps of the inner-sheet relaxation (step 5 in :mod:`facewarp._src.anatomy.extrude`);
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

    # 1. extrusion directions: head normals, smoothed over the patch, inside each vertex's
    # visibility cone
    A = _vertex_adjacency(Fl, p)
    n = _extrusion_directions(V, HF, src, Fl, A, normals=normals, smoothing=normal_smoothing)
    X = V[src]
    d_inward = -n
    t = thickness[src]
    d = t.copy()
    d_min = min_fraction * t
    # 2. medial-axis clamp against the whole head
    if probe > 0:
        d = _medial_axis_clamp(V, HF, X, n, d, d_min, probe=probe, max_sweeps=max_sweeps)
    # 3. 0.5-Lipschitz depth along edges
    d = _lipschitz_depth(X, A, d)
    # 4. build, and shrink around inverted / flat tets
    T, prism = _layer_tets(Fl, p, layers)
    d, d_inward = _shrink_flat_tets(X, Fl, A, T, prism, d, d_min, d_inward, layers,
                                    min_volume_ratio=min_volume_ratio, max_sweeps=max_sweeps)
    # 5. flat tets left by crossing directions (creases of adapted heads): the inner sheet is
    # relaxed toward a parallel copy of the skin, one node at a time where that helps
    if relax_sweeps > 0:
        d, d_inward = _relax_inner_sheet(X, Fl, d, d_inward, layers, T, prism, A, d_max=t, sweeps=relax_sweeps)
    P = _sheets(X, d, d_inward, layers)
    _raise_if_inverted(P, T, prism, X, Fl, src, face_index)

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
