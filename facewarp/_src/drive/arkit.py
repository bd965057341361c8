"""What each of the 52 ARKit blendshapes means on one head: an :class:`ArkitTable` of muscle
activations and jaw angles, built once per head and cached in its build folder.

Building (:func:`arkit_table`): each ARKit shape of the ICT-FaceKit rig
(:func:`~facewarp._src.importers.ict_arkit.load_ict_displacements`) is carried onto the head
(:func:`~facewarp._src.importers.ict_arkit.transfer_ict_displacements`, scaled to the head's own
proportions) at its FDPs on the skin; the target of a shape is the head's rest FDPs plus that
displacement. Then the controls are solved by a static inverse:

1. the static response of each control: every muscle alone at activation 1, the jaw opened by
   :data:`JAW_PROBE` and turned sideways by :data:`JAW_SIDE_PROBE`, each a converged static shape
   (:func:`~facewarp.static_surface`), gives one column of the linear model ``B`` (FDP displacement
   per unit control, (3 K, M + 2));
2. a bounded least-squares solve, ``min |B x - t|^2 + effort^2 |x|^2`` with the activations in
   [0, 1], the opening in [0, 60 deg] and the side angle in +-5 deg (``scipy.optimize.lsq_linear``);
3. ``refine`` rounds of a quasi-Newton refinement: the simulator's converged static shape at ``x``,
   its FDP residual against the target, and the same bounded solve for the correction, the model
   updated by Broyden's rank-one rule after each step (a step that does not lower the residual
   is not taken).

The residual left (FDP RMS over the head FDPs) is stored per shape. The shapes the muscle model
has no means for (:data:`ARKIT_OUT_OF_REACH`: gaze, tongue, jaw thrust, cheek puffing, the lips sealed
over an open jaw) are not solved: their entries are zero and listed with the reason, as are shapes
whose data was not found.

Using it: :meth:`ArkitTable.controls` blends the table's rows by a frame's weights in activation
space and clamps, ``a = clip(W A, 0, 1)``, ``jaw = clip(W J, limits)``; :meth:`ArkitTable.targets`
gives the blended target FDPs, which an inverse solve can refine against.

The table is cached as ``arkit_table.npz`` in the ``cache`` folder and reused while its key (a hash
of the rig, the simulator's solver and material, the shapes' data and the build settings) matches.
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
from .tracks import ARKIT_NAMES

__all__ = ["ARKIT_OUT_OF_REACH", "ARKIT_TABLE_FILE", "ArkitTable", "JAW_PROBE", "JAW_SIDE_PROBE", "arkit_table",
           "drive_arkit", "head_rotation_matrix", "load_arkit_table"]

ARKIT_TABLE_FILE = "arkit_table.npz"
_VERSION = 1
JAW_PROBE = 0.2
"""Jaw opening [rad] of the static probe giving the opening's column of the linear model."""
JAW_SIDE_PROBE = math.radians(4.0)
"""Jaw side angle [rad] of the static probe giving the side angle's column."""

_GAZE = "eye gaze: the eyeballs are rigid parts with no eye muscles in the model (they do not turn)"
ARKIT_OUT_OF_REACH: dict[str, str] = {
    **{f"eyeLook{d}{s}": _GAZE for d in ("Down", "In", "Out", "Up") for s in ("Left", "Right")},
    "tongueOut": "tongue: rigid, it rides the jaw (no tongue muscles); ICT-FaceKit has no tongueOut shape either",
    "jawForward": "jaw thrust: the jaw is a hinge (opening about the condyle axis and a +-5 deg side turn), "
                  "it does not slide forward",
    "cheekPuff": "air pressure inside the mouth pushes the cheeks out; no muscle of the model does",
    "mouthClose": "a corrective for jawOpen (the lips sealed over an open jaw); alone it asks the lips to pass "
                  "through each other, which the lip contact forbids",
}
"""ARKit shapes beyond the muscle model, name -> why: their table entries are zero."""


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
        reasons: ARKit name -> why its entry is zero (out of reach, or no data).
        key: The cache key (rig, solver, shapes, settings).
        info: Build settings and timings (JSON-ready).
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

    def targets_for(self, weights) -> np.ndarray:
        """Blended target FDPs of frames of weights [m], (T, K, 3) float64, head frame: the rest
        FDPs plus the weighted sum of the shapes' displacements (what the face should show)."""
        W = self._weights(weights)
        return self.rest_fdp[None] + np.einsum("ts,skd->tkd", W, self.targets)

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
        """Write the table to ``path`` (``.npz``) atomically."""
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, names=np.array(self.names), muscle_names=np.array(self.muscle_names),
                            activations=self.activations, jaw=self.jaw, solved=self.solved,
                            residual_m=self.residual_m, target_rms_m=self.target_rms_m,
                            fdp_ids=np.array(self.fdp_ids), rest_fdp=self.rest_fdp, targets=self.targets,
                            reached=self.reached, basis=self.basis,
                            reasons=np.array(json.dumps(self.reasons)), key=np.array(self.key),
                            info=np.array(json.dumps(self.info)), version=np.array(_VERSION))
        os.replace(tmp, path)
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
    if t.names != ARKIT_NAMES or t.activations.shape != (len(ARKIT_NAMES), len(t.muscle_names)):
        raise InputError(f"{path}: not a facewarp ARKit table (wrong names or shapes)")
    return t


