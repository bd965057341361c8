"""Adaptation on a REAL face scan with landmarks: distance to the scan, landmark error per landmark, pictures (issue 41).

Run: ``python -m benchmarks.adapt_real --rvcg DIR`` (``DIR``: a checkout of
github.com/zarquon42b/Rvcg, whose ``data/humface.rda`` holds a surface scan of a person's face,
10,381 vertices in mm, with 7 hand-placed landmarks; GPL >= 2, the licence of the package; the
``rdata`` package reads the R file), or ``--scan OBJ --landmarks FILE --units mm --name NAME
--licence TEXT`` for any other scan with landmarks.

The scan is a partial face (forehead to chin, ear to ear, ragged borders, no texture): the
default template's crown, neck and ears have no data and follow the smooth field. Each scan runs
through ``facewarp adapt scan.obj --landmarks lm.json --units mm`` in a fresh process (wall and CPU
seconds, pictures included), then:

- distance to the scan [mm]: every scan vertex to the adapted surface (scan -> head: the whole
  scan is covered by the head, so this is the fit), and every adapted vertex whose closest scan
  point is inside the scan (not on its border) to the scan (head -> scan); median, p95, max;
- landmark error per landmark [mm]: the template's FDP carried by the adaptation (the command's
  ``adapted_landmarks.json``) against the scan's landmark; with all landmarks given (a training
  error) and held out (adapted again without that landmark, through the library);
- pictures: the scan and the adapted head side by side from the same cameras (front, side), and
  the scan -> head distance on the scan.

Humface's landmarks have no names in the package; their order, read from their places (4 points
across the eyes at the same height, the most protruding point, 2 points at the mouth) is: right eye
outer and inner corner, left eye inner and outer corner, nose tip, right and left mouth corner
(the subject's sides; FDPs 3.12, 3.8, 3.11, 3.7, 9.3, 8.4, 8.3).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from benchmarks._common import limit_threads, threads_from_argv

THREADS = 1

if __name__ == "__main__":
    limit_threads(threads_from_argv(sys.argv[1:], THREADS))

import numpy as np  # noqa: E402

from benchmarks._common import RESULTS, load, machine_line, save  # noqa: E402

HUMFACE_FDPS = ("3.12", "3.8", "3.11", "3.7", "9.3", "8.4", "8.3")
"""FDP of each humface landmark, in the file's order (see the module docstring)."""

TARGETS = {"distance_median_mm": 0.5}


def rvcg_humface(rvcg: Path, folder: Path) -> dict:
    """humface from an Rvcg checkout -> ``folder/scan.obj`` (mm) and ``folder/landmarks.json`` (mm)."""
    try:
        import rdata
    except ImportError:
        raise SystemExit("adapt_real: reading Rvcg's humface.rda needs the rdata package (pip install rdata)") from None
    import warnings

    import facewarp as fw

    src = Path(rvcg) / "data" / "humface.rda"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "no constructor for mesh3d": its fields come as a dict
        conv = rdata.conversion.convert(rdata.parser.parse_file(src), default_encoding="utf8")
    m = conv["humface"]
    V = np.asarray(m["vb"], dtype=np.float64)[:3].T
    F = np.asarray(m["it"], dtype=np.int64).T - 1
    L = np.asarray(conv["humface.lm"], dtype=np.float64)
    folder.mkdir(parents=True, exist_ok=True)
    fw.geometry.save_obj(folder / "scan.obj", V * 1e-3, F, units="mm")
    (folder / "landmarks.json").write_text(json.dumps({k: p.tolist() for k, p in zip(HUMFACE_FDPS, L)}))
    return {"name": "humface", "source": "github.com/zarquon42b/Rvcg data/humface.rda (Stefan Schlager)",
            "licence": "GPL (>= 2), the Rvcg package's licence", "units": "mm",
            "scan": folder / "scan.obj", "landmarks": folder / "landmarks.json"}


