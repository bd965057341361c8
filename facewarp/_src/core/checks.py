"""Argument checks of the public API: type, shape, dtype, range and finiteness, each failure an
:class:`~facewarp.InputError` whose one-line message names the argument and says what was
expected and what came (never a bare ``ValueError`` / ``TypeError`` from deep inside NumPy).

Small functions, called in the first lines of public functions and methods.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping

import numpy as np

from .errors import InputError

__all__ = [
    "check_array", "check_bool", "check_choice", "check_device", "check_face_rig", "check_indices", "check_int",
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


# ----------------------------------------------------------------------------- face rigs
def check_face_rig(fr, source: str) -> None:
    """The arrays of a face rig agree with each other: shapes, finite positions, indices in
    range. ``source`` (the file) starts the message of the :class:`InputError`."""
    try:
        nodes = check_array("nodes", fr.nodes, shape=(None, 3))
        p = len(nodes)
        check_indices("tets", fr.tets, p, shape=(None, 4))
        hv = check_array("head_vertices", fr.head_vertices, shape=(None, 3))
        check_indices("head_faces", fr.head_faces, len(hv), shape=(None, 3))
        check_indices("surface_vertex", fr.surface_vertex, len(hv), allow=-1)
        for nm in ("layer", "surface_vertex"):
            if len(getattr(fr, nm)) != p:
                raise InputError(f"{nm}: {len(getattr(fr, nm))} entries for {p} nodes")
        for nm in ("fixed", "held"):
            a = check_array(nm, getattr(fr, nm), shape=(p,), kind="b")
            del a
        check_indices("jaw_nodes", fr.jaw_nodes, p)
        check_array("jaw_amount", fr.jaw_amount, shape=(len(fr.jaw_nodes),))
        check_indices("support_nodes", fr.support_nodes, p)
        check_array("support_normal", fr.support_normal, shape=(len(fr.support_nodes), 3))
        check_array("support_amount", fr.support_amount, shape=(len(fr.support_nodes),))
        for nm in ("jaw_pivot", "jaw_u", "jaw_v"):
            check_array(nm, getattr(fr, nm), shape=(3,))
        check_indices("fdp_face", fr.fdp_face, len(fr.head_faces))
        check_array("fdp_bary", fr.fdp_bary, shape=(len(fr.fdp_face), 3))
        rig = fr.rig
        check_indices("rig att_node", rig.att_node, p)
        for nm in ("ctrl_rest", "att_rest_length", "att_stiffness", "att_weight", "contraction"):
            a = getattr(rig, nm, None)
            if a is not None:
                check_array(f"rig {nm}", a, shape=(None,) * np.ndim(a))
        for k, (V, F) in fr.parts.items():
            Vp = check_array(f"part {k} vertices", V, shape=(None, 3))
            check_indices(f"part {k} faces", F, len(Vp), shape=(None, 3))
    except InputError as e:
        raise InputError(f"{source}: corrupt face rig ({e})") from None


def check_mapping(name: str, value) -> Mapping:
    """``value`` when it is a dict-like mapping."""
    if not isinstance(value, Mapping):
        raise InputError(f"{name}: expected a dict, got {describe(value)}")
    return value


# ----------------------------------------------------------------------------- FaceSimulator
def check_simulator_args(fr, *, device, solver, solvers, dt, substeps, fps, iterations, tolerance, method,
                         solver_options, support_stiffness, edge_damping, mass_scaling, contact,
                         contact_modulus) -> str:
    """The arguments of :class:`~facewarp.FaceSimulator` (see its docstring); returns the device
    name. Sizes are bounded by :mod:`facewarp._src.core.limits`."""
    from .limits import MAX_FPS, MAX_SUBSTEPS

    if not all(hasattr(fr, k) for k in ("nodes", "tets", "rig", "head_vertices")):
        raise InputError(f"fr: expected a FaceRig (build_face or load_face_rig), got {describe(fr)}")
    device = check_device(device)
    check_choice("solver", solver, solvers)
    check_number("dt", dt, low=0.0, low_open=True, high=1.0, allow_none=True)
    check_int("substeps", substeps, low=1, high=MAX_SUBSTEPS, allow_none=True)
    check_number("fps", fps, low=0.0, low_open=True, high=MAX_FPS)
    check_int("iterations", iterations, low=1, high=100_000, allow_none=True)
    check_number("tolerance", tolerance, low=0.0, low_open=True, allow_none=True)
    if method is not None and not isinstance(method, str):
        raise InputError(f"method: expected a method name or None, got {describe(method)}")
    if solver_options is not None:
        opts = check_mapping("solver_options", solver_options)
        bad = [k for k in opts if not isinstance(k, str)]
        if bad:
            raise InputError(f"solver_options: keys must be option names, got {bad[0]!r}")
    check_number("support_stiffness", support_stiffness, low=0.0, allow_none=True)
    check_number("edge_damping", edge_damping, low=0.0, allow_none=True)
    check_bool("mass_scaling", mass_scaling)
    check_bool("contact", contact)
    check_number("contact_modulus", contact_modulus, low=0.0, low_open=True, allow_none=True)
    return device


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


def check_run_args(timeline, seconds, progress, curve_samples, *, fps: float, vertex_count: int) -> float:
    """The arguments of :meth:`~facewarp.FaceSimulator.run`; the memory of the kept frames is
    checked against the machine's. Returns ``seconds`` as a float."""
    from .limits import MAX_SECONDS, check_memory, estimate_frames_bytes

    if not (hasattr(timeline, "sample") and hasattr(timeline, "for_head")):
        raise InputError(f"timeline: expected a Timeline (preset(...), load_sequence(...)), got {describe(timeline)}")
    seconds = check_number("seconds", seconds, low=0.0, low_open=True, high=MAX_SECONDS)
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a function progress(k, frame_count) or None, got {describe(progress)}")
    check_int("curve_samples", curve_samples, low=2, high=10_000)
    frames = round(seconds * fps) + 1
    check_memory(estimate_frames_bytes(frames, vertex_count) + frames * curve_samples * 12 * 64,
                 f"seconds: {frames} frames of {vertex_count} vertices")
    return seconds


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
