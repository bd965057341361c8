"""One step of one scan, as run in a worker process (a local process or a Ray worker).

:func:`run_step` calls the job of the step (:func:`~facewarp._src.jobs.adapt.adapt_files`,
:func:`~facewarp._src.jobs.face.build_files`, :func:`~facewarp._src.jobs.face.simulate_files`,
:func:`~facewarp._src.jobs.rig.rig_files`) on the scan's folder: it writes into
``FOLDER/.STEP.partial`` and renames that to ``FOLDER/STEP`` only when the job succeeded, so a
step's folder is either complete or absent. An error of the scan (a bad file, a failed
adaptation) is returned as the one-line error of a ``failed`` record and never raised: a bad
scan does not stop the batch, and Ray does not retry it. Only the death of the worker process
itself (killed, out of memory) reaches the caller, which retries the step.

A *group* task (``{"step": "simulate", "group": [task, ...], ...}``) is the ``simulate`` step of
several scans in one :class:`~facewarp.FaceBatch` (:func:`run_group`): each scan's folder is
staged and renamed as above, and the result is one record per scan (a head frozen by a failure
is its scan's ``failed`` record, the others are ``done``).

The task and its result are plain dicts (they cross process and machine boundaries).
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import sys
import time
from pathlib import Path

__all__ = ["KILL_ENV", "init_worker", "run_group", "run_step", "step_summary"]

KILL_ENV = "FACEWARP_FLEET_TEST_KILL"
"""Test hook: ``NAME:STEP`` makes the worker running that step of the scan named ``NAME`` kill
itself (SIGKILL), as a crashed or out-of-memory worker would die (a group task: when any of
its scans is named)."""

MAX_ERROR = 400
"""Longest error line kept in the manifest [characters]."""


def init_worker() -> None:
    """Initialiser of a local worker process.

    Ctrl-C is the driver's to handle (it stops the workers); anything a library prints goes to
    stderr (stdout carries the command's result). The worker starts a session of its own, as Ray's
    workers do: Linux's autogroup scheduler shares a busy machine's cores per session, and in the
    driver's session N workers would get one share between them (measured: 2 local workers no
    faster than 1 on a loaded box, 2 Ray workers 2x). Out of the driver's session it no longer
    hears the terminal, so it watches the driver and exits when the driver is gone.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass
    if hasattr(os, "setsid"):
        try:
            os.setsid()
        except OSError:
            pass
    import threading

    parent = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(1.0)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="facewarp-parent-watch", daemon=True).start()


def _one_line(e: BaseException) -> str:
    from ..core.errors import FacewarpError

    text = str(e) if isinstance(e, FacewarpError) else f"{type(e).__name__}: {e}"
    text = " ".join(text.split()) or type(e).__name__
    return text[: MAX_ERROR - 3] + "..." if len(text) > MAX_ERROR else text


def _cpu_seconds() -> float | None:
    """User + system CPU time of this process so far [s]."""
    try:
        import resource

        r = resource.getrusage(resource.RUSAGE_SELF)
        return r.ru_utime + r.ru_stime
    except (ImportError, OSError):
        return None


def _peak_rss_mib() -> float | None:
    try:
        import resource

        kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux, bytes on macOS
        return round(kib / (2**20 if sys.platform == "darwin" else 2**10), 1)
    except (ImportError, OSError):
        return None


