"""``facewarp batch run``: every scan through the chosen steps, in local processes or as Ray tasks.

The plan: per scan a chain of steps (adapt -> build -> simulate, those chosen). A step is a task
(:func:`~facewarp._src.fleet.tasks.run_step`); when it is done the scan's next step is submitted,
when it fails the scan's remaining steps are recorded ``skipped``. The loop keeps ``capacity``
tasks in flight (the local workers, or the Ray cluster's CPUs), records every finished task in the
manifest (rewritten atomically each time) and moves one progress bar.

Re-running is idempotent by content: a step already ``done`` with the same options (and its
folder present) is kept, a ``failed`` one is kept unless ``retry_failed``. A worker that dies is
retried up to ``max_retries`` times (by the loop for local processes, by Ray for Ray tasks), then
recorded failed. The manifest is rewritten as tasks finish (at most every half second, or
every ten times its own write time for a large batch) and at the end. Ctrl-C kills the running
tasks, leaves the finished ones and a valid manifest, writes the reports and raises
:class:`KeyboardInterrupt`.

Outputs in ``out``: ``manifest.json``, ``scans/NAME-KEY12/{adapt,build,simulate}/`` (each the
folder its job writes), ``report.json`` and ``report.csv`` (one row per scan: the adaptation's
errors, the anatomy's quality, the simulation's speed, the status and error).
"""

from __future__ import annotations

import csv
import io
import os
import shutil
import time
from pathlib import Path

from ..core.errors import InputError
from ..core.fileio import atomic_write, write_json
from .manifest import STEPS, Manifest, ScanInput, plain

__all__ = ["REPORT_COLUMNS", "run_batch", "write_reports"]

REPORT_COLUMNS = (
    "name", "key", "scan", "status", "failed_step", "error",
    "adapt_s", "distance_median_mm", "distance_rms_mm", "distance_p95_mm", "folds", "stretch_rms_percent",
    "build_s", "tet_count", "inverted_count", "min_dihedral_deg", "muscle_count",
    "simulate_s", "frames", "frames_per_second", "realtime_factor", "worker_peak_rss_mib",
)
"""Columns of ``report.csv`` (and keys of each row of ``report.json``), seconds per step in ``*_s``."""


def _params(step: str, *, levels, expression, seconds, fps, jaw) -> dict:
    if step == "adapt":
        return {"levels": levels}
    if step == "build":
        return {"layers": 1}
    return {"expression": expression, "seconds": float(seconds), "fps": float(fps), "jaw": jaw}


class _Bar:
    """One bar for the whole batch: steps finished of steps planned, with done / failed / running."""

    def __init__(self, total: int, initial: int, enabled: bool):
        from tqdm import tqdm
        import sys

        self.bar = tqdm(total=total, initial=initial, desc="batch", unit="step", file=sys.stderr,
                        disable=None if enabled else True, leave=False)

    def show(self, done: int, failed: int, running: int, advance: int = 0) -> None:
        self.bar.set_postfix_str(f"done {done}, failed {failed}, running {running}", refresh=False)
        self.bar.update(advance) if advance else self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


class _Saver:
    """Rewrites the manifest after tasks finish, at most every ``max(MIN_SAVE_INTERVAL, 10 x the
    last write's time)`` seconds: a write per finished task for small batches, a bounded share of
    the driver's time for 10,000 scans (a manifest of tens of MB)."""

    MIN_SAVE_INTERVAL = 0.5

    def __init__(self, manifest: Manifest):
        self.manifest, self.dirty, self.last, self.cost = manifest, False, 0.0, 0.0

    def changed(self) -> None:
        self.dirty = True
        self.tick()

    def tick(self) -> None:
        now = time.perf_counter()
        if self.dirty and now - self.last >= max(self.MIN_SAVE_INTERVAL, 10.0 * self.cost):
            self.manifest.save()
            self.dirty, self.last, self.cost = False, time.perf_counter(), time.perf_counter() - now


