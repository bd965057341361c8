"""The ARKit rig against the simulator: one bake of the ARKit-named and the muscle shapes, and how far its linear blend lands from the simulated face.

For a build folder and its ARKit table (``fw.arkit_table``, cached in the build; built here when
missing: minutes), the rig is baked once with ``shapes="both"`` (``fw.blendshapes.bake_blendshapes``: the
shapes the table solved, every muscle, the jaw corrective), timed. Then random sparse blends (a
generator of our own, ``--seed``): each picks 1..``--max-active`` of the baked ARKit shapes with
weights uniform in [0.2, 1]; the simulated face is the converged static face
(``fw.blendshapes.static_surface``) of the table's blended controls (``ArkitTable.controls``: activations and
jaw blended in control space, clamped), the rig's face is its linear blend
(``BlendshapeRig.evaluate_arkit``: offsets summed in the bind pose, the jaw joint at the blended
opening). Reported: per blend the p95 and the largest vertex distance [mm] over the skin, and the
p95 over all blends' vertices; the bake's seconds (static shapes, on a shared 2-core machine the
figures carry the other processes' load).

    python -m benchmarks rig_arkit --build BUILD [--blends 24] [--seed 0]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import facewarp as fw
from benchmarks._common import save


def run(build: Path, blends: int, max_active: int, seed: int, device: str) -> dict:
    fr = fw.load_face_rig(build)
    sim = fw.FaceSimulator(fr, device=device)
    t0 = time.perf_counter()
    table = fw.arkit_table(sim, cache=build)
    table_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    rig = fw.blendshapes.bake_blendshapes(fr, shapes="both", arkit=table, device=device)
    bake_s = time.perf_counter() - t0
    names = rig.arkit_names
    rng = np.random.default_rng(seed)
    rows = []
    every = []
    for b in range(blends):
        k = int(rng.integers(1, max_active + 1))
        pick = rng.choice(len(names), size=k, replace=False)
        w = {names[i]: float(rng.uniform(0.2, 1.0)) for i in pick}
        W = np.zeros(len(fw.ARKIT_NAMES))
        for n, v in w.items():
            W[list(fw.ARKIT_NAMES).index(n)] = v
        a, j = table.controls(W)
        acts = {sim.muscle_names[m]: float(a[0, m]) for m in np.flatnonzero(a[0] > 0)}
        V_sim, frames = fw.blendshapes.static_surface(sim, acts, (float(j[0, 0]), float(j[0, 1])))
        V_rig = rig.evaluate_arkit(w)
        d = 1e3 * np.linalg.norm(V_rig - V_sim, axis=1)
        moved = 1e3 * np.linalg.norm(V_sim - rig.rest, axis=1).max()
        every.append(d)
        rows.append({"weights": {n: round(v, 3) for n, v in w.items()}, "p95_mm": float(np.percentile(d, 95)),
                     "max_mm": float(d.max()), "face_moved_max_mm": float(moved), "frames": int(frames)})
        print(f"blend {b}: {len(w)} shapes, p95 {rows[-1]['p95_mm']:.3f} mm, max {rows[-1]['max_mm']:.3f} mm "
              f"(face moved {moved:.1f} mm)", flush=True)
    alld = np.concatenate(every)
    return {"build": str(build), "vertices": int(len(rig.rest)), "arkit_baked": len(names),
            "arkit_left_out": rig.left_out, "muscles_baked": len(rig.muscle_names), "targets": len(rig.names),
            "seconds": {"arkit_table": table_s, "table_from_cache": bool(table.info.get("from_cache")),
                        "bake": bake_s, "static_shapes": rig.bake_seconds},
            "blends": rows, "p95_mm_all": float(np.percentile(alld, 95)),
            "p95_mm_per_blend_max": float(max(r["p95_mm"] for r in rows)),
            "p95_mm_per_blend_median": float(np.median([r["p95_mm"] for r in rows])),
            "max_mm": float(alld.max()), "settings": {"blends": blends, "max_active": max_active, "seed": seed}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", required=True, type=Path)
    ap.add_argument("--blends", type=int, default=24)
    ap.add_argument("--max-active", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--name", default="rig_arkit")
    a = ap.parse_args(argv)
    rep = run(a.build, a.blends, a.max_active, a.seed, a.device)
    print(f"p95 over all blends {rep['p95_mm_all']:.3f} mm (worst blend's p95 {rep['p95_mm_per_blend_max']:.3f} mm); "
          f"bake {rep['seconds']['bake']:.1f} s for {rep['targets']} shapes")
    save(a.name, rep, device=a.device)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
