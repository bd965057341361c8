"""Adaptation on UNSEEN faces: random ICT identities, any pose, scale, mm, new tessellation (issue 11).

Run: ``python -m benchmarks.adapt_unseen [--cases 20] [--seed S] [--identities DIR] [--no-peers] [--no-ict-peers] [--threads 1]``

Every run draws new cases from a new seed (printed and stored; ``--seed`` repeats a run):

- shape: the ICT-FaceKit neutral head (vertices 0-11247: face 0-9408, head and neck) plus
  ``sum_k w_k (identity_k - neutral)`` with ``w_k ~ N(0, 1)`` (ICT's own ``randomize_identity``)
  over all the identity modes found: the 100 of the public rig with ``--identities
  .../FaceXModel`` (or ``$FACEWARP_ICT_IDENTITIES``), else the shared folder's ``identity000-009``;
- scan: the shape linearly subdivided twice (libigl ``upsample``) and decimated to ~60k
  triangles (libigl ``decimate``), its vertices jittered along the surface (a random tangent
  step up to 0.4 of the local edge length, then back onto the true surface by closest point),
  Gaussian noise along the normals (sigma 0.05-0.3 mm, drawn per case), 2-6 holes (discs of
  4-10 mm radius on the face, away from the landmarks), a uniformly random rotation (any
  orientation), scale 0.8-1.2, a random translation, millimetre units;
- landmarks: the 12 FDPs with ICT indices in ``docs/MPEG4_FDP.md``, at the true shape's
  vertices (scan frame, mm);
- template: the ICT neutral head, so the true place of every template vertex on the scan is
  the shape's own vertex: E_v (vertex-to-vertex distance to the truth, scan frame, mm) over the
  face vertices 0-9408 is exact. Its tangential part (the error's component in the truth's
  tangent plane) is reported too: it is what a distance-to-scan heat map cannot show.

The user's path, ``facewarp adapt scan.obj --landmarks lm.json --units mm`` (``--landmarks68``: the
68-point scheme, ICT's 68 landmark vertices of the true shape, for the command and its nricp peer) with the DEFAULT
template (3,415 vertices), runs in a fresh process per case (wall and CPU seconds from process
start to every file written). Its truth: each template vertex's place on the ICT neutral head
(where facewarp puts it there with the true FDPs, found once per run) carried to the case's shape
by the ICT model's own correspondence (same triangle and barycentric coordinates); E_v over the
frontal vertices inside the ICT face area. Its peer: ``nricp_amberg`` with the same template,
landmarks and calibration, timed in-process. E_v RMS per region (lips, eyes, nose, cheeks,
forehead, jaw line; the ICT template's by its 68 landmarks, plus ears) says where the error sits.
``--part K/N`` and ``--merge N`` split a run over N processes (same ``--seed``).

Peers on the same cases in the same run: ``trimesh.registration.nricp_amberg`` (default
settings, the same 12 landmarks, template pre-aligned by the same calibration, distance
threshold 10 mm), and facewarp with the thesis's levels only (``refine="none"``).
Timings: one CPU core (threads limited before numpy is imported, process pinned); Warp on the
CPU with its kernels compiled beforehand (an untimed warm-up).
"""

from __future__ import annotations

import argparse
import os
import sys

from benchmarks._common import limit_threads, threads_from_argv

THREADS = 1  # timed on one core: pinned before numpy loads (the runner does it too; --threads N)

if __name__ == "__main__":
    limit_threads(threads_from_argv(sys.argv[1:], THREADS))

import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks._common import RESULTS, add_case_args, load, machine_line, save  # noqa: E402
from benchmarks._ict import (ICT_FDP, TEMPLATE_REGION_GROUPS, Case, ICTModel, TemplateTruth,  # noqa: E402
                             default_template_truth, error_stats, ict_dir, ict_regions, load_model, make_case, region_rms)
TARGETS = {"median_mm": 1.0, "rms_mm": 1.5, "p95_mm": 3.0, "beat_nricp_fraction": 0.9}