def run_batch(scans: list[ScanInput], out, *, steps=STEPS, expression: str = "smile", seconds: float = 2.0,
              fps: float = 30.0, levels: int | None = 2, jaw: str = "mujoco", device: str = "cpu",
              ray: str | None = None, workers: int | None = None, gpus_per_task: float | None = None,
              max_retries: int = 2, retry_failed: bool = False, progress: bool = True) -> dict:
    """Run ``scans`` through ``steps`` into the folder ``out``; returns the batch summary.

    Args:
        scans: The scans (:class:`ScanInput`); two with the same content are one.
        out: The batch folder (created; a manifest already in it is continued).
        steps: Some of ``adapt``, ``build``, ``simulate`` (run in that order per scan; a step not
            chosen must be done already from an earlier run for a later one to run).
        expression, seconds, fps, jaw: What ``simulate`` plays (:func:`~facewarp._src.jobs.face.simulate_files`).
        levels: ``adapt``'s refinement levels.
        device: Warp device of the local workers (Ray: adapt and build on the CPU, simulate on a GPU
            when ``gpus_per_task`` > 0 and the cluster has one).
        ray: None (local processes), ``"local"`` (a local Ray started here) or a cluster address.
        workers: Local processes (default: the usable cores), or the Ray CPUs to start / tasks in flight.
        gpus_per_task: GPUs per simulate task on Ray (default 1 when the cluster has a GPU, else 0).
        max_retries: Retries of a task whose worker died, >= 0.
        retry_failed: Run the steps that failed in an earlier run again.
        progress: Show the bar on stderr (when it is a terminal).

    Returns:
        ``{"out", "manifest", "report", "report_csv", "executor", "scans", "done", "failed",
        "incomplete", "tasks_run", "tasks_kept", "seconds", "interrupted", "rows"}``.
    """
    t0 = time.perf_counter()
    steps = tuple(s for s in STEPS if s in set(steps))
    if not steps:
        raise InputError(f"steps: choose some of {', '.join(STEPS)}")
    if not scans:
        raise InputError("batch: no scans given (SCANS... or --manifest IN.json)")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"out {out}: exists and is not a folder")
    if not (isinstance(max_retries, int) and max_retries >= 0):
        raise InputError(f"max_retries: expected a whole number >= 0, got {max_retries!r}")
    manifest = Manifest(out)
    keys: list[str] = []
    for s in scans:
        k = manifest.add(s)
        if k not in keys:
            keys.append(k)
    try:
        manifest.save()
    except OSError as e:
        raise InputError(f"out {out}: cannot write the manifest ({e.strerror or e})") from None
    params = {s: _params(s, levels=levels, expression=expression, seconds=seconds, fps=fps, jaw=jaw) for s in STEPS}

    # the plan: per scan the chosen steps still to run, the first one ready now
    todo: dict[str, list[str]] = {}
    kept = failed_kept = 0
    for key in keys:
        chain: list[str] = []
        for s in steps:
            rec = manifest.step(key, s)
            same = rec is not None and rec.get("params") == params[s] and not chain
            if same and rec["status"] == "done" and (manifest.folder(key) / s).is_dir():
                kept += 1
            elif same and rec["status"] == "failed" and not retry_failed:
                failed_kept += 1
                break  # the scan stays failed at this step; its later steps stay as recorded
            else:
                chain.append(s)
        if chain:
            before = STEPS[STEPS.index(chain[0]) - 1] if chain[0] != "adapt" else None
            if before and before not in steps:
                rec = manifest.step(key, before)
                if rec is None or rec["status"] != "done" or not (manifest.folder(key) / before).is_dir():
                    for s in chain:
                        manifest.set_step(key, s, {"status": "skipped", "params": params[s],
                                                   "error": f"needs {before} done first (add it to --steps)"})
                    chain = []
        if chain:
            todo[key] = chain
    manifest.save()

    if ray is None:
        from .executors import LocalExecutor

        n = workers or (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)
        executor = LocalExecutor(n)
    else:
        from .executors import RayExecutor

        executor = RayExecutor(None if ray == "local" else ray, workers=workers, gpus_per_task=gpus_per_task,
                               max_retries=max_retries)

    total = sum(len(c) for c in todo.values())
    counts = {"done": 0, "failed": 0}
    bar = _Bar(total, 0, progress)
    ready = [k for k in keys if k in todo]
    inflight: dict = {}  # handle -> (key, step, task)
    attempts: dict[tuple[str, str], int] = {}
    interrupted = False
    saver = _Saver(manifest)

    def task_of(key: str, step: str) -> dict:
        e = manifest.scans[key]
        lm = e["inputs"]["landmarks"]
        return {"step": step, "name": e["name"], "folder": str(manifest.folder(key).absolute()),
                "out": str(out.absolute()),
                "scan": e["inputs"]["scan"]["path"], "landmarks": lm["path"] if lm else None,
                "units": e["inputs"]["units"], "params": params[step], "device": executor.device(step, device)}

    def finish(key: str, step: str, record: dict) -> None:
        record = dict(record, params=params[step], attempts=attempts.get((key, step), 0) + 1)
        manifest.set_step(key, step, record)
        chain = todo[key]
        chain.pop(0)
        if record["status"] == "done":
            counts["done"] += 1
            for later in STEPS[STEPS.index(step) + 1:]:  # made from the old output: no longer valid
                if later not in chain:
                    manifest.scans[key]["steps"].pop(later, None)
            if chain:
                ready.append(key)
            else:
                del todo[key]
        else:
            counts["failed"] += 1
            for s in chain:
                manifest.set_step(key, s, {"status": "skipped", "params": params[s], "error": f"{step} failed"})
            bar.show(counts["done"], counts["failed"], len(inflight), advance=len(chain))
            del todo[key]
        saver.changed()

    try:
        bar.show(0, 0, 0)
        while ready or inflight:
            while ready and len(inflight) < executor.capacity:
                key = ready.pop(0)
                step = todo[key][0]
                task = task_of(key, step)
                inflight[executor.submit(task)] = (key, step, task)
            bar.show(counts["done"], counts["failed"], len(inflight))
            for handle, record, died in executor.wait(inflight, timeout=0.5):
                key, step, task = inflight.pop(handle)
                if record is None:
                    n = attempts.get((key, step), 0) + 1
                    if not executor.retries_inside and n <= max_retries:
                        attempts[(key, step)] = n
                        inflight[executor.submit(task)] = (key, step, task)
                        continue
                    record = {"status": "failed", "error": died + (f" ({n} attempts)" if not executor.retries_inside
                                                                   else ""),
                              "outputs": [], "summary": {}, "seconds": None, "worker": None}
                    attempts[(key, step)] = n - 1 if not executor.retries_inside else max_retries
                finish(key, step, record)
                bar.show(counts["done"], counts["failed"], len(inflight), advance=1)
            saver.tick()
    except KeyboardInterrupt:
        interrupted = True
    finally:
        bar.close()
        executor.close(abort=bool(inflight) or interrupted, handles=list(inflight))
        for key, step, _ in inflight.values():  # killed halfway: no half-written step folder stays
            shutil.rmtree(manifest.folder(key) / f".{step}.partial", ignore_errors=True)
        manifest.save()
    summary = write_reports(manifest, keys)
    summary.update(executor=executor.description, tasks_run=counts["done"] + counts["failed"], tasks_kept=kept,
                   tasks_failed_kept=failed_kept, seconds=round(time.perf_counter() - t0, 3),
                   interrupted=interrupted, steps=list(steps))
    if interrupted:
        raise KeyboardInterrupt
    return summary


