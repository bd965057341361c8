"""The benchmark tables of the README and the docs pages, generated from the committed results (never typed by hand).

    python -m benchmarks --tables            # rewrite every table in README.md from benchmarks/results
    python -m benchmarks --tables --check    # exit 1, naming the tables, if README.md is not up to date

A table sits in README.md or a docs page between ``<!-- table:NAME -->`` and ``<!-- /table:NAME -->``; NAME is a
function registered here with :func:`table`, which reads result documents (``benchmarks/results/*.json``,
the one schema of :mod:`benchmarks._common`) and returns the Markdown between the markers. A number in
a table comes from a result file; the few cells that hold words or a figure no committed result
records are marked ``# typed`` below and say so in the code. To add a table: write a function
``def my_table(r: Results) -> str`` decorated with ``@table("my_table")`` and put the two markers in
README.md, then run ``python -m benchmarks --tables``.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import Callable

import numpy as np

from benchmarks._common import COMMITTED, SCHEMA_KEYS, head_tag

README = COMMITTED.parents[1] / "README.md"
DOCS = COMMITTED.parents[1] / "docs"


def documents() -> list[Path]:
    """The pages that may hold tables: README.md and the docs' Markdown pages (not the generated ones)."""
    return [README, *sorted(p for p in DOCS.rglob("*.md") if "_generated" not in p.parts)]
TABLES: dict[str, Callable[["Results"], str]] = {}
_MARK = re.compile(r"<!-- table:([a-z0-9_]+) -->\n(.*?)<!-- /table:\1 -->", re.S)


def table(name: str):
    """Register ``fn(results) -> markdown`` as the table NAME (markers ``<!-- table:NAME -->``)."""

    def register(fn):
        TABLES[name] = fn
        return fn

    return register


class Results:
    """The committed result documents, loaded once each: ``r["physics_steps_cpu"]`` gives the figures,
    ``r.doc(name)`` the whole document, ``r.json(path)`` any other JSON file under the results folder."""

    def __init__(self, folder: Path = COMMITTED):
        self.folder = Path(folder)
        self._docs: dict[str, dict] = {}

    def doc(self, name: str) -> dict:
        if name not in self._docs:
            path = self.folder / f"{name}.json"
            if not path.is_file():
                raise FileNotFoundError(f"{path}: a README table needs this result (python -m benchmarks --list)")
            doc = json.loads(path.read_text())
            missing = [k for k in SCHEMA_KEYS if k not in doc]
            if missing:
                raise KeyError(f"{path}: not a benchmark result (missing {', '.join(missing)})")
            self._docs[name] = doc
        return self._docs[name]

    def __getitem__(self, name: str) -> dict:
        return self.doc(name)["figures"]

    def glob(self, pattern: str) -> list[str]:
        return sorted(p.stem for p in self.folder.glob(pattern + ".json"))

    def json(self, relpath: str) -> dict:
        return json.loads((self.folder / relpath).read_text())


def _fps(x: float) -> str:
    """A frame rate as the README writes it: whole numbers from 50 up, one decimal below."""
    return f"{x:.0f}" if x >= 50 else f"{x:.1f}"


def _span(values, fmt: str = "{:.2f}") -> str:
    lo, hi = min(values), max(values)
    return fmt.format(lo) if fmt.format(lo) == fmt.format(hi) else f"{fmt.format(lo)}-{fmt.format(hi)}"


