"""The file-level job behind ``facewarp drive``: a performance (a marker take, or ARKit curves) on a
``build`` output, solved into muscle activations and jaw angles per frame and played.

Steps: the take is read and checked first (:mod:`~facewarp._src.drive.formats`), then the face
rig; a marker take's points are checked against the head (FDP ids it has, vertices in range), its
rigid head motion removed when it has three or more stable points
(:func:`~facewarp.takes.remove_head_motion`), and :func:`~facewarp.drive` solves and plays it through
the sinks (frames kept, the USD animation streamed). ARKit curves go through the head's ARKit
table (built once and cached in the build folder).

Outputs (a folder): ``activations.csv`` (per frame the time, every muscle's activation and the jaw's
opening and side angles), ``frames.npz`` (as ``simulate`` writes), ``animation.usdc``,
``report.json`` (per frame and point the distance simulated to target, what was out of reach, the
head poses) and two pictures, ``drive.png`` (targets and simulated points on the simulated head at
a few frames) and ``activations.png`` (the curves over time). A ``.usda`` / ``.usdc`` / ``.usdz``
output is the USD animation alone.
"""

from __future__ import annotations

import csv
import io
import time
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fileio import atomic_write, write_json
from ..core.limits import MAX_FPS, check_memory, estimate_sim_bytes
from ..drive.formats import _VERTEX, load_arkit, load_markers
from ..drive.arkit import ARKIT_TABLE_FILE
from ..drive.rigid import STABLE_POINTS, remove_head_motion
from ..drive.tracks import ArkitTrack, MarkerTrack
from ..physics.face_rig import load_face_rig
from ..present.plot import line_chart
from ..present.render import render_mesh, save_png
from ..sim.frames import save_frames_npz
from ..sim.play import FrameRecorder
from ..sim.simulator import FaceSimulator
from .animation import USD_SUFFIXES, UsdAnimation, check_usd_path
from .checks import check_out_dir, make_out_dir

__all__ = ["MAX_DRIVE_FRAMES", "USD_NAME", "drive_files", "load_performance"]

USD_NAME = "animation.usdc"
"""The USD animation ``drive`` writes into its output folder."""

MAX_DRIVE_FRAMES = 100_000
"""Most frames one ``drive`` run keeps in memory (as ``simulate``'s :data:`MAX_FRAMES`)."""

PICTURE_FRAMES = 3
"""Frames shown in ``drive.png``: the first, the one whose targets moved most, the last (the middle
one when these coincide)."""

CROSS_M = 0.003
"""Half the size [m] of the cross that marks a simulated point in ``drive.png``."""


def load_performance(*, markers=None, arkit=None, mediapipe=None, map=None, units=None,  # noqa: A002
                     fps=None) -> MarkerTrack | ArkitTrack:
    """The track of exactly one of ``markers`` (JSON, CSV or C3D), ``arkit`` (Live Link Face CSV)
    or ``mediapipe`` (MediaPipe Face Landmarker JSON); ``map``, ``units`` go with markers."""
    given = [k for k, v in (("markers", markers), ("arkit", arkit), ("mediapipe", mediapipe)) if v is not None]
    if len(given) != 1:
        raise InputError("drive: give exactly one of markers, arkit or mediapipe"
                         + (f" (got {', '.join(given)})" if given else ""))
    if markers is not None:
        return load_markers(markers, map=map, units=units, fps=fps)
    if map is not None or units is not None:
        raise InputError("map, units: they go with markers (ARKit curves have neither)")
    path = arkit if arkit is not None else mediapipe
    want = ".csv" if arkit is not None else ".json"
    if Path(path).suffix.lower() != want:
        raise InputError(f"{path}: expected a {'Live Link Face .csv' if arkit is not None else 'MediaPipe .json'} file")
    return load_arkit(path, fps=fps)


def _check_points(track: MarkerTrack, fr) -> None:
    ids = {str(i) for i in fr.fdp_ids}
    n = len(fr.head_vertices)
    for name in track.names:
        if _VERTEX.match(name):
            if int(name[1:]) >= n:
                raise InputError(f"{track.source}: marker {name!r} is beyond the head's {n} vertices")
        elif name not in ids:
            raise InputError(f"{track.source}: the head has no FDP {name!r}")


