"""``facewarp demo``: the whole main job on built-in data."""

from __future__ import annotations

from pathlib import Path

from ..core.limits import MAX_SECONDS, MAX_SEED
from .common import StageBar, emit, frame_stats_lines, out_dir, seconds, whole_in


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    d = sub.add_parser("demo", example="facewarp demo --out demo",
                       help="the whole main job on built-in data: synthetic scan -> adaptation -> anatomy -> "
                                    "the Fig. 6.16 sequence -> USD, MuJoCo head, pictures",
                       epilog="Writes DIR/animation.usdc, DIR/head.xml, DIR/scene.xml, DIR/report.json, DIR/adapted_head.png, "
                              "DIR/expressions.png, DIR/sequence.gif and the intermediate folders scan/, adapt/, "
                              "build/.")
    d.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    d.add_argument("--seconds", type=seconds, metavar="S",
                   help=f"length of the sequence [s], > 0 and <= {MAX_SECONDS:g} (default: the full sequence, 8 s; "
                        "shorter squeezes it)")
    d.add_argument("--quick", action="store_true", help="a smoke run: 0.2 s of sequence, small pictures")
    d.add_argument("--seed", type=whole_in(0, MAX_SEED), metavar="N", default=0,
                   help=f"seed of the synthetic scan (face proportions, noise, holes, pose), 0..{MAX_SEED}, default 0")
    d.add_argument("--jaw", choices=["mujoco", "kinematic"], default="mujoco",
                   help="the jaw: the MuJoCo hinge body of head.xml, two-way coupled (default), or kinematic (Eq. 6.4.9)")
    d.set_defaults(func=run, outputs=out_dir)


# ----------------------------------------------------------------------------- run and report
def run(args):
    from ..jobs.demo import DEMO_STAGES, demo_files

    bar = StageBar(DEMO_STAGES, "demo", not args.json)
    try:
        rep = demo_files(args.out, seconds=args.seconds, quick=args.quick, device=args.device, jaw=args.jaw,
                         seed=args.seed, progress=bar, frame_progress=lambda k, n: bar.frames(k, n))
    finally:
        bar.close()
    a, q, s = rep["adaptation"], rep["anatomy"], rep["simulation"]
    emit(args, rep, [
        f"demo in {args.out} ({rep['timings_s']['total']:.1f} s on {s['device']}):",
        f"  scan: {rep['scan']['vertex_count']} vertices in mm, {rep['scan']['landmark_count']} FDPs, "
        f"pose {rep['scan']['pose']['rotation_deg']:.1f} deg",
        f"  adaptation: {a['seconds']:.1f} s, vertex error E_v median {a['E_v_mm']['median']:.2f} mm, RMS "
        f"{a['E_v_mm']['rms']:.2f} mm; distance to scan median {a['distance_to_scan_mm']['median']:.2f} mm",
        f"  anatomy: {q['tet_count']} tets, {q['inverted_count']} inverted, {q['muscle_count']} muscles",
        f"  simulation: {s['frames']} frames ({s['seconds']:g} s), {s['frames_per_second']:.1f} frames/s "
        f"({s['jaw']} jaw)",
        *frame_stats_lines(s.get("frame_stats")),
        *[f"  MuJoCo: {e}" for e in s.get("mujoco_events", [])[:5]],
        "  wrote animation.usdc, head.xml, scene.xml, report.json, adapted_head.png, likeness.png, expressions.png, sequence.gif",
    ])

