"""The job behind ``facewarp live BUILD --livelink [PORT]``: Live Link Face's UDP stream drives the
face of a ``build`` output in real time, shown in MuJoCo's viewer where there is a display, and the
take is recorded when it ends.

Each frame the newest packet of the stream (:class:`~facewarp.LiveLink`: what arrived while the
last frame was simulated is read and dropped, never queued) becomes controls through the head's
ARKit table, as the offline ARKit drive does (:meth:`~facewarp.takes.ArkitTable.controls`: the 52
weights blended into muscle activations and jaw angles; the head's yaw, pitch and roll into the
head pose, :func:`~facewarp._src.drive.arkit.head_rotation_matrix`), and the simulator takes one
step of ``1 / fps``. Where a frame takes longer than the stream's period the packets in between
are dropped and counted, so the face shows the newest expression, late by at most one frame's
cost; the simulator's head then turns only as far as the real head turned in one step's time
(:func:`_head_goal`: its inertial loads those of the real motion), while the face is shown and
recorded at the stream's head pose. A packet that turns the head faster than a head turns (a
tracking glitch, the face found again elsewhere) moves the head part of the way this frame and on
in the next (counted).

The take ends on Ctrl-C or SIGTERM, after ``seconds`` of stream, when the viewer window is
closed, when the stream stops for ``timeout`` seconds, or when the memory for frames is full;
then it is written, whole or not at all (a second Ctrl-C while writing leaves nothing):
``take.csv`` (every packet taken in, in Live Link Face's CSV layout, as sent: the full-rate take
for an offline ``facewarp drive --arkit``), ``frames.npz`` (the simulated frames, at the stream
times of their packets), ``animation.usdc`` (the same frames) and ``report.json`` (the stream,
what was dropped, malformed or late, the frame cost profile). When nothing arrives within
``timeout`` seconds of listening, the run is an :class:`~facewarp.InputError` (exit 2) naming the
port, and writes nothing.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fileio import write_json
from ..drive.livelink import DEFAULT_PORT, LiveLink, write_livelink_csv

__all__ = ["LIVE_FILES", "MAX_LIVE_FRAMES", "VIEWER_MODES", "live_files"]

LIVE_FILES = ("take.csv", "frames.npz", "animation.usdc", "report.json")
"""What ``live`` writes into its output folder."""

MAX_LIVE_FRAMES = 100_000
"""Most simulated frames one take keeps (fewer when the memory is smaller: the take then ends)."""

VIEWER_MODES = ("auto", "on", "off")
"""``auto``: MuJoCo's viewer where there is a display, headless otherwise; ``on``: the viewer or an
error; ``off``: headless."""

STATUS_EVERY_S = 5.0
"""Seconds of stream between status lines."""

POLL_S = 0.1
"""Longest wait for a packet before the loop looks at its stop conditions again [s]."""


# ----------------------------------------------------------------------------------- stopping
class _Stop:
    """Why the take ends (None while it runs); set by a signal handler or the loop."""

    def __init__(self):
        self.reason: str | None = None

    def set(self, reason: str) -> None:
        if self.reason is None:
            self.reason = reason


@contextlib.contextmanager
def _signals_stop(stop: _Stop):
    """SIGINT / SIGTERM end the take (set ``stop``) instead of interrupting the job, while the
    body runs (main thread only); the handlers before come back afterwards, so a signal while
    the take is written interrupts the writing (and nothing is left)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    names = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}
    old = {s: signal.getsignal(s) for s in names}
    for s in names:
        signal.signal(s, lambda signum, frame: stop.set(names[signum]))
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)


