"""The Verlet reference on the default head: every Table 6.4 preset and the Fig. 6.16 sequence.

``python benchmarks/verlet_reference.py [--seconds S] [--sequence-each S] [--materials thesis,physical]
[--jobs N]`` runs :class:`facewarp.FaceSimulator` with ``solver="verlet"`` (the explicit reference
at its stable substep, kinematic jaw) on the default head (level 0) for the five presets (each
over ``--seconds``, the CLI's timeline: ramp up, hold, ramp down) and the Fig. 6.16 sequence
(:func:`facewarp.thesis_sequence` with ``--sequence-each`` seconds per expression, run to its
end), for each material profile, and writes ``benchmarks/results/verlet_reference.json``: per
case the frames, substeps, whether and where a tet inverted or a node went NaN (the solver's
guard), the smallest tet volume over rest volume seen in any frame, and the wall seconds.
Durations shorter than the CLI's defaults keep a run of both profiles within the hour on a
2-core box; the JSON says which were used. Public API only.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

if __package__ in (None, ""):  # run as a script: the repository root on the path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._common import machine, save  # noqa: E402

PRESETS = ("smile", "laugh", "surprise", "angry", "sad")
MATERIALS = ("thesis", "physical")


def _volumes(X, T):
    import numpy as np

    e1, e2, e3 = (X[T[:, c]] - X[T[:, 0]] for c in (1, 2, 3))
    return np.einsum("ij,ij->i", e1, np.cross(e2, e3)) / 6.0


def run_case(case: str, material: str, seconds: float, sequence_each: float, device: str = "cpu") -> dict:
    """One preset (or ``"sequence"``) with one material profile; the row of the result JSON."""
    import numpy as np

    import facewarp as fw

    rig = fw.build_face(fw.default_template(0))
    if case == "sequence":
        timeline = fw.thesis_sequence(each=sequence_each)
        seconds = float(max(s.end for s in timeline.segments))
    else:
        timeline = fw.expressions.timeline_from_spec(case, seconds)
    sim = fw.FaceSimulator(rig, device=device, solver="verlet", material=material)
    T = np.asarray(rig.tets, np.int64)
    v0 = _volumes(np.asarray(rig.nodes, np.float64), T)
    low = [float("inf")]
    nan = [False]

    def on_frame(k, n):
        X = sim.positions().astype(np.float64)
        if not np.isfinite(X).all():
            nan[0] = True
            return
        low[0] = min(low[0], float((_volumes(X, T) / v0).min()))

    row = {"case": case, "material": material, "seconds": seconds, "substeps_per_frame": int(sim.substeps),
           "dt_s": float(sim.dt), "added_mass_fraction": float(sim.added_mass_fraction)}
    t0 = time.perf_counter()
    error = None
    try:
        frames = sim.run(timeline, seconds, progress=on_frame)
        row["frames"] = int(len(frames.times))
    except fw.SimulationError as e:
        error = str(e)
        row["frames"] = None
    row["wall_seconds"] = round(time.perf_counter() - t0, 1)
    row["substeps"] = int(sim.solver.step_count)
    row["failed"] = error
    row["inverted_tets"] = int(error is not None and "inverted" in error)
    row["nan"] = bool(nan[0] or (error is not None and "non-finite" in error))
    row["min_tet_volume_ratio"] = None if low[0] == float("inf") else round(low[0], 4)
    return row


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=1.0, help="length of each preset run [s] (default 1)")
    p.add_argument("--sequence-each", type=float, default=0.8,
                   help="seconds per expression of the Fig. 6.16 sequence (default 0.8: 3 s in all)")
    p.add_argument("--materials", default=",".join(MATERIALS), help="comma-separated profiles")
    p.add_argument("--cases", default=",".join(PRESETS + ("sequence",)), help="comma-separated presets / sequence")
    p.add_argument("--jobs", type=int, default=1, help="cases run in parallel processes (default 1)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--name", default="verlet_reference", help="result file name in benchmarks/results")
    args = p.parse_args(argv)
    materials = [m for m in args.materials.split(",") if m]
    cases = [c for c in args.cases.split(",") if c]
    result = {"machine": machine(args.device), "head": "default template, level 0", "solver": "verlet",
              "jaw": "kinematic", "preset_seconds": args.seconds, "sequence_each_s": args.sequence_each,
              "note": ("shortened runs: presets over --seconds (the CLI's timeline: ramp min(0.3, s/4), hold, "
                       "release), the sequence with --sequence-each seconds per expression"),
              "cases": []}
    import facewarp

    result["machine"]["facewarp"] = getattr(facewarp, "__version__", "")
    # profile by profile in the order given, the sequence (the longest) first
    todo = sorted(((c, m) for m in materials for c in cases), key=lambda cm: (materials.index(cm[1]), cm[0] != "sequence"))
    t0 = time.perf_counter()

    def done(row):
        result["cases"].append(row)
        result["cases"].sort(key=lambda r: (r["material"], r["case"]))
        result["total_wall_seconds"] = round(time.perf_counter() - t0, 1)
        save(args.name, result)  # after every case: a long run keeps what it has
        print(f"{row['material']:8s} {row['case']:9s} frames {row['frames']} substeps {row['substeps']} "
              f"min V/V0 {row['min_tet_volume_ratio']} {row['wall_seconds']} s {row['failed'] or 'ok'}", flush=True)

    if args.jobs <= 1:
        for c, m in todo:
            done(run_case(c, m, args.seconds, args.sequence_each, args.device))
    else:
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            futures = [pool.submit(run_case, c, m, args.seconds, args.sequence_each, args.device) for c, m in todo]
            for f in as_completed(futures):
                done(f.result())
    return result


if __name__ == "__main__":
    main()
