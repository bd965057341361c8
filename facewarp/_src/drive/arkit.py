"""What each of the 52 ARKit blendshapes means on one head: an :class:`ArkitTable` of muscle
activations, jaw angles and eye gaze, built once per head and cached in its build folder.

Where the shapes come from (``source``): the ICT-FaceKit rig's ARKit-named expressions. facewarp
ships them carried onto its default template
(:func:`~facewarp._src.importers.ict_arkit.load_arkit_basis`, MIT, 0.9 MB), so a fresh install
drives any head; a folder with the kit's own OBJs (:func:`~facewarp.takes.ict_shape_dirs`) is used
instead when it holds every shape (``source="auto"``), and ``shapes=`` takes your own displacements.
Each shape is carried onto the head (scaled to the head's own proportions) at its FDPs on the
skin; the target of a shape is the head's rest FDPs plus that displacement. Then the controls are
solved by a static inverse:

1. the static response of each control: every muscle alone at activation 1, the jaw opened by
   :data:`JAW_PROBE` and turned sideways by :data:`JAW_SIDE_PROBE`, each a converged static shape
   (:func:`~facewarp.blendshapes.static_surface`), gives one column of the linear model ``B`` (FDP displacement
   per unit control, (3 K, M + 2));
2. a bounded least-squares solve, ``min |B x - t|^2 + effort^2 |x|^2`` with the activations in
   [0, 1], the opening in [0, 60 deg] and the side angle in +-5 deg (``scipy.optimize.lsq_linear``);
3. ``refine`` rounds of a quasi-Newton refinement: the simulator's converged static shape at ``x``,
   its FDP residual against the target, and the same bounded solve for the correction, the model
   updated by Broyden's rank-one rule after each step (a step that does not lower the residual
   is not taken).

Shapes are solved on demand (``solve=``: the ones a take uses) and added to the cached table; the
probes are made once. The residual left (FDP RMS over the head FDPs) is stored per shape.

Rigid parts: the jaw is a control of the solve. The eyeballs are turned, not solved: each
``eyeLook*`` shape turns its eye by :data:`EYE_LOOK_DEG` at weight 1 (a convention: ARKit does not
state the angle, and ICT-FaceKit's expressions leave the eyeballs still); the lid motion of the
same ICT shape is solved by the muscles like any other shape. Blinks close the lids with the
muscles (orbicularis oculi and the lid ties of the simulated skin; no displacement is imposed on
the lids). The shapes the model has no means for (:data:`ARKIT_OUT_OF_REACH`: tongue, jaw thrust,
cheek puffing, the lips sealed over an open jaw) are not solved: their entries are zero and listed
with the reason; :meth:`ArkitTable.reach` says per shape what reaches it and how closely.

Using it: :meth:`ArkitTable.controls` blends the table's rows by a frame's weights in activation
space and clamps, ``a = clip(W A, 0, 1)``, ``jaw = clip(W J, limits)``; :meth:`ArkitTable.gaze_for`
blends the eye angles; :meth:`ArkitTable.targets_for` gives the blended target FDPs, which an
inverse solve can refine against.

The table is cached as ``arkit_table.npz`` in the ``cache`` folder and reused while its key (a hash
of the rig, the simulator's solver and material, the shapes' data and the build settings) matches;
a cache folder that cannot be written is skipped with a note (``table.info["cache_note"]``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..sim.readout import eye_gaze_rotation
from .result import DriveResult
from .tracks import ARKIT_NAMES

__all__ = ["ARKIT_OUT_OF_REACH", "ARKIT_TABLE_FILE", "ArkitTable", "EYE_GAZE_MAX", "EYE_LOOK_DEG", "JAW_PROBE",
           "JAW_SIDE_PROBE", "arkit_table", "drive_arkit", "eye_gaze_rotation", "head_rotation_matrix",
           "load_arkit_table"]

ARKIT_TABLE_FILE = "arkit_table.npz"
_VERSION = 2
JAW_PROBE = 0.2
"""Jaw opening [rad] of the static probe giving the opening's column of the linear model."""
JAW_SIDE_PROBE = math.radians(4.0)
"""Jaw side angle [rad] of the static probe giving the side angle's column."""
EYE_LOOK_DEG: dict[str, float] = {"In": 30.0, "Out": 30.0, "Up": 25.0, "Down": 30.0}
"""How far [deg] an ``eyeLook{In,Out,Up,Down}{Left,Right}`` weight of 1 turns its eye (a convention:
ARKit does not state it; the human eye's usual range)."""
EYE_GAZE_MAX = math.radians(45.0)
"""Largest eye yaw or pitch [rad] the drive sets (blends and recorded angles are clamped to it)."""

ARKIT_OUT_OF_REACH: dict[str, str] = {
    "tongueOut": "tongue: rigid, it rides the jaw (no tongue muscles); ICT-FaceKit has no tongueOut shape either",
    "jawForward": "jaw thrust: the jaw is a hinge (opening about the condyle axis and a +-5 deg side turn), "
                  "it does not slide forward",
    "cheekPuff": "air pressure inside the mouth pushes the cheeks out; no muscle of the model does",
    "mouthClose": "a corrective for jawOpen (the lips sealed over an open jaw); alone it asks the lips to pass "
                  "through each other, which the lip contact forbids",
}
"""ARKit shapes beyond the model, name -> why: their table entries are zero."""


