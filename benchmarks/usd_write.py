"""Speed, size and memory of the streaming USD animation writer (usd_export.AnimationWriter).

    python -m benchmarks.usd_write [--frames 300] [--long-frames 3000] [--formats usda usdc usdz]

Writes a synthetic head (an icosphere of 10,242 vertices and 20,480 triangles, 0.1 m radius,
breathing with a per-vertex phase, no two frames alike) with 4 rigid parts (eyes, teeth, tongue),
27 muscles of 16 samples with activations, for ``--frames`` frames at 30 fps to each format, and
the ``.usdc`` once
more for ``--long-frames`` frames (memory over a long take). Each case runs in a fresh
subprocess so that its memory numbers are its own. Reported per case:

* ``frames_per_second``: frames / (writer construction + every ``add_frame`` + ``close``),
  ``add_frame_per_second`` (without ``close``) and ``close_seconds``;
* ``bytes_per_frame``: final file size / frames;
* RSS growth per frame between just before the writer is made and just before ``close``:
  ``rss_anon_growth_kb_per_frame`` (process-owned memory, /proc/self/status RssAnon) and
  ``rss_growth_kb_per_frame`` (VmRSS, which also counts the clean, reclaimable file pages mapped
  from the written file); ``rss_anon_peak_growth_{first,second}_half_mb``: the largest RssAnon
  growth seen (every 8 frames) in each half of the take: equal halves mean memory is bounded
  (the writer's pending samples rise and fall with its ``flush_bytes``); ``peak_rss_mb`` (VmHWM);
  ``peak_rss_anon_growth_mb``: the child's largest RssAnon over the whole case (polled every 10 ms
  from this process, so it covers ``close()``: text export, usdz packaging) minus its RssAnon
  just before the writer was made;
* ``compliance_problems``: usd_export.validate_usd on the output (``--frames`` cases).

Saves benchmarks/results/usd_write.json with the machine description.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks._common import save

FPS = 30.0
MUSCLES, SAMPLES = 27, 16


def _mem_mb() -> dict:
    """VmRSS, RssAnon, RssFile and VmHWM of this process [MiB] (Linux /proc; psutil is not needed)."""
    out = {}
    with open("/proc/self/status") as f:
        for line in f:
            key, _, val = line.partition(":")
            if key in ("VmRSS", "RssAnon", "RssFile", "VmHWM"):
                out[key] = int(val.split()[0]) / 1024
    return out


def _rot_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])  # row-vector convention: p' = p @ R


def synthetic_head():
    """Rest geometry: head (V, F), 4 parts, muscle end points, per-vertex phases."""
    import trimesh

    head = trimesh.creation.icosphere(subdivisions=5, radius=0.1)
    eye = trimesh.creation.icosphere(subdivisions=3, radius=0.012)
    teeth = trimesh.creation.box((0.05, 0.01, 0.02))
    tongue = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
    parts = {"eye_L": (eye.vertices + [0.032, 0.03, 0.085], eye.faces),
             "eye_R": (eye.vertices + [-0.032, 0.03, 0.085], eye.faces),
             "teeth": (teeth.vertices + [0.0, -0.03, 0.08], teeth.faces),
             "tongue": (tongue.vertices * [1.0, 0.4, 1.5] + [0.0, -0.04, 0.05], tongue.faces)}
    rng = np.random.default_rng(0)
    ends = rng.normal(size=(MUSCLES, 2, 3))
    ends *= 0.09 / np.linalg.norm(ends, axis=2, keepdims=True)
    phase = rng.uniform(0, 2 * np.pi, len(head.vertices))
    return np.asarray(head.vertices), np.asarray(head.faces), parts, ends, phase


def _frame(k: int, V, parts, ends, phase):
    t = k / FPS
    # two incommensurate frequencies: no frame repeats (crate files store repeated arrays once)
    scale = 1.0 + 0.02 * np.sin(2 * np.pi * t + phase) + 0.01 * np.sin(2 * np.pi * np.sqrt(2) * t + 2 * phase)
    P = V * scale[:, None]
    transforms = {}
    for name, (Vp, _) in parts.items():
        M = np.eye(4)
        c = Vp.mean(axis=0)
        M[:3, :3] = _rot_y(0.3 * np.sin(2 * np.pi * 0.5 * t))
        M[3, :3] = c - c @ M[:3, :3]  # rotate about the part's centre
        transforms[name] = M
    a = 0.5 + 0.5 * np.sin(2 * np.pi * t + np.arange(MUSCLES))
    s = np.linspace(0, 1, SAMPLES)[None, :, None]
    C = ends[:, :1] + s * (ends[:, 1:] - ends[:, :1]) * (1.0 - 0.2 * a)[:, None, None]
    return P, transforms, C, a


def run_case(fmt: str, frames: int, folder: Path) -> dict:
    """One case in this process: write, time, measure; returns a result row."""
    import usd_export

    V, F, parts, ends, phase = synthetic_head()
    names = [f"muscle_{i:02d}" for i in range(MUSCLES)]
    kw = dict(fps=FPS, faces=F, rest_points=V, parts=parts, muscles=names, muscle_samples=SAMPLES)
    with usd_export.AnimationWriter(folder / f"warmup.{fmt}", **kw) as w:  # loads plugins, warms caches
        w.add_frame(0.0, V)
    path = folder / f"head.{fmt}"
    m0 = _mem_mb()
    t0 = time.perf_counter()
    w = usd_export.AnimationWriter(path, **kw)
    peak_anon = [0.0, 0.0]  # largest RssAnon growth [MiB] seen in the first and the second half of the frames
    t_gen = 0.0  # every frame is distinct (crate files deduplicate repeated values); making it is not timed
    for k in range(frames):
        tg = time.perf_counter()
        P, transforms, C, a = _frame(k, V, parts, ends, phase)
        t_gen += time.perf_counter() - tg
        w.add_frame(k / FPS, P, part_transforms=transforms, muscle_points=C, activations=a)
        del P, transforms, C, a
        if k % 8 == 7:  # sawtooth: pending samples grow until the writer flushes them (flush_bytes)
            half = 2 * k >= frames
            peak_anon[half] = max(peak_anon[half], _mem_mb()["RssAnon"] - m0["RssAnon"])
    t1 = time.perf_counter()
    t0 += t_gen
    m1 = _mem_mb()
    w.close()
    t2 = time.perf_counter()
    m2 = _mem_mb()
    size = path.stat().st_size
    row = {"format": fmt, "frames": frames, "vertex_count": len(V), "face_count": len(F), "parts": len(parts),
           "muscles": MUSCLES, "muscle_samples": SAMPLES,
           "seconds": t2 - t0, "frames_per_second": frames / (t2 - t0), "add_frame_per_second": frames / (t1 - t0),
           "close_seconds": t2 - t1, "file_bytes": size, "bytes_per_frame": size / frames,
           "rss_growth_kb_per_frame": (m1["VmRSS"] - m0["VmRSS"]) * 1024 / frames,
           "rss_anon_growth_kb_per_frame": (m1["RssAnon"] - m0["RssAnon"]) * 1024 / frames,
           "rss_anon_growth_mb": m1["RssAnon"] - m0["RssAnon"],
           "rss_anon_peak_growth_first_half_mb": peak_anon[0], "rss_anon_peak_growth_second_half_mb": peak_anon[1],
           "rss_anon_growth_after_close_mb": m2["RssAnon"] - m0["RssAnon"],
           "rss_file_growth_mb": m1["RssFile"] - m0["RssFile"], "peak_rss_mb": m2["VmHWM"],
           "rss_anon_start_mb": m0["RssAnon"]}
    return row


def _subprocess_case(fmt: str, frames: int, check: bool) -> dict:
    with tempfile.TemporaryDirectory(prefix="usd_write_") as d:
        cmd = [sys.executable, "-m", "benchmarks.usd_write", "--case", fmt, "--frames", str(frames), "--dir", d]
        with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
            proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True, cwd=Path(__file__).resolve().parents[1])
            peak = 0.0
            while proc.poll() is None:  # the child's RssAnon, close() included (a C++ call holds the GIL)
                peak = max(peak, _proc_rss_anon_mb(proc.pid))
                time.sleep(0.01)
            out.seek(0), err.seek(0)
            if proc.returncode != 0:
                raise RuntimeError(f"case {fmt} x {frames} failed:\n{err.read()}")
            row = json.loads(out.read().strip().splitlines()[-1])
        row["peak_rss_anon_mb"] = peak
        row["peak_rss_anon_growth_mb"] = peak - row.pop("rss_anon_start_mb")
        if check:  # here, not in the child: the checks read every sample and would swamp its memory peak
            import usd_export

            row["compliance_problems"] = usd_export.validate_usd(Path(d) / f"head.{fmt}")
        return row


def _proc_rss_anon_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("RssAnon:"):
                    return int(line.split()[1]) / 1024
    except OSError:  # the child just ended
        pass
    return 0.0


def _summary(r: dict) -> str:
    line = (f"{r['format']} x {r['frames']:5d} frames: {r['frames_per_second']:6.1f} frames/s (add_frame "
            f"{r['add_frame_per_second']:.1f}/s, close {r['close_seconds']:.2f} s), {r['bytes_per_frame'] / 1024:.1f} "
            f"KiB/frame; RSS +{r['rss_growth_kb_per_frame']:.1f} KiB/frame, "
            f"RssAnon +{r['rss_anon_growth_kb_per_frame']:.2f} KiB/frame, "
            f"RssAnon peak +{r['rss_anon_peak_growth_first_half_mb']:.0f}/"
            f"+{r['rss_anon_peak_growth_second_half_mb']:.0f} MiB in 1st/2nd half, +{r['peak_rss_anon_growth_mb']:.0f} "
            f"MiB incl. close; VmHWM {r['peak_rss_mb']:.0f} MiB")
    if "compliance_problems" in r:
        line += f"; compliance problems: {len(r['compliance_problems'])}"
    return line


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--long-frames", type=int, default=3000, help="frames of the long .usdc case (0: skip)")
    ap.add_argument("--formats", nargs="+", default=["usda", "usdc", "usdz"], choices=["usda", "usdc", "usdz"])
    ap.add_argument("--case", help=argparse.SUPPRESS)  # worker mode: one case, JSON row on stdout
    ap.add_argument("--dir", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.case:
        print(json.dumps(run_case(args.case, args.frames, Path(args.dir))))
        return
    rows = []
    cases = [(f, args.frames, True) for f in args.formats]
    if args.long_frames:
        cases.append(("usdc", args.long_frames, False))
    for fmt, frames, check in cases:
        row = _subprocess_case(fmt, frames, check)
        rows.append(row)
        print(_summary(row), flush=True)
    # the load average (in "machine") matters: other jobs on the machine slow the frames/s
    print("wrote", save("usd_write", {"fps": FPS, "cases": rows}))


if __name__ == "__main__":
    raise SystemExit(main())
