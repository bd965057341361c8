"""The README's MuJoCo example runs as printed (issue 13): the default face coupled to its MJCF
head, stepped in a user loop with a changing head pose, printing FDP 2.1's path."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "docs" / "guides" / "robot.md"  # the README links to it
HEADING = "## The head in MuJoCo, the jaw and a moving head"


def test_readme_mujoco_example_runs(tmp_path):
    pytest.importorskip("mujoco")
    text = README.read_text(encoding="utf-8")
    assert HEADING in text
    section = text[text.index(HEADING):]
    section = section[: section.index("\n## ", 5)]
    code = re.search(r"^```python\n(.*?)^```", section, flags=re.S | re.M).group(1)
    assert "_src" not in code
    for call in ("fw.head_mjcf(", "fw.MujocoJaw(", "sim.set_head_pose(", "jaw.step()", 'sim.fdp("2.1")'):
        assert call in code
    script = tmp_path / "example.py"
    script.write_text(code)
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    lines = run.stdout.splitlines()
    rows = [ln.split("jaw") for ln in lines[lines.index("chin path [mm]:") + 1:]]
    chin = np.array([[float(v) for v in a.split()] for a, _ in rows])
    jaw = np.array([float(b.split()[0]) for _, b in rows])
    assert chin.shape == (12, 3)
    assert jaw[:8].max() > 0.2 and jaw[-1] < jaw[7]  # opens toward 0.25 rad, closes after
    assert np.ptp(chin[:, 0]) > 5.0  # the head turned: the chin swept sideways in the world


def test_readme_mujoco_skin_example_runs(tmp_path):
    """The second example: the skin inside MuJoCo, rendered offscreen after a smile."""
    pytest.importorskip("mujoco")
    text = README.read_text(encoding="utf-8")
    section = text[text.index(HEADING):]
    section = section[: section.index("\n## ", 5)]
    blocks = re.findall(r"^```python\n(.*?)^```", section, flags=re.S | re.M)
    code = blocks[1]
    assert "_src" not in code and "fw.MujocoSkin(" in code and "skin.update(renderer)" in code
    script = tmp_path / "example.py"
    script.write_text(code)
    env = dict(__import__("os").environ, MUJOCO_GL="egl")
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=tmp_path, timeout=600,
                         env=env)
    if run.returncode != 0 and ("OpenGL" in run.stderr or "EGL" in run.stderr):
        pytest.skip("no offscreen OpenGL (EGL) for MuJoCo's renderer")
    assert run.returncode == 0, run.stderr[-3000:]
    assert "skin update" in run.stdout
    from PIL import Image

    img = np.asarray(Image.open(tmp_path / "smile_in_mujoco.png"))
    assert img.std() > 10  # a picture of the face, not a blank frame
