"""The command reference of ``docs/commands.md``, generated from the ``facewarp`` argument parser.

The block between ``<!-- cli-reference:begin -->`` and ``<!-- cli-reference:end -->`` in
docs/commands.md is :func:`reference` (plain Markdown, read on GitHub as in the built docs): a
usage line per command, the global options, then a section per command (its heading is the
anchor every ``--help`` links to) with a table of its arguments (required, default, values or
bounds, meaning), its notes and its example. ``tests/test_readme_cli.py`` fails when the block is
out of date. Rewrite it with::

    python -m facewarp._src.cli_reference docs/commands.md

This module imports the parser (``facewarp._src.cli``); nothing there imports this one.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from .cli import build_parser, leaf_commands
from .cli.common import command_options, docs_link

__all__ = ["BEGIN", "END", "commands", "reference", "update_readme"]

BEGIN = "<!-- cli-reference:begin (generated from the parser: python -m facewarp._src.cli_reference docs/commands.md) -->"
END = "<!-- cli-reference:end -->"


def commands(parser: argparse.ArgumentParser | None = None) -> list[tuple[str, argparse.ArgumentParser]]:
    """(``"adapt"``, its parser), (``"template export"``, ...) for every leaf command, in order."""
    return leaf_commands(parser if parser is not None else build_parser())


def _metavar(a: argparse.Action) -> str:
    if a.choices is not None:
        return "|".join(str(c) for c in a.choices)
    if a.metavar is not None:
        return str(a.metavar)
    return a.dest.upper()


def _usage_item(a: argparse.Action) -> str:
    if not a.option_strings:  # positional
        text = _metavar(a)
        if a.nargs == "+":
            return f"{text} [{text} ...]"
        return f"[{text} ...]" if a.nargs == "*" else text
    flag = max(a.option_strings, key=len)
    text = flag if a.nargs == 0 else f"{flag} {_metavar(a)}"
    return text if a.required else f"[{text}]"


_DEFAULT_TEXT = re.compile(r"\(default:? ([^;)]*)")


def _default(a: argparse.Action) -> str:
    if not a.option_strings or a.required:
        return ""
    if a.nargs == 0:
        return "off"
    if a.default is None:
        m = _DEFAULT_TEXT.search(a.help or "")
        return m.group(1).strip() if m else "none"
    if isinstance(a.default, (tuple, list)):
        return ",".join(str(v) for v in a.default)
    return f"{a.default:g}" if isinstance(a.default, float) else str(a.default)


_BOUND = re.compile(r"(whole number [^,;)]*|> 0 and <= [0-9.e+]+|0\.\.[0-9]+|[0-9]+\.\.[0-9]+)")


def _values(a: argparse.Action) -> str:
    if a.choices is not None:
        return ", ".join(str(c) for c in a.choices)
    if not a.option_strings:
        return ""
    m = _BOUND.search(a.help or "")
    return m.group(1) if m else ""


def _cell(text) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _name(a: argparse.Action) -> str:
    if not a.option_strings:
        return f"`{_metavar(a)}`"
    flag = max(a.option_strings, key=len)
    return f"`{flag}`" if a.nargs == 0 else f"`{flag} {_metavar(a)}`"


def _required(a: argparse.Action) -> str:
    return "yes" if a.required or (not a.option_strings and a.nargs not in ("?", "*")) else "no"


def _table(actions: list[argparse.Action]) -> list[str]:
    rows = ["| argument | required | default | values | meaning |", "|---|---|---|---|---|"]
    for a in actions:
        rows.append(f"| {_cell(_name(a))} | {_required(a)} | {_cell(_default(a))} | {_cell(_values(a))} | "
                    f"{_cell(a.help or '')} |")
    return rows


def _helps(parser: argparse.ArgumentParser) -> dict[str, str]:
    """Command name -> its one-line help, from the parent's command list."""
    out = {}

    def walk(prefix: str, p: argparse.ArgumentParser):
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                helps = {c.dest: c.help for c in a._choices_actions}
                for name, child in a.choices.items():
                    full = f"{prefix} {name}".strip()
                    out[full] = helps.get(name) or ""
                    walk(full, child)

    walk("", parser)
    return out


def _notes(p: argparse.ArgumentParser) -> list[str]:
    """The command's epilog: a paragraph, or a text block when it is laid out in lines."""
    if getattr(p, "_epilog_factory", None) is not None:
        p.epilog, p._epilog_factory = p._epilog_factory(), None
    if not p.epilog:
        return []
    if any(line.startswith(" ") for line in p.epilog.splitlines()[1:]):
        return ["```text", p.epilog.rstrip(), "```", ""]
    return [" ".join(p.epilog.split()), ""]


def reference(parser: argparse.ArgumentParser | None = None) -> str:
    """The generated block of docs/commands.md (without the marker lines)."""
    top = parser or build_parser()
    cmds = commands(top)
    helps = _helps(top)
    glob = command_options(top)
    lines = ["```text", "facewarp " + " ".join(_usage_item(a) for a in glob) + " COMMAND ...", ""]
    for name, p in cmds:
        lines.append(f"facewarp {name} " + " ".join(_usage_item(a) for a in command_options(p)))
    lines += ["```", "", "### Global options", "",
              "Accepted before the command (`facewarp --device cuda simulate ...`) or after it "
              "(`facewarp simulate ... --device cuda`); `facewarp --version` prints the version, a bare `facewarp` "
              "the list of commands.", "", *_table(glob), ""]
    for name, p in cmds:
        example = p.example_and_link()[0] if hasattr(p, "example_and_link") else None
        lines += [f"### facewarp {name}", "", _cell(helps.get(name, "")), "",
                  *_table(command_options(p)), "", *_notes(p)]
        if example:
            lines += ["```bash", example, "```", ""]
    return "\n".join(lines).rstrip()


def anchors(parser: argparse.ArgumentParser | None = None) -> dict[str, str]:
    """Command name -> the docs link its ``--help`` ends with (``docs/commands.md#facewarp-rig``)."""
    return {name: docs_link(f"facewarp {name}") for name, _ in commands(parser)}


def update_readme(path: str | Path) -> bool:
    """Rewrite the generated block of the page at ``path``; True when it changed."""
    path = Path(path)
    text = path.read_text()
    i, j = text.index(BEGIN) + len(BEGIN), text.index(END)
    new = text[:i] + "\n" + reference() + "\n" + text[j:]
    if new != text:
        path.write_text(new)
    return new != text


if __name__ == "__main__":
    changed = update_readme(sys.argv[1] if len(sys.argv) > 1 else "docs/commands.md")
    print("updated" if changed else "up to date")
