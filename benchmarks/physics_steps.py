"""Frames per second of the face solvers per template level and device, and CPU/CUDA parity.

    python -m benchmarks.physics_steps [--levels 0 1] [--device cpu|cuda] [--seconds 2]
                                       [--expression laugh] [--verlet-frames 3] [--parity]
                                       [--modes implicit interactive_3 ...] [--tag T]

Builds the default head at each level and plays ``expression`` (default laugh: muscles and a
30 degree jaw) for ``seconds`` at 30 fps through :class:`facewarp.FaceSimulator`:

* ``implicit`` (the default solver; physical material; on CUDA the device method, every frame one
  replayed CUDA graph): frames per second of the stepping, real-time factor, iterations and
  factorisations, and where the time goes (stage preparation, gradients, solves, factorisations);
* ``interactive_1`` / ``_2`` / ``_3``: the same with a fixed 1, 2 or 3 iterations per frame (3: the
  fewest that keep every FDP within 0.5 mm of the converged steps, ``solver_accuracy.py``);
* ``verlet``: the explicit reference (thesis and physical profiles) over ``--verlet-frames``
  frames: substeps per frame and per second, real-time factor.

A first frame (kernel compilation, graph capture, first factorisation) is run and discarded.
With ``--parity`` (needs CUDA) the laugh ramp is run with the device method on "cpu" and "cuda:0"
and the node positions compared, relative to the largest displacement.
Writes benchmarks/results/physics_steps_<device>[_<tag>].json.

    python -m benchmarks.physics_steps --contact [--levels 0] [--expressions laugh pucker blink smile]
                                       [--head default|BUILD_DIR ...] [--method lbfgs|newton-pcg] [--tag T]

The cost and the effect of the contact stage (issue 12): each expression on each head with the
contact on and off (``FaceSimulator(contact=...)``): frames per second of the stepping and, every
frame, the crossings (:func:`facewarp.physics.contact_crossings`: lip nodes inside the other lip,
nodes inside the teeth, lid nodes deeper inside an eyeball than at rest, and the deepest of each).
Writes benchmarks/results/physics_steps_contact_<device>[_<heads>][_<tag>].json (the heads' names
when not the default head).
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks._common import add_case_args, save


def _frames(fr, device, expression, seconds, **kw) -> dict:
    import facewarp

    tl = facewarp.expressions.timeline_from_spec(expression, seconds)
    sim = facewarp.FaceSimulator(fr, device=device, **kw)
    sim.step()  # warm-up: kernels, graphs, the first factorisation
    sim.reset()
    solver = sim.solver
    if hasattr(solver, "timings"):
        solver.timings = {k: 0.0 for k in solver.timings}
        f0, i0 = solver.factorizations, solver.total_iterations
    frames = sim.run(tl, seconds)
    nf = len(frames.times) - 1
    out = {"solver": sim.solver_name, "material": sim.material.name, "steps_per_frame": sim.substeps,
           "dt_s": sim.dt, "frames": nf, "frames_per_second": round(frames.frames_per_second, 3),
           "realtime_factor": round(frames.realtime_factor, 4), "ms_per_frame": round(1e3 / frames.frames_per_second, 2)}
    if hasattr(solver, "timings"):
        out["method"] = solver.method
        out["factorizations"] = solver.factorizations - f0
        # a fixed count (the interactive mode) is not counted by a replayed CUDA graph
        out["newton_iterations_per_frame"] = kw.get("iterations") or round((solver.total_iterations - i0) / nf, 2)
        out["ms_per_frame_in"] = {k: round(v / nf * 1e3, 2) for k, v in solver.timings.items()}
    return out


def _verlet(fr, device, expression, frames, material) -> dict:
    import time

    import facewarp

    sim = facewarp.FaceSimulator(fr, device=device, solver="verlet", material=material)
    e = facewarp.preset(expression)
    sim.set_activations(e)
    sim.set_jaw(e.jaw_u * 0.5)
    sim.step()  # warm-up
    t0 = time.perf_counter()
    for _ in range(frames):
        sim.step()
    wall = time.perf_counter() - t0
    return {"solver": "verlet", "material": material, "steps_per_frame": sim.substeps, "dt_s": sim.dt,
            "frames": frames, "frames_per_second": round(frames / wall, 4),
            "steps_per_second": round(frames * sim.substeps / wall, 1),
            "realtime_factor": round(frames / sim.fps / wall, 5), "added_mass_fraction": sim.added_mass_fraction}


MODES = {"implicit": {}, "interactive_1": dict(iterations=1), "interactive_2": dict(iterations=2),
         "interactive_3": dict(iterations=3), "implicit_thesis": dict(material="thesis")}
"""The implicit solver's settings timed per level (interactive_3: the fixed count that keeps every FDP
within 0.5 mm of the converged steps, benchmarks/solver_accuracy.py)."""


def time_level(level: int, device: str, expression: str, seconds: float, verlet_frames: int,
               modes=tuple(MODES)) -> dict:
    import facewarp
    from facewarp import SimulationError

    fr = facewarp.build_face(facewarp.default_template(level))
    row = {"level": level, "nodes": int(len(fr.nodes)), "tets": int(len(fr.tets))}
    for mode in modes:
        try:
            row[mode] = _frames(fr, device, expression, seconds, **MODES[mode])
        except SimulationError as e:  # recorded, the other settings still run
            row[mode] = {"error": str(e)}
        print({"level": level, mode: row[mode]}, flush=True)
    if verlet_frames > 0:
        row["verlet_thesis"] = _verlet(fr, device, expression, verlet_frames, "thesis")
        row["verlet_physical"] = _verlet(fr, device, expression, verlet_frames, "physical")
    print(row, flush=True)
    return row


def parity(level: int = 0, frames: int = 6) -> dict:
    import facewarp

    fr = facewarp.build_face(facewarp.default_template(level))
    e = facewarp.preset("laugh")
    out = {}
    for dev in ("cpu", "cuda:0"):
        sim = facewarp.FaceSimulator(fr, device=dev, method="newton-pcg")
        for k in range(1, frames + 1):
            sim.set_activations({m: v * k / frames for m, v in e.activations.items()})
            sim.set_jaw(e.jaw_u * k / frames)
            sim.step()
        out[dev] = sim.positions()
    diff = np.linalg.norm(out["cpu"] - out["cuda:0"], axis=1).max()
    scale = np.linalg.norm(out["cpu"] - fr.nodes, axis=1).max()
    return {"level": level, "frames": frames, "method": "newton-pcg", "max_abs_difference_m": float(diff),
            "max_displacement_m": float(scale), "relative_difference": float(diff / max(scale, 1e-30)),
            "within_1e-4": bool(diff / max(scale, 1e-30) <= 1e-4)}


def contact_cost(fr, device, expression, seconds, contact, method=None) -> dict:
    """One expression with the contact on or off: stepping fps and the worst crossings of any frame."""
    import facewarp

    tl = facewarp.expressions.timeline_from_spec(expression, seconds).for_head(fr)
    sim = facewarp.FaceSimulator(fr, device=device, contact=contact, method=method)
    sim.step()  # warm-up: kernels, the first factorisation
    sim.reset()
    s0 = sim.step_seconds
    nf = int(round(seconds * sim.fps))
    worst = {}
    for k in range(1, nf + 1):
        e = tl.sample(k / sim.fps)
        sim.set_activations(e)
        sim.set_jaw(e.jaw_u, e.jaw_v)
        sim.step()
        for key, v in sim.contact_crossings().items():
            worst[key] = max(worst.get(key, 0), v)
        if not np.isfinite(sim.positions()).all():
            worst["nan_frames"] = worst.get("nan_frames", 0) + 1
    fps = nf / max(sim.step_seconds - s0, 1e-9)
    row = {"expression": expression, "contact": contact, "method": sim.solver.method, "frames": nf,
           "frames_per_second": round(fps, 2), "worst_per_frame": {k: (round(v * 1e3, 4) if k.endswith("_m") else v)
                                                                  for k, v in worst.items()}}
    row["worst_per_frame"] = {(k[:-2] + "_mm" if k.endswith("_m") else k): v for k, v in row["worst_per_frame"].items()}
    if contact:
        row["candidates"] = sim.contact.counts
    print(row, flush=True)
    return row


def main_contact(args):
    from pathlib import Path

    import facewarp
    from facewarp import SimulationError

    rows = []
    heads = args.head or ["default"]
    for head in heads:
        for lv in (args.levels if head == "default" else [None]):
            if head == "default":
                fr, name = facewarp.build_face(facewarp.default_template(lv)), f"default_L{lv}"
            elif Path(head, "face_rig.npz").is_file():
                fr, name = facewarp.load_face_rig(head), Path(head).resolve().parent.name
            else:
                fr, name = facewarp.build_face(facewarp.load_head(head)), Path(head).resolve().parent.name
            for ex in args.expressions:
                for contact in (False, True):
                    try:
                        r = contact_cost(fr, args.device, ex, args.seconds, contact, args.method)
                    except SimulationError as e:
                        r = {"expression": ex, "contact": contact, "error": str(e)}
                        print(r, flush=True)
                    rows.append({"head": name, **r})
    result = {"seconds": args.seconds, "rows": rows}
    tag = "" if heads == ["default"] else "_" + "_".join(r["head"] for r in rows[:: 2 * len(args.expressions)])
    tag += f"_{args.tag}" if args.tag else ""
    print("wrote", save("physics_steps_contact_" + args.device.split(":")[0] + tag, result, device=args.device))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_case_args(ap, levels=[0, 1], device="cpu")
    ap.add_argument("--expression", default="laugh")
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--verlet-frames", type=int, default=2)
    ap.add_argument("--parity", action="store_true")
    ap.add_argument("--contact", action="store_true", help="the contact stage's cost and crossings, on and off")
    ap.add_argument("--expressions", nargs="+", default=["laugh", "pucker", "blink", "smile"])
    ap.add_argument("--head", nargs="+", help="with --contact: heads (default, a head folder or a build folder)")
    ap.add_argument("--method", help="with --contact: the implicit method (default: the device's)")
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES),
                    help="the implicit solver's settings to time per level")
    ap.add_argument("--tag", help="a suffix of the results file's name")
    args = ap.parse_args(argv)
    if args.contact:
        return main_contact(args)
    from facewarp import SimulationError
    from facewarp.physics import factorization_backend

    rows = []
    result = {"expression": args.expression, "seconds": args.seconds,
              "factorization_backend": factorization_backend(), "levels": rows}
    name = "physics_steps_" + args.device.split(":")[0] + (f"_{args.tag}" if args.tag else "")
    for lv in args.levels:
        try:
            r = time_level(lv, args.device, args.expression, args.seconds,
                           args.verlet_frames if lv < 2 or args.device != "cpu" else 0, args.modes)
        except SimulationError as e:
            r = {"level": lv, "error": str(e)}
        rows.append(r)
        save(name, result, device=args.device)  # after every level: a long run keeps what it measured
    if args.parity:
        result["parity_cpu_cuda"] = parity()
        print(result["parity_cpu_cuda"])
    print("wrote", save(name, result, device=args.device))


if __name__ == "__main__":
    raise SystemExit(main())
