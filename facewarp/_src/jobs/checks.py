"""Checks shared by the file-level jobs: output folders, done before any heavy work."""

from __future__ import annotations

import os
from pathlib import Path

from ..core.errors import InputError

__all__ = ["check_out_dir", "make_out_dir"]


def check_out_dir(out) -> Path:
    """``out`` as a Path; raises :class:`InputError` when it exists and is not a folder (no side effects)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"out {out}: exists and is not a folder")
    return out


def make_out_dir(out) -> Path:
    """Create the output folder ``out`` (with its parents) and check that it is writable.

    Called after the inputs are read and checked and before the long work, so that a folder
    that cannot be written fails in seconds rather than after the simulation.

    Raises:
        InputError: ``out`` exists and is not a folder, cannot be created (a parent is a
            file, no permission, read-only file system) or is not writable.
    """
    out = check_out_dir(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"out {out}: cannot create the folder ({e.strerror or e})") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"out {out}: the folder is not writable")
    return out