# ------------------------------------------------------------------------------------ viewer
def has_display() -> bool:
    """Whether a window can be opened: a desktop on macOS or Windows, X11 or Wayland on Linux."""
    if sys.platform.startswith("linux") or "bsd" in sys.platform:
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def _open_view(build_dir: Path, sim, mode: str, log):
    """The viewer of ``mode`` (:data:`VIEWER_MODES`), or None (headless; said once)."""
    from ..coupling.mujoco_view import MujocoView

    if mode == "off":
        return None
    if not has_display():
        if mode == "on":
            raise InputError("viewer: no display (DISPLAY / WAYLAND_DISPLAY unset); run with the viewer off")
        log("no display: running headless (the take is recorded; MuJoCo's viewer needs a display)")
        return None
    mjcf = build_dir / "head.xml"
    if not mjcf.is_file():
        if mode == "on":
            raise InputError(f"{build_dir}: no head.xml for the viewer (rebuild with `facewarp build`)")
        log(f"{build_dir}: no head.xml: running headless (rebuild with `facewarp build` for the viewer)")
        return None
    view = MujocoView(mjcf, sim)
    try:
        view.open()
    except Exception as e:  # no GL, mjpython needed on macOS, ...: headless
        why = str(e).splitlines()[0] if str(e) else type(e).__name__
        if mode == "on":
            raise InputError(f"viewer: MuJoCo's viewer did not open ({why})") from None
        log(f"MuJoCo's viewer did not open ({why}): running headless")
        return None
    return view


# ------------------------------------------------------------------------------------ recording
class _Recorder:
    """The simulated frames kept in memory: per frame only what the step produced (the tet nodes,
    the muscles' control points, activations, jaw angles and head rotation; two host copies), the
    surfaces, parts and fibres read out after the take (:meth:`frames`), so that recording costs
    the live loop little."""

    def __init__(self, sim, samples: int = 24):
        self.samples = samples
        self.rest_curves = sim.muscle_curves(samples).astype(np.float32)
        self.times, self.nodes, self.ctrl, self.acts, self.jaw, self.heads = [], [], [], [], [], []

    def __len__(self) -> int:
        return len(self.times)

    def frame(self, sim, t: float, R) -> None:
        self.times.append(t)
        self.nodes.append(sim.state.positions.numpy().astype(np.float32))
        self.ctrl.append(sim.state.muscle_ctrl.numpy().copy())
        self.acts.append(sim.activations)
        self.jaw.append(sim.jaw_angles)
        self.heads.append(np.asarray(R, np.float64))

    def frames(self, sim, stats: dict):
        """The take as :class:`~facewarp.Frames` (world frame: the head rotation applied, as
        :meth:`~facewarp.FaceSimulator.surface` gives it)."""
        from ..sim.frames import Frames
        from ..sim.readout import fdp_points, head_surface, muscle_curves, parts_at, surface_index

        fr = sim.fr
        index = surface_index(fr)
        n = len(self.times)
        pts = np.empty((n, len(fr.head_vertices), 3), np.float32)
        curves = np.empty((n, len(sim.muscle_names), self.samples, 3), np.float32)
        parts = {k: np.empty((n, len(V), 3), np.float32) for k, (V, _) in fr.parts.items()}
        for k in range(n):
            R, j = self.heads[k], self.jaw[k]
            pts[k] = head_surface(fr, self.nodes[k].astype(np.float64), j, index) @ R.T
            C = muscle_curves(fr.rig, self.ctrl[k], self.samples)
            curves[k] = (C.reshape(-1, 3) @ R.T).reshape(C.shape)
            for name, P in parts_at(fr, j).items():
                parts[name][k] = np.asarray(P, np.float64) @ R.T
        return Frames(np.asarray(self.times, np.float64), pts, fr.head_faces, fr.fdp_ids, fdp_points(fr, pts, parts),
                      {k: (v, fr.parts[k][1]) for k, v in parts.items()}, list(sim.muscle_names), curves,
                      np.stack(self.acts), np.stack(self.jaw), stats.get("steps_per_second", 0.0), sim.substeps, sim.dt,
                      frames_per_second=stats.get("frames_per_second", 0.0),
                      realtime_factor=stats.get("realtime_factor", 0.0), solver=sim.solver_name,
                      material=sim.material.name)


