"""ARKit drive with no external data: per-shape reach and the driving guide's smile with the shipped ARKit basis vs the full ICT-FaceKit rig, on the default head and an ICT identity.

    python -m benchmarks arkit_basis --ict-dir FACEXMODEL [--heads default identity000] [--refine 3]

``--ict-dir`` is a folder with the ICT-FaceKit rig's ``generic_neutral_mesh.obj`` and all its
ARKit-named expression OBJs (the kit's ``FaceXModel``; default ``$FACEWARP_ICT_SHAPES``). Per head
(level 0; ``identityNNN`` is the default template adapted to that ICT identity and built, as the
other benchmarks make it) two ARKit tables are built with ``fw.arkit_table``: ``source="shipped"``
(the basis facewarp ships: the kit's expressions carried onto the default template, then onto the
head) and ``source="ict"`` (the kit's OBJs carried onto the head directly). Per shape:

- how it is reached (``table.reach()``: muscles, jaw, eyes, or not at all),
- ``target_diff_mm``: the shipped target vs the full rig's on this head (FDP RMS and max over the
  head FDPs): what shipping the basis on the template costs before any solve,
- ``reach_mm``: the converged static face at the shape's controls vs the full rig's target (FDP
  RMS over the head FDPs), for the shipped table and for the full rig's own table.

The guide's smile (``docs/guides/driving.md``: 45 frames at 30 fps, both smiles up to 1, jawOpen
up to 0.3, a head yaw) is driven through each table; its error is each head FDP's distance from
the full rig's blended targets (RMS and max over the frames), and from the table's own targets.
The tables are cached under ``$FACEWARP_BENCH_HEADS/arkit_basis`` (a rerun reuses them).
Writes benchmarks/results/arkit_basis.json (after each head).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from benchmarks._common import case_face, heads_dir, save

THREADS = 1


def guide_take():
    """The driving guide's Live Link example: 45 frames at 30 fps."""
    import facewarp as fw

    t = np.arange(45) / 30.0
    w = np.zeros((len(t), 52))
    w[:, fw.ARKIT_NAMES.index("mouthSmileLeft")] = 0.5 * (1 - np.cos(2 * np.pi * t / 1.5))
    w[:, fw.ARKIT_NAMES.index("mouthSmileRight")] = w[:, fw.ARKIT_NAMES.index("mouthSmileLeft")]
    w[:, fw.ARKIT_NAMES.index("jawOpen")] = 0.3 * np.sin(np.pi * t / 1.5)
    head = np.stack([0.1 * np.sin(2 * np.pi * t / 1.5), 0 * t, 0 * t], axis=1)
    return fw.takes.ArkitTrack(30.0, w, head, "driving guide smile")


def _rms(x, axis=None):
    return float(np.sqrt(np.mean(np.asarray(x) ** 2, axis=axis)))


