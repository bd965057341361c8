"""`facewarp batch run`: a fleet of scans in local processes and on a local Ray of 2 workers.

Tiny synthetic scans (4,000 triangles), one refinement level, adapt + build (simulate for one scan,
0.1 s; the rig of two muscles for another): a broken scan in the batch, a re-run that skips finished
work (a renamed copy is known by its content), --retry-failed, a killed worker retried then failed,
Ctrl-C semantics of the manifest, the device the physics steps get with --gpus-per-task (a GPU
mocked: Warp's device count locally, a stand-in ``ray`` module for Ray), and grouped simulations
(--simulate-batch: the two good scans' simulate in one FaceBatch task, on the CPU here) against the
same simulations one task per scan.
"""

from __future__ import annotations

import csv
import json
import shutil
import sys
import types

import pytest

import facewarp as fw
from facewarp.cli import main

KILL_ENV = "FACEWARP_FLEET_TEST_KILL"  # the worker running NAME:STEP kills itself (SIGKILL)


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    d = tmp_path_factory.mktemp("scans")
    for i in (1, 2):
        s = fw.synthetic_scan(i, faces=4000)
        fw.geometry.save_obj(d / f"good{i}.obj", s.vertices, s.faces)
        fw.geometry.save_landmarks_json(d / f"good{i}_landmarks.json", s.landmarks)
    (d / "broken.obj").write_text("this is not a mesh\n")
    return d


def _run(capsys, *argv):
    """``batch run --json``; its exit code is 0 when every scan is done, else 1 (and says so)."""
    code = main(["--json", "batch", "run", *map(str, argv)])
    o, err = capsys.readouterr()
    assert code in (0, 1), err
    rep = json.loads(o)
    assert code == rep["exit_code"] == (1 if rep["failed"] or rep["incomplete"] else 0), (code, rep["outcome"])
    return rep


def _manifest(out):
    m = json.loads((out / "manifest.json").read_text())
    return {e["name"]: e for e in m["scans"].values()}


@pytest.fixture(scope="module")
def first(scans, tmp_path_factory):
    """adapt + build of two good scans and a broken one in 2 local processes."""
    out = tmp_path_factory.mktemp("batch") / "out"
    code = main(["batch", "run", str(scans / "good1.obj"), str(scans / "broken.obj"), str(scans / "good2.obj"),
                 "--out", str(out), "--steps", "adapt,build", "--levels", "1", "--workers", "2"])
    assert code == 1  # the broken scan failed: a script sees it
    return out