def run_facewarp(model: ICTModel, case: Case, **settings):
    from facewarp import adapt

    tl = {f: model.neutral[i] for f, i in ICT_FDP.items()}
    sl = {f: v * 1e-3 for f, v in case.landmarks_mm.items()}  # what `--units mm` gives the library
    t0, c0 = time.perf_counter(), time.process_time()
    res = adapt(model.neutral, model.faces, tl, case.scan_V_mm * 1e-3, case.scan_F, sl, **settings)
    return res, time.perf_counter() - t0, time.process_time() - c0


def run_nricp(model: ICTModel, case: Case, res):
    """nricp_amberg (default settings, 12 landmarks, 10 mm threshold) from our calibration."""
    import trimesh
    from trimesh.registration import nricp_amberg

    T = res.calibration.transform
    Q = T.apply(case.scan_V_mm * 1e-3)
    Qf = T.apply(np.array([case.landmarks_mm[f] for f in ICT_FDP]) * 1e-3)
    t0, c0 = time.perf_counter(), time.process_time()
    src = trimesh.Trimesh(model.neutral * 1e3, model.faces, process=False)
    tgt = trimesh.Trimesh(Q * 1e3, case.scan_F, process=False)
    out = nricp_amberg(src, tgt, source_landmarks=np.array(list(ICT_FDP.values())), target_positions=Qf * 1e3,
                       distance_threshold=10.0)
    V = T.inverse().apply(np.asarray(out) * 1e-3) * 1e3
    return V, time.perf_counter() - t0, time.process_time() - c0


def run_detected(model: ICTModel, case: Case) -> tuple[dict, dict]:
    """Automatic landmarks (ICT neutral as template) against the true FDPs, and facewarp with them."""
    from facewarp import adapt
    from facewarp.adaptation import detect_landmarks

    tl = {f: model.neutral[i] for f, i in ICT_FDP.items()}
    t0 = time.perf_counter()
    lm, conf = detect_landmarks(case.scan_V_mm * 1e-3, case.scan_F, template=(model.neutral, model.faces, tl))
    sec = time.perf_counter() - t0
    err = {k: float(np.linalg.norm(np.asarray(lm[k]) * 1e3 - case.landmarks_mm[k])) for k in ICT_FDP if k in lm}
    det = {"seconds": sec, "error_mm": err, "median_error_mm": float(np.median(list(err.values()))),
           "max_error_mm": float(max(err.values())), "found": len(err), "confidence": conf, "info": lm.info}
    t0, c0 = time.perf_counter(), time.process_time()
    res = adapt(model.neutral, model.faces, tl, case.scan_V_mm * 1e-3, case.scan_F, dict(lm))
    sec, cpu = time.perf_counter() - t0, time.process_time() - c0
    st, _, _ = error_stats(res.vertices_scan_frame * 1e3, case, model.faces)
    return det, {**st, "seconds": sec, "cpu_seconds": cpu}


def _stats(e: np.ndarray) -> dict:
    return {"E_v_median_mm": float(np.median(e)), "E_v_rms_mm": float(np.sqrt(np.mean(e**2))),
            "E_v_p95_mm": float(np.percentile(e, 95)), "E_v_max_mm": float(e.max())}


def run_command(truth: TemplateTruth, model: ICTModel, case: Case, tmp: Path, lm68: bool = False) -> tuple[dict, np.ndarray]:
    """``facewarp adapt scan.obj --landmarks lm.json --units mm`` (the default template) in a
    fresh process: wall and CPU seconds from process start to files written, E_v of the
    template's measured vertices against their true places (scan frame, mm)."""
    import json
    import resource
    import subprocess

    from facewarp import load_mesh
    from facewarp.geometry import save_obj

    tmp.mkdir(parents=True, exist_ok=True)
    save_obj(tmp / "scan.obj", case.scan_V_mm * 1e-3, case.scan_F, units="mm")
    (tmp / "lm.json").write_text(json.dumps({k: np.asarray(v).tolist() for k, v in case.landmarks_mm.items()}))
    if lm68:  # the 68-point scheme: ICT's 68 landmark vertices of the true shape, as a JSON list
        P = case.truth_scan_mm[np.asarray(model.markers)]
        (tmp / "lm.json").write_text(json.dumps(P.tolist()))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "facewarp", "adapt", str(tmp / "scan.obj"), "--landmarks", str(tmp / "lm.json"),
           "--units", "mm", "--out", str(tmp / "out")]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise SystemExit(f"facewarp adapt failed ({r.returncode}): {r.stderr.strip()[-400:]}")
    V = load_mesh(tmp / "out" / "adapted_scan_frame.obj", units="mm").vertices * 1e3
    e = np.linalg.norm(V - truth.truth_scan_mm(model, case), axis=1)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {**_stats(e[truth.mask]), "seconds": wall, "cpu_seconds": cpu,
            "regions_rms_mm": region_rms(e, truth.region, TEMPLATE_REGION_GROUPS, truth.mask)}, e