def head_case(head: str, ict: Path, refine: int) -> dict:
    import facewarp as fw

    t0 = time.perf_counter()
    sim = fw.FaceSimulator(case_face(head, 0))
    head_s = time.perf_counter() - t0
    tables, seconds = {}, {}
    for source in ("shipped", "ict"):
        cache = heads_dir() / "arkit_basis" / head / source
        t1 = time.perf_counter()
        tables[source] = fw.arkit_table(sim, source=source, ict_dir=ict if source == "ict" else None, cache=cache,
                                        refine=refine, progress=lambda d, n, name, s=source: print(
                                            f"  {head} {s}: {d}/{n} {name} {time.perf_counter() - t1:.0f} s",
                                            flush=True))
        seconds[source] = round(time.perf_counter() - t1, 1)
        if tables[source].info.get("cache_note"):
            print("  " + tables[source].info["cache_note"], flush=True)
    ts, ti = tables["shipped"], tables["ict"]
    mm = 1e3
    shapes = {}
    rows_s, rows_i = ts.reach(), ti.reach()
    for i, name in enumerate(ts.names):
        row = {"by": rows_s[i]["by"], "reason": rows_s[i]["reason"] or None,
               "target_mm": rows_i[i]["target_mm"], "gaze_deg": rows_s[i]["gaze_deg"]}
        if np.isfinite(ti.target_rms_m[i]) and np.isfinite(ts.target_rms_m[i]):
            d = np.linalg.norm(ts.targets[i] - ti.targets[i], axis=1)
            row["target_diff_mm"] = {"rms": round(_rms(d) * mm, 3), "max": round(float(d.max()) * mm, 3)}
        for src, t in (("shipped", ts), ("full_rig", ti)):
            if t.solved[i] and np.isfinite(ti.target_rms_m[i]):
                e = np.linalg.norm(t.reached[i] - ti.targets[i], axis=1)
                row[f"reach_{src}_mm"] = {"rms": round(_rms(e) * mm, 3), "max": round(float(e.max()) * mm, 3)}
        shapes[name] = row
    # the guide's smile through each table
    track = guide_take()
    full_targets = ti.targets_for(track.weights)
    smile = {}
    for src, t in (("shipped", ts), ("full_rig", ti)):
        own = t.targets_for(track.weights)
        rec = fw.FrameRecorder()
        t2 = time.perf_counter()
        r = fw.drive(sim, track, table=t, sinks=[rec])
        wall = time.perf_counter() - t2
        frames = rec.frames
        ids = [str(k) for k in frames.fdp_ids]
        cols = [ids.index(k) for k in t.fdp_ids]
        R = np.asarray(r.head_poses)[:, :3, :3]
        sim_fdp = np.einsum("tji,tkj->tki", R, np.asarray(frames.fdp_points, np.float64)[:, cols])  # world -> head
        e_full = np.linalg.norm(sim_fdp - full_targets, axis=2)
        e_own = np.linalg.norm(sim_fdp - own, axis=2)
        smile[src] = {"vs_full_rig_targets_mm": {"rms": round(_rms(e_full) * mm, 3),
                                                 "max": round(float(e_full.max()) * mm, 3),
                                                 "worst_fdp": t.fdp_ids[int(np.argmax(e_full.max(axis=0)))]},
                      "vs_own_targets_mm": {"rms": round(_rms(e_own) * mm, 3), "max": round(float(e_own.max()) * mm, 3)},
                      "drive_reported_rms_mm_max_frame": round(float(np.max(r.rms)) * mm, 3),
                      "moved_mm": round(float(np.linalg.norm(sim_fdp - sim_fdp[:1], axis=2).max()) * mm, 2),
                      "warnings": list(r.warnings), "frames_per_second": round(len(track.weights) / wall, 1)}
        print(f"  {head} smile via {src}: {smile[src]}", flush=True)
    solved = [n for n, r in shapes.items() if "reach_shipped_mm" in r]
    summary = {src: {"median_rms": round(float(np.median([shapes[n][f"reach_{src}_mm"]["rms"] for n in solved
                                                           if f"reach_{src}_mm" in shapes[n]])), 3),
                     "max_rms": round(float(np.max([shapes[n][f"reach_{src}_mm"]["rms"] for n in solved
                                                    if f"reach_{src}_mm" in shapes[n]])), 3)}
               for src in ("shipped", "full_rig")}
    summary["target_diff_rms_max_mm"] = max(r["target_diff_mm"]["rms"] for r in shapes.values() if "target_diff_mm" in r)
    summary["target_diff_max_mm"] = max(r["target_diff_mm"]["max"] for r in shapes.values() if "target_diff_mm" in r)
    return {"head": head, "nodes": int(len(sim.fr.nodes)), "head_seconds": round(head_s, 1), "table_seconds": seconds,
            "statics": {s: t.info.get("statics") for s, t in tables.items()},
            "from_cache": {s: bool(t.info.get("from_cache")) for s, t in tables.items()},
            "by": {k: sorted(n for n, r in shapes.items() if r["by"] == k) for k in sorted({r["by"] for r in shapes.values()})},
            "summary": summary, "smile": smile, "shapes": shapes}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ict-dir", type=Path, default=os.environ.get("FACEWARP_ICT_SHAPES"),
                    help="the ICT-FaceKit FaceXModel folder (all expression OBJs)")
    ap.add_argument("--heads", nargs="+", default=["default", "identity000"])
    ap.add_argument("--refine", type=int, default=3)
    args = ap.parse_args(argv)
    if args.ict_dir is None or not (Path(args.ict_dir) / "eyeBlink_L.obj").is_file():
        raise SystemExit("--ict-dir: give the ICT-FaceKit FaceXModel folder (all 53 expression OBJs)")
    out = {"metric": "FDP distances over the head FDPs [mm], head frame; targets: the full ICT-FaceKit rig carried "
                     "onto the head directly", "level": 0, "refine": args.refine, "heads": {}}
    for head in args.heads:
        out["heads"][head] = head_case(head, Path(args.ict_dir), args.refine)
        save("arkit_basis", out)


if __name__ == "__main__":
    main()
