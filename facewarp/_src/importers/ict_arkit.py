"""The ARKit blendshapes of the ICT-FaceKit rig, carried onto a facewarp head.

The public ICT-FaceKit rig (MIT, github ICT-VGL/ICT-FaceKit, folder ``FaceXModel``) has one OBJ
per ARKit-named expression on its neutral topology (``browDown_L.obj``, ``jawOpen.obj``, ...;
ICT splits ``browInnerUp`` and ``cheekPuff`` into a left and a right half and has no
``tongueOut``). A shape's displacement is its OBJ minus ``generic_neutral_mesh.obj``, on the
skin vertices 0-11247, centimetres -> metres (:func:`load_ict_displacements`).

The data is not part of facewarp: :func:`ict_shape_dirs` lists where it is looked for (an
argument, ``$FACEWARP_ICT_SHAPES``, ``~/.cache/facewarp/ict``, then the shared data folder
``$FACEWARP_SHARED/data/ict-facekit``, which holds five of the shapes); a shape found nowhere is
simply absent from the result.

Transfer onto a head (:func:`transfer_ict_displacements`): the ICT neutral skin is warped onto the
head by the FDPs both know (the 12 of :data:`~facewarp.ICT_FDP_VERTICES`, the inner lip contour
2.4-2.9 of :data:`~facewarp.ICT_INNER_LIP_VERTICES` and the lid margins 3.1-3.4): a least-squares
similarity, then a thin-plate spline through the remaining FDP residuals. Each head point takes the
closest point of the warped ICT neutral skin, and its displacement is the difference of the warped
expression and the warped neutral there, ``W(x + d) - W(x)``: so the displacement is scaled and
turned with the head's own local proportions (a wider mouth smiles wider), not copied in ICT's
centimetres. Head points farther than ``max_dist`` from the warped ICT skin get no displacement.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError

__all__ = ["ICT_ARKIT_SHAPES", "IctWarp", "ict_shape_dirs", "load_ict_displacements", "transfer_ict_displacements"]

ICT_ARKIT_SHAPES: dict[str, tuple[str, ...]] = {
    "eyeBlinkLeft": ("eyeBlink_L",), "eyeLookDownLeft": ("eyeLookDown_L",), "eyeLookInLeft": ("eyeLookIn_L",),
    "eyeLookOutLeft": ("eyeLookOut_L",), "eyeLookUpLeft": ("eyeLookUp_L",), "eyeSquintLeft": ("eyeSquint_L",),
    "eyeWideLeft": ("eyeWide_L",), "eyeBlinkRight": ("eyeBlink_R",), "eyeLookDownRight": ("eyeLookDown_R",),
    "eyeLookInRight": ("eyeLookIn_R",), "eyeLookOutRight": ("eyeLookOut_R",), "eyeLookUpRight": ("eyeLookUp_R",),
    "eyeSquintRight": ("eyeSquint_R",), "eyeWideRight": ("eyeWide_R",), "jawForward": ("jawForward",),
    "jawLeft": ("jawLeft",), "jawRight": ("jawRight",), "jawOpen": ("jawOpen",), "mouthClose": ("mouthClose",),
    "mouthFunnel": ("mouthFunnel",), "mouthPucker": ("mouthPucker",), "mouthLeft": ("mouthLeft",),
    "mouthRight": ("mouthRight",), "mouthSmileLeft": ("mouthSmile_L",), "mouthSmileRight": ("mouthSmile_R",),
    "mouthFrownLeft": ("mouthFrown_L",), "mouthFrownRight": ("mouthFrown_R",), "mouthDimpleLeft": ("mouthDimple_L",),
    "mouthDimpleRight": ("mouthDimple_R",), "mouthStretchLeft": ("mouthStretch_L",),
    "mouthStretchRight": ("mouthStretch_R",), "mouthRollLower": ("mouthRollLower",),
    "mouthRollUpper": ("mouthRollUpper",), "mouthShrugLower": ("mouthShrugLower",),
    "mouthShrugUpper": ("mouthShrugUpper",), "mouthPressLeft": ("mouthPress_L",), "mouthPressRight": ("mouthPress_R",),
    "mouthLowerDownLeft": ("mouthLowerDown_L",), "mouthLowerDownRight": ("mouthLowerDown_R",),
    "mouthUpperUpLeft": ("mouthUpperUp_L",), "mouthUpperUpRight": ("mouthUpperUp_R",),
    "browDownLeft": ("browDown_L",), "browDownRight": ("browDown_R",),
    "browInnerUp": ("browInnerUp_L", "browInnerUp_R"), "browOuterUpLeft": ("browOuterUp_L",),
    "browOuterUpRight": ("browOuterUp_R",), "cheekPuff": ("cheekPuff_L", "cheekPuff_R"),
    "cheekSquintLeft": ("cheekSquint_L",), "cheekSquintRight": ("cheekSquint_R",),
    "noseSneerLeft": ("noseSneer_L",), "noseSneerRight": ("noseSneer_R",), "tongueOut": (),
}  # fmt: skip
"""ARKit name -> the ICT-FaceKit expression OBJs (stems) whose displacements add up to it. ARKit's
Left is the subject's left, ICT's ``_L`` (both at +x). ``tongueOut``: ICT has no such shape."""

_ICT_NEUTRAL = "generic_neutral_mesh.obj"
_ICT_SKIN = 11248  # vertices 0..11247: face, head and neck
MM = 1e-3


def ict_shape_dirs(ict_dir: str | os.PathLike | None = None) -> list[Path]:
    """The folders searched for ICT-FaceKit expression OBJs, first match wins: ``ict_dir`` (when
    given), ``$FACEWARP_ICT_SHAPES``, ``~/.cache/facewarp/ict``, ``$FACEWARP_SHARED/data/ict-facekit``.
    Only folders that hold ``generic_neutral_mesh.obj`` are listed."""
    cands = []
    if ict_dir is not None:
        d = Path(ict_dir)
        if not (d / _ICT_NEUTRAL).is_file():
            raise InputError(f"ict_dir: {d} holds no ICT-FaceKit {_ICT_NEUTRAL}")
        cands.append(d)
    if os.environ.get("FACEWARP_ICT_SHAPES"):
        cands.append(Path(os.environ["FACEWARP_ICT_SHAPES"]))
    cands.append(Path.home() / ".cache" / "facewarp" / "ict")
    if os.environ.get("FACEWARP_SHARED"):
        cands.append(Path(os.environ["FACEWARP_SHARED"]) / "data" / "ict-facekit")
    out = []
    for d in cands:
        if (d / _ICT_NEUTRAL).is_file() and d not in out:
            out.append(d)
    return out


_SKIN_MEMO: dict = {}


def _load_skin(path: Path) -> np.ndarray:
    """The skin vertices [m] (11248, 3) of one ICT OBJ (memoised per path, size and mtime)."""
    from ..geometry.mesh import load_mesh

    st = path.stat()
    memo = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if memo in _SKIN_MEMO:
        return _SKIN_MEMO[memo]
    V = load_mesh(path, units="cm").vertices
    if len(V) < _ICT_SKIN:
        raise InputError(f"{path}: {len(V)} vertices, expected the ICT-FaceKit topology (26719 vertices)")
    V = np.asarray(V[:_ICT_SKIN], np.float64)
    V.setflags(write=False)
    if len(_SKIN_MEMO) > 128:
        _SKIN_MEMO.clear()
    _SKIN_MEMO[memo] = V
    return V


def load_ict_displacements(names=None, ict_dir: str | os.PathLike | None = None) -> dict[str, np.ndarray]:
    """The ICT-FaceKit displacements of ARKit shapes that can be found (:func:`ict_shape_dirs`).

    Args:
        names: ARKit names (default all of :data:`ICT_ARKIT_SHAPES`).
        ict_dir: A folder searched first.

    Returns:
        ARKit name -> displacement [m], shape (11248, 3), float64, on the ICT skin vertices, for
        every shape whose OBJs were all found in one folder (``tongueOut`` never is).

    Raises:
        InputError: An unknown name, or an OBJ without the ICT topology.
    """
    names = list(ICT_ARKIT_SHAPES) if names is None else [str(n) for n in names]
    for n in names:
        if n not in ICT_ARKIT_SHAPES:
            raise InputError(f"names: {n!r} is not an ARKit blendshape name")
    out: dict[str, np.ndarray] = {}
    neutral: dict[Path, np.ndarray] = {}
    for n in names:
        stems = ICT_ARKIT_SHAPES[n]
        if not stems:
            continue
        for d in ict_shape_dirs(ict_dir):
            if all((d / f"{s}.obj").is_file() for s in stems):
                if d not in neutral:
                    neutral[d] = _load_skin(d / _ICT_NEUTRAL)
                out[n] = sum(_load_skin(d / f"{s}.obj") - neutral[d] for s in stems)
                break
    return out


@dataclass
class IctWarp:
    """The ICT neutral skin warped onto a head (see the module docstring).

    Attributes:
        similarity: ICT -> head least-squares similarity on the shared FDPs.
        centers: Thin-plate spline centres: the shared FDPs after the similarity [m], (k, 3), float64.
        coef: Spline coefficients (k, 3) and the affine part (4, 3) stacked, (k + 4, 3), float64.
        fdps: The FDP ids used, length k.
        residual_m: Distance of each warped ICT FDP to the head's FDP [m], (k,) (~0: the spline interpolates).
    """

    similarity: object
    centers: np.ndarray
    coef: np.ndarray
    fdps: list
    residual_m: np.ndarray

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """Warp ICT points X [m] (n, 3) float64 -> head frame [m] (n, 3) float64."""
        Y = self.similarity.apply(np.asarray(X, np.float64))
        k = len(self.centers)
        r = np.linalg.norm(Y[:, None, :] - self.centers[None], axis=2)  # 3-D biharmonic kernel: |r|
        return Y + r @ self.coef[:k] + np.c_[np.ones(len(Y)), Y] @ self.coef[k:]


def _fit_warp(src: dict, dst: dict, smoothing: float = 0.0) -> IctWarp:
    from ..geometry.similarity import fit_similarity

    ids = [k for k in src if k in dst]
    if len(ids) < 6:
        raise InputError(f"head: only {len(ids)} of the FDPs shared with ICT-FaceKit were found (need >= 6)")
    S = np.array([src[k] for k in ids], np.float64)
    D = np.array([dst[k] for k in ids], np.float64)
    sim = fit_similarity(S, D)
    C = sim.apply(S)
    k = len(ids)
    K = np.linalg.norm(C[:, None] - C[None], axis=2) + smoothing * np.eye(k)
    P = np.c_[np.ones(k), C]
    A = np.zeros((k + 4, k + 4))
    A[:k, :k], A[:k, k:], A[k:, :k] = K, P, P.T
    b = np.zeros((k + 4, 3))
    b[:k] = D - C
    coef = np.linalg.lstsq(A, b, rcond=None)[0]
    w = IctWarp(sim, C, coef, ids, np.zeros(k))
    w.residual_m = np.linalg.norm(w(S) - D, axis=1)
    return w


def ict_landmarks(ict_dir: str | os.PathLike | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """The ICT neutral skin (V (11248, 3) [m] float64, F (m, 3) int64) and its FDPs known exactly
    (FDP id -> position [m] (3,)): the 12 of ICT_FDP_VERTICES, inner lips 2.4-2.9, lid margins 3.1-3.4."""
    from ..template.likeness import ICT_FDP_VERTICES
    from .ict import ICT_INNER_LIP_VERTICES, ICT_PART_RANGES, _lid_margin_vertices, _load_ict, _sub_mesh

    dirs = ict_shape_dirs(ict_dir)
    if not dirs:
        raise InputError("ICT-FaceKit: generic_neutral_mesh.obj found in none of the searched folders "
                         "(pass ict_dir, or set FACEWARP_ICT_SHAPES or FACEWARP_SHARED)")
    V_all, F_all = _load_ict(dirs[0])
    V, F = _sub_mesh(V_all, F_all, 0, _ICT_SKIN)
    parts = {p: _sub_mesh(V_all, F_all, *ICT_PART_RANGES[p]) for p in ("eye_L", "eye_R")}
    idx = {**ICT_FDP_VERTICES, **ICT_INNER_LIP_VERTICES, **_lid_margin_vertices(V, F, parts)}
    return V, F, {k: V[i].copy() for k, i in idx.items()}


def transfer_ict_displacements(displacements: dict, head_vertices: np.ndarray, head_landmarks: dict, *,
                               point_ids=None, ict_dir: str | os.PathLike | None = None, max_dist: float = 0.01,
                               device: str = "cpu", report: dict | None = None) -> dict[str, np.ndarray]:
    """Carry ICT skin displacements onto a head's points (see the module docstring).

    Args:
        displacements: name -> displacement on the ICT skin [m], (11248, 3) float64
            (:func:`load_ict_displacements`).
        head_vertices: The head points to carry them to [m], (n, 3) float64, head frame (y up, +z front).
        head_landmarks: FDP id -> the head's FDP position [m] (3,), same frame (at least six of
            2.1, 2.2, 2.3, 2.4-2.9, 3.1-3.4, 3.7, 3.8, 3.11, 3.12, 8.1-8.4, 9.3).
        point_ids: Optional name of each head point (length n, e.g. FDP ids): a point named as one
            of the FDPs known exactly on ICT takes that ICT vertex's displacement (warped) instead
            of the closest point's (the lid margins: ICT's skin curls into the eye socket there).
        ict_dir: Folder searched first for the ICT neutral mesh.
        max_dist: Points farther than this from the warped ICT skin [m] get a zero displacement.
        device: Warp device of the closest-point query.
        report: Optional dict filled with the warp's FDP residuals [m], the points beyond
            ``max_dist`` and the distance statistics.

    Returns:
        name -> displacement [m], (n, 3) float64, at ``head_vertices``.
    """
    from ..core.checks import check_array
    from ..geometry.surface import closest_point

    P = check_array("head_vertices", head_vertices, shape=(None, 3)).astype(np.float64)
    if not isinstance(displacements, dict):
        raise InputError(f"displacements: expected a dict name -> (11248, 3) array, got {type(displacements).__name__}")
    for n, D in displacements.items():
        check_array(f"displacements[{n!r}]", D, shape=(_ICT_SKIN, 3))
    V, F, lm = ict_landmarks(ict_dir)
    dst = {str(k): np.asarray(v, np.float64) for k, v in dict(head_landmarks).items()}
    warp = _fit_warp(lm, dst)
    WV = warp(V)
    cp = closest_point(WV, F, P, device=device)
    far = ~(cp.dist <= max_dist)
    face = np.where(far, 0, cp.face)
    bary = np.array(cp.bary, np.float64)
    if point_ids is not None:
        point_ids = [str(i) for i in point_ids]
        if len(point_ids) != len(P):
            raise InputError(f"point_ids: {len(point_ids)} names for {len(P)} head points")
        vid = {k: int(np.argmin(np.linalg.norm(V - p, axis=1))) for k, p in lm.items()}
        for j, k in enumerate(point_ids):
            if k in vid:  # the ICT vertex of this FDP: a face holding it, one-hot weights
                r, c = np.nonzero(F == vid[k])
                face[j], bary[j], far[j] = r[0], np.eye(3)[c[0]], False
    out = {}
    for n, D in displacements.items():
        WD = warp(V + np.asarray(D, np.float64)) - WV
        d = np.einsum("kc,kcd->kd", bary, WD[F[face]])
        d[far] = 0.0
        out[n] = d
    if report is not None:
        report.update({"fdps": warp.fdps, "warp_fdp_residual_m": warp.residual_m.tolist(),
                       "similarity_scale": float(warp.similarity.scale), "beyond_max_dist": int(far.sum()),
                       "distance_m": {"median": float(np.median(cp.dist)), "max": float(np.max(cp.dist))}})
    return out


def displacements_digest(displacements: dict) -> str:
    """A short hash of named displacement arrays (for cache keys)."""
    h = hashlib.sha256()
    for n in sorted(displacements):
        h.update(n.encode())
        h.update(np.ascontiguousarray(displacements[n], np.float64).tobytes())
    return h.hexdigest()[:16]
