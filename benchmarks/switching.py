"""Speed of the CPU solver on a control stream that switches every frame, and where its time goes.

    python -m benchmarks switching [--frames 60] [--accuracy-frames 10] [--seed 1] [--name switching_cpu]
                                   [--modes interactive:4,interactive:8,newton,newton:3e-4]

The soak's stream (``benchmarks/soak.py``: about 40 % of the muscles on with activations drawn in
[0, 1], the jaw anywhere in 0-40 deg opening and +-5 deg side, a new angle every frame, the head
spinning at up to 5 rev/s) on the default head at level 0, CPU, the default solver (L-BFGS on a
reused factorisation, tolerance 3e-5 m), ``--frames`` frames from rest. Per frame: process CPU
seconds (the box may be shared: wall time is recorded beside it), L-BFGS iterations, sparse
factorisations and line-search trials (energy evaluations), and the solver's own timings
(``gradient``: energy and gradient kernels, ``factor``, ``solve``: back-substitution and L-BFGS).
The stream is played twice, with the line search's skipping of inverting trials
(``solver.step_bound``, the default) and without it: the positions must agree (the same steps)
and the trials show what it saves. ``--accuracy-frames`` of the stream are played again fully
converged (tolerance 1e-7 m, springs to 1e-4, up to 500 iterations): the largest distance of any
FDP from the converged one per frame (the 0.5 mm criterion of ``solver_accuracy.py``).
``--modes`` plays the same frames with other settings of the solver, each with its speed and its
distance to the converged frames: ``interactive:K`` (``FaceSimulator(iterations=K)``: K L-BFGS
iterations a frame whatever the residual, the fibre cosine lagged one step), ``newton`` (Newton
with a fresh factorisation every iteration, ``method="newton"``) and ``newton:TOL`` (the same with
the convergence step ``TOL`` [m] and 2 cosine updates).
Writes benchmarks/results/<name>.json (default ``switching_cpu``).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks._common import save
from benchmarks._streams import control_stream

THREADS = 1


def play(rig, frames: int, seed: int, *, step_bound: bool = True, tolerance=None, solver_options=None,
         iterations=None, method=None) -> dict:
    """Play ``frames`` frames of the soak's stream (seed ``seed``) on ``rig``; per-frame figures."""
    import facewarp as fw

    sim = fw.FaceSimulator(rig, device="cpu", tolerance=tolerance, solver_options=solver_options,
                           iterations=iterations, method=method)
    solver = sim.solver
    solver.step_bound = step_bound
    stream = control_stream(np.random.default_rng(seed), len(sim.muscle_names), sim.fps)
    rows = {"cpu_s": [], "wall_s": [], "iterations": [], "factorizations": [], "line_search_trials": []}
    fdp = []
    for _ in range(frames):
        a, u, v, dR = next(stream)
        sim.set_activations(a)
        sim.set_head_pose(dR @ sim.head_pose[0], np.zeros(3))
        f0, l0 = solver.factorizations, solver.line_search_trials
        c0, w0 = time.process_time(), time.perf_counter()
        sim.set_jaw(u, v)
        sim.step()
        rows["cpu_s"].append(time.process_time() - c0)
        rows["wall_s"].append(time.perf_counter() - w0)
        rows["iterations"].append(int(solver.last_iterations))
        rows["factorizations"].append(int(solver.factorizations - f0))
        rows["line_search_trials"].append(int(solver.line_search_trials - l0))
        fdp.append(sim.fdp_points())
    st = sim.stats.as_dict()
    out = {
        "frames": frames,
        "frames_per_second_cpu": frames / sum(rows["cpu_s"]),
        "frames_per_second_wall": frames / sum(rows["wall_s"]),
        "per_frame_mean": {k: float(np.mean(v)) for k, v in rows.items()},
        "per_frame_max": {k: float(np.max(v)) for k, v in rows.items()},
        "timings_s": {k: float(v) for k, v in solver.timings.items()},
        "substepped_frames": st["substepped_frames"], "retries": st["retries"],
        "min_volume_ratio": st["min_volume_ratio"],
    }
    return out, np.asarray(fdp), sim.positions()


