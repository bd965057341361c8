"""Surface guards of the adaptation: folds and squeezed triangles.

Not steps of the thesis: an RBF fitted to dense FP pairs can fold the template where pairs
cross (a face normal turned more than 75 degrees, a crease sharper than 80 degrees that the
template did not have), and closed lips can squeeze the mouth corner's triangles flat. Both
would make inverted or flat tets in the skin layer (Sec. 6.2) and set the solver's step
(Sec. 6.4.4). :func:`unfold` steps folded vertices back toward a safe shape;
:func:`relax_squeezed` relaxes squeezed triangles tangentially on the scan.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FoldCheck", "TRI_QUALITY_FLOOR", "relax_squeezed", "tri_quality", "unfold"]


class FoldCheck:
    """Folds of a deformed template: faces turned by more than 75 degrees from their template
    normal, and pairs of neighbouring faces whose normals turned more than 100 degrees apart
    (a crease sharper than 80 degrees) where the template had none. Such creases leave no
    inward direction from which a skin layer can be extruded (Sec. 6.2)."""

    TURN_COS = 0.26  # cos 75 deg
    CREASE_COS = -0.17  # cos 100 deg

    def __init__(self, V0: np.ndarray, F: np.ndarray):
        self.F = F
        self.V0 = V0
        self.n0 = self._normals(V0)
        E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        fid = np.tile(np.arange(len(F)), 3)
        key = np.sort(E, axis=1)
        order = np.lexsort((key[:, 1], key[:, 0]))
        ks, fs = key[order], fid[order]
        same = np.all(ks[1:] == ks[:-1], axis=1)
        self.pairs = np.stack([fs[:-1][same], fs[1:][same]], 1)
        self.dot0 = np.einsum("kd,kd->k", self.n0[self.pairs[:, 0]], self.n0[self.pairs[:, 1]])

    def _normals(self, V):
        n = np.cross(V[self.F[:, 1]] - V[self.F[:, 0]], V[self.F[:, 2]] - V[self.F[:, 0]])
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    def __call__(self, V: np.ndarray) -> np.ndarray:
        n = self._normals(V)
        bad = np.einsum("kd,kd->k", n, self.n0) <= self.TURN_COS
        d = np.einsum("kd,kd->k", n[self.pairs[:, 0]], n[self.pairs[:, 1]])
        crease = (d < self.CREASE_COS) & (self.dot0 >= self.CREASE_COS)
        bad[self.pairs[crease].ravel()] = True
        return bad


def unfold(V: np.ndarray, V_safe: np.ndarray, F: np.ndarray, folds: FoldCheck, allowed: np.ndarray, *, rounds: int = 20) -> np.ndarray:
    """Move the vertices of newly folded faces back toward ``V_safe`` (halving their step each
    round) until no face folds that did not fold in ``V_safe``; returns the repaired vertices."""
    V = V.copy()
    for _ in range(rounds):
        bad = folds(V) & ~allowed
        if not bad.any():
            break
        idx = np.unique(F[bad])
        V[idx] = 0.5 * (V[idx] + V_safe[idx])
    bad = folds(V) & ~allowed
    if bad.any():
        idx = np.unique(F[bad])
        V[idx] = V_safe[idx]
    return V


TRI_QUALITY_FLOOR = 0.3
"""A triangle whose quality ``4 sqrt(3) area / sum(edge^2)`` (1 equilateral, 0 flat) is below this
and below half its template quality is *squeezed* (e.g. a 150-degree cap, or a 10-degree needle)."""


def tri_quality(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    return tri_quality_points(V[F])


def relax_squeezed(V, F, scan_q, folds: FoldCheck, allowed, reject, *, rounds: int = 60):
    """Tangential relaxation of squeezed triangles (see :data:`TRI_QUALITY_FLOOR`), on the scan.

    Where the adapted surface squeezed triangles flat (closed lips pressing the template's mouth
    corner, a crease of the nostril), their vertices and those vertices' neighbours step halfway
    to their neighbours' mean in the tangent plane and are put back on the scan (closest point).
    A step is kept only if it raises the smallest quality of the vertex's triangles, and a
    round's steps are undone on any triangle they made worse than both its old quality and the
    floor, so the relaxation never trades one flat triangle for another. A flat triangle makes a
    flat tet in the skin layer (Sec. 6.2), and a flat tet sets the solver's step (Sec. 6.4.4).
    """
    import scipy.sparse as sp

    q0 = tri_quality(folds.V0, F)
    target = np.minimum(TRI_QUALITY_FLOOR, 0.5 * q0)
    q = tri_quality(V, F)
    if not (q < target).any():
        return V
    n, m = len(V), len(F)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    E = np.concatenate([E, E[:, ::-1]])
    adj = sp.csr_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n))
    deg = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1)  # an interior edge counts twice
    vf = sp.csr_matrix((np.ones(3 * m), (F.ravel(), np.repeat(np.arange(m), 3))), shape=(n, m))
    W = V.copy()
    for _ in range(rounds):
        bad = q < target
        if not bad.any():
            break
        act = np.zeros(n, bool)
        act[F[bad].ravel()] = True
        act[adj[np.flatnonzero(act)].indices] = True  # and their one-ring
        idx = np.flatnonzero(act)
        fl = np.unique(vf[idx].indices)  # every face around an active vertex
        Fl = F[fl]
        mean = (adj[idx] @ W) / deg[idx][:, None]
        fn = np.cross(W[Fl[:, 1]] - W[Fl[:, 0]], W[Fl[:, 2]] - W[Fl[:, 0]])  # area-weighted face normals
        N = np.zeros((n, 3))
        for d in range(3):
            N[:, d] = np.bincount(Fl.ravel(), weights=np.repeat(fn[:, d], 3), minlength=n)
        N = N[idx] / np.maximum(np.linalg.norm(N[idx], axis=1, keepdims=True), 1e-300)
        step = mean - W[idx]
        step -= np.einsum("kd,kd->k", step, N)[:, None] * N  # stay in the tangent plane
        C = W.copy()
        C[idx] += 0.5 * step
        cp = scan_q.closest_point(C[idx], reject)
        ok = cp.face >= 0
        C[idx[ok]] = cp.points[ok]
        # keep a vertex's step if, with its neighbours where they were, its worst triangle improves
        ql = q[fl]
        old_min = np.full(n, np.inf)
        np.minimum.at(old_min, Fl.ravel(), np.repeat(ql, 3))
        new_min = np.full(n, np.inf)
        PW = W[Fl]
        for k in range(3):  # move one corner at a time
            P = PW.copy()
            P[:, k] = C[Fl[:, k]]
            np.minimum.at(new_min, Fl[:, k], tri_quality_points(P))
        keep = act & (new_min > old_min)
        if not keep.any():
            break
        Wn = W.copy()
        Wn[keep] = C[keep]
        qn = tri_quality(Wn, Fl)
        worse = (qn < ql) & (qn < target[fl])
        Wn[Fl[worse].ravel()] = W[Fl[worse].ravel()]
        if np.array_equal(Wn, W):
            break
        W = Wn
        q[fl] = tri_quality(W, Fl)
    return unfold(W, V, F, folds, allowed)


def tri_quality_points(P: np.ndarray) -> np.ndarray:
    e2 = (np.linalg.norm(P - np.roll(P, 1, axis=1), axis=2) ** 2).sum(1)
    A = 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
    return 4.0 * np.sqrt(3.0) * A / np.maximum(e2, 1e-300)
