"""The adaptation's one-BLAS-thread block (facewarp._src.adapt.threads)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from facewarp._src.adapt.threads import _openblas_handles, single_blas_thread


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="OpenBLAS libraries are found in /proc/self/maps")
def test_single_blas_thread_sets_one_and_restores():
    import scipy.linalg  # noqa: F401  (loads SciPy's own OpenBLAS beside NumPy's)

    handles = _openblas_handles()
    if not handles:
        pytest.skip("no OpenBLAS loaded (another BLAS: the block runs unchanged)")
    before = [g() for g, _ in handles]
    with single_blas_thread() as n:
        assert n == len(handles)
        assert [g() for g, _ in handles] == [1] * len(handles)
        A = np.random.default_rng(0).normal(size=(50, 50))
        np.testing.assert_allclose(np.linalg.inv(A) @ A, np.eye(50), atol=1e-9)  # BLAS still works
    assert [g() for g, _ in handles] == before


def test_single_blas_thread_restores_after_an_error():
    handles = _openblas_handles()
    before = [g() for g, _ in handles]
    with pytest.raises(RuntimeError):
        with single_blas_thread():
            raise RuntimeError("inside")
    assert [g() for g, _ in handles] == before