def run_nricp_template(truth: TemplateTruth, model: ICTModel, case: Case, lm68: bool = False) -> tuple[dict, np.ndarray]:
    """nricp_amberg with the default template (the same 12 landmarks as surface points, 10 mm
    threshold, pre-aligned by facewarp's calibration; ``lm68``: the 68 points of the scheme at their
    places on the template, ``facewarp.heads.IBUG68_TEMPLATE``); in-process seconds (no process start)."""
    import trimesh
    from trimesh.registration import nricp_amberg

    from facewarp.geometry import MeshQuery
    from facewarp.adaptation import calibrate

    ids = list(truth.landmarks)
    sl = {k: case.landmarks_mm[k] * 1e-3 for k in ids}
    T = calibrate(sl, truth.landmarks).transform
    t0, c0 = time.perf_counter(), time.process_time()
    src_pts = np.array([truth.landmarks[k] for k in ids])
    tgt_pts = np.array([sl[k] for k in ids])
    if lm68:
        from facewarp.heads import IBUG68_TEMPLATE

        src_pts, tgt_pts = IBUG68_TEMPLATE, case.truth_scan_mm[np.asarray(model.markers)] * 1e-3
    cpl = MeshQuery(truth.vertices, truth.faces).closest_point(src_pts)
    out = nricp_amberg(trimesh.Trimesh(truth.vertices * 1e3, truth.faces, process=False),
                       trimesh.Trimesh(T.apply(case.scan_V_mm * 1e-3) * 1e3, case.scan_F, process=False),
                       source_landmarks=(cpl.face, cpl.bary), target_positions=T.apply(tgt_pts) * 1e3,
                       distance_threshold=10.0)
    sec, cpu = time.perf_counter() - t0, time.process_time() - c0
    e = np.linalg.norm(T.inverse().apply(np.asarray(out) * 1e-3) * 1e3 - truth.truth_scan_mm(model, case), axis=1)
    return {**_stats(e[truth.mask]), "seconds": sec, "cpu_seconds": cpu,
            "regions_rms_mm": region_rms(e, truth.region, TEMPLATE_REGION_GROUPS, truth.mask)}, e


def heat_map(path: Path, V_mm: np.ndarray, faces: np.ndarray, values_mm: np.ndarray, title: str, vmax: float = 5.0) -> None:
    """Front and side pictures of the truth-frame head coloured by a per-vertex error [mm]."""
    from facewarp.render import colormap
    from facewarp import render_mesh, save_png

    colors = colormap(values_mm, 0.0, vmax)
    img = np.concatenate([render_mesh(V_mm * 1e-3, faces, view=v, width=420, height=420, vertex_colors=colors)
                          for v in ("front", "side")], axis=1)
    save_png(path, img, title=title, colorbar=(0.0, vmax, "mm"))


def summarise(rows: list) -> dict:
    keys = ("seconds", "cpu_seconds", "E_v_median_mm", "E_v_rms_mm", "E_v_p95_mm", "E_v_max_mm", "tangential_median_mm", "tangential_rms_mm")
    out = {}
    for k in keys:
        v = [r[k] for r in rows if k in r]
        if v:
            out[k] = {"mean": float(np.mean(v)), "median": float(np.median(v)), "worst": float(np.max(v))}
    return out


