"""Anatomy of the default template at levels 0-3: tet counts, quality, build time.

    python -m benchmarks.anatomy_levels [--levels 0 1 2 3]

Writes benchmarks/results/anatomy_levels.json (0 inverted tets and a conforming mesh expected).
"""

from __future__ import annotations

import argparse
import time

from benchmarks._common import add_case_args, save


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_case_args(ap, levels=[0, 1, 2, 3])
    args = ap.parse_args(argv)
    from facewarp import InputError, build_anatomy, default_template

    rows = []
    for lv in args.levels:
        t = default_template(lv)
        t0 = time.perf_counter()
        try:
            a = build_anatomy(t, check_intersections=lv <= 1)
            q = a.quality
            row = {"level": lv, "head_vertices": t.vertex_count, "nodes": q["vertex_count"], "tets": q["tet_count"],
                   "inverted": q["inverted_count"], "conforming": q["conforming"],
                   "min_dihedral_deg": q["min_dihedral_deg"], "min_volume_m3": q["min_volume_m3"],
                   "min_attached_nodes": q["min_attached_nodes"],
                   "boundary_intersections": q.get("boundary_intersection_count"),
                   "seconds": time.perf_counter() - t0}
        except InputError as e:
            row = {"level": lv, "error": str(e), "seconds": time.perf_counter() - t0}
        print(row, flush=True)
        rows.append(row)
    print("wrote", save("anatomy_levels", {"levels": rows}))


if __name__ == "__main__":
    raise SystemExit(main())
