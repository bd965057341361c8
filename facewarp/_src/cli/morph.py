"""``facewarp morph``: in-between heads of two heads of the same topology, as one USD."""

from __future__ import annotations

from pathlib import Path

from ..core.limits import MAX_FPS, MAX_MORPH_STEPS
from .common import Progress, emit, fps, path, whole_in


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    mo = sub.add_parser("morph", example="facewarp morph head_a head_b --steps 8 --out morph.usdc",
                        help="in-between heads of two heads of the same topology, as one USD",
                        epilog="A and B: template folders, adapt outputs or default[:LEVEL] made from one template. "
                               "The USD holds steps + 2 time samples (A, the in-betweens, B); a picture "
                               "FILE.png is written beside it.")
    mo.add_argument("a", metavar="A", help="first head (s = 0)")
    mo.add_argument("b", metavar="B", help="second head (s = 1)")
    mo.add_argument("--steps", type=whole_in(1, MAX_MORPH_STEPS), metavar="N", default=8,
                    help=f"in-between heads, 1..{MAX_MORPH_STEPS} (default 8)")
    mo.add_argument("--out", required=True, type=path, metavar="FILE.usd[a|c|z]", help="the USD file")
    mo.add_argument("--fps", type=fps, metavar="F", default=30.0,
                    help=f"time codes per second of the file, > 0 and <= {MAX_FPS:g} (default 30)")
    mo.add_argument("--build", type=path, metavar="DIR",
                    help="also write every head as a template folder DIR/head_KK with its anatomy in "
                         "DIR/head_KK/build (simulate it with `facewarp simulate DIR/head_KK/build`)")
    mo.set_defaults(func=run, outputs=outputs)


# ----------------------------------------------------------------------------- run and report
def outputs(args) -> list[tuple[str, Path, str]]:
    """The USD file, and the ``--build`` folder when given."""
    return [("out", args.out, "file")] + ([("build", args.build, "dir")] if args.build is not None else [])


def run(args):
    from ..jobs.morph import morph_files

    prog = Progress(3 + (args.steps + 2 if args.build is not None else 0), "morph", not args.json)
    try:
        rep = morph_files(args.a, args.b, args.out, steps=args.steps, fps=args.fps, build=args.build,
                          device=args.device, progress=prog)
    finally:
        prog.close()
    lines = [f"morphed {args.a} into {args.b}: {rep['samples']} heads (s = 0..1) in {args.out}",
             f"  largest vertex distance A-B {rep['max_vertex_distance_mm']:.1f} mm; parts "
             + ", ".join(f"{k} {'rigid' if v['rigid'] else 'affine'}" for k, v in rep["parts"].items())]
    if "heads" in rep:
        lines.append(f"  anatomy of every head in {args.build}: "
                     + ", ".join(f"{h['tet_count']} tets/{h['inverted_count']} inverted" for h in rep["heads"]))
    emit(args, rep, lines)

