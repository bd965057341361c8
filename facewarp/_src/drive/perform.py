"""A performance played on a head through the one frame loop (:func:`~facewarp.play`): the play
sources of a marker take (:class:`MarkerSource`, a :class:`~facewarp.Tracker` solving each frame)
and of ARKit curves (:class:`ArkitSource`, through the head's :class:`~facewarp.takes.ArkitTable`), and
:func:`drive`, which picks the source, retargets an actor's take when asked
(:mod:`.retarget`), plays it and gathers the :class:`~facewarp.takes.DriveResult`.
"""

from __future__ import annotations

import numpy as np

from ..core.checks import check_array, check_bool, check_number
from ..core.errors import InputError
from ..sim.play import Source, play
from .inverse import Tracker
from .result import DriveResult
from .tracks import ArkitTrack, MarkerTrack

__all__ = ["ArkitSource", "MarkerSource", "drive", "head_rest_points"]


class MarkerSource(Source):
    """A marker take as a play source: each frame :meth:`Tracker.update` solves the controls whose
    simulated points match the frame's targets and steps the simulator (frame 0 included).

    Args:
        tracker: The :class:`~facewarp.Tracker` (its simulator is the one played).
        targets: (T, K, 3) float64 [m], the targets in the head's frame, NaN where missing.
        fps: The take's frame rate [1/s].

    After :func:`~facewarp.play`: ``activations`` (T, M) float32, ``jaw`` (T, 2) float32 [rad],
    ``error`` (T, K) float64 [m] (NaN where missing).
    """

    steps_first = True
    name = "tracker"

    def __init__(self, tracker: Tracker, targets, fps: float):
        if not isinstance(tracker, Tracker):
            raise InputError(f"tracker: expected a facewarp Tracker, got {type(tracker).__name__}")
        self.tracker = tracker
        self.targets = check_array("targets", targets, shape=(None, tracker.count, 3), finite=False)
        self.fps = float(fps)
        self.frames = int(len(self.targets))

    def start(self, sim, frame_count: int) -> None:
        self.tracker.reset_tracking()
        M, K = self.tracker.M, self.tracker.count
        self.activations = np.zeros((frame_count, M), np.float32)
        self.jaw = np.zeros((frame_count, 2), np.float32)
        self.error = np.full((frame_count, K), np.nan)

    def apply(self, sim, k: int, t: float) -> None:
        self.activations[k], self.jaw[k] = self.tracker.update(self.targets[k])
        self.error[k] = self.tracker.last_error

    @property
    def steps(self) -> int:
        return int(self.tracker.stats.steps)


class ArkitSource(Source):
    """ARKit curves as a play source: each frame's weights become controls through the head's
    table (:meth:`~facewarp.takes.ArkitTable.controls`: blended in activation space, clamped), the eyes
    turn by :func:`.arkit.track_gaze` (the track's recorded eye angles, else its eyeLook* weights),
    the track's head rotation is the head pose; with ``refine=True`` a :class:`~facewarp.Tracker`
    tracks each frame towards its blended target FDPs instead (:meth:`~facewarp.takes.ArkitTable.targets_for`).

    After :func:`~facewarp.play`: ``activations``, ``jaw``, ``error`` (T, F) float64 [m] (each
    table FDP's distance from its blended target, head frame), ``targets`` (T, F, 3) [m],
    ``poses`` (T, 4, 4) or None, ``gaze`` (T, 2, 2) [rad], ``warnings`` (shapes used but not mapped).

    Raises:
        InputError: a table of another head, a Tracker option without ``refine``, a track of which
        nothing can move this face (every shape it uses unmapped, no head or eye rotation).
    """

    steps_first = True

    def __init__(self, sim, table, track: ArkitTrack, *, refine: bool = False, mode: str = "offline", **options):
        from .arkit import _head_fdps, arkit_warnings, check_table, head_rotation_matrix, track_gaze

        check_table(sim, table)
        refine = check_bool("refine", refine)
        if options and not refine:
            raise InputError(f"{sorted(options)[0]}: a Tracker option, only with refine=True")
        self.warnings, moves = arkit_warnings(track, table)
        if not moves:
            used = [n for n, w in zip(table.names, np.asarray(track.weights).max(axis=0)) if w > 0]
            what = (f"none of the {len(used)} ARKit shapes it uses ({', '.join(used[:4])}"
                    f"{', ...' if len(used) > 4 else ''}) is mapped on this head" if used else "every ARKit weight is 0")
            raise InputError(f"{track.source or 'track'}: the face cannot move: {what}, and the head and eyes do not turn")
        self.table, self.track, self.fps, self.frames = table, track, float(track.fps), int(track.frames)
        self.name = "arkit tracker" if refine else "arkit table"
        self.A, self.J = table.controls(track.weights)
        self.gaze = track_gaze(track, table)
        self.targets = table.targets_for(track.weights)
        self.poses = None
        if track.head_rotation is not None:
            self.poses = np.tile(np.eye(4), (track.frames, 1, 1))
            for k, (y, p, r) in enumerate(track.head_rotation):
                self.poses[k, :3, :3] = head_rotation_matrix(y, p, r)
        _, self._idx = _head_fdps(sim.fr)
        self.tracker = Tracker(sim, table.fdp_ids, mode=mode, **options) if refine else None

    def start(self, sim, frame_count: int) -> None:
        if self.tracker is not None:
            self.tracker.reset_tracking()
        self.activations = np.zeros((frame_count, len(sim.muscle_names)), np.float32)
        self.jaw = np.zeros((frame_count, 2), np.float32)
        self.error = np.zeros((frame_count, len(self.table.fdp_ids)))

    def apply(self, sim, k: int, t: float) -> None:
        from .arkit import _fdp_of

        if self.poses is not None:
            sim.set_head_pose(self.poses[k, :3, :3], np.zeros(3))
        sim.set_eye_gaze(self.gaze[k])
        if self.tracker is None:
            sim.set_activations(self.A[k])
            sim.set_jaw(float(self.J[k, 0]), float(self.J[k, 1]))
            sim.step()
            self.activations[k], self.jaw[k] = sim.activations, sim.jaw_angles
        else:
            self.activations[k], self.jaw[k] = self.tracker.update(self.targets[k])
        self.error[k] = np.linalg.norm(_fdp_of(sim.fr, self._idx, sim.surface(frame="head")) - self.targets[k], axis=1)

    @property
    def steps(self) -> int:
        return int(self.tracker.stats.steps) if self.tracker is not None else None


