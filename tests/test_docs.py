"""The documentation site: it builds with warnings as errors, every public name has a docstring,
and the guides' code blocks run as a user would run them (in an empty folder, in order)."""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
GUIDES = sorted((DOCS / "guides").glob("*.md"))

pytest.importorskip("sphinx", reason="the docs extra is not installed (pip install -e '.[docs]')")
pytest.importorskip("myst_parser", reason="the docs extra is not installed (pip install -e '.[docs]')")


def _generated():
    spec = importlib.util.spec_from_file_location("fw_generated", DOCS / "_ext" / "fw_generated.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return env


def test_every_public_name_has_a_docstring():
    rows = _generated().public_names()
    assert len(rows) > 200, f"expected the public API, found {len(rows)} names"
    missing = [f"{m}.{n}" for m, n, _, _, doc in rows if not doc.strip()]
    assert not missing, f"public names without a docstring: {missing}"


def test_cli_reference_lists_every_command_and_option():
    from facewarp.cli import build_parser

    text = _generated().cli_markdown()
    help_text = build_parser().format_help()
    for cmd in ("adapt", "build", "simulate", "demo", "morph", "retarget"):
        assert f"## `facewarp {cmd}`" in text, cmd
        assert cmd in help_text
    assert "--landmarks" in text and "--device" in text


@pytest.mark.slow
def test_docs_build_with_warnings_as_errors(tmp_path):
    r = subprocess.run([sys.executable, "-m", "sphinx", "-W", "-q", "-b", "html", str(DOCS), str(tmp_path / "html")],
                       capture_output=True, text=True, env=_env(), cwd=ROOT, timeout=900)
    assert r.returncode == 0, f"sphinx-build failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    assert (tmp_path / "html" / "index.html").exists()
    assert (tmp_path / "html" / "_generated" / "api" / "facewarp.html").exists()


def _blocks(page: Path) -> list[tuple[str, str]]:
    return re.findall(r"^```(python|bash)\n(.*?)^```", page.read_text(), flags=re.S | re.M)


@pytest.mark.slow
@pytest.mark.parametrize("page", GUIDES, ids=[p.stem for p in GUIDES])
def test_guide_code_blocks_run(page, tmp_path):
    blocks = _blocks(page)
    assert blocks, f"{page.name} has no code blocks"
    for lang, code in blocks:
        if lang == "python":
            env = dict(_env(), MUJOCO_GL="egl")
            r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True,
                               text=True, timeout=600)
            if r.returncode != 0 and "mujoco.Renderer" in code and ("OpenGL" in r.stderr or "EGL" in r.stderr):
                continue  # no offscreen OpenGL here for MuJoCo's renderer (tests/test_readme_mujoco.py skips too)
            assert r.returncode == 0, f"{page.name}: python block failed:\n{code}\n{r.stderr[-3000:]}"
        else:
            for line in code.splitlines():
                line = line.split("  #")[0].strip()
                if not line.startswith("facewarp "):
                    continue
                args = []
                for a in shlex.split(line)[1:]:  # the shell's globbing, in the page's folder
                    args += sorted(str(p.relative_to(tmp_path)) for p in tmp_path.glob(a)) if "*" in a else [a]
                cmd = [sys.executable, "-m", "facewarp", *args]
                r = subprocess.run(cmd, cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=600)
                assert r.returncode == 0, f"{page.name}: `{line}` failed:\n{r.stderr[-3000:]}"
