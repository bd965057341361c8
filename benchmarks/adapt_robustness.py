"""Robustness of the adaptation, after the thesis's Tables 5.4-5.7, on unseen ICT faces (issue 11).

Run: ``python -m benchmarks.adapt_robustness [--cases 2] [--sets 20] [--seed S]``

Cases: random unseen faces of ``benchmarks.adapt_unseen`` (ICT neutral template, 12 FDPs, mm).
Per case and per stage (L1: the FDP RBF; L2, L3: the thesis's refinement levels; field: the
smooth point-to-plane field; final: field + landing), E_v is measured against the adaptation of
the clean case at the same stage (the thesis's E_v: "between the adapted model and Fig. 5.4")
and against the truth, and E_d (Eq. 5.2.1) against the scan used:

- Table 5.4, large holes: a 25 mm disc removed over the left cheek and the left side of the
  nose (the thesis's Fig. 5.6 removes the right cheek and nose side);
- Table 5.5, nose FPs missing: the nose FDP (9.3) dropped from the landmarks;
- Table 5.6, misplaced FPs: every FDP moved along the surface by 2, 5 and 10 mm in a random
  direction (then put back on the scan);
- Table 5.7, noisy FPs: ``--sets`` landmark sets with Gaussian noise (sigma 1 mm per axis,
  back on the scan); the standard deviation of E_v (to the truth) and of E_d over the sets.

E_v: RMS over the face vertices 0-9408, mm (scan frame); E_d in mm^2. Results:
``benchmarks/results/adapt_robustness.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import os
import sys

from benchmarks._common import limit_threads, threads_from_argv

THREADS = 1  # timed on one core: pinned before numpy loads (the runner does it too; --threads N)

if __name__ == "__main__":
    limit_threads(threads_from_argv(sys.argv[1:], THREADS))

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks._common import RESULTS, add_case_args, load, machine_line, save  # noqa: E402
from benchmarks._ict import FACE_VERTS, ICT_FDP, ict_dir  # noqa: E402
STAGES = {
    "L1 FDP RBF": {"levels": 0, "refine": "none", "project": False},
    "L2": {"levels": 1, "refine": "none", "project": False},
    "L3": {"levels": 2, "refine": "none", "project": False},
    "field": {"levels": 2, "refine": "field"},
    "final": {"levels": 2},
}


def _run_stages(model, V_mm, F, lm_mm: dict) -> dict:
    from facewarp import adapt

    tl = {f: model.neutral[i] for f, i in ICT_FDP.items()}
    out = {}
    for name, st in STAGES.items():
        r = adapt(model.neutral, model.faces, tl, V_mm * 1e-3, F, {k: np.asarray(v) * 1e-3 for k, v in lm_mm.items()}, **st)
        out[name] = (r.vertices_scan_frame * 1e3, r.levels[-1].E_d * 1e6)
    return out


def _rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a[:FACE_VERTS] - b[:FACE_VERTS]) ** 2, axis=1))))


def _on_scan(V_mm, F, P_mm: np.ndarray) -> np.ndarray:
    from facewarp.geometry import closest_point

    return closest_point(V_mm * 1e-3, F, P_mm * 1e-3).points * 1e3


def _slide(V_mm, F, p: np.ndarray, dist_mm: float, rng) -> np.ndarray:
    """p moved about dist_mm along the scan surface in a random tangent direction."""
    from facewarp.geometry import closest_point, vertex_normals

    cp = closest_point(V_mm * 1e-3, F, p[None] * 1e-3)
    n = vertex_normals(V_mm, F)[F[cp.face[0]]].mean(axis=0)
    n /= np.linalg.norm(n)
    d = rng.normal(size=3)
    d -= (d @ n) * n
    d /= np.linalg.norm(d)
    return _on_scan(V_mm, F, (p + dist_mm * d)[None])[0]


def _cut(V_mm, F, centre_mm: np.ndarray, radius_mm: float):
    keep = np.linalg.norm(V_mm[F].mean(axis=1) - centre_mm, axis=1) > radius_mm
    F2 = F[keep]
    used = np.unique(F2)
    remap = np.full(len(V_mm), -1)
    remap[used] = np.arange(len(used))
    return V_mm[used], remap[F2]


def run_case(model, case, sets: int, rng) -> dict:
    truth = case.truth_scan_mm
    clean = _run_stages(model, case.scan_V_mm, case.scan_F, case.landmarks_mm)

    def table(runs: dict) -> dict:
        return {s: {"E_v_to_clean_mm": _rms(runs[s][0], clean[s][0]), "E_v_to_truth_mm": _rms(runs[s][0], truth), "E_d_mm2": runs[s][1]}
                for s in STAGES}

    out = {"clean": {s: {"E_v_to_truth_mm": _rms(clean[s][0], truth), "E_d_mm2": clean[s][1]} for s in STAGES}}
    # Table 5.4: a large hole over the left cheek and the left side of the nose (subject's left: +x)
    c = 0.5 * (truth[ICT_FDP["3.11"]] + truth[ICT_FDP["8.3"]])  # between the left inner eye corner and mouth corner
    V_h, F_h = _cut(case.scan_V_mm, case.scan_F, c, 25.0)
    lm_h = {k: v for k, v in case.landmarks_mm.items() if np.linalg.norm(v - c) > 25.0}
    out["table_5_4_large_hole"] = {"removed_faces": int(len(case.scan_F) - len(F_h)), "landmarks_left": len(lm_h),
                                   **table(_run_stages(model, V_h, F_h, lm_h))}
    # Table 5.5: the nose FDP missing
    lm_n = {k: v for k, v in case.landmarks_mm.items() if k != "9.3"}
    out["table_5_5_nose_fp_missing"] = table(_run_stages(model, case.scan_V_mm, case.scan_F, lm_n))
    # Table 5.6: misplaced FPs
    out["table_5_6_misplaced"] = {}
    for d in (2.0, 5.0, 10.0):
        lm_m = {k: _slide(case.scan_V_mm, case.scan_F, np.asarray(v), d, rng) for k, v in case.landmarks_mm.items()}
        out["table_5_6_misplaced"][f"{d:g} mm"] = table(_run_stages(model, case.scan_V_mm, case.scan_F, lm_m))
    # Table 5.7: noisy FP sets
    ev = {s: [] for s in STAGES}
    ed = {s: [] for s in STAGES}
    for _ in range(sets):
        lm_s = {k: _on_scan(case.scan_V_mm, case.scan_F, (np.asarray(v) + rng.normal(scale=1.0, size=3))[None])[0]
                for k, v in case.landmarks_mm.items()}
        runs = _run_stages(model, case.scan_V_mm, case.scan_F, lm_s)
        for s in STAGES:
            ev[s].append(_rms(runs[s][0], truth))
            ed[s].append(runs[s][1])
    out["table_5_7_noisy_sets"] = {"sets": sets, "sigma_fp_mm": 1.0,
                                   **{s: {"E_v_mean_mm": float(np.mean(ev[s])), "sigma_E_v_mm": float(np.std(ev[s])),
                                          "E_d_mean_mm2": float(np.mean(ed[s])), "sigma_E_d_mm2": float(np.std(ed[s]))}
                                      for s in STAGES}}
    return out


def write_markdown(result: dict, path: Path, doc: dict) -> None:
    L = ["# Robustness of the adaptation (after Tables 5.4-5.7) on unseen ICT faces", "",
         f"Generated by `python -m benchmarks.adapt_robustness` (seed {result['seed']}). Stages: L1 the FDP RBF, L2/L3 the",
         "thesis's levels, field: the smooth point-to-plane field, final: field + landing. E_v: RMS over the face vertices",
         "0-9408 [mm], to the clean case's result at the same stage and to the truth; E_d (Eq. 5.2.1) [mm^2] to the scan used.", ""]
    for ci, c in enumerate(result["cases"]):
        L += [f"## Case {ci} (seed {c['seed']})", "", "Clean: " + ", ".join(
            f"{s} E_v {v['E_v_to_truth_mm']:.2f} mm / E_d {v['E_d_mm2']:.3f}" for s, v in c["clean"].items()), ""]
        for title, key in (("Table 5.4: large hole (25 mm, left cheek and nose side)", "table_5_4_large_hole"),
                           ("Table 5.5: nose FDP missing", "table_5_5_nose_fp_missing")):
            L += [f"{title}", "", "| stage | E_v to clean [mm] | E_v to truth [mm] | E_d [mm^2] |", "|---|---|---|---|"]
            L += [f"| {s} | {c[key][s]['E_v_to_clean_mm']:.2f} | {c[key][s]['E_v_to_truth_mm']:.2f} | {c[key][s]['E_d_mm2']:.3f} |" for s in STAGES]
            L.append("")
        L += ["Table 5.6: every FDP misplaced along the surface", "", "| shift | " + " | ".join(f"{s} E_v to truth [mm]" for s in STAGES) + " |",
              "|---|" + "---|" * len(STAGES)]
        for d, t in c["table_5_6_misplaced"].items():
            L.append(f"| {d} | " + " | ".join(f"{t[s]['E_v_to_truth_mm']:.2f}" for s in STAGES) + " |")
        t = c["table_5_7_noisy_sets"]
        L += ["", f"Table 5.7: {t['sets']} FDP sets with Gaussian noise (sigma {t['sigma_fp_mm']} mm per axis)", "",
              "| stage | mean E_v [mm] | sigma E_v [mm] | mean E_d [mm^2] | sigma E_d [mm^2] |", "|---|---|---|---|---|"]
        L += [f"| {s} | {t[s]['E_v_mean_mm']:.2f} | {t[s]['sigma_E_v_mm']:.3f} | {t[s]['E_d_mean_mm2']:.3f} | {t[s]['sigma_E_d_mm2']:.4f} |" for s in STAGES]
        L.append("")
    L += [machine_line(doc), ""]
    path.write_text("\n".join(L))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=2)
    ap.add_argument("--sets", type=int, default=20)
    add_case_args(ap, seed=None)
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args(argv)
    if not (ict_dir() / "generic_neutral_mesh.obj").is_file():
        print("adapt_robustness: skipped, no ICT-FaceKit data")
        return 0
    from benchmarks._ict import load_model, make_case

    seed = int(args.seed) if args.seed is not None else int.from_bytes(os.urandom(4), "little")
    print(f"adapt_robustness: seed {seed}", flush=True)
    rng = np.random.default_rng(seed)
    model = load_model()
    cases = []
    for s in rng.integers(0, 2**31 - 1, size=args.cases):
        case = make_case(model, int(s))
        c = run_case(model, case, args.sets, rng)
        c["seed"] = int(s)
        cases.append(c)
        print(f"case seed {s}: clean final E_v {c['clean']['final']['E_v_to_truth_mm']:.2f} mm; hole final E_v to clean "
              f"{c['table_5_4_large_hole']['final']['E_v_to_clean_mm']:.2f} mm; nose missing {c['table_5_5_nose_fp_missing']['final']['E_v_to_clean_mm']:.2f} mm; "
              f"misplaced 10 mm {c['table_5_6_misplaced']['10 mm']['final']['E_v_to_truth_mm']:.2f} mm; "
              f"noisy sigma E_v {c['table_5_7_noisy_sets']['final']['sigma_E_v_mm']:.3f} mm", flush=True)
    result = {"seed": seed, "stages": STAGES, "cases": cases}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = save("adapt_robustness", result, folder=out)
    write_markdown(result, out / "adapt_robustness.md", load(path))
    print(f"wrote {out / 'adapt_robustness.json'} and {out / 'adapt_robustness.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
