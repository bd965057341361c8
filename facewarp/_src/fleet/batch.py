"""``facewarp batch run``: every scan through the chosen steps, in local processes or as Ray tasks.

The plan: per scan a chain of steps (adapt -> build -> simulate -> rig, those chosen; simulate and
rig both read the build). A step is a task (:func:`~facewarp._src.fleet.tasks.run_step`); when it
is done the scan's next step is submitted, when it fails the scan's steps that read its output are
recorded ``skipped`` (a failed simulation does not stop the rig). The loop keeps ``capacity``
tasks in flight (the local workers, or the Ray cluster's CPUs), records every finished task in the
manifest (rewritten atomically each time) and moves one progress bar.

Re-running is idempotent by content: a step already ``done`` with the same options (and its
folder present) is kept, a ``failed`` one is kept unless ``retry_failed``. A worker that dies is
retried up to ``max_retries`` times (by the loop for local processes, by Ray for Ray tasks), then
recorded failed. The manifest is rewritten as tasks finish (at most every half second, or
every ten times its own write time for a large batch) and at the end. Ctrl-C kills the running
tasks, leaves the finished ones and a valid manifest, writes the reports and raises
:class:`KeyboardInterrupt`.

Grouped simulations: with ``simulate_batch`` K > 1 (default 64 when simulate runs on a GPU, 1 on
the CPU, where a :class:`~facewarp.FaceBatch` only loops over its heads) the scans whose build is
done wait for their ``simulate`` and go as one task of up to K scans
(:func:`~facewarp._src.fleet.tasks.run_group`): the heads step together in one FaceBatch and each
scan's ``simulate/`` folder and record are what it gets alone (its seconds the group's shared
evenly, ``batched_with`` the group's size). A group leaves when it is full, or when no scan still
on its way to simulate could join it; a group of one is an ordinary task. A group whose worker
dies is retried whole, as a task is.

A step not chosen must be done from an earlier run for the steps that read it (``--steps rig``
finds the build in the manifest); a scan without it gets the step ``skipped`` with the one-line
reason, and when no scan has it the batch stops before it starts (:class:`InputError`, one line).

Outputs in ``out``: ``manifest.json``, ``scans/NAME-KEY12/{adapt,build,simulate,rig}/`` (each the
folder its job writes; ``rig/rig.usdc``, ``rig/rig.glb``, ``rig/report.json``), ``report.json``
and ``report.csv`` (one row per scan: the adaptation's errors, the anatomy's quality, the
simulation's speed, the rig's shapes, the status and error).
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
from .manifest import NEEDS, STEPS, Manifest, ScanInput, depends, plain

__all__ = ["GPU_SIMULATE_BATCH", "MAX_SIMULATE_BATCH", "REPORT_COLUMNS", "batch_outcome", "check_batch_options",
           "run_batch", "write_reports"]

REPORT_COLUMNS = (
    "name", "key", "scan", "status", "failed_step", "error",
    "adapt_s", "distance_median_mm", "distance_rms_mm", "distance_p95_mm", "folds", "stretch_rms_percent",
    "build_s", "tet_count", "inverted_count", "min_dihedral_deg", "muscle_count",
    "simulate_s", "frames", "frames_per_second", "realtime_factor",
    "rig_s", "rig_targets", "rig_bake_frames_max", "worker_peak_rss_mib",
)
"""Columns of ``report.csv`` (and keys of each row of ``report.json``), seconds per step in ``*_s``."""


MAX_SIMULATE_BATCH = 4096
"""Most scans one grouped ``simulate`` task steps together."""

GPU_SIMULATE_BATCH = 64
"""Scans per grouped ``simulate`` task by default when simulate runs on a GPU (1 on the CPU)."""

RIG_FORMATS = ("usdc", "usda", "glb")
"""Files the ``rig`` step can write (one bake, each format a file ``rig/rig.FORMAT``)."""


def _params(step: str, *, levels, expression, seconds, fps, jaw, rig_formats, rig_inbetweens, rig_muscles) -> dict:
    if step == "adapt":
        return {"levels": levels}
    if step == "build":
        return {"layers": 1}
    if step == "rig":
        return {"formats": list(rig_formats), "inbetweens": int(rig_inbetweens),
                "muscles": None if rig_muscles is None else list(rig_muscles)}
    return {"expression": expression, "seconds": float(seconds), "fps": float(fps), "jaw": jaw}


def _rig_options(formats, inbetweens, muscles):
    """The rig step's options checked, formats in :data:`RIG_FORMATS` order (the same set is the same step)."""
    formats = [formats] if isinstance(formats, str) else list(formats)
    bad = [f for f in formats if f not in RIG_FORMATS]
    if not formats or bad:
        raise InputError(f"rig_formats: expected some of {', '.join(RIG_FORMATS)}, got {formats!r}")
    if not (isinstance(inbetweens, int) and not isinstance(inbetweens, bool) and 0 <= inbetweens <= 8):
        raise InputError(f"rig_inbetweens: expected a whole number 0..8, got {inbetweens!r}")
    if muscles is not None:
        muscles = [muscles] if isinstance(muscles, str) else list(muscles)
        if not muscles or not all(isinstance(m, str) and m for m in muscles):
            raise InputError(f"rig_muscles: expected muscle names, got {muscles!r}")
    return [f for f in RIG_FORMATS if f in formats], inbetweens, muscles


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


