"""The tissue's elements, derived from a tet mesh (thesis Sec. 6.4.2): free NumPy functions on arrays.

:func:`tissue_elements` validates a tet mesh and gives the elements of the deformation model:
unique tet edges (distance energy, Eq. 6.4.4 with the nonlinear stiffness of Eq. 6.4.6) with their
class by layer, unique tet faces (area energy, Eq. 6.4.7), the tets themselves (volume energy,
Eq. 6.4.8), each element's rest measure and share of the volume, and each node's sheet area
(:func:`sheet_areas`). :func:`rest_geometry` measures the rest lengths, areas, volumes and rest
inverses again on placed positions (:meth:`~.builder.ModelBuilder.replicate`). The material's
numbers (stiffness, damping, masses) are the builder's (:meth:`~.builder.ModelBuilder.add_tissue`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from ..geometry.tets import TET_EDGES, TET_FACES

__all__ = ["EDGE_CROSS", "EDGE_INNER", "EDGE_OUTER", "TissueElements", "check_tet_mesh", "rest_geometry", "sheet_areas",
           "tissue_elements"]

EDGE_OUTER = 0
"""Edge class of an edge whose two nodes are both on the outer layer (``layer == 0``)."""
EDGE_INNER = 1
"""Edge class of an edge whose two nodes are both on the inner layer (``layer == 1``)."""
EDGE_CROSS = 2
"""Edge class of an edge joining the outer and the inner layer."""

_TET_EDGES, _TET_FACES = TET_EDGES, TET_FACES


def sheet_areas(V, T, layer) -> np.ndarray:
    """Each node's share of the boundary area of its own sheet [m^2], shape (n,), float64.

    The boundary faces of the tet mesh whose three nodes lie in one layer (the skin surface for
    layer 0, the inner sheet for layer 1) give a third of their area to each node; nodes on no
    such face (a side wall) get 0.
    """
    V = np.asarray(V, dtype=np.float64)
    T = np.asarray(T)
    n = len(V)
    F = np.sort(T[:, _TET_FACES].reshape(-1, 3), axis=1)
    uniq, count = np.unique(F, axis=0, return_counts=True)
    B = uniq[count == 1]
    lay = np.asarray(layer)[B]
    B = B[(lay == lay[:, :1]).all(axis=1)]
    a = 0.5 * np.linalg.norm(np.cross(V[B[:, 1]] - V[B[:, 0]], V[B[:, 2]] - V[B[:, 0]]), axis=1)
    return np.bincount(B.ravel(), weights=np.repeat(a / 3.0, 3), minlength=n)


@dataclass(frozen=True, eq=False)
class TissueElements:
    """The elements of a tet mesh (:func:`tissue_elements`); float64 / int64 NumPy arrays."""

    vertices: np.ndarray
    """Rest positions [m], shape (n, 3), float64 (as given)."""
    tets: np.ndarray
    """Tetrahedra, shape (k, 4), int64, each with positive signed volume."""
    layer: np.ndarray
    """Layer of each vertex, shape (n,), int64: 0 outer, 1 inner."""
    edges: np.ndarray
    """Unique tet edges (i, j), i < j, shape (e, 2), int64."""
    edge_class: np.ndarray
    """EDGE_OUTER / EDGE_INNER / EDGE_CROSS of each edge, shape (e,), int64."""
    edge_rest_lengths: np.ndarray
    """Rest length D0 [m], shape (e,), float64."""
    faces: np.ndarray
    """Unique tet faces (sorted vertex triples), shape (f, 3), int64."""
    face_rest_areas: np.ndarray
    """Rest area A0 [m^2], shape (f,), float64."""
    tet_rest_volumes: np.ndarray
    """Rest signed volume V0 [m^3], shape (k,), float64."""
    tet_rest_inverse: np.ndarray
    """Inverse of the rest edge matrix D_m = [x1 - x0, x2 - x0, x3 - x0] [1/m], shape (k, 3, 3), float64."""
    tet_edge_index: np.ndarray
    """Each tet's edges (``TET_EDGES`` order) as rows of :attr:`edges`, shape (k, 6), int64."""
    tet_face_index: np.ndarray
    """Each tet's faces (``TET_FACES`` order) as rows of :attr:`faces`, shape (k, 4), int64."""
    vertex_volume: np.ndarray
    """A quarter of each incident tet's volume [m^3], shape (n,), float64."""
    edge_volume: np.ndarray
    """A sixth of each incident tet's volume [m^3], shape (e,), float64."""
    face_volume: np.ndarray
    """A quarter of each incident tet's volume [m^3], shape (f,), float64."""
    vertex_area: np.ndarray
    """Each node's share of its sheet's boundary area [m^2] (:func:`sheet_areas`), shape (n,), float64."""


