"""One playback path: a :class:`~facewarp.Timeline` played on a simulator, each frame handed to sinks.

:func:`play` is the only loop that steps a simulator through a timeline: frame 0 is the rest,
then per frame ``1 / sim.fps`` it samples the timeline, sets the controls through the
simulator's public methods (:meth:`~facewarp.FaceSimulator.set_activations`; the jaw through a
jaw driver, :mod:`facewarp.coupling`), steps, and calls every sink with the simulator. What is
kept per frame is the sinks' business: :class:`FrameRecorder` keeps every frame as
:class:`Frames` (what :meth:`~facewarp.FaceSimulator.run` returns), the USD writer
(:class:`~facewarp.UsdAnimation`) streams it to disk, the jobs' previews keep a few.

The timeline's chin drops become this head's jaw angles here, once
(:meth:`~facewarp.Timeline.for_head`); a timeline already converted for the head is played as it is.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np

from ..core.errors import InputError
from ..expressions import Timeline
from .frames import Frames
from .readout import fdp_points

__all__ = ["FrameRecorder", "PlayStats", "Sink", "check_seconds", "play"]


# ------------------------------------------------------------------------------------- sinks
@dataclass(frozen=True)
class PlayStats:
    """What one :func:`play` took.

    Attributes:
        frames: Frames played, the rest frame 0 included.
        seconds: Simulated length [s].
        wall_s: Wall-clock time of the whole loop (stepping and sinks) [s].
        simulation_wall_s: Wall-clock time of the stepping alone (the jaw driver's steps: the
            solver, and MuJoCo with its jaw) [s].
        frames_per_second: Simulated frames per second of stepping.
        steps_per_second: Solver substeps per second of stepping.
        realtime_factor: Simulated seconds per second of stepping (1: real time).
        substeps: Solver substeps per frame; dt_s: substep [s].
        device: The simulator's device; jaw: the jaw driver's name.
        frame_stats: The simulator's :attr:`~facewarp.FaceSimulator.stats` as a dict (frames
            sub-stepped by the rollback, the smallest tet volume ratio, frames below the floor).
        mujoco_events: MuJoCo warnings met on the way (the MuJoCo jaw's ``events``; [] otherwise).
    """

    frames: int
    seconds: float
    wall_s: float
    simulation_wall_s: float
    frames_per_second: float
    steps_per_second: float
    realtime_factor: float
    substeps: int
    dt_s: float
    device: str
    jaw: str
    frame_stats: dict
    mujoco_events: list

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def measured(cls, sim, *, frames: int, seconds: float, wall_s: float, stepping_s: float, jaw: str,
                 mujoco_events=()) -> PlayStats:
        """The figures of ``frames`` played (frame 0 the rest, ``frames - 1`` stepped) on the
        :class:`~facewarp.FaceSimulator` ``sim``: ``stepping_s`` [s] of stepping (> 0) in ``wall_s`` [s]."""
        n = frames - 1
        return cls(frames=frames, seconds=seconds, wall_s=wall_s, simulation_wall_s=stepping_s,
                   frames_per_second=n / stepping_s, steps_per_second=n * sim.substeps / stepping_s,
                   realtime_factor=n / sim.fps / stepping_s, substeps=int(sim.substeps), dt_s=float(sim.dt),
                   device=str(sim.device), jaw=jaw, frame_stats=sim.stats.as_dict(), mujoco_events=list(mujoco_events))


class Sink:
    """Receives the frames of :func:`play`. Override :meth:`frame`; :meth:`start` and
    :meth:`finish` are optional. A plain callable ``f(sim, k, t)`` is a sink too."""

    def start(self, sim, frame_count: int) -> None:
        """Called once after the reset, before frame 0, with the number of frames to come."""

    def frame(self, sim, k: int, t: float) -> None:
        """Frame ``k`` at time ``t`` [s]: ``sim`` holds its state."""
        raise NotImplementedError

    def finish(self, sim, stats: PlayStats) -> None:
        """Called once after the last frame."""


class _CallableSink(Sink):
    def __init__(self, f):
        self.f = f

    def frame(self, sim, k: int, t: float) -> None:
        self.f(sim, k, t)


def _as_sink(s) -> Sink:
    if isinstance(s, Sink):
        return s
    if callable(s):
        return _CallableSink(s)
    raise InputError(f"sinks: expected Sink objects or callables f(sim, k, t), got {type(s).__name__}")


class FrameRecorder(Sink):
    """Keeps every frame as :class:`Frames`: the head surface and rigid parts (world frame), the
    muscle fibres, activations and jaw angles; the FDPs follow from them at the end.

    Args:
        curve_samples: Points per muscle fibre polyline.

    After :func:`play`, :attr:`frames` holds the :class:`Frames`.
    """

    def __init__(self, *, curve_samples: int = 24):
        if not (isinstance(curve_samples, (int, np.integer)) and curve_samples >= 2):
            raise InputError(f"curve_samples: expected a whole number >= 2, got {curve_samples!r}")
        self.curve_samples = int(curve_samples)
        self.frames: Frames | None = None

    def start(self, sim, frame_count: int) -> None:
        fr = sim.fr
        nf, m = frame_count, len(sim.muscle_names)
        self.times = np.arange(nf) / sim.fps
        self.points = np.zeros((nf, len(fr.head_vertices), 3), np.float32)
        self.activations = np.zeros((nf, m), np.float32)
        self.jaw = np.zeros((nf, 2), np.float32)
        self.curves = np.zeros((nf, m, self.curve_samples, 3), np.float32)
        self.parts = {k: np.zeros((nf, len(V), 3), np.float32) for k, (V, _) in fr.parts.items()}

    def frame(self, sim, k: int, t: float) -> None:
        self.points[k] = sim.surface()
        self.activations[k], self.jaw[k] = sim.activations, sim.jaw_angles
        self.curves[k] = sim.muscle_curves(self.curve_samples)
        for name, P in sim.part_points().items():
            self.parts[name][k] = P

    def finish(self, sim, stats: PlayStats) -> None:
        fr = sim.fr
        self.frames = Frames(self.times, self.points, fr.head_faces, fr.fdp_ids,
                             fdp_points(fr, self.points, self.parts),
                             {k: (v, fr.parts[k][1]) for k, v in self.parts.items()}, list(sim.muscle_names),
                             self.curves, self.activations, self.jaw, stats.steps_per_second, sim.substeps, sim.dt,
                             frames_per_second=stats.frames_per_second, realtime_factor=stats.realtime_factor,
                             solver=sim.solver_name, material=sim.material.name)


# -------------------------------------------------------------------------------------- play
def check_seconds(seconds) -> float:
    """``seconds`` as a float if it is a finite number > 0, else :class:`InputError`."""
    if not (isinstance(seconds, (int, float, np.integer, np.floating)) and not isinstance(seconds, bool)
            and math.isfinite(seconds) and seconds > 0):
        raise InputError(f"seconds: expected a finite number > 0, got {seconds!r}")
    return float(seconds)


def play(sim, timeline: Timeline, seconds: float, *, sinks=(), jaw=None, progress=None) -> PlayStats:
    """Play ``seconds`` of ``timeline`` on ``sim`` from rest, handing every frame to ``sinks``.

    Frame ``k`` is at ``k / sim.fps`` s; frame 0 is the rest (:meth:`~facewarp.FaceSimulator.reset`:
    no activation, jaw closed), then each frame sets the timeline's activations
    (:meth:`~facewarp.FaceSimulator.set_activations`) and lets the jaw driver set the jaw and step
    (the controls ramp across the step, :meth:`~facewarp.FaceSimulator.step`).

    Args:
        sim: The :class:`~facewarp.FaceSimulator`.
        timeline: The expressions over time; its chin drops become this head's jaw angles
            (:meth:`~facewarp.Timeline.for_head`) unless it is already converted for it.
        seconds: Length [s], > 0.
        sinks: :class:`Sink` objects or callables ``f(sim, k, t)``, called in order after each frame.
        jaw: A jaw driver (``step(expression)`` sets the jaw and steps ``sim`` one frame; ``name``):
            default the kinematic jaw (:class:`~facewarp.coupling.KinematicJawDriver`); the
            MuJoCo jaw is :class:`~facewarp.coupling.MujocoJawDriver`.
        progress: Optional ``progress(k, frame_count)`` after each frame.

    Returns:
        The :class:`PlayStats` (also handed to every sink's ``finish``).

    Raises:
        InputError: ``seconds`` not a finite number > 0, ``timeline`` not a Timeline, a bad sink.
    """
    check_play_arguments(sim, jaw, progress)
    seconds = check_seconds(seconds)
    if not isinstance(timeline, Timeline):
        raise InputError(f"timeline: expected a facewarp Timeline, got {type(timeline).__name__}")
    if isinstance(sinks, (str, bytes)) or not hasattr(sinks, "__iter__"):
        raise InputError(f"sinks: expected a list of Sink objects or callables f(sim, k, t), got {type(sinks).__name__}")
    sinks = [_as_sink(s) for s in sinks]
    check_play_length(sim, seconds, sinks)
    return _play(sim, timeline, seconds, sinks, jaw, progress)


def check_play_arguments(sim, jaw, progress) -> None:
    """The types of :func:`play`'s ``sim``, ``jaw`` and ``progress``: :class:`InputError` naming the argument."""
    from .simulator import FaceSimulator

    if not isinstance(sim, FaceSimulator):
        raise InputError(f"sim: expected a FaceSimulator, got {type(sim).__name__}")
    if jaw is not None and not (callable(getattr(jaw, "step", None)) and not isinstance(jaw, (str, bytes))):
        raise InputError(f"jaw: expected a jaw driver (facewarp.coupling.KinematicJawDriver or MujocoJawDriver) or "
                         f"None, got {type(jaw).__name__} {jaw!r:.40}")
    if jaw is not None and getattr(jaw, "sim", sim) is not sim:
        raise InputError("jaw: the jaw driver drives another simulator than sim")
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a callable progress(k, frame_count) or None, got {type(progress).__name__}")


def check_play_length(sim, seconds: float, sinks=()) -> None:
    """A run of ``seconds`` at ``sim.fps`` within :data:`~facewarp._src.core.limits.MAX_ADVANCE_FRAMES`
    frames and this machine's time; a :class:`FrameRecorder` among ``sinks`` keeps every frame,
    so its memory is checked too. The refusal states the estimates."""
    from ..core.limits import MAX_ADVANCE_FRAMES, check_work, describe_seconds, estimate_frames_bytes, estimate_seconds

    frames = seconds * sim.fps
    V = len(sim.fr.head_vertices)
    if not frames <= MAX_ADVANCE_FRAMES:
        t = estimate_seconds(frames, str(sim.device), V)
        raise InputError(f"seconds: {seconds:g} s at {sim.fps:g} fps is {frames:.3g} frames (about "
                         f"{describe_seconds(t)} on {sim.device}), more than {MAX_ADVANCE_FRAMES:,} per run")
    keep = sum(isinstance(s, FrameRecorder) for s in sinks)
    check_work(f"seconds: {seconds:g} s at {sim.fps:g} fps", head_frames=frames, vertex_count=V,
               device=str(sim.device), memory_bytes=keep * estimate_frames_bytes(frames + 1, V))


def _play(sim, timeline: Timeline, seconds: float, sinks: list, jaw, progress) -> PlayStats:
    """:func:`play` on checked inputs."""
    if jaw is None:
        from ..coupling.drivers import KinematicJawDriver

        jaw = KinematicJawDriver(sim)
    timeline = timeline.for_head(sim.fr)  # chin drops -> this head's jaw angles (once per timeline)
    sim.reset()
    nf = int(round(seconds * sim.fps)) + 1
    for s in sinks:
        s.start(sim, nf)
    t0 = time.perf_counter()
    stepping = 0.0
    for k in range(nf):
        t = k / sim.fps
        if k > 0:
            e = timeline.sample(t)
            sim.set_activations(e)
            s0 = time.perf_counter()
            jaw.step(e)  # the stepping: what frames_per_second measures
            stepping += time.perf_counter() - s0
        for s in sinks:
            s.frame(sim, k, t)
        if progress:
            progress(k, nf)
    wall = time.perf_counter() - t0
    stepping = max(stepping, 1e-9)
    stats = PlayStats.measured(sim, frames=nf, seconds=seconds, wall_s=wall, stepping_s=stepping,
                               jaw=str(getattr(jaw, "name", type(jaw).__name__)),
                               mujoco_events=getattr(getattr(jaw, "coupler", None), "events", ()))
    for s in sinks:
        s.finish(sim, stats)
    return stats
