"""The README's Python API example runs as printed (issue 9): public names only, a user loop
with changing activations and jaw, a reset, and the chin's (FDP 2.1) path."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "docs" / "python-api.md"  # the README links to it
HEADING = "# The Python API"


def readme_example(path: Path = README) -> str:
    """The first fenced ``python`` block after the heading ``# The Python API``."""
    text = path.read_text(encoding="utf-8")
    head = re.search(rf"^{re.escape(HEADING)}[ \t]*$", text, flags=re.M)
    assert head, f"{path.name} has no heading {HEADING!r}"
    section = text[head.end():]
    section = section[: m.start()] if (m := re.search(r"^## ", section, flags=re.M)) else section
    block = re.search(r"^```python\n(.*?)^```", section, flags=re.S | re.M)
    assert block, f"no ```python block under {HEADING!r} in {path.name}"
    return block.group(1)


def test_readme_example_runs(tmp_path):
    code = readme_example()
    assert "_src" not in code, "the example must use public names only"
    for call in ("fw.build_face(fw.default_template(0))", "fw.FaceSimulator(", "sim.set_activations(",
                 "sim.set_jaw(", "sim.step()", "sim.reset()", 'sim.fdp("2.1")'):
        assert call in code, f"the example no longer shows {call}"
    script = tmp_path / "example.py"
    script.write_text(code)
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    lines = run.stdout.splitlines()
    assert "chin path [mm]:" in lines, run.stdout
    rows = np.array([[float(v) for v in ln.split()] for ln in lines[lines.index("chin path [mm]:") + 1:]])
    frames = int(re.search(r"for k in range\(1, (\d+)\)", code).group(1))
    assert rows.shape == (frames + 1, 3), rows  # rest, one row per step, and one after the reset
    path, after_reset = rows[:-1], rows[-1]
    assert np.all(np.diff(path[:, 1]) < -0.5), f"the chin must move down as the jaw opens: {path[:, 1]}"
    assert path[0, 1] - path[-1, 1] > 3.0, path  # a few millimetres for 12 deg of opening
    np.testing.assert_allclose(after_reset, path[0], atol=1e-6, err_msg="reset goes back to rest")
