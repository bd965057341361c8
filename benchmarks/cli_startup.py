"""Start-up of the ``facewarp`` command and its time to an input error (issue 9).

Run: ``python -m benchmarks.cli_startup [--repeat 2]``

Each command runs in a fresh process (``python -m facewarp ...``), ``--repeat`` times in a row:
the first run may pay for cold file caches and Python byte-compilation, the later ones show
the warm start a user sees. Measured: wall time and the CPU time (user + system) of the child
process. Commands: ``--help``, ``template info`` (level 0 and 1), and, when the ICT-FaceKit
data is present, ``adapt`` of ICT identity 000 (a 27k-vertex scan in cm) with four bad
landmark files derived from its 12 FDPs (docs/MPEG4_FDP.md): too few shared FDPs, coplanar
FDPs, one FDP 8 cm off the surface, landmarks in mm beside the scan in cm. Results:
``benchmarks/results/cli_startup.json`` with the machine and its load average (this is a
shared box: CPU time is the steadier figure).
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

import numpy as np

from benchmarks._common import save, shared_dir


def timed(argv: list[str]) -> dict:
    """Run ``python -m facewarp ARGV`` in a fresh process; wall and CPU seconds, exit code, stderr."""
    env = {k: v for k, v in os.environ.items() if k != "FACEWARP_VERBOSE"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "facewarp", *argv], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": round(wall, 3), "cpu_s": round(cpu, 3), "exit_code": r.returncode,
            "stderr": r.stderr.strip()[-300:]}


def ict_cases(d: Path, ict: Path) -> dict[str, Path]:
    """Landmark files with faults for ICT identity 000 as the scan (cm), made from its 12 FDPs at
    the ICT vertices of docs/MPEG4_FDP.md: too few, coplanar, one 8 cm off, or in mm."""
    from benchmarks._ict import ICT_FDP

    import facewarp

    V = facewarp.load_mesh(ict, units="cm").vertices * 100.0  # file numbers (cm)
    good = {k: V[i] for k, i in ICT_FDP.items()}
    z = float(np.mean([p[2] for p in good.values()]))
    cases = {
        "few FDPs": {k: good[k] for k in ("2.1", "3.7", "3.12")},
        "coplanar FDPs": {k: np.array([p[0], p[1], z]) for k, p in good.items()},
        "FDP 8 cm off the scan": {**good, "9.3": good["9.3"] + [0.0, 0.0, 8.0]},
        "landmarks in mm, scan in cm": {k: p * 10.0 for k, p in good.items()},
    }
    files = {}
    for i, (name, pts) in enumerate(cases.items()):
        files[name] = d / f"case{i}.json"
        files[name].write_text(json.dumps({k: np.asarray(p).tolist() for k, p in pts.items()}))
    return files


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=2, help="runs of each command in a row (default 2)")
    args = ap.parse_args(argv)
    rows = []

    def measure(name: str, argv: list[str], expect: int):
        runs = [timed(argv) for _ in range(args.repeat)]
        for r in runs:
            if r["exit_code"] != expect:
                raise SystemExit(f"{name}: exit code {r['exit_code']}, expected {expect}: {r['stderr']}")
        row = {"command": "facewarp " + " ".join(a if "/" not in a else Path(a).name for a in argv),
               "case": name, "runs": runs}
        if expect:
            row["error"] = runs[-1]["stderr"]
        rows.append(row)
        print(f"{name:<34} " + "  ".join(f"{r['wall_s']:6.2f} s wall {r['cpu_s']:6.2f} s CPU" for r in runs),
              flush=True)

    measure("--help", ["--help"], 0)
    measure("template info", ["template", "info"], 0)
    measure("template info --level 1", ["template", "info", "--level", "1"], 0)
    ict = shared_dir() / "data" / "ict-facekit" / "identity000.obj"
    if ict.is_file():
        with tempfile.TemporaryDirectory() as tmp:
            d = Path(tmp)
            files = ict_cases(d, ict)
            for name, lm in files.items():
                measure(f"adapt: {name}", ["adapt", str(ict), "--units", "cm", "--landmarks", str(lm),
                                           "--out", str(d / "o")], 2)
    else:
        print(f"no ICT-FaceKit data at {ict.parent}: adapt error timings skipped")
    result = {"load_average_1_5_15_min": list(os.getloadavg()), "repeat": args.repeat,
              "rows": rows}
    print(f"wrote {save('cli_startup', result)}")


if __name__ == "__main__":
    raise SystemExit(main())
