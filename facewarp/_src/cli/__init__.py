"""The commands of ``facewarp``: one module per command family, each with its options
(``add_parser``, at the top of the module), its run function and its report lines.

:func:`build_parser` puts them together under the global options; ``facewarp/cli.py`` runs the
parsed command (errors, exit codes, signals, staged outputs). A command module declares what it
writes with ``set_defaults(func=run, outputs=...)`` (see :mod:`.common`). Nothing heavy is
imported here: the work is in ``_src.jobs`` (and ``_src.fleet``), imported when a command runs.
"""

from __future__ import annotations

import argparse

from . import adapt, batch, build, demo, drive, landmarks, mesh, morph, retarget, rig, simulate, template
from .common import Parser, device

__all__ = ["COMMAND_MODULES", "build_parser"]

# in the order of ``facewarp --help``
COMMAND_MODULES = (template, mesh, landmarks, adapt, build, rig, simulate, drive, demo, morph, retarget, batch)


def add_global_options(p: argparse.ArgumentParser) -> None:
    """The options of every command (``facewarp --device cuda simulate ...``)."""
    p.add_argument("--device", type=device, metavar="cpu|cuda|cuda:N", default="cpu", help="Warp device: cpu (default), cuda or cuda:N")
    p.add_argument("--json", action="store_true", help="print the result as one JSON document on stdout")
    p.add_argument("--verbose", action="store_true",
                   help="let Warp print its messages (banner, CUDA driver notes, kernel builds) on stderr, "
                        "and show tracebacks of internal errors")


def build_parser() -> argparse.ArgumentParser:
    """The ``facewarp`` argument parser: the global options, then every command module's commands."""
    p = Parser(
        prog="facewarp",
        description="Personalized, physically simulated faces (template head, adaptation, anatomy, physics).",
        epilog="Units: the library works in metres; --units converts input files. Results go to stdout (one JSON "
               "document with --json); progress and errors to stderr. Errors: one line, exit code 2.",
    )
    add_global_options(p)
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    sub.required = True
    for module in COMMAND_MODULES:
        module.add_parser(sub)
    return p
