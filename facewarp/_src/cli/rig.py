"""``facewarp rig``: a blendshape rig baked from the physics, once, written as USD (UsdSkel) and glTF."""

from __future__ import annotations

from pathlib import Path

from .common import Progress, emit, muscle_list, whole_in


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    rg = sub.add_parser("rig", example="facewarp rig build --out rig --muscles zygomatic_major,corrugator_L",
                        help="a blendshape rig baked from the physics (muscles and/or the 52 ARKit names; "
                             "USD UsdSkel and glTF from one bake), the jaw as a joint")
    rg.add_argument("build", type=Path, metavar="BUILD", help="a `facewarp build` output folder")
    rg.add_argument("--out", required=True, type=Path, metavar="DIR|FILE",
                    help="a folder (rig.usdc, rig.glb, rig.npz, report.json and the skin texture) or one file: "
                         "rig.usdc, rig.usda, rig.usdz or rig.glb")
    rg.add_argument("--shapes", choices=["muscles", "arkit", "both"], default="muscles",
                    help="muscles: each muscle alone and the jaw corrective (default); arkit: the ARKit-named shapes "
                         "of the head's ARKit table (built once and cached in BUILD: minutes), those no muscle reaches "
                         "left out and listed; both: the two sets on one skin")
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
    what = []
    if rep["muscles"]:
        what.append(f"{rep['muscles']} muscle shapes ({rep['inbetweens']} in-betweens each) and the jaw corrective")
    if rep["arkit"]:
        what.append(f"{rep['arkit']} ARKit shapes ({len(rep['left_out'])} left out: no muscle reaches them)")
    t = rep["timings_s"]
    emit(args, rep, [
        f"baked {' and '.join(what)} of {args.build} ({rep['vertices']} skin vertices"
        f"{', textured' if rep['textured'] else ''}), the jaw as a joint, in {t['bake']:.1f} s"
        + (f" (ARKit table {t['arkit_table']:.1f} s)" if t["arkit_table"] else ""),
        "  animations: " + ", ".join(f"{k} ({v['frames']} frames)" for k, v in rep["clips"].items())
        + "; wrote " + ", ".join(rep["files"] + ([rep["report"]] if rep.get("report") else [])),
    ])
