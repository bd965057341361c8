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
import time
from pathlib import Path

from ..core.errors import FacewarpError
from ..core.limits import MAX_FPS, MAX_SECONDS

__all__ = ["DOCS_PAGE", "EXIT_USAGE", "FacewarpError", "FrameBar", "GLOBAL_TITLE", "HelpFormatter",
           "MAX_TEMPLATE_LEVEL", "Parser", "Progress", "StageBar", "add_global_options", "amount_up_to",
           "close_progress", "command_options", "device", "docs_link", "emit", "fps", "frame_stats_lines", "jsonable",
           "level", "muscle_list", "number", "out_dir", "out_dir_or_usd", "out_file", "path", "progress_lines",
           "progress_mode", "seconds", "whole_in"]

EXIT_USAGE = 2

MAX_TEMPLATE_LEVEL = 4  # facewarp._src.template.head.MAX_LEVEL (a test keeps them equal)


DOCS_PAGE = "docs/commands.md"
"""The command reference in the repository; every ``--help`` ends with a link to its command's section."""

GLOBAL_TITLE = "global options (also accepted before the command)"


def docs_link(prog: str) -> str:
    """``docs/commands.md#facewarp-simulate`` for ``"facewarp simulate"`` (the heading's anchor on
    GitHub); the page alone for ``"facewarp"``."""
    words = prog.split()
    return DOCS_PAGE + ("#" + "-".join(words).lower() if len(words) > 1 else "")


class HelpFormatter(argparse.HelpFormatter):
    """Wraps each paragraph of a description or epilog, except one whose lines after the first are
    indented (an example, the sequence file schema): that one is kept as written."""

    def _fill_text(self, text, width, indent):
        out = []
        for para in text.split("\n\n"):
            lines = para.splitlines()
            if any(line.startswith(" ") for line in lines[1:]):
                out.append("\n".join(indent + line for line in lines))
            else:
                out.append(super()._fill_text(para, width, indent))
        return "\n\n".join(out)


class Parser(argparse.ArgumentParser):
    """One-line usage errors; the usage with the command list when a command is missing (a bare
    ``facewarp``); a help that ends with the command's example and its docs link; an epilog that
    can be made only when the help is shown (``epilog_factory``), so that building the parser
    imports nothing heavy."""

    def __init__(self, *args, epilog_factory=None, example: str | None = None, **kwargs):
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        self._epilog_factory = epilog_factory
        self.example = example

    def _commands(self):
        for a in self._actions:
            if isinstance(a, argparse._SubParsersAction):
                return a
        return None

    def example_and_link(self) -> tuple[str | None, str]:
        """This command's example (a group's: its first command's) and its docs link."""
        if self.example is not None or self._commands() is None:
            return self.example, docs_link(self.prog)
        first = next(iter(self._commands().choices.values()))
        example, link = first.example_and_link()
        return example, (link if " " in self.prog else docs_link(self.prog))

    def format_help(self):
        if self._epilog_factory is not None:
            self.epilog, self._epilog_factory = self._epilog_factory(), None
        example, link = self.example_and_link()
        epilog = self.epilog
        tail = (f"example:\n  {example}\n\n" if example else "") + f"docs: {link}"
        self.epilog = f"{epilog}\n\n{tail}" if epilog else tail
        try:
            return super().format_help()
        finally:
            self.epilog = epilog

    def parse_args(self, args=None, namespace=None):
        ns, extras = self.parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}{self._hint(ns, extras[0])}")
        return ns

    def _hint(self, ns, word: str) -> str:
        """" (did you mean --device? `facewarp simulate --help` lists its options)": the closest
        option of the command that was given."""
        import difflib

        p, words = self, [self.prog]
        while (sub := p._commands()) is not None and getattr(ns, sub.dest, None) in sub.choices:
            p = sub.choices[getattr(ns, sub.dest)]
            words.append(getattr(ns, sub.dest))
        flags = [s for a in p._actions for s in a.option_strings if s.startswith("--")]
        close = difflib.get_close_matches(word.split("=")[0], flags, n=1) if word.startswith("-") else []
        return (f" (did you mean {close[0]}? " if close else " (") + f"`{' '.join(words)} --help` lists its options)"

    def error(self, message):  # one line, exit 2, like every other error
        commands = self._commands()
        if commands is not None and message == f"the following arguments are required: {commands.metavar}":
            # no command given (a bare `facewarp`): the usage with the list of commands
            self.print_help(sys.stderr)
            self.exit(EXIT_USAGE)
        self.exit(EXIT_USAGE, f"facewarp: error: {message}\n")