def _row(manifest: Manifest, key: str) -> dict:
    e = manifest.scans[key]
    st = e["steps"]
    row = dict.fromkeys(REPORT_COLUMNS)
    row.update(name=e["name"], key=key[:12], scan=e["inputs"]["scan"]["path"])
    failed = next((s for s in STEPS if s in st and st[s]["status"] == "failed"), None)
    if failed:
        row.update(status="failed", failed_step=failed, error=st[failed].get("error"))
    elif st and all(r["status"] == "done" for r in st.values()):
        row["status"] = "done"
    else:
        row["status"] = "incomplete"
        skipped = next((s for s in STEPS if s in st and st[s]["status"] == "skipped"), None)
        if skipped:
            row.update(failed_step=skipped, error=st[skipped].get("error"))
    rss = []
    for s in STEPS:
        r = st.get(s)
        if not r or r["status"] != "done":
            continue
        row[f"{s}_s"] = r.get("seconds")
        for k, v in (r.get("summary") or {}).items():
            if k in row and k not in ("name", "key", "scan", "status", "error"):
                row[k] = v
        if (r.get("worker") or {}).get("peak_rss_mib") is not None:
            rss.append(r["worker"]["peak_rss_mib"])
    row["worker_peak_rss_mib"] = max(rss) if rss else None
    return row


def write_reports(manifest: Manifest, keys: list[str]) -> dict:
    """``report.json`` (the per-scan rows of the batch's scans, plus totals) and ``report.csv``;
    returns the summary (out, files, counts, rows)."""
    out = manifest.out
    rows = [_row(manifest, k) for k in keys]
    totals = {"scans": len(rows), "done": sum(r["status"] == "done" for r in rows),
              "failed": sum(r["status"] == "failed" for r in rows),
              "incomplete": sum(r["status"] == "incomplete" for r in rows)}
    write_json(out / "report.json", plain({"columns": list(REPORT_COLUMNS), "totals": totals, "scans": rows}))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(REPORT_COLUMNS), lineterminator="\n")
    w.writeheader()
    for r in plain(rows):
        w.writerow({k: ("" if v is None else v) for k, v in r.items()})
    with atomic_write(out / "report.csv", "w") as f:
        f.write(buf.getvalue())
    return {"out": str(out), "manifest": str(manifest.path), "report": str(out / "report.json"),
            "report_csv": str(out / "report.csv"), **totals, "rows": rows}
