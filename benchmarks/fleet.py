"""A fleet of scans: 16 synthetic scans through adapt + build + a 2 s smile, one after another vs local processes vs a local Ray.

    python -m benchmarks fleet [--scans 16] [--workers 2] [--seconds 2] [--levels 2] [--faces 8000]

Each mode is ``facewarp batch run`` in a fresh process on a fresh output folder: ``serial`` with
one worker process (every step of every scan one after another), ``local`` with ``--workers``
processes, ``ray`` on a local Ray of ``--workers`` CPUs (started by the command, its start-up
included). Two of the scans are deliberately broken (a file that is not a mesh, landmarks in mm
beside a scan in m) and fail in seconds without stopping the batch. Figures: the wall time of each
mode [s], the speed-up of ``local`` and ``ray`` over ``serial``, Ray's overhead over local
processes (and the start-up of a bare local Ray, where most of it goes), per step the seconds of a
task (median, max over the good scans, from the serial run where nothing competes inside the batch)
and the peak resident memory of a worker process [MiB], and the load average of the machine before
and after each mode (a shared box: the load says how much the timings can be trusted). Result:
``benchmarks/results/fleet_cpu.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks._common import save

STEPS = ("adapt", "build", "simulate")


def make_scans(folder: Path, count: int, faces: int) -> list[Path]:
    """``count`` scans in ``folder``: synthetic scans of seeds 0.. with their landmarks, the last two broken."""
    import facewarp as fw

    paths = []
    for seed in range(count - 2):
        s = fw.synthetic_scan(seed, faces=faces)
        fw.geometry.save_obj(folder / f"scan{seed:02d}.obj", s.vertices, s.faces)
        fw.geometry.save_landmarks_json(folder / f"scan{seed:02d}_landmarks.json", s.landmarks)
        paths.append(folder / f"scan{seed:02d}.obj")
    (folder / "broken_not_a_mesh.obj").write_text("this is not a mesh\n")
    paths.append(folder / "broken_not_a_mesh.obj")
    s = fw.synthetic_scan(count, faces=faces)  # the landmarks in mm, the scan in m: refused by adapt's unit check
    fw.geometry.save_obj(folder / "broken_units.obj", s.vertices, s.faces)
    fw.geometry.save_landmarks_json(folder / "broken_units_landmarks.json", s.landmarks, units="mm")  # read as m
    paths.append(folder / "broken_units.obj")
    return paths


def run_mode(scans: list[Path], out: Path, extra: list[str], args) -> dict:
    """``facewarp --json batch run`` in a fresh process; its summary, wall time and the load around it."""
    cmd = [sys.executable, "-m", "facewarp", "--json", "batch", "run", *map(str, scans), "--out", str(out),
           "--steps", "adapt,build,simulate", "--expression", "smile", "--seconds", str(args.seconds),
           "--levels", str(args.levels), *extra]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    load_before = [round(v, 2) for v in os.getloadavg()]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if r.returncode not in (0, 1) or not r.stdout.strip():
        raise SystemExit(f"fleet: {' '.join(cmd[2:])} failed ({r.returncode}): {r.stderr.strip()[-2000:]}")
    rep = json.loads(r.stdout)
    if r.returncode != rep["exit_code"] or (r.returncode == 1) != bool(rep["failed"] or rep["incomplete"]):
        raise SystemExit(f"fleet: exit code {r.returncode} for {rep['done']} done, {rep['failed']} failed")
    manifest = json.loads((out / "manifest.json").read_text())
    return {"wall_s": round(wall, 2), "batch_s": rep["seconds"], "done": rep["done"], "failed": rep["failed"],
            "executor": rep["executor"], "load_before": load_before,
            "load_after": [round(v, 2) for v in os.getloadavg()], "manifest": manifest}


def per_step(manifest: dict) -> dict:
    """Per step over the done tasks: seconds (median, max, sum) and the worker's peak memory [MiB]."""
    out = {}
    for step in STEPS:
        recs = [e["steps"][step] for e in manifest["scans"].values()
                if e["steps"].get(step, {}).get("status") == "done"]
        secs = [r["seconds"] for r in recs]
        cpu = [r["cpu_seconds"] for r in recs if r.get("cpu_seconds") is not None]
        rss = [r["worker"]["peak_rss_mib"] for r in recs if r.get("worker") and r["worker"].get("peak_rss_mib")]
        out[step] = {"tasks": len(recs), "seconds_median": round(statistics.median(secs), 2) if secs else None,
                     "seconds_max": round(max(secs), 2) if secs else None, "seconds_sum": round(sum(secs), 2),
                     "cpu_seconds_median": round(statistics.median(cpu), 2) if cpu else None,
                     "cpu_seconds_sum": round(sum(cpu), 2),
                     "worker_peak_rss_mib_max": max(rss) if rss else None}
    return out