def run_batch(scans: list[ScanInput], out, *, steps=("adapt", "build", "simulate"), expression: str = "smile",
              seconds: float = 2.0, fps: float = 30.0, levels: int | None = 2, jaw: str = "mujoco", rig_formats=("usdc", "glb"),
              rig_inbetweens: int = 0, rig_muscles=None, device: str = "cpu", ray: str | None = None,
              workers: int | None = None, gpus_per_task: float | None = None, simulate_batch: int | None = None,
              max_retries: int = 2, retry_failed: bool = False, progress: bool = True) -> dict:
    """Run ``scans`` through ``steps`` into the folder ``out``; returns the batch summary.

    Every option of every step is checked before anything is written or any scan is adapted
    (:func:`check_batch_options`), and ``out`` is locked for the run (a second run on it, of this
    or any facewarp command, is refused with one line).

    Args:
        scans: The scans (:class:`ScanInput`); two with the same content are one.
        out: The batch folder (created; a manifest already in it is continued).
        steps: Some of ``adapt``, ``build``, ``simulate``, ``rig`` (run in that order per scan;
            simulate and rig read the build; a step not chosen must be done already from an earlier
            run for the steps that read it to run; default adapt, build, simulate).
        expression, seconds, fps, jaw: What ``simulate`` plays (:func:`~facewarp._src.jobs.face.simulate_files`).
        levels: ``adapt``'s refinement levels.
        rig_formats: The files of the ``rig`` step (:func:`~facewarp._src.jobs.rig.rig_files`),
            some of ``usdc``, ``usda`` (UsdSkel), ``glb`` (glTF); one bake written in each.
        rig_inbetweens: In-between shapes per muscle, 0..8.
        rig_muscles: Muscle names to bake (default all); a paired muscle's name without ``_L`` /
            ``_R`` means both sides.
        device: Warp device of the local workers (Ray: adapt and build on the CPU, simulate and rig
            on a GPU when ``gpus_per_task`` > 0 and the cluster has one).
        ray: None (local processes), ``"local"`` (a local Ray started here) or a cluster address.
        workers: Local processes (default: the usable cores), or the Ray CPUs to start / tasks in flight.
        gpus_per_task: GPUs per simulate or rig task (Ray: default 1 when the cluster has a GPU, else 0;
            local processes: > 0 runs those two steps on ``cuda`` when this machine has a CUDA device,
            default ``device``).
        simulate_batch: Scans whose ``simulate`` steps together in one :class:`~facewarp.FaceBatch`
            task, 1..:data:`MAX_SIMULATE_BATCH` (default :data:`GPU_SIMULATE_BATCH` when simulate
            runs on a GPU, else 1: a task per scan); module doc.
        max_retries: Retries of a task whose worker died, >= 0.
        retry_failed: Run the steps that failed in an earlier run again.
        progress: Show the bar on stderr (when it is a terminal).

    Returns:
        ``{"out", "manifest", "report", "report_csv", "executor", "scans", "done", "failed",
        "incomplete", "tasks_run", "tasks_kept", "seconds", "interrupted", "rows", "simulate_grouping",
        "exit_code", "outcome"}``; ``simulate_grouping``: ``{"batch"`` (K), ``"groups"`` (grouped tasks
        run), ``"grouped_scans"``, ``"fallbacks"`` (scans of a group that could not step together, run
        alone), ``"fallback_errors"`` (why, one line each)``}``; ``exit_code`` and ``outcome``:
        :func:`batch_outcome`.

    Raises:
        InputError: a bad option or scan list, an ``out`` that cannot be written or that another run
            holds, or no scan that could start (nothing is written then).
        KeyboardInterrupt: SIGINT or SIGTERM (the :class:`~facewarp._src.core.outputs.Interrupted`
            that came, its signal kept): the running tasks are stopped, their half-written step
            folders removed, the manifest and the reports written.
    """
    t0 = time.perf_counter()
    opts = check_batch_options(scans, out, steps=steps, expression=expression, seconds=seconds, fps=fps,
                               levels=levels, jaw=jaw, rig_formats=rig_formats, rig_inbetweens=rig_inbetweens,
                               rig_muscles=rig_muscles, device=device, ray=ray, workers=workers,
                               gpus_per_task=gpus_per_task, simulate_batch=simulate_batch,
                               max_retries=max_retries, retry_failed=retry_failed, progress=progress)
    from ..core.outputs import output_lock

    with output_lock("out", out):
        return _run_batch_locked(scans, Path(out), t0=t0, **opts)


