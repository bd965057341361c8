"""All Table 6.4 presets and the Fig. 6.16 sequence for 10 simulated seconds each: no NaN, no inverted tet.

    python -m benchmarks.expressions_long [--device cpu|cuda] [--seconds 10] [--head default|BUILD_DIR] [--name NAME]

Each expression ramps up, holds and releases within the run; the solver's guard checks every frame
for NaN and inverted tets (a failure is recorded with the step and tet it names). Writes
benchmarks/results/expressions_long_<device>[_<NAME>].json and a frame strip per expression to
benchmarks/results/expressions/[<NAME>_]<expression>_<device>.png (NAME defaults to the build folder's
parent, e.g. identity001 for .../identity001/build; nothing for the default template).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks._common import RESULTS, machine, save


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--head", default="default")
    ap.add_argument("--name", help="tag of the head in the output names")
    ap.add_argument("--expressions", nargs="+", default=["smile", "laugh", "surprise", "angry", "sad", "sequence"])
    args = ap.parse_args()
    from facewarp._src.anatomy.build import build_anatomy
    from facewarp._src.core.errors import SimulationError
    from facewarp._src.sim.face import FaceSimulator, face_rig_from_anatomy, load_face_rig
    from facewarp._src.jobs.files import _timeline, displacement_max, load_head, render_strip
    from facewarp._src.present.render import save_png

    if Path(args.head, "face_rig.npz").is_file():
        fr = load_face_rig(args.head)
    else:
        fr = face_rig_from_anatomy(build_anatomy(load_head(args.head), check_intersections=False))
    rows = []
    outdir = RESULTS / "expressions"
    outdir.mkdir(parents=True, exist_ok=True)
    tag = args.device.split(":")[0]
    head_name = args.name or ("" if args.head == "default" else Path(args.head).resolve().parent.name)
    prefix = f"{head_name}_" if head_name else ""
    for name in args.expressions:
        sim = FaceSimulator(fr, device=args.device, fps=args.fps)
        t0 = time.perf_counter()
        row = {"expression": name, "seconds_simulated": args.seconds, "substeps": sim.substeps, "dt_s": sim.dt,
               "added_mass_fraction": sim.added_mass_fraction}
        try:
            frames = sim.run(_timeline(name, args.seconds), args.seconds)
            row.update(ok=True, nan_count=int((~np.isfinite(frames.points)).sum()), inverted_count=0,
                       steps_per_second=frames.steps_per_second)
            moved = np.linalg.norm(frames.fdp_points - frames.fdp_points[:1], axis=2)
            ids = list(map(str, frames.fdp_ids))
            peak = int(np.argmax(moved.max(1)))
            row["peak_time_s"] = float(frames.times[peak])
            row["peak_fdp_motion_mm"] = {k: round(float(moved[peak, i]) * 1e3, 2) for i, k in enumerate(ids)
                                         if moved[peak, i] > 5e-4}
            nf = len(frames.times)
            idx = np.unique(np.r_[0, np.linspace(0, nf - 1, 6).round().astype(int), peak])
            hmax = displacement_max(frames, idx)
            save_png(outdir / f"{prefix}{name}_{tag}.png", render_strip(frames, idx, device=args.device, heat_max=hmax),
                     title=f"{prefix}{name} ({args.device}): " + ", ".join(f"{frames.times[k]:.1f} s" for k in idx),
                     colorbar=(0.0, hmax * 1e3, "displacement from rest [mm]"))
        except SimulationError as e:
            row.update(ok=False, error=str(e))
        row["wall_seconds"] = time.perf_counter() - t0
        print(row if not row.get("ok") else {k: v for k, v in row.items() if k != "peak_fdp_motion_mm"}, flush=True)
        rows.append(row)
    out = f"expressions_long_{tag}" + (f"_{head_name}" if head_name else "")
    print("wrote", save(out, {"machine": machine(args.device), "head": args.head, "tets": int(len(fr.tets)),
                              "all_ok": all(r.get("ok") for r in rows), "runs": rows}))


if __name__ == "__main__":
    main()