def _mode(spec: str) -> dict:
    """The :func:`play` keywords of a ``--modes`` entry."""
    name, _, arg = spec.partition(":")
    if name == "interactive" and arg.isdigit() and int(arg) >= 1:
        return {"iterations": int(arg)}
    if name == "newton" and not arg:
        return {"method": "newton"}
    if name == "newton":
        return {"method": "newton", "tolerance": float(arg), "solver_options": {"spring_updates": 2}}
    raise ValueError(spec)


def main(argv=None) -> dict:
    import facewarp as fw

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--accuracy-frames", type=int, default=10, help="frames played fully converged too (0: none)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--name", default="switching_cpu")
    ap.add_argument("--modes", default="", help="other solver settings to compare (module doc), comma-separated")
    args = ap.parse_args(argv)
    if args.frames < 1 or not 0 <= args.accuracy_frames <= args.frames:
        ap.error("--frames must be >= 1 and --accuracy-frames in [0, --frames]")
    modes = {}  # --modes entry -> its play() keywords, parsed once
    for m in (m for m in args.modes.split(",") if m):
        try:
            modes[m] = _mode(m)
        except ValueError:
            ap.error(f"--modes: unknown mode {m!r} (interactive:K, newton or newton:TOL)")
    rig = fw.build_face(fw.default_template(0))
    result = {"seed": args.seed, "head": "default_level0", "nodes": int(len(rig.nodes)), "tets": int(len(rig.tets))}
    on, fdp_on, X_on = play(rig, args.frames, args.seed, step_bound=True)
    print("step bound on ", {k: round(v, 2) for k, v in on["per_frame_mean"].items()},
          f"{on['frames_per_second_cpu']:.2f} frames/s (CPU time)", flush=True)
    off, _, X_off = play(rig, args.frames, args.seed, step_bound=False)
    print("step bound off", {k: round(v, 2) for k, v in off["per_frame_mean"].items()},
          f"{off['frames_per_second_cpu']:.2f} frames/s (CPU time)", flush=True)
    result["default"] = on
    result["without_step_bound"] = off
    result["positions_max_difference_m"] = float(np.abs(X_on - X_off).max())
    if args.accuracy_frames:
        conv, fdp_conv, _ = play(rig, args.accuracy_frames, args.seed, tolerance=1e-7,
                                 solver_options={"max_iterations": 500, "spring_tolerance": 1e-4})

        def distance(fdp):  # per frame, the largest FDP distance [m] to the converged frame
            return np.linalg.norm(fdp[:args.accuracy_frames] - fdp_conv, axis=2).max(axis=1)

        d = distance(fdp_on)
        result["accuracy"] = {
            "frames": args.accuracy_frames,
            "fdp_distance_to_converged_max_mm": float(1e3 * d.max()),
            "fdp_distance_to_converged_median_mm": float(1e3 * np.median(d)),
            "fdp_distance_to_converged_per_frame_mm": [round(float(1e3 * x), 4) for x in d],
            "frames_within_0_5_mm": int((d <= 5e-4).sum()),
            "converged_run": {k: conv[k] for k in ("frames_per_second_cpu", "per_frame_mean", "retries")},
        }
        print("accuracy", {k: v for k, v in result["accuracy"].items() if "per_frame" not in k}, flush=True)
    result["modes"] = {}
    for m, settings in modes.items():
        row, fdp_m, _ = play(rig, args.frames, args.seed, **settings)
        row["settings"] = settings
        if args.accuracy_frames:
            dm = distance(fdp_m)
            row["fdp_distance_to_converged_mm"] = {"max": float(1e3 * dm.max()), "median": float(1e3 * np.median(dm)),
                                                   "mean": float(1e3 * dm.mean())}
        result["modes"][m] = row
        print(m, f"{row['frames_per_second_cpu']:.2f} frames/s (CPU time)", row.get("fdp_distance_to_converged_mm"),
              flush=True)
    print("wrote", save(args.name, result, device="cpu", benchmark="switching"))
    return result


if __name__ == "__main__":
    main()
