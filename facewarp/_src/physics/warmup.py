"""The first run: every Warp module a simulation launches, compiled up front and side by side.

Warp compiles a module the first time one of its kernels is launched, one module after another,
inside the first frames. :func:`load_kernels` loads them all before the first step with
``wp.force_load(..., max_workers=...)``, which compiles the modules not in the kernel cache in
parallel threads, and says on stderr that it does so and how long it took (a first run off a
terminal shows a line, not a silence of minutes). A warm run (everything in the cache) loads the
binaries and prints nothing.
"""

from __future__ import annotations

import os
import sys
import time

import warp as wp  # as the kernel modules: Warp is set up by the time a Model exists (core.warp)

__all__ = ["load_kernels", "solver_kernel_modules"]


def solver_kernel_modules(solver) -> list:
    """The Python modules of the kernels a face simulation with ``solver`` launches (tissue, muscles,
    contact; the implicit step's potential, Hessian and line search; the device solver's linear solve)."""
    from . import kernels_contact, kernels_muscle, kernels_tissue
    from .solvers.implicit import SolverImplicit
    from .solvers.newton_pcg import SolverDeviceNewtonPCG

    mods = [kernels_tissue, kernels_muscle, kernels_contact]
    if isinstance(solver, SolverImplicit):
        from .solvers import kernels_hessian, kernels_line_search, kernels_potential

        mods += [kernels_potential, kernels_hessian, kernels_line_search]
        if isinstance(solver, SolverDeviceNewtonPCG):
            from .solvers import kernels_linear

            mods.append(kernels_linear)
    return mods


def _cached(module, device) -> bool:
    """Whether ``module`` (a Warp module) has a binary for ``device`` in the kernel cache (best effort:
    the cache's folder naming; False when it cannot tell)."""
    try:
        ident = module.get_module_identifier(1 if device.is_cpu else None)
        folder = os.path.join(wp.config.kernel_cache_dir, ident)
        return os.path.isdir(folder) and any(os.scandir(folder))
    except Exception:  # another Warp's cache layout: say nothing was cached
        return False


def load_kernels(device, modules, *, max_workers: int | None = None, out=None) -> float:
    """Load (compile where not cached) the Warp modules of ``modules`` (Python modules with kernels)
    on ``device``, in parallel threads.

    Args:
        device: A Warp device or its name.
        modules: Python modules holding Warp kernels (e.g. :func:`solver_kernel_modules`).
        max_workers: Threads compiling side by side (default: one per module, at most the CPU count).
        out: Where the first-run lines go (default ``sys.stderr``); nothing is written when every
            module is cached, or when ``FACEWARP_PROGRESS=off`` (tests, ``--json``) and no ``out`` is given.

    Returns:
        The seconds the loading took.
    """
    dev = wp.get_device(device)
    mods, seen = [], set()
    for m in modules:
        if m.__name__ not in seen:
            seen.add(m.__name__)
            mods.append(wp.get_module(m.__name__))
    cold = [m for m in mods if not _cached(m, dev)]
    quiet = out is None and os.environ.get("FACEWARP_PROGRESS", "").strip().lower() == "off"
    out = sys.stderr if out is None else out
    workers = max_workers if max_workers is not None else max(1, min(len(mods), os.cpu_count() or 1))
    if cold and not quiet:
        print(f"facewarp: compiling {len(cold)} Warp kernel module(s) for {dev} with {workers} thread(s) "
              "(first run only; later runs load them from the kernel cache) ...", file=out, flush=True)
    t0 = time.perf_counter()
    wp.force_load(device=dev, modules=mods, max_workers=workers)
    seconds = time.perf_counter() - t0
    if cold and not quiet:
        print(f"facewarp: Warp kernels compiled in {seconds:.0f} s", file=out, flush=True)
    return seconds