def add_global_options(p: argparse.ArgumentParser, *, after_command: bool = False) -> None:
    """The options of every command: on the top parser (``facewarp --device cuda simulate ...``) and,
    with ``after_command``, on each command too (``facewarp simulate ... --device cuda``), there
    without defaults so that they do not overwrite one given before the command."""
    g = p.add_argument_group(GLOBAL_TITLE) if after_command else p
    dflt = (lambda v: argparse.SUPPRESS) if after_command else (lambda v: v)
    g.add_argument("--device", type=device, metavar="cpu|cuda|cuda:N", default=dflt("cpu"),
                   help="Warp device: cpu (default), cuda or cuda:N")
    g.add_argument("--json", action="store_true", default=dflt(False),
                   help="print the result as one JSON document on stdout")
    g.add_argument("--verbose", action="store_true", default=dflt(False),
                   help="let Warp print its messages (banner, CUDA driver notes, kernel builds) on stderr, "
                        "and show tracebacks of internal errors")


def command_options(p: argparse.ArgumentParser) -> list[argparse.Action]:
    """A command's own arguments (not --help, not its subcommands, not the global options)."""
    glob = {id(a) for g in p._action_groups if g.title == GLOBAL_TITLE for a in g._group_actions}
    return [a for a in p._actions if id(a) not in glob
            and not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction, argparse._VersionAction))]


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