def _g(d, *keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _mm(v):
    return None if v is None else v * 1e3


def step_summary(step: str, rep: dict) -> dict:
    """The few figures of a step's report that go into the manifest and ``report.json``."""
    if step == "adapt":
        last = rep["levels"][-1] if rep.get("levels") else {}
        stretch = _g(rep, "quality", "distortion", "all", "stretch_rms")
        return {"adapt_seconds": rep.get("seconds"), "fp_count": rep.get("fp_count"), "E_d_m2": last.get("E_d"),
                "distance_median_mm": _mm(_g(rep, "distance_to_scan_m", "median")),
                "distance_rms_mm": _mm(_g(rep, "distance_to_scan_m", "rms")),
                "distance_p95_mm": _mm(_g(rep, "distance_to_scan_m", "p95")),
                "folds": _g(rep, "quality", "surface", "folds"),
                "stretch_rms_percent": None if stretch is None else stretch * 100.0}
    if step == "build":
        return {k: rep.get(k) for k in ("tet_count", "inverted_count", "min_dihedral_deg", "muscle_count",
                                         "conforming")}
    if step == "rig":  # own names: "frames" is the simulation's in report.json
        return {"rig_targets": rep.get("targets"), "rig_inbetweens": rep.get("inbetweens"),
                "rig_vertices": rep.get("vertices"), "rig_animation_frames": rep.get("frames"),
                "rig_bake_frames_max": rep.get("bake_frames_max"),
                "rig_files": [Path(f).name for f in rep.get("files", [])]}
    return {k: rep.get(k) for k in ("expression", "frames", "frames_per_second", "realtime_factor",
                                     "steps_per_second", "device", "nodes", "tets")}


def _kill_hook(names, step: str) -> None:
    """The :data:`KILL_ENV` test hook: SIGKILL this worker when it runs ``step`` of one of ``names``."""
    kill = os.environ.get(KILL_ENV, "")
    if kill and any(kill == f"{n}:{step}" for n in names):
        os.kill(os.getpid(), signal.SIGKILL)


def _worker() -> dict:
    """The record's ``worker``: pid, host and peak resident memory of this process [MiB]."""
    return {"pid": os.getpid(), "host": socket.gethostname(), "peak_rss_mib": _peak_rss_mib()}


def _write_simulate_report(rep: dict, folder: Path, tmp: Path) -> dict:
    """A simulate report's files named where the step's folder will be (``folder/simulate``), written as
    ``tmp/report.json``; returns ``rep``."""
    from ..core.fileio import write_json
    from .manifest import plain

    rep["files"] = [str(folder / "simulate" / Path(f).name) for f in rep.get("files", [])]
    write_json(tmp / "report.json", plain(rep))
    return rep


def _promote(step: str, rep: dict, tmp: Path, final: Path, out: Path) -> dict:
    """The finished step's staging folder ``tmp`` renamed to ``final`` (an older one replaced);
    returns the record's ``status``, ``summary`` and ``outputs`` (files relative to ``out``)."""
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp, final)
    return {"status": "done", "summary": step_summary(step, rep),
            "outputs": sorted(str(f.relative_to(out)) for f in final.rglob("*") if f.is_file())}


def _run_job(task: dict, tmp: Path) -> dict:
    step, folder, p = task["step"], Path(task["folder"]), task["params"]
    device = task.get("device", "cpu")
    if step == "adapt":
        from ..jobs.adapt import adapt_files

        return adapt_files(task["scan"], task.get("landmarks"), tmp, units=task.get("units"),
                           levels=p.get("levels"), device=device)
    if step == "build":
        from ..jobs.face import build_files

        return build_files(folder / "adapt", tmp, layers=p.get("layers", 1), device=device)
    if step == "simulate":
        from ..jobs.face import simulate_files

        rep = simulate_files(folder / "build", p["expression"], tmp, seconds=p["seconds"], fps=p.get("fps", 30.0),
                             device=device, jaw=p.get("jaw", "mujoco"))
        return _write_simulate_report(rep, folder, tmp)
    if step == "rig":
        from ..core.fileio import write_json
        from ..jobs.rig import rig_files
        from .manifest import plain

        tmp.mkdir(parents=True)
        rep = rig_files(folder / "build", [tmp / f"rig.{f}" for f in p["formats"]], inbetweens=p.get("inbetweens", 0),
                        muscles=p.get("muscles"), device=device)
        rep["file"] = str(folder / step / Path(rep["file"]).name)
        rep["files"] = [str(folder / step / Path(f).name) for f in rep["files"]]
        rep["device"] = device
        write_json(tmp / "report.json", plain(rep))
        return rep
    raise ValueError(f"unknown step {step!r}")


