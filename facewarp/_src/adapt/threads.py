"""One BLAS thread for the adaptation's small dense algebra.

The adaptation's dense problems are small (the field stage's normal matrix is 3 x (centres + 4)
square, a few hundred rows; its products are (samples x centres)), far below the size where
OpenBLAS's threads pay. On a busy machine those threads hurt: OpenBLAS's workers spin while they
wait for a core, so a 0.5 ms Cholesky factorisation took 0.6 s on the two shared cores of the
development box with ten other processes running (the whole ``facewarp adapt`` 37 s wall instead
of 6 s). :func:`single_blas_thread` sets every OpenBLAS loaded in the process (NumPy's and
SciPy's own copies) to one thread for the block and puts the old counts back afterwards.

The libraries are found in ``/proc/self/maps`` (Linux); elsewhere, or for a BLAS without
OpenBLAS's ``*_set_num_threads`` entry points (MKL, Accelerate), the block runs unchanged.
"""

from __future__ import annotations

import contextlib
import ctypes
import sys

__all__ = ["single_blas_thread"]

_SETTERS = (("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
            ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
            ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
            ("openblas_get_num_threads", "openblas_set_num_threads"))


def _openblas_handles() -> list[tuple]:
    """(get, set) function pairs of every OpenBLAS shared library mapped into this process."""
    if not sys.platform.startswith("linux"):
        return []
    try:
        with open("/proc/self/maps") as f:
            paths = {cols[5] for cols in (line.split() for line in f) if len(cols) >= 6}
    except OSError:
        return []
    out = []
    for p in sorted(paths):
        if "openblas" not in p.rsplit("/", 1)[-1].lower():
            continue
        try:
            lib = ctypes.CDLL(p)
        except OSError:
            continue
        for get, put in _SETTERS:
            g, s = getattr(lib, get, None), getattr(lib, put, None)
            if g is not None and s is not None:
                g.restype = ctypes.c_int
                s.argtypes = [ctypes.c_int]
                out.append((g, s))
                break
    return out


@contextlib.contextmanager
def single_blas_thread():
    """Run the block with one OpenBLAS thread in every loaded OpenBLAS; restore the counts after."""
    import numpy  # noqa: F401  (NumPy's and SciPy's BLAS are loaded before they are looked up)
    import scipy.linalg  # noqa: F401

    handles = _openblas_handles()
    old = []
    for g, s in handles:
        try:
            old.append((s, int(g())))
            s(1)
        except Exception:  # noqa: BLE001 - a library that refuses keeps its threads
            continue
    try:
        yield len(old)
    finally:
        for s, n in old:
            with contextlib.suppress(Exception):
                s(max(n, 1))
