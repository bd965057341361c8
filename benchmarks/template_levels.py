"""Default template: build time and size per level, manifoldness, and human-likeness vs ICT.

    python -m benchmarks.template_levels [--levels 0 1 2 3]

Writes benchmarks/results/template_levels.json.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks._common import add_case_args, save, shared_dir


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    add_case_args(ap, levels=[0, 1, 2, 3])
    args = ap.parse_args(argv)
    from facewarp import default_template
    from facewarp.geometry import mesh_report

    rows = []
    for lv in args.levels:
        t0 = time.perf_counter()
        t = default_template(lv)  # the first call per level builds it (later calls hit its cache)
        dt = time.perf_counter() - t0
        rep = mesh_report(t.vertices, t.faces)
        rows.append({"level": lv, "vertices": t.vertex_count, "faces": t.face_count,
                     "frontal_faces": int(t.frontal.sum()), "seconds": round(dt, 3),
                     "non_manifold_edges": rep["non_manifold_edge_count"],
                     "boundary_loops": rep["boundary_loop_count"],
                     "consistently_oriented": rep["consistently_oriented"]})
        print(rows[-1])
    result = {"levels": rows}
    ict = shared_dir() / "data" / "ict-facekit"
    if (ict / "generic_neutral_mesh.obj").is_file():
        from facewarp.heads import human_likeness

        r = human_likeness(default_template(0), ict)
        d = r.pop("distances_m")
        r["within_6mm_target"] = r["rms_m"] <= 6e-3
        r["histogram_mm"] = np.histogram(d * 1e3, bins=[0, 1, 2, 4, 6, 10, 20, 100])[0].tolist()
        result["human_likeness_level0"] = r
        print(f"human likeness (ICT face vertices 0-9408 to template surface): RMS {r['rms_m'] * 1e3:.2f} mm, "
              f"median {r['median_m'] * 1e3:.2f} mm")
    else:
        print(f"ICT-FaceKit data not found at {ict}: human-likeness skipped")
    print("wrote", save("template_levels", result))


if __name__ == "__main__":
    raise SystemExit(main())
