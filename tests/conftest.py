"""Shared pytest fixtures: the shared data folder and the Warp devices to test on."""

from __future__ import annotations

import os
from pathlib import Path

import itertools

import numpy as np
import pytest

from facewarp.geometry import signed_tet_volumes

# progress off a terminal is plain lines on stderr (CI, nohup, | tee); the tests read stderr for the
# one-line errors, so they run without progress unless a test asks for it (tests/test_cli_usability.py)
os.environ.setdefault("FACEWARP_PROGRESS", "off")


def shared_dir() -> Path:
    """The shared data folder: $FACEWARP_SHARED, else ``shared/`` beside the repository root."""
    env = os.environ.get("FACEWARP_SHARED")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(scope="session")
def ict_dir() -> Path:
    """The ICT-FaceKit data folder; skips the test when it is absent."""
    d = shared_dir() / "data" / "ict-facekit"
    if not (d / "generic_neutral_mesh.obj").is_file():
        pytest.skip(f"ICT-FaceKit data not found at {d} (set FACEWARP_SHARED to the shared folder)")
    return d


def warp_devices() -> list[str]:
    """Warp devices to run device tests on: "cpu" always, "cuda:0" when a GPU is present."""
    devices = ["cpu"]
    try:
        import warp as wp

        wp.config.quiet = True  # as facewarp runs it (no banner, no "no CUDA driver" note)
        if wp.get_cuda_device_count() > 0:
            devices.append("cuda:0")
    except Exception:  # no Warp: the device tests themselves will fail loudly
        pass
    return devices


def pytest_generate_tests(metafunc):
    """Run every test that takes a ``device`` argument on each of :func:`warp_devices`."""
    if "device" in metafunc.fixturenames:
        metafunc.parametrize("device", warp_devices())


def grid_tets(nx: int, ny: int, nz: int, h: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Test fixture: a box of nx x ny x nz cubes of side h, each split into 6 tets (Kuhn), all oriented
    positively; vertex index = (k * (ny + 1) + j) * (nx + 1) + i."""
    g = np.stack(np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij"), -1)
    V = g.transpose(2, 1, 0, 3).reshape(-1, 3).astype(np.float64) * h

    def vid(i, j, k):
        return (k * (ny + 1) + j) * (nx + 1) + i

    T = []
    for i, j, k in itertools.product(range(nx), range(ny), range(nz)):
        for perm in itertools.permutations(range(3)):
            c = np.array([i, j, k])
            tet = [vid(*c)]
            for axis in perm:
                c = c.copy()
                c[axis] += 1
                tet.append(vid(*c))
            T.append(tet)
    T = np.array(T)
    neg = signed_tet_volumes(V, T) < 0
    T[neg] = T[neg][:, [0, 2, 1, 3]]
    return V, T


def step_together(batch, alone, es):
    """One frame of the batch and of each head's simulator alone, the same expressions (head i: es[i])."""
    batch.set_activations(es)
    batch.set_jaw(np.array([[e.jaw_u, e.jaw_v] for e in es]))
    batch.step()
    for sim, e in zip(alone, es):
        sim.set_activations(e)
        sim.set_jaw(e.jaw_u, e.jaw_v)
        sim.step()