# ---------------------------------------------------------------------- building
def _head_fdps(fr) -> tuple[list, np.ndarray]:
    idx = [i for i, p in enumerate(fr.fdp_part) if str(p) == "head"]
    return [str(fr.fdp_ids[i]) for i in idx], np.asarray(idx)


def _fdp_of(fr, idx, V) -> np.ndarray:
    F = np.asarray(fr.head_faces)
    return np.einsum("kc,kcd->kd", np.asarray(fr.fdp_bary, np.float64)[idx], V[F[np.asarray(fr.fdp_face)[idx]]])


def _resolve_shapes(shapes, ict_dir) -> dict:
    from ..importers.ict_arkit import ICT_ARKIT_SHAPES, load_ict_displacements

    if shapes is None:  # all, those out of reach too (their targets are kept, not solved)
        return load_ict_displacements(ARKIT_NAMES, ict_dir=ict_dir)
    if isinstance(shapes, dict):
        out = {}
        for n, D in shapes.items():
            if n not in ICT_ARKIT_SHAPES:
                raise InputError(f"shapes: {n!r} is not an ARKit blendshape name")
            D = np.asarray(D, np.float64) if not isinstance(D, str) else None
            if D is None or D.shape != (11248, 3) or not np.isfinite(D).all():
                raise InputError(f"shapes[{n!r}]: expected an ICT-skin displacement, shape (11248, 3), finite, in metres")
            out[n] = D
        return out
    if isinstance(shapes, str) or not hasattr(shapes, "__iter__"):
        raise InputError(f"shapes: expected ARKit names or a dict name -> displacement, got {shapes!r:.80}")
    names = [str(n) for n in shapes]
    for n in names:
        if n not in ICT_ARKIT_SHAPES:
            raise InputError(f"shapes: {n!r} is not an ARKit blendshape name")
    return load_ict_displacements(names, ict_dir=ict_dir)


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


