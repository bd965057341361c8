"""All Table 6.4 presets and the Fig. 6.16 sequence for 10 simulated seconds each: no NaN, no inverted tet,
no lip-lip, lip-teeth or lid-lid crossing in any frame.

    python -m benchmarks.expressions_long [--device cpu|cuda] [--seconds 10] [--head default|identityNNN|BUILD_DIR] [--name NAME]
                                          [--solver implicit|verlet] [--material physical|thesis]

Each expression ramps up, holds and releases within the run; the solver's guard checks every frame
for NaN and inverted tets (a failure is recorded with the step and tet it names), and every frame's
contact crossings (:meth:`facewarp.FaceSimulator.contact_crossings`: lip nodes inside the other lip,
nodes inside the teeth, lid nodes across their fissure plane; lid nodes in an eyeball by their depth,
since some sit inside it at rest) are recorded at their worst. Writes
benchmarks/results/expressions_long_<device>[_<solver>_<material>][_<NAME>].json (the suffix for other
than the default implicit solver and physical material) and a frame strip per expression to
benchmarks/results/expressions/[<NAME>_]<expression>_<device>.png (NAME defaults to the build folder's
parent, e.g. identity001 for .../identity001/build; nothing for the default template).
"""

from __future__ import annotations

import argparse
import time
import numpy as np

from benchmarks._common import RESULTS, add_case_args, case_face, head_tag, save


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--fps", type=float, default=30.0)
    add_case_args(ap, device="cpu", head="default")
    ap.add_argument("--name", help="tag of the head in the output names")
    ap.add_argument("--expressions", nargs="+", default=["smile", "laugh", "surprise", "angry", "sad", "sequence"])
    ap.add_argument("--solver", default="implicit", choices=["implicit", "verlet"])
    ap.add_argument("--material", default="physical", choices=["physical", "thesis"])
    args = ap.parse_args(argv)
    from facewarp import FaceSimulator, SimulationError, save_png
    from facewarp.render import render_strip
    from facewarp.expressions import timeline_from_spec
    from facewarp.render import displacement_max

    fr = case_face(args.head)
    rows = []
    outdir = RESULTS / "expressions"
    outdir.mkdir(parents=True, exist_ok=True)
    tag = args.device.split(":")[0]
    head_name = args.name or head_tag(args.head)
    prefix = f"{head_name}_" if head_name else ""
    if (args.solver, args.material) != ("implicit", "physical"):
        prefix += f"{args.solver}_{args.material}_"
    for name in args.expressions:
        sim = FaceSimulator(fr, device=args.device, fps=args.fps, solver=args.solver, material=args.material)
        t0 = time.perf_counter()
        row = {"expression": name, "seconds_simulated": args.seconds, "solver": args.solver, "material": args.material,
               "substeps": sim.substeps, "dt_s": sim.dt, "added_mass_fraction": sim.added_mass_fraction}
        worst = {}

        def check(k, nf, sim=sim, worst=worst):  # every frame's crossings, the worst kept
            for key, v in sim.contact_crossings().items():
                worst[key] = max(worst.get(key, 0), v)

        try:
            frames = sim.run(timeline_from_spec(name, args.seconds), args.seconds, progress=check)
            crossed = sum(worst.get(k, 0) for k in ("lip_lip", "lip_teeth", "lid_lid"))
            row.update(ok=crossed == 0, crossings_worst_frame={(k[:-2] + "_mm" if k.endswith("_m") else k):
                                                               (round(v * 1e3, 4) if k.endswith("_m") else v)
                                                               for k, v in worst.items()},
                       nan_count=int((~np.isfinite(frames.points)).sum()), inverted_count=0,
                       steps_per_second=frames.steps_per_second, frames_per_second=frames.frames_per_second,
                       realtime_factor=frames.realtime_factor)
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
    variant = "" if (args.solver, args.material) == ("implicit", "physical") else f"_{args.solver}_{args.material}"
    out = f"expressions_long_{tag}{variant}" + (f"_{head_name}" if head_name else "")
    print("wrote", save(out, {"head": args.head, "tets": int(len(fr.tets)),
                              "all_ok": all(r.get("ok") for r in rows), "runs": rows}, device=args.device))


if __name__ == "__main__":
    raise SystemExit(main())