@pytest.mark.slow
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
        ([scans / "good1.obj", "--steps", "rig,"], "--steps"),
        ([scans / "good1.obj", "--steps", "build,rigs"], "--steps"),
        ([scans / "good1.obj", "--rig-formats", "fbx"], "--rig-formats"),
        ([scans / "good1.obj", "--rig-inbetweens", "9"], "--rig-inbetweens"),
        ([scans / "good1.obj", "--steps", "rig"], "rig needs build done first"),  # a fresh DIR has no build
        ([scans / "good1.obj", "--max-retries", "-1"], "--max-retries"),
        ([scans / "good1.obj", "--simulate-batch", "0"], "--simulate-batch"),
        ([scans / "good1.obj", "--simulate-batch", "-2"], "--simulate-batch"),
        ([scans / "good1.obj", "--simulate-batch", "4097"], "--simulate-batch"),
        ([scans / "good1.obj", "--simulate-batch", "2.5"], "--simulate-batch"),
    ):
        code = main(["batch", "run", *map(str, argv), "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1, (argv, err)
    bad = tmp_path / "in.json"
    bad.write_text(json.dumps({"scans": [{"scan": "nowhere.obj"}]}))
    assert main(["batch", "run", "--manifest", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "scans[0]" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # refused before anything was written


RIG = ["--rig-muscles", "zygomatic_major_L,zygomatic_major_R"]  # two muscle shapes (+ the jaw's): a quick bake


def test_rig_step_after_build_then_skipped_when_done(first, scans, capsys):
    rep = _run(capsys, scans / "good2.obj", "--out", first, "--steps", "adapt,build,rig", "--levels", "1", *RIG,
               "--rig-formats", "usda,glb", "--workers", "1")
    assert rep["tasks_run"] == 1 and rep["tasks_kept"] == 2 and rep["done"] == 1
    e = _manifest(first)["good2"]
    r = e["steps"]["rig"]
    assert r["status"] == "done" and r["error"] is None and r["attempts"] == 1 and r["device"] == "cpu"
    assert r["seconds"] > 0 and r["worker"]["pid"] > 0 and r["worker"]["host"]
    assert r["params"] == {"formats": ["usda", "glb"], "inbetweens": 0, "muscles": RIG[1].split(",")}
    folder = first / e["folder"] / "rig"
    # the USD file's skin texture beside it (rig_skin.png, named by the file; the glTF embeds its own)
    assert sorted(p.name for p in folder.iterdir()) == ["report.json", "rig.glb", "rig.usda", "rig_skin.png"]
    assert sorted(r["outputs"]) == sorted(str((folder / n).relative_to(first)) for n in ("report.json", "rig.glb",
                                                                                           "rig.usda", "rig_skin.png"))
    assert (folder / "rig.glb").read_bytes()[:4] == b"glTF" and (folder / "rig.usda").read_text().startswith("#usda")
    job = json.loads((folder / "report.json").read_text())  # the rig job's own report, its figures in the summary
    assert job["targets"] == 3 and job["muscles"] == 2 and job["files"] == [str(folder / "rig.usda"),
                                                                            str(folder / "rig.glb")]
    assert r["summary"]["rig_targets"] == 3 and r["summary"]["rig_animation_frames"] == job["frames"] > 1
    assert r["summary"]["rig_files"] == ["rig.usda", "rig.glb"]
    row = rep["rows"][0]
    assert row["rig_targets"] == 3 and row["rig_s"] > 0 and row["status"] == "done"
    # again, the rig step alone: it finds the build in the manifest and keeps the rig (formats in any order);
    # the broken scan has no build: its rig is skipped with the one-line reason, the batch goes on
    before = e["steps"]
    rep = _run(capsys, scans / "good2.obj", scans / "broken.obj", "--out", first, "--steps", "rig", *RIG,
               "--rig-formats", "glb,usda")
    assert rep["tasks_run"] == 0 and rep["tasks_kept"] == 1
    m = _manifest(first)
    assert m["good2"]["steps"] == before
    assert m["broken"]["steps"]["rig"]["status"] == "skipped"
    assert m["broken"]["steps"]["rig"]["error"] == "needs build done first (add it to --steps)"
    assert m["broken"]["steps"]["adapt"]["status"] == "failed"  # as recorded
    # the broken scan alone: nothing can run; one line, the manifest untouched
    text = (first / "manifest.json").read_text()
    assert main(["batch", "run", str(scans / "broken.obj"), "--out", str(first), "--steps", "rig"]) == 2
    err = capsys.readouterr().err
    assert "rig needs build done first" in err and "add build to --steps" in err and len(err.strip().splitlines()) == 1
    assert (first / "manifest.json").read_text() == text


@pytest.mark.parametrize("gpus_per_task, cuda, want", [(None, 1, "cpu"), ("0", 1, "cpu"), ("1", 0, "cpu"),
                                                       ("1", 1, "cuda")])
def test_local_physics_steps_device(first, tmp_path, capsys, monkeypatch, gpus_per_task, cuda, want):
    """With --gpus-per-task > 0 and a GPU here (mocked: Warp's device count), the rig step's worker
    gets cuda; otherwise --device. Without a real GPU the step then fails on cuda, one line (with
    one it is done there). The CPU cases find good2's rig of the test above done and keep it (the
    choice shows in the executor)."""
    import warp

    real_gpu = warp.get_cuda_device_count() > 0
    monkeypatch.setattr(warp, "get_cuda_device_count", lambda: cuda)
    out = tmp_path / "out"
    shutil.copytree(first, out)
    scan = _manifest(out)["good2"]["inputs"]["scan"]["path"]
    formats = "glb" if want == "cuda" else "usda,glb"  # cuda: options not run before, so the step runs
    argv = [scan, "--out", out, "--steps", "adapt,build,rig", "--levels", "1", *RIG, "--rig-formats", formats,
            "--workers", "1"]
    rep = _run(capsys, *argv, *(["--gpus-per-task", gpus_per_task] if gpus_per_task else []))
    assert ("simulate and rig on cuda" in rep["executor"]) == (want == "cuda")
    r = _manifest(out)["good2"]["steps"]
    assert r["rig"]["device"] == want and r["adapt"]["device"] == r["build"]["device"] == "cpu"
    if want == "cuda" and not real_gpu:
        assert rep["tasks_run"] == 1 and r["rig"]["status"] == "failed" and "cuda" in r["rig"]["error"]
    elif want == "cuda":  # a GPU machine: the worker's rig ran on it
        assert rep["tasks_run"] == 1 and r["rig"]["status"] == "done", r["rig"]
    else:
        assert r["rig"]["status"] == "done"


class _Ref:
    """A stand-in object reference (hashable, as Ray's are)."""

    def __init__(self, record: dict):
        self.record = record


class _FakeRay(types.ModuleType):
    """A stand-in ``ray``: a cluster of 2 CPUs and ``gpus`` GPUs; a task is recorded (its options and
    its task dict) and reported done at once."""

    def __init__(self, gpus: float):
        super().__init__("ray")
        self.gpus, self.submitted, self.groups, self._up = gpus, [], [], False
        self.exceptions = types.SimpleNamespace(WorkerCrashedError=type("WorkerCrashedError", (Exception,), {}),
                                                NodeDiedError=type("NodeDiedError", (Exception,), {}),
                                                RayError=type("RayError", (Exception,), {}))

    def is_initialized(self):
        return self._up

    def init(self, **kw):
        self._up = True

    def shutdown(self):
        self._up = False

    def cluster_resources(self):
        return {"CPU": 2.0, "GPU": float(self.gpus)}

    def remote(self, **kw):
        ray = self

        class Remote:
            def __init__(self, fn, opts=None):
                self.fn, self.opts = fn, opts or {}

            def options(self, **opts):
                return Remote(self.fn, opts)

            def remote(self, task):
                ray.submitted.append((task["step"], task["device"], self.opts))
                ray.groups.append(len(task.get("group", [task])))
                record = {"status": "done", "error": None, "outputs": [], "summary": {}, "device": task["device"],
                          "seconds": 0.0, "worker": None}
                return _Ref([dict(record, batched_with=len(task["group"])) for _ in task["group"]]
                            if "group" in task else record)

        return lambda fn: Remote(fn)

    def wait(self, refs, num_returns=1, timeout=None):
        return refs[:num_returns], refs[num_returns:]

    def get(self, ref):
        return ref.record

    def cancel(self, ref, force=False):
        pass


@pytest.mark.parametrize("gpus, flag, want, num_gpus", [(1, None, "cuda", 1.0), (1, "0.25", "cuda", 0.25),
                                                          (1, "0", "cpu", None), (0, None, "cpu", None),
                                                          (0, "1", "cpu", None)])
def test_ray_physics_steps_device(scans, tmp_path, capsys, monkeypatch, gpus, flag, want, num_gpus):
    """On Ray, simulate and rig ask for num_gpus and get device cuda when the cluster has a GPU;
    adapt and build are CPU tasks."""
    ray = _FakeRay(gpus)
    monkeypatch.setitem(sys.modules, "ray", ray)
    argv = [scans / "good1.obj", "--out", tmp_path / "out", "--steps", "adapt,build,simulate,rig", "--ray"]
    rep = _run(capsys, *argv, *(["--gpus-per-task", flag] if flag else []))
    assert rep["done"] == 1 and rep["tasks_run"] == 4
    got = {step: (dev, opts) for step, dev, opts in ray.submitted}
    assert list(got) == ["adapt", "build", "simulate", "rig"]
    for step in ("adapt", "build"):
        assert got[step] == ("cpu", {"num_cpus": 1})
    for step in ("simulate", "rig"):
        assert got[step] == (want, {"num_cpus": 1, **({"num_gpus": num_gpus} if num_gpus else {})})
    assert _manifest(tmp_path / "out")["good1"]["steps"]["rig"]["device"] == want


@pytest.mark.parametrize("error, words", [
    (ConnectionError("ray client connection timeout"), "cannot connect to the Ray cluster"),
    (RuntimeError("Ray Client requires pip package `ray[client]`. If you installed the minimal Ray (e.g. `pip "
                  "install ray`), please reinstall by executing `pip install ray[client]`."), "facewarp[ray]")])
def test_ray_cluster_that_cannot_start_leaves_nothing(scans, tmp_path, capsys, monkeypatch, error, words):
    """`--ray ray://HOST:PORT` that cannot connect (or a Ray without its client): one line, exit 2, no
    manifest, no lock (the [ray] extra installs ray[client], which the documented ray:// form needs)."""
    ray = _FakeRay(0)

    def init(**kw):
        raise error

    ray.init = init
    monkeypatch.setitem(sys.modules, "ray", ray)
    out = tmp_path / "out"
    code = main(["batch", "run", str(scans / "good1.obj"), "--out", str(out), "--ray", "ray://127.0.0.1:9"])
    err = capsys.readouterr().err
    assert code == 2 and words in err and len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []


def test_ray_extra_installs_the_client():
    import tomllib
    from pathlib import Path

    extras = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]
    assert any(r.replace(" ", "").startswith(("ray[client]", "ray[default]")) for r in extras["ray"]), extras["ray"]


def test_ray_gpu_groups_the_simulations(scans, tmp_path, capsys, monkeypatch):
    """On a Ray cluster with a GPU the scans' simulations go as one group task (default up to 64)
    asking for the GPU; --simulate-batch 1 keeps a task per scan."""
    for flag, groups in ((None, [2]), ("1", [1, 1])):
        ray = _FakeRay(1)
        monkeypatch.setitem(sys.modules, "ray", ray)
        out = tmp_path / f"out{flag}"
        rep = _run(capsys, scans / "good1.obj", scans / "good2.obj", "--out", out, "--steps", "adapt,build,simulate",
                   "--ray", *(["--simulate-batch", flag] if flag else []))
        assert rep["done"] == 2 and rep["tasks_run"] == 6
        assert rep["simulate_grouping"]["batch"] == (64 if not flag else 1)
        sims = [(dev, opts, n) for (step, dev, opts), n in zip(ray.submitted, ray.groups) if step == "simulate"]
        assert [n for _, _, n in sims] == groups
        assert all(dev == "cuda" and opts == {"num_cpus": 1, "num_gpus": 1.0} for dev, opts, _ in sims)
        m = _manifest(out)
        assert [m[n]["steps"]["simulate"].get("batched_with") for n in ("good1", "good2")] == (
            [2, 2] if not flag else [None, None])


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


@pytest.mark.parametrize("sig, code", [("SIGINT", 130), pytest.param("SIGTERM", 143, marks=pytest.mark.slow)])
def test_ctrl_c_leaves_finished_work_and_a_valid_manifest(scans, tmp_path, sig, code):
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
        proc.send_signal(getattr(signal, sig))
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == code, err
    assert "interrupted" in err
    m = _manifest(out)  # valid JSON
    done = [(n, s) for n, e in m.items() for s, r in e["steps"].items() if r["status"] == "done"]
    assert done and all((out / m[n]["folder"] / s).is_dir() for n, s in done)
    assert len(done) < 4 and not list(out.glob("scans/*/.*.partial"))
    assert json.loads((out / "report.json").read_text())["totals"]["scans"] == 2
    assert not [p.name for p in tmp_path.iterdir() if ".facewarp-" in p.name]  # the lock is gone


def test_exit_code_and_summary_line_say_what_happened(first, scans, capsys):
    """0 when every scan is done, 1 when some failed (a script or CI sees it), in the summary line too."""
    code = main(["batch", "run", str(scans / "good1.obj"), str(scans / "good2.obj"), "--out", str(first),
                 "--steps", "adapt,build", "--levels", "1"])
    out = capsys.readouterr().out
    assert code == 0 and out.splitlines()[0].endswith("all done (exit 0)"), out
    code = main(["batch", "run", str(scans / "broken.obj"), "--out", str(first), "--steps", "adapt,build",
                 "--levels", "1"])
    out = capsys.readouterr().out
    assert code == 1 and out.splitlines()[0].endswith("no scan done (exit 1)"), out
    assert "broken" in out and "failed" in out


@pytest.mark.slow
def test_a_second_run_on_one_out_is_refused_and_mm_scans_are_read_as_adapt_reads_them(scans, tmp_path, capsys):
    """The first run (a scan in millimetres, no --units: read as `facewarp adapt` reads it) holds
    --out: a second batch run, and a simulate, on it are refused with one line, exit 2, and touch
    nothing; the first finishes with its scan adapted."""
    import os
    import subprocess
    import sys
    import time

    s = fw.synthetic_scan(3, faces=4000)
    fw.geometry.save_obj(tmp_path / "mm.obj", s.vertices * 1e3, s.faces)
    fw.geometry.save_landmarks_json(tmp_path / "mm_landmarks.json", {k: v * 1e3 for k, v in s.landmarks.items()})
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "facewarp", "--json", "batch", "run", str(tmp_path / "mm.obj"),
                             "--out", str(out), "--steps", "adapt", "--levels", "1", "--workers", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None and not (out / "manifest.json").is_file():
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()
        before = (out / "manifest.json").read_text()
        for argv in (["batch", "run", str(scans / "good1.obj"), "--out", str(out), "--steps", "adapt", "--levels", "1"],
                     ["simulate", "default", "--out", str(out)]):
            code = main(argv)
            o, err = capsys.readouterr()
            assert code == 2 and o == "" and len(err.strip().splitlines()) == 1, err
            assert "another facewarp run is writing it" in err and str(out) in err, err
        assert (out / "manifest.json").read_text() == before
        o, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    rep = json.loads(o)
    assert rep["done"] == 1 and rep["exit_code"] == 0
    assert not [p.name for p in tmp_path.iterdir() if ".facewarp-" in p.name]
    adapt = json.loads((out / _manifest(out)["mm"]["folder"] / "adapt" / "report.json").read_text())
    assert adapt["distance_to_scan_m"]["median"] < 2e-3  # in metres: the mm scan was read as mm


def test_options_of_later_steps_are_checked_before_the_first_adapt(scans, tmp_path, capsys):
    """--expression, --seconds and --rig-muscles are refused before anything runs or is written
    (they were checked only after each scan's adapt and build, 17 s a scan)."""
    out = tmp_path / "o"
    for extra, words in ((["--expression", "bogus"], "bogus"), (["--seconds", "0.01"], "no frame after the rest pose"),
                         (["--steps", "adapt,build,rig", "--rig-muscles", "bogus"], "bogus")):
        t0 = __import__("time").perf_counter()
        code = main(["batch", "run", str(scans / "good1.obj"), "--out", str(out), *extra])
        err = capsys.readouterr().err
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists() and __import__("time").perf_counter() - t0 < 30


@pytest.mark.slow
def test_ray_sigterm_shuts_ray_down_and_leaves_a_valid_batch(scans, tmp_path):
    """SIGTERM to a batch on a local Ray: exit 143, the reports written, no .STEP.partial left, Ray
    shut down (its handler, which exited the driver past the clean-up, is not in the way)."""
    pytest.importorskip("ray")
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "facewarp", "batch", "run", str(scans / "good1.obj"),
                             str(scans / "good2.obj"), "--out", str(out), "--steps", "adapt,build", "--levels", "1",
                             "--ray", "--workers", "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None and not list(out.glob("scans/*/.adapt.partial")):
            time.sleep(0.1)
        assert proc.poll() is None, proc.communicate()
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "facewarp: interrupted", err
    assert not list(out.glob("scans/*/.*.partial"))
    assert json.loads((out / "report.json").read_text())["totals"]["scans"] == 2
    assert not [p.name for p in tmp_path.iterdir() if ".facewarp-" in p.name]


SIM = ["--steps", "adapt,build,simulate", "--levels", "1", "--expression", "laugh", "--seconds", "0.1"]
"""The simulate of the grouped tests: 4 frames of a laugh (its jaw opens: the MuJoCo jaw is coupled)."""


def _sim_run(first, scans, tmp_path_factory, *extra):
    """A copy of the adapt + build batch with the simulate step added (the broken scan too)."""
    import io
    from contextlib import redirect_stdout

    out = tmp_path_factory.mktemp("sim") / "out"
    shutil.copytree(first, out)
    buf = io.StringIO()
    with redirect_stdout(buf):
        code = main(["--json", "batch", "run", *(str(scans / f"{n}.obj") for n in ("good1", "broken", "good2")),
                     "--out", str(out), *SIM, "--workers", "2", *extra])
    assert code == 1  # the broken scan
    return out, json.loads(buf.getvalue())


@pytest.fixture(scope="module")
def grouped(first, scans, tmp_path_factory):
    """The two good scans' simulate as one group task (--simulate-batch 3 on the CPU)."""
    return _sim_run(first, scans, tmp_path_factory, "--simulate-batch", "3")


@pytest.fixture(scope="module")
def alone(first, scans, tmp_path_factory):
    """The same simulate, one task per scan (the CPU's default)."""
    return _sim_run(first, scans, tmp_path_factory)


@pytest.mark.slow
def test_grouped_simulate_writes_what_each_scan_gets_alone(grouped, alone):
    import numpy as np

    (g, grep), (a, arep) = grouped, alone
    assert grep["simulate_grouping"]["groups"] == 1 and grep["simulate_grouping"]["grouped_scans"] == 2
    assert arep["simulate_grouping"]["groups"] == 0 and arep["simulate_grouping"]["batch"] == 1
    assert grep["tasks_run"] == 1 * 2 and grep["tasks_failed_kept"] == 1 and grep["tasks_kept"] == 4
    mg, ma = _manifest(g), _manifest(a)
    assert mg["broken"]["steps"]["adapt"]["status"] == "failed"  # still failed at adapt
    assert mg["broken"]["steps"]["build"]["status"] == "skipped" and "simulate" not in mg["broken"]["steps"]
    recs = [mg[n]["steps"]["simulate"] for n in ("good1", "good2")]
    for r, n in zip(recs, ("good1", "good2")):
        ra = ma[n]["steps"]["simulate"]
        assert r["status"] == "done" and r["error"] is None and r["batched_with"] == 2 and "batched_with" not in ra
        assert r["params"] == ra["params"] and r["device"] == ra["device"] == "cpu" and r["attempts"] == 1
        assert r["seconds"] == pytest.approx(r["group_seconds"] / 2, abs=2e-3) and r["worker"]["pid"] > 0
        assert set(r["summary"]) == set(ra["summary"]) and r["summary"]["frames"] == ra["summary"]["frames"] == 4
        assert r["summary"]["nodes"] == ra["summary"]["nodes"] and r["summary"]["expression"] == "laugh"
        fg, fa = g / mg[n]["folder"] / "simulate", a / ma[n]["folder"] / "simulate"
        assert sorted(p.name for p in fg.iterdir()) == sorted(p.name for p in fa.iterdir()) == [
            "frames.npz", "frames.png", "report.json"]
        assert sorted(r["outputs"]) == sorted(str((fg / f).relative_to(g)) for f in ("frames.npz", "frames.png",
                                                                                   "report.json"))
        jg, ja = json.loads((fg / "report.json").read_text()), json.loads((fa / "report.json").read_text())
        assert set(jg) == set(ja) and jg["jaw"] == ja["jaw"] == "mujoco"
        assert jg["files"] == [str(fg / "frames.npz"), str(fg / "frames.png")]
        assert jg["max_fdp_motion_m"].keys() == ja["max_fdp_motion_m"].keys()
        with np.load(fg / "frames.npz") as zg, np.load(fa / "frames.npz") as za:
            assert set(zg.files) == set(za.files)
            for k in ("points", "fdp_points", "muscle_curves", "jaw", "activations"):
                np.testing.assert_allclose(zg[k], za[k], atol=1e-6, rtol=0, err_msg=f"{n}: {k}")
            assert np.abs(zg["fdp_points"][-1] - zg["fdp_points"][0]).max() > 1e-4  # the laugh moved the face
    assert not list(g.glob("scans/*/.*.partial"))
    rows_g, rows_a = ({r["name"]: r for r in rep["rows"]} for rep in (grep, arep))
    for n in ("good1", "good2", "broken"):
        assert rows_g[n].keys() == rows_a[n].keys() and rows_g[n]["status"] == rows_a[n]["status"]
        assert [k for k, v in rows_g[n].items() if v is None] == [k for k, v in rows_a[n].items() if v is None]
    assert rows_g["good1"]["status"] == "done" and rows_g["good1"]["frames"] == 4 and rows_g["good1"]["simulate_s"] > 0
    with open(g / "report.csv") as f:
        assert [r["name"] for r in csv.DictReader(f)] == ["good1", "broken", "good2"]


def test_grouped_rerun_keeps_everything(grouped, alone, scans, capsys):
    """A re-run keeps the grouped simulations, and grouping keeps simulations run one per task."""
    for out, extra in ((grouped[0], ["--simulate-batch", "3"]), (alone[0], ["--simulate-batch", "2"])):
        before = _manifest(out)
        rep = _run(capsys, *(scans / f"{n}.obj" for n in ("good1", "broken", "good2")), "--out", out, *SIM, *extra)
        assert rep["tasks_run"] == 0 and rep["tasks_kept"] == 6 and rep["simulate_grouping"]["groups"] == 0
        after = _manifest(out)
        assert {n: e["steps"] for n, e in after.items()} == {n: e["steps"] for n, e in before.items()}


def test_grouped_simulate_killed_then_one_bad_head(first, scans, tmp_path, capsys, monkeypatch):
    """A group whose worker dies is retried whole, then failed for each scan; a head that cannot be
    simulated (its build lost its head.xml) fails alone while the group's other scan is done."""
    out = tmp_path / "out"
    shutil.copytree(first, out)
    goods = [scans / "good1.obj", scans / "good2.obj"]
    monkeypatch.setenv(KILL_ENV, "good2:simulate")
    rep = _run(capsys, *goods, "--out", out, *SIM, "--simulate-batch", "2", "--max-retries", "1", "--workers", "1")
    assert rep["failed"] == 2 and rep["simulate_grouping"]["groups"] == 1
    for n in ("good1", "good2"):
        r = _manifest(out)[n]["steps"]["simulate"]
        assert r["status"] == "failed" and "died" in r["error"] and "(2 attempts)" in r["error"], r
        assert r["attempts"] == 2 and r["batched_with"] == 2
    monkeypatch.delenv(KILL_ENV)
    (out / _manifest(out)["good2"]["folder"] / "build" / "head.xml").unlink()
    rep = _run(capsys, *goods, "--out", out, *SIM, "--simulate-batch", "2", "--retry-failed", "--workers", "1")
    assert rep["tasks_run"] == 2 and rep["done"] == 1 and rep["failed"] == 1
    m = _manifest(out)
    ok, bad = m["good1"]["steps"]["simulate"], m["good2"]["steps"]["simulate"]
    assert ok["status"] == "done" and ok["batched_with"] == 2 and ok["summary"]["frames"] == 4
    assert bad["status"] == "failed" and "head.xml" in bad["error"] and "\n" not in bad["error"]
    assert bad["batched_with"] == 2 and not (out / m["good2"]["folder"] / "simulate").exists()
    assert not list(out.glob("scans/*/.*.partial"))
