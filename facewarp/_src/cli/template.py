"""``facewarp template``: the default template head authored in code (export, info) and the
ICT-FaceKit neutral head made a template (import-ict)."""

from __future__ import annotations

import time
from pathlib import Path

from .common import MAX_TEMPLATE_LEVEL, Parser, Progress, emit, level, out_dir


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    t = sub.add_parser("template", help="the default template head authored in code")
    tsub = t.add_subparsers(dest="template_command", metavar="ACTION", parser_class=Parser)
    tsub.required = True
    level_help = (f"resolution level 0..{MAX_TEMPLATE_LEVEL} (default 0: 3,415 vertices; each level has about 4x the "
                  "vertices of the one before)")
    e = tsub.add_parser("export", example="facewarp template export --out template --level 1",
                        help="write the template (mesh, FDPs, regions, anatomy refs, previews) to a folder")
    e.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (created if needed)")
    e.add_argument("--level", type=level, metavar="N", default=0, help=level_help)
    e.add_argument("--no-preview", action="store_true", help="skip preview_front.png / preview_side.png")
    e.add_argument("--usd", action="store_true", help="also write template.usda (skin and rigid parts)")
    e.set_defaults(func=run_export, outputs=out_dir)
    i = tsub.add_parser("info", example="facewarp template info --level 2",
                        help="print counts, FDPs, regions and bounding box")
    i.add_argument("--level", type=level, metavar="N", default=0, help=level_help)
    i.set_defaults(func=run_info)
    ic = tsub.add_parser("import-ict", example="facewarp template import-ict ICT-FaceKit/FaceXModel --out ict_template",
                         help="make the ICT-FaceKit neutral head a full template (FDPs, regions, parts)")
    ic.add_argument("ict_dir", type=Path, metavar="ICT_DIR", help="ICT-FaceKit folder with generic_neutral_mesh.obj")
    ic.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (created if needed)")
    ic.add_argument("--no-preview", action="store_true", help="skip preview_front.png / preview_side.png")
    ic.set_defaults(func=run_import_ict, outputs=out_dir)


# ----------------------------------------------------------------------------- run and report
def run_export(args):
    from ..jobs.checks import check_out_dir
    from ..jobs.template import export_template
    from ..template import default_template

    t0 = time.perf_counter()
    check_out_dir(args.out)
    prog = Progress(5 if not args.no_preview else 3, "template export", not args.json)
    prog("building level %d" % args.level)
    t = default_template(args.level)
    written = export_template(t, args.out, previews=not args.no_preview, device=args.device, progress=prog)
    if args.usd:
        from usd_export import write_meshes_usd

        meshes = {"skin": (t.vertices, t.faces), **t.parts}
        written.append(write_meshes_usd(Path(args.out) / "template.usda", meshes))
    prog.close()
    data = {"out": str(args.out), "level": t.level, "vertex_count": t.vertex_count, "face_count": t.face_count,
            "fdp_count": len(t.fdp), "files": [str(p) for p in written], "seconds": round(time.perf_counter() - t0, 3)}
    emit(args, data, [f"wrote {len(written)} files to {args.out} (level {t.level}: {t.vertex_count} vertices, "
                       f"{t.face_count} faces, {len(t.fdp)} FDPs) in {data['seconds']:.1f} s"])


def run_info(args):
    from ..template import default_template
    from ..template.files import template_summary

    t = default_template(args.level)
    s = template_summary(t)
    bb = s["bounding_box_m"]
    lines = [
        f"default template, level {s['level']}",
        f"  vertices {s['vertex_count']}, faces {s['face_count']} ({s['frontal_face_count']} in the frontal face)",
        f"  FDPs {s['fdp_count']}, boundary loops {s['boundary_loops']} (neck, mouth, two eyes)",
        f"  bounding box [m] min {[round(v, 4) for v in bb[0]]} max {[round(v, 4) for v in bb[1]]}",
        f"  skin thickness factor {s['thickness_factor']} x Table 6.1",
        "  regions (faces): " + ", ".join(f"{k} {v}" for k, v in s["regions"].items()),
        "  rigid parts (vertices): " + ", ".join(f"{k} {v}" for k, v in s["parts"].items()),
    ]
    emit(args, s, lines)


def run_import_ict(args):
    from ..jobs.template import import_ict_files

    prog = Progress(5 if not args.no_preview else 4, "template import-ict", not args.json)
    rep = import_ict_files(args.ict_dir, args.out, previews=not args.no_preview, device=args.device, progress=prog)
    prog.close()
    emit(args, rep, [f"imported {args.ict_dir} into {args.out}: {rep['vertex_count']} vertices, {rep['face_count']} "
                      f"faces ({rep['frontal_face_count']} frontal), {rep['fdp_count']} FDPs, parts "
                      + ", ".join(f"{k} {v}" for k, v in rep["parts"].items())
                      + f"; wrote {len(rep['files'])} files in {rep['seconds']:.1f} s"])

