"""A newcomer's first hour with the command (issue 35): ``--version``; the global options after the
command too; a bare ``facewarp`` prints the usage with the commands; every ``--help`` ends with an
example that parses and a link to its section of docs/commands.md; BUILD names the build folder
everywhere; one muscle-name rule (a bare name means both sides); progress as plain lines on stderr
when it is not a terminal."""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

import facewarp
from facewarp.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
COMMANDS_PAGE = ROOT / "docs" / "commands.md"


def leaves(parser=None):
    """(command words, parser) of every command that runs."""
    out = []

    def walk(words, p):
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            out.append((words, p))
            return
        for name, child in subs[0].choices.items():
            walk(words + [name], child)

    walk([], parser or build_parser())
    return out


def process(*argv, env_extra=None, drop=("FACEWARP_PROGRESS", "FACEWARP_VERBOSE")):
    """``python -m facewarp ARGV`` in a fresh process with stdout and stderr pipes (not terminals)."""
    env = {k: v for k, v in os.environ.items() if k not in drop} | dict(env_extra or {})
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-m", "facewarp", *map(str, argv)], capture_output=True, text=True,
                          env=env, timeout=600)


def github_anchor(heading: str) -> str:
    """The anchor GitHub (and MyST) gives a Markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


# ----------------------------------------------------------------------------- --version, bare facewarp
def test_version(capsys):
    assert main(["--version"]) == 0
    out, err = capsys.readouterr()
    assert out.strip() == f"facewarp {facewarp.__version__}" and err == ""


def test_bare_facewarp_prints_the_usage_and_the_commands(capsys):
    assert main([]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.startswith("usage: facewarp")
    for words, _ in leaves():
        assert words[0] in err, words
    assert "docs: docs/commands.md" in err
    assert main(["template"]) == 2  # a group without its action: its actions
    _, err = capsys.readouterr()
    assert err.startswith("usage: facewarp template") and "import-ict" in err


# ----------------------------------------------------------------------------- global options after the command
def _value_for(a) -> str:
    """A value the option's type accepts: a file name, or a number for numeric options."""
    for v in ("x.usda" if "usd" in str(a.metavar).lower() else "x", "1"):
        try:
            if a.type is None or a.type(v) is not None:
                return v
        except (argparse.ArgumentTypeError, ValueError, TypeError):
            continue
    return "x"


@pytest.mark.parametrize("words, p", leaves(), ids=[" ".join(w) for w, _ in leaves()])
def test_global_options_parse_after_the_command(words, p):
    """Every command takes --device, --json and --verbose after its own arguments too, with the
    same result as before the command; one given after wins over one given before."""
    parser = build_parser()
    required = []
    for a in p._actions:
        if isinstance(a, argparse._HelpAction):
            continue
        if not a.option_strings:
            required += [] if a.nargs == "*" else ["x"]
        elif a.required:
            required += [a.option_strings[-1], _value_for(a)]
    groups = [g for g in p._mutually_exclusive_groups if g.required]
    for g in groups:
        required += [g._group_actions[0].option_strings[-1], "x"]
    before = parser.parse_args(["--device", "cuda:1", "--json", "--verbose", *words, *required])
    after = parser.parse_args([*words, *required, "--device", "cuda:1", "--json", "--verbose"])
    plain = parser.parse_args([*words, *required])
    assert (before.device, before.json, before.verbose) == (after.device, after.json, after.verbose) == \
        ("cuda:1", True, True)
    assert (plain.device, plain.json, plain.verbose) == ("cpu", False, False)
    both = parser.parse_args(["--device", "cuda:1", *words, *required, "--device", "cpu"])
    assert both.device == "cpu"


def test_global_option_after_the_command_runs(tmp_path, capsys):
    p = tmp_path / "quad.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    assert main(["mesh", "check", str(p), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["face_count"] == 2
    code = main(["template", "info", "--device", "cuda:99"])
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1 and "--device cuda:99" in err, err