def write_markdown(result: dict, path: Path, doc: dict) -> None:
    T = result["targets"]
    methods = [m for m in ("facewarp", "nricp_amberg", "facewarp_levels_only", "facewarp_detected") if m in result["summary"]]
    allm = [m for m in (*methods, "command", "nricp_amberg_template") if m in result["summary"]]
    lines = [
        "# Adaptation on unseen faces (random ICT identities, any pose)",
        "",
        f"Generated by `python -m benchmarks.adapt_unseen` (seed {result['seed']}, {len(result['cases'])} cases;",
        f"each case: ICT neutral + N(0,1)-weighted offsets of {result.get('identity_modes', 10)} ICT identity modes, re-tessellated to ~60k triangles",
        "with surface jitter, normal noise, 2-6 holes, any rotation, scale 0.8-1.2, mm). Template: ICT neutral",
        "head (11,248 vertices), 12 FDP landmarks. E_v: distance of each face vertex (0-9408) to its true",
        "place, scan frame, mm; tangential: its component along the surface. Peers in the same run:",
        "`trimesh.registration.nricp_amberg` (defaults, same landmarks, 10 mm threshold) and facewarp with the",
        "thesis's levels only. Times: one CPU core, adaptation only (no file I/O).",
        "",
        f"Targets: median <= {T['median_mm']} mm, RMS <= {T['rms_mm']} mm, p95 <= {T['p95_mm']} mm, better than",
        f"nricp on >= {T['beat_nricp_fraction']:.0%} of cases and in aggregate, >= 5x faster than nricp.",
        "",
        "| case | seed | scale | " + " | ".join(f"{m} median / RMS / p95 [mm] | {m} s" for m in methods) + " |",
        "|---|---|---|" + "---|---|" * len(methods),
    ]
    for c in result["cases"]:
        cells = []
        for m in methods:
            r = c.get(m)
            cells += [f"{r['E_v_median_mm']:.2f} / {r['E_v_rms_mm']:.2f} / {r['E_v_p95_mm']:.2f}", f"{r['seconds']:.2f}"] if r else ["", ""]
        lines.append(f"| {c['index']} | {c['case']['seed']} | {c['case']['scale']:.2f} | " + " | ".join(cells) + " |")
    lines += ["", "Aggregate (mean over cases of each per-case figure; worst case in brackets):", "",
              "| method | E_v median [mm] | E_v RMS [mm] | E_v p95 [mm] | tangential RMS [mm] | time [s] | CPU [s] |", "|---|---|---|---|---|---|---|"]
    for m in allm:
        s = result["summary"][m]
        lines.append(
            f"| {m} | {s['E_v_median_mm']['mean']:.2f} ({s['E_v_median_mm']['worst']:.2f}) | {s['E_v_rms_mm']['mean']:.2f} ({s['E_v_rms_mm']['worst']:.2f}) | "
            f"{s['E_v_p95_mm']['mean']:.2f} ({s['E_v_p95_mm']['worst']:.2f}) | {s['tangential_rms_mm']['mean'] if 'tangential_rms_mm' in s else float('nan'):.2f} | {s['seconds']['mean']:.2f} | {s['cpu_seconds']['mean']:.2f} |"
        )
    cmd = [c for c in result["cases"] if "command" in c]
    if cmd:
        lines += ["", "## The `facewarp adapt` command with the default template", "",
                  "`facewarp adapt scan.obj --landmarks lm.json --units mm` (the default template, 3,415 vertices; landmarks: "
                  f"{result.get('command_landmarks', '12 FDPs')}) in a fresh",
                  "process per case: wall and CPU seconds from process start to every file written (OBJ, glTF, report, pictures).",
                  "Truth: each template vertex's place on the ICT neutral head (where facewarp puts it there with the true FDPs,",
                  "fixed once per run) carried to the case's shape by the ICT model's own correspondence (same triangle,",
                  "same barycentric coordinates); E_v over the frontal vertices inside the ICT face area, scan frame, mm.",
                  "Peer: `nricp_amberg` with the same template, landmarks and calibration, timed in-process (its process",
                  "start and file reading not counted).", "",
                  "| case | command median / RMS / p95 [mm] | wall s | CPU s | nricp median / RMS / p95 [mm] | nricp s | speed-up (wall) | "
                  + " | ".join(f"{g} RMS" for g in TEMPLATE_REGION_GROUPS) + " |",
                  "|---|---|---|---|---|---|---|" + "---|" * len(TEMPLATE_REGION_GROUPS)]
        for c in cmd:
            a, n = c["command"], c.get("nricp_amberg_template")
            nr = (f"{n['E_v_median_mm']:.2f} / {n['E_v_rms_mm']:.2f} / {n['E_v_p95_mm']:.2f} | {n['seconds']:.1f} | "
                  f"{n['seconds'] / a['seconds']:.1f}x") if n else " | | "
            lines.append(f"| {c['index']} | {a['E_v_median_mm']:.2f} / {a['E_v_rms_mm']:.2f} / {a['E_v_p95_mm']:.2f} | {a['seconds']:.2f} | "
                         f"{a['cpu_seconds']:.2f} | {nr} | " + " | ".join(f"{a['regions_rms_mm'].get(g, float('nan')):.2f}" for g in TEMPLATE_REGION_GROUPS) + " |")
    regs = [c["facewarp"].get("regions_rms_mm") for c in result["cases"] if c["facewarp"].get("regions_rms_mm")]
    if regs:
        names = list(regs[0])
        lines += ["", "Where the error sits (E_v RMS per region [mm], mean over cases; ICT regions by its 68 landmarks, template",
                  "regions by its own labels):", "", "| template | " + " | ".join(names) + " |", "|---|" + "---|" * len(names),
                  "| ICT neutral (library) | " + " | ".join(f"{np.mean([r[g] for r in regs if g in r]):.2f}" for g in names) + " |"]
        if cmd:
            lines += ["", "| template | " + " | ".join(TEMPLATE_REGION_GROUPS) + " |", "|---|" + "---|" * len(TEMPLATE_REGION_GROUPS),
                      "| default (`facewarp adapt`) | " + " | ".join(
                          f"{np.mean([c['command']['regions_rms_mm'][g] for c in cmd if g in c['command']['regions_rms_mm']]):.2f}"
                          for g in TEMPLATE_REGION_GROUPS) + " |"]
            if "nricp_amberg_template" in cmd[0]:
                lines.append("| default (nricp_amberg) | " + " | ".join(
                    f"{np.mean([c['nricp_amberg_template']['regions_rms_mm'][g] for c in cmd if g in c['nricp_amberg_template']['regions_rms_mm']]):.2f}"
                    for g in TEMPLATE_REGION_GROUPS) + " |")
    v = result["verdict"]
    lines += ["", "Verdict:", ""] + [f"- {k}: {val}" for k, val in v.items()]
    if result.get("heat_maps"):
        lines += ["", "Heat maps (total and tangential E_v of the worst cases): " + ", ".join(f"`{p}`" for p in result["heat_maps"])]
    lines += ["", machine_line(doc), ""]
    path.write_text("\n".join(lines))


