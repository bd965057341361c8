"""``facewarp demo`` timed as a new user runs it: cold (empty Warp kernel cache) and warm (issue 14).

Run: ``python -m benchmarks.demo [--device cpu|cuda] [--seconds S] [--quick] [--warm-runs 1]``

Each run is a fresh process, ``python -m facewarp --json [--device D] demo --out DIR``: the
first with ``WARP_CACHE_PATH`` pointing at an empty folder, so every Warp kernel is compiled
(what a fresh install pays once), then ``--warm-runs`` more with that cache filled. Measured per
run: wall and CPU time (user + system) of the child, and the demo's own report (seconds per
stage, simulation frames per second, adaptation errors, anatomy quality). Targets: under 4 min
cold and 2 min warm on the 2-core CPU box, under 30 s on a GPU, for the full 8 s sequence.
Results: ``benchmarks/results/demo_<device>.json`` (``demo_<device>_<S>s.json`` for another
length).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks._common import add_case_args, save


def run_demo(out: Path, cache: Path, *, device: str, seconds: float | None, quick: bool) -> dict:
    """One demo in a fresh process; its wall and CPU seconds and its report."""
    env = {k: v for k, v in os.environ.items() if k != "FACEWARP_VERBOSE"}
    env["WARP_CACHE_PATH"] = str(cache)
    argv = [sys.executable, "-m", "facewarp", "--json", "--device", device, "demo", "--out", str(out)]
    if seconds is not None:
        argv += ["--seconds", str(seconds)]
    if quick:
        argv.append("--quick")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(argv, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise SystemExit(f"demo failed ({r.returncode}): {r.stderr.strip()}")
    rep = json.loads(r.stdout)
    return {"wall_s": round(wall, 2), "cpu_s": round((after.ru_utime - before.ru_utime)
                                                     + (after.ru_stime - before.ru_stime), 2),
            "timings_s": rep["timings_s"], "simulation": rep["simulation"], "adaptation": rep["adaptation"],
            "anatomy": rep["anatomy"], "demo": rep["demo"]}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_case_args(ap, device="cpu")
    ap.add_argument("--seconds", type=float, help="sequence length [s] (default: the full 8 s sequence)")
    ap.add_argument("--quick", action="store_true", help="the demo's --quick smoke run")
    ap.add_argument("--warm-runs", type=int, default=1, help="runs with the filled kernel cache (default 1)")
    ap.add_argument("--keep", type=Path, help="keep the last run's output folder here")
    args = ap.parse_args(argv)
    runs = []
    with tempfile.TemporaryDirectory(prefix="facewarp_demo_bench_") as tmp:
        cache = Path(tmp) / "kernel_cache"
        cache.mkdir()
        for i in range(1 + args.warm_runs):
            out = args.keep if (args.keep is not None and i == args.warm_runs) else Path(tmp) / f"run{i}"
            r = run_demo(out, cache, device=args.device, seconds=args.seconds, quick=args.quick)
            r["kernel_cache"] = "cold" if i == 0 else "warm"
            runs.append(r)
            print(f"{r['kernel_cache']}: {r['wall_s']:.1f} s wall, {r['cpu_s']:.1f} s CPU; stages {r['timings_s']}; "
                  f"{r['simulation']['frames']} frames at {r['simulation']['frames_per_second']:.1f} frames/s",
                  file=sys.stderr)
    seconds = runs[0]["demo"]["seconds"]
    data = {
        "load_average": os.getloadavg() if hasattr(os, "getloadavg") else None,
        "command": f"facewarp --device {args.device} demo --out DIR" + (f" --seconds {args.seconds:g}" if args.seconds else "")
                   + (" --quick" if args.quick else ""),
        "sequence_seconds": seconds,
        "cold": runs[0],
        "warm": runs[1:],
        "targets_s": {"cpu_warm": 120, "cpu_cold": 240, "gpu": 30},
    }
    dev = args.device.split(":")[0]
    name = f"demo_{dev}" if args.seconds is None and not args.quick else f"demo_{dev}_{seconds:g}s"
    path = save(name, data, device=args.device)
    print(f"wrote {path}", file=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(main())