def path(text: str) -> Path:
    """An argparse ``type=`` for a file or folder path: an empty one (``--out ''``, which ``Path``
    reads as the current folder) is a usage error."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a path, got {text!r}")
    return Path(text)


def device(text: str) -> str:
    t = text.strip().lower()
    if t == "cpu" or t == "cuda" or (t.startswith("cuda:") and t[5:].isdigit()):
        return t
    raise argparse.ArgumentTypeError(f"expected cpu, cuda or cuda:N, got {text!r}")


def muscle_list(text: str) -> list[str]:
    """An option's comma list of muscle names, each checked by the one muscle-name rule
    (:func:`facewarp._src.expressions.muscle_base`: a Table 6.2 name means both sides, NAME_L or
    NAME_R one side)."""
    from ..core.errors import InputError
    from ..expressions import muscle_base

    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"expected muscle names A,B,..., got {text!r}")
    try:
        for n in names:
            muscle_base(n, what=None)
    except InputError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return names


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
LINE_EVERY_S = 5.0
"""Off a terminal, a line of frame progress at most this often [s]."""

HEARTBEAT_S = 10.0
"""Off a terminal, a "still working" line after this long without one [s] (kernel compilation, long stages)."""


def _raise_if_interrupted() -> None:
    """Raise again at a progress callback when a signal came and a library swallowed its exception."""
    from ..core.outputs import raise_if_interrupted

    raise_if_interrupted()


def progress_mode() -> str:
    """How progress shows on stderr: ``"bars"`` (tqdm bars, erased when done) on a terminal,
    ``"lines"`` (plain lines: CI, nohup, ``| tee``) off it; ``FACEWARP_PROGRESS`` = ``bars``,
    ``lines`` or ``off`` overrides it (the tests set ``off``)."""
    env = os.environ.get("FACEWARP_PROGRESS", "").strip().lower()
    if env in ("bars", "lines", "off"):
        return env
    try:
        return "bars" if sys.stderr.isatty() else "lines"
    except (AttributeError, ValueError):  # stderr replaced or closed
        return "lines"


class _Lines:
    """Progress as plain lines on stderr, ``facewarp NAME: TEXT (T s)`` with T the seconds since the
    command began: a line per stage, a frame line at most every :data:`LINE_EVERY_S` and a
    "still working" line after :data:`HEARTBEAT_S` without one (a daemon thread, so that a kernel
    compilation or a long stage without callbacks shows too)."""

    def __init__(self, name: str, waiting: str):
        import threading

        self.name, self.waiting = name, waiting
        self.t0 = self.last = time.perf_counter()
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._heartbeat, name="facewarp-progress", daemon=True)
        _WRITERS.add(self)
        self.thread.start()

    def line(self, text: str, *, still: bool = False) -> None:
        with self.lock:
            now = time.perf_counter()
            if still and now - self.last < HEARTBEAT_S:
                return
            self.last = now
            try:
                print(f"facewarp {self.name}: {text} ({now - self.t0:.1f} s)", file=sys.stderr, flush=True)
            except (OSError, ValueError):  # stderr went away: progress is not worth an error
                self.stop.set()

    def _heartbeat(self) -> None:
        while not self.stop.wait(1.0):
            self.line(f"{self.waiting}, still working", still=True)

    def close(self) -> None:
        self.stop.set()
        _WRITERS.discard(self)


_WRITERS: set[_Lines] = set()


def close_progress() -> None:
    """Stop every line writer still running (a command that raised before closing its bars): the
    main loop calls it after each command, so that no heartbeat outlives its command."""
    for w in list(_WRITERS):
        w.close()


def progress_lines(name: str, waiting: str, enabled: bool):
    """One line writer for a command's several bars off a terminal (None on a terminal, with
    ``--json`` or ``FACEWARP_PROGRESS=off``); the caller closes it."""
    return _Lines(name, waiting) if enabled and progress_mode() == "lines" else None


class Progress:
    """Progress over named steps on stderr: a tqdm bar on a terminal, lines off it
    (:func:`progress_mode`); nothing with ``--json`` (``enabled`` False)."""

    def __init__(self, total: int, desc: str, enabled: bool):
        self.mode = progress_mode() if enabled else "off"
        self.total, self.done = total, 0
        self.lines = _Lines(desc, "starting") if self.mode == "lines" else None
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=desc, disable=None if self.mode == "bars" else True, file=sys.stderr,
                        leave=False)

    def set_total(self, n: int) -> None:
        self.total = self.bar.total = n

    def __call__(self, msg: str):
        _raise_if_interrupted()
        self.done += 1
        if self.lines is not None:
            self.lines.waiting = f"[{self.done}/{self.total}] {msg}"
            self.lines.line(self.lines.waiting)
        self.bar.set_postfix_str(msg)
        self.bar.update(1)

    def close(self):
        if self.lines is not None:
            self.lines.close()
        self.bar.close()


class FrameBar:
    """Progress over simulated frames on stderr: a tqdm bar on a terminal, made at the first frame
    (the count is known then); off it, lines (the first frame, then at most every
    :data:`LINE_EVERY_S`, the last frame) and a heartbeat while waiting for the first frame."""

    def __init__(self, enabled: bool, *, desc: str = "simulate", unit: str = "frame", lines=None):
        self.mode = progress_mode() if enabled else "off"
        self.enabled, self.desc, self.unit = self.mode == "bars", desc, unit
        self.bar = None
        self.done, self.first_at, self.printed_at = 0, None, 0.0
        self.lines = None
        if self.mode == "lines":
            self.lines = lines if lines is not None else _Lines(desc, f"waiting for the first {unit} (the first run "
                                                                      "on a machine compiles Warp's kernels)")
            self.own_lines = lines is None

    def __call__(self, k: int, n: int):
        _raise_if_interrupted()
        self.done += 1
        if self.lines is not None:
            self._line(n)
        if not self.enabled:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=n, desc=self.desc, unit=self.unit, file=sys.stderr, disable=None, leave=False)
        self.bar.update(1)

    def _line(self, n: int) -> None:
        now = time.perf_counter()
        what = f"{self.unit} {self.done}/{n}"
        if self.lines.name != self.desc:  # a frame bar inside a longer job: "simulate frame 3/7"
            what = f"{self.desc} {what}"
        if self.first_at is None:
            self.first_at = self.printed_at = now
            self.lines.line(what)
        elif self.done >= n or now - self.printed_at >= LINE_EVERY_S:
            self.printed_at = now
            rate = (self.done - 1) / max(now - self.first_at, 1e-9)
            self.lines.line(f"{what}, {rate:.1f} {self.unit}s/s")
        self.lines.waiting = what

    def close(self):
        if self.bar is not None:
            self.bar.close()
        if self.lines is not None and self.own_lines:
            self.lines.close()


class StageBar:
    """Progress over a job's named stages that gives way to a frame bar while simulating (off a
    terminal: a line per stage and the frame lines, under one name)."""

    def __init__(self, stages, desc: str, enabled: bool):
        self.stages, self.enabled = list(stages), enabled
        self.bar = Progress(len(self.stages), desc, enabled)
        self.frames = FrameBar(enabled, lines=self.bar.lines)

    def __call__(self, msg: str):
        self.frames.close()
        self.frames = FrameBar(self.enabled, lines=self.bar.lines)
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
