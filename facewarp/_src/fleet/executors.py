"""Where the tasks of a batch run: local worker processes, or Ray tasks (local or on a cluster).

Both executors offer the same four calls to the batch loop (:mod:`~facewarp._src.fleet.batch`):
``capacity`` (tasks kept in flight), ``submit(task) -> handle``, ``wait(handles, timeout)`` (the
finished ones, each with its record or the one-line reason its worker died) and ``close(abort)``.

- :class:`LocalExecutor`: ``workers`` processes (``spawn``), each a one-process
  :class:`concurrent.futures.ProcessPoolExecutor`, so a worker that dies (killed, out of memory)
  breaks only its own pool: that task is known, its slot gets a fresh process and the batch loop
  retries the task (``retries_inside`` False). The steps run on the batch's ``device``, except
  that with ``gpus_per_task`` > 0 on a machine with a CUDA device the physics steps (simulate,
  rig) run on ``cuda`` (the workers share it).
- :class:`RayExecutor`: :func:`~facewarp._src.fleet.tasks.run_step` as a Ray task, adapt and build
  with ``num_cpus=1``, simulate and rig with ``num_gpus=F`` and ``device="cuda"`` when the cluster
  has GPUs; Ray retries a task whose worker died up to ``max_retries`` times (``retries_inside``
  True) and reports it failed after.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import signal

from ..core.errors import InputError
from .manifest import GPU_STEPS
from .tasks import init_worker, run_step

__all__ = ["LocalExecutor", "RayExecutor", "cuda_device_count"]


def cuda_device_count() -> int:
    """CUDA devices Warp sees on this machine (0 without a GPU or a driver)."""
    from ..core.warp import get_warp

    try:
        return int(get_warp().get_cuda_device_count())
    except Exception:  # no driver, a broken CUDA install: no GPU for the batch
        return 0


class LocalExecutor:
    """``workers`` local worker processes (spawn start method); ``gpus_per_task`` > 0: simulate and
    rig on ``cuda`` when this machine has a CUDA device."""

    retries_inside = False

    def __init__(self, workers: int, *, gpus_per_task: float | None = None):
        self.capacity = int(workers)
        self.gpu = bool(gpus_per_task) and cuda_device_count() > 0
        self.description = f"local processes ({self.capacity}" + (", simulate and rig on cuda)" if self.gpu else ")")
        self._ctx = multiprocessing.get_context("spawn")
        self._free: list[cf.ProcessPoolExecutor] = []
        self._busy: dict[cf.Future, tuple[cf.ProcessPoolExecutor, int]] = {}
        self._pids: dict[cf.ProcessPoolExecutor, int] = {}

    def _slot(self) -> cf.ProcessPoolExecutor:
        if self._free:
            return self._free.pop()
        pool = cf.ProcessPoolExecutor(1, mp_context=self._ctx, initializer=init_worker)
        self._pids[pool] = pool.submit(os.getpid).result()
        return pool

    def submit(self, task: dict):
        pool = self._slot()
        fut = pool.submit(run_step, task)
        self._busy[fut] = (pool, self._pids[pool])
        return fut

    def device(self, step: str, device: str) -> str:
        """The batch's device; the physics steps on ``cuda`` when a GPU was asked for and is here."""
        return "cuda" if self.gpu and step in GPU_STEPS else device

    def wait(self, handles, timeout: float) -> list[tuple[object, dict | None, str | None]]:
        """(handle, record, None) per finished task, or (handle, None, why) when its worker died."""
        done, _ = cf.wait(list(handles), timeout=timeout, return_when=cf.FIRST_COMPLETED)
        out = []
        for fut in done:
            pool, pid = self._busy.pop(fut)
            try:
                out.append((fut, fut.result(), None))
                self._free.append(pool)
            except cf.process.BrokenProcessPool:
                pool.shutdown(wait=False, cancel_futures=True)
                self._pids.pop(pool, None)
                out.append((fut, None, f"the worker process (pid {pid}) died"))
        return out

    def close(self, abort: bool = False, handles=()) -> None:
        """Stop the workers; with ``abort`` the running tasks are killed (Ctrl-C)."""
        pools = self._free + [p for p, _ in self._busy.values()]
        if abort:
            for pool, pid in self._busy.values():
                try:
                    os.kill(pid, signal.SIGTERM)
                except OSError:
                    pass
        for pool in pools:
            pool.shutdown(wait=True, cancel_futures=True)
        self._free, self._busy, self._pids = [], {}, {}


