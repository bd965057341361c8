"""Argument checks of the public API: type, shape, dtype, range and finiteness, each failure an
:class:`~facewarp.InputError` whose one-line message names the argument and says what was
expected and what came (never a bare ``ValueError`` / ``TypeError`` from deep inside NumPy).

Small functions, called in the first lines of public functions and methods. The checks of one
domain object sit beside their owner (a face rig's in :mod:`facewarp._src.physics.face_rig`, the
simulator's arguments in :mod:`facewarp._src.sim.simulator`); these are the common ones.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping

import numpy as np

from .errors import InputError

__all__ = [
    "check_array", "check_bool", "check_choice", "check_device", "check_indices", "check_int",
    "check_number", "check_step_count", "describe",
]


def describe(value) -> str:
    """A short description of ``value`` for a message: ``array of shape (2,) float64``, ``'tpu'``, ``a list of 27 str``."""
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape} {value.dtype}"
    if isinstance(value, (list, tuple)):
        kinds = sorted({type(v).__name__ for v in value})
        return f"a {type(value).__name__} of {len(value)} {'/'.join(kinds) or 'items'}"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_number(name: str, value, *, low: float | None = None, high: float | None = None,
                 low_open: bool = False, allow_none: bool = False) -> float | None:
    """``value`` as a float: a real number (not a bool, not an array), finite, within
    ``low``..``high`` (``low`` excluded when ``low_open``)."""
    if value is None and allow_none:
        return None
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if not isinstance(value, numbers.Real) or isinstance(value, (bool, np.bool_)):
        raise InputError(f"{name}: expected a number, got {describe(value)}")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{name}: expected a finite number, got {value!r}")
    if low is not None and (v <= low if low_open else v < low):
        raise InputError(f"{name}: expected a number {'>' if low_open else '>='} {low:g}, got {value!r}")
    if high is not None and v > high:
        raise InputError(f"{name}: expected a number <= {high:g}, got {value!r}")
    return v


def check_int(name: str, value, *, low: int | None = None, high: int | None = None,
              allow_none: bool = False) -> int | None:
    """``value`` as an int: a whole number (not a bool, not a float), within ``low``..``high``."""
    if value is None and allow_none:
        return None
    if not isinstance(value, numbers.Integral) or isinstance(value, (bool, np.bool_)):
        raise InputError(f"{name}: expected a whole number, got {describe(value)}")
    v = int(value)
    if (low is not None and v < low) or (high is not None and v > high):
        lo = "" if low is None else f"{low}"
        hi = "" if high is None else f"{high}"
        rng = f"{lo}..{hi}" if lo and hi else (f">= {lo}" if lo else f"<= {hi}")
        raise InputError(f"{name}: expected a whole number {rng}, got {value!r}")
    return v


def check_bool(name: str, value) -> bool:
    """``value`` when it is True or False (NumPy bools too)."""
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(f"{name}: expected True or False, got {describe(value)}")
    return bool(value)


def check_choice(name: str, value, choices) -> str:
    """``value`` when it is one of the strings ``choices``."""
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"{name}: expected one of {', '.join(map(repr, choices))}, got {describe(value)}")
    return value


def check_array(name: str, value, *, shape: tuple, kind: str = "f", finite: bool = True,
                dtype=None) -> np.ndarray:
    """``value`` as an array of ``shape`` (``None`` in it: any length) whose dtype is of ``kind``
    ("f": real numbers, integers accepted; "i": integers; "b": booleans); with ``finite``, no NaN
    or infinity. ``dtype``: the dtype to return (default float64 / int64 / bool)."""
    try:
        a = np.asarray(value)
    except (ValueError, TypeError) as e:  # ragged lists
        raise InputError(f"{name}: expected an array of shape {_shape_text(shape)}, got {describe(value)} ({e})") from None
    ok_kind = {"f": "fiu", "i": "iu", "b": "b"}[kind]
    if a.dtype.kind not in ok_kind or a.dtype == object:
        want = {"f": "numbers", "i": "whole numbers", "b": "booleans"}[kind]
        raise InputError(f"{name}: expected an array of {want}, got dtype {a.dtype} ({describe(value)})")
    if a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape)):
        raise InputError(f"{name}: expected shape {_shape_text(shape)}, got {a.shape}")
    out = a.astype(dtype or {"f": np.float64, "i": np.int64, "b": bool}[kind], copy=False)
    if finite and kind == "f" and out.size and not np.isfinite(out).all():
        bad = np.argwhere(~np.isfinite(out))[0]
        raise InputError(f"{name}: non-finite value {float(out[tuple(bad)])!r} at index {tuple(int(i) for i in bad)}")
    return out


def _shape_text(shape) -> str:
    return "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def check_indices(name: str, value, count: int, *, shape: tuple = (None,), allow: int | None = None) -> np.ndarray:
    """Integer array of ``shape`` whose entries index ``count`` items (0..count-1; ``allow`` is
    one more value that may appear, e.g. -1 for "none")."""
    a = check_array(name, value, shape=shape, kind="i")
    bad = (a < 0) | (a >= count)
    if allow is not None:
        bad &= a != allow
    if bad.any():
        i = tuple(int(j) for j in np.argwhere(bad)[0])
        raise InputError(f"{name}: entry {i} is {int(a[i])}, outside 0..{count - 1}")
    return a


def check_device(value, name: str = "device") -> str:
    """A Warp device name ``"cpu"``, ``"cuda"`` or ``"cuda:N"`` (a Warp ``Device`` gives its
    alias); CUDA names must name a present GPU."""
    if value is not None and not isinstance(value, str) and hasattr(value, "alias"):
        value = value.alias
    if not isinstance(value, str):
        raise InputError(f"{name}: expected 'cpu', 'cuda' or 'cuda:N', got {describe(value)}")
    t = value.strip().lower()
    if not (t == "cpu" or t == "cuda" or (t.startswith("cuda:") and t[5:].isdigit())):
        raise InputError(f"{name}: expected 'cpu', 'cuda' or 'cuda:N', got {value!r}")
    if t.startswith("cuda"):
        from .warp import get_warp

        n = get_warp().get_cuda_device_count()
        idx = int(t[5:]) if ":" in t else 0
        if idx >= n:
            raise InputError(f"{name}: {value!r} is not present on this machine ({n} CUDA device(s))")
    return t


def check_step_count(dt, substep: float, name: str = "dt") -> int:
    """The number of solver steps of length ``substep`` [s] that make ``dt`` [s]; refuses a
    ``dt`` that is not a whole number of them (to 1e-6 relative), so that ``step(dt)`` always
    advances exactly ``dt``."""
    from .limits import MAX_SECONDS

    v = check_number(name, dt, low=0.0, low_open=True, high=MAX_SECONDS)
    n = round(v / substep)
    if n < 1 or abs(n * substep - v) > 1e-6 * max(v, substep):
        near = sorted({max(1, math.floor(v / substep)), max(1, math.ceil(v / substep))})
        give = " or ".join(f"{k * substep:.6g}" for k in near)
        raise InputError(f"{name}: {v:g} s is not a whole number of the solver's steps of {substep:.6g} s "
                         f"(give {give} s, or make the simulator with dt= or substeps= to suit)")
    return int(n)


def check_mapping(name: str, value) -> Mapping:
    """``value`` when it is a dict-like mapping."""
    if not isinstance(value, Mapping):
        raise InputError(f"{name}: expected a dict, got {describe(value)}")
    return value


def check_activations(activations, count: int):
    """What :meth:`~facewarp.FaceSimulator.set_activations` takes: an Expression (passed on), a
    dict name -> number (names strings, values real numbers) or a sequence/array of ``count``
    numbers (returned as float64)."""
    if hasattr(activations, "activation") and hasattr(activations, "jaw_u"):
        return activations
    if isinstance(activations, Mapping):
        for k, v in activations.items():
            if not isinstance(k, str):
                raise InputError(f"activations: muscle names must be strings, got {k!r}")
            check_number(f"activations[{k!r}]", v)
        return activations
    if isinstance(activations, (str, bytes)) or activations is None:
        raise InputError(f"activations: expected an Expression, a dict or {count} numbers, got {describe(activations)}")
    return check_array("activations", activations, shape=(count,), finite=False)


def check_jaw_angles(opening, side) -> tuple[float, float]:
    """The two jaw angles of :meth:`~facewarp.FaceSimulator.set_jaw` as floats (the range is
    checked there)."""
    return check_number("jaw opening", opening), check_number("jaw side", side)


def check_positions(name: str, X, count: int, *, allow_none: bool = True):
    """Node positions (count, 3) [m], finite, or None."""
    if X is None and allow_none:
        return None
    return check_array(name, X, shape=(count, 3))


# ----------------------------------------------------------------------------- common public arguments
def check_path(name: str, value):
    """``value`` as a :class:`~pathlib.Path` when it is a ``str`` or ``os.PathLike``."""
    import os
    from pathlib import Path

    if isinstance(value, bytes) or not isinstance(value, (str, os.PathLike)):
        raise InputError(f"{name}: expected a file or folder path, got {describe(value)}")
    if isinstance(value, str) and not value.strip():
        raise InputError(f"{name}: expected a file or folder path, got an empty string")
    return Path(value)


def check_head_arg(name: str, value):
    """A head (:class:`~facewarp.Template`, or an object with its ``vertices``, ``faces`` and
    ``fdp``)."""
    if not all(hasattr(value, k) for k in ("vertices", "faces", "fdp")):
        raise InputError(f"{name}: expected a head (default_template, load_head, a Template), got {describe(value)}")
    return value


def check_landmark_dict(name: str, value) -> Mapping:
    """FDP id -> position (3,): a mapping with string keys (positions are checked where used)."""
    check_mapping(name, value)
    for k in value:
        if not isinstance(k, str):
            raise InputError(f"{name}: FDP ids must be strings such as '2.1', got {k!r}")
    return value


def check_has(name: str, value, fields: tuple, what: str):
    """``value`` when it has every attribute of ``fields`` (a duck-typed object), else InputError."""
    if not all(hasattr(value, k) for k in fields):
        raise InputError(f"{name}: expected {what}, got {describe(value)}")
    return value


def check_name(name: str, value) -> str:
    """A name (a preset, an FDP id): a string."""
    if not isinstance(value, str):
        raise InputError(f"{name}: expected a name (a string), got {describe(value)}")
    return value
