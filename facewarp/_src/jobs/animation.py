"""A simulated face streamed into a USD animation, frame by frame as it is simulated.

:class:`UsdAnimation` wraps :class:`usd_export.AnimationWriter` for one face rig: the whole head
(:meth:`FaceSimulator.surface`: the simulated face written into the template's full mesh, the
rest moved by the jaw), the rigid parts as ``Xform``\\ s with time-sampled transforms (lower teeth
and tongue turn with the jaw by their jaw amount: the jaw transform is the rotation about
``jaw_pivot`` by the jaw angles of Sec. 6.4.3; eyes and upper teeth stay), and the muscles as
``BasisCurves`` with their activations. :func:`play_timeline` steps a simulator through a
timeline and hands each frame to callbacks (the USD writer, picture makers), keeping no frames.

The file appears only when the animation is complete (``usd_export`` writes to a temporary
folder and renames); an error or Ctrl-C leaves nothing behind.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..expressions import Timeline

__all__ = ["JAWS", "MUSCLE_SAMPLES", "USD_SUFFIXES", "UsdAnimation", "check_usd_path", "load_mjcf", "part_points",
           "part_transforms", "peak_frames", "play_timeline", "sim_controls"]

USD_SUFFIXES = (".usda", ".usdc", ".usdz")
"""File types of USD animations: text, binary crate, package."""

MUSCLE_SAMPLES = 24
"""Points per muscle curve in the USD (as in :meth:`FaceSimulator.run`)."""

JAWS = ("kinematic", "mujoco")
"""How the jaw is driven: the kinematic jaw of Eq. 6.4.9 (angles set per frame) or the MuJoCo
hinge body of ``head.xml`` (angles as actuator targets, two-way coupled)."""


def check_usd_path(path, name: str = "out") -> Path:
    """``path`` as a Path ending in .usda, .usdc or .usdz whose folder exists, else :class:`InputError`."""
    p = Path(path)
    if p.suffix.lower() not in USD_SUFFIXES:
        raise InputError(f"{name} {p}: expected a file ending in {', '.join(USD_SUFFIXES)}")
    if p.is_dir():
        raise InputError(f"{name} {p}: is a folder, expected a USD file name")
    if not p.parent.is_dir():
        raise InputError(f"{name} {p}: folder {p.parent} does not exist")
    return p


def _rigid_matrix(f) -> np.ndarray:
    """The 4x4 row-vector matrix (``p' = p @ M``) of an affine map ``f`` of (k, 3) points."""
    O = f(np.zeros((1, 3)))[0]
    M = np.eye(4)
    M[:3, :3] = f(np.eye(3)) - O
    M[3, :3] = O
    return M


def part_transforms(fr, jaw_angles) -> dict:
    """Rest-to-current transform of every rigid part of ``fr`` at ``jaw_angles`` (u, v) [rad].

    Returns:
        name -> 4x4 float64 matrix in USD's row-vector convention (``p' = p @ M``): identity for
        parts with jaw amount 0 (eyes, upper teeth), the jaw rotation about ``fr.jaw_pivot``
        scaled by the part's amount for the others (lower teeth and tongue: 1).
    """
    jaw = fr.jaw
    u, v = float(jaw_angles[0]), float(jaw_angles[1])
    out = {}
    for name in fr.parts:
        a = float(fr.part_jaw.get(name, 0.0))
        if a == 0.0 or (u == 0.0 and v == 0.0):
            out[name] = np.eye(4)
        else:
            out[name] = _rigid_matrix(lambda P, a=a: jaw.apply(P, np.full(len(P), a), u, v))
    return out


def part_points(fr, jaw_angles) -> dict:
    """Vertices [m] of every rigid part of ``fr`` at ``jaw_angles`` (u, v) [rad]: name -> (k, 3)
    float64 (:meth:`FaceRig.part_at` of each part)."""
    return {name: fr.part_at(name, jaw_angles) for name in fr.parts}


def peak_frames(timeline: Timeline, seconds: float, fps: float) -> list[tuple[str, int]]:
    """(name, frame) of the peak of each segment of ``timeline`` that starts within ``seconds``.

    The peak is the end of the segment's hold (the expression at full weight and longest held,
    before its release and before the next segment of a sequence ramps in), or the last frame
    where the run ends earlier; frame ``k`` is at ``k / fps`` s, frame 0 the rest.
    """
    last = int(round(seconds * fps))
    out = []
    for s in timeline.segments:
        if s.start < seconds:
            held = int(np.floor((s.start + s.attack + s.hold) * fps + 1e-9))
            out.append((s.expression.name, min(last, max(1, held))))
    return out or [("end", last)]


def sim_controls(sim) -> tuple[np.ndarray, np.ndarray]:
    """The activations (M,) and jaw angles (2,) [rad] the simulator reached at its last step
    (those :meth:`FaceSimulator.surface` uses)."""
    return np.asarray(sim.activations, np.float32), np.asarray(sim.jaw_angles, np.float64)


def muscle_curves(sim, samples: int = MUSCLE_SAMPLES) -> np.ndarray:
    """Muscle fibre polylines [m] of the simulator's current state, shape (M, samples, 3)."""
    return sim.muscle_curves(samples)


class UsdAnimation:
    """Stream a simulator's frames into a USD file (see the module docstring).

    Use as a context manager; :meth:`add` writes the simulator's current state::

        with UsdAnimation("take.usdc", sim) as usd:
            for k in range(frames):
                sim.step()
                usd.add(sim, (k + 1) / sim.fps)

    Args:
        path: ``.usda``, ``.usdc`` or ``.usdz`` file.
        sim: The :class:`~facewarp.FaceSimulator` (its rig, fps and rest muscles are read).
        muscle_samples: Points per muscle curve.
        tets: Also write the skin's tet layer as a ``TetMesh`` (purpose ``guide``) with
            time-sampled nodes.

    Raises:
        InputError: a bad path (extension, missing folder) or input the writer refuses.
    """

    def __init__(self, path, sim, *, muscle_samples: int = MUSCLE_SAMPLES, tets: bool = False):
        from usd_export import AnimationWriter, UsdExportError

        self.path = check_usd_path(path)
        self.fr = fr = sim.fr
        self.samples = int(muscle_samples)
        self.tets = bool(tets)
        self._error = UsdExportError
        try:
            self.writer = AnimationWriter(self.path, fps=sim.fps, faces=fr.head_faces, rest_points=fr.head_vertices,
                                          parts=dict(fr.parts), muscles=list(fr.rig.names),
                                          muscle_samples=self.samples, muscle_rest=muscle_curves(sim, self.samples),
                                          tets=(fr.tets, fr.nodes) if self.tets else None)
        except UsdExportError as e:
            raise InputError(str(e)) from None

    @property
    def frame_count(self) -> int:
        return self.writer.frame_count

    def add(self, sim, time_s: float) -> None:
        """Write the simulator's current state as the frame at ``time_s`` [s]."""
        a, j = sim_controls(sim)
        try:
            self.writer.add_frame(time_s, sim.surface(), part_transforms=part_transforms(self.fr, j),
                                  muscle_points=muscle_curves(sim, self.samples), activations=a,
                                  tet_points=sim.positions() if self.tets else None)
        except self._error as e:
            raise InputError(str(e)) from None

    def close(self) -> Path:
        return self.writer.close()

    def abort(self) -> None:
        self.writer.abort()

    def __enter__(self) -> UsdAnimation:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.writer.__exit__(exc_type, exc, tb)


class _KinematicJaw:
    """The jaw angles set directly each frame (Eq. 6.4.9)."""

    def __init__(self, sim):
        self.sim = sim

    def step(self, expr) -> None:
        self.sim.set_jaw(expr.jaw_u, expr.jaw_v)
        self.sim.step()


def load_mjcf(mjcf):
    """The ``mujoco.MjModel`` of a head's ``head.xml``; a missing or broken file is one
    :class:`InputError` line naming it (MuJoCo's parse errors span several lines)."""
    from ..coupling.mujoco import _mujoco

    mj = _mujoco()
    if mjcf is None or not Path(mjcf).is_file():
        raise InputError(f"jaw: the MuJoCo jaw needs the head's head.xml, not found at {mjcf}")
    try:
        return mj.MjModel.from_xml_path(str(mjcf))
    except Exception as e:  # MuJoCo's parse errors are multi-line ValueErrors
        raise InputError(f"{mjcf}: not a valid MuJoCo model ({' '.join(str(e).split())})") from None


class _MujocoJawDriver:
    """The jaw as the MuJoCo hinge body of ``head.xml``: the expression's angles are the actuator
    targets, :class:`~facewarp.coupling.MujocoJaw` steps skin and body together."""

    def __init__(self, sim, mjcf):
        from ..coupling.mujoco import MujocoJaw, _mujoco

        mj = _mujoco()
        self.model = load_mjcf(mjcf)
        self.data = mj.MjData(self.model)
        self.coupler = MujocoJaw(sim, self.model, self.data)
        self.act = [mj.mj_name2id(self.model, mj.mjtObj.mjOBJ_ACTUATOR, n) for n in ("jaw_open", "jaw_side")]

    def step(self, expr) -> None:
        for i, target in zip(self.act, (expr.jaw_u, expr.jaw_v)):
            if i >= 0:
                self.data.ctrl[i] = target
        self.coupler.step()


def jaw_driver(sim, jaw: str = "kinematic", *, mjcf=None):
    """The object that advances ``sim`` one frame toward an expression's jaw angles.

    Args:
        sim: The simulator.
        jaw: One of :data:`JAWS`.
        mjcf: ``head.xml`` of the head (for ``"mujoco"``).
    """
    if jaw == "kinematic":
        return _KinematicJaw(sim)
    if jaw == "mujoco":
        return _MujocoJawDriver(sim, mjcf)
    raise InputError(f"jaw: expected one of {', '.join(JAWS)}, got {jaw!r}")


def play_timeline(sim, timeline: Timeline, seconds: float, *, on_frame=(), progress=None, jaw: str = "kinematic",
                  mjcf=None) -> dict:
    """Simulate ``seconds`` of ``timeline`` from rest, one frame every ``1 / sim.fps``, frame 0 at
    rest, calling ``f(sim, k, t)`` for each ``f`` in ``on_frame`` after frame ``k`` at time ``t``.

    Nothing is kept per frame here: the callbacks decide what to keep (a USD writer streams it
    to disk). Activations and jaw angles ramp across each step (:meth:`FaceSimulator.step`).

    Args:
        sim: The :class:`~facewarp.FaceSimulator` (reset first).
        timeline: The expressions over time (its chin drops are converted by the head's lever,
            :meth:`Timeline.for_head`).
        seconds: Length [s], > 0.
        on_frame: Callbacks ``f(sim, k, t)``.
        progress: Optional ``progress(k, frame_count)`` after each frame.
        jaw: ``"kinematic"`` or ``"mujoco"`` (:data:`JAWS`).
        mjcf: ``head.xml`` for the MuJoCo jaw.

    Returns:
        ``frames``, ``seconds`` (simulated), ``wall_s``, ``frames_per_second`` (simulated frames
        per wall-clock second, the first step included), ``steps_per_second`` (substeps per
        wall-clock second), ``substeps``, ``dt_s``, ``device``, ``jaw``.
    """
    if not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds > 0):
        raise InputError(f"seconds: expected a finite number > 0, got {seconds!r}")
    driver = jaw_driver(sim, jaw, mjcf=mjcf)
    callbacks = [on_frame] if callable(on_frame) else list(on_frame)
    timeline = timeline.for_head(sim.fr)  # chin drops -> this head's jaw angles
    sim.reset()
    nf = int(round(seconds * sim.fps)) + 1
    t0 = time.perf_counter()
    sim_wall = 0.0
    for k in range(nf):
        t = k / sim.fps
        e = timeline.sample(t)
        sim.set_activations(e)
        if k > 0:
            s0 = time.perf_counter()
            driver.step(e)
            sim_wall += time.perf_counter() - s0
        for f in callbacks:
            f(sim, k, t)
        if progress:
            progress(k, nf)
    wall = time.perf_counter() - t0
    steps = (nf - 1) * sim.substeps
    return {"frames": nf, "seconds": float(seconds), "wall_s": wall, "simulation_wall_s": sim_wall,
            "frames_per_second": (nf - 1) / max(sim_wall, 1e-9), "steps_per_second": steps / max(sim_wall, 1e-9),
            "substeps": int(sim.substeps), "dt_s": float(sim.dt), "device": str(sim.device), "jaw": jaw}