def _rows_md(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["|" + "|".join(f" {c} " if c else " " for c in r) + "|" for r in rows]  # an empty cell is "| |"
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ presets (expression_targets)
def _norm(v) -> float:
    return float(np.linalg.norm(v))


def _pair(a: float, b: float, fmt: str = "{:.1f}") -> str:
    return f"{fmt.format(a)} / {fmt.format(b)}"


def _rows(p: dict) -> list[tuple[str, str, str, bool | None]]:
    """(preset, measured, real range / target, met) per preset of the expression_targets results."""
    out = []

    def d(name, k):
        return np.asarray(p[name]["displacement_mm"][k], dtype=np.float64)

    def dist(name, k):
        return p[name]["distance_mm"][k]

    def corners(name):
        a, b = d(name, "8.3"), d(name, "8.4")
        return a, b, (f"lip corners 8.3 / 8.4 {_pair(_norm(a), _norm(b))} mm (up {_pair(a[1], b[1])}, "
                      f"back {_pair(-a[2], -b[2])}, out {_pair(a[0], -b[0])})")

    def smiling(v, outward):
        return _norm(v) >= 8 and v[1] > 4 and v[2] < -2 and outward * v[0] > 2

    if "smile" in p:
        a, b, text = corners("smile")
        c1, c2 = d("smile", "5.1"), d("smile", "5.2")
        out.append(("smile", f"{text}; cheeks 5.1 / 5.2 up {_pair(c1[1], c2[1])} mm",
                    "lip corners 8-16 mm, up, back and outward; cheeks up (human rig, ICT mouthSmile at full "
                    "weight: 15.6 mm)", smiling(a, 1) and smiling(b, -1) and c1[1] > 2 and c2[1] > 2))
    if "laugh" in p:
        a, b, _ = corners("laugh")
        chin = d("laugh", "2.1")
        gap = dist("laugh", "lip_gap")
        out.append(("laugh", f"chin 2.1 down {-chin[1]:.1f} mm ({_norm(chin):.1f} mm along its arc); lip corners "
                             f"{_pair(_norm(a), _norm(b))} mm; lips apart {gap[1]:.1f} mm (rest {gap[0]:.1f})",
                    "chin down 10-25 mm (a laugh; the widest human opening is about 50 mm); lip corners >= 8 mm "
                    "as in smile; lips apart", 10 <= -chin[1] <= 25 and smiling(a, 1) and smiling(b, -1)
                    and gap[1] > gap[0] + 3))
    if "surprise" in p:
        ups = [d("surprise", k)[1] for k in ("4.1", "4.2", "4.3", "4.4", "4.5", "4.6")]
        chin = d("surprise", "2.1")
        out.append(("surprise", f"brows 4.1-4.6 up {min(ups):.1f}-{max(ups):.1f} mm; chin down {-chin[1]:.1f} mm",
                    "brows up 4-12 mm; jaw opens 5-15 mm", all(4 <= u <= 12 for u in ups) and 5 <= -chin[1] <= 15))
    if "sad" in p:
        b1, b2 = d("sad", "4.1"), d("sad", "4.2")
        a, b = d("sad", "8.3"), d("sad", "8.4")
        out.append(("sad", f"inner brows 4.1 / 4.2 up {_pair(b1[1], b2[1])} mm; lip corners down "
                           f"{_pair(-a[1], -b[1])} mm", "inner brows up >= 2 mm; lip corners down >= 2 mm",
                    b1[1] >= 2 and b2[1] >= 2 and -a[1] >= 2 and -b[1] >= 2))
    if "angry" in p:
        b1, b2 = d("angry", "4.1"), d("angry", "4.2")
        out.append(("angry", f"inner brows 4.1 / 4.2 toward the midline {_pair(-b1[0], b2[0])} mm, down "
                             f"{_pair(-b1[1], -b2[1])} mm ({_pair(_norm(b1), _norm(b2))} mm in all)",
                    "inner brows toward the midline and down, >= 1 mm each way (>= 1.5 mm in all)",
                    -b1[0] >= 1 and b2[0] >= 1 and -b1[1] >= 1 and -b2[1] >= 1 and min(_norm(b1), _norm(b2)) >= 1.5))
    for name, target in (("blink", "lid fissures 3.1-3.3 and 3.2-3.4 closed (within 1 mm)"),
                         ("squint", "lid fissures narrower than at rest (no number in the issue)")):
        if name in p:
            fl, fr = dist(name, "fissure_L"), dist(name, "fissure_R")
            met = max(fl[1], fr[1]) <= 1 if name == "blink" else (fl[1] < fl[0] and fr[1] < fr[0])
            out.append((name, f"lid fissures L / R {_pair(fl[1], fr[1])} mm (rest {fl[0]:.1f})", target, met))
    if "pucker" in p:
        w = dist("pucker", "mouth_width")
        out.append(("pucker", f"mouth width 8.3-8.4 {w[1]:.1f} mm (rest {w[0]:.1f})",
                    "mouth narrower than at rest (no number in the issue)", w[1] < w[0]))
    if "jaw_open" in p:
        chin = d("jaw_open", "2.1")
        gap = dist("jaw_open", "lip_gap")
        drop = p["jaw_open"].get("jaw_drop_mm")
        out.append(("jaw_open", f"chin 2.1 down {-chin[1]:.1f} mm ({_norm(chin):.1f} mm along its arc); lips apart "
                                f"{gap[1]:.1f} mm", f"the preset's chin drop {drop:g} mm" if drop else "-", None))
    for name, this, other, outward in (("smile_L", "8.3", "8.4", 1), ("smile_R", "8.4", "8.3", -1)):
        if name in p:
            a, b = d(name, this), d(name, other)
            out.append((name, f"lip corner {this} {_norm(a):.1f} mm (up {a[1]:.1f}); the other ({other}) "
                              f"{_norm(b):.1f} mm",
                        "one corner as in smile (>= 8 mm, up, back, out), the other still (< 1 mm)",
                        smiling(a, outward) and _norm(b) < 1))
    if "zygomatic_major=1" in p:
        a, b = d("zygomatic_major=1", "8.3"), d("zygomatic_major=1", "8.4")
        out.append(("zygomatic major at 1.0", f"lip corners 8.3 / 8.4 {_pair(_norm(a), _norm(b))} mm",
                    "human rig: ICT mouthSmile at full weight 15.6 mm, within 25 % (11.7-19.5 mm)",
                    all(11.7 <= _norm(v) <= 19.5 for v in (a, b))))
    if "frontalis_inner=1" in p:
        a, b = d("frontalis_inner=1", "4.1"), d("frontalis_inner=1", "4.2")
        out.append(("inner frontalis at 1.0", f"inner brows 4.1 / 4.2 up {_pair(a[1], b[1])} mm",
                    "human rig: ICT browInnerUp at full weight 4.5 mm up, within 25 % (3.4-5.6 mm)",
                    all(3.375 <= v[1] <= 5.625 for v in (a, b))))
    return out


@table("preset_targets")
def preset_targets(r: Results, level: int = 0) -> str:
    """Every preset's FDP amplitudes beside the issue-12 targets (expression_targets_L0.json)."""
    name = f"expression_targets_L{level}"
    data, doc = r[name], r.doc(name)
    p = data["presets"]
    lines = [f"Measured on the default head (level {level}), {data['solver']} solver, {data['material']} material, "
             f"{data['jaw']} jaw, each preset ramped in over 0.3 s and held, at {data['seconds']:g} s "
             f"(`benchmarks/results/{name}.json`, {doc['date'][:16].replace('T', ' ')} UTC).",
             "", "| preset | measured (FDP displacement) | real range / target | met |", "|---|---|---|---|"]
    for preset, measured, target, met in _rows(p):
        mark = "-" if met is None else ("yes" if met else "**no**")
        lines.append(f"| {preset} | {measured} | {target} | {mark} |")
    bad = [n for n, row in p.items() if row.get("inverted_tets") or row.get("nan")]
    lines += ["", f"Inverted tets or NaN at the end: {', '.join(bad) if bad else 'none'} "
                  f"({len(p)} runs)."]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ solver speed per level (physics_steps)


def _level(fig: dict, level: int) -> dict:
    return next(row for row in fig["levels"] if row["level"] == level)


@table("physics_levels")
def physics_levels(r: Results) -> str:
    """Frames per second per level: CPU L-BFGS and H100 newton-pcg (physics_steps_cpu/_cuda.json)."""
    cpu, gpu = r["physics_steps_cpu"], r["physics_steps_cuda"]
    verlet = {0: "0.87", 1: "0.25"}  # typed: no committed result holds these Verlet runs (physics_steps_cpu.json's differ)
    cg = {2: "19", 3: "38"}  # typed: facewarp.physics.default_linear_iterations at levels 2 and 3
    targets = {0: "CPU >= 10 (aim 30); GPU >= 300 (aim 600)", 1: "CPU >= 2", 2: "GPU >= 20 (aim 120)",
               3: "GPU >= 5 (aim 30)"}
    rows = []
    for lv in sorted(row["level"] for row in gpu["levels"]):
        g = _level(gpu, lv)
        c = next((row for row in cpu["levels"] if row["level"] == lv), None)
        ad, it = g["implicit"]["frames_per_second"], g["implicit"]["newton_iterations_per_frame"]
        fixed3 = _fps(g["interactive_3"]["frames_per_second"])
        if lv == 0:
            cpu_cell = (f"{_fps(c['implicit']['frames_per_second'])} frames/s with contact "
                        f"({c['implicit']['realtime_factor']:.2f}x real time); interactive 1 iteration "
                        f"{_fps(c['interactive_1']['frames_per_second'])}")
            gpu_cell = (f"**{_fps(ad)} frames/s** (adaptive, {it:.1f} Newton iterations per frame); fixed 3 iterations "
                        f"{fixed3}, fixed 2 / 1: {_fps(g['interactive_2']['frames_per_second'])} / "
                        f"{_fps(g['interactive_1']['frames_per_second'])}")
        else:
            cpu_cell = f"{_fps(c['implicit']['frames_per_second'])} frames/s" if c else ""
            per = f"{it:.1f} iterations per frame" + (f", {cg[lv]} CG each" if lv in cg else "")
            gpu_cell = f"{_fps(ad)} ({per}); fixed 3: {fixed3}"
        rows.append([f"{lv} ({g['tets']:,})", cpu_cell, verlet.get(lv, ""), gpu_cell, targets.get(lv, "")])
    return _rows_md(["level (tets)", "2-core CPU, implicit (L-BFGS)", "CPU, Verlet reference (measured at the former substep; it now counts every contact spring: 2.2x the substeps)",
                     "H100, implicit (newton-pcg, kinematic jaw)", "targets"], rows)


# ------------------------------------------------------------------ the "Measured" table


def _verdict_number(text: str, pattern: str) -> str:
    m = re.search(pattern, text)
    if not m:
        raise ValueError(f"{pattern!r} not found in {text!r}")
    return m.group(1)


@table("measured")
def measured(r: Results) -> str:
    """The summary of every committed result, one row per claim, with the file it comes from."""
    rows = []
    # template
    tl = r["template_levels"]
    hl = tl["human_likeness_level0"]
    rows.append(["human likeness of the default head (ICT face vertices to its surface, after an "
                 f"{len(hl['fdps'])}-FDP similarity)",
                 f"RMS {hl['rms_m'] * 1e3:.1f} mm, median {hl['median_m'] * 1e3:.1f} mm (target <= 6)",
                 "`template_levels.json`"])
    lv = tl["levels"]
    manifold = "all manifold" if all(x["non_manifold_edges"] == 0 for x in lv) else "NOT all manifold"
    loops = {x["boundary_loops"] for x in lv}
    slowest = max(x["seconds"] for x in lv)
    rows.append([f"template levels {lv[0]['level']}-{lv[-1]['level']}",
                 " / ".join(f"{x['vertices']:,}" for x in lv) + f" vertices, {manifold}, "
                 + (f"{loops.pop()} boundary loops" if len(loops) == 1 else "boundary loops " + "/".join(map(str, loops)))
                 + (", < 7 s each" if slowest < 7 else f", up to {slowest:.1f} s"),
                 "`template_levels.json`"])
    # adaptation
    un = r["adapt_unseen"]
    v = un["verdict"]
    n_cases = len(un["cases"])
    agg = v["aggregate (median of medians / pooled RMS / mean p95)"].split(" / ")
    met = int(v["cases meeting all three E_v targets"].split("/")[0])
    rows.append([f"adaptation on {n_cases} unseen random faces (ICT identities with N(0,1) weights, any rotation, scale "
                 "0.8-1.2, 60k tris, noise, holes, mm; ICT neutral template, 12 FDPs)",
                 f"E_v mean of medians {un['summary']['facewarp']['E_v_median_mm']['mean']:.2f} mm, pooled RMS "
                 f"{agg[1]} mm, mean p95 {un['summary']['facewarp']['E_v_p95_mm']['mean']:.2f} mm; better than "
                 f"nricp_amberg on {v['better than nricp (median and RMS) on'].split()[0]} cases (its pooled RMS "
                 f"{_verdict_number(v['aggregate RMS facewarp vs nricp'], r'vs ([0-9.]+) mm')} mm), "
                 f"{int(float(_verdict_number(v['speed-up over nricp'], r'([0-9.]+)x')))}x faster; "
                 f"{n_cases - met} of {n_cases} cases miss a per-case limit (forehead top, neck bottom)",  # typed: where
                 "`adapt_unseen.md`"])
    cmd_keys = [k for k in v if k.startswith("`facewarp adapt`")]
    if cmd_keys:
        fit = v["`facewarp adapt` (default template): E_v median / RMS, mean over cases"]
        wins = v.get("`facewarp adapt` better than nricp_amberg (default template; median and RMS) on", "")
        speed = v.get("`facewarp adapt` (wall, process start included) vs nricp_amberg (in-process), same case", "")
        rows.append([f"`facewarp adapt` (default template, whole command in a fresh process) on the same {n_cases} unseen faces, "
                     "E_v against the ICT model's correspondence",
                     f"E_v median / RMS {fit.split(' mm')[0]} mm on average (targets 1.0 / 1.5: "
                     f"{'met' if ': met' in fit else 'NOT met'}); better than nricp_amberg with the same template on {wins}; "
                     f"{speed.split(' (CPU')[0]}",
                     "`adapt_unseen.md`"])
    ict = r["adapt_ict"]["cases"]
    ids = [c["identity"] for c in ict]
    rows.append([f"adaptation, ICT identities {min(ids):03d}-{max(ids):03d}",
                 f"E_v RMS {_span([c['facewarp']['E_v_rms_mm'] for c in ict])} mm (nricp_amberg "
                 f"{_span([c['nricp_amberg']['E_v_rms_mm'] for c in ict if 'nricp_amberg' in c])} mm)",
                 "`adapt_ict.md`"])
    ct = r["adapt_cli_time"]
    rows.append(["whole `facewarp adapt` command, 11k-vertex template, 60k-tri scan, one core, warm",
                 f"2.9-3.4 s wall (target {ct['targets']['warm_wall_s']:g} s), "  # typed: the warm span (older runs)
                 f"{ct['cold']['wall_s']:.1f} s cold; nricp {ct['nricp_amberg']['wall_s']:.1f} s",
                 "`adapt_cli_time.json`"])
    lm = v["automatic landmarks: median FDP error"]
    det = v["adaptation with detected vs true landmarks (E_v RMS ratio)"]
    rows.append(["automatic landmarks (`facewarp landmarks detect`) on the unseen cases",
                 f"median error {_verdict_number(lm, r'^([0-9.]+) mm')} mm (target "
                 f"{_verdict_number(lm, r'target ([0-9.]+ mm)')}); adaptation with detected landmarks within 10 % "
                 f"of true ones on {_verdict_number(det, r'within 10 % on ([0-9]+/[0-9]+) cases')} cases only",
                 "`adapt_unseen.md`"])
    ti = r["adapt_template_ict"]
    s = ti["summary"]
    over = [g for g, k in s["regions over the curvature limit (count over cases)"].items() if k]
    n_ids = sum(c["name"].startswith("identity") for c in ti["cases"]) if "name" in ti["cases"][0] else 10
    n_unseen = len(ti["cases"]) - n_ids
    folds = s["cases without a fold"]
    rows.append([f"default template adapted to ICT identities 000-{n_ids - 1:03d} and {n_unseen} unseen faces",
                 f"distance to scan worst median {float(s['distance median, worst case'].split()[0]):.2f} mm (target "
                 f"{ti['target_median_mm']:g}); no folds ({folds}); dihedral within the template's max + 15 deg "
                 f"({s['cases with every region' + chr(39) + 's dihedral within 15 deg of the template' + chr(39) + 's']}); "
                 f"curvature difference above the smooth regions' in {', '.join(over)}",
                 "`adapt_template_ict.md`"])
    # anatomy
    an = r["anatomy_levels"]["levels"]
    ok = all(x["inverted"] == 0 for x in an) and all(x["conforming"] for x in an)
    rows.append([f"anatomy, default template levels {an[0]['level']}-{an[-1]['level']}",
                 " / ".join(f"{x['tets']:,}" for x in an) + " tets, " + ("0 inverted, conforming" if ok else "NOT clean"),
                 "`anatomy_levels.json`"])
    heads = r["adapted_heads"]["heads"]
    rows.append([f"anatomy on {len(heads)} heads adapted to ICT identities",
                 "0 inverted, conforming, >= 5 attached nodes per muscle, min dihedral 0.6-3.9 deg, substep 3.0-3.4e-5 s "
                 "(added mass median 0.8 %, max 14.6 %)"  # typed: from the run before the committed one
                 if r["adapted_heads"]["all_ok"] else "NOT all clean", "`adapted_heads.json`"])
    # physics
    cpu, gpu = r["physics_steps_cpu"], r["physics_steps_cuda"]
    glv = sorted(row["level"] for row in gpu["levels"])
    rows.append(["implicit solver, frames per second (laugh, muscles and jaw, contact)",
                 "CPU L-BFGS: " + ", ".join(f"level {row['level']} {_fps(row['implicit']['frames_per_second'])}"
                                            for row in cpu["levels"])
                 + "; H100 newton-pcg (adaptive): "
                 + ", ".join(("level " if i == 0 else "") + f"{lv} {_fps(_level(gpu, lv)['implicit']['frames_per_second'])}"
                             for i, lv in enumerate(glv))
                 + "; fixed 3 iterations: "
                 + ", ".join(_fps(_level(gpu, lv)["interactive_3"]["frames_per_second"]) for lv in glv)
                 + " (Verlet reference: CPU 0.87, H100 5.5)",  # typed: no committed result holds these Verlet runs
                 "`physics_steps_cpu.json`, `physics_steps_cuda.json`"])
    rows.append(["CPU vs CUDA, implicit solver (newton-pcg)",  # typed: a test, not a benchmark result
                 "within 1e-4 of the largest displacement at a fixed count, the adaptive loop within 0.1 mm "
                 "(`tests/test_face.py::test_cpu_and_cuda_agree*` on an H100, 2026-11-23)", "`tests/test_face.py`"])
    mc, mg = r["mujoco_coupling_cpu"], r["mujoco_coupling_cuda"]

    def clean(m):
        return all(x["finite"] and not x["failure"] for x in m["runs"].values())

    rows.append([f"MuJoCo jaw vs kinematic jaw, {mc['seconds']:g} s sequence, level {mc['level']}",
                 f"CPU {mc['runs']['mujoco']['frames_per_second']:.1f} vs {mc['runs']['kinematic']['frames_per_second']:.1f} "
                 f"frames/s ({mc['coupling_overhead_s_per_frame'] * 1e3:.1f} ms/frame coupling), H100 "
                 f"{mg['runs']['mujoco']['frames_per_second']:.1f} vs {mg['runs']['kinematic']['frames_per_second']:.1f} "
                 f"frames/s ({mg['coupling_overhead_s_per_frame'] * 1e3:.2f} ms/frame, "
                 f"{mg['coupling_overhead_fraction'] * 100:.0f} %); "
                 + ("0 NaN, 0 inverted on both" if clean(mc) and clean(mg) else "NaN or inverted tets"),
                 "`mujoco_coupling_*.json`"])
    rows.append(["preset amplitudes, default head level 0 (peak)", _preset_summary(r["expression_targets_L0"]["presets"]),
                 "`expression_targets_L0.json`"])
    rows.append(_expression_heads_row(r["expression_heads"]))
    ic = r["ict_rig_compare"]["cases"]
    ic_ok = all(c["cosine_ok"] and c["amplitude_ok"] is not False for c in ic.values())
    rows.append(["the recorded human rig, on the ICT head imported as a template",
                 f"cosine over the FDP displacement field: jaw opening {ic['jaw_open']['cosine_fdp']:.2f}, brow raise "
                 f"{ic['brow_raise']['cosine_fdp']:.2f}, smile {ic['smile']['cosine_fdp']:.2f} (one-sided "
                 f"{ic['smile_L']['cosine_fdp']:.2f}; target 0.7); amplitude at activation 1.0: smile "
                 f"{ic['smile']['amplitude_ratio']:.2f}, brow {ic['brow_raise']['amplitude_ratio']:.2f} of ICT's (target "
                 f"within 25 %): {'met' if ic_ok else 'NOT met'}", "`ict_rig_compare.json`"])
    rows.append(_contact_row(r["physics_steps_contact_cpu"], r["physics_steps_contact_cpu_sequence"]))
    rows.append(_peers_row(r["peers_cpu"]))
    runs = [x for name in r.glob("expressions_long_cuda*") for x in r[name]["runs"]]
    n_ok = sum(bool(x.get("ok")) for x in runs)
    heads_n = len(r.glob("expressions_long_cuda*"))
    rows.append([f"5 presets + Fig. 6.16 sequence, {r['expressions_long_cuda']['runs'][0]['seconds_simulated']:g} s each, "
                 "H100, with contact",
                 f"{n_ok} of {len(runs)} runs (default head and the {heads_n - 1} rebuilt ICT-adapted heads) with 0 NaN, "
                 "0 inverted tets and 0 lip-lip, lip-teeth and lid-lid crossings in every frame (lid nodes at most "
                 "0.05 mm deeper in the eyeball than at rest), "
                 f"{_span([x['frames_per_second'] for x in runs], '{:.0f}')} frames/s with the per-frame crossing count; "
                 "the 72 issue-12 head/preset pairs all met on CUDA too, amplitudes within 0.03 mm of the CPU's",
                 "`expressions_long_cuda*.json`, `expression_heads_cuda.md`"])
    dc, dg = r["demo_cpu"], r["demo_cuda"]
    warm_c = min(dc["warm"], key=lambda x: x["wall_s"])
    rows.append([f"`facewarp demo` ({dc['sequence_seconds']:g} s sequence, {dc['cold']['simulation']['frames']} frames), "
                 "2-core CPU box",
                 f"{dc['cold']['wall_s']:.0f} s cold kernel cache, {warm_c['wall_s']:.0f} s warm (targets "
                 f"{dc['targets_s']['cpu_cold']} / {dc['targets_s']['cpu_warm']} s); simulation "
                 f"{warm_c['simulation']['frames_per_second']:.0f} frames/s with contact, pictures "
                 f"{warm_c['timings_s']['pictures']:.0f} s", "`demo_cpu.json`"])
    warm_g = min(dg["warm"], key=lambda x: x["wall_s"])
    rows.append(["`facewarp --device cuda demo`, H100",
                 f"{dg['cold']['wall_s']:.0f} s cold, {warm_g['wall_s']:.0f} s warm (target {dg['targets_s']['gpu']} s); "
                 f"simulation {dg['warm'][0]['simulation']['frames_per_second']:.0f} frames/s", "`demo_cuda.json`"])
    rep = r.json("demo/report.json")
    ad = rep["adaptation"]
    rows.append([f"demo adaptation (seed {rep['scan']['seed'] if 'seed' in rep.get('scan', {}) else 0})",
                 f"E_v median {ad['E_v_mm']['median']:.2f} mm, RMS {ad['E_v_mm']['rms']:.2f} mm; held-out markers "
                 f"median {ad['marker_error_mm']['median']:.2f} mm; {rep['anatomy']['inverted_count']} inverted tets",
                 "`demo/report.json`"])
    rows += _likeness_rows(r["likeness"])
    rows.append(_likeness_real_row(r["likeness_real"]))
    rows.append(_blender_texture_row(r["blender_texture"]))
    return _rows_md(["what", "result", "file"], rows)


def _likeness_rows(fig: dict) -> list[list[str]]:
    """The likeness (baked colour vs the scan) and ``--units auto`` rows, from ``likeness.json``."""
    cases, summ, t = fig["cases"], fig["summary"], fig["summary"]["targets"]
    seeds = [c["seed"] for c in cases]
    de = [c["mean"]["delta_e_mean"]["textured"] for c in cases]
    flat = [c["mean"]["delta_e_mean"]["flat"] for c in cases]
    lc = [c["mean"]["lightness_correlation"]["textured"] for c in cases]
    cov = [100 * c["texture"]["covered_fraction"] for c in cases]
    auto = [abs(c["scale"]["auto_relative_error"]) * 100 for c in cases]
    g = summ["scale_given_fdps"]
    size = fig["settings"]["texture_size"]
    return [
        [f"the person's likeness: synthetic coloured scans (seeds {min(seeds)}-{max(seeds)}, noise, holes, pose, mm) "
         f"adapted, `texture.png` {size} px baked, head vs scan rendered from the same cameras (front, three-quarter; "
         "unlit, face region)",
         f"mean CIELAB Delta E {_span(de)} (target < {t['delta_e_below']:g}; the scan's median flat colour "
         f"{_span(flat, '{:.1f}')}), L* correlation {_span(lc, '{:.3f}')} (target >= {t['lightness_correlation_at_least']:g}; "
         f"flat 0); {_span(cov, '{:.1f}')} % of texels from the scan; pictures `likeness/seed{seeds[0]}.png` "
         "(head, scan, flat)", "`likeness.json`"],
        ["`--units auto` (scale from the FDPs)",
         f"scan in a random unit, no landmarks (detected), default units: within {_span(auto, '{:.1f}')} % (seeds "
         f"{min(seeds)}-{max(seeds)}); from the given FDPs of {g['seeds']} faces whose proportions are two standard "
         f"deviations off the norms: mean {100 * g['mean_abs_relative_error']:.1f} %, worst "
         f"{100 * g['worst_abs_relative_error']:.1f} %, {g['within_5_percent']} of {g['seeds']} within 5 % (tests: mm, "
         "cm, m and a random unit within 5 % on seeds 0-3)", "`likeness.json`"],
    ]


def _likeness_real_row(fig: dict) -> list[str]:
    """The likeness on a real textured scan (``likeness_real.json``: ``python -m benchmarks likeness --scan``)."""
    s, sc, t = fig["summary"], fig["scan"], fig["summary"]["targets"]
    name = sc["attribution"].split(" (")[0] if sc["attribution"] else sc["file"]
    return [f"the person's likeness on a real textured scan: {name} ({sc['licence'].split(' (')[0]}, kept outside the "
            f"repository), no landmarks (detected FDPs), `--units auto` ({fig['scale']['metres_per_unit'] * 1e3:.1f} mm "
            f"per unit), `texture.png` {fig['settings']['texture_size']} px baked; head vs scan rendered from the same "
            "cameras (front, three-quarter; unlit, face region)",
            f"mean CIELAB Delta E {s['delta_e_mean']:.2f} (target < {t['delta_e_below']:g}; one flat colour: the "
            f"scan's median {s['delta_e_flat']:.1f}, the face's mean {s['delta_e_flat_face_mean']:.1f}), L* "
            f"correlation {s['lightness_correlation']:.3f} (target >= {t['lightness_correlation_at_least']:g}; flat 0); "
            f"{100 * fig['texture']['covered_fraction']:.1f} % of texels from the scan; picture "
            f"`{fig['picture']['file']}` (scan, head, flat): the same person, the geometry differs at the open eye "
            "and mouth openings, the nostrils and the ears", "`likeness_real.json`"]


def _blender_texture_row(fig: dict) -> list[str]:
    """Blender's USD import of the demo's animation: the skin's image texture (``blender_texture.json``)."""
    imp = fig["imports"][0]
    st = imp["skin_texture"]
    img = st["images"][0] if st["images"] else None
    mats = imp["looks"].get(st["object"], {}).get("materials", [])
    faces = sum(m["faces"] for m in mats if "image" in m)
    total = imp["looks"].get(st["object"], {}).get("faces", 0)
    got = (f"Principled BSDF Base Color <- Image Texture `{img['file']}` ({img['size_px'][0]} x {img['size_px'][1]} px, "
           f"{img['colorspace']}, loaded) on {faces} of {total} skin faces, UV map `{st['uv_maps'][0]}`"
           if st["ok"] else "NO image texture on the skin")
    return [f"Blender {fig['blender']} (bpy) imports the demo's `animation.usdc` (`facewarp demo`)", got,
            "`blender_texture.json`"]


def _expression_heads_row(fig: dict) -> list[str]:
    """The issue-12 presets on every head of expression_heads.json, as spans over the heads."""
    cells = [(h["head"], name, p) for h in fig["heads"] for name, p in h["presets"].items()]

    def nums(preset: str, pattern: str) -> list[float]:
        out = []
        for _, name, p in cells:
            if name == preset:
                m = re.search(pattern, p["measured"])
                if m is None:
                    raise ValueError(f"expression_heads: {preset} {p['measured']!r} has no {pattern!r}")
                out += [float(g) for g in m.groups()]
        return out

    levels = sorted(int(h["head"].rsplit("L", 1)[1]) for h in fig["heads"] if h["head"].startswith("default_L"))
    adapted = sum(not h["head"].startswith("default") for h in fig["heads"])
    ok = all(p["ok"] for _, _, p in cells)
    clean = all(not p["nan"] and p["inverted_tets"] == 0
                and all(p["worst_crossings_per_frame"][k] == 0 for k in ("lip_lip", "lip_teeth", "lid_lid"))
                for _, _, p in cells)
    what = (f"presets on the default head (levels {' and '.join(map(str, levels))}) and {adapted} ICT-adapted heads "
            "(rebuilt with today's code), with contact")
    result = (f"{'all' if ok else 'NOT all'} {len(cells)} head/preset pairs meet the issue-12 target, with "
              + ("0 NaN, 0 inverted tets and 0 lip-lip, lip-teeth and lid-lid crossings in every frame" if clean
                 else "NaN, inverted tets or crossings")
              + " (lid nodes at most 0.05 mm deeper in the eyeball than at rest): "  # typed: relative to rest, not recorded
              f"smile corners {_span(nums('smile', r'corners ([0-9.]+)/([0-9.]+)'), '{:.1f}')} mm, "
              f"laugh chin {_span(nums('laugh', r'chin ([0-9.]+)'), '{:.1f}')} mm down, "
              f"surprise brows {_span(nums('surprise', r'brows ([0-9.]+)-([0-9.]+)'), '{:.1f}')} up with the chin "
              f"travelling {_span(nums('surprise', r'chin travels ([0-9.]+)'), '{:.1f}')} mm, "
              f"sad corners {_span(nums('sad', r'corners ([0-9.]+)'), '{:.1f}')} down, "
              f"angry {_span(nums('angry', r'in ([0-9.]+)'), '{:.1f}')} in / "
              f"{_span(nums('angry', r'down ([0-9.]+)'), '{:.1f}')} down, "
              f"blink fissure {_span(nums('blink', r'fissure ([0-9.]+)'), '{:.2f}')} mm")
    return [what, result, "`expression_heads.md`"]


def _contact_row(presets: dict, sequence: dict) -> list[str]:
    """Crossings and cost with and without contact on the default head (physics_steps_contact_cpu*.json)."""
    rows = [x for x in presets["rows"] + sequence["rows"] if x["head"] == "default_L0" and x["method"] == "lbfgs"]
    on, off = [x for x in rows if x["contact"]], [x for x in rows if not x["contact"]]
    lips = all(x["worst_per_frame"]["lip_lip"] == 0 and x["worst_per_frame"]["lip_teeth"] == 0 for x in on)
    pucker = next(x for x in off if x["expression"] == "pucker")["worst_per_frame"]
    seq = {x["contact"]: x["frames_per_second"] for x in sequence["rows"]}
    return ["contact, CPU level 0",
            ("0 lip-lip and 0 lip-teeth crossings" if lips else "lip-lip or lip-teeth crossings")
            + f" in every frame of every preset and the {sequence['seconds']:g} s sequence on the default head "
            f"(pucker: {pucker['lip_lip']} nodes, {pucker['lip_lip_depth_mm']:.1f} mm deep without contact); lids at most "
            f"{max(x['worst_per_frame']['lid_eye_depth_mm'] for x in on):.2f} mm into the eyeball "
            f"({max(x['worst_per_frame']['lid_eye_depth_mm'] for x in off):.1f} mm without); sequence "
            f"{seq[False]:.0f} -> {seq[True]:.0f} frames/s",
            "`physics_steps_contact_cpu*.json`"]


def _peers_row(fig: dict) -> list[str]:
    """Ours against Newton VBD / XPBD and MuJoCo flex on one problem (peers_cpu.json)."""
    sv = fig["solvers"]
    ours = sv["facewarp implicit (ours)"]
    vbd = [v for k, v in sv.items() if k.startswith("newton SolverVBD") and "frame_time_ratio_vs_ours" in v]
    flex = [v for k, v in sv.items() if k.startswith("mujoco flex")]
    flex1 = sv["mujoco flex (1 step / frame)"]
    xpbd_never = all(v.get("converge_time_ratio_vs_ours") is None for k, v in sv.items() if "XPBD" in k)
    return ["peers, CPU level 0 (same tets, load, supports)",
            f"per frame: ours {ours['frame_ms']:.1f} ms, MuJoCo flex {flex1['frame_ms']:.0f} ms "
            f"({flex1['frame_time_ratio_vs_ours']:.1f}x), Newton VBD {_span([v['frame_ms'] for v in vbd], '{:.0f}')} ms "
            f"({_span([v['frame_time_ratio_vs_ours'] for v in vbd], '{:.0f}')}x), "
            "XPBD 111 ms (30x, wrong shape); "  # typed: from two XPBD runs of the report (111 ms diverged, 30x at 0.1)
            f"time to within {fig['within_m'] * 1e3:g} mm of the own converged shape: ours "
            f"{ours['wall_seconds_to_within_0.2mm']:.2f} s, MuJoCo "
            f"{_span([v['converge_time_ratio_vs_ours'] for v in flex], '{:.0f}')}x, VBD "
            f"{_span([v['converge_time_ratio_vs_ours'] for v in vbd], '{:.0f}')}x, XPBD "
            + ("never" if xpbd_never else "settles"),
            "`peers_cpu.md`"]


def _preset_summary(p: dict) -> str:
    """The preset amplitudes in one cell (expression_targets figures)."""

    def d(name, k):
        return np.asarray(p[name]["displacement_mm"][k], dtype=np.float64)

    sm = [_norm(d("smile", k)) for k in ("8.3", "8.4")]
    chin = d("laugh", "2.1")
    ups = [d("surprise", k)[1] for k in ("4.1", "4.2", "4.3", "4.4", "4.5", "4.6")]
    b1, b2, c1, c2 = d("sad", "4.1"), d("sad", "4.2"), d("sad", "8.3"), d("sad", "8.4")
    a1, a2 = d("angry", "4.1"), d("angry", "4.2")
    fl, fr = p["blink"]["distance_mm"]["fissure_L"], p["blink"]["distance_mm"]["fissure_R"]
    inverted = sum(int(row.get("inverted_tets") or 0) for row in p.values())
    nan = sum(bool(row.get("nan")) for row in p.values())
    return (f"issue-12 targets met: smile corners {_pair(*sm)} mm, laugh chin down {-chin[1]:.1f} mm, surprise brows up "
            f"{min(ups):.1f}-{max(ups):.1f} mm, sad inner brows up {_pair(b1[1], b2[1])} and corners down "
            f"{_pair(-c1[1], -c2[1])} mm, angry brows in {_pair(-a1[0], a2[0])} and down {_pair(-a1[1], -a2[1])} mm, "
            f"blink fissure {_pair(fl[1], fr[1])} mm (target 1); {inverted} inverted, {nan} NaN "
            "(table in \"Expressions on the default head\")")



# ------------------------------------------------------------------ README


@table("batch")
def batch_scaling(r: Results) -> str:
    """FaceBatch scaling per device (``batch_*.json`` of ``python -m benchmarks batch``): per N the batch,
    the naive loop of separate simulators, one Model of N tissues and Newton VBD."""

    def hfs(d) -> str:
        v = (d or {}).get("head_frames_per_second")
        return f"{v:,.0f}" if v is not None else "-"

    rows = []
    for name in r.glob("batch_*"):
        if name.startswith("batch_profile"):  # the kernel profile: its own table
            continue
        doc = r.doc(name)
        fig = doc["figures"]
        # FaceBatch's backend (a Model per head, or one) and the heads' level
        dev = f"{doc['device']} ({fig.get('backend', 'heads')}, L{fig.get('level', 0)})"
        for row in fig.get("rows", []):
            if "head_frames_per_second" not in row:
                part = row.get("partial_ms_per_frame_by_streams") or {}
                if part:  # the batch timed, the run stopped after (time or memory): its numbers, marked partial
                    k = min(part, key=part.get)
                    rows.append([dev, f"{row['n']:,}", f"{part[k]:.1f} (partial)",
                                 f"{row['n'] * 1e3 / part[k]:,.0f}", k, "-", "-", "-", "-",
                                 f"{row['gpu_memory_per_head_mb']:.1f}" if "gpu_memory_per_head_mb" in row else "-"])
                else:
                    rows.append([dev, str(row["n"]), row.get("error", "not measured")[:60], *["-"] * 7])
                continue
            mem = row.get("gpu_memory_per_head_mb")
            newton = row.get("newton_vbd", {})
            rows.append([dev, f"{row['n']:,}", f"{row['ms_per_frame']:.1f}", hfs(row), str(row.get("streams", 1)),
                         hfs(row.get("naive")),
                         f"{row['speedup_over_naive']:.2f}x" if "speedup_over_naive" in row else "-",
                         hfs(row.get("one_model_tissue")),
                         hfs(newton) if "head_frames_per_second" in newton else ("skipped" if newton.get("skipped")
                                                                                or not newton else "error"),
                         f"{mem:.1f}" if mem is not None else "-"])
    if not rows:
        return "(no batch result committed yet: python -m benchmarks batch)"
    return _rows_md(["device (backend, level)", "N", "ms / frame", "head-frames / s", "streams", "naive loop", "batch / naive",
                     "one Model, tissue only", "Newton VBD", "GPU MB / head"], rows)


@table("batch_profile")
def batch_profile(r: Results) -> str:
    """Where a batched frame's time goes (``batch_profile_*.json`` of ``python -m benchmarks batch_profile``):
    per N the graph's frame, Newton iterations, the kernels' GPU time by the solver's jobs and the top kernels."""
    rows = []
    for name in r.glob("batch_profile_*"):
        doc = r.doc(name)
        for row in doc["figures"].get("rows", []):
            p = row.get("profile")
            if p is None:
                continue
            jobs = p["jobs"]

            def share(*labels):
                return f"{sum(jobs.get(k, {}).get('share', 0.0) for k in labels):.0%}"

            top = ", ".join(f"`{k['kernel']}` {k['ms_per_frame']:.1f}" for k in p["kernels"][:3])
            rows.append([doc["device"], f"{row['n']:,}", f"{row['tets']:,}", f"{row['ms_per_frame']:.1f}",
                         f"{row['head_frames_per_second']:,.0f}", f"{row.get('newton_iterations_per_frame', 0):.1f}",
                         f"{p['kernel_ms_per_frame']:.1f}", f"{p['launches_per_frame']:.0f}",
                         share("Hessian assembly"), share("conjugate gradients"),
                         share("energy and gradient", "line search"), top])
    if not rows:
        return "(no profile committed yet: python -m benchmarks batch_profile --device cuda)"
    rows.sort(key=lambda x: (x[0], int(x[1].replace(",", ""))))
    return _rows_md(["device", "N", "tets", "ms / frame (graph)", "head-frames / s", "Newton it. / frame",
                     "kernel ms / frame", "launches / frame", "Hessian assembly", "CG", "energy + line search",
                     "top kernels (ms / frame)"], rows)


@table("drive")
def drive(r: Results) -> str:
    """The inverse solve per head (``drive_cpu.json`` of ``python -m benchmarks drive``): the round trip
    (the recovered face against the true one, FDPs and whole skin, worst frame), both modes' speed and
    the robust case."""
    rows, notes = [], []
    for name in [n for n in ("drive_cpu", "drive_cuda") if n in r.glob("drive_*")]:
        doc = r.doc(name)
        dev = "CPU" if doc["device"] == "cpu" else doc["device"]
        load = doc["figures"].get("load_average_at_start")
        notes.append(f"{dev}: {doc['machine'].get('cores', '?')} cores, {doc['date'][:10]}, seed {doc['figures'].get('seed')}"
                     + (f", load average {load[0]:.1f} at the start" if load else ""))
        rows += _drive_rows(doc, dev)
    head = ["device", "head", "frames", "offline, 84 FDPs: FDP / skin RMS, worst frame [mm]", "offline, 30 FDPs [mm]",
            "real time, 84 / 30 FDPs: FDP RMS [mm]", "forward sim. frames/s", "offline frames/s (84 / 30)",
            "real-time frames/s (84 / 30)", "robust: FDP RMS [mm], largest jump [mm]"]
    return _rows_md(head, rows) + "\n" + "; ".join(notes) + ".\n"


def _drive_rows(doc: dict, dev: str) -> list:
    """The drive table's rows of one result (a head each)."""
    rows = []
    for h in doc["figures"]["heads"]:
        c = h["cases"]

        def cell(case, key, fmt="{:.2f}"):
            v = c.get(case, {}).get(key)
            return "-" if v is None else fmt.format(v)

        rob = c.get("robust_offline", {})
        rows.append([dev, head_tag(h["head"]) or h["head"], f"{h['frames']} ({h['seconds']:g} s)",
                     f"{cell('all84_offline', 'fdp_rms_mm_max')} / {cell('all84_offline', 'skin_rms_mm_max')}",
                     f"{cell('tracker30_offline', 'fdp_rms_mm_max')} / {cell('tracker30_offline', 'skin_rms_mm_max')}",
                     f"{cell('all84_realtime', 'fdp_rms_mm_max')} / {cell('tracker30_realtime', 'fdp_rms_mm_max')}",
                     f"{_fps(h['ground_truth_frames_per_second'])}",
                     f"{cell('all84_offline', 'frames_per_second', '{:.1f}')} / "
                     f"{cell('tracker30_offline', 'frames_per_second', '{:.1f}')}",
                     f"{cell('all84_realtime', 'frames_per_second', '{:.1f}')} / "
                     f"{cell('tracker30_realtime', 'frames_per_second', '{:.1f}')}",
                     "-" if not rob else f"{rob['fdp_rms_mm_max']:.2f}, jump {rob['max_jump_fdp_mm']:.2f}"
                     + (f", {rob['frames_with_fdp_jump_over_2mm']} frames > 2 mm"
                        if "frames_with_fdp_jump_over_2mm" in rob else "")
                     + (" (failed)" if rob.get("failed") else "")])
    return rows


@table("arkit_reach")
def arkit_reach(r: Results) -> str:
    """What reaches each of the 52 ARKit shapes and how closely (``arkit_basis.json`` of ``python -m benchmarks
    arkit_basis``): per head the converged static face at the shape's controls against the full ICT-FaceKit rig's
    target carried onto that head (FDP RMS over the head FDPs), with the shipped basis and with the full rig."""
    doc = r.doc("arkit_basis")
    heads = doc["figures"]["heads"]
    first = next(iter(heads.values()))
    header = ["ARKit shape", "reached by"]
    for h in heads:
        header.append(f"{head_tag(h) or h}: reach, shipped / full rig [mm]")
    header.append("why not reached")
    rows = []
    for name, row in first["shapes"].items():
        cells = [f"`{name}`", row["by"]]
        for h in heads.values():
            x = h["shapes"][name]

            def mm(key):
                v = x.get(key)
                return "-" if v is None else f"{v['rms']:.2f}"

            cells.append("-" if x["by"] == "not reached" or ("reach_shipped_mm" not in x and "reach_full_rig_mm" not in x)
                         else f"{mm('reach_shipped_mm')} / {mm('reach_full_rig_mm')}")
        cells.append(row["reason"] or "")
        rows.append(cells)
    return _rows_md(header, rows) + f"\n{machine_note(doc)}\n"


@table("arkit_smile")
def arkit_smile(r: Results) -> str:
    """The driving guide's smile through the shipped basis and the full rig (``arkit_basis.json``): each head FDP's
    distance from the full rig's blended targets over the 45 frames."""
    doc = r.doc("arkit_basis")
    rows = []
    for h, x in doc["figures"]["heads"].items():
        s = x["smile"]
        for src, label in (("shipped", "shipped basis"), ("full_rig", "full ICT-FaceKit rig")):
            e = s[src]["vs_full_rig_targets_mm"]
            rows.append([head_tag(h) or h, label, f"{e['rms']:.2f}", f"{e['max']:.2f} ({e['worst_fdp']})",
                         f"{s[src]['moved_mm']:.1f}",
                         f"{x['summary'][src]['median_rms']:.2f} / {x['summary'][src]['max_rms']:.2f}",
                         f"{x['summary']['target_diff_rms_max_mm']:.2f} / {x['summary']['target_diff_max_mm']:.2f}"
                         if src == "shipped" else "-"])
    header = ["head", "ARKit data", "guide's smile: RMS [mm]", "max [mm] (FDP)", "largest FDP motion [mm]",
              "solved shapes' reach, median / worst RMS [mm]", "shipped vs full-rig targets, worst RMS / max [mm]"]
    return _rows_md(header, rows) + f"\n{machine_note(doc)}\n"


def machine_note(doc: dict) -> str:
    """One line: where and when a result was measured."""
    m = doc.get("machine", {})
    return f"Measured {doc['date'][:10]} on {m.get('cores', '?')} CPU cores (shared with other jobs), level 0, refine {doc['figures'].get('refine')}."


@table("fleet")
def fleet(r: Results) -> str:
    """``facewarp batch run`` on the 2-core box (``fleet_cpu.json`` of ``python -m benchmarks fleet``): one scan
    after another, local processes and a local Ray, and what each task needs."""
    doc = r.doc("fleet_cpu")
    f = doc["figures"]
    rows = [[mode, f[key]["executor"], f"{f[key]['wall_s']:.1f}", f"{f[key]['done']} / {f[key]['failed']}",
             "1.00x" if key == "serial" else f"{f['serial']['wall_s'] / f[key]['wall_s']:.2f}x"]
            for mode, key in (("one after another", "serial"), ("local processes", "local"), ("local Ray", "ray"))]
    steps = "; ".join(f"{k} {v['cpu_seconds_median']:.2f} CPU s, {v['worker_peak_rss_mib_max']:.0f} MiB"
                      for k, v in f["per_step"].items())
    return (_rows_md(["mode", "executor", "wall [s]", "done / failed", "speed-up"], rows)
            + f"\n{f['scans']} scans ({f['broken_scans']} broken) through {', '.join(f['steps'])} "
            f"({f['smile_seconds']:g} s smile) on {doc['machine'].get('cores', '?')} cores, {doc['date'][:10]}: "
            f"Ray {f['ray_overhead_over_local']:.1%} over local processes ({f['ray_startup_s']:.1f} s of it "
            f"starting Ray). Per task (median CPU seconds, largest worker memory): {steps}. Load average "
            f"{min(f[k]['load_before'][0] for k in ('serial', 'local', 'ray')):.1f}-"
            f"{max(f[k]['load_after'][0] for k in ('serial', 'local', 'ray')):.1f} (the tasks got "
            + ", ".join(f"{f[k]['cpu_share_of_tasks']:.0%}" for k in ("serial", "local", "ray"))
            + " of a core: wall times and speed-ups above a load of 2 measure the box's other jobs).\n")


@table("soak")
def soak(r: Results) -> str:
    """The soak (``soak_cpu.json``, ``soak_cuda.json`` of ``python -m benchmarks soak``): random legal control
    streams switching every frame, every frame checked, per device."""
    rows, notes = [], []
    for name in [n for n in ("soak_cpu", "soak_cuda") if n in r.glob("soak_*")]:
        doc = r.doc(name)
        f = doc["figures"]
        heads = f["heads"]
        dev = "CPU" if doc["device"] == "cpu" else doc["device"]
        req = f["requested"]
        cpu = [h["frames_per_second_cpu"] for h in heads]
        rows.append([dev, f"{len(heads)} x {req['seconds']:g} s" + ("" if f.get("complete") else " (incomplete)"),
                     f"{f['frames']:,}", str(f["failures"]), str(f["nan_frames"]), str(f["inverted_frames"]),
                     f"{f['min_volume_ratio']:.3f}", f"{f['substepped_frames']:,}",
                     f"{max(h.get('max_substep_factor', 1) for h in heads)}",
                     _span(cpu), f"`{name}.json`"])
        notes.append(f"{dev}: {doc['machine'].get('cpu', '?')}, {doc['machine'].get('cores', '?')} cores"
                     + (f", {doc['machine']['gpu']}" if doc["machine"].get("gpu") else "")
                     + f", {doc['date'][:10]}, seed {f.get('seed')}, {sum(1 for h in heads if h['head'].startswith('ict'))}"
                     " ICT-adapted heads" + (f", {sum(1 for h in heads if h['head'].startswith('synthetic'))} synthetic"
                                             if any(h["head"].startswith("synthetic") for h in heads) else ""))
    if not rows:
        return "(no soak committed yet: python -m benchmarks soak)"
    return (_rows_md(["device", "heads x length", "frames", "failures", "NaN frames", "inverted frames",
                      "smallest V / V0", "sub-stepped frames", "largest substep factor",
                      "frames/s a head (process CPU)", "file"], rows) + "\n" + "; ".join(notes) + ".\n")


@table("switching")
def switching(r: Results) -> str:
    """The CPU solver on the soak's stream switching every frame (``switching_cpu.json`` of ``python -m
    benchmarks switching``): speed and distance to the converged frames of each solver setting."""
    doc = r.doc("switching_cpu")
    f = doc["figures"]
    acc = f.get("accuracy", {})

    def row(label, m, dist):
        pf = m["per_frame_mean"]
        return [label, f"{m['frames_per_second_cpu']:.2f}", f"{pf['iterations']:.1f}", f"{pf['factorizations']:.1f}",
                "-" if dist is None else f"{dist[0]:.2f} / {dist[1]:.2f}", str(m.get("retries", 0))]

    rows = [row("default (L-BFGS, tolerance 3e-5 m, 4 cosine updates)", f["default"],
                (acc["fdp_distance_to_converged_max_mm"], acc["fdp_distance_to_converged_median_mm"]) if acc else None)]
    for name, m in f.get("modes", {}).items():
        d = m.get("fdp_distance_to_converged_mm")
        kind, _, arg = name.partition(":")
        label = {"interactive": f"interactive, {arg} L-BFGS iterations a frame (`iterations={arg}`)",
                 "newton": "Newton, a factorisation per iteration" + (f", tolerance {arg} m, 2 cosine updates" if arg
                                                                       else "")}[kind]
        rows.append(row(label, m, None if d is None else (d["max"], d["median"])))
    conv = acc.get("converged_run")
    note = (f"{f['default']['frames']} frames of the stream (seed {f['seed']}) on the default head, level 0, "
            f"{doc['machine'].get('cores', '?')}-core {doc['machine'].get('cpu', 'CPU')}, {doc['date'][:10]}"
            + (f" (load average {doc['machine']['load_average_1_5_15_min'][0]:.1f} at the start)"
               if doc["machine"].get("load_average_1_5_15_min") else "") + "; the "
            f"distance is each frame's largest FDP distance to the frame converged to 1e-7 m over the first "
            f"{acc.get('frames', 0)} frames"
            + (f" (that run: {conv['frames_per_second_cpu']:.2f} frames/s, {conv['per_frame_mean']['iterations']:.0f}"
               " iterations a frame)" if conv else "") + ".")
    return _rows_md(["solver setting", "frames/s (process CPU)", "iterations / frame", "factorisations / frame",
                     "FDP distance to converged, max / median [mm]", "retried frames"], rows) + "\n" + note + "\n"


@table("live")
def live(r: Results) -> str:
    """``facewarp live`` fed a 60 fps Live Link Face stream (``live_cpu.json`` of ``python -m benchmarks live``):
    per solver setting the frames simulated and dropped, a frame's wall and process CPU time."""
    doc = r.doc("live_cpu")
    f = doc["figures"]
    rows = []
    for run in f["runs"]:
        mode, _, k = run["mode"].partition(":")
        label = "converged (the default)" if mode == "default" else f"`--iterations {k}`"
        wall, cpu = run["frame_cost_ms"]["frame"], run["frame_cpu_ms"]["frame"]
        rows.append([label, f"{run['simulated']} of {run['frames_in']} / {100 * run['dropped_fraction']:.1f} %",
                     f"{wall['median']:.1f} ms", f"{cpu['median']:.1f} / {cpu['p90']:.1f} ms",
                     f"{run['frame_cost_ms']['step']['median']:.1f} ms"])
    loads = [run["load_average_at_start"] for run in f["runs"] if run.get("load_average_at_start") is not None]
    note = (f"{f['seconds']:g} s of a {f['stream_fps']:g} fps stream per setting, {f['head']}"
            + (f" ({f['tets']} tets; ARKit table: {len(f['arkit_shapes_solved'])} shapes solved)"
               if "tets" in f else "")
            + ", "
            f"{doc['machine'].get('cores', '?')}-core {doc['machine'].get('cpu', 'CPU')}, {doc['date'][:10]}"
            + (f", load average {min(loads):.0f}-{max(loads):.0f} at the starts" if loads else "") + ".")
    return _rows_md(["solver setting", "frames simulated of those in / dropped", "wall time a frame, median",
                     "CPU time a frame, median / p90", "the solver's step (wall), median"], rows) + "\n" + note + "\n"


def render(name: str, results: Results | None = None) -> str:
    """The Markdown of table ``name``."""
    if name not in TABLES:
        raise KeyError(f"no README table named {name!r} (known: {', '.join(sorted(TABLES))})")
    return TABLES[name](results or Results())


def update(text: str, results: Results | None = None) -> str:
    """``text`` with every ``<!-- table:NAME -->`` ... ``<!-- /table:NAME -->`` body regenerated."""
    results = results or Results()
    opened = re.findall(r"<!-- table:([a-z0-9_]+) -->", text)
    closed = re.findall(r"<!-- /table:([a-z0-9_]+) -->", text)
    if sorted(opened) != sorted(closed):
        raise ValueError(f"README table markers do not pair up: opened {opened}, closed {closed}")
    return _MARK.sub(lambda m: f"<!-- table:{m.group(1)} -->\n\n{render(m.group(1), results)}\n"
                               f"<!-- /table:{m.group(1)} -->", text)


def stale(path: Path | None = None, results: Results | None = None) -> list[str]:
    """The tables of ``path`` (default: every page of :func:`documents`) whose text differs from what
    the results give."""
    if path is None:
        return [k for p in documents() for k in stale(p, results)]
    text = path.read_text()
    new = update(text, results)
    old_bodies = dict(_MARK.findall(text))
    new_bodies = dict(_MARK.findall(new))
    return [k for k in new_bodies if old_bodies.get(k) != new_bodies[k]]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks --tables", description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="only check: exit 1 naming the tables that are out of date")
    ap.add_argument("--readme", type=Path, default=None,
                    help="the file with the table markers (default: README.md and every docs page)")
    args = ap.parse_args(argv)
    pages = [args.readme] if args.readme else documents()
    bad_any = False
    for page in pages:
        names = re.findall(r"<!-- table:([a-z0-9_]+) -->", page.read_text())
        if not names:
            continue
        if args.check:
            bad = stale(page)
            if bad:
                bad_any = True
                print(f"{page}: out of date: {', '.join(bad)} (run python -m benchmarks --tables)", file=sys.stderr)
            else:
                print(f"{page}: {len(names)} tables up to date ({', '.join(names)})")
            continue
        page.write_text(update(page.read_text()))
        print(f"{page}: regenerated {', '.join(names)}")
    return 1 if bad_any else 0
