"""The ARKit blendshapes of the ICT-FaceKit rig, carried onto a facewarp head.

The public ICT-FaceKit rig (MIT, github ICT-VGL/ICT-FaceKit, folder ``FaceXModel``) has one OBJ
per ARKit-named expression on its neutral topology (``browDown_L.obj``, ``jawOpen.obj``, ...;
ICT splits ``browInnerUp`` and ``cheekPuff`` into a left and a right half and has no
``tongueOut``). A shape's displacement is its OBJ minus ``generic_neutral_mesh.obj``, on the
skin vertices 0-11247, centimetres -> metres (:func:`load_ict_displacements`).

The OBJs are not part of facewarp: :func:`ict_shape_dirs` lists where they are looked for (an
argument, ``$FACEWARP_ICT_SHAPES``, ``~/.cache/facewarp/ict``, then the shared data folder
``$FACEWARP_SHARED/data/ict-facekit``, which holds five of the shapes); a shape found nowhere is
simply absent from the result.

What facewarp ships instead (:func:`load_arkit_basis`, ``data/arkit_basis.npz`` beside this module,
MIT notice in ``data/ICT-FaceKit-LICENSE.txt``): the 51 ICT-FaceKit expressions carried onto the
default template's skin (level :data:`BASIS_LEVEL`) by the transfer below, on every skin vertex and
at the template's head FDPs, quantized to :data:`BASIS_STEP_M`. :func:`make_arkit_basis` regenerates
it from a folder of the kit's ``FaceXModel`` OBJs. A head is then reached from the template by the
same kind of warp (:func:`transfer_basis_displacements`: the template's head FDPs onto the head's).

Transfer onto a head (:func:`transfer_ict_displacements`): the ICT neutral skin is warped onto the
head by the FDPs both know (the 12 of :data:`~facewarp.heads.ICT_FDP_VERTICES`, the inner lip contour
2.4-2.9 of :data:`~facewarp.heads.ICT_INNER_LIP_VERTICES` and the lid margins 3.1-3.4): a least-squares
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

__all__ = ["ARKIT_BASIS_FILE", "ArkitBasis", "BASIS_LEVEL", "BASIS_STEP_M", "ICT_ARKIT_SHAPES", "IctWarp",
           "ict_shape_dirs", "load_arkit_basis", "load_ict_displacements", "make_arkit_basis",
           "transfer_basis_displacements", "transfer_ict_displacements"]

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


# ---------------------------------------------------------------------- the shipped basis
ARKIT_BASIS_FILE = Path(__file__).resolve().parent / "data" / "arkit_basis.npz"
"""The shipped ICT-FaceKit expressions on the default template (:func:`load_arkit_basis`)."""
BASIS_LEVEL = 1
"""Template level whose skin carries the shipped displacements (13,569 vertices)."""
BASIS_STEP_M = 2e-6
"""Quantization step of the shipped displacements [m] (int16: up to +-65 mm)."""
_BASIS_VERSION = 1


@dataclass
class ArkitBasis:
    """The ICT-FaceKit ARKit expressions on the default template (see the module docstring).

    Attributes:
        names: The ARKit names that have data (51: all but ``tongueOut``).
        vertices: The template skin at rest [m], (n, 3), float64, head frame (y up, +z front).
        faces: Its triangles, (m, 3), int64.
        skin: name -> displacement of every skin vertex [m], (n, 3), float64.
        fdp_ids: The template's head FDP ids, length k.
        fdp_points: Their rest positions [m], (k, 3), float64.
        fdp: name -> displacement of each of those FDPs [m], (k, 3), float64.
        source: Where the data came from (the kit's commit, the transfer), for reports.
        digest: A hash of the file's arrays (for cache keys).
    """

    names: tuple
    vertices: np.ndarray
    faces: np.ndarray
    skin: dict
    fdp_ids: list
    fdp_points: np.ndarray
    fdp: dict
    source: str
    digest: str
    file: Path | None = None
    step_m: float = BASIS_STEP_M
    level: int = BASIS_LEVEL

    @property
    def licence_file(self) -> Path | None:
        """The ICT-FaceKit licence notice shipped beside the file (None for a basis not in the package)."""
        p = None if self.file is None else self.file.parent / "ICT-FaceKit-LICENSE.txt"
        return p if p is not None and p.is_file() else None

    def transfer(self, head_vertices, head_landmarks, **kw) -> dict:
        """:func:`transfer_basis_displacements` of this basis (its keywords: ``names``, ``point_ids``,
        ``max_dist``, ``device``, ``report``)."""
        return transfer_basis_displacements(self, head_vertices, head_landmarks, **kw)

    @staticmethod
    def make(ict_dir, path=None, **kw) -> Path:
        """:func:`make_arkit_basis`: regenerate the file from the kit's OBJs (keywords ``level``, ``source``)."""
        return make_arkit_basis(ict_dir, path, **kw)


def _template_head_fdps(t) -> tuple[list, np.ndarray]:
    """The head-part FDP ids of a template and their positions [m] (k, 3) on its skin."""
    V, F = np.asarray(t.vertices, np.float64), np.asarray(t.faces)
    ids, pts = [], []
    for k, (part, sp) in t.fdp.items():
        if str(part) == "head":
            ids.append(str(k))
            pts.append(np.einsum("c,cd->d", np.asarray(sp.bary, np.float64)[0], V[F[int(np.asarray(sp.face)[0])]]))
    return ids, np.array(pts)


def make_arkit_basis(ict_dir, path=None, *, level: int = BASIS_LEVEL, source: str = "") -> Path:
    """Regenerate the shipped basis from the ICT-FaceKit OBJs (our transfer of their data).

    Args:
        ict_dir: A folder with the kit's ``generic_neutral_mesh.obj`` and all 51 ARKit-named
            expression OBJs (its ``FaceXModel``).
        path: Output ``.npz`` (default :data:`ARKIT_BASIS_FILE`).
        level: Template level of the skin the displacements are given on.
        source: A note on the data's origin (e.g. the kit's commit), stored in the file.

    Returns:
        The path written.

    Raises:
        InputError: a folder without the whole rig.
    """
    from ..template.head import default_template

    D = load_ict_displacements(None, ict_dir=ict_dir)
    missing = [n for n, stems in ICT_ARKIT_SHAPES.items() if stems and n not in D]
    if missing:
        raise InputError(f"ict_dir: {ict_dir} lacks {len(missing)} ARKit shapes ({', '.join(missing[:4])}, ...)")
    t = default_template(level)
    V, F = np.asarray(t.vertices, np.float64), np.asarray(t.faces, np.int64)
    ids, P = _template_head_fdps(t)
    lm = dict(zip(ids, P))
    names = [n for n in ICT_ARKIT_SHAPES if n in D]
    skin = transfer_ict_displacements(D, V, lm, ict_dir=ict_dir)
    fdp = transfer_ict_displacements(D, P, lm, point_ids=ids, ict_dir=ict_dir)
    q = lambda X: np.round(np.asarray(X) / BASIS_STEP_M).astype(np.int16)  # noqa: E731
    big = max(float(np.abs(skin[n]).max()) for n in names)
    if big >= 32767 * BASIS_STEP_M:
        raise InputError(f"ict_dir: a displacement of {big * 1e3:.1f} mm exceeds the basis' int16 range")
    path = Path(ARKIT_BASIS_FILE if path is None else path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, version=np.array(_BASIS_VERSION), names=np.array(names), level=np.array(level),
                        vertices=V.astype(np.float32), faces=F.astype(np.int32),
                        skin=np.stack([q(skin[n]) for n in names]), fdp_ids=np.array(ids),
                        fdp_points=P.astype(np.float64), fdp=np.stack([q(fdp[n]) for n in names]),
                        step_m=np.array(BASIS_STEP_M),
                        source=np.array(source or "ICT-FaceKit FaceXModel (MIT, USC Institute for Creative "
                                        "Technologies), carried onto the facewarp default template"))
    return path


_BASIS_MEMO: dict = {}


def load_arkit_basis(path=None) -> ArkitBasis:
    """The shipped basis (default :data:`ARKIT_BASIS_FILE`), or one written by :func:`make_arkit_basis`.

    Raises:
        InputError: a missing or damaged file.
    """
    path = Path(ARKIT_BASIS_FILE if path is None else path)
    if not path.is_file():
        raise InputError(f"{path}: the ARKit basis is missing (reinstall facewarp, or regenerate it with "
                         "facewarp._src.importers.ict_arkit.make_arkit_basis)")
    st = path.stat()
    memo = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if memo in _BASIS_MEMO:
        return _BASIS_MEMO[memo]
    try:
        with np.load(path, allow_pickle=False) as z:
            if int(z["version"]) != _BASIS_VERSION:
                raise InputError(f"{path}: ARKit basis version {int(z['version'])}, this facewarp reads {_BASIS_VERSION}")
            names = tuple(str(n) for n in z["names"])
            step = float(z["step_m"])
            skin_q, fdp_q = z["skin"], z["fdp"]
            h = hashlib.sha256()
            for a in (skin_q, fdp_q, z["vertices"], z["fdp_points"]):
                h.update(np.ascontiguousarray(a).tobytes())
            b = ArkitBasis(names=names, vertices=z["vertices"].astype(np.float64), faces=z["faces"].astype(np.int64),
                           skin={n: skin_q[i].astype(np.float64) * step for i, n in enumerate(names)},
                           fdp_ids=[str(i) for i in z["fdp_ids"]], fdp_points=z["fdp_points"].astype(np.float64),
                           fdp={n: fdp_q[i].astype(np.float64) * step for i, n in enumerate(names)},
                           source=str(z["source"]), digest=h.hexdigest()[:16], file=path, step_m=step,
                           level=int(z["level"]))
    except InputError:
        raise
    except Exception as e:  # a damaged file: one line
        raise InputError(f"{path}: not a facewarp ARKit basis ({type(e).__name__}: {e})") from None
    if any(n not in ICT_ARKIT_SHAPES for n in names) or b.skin and next(iter(b.skin.values())).shape != b.vertices.shape:
        raise InputError(f"{path}: not a facewarp ARKit basis (unknown names or wrong shapes)")
    _BASIS_MEMO[memo] = b
    return b


def transfer_basis_displacements(basis: ArkitBasis, head_vertices: np.ndarray, head_landmarks: dict, *,
                                 names=None, point_ids=None, max_dist: float = 0.01, device: str = "cpu",
                                 report: dict | None = None) -> dict[str, np.ndarray]:
    """Carry the shipped basis from the template onto a head's points.

    The template's head FDPs are warped onto the head's (a least-squares similarity and a thin-plate
    spline through the FDPs both have, :func:`transfer_ict_displacements`'s warp); a head point named
    as one of the template's FDPs (``point_ids``) takes that FDP's displacement, any other point the
    closest point's of the warped template skin; either as ``W(x + d) - W(x)``.

    Args:
        basis: :func:`load_arkit_basis`.
        head_vertices: The head points [m], (n, 3) float64, head frame.
        head_landmarks: FDP id -> the head's FDP position [m] (3,) (at least six of the template's head FDPs).
        names: ARKit names to carry (default all the basis has).
        point_ids: Optional name of each head point (e.g. its FDP id).
        max_dist: Points (not named as FDPs) farther than this from the warped skin [m] get zero.
        device: Warp device of the closest-point query.
        report: Optional dict filled with the warp's statistics.

    Returns:
        name -> displacement [m], (n, 3) float64, at ``head_vertices``.
    """
    from ..core.checks import check_array
    from ..geometry.surface import closest_point

    P = check_array("head_vertices", head_vertices, shape=(None, 3)).astype(np.float64)
    names = list(basis.names) if names is None else [str(n) for n in names]
    for n in names:
        if n not in basis.skin:
            raise InputError(f"names: the ARKit basis has no shape {n!r}")
    src = dict(zip(basis.fdp_ids, basis.fdp_points))
    dst = {str(k): np.asarray(v, np.float64) for k, v in dict(head_landmarks).items()}
    warp = _fit_warp(src, dst)
    ids = [str(i) for i in point_ids] if point_ids is not None else [None] * len(P)
    if len(ids) != len(P):
        raise InputError(f"point_ids: {len(ids)} names for {len(P)} head points")
    fdp_row = {k: i for i, k in enumerate(basis.fdp_ids)}
    named = np.array([i in fdp_row for i in ids], bool)
    rows = np.array([fdp_row[i] for i in ids if i in fdp_row], np.int64)
    rest = np.flatnonzero(~named)
    far = np.zeros(len(P), bool)
    if len(rest):
        WV = warp(basis.vertices)
        cp = closest_point(WV, basis.faces, P[rest], device=device)
        far[rest] = ~(cp.dist <= max_dist)
        face = np.where(far[rest], 0, cp.face)
        bary = np.array(cp.bary, np.float64)
        used = np.unique(basis.faces[face])
    out = {}
    WX = warp(basis.fdp_points[rows]) if len(rows) else None
    for n in names:
        d = np.zeros_like(P)
        if len(rows):
            d[named] = warp(basis.fdp_points[rows] + basis.fdp[n][rows]) - WX
        if len(rest):
            WD = np.zeros((len(basis.vertices), 3))
            WD[used] = warp(basis.vertices[used] + basis.skin[n][used]) - WV[used]
            d[rest] = np.einsum("kc,kcd->kd", bary, WD[basis.faces[face]])
        d[far] = 0.0
        out[n] = d
    if report is not None:
        report.update({"source": "shipped ARKit basis (ICT-FaceKit on the default template)", "fdps": warp.fdps,
                       "similarity_scale": float(warp.similarity.scale), "beyond_max_dist": int(far.sum()),
                       "named_points": int(named.sum())})
    return out
