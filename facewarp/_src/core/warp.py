"""Warp, imported and initialised once, quietly (the one place that does it).

Warp is imported lazily (never at package import, so ``facewarp --help`` stays fast) and its
informational output is off unless ``FACEWARP_VERBOSE=1`` is set (the CLI's ``--verbose`` sets
it). The library never calls ``wp.set_device``.
"""

from __future__ import annotations

import os
import threading

__all__ = ["get_warp", "verbose"]

_lock = threading.Lock()
_ready = False


def verbose() -> bool:
    """Whether Warp may print (``FACEWARP_VERBOSE`` set to a non-empty value other than 0)."""
    return os.environ.get("FACEWARP_VERBOSE", "") not in ("", "0")


def get_warp():
    """Import and initialise Warp once; returns the ``warp`` module.

    Quiet unless :func:`verbose`: the banner and the "could not find the CUDA driver" note on
    machines without a GPU are suppressed (``wp.config.quiet`` for Warp < 1.10,
    ``wp.config.log_level`` after), so errors stay one line and stdout stays for results.
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
                wp.init()
                _ready = True
    return wp
