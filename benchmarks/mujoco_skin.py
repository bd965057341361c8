"""What showing the simulated face inside MuJoCo costs per frame (fw.MujocoSkin).

The default head's head.xml with its skin mesh, the jaw coupled (fw.MujocoJaw), a smile and jaw
openings from the Fig. 6.16 sequence; each frame the skin is written into the MjModel and uploaded
to an offscreen ``mujoco.Renderer`` (``mjr_uploadMesh``), then a frame is rendered. Reported per
frame (min, p10, median and p95 over the frames after the first: on a shared machine the
median carries other processes' load): the face's vertices from the simulator,
the transform and normals into the model, the upload, and for scale the render and the physics
frame. The GL backend is MUJOCO_GL (egl by default here; osmesa on a CPU box without EGL).
Results: benchmarks/results/mujoco_skin_<device>_<MUJOCO_GL>.json.

    MUJOCO_GL=egl python -m benchmarks.mujoco_skin [--device cpu] [--frames 60] [--levels 0 1] [--size 480]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

import facewarp as fw  # noqa: E402
from benchmarks._common import machine, save  # noqa: E402


def run(level: int, *, frames: int, size: int, device: str) -> dict:
    import mujoco

    head = fw.default_template(level)
    rig = fw.build_face(head)
    with tempfile.TemporaryDirectory() as tmp:  # head.xml and the scene.xml that includes it
        fw.coupling.write_head_mjcf(Path(tmp) / "head.xml", head, jaw=rig.jaw, skin=(rig.head_vertices, rig.head_faces),
                           prefix="h_")
        model = mujoco.MjModel.from_xml_path(str(Path(tmp) / "scene.xml"))
    data = mujoco.MjData(model)
    sim = fw.FaceSimulator(rig, device=device)
    jaw = fw.MujocoJaw(sim, model, data)
    skin = fw.MujocoSkin(sim, model)
    renderer = mujoco.Renderer(model, size, size)
    timeline = fw.thesis_sequence(each=0.8).for_head(rig)
    parts = {"surface": [], "model": [], "upload": [], "render": [], "physics": []}
    for k in range(frames):
        e = timeline.sample(k / sim.fps)
        sim.set_activations(e)
        data.ctrl[model.actuator("h_jaw_open").id] = e.jaw_u
        t0 = time.perf_counter()
        jaw.step()
        t1 = time.perf_counter()
        before = dict(skin.update_seconds)
        skin.update(renderer)
        t2 = time.perf_counter()
        renderer.update_scene(data, camera="face")
        renderer.render()
        t3 = time.perf_counter()
        for key in ("surface", "model", "upload"):
            parts[key].append(skin.update_seconds[key] - before[key])
        parts["physics"].append(t1 - t0)
        parts["render"].append(t3 - t2)
    parts["skin_update_total"] = [a + b + c for a, b, c in zip(parts["surface"], parts["model"], parts["upload"])]
    # min and p10 too: on a shared machine the median and p95 carry other processes' load
    stats = {key: {"min_ms": 1e3 * float(np.min(v[1:])), "p10_ms": 1e3 * float(np.percentile(v[1:], 10)),
                   "median_ms": 1e3 * float(np.median(v[1:])), "p95_ms": 1e3 * float(np.percentile(v[1:], 95))}
             for key, v in parts.items()}
    return {"level": level, "skin_vertices": int(len(rig.head_vertices)), "skin_triangles": int(len(rig.head_faces)),
            "frames": frames, "size_px": size, "per_frame": stats}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--levels", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--size", type=int, default=480)
    a = ap.parse_args(argv)
    import mujoco

    runs = [run(level, frames=a.frames, size=a.size, device=a.device) for level in a.levels]
    info = machine(a.device)
    info.update({"mujoco": mujoco.__version__, "mujoco_gl": os.environ.get("MUJOCO_GL")})
    path = save(f"mujoco_skin_{a.device.split(':')[0]}_{os.environ['MUJOCO_GL']}", {"machine": info, "runs": runs})
    for r in runs:
        s = r["per_frame"]
        print(f"level {r['level']} ({r['skin_vertices']} skin vertices): skin update "
              f"{s['skin_update_total']['p10_ms']:.2f} / {s['skin_update_total']['median_ms']:.2f} ms/frame p10 / median "
              f"(surface {s['surface']['p10_ms']:.2f}, model {s['model']['p10_ms']:.2f}, upload "
              f"{s['upload']['p10_ms']:.2f} p10); render {s['render']['median_ms']:.1f} ms, physics "
              f"{s['physics']['median_ms']:.1f} ms median")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
