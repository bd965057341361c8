"""``facewarp rig``: a blendshape rig baked from the physics (USD UsdSkel or glTF)."""

from __future__ import annotations

from pathlib import Path

from .common import Progress, emit, muscle_list, whole_in


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    rg = sub.add_parser("rig", example="facewarp rig build --out rig.usdc --muscles zygomatic_major,corrugator_L",
                        help="a blendshape rig baked from the physics (USD UsdSkel or glTF), the jaw as a joint")
    rg.add_argument("build", type=Path, metavar="BUILD", help="a `facewarp build` output folder")
    rg.add_argument("--out", required=True, type=Path, metavar="FILE", help="rig.usdc, rig.usda or rig.glb")
    rg.add_argument("--shapes", choices=["muscles"], default="muscles", help="muscles: each muscle alone (default)")
    rg.add_argument("--inbetweens", type=whole_in(0, 8), default=0, metavar="K",
                    help="in-between shapes per muscle at k/(K+1) of full activation (0..8, default 0)")
    rg.add_argument("--muscles", type=muscle_list, default=None, metavar="A,B,...",
                    help="bake only these muscles (default all): a Table 6.2 name bakes both sides, NAME_L or "
                         "NAME_R one")
    rg.set_defaults(func=run)


# ----------------------------------------------------------------------------- run and report
def run(args):
    from ..jobs.rig import rig_files

    prog = Progress(1, "rig", not args.json)
    rep = rig_files(args.build, args.out, shapes=args.shapes, inbetweens=args.inbetweens, muscles=args.muscles,
                    device=args.device, progress=lambda k, n, name: (prog.set_total(n), prog(name)))
    prog.close()
    emit(args, rep, [
        f"baked {rep['muscles']} muscle shapes ({rep['inbetweens']} in-betweens each) and the jaw corrective of "
        f"{args.build} ({rep['vertices']} skin vertices), the jaw as a joint",
        f"  animation: the Fig. 6.16 sequence, {rep['frames']} frames; wrote {rep['file']}",
    ])