def _expand_muscles(names: list[str]) -> list[str]:
    """Muscle names of the default head's rig: a paired muscle's bare name is both sides; an unknown
    name is an :class:`InputError` listing the known ones."""
    from ..anatomy.muscles import load_muscle_defs

    paired, single = [], []
    for m in load_muscle_defs()["muscles"]:
        (paired if m.get("paired", False) else single).append(m["name"])
    known = [n for p in paired for n in (f"{p}_L", f"{p}_R")] + single
    out: list[str] = []
    for n in names:
        got = [f"{n}_L", f"{n}_R"] if n in paired else [n] if n in known else None
        if got is None:
            raise InputError(f"rig_muscles: {n!r} is not a muscle of the rig; muscles are {', '.join(known)} "
                             "(a paired muscle's name alone is both sides)")
        out += [g for g in got if g not in out]
    return out


def check_batch_options(scans, out, *, steps, expression, seconds, fps, levels, jaw, rig_formats, rig_inbetweens,
                        rig_muscles, device, ray, workers, gpus_per_task, simulate_batch, max_retries, retry_failed,
                        progress) -> dict:
    """Every option of :func:`run_batch` checked, before anything is written or run: the steps, the
    scans, ``out``, the options of every step whether chosen or not (a bad ``--expression`` is a typo
    either way; simulate's frames and memory, the rig's muscles), the executor's numbers. Returns
    the checked options (the keywords of the locked run). Raises :class:`InputError`, one line."""
    import math

    from ..core.limits import MAX_ADAPT_LEVELS, check_count, check_work, estimate_frames_bytes, estimate_sim_bytes
    from ..jobs.checks import check_kept_frames, check_some_frames
    from ..jobs.face import _check_simulate

    if isinstance(steps, str):
        steps = [s.strip() for s in steps.split(",") if s.strip()]
    try:
        wanted = set(steps)
    except TypeError:
        raise InputError(f"steps: expected some of {', '.join(STEPS)}, got {steps!r}") from None
    unknown = sorted(str(s) for s in wanted - set(STEPS))
    if unknown:
        raise InputError(f"steps: {unknown[0]!r} is not a step; choose some of {', '.join(STEPS)}")
    steps = tuple(s for s in STEPS if s in wanted)
    if not steps:
        raise InputError(f"steps: choose some of {', '.join(STEPS)}")
    if isinstance(scans, (str, bytes, os.PathLike)) or not hasattr(scans, "__iter__"):
        raise InputError(f"scans: expected a list of ScanInput, got {type(scans).__name__}")
    scans = list(scans)
    if not scans:
        raise InputError("batch: no scans given (SCANS... or --manifest IN.json)")
    bad = next((s for s in scans if not isinstance(s, ScanInput)), None)
    if bad is not None:
        raise InputError(f"scans: expected ScanInput entries (scans_from_paths, read_input_list), got {type(bad).__name__}")
    if not isinstance(out, (str, os.PathLike)) or not str(out).strip():
        raise InputError(f"out: expected a folder path, got {out!r}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"out {out}: exists and is not a folder")
    for s in scans:  # the batch folder is not a scan's: a scan or its landmarks inside a step's folder would be replaced
        for p in (s.scan, s.landmarks):
            if p is not None and _inside(Path(p), out / "scans"):
                raise InputError(f"out {out}: holds the input {p} in its scans/ folder (a step would replace it); "
                                 "choose another --out")
    if levels is not None:
        levels = check_count("levels", levels, high=MAX_ADAPT_LEVELS)
    # simulate's options as `facewarp simulate` checks them (expression, seconds, fps, jaw, steps)
    seconds, _, _, jaw = _check_simulate(str(expression) if isinstance(expression, os.PathLike) else expression,
                                         seconds, fps, None, jaw, "physical", None)
    fps = float(fps)
    check_some_frames(seconds, fps)
    check_kept_frames(seconds, fps)
    rig_formats, rig_inbetweens, rig_muscles = _rig_options(rig_formats, rig_inbetweens, rig_muscles)
    if rig_muscles is not None:
        rig_muscles = _expand_muscles(rig_muscles)
    if not isinstance(device, str) or not (device == "cpu" or device == "cuda" or (
            device.startswith("cuda:") and device[5:].isdigit())):
        raise InputError(f"device: expected cpu, cuda or cuda:N, got {device!r}")
    if ray is not None and (not isinstance(ray, str) or not ray.strip()):
        raise InputError(f"ray: expected None, 'local' or a cluster address (auto, ray://HOST:10001, HOST:6379), got {ray!r}")
    if workers is not None:
        workers = check_count("workers", workers, high=1024)
    if gpus_per_task is not None and not (isinstance(gpus_per_task, (int, float)) and not isinstance(gpus_per_task, bool)
                                          and math.isfinite(gpus_per_task) and 0 <= gpus_per_task <= 64):
        raise InputError(f"gpus_per_task: expected a number 0..64, got {gpus_per_task!r}")
    if not (isinstance(max_retries, int) and not isinstance(max_retries, bool) and 0 <= max_retries <= 100):
        raise InputError(f"max_retries: expected a whole number 0..100, got {max_retries!r}")
    if simulate_batch is not None and not (isinstance(simulate_batch, int) and not isinstance(simulate_batch, bool)
                                           and 1 <= simulate_batch <= MAX_SIMULATE_BATCH):
        raise InputError(f"simulate_batch: expected a whole number 1..{MAX_SIMULATE_BATCH}, got {simulate_batch!r}")
    if "simulate" in steps:  # a level-0 head of the default template per scan: memory, disk and time before the first adapt
        V, F = 3415, 6742
        frames = round(seconds * fps) + 1
        kept = estimate_sim_bytes(2 * V, 1.1 * F, frames, V)
        check_work(f"seconds, fps: {len(scans)} scans x {frames} frames", head_frames=len(scans) * frames,
                   vertex_count=V, device=device if ray is None else "cpu", memory_bytes=kept,
                   disk_bytes=len(scans) * frames * V * 12.0, folder=out)
    return {"steps": steps, "expression": expression, "seconds": seconds, "fps": fps, "levels": levels, "jaw": jaw,
            "rig_formats": rig_formats, "rig_inbetweens": rig_inbetweens, "rig_muscles": rig_muscles, "device": device,
            "ray": ray, "workers": workers, "gpus_per_task": gpus_per_task, "simulate_batch": simulate_batch,
            "max_retries": max_retries, "retry_failed": bool(retry_failed), "progress": bool(progress)}


def _inside(p: Path, folder: Path) -> bool:
    """Whether the path ``p`` is ``folder`` or lies under it (symbolic links resolved)."""
    try:
        p.resolve().relative_to(folder.resolve())
        return True
    except (ValueError, OSError):
        return False


def batch_outcome(summary: dict) -> tuple[int, str]:
    """The exit code of ``facewarp batch run`` and the words of its summary line, from the batch's
    totals: 0 every scan done; 1 some scans failed or are incomplete (a step failed or was skipped;
    the others are done); (2 is a batch refused before it started: :class:`InputError`)."""
    if summary["failed"] == 0 and summary["incomplete"] == 0:
        return 0, "all done"
    if summary["done"] == 0:
        return 1, "no scan done"
    return 1, "some scans not done"


def _run_batch_locked(scans: list[ScanInput], out: Path, *, t0: float, steps, expression, seconds, fps, levels, jaw,
                      rig_formats, rig_inbetweens, rig_muscles, device, ray, workers, gpus_per_task, simulate_batch,
                      max_retries, retry_failed, progress) -> dict:
    """:func:`run_batch` on checked options, ``out`` locked."""
    manifest = Manifest(out)
    keys: list[str] = []
    for s in scans:
        k = manifest.add(s)
        if k not in keys:
            keys.append(k)
    params = {s: _params(s, levels=levels, expression=expression, seconds=seconds, fps=fps, jaw=jaw,
                         rig_formats=rig_formats, rig_inbetweens=rig_inbetweens, rig_muscles=rig_muscles)
              for s in STEPS}

    # the plan: per scan the chosen steps still to run, the first one ready now
    todo: dict[str, list[str]] = {}
    missing: dict[str, tuple[str, str]] = {}  # scan -> (step, the step it reads: not chosen, not done before)
    kept = failed_kept = 0
    for key in keys:
        chain: list[str] = []
        blocked: dict[str, str | None] = {}  # step -> the reason its readers are skipped (None: left as recorded)
        for s in steps:
            rec = manifest.step(key, s)
            same = (rec is not None and rec.get("params") == params[s]
                    and not any(depends(s, c) for c in chain))  # its input is made again: so is it
            above = next((b for b in blocked if depends(s, b)), None)
            need = NEEDS[s]
            if same and rec["status"] == "done" and (manifest.folder(key) / s).is_dir():
                kept += 1
            elif above is not None:  # what it reads failed before or is missing
                blocked[s] = blocked[above]
                if blocked[s] is not None:
                    manifest.set_step(key, s, {"status": "skipped", "params": params[s], "error": blocked[s]})
            elif same and rec["status"] == "failed" and not retry_failed:
                failed_kept += 1
                blocked[s] = None  # the scan stays failed at this step; the steps reading it stay as recorded
            elif need is not None and need not in chain and not (
                    (manifest.step(key, need) or {}).get("status") == "done"
                    and (manifest.folder(key) / need).is_dir()):
                failed = (manifest.step(key, need) or {}).get("status") == "failed"
                blocked[s] = f"{need} failed" if failed else f"needs {need} done first (add it to --steps)"
                missing.setdefault(key, (s, need))
                manifest.set_step(key, s, {"status": "skipped", "params": params[s], "error": blocked[s]})
            else:
                chain.append(s)
        if chain:
            todo[key] = chain
    if not todo and len(missing) == len(keys):  # nothing can run: say so before writing anything
        s, need = missing[keys[0]]
        raise InputError(f"--steps {','.join(steps)}: {s} needs {need} done first, and no scan has it done in "
                         f"{manifest.path} (add {need} to --steps)")
    # the workers (or the Ray cluster) before anything is written: a cluster that cannot be reached
    # leaves no manifest
    if ray is None:
        from .executors import LocalExecutor

        n = workers or (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)
        executor = LocalExecutor(n, gpus_per_task=gpus_per_task)
    else:
        from .executors import RayExecutor

        executor = RayExecutor(None if ray == "local" else ray, workers=workers, gpus_per_task=gpus_per_task,
                               max_retries=max_retries)
    try:
        manifest.save()
    except OSError as e:
        executor.close()
        raise InputError(f"out {out}: cannot write the manifest ({e.strerror or e})") from None
    except BaseException:
        executor.close()
        raise

    if simulate_batch is None:
        simulate_batch = GPU_SIMULATE_BATCH if executor.device("simulate", device).startswith("cuda") else 1
    total = sum(len(c) for c in todo.values())
    counts = {"done": 0, "failed": 0}
    grouping = {"batch": simulate_batch, "groups": 0, "grouped_scans": 0, "fallbacks": 0, "fallback_errors": []}
    held: list[str] = []  # scans whose simulate waits for its group
    # scans with a simulate still ahead of their current step: they may join a group that waits
    coming = {k for k, c in todo.items() if "simulate" in c[1:]}
    bar = _Bar(total, 0, progress)
    ready = []
    for k in (k for k in keys if k in todo):  # a scan whose build is kept: its simulate waits for its group
        (held if todo[k][0] == "simulate" and simulate_batch > 1 else ready).append(k)
    inflight: dict = {}  # handle -> (key, step, task)
    attempts: dict[tuple[str, str], int] = {}
    interrupted: KeyboardInterrupt | None = None
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
        if record.get("group_fallback"):
            grouping["fallbacks"] += 1
            if record["group_fallback"] not in grouping["fallback_errors"]:
                grouping["fallback_errors"].append(record["group_fallback"])
        manifest.set_step(key, step, record)
        chain = todo[key]
        chain.pop(0)
        if record["status"] == "done":
            counts["done"] += 1
            for later in STEPS:  # made from the old output: no longer valid
                if depends(later, step) and later not in chain:
                    manifest.scans[key]["steps"].pop(later, None)
        else:
            counts["failed"] += 1
            readers = [s for s in chain if depends(s, step)]
            for s in readers:
                manifest.set_step(key, s, {"status": "skipped", "params": params[s], "error": f"{step} failed"})
            chain[:] = [s for s in chain if s not in readers]  # a failed simulation does not stop the rig
            bar.show(counts["done"], counts["failed"], len(inflight), advance=len(readers))
        if key in coming and "simulate" not in chain[1:]:
            coming.discard(key)  # its simulate is next (it joins the held ones) or no longer comes
        if chain and chain[0] == "simulate" and simulate_batch > 1:
            held.append(key)  # waits for its group (no slot taken)
        elif chain:
            ready.append(key)
        else:
            del todo[key]
        saver.changed()

    def submit_group(group: list[str]) -> None:
        if len(group) == 1:  # a group of one: the ordinary task
            task = task_of(group[0], "simulate")
            inflight[executor.submit(task)] = (group[0], "simulate", task)
            return
        members = [task_of(k, "simulate") for k in group]
        task = {"step": "simulate", "group": members, "out": members[0]["out"], "params": params["simulate"],
                "device": members[0]["device"], "name": ",".join(m["name"] for m in members)}
        inflight[executor.submit(task)] = (tuple(group), "simulate", task)
        grouping["groups"] += 1
        grouping["grouped_scans"] += len(group)

    try:
        bar.show(0, 0, 0)
        while ready or inflight or held:
            while ready and len(inflight) < executor.capacity:
                key = ready.pop(0)
                step = todo[key][0]
                task = task_of(key, step)
                inflight[executor.submit(task)] = (key, step, task)
            # a group leaves when full, or when no scan on its way to simulate could still join it
            while held and len(inflight) < executor.capacity and (len(held) >= simulate_batch or not coming):
                group, held[:] = held[:simulate_batch], held[simulate_batch:]
                submit_group(group)
            bar.show(counts["done"], counts["failed"], len(inflight))
            if not inflight:
                continue
            for handle, record, died in executor.wait(inflight, timeout=0.5):
                key, step, task = inflight.pop(handle)
                group = list(key) if isinstance(key, tuple) else [key]
                if record is None:
                    n = attempts.get((group[0], step), 0) + 1
                    if not executor.retries_inside and n <= max_retries:
                        for k in group:
                            attempts[(k, step)] = n
                        inflight[executor.submit(task)] = (key, step, task)
                        continue
                    dead = {"status": "failed", "error": died + (f" ({n} attempts)" if not executor.retries_inside
                                                                 else ""),
                            "outputs": [], "summary": {}, "seconds": None, "worker": None}
                    if len(group) > 1:
                        dead["batched_with"] = len(group)
                    records = [dead] * len(group)
                    for k in group:
                        attempts[(k, step)] = n - 1 if not executor.retries_inside else max_retries
                else:
                    records = record if isinstance(record, list) else [record]
                for k, r in zip(group, records):
                    finish(k, step, r)
                bar.show(counts["done"], counts["failed"], len(inflight), advance=len(group))
            saver.tick()
    except KeyboardInterrupt as e:  # SIGINT or SIGTERM (core.outputs.Interrupted keeps which)
        from ..core.outputs import Interrupted, interrupted_by

        # a library on the way (Ray's wait) may re-raise a bare KeyboardInterrupt: the signal that came says which
        interrupted = Interrupted(interrupted_by()) if not isinstance(e, Interrupted) and interrupted_by() else e
    finally:
        bar.close()
        executor.close(abort=bool(inflight) or interrupted is not None, handles=list(inflight))
        for key, step, _ in inflight.values():  # killed halfway: no half-written step folder stays
            for k in key if isinstance(key, tuple) else (key,):
                shutil.rmtree(manifest.folder(k) / f".{step}.partial", ignore_errors=True)
        manifest.save()
    summary = write_reports(manifest, keys)
    summary.update(executor=executor.description, tasks_run=counts["done"] + counts["failed"], tasks_kept=kept,
                   tasks_failed_kept=failed_kept, seconds=round(time.perf_counter() - t0, 3),
                   interrupted=interrupted is not None, steps=list(steps), simulate_grouping=grouping)
    summary["exit_code"], summary["outcome"] = batch_outcome(summary)
    if interrupted is not None:
        raise interrupted
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
