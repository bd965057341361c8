"""Simulated steps per second of the face solver per template level and device, and CPU/CUDA parity.

    python -m benchmarks.physics_steps [--levels 0 1 2] [--device cpu|cuda] [--steps 2000] [--parity]

Builds the anatomy of the default template at each level, activates the smile preset and times
substeps (after a warm-up that compiles the kernels and, on CUDA, records the graphs). With
``--parity`` (needs CUDA) it runs 1,000 identical substeps on "cpu" and "cuda:0" and reports the
relative difference of the node positions (laugh: muscles and a 30 deg jaw), relative to the
largest displacement. Writes benchmarks/results/physics_steps_<device>.json.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks._common import machine, save


def _sim(level: int, device: str, ramp: int = 20, chunk: int = 100, expression: str = "smile"):
    from facewarp import default_template
    from facewarp._src.anatomy.build import build_anatomy
    from facewarp._src.expressions import preset
    from facewarp._src.sim.face import FaceSimulator, _activation_vector, face_rig_from_anatomy

    fr = face_rig_from_anatomy(build_anatomy(default_template(level), check_intersections=False))
    sim = FaceSimulator(fr, device=device)
    e = preset(expression)
    a = _activation_vector(fr.rig.names, e)
    for k in range(1, ramp + 1):  # ramp the expression in (a step would jolt the skin)
        sim.control.activations.assign(a * (k / ramp))
        sim.control.jaw_angles.assign(np.array([e.jaw_u * k / ramp, 0.0], np.float32))
        sim.advance(chunk)
    return fr, sim


def time_level(level: int, device: str, steps: int) -> dict:
    import warp as wp

    fr, sim = _sim(level, device)
    chunk = 100
    wp.synchronize_device(sim.device)  # the ramp in _sim compiled the kernels and recorded the graph
    n = max(chunk, (steps // chunk) * chunk)
    t0 = time.perf_counter()
    for _ in range(n // chunk):
        sim.advance(chunk)
    wp.synchronize_device(sim.device)
    dt = time.perf_counter() - t0
    sim.solver.check(sim.state)
    return {"level": level, "nodes": int(len(fr.nodes)), "tets": int(len(fr.tets)), "steps": n,
            "seconds": dt, "steps_per_second": n / dt, "dt_s": sim.dt,
            "realtime_factor_at_stable_dt": n / dt * sim.dt}


def parity(level: int = 0, steps: int = 1000) -> dict:
    out = {}
    for dev in ("cpu", "cuda:0"):
        fr, sim = _sim(level, dev, ramp=10, chunk=steps // 10, expression="laugh")
        sim.solver.check(sim.state)
        out[dev] = sim.state.positions.numpy().astype(np.float64)
        rest = fr.nodes
    disp = out["cpu"] - rest
    diff = np.linalg.norm(out["cpu"] - out["cuda:0"], axis=1).max()
    scale = np.linalg.norm(disp, axis=1).max()
    return {"level": level, "steps": steps, "max_abs_difference_m": float(diff), "max_displacement_m": float(scale),
            "relative_difference": float(diff / max(scale, 1e-30)), "within_1e-4": bool(diff / max(scale, 1e-30) <= 1e-4)}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--levels", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--parity", action="store_true")
    args = ap.parse_args()
    rows = []
    from facewarp._src.core.errors import SimulationError

    for lv in args.levels:
        try:
            r = time_level(lv, args.device, args.steps if lv < 2 or args.device != "cpu" else max(200, args.steps // 10))
        except SimulationError as e:
            r = {"level": lv, "error": str(e)}
        print(r, flush=True)
        rows.append(r)
    result = {"machine": machine(args.device), "levels": rows}
    if args.parity:
        result["parity_cpu_cuda"] = parity()
        print(result["parity_cpu_cuda"])
    name = "physics_steps_" + args.device.split(":")[0]
    print("wrote", save(name, result))


if __name__ == "__main__":
    main()
