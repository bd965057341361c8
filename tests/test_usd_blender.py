"""The USD files' camera and lights open right in Blender: a frame rendered with Blender's own
USD importer (``benchmarks/blender_render.py``) is lit by the key light and the fill dome, and
two Blender versions (4.2, whose importer ignores ``inputs:normalize``, and 5.x, which applies
UsdLux's rule that an unnormalized light's power scales with its angular size) render it equally
bright.

Blender is not a facewarp dependency: each Blender is a ``bpy`` install (``pip install --target
DIR bpy==4.2.0``) named in ``FACEWARP_BPY`` (``os.pathsep``-separated folders, each put on the
PYTHONPATH of one render; a folder ``np1`` beside them, holding NumPy 1.x for bpy's own modules,
is put first where present), or the ``bpy`` of this interpreter. Skipped when there is none.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "blender_render.py"


def _blenders() -> list[list[str]]:
    """PYTHONPATH entries of each Blender to try ([] for this interpreter's own bpy)."""
    out = []
    for d in filter(None, os.environ.get("FACEWARP_BPY", "").split(os.pathsep)):
        if (Path(d) / "bpy").is_dir():
            np1 = Path(d).parent / "np1"
            out.append(([str(np1)] if np1.is_dir() else []) + [d])
    if not out and importlib.util.find_spec("bpy") is not None:
        out.append([])
    return out


def _sphere(n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """A UV sphere of radius 0.1 m: V (k, 3), F (m, 3) counter-clockwise seen from outside."""
    th = np.linspace(0, np.pi, n + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, 2 * n, endpoint=False)
    V = [[0, 0.1, 0]] + [[0.1 * np.sin(t) * np.cos(p), 0.1 * np.cos(t), 0.1 * np.sin(t) * np.sin(p)]
                        for t in th for p in ph] + [[0, -0.1, 0]]
    m = 2 * n
    F = [[0, 1 + (j + 1) % m, 1 + j] for j in range(m)]
    for i in range(len(th) - 1):
        for j in range(m):
            a, b = 1 + i * m + j, 1 + i * m + (j + 1) % m
            F += [[a, b, b + m], [a, b + m, a + m]]
    last = len(V) - 1
    F += [[last, last - m + j, last - m + (j + 1) % m] for j in range(m)]
    return np.asarray(V, np.float64), np.asarray(F, np.int64)


def _render(paths: list[str], usd: Path, png: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(paths)}
    run = subprocess.run([sys.executable, str(SCRIPT), str(usd), "--png", str(png), "--json", str(png) + ".json",
                          "--size", "64", "--samples", "4", "--frame", "0"], env=env, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(Path(str(png) + ".json").read_text())


def test_blender_renders_the_scene_lit(tmp_path):
    blenders = _blenders()
    if not blenders:
        pytest.skip("no Blender: set FACEWARP_BPY to bpy install folders (pip install --target DIR bpy)")
    pytest.importorskip("pxr")
    import usd_export

    V, F = _sphere()
    usd = tmp_path / "ball.usda"
    cam = {"position": (0.0, 0.0, 0.6), "target": (0.0, 0.0, 0.0), "up": (0.0, 1.0, 0.0)}
    with usd_export.AnimationWriter(usd, fps=30, faces=F, rest_points=V, camera=cam, lights=True) as w:
        w.add_frame(0.0, V)
        w.add_frame(1 / 30, V * 1.01)
    results = [_render(p, usd, tmp_path / f"b{k}.png") for k, p in enumerate(blenders)]
    for r in results:
        assert r["camera"], r
        assert [light["type"] for light in r["lights"]] == ["SUN"], r
        assert r["world"] is not None and r["world"]["strength"] > 0 and min(r["world"]["color"]) > 0.5, r
        assert r["covered_px"] > 500, r
        assert 0.25 < r["mean_brightness"] < 0.97, r  # lit, not black, not blown out
    b = [r["mean_brightness"] for r in results]
    assert max(b) <= 1.2 * min(b), results  # Blender 4.2 and 5.x alike
