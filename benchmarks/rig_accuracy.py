"""How far the physics-baked linear rig (`facewarp rig`) is from the full simulation.

The default head (``--level``): every muscle baked alone (and with ``--inbetweens`` at fractions),
the jaw as a joint with its corrective. Test cases, each a converged static shape of the full
simulation (`fw.blendshapes.static_surface`) against the linear rig (`BlendshapeRig.evaluate`, with and
without in-betweens): the Fig. 6.16 sequence's five expressions at their peak (jaw included) and
``--blends`` random blends of 3-5 muscles (activations 0.2-1, half of them with a jaw opening up
to 0.25 rad; seed 0). Reported per-vertex error [mm] p50 / p95 / max over the vertices the
simulation moves by more than 0.5 mm (and over all skin vertices), per case and pooled; the rig
written as glTF and USD, checked by the Khronos validator (where ``node`` has the npm package
``gltf-validator``) and `usd_export.validate_usd`; and a picture of where the worst case differs.
Results: benchmarks/results/rig_accuracy.json, rig_accuracy.png.

    python -m benchmarks.rig_accuracy [--level 0] [--inbetweens 1] [--blends 10] [--device cpu]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import facewarp as fw
from benchmarks._common import RESULTS, machine, save

MOVING = 0.5e-3  # vertices the simulation moves by more than this [m] count as "moving"


def _stats(err_m: np.ndarray) -> dict:
    e = 1e3 * np.asarray(err_m)
    if not e.size:
        return {"p50_mm": 0.0, "p95_mm": 0.0, "max_mm": 0.0, "count": 0}
    return {"p50_mm": float(np.percentile(e, 50)), "p95_mm": float(np.percentile(e, 95)), "max_mm": float(e.max()),
            "count": int(e.size)}


def cases(fr, rig, blends: int, seed: int = 0) -> list:
    """(label, {muscle: activation}, jaw [rad]) test cases."""
    sim = fw.FaceSimulator(fr)
    timeline = fw.thesis_sequence(each=0.8).for_head(fr)
    out = []
    for s in timeline.segments:
        e = s.expression
        a = sim.activation_vector(e)
        acts = {m: float(v) for m, v in zip(sim.muscle_names, a) if v and m in rig.shapes}
        out.append((e.name, acts, float(e.jaw_u)))
    rng = np.random.default_rng(seed)
    names = rig.muscle_names
    for b in range(blends):
        k = int(rng.integers(3, 6))
        picked = rng.choice(len(names), size=k, replace=False)
        acts = {names[i]: float(rng.uniform(0.2, 1.0)) for i in picked}
        jaw = float(rng.uniform(0.0, 0.25)) if b % 2 else 0.0
        out.append((f"blend{b}", acts, jaw))
    return out


def _validate_gltf(path: Path) -> dict | None:
    node = shutil.which("node")
    if not node:
        return None
    script = Path(__file__).with_name("gltf_validate.js")
    run = subprocess.run([node, str(script), str(path)], capture_output=True, text=True, timeout=300)
    if run.returncode != 0:
        return {"error": run.stderr.strip().splitlines()[-1] if run.stderr.strip() else "failed"}
    rep = json.loads(run.stdout)
    return {k: rep[k] for k in ("validatorVersion", "numErrors", "numWarnings", "numInfos", "numHints", "codes")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--level", type=int, default=0)
    ap.add_argument("--inbetweens", type=int, default=1)
    ap.add_argument("--blends", type=int, default=10)
    ap.add_argument("--device", default="cpu")
    a = ap.parse_args(argv)
    head = fw.default_template(a.level)
    fr = fw.build_face(head)
    t0 = time.perf_counter()
    rig = fw.blendshapes.bake_blendshapes(fr, inbetweens=a.inbetweens, device=a.device)
    bake_s = time.perf_counter() - t0
    sim = fw.FaceSimulator(fr, device=a.device)
    per_case, pooled = [], {"with_inbetweens": {"moving": [], "all": []}, "linear": {"moving": [], "all": []}}
    worst = (-1.0, None)
    for label, acts, jaw in cases(fr, rig, a.blends):
        full, frames = fw.blendshapes.static_surface(sim, acts, jaw)
        moving = np.linalg.norm(full - rig.rest, axis=1) > MOVING
        row = {"case": label, "activations": acts, "jaw_rad": jaw, "frames": frames,
               "moving_vertices": int(moving.sum()),
               "largest_motion_mm": float(1e3 * np.linalg.norm(full - rig.rest, axis=1).max())}
        for key, ib in (("with_inbetweens", True), ("linear", False)):
            err = np.linalg.norm(rig.evaluate(acts, jaw, inbetweens=ib) - full, axis=1)
            row[key] = {"moving": _stats(err[moving]), "all": _stats(err)}
            pooled[key]["moving"].append(err[moving])
            pooled[key]["all"].append(err)
            if ib and err.max() > worst[0]:
                worst = (float(err.max()), (label, full, err))
        per_case.append(row)
        print(f"{label:>9}: {row['moving_vertices']} moving vertices, motion up to {row['largest_motion_mm']:.1f} mm; "
              f"error p50/p95/max {row['with_inbetweens']['moving']['p50_mm']:.2f} / "
              f"{row['with_inbetweens']['moving']['p95_mm']:.2f} / {row['with_inbetweens']['moving']['max_mm']:.2f} mm "
              f"(no in-betweens: max {row['linear']['moving']['max_mm']:.2f} mm)")
    summary = {key: {part: _stats(np.concatenate(v)) for part, v in d.items()} for key, d in pooled.items()}
    with tempfile.TemporaryDirectory() as tmp:
        build = Path(tmp) / "build"
        from facewarp.cli import main as cli

        cli(["--json", "build", f"default:{a.level}", "--out", str(build)])
        checks = {}
        for ext in ("glb", "usdc"):
            out = Path(tmp) / f"rig.{ext}"
            cli(["--json", "rig", str(build), "--out", str(out), "--inbetweens", str(a.inbetweens)])
            checks[ext] = {"bytes": out.stat().st_size}
            if ext == "glb":
                checks[ext]["gltf_validator"] = _validate_gltf(out)
            else:
                import usd_export

                checks[ext]["validate_usd"] = usd_export.validate_usd(out)
    label, full, err = worst[1]
    img = fw.render_mesh(full, fr.head_faces, vertex_colors=fw.render.colormap(1e3 * err, 0.0, max(1.0, 1e3 * err.max())),
                         width=420, height=420, view="front")
    RESULTS.mkdir(parents=True, exist_ok=True)
    fw.save_png(RESULTS / "rig_accuracy.png", img,
                title=f"linear rig vs simulation, {label}: error 0 (blue) to {1e3 * err.max():.1f} mm (red)")
    info = machine(a.device)
    result = {"machine": info, "level": a.level, "inbetweens": a.inbetweens, "targets": len(rig.names),
              "bake_seconds": bake_s, "moving_threshold_mm": 1e3 * MOVING, "summary": summary, "cases": per_case,
              "files": checks, "node": shutil.which("node") is not None, "node_path": os.environ.get("NODE_PATH")}
    path = save("rig_accuracy", result)
    for key, d in summary.items():
        s = d["moving"]
        print(f"{key}: moving vertices p50 / p95 / max {s['p50_mm']:.2f} / {s['p95_mm']:.2f} / {s['max_mm']:.2f} mm")
    print(f"files: {json.dumps(checks)}; wrote {path}, {RESULTS / 'rig_accuracy.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
