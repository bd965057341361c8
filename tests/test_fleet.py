"""`facewarp batch run`: a fleet of scans in local processes and on a local Ray of 2 workers.

Tiny synthetic scans (4,000 triangles), one refinement level, adapt + build (simulate for one scan,
0.1 s): a broken scan in the batch, a re-run that skips finished work (a renamed copy is known by
its content), --retry-failed, a killed worker retried then failed, Ctrl-C semantics of the manifest.
"""

from __future__ import annotations

import csv
import json
import shutil

import pytest

import facewarp as fw
from facewarp.cli import main

KILL_ENV = "FACEWARP_FLEET_TEST_KILL"  # the worker running NAME:STEP kills itself (SIGKILL)


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    d = tmp_path_factory.mktemp("scans")
    for i in (1, 2):
        s = fw.synthetic_scan(i, faces=4000)
        fw.save_obj(d / f"good{i}.obj", s.vertices, s.faces)
        fw.save_landmarks_json(d / f"good{i}_landmarks.json", s.landmarks)
    (d / "broken.obj").write_text("this is not a mesh\n")
    return d


def _run(capsys, *argv):
    code = main(["--json", "batch", "run", *map(str, argv)])
    o, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(o)


def _manifest(out):
    m = json.loads((out / "manifest.json").read_text())
    return {e["name"]: e for e in m["scans"].values()}


@pytest.fixture(scope="module")
def first(scans, tmp_path_factory):
    """adapt + build of two good scans and a broken one in 2 local processes."""
    out = tmp_path_factory.mktemp("batch") / "out"
    code = main(["batch", "run", str(scans / "good1.obj"), str(scans / "broken.obj"), str(scans / "good2.obj"),
                 "--out", str(out), "--steps", "adapt,build", "--levels", "1", "--workers", "2"])
    assert code == 0
    return out


def test_broken_scan_does_not_sink_the_batch(first, scans):
    m = _manifest(first)
    assert set(m) == {"good1", "good2", "broken"}
    for name in ("good1", "good2"):
        e = m[name]
        assert [e["steps"][s]["status"] for s in ("adapt", "build")] == ["done", "done"]
        assert e["inputs"]["scan"]["size"] == (scans / f"{name}.obj").stat().st_size
        assert len(e["inputs"]["scan"]["sha256"]) == 64 and e["inputs"]["landmarks"]["path"].endswith("_landmarks.json")
        for s in ("adapt", "build"):
            r = e["steps"][s]
            assert r["seconds"] > 0 and r["worker"]["pid"] > 0 and r["worker"]["host"] and r["attempts"] == 1
            assert all((first / f).is_file() for f in r["outputs"])
        assert (first / e["folder"] / "adapt" / "adapted.obj").is_file()
        assert (first / e["folder"] / "build" / "face_rig.npz").is_file()
        assert not list((first / e["folder"]).glob(".*.partial"))
    b = m["broken"]["steps"]
    assert b["adapt"]["status"] == "failed" and "broken.obj" in b["adapt"]["error"] and "\n" not in b["adapt"]["error"]
    assert b["build"] == {"status": "skipped", "params": {"layers": 1}, "error": "adapt failed"}
    rep = json.loads((first / "report.json").read_text())
    assert rep["totals"] == {"scans": 3, "done": 2, "failed": 1, "incomplete": 0}
    rows = {r["name"]: r for r in rep["scans"]}
    assert rows["good1"]["status"] == "done" and rows["good1"]["tet_count"] > 1000
    assert rows["good1"]["inverted_count"] == 0 and rows["good1"]["distance_median_mm"] < 2.0
    assert rows["broken"]["failed_step"] == "adapt"
    with open(first / "report.csv") as f:
        table = list(csv.DictReader(f))
    assert [r["name"] for r in table] == ["good1", "broken", "good2"] and table[1]["status"] == "failed"


def test_rerun_skips_done_work_and_knows_a_renamed_copy(first, scans, tmp_path, capsys):
    copy = tmp_path / "renamed.obj"  # the same bytes under another name
    shutil.copy(scans / "good1.obj", copy)
    shutil.copy(scans / "good1_landmarks.json", tmp_path / "renamed_landmarks.json")
    before = (first / "manifest.json").read_text()
    rep = _run(capsys, copy, scans / "broken.obj", "--out", first, "--steps", "adapt,build", "--levels", "1")
    assert rep["tasks_run"] == 0 and rep["tasks_kept"] == 2 and rep["tasks_failed_kept"] == 1
    m = _manifest(first)
    assert len(m) == 3 and str(copy) in m["good1"]["paths"]
    assert m["good1"]["steps"] == json.loads(before)["scans"][_key(first, "good1")]["steps"]
    # simulate added on top of the kept adapt and build, for that scan only
    rep = _run(capsys, copy, "--out", first, "--steps", "adapt,build,simulate", "--levels", "1", "--seconds", "0.1",
               "--workers", "1")
    assert rep["tasks_run"] == 1 and rep["tasks_kept"] == 2 and rep["done"] == 1
    sim = _manifest(first)["good1"]["steps"]["simulate"]
    assert sim["status"] == "done" and sim["params"]["seconds"] == 0.1 and sim["summary"]["frames"] == 4
    assert any(f.endswith("frames.npz") for f in sim["outputs"])
    row = rep["rows"][0]
    assert row["frames_per_second"] > 0 and row["simulate_s"] > 0