def ray_startup_s(workers: int) -> float | None:
    """Seconds to start and stop a bare local Ray of ``workers`` CPUs in a fresh process (None without Ray)."""
    code = ("import time; t = time.perf_counter(); import ray; "
            f"ray.init(num_cpus={workers}, include_dashboard=False, log_to_driver=False); "
            "ray.get(ray.remote(lambda: 1).remote()); print(time.perf_counter() - t); ray.shutdown()")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    return round(float(r.stdout.strip().splitlines()[-1]), 2) if r.returncode == 0 else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scans", type=int, default=16, help="scans in the batch, two of them broken (default 16)")
    ap.add_argument("--workers", type=int, default=2, help="local processes and local Ray CPUs (default 2)")
    ap.add_argument("--seconds", type=float, default=2.0, help="length of the smile [s] (default 2)")
    ap.add_argument("--levels", type=int, default=2, help="adapt's refinement levels (default 2)")
    ap.add_argument("--faces", type=int, default=8000, help="triangles per synthetic scan (default 8000)")
    ap.add_argument("--modes", nargs="+", default=["serial", "local", "ray"], choices=["serial", "local", "ray"])
    args = ap.parse_args(argv)
    if args.scans < 3:
        ap.error("--scans: at least 3 (two are broken)")
    with tempfile.TemporaryDirectory(prefix="facewarp_fleet_") as tmp:
        tmp = Path(tmp)
        (tmp / "in").mkdir()
        t0 = time.perf_counter()
        scans = make_scans(tmp / "in", args.scans, args.faces)
        print(f"made {len(scans)} scans in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        modes = {"serial": ["--workers", "1"], "local": ["--workers", str(args.workers)],
                 "ray": ["--ray", "--workers", str(args.workers)]}
        runs = {}
        for mode in args.modes:
            runs[mode] = run_mode(scans, tmp / mode, modes[mode], args)
            print(f"{mode}: {runs[mode]['wall_s']:.1f} s, {runs[mode]['done']} done, {runs[mode]['failed']} failed, "
                  f"load {runs[mode]['load_before']} -> {runs[mode]['load_after']}", file=sys.stderr)
    try:  # 1: the cores are shared per session, so a busy box gives one batch's local workers one share
        autogroup = int(Path("/proc/sys/kernel/sched_autogroup_enabled").read_text())
    except (OSError, ValueError):
        autogroup = None
    figures = {"scheduler_autogroup": autogroup, "scans": args.scans, "broken_scans": 2, "workers": args.workers,
               "smile_seconds": args.seconds,
               "adapt_levels": args.levels, "scan_faces": args.faces, "steps": list(STEPS)}
    for mode, r in runs.items():
        figures[mode] = {k: v for k, v in r.items() if k != "manifest"}
    if "serial" in runs:
        figures["per_step"] = per_step(runs["serial"]["manifest"])
        for mode in ("local", "ray"):
            if mode in runs:
                figures[f"speedup_{mode}_over_serial"] = round(runs["serial"]["wall_s"] / runs[mode]["wall_s"], 3)
    if "local" in runs and "ray" in runs:
        figures["ray_overhead_over_local"] = round(runs["ray"]["wall_s"] / runs["local"]["wall_s"] - 1.0, 4)
        figures["ray_startup_s"] = ray_startup_s(args.workers)
    for mode, r in runs.items():
        steps = per_step(r["manifest"])
        figures.setdefault("per_step_" + mode, steps)
        busy = sum(s["seconds_sum"] for s in steps.values())
        cpu = sum(s["cpu_seconds_sum"] for s in steps.values())
        # CPU the workers got per second of task: 1.0 on an idle machine; below it when other
        # processes take the cores (then more workers cannot shorten the wall time)
        figures[mode].update(task_seconds_sum=round(busy, 2), task_cpu_seconds_sum=round(cpu, 2),
                             cpu_share_of_tasks=round(cpu / busy, 3) if busy else None)
    print(json.dumps({k: v for k, v in figures.items() if not k.startswith("per_step_")}, indent=1), file=sys.stderr)
    print("wrote", save("fleet_cpu", figures, device="cpu"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