def _gaze_rows() -> np.ndarray:
    """(52, 2, 2) float64 [rad]: each shape's eye turn, per eye (left, right) its (yaw, pitch);
    yaw > 0 turns the gaze towards +x (the subject's left), pitch > 0 up."""
    G = np.zeros((len(ARKIT_NAMES), 2, 2))
    for i, n in enumerate(ARKIT_NAMES):
        if not n.startswith("eyeLook"):
            continue
        side = 0 if n.endswith("Left") else 1
        d = n[len("eyeLook"):-len("Left" if side == 0 else "Right")]
        a = math.radians(EYE_LOOK_DEG[d])
        if d == "Up":
            G[i, side, 1] = a
        elif d == "Down":
            G[i, side, 1] = -a
        else:  # the left eye looks out towards +x, the right eye in towards +x
            G[i, side, 0] = a if (d == "Out") == (side == 0) else -a
    return G


def _digest(*parts) -> str:
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, np.ndarray):
            h.update(str(p.dtype).encode())
            h.update(np.ascontiguousarray(p).tobytes())
        else:
            h.update(json.dumps(p, sort_keys=True, default=str).encode())
    return h.hexdigest()[:20]


def rig_key(sim) -> str:
    """A hash of what a table depends on in ``sim``: its rig's geometry, muscles and FDPs, solver and material."""
    fr = sim.fr
    arrays = [np.asarray(getattr(fr, k)) for k in ("head_vertices", "head_faces", "nodes", "tets", "fdp_face",
                                                   "fdp_bary", "jaw_pivot", "jaw_u", "jaw_v")]
    return _digest(*arrays, list(fr.rig.names), [str(i) for i in fr.fdp_ids], str(sim.solver_name),
                   type(sim.material).__name__)