def _rest_points(sim, names) -> dict:
    """The head's rest position [m] of each point name (FDP ids and ``v<index>``)."""
    fdp = dict(zip((str(i) for i in sim.fr.fdp_ids), sim.fdp_points()))
    skin = sim.surface()
    return {n: (skin[int(n[1:])] if _VERTEX.match(n) else fdp[n]).astype(np.float64) for n in names}


def _simulated_points(frames, names) -> np.ndarray:
    """(f, K, 3) [m] of the named points in recorded frames."""
    ids = [str(i) for i in frames.fdp_ids]
    cols = [frames.points[:, int(n[1:])] if _VERTEX.match(n) else frames.fdp_points[:, ids.index(n)] for n in names]
    return np.stack(cols, axis=1).astype(np.float64)


def _write_activations_csv(path: Path, times, muscles, A, J) -> None:
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["frame", "time_s", *muscles, "jaw_open_rad", "jaw_side_rad"])
    for k in range(len(A)):
        w.writerow([k, f"{times[k]:.6f}", *(f"{v:.6g}" for v in A[k]), f"{J[k, 0]:.6g}", f"{J[k, 1]:.6g}"])
    with atomic_write(path, "w") as f:
        f.write(out.getvalue())


def _picture(path: Path, frames, names, targets, device: str) -> None:
    """Targets (red) and simulated points (blue) on the simulated head at a few frames."""
    sim_pts = _simulated_points(frames, names)
    T = len(targets)
    moved = np.nan_to_num(np.linalg.norm(targets - targets[:1], axis=2), nan=0.0).max(axis=1)
    picks = {0, int(np.argmax(moved)), T - 1}
    if len(picks) < PICTURE_FRAMES and T > 2:
        picks.add(T // 2)
    picks = sorted(picks)
    blue = (0.1, 0.25, 0.85)
    tiles = []
    for k in picks:
        ok = np.isfinite(targets[k]).all(axis=1)
        crosses = []
        for p in sim_pts[k] + (0.0, 0.0, CROSS_M):  # a cross at each simulated point, lifted off the skin
            for d in ((CROSS_M, 0.0, 0.0), (0.0, CROSS_M, 0.0)):
                crosses.append((np.array([p - d, p + d]), blue))
        tiles.append(render_mesh(frames.points[k], frames.faces, points=targets[k][ok], point_color=(0.85, 0.1, 0.1),
                                 extra_meshes=[(V[k], F, (0.85, 0.85, 0.8)) for V, F in frames.parts.values()],
                                 point_radius=4.0, polylines=crosses, line_width=2.5, width=360, height=400,
                                 depth_tolerance=0.004, frame_points=np.concatenate([targets[k][ok], sim_pts[k]]),
                                 device=device))
    save_png(path, np.concatenate(tiles, axis=1),
             title="frames " + ", ".join(str(k) for k in picks) + ": targets red dots, simulated blue crosses")


def _activation_picture(path: Path, times, muscles, A, J) -> None:
    """The most active muscles' curves (up to 5 with the jaw) over time."""
    peak = A.max(axis=0) if len(A) else np.zeros(len(muscles))
    top = [int(i) for i in np.argsort(-peak)[:4] if peak[i] > 0]
    series = {muscles[i]: A[:, i] for i in top}
    series["jaw opening / 30 deg"] = J[:, 0] / np.radians(30.0)
    end = float(times[-1]) if len(times) > 1 else 1.0
    ticks = np.linspace(0.0, end, min(len(times), 6))
    line_chart(path, times, series, title="activations", xlabel="time [s]", ylabel="activation",
               xticks=np.round(ticks, 3))


def drive_files(build, out, *, markers=None, arkit=None, mediapipe=None, map=None, units=None,  # noqa: A002
                fps=None, rigid: bool = True, device: str = "cpu", progress=None, table_progress=None,
                rig=None) -> dict:
    """Drive the face of a ``build`` output from a performance file and write the results.

    Args:
        build: A ``facewarp build`` output folder.
        out: Output folder (``activations.csv``, ``frames.npz``, ``animation.usdc``,
            ``report.json``, ``drive.png``, ``activations.png``), or a ``.usda`` / ``.usdc`` /
            ``.usdz`` file (the animation alone).
        markers, arkit, mediapipe: Exactly one performance file (:func:`load_performance`).
        map, units, fps: For marker takes (:func:`~facewarp.load_markers`); ``fps`` also for
            ARKit files that cannot tell their rate.
        rigid: Remove the take's rigid head motion (needs three stable points; else the take is
            taken as already in the head's frame, and the report says so).
        device: Warp device.
        progress: ``f(k, n)`` per frame.
        table_progress: ``f(done, total, name)`` while the head's ARKit table is built (the first
            ARKit run on a build: minutes; later runs read ``arkit_table.npz`` from the build folder).
        rig: Optional ``facewarp rig --out DIR`` folder of this head: the take is also written as an
            animation of that rig (``take.glb``, ``take.usdc``; ARKit weights on its ARKit shapes,
            else muscle weights) with the error of the rig's linear blend against the simulated
            frames in the report (``rig_take``; :class:`~facewarp._src.bake.take.RigTake`).

    Returns:
        The report (what ``report.json`` holds, less the per-frame arrays).
    """
    t0 = time.perf_counter()
    track = load_performance(markers=markers, arkit=arkit, mediapipe=mediapipe, map=map, units=units, fps=fps)
    usd_out = Path(out).suffix.lower() in USD_SUFFIXES
    out = check_usd_path(out) if usd_out else check_out_dir(out)
    if track.fps > MAX_FPS:
        raise InputError(f"{track.source}: {track.fps:g} fps is above the simulator's {MAX_FPS:g}")
    if not usd_out and track.frames > MAX_DRIVE_FRAMES:
        raise InputError(f"{track.source}: {track.frames} frames, more than {MAX_DRIVE_FRAMES} per run")
    baked = None
    if rig is not None and usd_out:
        raise InputError("--rig: the take on the rig is written into an output folder (take.glb, take.usdc); "
                         "give --out DIR")
    if rig is not None:  # the rig to put the take on, read before the heavy work
        from ..bake.blendshapes import load_rig

        baked = load_rig(rig)
    fr = load_face_rig(build)
    fr_dir = Path(build) if Path(build).is_dir() else Path(build).parent
    check_memory(estimate_sim_bytes(len(fr.nodes), len(fr.tets), track.frames, len(fr.head_vertices)),
                 f"{track.source}: {track.frames} frames of a head of {len(fr.nodes)} nodes")
    motion = None
    notes = []
    if isinstance(track, MarkerTrack):
        _check_points(track, fr)
    sim = FaceSimulator(fr, device=device, fps=track.fps)
    if isinstance(track, MarkerTrack) and rigid:
        stable = [p for p in STABLE_POINTS if p in track.names]
        if len(stable) >= 3:
            track, motion = remove_head_motion(track, _rest_points(sim, track.names))
        else:
            notes.append(f"head motion not removed: the take has {len(stable)} of the stable points "
                         f"{', '.join(STABLE_POINTS)} (it is taken as in the head's frame)")
    table = None
    if isinstance(track, ArkitTrack):
        from ..drive.arkit import arkit_table

        step = table_progress or (lambda done, total, name: None)
        used = [n for n, w in zip(track.names, np.asarray(track.weights).max(axis=0)) if w > 0]
        table = arkit_table(sim, cache=fr_dir, progress=step, solve=used)  # the shapes the take uses, added to the cache
    from ..drive.inverse import drive

    keep = None if usd_out else FrameRecorder()
    usd_path = out if usd_out else out / USD_NAME
    if not usd_out:
        make_out_dir(out)
    anim = UsdAnimation(usd_path, sim)
    take = None
    if baked is not None:
        from ..bake.take import RigTake

        take = RigTake(baked, track.weights if isinstance(track, ArkitTrack) else None, fps=track.fps)
    sinks = [s for s in (keep, anim, take) if s is not None]
    poses = None
    if motion is not None:  # the removed poses as 4x4 maps rest -> take (scale in the 3x3 block)
        poses = np.tile(np.eye(4), (motion.frames, 1, 1))
        poses[:, :3, :3] = motion.scale[:, None, None] * motion.rotation
        poses[:, :3, 3] = motion.translation
    with anim:
        result = drive(sim, track, table=table, sinks=sinks, progress=progress,
                       **({"head_poses": poses} if poses is not None else {}))
    A = np.asarray(result.activations, dtype=np.float64)
    J = np.asarray(result.jaw, dtype=np.float64)
    times = np.arange(len(A)) / track.fps
    names = list(result.names)
    err = np.asarray(result.error, dtype=np.float64)
    ok = np.isfinite(err)
    rep = {
        "build": str(build), "source": track.source, "kind": "markers" if isinstance(track, MarkerTrack) else "arkit",
        "frames": int(len(A)), "fps": track.fps, "device": str(sim.device), "mode": result.mode,
        "frames_per_second": float(result.frames_per_second), "muscles": list(sim.muscle_names),
        "points": names,
        "error_mm": {"rms": float(np.sqrt(np.mean(err[ok] ** 2)) * 1e3) if ok.any() else None,
                     "max": float(err[ok].max() * 1e3) if ok.any() else None,
                     "per_point_rms": {n: (float(np.sqrt(np.nanmean(err[:, k] ** 2)) * 1e3) if ok[:, k].any() else None)
                                       for k, n in enumerate(names)}},
        "notes": notes + list(result.unreachable), "seconds": None, "files": [],
    }
    if isinstance(track, ArkitTrack):
        rep["error_is"] = "distance of each head FDP from its blended ARKit target (the table's shapes, head frame)"
        rep["out_of_reach"] = table.out_of_reach()
        rep["warnings"] = list(result.warnings)
        rep["reach"] = [r for r in table.reach() if r["name"] in track.names and np.max(track.curve(r["name"])) > 0]
        rep["table"] = {"file": str(fr_dir / ARKIT_TABLE_FILE), "from_cache": bool(table.info.get("from_cache")),
                        "cached": not table.info.get("cache_note"), "source": table.info.get("source")}
    report_full = dict(rep)
    report_full["error_per_frame_mm"] = [[None if not np.isfinite(v) else round(float(v) * 1e3, 4) for v in row]
                                         for row in err]
    if motion is not None:
        rep["head_motion"] = {"stable_points": list(motion.points), "frames_held": int(motion.held.sum())}
        report_full["head_motion"] = motion.to_dict()
    elif result.head_poses is not None:  # ARKit's head rotation, played as the head pose
        R = np.asarray(result.head_poses)[:, :3, :3]
        report_full["head_motion"] = {"yaw_pitch_roll_deg": np.round(np.degrees(track.head_rotation), 3).tolist(),
                                      "rotation": np.round(R, 6).tolist()}
    if usd_out:
        rep["files"] = [str(out)]
    else:
        frames = keep.frames
        save_frames_npz(out / "frames.npz", frames)
        _write_activations_csv(out / "activations.csv", times, list(sim.muscle_names), A, J)
        _activation_picture(out / "activations.png", times, list(sim.muscle_names), A, J)
        if isinstance(track, MarkerTrack):
            targets = track.positions
        else:  # the blended target FDPs, moved by the head pose as the simulated face was
            targets = table.targets_for(track.weights)
            if result.head_poses is not None:
                H = np.asarray(result.head_poses)
                targets = np.einsum("tij,tkj->tki", H[:, :3, :3], targets) + H[:, None, :3, 3]
        _picture(out / "drive.png", frames, names, targets, device)
        written = [out / "activations.csv", out / "frames.npz", usd_path, out / "report.json", out / "drive.png",
                   out / "activations.png"]
        if take is not None:
            written += [out / "take.glb", out / "take.usdc"]
            take.write(out / "take.glb", out / "take.usdc")
            rep["rig_take"] = report_full["rig_take"] = take.report()
        rep["files"] = report_full["files"] = [str(w) for w in written]
    rep["seconds"] = report_full["seconds"] = round(time.perf_counter() - t0, 3)
    if not usd_out:
        write_json(out / "report.json", report_full)
    return rep
