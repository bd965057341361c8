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
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

from benchmarks._common import save
from benchmarks._ict import ICT_FDP, ict_dir, load_ict, make_scan


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--identities", type=int, nargs="+", default=list(range(10)))
    ap.add_argument("--keep", type=Path)
    args = ap.parse_args(argv)
    d = ict_dir()
    if not (d / "generic_neutral_mesh.obj").is_file():
        print(f"ICT-FaceKit data not found at {d}: nothing to measure")
        return
    from facewarp import ModelBuilder, load_face_rig, load_mesh, save_obj
    from facewarp.cli import main as facewarp_cli
    from facewarp.physics import node_stable_dt, scale_masses

    def cli(*argv):  # `facewarp ...`; the results are the files it writes
        with contextlib.redirect_stdout(io.StringIO()):
            code = facewarp_cli([str(a) for a in argv])
        if code != 0:
            raise SystemExit(f"facewarp {' '.join(map(str, argv))} failed with exit code {code}")

    _, F, _ = load_ict(d)
    rows = []
    root = args.keep or Path(tempfile.mkdtemp(prefix="facewarp_heads_"))
    for k in args.identities:
        V = load_mesh(d / f"identity{k:03d}.obj", units="cm").vertices[:11248]
        SV, SF, pose = make_scan(V, F, seed=100 + k)
        case = root / f"identity{k:03d}"
        case.mkdir(parents=True, exist_ok=True)
        save_obj(case / "scan.obj", SV, SF)
        lm = {fid: (1000.0 * V[i] @ pose[0].T + pose[1]).tolist() for fid, i in ICT_FDP.items()}
        (case / "scan_landmarks.json").write_text(json.dumps(lm))
        t0 = time.perf_counter()
        cli("adapt", case / "scan.obj", "--landmarks", case / "scan_landmarks.json", "--out", case / "adapt",
            "--units", "mm")
        rep = json.loads((case / "adapt" / "report.json").read_text())
        t1 = time.perf_counter()
        cli("build", case / "adapt", "--out", case / "build")
        q = json.loads((case / "build" / "anatomy.json").read_text())
        t2 = time.perf_counter()
        fr = load_face_rig(case / "build")
        b = ModelBuilder(fr.nodes, fr.tets, layer=fr.layer, fixed=fr.fixed, held=fr.held)
        dt_min = float(node_stable_dt(b)[~b.fixed].min())
        dt, added = scale_masses(b)
        row = {"identity": k, "adapt_seconds": t1 - t0, "build_seconds": t2 - t1,
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
