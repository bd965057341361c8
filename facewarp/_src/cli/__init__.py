"""The commands of ``facewarp``: one module per command family, each with its options
(``add_parser``, at the top of the module), its run function and its report lines.

:func:`build_parser` puts them together under the global options; ``facewarp/cli.py`` runs the
parsed command (errors, exit codes, signals, staged outputs). A command module declares what it
writes with ``set_defaults(func=run, outputs=...)`` and its ``--help`` example with
``add_parser(..., example=...)`` (see :mod:`.common`). Nothing heavy is imported here: the work is
in ``_src.jobs`` (and ``_src.fleet``), imported when a command runs.
"""

from __future__ import annotations

import argparse

from . import adapt, batch, build, demo, drive, landmarks, live, mesh, morph, retarget, rig, simulate, template
from .common import Parser, add_global_options

__all__ = ["COMMAND_MODULES", "build_parser", "leaf_commands"]

# in the order of ``facewarp --help``
COMMAND_MODULES = (template, mesh, landmarks, adapt, build, rig, simulate, drive, live, demo, morph, retarget, batch)


def leaf_commands(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser]]:
    """(``"adapt"``, its parser), (``"template export"``, ...) for every command that runs, in order."""
    out = []

    def walk(prefix: str, p: argparse.ArgumentParser):
        sub = next((a for a in p._actions if isinstance(a, argparse._SubParsersAction)), None)
        if sub is None:
            out.append((prefix, p))
            return
        for name, child in sub.choices.items():
            walk(f"{prefix} {name}".strip(), child)

    walk("", parser)
    return out


def build_parser() -> argparse.ArgumentParser:
    """The ``facewarp`` argument parser: the global options (accepted before the command and after
    it), ``--version``, then every command module's commands."""
    from ... import __version__

    p = Parser(
        prog="facewarp",
        description="Personalized, physically simulated faces (template head, adaptation, anatomy, physics).",
        epilog="Units: the library works in metres; --units converts input files. Results go to stdout (one JSON "
               "document with --json); progress and errors to stderr. Errors: one line, exit code 2.",
        example="facewarp demo --out demo",
    )
    add_global_options(p)
    p.add_argument("--version", action="version", version=f"facewarp {__version__}",
                   help="print facewarp's version and exit")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    sub.required = True
    for module in COMMAND_MODULES:
        module.add_parser(sub)
    for _, leaf in leaf_commands(p):
        add_global_options(leaf, after_command=True)
    return p
