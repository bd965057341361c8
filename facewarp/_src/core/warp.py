"""Warp, imported and initialised once, quietly (the one place that does it).

Warp is imported lazily (never at package import, so ``facewarp --help`` stays fast) and its
informational output is off unless ``FACEWARP_VERBOSE=1`` is set (the CLI's ``--verbose`` sets
it). The library never calls ``wp.set_device``.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading

__all__ = ["get_warp", "verbose"]

_lock = threading.Lock()
_ready = False


def verbose() -> bool:
    """Whether Warp may print (``FACEWARP_VERBOSE`` set to a non-empty value other than 0)."""
    return os.environ.get("FACEWARP_VERBOSE", "") not in ("", "0")


@contextlib.contextmanager
def _native_stderr_silenced():
    """Point file descriptor 2 at /dev/null for the duration (C code that prints to stderr).

    Warp's native library prints "Warp CUDA warning: Could not find or load the NVIDIA CUDA
    driver" with ``fprintf(stderr, ...)`` from ``wp_init`` on machines without a GPU, whatever
    ``wp.config`` says; only the file descriptor can hold it back.
    """
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no usable fd 2 (embedded interpreters)
        yield
        return
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, 2)
        finally:
            os.close(devnull)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def get_warp():
    """Import and initialise Warp once; returns the ``warp`` module.

    Quiet unless :func:`verbose`: the banner and kernel-load messages are off
    (``wp.config.quiet``, and ``wp.config.log_level`` where Warp has one), and the native
    "could not find the CUDA driver" note on machines without a GPU is held back by
    silencing file descriptor 2 while ``wp.init()`` runs; so errors stay one line and stdout
    stays for results. A failure of ``wp.init()`` itself still raises.
    """
    global _ready
    import warp as wp

    if not _ready:
        with _lock:
            if not _ready:
                loud = verbose()
                wp.config.quiet = not loud
                if hasattr(wp, "LOG_WARNING") and not loud:
                    wp.config.log_level = max(int(wp.config.log_level), int(getattr(wp, "LOG_ERROR", wp.LOG_WARNING)))
                if loud:
                    wp.init()
                else:
                    with _native_stderr_silenced():
                        wp.init()
                _ready = True
    return wp
