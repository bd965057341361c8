"""Where level 0 and level 1 disagree: maps of the static expression on the default head.

    python -m benchmarks.level_maps [--presets angry sad] [--shear-modulus 3e4] [--size 360]

For each preset, with the default physical material and with the shear term in place of the
distance and area energies (``benchmarks/solver_accuracy.py --shear-modulus``), the static shape
(ramped in over 0.3 s, held 0.5 s; CPU L-BFGS, tolerance 1e-6 m) at levels 0 and 1. Each row of the
picture: the skin's displacement from rest at level 0 and at level 1 (each on its own mesh, one
colour scale), and the difference ``|d1 - d0|`` on the level-0 head, with level 1's displacement
taken at the closest point of its surface, drawn 4x (its colour scale is a quarter of the
displacement's: the bar's 14 mm is 3.5 mm there). The numbers beside: the median and 95th percentile of
the difference over the level-0 skin vertices moving more than 1 mm.

Writes benchmarks/results/levels/<preset>_levels.png and benchmarks/results/level_maps.json.
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks._common import RESULTS, add_case_args, case_face, material_label, save, shear_material, static_shape


def _head_displacement(fr, preset, material):
    """Rest head vertices (n, 3) and their displacement at the static shape (n, 3) [m]."""
    _, _, sim = static_shape(fr, preset, material, "cpu", tolerance=1e-6)
    rest = sim.surface(fr.nodes, jaw_angles=(0.0, 0.0))
    return rest, sim.surface() - rest


def main(argv=None):
    from facewarp.geometry import closest_surface_points
    from facewarp.render import colormap
    from facewarp import render_mesh, save_png

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_case_args(ap, presets=["angry", "sad"])
    ap.add_argument("--shear-modulus", type=float, default=3e4)
    ap.add_argument("--size", type=int, default=360)
    args = ap.parse_args(argv)

    rigs = {0: case_face("default", 0), 1: case_face("default", 1)}
    out = RESULTS / "levels"
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for preset in args.presets:
        maps = []
        for material in ("physical", shear_material(args.shear_modulus)):
            (r0, d0), (r1, d1) = (_head_displacement(rigs[lv], preset, material) for lv in (0, 1))
            F0, F1 = rigs[0].head_faces, rigs[1].head_faces
            sp = closest_surface_points(r1, F1, r0)
            d1_on_0 = np.einsum("kj,kjc->kc", sp.bary, d1[F1[sp.face]])
            diff = np.linalg.norm(d1_on_0 - d0, axis=1) * 1e3
            n0, n1 = np.linalg.norm(d0, axis=1) * 1e3, np.linalg.norm(d1, axis=1) * 1e3
            moving = n0 > 1.0
            row = {"preset": preset, "material": material_label(material),
                   "max_displacement_mm": [round(float(n0.max()), 2), round(float(n1.max()), 2)],
                   "difference_median_mm": round(float(np.median(diff[moving])), 3),
                   "difference_p95_mm": round(float(np.quantile(diff[moving], 0.95)), 3),
                   "difference_relative_median": round(float(np.median(diff[moving] / n0[moving])), 4)}
            print(row, flush=True)
            rows.append(row)
            maps.append((r0, F0, n0, r1, F1, n1, diff))
        vmax = float(np.ceil(max(max(m[2].max(), m[5].max()) for m in maps)))
        s = args.size
        images = []
        for r0, F0, n0, r1, F1, n1, diff in maps:
            panels = [render_mesh(r0, F0, view="front", width=s, height=s, vertex_colors=colormap(n0, 0.0, vmax)),
                      render_mesh(r1, F1, view="front", width=s, height=s, vertex_colors=colormap(n1, 0.0, vmax)),
                      render_mesh(r0, F0, view="front", width=s, height=s,
                                  vertex_colors=colormap(diff, 0.0, 0.25 * vmax))]
            images.append(np.concatenate(panels, axis=1))
        path = save_png(out / f"{preset}_levels.png", np.concatenate(images, axis=0),
                        title=f"{preset}: L0 | L1 | |L1 - L0| x4; top thesis energies, bottom shear term",
                        colorbar=(0.0, vmax, "mm"))
        print("wrote", path)
    print("wrote", save("level_maps", {"rows": rows}))


if __name__ == "__main__":
    raise SystemExit(main())
