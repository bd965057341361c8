"""``facewarp drive``: drive a ``build`` output from data (markers, ARKit curves)."""

from __future__ import annotations

from pathlib import Path

from .common import FrameBar, emit, fps, out_dir_or_usd, progress_lines


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    dr = sub.add_parser("drive", example="facewarp drive build --arkit take.csv --out take.usdc",
                        help="drive a `build` output from data: muscle activations and jaw solved per frame from markers, "
                      "or ARKit curves through the head's ARKit table",
        epilog="Formats (docs: guides/driving): markers JSON {\"fps\": 30, \"units\": \"mm\", \"markers\": "
               "{\"2.1\": [[x, y, z], null, ...], \"v123\": [...]}}; markers CSV: time (s) or frame column, then "
               "NAME_x, NAME_y, NAME_z per marker; C3D (pip install 'facewarp[mocap]') with --map; points are FDP "
               "ids or v<vertex index>. Live Link Face CSV (Timecode, BlendShapeCount, EyeBlinkLeft, ..., HeadYaw, "
               "HeadPitch, HeadRoll, ...); MediaPipe Face Landmarker JSON [{\"timestamp_ms\": .., "
               "\"face_blendshapes\": [[{\"category_name\": .., \"score\": ..}, ...]]}, ...]. Writes "
               "DIR/activations.csv, frames.npz, animation.usdc, report.json, drive.png (markers), activations.png; "
               "a .usd[a|c|z] --out is the animation alone.")
    dr.add_argument("build", type=Path, metavar="BUILD", help="a `facewarp build` output folder")
    src = dr.add_mutually_exclusive_group(required=True)
    src.add_argument("--markers", type=Path, metavar="FILE", help="a marker take: .json, .csv or .c3d")
    src.add_argument("--arkit", type=Path, metavar="FILE.csv", help="ARKit curves: a Live Link Face CSV")
    src.add_argument("--mediapipe", type=Path, metavar="FILE.json", help="ARKit curves: MediaPipe Face Landmarker "
                     "blendshapes")
    dr.add_argument("--map", type=Path, metavar="MAP.json", help='marker labels to points: {"LBRO": "4.1", '
                    '"CHIN": "2.1", "M12": "v966"}; labels not in it are left out')
    dr.add_argument("--units", choices=["mm", "cm", "m"], default=None,
                    help="units of the marker coordinates (CSV: default m; JSON and C3D say their own)")
    dr.add_argument("--fps", type=fps, metavar="F", default=None,
                    help="frames per second, for files that do not carry it (a CSV with a frame column)")
    dr.add_argument("--no-rigid", action="store_true",
                    help="keep the take as it is (already in the head's frame): no fit of forehead, nose bridge and "
                         "ear roots to remove head motion")
    dr.add_argument("--out", required=True, type=Path, metavar="DIR|FILE.usd[a|c|z]",
                    help="output folder, or a USD file (the animation alone)")
    dr.add_argument("--rig", type=Path, metavar="RIGDIR", default=None,
                    help="a `facewarp rig --out RIGDIR` folder of this head: also write the take as that rig's "
                         "animation (take.glb, take.usdc: ARKit weights on its ARKit shapes, else muscle weights) "
                         "and report how far the rig's blend lands from the simulated face")
    dr.set_defaults(func=run, outputs=out_dir_or_usd)


# ----------------------------------------------------------------------------- run and report
def run(args):
    from ..jobs.drive import drive_files

    writer = progress_lines("drive", "reading the take and the build (the first run on a machine compiles Warp's "
                                    "kernels)", not args.json)  # off a terminal: one writer for both bars
    bar = FrameBar(not args.json, lines=writer)
    table_bar = FrameBar(not args.json, desc="ARKit table (once per build)", unit="shape", lines=writer)
    try:
        rep = drive_files(args.build, args.out, markers=args.markers, arkit=args.arkit, mediapipe=args.mediapipe,
                          map=args.map, units=args.units, fps=args.fps, rigid=not args.no_rigid, device=args.device,
                          progress=bar, table_progress=lambda done, total, name: table_bar(done, total),
                          **({"rig": args.rig} if getattr(args, "rig", None) is not None else {}))
    finally:
        table_bar.close()
        bar.close()
        if writer is not None:
            writer.close()
    lines = [f"drove {args.build} from {rep['source']} ({rep['kind']}): {rep['frames']} frames at {rep['fps']:g} fps "
             f"in {rep['seconds']:.1f} s on {rep['device']}"]
    e = rep.get("error_mm")
    if e and e.get("rms") is not None:
        worst = max(((v, k) for k, v in e["per_point_rms"].items() if v is not None), default=(None, None))
        what = "simulated to target" if rep["kind"] == "markers" else "head FDPs to the blended ARKit targets"
        lines.append(f"  distance {what}: RMS {e['rms']:.2f} mm, max {e['max']:.2f} mm"
                     + (f" (worst point {worst[1]}: RMS {worst[0]:.2f} mm)" if worst[1] is not None else ""))
    if rep.get("table"):
        t = rep["table"]
        lines.append(f"  ARKit table {t['file']}" + (" (cached)" if t["from_cache"] else
                                                     " (built now, cached for later runs)" if t.get("cached", True)
                                                     else " (built now, not cached: see the note)"))
    reach = rep.get("reach", [])
    for r in reach[:8]:  # each ARKit shape the take uses: what reaches it and how closely
        lines.append(f"  reach {r['name']}: {r['by']}" + (f", {r['residual_mm']:.2f} mm RMS from its shape "
                                                          f"({r['target_mm']:.2f} mm)" if r["residual_mm"] is not None else ""))
    if len(reach) > 8:
        lines.append(f"  ... {len(reach) - 8} more shapes' reach in report.json")
    warnings = rep.get("warnings", [])
    lines += [f"  warning: {w}" for w in warnings]
    hm = rep.get("head_motion")
    if hm:
        lines.append(f"  head motion removed by a fit of {len(hm['stable_points'])} stable points"
                     + (f" ({hm['frames_held']} frames held the pose before them)" if hm["frames_held"] else ""))
    rt = rep.get("rig_take")
    if rt:
        lines.append(f"  on the rig ({rt['clip']} clip, {len(rt['shapes'])} shapes): its blend from the simulated face "
                     f"p95 {rt['error_mm']['p95']:.2f} mm, max {rt['error_mm']['max']:.2f} mm")
    notes = [n for n in rep.get("notes", []) if n not in warnings]
    lines += [f"  note: {n}" for n in notes[:6]]
    if len(notes) > 6:
        lines.append(f"  ... {len(notes) - 6} more notes in report.json")
    lines.append("  wrote " + ", ".join(rep["files"]))
    emit(args, rep, lines)

