"""Whole outputs or none: staged outputs moved into place at the end, nothing left by a failed or
interrupted run (SIGINT -> exit 130, SIGTERM -> exit 143), a second run on one --out refused."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from facewarp.cli import main
from conftest import fresh_build


def _env():
    return {k: v for k, v in os.environ.items() if k != "FACEWARP_VERBOSE"}


def _leftovers(folder: Path) -> list[str]:
    """Staging folders and lock files left in ``folder``."""
    return sorted(p.name for p in folder.iterdir() if ".facewarp-" in p.name)


@pytest.fixture(scope="module")
def built(tmp_path_factory, default_build_dir):
    return fresh_build(tmp_path_factory, default_build_dir)


def _start(argv, cwd):
    return subprocess.Popen([sys.executable, "-m", "facewarp", *argv], cwd=cwd, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_staging(folder: Path, name: str, proc, timeout: float = 120.0) -> None:
    """Wait until the run ``proc`` staged ``name`` in ``folder`` (its work has begun)."""
    t0 = time.time()
    while time.time() - t0 < timeout:
        if any(p.name.startswith(f".{name}.facewarp-partial-") for p in folder.iterdir()):
            return
        if proc.poll() is not None:
            pytest.fail(f"the run ended before it staged its output: {proc.communicate()}")
        time.sleep(0.05)
    proc.kill()
    pytest.fail("the run never staged its output")


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("out_name", ["o", "o.usdc"])
def test_interrupted_run_leaves_nothing(built, tmp_path, sig, code, out_name):
    proc = _start(["simulate", str(built), "--expression", "smile", "--seconds", "60", "--jaw", "kinematic",
                   "--out", out_name] + (["--usd"] if out_name == "o" else []), tmp_path)
    _wait_for_staging(tmp_path, out_name, proc)
    time.sleep(1.5)  # inside the simulation (the Warp kernels are cached by the fixture's build)
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("the run did not stop within 60 s of the signal")
    assert proc.returncode == code, err
    assert "Traceback" not in err and err.strip().splitlines()[-1] == "facewarp: interrupted", err
    assert not (tmp_path / out_name).exists()
    assert _leftovers(tmp_path) == []


def test_second_run_on_one_out_is_refused(built, tmp_path, capsys):
    proc = _start(["simulate", str(built), "--expression", "smile", "--seconds", "60", "--jaw", "kinematic",
                   "--out", "o"], tmp_path)
    try:
        _wait_for_staging(tmp_path, "o", proc)
        code = main(["simulate", str(built), "--expression", "smile", "--seconds", "0.1", "--out",
                     str(tmp_path / "o")])
        out, err = capsys.readouterr()
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
        assert "another facewarp run is writing it" in err and str(tmp_path / "o") in err
    finally:
        proc.send_signal(signal.SIGTERM)
        _, first_err = proc.communicate(timeout=60)
    assert proc.returncode == 143, first_err
    assert not (tmp_path / "o").exists() and _leftovers(tmp_path) == []


def test_signal_inside_an_import_is_raised_after_it(tmp_path, monkeypatch):
    """A SIGTERM that lands while a module is imported: a compiled module's init (NumPy's
    ``import_array`` in SciPy's and others') turns any exception into ``ImportError: ... failed to
    import``, which made an interrupted run exit 1 (an internal error) instead of 143 when the
    signal came during the job's first imports (test_second_run_on_one_out_is_refused under load).
    The interrupt is raised once the import is over, as an Interrupted."""
    import importlib
    import threading

    outputs = importlib.import_module("facewarp." + "_src.core.outputs")  # spelled apart: a unit test of a part
    Interrupted, signals_as_exceptions = outputs.Interrupted, outputs.signals_as_exceptions

    (tmp_path / "fw_like_import_array.py").write_text(
        "import time\ntry:\n    time.sleep(0.6)\nexcept BaseException:\n"
        "    raise ImportError('numpy.core.multiarray failed to import')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with signals_as_exceptions():
        timer = threading.Timer(0.2, lambda: os.kill(os.getpid(), signal.SIGTERM))
        timer.start()
        with pytest.raises(Interrupted) as e:
            importlib.import_module("fw_like_import_array")
            time.sleep(5)  # the retry raises it here, right after the import
        timer.join()
    assert e.value.signum == signal.SIGTERM and "fw_like_import_array" in sys.modules
    sys.modules.pop("fw_like_import_array", None)


def test_failed_run_leaves_nothing_and_existing_output_is_kept(built, tmp_path, capsys):
    out = tmp_path / "deep" / "er" / "o"
    bad = tmp_path / "bad.json"
    bad.write_text('{"segments": [{"expression": "grin"}]}')
    code = main(["simulate", str(built), "--expression", str(bad), "--out", str(out)])
    _, err = capsys.readouterr()
    assert code == 2 and "grin" in err
    assert not (tmp_path / "deep").exists()  # the parents made for it are gone too
    old = tmp_path / "old"
    old.mkdir()
    (old / "keep.txt").write_text("mine")
    (old / "frames.npz").write_text("an older run")
    code = main(["simulate", str(built), "--expression", str(bad), "--out", str(old)])
    assert code == 2
    assert sorted(p.name for p in old.iterdir()) == ["frames.npz", "keep.txt"]
    assert (old / "frames.npz").read_text() == "an older run"
    assert _leftovers(tmp_path) == []


def test_finished_run_moves_outputs_into_place(built, tmp_path, capsys):
    old = tmp_path / "o"
    old.mkdir()
    (old / "keep.txt").write_text("mine")
    code = main(["--json", "simulate", str(built), "--expression", "smile", "--seconds", "0.1", "--jaw", "kinematic",
                 "--out", str(old)])
    out, err = capsys.readouterr()
    assert code == 0, err
    rep = json.loads(out)
    assert rep["files"] == [str(old / "frames.npz"), str(old / "frames.png")]  # the destination, not the stage
    assert sorted(p.name for p in old.iterdir()) == ["frames.npz", "frames.png", "keep.txt"]
    assert _leftovers(tmp_path) == []
    usd = tmp_path / "a.usda"
    code = main(["--json", "simulate", str(built), "--expression", "smile", "--seconds", "0.1", "--jaw", "kinematic",
                 "--out", str(usd)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert json.loads(out)["files"] == [str(usd)]
    assert usd.is_file() and ".facewarp-partial" not in usd.read_text()
    assert _leftovers(tmp_path) == []


def test_read_only_usd_output_is_named(built, tmp_path, capsys):
    if os.geteuid() == 0:
        pytest.skip("root writes read-only files")
    usd = tmp_path / "a.usdc"
    usd.write_bytes(b"old")
    usd.chmod(0o444)
    code = main(["simulate", str(built), "--expression", "smile", "--seconds", "0.1", "--out", str(usd)])
    _, err = capsys.readouterr()
    assert code == 2 and str(usd) in err and "read-only" in err and ".facewarp" not in err
    assert usd.read_bytes() == b"old"


def test_interrupted_demo_leaves_no_folders(tmp_path):
    """Ctrl-C while the demo writes scan/ and adapt/: none of its folders or files are left."""
    proc = _start(["demo", "--quick", "--out", "d"], tmp_path)
    _wait_for_staging(tmp_path, "d", proc)
    stage = next(p for p in tmp_path.iterdir() if p.name.startswith(".d.facewarp-partial-"))
    t0 = time.time()
    while not (stage / "scan").exists() and time.time() - t0 < 120 and proc.poll() is None:
        time.sleep(0.05)
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert not (tmp_path / "d").exists() and _leftovers(tmp_path) == []
