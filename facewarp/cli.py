"""The ``facewarp`` command.

Every error a user can cause ends as one line on stderr (``facewarp: error: ...``) and exit
code 2; nothing below this module prints or exits.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from ._src.core.errors import FacewarpError

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2, like every other error
        self.exit(EXIT_USAGE, f"facewarp: error: {message}\n")


def _level(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer level, got {text!r}") from None
    if not 0 <= v <= 4:
        raise argparse.ArgumentTypeError(f"level must be 0..4, got {v}")
    return v


def _device(text: str) -> str:
    t = text.strip().lower()
    if t == "cpu" or t == "cuda" or (t.startswith("cuda:") and t[5:].isdigit()):
        return t
    raise argparse.ArgumentTypeError(f"expected cpu, cuda or cuda:N, got {text!r}")


class _Progress:
    """A tqdm bar on stderr over named steps (hidden when stderr is not a terminal or --json)."""

    def __init__(self, total: int, desc: str, enabled: bool):
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=desc, disable=None if enabled else True, file=sys.stderr, leave=False)

    def __call__(self, msg: str):
        self.bar.set_postfix_str(msg)
        self.bar.update(1)

    def close(self):
        self.bar.close()


def _check_device(device: str) -> str:
    if device.startswith("cuda"):
        import warp as wp

        wp.config.quiet = True
        wp.init()
        if wp.get_cuda_device_count() == 0:
            raise FacewarpError(f"--device {device}: no CUDA device is available on this machine")
        idx = int(device.split(":")[1]) if ":" in device else 0
        if idx >= wp.get_cuda_device_count():
            raise FacewarpError(f"--device {device}: only {wp.get_cuda_device_count()} CUDA device(s) present")
    return device


def _emit(args, data: dict, lines: list[str]):
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        print("\n".join(lines))


# ----------------------------------------------------------------------------- template
def cmd_template_export(args):
    from ._src.template import default_template
    from ._src.jobs.template import export_template

    t0 = time.perf_counter()
    prog = _Progress(5 if not args.no_preview else 3, "template export", not args.json)
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
    _emit(args, data, [f"wrote {len(written)} files to {args.out} (level {t.level}: {t.vertex_count} vertices, "
                       f"{t.face_count} faces, {len(t.fdp)} FDPs) in {data['seconds']:.1f} s"])


def cmd_template_info(args):
    from ._src.template import default_template
    from ._src.template.files import template_summary

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
    _emit(args, s, lines)


# ----------------------------------------------------------------------------- inputs
def cmd_mesh_check(args):
    from ._src.geometry.mesh import load_mesh, mesh_report

    m = load_mesh(args.mesh, units=args.units)
    rep = mesh_report(m.vertices, m.faces)
    rep["path"] = str(args.mesh)
    rep["has_uv"] = m.uv is not None
    lines = [f"{args.mesh}: " + ", ".join(f"{k} {v}" for k, v in rep.items() if k not in ("path", "bounding_box"))]
    _emit(args, rep, lines)


def cmd_landmarks_check(args):
    from ._src.geometry.landmarks import FDP_CATALOGUE, fdp_sort_key, load_landmarks

    lm = load_landmarks(args.landmarks, units=args.units)
    ids = sorted(lm, key=fdp_sort_key)
    data = {"path": str(args.landmarks), "count": len(ids), "fdps": {k: lm[k].tolist() for k in ids}}
    lines = [f"{args.landmarks}: {len(ids)} FDPs"] + [
        f"  {k:>5} {FDP_CATALOGUE[k].description:<45} {lm[k][0]:+.4f} {lm[k][1]:+.4f} {lm[k][2]:+.4f} m" for k in ids
    ]
    _emit(args, data, lines)


def cmd_adapt(args):
    from ._src.jobs.adapt import adapt_files

    prog = _Progress(4, "adapt", not args.json)
    rep = adapt_files(args.scan, args.landmarks, args.out, template_dir=args.template, template_mesh=args.template_mesh,
                      template_landmarks=args.template_landmarks, method=args.method, levels=args.levels,
                      markers=args.markers, units=args.units, template_units=args.template_units,
                      device=args.device, progress=prog)
    prog.close()
    last = rep["levels"][-1] if rep["levels"] else {}
    d = rep["distance_to_scan_m"]
    _emit(args, rep, [
        f"adapted {rep['vertex_count']} template vertices to {args.scan} in {rep['seconds']:.2f} s ({rep['method']})",
        f"  calibration FDPs: {', '.join(rep['calibration']['fdps_used'])}",
        f"  levels {len(rep['levels'])}, final FPs {rep['fp_count']}, E_d {last.get('E_d', float('nan')):.3g} m^2",
        f"  distance to scan: median {d['median'] * 1e3:.2f} mm, RMS {d['rms'] * 1e3:.2f} mm",
        f"  wrote {args.out}/adapted.obj, adapted_scan_frame.obj, adapted_landmarks.json, report.json, "
        "error_heatmap.png, error_curve.png",
    ])


def cmd_build(args):
    from ._src.jobs.face import build_files

    prog = _Progress(4, "build", not args.json)
    q = build_files(args.head, args.out, layers=args.layers, device=args.device, progress=prog)
    prog.close()
    _emit(args, q, [
        f"built anatomy of {args.head} into {args.out}: {q['tet_count']} tets, {q['inverted_count']} inverted, "
        f"min dihedral {q.get('min_dihedral_deg', float('nan')):.1f} deg, conforming {q.get('conforming')}",
        f"  {q['muscle_count']} muscles, attached skin nodes per muscle: min {q.get('min_attached_nodes', 0)}",
        f"  wrote tets.npz, muscles.json, anatomy.json, anatomy.png, face_rig.npz",
    ])


def cmd_simulate(args):
    from ._src.jobs.face import simulate_files

    bar = None
    if not args.json:
        from tqdm import tqdm

        bar = tqdm(total=int(round(args.seconds * args.fps)) + 1, desc="simulate", unit="frame", file=sys.stderr,
                   disable=None, leave=False)
    prog = (lambda k, n: bar.update(1)) if bar is not None else None
    rep = simulate_files(args.head, args.expression, args.out, seconds=args.seconds, fps=args.fps,
                         substeps=args.substeps, device=args.device, usd=args.usd, progress=prog)
    if bar is not None:
        bar.close()
    _emit(args, rep, [
        f"simulated {rep['expression']} for {rep['seconds']} s on {rep['device']}: {rep['frames']} frames x "
        f"{rep['substeps']} substeps (dt {rep['dt_s']:.2e} s), {rep['nodes']} nodes, {rep['tets']} tets",
        f"  {rep['steps_per_second']:.0f} simulated steps per second",
        "  wrote " + ", ".join(rep["files"]),
    ])


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="facewarp",
        description="Personalized, physically simulated faces (template head, adaptation, anatomy, physics).",
        epilog="Units: the library works in metres; --units converts input files. Errors: one line, exit code 2.",
    )
    p.add_argument("--device", type=_device, default="cpu", help="Warp device: cpu (default), cuda or cuda:N")
    p.add_argument("--json", action="store_true", help="print machine-readable JSON instead of text")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    t = sub.add_parser("template", help="the default template head authored in code")
    tsub = t.add_subparsers(dest="template_command", metavar="ACTION", parser_class=_Parser)
    tsub.required = True
    e = tsub.add_parser("export", help="write the template (mesh, FDPs, regions, anatomy refs, previews) to a folder")
    e.add_argument("--out", required=True, type=Path, help="output folder (created if needed)")
    e.add_argument("--level", type=_level, default=0, help="resolution level 0..4 (0: ~3,400 vertices, x4 per level)")
    e.add_argument("--no-preview", action="store_true", help="skip preview_front.png / preview_side.png")
    e.add_argument("--usd", action="store_true", help="also write template.usda (skin and rigid parts)")
    e.set_defaults(func=cmd_template_export)
    i = tsub.add_parser("info", help="print counts, FDPs, regions and bounding box")
    i.add_argument("--level", type=_level, default=0, help="resolution level 0..4")
    i.set_defaults(func=cmd_template_info)

    def cmd_template_import_ict(args):
        from ._src.jobs.template import import_ict_files

        prog = _Progress(5 if not args.no_preview else 4, "template import-ict", not args.json)
        rep = import_ict_files(args.ict_dir, args.out, previews=not args.no_preview, device=args.device, progress=prog)
        prog.close()
        _emit(args, rep, [f"imported {args.ict_dir} into {args.out}: {rep['vertex_count']} vertices, {rep['face_count']} "
                          f"faces ({rep['frontal_face_count']} frontal), {rep['fdp_count']} FDPs, parts "
                          + ", ".join(f"{k} {v}" for k, v in rep["parts"].items())
                          + f"; wrote {len(rep['files'])} files in {rep['seconds']:.1f} s"])

    ic = tsub.add_parser("import-ict", help="make the ICT-FaceKit neutral head a full template (FDPs, regions, parts)")
    ic.add_argument("ict_dir", type=Path, metavar="ICT_DIR", help="ICT-FaceKit folder with generic_neutral_mesh.obj")
    ic.add_argument("--out", required=True, type=Path, help="output folder (created if needed)")
    ic.add_argument("--no-preview", action="store_true", help="skip preview_front.png / preview_side.png")
    ic.set_defaults(func=cmd_template_import_ict)

    m = sub.add_parser("mesh", help="inspect input meshes")
    msub = m.add_subparsers(dest="mesh_command", metavar="ACTION", parser_class=_Parser)
    msub.required = True
    c = msub.add_parser("check", help="load and validate a mesh; report degenerate faces, non-manifold edges, holes")
    c.add_argument("mesh", type=Path, help="OBJ, PLY, STL, OFF, GLB or GLTF file")
    c.add_argument("--units", choices=["mm", "cm", "m"], default="m", help="units of the file (default m)")
    c.set_defaults(func=cmd_mesh_check)

    lmp = sub.add_parser("landmarks", help="inspect FDP landmark files")
    lsub = lmp.add_subparsers(dest="landmarks_command", metavar="ACTION", parser_class=_Parser)
    lsub.required = True
    c = lsub.add_parser("check", help="load and validate a landmark file (JSON or MeshLab .pp)")
    c.add_argument("landmarks", type=Path, help='JSON {"3.7": [x, y, z], ...} or MeshLab picked points .pp')
    c.add_argument("--units", choices=["mm", "cm", "m"], default="m", help="units of the file (default m)")
    c.set_defaults(func=cmd_landmarks_check)

    a = sub.add_parser("adapt", help="fit the template to a range scan (calibration, RBF, multi-level CSRBF)")
    a.add_argument("scan", type=Path, help="scan mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    a.add_argument("--landmarks", required=True, type=Path, help="FDPs on the scan (JSON or .pp), in --units")
    a.add_argument("--out", required=True, type=Path, help="output folder")
    a.add_argument("--template", type=Path, help="template folder from `facewarp template export` (default: the built-in level 0)")
    a.add_argument("--template-mesh", type=Path, help="any template mesh with FDP landmarks (e.g. ICT-FaceKit neutral)")
    a.add_argument("--template-landmarks", type=Path, help="FDPs of --template-mesh (JSON or .pp)")
    a.add_argument("--method", choices=["rbf", "csrbf", "multilevel"], default="multilevel")
    a.add_argument("--levels", type=int, default=5, help="level limit (default 5)")
    a.add_argument("--markers", type=Path, help="FDPs held out of training, for the marker error E_m")
    a.add_argument("--units", choices=["mm", "cm", "m"], default="m", help="units of the scan and its landmarks")
    a.add_argument("--template-units", choices=["mm", "cm", "m"], default="m", help="units of --template-mesh")
    a.set_defaults(func=cmd_adapt)

    b = sub.add_parser("build", help="skin tetrahedra, muscles and boundary conditions of a head (Sec. 6.2-6.3)")
    b.add_argument("head", help="a `template export` folder, an `adapt` output folder, or 'default[:LEVEL]'")
    b.add_argument("--out", required=True, type=Path, help="output folder")
    b.add_argument("--layers", type=int, default=1, help="tet layers through the skin (default 1)")
    b.set_defaults(func=cmd_build)

    s = sub.add_parser("simulate", help="play an expression on a `build` output (Warp physics, Sec. 6.4-6.5)")
    s.add_argument("head", type=Path, help="a `facewarp build` output folder")
    s.add_argument("--expression", required=True,
                   help="smile, laugh, surprise, angry, sad (Table 6.4), 'sequence' (Fig. 6.16) or a sequence .json")
    s.add_argument("--seconds", type=float, default=2.0, help="simulated time [s] (default 2)")
    s.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    s.add_argument("--substeps", type=int, help="substeps per frame (default: from the stable time step)")
    s.add_argument("--out", required=True, type=Path, help="output folder")
    s.add_argument("--usd", action="store_true", help="also write frames.usda (time-sampled skin, eyes, teeth)")
    s.set_defaults(func=cmd_simulate)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, or a usage error already printed as one line
        return int(e.code or 0)
    try:
        _check_device(args.device)
        args.func(args)
    except FacewarpError as e:
        print(f"facewarp: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("facewarp: interrupted", file=sys.stderr)
        return 130
    except OSError as e:
        print(f"facewarp: error: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
        return EXIT_USAGE
    return 0


if __name__ == "__main__":
    sys.exit(main())