def head_rest_points(sim, names) -> dict:
    """The head's rest position [m] (shape (3,), its own frame) of each point name: FDP ids and ``v<index>``."""
    fdp = dict(zip((str(i) for i in sim.fr.fdp_ids), sim.fdp_points()))
    skin = sim.surface()
    out = {}
    for n in names:
        if n.startswith("v") and n[1:].isdigit():
            i = int(n[1:])
            if i >= len(skin):
                raise InputError(f"points: {n!r} is beyond the head's {len(skin)} vertices")
            out[n] = skin[i].astype(np.float64)
        elif n in fdp:
            out[n] = np.asarray(fdp[n], dtype=np.float64)
        else:
            raise InputError(f"points: the head has no FDP {n!r}")
    return out


def _notes_off(names, err, limit) -> list:
    notes = []
    bad = np.where(np.nan_to_num(err, nan=0.0) > limit)
    for i in np.unique(bad[1]):
        fr_k = bad[0][bad[1] == i]
        notes.append(f"point {names[i]}: {len(fr_k)} frame(s) off by more than {limit * 1e3:g} mm (worst "
                     f"{np.nanmax(err[:, i]) * 1e3:.2f} mm at frame {int(np.nanargmax(err[:, i]))})")
    return notes


def drive(sim, track, *, table=None, sinks=(), progress=None, mode: str = "offline", head_poses=None,
          unreachable_limit: float = 2e-3, retarget: bool = False, method: str = "fapu", rigid: bool = True,
          **options) -> DriveResult:
    """Solve a performance's activations and jaw per frame and play them on ``sim`` (through
    :func:`~facewarp.play`: the sinks see frame ``k`` at ``t = k / fps``; a
    :class:`~facewarp.FrameRecorder` keeps the frames, a :class:`~facewarp.UsdAnimation` streams them).

    Args:
        sim: The :class:`~facewarp.FaceSimulator` (implicit solver), at the track's frame rate.
        track: A :class:`~facewarp.MarkerTrack` (points in the head's frame, NaN where missing; or,
            with ``retarget=True``, an actor's take in any frame) or an :class:`~facewarp.takes.ArkitTrack`.
        table: For an ArkitTrack: the head's :class:`~facewarp.takes.ArkitTable` (:func:`~facewarp.arkit_table`);
            ``refine=True`` then tracks each frame towards its blended target FDPs.
        sinks: :class:`~facewarp.takes.Sink` objects or callables ``f(sim, k, t)``, called after each frame.
        progress: Optional ``progress(k, frame_count)`` after each frame.
        mode: ``"offline"`` or ``"realtime"`` (:class:`~facewarp.Tracker`).
        head_poses: Optional (T, 4, 4) rigid poses already removed from a marker take, kept in the result.
        unreachable_limit: A frame whose point is farther than this [m] from its target is noted (default 2 mm).
        retarget: The marker take is of another face (an actor): its displacements from its neutral
            (:attr:`~facewarp.MarkerTrack.neutral`, default the first frame) are carried to this head
            (:mod:`retargeting <facewarp._src.drive.retarget>`), the actor's head motion removed first.
        method: The retargeting's map: ``"fapu"`` (MPEG-4 face animation parameter units, default) or
            ``"affine"`` (per region).
        rigid: With ``retarget``: remove the actor's head motion (default True).
        **options: Further keywords of :class:`~facewarp.Tracker` (``smoothness``, ``effort``, ``robust``, ...).

    Returns:
        The :class:`~facewarp.takes.DriveResult` (``targets``: what the error is measured against;
        ``head_poses``: the removed head motion; ``retarget``: the map, when retargeted).

    Raises:
        InputError: a bad argument, a track at another frame rate than ``sim``, unknown point names,
        stable points that cannot give the head motion.
    """
    import time

    from ..sim.simulator import FaceSimulator

    if not isinstance(sim, FaceSimulator):
        raise InputError(f"sim: expected a facewarp FaceSimulator, got {type(sim).__name__}")
    retarget = check_bool("retarget", retarget)
    rigid = check_bool("rigid", rigid)
    unreachable_limit = check_number("unreachable_limit", unreachable_limit, low=0.0, low_open=True)
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a callable progress(k, frame_count), got {type(progress).__name__}")
    if isinstance(track, ArkitTrack):
        if head_poses is not None:
            raise InputError("head_poses: not for an ArkitTrack (its head_rotation drives the head pose)")
        if retarget:
            raise InputError("retarget: only for a marker take (ARKit curves are this head's already)")
        if abs(track.fps - sim.fps) > 1e-6 * sim.fps:
            raise InputError(f"track: {track.fps:g} frames/s, but the simulator runs at {sim.fps:g}: "
                             f"make the FaceSimulator with fps={track.fps:g}")
        refine = options.pop("refine", False)
        src = ArkitSource(sim, table, track, refine=refine, mode=mode, **options)
        stats = play(sim, src, sinks=sinks, progress=progress)
        rms = np.sqrt(np.mean(src.error**2, axis=1))
        notes = list(track.notes) + list(src.warnings)
        if table.info.get("cache_note"):
            notes.append(table.info["cache_note"])
        notes += _notes_off(list(table.fdp_ids), src.error, unreachable_limit)
        return DriveResult(fps=track.fps, names=list(table.fdp_ids), muscle_names=list(sim.muscle_names),
                           activations=src.activations, jaw=src.jaw, error=src.error, rms=rms, unreachable=notes,
                           seconds=stats.simulation_wall_s, frames_per_second=stats.frames_per_second,
                           mode="arkit-tracker" if refine else "arkit-table",
                           stats=src.tracker.stats.as_dict() if src.tracker is not None else {"frames": track.frames},
                           head_poses=src.poses, warnings=list(src.warnings), gaze=src.gaze, targets=src.targets)
    if not isinstance(track, MarkerTrack):
        raise InputError(f"track: expected a facewarp MarkerTrack or ArkitTrack, got {type(track).__name__}")
    if table is not None:
        raise InputError("table: only for an ArkitTrack")
    if abs(track.fps - sim.fps) > 1e-6 * sim.fps:
        raise InputError(f"track: {track.fps:g} frames/s, but the simulator runs at {sim.fps:g}: "
                         f"make the FaceSimulator with fps={track.fps:g}")
    if not retarget and method != "fapu":
        raise InputError(f"method: {method!r} goes with retarget=True (a take of another face)")
    nf = track.frames
    tracker = Tracker(sim, track.names, mode=mode, **options)  # checks the point names against the head
    notes = []
    info = None
    if retarget:
        from .retarget import retarget_track

        if head_poses is not None:
            raise InputError("head_poses: not with retarget (the actor's head motion is fitted here)")
        rest = head_rest_points(sim, track.names)
        t0 = time.perf_counter()
        targets, motion, m = retarget_track(track, rest, method=method, rigid=rigid)
        notes += targets.notes
        info = m.to_dict()
        info["seconds"] = round(time.perf_counter() - t0, 4)
        if motion is not None:
            head_poses = np.tile(np.eye(4), (nf, 1, 1))
            head_poses[:, :3, :3] = motion.rotation
            head_poses[:, :3, 3] = motion.translation
            info["head_motion"] = motion.to_dict()
        track = targets
    else:
        notes += list(track.notes)
        if head_poses is not None:
            head_poses = check_array("head_poses", head_poses, shape=(nf, 4, 4))
    src = MarkerSource(tracker, track.positions, track.fps)
    stats = play(sim, src, sinks=sinks, progress=progress)
    err = src.error
    with np.errstate(invalid="ignore"):
        present = np.isfinite(err)
        rms = np.sqrt(np.where(present.any(1), np.nansum(err**2, 1) / np.maximum(present.sum(1), 1), np.nan))
    never = [n for n, seen in zip(track.names, present.any(0)) if not seen]
    if never:
        notes.append(f"never present: {', '.join(never)}")
    notes += _notes_off(track.names, err, unreachable_limit)
    return DriveResult(fps=track.fps, names=list(track.names), muscle_names=list(sim.muscle_names),
                       activations=src.activations, jaw=src.jaw, error=err, rms=rms, unreachable=notes,
                       seconds=stats.simulation_wall_s, frames_per_second=stats.frames_per_second,
                       mode=tracker.mode, stats=tracker.stats.as_dict(), head_poses=head_poses,
                       targets=track.positions, retarget=info)