class _Replay:
    """A recorded frame as the simulator's face for :class:`~facewarp.UsdAnimation` (which reads
    ``fr``, ``fps``, ``surface()``, ``muscle_curves()``, ``activations`` and ``jaw_angles``)."""

    def __init__(self, sim, frames, rest_curves):
        self.fr, self.fps, self._f, self._rest, self.k = sim.fr, sim.fps, frames, rest_curves, None

    def surface(self):
        return self._f.points[self.k].astype(np.float64)

    def muscle_curves(self, samples):
        return (self._rest if self.k is None else self._f.muscle_curves[self.k]).astype(np.float64)

    @property
    def activations(self):
        return self._f.activations[self.k] if self.k is not None else np.zeros(len(self._f.muscle_names), np.float32)

    @property
    def jaw_angles(self):
        return self._f.jaw[self.k] if self.k is not None else np.zeros(2, np.float32)

    @property
    def eye_gaze(self):
        """The eyes' (yaw, pitch) [rad], (2, 2) float32: the live loop does not turn the eyes yet (rest)."""
        return np.zeros((2, 2), np.float32)


def _write_usd(path: Path, sim, frames, rest_curves) -> None:
    from .animation import UsdAnimation

    replay = _Replay(sim, frames, rest_curves)
    with UsdAnimation(path, replay) as usd:
        last = -math.inf
        for k, t in enumerate(frames.times):
            replay.k = k
            t = max(float(t), last + 1e-6)  # strictly increasing time codes
            usd.add(replay, t)
            last = t


EASE_FRACTIONS = (0.5, 0.25, 0.125, 0.0)
"""Where a packet turns the head faster than a head turns (a tracking glitch, the face found
again elsewhere), the frame goes this part of the way from the last pose instead, the first that
the simulator takes (0: the last pose held); the next frames go on towards the stream's pose."""


def _head_goal(R_sim, R, gap, h):
    """The head pose the simulator steps to: the stream's ``R`` where the frame before was simulated
    ``h`` [s] of stream ago (no packet dropped; ``gap`` None: the first frame); after a gap of dropped
    packets, the share ``h / gap`` of the way from the simulator's pose ``R_sim``, so that the head
    turns in the simulator's step of ``h`` about as fast as it turned in the stream (its inertial
    loads those of the real motion, not of the whole gap's turn squeezed into one step), catching up
    over the frames that follow. The face is shown and recorded at the stream's pose all the same."""
    from scipy.spatial.transform import Rotation, Slerp

    if gap is None or gap <= h * 1.0001:
        return R
    return Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([R_sim, R])))([h / gap]).as_matrix()[0]


def _step_easing_head(sim, R_prev, R):
    """Step ``sim`` with its controls and the head pose ``R`` (set); where that pose is a jump
    (:class:`~facewarp.InputError` from the step, nothing changed), with a pose part of the way
    from ``R_prev`` (:data:`EASE_FRACTIONS`). Returns None, or the pose used instead."""
    from scipy.spatial.transform import Rotation, Slerp

    try:
        sim.step()
        return None
    except InputError:
        pass
    ends = Rotation.from_matrix(np.stack([R_prev, R]))
    for f in EASE_FRACTIONS:
        Rf = Slerp([0.0, 1.0], ends)([f]).as_matrix()[0]
        sim.set_head_pose(Rf, np.zeros(3))
        try:
            sim.step()
            return Rf
        except InputError:
            if f == 0.0:
                raise
    return None


def _memory_frames(sim) -> int:
    """Frames the memory holds (half of what is available), at most :data:`MAX_LIVE_FRAMES`."""
    from ..core.limits import BYTES_PER_FRAME, BYTES_PER_FRAME_VERTEX, available_memory

    per = BYTES_PER_FRAME_VERTEX * len(sim.fr.head_vertices) + BYTES_PER_FRAME
    room = available_memory()
    return MAX_LIVE_FRAMES if room is None else int(max(10, min(MAX_LIVE_FRAMES, 0.5 * room / per)))


