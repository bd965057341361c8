"""Frames per second of the face solvers per template level and device, and CPU/CUDA parity.

    python -m benchmarks.physics_steps [--levels 0 1] [--device cpu|cuda] [--seconds 2]
                                       [--expression laugh] [--verlet-frames 3] [--parity]

Builds the default head at each level and plays ``expression`` (default laugh: muscles and a
30 degree jaw) for ``seconds`` at 30 fps through :class:`facewarp.FaceSimulator`:

* ``implicit`` (the default solver; physical material; on CUDA the device method, every frame one
  replayed CUDA graph): frames per second of the stepping, real-time factor, iterations and
  factorisations, and where the time goes (stage preparation, gradients, solves, factorisations);
* ``interactive_1`` / ``interactive_2``: the same with a fixed 1 or 2 iterations per frame;
* ``verlet``: the explicit reference (thesis and physical profiles) over ``--verlet-frames``
  frames: substeps per frame and per second, real-time factor.

A first frame (kernel compilation, graph capture, first factorisation) is run and discarded.
With ``--parity`` (needs CUDA) the laugh ramp is run with the device method on "cpu" and "cuda:0"
and the node positions compared, relative to the largest displacement.
Writes benchmarks/results/physics_steps_<device>.json.
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks._common import machine, save


def _frames(fr, device, expression, seconds, **kw) -> dict:
    import facewarp

    tl = facewarp.timeline_from_spec(expression, seconds)
    sim = facewarp.FaceSimulator(fr, device=device, **kw)
    sim.step()  # warm-up: kernels, graphs, the first factorisation
    sim.reset()
    solver = sim.solver
    if hasattr(solver, "timings"):
        solver.timings = {k: 0.0 for k in solver.timings}
        f0 = solver.factorizations
    frames = sim.run(tl, seconds)
    nf = len(frames.times) - 1
    out = {"solver": sim.solver_name, "material": sim.material.name, "steps_per_frame": sim.substeps,
           "dt_s": sim.dt, "frames": nf, "frames_per_second": round(frames.frames_per_second, 3),
           "realtime_factor": round(frames.realtime_factor, 4), "ms_per_frame": round(1e3 / frames.frames_per_second, 2)}
    if hasattr(solver, "timings"):
        out["method"] = solver.method
        out["factorizations"] = solver.factorizations - f0
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


def time_level(level: int, device: str, expression: str, seconds: float, verlet_frames: int) -> dict:
    import facewarp

    fr = facewarp.build_face(facewarp.default_template(level))
    row = {"level": level, "nodes": int(len(fr.nodes)), "tets": int(len(fr.tets))}
    row["implicit"] = _frames(fr, device, expression, seconds)
    print(row, flush=True)
    row["interactive_1"] = _frames(fr, device, expression, seconds, iterations=1)
    row["interactive_2"] = _frames(fr, device, expression, seconds, iterations=2)
    row["implicit_thesis"] = _frames(fr, device, expression, seconds, material="thesis")
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


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--levels", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--expression", default="laugh")
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--verlet-frames", type=int, default=2)
    ap.add_argument("--parity", action="store_true")
    args = ap.parse_args()
    from facewarp import SimulationError
    from facewarp.physics import factorization_backend

    rows = []
    for lv in args.levels:
        try:
            r = time_level(lv, args.device, args.expression, args.seconds,
                           args.verlet_frames if lv < 2 or args.device != "cpu" else 0)
        except SimulationError as e:
            r = {"level": lv, "error": str(e)}
        rows.append(r)
    result = {"machine": machine(args.device), "expression": args.expression, "seconds": args.seconds,
              "factorization_backend": factorization_backend(), "levels": rows}
    if args.parity:
        result["parity_cpu_cuda"] = parity()
        print(result["parity_cpu_cuda"])
    name = "physics_steps_" + args.device.split(":")[0]
    print("wrote", save(name, result))


if __name__ == "__main__":
    main()
