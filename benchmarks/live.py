"""Live Link Face in real time: a 60 fps stream to `facewarp live`, the frames dropped, what a frame costs.

    python -m benchmarks live [--device cpu] [--seconds 10] [--modes default interactive:4 interactive:1] [--build DIR]

A generated take (smooth ARKit curves: the jaw opening and closing, smiles, brows and blinks, the
head turning and nodding; 60 fps) is sent as Live Link Face's UDP packets (``fw.LiveLink.packet``)
at the app's pace, looped, to ``facewarp live BUILD --livelink PORT --seconds S --viewer off``
(a subprocess: the command as a user runs it). Each mode is one run: ``default`` (converged frames)
or ``interactive:K`` (``--iterations K``, a fixed solver cost per frame). From the run's
report.json: packets taken in, frames simulated, dropped (count and share: the target is at most
5 % at 60 fps on the CPU at level 0), malformed, and what a frame costs (median / p90 [ms] of
reading the socket, the controls, the solver's step, recording, the whole frame; the latency
from a packet's arrival to its frame done) in wall time and in process CPU time (which other
processes' load on a shared box stretches far less: on an idle machine a frame's wall time is
about its CPU time where the solver runs on one core). The build (``facewarp build default``, level 0) and
its ARKit table (built on the first run, cached in the build) are made in a temporary folder
unless ``--build`` names one. Results: benchmarks/results/live_<device>.json, with the machine's
load average at the start of each run (other processes on a shared box slow every figure).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from benchmarks._common import add_case_args, save


def generated_take(seconds: float = 4.0, fps: float = 60.0):
    """(weights (T, 52), head yaw/pitch/roll (T, 3) [rad]): smooth curves that loop."""
    import facewarp as fw

    t = np.arange(int(round(seconds * fps))) / fps
    w = np.zeros((len(t), 52))
    ph = 2 * np.pi * t / seconds

    def put(name, values):
        w[:, fw.ARKIT_NAMES.index(name)] = np.clip(values, 0.0, 1.0)

    put("jawOpen", 0.35 * (1 - np.cos(2 * ph)) / 2)
    put("mouthSmileLeft", 0.7 * (1 - np.cos(ph)) / 2)
    put("mouthSmileRight", 0.7 * (1 - np.cos(ph)) / 2)
    put("browInnerUp", 0.5 * (1 - np.cos(3 * ph)) / 2)
    put("browOuterUpLeft", 0.4 * (1 - np.cos(3 * ph)) / 2)
    put("eyeBlinkLeft", np.exp(-((t % 2.0 - 1.0) / 0.05) ** 2))
    put("eyeBlinkRight", np.exp(-((t % 2.0 - 1.0) / 0.05) ** 2))
    head = np.stack([0.2 * np.sin(ph), 0.08 * np.sin(2 * ph), 0.03 * np.sin(ph)], axis=1)
    return w, head


def _wait_bound(port: int, proc, limit_s: float) -> bool:
    """True once something listens on UDP ``port`` (our bind fails), False if ``proc`` ended first."""
    end = time.perf_counter() + limit_s
    while time.perf_counter() < end and proc.poll() is None:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return True
        finally:
            s.close()
        time.sleep(0.05)
    return False


def _send(port: int, fps: float, stop: threading.Event, proc) -> int:
    """The phone: the take's packets at ``fps``, looped, until ``stop``; returns how many were sent."""
    import facewarp as fw

    if not _wait_bound(port, proc, 3600.0):
        return 0
    w, head = generated_take(fps=fps)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    t0, k = time.perf_counter(), 0
    while not stop.is_set():
        due = t0 + k / fps
        while time.perf_counter() < due:
            time.sleep(0.0005)
        i = k % len(w)
        s.sendto(fw.LiveLink.packet(w[i], head=head[i], frame_number=10_000 + k, rate=(int(fps), 1),
                                    device_id="benchmark-sender", subject="benchmark"), ("127.0.0.1", port))
        k += 1
    s.close()
    return k


