"""Time of the whole ``facewarp adapt`` command on one core, against ``nricp_amberg`` (issue 11).

Run: ``python -m benchmarks.adapt_cli_time [--repeat 3] [--seed S]``

One unseen case of ``benchmarks.adapt_unseen`` (a random ICT identity, any pose, ~60k
triangles, mm) is written as an OBJ with its 12 FDPs as JSON; the template is the ICT neutral
head (11,248 vertices) as ``--template-mesh`` with its FDPs. The command runs in a fresh
process pinned to one core (``taskset -c 0``, BLAS threads 1), from process start to files
written: first with an empty Warp kernel cache (``WARP_CACHE_PATH`` set to a new folder: the
cold run, kernels compiled), then ``--repeat`` times with the cache warm. Then
``trimesh.registration.nricp_amberg`` (default settings, the same 12 landmarks, 10 mm
threshold, template pre-aligned by facewarp's calibration) on the same case in the same run,
also in a fresh process pinned to one core. Wall and CPU seconds (user + system of the child)
are stored: on this shared box CPU time is the steadier figure. Results:
``benchmarks/results/adapt_cli_time.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks._common import add_case_args, save

NRICP = r"""
import sys, json, numpy as np, trimesh
from trimesh.registration import nricp_amberg
from facewarp.adaptation import calibrate
from facewarp import load_mesh
d = sys.argv[1]
t = load_mesh(d + "/template.obj", units="mm"); s = load_mesh(d + "/scan.obj", units="mm")
tl = {k: np.array(v) * 1e-3 for k, v in json.load(open(d + "/template_lm.json")).items()}
sl = {k: np.array(v) * 1e-3 for k, v in json.load(open(d + "/scan_lm.json")).items()}
idx = json.load(open(d + "/template_idx.json"))
T = calibrate(sl, tl).transform
Q = T.apply(s.vertices)
ids = list(idx)
out = nricp_amberg(trimesh.Trimesh(t.vertices * 1e3, t.faces, process=False), trimesh.Trimesh(Q * 1e3, s.faces, process=False),
                   source_landmarks=np.array([idx[k] for k in ids]), target_positions=T.apply(np.array([sl[k] for k in ids])) * 1e3,
                   distance_threshold=10.0)
np.save(d + "/nricp.npy", T.inverse().apply(np.asarray(out) * 1e-3))
"""


def timed(cmd: list[str], env: dict) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd[:4])}...: exit code {r.returncode}: {r.stderr.strip()[-500:]}")
    return {"wall_s": round(wall, 3), "cpu_s": round(cpu, 3)}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    add_case_args(ap, seed=None)
    args = ap.parse_args(argv)
    from benchmarks._ict import ICT_FDP, error_stats, ict_dir, load_model, make_case
    from facewarp import load_mesh
    from facewarp.geometry import save_obj

    if not (ict_dir() / "generic_neutral_mesh.obj").is_file():
        print("adapt_cli_time: skipped, no ICT-FaceKit data")
        return
    seed = int(args.seed) if args.seed is not None else int.from_bytes(os.urandom(4), "little")
    print(f"adapt_cli_time: seed {seed}", flush=True)
    model = load_model()
    case = make_case(model, seed)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    env.pop("FACEWARP_VERBOSE", None)
    pin = ["taskset", "-c", "0"] if shutil.which("taskset") else []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        save_obj(d / "scan.obj", case.scan_V_mm * 1e-3, case.scan_F, units="mm")
        save_obj(d / "template.obj", model.neutral, model.faces, units="mm")
        (d / "scan_lm.json").write_text(json.dumps({k: np.asarray(v).tolist() for k, v in case.landmarks_mm.items()}))
        (d / "template_lm.json").write_text(json.dumps({k: (model.neutral[i] * 1e3).tolist() for k, i in ICT_FDP.items()}))
        (d / "template_idx.json").write_text(json.dumps(ICT_FDP))
        cmd = [*pin, sys.executable, "-m", "facewarp", "adapt", str(d / "scan.obj"), "--units", "mm", "--landmarks",
               str(d / "scan_lm.json"), "--template-mesh", str(d / "template.obj"), "--template-landmarks",
               str(d / "template_lm.json"), "--template-units", "mm", "--out", str(d / "out")]
        cold = timed(cmd, {**env, "WARP_CACHE_PATH": str(d / "warp_cache")})
        print(f"cold (empty kernel cache): {cold['wall_s']:.2f} s wall, {cold['cpu_s']:.2f} s CPU", flush=True)
        warm = []
        for _ in range(args.repeat):
            warm.append(timed(cmd, env))
            print(f"warm: {warm[-1]['wall_s']:.2f} s wall, {warm[-1]['cpu_s']:.2f} s CPU", flush=True)
        V = load_mesh(d / "out" / "adapted_scan_frame.obj", units="mm").vertices
        st_f, _, _ = error_stats(V * 1e3, case, model.faces)
        (d / "nricp.py").write_text(NRICP)
        nr = timed([*pin, sys.executable, str(d / "nricp.py"), str(d)], env)
        print(f"nricp_amberg: {nr['wall_s']:.2f} s wall, {nr['cpu_s']:.2f} s CPU", flush=True)
        st_n, _, _ = error_stats(np.load(d / "nricp.npy") * 1e3, case, model.faces)
        report = json.loads((d / "out" / "report.json").read_text())
    best = min(warm, key=lambda r: r["wall_s"])
    result = {
        "load_average_1_5_15_min": list(os.getloadavg()), "seed": seed, "case": case.info(),
        "command": "facewarp adapt scan.obj --units mm --landmarks scan_lm.json --template-mesh template.obj "
                   "--template-landmarks template_lm.json --template-units mm --out out",
        "pinned_to_one_core": bool(pin), "cold": cold, "warm": warm, "warm_best": best, "nricp_amberg": nr,
        "speedup_wall": nr["wall_s"] / best["wall_s"], "speedup_cpu": nr["cpu_s"] / min(r["cpu_s"] for r in warm),
        "adapt_seconds_in_report": report["seconds"], "stages": [(r["kind"], r["seconds"]) for r in report["levels"]],
        "facewarp_E_v": st_f, "nricp_E_v": st_n,
        "targets": {"warm_wall_s": 3.0, "speedup": 5.0},
    }
    print(f"warm best {best['wall_s']:.2f} s wall / {best['cpu_s']:.2f} s CPU (target 3 s); nricp {nr['wall_s']:.2f} s: "
          f"{result['speedup_wall']:.1f}x (CPU {result['speedup_cpu']:.1f}x); E_v RMS {st_f['E_v_rms_mm']:.2f} vs {st_n['E_v_rms_mm']:.2f} mm")
    print(f"wrote {save('adapt_cli_time', result)}")


if __name__ == "__main__":
    raise SystemExit(main())
