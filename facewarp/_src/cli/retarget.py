"""``facewarp retarget``: one activation sequence on several heads."""

from __future__ import annotations

from pathlib import Path

from ..core.limits import MAX_FPS, MAX_SECONDS
from .common import StageBar, emit, fps, out_dir, path, seconds


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    r = sub.add_parser("retarget", example="facewarp retarget sequence build_a build_b --out crowd",
                       help="one activation sequence on several heads: a USD per head and a picture",
                       epilog="SEQUENCE: a sequence file (see `facewarp simulate --help`), a preset name or "
                              "'sequence'. HEAD: a `facewarp build` output, a template folder, an adapt output or "
                              "default[:LEVEL]. Every head gets the same physical parameters.")
    r.add_argument("expression", metavar="SEQUENCE", help="sequence .json, preset or 'sequence'")
    r.add_argument("heads", nargs="+", metavar="HEAD", help="heads to play it on")
    r.add_argument("--out", required=True, type=path, metavar="DIR", help="output folder")
    r.add_argument("--seconds", type=seconds, metavar="S",
                   help=f"length [s], > 0 and <= {MAX_SECONDS:g} (default: the file's length + 0.5 s; 2 s for a "
                        "preset, 8 s for 'sequence')")
    r.add_argument("--fps", type=fps, metavar="F", default=30.0,
                   help=f"frames per second, > 0 and <= {MAX_FPS:g} (default 30)")
    r.set_defaults(func=run, outputs=out_dir)


# ----------------------------------------------------------------------------- run and report
def run(args):
    from ..jobs.retarget import retarget_files

    bar = StageBar(range(2 * len(args.heads) + 1), "retarget", not args.json)
    try:
        rep = retarget_files(args.expression, args.heads, args.out, seconds=args.seconds, fps=args.fps,
                             device=args.device, progress=bar, frame_progress=lambda k, n: bar.frames(k, n))
    finally:
        bar.close()
    emit(args, rep, [f"played {rep['expression']} ({rep['seconds']:g} s) on {len(rep['heads'])} heads into {args.out}:"]
          + [f"  {h['name']}: {h['frames']} frames, {h['frames_per_second']:.1f} frames/s, lip corners "
             f"{h['max_fdp_motion_mm'].get('8.3', float('nan')):.1f}/{h['max_fdp_motion_mm'].get('8.4', float('nan')):.1f} mm"
             for h in rep["heads"]] + ["  wrote " + ", ".join(Path(f).name for f in rep["files"])])

