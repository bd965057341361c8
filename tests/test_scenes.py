"""The scenes run as documented (``python -m scenes.<name> --device ... --out ...``), briefly."""

from __future__ import annotations

import pytest
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


@pytest.mark.slow
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


def test_jaw_scene(tmp_path):
    out = tmp_path / "jaw"
    run_scene("jaw", "--seconds", 0.5, "--size", 64, "--out", out)
    assert {p.name for p in out.iterdir()} == {"jaw.png", "jaw.json"}
    log = json.loads((out / "jaw.json").read_text())["frames"]
    assert len(log) == 15
    peak = max(r["angle_rad"] for r in log)
    assert 0.15 < peak < 0.32  # opening toward the 0.3 rad target, no overshoot
    assert min(r["skin_torque_Nm"] for r in log) < 0  # the skin pulls the jaw closed
    assert log[-1]["angle_rad"] < peak  # closing again in the second half


def test_robot_head_scene(tmp_path):
    out = tmp_path / "robot"
    run_scene("robot_head", "--seconds", 0.5, "--size", 64, "--out", out)
    log = json.loads((out / "robot_head.json").read_text())["frames"]
    assert len(log) == 15
    pan = [r["neck_pan"] for r in log]
    assert max(abs(p) for p in pan) > 0.05  # the neck turned
    world = np.array([r["chin_world_m"] for r in log])
    head = np.array([r["chin_head_m"] for r in log])
    assert np.ptp(world[:, 0]) > 5 * max(np.ptp(head[:, 0]), 1e-4)  # rides the neck, not dragged


def _offscreen_gl() -> bool:
    """Whether MuJoCo's offscreen renderer works here (EGL, as the scene uses headless)."""
    code = "import mujoco; mujoco.Renderer(mujoco.MjModel.from_xml_string('<mujoco/>'), 8, 8)"
    env = {**__import__("os").environ, "MUJOCO_GL": "egl"}
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, timeout=120).returncode == 0


def test_robot_scene(tmp_path):
    import pytest

    pytest.importorskip("mujoco")
    if not _offscreen_gl():
        pytest.skip("no offscreen OpenGL (EGL) for MuJoCo's renderer")
    out = tmp_path / "robot"
    run_scene("robot", "--frames", 22, "--size", 64, "--out", out)  # the smile peaks at frame 21
    assert {p.name for p in out.iterdir()} == {"robot.png", "robot_wide.png", "robot.json", "robot_head.xml"}
    rep = json.loads((out / "robot.json").read_text())
    log = rep["frames"]
    assert len(log) == 22
    smile = dict(rep["peaks"])["smile"]
    assert log[smile - 1]["mouth_width_change_mm"] > 2.0  # the smile widens the mouth
    assert max(abs(r["neck_pan"]) for r in log) > 0.05  # the neck turned
    import mujoco

    m = mujoco.MjModel.from_xml_path(str(out / "robot_head.xml"))  # the viewer's file loads
    assert {"head/mandible", "head/cranium", "torso"} <= {m.body(i).name for i in range(m.nbody)}
    img = np.asarray(Image.open(out / "robot.png"))
    assert img.std() > 10
