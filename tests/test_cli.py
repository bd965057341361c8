"""The facewarp command: template export/info, input checks, one-line errors with exit code 2,
numbers checked while parsing, stdout for results only, Warp quiet unless --verbose."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

import facewarp
import facewarp.cli
from facewarp.cli import main

EXPECTED = ["template.obj", "landmarks.json", "regions.json", "template.json", "template.npz", "skull.obj",
            "preview_front.png", "preview_side.png", "template.usda"]


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, out, err, *needles):
    """Exit code 2, nothing on stdout, exactly one line ``facewarp: error: ...`` on stderr."""
    assert code == 2, (code, err)
    assert out == "", out
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("facewarp: error: "), err
    for n in needles:
        assert n in lines[0], (n, lines[0])


def facewarp_process(*argv, **env_extra):
    """Run ``python -m facewarp ARGV`` in a fresh process (stdout and stderr kept apart; ``env_extra``
    added to its environment)."""
    env = {k: v for k, v in os.environ.items() if k != "FACEWARP_VERBOSE"} | env_extra
    return subprocess.run([sys.executable, "-m", "facewarp", *argv], capture_output=True, text=True, env=env)


@pytest.mark.slow
def test_template_export(tmp_path, capsys):
    out = tmp_path / "t"
    code, _, err = run(capsys, "--json", "template", "export", "--out", str(out), "--level", "0", "--usd")
    assert code == 0, err
    for name in EXPECTED:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    lm = json.loads((out / "landmarks.json").read_text())
    assert len(lm) == 84 and lm["3.7"][0] > 0 > lm["3.12"][0]
    regions = json.loads((out / "regions.json").read_text())
    meta = json.loads((out / "template.json").read_text())
    assert len(regions["face_region"]) == meta["face_count"]
    assert meta["units"] == "m" and meta["level"] == 0 and meta["fdp_count"] == 84
    assert not list(out.glob(".*")), "temporary files left behind"
    from PIL import Image

    assert Image.open(out / "preview_front.png").size[0] >= 400
    t = facewarp.heads.load_template_dir(out)  # the folder reads back as a template
    assert t.vertex_count == meta["vertex_count"] and len(t.fdp) == 84


def test_template_info_json(capsys):
    code, out, _ = run(capsys, "--json", "template", "info", "--level", "0")
    assert code == 0
    d = json.loads(out)
    assert d["fdp_count"] == 84 and d["boundary_loops"] == 4 and d["non_manifold_edges"] == 0


def test_bad_inputs(tmp_path, capsys):
    empty = tmp_path / "empty.obj"
    empty.write_text("")
    one_line_error(*run(capsys, "mesh", "check", str(empty)), "empty")
    nan = tmp_path / "nan.obj"
    nan.write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    one_line_error(*run(capsys, "mesh", "check", str(nan)), "nan.obj", "non-finite")
    one_line_error(*run(capsys, "mesh", "check", str(tmp_path / "missing.obj")), "missing.obj")
    one_line_error(*run(capsys, "mesh", "check", str(tmp_path)), "folder")  # a directory given as a file
    one_line_error(*run(capsys, "landmarks", "check", str(tmp_path)), "folder")
    unknown = tmp_path / "lm.json"
    unknown.write_text('{"3.7": [0, 0, 0], "99.9": [1, 2, 3]}')
    one_line_error(*run(capsys, "landmarks", "check", str(unknown)), "99.9")
    bad = tmp_path / "bad.json"
    bad.write_text('{"3.7": [0, 0, ')
    one_line_error(*run(capsys, "landmarks", "check", str(bad)), "bad.json")
    binary = tmp_path / "binary.json"
    binary.write_bytes(bytes(range(128, 256)))
    one_line_error(*run(capsys, "landmarks", "check", str(binary)), "binary.json")
    afile = tmp_path / "afile"
    afile.write_text("x")
    one_line_error(*run(capsys, "template", "export", "--out", str(afile), "--no-preview"), "not a folder")
    # an output folder that cannot be created fails before any work
    one_line_error(*run(capsys, "template", "export", "--out", str(afile / "sub"), "--no-preview"), "afile", "cannot create")
    one_line_error(*run(capsys, "build", "default", "--out", str(afile / "sub")), "cannot create")


BAD_NUMBERS = [
    (["simulate", "H", "--expression", "smile", "--out", "O", "--seconds", "nan"], "--seconds", "nan"),
    (["simulate", "H", "--expression", "smile", "--out", "O", "--seconds", "inf"], "--seconds", "inf"),
    (["simulate", "H", "--expression", "smile", "--out", "O", "--seconds", "-1"], "--seconds", "-1"),
    (["simulate", "H", "--expression", "smile", "--out", "O", "--seconds", "0"], "--seconds", "0"),
    (["simulate", "H", "--expression", "smile", "--out", "O", "--seconds", "two"], "--seconds", "two"),
    (["simulate", "H", "--expression", "smile", "--out", "O", "--fps", "nan"], "--fps", "nan"),
    (["simulate", "H", "--expression", "smile", "--out", "O", "--fps", "0"], "--fps", "0"),
    (["simulate", "H", "--expression", "smile", "--out", "O", "--fps=-inf"], "--fps", "-inf"),
    (["simulate", "H", "--expression", "smile", "--out", "O", "--substeps", "0"], "--substeps", "0"),
    (["simulate", "H", "--expression", "smile", "--out", "O", "--substeps", "2.5"], "--substeps", "2.5"),
    (["build", "default", "--out", "O", "--layers", "0"], "--layers", "0"),
    (["build", "default", "--out", "O", "--layers", "-2"], "--layers", "-2"),
    (["adapt", "S", "--landmarks", "L", "--out", "O", "--levels", "0"], "--levels", "0"),
    (["adapt", "S", "--landmarks", "L", "--out", "O", "--levels", "-3"], "--levels", "-3"),
    (["adapt", "S", "--landmarks", "L", "--out", "O", "--levels", "nan"], "--levels", "nan"),
    (["template", "info", "--level", "9"], "--level", "9"),
    (["template", "info", "--level", "-1"], "--level", "-1"),
    (["template", "export", "--out", "O", "--level", "1.5"], "--level", "1.5"),
    (["--device", "gpu", "template", "info"], "--device", "gpu"),
]


@pytest.mark.parametrize("argv, flag, value", BAD_NUMBERS, ids=[f"{f} {v}" for _, f, v in BAD_NUMBERS])
def test_numbers_checked_while_parsing(argv, flag, value, tmp_path, capsys):
    """Every numeric argument is checked before any work (the paths here do not even exist)."""
    one_line_error(*run(capsys, *argv), flag, repr(value))


def test_level_limit_is_the_templates(capsys):
    """The CLI's level range is the one default_template accepts."""
    top = facewarp.cli.MAX_TEMPLATE_LEVEL
    with pytest.raises(facewarp.InputError, match=f"0..{top}"):
        facewarp.default_template(top + 1)
    one_line_error(*run(capsys, "template", "info", "--level", str(top + 1)), f"0..{top}")