def _profile(ms: list) -> dict:
    a = np.asarray(ms, np.float64)
    if not len(a):
        return {"median": None, "p90": None, "max": None}
    return {"median": round(float(np.median(a)), 3), "p90": round(float(np.percentile(a, 90)), 3),
            "max": round(float(a.max()), 3)}


# ------------------------------------------------------------------------------------ the job
def live_files(build, out, *, port: int = DEFAULT_PORT, host: str = "0.0.0.0", seconds: float | None = None,
               timeout: float = 10.0, fps: float = 60.0, viewer: str = "auto", device: str = "cpu",
               iterations: int | None = None, table=None, log=None, table_progress=None, ready=None) -> dict:
    """Drive a ``build`` output's face from Live Link Face's stream in real time and record the take.

    Args:
        build: A ``facewarp build`` output folder (its ARKit table is built once and cached there).
        out: Output folder (:data:`LIVE_FILES`).
        port, host: Where to listen (the app's target: this machine's IP address and this port).
        seconds: End the take after this many seconds of stream (None: on Ctrl-C / SIGTERM).
        timeout: Seconds to wait for the first packet (none: :class:`~facewarp.InputError`), and
            the longest pause of a running stream before the take ends.
        fps: The simulator's frame rate (one step of ``1 / fps`` per simulated packet; Live Link
            Face sends 60).
        viewer: :data:`VIEWER_MODES`.
        device: Warp device.
        iterations: A fixed solver iteration count per frame (the interactive mode: a fixed cost
            per frame, further from the converged face); None: converged frames.
        table: The head's :class:`~facewarp.takes.ArkitTable` (default: :func:`~facewarp.arkit_table`
            of the build, cached there).
        log: ``f(line)`` for status lines (listening, headless, every few seconds of stream).
        table_progress: ``f(done, total, name)`` while the ARKit table is built (first run on a build).
        ready: ``f(port)`` once the socket listens and the face is ready (a test's sender starts there).

    Returns:
        The report (what ``report.json`` holds).

    Raises:
        InputError: bad arguments, a port in use or out of range, nothing received in ``timeout`` s.
    """
    from ..core.checks import check_choice, check_int, check_number
    from ..core.limits import MAX_FPS, MAX_SECONDS
    from ..drive.arkit import ArkitTable, arkit_table, head_rotation_matrix, rig_key
    from ..physics.face_rig import load_face_rig
    from ..sim.frames import save_frames_npz
    from ..sim.simulator import FaceSimulator
    from .checks import check_out_dir, make_out_dir

    t_start = time.perf_counter()
    log = log or (lambda line: None)
    if seconds is not None:
        seconds = check_number("seconds", seconds, low=0.0, high=MAX_SECONDS, low_open=True)
    timeout = check_number("timeout", timeout, low=0.0, high=MAX_SECONDS, low_open=True)
    fps = check_number("fps", fps, low=0.0, high=MAX_FPS, low_open=True)
    viewer = check_choice("viewer", viewer, VIEWER_MODES)
    if viewer == "on" and not has_display():  # before the slow part
        raise InputError("viewer: no display (DISPLAY / WAYLAND_DISPLAY unset); run with the viewer off")
    if iterations is not None:
        iterations = check_int("iterations", iterations, low=1, high=1000)
    out = check_out_dir(out)
    made = not out.exists()
    build_dir = Path(build) if Path(build).is_dir() else Path(build).parent
    with LiveLink(port, host=host, keep=True) as link:  # a port in use fails here, before the slow part
        fr = load_face_rig(build)
        sim = FaceSimulator(fr, device=device, fps=fps, iterations=iterations)
        if table is None:
            table = arkit_table(sim, cache=build_dir, progress=table_progress)
        elif not isinstance(table, ArkitTable):
            raise InputError(f"table: expected an ArkitTable, got {type(table).__name__}")
        if list(table.muscle_names) != list(sim.muscle_names) or table.key_rig != rig_key(sim):
            raise InputError("table: built for another head (or solver) than this build's")
        if not np.asarray(table.solved).any():
            raise InputError(f"{build}: the head's ARKit table moves nothing (no shape solved: "
                             + "; ".join(sorted(set(table.reasons.values())))[:200] + ")")
        make_out_dir(out)
        view = _open_view(build_dir, sim, viewer, log)
        try:
            rep = _stream(link, sim, table, view, seconds=seconds, timeout=timeout, log=log, ready=ready,
                          rotation=head_rotation_matrix)
        finally:
            if view is not None:
                view.close()
        rec, stats = rep.pop("_recorder"), link.stats
        if stats.frames == 0:
            if made:  # nothing to record: leave no empty folder behind
                with contextlib.suppress(OSError):
                    out.rmdir()
            when = f"in {timeout:g} s" if rep["stopped_by"] == "nothing arrived" else f"before {rep['stopped_by']}"
            raise InputError(f"nothing arrived on port {link.port} {when}: set Live Link Face's target "
                             f"(Settings > Live Link) to this machine's IP address and port {link.port}, on the same "
                             "network" + ("" if stats.datagrams == 0 else
                                          f" ({stats.datagrams} datagrams came, none a Live Link Face packet: "
                                          f"{next(iter(stats.malformed_reasons), 'another source')})"))
        if len(rec) == 0:  # stopped between the first packet and its frame
            raise InputError(f"the take ended ({rep['stopped_by']}) before a frame was simulated: nothing to record")
        frames = rec.frames(sim, rep["simulation"])
        files = [out / n for n in LIVE_FILES]
        take = [f for f in link.history if seconds is None or f.elapsed < seconds]  # the take, up to its end
        write_livelink_csv(take, files[0])
        save_frames_npz(files[1], frames)
        _write_usd(files[2], sim, frames, rec.rest_curves)
        files[3:3] = sorted(out.glob("animation_*.png"))  # the USD's skin texture, where the build has one
        first = take[0]
        rep.update({"build": str(build), "port": link.port, "host": link.host, "device_id": first.device_id,
                    "subject": first.subject, "stream_fps": first.fps, "take_frames": len(take),
                    "received": stats.as_dict(),
                    "dropped_fraction": round(stats.dropped_fraction, 4), "files": [str(f) for f in files]})
    used = np.max([f.weights for f in take], axis=0)
    rep["notes"] += [f"{n}: out of reach ({table.reasons[n]}); weight up to {used[i]:.2f}"
                     for i, n in enumerate(table.names) if n in table.reasons and used[i] > 0]
    if abs(first.fps - fps) > 0.01 * fps:
        rep["notes"].append(f"the stream is at {first.fps:g} fps, the simulator at {fps:g} (--fps {first.fps:g} "
                            "steps it at the stream's rate)")
    rep["wall_s"] = round(time.perf_counter() - t_start, 3)
    write_json(files[-1], rep)
    return rep


