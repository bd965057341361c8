"""What every command module of the ``facewarp`` command shares: the parser class, the argument
types (numbers checked while parsing), the progress bars on stderr, the result on stdout and the
kinds of output a command declares.

Nothing heavy is imported at module level, so that ``facewarp --help`` starts in a fraction of a
second; nothing here prints (but the bars on stderr and the result through :func:`emit`) or exits.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from ..core.errors import FacewarpError
from ..core.limits import MAX_FPS, MAX_SECONDS

__all__ = ["EXIT_USAGE", "FacewarpError", "FrameBar", "HelpFormatter", "MAX_TEMPLATE_LEVEL", "Parser", "Progress",
           "StageBar", "amount_up_to", "device", "emit", "fps", "frame_stats_lines", "jsonable", "level", "number",
           "out_dir", "out_dir_or_usd", "out_file", "seconds", "whole_in"]

EXIT_USAGE = 2

MAX_TEMPLATE_LEVEL = 4  # facewarp._src.template.head.MAX_LEVEL (a test keeps them equal)


class Parser(argparse.ArgumentParser):
    """One-line usage errors; an epilog can be made only when the help is shown (``epilog_factory``),
    so that building the parser imports nothing heavy."""

    def __init__(self, *args, epilog_factory=None, **kwargs):
        super().__init__(*args, **kwargs)
        self._epilog_factory = epilog_factory

    def format_help(self):
        if self._epilog_factory is not None:
            self.epilog, self._epilog_factory = self._epilog_factory(), None
        return super().format_help()

    def error(self, message):  # one line, exit 2, like every other error
        self.exit(EXIT_USAGE, f"facewarp: error: {message}\n")


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the line breaks of epilogs (the sequence file schema)."""


# ----------------------------------------------------------------------------- argument types
def number(parse, ok, expected: str):
    """An argparse ``type=``: ``parse(text)`` must succeed and satisfy ``ok``, else the usage
    error "argument --flag: expected <expected>, got 'text'"."""

    def check(text: str):
        try:
            v = parse(text)
        except ValueError:
            v = None
        if v is None or not ok(v):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return v

    return check


def whole_in(low: int, high: int):
    return number(int, lambda v: low <= v <= high, f"a whole number {low}..{high}")


def amount_up_to(high: float):
    return number(float, lambda v: math.isfinite(v) and 0 < v <= high, f"a finite number > 0 and <= {high:g}")


seconds = amount_up_to(MAX_SECONDS)
fps = amount_up_to(MAX_FPS)
level = number(int, lambda v: 0 <= v <= MAX_TEMPLATE_LEVEL, f"a level 0..{MAX_TEMPLATE_LEVEL}")


def device(text: str) -> str:
    t = text.strip().lower()
    if t == "cpu" or t == "cuda" or (t.startswith("cuda:") and t[5:].isdigit()):
        return t
    raise argparse.ArgumentTypeError(f"expected cpu, cuda or cuda:N, got {text!r}")


# ----------------------------------------------------------------------------- outputs a command declares
# ``set_defaults(outputs=...)``: the command's outputs as (argument, path, "dir" | "file"), staged by the
# main loop (written into hidden siblings, moved into place when the command finished).
def out_dir(args) -> list[tuple[str, Path, str]]:
    return [("out", args.out, "dir")]


def out_file(args) -> list[tuple[str, Path, str]]:
    return [("out", args.out, "file")]


def out_dir_or_usd(args) -> list[tuple[str, Path, str]]:
    """``--out`` is a USD file (the animation alone) or a folder."""
    usd = Path(args.out).suffix.lower() in (".usda", ".usdc", ".usdz")  # jobs.animation.USD_SUFFIXES
    return [("out", args.out, "file" if usd else "dir")]


# ----------------------------------------------------------------------------- progress on stderr
def _raise_if_interrupted() -> None:
    """Raise again at a progress callback when a signal came and a library swallowed its exception."""
    from ..core.outputs import raise_if_interrupted

    raise_if_interrupted()


class Progress:
    """A tqdm bar on stderr over named steps (hidden when stderr is not a terminal or --json)."""

    def __init__(self, total: int, desc: str, enabled: bool):
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=desc, disable=None if enabled else True, file=sys.stderr, leave=False)

    def __call__(self, msg: str):
        _raise_if_interrupted()
        self.bar.set_postfix_str(msg)
        self.bar.update(1)

    def close(self):
        self.bar.close()


class FrameBar:
    """A tqdm bar on stderr over simulated frames, made at the first frame (the count is known then)."""

    def __init__(self, enabled: bool, *, desc: str = "simulate", unit: str = "frame"):
        self.enabled, self.desc, self.unit = enabled, desc, unit
        self.bar = None

    def __call__(self, k: int, n: int):
        _raise_if_interrupted()
        if not self.enabled:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=n, desc=self.desc, unit=self.unit, file=sys.stderr, disable=None, leave=False)
        self.bar.update(1)

    def close(self):
        if self.bar is not None:
            self.bar.close()


class StageBar:
    """A tqdm bar over a job's named stages that gives way to a frame bar while simulating."""

    def __init__(self, stages, desc: str, enabled: bool):
        self.stages, self.enabled = list(stages), enabled
        self.bar = Progress(len(self.stages), desc, enabled)
        self.frames = FrameBar(enabled)

    def __call__(self, msg: str):
        self.frames.close()
        self.frames = FrameBar(self.enabled)
        self.bar(msg)

    def close(self):
        self.frames.close()
        self.bar.close()


# ----------------------------------------------------------------------------- the result on stdout
def jsonable(o):
    """``o`` with numpy scalars/arrays as Python numbers/lists, paths as strings and non-finite
    floats as null (strict JSON has no NaN or Infinity)."""
    if isinstance(o, dict):
        return {str(k): jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [jsonable(v) for v in o]
    if isinstance(o, bool) or o is None or isinstance(o, (int, str)):
        return o
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if isinstance(o, os.PathLike):
        return os.fspath(o)
    if hasattr(o, "tolist"):  # numpy scalar or array
        return jsonable(o.tolist())
    return str(o)


def emit(args, data: dict, lines: list[str]):
    """The command's result on stdout: one JSON document (``--json``) or text lines."""
    out = args.stdout
    if args.json:
        out.write(json.dumps(jsonable(data), indent=2, allow_nan=False) + "\n")
    else:
        out.write("\n".join(lines) + "\n")
    out.flush()


def frame_stats_lines(st) -> list[str]:
    """The report lines of the simulator's frame stats (sub-stepped frames, volume floor)."""
    if not st:
        return []
    line = (f"  {st['substepped_frames']} of {st['frames']} frames sub-stepped (up to {st['max_substep_factor']}x), "
            f"smallest tet volume {st['min_volume_ratio'] * 100:.1f} % of rest")
    if st.get("frames_below_floor"):
        line += f", {st['frames_below_floor']} frames below the {st['volume_floor'] * 100:.0f} % floor"
    if st.get("unconverged_frames"):
        line += f", {st['unconverged_frames']} frames not converged"
    return [line]