@dataclass
class ArkitTable:
    """Per-head controls of the 52 ARKit shapes (see the module docstring).

    Attributes:
        names: The 52 ARKit names (:data:`~facewarp.ARKIT_NAMES` order).
        muscle_names: The M muscles, in the simulator's order.
        activations: (52, M) float32 in [0, 1], each shape's activations.
        jaw: (52, 2) float32 [rad], each shape's jaw (opening, side).
        gaze: (52, 2, 2) float32 [rad], each shape's eye turn: per eye (left, right) its (yaw, pitch)
            (:func:`eye_gaze_rotation`; nonzero for the ``eyeLook*`` shapes).
        solved: (52,) bool: the entry was solved (False: zero, see ``reasons``).
        residual_m: (52,) float64 [m]: FDP RMS over the head FDPs of the solved static shape
            against the target (NaN where not solved).
        target_rms_m: (52,) float64 [m]: the target's own FDP RMS displacement (its size; NaN where no data).
        fdp_ids: The K head FDP ids the targets are given at.
        rest_fdp: (K, 3) float64 [m]: those FDPs of the static rest shape, head frame.
        targets: (52, K, 3) float64 [m]: each shape's FDP displacement on this head (zero where no data).
        reached: (52, K, 3) float64 [m]: the FDP displacement of the converged static face at
            each shape's controls (zero where not solved).
        basis: (3 K, M + 2) float64: the linear model, FDP displacement [m] per unit control
            (activation; jaw opening and side per rad), from the static probes.
        reasons: ARKit name -> why its entry is zero (out of reach, no data, not solved yet).
        key: The cache key (rig, solver, shapes, settings).
        info: Build settings, the data source and timings (JSON-ready).
    """

    names: tuple
    muscle_names: list
    activations: np.ndarray
    jaw: np.ndarray
    solved: np.ndarray
    residual_m: np.ndarray
    target_rms_m: np.ndarray
    fdp_ids: list
    rest_fdp: np.ndarray
    targets: np.ndarray
    reached: np.ndarray
    basis: np.ndarray
    reasons: dict = field(default_factory=dict)
    key: str = ""
    info: dict = field(default_factory=dict)
    gaze: np.ndarray = field(default_factory=lambda: _gaze_rows().astype(np.float32))

    # ------------------------------------------------------------------ use
    def _weights(self, weights) -> np.ndarray:
        from ..core.checks import check_array

        W = check_array("weights", weights, shape=(None, len(self.names)) if np.ndim(weights) == 2
                        else (len(self.names),)).astype(np.float64)
        W = np.atleast_2d(W)
        if W.min() < -1e-3 or W.max() > 1.0 + 1e-3:
            raise InputError(f"weights: ARKit weights lie in [0, 1], got {W.min():.3g}..{W.max():.3g}")
        return np.clip(W, 0.0, 1.0)

    def controls(self, weights) -> tuple[np.ndarray, np.ndarray]:
        """Controls of frames of ARKit weights: blended in activation space, clamped.

        Args:
            weights: (T, 52) or (52,) float in [0, 1], :data:`~facewarp.ARKIT_NAMES` order.

        Returns:
            (activations (T, M) float32 in [0, 1], jaw (T, 2) float32 [rad], opening in
            [0, 60 deg] and side in +-5 deg).
        """
        from ..expressions import JAW_U_MAX, JAW_V_MAX

        W = self._weights(weights)
        A = np.clip(W @ self.activations.astype(np.float64), 0.0, 1.0)
        J = W @ self.jaw.astype(np.float64)
        J[:, 0] = np.clip(J[:, 0], 0.0, JAW_U_MAX)
        J[:, 1] = np.clip(J[:, 1], -JAW_V_MAX, JAW_V_MAX)
        return A.astype(np.float32), J.astype(np.float32)

    def gaze_for(self, weights) -> np.ndarray:
        """Eye angles of frames of weights [rad], (T, 2, 2) float64: per eye (left, right) its
        (yaw, pitch), the ``eyeLook*`` weights blended and clamped to +-:data:`EYE_GAZE_MAX`."""
        W = self._weights(weights)
        return np.clip(np.einsum("ts,sed->ted", W, self.gaze.astype(np.float64)), -EYE_GAZE_MAX, EYE_GAZE_MAX)

    def targets_for(self, weights) -> np.ndarray:
        """Blended target FDPs of frames of weights [m], (T, K, 3) float64, head frame: the rest
        FDPs plus the weighted sum of the shapes' displacements (what the face should show)."""
        W = self._weights(weights)
        return self.rest_fdp[None] + np.einsum("ts,skd->tkd", W, self.targets)

    def mapped(self) -> np.ndarray:
        """(52,) bool: the shapes that move something on this head (solved with nonzero controls, or a gaze)."""
        moves = (np.abs(self.activations).max(axis=1) > 1e-3) | (np.abs(self.jaw).max(axis=1) > 1e-4)
        return (self.solved & moves) | (np.abs(self.gaze).reshape(len(self.names), -1).max(axis=1) > 0)

    def reach(self) -> list[dict]:
        """Per ARKit shape what reaches it on this head and how closely, 52 dicts: ``name``, ``by``
        (``"muscles"``, ``"jaw"``, ``"eyes"`` joined by ``" + "``, or ``"not reached"``),
        ``residual_mm`` (the solved static face's FDP RMS from the shape's target, None where not
        solved), ``target_mm`` (the target's own FDP RMS), ``jaw_deg`` (opening, side),
        ``gaze_deg`` (left and right eye's yaw, pitch) and ``reason`` (why not reached)."""
        rows = []
        for i, n in enumerate(self.names):
            by = []
            if self.solved[i] and np.abs(self.activations[i]).max() > 1e-3:
                by.append("muscles")
            if self.solved[i] and np.abs(self.jaw[i]).max() > math.radians(0.5):
                by.append("jaw")
            if np.abs(self.gaze[i]).max() > 0:
                by.append("eyes")
            rows.append({"name": n, "by": " + ".join(by) if by else "not reached",
                         "residual_mm": None if not self.solved[i] else round(float(self.residual_m[i]) * 1e3, 3),
                         "target_mm": None if not np.isfinite(self.target_rms_m[i])
                         else round(float(self.target_rms_m[i]) * 1e3, 3),
                         "jaw_deg": np.round(np.degrees(self.jaw[i].astype(np.float64)), 2).tolist(),
                         "gaze_deg": np.round(np.degrees(self.gaze[i].astype(np.float64)), 1).tolist(),
                         "reason": self.reasons.get(n, "")})
        return rows

    def refine(self, sim, weights, *, rounds: int = 3, tol: float = 2e-5, max_frames: int = 40):
        """One frame's controls refined against its blended target by the static quasi-Newton method
        (converged static shapes of ``sim``, corrections from :attr:`basis`; see the module docstring).

        Args:
            sim: The :class:`~facewarp.FaceSimulator` of this table's head (reset and stepped; left reset).
            weights: (52,) float in [0, 1].
            rounds: Refinement rounds (0..10).

        Returns:
            (activations (M,) float32, jaw (2,) float32 [rad], FDP RMS residual [m] per static
            evaluation, a list starting with the blended controls'; the controls returned are the best's).
        """
        from ..core.checks import check_int

        W = self._weights(weights)
        if len(W) != 1:
            raise InputError(f"weights: refine takes one frame, (52,), got {len(W)} frames")
        rounds = check_int("rounds", rounds, low=0, high=10)
        if list(getattr(sim, "muscle_names", [])) != list(self.muscle_names) or rig_key(sim) != self.key_rig:
            raise InputError("sim: not the head (or the solver) this ARKit table was built for")
        a, j = self.controls(W)
        statics = _Statics(sim, _head_fdps(sim.fr)[1], tol, max_frames)
        target = self.targets_for(W)[0]
        x, res, _ = _refine_static(statics, self.basis, self._effort(), np.r_[a[0], j[0]].astype(np.float64), target, rounds)
        sim.reset()
        return x[:-2].astype(np.float32), x[-2:].astype(np.float32), res

    def _effort(self) -> float:
        return float(self.info.get("settings", {}).get("effort", 1e-3))

    @property
    def key_rig(self) -> str:
        """The rig part of :attr:`key` (:func:`rig_key` of the simulator it was built with)."""
        return str(self.info.get("rig_key", ""))

    def out_of_reach(self) -> dict:
        """ARKit name -> reason, for the shapes whose entry is zero."""
        return dict(self.reasons)

    # ------------------------------------------------------------------ files
    def save(self, path) -> Path:
        """Write the table to ``path`` (``.npz``) atomically: a temporary file beside it, renamed;
        nothing is left behind when writing fails (the OSError is raised)."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
        try:
            np.savez_compressed(tmp, names=np.array(self.names), muscle_names=np.array(self.muscle_names),
                                activations=self.activations, jaw=self.jaw, gaze=self.gaze, solved=self.solved,
                                residual_m=self.residual_m, target_rms_m=self.target_rms_m,
                                fdp_ids=np.array(self.fdp_ids), rest_fdp=self.rest_fdp, targets=self.targets,
                                reached=self.reached, basis=self.basis,
                                reasons=np.array(json.dumps(self.reasons)), key=np.array(self.key),
                                info=np.array(json.dumps(self.info)), version=np.array(_VERSION))
            os.replace(tmp, path)
        except BaseException:
            try:
                tmp.unlink()
            except OSError:
                pass
            raise
        return path


def load_arkit_table(path) -> ArkitTable:
    """Read a table written by :meth:`ArkitTable.save` (a file, or a folder holding ``arkit_table.npz``)."""
    path = Path(path)
    if path.is_dir():
        path = path / ARKIT_TABLE_FILE
    if not path.is_file():
        raise InputError(f"{path}: not found (expected an {ARKIT_TABLE_FILE})")
    try:
        with np.load(path, allow_pickle=False) as z:
            if int(z["version"]) != _VERSION:
                raise InputError(f"{path}: table version {int(z['version'])}, this facewarp reads {_VERSION}")
            t = ArkitTable(names=tuple(str(n) for n in z["names"]), muscle_names=[str(n) for n in z["muscle_names"]],
                           activations=z["activations"].astype(np.float32), jaw=z["jaw"].astype(np.float32),
                           gaze=z["gaze"].astype(np.float32),
                           solved=z["solved"].astype(bool), residual_m=z["residual_m"].astype(np.float64),
                           target_rms_m=z["target_rms_m"].astype(np.float64),
                           fdp_ids=[str(n) for n in z["fdp_ids"]], rest_fdp=z["rest_fdp"].astype(np.float64),
                           targets=z["targets"].astype(np.float64), reached=z["reached"].astype(np.float64),
                           basis=z["basis"].astype(np.float64), reasons=json.loads(str(z["reasons"])),
                           key=str(z["key"]), info=json.loads(str(z["info"])))
    except InputError:
        raise
    except Exception as e:  # a damaged or foreign file: one line
        raise InputError(f"{path}: not a facewarp ARKit table ({type(e).__name__}: {e})") from None
    if t.names != ARKIT_NAMES or t.activations.shape != (len(ARKIT_NAMES), len(t.muscle_names)) \
            or t.gaze.shape != (len(ARKIT_NAMES), 2, 2):
        raise InputError(f"{path}: not a facewarp ARKit table (wrong names or shapes)")
    return t


# ---------------------------------------------------------------------- building
def _head_fdps(fr) -> tuple[list, np.ndarray]:
    idx = [i for i, p in enumerate(fr.fdp_part) if str(p) == "head"]
    return [str(fr.fdp_ids[i]) for i in idx], np.asarray(idx)


def _fdp_of(fr, idx, V) -> np.ndarray:
    F = np.asarray(fr.head_faces)
    return np.einsum("kc,kcd->kd", np.asarray(fr.fdp_bary, np.float64)[idx], V[F[np.asarray(fr.fdp_face)[idx]]])


_NO_DATA = "no ICT-FaceKit shape data found (see facewarp.takes.ict_shape_dirs)"
_SOURCES = ("auto", "shipped", "ict")


def _names_arg(arg, what: str) -> list:
    from ..importers.ict_arkit import ICT_ARKIT_SHAPES

    if isinstance(arg, (str, bytes)) or not hasattr(arg, "__iter__"):
        raise InputError(f"{what}: expected ARKit names, got {arg!r:.80}")
    names = [str(n) for n in arg]
    for n in names:
        if n not in ICT_ARKIT_SHAPES:
            raise InputError(f"{what}: {n!r} is not an ARKit blendshape name")
    return names


def _resolve_source(shapes, source: str, ict_dir):
    """The shapes' data: ("custom" | "ict", {name: ICT-skin displacement}) or ("shipped", names)."""
    from ..importers.ict_arkit import ICT_ARKIT_SHAPES, ict_shape_dirs, load_arkit_basis, load_ict_displacements

    if isinstance(shapes, dict):
        out = {}
        for n, D in shapes.items():
            if n not in ICT_ARKIT_SHAPES:
                raise InputError(f"shapes: {n!r} is not an ARKit blendshape name")
            D = np.asarray(D, np.float64) if not isinstance(D, str) else None
            if D is None or D.shape != (11248, 3) or not np.isfinite(D).all():
                raise InputError(f"shapes[{n!r}]: expected an ICT-skin displacement, shape (11248, 3), finite, in metres")
            out[n] = D
        return "custom", out
    names = list(ARKIT_NAMES) if shapes is None else _names_arg(shapes, "shapes")
    if source not in _SOURCES:
        raise InputError(f"source: expected one of {', '.join(_SOURCES)}, got {source!r:.80}")
    if source == "auto":  # the kit's OBJs when a folder holds every shape asked for, else the shipped basis
        wanted = [n for n in names if ICT_ARKIT_SHAPES[n]]
        full = [d for d in ict_shape_dirs(ict_dir) if all((d / f"{s}.obj").is_file()
                                                           for n in wanted for s in ICT_ARKIT_SHAPES[n])]
        source = "ict" if full else "shipped"
        ict_dir = full[0] if full else ict_dir
    if source == "ict":
        return "ict", load_ict_displacements(names, ict_dir=ict_dir), ict_dir
    basis = load_arkit_basis()
    return "shipped", [n for n in names if n in basis.skin], basis