def check_tet_mesh(V, T) -> tuple[np.ndarray, np.ndarray]:
    """``V`` (n, 3) finite [m] and ``T`` (k, 4) int indexing it, no repeated vertex in a tet, as
    float64 / int64 arrays; an :class:`InputError` naming the first bad vertex or tet otherwise."""
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3:
        raise InputError(f"vertices must have shape (n, 3), got {V.shape}")
    if not np.all(np.isfinite(V)):
        bad = int(np.nonzero(~np.all(np.isfinite(V), axis=1))[0][0])
        raise InputError(f"vertices must be finite, vertex {bad} is {V[bad].tolist()}")
    T = np.asarray(T)
    if T.ndim != 2 or T.shape[1] != 4:
        raise InputError(f"tets must have shape (k, 4), got {T.shape}")
    if len(T) == 0:
        raise InputError("tets is empty: the model needs at least one tetrahedron")
    if not np.issubdtype(T.dtype, np.integer):
        raise InputError(f"tets must be an integer array, got dtype {T.dtype}")
    T = T.astype(np.int64)
    n = len(V)
    if T.min() < 0 or T.max() >= n:
        bad = int(np.nonzero((T < 0).any(axis=1) | (T >= n).any(axis=1))[0][0])
        raise InputError(f"tet {bad} indexes vertices {T[bad].tolist()}, but there are {n} vertices")
    srt = np.sort(T, axis=1)
    rep = (srt[:, 1:] == srt[:, :-1]).any(axis=1)
    if rep.any():
        bad = int(np.nonzero(rep)[0][0])
        raise InputError(f"tet {bad} repeats a vertex: {T[bad].tolist()}")
    return V, T


def rest_geometry(V, T, edges, faces) -> dict:
    """Rest measures on the float32-rounded positions the kernels see (so that the rest state is an
    equilibrium up to float32 arithmetic only, and a tet valid here is not inverted in the kernels' eyes).

    Args:
        V: Rest positions [m], shape (n, 3), float. T: tets (k, 4); edges (e, 2); faces (f, 3), int.

    Returns:
        ``{"edge_rest_lengths" (e,) [m], "face_rest_areas" (f,) [m^2], "tet_rest_volumes" (k,) [m^3]
        (signed), "tet_rest_inverse" (k, 3, 3) [1/m]}``, float64.
    """
    V32 = np.asarray(V, np.float64).astype(np.float32).astype(np.float64)
    E, Fc = edges, faces
    x0, x1, x2, x3 = (V32[T[:, c]] for c in range(4))  # geometry.tets.signed_tet_volumes, the builder's own
    vol = np.einsum("ij,ij->i", x1 - x0, np.cross(x2 - x0, x3 - x0)) / 6.0
    Dm = np.stack([V32[T[:, c]] - V32[T[:, 0]] for c in (1, 2, 3)], axis=2)  # columns: rest edge vectors
    return {"edge_rest_lengths": np.linalg.norm(V32[E[:, 1]] - V32[E[:, 0]], axis=1),
            "face_rest_areas": 0.5 * np.linalg.norm(np.cross(V32[Fc[:, 1]] - V32[Fc[:, 0]],
                                                             V32[Fc[:, 2]] - V32[Fc[:, 0]]), axis=1),
            "tet_rest_volumes": vol, "tet_rest_inverse": np.linalg.inv(Dm)}


