"""Helpers shared by the benchmarks: machine description, shared data folder, result files."""

from __future__ import annotations

import json
import os
import platform
import sys
from datetime import datetime, timezone
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def shared_dir() -> Path:
    env = os.environ.get("FACEWARP_SHARED")
    return Path(env) if env else Path(__file__).resolve().parents[1].parent / "shared"


def machine(device: str = "cpu") -> dict:
    import numpy as np
    import warp as wp

    info = {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "warp": wp.__version__,
        "device": device,
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    if device.startswith("cuda"):
        wp.init()
        info["device_name"] = wp.get_device(device).name
    return info


def _plain(obj):
    """JSON form of NumPy arrays and scalars (``tolist``) and of paths (``str``)."""
    return obj.tolist() if hasattr(obj, "tolist") else str(obj)


def save(name: str, data: dict) -> Path:
    """Write ``benchmarks/results/<name>.json`` (NaN and infinity are refused: not JSON)."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    text = json.dumps(data, indent=2, default=_plain, allow_nan=False) + "\n"
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)  # a failed run leaves the old results
    return path
