"""``facewarp simulate``: play an expression on a ``build`` output (Warp physics, Sec. 6.4-6.5)."""

from __future__ import annotations

from pathlib import Path

from ..core.limits import MAX_FPS, MAX_SECONDS, MAX_SUBSTEPS
from .common import FrameBar, HelpFormatter, emit, fps, frame_stats_lines, out_dir_or_usd, seconds, whole_in


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    s = sub.add_parser("simulate", example="facewarp simulate build --expression smile --out smile.usdc",
                       help="play an expression on a `build` output (Warp physics, Sec. 6.4-6.5)",
                       epilog_factory=_simulate_epilog, formatter_class=HelpFormatter)
    s.add_argument("build", type=Path, metavar="BUILD", help="a `facewarp build` output folder")
    s.add_argument("--expression", metavar="NAME|sequence|FILE.json",
                   help="a preset, 'sequence' or a sequence file (see below); or use --activations")
    s.add_argument("--activations", metavar="MUSCLE=V,...",
                   help="your own expression instead of --expression: muscle=activation (0..1) items (a Table 6.2 name means both "
                        "sides, NAME_L or NAME_R one), e.g. zygomatic_major=0.6,corrugator_L=0.3,jaw_drop_mm=10")
    s.add_argument("--seconds", type=seconds, metavar="S", default=2.0,
                   help=f"simulated time [s], > 0 and <= {MAX_SECONDS:g} (default 2)")
    s.add_argument("--fps", type=fps, metavar="F", default=30.0,
                   help=f"frames per second, > 0 and <= {MAX_FPS:g} (default 30)")
    s.add_argument("--substeps", type=whole_in(1, MAX_SUBSTEPS), metavar="N",
                   help=f"substeps per frame, 1..{MAX_SUBSTEPS} (default: enough for the stable time step)")
    s.add_argument("--out", required=True, type=Path, metavar="DIR|FILE.usd[a|c|z]",
                   help="output folder (frames.npz, frames.png), or a .usda/.usdc/.usdz file: only the USD "
                        "animation, streamed while simulating, no frame cap")
    s.add_argument("--usd", action="store_true",
                   help="with an output folder, also write animation.usdc (whole head, eyes, teeth and tongue "
                        "as moving parts, muscles with activations), streamed while simulating")
    s.add_argument("--tets", action="store_true",
                   help="put the skin's tet layer into the USD too (a TetMesh of purpose guide, hidden by default)")
    s.add_argument("--solver", choices=["implicit", "verlet"], default="implicit",
                   help="implicit (default: backward Euler, one step per frame) or verlet (the thesis's explicit "
                        "reference, ~2,000-5,500 substeps per frame)")
    s.add_argument("--material", choices=["physical", "thesis"], default="physical",
                   help="physical (default: tissue density and moduli in SI) or thesis (Table 6.3 as printed)")
    s.add_argument("--jaw", choices=["mujoco", "kinematic"], default=None,
                   help="mujoco (default with --material physical: the mandible is the hinge body of the build's "
                        "head.xml, two-way coupled to the skin) or kinematic (Eq. 6.4.9 angles imposed; default "
                        "with --material thesis; the MuJoCo jaw couples it too, its stiff holds scaled to MuJoCo's step)")
    s.set_defaults(func=run, outputs=out_dir_or_usd)


def _simulate_epilog() -> str:
    import textwrap

    from ..expressions import MUSCLES, PRESETS

    muscles = textwrap.fill("muscles (Table 6.2; add _L or _R for one side): " + ", ".join(MUSCLES), width=100,
                            initial_indent="  ", subsequent_indent="    ")
    return f"""\
expressions:
  presets      {', '.join(PRESETS)}
               (Table 6.4 and named activation sets; ramp up 0.3 s, hold, ramp down; jaw openings
               are chin drops in mm turned into this head's angle by its condyle-to-chin lever)
  --activations MUSCLE=V,...  your own: e.g. zygomatic_major_L=0.8,frontalis_inner=0.5,jaw_drop_mm=12
  sequence     Fig. 6.16: smile, laugh, surprise, angry, sad, each ramping into the next,
               spread over --seconds
  FILE.json    a sequence file:
    {{"segments": [
      {{"expression": "smile", "start": 0.5, "attack": 0.3, "hold": 1.0, "release": 0.3, "weight": 1.0}},
      {{"expression": {{"blend": {{"smile": 0.5, "surprise": 0.5}}}}, "start": 2.0}},
      {{"expression": {{"muscles": {{"zygomatic_major": 0.6, "corrugator_L": 0.3}}, "jaw_deg": 10}}, "start": 3.5}}]}}
    expression: a preset name, {{"blend": {{preset: weight}}}}, or {{"muscles": {{name: 0..1}}, "jaw_deg": 0..60
    or "jaw_drop_mm": chin drop, "jaw_side_deg": -5..5}}; times in seconds >= 0 (defaults: start 0, attack 0.3, hold 1, release 0.3),
    weight >= 0 (default 1). Overlapping segments add; activations are clamped to 0..1.
    The run lasts --seconds whatever the segments' end.
{muscles}"""



# ----------------------------------------------------------------------------- run and report
def run(args):
    from ..core.errors import InputError
    from ..expressions import Timeline, expression_from_activations, timeline_from_spec
    from ..jobs.face import simulate_files

    if (args.expression is None) == (args.activations is None):
        raise InputError("simulate: give exactly one of expression or activations")
    if args.activations is not None:  # the user's own muscles, held over the run
        name = args.activations
        timeline = Timeline.held(expression_from_activations(args.activations), args.seconds)
    else:  # a preset, "sequence" or a sequence file
        name = args.expression
        timeline = timeline_from_spec(args.expression, args.seconds)
    bar = FrameBar(not args.json)
    try:
        rep = simulate_files(args.build, timeline, args.out, seconds=args.seconds, fps=args.fps, name=name,
                             substeps=args.substeps, device=args.device, usd=args.usd, tets=args.tets, progress=bar,
                             solver=args.solver, material=args.material, jaw=args.jaw)
    finally:
        bar.close()
    emit(args, rep, [
        f"simulated {rep['expression']} for {rep['seconds']} s on {rep['device']}: {rep['frames']} frames x "
        f"{rep['substeps']} substeps (dt {rep['dt_s']:.2e} s), {rep['nodes']} nodes, {rep['tets']} tets",
        f"  {rep.get('solver', 'implicit')} solver, {rep.get('material', 'physical')} material, "
        f"{rep.get('jaw', 'kinematic')} jaw: {rep.get('frames_per_second', float('nan')):.1f} frames/s "
        f"({rep.get('frames_per_second', float('nan')) / rep['fps']:.2f}x real time), "
        f"{rep['steps_per_second']:.0f} steps/s",
        *frame_stats_lines(rep.get("frame_stats")),
        *[f"  MuJoCo: {e}" for e in rep.get("mujoco_events", [])[:5]],
        "  wrote " + ", ".join(rep["files"]),
    ])

