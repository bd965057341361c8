"""The README agrees with the command line: the generated command reference is up to date, every
"`COMMAND ... --option ...` (default X" in its prose names the parser's default, and every
`facewarp ...` line of its shell examples parses (required options present, values in range)."""

from __future__ import annotations

import argparse
import re
import shlex
from pathlib import Path

import pytest

from facewarp.cli import build_parser, readme_reference

BEGIN, _, END = readme_reference()


def reference() -> str:
    return readme_reference()[1]


def commands(parser):
    """(command name, its parser) of every leaf command."""
    out = []

    def walk(prefix, p):
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            out.append((prefix, p))
            return
        for name, child in subs[0].choices.items():
            walk(f"{prefix} {name}".strip(), child)

    walk("", parser)
    return out

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "docs" / "commands.md"  # the command reference (the README links to it)
PAGES = [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").rglob("*.md") if "_generated" not in p.parts)]


def _text() -> str:
    return README.read_text()


def _all_text() -> str:
    return "\n".join(p.read_text() for p in PAGES)


def test_generated_reference_is_up_to_date():
    text = _text()
    assert BEGIN in text and END in text
    block = text[text.index(BEGIN) + len(BEGIN):text.index(END)].strip()
    assert block == reference(), "README's command reference is stale: run the command on its begin marker line"


def _option(command: str, flag: str):
    for name, p in commands(build_parser()):
        if name == command:
            for a in p._actions:
                if flag in a.option_strings:
                    return a
    return None


def test_defaults_in_prose_match_the_parser():
    """`adapt --levels N` (default 2 ...): the number after "default" is the parser's default."""
    names = [name for name, _ in commands(build_parser())]
    found = 0
    for m in re.finditer(r"`(?:facewarp )?([a-z -]+?) (--[a-z-]+)[^`]*` \(default:? ([^,;)]+)", _all_text()):
        command, flag, claimed = m.group(1).strip(), m.group(2), m.group(3).strip()
        if command not in names:
            continue
        a = _option(command, flag)
        assert a is not None, f"README names {command} {flag}, which the parser does not have"
        default = a.default
        if isinstance(default, float):
            default = f"{default:g}"
        assert claimed.split()[0] == str(default), f"README: {command} {flag} default {claimed!r}, parser {a.default!r}"
        found += 1
    assert found >= 1  # the adapt --levels sentence at least


def _examples():
    """Every `facewarp ...` command line in the bash blocks of the README and the docs pages."""
    out = []
    for block in re.findall(r"```bash\n(.*?)```", _all_text(), flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" #")[0].strip()
            if line.startswith("facewarp "):
                out.append(line)
    return out


@pytest.mark.parametrize("line", _examples())
def test_shell_examples_parse(line):
    argv = shlex.split(line)[1:]
    try:
        build_parser().parse_args(argv)
    except SystemExit as e:
        pytest.fail(f"README example does not parse ({e.code}): {line}")


def test_required_and_optional_in_usage_lines():
    """The usage lines mark exactly the required options without brackets (from the parser)."""
    block = reference()
    top = build_parser()
    glob = {a.dest for a in top._actions}  # the global options, accepted after the command too
    for name, p in commands(top):
        line = next(ln for ln in block.splitlines() if ln.startswith(f"facewarp {name} "))
        for a in p._actions:
            if not a.option_strings or a.dest == "help" or a.dest in glob:
                continue
            flag = max(a.option_strings, key=len)
            bracketed = f"[{flag}" in line
            assert bracketed != a.required, (name, flag, line)