def test_an_unknown_option_names_the_closest_one(capsys):
    assert main(["simulate", "b", "--out", "o", "--devise", "cuda"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == ("facewarp: error: unrecognized arguments: --devise cuda (did you mean --device? "
                           "`facewarp simulate --help` lists its options)"), err


# ----------------------------------------------------------------------------- --help: example and docs link
@pytest.mark.parametrize("words, p", leaves(), ids=[" ".join(w) for w, _ in leaves()])
def test_help_ends_with_an_example_and_the_docs_link(words, p):
    lines = p.format_help().rstrip().splitlines()
    assert lines[-4] == "example:" and lines[-2] == "" and lines[-1].startswith("docs: "), lines[-6:]
    example = lines[-3].strip()
    assert example.startswith("facewarp " + " ".join(words) + " "), example
    build_parser().parse_args(shlex.split(example)[1:])  # the example parses (SystemExit fails the test)
    page, anchor = lines[-1][len("docs: "):].split("#")
    assert (ROOT / page) == COMMANDS_PAGE
    headings = [ln.lstrip("#").strip() for ln in COMMANDS_PAGE.read_text().splitlines() if ln.startswith("#")]
    assert anchor == github_anchor("facewarp " + " ".join(words)) and anchor in map(github_anchor, headings)
    assert example in COMMANDS_PAGE.read_text()  # the page shows the same example


def test_top_level_help_ends_with_an_example_and_the_page(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out.rstrip().splitlines()
    assert out[-1] == "docs: docs/commands.md" and out[-3:-1] == ["  facewarp demo --out demo", ""]


def test_commands_page_is_plain_markdown():
    """docs/commands.md reads on GitHub: no Sphinx roles or directives."""
    text = COMMANDS_PAGE.read_text()
    assert not re.search(r"\{(doc|ref|include|image|eval-rst)\}", text)
    assert not re.search(r"\]\(\.\./\.\./", text)  # no link out of the repository (docs/../.. )


# ----------------------------------------------------------------------------- BUILD
def test_the_build_folder_is_BUILD_everywhere():
    """Every positional that takes a `facewarp build` output folder is shown as BUILD."""
    seen = []
    for words, p in leaves():
        for a in p._actions:
            if a.option_strings:
                continue
            if "`facewarp build` output" in (a.help or "") and "template" not in (a.help or ""):
                assert a.metavar == "BUILD", (words, a.metavar)
                seen.append(" ".join(words))
            assert a.metavar not in ("BUILD_DIR", "head", "build"), (words, a.metavar)
    assert set(seen) == {"rig", "simulate", "drive", "live", "batch simulate"}, seen


# ----------------------------------------------------------------------------- one muscle-name rule
@pytest.mark.parametrize("argv", [["rig", "b", "--out", "r.glb", "--muscles"],
                                  ["batch", "run", "s.obj", "--out", "o", "--rig-muscles"]])
def test_muscle_options_take_bare_names(argv):
    parser = build_parser()
    args = parser.parse_args(argv + ["zygomatic_major, corrugator_L,orbicularis_oris"])
    names = args.muscles if argv[0] == "rig" else args.rig_muscles
    assert names == ["zygomatic_major", "corrugator_L", "orbicularis_oris"]


@pytest.mark.parametrize("bad", ["nose", "zygomatic_major_X", ",", "corrugator_l"])
def test_muscle_options_refuse_unknown_names_while_parsing(bad, capsys):
    assert main(["rig", "missing_build", "--out", "r.glb", "--muscles", bad]) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1 and "argument --muscles" in err, err


def test_activations_take_the_same_names():
    """--activations and --muscles read a name the same way: bare = both sides, _L / _R = one."""
    e = facewarp.expressions.expression_from_activations("zygomatic_major=0.6,corrugator_L=0.3")
    assert e.activation("zygomatic_major", "L") == e.activation("zygomatic_major", "R") == pytest.approx(0.6)
    assert e.activation("corrugator", "L") == pytest.approx(0.3) and e.activation("corrugator", "R") == 0.0
    with pytest.raises(facewarp.InputError, match="unknown muscle 'nose'.*both sides"):
        facewarp.expressions.expression_from_activations("nose=0.5")


@pytest.fixture(scope="module")
def build(default_build_dir):
    return default_build_dir  # read only here (rig and simulate write beside it, in tmp_path)


@pytest.mark.slow
def test_rig_bakes_both_sides_of_a_bare_name(build, tmp_path, capsys):
    capsys.readouterr()
    assert main(["rig", str(build), "--out", str(tmp_path / "r.glb"), "--muscles", "zygomatic_major", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["muscles"] == 2  # zygomatic_major_L and _R
    code = main(["rig", str(build), "--out", str(tmp_path / "r2.glb"), "--muscles", "zygomatic_major_L", "--json"])
    assert code == 0 and json.loads(capsys.readouterr().out)["muscles"] == 1


# ----------------------------------------------------------------------------- progress off a terminal
def test_progress_is_a_line_per_stage_off_a_terminal(tmp_path):
    r = process("template", "export", "--out", tmp_path / "t", "--no-preview")
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) >= 3 and all(re.fullmatch(r"facewarp template export: \[\d/\d\] .* \(\d+\.\d s\)", ln)
                                   for ln in lines), lines
    assert lines[0].startswith("facewarp template export: [1/3] ")
    assert "\r" not in r.stderr and "\x1b" not in r.stderr  # no bar drawing
    assert r.stdout.startswith("wrote ")  # the result alone on stdout
    quiet = process("--json", "template", "export", "--out", tmp_path / "t2", "--no-preview")
    off = process("template", "export", "--out", tmp_path / "t3", "--no-preview", env_extra={"FACEWARP_PROGRESS": "off"})
    assert quiet.returncode == off.returncode == 0 and quiet.stderr == off.stderr == ""


@pytest.mark.slow
def test_frames_show_off_a_terminal(build, tmp_path):
    r = process("simulate", build, "--expression", "smile", "--seconds", "0.2", "--jaw", "kinematic", "--out",
                tmp_path / "s.usdc")
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert lines[0].startswith("facewarp simulate: frame 1/7 (") and lines[-1].startswith("facewarp simulate: frame 7/7, ")
    assert all(ln.startswith("facewarp simulate: ") for ln in lines), lines


def test_no_progress_line_outlives_its_command(tmp_path, capsys, monkeypatch):
    """A command that fails after making its progress (here: adapt on a missing scan) leaves no
    writer behind to print "still working" into later output."""
    import threading

    monkeypatch.setenv("FACEWARP_PROGRESS", "lines")
    assert main(["adapt", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "o")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1].startswith("facewarp: error: ") and "missing.ply" in lines[-1], lines
    assert all(ln.startswith("facewarp adapt: [") for ln in lines[:-1]), lines  # the stages begun, then the error
    for t in threading.enumerate():
        if t.name == "facewarp-progress":
            t.join(timeout=5)
            assert not t.is_alive()