def _free_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def run_mode(build: Path, out: Path, mode: str, *, seconds: float, device: str, fps: float) -> dict:
    argv = [sys.executable, "-m", "facewarp", "--device", device, "--json", "live", str(build), "--livelink",
            str(_free_port()), "--host", "127.0.0.1", "--seconds", str(seconds), "--viewer", "off", "--fps", str(fps),
            "--out", str(out)]
    if mode != "default":
        argv[argv.index("--out"):argv.index("--out")] = ["--iterations", mode.split(":")[1]]
    port = int(argv[argv.index("--livelink") + 1])
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stop = threading.Event()
    sent = []
    th = threading.Thread(target=lambda: sent.append(_send(port, fps, stop, proc)), daemon=True)
    th.start()
    stdout, stderr = proc.communicate()
    stop.set()
    th.join()
    if proc.returncode != 0:
        raise SystemExit(f"live ({mode}) failed with exit {proc.returncode}: {stderr.strip()[-2000:]}")
    rep = json.loads(stdout)
    rec, sim, cost = rep["received"], rep["simulation"], rep["frame_cost_ms"]
    return {"mode": mode, "iterations": sim["iterations"], "load_average_at_start": load,
            "stream_fps": rep["stream_fps"],
            "seconds": rep["seconds"], "packets_sent": sent[0] if sent else None, "frames_in": rec["frames"],
            "simulated": sim["frames"], "dropped": rec["dropped"], "dropped_fraction": rep["dropped_fraction"],
            "malformed": rec["malformed"], "missing": rec["missing"], "late": rec["late"],
            "simulated_frames_per_stream_second": sim["stream_frames_per_second"],
            "step_frames_per_second": sim["frames_per_second"], "frame_cost_ms": cost,
            "frame_cpu_ms": rep["frame_cpu_ms"],
            "frame_stats": sim["frame_stats"], "stopped_by": rep["stopped_by"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_case_args(ap, device="cpu")
    ap.add_argument("--seconds", type=float, default=10.0, help="seconds of stream per mode (default 10)")
    ap.add_argument("--fps", type=float, default=60.0, help="the stream's rate (default 60, the app's)")
    ap.add_argument("--modes", nargs="+", default=["default", "interactive:4", "interactive:1"],
                    help="default and/or interactive:K (a fixed K solver iterations a frame)")
    ap.add_argument("--build", type=Path, default=None, help="a `facewarp build` folder (default: the default head, "
                    "level 0, built in a temporary folder)")
    args = ap.parse_args(argv)
    for m in args.modes:
        if not (m == "default" or (m.startswith("interactive:") and m.split(":")[1].isdigit()
                                   and int(m.split(":")[1]) >= 1)):
            ap.error(f"--modes: unknown mode {m!r} (default or interactive:K)")
    with tempfile.TemporaryDirectory() as tmp:
        build = args.build
        if build is None:
            build = Path(tmp) / "build"
            subprocess.run([sys.executable, "-m", "facewarp", "build", "default", "--out", str(build)], check=True,
                           stdout=subprocess.DEVNULL)
        runs = []
        for k, mode in enumerate(args.modes):
            r = run_mode(build, Path(tmp) / f"take{k}", mode, seconds=args.seconds, device=args.device, fps=args.fps)
            c = r["frame_cost_ms"]
            print(f"{mode}: {r['frames_in']} frames in over {r['seconds']:.1f} s, {r['simulated']} simulated "
                  f"({r['simulated_frames_per_stream_second']:.1f} a second of stream), dropped "
                  f"{100 * r['dropped_fraction']:.1f} %; a frame {c['frame']['median']:.1f} ms median (step "
                  f"{c['step']['median']:.1f}, record {c['record']['median']:.1f}, read {c['receive']['median']:.2f}); "
                  f"CPU time a frame {r['frame_cpu_ms']['frame']['median']:.1f} ms median, "
                  f"{r['frame_cpu_ms']['frame']['p90']:.1f} p90; load {r['load_average_at_start']}", flush=True)
            runs.append(r)
        import facewarp as fw

        rig = fw.load_face_rig(build)
        table = fw.takes.load_arkit_table(build)  # made by the first run
        head = {"head": "default, level 0" if args.build is None else f"the build {args.build.name}",
                "tets": int(len(rig.tets)), "skin_vertices": int(len(rig.head_vertices)),
                "arkit_shapes_solved": [n for n, ok in zip(table.names, table.solved) if ok]}
    figures = {**head, "seconds": args.seconds, "stream_fps": args.fps, "target_dropped_fraction": 0.05, "runs": runs}
    print("wrote", save(f"live_{args.device.split(':')[0]}", figures, device=args.device))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
