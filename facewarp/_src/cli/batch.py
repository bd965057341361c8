"""``facewarp batch``: many scans through the pipeline (run), many builds in one FaceBatch (simulate)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ..core.limits import MAX_ADAPT_LEVELS, MAX_FPS, MAX_SECONDS
from .common import FacewarpError, FrameBar, Parser, emit, muscle_list, fps, number, out_dir, path, seconds, whole_in


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    bt = sub.add_parser("batch", help="many scans through adapt, build, simulate and rig, in local processes or on Ray")
    btsub = bt.add_subparsers(dest="batch_command", metavar="ACTION", parser_class=Parser)
    btsub.required = True
    br = btsub.add_parser("run", example="facewarp batch run scans/a.ply scans/b.ply --units mm --out batch --workers 2",
                          help="run every scan through the chosen steps; a manifest makes re-runs skip finished work",
        epilog="Writes DIR/manifest.json (per scan: inputs with their SHA-256, each step's status, error, outputs, "
               "seconds and worker; rewritten atomically as tasks finish), DIR/scans/NAME-KEY/{adapt,build,simulate,rig}/, "
               "DIR/report.json and DIR/report.csv. A scan is known by its content: a re-run (or a renamed copy) "
               "skips the steps done; a step not chosen must be done from an earlier run for the steps that read it "
               "(simulate and rig read the build: --steps rig alone rigs the builds in DIR). A scan's landmarks are looked for beside it (NAME_landmarks.json, "
               "NAME.landmarks.json, NAME.json, NAME.pp, landmarks.json), else found on the scan. Ray: "
               "pip install 'facewarp[ray]'; --ray alone starts a local Ray, --ray auto or --ray ray://HOST:10001 "
               "joins a cluster (`ray start --head`; the scans and DIR on a file system every node sees). Every option "
               "is checked before the first scan's adapt. Exit code: 0 every scan done; 1 some scans failed or are "
               "incomplete (the summary line says which, report.csv why); 2 nothing could start (a bad option, "
               "scan or --out, or --out held by another run); 130 / 143 interrupted (SIGINT / SIGTERM: the "
               "finished steps, the manifest and the reports kept).")
    br.add_argument("scans", nargs="*", type=Path, metavar="SCANS", help="scan meshes (OBJ, PLY, STL, OFF, GLB, GLTF)")
    br.add_argument("--manifest", type=Path, metavar="IN.json",
                    help='the scans as a file: {"scans": ["a.obj", {"scan": "b.ply", "landmarks": "b.json", '
                         '"units": "mm", "name": "b"}]} (paths relative to the file), or a batch\'s manifest.json')
    br.add_argument("--out", required=True, type=path, metavar="DIR",
                    help="batch folder (continued if it has a manifest; locked while the batch runs)")
    br.add_argument("--steps", type=steps, default=("adapt", "build", "simulate"), metavar="adapt,build,simulate,rig",
                    help="the steps to run, in this order per scan (default adapt,build,simulate); rig: the build's "
                         "blendshape rig as `facewarp rig` bakes it (UsdSkel, glTF) into NAME-KEY/rig/")
    br.add_argument("--expression", default="smile", metavar="NAME|sequence|FILE.json",
                    help="what simulate plays (as `facewarp simulate --expression`; default smile)")
    br.add_argument("--seconds", type=seconds, metavar="S", default=2.0,
                    help=f"simulated time [s], > 0 and <= {MAX_SECONDS:g} (default 2)")
    br.add_argument("--levels", type=whole_in(1, MAX_ADAPT_LEVELS), metavar="N", default=2,
                    help=f"adapt's refinement levels after the FDP level (as `facewarp adapt --levels`; 1..{MAX_ADAPT_LEVELS}, default 2)")
    br.add_argument("--rig-formats", type=rig_formats, default=("usdc", "glb"), metavar="usdc,usda,glb",
                    help="the rig step's files rig.FORMAT, one bake written in each (default usdc,glb)")
    br.add_argument("--rig-inbetweens", type=whole_in(0, 8), default=0, metavar="K",
                    help="the rig step's in-between shapes per muscle (as `facewarp rig --inbetweens`; 0..8, default 0)")
    br.add_argument("--rig-muscles", type=muscle_list, default=None, metavar="A,B,...",
                    help="the rig step bakes only these muscles (as `facewarp rig --muscles`; default all)")
    br.add_argument("--units", choices=["mm", "cm", "m", "auto"], default=None,
                    help="units of the scans and their landmarks, as `facewarp adapt --units`; default: m when a "
                         "scan's extent is a plausible head in metres, else auto (the scale from the FDPs)")
    br.add_argument("--ray", nargs="?", const="local", metavar="ADDRESS",
                    help="run as Ray tasks: alone, on a local Ray started here; with auto, ray://HOST:10001 or "
                         "HOST:6379, on that cluster")
    br.add_argument("--workers", type=whole_in(1, 1024), metavar="N",
                    help="local worker processes, 1..1024 (default: the usable cores); with --ray the CPUs of the local Ray "
                         "(default: all) or the tasks kept in flight on a cluster")
    br.add_argument("--gpus-per-task", type=number(float, lambda v: math.isfinite(v) and 0 <= v <= 64, "a number 0..64"),
                    metavar="F", help="GPUs per simulate or rig task, 0..64: on Ray its num_gpus (default 1 when the "
                         "cluster has a GPU, else 0: on the CPU); with local processes > 0 runs those steps on cuda "
                         "when this machine has a GPU (default: on --device)")
    br.add_argument("--simulate-batch", type=whole_in(1, 4096), metavar="K",
                    help="scans whose simulate steps together in one FaceBatch task, 1..4096 (default 64 when "
                         "simulate runs on a GPU, else 1: a task per scan); each scan still gets its own "
                         "simulate/ folder and record")
    br.add_argument("--max-retries", type=whole_in(0, 100), metavar="N", default=2,
                    help="retries of a step whose worker process died (killed, out of memory), 0..100, default 2")
    br.add_argument("--retry-failed", action="store_true", help="run the steps that failed in an earlier run again")
    br.set_defaults(func=run_batch_run)
    bs = btsub.add_parser("simulate", example="facewarp batch simulate build_a build_b --expression laugh --out crowd",
                          help="many built heads played together in one FaceBatch (one step, one CUDA graph per frame for all)",
        epilog="Writes DIR/head_KK.usdc (one USD animation per head, in the order given) and DIR/report.json "
               "(per head: status, error, frames sub-stepped; frames/s and head-frames/s of the batch). A head that fails (NaN, inverted tet even when sub-stepped) is frozen at its "
               "last good frame and reported; the others go on. --per-head FILE.json: {\"heads\": [\"smile\", "
               "{\"expression\": \"laugh\"}, ...]}, one entry per BUILD.")
    bs.add_argument("builds", nargs="+", type=Path, metavar="BUILD", help="`facewarp build` output folders")
    bs.add_argument("--expression", default="smile", metavar="NAME|sequence|FILE.json",
                    help="what every head plays (as `facewarp simulate --expression`; default smile)")
    bs.add_argument("--per-head", type=path, metavar="FILE.json", help="one expression per head (overrides --expression)")
    bs.add_argument("--seconds", type=seconds, metavar="S", default=2.0,
                    help=f"simulated time [s], > 0 and <= {MAX_SECONDS:g} (default 2)")
    bs.add_argument("--fps", type=fps, metavar="F", default=30.0,
                    help=f"frames per second, > 0 and <= {MAX_FPS:g} (default 30)")
    bs.add_argument("--jaw", choices=["kinematic", "mujoco"], default="kinematic",
                    help="kinematic (default: Eq. 6.4.9 angles, inside the batched step) or mujoco (each build's "
                         "head.xml hinge body two-way coupled, one CPU MuJoCo per head stepped in a loop)")
    bs.add_argument("--stage", metavar="FILE.usda|FILE.usdc",
                    help="also DIR/FILE: one stage with every head as /Crowd/head_KK (referencing its file), side by side")
    bs.add_argument("--out", required=True, type=path, metavar="DIR", help="output folder")
    bs.set_defaults(func=run_batch_simulate, outputs=out_dir)


# ----------------------------------------------------------------------------- argument types of batch
def steps(text: str) -> tuple[str, ...]:
    from ..fleet.manifest import STEPS as known

    names = [t.strip() for t in text.split(",") if t.strip()]
    bad = [n for n in names if n not in known]
    if not names or bad:
        raise argparse.ArgumentTypeError(f"expected a comma list of {', '.join(known)}, got {text!r}")
    return tuple(names)




def rig_formats(text: str) -> tuple[str, ...]:
    from ..fleet.batch import RIG_FORMATS

    names = [t.strip().lower().lstrip(".") for t in text.split(",") if t.strip()]
    bad = [n for n in names if n not in RIG_FORMATS]
    if not names or bad:
        raise argparse.ArgumentTypeError(f"expected a comma list of {', '.join(RIG_FORMATS)}, got {text!r}")
    return tuple(names)



# ----------------------------------------------------------------------------- run and report
def run_batch_run(args):
    from ..fleet.batch import run_batch
    from ..fleet.manifest import STEPS, read_input_list, scans_from_paths

    if bool(args.scans) == (args.manifest is not None):
        raise FacewarpError("batch run: give scans or --manifest IN.json, not both" if args.scans
                            else "batch run: give scans (SCANS...) or --manifest IN.json")
    if args.ray is not None and args.ray != "local" and Path(args.ray).is_file():
        raise FacewarpError(f"--ray {args.ray}: is a file, not a Ray address (put --ray after the scans, "
                            "or write --ray local)")
    scans = (read_input_list(args.manifest, units=args.units) if args.manifest is not None
             else scans_from_paths(args.scans, units=args.units))
    rep = run_batch(scans, args.out, steps=args.steps, expression=args.expression, seconds=args.seconds,
                    levels=args.levels, rig_formats=args.rig_formats, rig_inbetweens=args.rig_inbetweens,
                    rig_muscles=args.rig_muscles,
                    device=args.device, ray=args.ray, workers=args.workers,
                    gpus_per_task=args.gpus_per_task, simulate_batch=args.simulate_batch,
                    max_retries=args.max_retries, retry_failed=args.retry_failed,
                    progress=not args.json)
    cols = list(STEPS)
    width = max([len(r["name"]) for r in rep["rows"]] + [4])
    lines = [f"batch of {rep['scans']} scans in {args.out} on {rep['executor']}: {rep['done']} done, "
             f"{rep['failed']} failed, {rep['incomplete']} incomplete ({rep['tasks_run']} steps run, "
             f"{rep['tasks_kept']} kept from earlier runs) in {rep['seconds']:.1f} s: {rep['outcome']} "
             f"(exit {rep['exit_code']})",
             f"  {'scan':<{width}}  " + "  ".join(f"{c + ' [s]':>12}" for c in cols) + "  status"]
    shown = rep["rows"][:50]
    for r in shown:
        cells = []
        for c in cols:
            v = r.get(f"{c}_s")
            cells.append(f"{v:>12.1f}" if v is not None else f"{('failed' if r['failed_step'] == c else '-'):>12}")
        lines.append(f"  {r['name']:<{width}}  " + "  ".join(cells) + f"  {r['status']}"
                     + (f": {r['failed_step']}: {r['error']}" if r["error"] else ""))
    if len(rep["rows"]) > len(shown):
        lines.append(f"  ... {len(rep['rows']) - len(shown)} more in {rep['report_csv']}")
    g = rep["simulate_grouping"]
    if g["groups"]:
        lines.append(f"  simulate: {g['grouped_scans']} scans in {g['groups']} FaceBatch groups of up to "
                     f"{g['batch']}")
    if g["fallbacks"]:
        lines.append(f"  simulate: {g['fallbacks']} scans of a group simulated alone instead (the group could not "
                     f"step together: {'; '.join(g['fallback_errors'])})")
    lines.append(f"  wrote {rep['manifest']}, {rep['report']}, {rep['report_csv']}")
    emit(args, rep, lines)
    return rep["exit_code"]


def run_batch_simulate(args):
    from ..jobs.batch_simulate import batch_simulate_files

    bar = FrameBar(not args.json)
    try:
        rep = batch_simulate_files(args.builds, args.expression, args.out, per_head=args.per_head,
                                   seconds=args.seconds, fps=args.fps, device=args.device, jaw=args.jaw, stage=args.stage,
                                   progress=bar)
    finally:
        bar.close()
    width = max(len(Path(r["build"]).name) for r in rep["rows"])
    lines = [f"batch of {rep['heads']} heads on {rep['device']} ({rep['jaw']} jaw): {rep['ok']} ok, {rep['failed']} failed; "
             f"{rep['frames']} frames ({rep['seconds']:g} s) at {rep['frames_per_second']:.1f} frames/s, "
             f"{rep['head_frames_per_second']:.1f} head-frames/s (heads made in {rep['build_seconds']:.1f} s)"]
    for r in rep["rows"][:50]:
        lines.append(f"  {r['head']:>4}  {Path(r['build']).name:<{width}}  {r['expression']:<12}  "
                     + ("ok" if r["ok"] else f"FAILED: {r['error']}")
                     + (f" ({r['substepped_frames']} frames sub-stepped)" if r["substepped_frames"] else ""))
    if len(rep["rows"]) > 50:
        lines.append(f"  ... {len(rep['rows']) - 50} more in report.json")
    lines.append(f"  wrote {len(rep['files']) - 1} USD files and report.json in {args.out}"
                 + (f" ({args.stage}: every head in one stage)" if args.stage else ""))
    emit(args, rep, lines)