def _stream(link, sim, table, view, *, seconds, timeout, log, ready, rotation) -> dict:
    """The live loop (module doc); returns the report's simulation part and the recorder."""
    stats = link.stats
    rec = _Recorder(sim)
    cap = _memory_frames(sim)
    cost = {k: [] for k in ("receive", "controls", "step", "record", "view", "frame", "latency")}
    cpu = {"step": [], "frame": []}  # process CPU time [ms]: what another process's load does not stretch
    eased = 0
    R_sim = np.eye(3)  # the head pose the simulator holds (its inertial loads come from its motion)
    last_t = None  # stream time of the frame simulated before [s]
    sim_heads, packets = [], []
    stop = _Stop()
    sim.reset()
    if view is not None:
        view.show()
    next_status = STATUS_EVERY_S
    stepping = 0.0
    with _signals_stop(stop):  # from here a signal ends the take (and the take is recorded)
        before = link.flush()  # what came while the face was made up is not the take
        log(f"listening on {link.host}:{link.port} for Live Link Face (the app's Live Link target: this machine's "
            f"IP address, port {link.port}); Ctrl-C ends and records the take")
        if ready is not None:
            ready(link.port)
        t_listen = time.perf_counter()
        while stop.reason is None:
            t0 = time.perf_counter()
            f = link.receive(timeout=POLL_S)
            t1 = time.perf_counter()
            if f is None:
                now = time.perf_counter()
                if stats.frames == 0 and now - t_listen > timeout:
                    stop.set("nothing arrived")
                elif stats.frames > 0 and now - link.last.received > timeout:
                    stop.set(f"the stream stopped (nothing for {timeout:g} s)")
                if view is not None and not view.running:
                    stop.set("the viewer was closed")
                continue
            if seconds is not None and f.elapsed >= seconds:
                stop.set(f"{seconds:g} s of stream")
                break
            c1 = time.process_time()
            a, j = table.controls(f.weights)
            R = rotation(*f.head_rotation)
            R_goal = _head_goal(R_sim, R, (f.elapsed - last_t) if last_t is not None else None, 1.0 / sim.fps)
            sim.set_activations(a[0])
            sim.set_jaw(float(j[0, 0]), float(j[0, 1]))
            sim.set_head_pose(R_goal, np.zeros(3))
            t2, c2 = time.perf_counter(), time.process_time()
            if _step_easing_head(sim, R_sim, R_goal) is not None:
                eased += 1
            R_sim, last_t = sim.head_pose[0], f.elapsed  # the pose the frame reached
            t3, c3 = time.perf_counter(), time.process_time()
            stepping += t3 - t2
            rec.frame(sim, f.elapsed, R)  # shown and recorded at the stream's pose
            sim_heads.append(R_sim)
            packets.append(f.frame_number)
            t4 = time.perf_counter()
            if view is not None:
                view.show(R)
            t5, c5 = time.perf_counter(), time.process_time()
            cpu["step"].append(1e3 * (c3 - c2))
            cpu["frame"].append(1e3 * (c5 - c1))
            for k, v in (("receive", t1 - max(t0, f.received)), ("controls", t2 - t1), ("step", t3 - t2),
                         ("record", t4 - t3), ("view", t5 - t4), ("frame", t5 - max(t0, f.received)),
                         ("latency", t5 - f.received)):
                cost[k].append(1e3 * max(v, 0.0))
            if len(rec) >= cap:
                stop.set(f"the memory for frames is full ({cap} frames)")
            if f.elapsed >= next_status:
                next_status += STATUS_EVERY_S
                log(f"live: {f.elapsed:.1f} s of stream, {stats.frames} frames in, {len(rec)} simulated, "
                    f"{stats.dropped} dropped ({100 * stats.dropped_fraction:.1f} %), {stats.malformed} malformed")
    n = len(rec)
    span = rec.times[-1] - rec.times[0] if n > 1 else 0.0
    stepping = max(stepping, 1e-9)
    sim_stats = {"frames": n, "frames_per_second": n / stepping, "steps_per_second": n * sim.substeps / stepping,
                 "realtime_factor": n / sim.fps / stepping,
                 "stream_frames_per_second": (n - 1) / span if span else None,
                 "fps": sim.fps, "dt_s": sim.dt, "substeps": int(sim.substeps), "device": str(sim.device),
                 "iterations": getattr(sim.solver, "iterations", None), "head_jumps_eased": eased,
                 "frame_stats": sim.stats.as_dict()}
    return {"kind": "livelink", "stopped_by": stop.reason, "discarded_before_start": before, "seconds": round(span, 4),
            "viewer": "window" if view is not None else "headless", "simulation": sim_stats,
            "frame_cost_ms": {k: _profile(v) for k, v in cost.items()},
            "frame_cpu_ms": {k: _profile(v) for k, v in cpu.items()}, "notes": [], "_recorder": rec,
            "frames": [{"time_s": round(float(t), 6), "frame_number": int(k),
                        "head_rotation_simulated": Rs.tolist()}
                       for t, k, Rs in zip(rec.times, packets, sim_heads)]}