def _bounds(M: int) -> tuple[np.ndarray, np.ndarray]:
    from ..expressions import JAW_U_MAX, JAW_V_MAX

    return np.r_[np.zeros(M), 0.0, -JAW_V_MAX], np.r_[np.ones(M), JAW_U_MAX, JAW_V_MAX]


def _bounded_step(B: np.ndarray, effort: float, r: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """d minimising |B d - r|^2 + |reg (x0 + d)|^2 with lo <= x0 + d <= hi (the jaw's unit in the
    effort term: 0.1 rad)."""
    from scipy.optimize import lsq_linear

    M = B.shape[1] - 2
    lo, hi = _bounds(M)
    reg = effort * np.diag(np.r_[np.ones(M), 10.0, 10.0])
    A = np.vstack([B, reg])
    b = np.r_[r, -reg @ x0]
    return lsq_linear(A, b, bounds=(np.minimum(lo - x0, 0.0), np.maximum(hi - x0, 0.0) + 1e-12), method="bvls").x


def _refine_static(statics, B, effort, x, target, rounds):
    """Static refinement from controls x (M + 2,) towards target FDPs (K, 3) [m]: the converged
    static shape at x, its residual, a bounded correction through the linear model, which each
    round updates by Broyden's rank-one rule with the step it saw (the response is not linear); a
    step that does not lower the FDP RMS is not taken (the next one starts from the corrected
    model). Returns (best x, FDP RMS [m] per evaluation, the FDPs (K, 3) [m] at the best x)."""
    lo, hi = _bounds(B.shape[1] - 2)
    M = B.shape[1] - 2
    B = B.copy()
    P = statics(x[:M], x[M:])
    err = float(np.sqrt(np.mean(np.sum((P - target) ** 2, axis=1))))
    hist = [err]
    for _ in range(rounds):
        x1 = np.clip(x + _bounded_step(B, effort, (target - P).ravel(), x), lo, hi)
        dx = x1 - x
        if not np.any(np.abs(dx) > 1e-6):
            break
        P1 = statics(x1[:M], x1[M:])
        e1 = float(np.sqrt(np.mean(np.sum((P1 - target) ** 2, axis=1))))
        hist.append(e1)
        B += np.outer((P1 - P).ravel() - B @ dx, dx) / float(dx @ dx)
        if e1 < err:  # else stay, with the model corrected by what the step showed
            x, P, err = x1, P1, e1
    return x, hist, P


class _Statics:
    """Converged static FDPs of ``sim`` under constant controls (counted and timed)."""

    def __init__(self, sim, idx, tol, max_frames):
        self.sim, self.idx, self.tol, self.max_frames = sim, idx, tol, max_frames
        self.count, self.frames, self.seconds = 0, 0, 0.0

    def __call__(self, a: np.ndarray, jaw) -> np.ndarray:
        """FDPs [m] (K, 3) of the static shape at activations a (M,) and jaw (opening, side) [rad]."""
        t0 = time.perf_counter()
        sim = self.sim
        names = sim.muscle_names
        sim.reset()
        sim.set_activations({names[m]: float(a[m]) for m in np.flatnonzero(np.asarray(a) > 0)})
        sim.set_jaw(float(jaw[0]), float(jaw[1]))
        prev = sim.surface(frame="head")
        k = 0
        for k in range(1, self.max_frames + 1):
            sim.step()
            V = sim.surface(frame="head")
            done = k >= 2 and np.abs(V - prev).max() < self.tol
            prev = V
            if done:
                break
        self.count, self.frames = self.count + 1, self.frames + k
        self.seconds += time.perf_counter() - t0
        return _fdp_of(sim.fr, self.idx, prev)


def _check_cache(cache):
    """The cache folder as a Path (None stays None); refuses up front what could only fail later."""
    if cache is None:
        return None
    if isinstance(cache, bytes) or not isinstance(cache, (str, os.PathLike)) or not str(cache).strip():
        raise InputError(f"cache: expected a folder path, got {cache!r:.80}")
    cache = Path(cache)
    if cache.exists() and not cache.is_dir():
        raise InputError(f"cache: {cache} is not a folder")
    f = cache / ARKIT_TABLE_FILE
    if f.exists() and not f.is_file():
        raise InputError(f"cache: {f} is not a file (a folder or a device is in the table's place); move it away")
    return cache


def _write_cache(table: ArkitTable, cache: Path) -> None:
    """Save into the cache folder; a folder that cannot be written is skipped with a note in ``table.info``."""
    path = cache / ARKIT_TABLE_FILE
    try:
        cache.mkdir(parents=True, exist_ok=True)
        table.save(path)
        table.info.pop("cache_note", None)
    except OSError as e:
        why = e.strerror or type(e).__name__
        table.info["cache_note"] = (f"ARKit table not cached: {path} cannot be written ({why}); "
                                    "it is built again on the next run")


def arkit_table(sim, *, shapes=None, source: str = "auto", solve=None, cache=None, ict_dir=None, refine: int = 3,
                effort: float = 1e-3, tol: float = 2e-5, max_frames: int = 40, progress=None,
                rebuild: bool = False) -> ArkitTable:
    """The :class:`ArkitTable` of ``sim``'s head (see the module docstring); cached.

    Args:
        sim: A :class:`~facewarp.FaceSimulator` (it is reset and stepped; left reset).
        shapes: Which ARKit shapes have data: None (all), a list of ARKit names, or a dict ARKit
            name -> your own displacement on the ICT skin [m] (11248, 3). Shapes not given are zero
            entries (reason: no data).
        source: Where the shapes' data comes from: ``"shipped"`` (the ICT-FaceKit expressions
            facewarp ships on its default template), ``"ict"`` (the kit's OBJs,
            :func:`~facewarp.takes.ict_shape_dirs`; shapes not found are zero entries) or ``"auto"``
            (the OBJs when one folder holds all the shapes asked for, else the shipped data).
        solve: ARKit names to solve now (default all with data); the others with data are left
            for a later call (reason "not solved yet") unless the cache already holds them. A
            cached table gains the shapes solved later.
        cache: A folder (the head's build folder): ``arkit_table.npz`` there is read when its key
            matches and written after a build; where the folder cannot be written the table is
            not cached (``info["cache_note"]`` says so). None: no cache.
        ict_dir: A folder searched first for the ICT-FaceKit OBJs.
        refine: Rounds of the static refinement (0..10).
        effort: Weight of the controls' size in the least squares [m per unit control].
        tol, max_frames: Convergence of each static shape (:func:`~facewarp.blendshapes.static_surface`).
        progress: Optional ``progress(done, total, name)``.
        rebuild: Build even when the cache matches.

    Raises:
        InputError: bad arguments, unknown shape names, a cache file that is not a table (or a
            folder in its place).
    """
    from ..core.checks import check_int, check_number
    from ..importers.ict_arkit import displacements_digest, transfer_basis_displacements, transfer_ict_displacements

    if not hasattr(sim, "fr") or not hasattr(sim, "muscle_names"):
        raise InputError(f"sim: expected a FaceSimulator, got {type(sim).__name__}")
    refine = check_int("refine", refine, low=0, high=10)
    max_frames = check_int("max_frames", max_frames, low=2, high=1000)
    effort = check_number("effort", effort, low=0.0, high=1.0)
    tol = check_number("tol", tol, low=0.0, high=1e-2, low_open=True)
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a callable progress(done, total, name), got {type(progress).__name__}")
    cache = _check_cache(cache)
    want = None if solve is None else set(_names_arg(solve, "solve"))
    resolved = _resolve_source(shapes, source, ict_dir)
    kind = resolved[0]
    if kind == "shipped":
        data_names, basis = resolved[1], resolved[2]
        digest = _digest("shipped", basis.digest, data_names)
    else:
        D_ict = resolved[1]
        ict_dir = resolved[2] if kind == "ict" else ict_dir
        data_names = [n for n in ARKIT_NAMES if n in D_ict]
        digest = displacements_digest(D_ict)
    settings = {"refine": refine, "effort": effort, "tol": tol, "max_frames": max_frames, "jaw_probe": JAW_PROBE,
                "jaw_side_probe": JAW_SIDE_PROBE, "eye_look_deg": EYE_LOOK_DEG, "version": _VERSION}
    key = _digest(rig_key(sim), digest, settings)
    t0 = time.perf_counter()
    fr = sim.fr
    fdp_ids, idx = _head_fdps(fr)
    statics = _Statics(sim, idx, tol, max_frames)
    M = len(sim.muscle_names)
    zero_a = np.zeros(M)
    lo, hi = _bounds(M)
    table = None
    if cache is not None and not rebuild and (cache / ARKIT_TABLE_FILE).is_file():
        try:
            cached = load_arkit_table(cache / ARKIT_TABLE_FILE)
        except InputError as e:
            if "table version" not in str(e):
                raise
            cached = None  # an older facewarp's table: built again
        if cached is not None and cached.key == key:
            table = cached
    todo = [n for n in data_names if n not in ARKIT_OUT_OF_REACH and (want is None or n in want)]
    if table is not None:
        todo = [n for n in todo if not table.solved[ARKIT_NAMES.index(n)]]
        if not todo:
            table.info["from_cache"] = True
            return table
    solvable = any(n not in ARKIT_OUT_OF_REACH for n in data_names)
    done, total = 0, len(todo) + (M + 2 if table is None and solvable else 0)

    def tick(name):
        nonlocal done
        done += 1
        if progress:
            progress(done, total, name)

    if table is None:
        rest = statics(zero_a, (0.0, 0.0))
        # 1. carry the shapes onto this head's FDPs
        rep: dict = {}
        lm = dict(zip(fdp_ids, rest))
        dev = str(sim.device) if "cuda" in str(sim.device) else "cpu"
        if not data_names:
            T_head = {}
        elif kind == "shipped":
            T_head = transfer_basis_displacements(basis, rest, lm, names=data_names, point_ids=fdp_ids, device=dev,
                                                  report=rep)
        else:
            T_head = transfer_ict_displacements(D_ict, rest, lm, point_ids=fdp_ids, ict_dir=ict_dir, device=dev,
                                                report=rep)
        # 2. the linear model: one static probe per control (none when no shape could ever be solved)
        cols = []
        for m in range(M if solvable else 0):
            a = zero_a.copy()
            a[m] = 1.0
            cols.append((statics(a, (0.0, 0.0)) - rest).ravel())
            tick(sim.muscle_names[m])
        if solvable:
            cols.append((statics(zero_a, (JAW_PROBE, 0.0)) - rest).ravel() / JAW_PROBE)
            tick("jaw_open")
            cols.append((statics(zero_a, (0.0, JAW_SIDE_PROBE)) - rest).ravel() / JAW_SIDE_PROBE)
            tick("jaw_side")
        else:
            cols = [np.zeros(rest.size)] * (M + 2)
        B = np.stack(cols, 1)
        n = len(ARKIT_NAMES)
        targets = np.zeros((n, len(fdp_ids), 3))
        size = np.full(n, np.nan)
        linear = {}
        for i, name in enumerate(ARKIT_NAMES):
            if name in T_head:  # the linear model's bounded fit alone (no statics): for every shape with data
                targets[i] = T_head[name]
                size[i] = float(np.sqrt(np.mean(np.sum(T_head[name] ** 2, axis=1))))
                xl = np.clip(_bounded_step(B, effort, T_head[name].ravel(), np.zeros(M + 2)), lo, hi)
                r = (B @ xl - T_head[name].ravel()).reshape(-1, 3)
                linear[name] = round(float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) * 1e3, 3)
        reasons = dict(ARKIT_OUT_OF_REACH)
        for name in ARKIT_NAMES:
            if name not in reasons:
                reasons[name] = _NO_DATA if name not in T_head else "not solved yet (solved when a take uses it)"
        source_note = {"shipped": basis.source if kind == "shipped" else "", "ict": f"ICT-FaceKit OBJs in {ict_dir}",
                       "custom": "displacements given as shapes="}[kind]
        info = {"settings": settings, "rig_key": rig_key(sim), "source": kind, "source_note": source_note,
                "transfer": {k: v for k, v in rep.items() if k != "warp_fdp_residual_m"},
                "statics": 0, "static_frames": 0, "static_seconds": 0.0, "build_seconds": 0.0,
                "residual_history_mm": {}, "linear_model_residual_mm": linear, "from_cache": False}
        table = ArkitTable(names=tuple(ARKIT_NAMES), muscle_names=list(sim.muscle_names),
                           activations=np.zeros((n, M), np.float32), jaw=np.zeros((n, 2), np.float32),
                           solved=np.zeros(n, bool), residual_m=np.full(n, np.nan), target_rms_m=size,
                           fdp_ids=fdp_ids, rest_fdp=rest, targets=targets, reached=np.zeros((n, len(fdp_ids), 3)),
                           basis=B, reasons=reasons, key=key, info=info)
    # 3. solve the shapes asked for: bounded least squares, then the static refinement
    B, rest = table.basis, table.rest_fdp
    for name in todo:
        i = ARKIT_NAMES.index(name)
        t = table.targets[i]
        x0 = np.clip(_bounded_step(B, effort, t.ravel(), np.zeros(M + 2)), lo, hi)
        x, hist, P = _refine_static(statics, B, effort, x0, rest + t, refine)
        table.activations[i], table.jaw[i], table.solved[i], table.residual_m[i] = x[:M], x[M:], True, min(hist)
        table.reached[i] = P - rest
        table.reasons.pop(name, None)
        table.info["residual_history_mm"][name] = [round(h * 1e3, 3) for h in hist]
        tick(name)
    sim.reset()
    info = table.info
    info["statics"] += statics.count
    info["static_frames"] += statics.frames
    info["static_seconds"] = round(info["static_seconds"] + statics.seconds, 1)
    info["build_seconds"] = round(info["build_seconds"] + time.perf_counter() - t0, 1)
    info["from_cache"] = False
    if cache is not None:
        _write_cache(table, cache)
    return table