def arkit_table(sim, *, shapes=None, cache=None, ict_dir=None, refine: int = 3, effort: float = 1e-3,
                tol: float = 2e-5, max_frames: int = 40, progress=None, rebuild: bool = False) -> ArkitTable:
    """The :class:`ArkitTable` of ``sim``'s head (see the module docstring); cached.

    Args:
        sim: A :class:`~facewarp.FaceSimulator` (it is reset and stepped; left reset).
        shapes: Which ARKit shapes to solve: None (every one found in the ICT-FaceKit data,
            :func:`~facewarp._src.importers.ict_arkit.ict_shape_dirs`), a list of ARKit names, or a
            dict ARKit name -> displacement on the ICT skin [m] (11248, 3). Shapes not given are
            zero entries (reason: no data).
        cache: A folder (the head's build folder): ``arkit_table.npz`` there is read when its key
            matches and written after a build. None: no cache.
        ict_dir: A folder searched first for the ICT-FaceKit OBJs.
        refine: Rounds of the static refinement (0..10).
        effort: Weight of the controls' size in the least squares [m per unit control].
        tol, max_frames: Convergence of each static shape (:func:`~facewarp.static_surface`).
        progress: Optional ``progress(done, total, name)``.
        rebuild: Build even when the cache matches.

    Raises:
        InputError: bad arguments, unknown shape names, a cache file that is not a table.
    """
    from ..core.checks import check_int, check_number
    from ..importers.ict_arkit import displacements_digest, transfer_ict_displacements

    if not hasattr(sim, "fr") or not hasattr(sim, "muscle_names"):
        raise InputError(f"sim: expected a FaceSimulator, got {type(sim).__name__}")
    refine = check_int("refine", refine, low=0, high=10)
    max_frames = check_int("max_frames", max_frames, low=2, high=1000)
    effort = check_number("effort", effort, low=0.0, high=1.0)
    tol = check_number("tol", tol, low=0.0, high=1e-2, low_open=True)
    if cache is not None:
        if isinstance(cache, bytes) or not isinstance(cache, (str, os.PathLike)) or not str(cache).strip():
            raise InputError(f"cache: expected a folder path, got {cache!r:.80}")
        cache = Path(cache)
        if cache.exists() and not cache.is_dir():
            raise InputError(f"cache: {cache} is not a folder")
    D_ict = _resolve_shapes(shapes, ict_dir)
    settings = {"refine": refine, "effort": effort, "tol": tol, "max_frames": max_frames, "jaw_probe": JAW_PROBE,
                "jaw_side_probe": JAW_SIDE_PROBE, "version": _VERSION}
    key = _digest(rig_key(sim), displacements_digest(D_ict), settings)
    if cache is not None and not rebuild and (cache / ARKIT_TABLE_FILE).is_file():
        t = load_arkit_table(cache / ARKIT_TABLE_FILE)
        if t.key == key:
            t.info["from_cache"] = True
            return t

    t0 = time.perf_counter()
    fr = sim.fr
    fdp_ids, idx = _head_fdps(fr)
    statics = _Statics(sim, idx, tol, max_frames)
    M = len(sim.muscle_names)
    zero_a = np.zeros(M)
    rest = statics(zero_a, (0.0, 0.0))
    total = M + 2 + len([n for n in D_ict if n not in ARKIT_OUT_OF_REACH])
    done = 0

    def tick(name):
        nonlocal done
        done += 1
        if progress:
            progress(done, total, name)

    # 1. transfer the shapes onto this head's FDPs
    rep: dict = {}
    lm = dict(zip(fdp_ids, rest))
    T_head = transfer_ict_displacements(D_ict, rest, lm, point_ids=fdp_ids, ict_dir=ict_dir,
                                        device=str(sim.device) if "cuda" in str(sim.device) else "cpu",
                                        report=rep) if D_ict else {}
    # 2. the linear model: one static probe per control
    cols = []
    todo = [n for n in T_head if n not in ARKIT_OUT_OF_REACH]
    for m in range(M if todo else 0):  # no probes when there is nothing to solve
        a = zero_a.copy()
        a[m] = 1.0
        cols.append((statics(a, (0.0, 0.0)) - rest).ravel())
        tick(sim.muscle_names[m])
    if todo:
        cols.append((statics(zero_a, (JAW_PROBE, 0.0)) - rest).ravel() / JAW_PROBE)
        tick("jaw_open")
        cols.append((statics(zero_a, (0.0, JAW_SIDE_PROBE)) - rest).ravel() / JAW_SIDE_PROBE)
        tick("jaw_side")
    else:
        cols = [np.zeros(rest.size)] * (M + 2)
    B = np.stack(cols, 1)
    lo, hi = _bounds(M)

    def solve(r, x0):
        return _bounded_step(B, effort, r, x0)

    n = len(ARKIT_NAMES)
    acts = np.zeros((n, M), np.float32)
    jaws = np.zeros((n, 2), np.float32)
    solved = np.zeros(n, bool)
    residual = np.full(n, np.nan)
    size = np.full(n, np.nan)
    targets = np.zeros((n, len(fdp_ids), 3))
    reached = np.zeros((n, len(fdp_ids), 3))
    reasons = {k: v for k, v in ARKIT_OUT_OF_REACH.items()}
    per_shape, linear = {}, {}
    for i, name in enumerate(ARKIT_NAMES):
        if name in T_head:  # and the linear model's bounded fit alone (no statics): also for the shapes out of reach
            targets[i] = T_head[name]
            size[i] = float(np.sqrt(np.mean(np.sum(T_head[name] ** 2, axis=1))))
            xl = np.clip(solve(T_head[name].ravel(), np.zeros(M + 2)), lo, hi)
            linear[name] = round(float(np.sqrt(np.mean(np.sum((B @ xl - T_head[name].ravel()).reshape(-1, 3) ** 2,
                                                                axis=1)))) * 1e3, 3)
        if name in ARKIT_OUT_OF_REACH:
            continue
        if name not in T_head:
            reasons[name] = "no ICT-FaceKit shape data found (see facewarp.ict_shape_dirs)"
            continue
        t = T_head[name]
        x, hist, P = _refine_static(statics, B, effort, np.clip(solve(t.ravel(), np.zeros(M + 2)), lo, hi), rest + t, refine)
        acts[i], jaws[i], solved[i], residual[i] = x[:M], x[M:], True, min(hist)
        reached[i] = P - rest
        per_shape[name] = [round(h * 1e3, 3) for h in hist]
        tick(name)
    sim.reset()
    info = {"settings": settings, "rig_key": rig_key(sim),
            "transfer": {k: v for k, v in rep.items() if k != "warp_fdp_residual_m"},
            "statics": statics.count, "static_frames": statics.frames, "static_seconds": round(statics.seconds, 1),
            "build_seconds": round(time.perf_counter() - t0, 1), "residual_history_mm": per_shape,
            "linear_model_residual_mm": linear,
            "from_cache": False}
    table = ArkitTable(names=tuple(ARKIT_NAMES), muscle_names=list(sim.muscle_names), activations=acts, jaw=jaws,
                       solved=solved, residual_m=residual, target_rms_m=size, fdp_ids=fdp_ids,
                       rest_fdp=rest, targets=targets, reached=reached, basis=B, reasons=reasons, key=key, info=info)
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        table.save(cache / ARKIT_TABLE_FILE)
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


