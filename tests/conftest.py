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


# --- builds made once per test run -------------------------------------------------------------------------------
# `facewarp build default` takes ~8 s and a dozen modules need one; under pytest-xdist every worker is its own
# process, so the build is made once under a file lock in the run's shared temporary folder and each module gets a
# private copy (tests may damage their copy: permissions, truncated files).


def _run_root(tmp_path_factory) -> Path:
    """The temporary folder shared by every xdist worker of this run (the worker's own base folder's parent)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


class _FileLock:
    """An exclusive lock on a file (fcntl on POSIX; on other systems a lock directory polled every 0.1 s)."""

    def __init__(self, path: Path):
        self.path = path

    def __enter__(self):
        try:
            import fcntl
        except ImportError:  # pragma: no cover - Windows
            import time

            while True:
                try:
                    os.mkdir(self.path)
                    break
                except FileExistsError:
                    time.sleep(0.1)
            self._fd = None
            return self
        self._fd = open(self.path, "w")
        fcntl.flock(self._fd, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc):
        if self._fd is None:  # pragma: no cover - Windows
            os.rmdir(self.path)
        else:
            self._fd.close()


def shared_build(tmp_path_factory, name: str, argv: list[str]) -> Path:
    """The output folder of ``facewarp <argv> --out DIR``, made once per run for every worker (``name`` keys it)."""
    import shutil

    from facewarp.cli import main

    root = _run_root(tmp_path_factory)
    target = root / f"shared-{name}"
    with _FileLock(root / f"shared-{name}.lock"):
        if not target.is_dir():
            partial = root / f"shared-{name}.partial"
            shutil.rmtree(partial, ignore_errors=True)
            assert main([*argv, "--out", str(partial)]) == 0, f"facewarp {' '.join(argv)} failed"
            partial.rename(target)
    return target


@pytest.fixture(scope="session")
def default_build_dir(tmp_path_factory) -> Path:
    """`facewarp build default` made once per run; read-only by convention (copy it with :func:`fresh_build`)."""
    return shared_build(tmp_path_factory, "build-default", ["build", "default"])


def fresh_build(tmp_path_factory, default_build_dir: Path, name: str = "build") -> Path:
    """A private copy of the run's default build, for a module that writes into or damages its build."""
    import shutil

    out = tmp_path_factory.mktemp(name) / "build"
    shutil.copytree(default_build_dir, out)
    return out


@pytest.fixture(scope="session")
def default_rig():
    """``fw.build_face(fw.default_template(0))``, made once per worker process (treat it as read-only)."""
    import facewarp as fw

    return fw.build_face(fw.default_template(0))
