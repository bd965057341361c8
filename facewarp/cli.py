"""The ``facewarp`` command: main, errors and exit codes, signals and staged outputs.

The commands themselves (their options, run functions and report lines) are the modules of
``facewarp._src.cli``, one per command family; :func:`build_parser` puts them together.

Streams: results go to stdout (text, or exactly one JSON document with ``--json``); progress
bars, Warp's messages (``--verbose``) and errors go to stderr. Every error a user can cause
ends as one line ``facewarp: error: ...`` on stderr and exit code 2; an internal error is one
line too (exit code 1; ``--verbose`` shows its traceback). Numbers are checked while the
arguments are parsed, before any work. Nothing heavy is imported at module level, so
``facewarp --help`` starts in a fraction of a second; nothing below this module prints or
exits.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys

from ._src.cli import build_parser
from ._src.cli.common import EXIT_USAGE, MAX_TEMPLATE_LEVEL, close_progress
from ._src.core.errors import FacewarpError

__all__ = ["EXIT_BROKEN_PIPE", "EXIT_INTERNAL", "EXIT_INTERRUPTED", "EXIT_USAGE", "MAX_TEMPLATE_LEVEL", "build_parser",
           "console_main", "main", "readme_reference"]

EXIT_INTERNAL = 1
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, as if killed by it


def _check_device(device: str) -> str:
    if device.startswith("cuda"):
        from ._src.core.warp import get_warp

        wp = get_warp()
        n = wp.get_cuda_device_count()
        if n == 0:
            raise FacewarpError(f"--device {device}: no CUDA device is available on this machine")
        idx = int(device.split(":")[1]) if ":" in device else 0
        if idx >= n:
            raise FacewarpError(f"--device {device}: only {n} CUDA device(s) present (cuda:0..cuda:{n - 1})")
    return device


# ----------------------------------------------------------------------------- main
def _error(message: str, code: int = EXIT_USAGE) -> int:
    print(f"facewarp: error: {message}", file=sys.stderr)
    return code


def _os_error_text(e: OSError) -> str:
    what = e.strerror or str(e) or type(e).__name__
    return f"{e.filename}: {what}" if e.filename else what


def _quiet_broken_pipe() -> None:
    """stdout's reader went away (``facewarp ... | head``): send what is left to /dev/null."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass


def main(argv=None) -> int:
    """Run the command line ``argv`` (default ``sys.argv[1:]``); returns the exit code."""
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, or a usage error already printed as one line
        return int(e.code or 0) if not isinstance(e.code, str) else EXIT_USAGE
    args.stdout = sys.stdout
    # --json shows no progress (stderr keeps the error line only): the library's own first-run lines
    # (the kernels' compilation) follow FACEWARP_PROGRESS too
    with _verbose_env(args.verbose), _env("FACEWARP_PROGRESS", "off", bool(getattr(args, "json", False))):
        return _run(args)


def console_main() -> None:
    """The ``facewarp`` program (``python -m facewarp`` and the installed script): :func:`main`
    on ``sys.argv[1:]``, then exit with its code.

    The process ends right after, so the cyclic garbage collector is frozen first
    (``gc.freeze``): the interpreter's last collection at exit then skips the objects alive now
    (Warp's builtins, the arrays of the job), which took ~0.35 s of a ~4.5 s ``facewarp adapt``
    (one core). Every output is written and closed before :func:`main` returns, and atexit
    handlers still run.
    """
    import gc

    code = main()
    gc.freeze()
    sys.exit(code)


@contextlib.contextmanager
def _env(name: str, value: str, on: bool):
    """``name=value`` in the environment while the command runs (when ``on``), the old value after."""
    old = os.environ.get(name)
    if on:
        os.environ[name] = value
    try:
        yield
    finally:
        if on:
            if old is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = old


def _verbose_env(on: bool):
    """``FACEWARP_VERBOSE=1`` (read by facewarp._src.core.warp.get_warp) while a --verbose command runs."""
    return _env("FACEWARP_VERBOSE", "1", on)


def _output_targets(args) -> list:
    """The outputs of the parsed command, as its module declared them (``set_defaults(outputs=...)``):
    (argument, path, "dir" | "file"), staged by _run."""
    outputs = getattr(args, "outputs", None)
    return outputs(args) if outputs is not None else []


def _run(args) -> int:
    """Run the parsed command; every error becomes one line on stderr and an exit code.

    Outputs are staged (:mod:`facewarp._src.core.outputs`): the command writes into hidden
    siblings of its ``--out`` (and ``--build``), moved into place only when it finished, under a
    lock that refuses a second run on the same output. SIGINT and SIGTERM stop it with exit
    130 / 143 and nothing written. The result is held back until the outputs are in place.
    """
    from ._src.core.outputs import Interrupted, interrupted_by, signals_as_exceptions, staged_outputs

    stdout, args.stdout = args.stdout, io.StringIO()
    staging = None
    try:
        with signals_as_exceptions():
            # anything printed on the way (Warp with --verbose, libraries) goes to stderr: stdout is
            # for the result alone, written by the command's emit
            with contextlib.redirect_stdout(sys.stderr):
                _check_device(args.device)
                targets = _output_targets(args)
                with staged_outputs(targets) as staging:
                    for name, _, _ in targets:
                        setattr(args, name, staging.path(name))
                    code = args.func(args)  # a command may say what happened (batch run: 1 some scans failed)
                    if interrupted_by() is not None:  # a library swallowed the KeyboardInterrupt
                        raise Interrupted(interrupted_by())
        text = args.stdout.getvalue()
        stdout.write(staging.unstage(text) if staging is not None else text)
        stdout.flush()
    except FacewarpError as e:
        return _error(_unstaged(staging, str(e)))
    except KeyboardInterrupt as e:
        print("facewarp: interrupted", file=sys.stderr)
        return 128 + e.signum if isinstance(e, Interrupted) else EXIT_INTERRUPTED
    except BrokenPipeError:
        _quiet_broken_pipe()
        return EXIT_BROKEN_PIPE
    except OSError as e:
        return _error(_unstaged(staging, _os_error_text(e)))
    except MemoryError:
        return _error("out of memory (try a lower level, fewer frames or a smaller mesh)", EXIT_INTERNAL)
    except Exception as e:  # a bug, or a broken installation (ImportError): one line unless --verbose
        if args.verbose:
            raise
        hint = "" if isinstance(e, ImportError) else "; --verbose shows the traceback, please report it"
        return _error(_unstaged(staging, f"{type(e).__name__}: {e}{hint}"), EXIT_INTERNAL)
    finally:
        close_progress()  # no progress line after the command, whatever ended it
    return code if isinstance(code, int) and not isinstance(code, bool) else 0


def _unstaged(staging, text: str) -> str:
    """``text`` (an error message) naming the user's output paths, not the staged ones, on one line."""
    text = staging.unstage(text) if staging is not None else text
    return " ".join(text.split("\n")).strip() if "\n" in text else text



def readme_reference() -> tuple[str, str, str]:
    """The command reference of docs/commands.md generated from :func:`build_parser`: (begin marker,
    block, end marker); ``python -m facewarp._src.cli_reference docs/commands.md`` rewrites it in place."""
    from ._src.cli_reference import BEGIN, END, reference

    return BEGIN, reference(), END


if __name__ == "__main__":
    sys.exit(main())