def run_step(task: dict) -> dict | list[dict]:
    """Run one step of one scan; returns its manifest record (a group task: :func:`run_group`'s records).

    ``task``: ``step`` (adapt, build, simulate or rig), ``name``, ``folder`` (the scan's output folder),
    ``out`` (the batch folder), ``scan``, ``landmarks`` (or None), ``units``, ``params`` (the
    step's options) and ``device``. The record: ``status`` (``done`` or ``failed``), ``error`` (one
    line or None), ``outputs`` (files relative to ``out``), ``device`` (the Warp device it was given),
    ``seconds`` (wall), ``cpu_seconds`` (user + system CPU time of the worker during the step),
    ``worker`` (pid, host, peak resident memory of the worker process [MiB]) and ``summary``
    (:func:`step_summary`).
    """
    if "group" in task:
        return run_group(task)
    t0, c0 = time.perf_counter(), _cpu_seconds()
    step, folder, out = task["step"], Path(task["folder"]), Path(task["out"])
    _kill_hook([task["name"]], step)
    final, tmp = folder / step, folder / f".{step}.partial"
    record = {"status": "failed", "error": None, "outputs": [], "summary": {}, "device": task.get("device", "cpu")}
    try:
        if tmp.exists():
            shutil.rmtree(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        record.update(_promote(step, _run_job(task, tmp), tmp, final, out))
    except Exception as e:  # the scan's error, recorded; the batch goes on
        record["error"] = _one_line(e)
        shutil.rmtree(tmp, ignore_errors=True)
    record["seconds"] = round(time.perf_counter() - t0, 3)
    c1 = _cpu_seconds()
    record["cpu_seconds"] = None if c0 is None or c1 is None else round(c1 - c0, 3)
    record["worker"] = _worker()
    return record


def run_group(task: dict) -> list[dict]:
    """The ``simulate`` step of several scans together in one :class:`~facewarp.FaceBatch`
    (:func:`~facewarp._src.jobs.batch_simulate.simulate_group_files`); returns one record per scan,
    in the order of ``task["group"]``.

    ``task``: ``step`` (``"simulate"``), ``group`` (the scans' own :func:`run_step` tasks),
    ``out``, ``params`` and ``device`` (those of every scan). Each scan's outputs are staged in
    ``FOLDER/.simulate.partial`` and renamed to ``FOLDER/simulate`` when its head is done. A record
    is :func:`run_step`'s with ``batched_with`` (the scans of the group), ``seconds`` and
    ``cpu_seconds`` the group's divided evenly between its scans, and ``group_seconds`` (the
    group's wall time). When the group as a whole fails (options bad for every scan, an error of the
    :class:`~facewarp.FaceBatch` itself rather than of one head), each scan runs alone here
    (:func:`run_step`) and its record says why in ``group_fallback``.
    """
    t0, c0 = time.perf_counter(), _cpu_seconds()
    members, out, p = task["group"], Path(task["out"]), task["params"]
    step = task["step"]
    _kill_hook([m["name"] for m in members], step)
    folders = [Path(m["folder"]) for m in members]
    tmps = [f / f".{step}.partial" for f in folders]
    for f, tmp in zip(folders, tmps):
        shutil.rmtree(tmp, ignore_errors=True)
        f.mkdir(parents=True, exist_ok=True)
    try:
        from ..jobs.batch_simulate import simulate_group_files

        results = simulate_group_files([f / "build" for f in folders], p["expression"], tmps, seconds=p["seconds"],
                                       fps=p.get("fps", 30.0), device=task.get("device", "cpu"),
                                       jaw=p.get("jaw", "mujoco"))
    except Exception as e:  # the group as a whole: each scan alone, as without grouping
        why = _one_line(e)
        for tmp in tmps:
            shutil.rmtree(tmp, ignore_errors=True)
        records = [run_step(m) for m in members]
        for r in records:
            r.update(batched_with=1, group_fallback=why)
        return records
    n = len(members)
    wall = time.perf_counter() - t0
    c1 = _cpu_seconds()
    worker = _worker()
    records = []
    for folder, tmp, rep in zip(folders, tmps, results):
        final = folder / step
        record = {"status": "failed", "error": None, "outputs": [], "summary": {}, "device": task.get("device", "cpu")}
        try:
            if isinstance(rep, BaseException):
                raise rep
            record.update(_promote(step, _write_simulate_report(rep, folder, tmp), tmp, final, out))
        except Exception as e:  # this scan's error; the group's other scans go on
            record["error"] = _one_line(e)
            shutil.rmtree(tmp, ignore_errors=True)
        record.update(seconds=round(wall / n, 3), group_seconds=round(wall, 3), batched_with=n, worker=worker,
                      cpu_seconds=None if c0 is None or c1 is None else round((c1 - c0) / n, 3))
        records.append(record)
    return records
