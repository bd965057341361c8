"""A driven ARKit take as an animation of the ARKit rig: how far the rig's clip lands from the simulated take.

A take of our own (``--seconds`` at 30 fps: sine bumps of a left and a right smile, the jaw, the
inner brows and a blink, overlapping; written as a Live Link Face CSV with ``fw.takes.save_livelink_csv``)
is driven on a build through its ARKit table (``facewarp drive BUILD --arkit take.csv --rig RIGDIR
--out DIR``, the CLI as a user runs it), with a ``facewarp rig --shapes arkit|both --out RIGDIR``
rig of the same build. The drive's report holds ``rig_take``: the distance of each skin vertex of
the rig's linear blend (the take's ARKit weights on the rig's shapes, the jaw joint at the blended
opening) from the simulated face of the same frame, p95 and largest over every frame's vertices,
and the worst frame's p95 [mm]. Results: benchmarks/results/rig_take.json.

    python -m benchmarks rig_take --build BUILD --rig RIGDIR
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import facewarp as fw
from benchmarks._common import save

BUMPS = (("mouthSmileLeft", 0.6, 1.0, 0.9), ("mouthSmileRight", 0.7, 1.0, 0.8), ("jawOpen", 1.1, 0.8, 0.6),
         ("browInnerUp", 0.9, 1.4, 0.7), ("eyeBlinkLeft", 1.5, 0.4, 1.0))
"""(ARKit name, centre [s], width [s], peak weight) of each curve of the take."""


def take(seconds: float, fps: float = 30.0) -> fw.takes.ArkitTrack:
    t = np.arange(int(round(seconds * fps))) / fps
    W = np.zeros((len(t), len(fw.ARKIT_NAMES)))
    for name, c, w, a in BUMPS:
        W[:, list(fw.ARKIT_NAMES).index(name)] = a * np.sin(np.pi * np.clip((t - c + w / 2) / w, 0, 1)) ** 2
    return fw.takes.ArkitTrack(fps, W, source="rig_take")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", required=True, type=Path)
    ap.add_argument("--rig", required=True, type=Path)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--name", default="rig_take")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "take.csv"
        fw.takes.save_livelink_csv(take(a.seconds), csv)
        out = Path(tmp) / "take"
        r = subprocess.run([sys.executable, "-m", "facewarp", "drive", str(a.build), "--arkit", str(csv), "--rig",
                            str(a.rig), "--out", str(out)], capture_output=True, text=True)
        if r.returncode:
            print(r.stderr[-2000:], file=sys.stderr)
            return 1
        rep = json.loads((out / "report.json").read_text())
        files = {p.name: p.stat().st_size for p in out.iterdir()}
    figures = {"build": str(a.build), "rig": str(a.rig), "take": {"seconds": a.seconds, "fps": 30.0,
                                                                   "curves": [list(b) for b in BUMPS]},
               "rig_take": rep["rig_take"], "drive_seconds": rep["seconds"],
               "fdp_error_mm": {k: rep["error_mm"][k] for k in ("rms", "max")}, "files_bytes": files}
    e = rep["rig_take"]["error_mm"]
    print(f"the take on the rig: p95 {e['p95']:.2f} mm, worst frame's p95 {e['worst_frame_p95']:.2f} mm, "
          f"max {e['max']:.2f} mm over {rep['rig_take']['frames']} frames")
    save(a.name, figures)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