# ---------------------------------------------------------------------- driving
def head_rotation_matrix(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """The head's rotation (3, 3) float64 from ARKit's HeadYaw, HeadPitch, HeadRoll [rad]:
    ``R = Ry(yaw) Rx(pitch) Rz(roll)`` in the head frame (y up, +z forward; yaw about y, pitch about
    x, roll about z)."""
    cy, sy, cp, sp, cr, sr = (math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch), math.cos(roll),
                              math.sin(roll))
    Ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    Rz = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    return Ry @ Rx @ Rz


def check_table(sim, table) -> None:
    """Refuse a table that is not ``sim``'s head's (one line)."""
    if not isinstance(table, ArkitTable):
        raise InputError("table: an ArkitTrack is driven through the head's ARKit table "
                         f"(fw.arkit_table(sim, cache=BUILD)), got {type(table).__name__}")
    if list(table.muscle_names) != list(sim.muscle_names) or table.key_rig != rig_key(sim):
        raise InputError("table: built for another head (or solver) than this simulator's; "
                         "build it with fw.arkit_table(sim, cache=BUILD)")


def track_gaze(track, table: ArkitTable) -> np.ndarray:
    """The eye angles a track asks for [rad], (T, 2, 2) float64 (per eye its yaw, pitch): the track's
    own recorded eye angles (``track.eye_rotation``, (T, 2, 2), e.g. Live Link Face's eye yaw and
    pitch columns) where it has them, else the ``eyeLook*`` weights through the table; clamped to
    +-:data:`EYE_GAZE_MAX`."""
    from ..core.checks import check_array

    eyes = getattr(track, "eye_rotation", None)
    if eyes is None:
        return table.gaze_for(track.weights)
    E = check_array("track.eye_rotation", eyes, shape=(track.frames, 2, 2)).astype(np.float64)
    return np.clip(E, -EYE_GAZE_MAX, EYE_GAZE_MAX)