def run_command(scan: dict, out: Path) -> dict:
    """``facewarp adapt`` in a fresh process; wall and CPU seconds, its report."""
    import resource
    import subprocess

    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "facewarp", "adapt", str(scan["scan"]), "--landmarks", str(scan["landmarks"]),
           "--units", scan["units"], "--out", str(out)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise SystemExit(f"facewarp adapt failed ({r.returncode}): {r.stderr.strip()[-400:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"seconds": wall, "cpu_seconds": cpu, "report": json.loads((out / "report.json").read_text())}


def _stats(d_mm: np.ndarray) -> dict:
    return {"median_mm": float(np.median(d_mm)), "p95_mm": float(np.percentile(d_mm, 95)), "max_mm": float(d_mm.max()),
            "rms_mm": float(np.sqrt(np.mean(d_mm**2))), "count": int(len(d_mm))}


def distances(scan_V, scan_F, head_V, head_F) -> tuple[dict, dict, np.ndarray]:
    """(scan -> head stats, head -> scan stats over vertices inside the scan, per-scan-vertex distance [mm])."""
    import facewarp as fw
    from facewarp.geometry import boundary_vertices

    d_sh = fw.geometry.MeshQuery(head_V, head_F).closest_point(scan_V).dist * 1e3
    cp = fw.geometry.MeshQuery(scan_V, scan_F).closest_point(head_V)
    border = np.zeros(len(scan_V), bool)
    border[boundary_vertices(scan_F, len(scan_V))] = True
    # inside: the closest scan point is not on a face touching the border, and within 10 mm
    on_border_face = border[scan_F].any(axis=1)
    inside = (cp.face >= 0) & ~on_border_face[np.maximum(cp.face, 0)] & (cp.dist < 0.01)
    return _stats(d_sh), _stats(cp.dist[inside] * 1e3), d_sh


def held_out(scan: dict, template) -> dict:
    """Landmark error [mm] of each landmark when it is left out of the adaptation (library call)."""
    import facewarp as fw
    from facewarp import adapt

    m = fw.load_mesh(scan["scan"], units=scan["units"])
    lm = fw.geometry.load_landmarks(scan["landmarks"], units=scan["units"])
    tl = {k: v for k, v in template.landmarks().items() if template.fdp[k][0] == "head"}
    sp = fw.geometry.closest_surface_points(template.vertices, template.faces, np.array([tl[k] for k in lm]))
    out = {}
    for i, k in enumerate(lm):
        rest = {j: v for j, v in lm.items() if j != k}
        if len(rest) < 4:
            continue
        res = adapt(template.vertices, template.faces, tl, m.vertices, m.faces, rest)
        P = sp.positions(res.vertices_scan_frame, template.faces)
        out[k] = float(np.linalg.norm(P[i] - lm[k]) * 1e3)
    return out


def pictures(path: Path, scan_V, scan_F, head_V, head_F, d_mm, title: str) -> None:
    """Scan | adapted head (same cameras, framed on the scan) and the scan -> head distance on the scan."""
    from facewarp.render import colormap
    from facewarp import render_mesh, save_png

    rows = []
    for view in ("front", "side"):
        kw = {"view": view, "width": 270, "height": 270, "frame_points": scan_V}
        rows.append(np.concatenate([render_mesh(scan_V, scan_F, **kw), render_mesh(head_V, head_F, **kw),
                                    render_mesh(scan_V, scan_F, vertex_colors=colormap(d_mm, 0.0, 2.0), **kw)], axis=1))
    save_png(path, np.concatenate(rows, axis=0), title=title, colorbar=(0.0, 2.0, "mm (right: scan -> head distance)"))


def write_markdown(doc: dict, path: Path) -> None:
    f = doc["figures"]
    lines = ["# Adaptation on real scans", "", f"Generated by `python -m benchmarks.adapt_real` ({len(f['scans'])} scan(s)).",
             "`facewarp adapt scan --landmarks lm.json --units mm` with the default template, in a fresh process; one CPU",
             "thread. Distances in mm: scan -> head is every scan vertex to the adapted surface; head -> scan every adapted",
             "vertex whose closest scan point is inside the scan (not at its border).", "",
             f"Target: distance to the scan median <= {TARGETS['distance_median_mm']} mm.", ""]
    for s in f["scans"]:
        a, b = s["scan_to_head"], s["head_to_scan"]
        lines += [f"## {s['name']}", "", f"Source: {s['source']}; licence: {s['licence']}. Scan: {s['scan_vertices']} vertices,"
                  f" {len(s['landmarks'])} landmarks.", "",
                  "| figure | median | p95 | max | RMS | count |", "|---|---|---|---|---|---|",
                  f"| scan -> head [mm] | {a['median_mm']:.3f} | {a['p95_mm']:.3f} | {a['max_mm']:.2f} | {a['rms_mm']:.3f} | {a['count']} |",
                  f"| head -> scan [mm] | {b['median_mm']:.3f} | {b['p95_mm']:.3f} | {b['max_mm']:.2f} | {b['rms_mm']:.3f} | {b['count']} |",
                  "", "| landmark (FDP) | error, all given [mm] | error, held out [mm] |", "|---|---|---|"]
        for k, e in s["landmark_error_mm"].items():
            ho = s["landmark_error_held_out_mm"].get(k)
            lines.append(f"| {k} | {e:.2f} | {'' if ho is None else f'{ho:.2f}'} |")
        lines += ["", f"`facewarp adapt`: {s['seconds']:.2f} s wall, {s['cpu_seconds']:.2f} s CPU (pictures included; "
                  "timings on a shared machine).", "", f"Picture: `{s['picture']}`", ""]
    lines += ["Verdict:", ""] + [f"- {k}: {v}" for k, v in f["verdict"].items()] + ["", machine_line(doc), ""]
    path.write_text("\n".join(lines))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rvcg", default=os.environ.get("FACEWARP_RVCG"), help="a checkout of github.com/zarquon42b/Rvcg")
    ap.add_argument("--scan", default=None)
    ap.add_argument("--landmarks", default=None)
    ap.add_argument("--units", default="mm")
    ap.add_argument("--name", default="scan")
    ap.add_argument("--licence", default="(not given)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args(argv)
    import tempfile

    import facewarp as fw

    scratch = Path(tempfile.mkdtemp(prefix="adapt_real_"))
    scans = []
    if args.rvcg:
        scans.append(rvcg_humface(Path(args.rvcg), scratch / "humface"))
    if args.scan:
        scans.append({"name": args.name, "source": str(args.scan), "licence": args.licence, "units": args.units,
                      "scan": Path(args.scan), "landmarks": Path(args.landmarks)})
    if not scans:
        print("adapt_real: skipped, no scan given (--rvcg DIR, or --scan OBJ --landmarks FILE)")
        return 0
    out = Path(args.out)
    (out / "adapt_real").mkdir(parents=True, exist_ok=True)
    template = fw.default_template(0)
    rows = []
    for s in scans:
        run = run_command(s, scratch / f"{s['name']}_out")
        m = fw.load_mesh(s["scan"], units=s["units"])
        head = fw.load_mesh(scratch / f"{s['name']}_out" / "adapted_scan_frame.obj", units=s["units"])
        a, b, d = distances(m.vertices, m.faces, head.vertices, head.faces)
        lm = fw.geometry.load_landmarks(s["landmarks"], units=s["units"])
        # adapted_landmarks.json is in the template frame: carry the FDPs on the scan-frame head instead
        tl = template.landmarks()
        sp = fw.geometry.closest_surface_points(template.vertices, template.faces, np.array([tl[k] for k in lm]))
        P = sp.positions(head.vertices, head.faces)
        err = {k: float(np.linalg.norm(p - lm[k]) * 1e3) for k, p in zip(lm, P)}
        pic = out / "adapt_real" / f"{s['name']}.png"
        pictures(pic, m.vertices, m.faces, head.vertices, head.faces, d,
                 f"{s['name']}: scan | adapted head | distance (median {a['median_mm']:.2f} mm)")
        row = {"name": s["name"], "source": s["source"], "licence": s["licence"], "scan_vertices": int(len(m.vertices)),
               "landmarks": list(lm), "scan_to_head": a, "head_to_scan": b, "landmark_error_mm": err,
               "landmark_error_held_out_mm": held_out(s, template), "seconds": run["seconds"],
               "cpu_seconds": run["cpu_seconds"], "picture": str(pic.relative_to(out)),
               "report_distance_to_scan_m": run["report"].get("distance_to_scan_m")}
        rows.append(row)
        print(f"{s['name']}: scan->head {a['median_mm']:.3f}/{a['p95_mm']:.3f} mm, head->scan {b['median_mm']:.3f}/"
              f"{b['p95_mm']:.3f} mm, landmarks {err}, held out {row['landmark_error_held_out_mm']}, {run['seconds']:.1f} s",
              flush=True)
    verdict = {f"{r['name']}: distance to the scan median (scan -> head)":
               f"{r['scan_to_head']['median_mm']:.3f} mm (target {TARGETS['distance_median_mm']}): "
               + ("met" if r["scan_to_head"]["median_mm"] <= TARGETS["distance_median_mm"] else "NOT met") for r in rows}
    path = save("adapt_real", {"targets": TARGETS, "scans": rows, "verdict": verdict}, folder=out)
    write_markdown(load(path), out / "adapt_real.md")
    import shutil

    shutil.rmtree(scratch, ignore_errors=True)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
