"""``facewarp adapt``: fit the template to a range scan (calibration, RBF, multi-level CSRBF)."""

from __future__ import annotations

from pathlib import Path

from ..core.limits import MAX_ADAPT_LEVELS
from .common import FacewarpError, Progress, emit, out_dir, whole_in


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    a = sub.add_parser("adapt", example="facewarp adapt scan.ply --landmarks scan_landmarks.json --units mm --out head",
                       help="fit the template to a range scan (calibration, RBF, multi-level CSRBF)",
                       epilog="Inputs are checked before the adaptation: scan and landmarks in the same units, at "
                              "least 4 FDPs shared with the template and not coplanar, every landmark near the scan "
                              "surface.")
    a.add_argument("scan", type=Path, help="scan mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    a.add_argument("--landmarks", type=Path, metavar="LM.json", help="landmarks on the scan, in --units: FDPs (JSON or .pp), or the "
                   "68- or 51-point scheme (a JSON list of [x, y, z] or an iBUG .pts file: with the default template every "
                   "point is used, else the points that mark an FDP; see --landmark-scheme) (default: found on the scan as by `facewarp landmarks detect`, "
                   "written to detected_landmarks.json)")
    a.add_argument("--landmark-scheme", choices=["auto", "fdp", "ibug68", "ibug51"], default="auto",
                   help="scheme of --landmarks: auto (default: named FDPs, or a list of 68 or 51 points), fdp, ibug68 "
                        "(iBUG 300-W / Multi-PIE order) or ibug51 (its 51 inner points); another scheme is an error")
    a.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    a.add_argument("--template", type=Path, metavar="DIR", help="template folder from `facewarp template export` (default: the built-in level 0)")
    a.add_argument("--template-mesh", type=Path, metavar="MESH", help="any template mesh with FDP landmarks (e.g. ICT-FaceKit neutral)")
    a.add_argument("--template-landmarks", type=Path, metavar="LM.json", help="FDPs of --template-mesh (JSON or .pp)")
    a.add_argument("--method", choices=["rbf", "csrbf", "multilevel"], default="multilevel",
                   help="multilevel (default: global RBF while the feature points are few, then compactly "
                        "supported RBF), rbf or csrbf at every level")
    a.add_argument("--levels", type=whole_in(1, MAX_ADAPT_LEVELS), metavar="N", default=2,
                   help="refinement levels after the FDP level, each adding feature points from the feature mesh "
                        f"and the curvature search (Sec. 4.5); whole number 1..{MAX_ADAPT_LEVELS}, default 2; stops early when the "
                        "error E (Eq. 5.2.3) rises. report.json numbers them 2..N+1 after level 0 (the calibrated "
                        "template) and level 1 (the FDPs), then the final stages (field: a smooth field fitted to "
                        "point-to-plane pairs; land: onto the scan along the normals; relax)")
    a.add_argument("--markers", type=Path, metavar="MARKERS.json", help="FDPs held out of training, for the marker error E_m")
    a.add_argument("--units", choices=["mm", "cm", "m", "auto"], default=None,
                   help="units of the scan and its landmarks; auto: the scale from the FDPs against human proportions "
                        "(eye distance, eye to mouth, nose length; README). Default: m when the scan's extent is a "
                        "plausible head in metres, else auto. FDPs far outside human proportions in the given units "
                        "stop the run")
    a.add_argument("--template-units", choices=["mm", "cm", "m"], default="m", help="units of --template-mesh")
    a.add_argument("--texture-size", type=whole_in(64, 16384), default=2048, metavar="PX",
                   help="side of texture.png, the scan's colour baked over the head's UVs (64..16384, default 2048; "
                        "written when the scan has colour)")
    a.set_defaults(func=run, outputs=out_dir)


# ----------------------------------------------------------------------------- run and report
def _refinement_summary(levels: list[dict], requested: int) -> str:
    """'FDP level + 3 of 5 refinement levels (level 5 raised E and was undone)'."""
    refine = [r for r in levels if r.get("level", 0) >= 2 and r.get("kind") in ("rbf", "csrbf")]
    kept = [r for r in refine if r.get("accepted", True)]
    undone = [r for r in refine if not r.get("accepted", True)]
    text = f"FDP level + {len(kept)} of {requested} refinement levels"
    if undone:
        text += f" (level {undone[0]['level']} raised the error E and was undone)"
    return text


def run(args):
    from ..jobs.adapt import adapt_files

    if args.template_mesh is not None and args.template is not None:
        raise FacewarpError("give --template or --template-mesh, not both")
    if (args.template_mesh is None) != (args.template_landmarks is None):
        raise FacewarpError("--template-mesh and --template-landmarks go together (a mesh and its FDPs)")
    prog = Progress(4, "adapt", not args.json)
    rep = adapt_files(args.scan, args.landmarks, args.out, template_dir=args.template, template_mesh=args.template_mesh,
                      template_landmarks=args.template_landmarks, method=args.method, levels=args.levels,
                      markers=args.markers, units=args.units, template_units=args.template_units,
                      device=args.device, progress=prog, texture_size=args.texture_size,
                      landmark_scheme=args.landmark_scheme)
    prog.close()
    last = rep["levels"][-1] if rep["levels"] else {}
    d = rep["distance_to_scan_m"]
    sc = rep["scale"]
    if sc["units"] == "auto":
        scale_line = (f"  scale: auto from the FDPs, 1 scan unit = {sc['metres_per_unit']:.4g} m (eye distance "
                      f"{sc['measures_file_units']['eye_distance']:.4g} units; measures agree within "
                      f"{(sc['spread'] - 1) * 100:.0f} %)")
    else:
        scale_line = f"  scale: units {sc['units']} (1 unit = {sc['metres_per_unit']:g} m)"
    tex = rep.get("texture")
    lk = rep.get("likeness", {}).get("mean")
    emit(args, rep, [
        f"adapted {rep['vertex_count']} template vertices to {args.scan} in {rep['seconds']:.2f} s ({rep['method']})",
        scale_line,
        *([f"  texture: the scan's colour baked into {args.out}/texture.png ({tex['size']} px; "
           f"{tex['covered_fraction'] * 100:.0f} % of the head's texels from the scan, the rest filled)",
           f"  likeness: head vs scan from the same cameras, Delta E {lk['delta_e_mean']['textured']:.2f} "
           f"(one flat colour {lk['delta_e_mean']['flat']:.2f}), L* correlation "
           f"{lk['lightness_correlation']['textured']:.2f} (likeness.png)"]
          if tex else []),
        f"  calibration FDPs: {', '.join(rep['calibration']['fdps_used'])}",
        f"  {_refinement_summary(rep['levels'], args.levels)}; final FPs {rep['fp_count']}, "
        f"E_d {last.get('E_d', float('nan')):.3g} m^2",
        f"  distance to scan: median {d['median'] * 1e3:.2f} mm, RMS {d['rms'] * 1e3:.2f} mm",
        f"  surface: {rep['quality']['surface']['folds']} folds; template edges stretched "
        f"{rep['quality']['distortion']['all']['stretch_rms'] * 100:.1f} % RMS (report.json: per region)",
        f"  wrote {args.out}/adapted.obj, adapted_scan_frame.obj, adapted_landmarks.json, report.json, "
        "error_heatmap.png, quality_heatmap.png, distortion_heatmap.png, error_curve.png"
        + (", adapted.glb" if rep.get("uv") else "") + (", texture.png, adapted.mtl, likeness.png" if tex else "")
        + (", detected_landmarks.json" if "detected_landmarks" in rep else ""),
    ])
