"""Shared pytest fixtures: the shared data folder and the Warp devices to test on."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


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