class RayExecutor:
    """Ray tasks on a local Ray (``address`` None: started here with ``workers`` CPUs) or on a
    running cluster (``auto``, ``ray://HOST:10001``, ``HOST:6379``)."""

    retries_inside = True

    def __init__(self, address: str | None, *, workers: int | None, gpus_per_task: float | None, max_retries: int):
        try:
            import ray
        except ImportError:
            raise InputError("--ray: Ray is not installed (pip install 'facewarp[ray]')") from None
        self.ray = ray
        self._owned = not ray.is_initialized()
        if self._owned:
            kw = {"log_to_driver": False}
            if address is None:
                kw.update(num_cpus=workers, include_dashboard=False)
            else:
                kw["address"] = address
            _init_ray(ray, address, kw)
        res = ray.cluster_resources()
        cpus, gpus = int(res.get("CPU", 1)), float(res.get("GPU", 0.0))
        self.capacity = int(workers) if workers else max(cpus, 1)
        if gpus_per_task is None:
            gpus_per_task = 1.0 if gpus > 0 else 0.0
        if gpus_per_task > 0 and gpus <= 0:
            gpus_per_task = 0.0  # no GPU in the cluster: simulate on the CPU
        self.gpus_per_task = gpus_per_task
        if gpus_per_task > 0:  # enough simulations in flight to fill the GPUs as well as the CPUs
            self.capacity = max(self.capacity, int(gpus / gpus_per_task))
        self.description = (f"Ray {'local' if address is None else address} ({cpus} CPUs, {gpus:g} GPUs"
                            + (f", {gpus_per_task:g} GPU per simulate or rig task" if gpus_per_task else "") + ")")
        self.max_retries = int(max_retries)
        self._remote = ray.remote(max_retries=self.max_retries, retry_exceptions=False)(run_step)
        self._refs: dict = {}

    def device(self, step: str, device: str) -> str:
        """Adapt and build are CPU tasks; simulate and rig run on the task's GPU when one was asked for
        (Ray sets the worker's ``CUDA_VISIBLE_DEVICES``, so ``cuda`` is that GPU)."""
        return "cuda" if step in GPU_STEPS and self.gpus_per_task > 0 else "cpu"

    def submit(self, task: dict):
        if task["step"] in GPU_STEPS and self.gpus_per_task > 0:
            opts = {"num_cpus": 1, "num_gpus": self.gpus_per_task}
        else:
            opts = {"num_cpus": 1}
        return self._remote.options(**opts).remote(task)

    def wait(self, handles, timeout: float):
        ray = self.ray
        ready, _ = ray.wait(list(handles), num_returns=1, timeout=timeout)
        out = []
        for ref in ready:
            try:
                out.append((ref, ray.get(ref), None))
            except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError) as e:
                why = " ".join(str(e).split())[:200]
                out.append((ref, None, f"the Ray worker died {self.max_retries + 1} times ({why})"))
            except ray.exceptions.RayError as e:
                out.append((ref, None, f"Ray: {type(e).__name__}: {' '.join(str(e).split())[:200]}"))
        return out

    def close(self, abort: bool = False, handles=()) -> None:
        """Shut down; with ``abort`` the running tasks are cancelled (their workers killed) and
        waited for (at most :data:`CANCEL_WAIT` s), so none still writes its step folder once the
        batch removes it."""
        if abort:
            for ref in handles:
                try:
                    self.ray.cancel(ref, force=True)
                except Exception:  # already finished, or the cluster went away
                    pass
            if handles:
                try:
                    self.ray.wait(list(handles), num_returns=len(handles), timeout=CANCEL_WAIT)
                except Exception:  # the cluster went away: nothing runs there any more
                    pass
        if self._owned:
            self.ray.shutdown()


CANCEL_WAIT = 10.0
"""Seconds :meth:`RayExecutor.close` waits for cancelled tasks to end."""


def _init_ray(ray, address, kw: dict) -> None:
    """``ray.init(**kw)``, and the process's own SIGINT / SIGTERM handlers put back after it:
    ``ray.init`` installs a SIGTERM handler that exits the driver (``sys.exit``) past the batch
    loop's clean-up, which then died in Ray's shutdown with SIGABRT and left half-written step
    folders and no report. With the handlers of the CLI
    (:func:`~facewarp._src.core.outputs.signals_as_exceptions`) a SIGTERM is an ``Interrupted``
    the loop handles: tasks cancelled, partial folders removed, reports written, Ray shut down,
    exit 143. A SIGTERM while ``ray.init`` runs (Ray's handler, ``SystemExit(15)``) is turned into
    that ``Interrupted`` too. (Signals are not blocked meanwhile: Ray's daemons started here would
    inherit the blocked mask and not stop on ``ray.shutdown``.)"""
    from ..core.outputs import Interrupted

    import logging
    import warnings

    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with warnings.catch_warnings():  # Ray Client's UserWarnings (a connection timeout): our one line says it
            warnings.simplefilter("ignore")
            ray.init(**kw, logging_level=logging.ERROR)
    except SystemExit as e:
        if e.code == signal.SIGTERM:
            raise Interrupted(signal.SIGTERM) from None
        raise
    except ConnectionError as e:
        raise InputError(f"--ray {address}: cannot connect to the Ray cluster ({' '.join(str(e).split())})") from None
    except RuntimeError as e:
        text = " ".join(str(e).split())
        if "pip install" in text or "requires pip package" in text:  # ray:// without the client extra
            raise InputError(f"--ray {address}: {text} (pip install 'facewarp[ray]')") from None
        raise
    finally:
        for s, h in handlers.items():
            if h is not None:
                signal.signal(s, h)
