"""The command reference of ``docs/commands.md``, generated from the ``facewarp`` argument parser.

The block between ``<!-- cli-reference:begin -->`` and ``<!-- cli-reference:end -->`` in
README.md is :func:`reference` (a usage line per command, then a table of every option with
whether it is required, its default and its values or bounds); ``tests/test_readme_cli.py``
fails when it is out of date. Rewrite it with::

    python -m facewarp._src.cli_reference docs/commands.md
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

__all__ = ["BEGIN", "END", "commands", "reference", "update_readme"]

BEGIN = "<!-- cli-reference:begin (generated from the parser: python -m facewarp._src.cli_reference docs/commands.md) -->"
END = "<!-- cli-reference:end -->"


def _subparsers(p: argparse.ArgumentParser):
    for a in p._actions:
        if isinstance(a, argparse._SubParsersAction):
            return a
    return None


def commands(parser: argparse.ArgumentParser | None = None) -> list[tuple[str, argparse.ArgumentParser]]:
    """(``"adapt"``, its parser), (``"template export"``, ...) for every leaf command, in order."""
    if parser is None:
        from .cli import build_parser

        parser = build_parser()
    out = []

    def walk(prefix: str, p: argparse.ArgumentParser):
        sub = _subparsers(p)
        if sub is None:
            out.append((prefix, p))
            return
        for name, child in sub.choices.items():
            walk(f"{prefix} {name}".strip(), child)

    walk("", parser)
    return out


def _options(p: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in p._actions if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]


def _metavar(a: argparse.Action) -> str:
    if a.choices is not None:
        return "|".join(str(c) for c in a.choices)
    if a.metavar is not None:
        return str(a.metavar)
    return a.dest.upper()


def _usage_item(a: argparse.Action) -> str:
    if not a.option_strings:  # positional
        text = _metavar(a)
        return f"{text} [{text} ...]" if a.nargs == "+" else text
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
    return f"{a.default:g}" if isinstance(a.default, float) else str(a.default)


_BOUND = re.compile(r"(whole number [^,;)]*|> 0 and <= [0-9.e+]+|0\.\.[0-9]+|[0-9]+\.\.[0-9]+)")


def _values(a: argparse.Action) -> str:
    if a.choices is not None:
        return ", ".join(str(c) for c in a.choices)
    if not a.option_strings:
        return ""
    m = _BOUND.search(a.help or "")
    return m.group(1) if m else ""


def reference(parser: argparse.ArgumentParser | None = None) -> str:
    """The generated README block (without the marker lines)."""
    from .cli import build_parser

    top = parser or build_parser()
    cmds = commands(top)
    glob = _options(top)
    lines = ["```", "facewarp " + " ".join(_usage_item(a) for a in glob) + " COMMAND ...", ""]
    for name, p in cmds:
        lines.append(f"facewarp {name} " + " ".join(_usage_item(a) for a in _options(p)))
    lines += ["```", "", "| command | option | required | default | values |", "|---|---|---|---|---|"]
    for a in glob:
        lines.append(f"| (all) | `{max(a.option_strings, key=len)}` | no | {_default(a)} | {_values(a)} |")
    for name, p in cmds:
        for a in _options(p):
            opt = f"`{max(a.option_strings, key=len)}`" if a.option_strings else f"`{_metavar(a)}`"
            req = "yes" if a.required or (not a.option_strings and a.nargs != "?") else "no"
            lines.append(f"| {name} | {opt} | {req} | {_default(a)} | {_values(a)} |")
    return "\n".join(lines)


def update_readme(path: str | Path) -> bool:
    """Rewrite the generated block of the README at ``path``; True when it changed."""
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
