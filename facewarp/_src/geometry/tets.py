"""Tetrahedron primitives shared by the anatomy and the physics (one helper each)."""

from __future__ import annotations

import numpy as np

__all__ = ["signed_tet_volumes", "tet_heights"]


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