def tissue_elements(V, T, layer=None) -> TissueElements:
    """The elements of the deformation model of a tet mesh (module doc), validated.

    Args:
        V: Rest positions [m], shape (n, 3), float.
        T: Tetrahedra, shape (k, 4), int; each must have positive signed volume
            ``(1/6) (x1 - x0) . ((x2 - x0) x (x3 - x0))``.
        layer: Layer of each vertex, shape (n,) or a scalar, int: 0 outer (skin surface), 1 inner
            (default all outer); sets each edge's class.

    Returns:
        :class:`TissueElements`.

    Raises:
        InputError: bad shapes, indices out of range, a repeated vertex in a tet, an inverted or
            degenerate tet (naming its index), a layer other than 0 / 1.
    """
    V, T = check_tet_mesh(V, T)
    n = len(V)
    V32 = V.astype(np.float32).astype(np.float64)
    x0, x1, x2, x3 = (V32[T[:, c]] for c in range(4))  # as rest_geometry: the float32 positions the kernels see
    vol = np.einsum("ij,ij->i", x1 - x0, np.cross(x2 - x0, x3 - x0)) / 6.0
    scale = np.linalg.norm(V[T[:, 1:]] - V[T[:, :1]], axis=2).max(axis=1)
    tiny = 1e-6 * scale**3  # a regular tet has 0.118 scale^3
    inv = vol <= tiny
    if inv.any():
        bad = int(np.nonzero(inv)[0][0])
        what = "inverted" if vol[bad] < -tiny[bad] else "degenerate (zero volume)"
        raise InputError(
            f"tet {bad} {T[bad].tolist()} is {what}: signed volume {vol[bad]:.3g} m^3; "
            "expected (1/6) (x1-x0).((x2-x0)x(x3-x0)) > 0 (swap two indices to flip it)"
        )
    if layer is None:
        layer = np.zeros(n, np.int64)
    else:
        layer = np.asarray(layer)
        if layer.ndim == 0:
            layer = np.full(n, layer)
        if layer.shape != (n,):
            raise InputError(f"layer must have shape ({n},) (one value per vertex), got {layer.shape}")
        layer = layer.astype(np.int64)
    if not np.isin(layer, (0, 1)).all():
        raise InputError(f"layer must be 0 (outer) or 1 (inner), got values {np.unique(layer).tolist()}")
    # unique edges (i < j) with their class; each tet's edges and faces map to the unique ones
    # (inverse) for the volume shares
    E_all = np.sort(T[:, _TET_EDGES].reshape(-1, 2), axis=1)
    E, e_inv = np.unique(E_all, axis=0, return_inverse=True)
    la, lb = layer[E[:, 0]], layer[E[:, 1]]
    edge_class = np.where(la != lb, EDGE_CROSS, np.where(la == 0, EDGE_OUTER, EDGE_INNER))
    # unique faces (sorted vertex triples: the area energy ignores the winding)
    F_all = np.sort(T[:, _TET_FACES].reshape(-1, 3), axis=1)
    Fc, f_inv = np.unique(F_all, axis=0, return_inverse=True)
    geo = rest_geometry(V, T, E, Fc)
    # volume shares: a node a quarter of each tet, an edge a sixth, a face a quarter
    return TissueElements(
        vertices=V, tets=T, layer=layer, edges=E, edge_class=edge_class, faces=Fc,
        tet_edge_index=e_inv.reshape(len(T), 6), tet_face_index=f_inv.reshape(len(T), 4),
        vertex_volume=np.bincount(T.ravel(), weights=np.repeat(vol / 4.0, 4), minlength=n),
        edge_volume=np.bincount(e_inv.ravel(), weights=np.repeat(vol / 6.0, 6), minlength=len(E)),
        face_volume=np.bincount(f_inv.ravel(), weights=np.repeat(vol / 4.0, 4), minlength=len(Fc)),
        vertex_area=sheet_areas(V32, T, layer), **geo)
