"""The scenes run as documented (``python -m scenes.<name> --device ... --out ...``), briefly."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]


def run_scene(name: str, *args) -> str:
    cmd = [sys.executable, "-m", f"scenes.{name}", "--device", "cpu", *map(str, args)]
    run = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    return run.stdout


def test_slab_muscle(tmp_path):
    out = tmp_path / "slab"
    run_scene("slab_muscle", "--seconds", 0.05, "--cells", 10, "--size", 64, "--out", out)
    assert {p.name for p in out.iterdir()} == {"slab_angle.png", "slab_activation.png", "slab.json"}
    cases = json.loads((out / "slab.json").read_text())["cases"]
    assert len(cases) == 8 and all(c["attached"] > 0 for c in cases)
    act = [c for c in cases if c["figure"] == "activation"]
    disp = [c["max_displacement_m"] for c in act]
    assert all(d > 1e-5 for d in disp), disp  # the muscle pulls the skin
    assert disp[-1] > disp[0], disp  # more at full activation than at a quarter
    # the angle limit of Fig. 6.4 attaches more nodes as it widens
    attached = [c["attached"] for c in cases if c["figure"] == "angle"]
    assert attached == sorted(attached) and attached[-1] > attached[0], attached


def test_template_preview(tmp_path):
    out = tmp_path / "views"
    run_scene("template_preview", "--num-frames", 2, "--size", 48, "--out", out)
    names = sorted(p.name for p in out.iterdir())
    assert names == ["turn_000.png", "turn_001.png"]
    front, back = (np.asarray(Image.open(out / n).convert("RGB"), dtype=float) for n in names)
    assert front.std() > 5 and back.std() > 5  # a head, not a blank picture
    assert np.abs(front - back).mean() > 1  # two different views
