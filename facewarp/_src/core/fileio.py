"""Atomic file writing shared by every writer in facewarp.

A writer never leaves a half-written file behind: it writes to a temporary file in the
target's folder and renames it over the target only once everything was written
(:func:`os.replace` is atomic on POSIX and Windows when both paths are on one file system).
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from .errors import InputError

__all__ = ["atomic_write", "write_json"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", *, encoding: str | None = "utf-8") -> Iterator[IO]:
    """Open a temporary file beside ``path``; on success rename it to ``path``.

    If the ``with`` body raises, the temporary file is deleted and ``path`` is left as it
    was (absent, or with its old contents). The new file gets the usual permissions
    (``0o666`` less the umask), not the private ones of a temporary file.

    Args:
        path: Destination file. Its folder must exist.
        mode: ``"w"`` (text) or ``"wb"`` (binary).
        encoding: Text encoding; ignored for binary mode.

    Yields:
        The open temporary file object.

    Raises:
        InputError: ``path`` is a folder, or its folder does not exist.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file path to write")
    if not folder.is_dir():
        raise InputError(f"{path}: folder {folder} does not exist")

    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    try:
        if "b" in mode:
            f = os.fdopen(fd, mode)
        else:
            f = os.fdopen(fd, mode, encoding=encoding, newline="\n")
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp_name, 0o666 & ~_umask())
        os.replace(tmp_name, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp_name)
        raise


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"object of type {type(obj).__name__} is not JSON serialisable")


def write_json(path: str | os.PathLike, obj: Any, *, indent: int | None = 2) -> None:
    """Write ``obj`` as JSON to ``path`` atomically (see :func:`atomic_write`).

    NumPy arrays and scalars are converted to lists and Python numbers. NaN and infinity are
    rejected (``ValueError``) because they are not valid JSON; the target is left untouched.

    Args:
        path: Destination file.
        obj: JSON-serialisable object (dicts, lists, str, numbers, bools, None, numpy values).
        indent: Indentation passed to :func:`json.dump`.
    """
    with atomic_write(path, "w") as f:
        json.dump(obj, f, indent=indent, default=_json_default, allow_nan=False)
        f.write("\n")