def arkit_warnings(track, table: ArkitTable) -> tuple[list, bool]:
    """What a track asks for that this head cannot show: (warnings, whether anything moves at all).

    A shape the track uses (a weight above 0 on some frame) that moves nothing on this head
    (:meth:`ArkitTable.mapped`) is one warning naming the shape, its largest weight and why."""
    W = np.asarray(track.weights)
    used = W.max(axis=0) > 0
    mapped = table.mapped()
    warnings = [f"{n}: not mapped on this head, weight up to {W[:, i].max():.2f} ignored ("
                f"{table.reasons.get(n) or 'the solve left it at zero controls'})"
                for i, n in enumerate(table.names) if used[i] and not mapped[i]]
    head = getattr(track, "head_rotation", None)
    turns = head is not None and bool(np.abs(head).max() > 0)
    eyes = getattr(track, "eye_rotation", None)
    looks = eyes is not None and bool(np.abs(eyes).max() > 0)
    return warnings, bool((used & mapped).any() or turns or looks)


def drive_arkit(sim, track, table: ArkitTable, *, sinks=(), progress=None, tracker=None,
                unreachable_limit: float = 2e-3):
    """Play an :class:`~facewarp.takes.ArkitTrack` on ``sim`` through its head's :class:`ArkitTable`
    (what :func:`~facewarp.drive` does for an ArkitTrack).

    Each frame's weights become controls by :meth:`ArkitTable.controls` (blend in activation
    space, clamp); with a ``tracker`` (a :class:`~facewarp.Tracker` on the table's FDP ids, which
    :func:`~facewarp.drive` makes for ``refine=True``) the frame is instead tracked towards its
    blended target FDPs (:meth:`ArkitTable.targets_for`), starting from the previous frame. The
    eyeballs turn by :func:`track_gaze` (:meth:`~facewarp.FaceSimulator.set_eye_gaze`). The track's
    head rotation, when it has one, drives :meth:`~facewarp.FaceSimulator.set_head_pose`
    (:func:`head_rotation_matrix`, no translation). The per-frame error is each head FDP's distance
    from its blended target (head frame).

    Returns:
        A :class:`~facewarp.takes.DriveResult` (``names``: the table's FDP ids; ``head_poses``: (T, 4, 4)
        when the track has head rotation; ``warnings``: the shapes used but not mapped; ``gaze``).

    Raises:
        InputError: a table of another head, a track at another rate, or a track of which nothing
            can move this face (every shape it uses unmapped, no head or eye rotation).
    """
    from ..core.checks import check_number
    from ..sim.play import PlayStats, _as_sink

    check_table(sim, table)
    if abs(track.fps - sim.fps) > 1e-6 * sim.fps:
        raise InputError(f"track: {track.fps:g} frames/s, but the simulator runs at {sim.fps:g}: "
                         f"make the FaceSimulator with fps={track.fps:g}")
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a callable progress(k, frame_count), got {type(progress).__name__}")
    unreachable_limit = check_number("unreachable_limit", unreachable_limit, low=0.0, low_open=True)
    warnings, moves = arkit_warnings(track, table)
    if not moves:
        used = [n for n, w in zip(table.names, np.asarray(track.weights).max(axis=0)) if w > 0]
        what = (f"none of the {len(used)} ARKit shapes it uses ({', '.join(used[:4])}{', ...' if len(used) > 4 else ''})"
                " is mapped on this head" if used else "every ARKit weight is 0")
        raise InputError(f"{track.source or 'track'}: the face cannot move: {what}, and the head and eyes do not turn")
    nf = track.frames
    A, J = table.controls(track.weights)
    G = track_gaze(track, table)
    targets = table.targets_for(track.weights)
    poses = None
    if track.head_rotation is not None:
        poses = np.tile(np.eye(4), (nf, 1, 1))
        for k, (y, p, r) in enumerate(track.head_rotation):
            poses[k, :3, :3] = head_rotation_matrix(y, p, r)
    sinks = [_as_sink(s) for s in sinks]
    _, idx = _head_fdps(sim.fr)
    sim.reset()
    if tracker is not None:
        tracker.reset_tracking()
    for s in sinks:
        s.start(sim, nf)
    M = len(sim.muscle_names)
    acts = np.zeros((nf, M), np.float32)
    jaw = np.zeros((nf, 2), np.float32)
    err = np.zeros((nf, len(table.fdp_ids)))
    t0 = time.perf_counter()
    stepping = 0.0
    for k in range(nf):
        s0 = time.perf_counter()
        if poses is not None:
            sim.set_head_pose(poses[k, :3, :3], np.zeros(3))
        sim.set_eye_gaze(G[k])
        if tracker is None:
            sim.set_activations(A[k])
            sim.set_jaw(float(J[k, 0]), float(J[k, 1]))
            sim.step()
            acts[k], jaw[k] = sim.activations, sim.jaw_angles
        else:
            acts[k], jaw[k] = tracker.update(targets[k])
        stepping += time.perf_counter() - s0
        err[k] = np.linalg.norm(_fdp_of(sim.fr, idx, sim.surface(frame="head")) - targets[k], axis=1)
        for s in sinks:
            s.frame(sim, k, k / track.fps)
        if progress:
            progress(k, nf)
    wall = time.perf_counter() - t0
    stepping = max(stepping, 1e-9)
    rms = np.sqrt(np.mean(err**2, axis=1))
    notes = list(warnings)
    if table.info.get("cache_note"):
        notes.append(table.info["cache_note"])
    bad = np.where(err > unreachable_limit)
    for i in np.unique(bad[1]):
        fr_k = bad[0][bad[1] == i]
        notes.append(f"point {table.fdp_ids[i]}: {len(fr_k)} frame(s) off by more than "
                     f"{unreachable_limit * 1e3:g} mm (worst {err[:, i].max() * 1e3:.2f} mm at frame "
                     f"{int(np.argmax(err[:, i]))})")
    steps = tracker.stats.steps if tracker is not None else nf
    stats = PlayStats(frames=nf, seconds=nf / track.fps, wall_s=wall, simulation_wall_s=stepping,
                      frames_per_second=nf / stepping, steps_per_second=steps * sim.substeps / stepping,
                      realtime_factor=nf / track.fps / stepping, substeps=int(sim.substeps), dt_s=float(sim.dt),
                      device=str(sim.device), jaw="arkit table", frame_stats=sim.stats.as_dict(), mujoco_events=[])
    for s in sinks:
        s.finish(sim, stats)
    return DriveResult(fps=track.fps, names=list(table.fdp_ids), muscle_names=list(sim.muscle_names),
                       activations=acts, jaw=jaw, error=err, rms=rms, unreachable=notes, seconds=stepping,
                       frames_per_second=nf / stepping, mode="arkit-tracker" if tracker is not None else "arkit-table",
                       stats=tracker.stats.as_dict() if tracker is not None else {"frames": nf},
                       head_poses=poses, warnings=warnings, gaze=G)