def test_build_default_level_message(tmp_path, capsys):
    one_line_error(*run(capsys, "build", "default:9", "--out", str(tmp_path / "o")), "default:9", "levels 0..4")
    assert not (tmp_path / "o").exists()


def test_device_cuda_without_gpu(capsys):
    code, out, err = run(capsys, "--device", "cuda", "template", "info")
    if code == 0:
        pytest.skip("a CUDA device is present")
    one_line_error(code, out, err, "--device cuda", "no CUDA device")


@pytest.mark.slow
def test_json_stdout_is_one_document_and_warp_is_quiet(tmp_path):
    """With --json stdout holds exactly one JSON document; Warp's messages (banner, the CUDA
    driver note on machines without a GPU) appear only with --verbose, and then on stderr."""
    r = facewarp_process("--json", "template", "info", FACEWARP_CACHE_DIR="off")  # no template cache: Warp runs
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["fdp_count"] == 84
    assert r.stderr == "", r.stderr  # Warp ran (FDP placement) but said nothing
    quad = tmp_path / "quad.obj"
    quad.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    r = facewarp_process("--json", "--device", "cpu", "mesh", "check", str(quad))
    assert r.returncode == 0 and json.loads(r.stdout)["face_count"] == 2 and r.stderr == ""
    r = facewarp_process("--json", "--verbose", "template", "info", FACEWARP_CACHE_DIR="off")
    assert r.returncode == 0 and json.loads(r.stdout)["vertex_count"] > 0
    assert "Warp" in r.stderr  # the banner went to stderr


