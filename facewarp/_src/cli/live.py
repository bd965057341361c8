"""``facewarp live``: drive a ``build`` output's face in real time from a live stream (Live Link Face)."""

from __future__ import annotations

import sys
from pathlib import Path

from .common import FrameBar, emit, fps, out_dir, seconds, whole_in

DEFAULT_PORT = 11111  # facewarp._src.drive.livelink.DEFAULT_PORT (a test keeps them equal)


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    lv = sub.add_parser(
        "live", example="facewarp live build --livelink 11111 --out take", help="drive a `build` output's face in real time from Live Link Face (the iPhone app's Live Link "
                     "target) and record the take",
        epilog="In Live Link Face: Settings > Live Link > add a target: this machine's IP address and the port "
               f"(default {DEFAULT_PORT}). Each frame simulates the newest packet through the head's ARKit table "
               "(packets that came while a frame was simulated are dropped, never queued, and counted). MuJoCo's "
               "viewer shows the face where there is a display. Ctrl-C (or SIGTERM, --seconds, a closed viewer, "
               "the stream stopping for --timeout) ends the take and writes DIR/take.csv (every packet, Live Link "
               "Face's CSV layout), frames.npz, animation.usdc, report.json. Nothing arriving within --timeout "
               "is an error (exit 2).")
    lv.add_argument("build", type=Path, metavar="BUILD", help="a `facewarp build` output folder")
    lv.add_argument("--livelink", nargs="?", const=DEFAULT_PORT, type=whole_in(0, 65535), metavar="PORT", required=True,
                    help=f"listen for Live Link Face on this UDP port (default {DEFAULT_PORT}, the app's; 0: any free "
                         "port, named on stderr)")
    lv.add_argument("--host", default="0.0.0.0", metavar="ADDR",
                    help="address to listen on (default 0.0.0.0: every network interface; 127.0.0.1: this machine "
                         "only)")
    lv.add_argument("--seconds", type=seconds, metavar="S", default=None,
                    help="end the take after this many seconds of stream (default: Ctrl-C ends it)")
    lv.add_argument("--timeout", type=seconds, metavar="S", default=10.0,
                    help="seconds to wait for the first packet (none: exit 2), and the longest pause of a running "
                         "stream before the take ends (default 10)")
    lv.add_argument("--fps", type=fps, metavar="F", default=60.0,
                    help="the simulator's frame rate: one step of 1/F per simulated packet (default 60, the app's)")
    lv.add_argument("--iterations", type=whole_in(1, 1000), metavar="K", default=None,
                    help="a fixed solver iteration count per frame (the interactive mode: a fixed frame cost, "
                         "further from the converged face); default converged frames")
    lv.add_argument("--viewer", choices=["auto", "on", "off"], default="auto",
                    help="MuJoCo's viewer: auto (where there is a display; headless otherwise), on, off")
    lv.add_argument("--table", type=Path, metavar="FILE.npz", default=None,
                    help="the head's ARKit table (an arkit_table.npz); default BUILD/arkit_table.npz, built once "
                         "and cached there")
    lv.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder of the take")
    lv.set_defaults(func=run, outputs=out_dir)


# ----------------------------------------------------------------------------- run and report
def run(args):
    from ..jobs.live import live_files

    def log(line: str) -> None:
        print(f"facewarp live: {line}", file=sys.stderr, flush=True)

    table = None
    if args.table is not None:
        from ..drive.arkit import load_arkit_table

        table = load_arkit_table(args.table)
    table_bar = FrameBar(not args.json, desc="ARKit table (once per build)", unit="shape")
    try:
        rep = live_files(args.build, args.out, port=args.livelink, host=args.host, seconds=args.seconds,
                         timeout=args.timeout, fps=args.fps, viewer=args.viewer, device=args.device,
                         iterations=args.iterations, table=table, log=log,
                         table_progress=lambda done, total, name: table_bar(done, total))
    finally:
        table_bar.close()
    rec, sim, cost = rep["received"], rep["simulation"], rep["frame_cost_ms"]
    per_s = sim["frames"] / rep["seconds"] if rep["seconds"] else float("nan")
    lines = [
        f"live: {rec['frames']} frames from {rep['subject']} ({rep['device_id']}) at {rep['stream_fps']:g} fps over "
        f"{rep['seconds']:.1f} s: {sim['frames']} simulated ({per_s:.1f} a second), dropped {rec['dropped']} "
        f"({100 * rep['dropped_fraction']:.1f} %), {rec['malformed']} malformed, {rec['late']} late, "
        f"{rec['missing']} missing in the stream",
        f"  stopped by {rep['stopped_by']}; {rep['viewer']}; a frame costs {cost['frame']['median']:.1f} ms median, "
        f"{cost['frame']['p90']:.1f} ms p90 (the solver's step {cost['step']['median']:.1f} ms median; CPU time "
        f"{rep['frame_cpu_ms']['frame']['median']:.1f} ms a frame)",
    ]
    notes = rep.get("notes", [])
    lines += [f"  note: {n}" for n in notes[:6]]
    if len(notes) > 6:
        lines.append(f"  ... {len(notes) - 6} more notes in report.json")
    lines.append("  wrote " + ", ".join(rep["files"]))
    emit(args, rep, lines)
