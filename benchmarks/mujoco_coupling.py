"""The MuJoCo jaw against the kinematic jaw: 10 s of the Fig. 6.16 sequence on the default head.

For each jaw (kinematic: Eq. 6.4.9 angles imposed; mujoco: the head.xml mandible, two-way coupled
once per frame) the sequence runs for ``--seconds`` with the default solver; reported: frames/s,
the coupling's overhead per frame, NaN / inverted tets (a SimulationError stops a run), the
largest jaw angle and the chin's largest drop. Results: benchmarks/results/mujoco_coupling_<device>.json.

    python -m benchmarks.mujoco_coupling [--device cpu|cuda] [--seconds 10] [--level 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import facewarp as fw
from benchmarks._common import add_case_args, save


def run(jaw: str, rig, head, *, seconds: float, device: str) -> dict:
    import mujoco

    sim = fw.FaceSimulator(rig, device=device)
    timeline = fw.thesis_sequence(each=max(seconds / 5 + 0.3, 0.8))
    driver = None
    if jaw == "mujoco":
        model = mujoco.MjModel.from_xml_string(fw.head_mjcf(head))
        data = mujoco.MjData(model)
        coupler = fw.MujocoJaw(sim, model, data)

        class Driver:
            def step(self, e):
                data.ctrl[0], data.ctrl[1] = e.jaw_u, e.jaw_v
                coupler.step()

        driver = Driver()
    chin0 = sim.fdp("2.1")
    drops, angles = [], []
    sim.advance(1)  # warm-up: kernels compiled, graph captured
    sim.reset()
    failure = None
    t0 = time.perf_counter()
    try:
        frames = sim.run(timeline, seconds, jaw=driver,
                         progress=lambda k, n: (drops.append(chin0[1] - sim.fdp("2.1")[1]),
                                                angles.append(float(sim.jaw_angles[0]))))
        finite = bool(np.isfinite(frames.points).all())
    except fw.SimulationError as e:
        failure, finite = str(e), False
    wall = time.perf_counter() - t0
    n = int(round(seconds * sim.fps))
    return {"jaw": jaw, "frames": n, "wall_s": wall, "frames_per_second": n / wall, "finite": finite,
            "failure": failure, "max_jaw_rad": max(angles, default=0.0), "max_chin_drop_m": max(drops, default=0.0)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_case_args(ap, device="cpu", level=0)
    ap.add_argument("--seconds", type=float, default=10.0)
    a = ap.parse_args(argv)
    head = fw.default_template(a.level)
    rig = fw.build_face(head)
    runs = {jaw: run(jaw, rig, head, seconds=a.seconds, device=a.device) for jaw in ("kinematic", "mujoco")}
    k, m = runs["kinematic"], runs["mujoco"]
    overhead = (m["wall_s"] - k["wall_s"]) / max(m["frames"], 1)
    result = {"level": a.level, "seconds": a.seconds, "runs": runs,
              "coupling_overhead_s_per_frame": overhead,
              "coupling_overhead_fraction": m["wall_s"] / max(k["wall_s"], 1e-9) - 1.0}
    path = save(f"mujoco_coupling_{a.device.split(':')[0]}", result, device=a.device)
    for r in runs.values():
        print(f"{r['jaw']:>9}: {r['frames']} frames, {r['frames_per_second']:.1f} frames/s, finite {r['finite']}, "
              f"max jaw {r['max_jaw_rad']:.3f} rad, chin drop {1e3 * r['max_chin_drop_m']:.1f} mm"
              + (f", FAILED: {r['failure']}" if r["failure"] else ""))
    print(f"coupling overhead {1e3 * overhead:.2f} ms/frame ({100 * result['coupling_overhead_fraction']:.0f} %); wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