def test_help_imports_nothing_heavy():
    code = ("import sys, contextlib, io\n"
            "from facewarp.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()) as f:\n"
            "    assert main(['--help']) == 0\n"
            "assert 'COMMAND' in f.getvalue()\n"
            "print(sorted({'numpy', 'scipy', 'warp', 'trimesh'} & set(sys.modules)))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]", r.stdout


def test_help_texts(capsys):
    code, out, _ = run(capsys, "simulate", "--help")
    assert code == 0
    for name in facewarp.PRESETS:
        assert name in out, name
    for word in ('"segments"', '"attack"', '"hold"', '"release"', '"blend"', '"muscles"', '"jaw_deg"'):
        assert word in out, word
    assert "zygomatic_major" in out
    code, out, _ = run(capsys, "adapt", "--help")
    assert code == 0 and "refinement levels after the FDP level" in out and "default 2" in out


def test_mesh_check_reports(tmp_path, capsys):
    p = tmp_path / "quad.obj"
    p.write_text("v 0 0 0\nv 10 0 0\nv 10 10 0\nv 0 10 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n")
    code, out, _ = run(capsys, "--json", "mesh", "check", str(p), "--units", "mm")
    d = json.loads(out)
    assert code == 0 and d["face_count"] == 2 and d["boundary_loop_count"] == 1 and d["has_uv"]


def test_internal_error_is_one_line(monkeypatch, capsys):
    def boom(args):
        raise RuntimeError("boom")

    real = facewarp.cli.build_parser

    def build():  # the real parser, with `template info` running boom
        top = real()
        sub = next(a for a in top._actions if a.__class__.__name__ == "_SubParsersAction")
        tsub = next(a for a in sub.choices["template"]._actions if a.__class__.__name__ == "_SubParsersAction")
        tsub.choices["info"].set_defaults(func=boom)
        return top

    monkeypatch.setattr(facewarp.cli, "build_parser", build)
    code, out, err = run(capsys, "template", "info")
    assert code == 1 and out == "" and len(err.strip().splitlines()) == 1
    assert "RuntimeError: boom" in err and "--verbose" in err
    with pytest.raises(RuntimeError, match="boom"):  # --verbose: the traceback
        main(["--verbose", "template", "info"])


def test_console_script_exit_code(tmp_path):
    r = facewarp_process("mesh", "check", str(tmp_path / "nope.ply"))
    assert r.returncode == 2 and "Traceback" not in r.stderr and "nope.ply" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_closed_stdout(tmp_path):
    """`facewarp ... | head -1`: the reader goes away; no traceback."""
    lm = tmp_path / "lm.json"
    lm.write_text(json.dumps({"3.7": [0.03, 0.0, 0.08], "3.12": [-0.03, 0.0, 0.08], "9.3": [0, -0.03, 0.1]}))
    p = subprocess.Popen([sys.executable, "-m", "facewarp", "landmarks", "check", str(lm)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    p.stdout.close()
    err = p.stderr.read()
    p.wait(timeout=60)
    p.stderr.close()
    assert "Traceback" not in err and p.returncode in (0, facewarp.cli.EXIT_BROKEN_PIPE), err
