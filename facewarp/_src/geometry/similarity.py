"""Similarity transforms (uniform scale, rotation, translation) and their least-squares fit
(Umeyama 1991), used by the FDP calibration (Eq. 4.3.2-4.3.4) and to place rigid parts."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.errors import InputError

__all__ = ["Similarity", "fit_similarity", "point_spread"]


@dataclass
class Similarity:
    """``x -> scale * rotation @ x + translation`` (Eq. 4.3.3 with ``t = p_c - s R q_c``).

    Attributes:
        scale: Uniform scale s (dimensionless; includes any unit change), > 0.
        rotation: Proper rotation R, shape (3, 3), float64.
        translation: Translation t [output units], shape (3,), float64.
    """

    scale: float = 1.0
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        self.scale = float(self.scale)
        self.rotation = np.asarray(self.rotation, dtype=np.float64).reshape(3, 3)
        self.translation = np.asarray(self.translation, dtype=np.float64).reshape(3)

    def apply(self, X) -> np.ndarray:
        """Transform points X, shape (k, 3) or (3,); returns the same shape, float64."""
        X = np.asarray(X, dtype=np.float64)
        return self.scale * X @ self.rotation.T + self.translation

    def apply_vectors(self, D) -> np.ndarray:
        """Transform displacement vectors (no translation), shape (k, 3) or (3,)."""
        return self.scale * np.asarray(D, dtype=np.float64) @ self.rotation.T

    def inverse(self) -> Similarity:
        """The inverse map ``y -> R^T (y - t) / s``."""
        Rt = self.rotation.T
        return Similarity(1.0 / self.scale, Rt, -(Rt @ self.translation) / self.scale)

    def compose(self, other: Similarity) -> Similarity:
        """``self o other``: apply ``other`` first, then ``self``."""
        return Similarity(
            self.scale * other.scale,
            self.rotation @ other.rotation,
            self.scale * self.rotation @ other.translation + self.translation,
        )

    def matrix(self) -> np.ndarray:
        """Homogeneous 4x4 matrix, float64."""
        M = np.eye(4)
        M[:3, :3] = self.scale * self.rotation
        M[:3, 3] = self.translation
        return M

    def to_dict(self) -> dict:
        """JSON-ready dict: scale, rotation (3x3 rows), translation."""
        return {"scale": self.scale, "rotation": self.rotation.tolist(), "translation": self.translation.tolist()}


def point_spread(P: np.ndarray) -> np.ndarray:
    """The spread of a point set about its centroid: the singular values of the centred points,
    largest first, shape (3,) for P of shape (k, 3) [the points' unit]. A small last value means the
    points are nearly coplanar (the calibration's check), a small second one nearly collinear."""
    return np.linalg.svd(P - P.mean(axis=0), compute_uv=False)


def fit_similarity(src, dst, *, with_scale: bool = True, weights=None) -> Similarity:
    """Least-squares similarity taking ``src`` onto ``dst`` (Umeyama 1991; Eq. 4.3.3).

    Minimises ``sum_i w_i ||s R src_i + t - dst_i||^2`` over s > 0, proper rotations R and t.

    Args:
        src: Source points, shape (k, 3), float64; k >= 3 and not collinear.
        dst: Target points, shape (k, 3), float64.
        with_scale: Fit s; else s = 1 (rigid).
        weights: Optional non-negative weights, shape (k,).

    Returns:
        The :class:`Similarity`.
    """
    from ..core.checks import check_array

    check_array("src", src, shape=(None, 3))
    check_array("dst", dst, shape=(None, 3))
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape:
        raise InputError(f"src and dst must have the same shape (k, 3), got {src.shape} and {dst.shape}")
    if len(src) < 3:
        raise InputError(f"fit_similarity: need at least 3 point pairs, got {len(src)}")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    w = w / w.sum()
    mu_s = w @ src
    mu_d = w @ dst
    A = src - mu_s
    B = dst - mu_d
    cov = (B * w[:, None]).T @ A  # (3, 3): sum w b a^T
    U, S, Vt = np.linalg.svd(cov)
    D = np.ones(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2] = -1.0
    R = U @ np.diag(D) @ Vt
    if with_scale:
        var_s = float((w * np.einsum("kd,kd->k", A, A)).sum())
        s = float((S * D).sum() / var_s) if var_s > 0 else 1.0
    else:
        s = 1.0
    t = mu_d - s * R @ mu_s
    return Similarity(s, R, t)