def _key(out, name):
    return next(k for k, e in json.loads((out / "manifest.json").read_text())["scans"].items() if e["name"] == name)


def test_retry_failed(first, scans, capsys):
    rep = _run(capsys, scans / "broken.obj", "--out", first, "--steps", "adapt,build", "--levels", "1")
    assert rep["tasks_run"] == 0 and rep["failed"] == 1  # failed stays failed without --retry-failed
    pid = _manifest(first)["broken"]["steps"]["adapt"]["worker"]["pid"]
    rep = _run(capsys, scans / "broken.obj", "--out", first, "--steps", "adapt,build", "--levels", "1",
               "--retry-failed", "--workers", "1")
    assert rep["tasks_run"] == 1 and rep["failed"] == 1
    b = _manifest(first)["broken"]["steps"]
    assert b["adapt"]["status"] == "failed" and b["adapt"]["worker"]["pid"] != pid
    assert b["build"]["status"] == "skipped"


def test_killed_worker_is_retried_then_failed(scans, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(KILL_ENV, "good2:adapt")
    out = tmp_path / "out"
    rep = _run(capsys, scans / "good2.obj", scans / "broken.obj", "--out", out, "--steps", "adapt",
               "--workers", "2", "--max-retries", "1")
    assert rep["failed"] == 2
    a = _manifest(out)["good2"]["steps"]["adapt"]
    assert a["status"] == "failed" and "died" in a["error"] and a["attempts"] == 2
    assert not list(out.glob("scans/*/.adapt.partial"))


def test_errors(scans, tmp_path, capsys):
    for argv, words in (
        ([], "give scans"),
        ([scans / "good1.obj", "--manifest", scans / "x.json"], "not both"),
        ([tmp_path / "missing.obj"], "no such file"),
        ([scans / "good1.obj", "--steps", "adapt,bake"], "--steps"),
        ([scans / "good1.obj", "--max-retries", "-1"], "--max-retries"),
    ):
        code = main(["batch", "run", *map(str, argv), "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1, (argv, err)
    bad = tmp_path / "in.json"
    bad.write_text(json.dumps({"scans": [{"scan": "nowhere.obj"}]}))
    assert main(["batch", "run", "--manifest", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "scans[0]" in capsys.readouterr().err


def test_ray_local_two_workers(scans, tmp_path, capsys, monkeypatch):
    pytest.importorskip("ray")
    monkeypatch.setenv(KILL_ENV, "victim:adapt")
    shutil.copy(scans / "good1.obj", tmp_path / "victim.obj")  # a copy of good1 under its own name
    listing = tmp_path / "in.json"
    listing.write_text(json.dumps({"scans": [
        {"scan": str(scans / "good2.obj")},
        {"scan": str(scans / "broken.obj"), "name": "broken"},
        {"scan": "victim.obj", "landmarks": str(scans / "good1_landmarks.json"), "name": "victim"}]}))
    out = tmp_path / "out"
    rep = _run(capsys, "--manifest", listing, "--out", out, "--steps", "adapt", "--levels", "1", "--ray",
               "--workers", "2", "--max-retries", "1")
    assert rep["executor"].startswith("Ray local (2 CPUs")
    m = _manifest(out)
    assert m["good2"]["steps"]["adapt"]["status"] == "done"
    assert m["broken"]["steps"]["adapt"]["status"] == "failed"
    v = m["victim"]["steps"]["adapt"]
    assert v["status"] == "failed" and "died 2 times" in v["error"]


def test_ctrl_c_leaves_finished_work_and_a_valid_manifest(scans, tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "facewarp", "batch", "run", str(scans / "good1.obj"),
                             str(scans / "good2.obj"), "--out", str(out), "--steps", "adapt,build", "--levels", "1",
                             "--workers", "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:  # until the first step is done
            if (out / "manifest.json").is_file() and '"done"' in (out / "manifest.json").read_text():
                break
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "interrupted" in err
    m = _manifest(out)  # valid JSON
    done = [(n, s) for n, e in m.items() for s, r in e["steps"].items() if r["status"] == "done"]
    assert done and all((out / m[n]["folder"] / s).is_dir() for n, s in done)
    assert len(done) < 4 and not list(out.glob("scans/*/.*.partial"))
    assert json.loads((out / "report.json").read_text())["totals"]["scans"] == 2
