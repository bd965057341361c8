"""``facewarp landmarks``: check a landmark file; detect the FDPs on a scan."""

from __future__ import annotations

from pathlib import Path

from .common import FacewarpError, Parser, Progress, emit, out_file


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    lmp = sub.add_parser("landmarks", help="inspect FDP landmark files")
    lsub = lmp.add_subparsers(dest="landmarks_command", metavar="ACTION", parser_class=Parser)
    lsub.required = True
    c = lsub.add_parser("check", example="facewarp landmarks check scan_landmarks.json --units mm",
                        help="load and validate a landmark file (JSON, MeshLab .pp, or the 68/51-point scheme)")
    c.add_argument("landmarks", type=Path, metavar="LANDMARKS.json|.pp|.pts", help='JSON {"3.7": [x, y, z], ...}, MeshLab picked points .pp, or the '
                   "68- or 51-point scheme (a JSON list of [x, y, z] or an iBUG .pts file; shown as the FDPs they mark)")
    c.add_argument("--units", choices=["mm", "cm", "m"], default="m", help="units of the file (default m)")
    c.set_defaults(func=run_check)
    dt = lsub.add_parser("detect", example="facewarp landmarks detect scan.ply --units mm --out scan_landmarks.json",
                         help="find the FDPs on a scan in any pose, without a person (symmetry plane, "
                         "coarse fit of the template, non-rigid fit); writes a landmarks JSON and confidences")
    dt.add_argument("scan", type=Path, help="scan mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    dt.add_argument("--out", required=True, type=Path, metavar="LM.json", help="landmarks JSON to write (confidences go beside it, "
                    "NAME_confidence.json)")
    dt.add_argument("--units", choices=["mm", "cm", "m"], default="m", help="units of the scan (and of the written landmarks)")
    dt.add_argument("--template", type=Path, metavar="DIR", help="template folder whose FDPs to find (default: the built-in level 0)")
    dt.add_argument("--template-mesh", type=Path, metavar="MESH", help="any template mesh with FDP landmarks (e.g. ICT-FaceKit neutral)")
    dt.add_argument("--template-landmarks", type=Path, metavar="LM.json", help="FDPs of --template-mesh (JSON or .pp)")
    dt.add_argument("--template-units", choices=["mm", "cm", "m"], default="m", help="units of --template-mesh")
    dt.set_defaults(func=run_detect, outputs=out_file)


# ----------------------------------------------------------------------------- run and report
def run_check(args):
    from ..geometry.landmarks import FDP_CATALOGUE, fdp_sort_key, load_landmarks

    lm = load_landmarks(args.landmarks, units=args.units)
    ids = sorted(lm, key=fdp_sort_key)
    data = {"path": str(args.landmarks), "count": len(ids), "fdps": {k: lm[k].tolist() for k in ids}}
    lines = [f"{args.landmarks}: {len(ids)} FDPs"] + [
        f"  {k:>5} {FDP_CATALOGUE[k].description:<45} {lm[k][0]:+.4f} {lm[k][1]:+.4f} {lm[k][2]:+.4f} m" for k in ids
    ]
    emit(args, data, lines)


def run_detect(args):
    from ..jobs.adapt import detect_landmarks_files

    if args.template_mesh is not None and args.template is not None:
        raise FacewarpError("give --template or --template-mesh, not both")
    if (args.template_mesh is None) != (args.template_landmarks is None):
        raise FacewarpError("--template-mesh and --template-landmarks go together (a mesh and its FDPs)")
    prog = Progress(3, "detect", not args.json)
    rep = detect_landmarks_files(args.scan, args.out, units=args.units, template_dir=args.template,
                                 template_mesh=args.template_mesh, template_landmarks=args.template_landmarks,
                                 template_units=args.template_units, device=args.device, progress=prog)
    prog.close()
    conf = rep["confidence"]
    emit(args, rep, [f"found {len(rep['landmarks'])} FDPs on {args.scan} (confidence 0..1):"]
          + [f"  {k:>5} {conf.get(k, 0.0):.2f}  " + " ".join(f"{x:+.4g}" for x in v) + f" {args.units}"
             for k, v in rep["landmarks"].items()]
          + [f"  wrote {rep['path']} and {rep['confidence_path']}"])

