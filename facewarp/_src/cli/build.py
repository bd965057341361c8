"""``facewarp build``: skin tetrahedra, muscles and boundary conditions of a head (Sec. 6.2-6.3)."""

from __future__ import annotations

from pathlib import Path

from ..core.limits import MAX_LAYERS
from .common import MAX_TEMPLATE_LEVEL, Progress, emit, out_dir, whole_in


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    b = sub.add_parser("build", example="facewarp build head --out build",
                       help="skin tetrahedra, muscles and boundary conditions of a head (Sec. 6.2-6.3)")
    b.add_argument("head", metavar="HEAD", help="a `template export` folder, an `adapt` output folder, or 'default[:LEVEL]' "
                                f"(LEVEL 0..{MAX_TEMPLATE_LEVEL}, default 0)")
    b.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    b.add_argument("--layers", type=whole_in(1, MAX_LAYERS), metavar="N", default=1,
                   help=f"tet layers through the skin (whole number 1..{MAX_LAYERS}, default 1)")
    b.add_argument("--up", choices=["z", "y"], default="z",
                   help="up axis of head.xml's world: z (MuJoCo's convention, the head looks along +x; default) or y "
                        "(the head's own frame)")
    b.add_argument("--prefix", default="", metavar="STR",
                   help="put STR before every name in head.xml (two heads in one model; letters, digits, _ . : / -)")
    b.set_defaults(func=run, outputs=out_dir)


# ----------------------------------------------------------------------------- run and report
def run(args):
    from ..jobs.face import build_files

    prog = Progress(4, "build", not args.json)
    q = build_files(args.head, args.out, layers=args.layers, device=args.device, progress=prog, up=args.up,
                    prefix=args.prefix)
    prog.close()
    emit(args, q, [
        f"built anatomy of {args.head} into {args.out}: {q['tet_count']} tets, {q['inverted_count']} inverted, "
        f"min dihedral {q.get('min_dihedral_deg', float('nan')):.1f} deg, conforming {q.get('conforming')}",
        f"  {q['muscle_count']} muscles, attached skin nodes per muscle: min {q.get('min_attached_nodes', 0)}",
        "  lips: {crossing_nodes_before} nodes crossing the other lip at rest, {moved_nodes} moved apart, "
        "{crossing_nodes_after} left".format(**q["lip_separation"]),
        "  wrote tets.npz, muscles.json, anatomy.json, anatomy.png, face_rig.npz, head.xml, scene.xml"
        + (", texture.png" if (Path(args.out) / "texture.png").is_file() else ""),
    ])

