"""Anatomy on personalized heads: the default template adapted to ICT-FaceKit identities, then built.

    python -m benchmarks.adapted_heads [--identities 0 1 ... 9] [--keep DIR]

For each identity: a scan-like target (new tessellation, noise, holes, random pose, mm; see
benchmarks/adapt_ict.py), `facewarp adapt` with the default template, `facewarp build` on the
adapted head (Sec. 6.6: regions, surface points and definitions reused, tets re-extruded), and the
anatomy quality: inverted tets (must be 0), conformity, smallest attachment count, and the solver's
substep with and without selective mass scaling (facewarp.physics.scale_masses) and the mass it adds. ``--keep`` keeps
the adapt/build folders (e.g. to simulate one of them). Writes benchmarks/results/adapted_heads.json.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from benchmarks._common import save
from benchmarks._ict import adapted_identity, ict_dir


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--identities", type=int, nargs="+", default=list(range(10)))
    ap.add_argument("--keep", type=Path)
    args = ap.parse_args(argv)
    d = ict_dir()
    if not (d / "generic_neutral_mesh.obj").is_file():
        print(f"ICT-FaceKit data not found at {d}: nothing to measure")
        return
    from facewarp.physics import ModelBuilder
    from facewarp import load_face_rig
    from facewarp.physics import node_stable_dt, scale_masses

    rows = []
    root = args.keep or Path(tempfile.mkdtemp(prefix="facewarp_heads_"))
    for k in args.identities:
        made = adapted_identity(k, root, fresh=True)
        case, rep = made["dir"], made["report"]
        q = json.loads((case / "build" / "anatomy.json").read_text())
        fr = load_face_rig(case / "build")
        b = ModelBuilder(fr.nodes, fr.tets, layer=fr.layer, fixed=fr.fixed, held=fr.held)
        dt_min = float(node_stable_dt(b)[~b.fixed].min())
        dt, added = scale_masses(b)
        row = {"identity": k, "adapt_seconds": made["adapt_seconds"], "build_seconds": made["build_seconds"],
               "distance_to_scan_median_mm": rep["distance_to_scan_m"]["median"] * 1e3,
               "tets": q["tet_count"], "inverted": q["inverted_count"], "conforming": q["conforming"],
               "min_dihedral_deg": q["min_dihedral_deg"], "min_attached_nodes": q["min_attached_nodes"],
               "boundary_intersections": q.get("boundary_intersection_count"),
               "substep_s": dt, "substep_without_mass_scaling_s": dt_min, "added_mass_fraction": added}
        print(row, flush=True)
        rows.append(row)
    ok = all(r["inverted"] == 0 and r["conforming"] for r in rows)
    print("all heads: 0 inverted and conforming" if ok else "some heads failed")
    print("wrote", save("adapted_heads", {"heads": rows, "all_ok": ok, "folders": str(root)}))


if __name__ == "__main__":
    raise SystemExit(main())
