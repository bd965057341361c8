"""The adaptation runs its dense algebra on one OpenBLAS thread and gives the caller's thread
counts back (NumPy's and SciPy's OpenBLAS, read here through their own C entry points)."""

from __future__ import annotations

import ctypes
import sys

import numpy as np
import pytest


def _openblas_thread_counts() -> dict:
    import scipy.linalg  # noqa: F401  (loads SciPy's own OpenBLAS beside NumPy's)

    out = {}
    with open("/proc/self/maps") as f:
        paths = {c[5] for c in (line.split() for line in f) if len(c) >= 6 and "openblas" in c[5].rsplit("/", 1)[-1]}
    for p in sorted(paths):
        lib = ctypes.CDLL(p)
        for name in ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads"):
            g = getattr(lib, name, None)
            if g is not None:
                out[p] = int(g())
                break
    return out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="OpenBLAS libraries are found in /proc/self/maps")
def test_adapt_gives_the_blas_threads_back():
    import facewarp as fw
    from facewarp import adapt

    before = _openblas_thread_counts()
    if not before:
        pytest.skip("no OpenBLAS loaded")
    t = fw.default_template(0)
    lm = {k: v for k, v in t.landmarks().items() if t.fdp[k][0] == "head"}
    S = np.diag([1.04, 0.97, 1.01])
    res = adapt(t.vertices, t.faces, lm, t.vertices @ S, t.faces, {k: v @ S for k, v in lm.items()}, levels=1)
    assert np.isfinite(res.vertices).all()
    assert _openblas_thread_counts() == before
    with pytest.raises(fw.InputError):  # and after an error inside
        adapt(t.vertices, t.faces, lm, t.vertices @ S, t.faces, {k: v @ S for k, v in list(lm.items())[:2]})
    assert _openblas_thread_counts() == before