def verdict(cases: list) -> dict:
    fw = [c["facewarp"] for c in cases]
    out = {
        "median_mm (worst case)": f"{max(r['E_v_median_mm'] for r in fw):.2f} (target {TARGETS['median_mm']}): "
                                  + ("met" if all(r["E_v_median_mm"] <= TARGETS["median_mm"] for r in fw) else "NOT met"),
        "rms_mm (worst case)": f"{max(r['E_v_rms_mm'] for r in fw):.2f} (target {TARGETS['rms_mm']}): "
                               + ("met" if all(r["E_v_rms_mm"] <= TARGETS["rms_mm"] for r in fw) else "NOT met"),
        "p95_mm (worst case)": f"{max(r['E_v_p95_mm'] for r in fw):.2f} (target {TARGETS['p95_mm']}): "
                               + ("met" if all(r["E_v_p95_mm"] <= TARGETS["p95_mm"] for r in fw) else "NOT met"),
    }
    ok = [r["E_v_median_mm"] <= TARGETS["median_mm"] and r["E_v_rms_mm"] <= TARGETS["rms_mm"] and r["E_v_p95_mm"] <= TARGETS["p95_mm"] for r in fw]
    out["cases meeting all three E_v targets"] = f"{sum(ok)}/{len(ok)}"
    agg = {"median": float(np.median([r["E_v_median_mm"] for r in fw])), "rms": float(np.sqrt(np.mean([r["E_v_rms_mm"] ** 2 for r in fw]))),
           "p95": float(np.mean([r["E_v_p95_mm"] for r in fw]))}
    out["aggregate (median of medians / pooled RMS / mean p95)"] = (
        f"{agg['median']:.2f} / {agg['rms']:.2f} / {agg['p95']:.2f} mm: "
        + ("met" if agg["median"] <= TARGETS["median_mm"] and agg["rms"] <= TARGETS["rms_mm"] and agg["p95"] <= TARGETS["p95_mm"] else "NOT met"))
    det = [c for c in cases if "detect" in c]
    if det:
        med = float(np.median([c["detect"]["median_error_mm"] for c in det]))
        ratio = [c["facewarp_detected"]["E_v_rms_mm"] / c["facewarp"]["E_v_rms_mm"] for c in det]
        out["automatic landmarks: median FDP error"] = (f"{med:.2f} mm (median over cases of the per-case median; worst case "
                                                         f"{max(c['detect']['median_error_mm'] for c in det):.2f} mm; target 3 mm)")
        out["adaptation with detected vs true landmarks (E_v RMS ratio)"] = (
            f"median {np.median(ratio):.3f}, worst {max(ratio):.3f} (target <= 1.10; within 10 % on "
            f"{sum(r <= 1.1 for r in ratio)}/{len(ratio)} cases)")
    cmd = [c for c in cases if "command" in c]
    if cmd:
        med = float(np.mean([c["command"]["E_v_median_mm"] for c in cmd]))
        rms = float(np.mean([c["command"]["E_v_rms_mm"] for c in cmd]))
        out["`facewarp adapt` (default template): E_v median / RMS, mean over cases"] = (
            f"{med:.2f} / {rms:.2f} mm (targets {TARGETS['median_mm']} / {TARGETS['rms_mm']}): "
            + ("met" if med <= TARGETS["median_mm"] and rms <= TARGETS["rms_mm"] else "NOT met")
            + f"; worst case {max(c['command']['E_v_median_mm'] for c in cmd):.2f} / {max(c['command']['E_v_rms_mm'] for c in cmd):.2f} mm")
        peer = [c for c in cmd if "nricp_amberg_template" in c]
        if peer:
            wins = sum(c["command"]["E_v_rms_mm"] < c["nricp_amberg_template"]["E_v_rms_mm"]
                       and c["command"]["E_v_median_mm"] < c["nricp_amberg_template"]["E_v_median_mm"] for c in peer)
            sp = [c["nricp_amberg_template"]["seconds"] / c["command"]["seconds"] for c in peer]
            spc = [c["nricp_amberg_template"]["cpu_seconds"] / c["command"]["cpu_seconds"] for c in peer]
            out["`facewarp adapt` better than nricp_amberg (default template; median and RMS) on"] = f"{wins}/{len(peer)} cases"
            every = [c["command"]["E_v_median_mm"] <= TARGETS["median_mm"] and c["command"]["E_v_rms_mm"] <= TARGETS["rms_mm"]
                     and c["command"]["E_v_p95_mm"] <= TARGETS["p95_mm"] for c in cmd]
            out["`facewarp adapt` (default template) meets median / RMS / p95 targets on"] = (
                f"{sum(every)}/{len(every)} cases (worst p95 {max(c['command']['E_v_p95_mm'] for c in cmd):.2f} mm)")
            out["`facewarp adapt` (wall, process start included) vs nricp_amberg (in-process), same case"] = (
                f"{np.mean(sp):.1f}x faster on average, slowest case {min(sp):.1f}x, >= 5x on {sum(x >= 5 for x in sp)}/{len(sp)} cases "
                f"(CPU seconds: {np.mean(spc):.1f}x on average, slowest {min(spc):.1f}x; target 5x)")
    both = [c for c in cases if "nricp_amberg" in c]
    if both:
        wins = sum(c["facewarp"]["E_v_rms_mm"] < c["nricp_amberg"]["E_v_rms_mm"] and c["facewarp"]["E_v_median_mm"] < c["nricp_amberg"]["E_v_median_mm"] for c in both)
        agg_f = float(np.sqrt(np.mean([c["facewarp"]["E_v_rms_mm"] ** 2 for c in both])))
        agg_n = float(np.sqrt(np.mean([c["nricp_amberg"]["E_v_rms_mm"] ** 2 for c in both])))
        speed = float(np.mean([c["nricp_amberg"]["seconds"] for c in both]) / np.mean([c["facewarp"]["seconds"] for c in both]))
        out["better than nricp (median and RMS) on"] = f"{wins}/{len(both)} cases ({wins / len(both):.0%}, target 90%)"
        out["aggregate RMS facewarp vs nricp"] = f"{agg_f:.2f} vs {agg_n:.2f} mm"
        out["speed-up over nricp"] = f"{speed:.1f}x (target 5x)"
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=20)
    add_case_args(ap, seed=None)
    ap.add_argument("--no-peers", action="store_true", help="skip nricp_amberg and the levels-only run")
    ap.add_argument("--no-ict-peers", action="store_true",
                    help="skip the peers with the ICT template (nricp_amberg, levels only); keep the default template's")
    ap.add_argument("--identities", default=None,
                    help="folder of the ICT identity OBJs (the public rig's FaceXModel: all 100 modes); default "
                         "$FACEWARP_ICT_IDENTITIES, else the shared folder's identity000-009")
    ap.add_argument("--no-detect", action="store_true", help="skip the automatic landmarks")
    ap.add_argument("--landmarks68", action="store_true",
                    help="the command and its nricp peer get the 68-point scheme (ICT's 68 landmark vertices of the "
                         "true shape, a JSON list) instead of the 12 FDPs")
    ap.add_argument("--no-command", action="store_true", help="skip the `facewarp adapt` command with the default template")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--heat-maps", type=int, default=2, help="heat maps of the N worst cases")
    ap.add_argument("--part", default=None, help="K/N: run only the cases i with i %% N == K and keep them in --part-dir")
    ap.add_argument("--merge", type=int, default=0, help="N: gather the N parts from --part-dir and write the result")
    ap.add_argument("--part-dir", default=None, help="folder of the parts (--part / --merge)")
    ap.add_argument("--name", default="adapt_unseen")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args(argv)
    if not (ict_dir() / "generic_neutral_mesh.obj").is_file():
        print(f"adapt_unseen: skipped, ICT-FaceKit data not found at {ict_dir()} (set FACEWARP_SHARED)")
        return 0
    seed = int(args.seed) if args.seed is not None else int.from_bytes(os.urandom(4), "little")
    print(f"adapt_unseen: seed {seed}", flush=True)
    model = load_model(args.identities or os.environ.get("FACEWARP_ICT_IDENTITIES") or None)
    print(f"adapt_unseen: {len(model.offsets)} identity modes", flush=True)
    from facewarp import adapt

    lm = {f: model.neutral[i] for f, i in ICT_FDP.items()}
    adapt(model.neutral, model.faces, lm, model.neutral * 1.02, model.faces, {f: v * 1.02 for f, v in lm.items()}, levels=1)  # warm-up
    seeds = np.random.default_rng(seed).integers(0, 2**31 - 1, size=args.cases)
    cases = []
    out = Path(args.out)
    from benchmarks._ict import FACE_VERTS

    ict_reg = ict_regions(model)
    truth = None if args.no_command else default_template_truth(model)
    import tempfile

    scratch = Path(tempfile.mkdtemp(prefix="adapt_unseen_"))
    import pickle

    part = tuple(int(x) for x in args.part.split("/")) if args.part else (0, 1)
    if args.merge:
        cases = []
        for k in range(args.merge):
            f = Path(args.part_dir) / f"part{k}.pkl"
            if f.is_file():
                with open(f, "rb") as fh:
                    cases += pickle.load(fh)
        cases.sort(key=lambda c: c["index"])
        seeds = []
    for i, s in enumerate(seeds):
        if i % part[1] != part[0]:
            continue
        case = make_case(model, int(s))
        row = {"index": i, "case": case.info()}
        res, sec, cpu = run_facewarp(model, case)
        st, e, tang = error_stats(res.vertices_scan_frame * 1e3, case, model.faces)
        row["facewarp"] = {**st, "seconds": sec, "cpu_seconds": cpu, "levels": [r.to_dict() for r in res.levels],
                           "refine": res.refine, "regions_rms_mm": region_rms(e[:FACE_VERTS], ict_reg[:FACE_VERTS])}
        row["_e"] = (e, tang)
        if truth is not None:
            row["command"], ec = run_command(truth, model, case, scratch / f"case{i:02d}", args.landmarks68)
            row["_ec"] = ec
            if not args.no_peers:
                row["nricp_amberg_template"], _ = run_nricp_template(truth, model, case, args.landmarks68)
        if not args.no_detect:
            row["detect"], row["facewarp_detected"] = run_detected(model, case)
        if not args.no_peers and not args.no_ict_peers:
            res0, sec0, cpu0 = run_facewarp(model, case, refine="none")
            st0, _, _ = error_stats(res0.vertices_scan_frame * 1e3, case, model.faces)
            row["facewarp_levels_only"] = {**st0, "seconds": sec0, "cpu_seconds": cpu0}
            Vn, secn, cpun = run_nricp(model, case, res)
            stn, _, _ = error_stats(Vn, case, model.faces)
            row["nricp_amberg"] = {**stn, "seconds": secn, "cpu_seconds": cpun}
        cases.append(row)
        if args.part:  # kept after every case: a run cut short still gives the cases it finished
            Path(args.part_dir).mkdir(parents=True, exist_ok=True)
            with open(Path(args.part_dir) / f"part{part[0]}.pkl", "wb") as fh:
                pickle.dump(cases, fh)
        f = row["facewarp"]
        print(f"case {i} (seed {s}, scale {case.scale:.2f}): facewarp {f['seconds']:.2f} s E_v {f['E_v_median_mm']:.2f}/{f['E_v_rms_mm']:.2f}/{f['E_v_p95_mm']:.2f} mm"
              + "".join(f" | {m} {row[m]['seconds']:.2f} s {row[m]['E_v_median_mm']:.2f}/{row[m]['E_v_rms_mm']:.2f}/{row[m]['E_v_p95_mm']:.2f}"
                        for m in ("facewarp_levels_only", "nricp_amberg", "command", "nricp_amberg_template") if m in row), flush=True)
    if args.part:
        Path(args.part_dir).mkdir(parents=True, exist_ok=True)
        with open(Path(args.part_dir) / f"part{part[0]}.pkl", "wb") as fh:
            pickle.dump(cases, fh)
        print(f"part {args.part}: {len(cases)} cases kept in {args.part_dir}")
        return 0
    heat = []
    folder = out / args.name  # the heat maps beside the run's JSON, by its name
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("case*.png"):
        old.unlink()
    worst = sorted(cases, key=lambda c: -c["facewarp"]["E_v_rms_mm"])[: args.heat_maps]
    for c in worst:
        e, tang = c["_e"]
        case = make_case(model, c["case"]["seed"])
        for name, val in (("total", e), ("tangential", tang)):
            p = folder / f"case{c['index']:02d}_{name}.png"
            heat_map(p, case.truth * 1e3, model.faces, val, f"case {c['index']} (seed {c['case']['seed']}): {name} E_v, truth frame")
            heat.append(str(p.relative_to(out)))
    if truth is not None:
        for c in sorted(cases, key=lambda c: -c["command"]["E_v_rms_mm"])[: args.heat_maps]:
            case = make_case(model, c["case"]["seed"])
            X = np.einsum("kj,kjd->kd", truth.bary, case.truth[model.faces[truth.face]])
            p = folder / f"case{c['index']:02d}_command.png"
            heat_map(p, X * 1e3, truth.faces, np.where(truth.mask, c["_ec"], 0.0),
                     f"case {c['index']}: E_v of `facewarp adapt` (default template), truth frame")
            heat.append(str(p.relative_to(out)))
    import shutil

    shutil.rmtree(scratch, ignore_errors=True)
    for c in cases:
        c.pop("_e")
        c.pop("_ec", None)
    methods = [m for m in ("facewarp", "facewarp_detected", "facewarp_levels_only", "nricp_amberg", "command",
                           "nricp_amberg_template") if m in cases[0]]
    result = {"seed": seed, "threads": args.threads, "identity_modes": int(len(model.offsets)),
              "command_landmarks": "68-point scheme" if args.landmarks68 else "12 FDPs", "targets": TARGETS, "cases": cases,
              "summary": {m: summarise([c[m] for c in cases]) for m in methods}, "verdict": verdict(cases), "heat_maps": heat}
    out.mkdir(parents=True, exist_ok=True)
    path = save(args.name, result, folder=out)
    write_markdown(result, out / f"{args.name}.md", load(path))
    for k, v in result["verdict"].items():
        print(f"{k}: {v}")
    print(f"wrote {out / (args.name + '.json')} and {out / (args.name + '.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