def drive_arkit(sim, track, table: ArkitTable, *, sinks=(), progress=None, refine: bool = False,
                mode: str = "offline", unreachable_limit: float = 2e-3, **options):
    """Play an :class:`~facewarp.ArkitTrack` on ``sim`` through its head's :class:`ArkitTable`
    (what :func:`~facewarp.drive` does for an ArkitTrack).

    Each frame's weights become controls by :meth:`ArkitTable.controls` (blend in activation
    space, clamp); with ``refine=True`` the frame is instead tracked by a :class:`~facewarp.Tracker`
    towards its blended target FDPs (:meth:`ArkitTable.targets_for`), starting from the previous
    frame. The track's head rotation, when it has one, drives :meth:`~facewarp.FaceSimulator.set_head_pose`
    (:func:`head_rotation_matrix`, no translation). The per-frame error is each head FDP's distance
    from its blended target (head frame).

    Returns:
        A :class:`~facewarp.DriveResult` (``names``: the table's FDP ids; ``head_poses``: (T, 4, 4)
        when the track has head rotation).
    """
    from ..core.checks import check_number
    from ..sim.play import PlayStats, _as_sink
    from .inverse import DriveResult, Tracker

    if not isinstance(table, ArkitTable):
        raise InputError("table: an ArkitTrack is driven through the head's ARKit table "
                         f"(fw.arkit_table(sim, cache=BUILD)), got {type(table).__name__}")
    if list(table.muscle_names) != list(sim.muscle_names) or table.key_rig != rig_key(sim):
        raise InputError("table: built for another head (or solver) than this simulator's; "
                         "build it with fw.arkit_table(sim, cache=BUILD)")
    if abs(track.fps - sim.fps) > 1e-6 * sim.fps:
        raise InputError(f"track: {track.fps:g} frames/s, but the simulator runs at {sim.fps:g}: "
                         f"make the FaceSimulator with fps={track.fps:g}")
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a callable progress(k, frame_count), got {type(progress).__name__}")
    if not isinstance(refine, (bool, np.bool_)):
        raise InputError(f"refine: expected True or False, got {refine!r}")
    if options and not refine:
        raise InputError(f"{sorted(options)[0]}: a Tracker option, only with refine=True")
    unreachable_limit = check_number("unreachable_limit", unreachable_limit, low=0.0, low_open=True)
    nf = track.frames
    A, J = table.controls(track.weights)
    targets = table.targets_for(track.weights)
    poses = None
    if track.head_rotation is not None:
        poses = np.tile(np.eye(4), (nf, 1, 1))
        for k, (y, p, r) in enumerate(track.head_rotation):
            poses[k, :3, :3] = head_rotation_matrix(y, p, r)
    sinks = [_as_sink(s) for s in sinks]
    _, idx = _head_fdps(sim.fr)
    tracker = Tracker(sim, table.fdp_ids, mode=mode, **options) if refine else None
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
    notes = [f"{n}: out of reach ({table.reasons[n]}); weight up to {track.weights[:, i].max():.2f}"
             for i, n in enumerate(table.names) if n in table.reasons and track.weights[:, i].max() > 0]
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
                       frames_per_second=nf / stepping, mode="arkit-tracker" if refine else "arkit-table",
                       stats=tracker.stats.as_dict() if tracker is not None else {"frames": nf},
                       head_poses=poses)
