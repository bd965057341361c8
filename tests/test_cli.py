"""The facewarp command: template export/info, input checks, one-line errors with exit code 2."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from facewarp.cli import main

EXPECTED = ["template.obj", "landmarks.json", "regions.json", "template.json", "template.npz", "skull.obj",
            "preview_front.png", "preview_side.png", "template.usda"]


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


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
    # the folder reads back as a template
    from facewarp import load_template_dir

    t = load_template_dir(out)
    assert t.vertex_count == meta["vertex_count"] and len(t.fdp) == 84


def test_template_info_json(capsys):
    code, out, _ = run(capsys, "--json", "template", "info", "--level", "0")
    assert code == 0
    d = json.loads(out)
    assert d["fdp_count"] == 84 and d["boundary_loops"] == 4 and d["non_manifold_edges"] == 0


def one_line_error(code, err, *needles):
    assert code == 2
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("Warp")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for n in needles:
        assert n in lines[0], lines[0]


def test_bad_inputs(tmp_path, capsys):
    empty = tmp_path / "empty.obj"
    empty.write_text("")
    one_line_error(*run(capsys, "mesh", "check", str(empty))[::2], "empty")
    nan = tmp_path / "nan.obj"
    nan.write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    one_line_error(*run(capsys, "mesh", "check", str(nan))[::2], "nan.obj", "non-finite")
    one_line_error(*run(capsys, "mesh", "check", str(tmp_path / "missing.obj"))[::2], "missing.obj")
    unknown = tmp_path / "lm.json"
    unknown.write_text('{"3.7": [0, 0, 0], "99.9": [1, 2, 3]}')
    one_line_error(*run(capsys, "landmarks", "check", str(unknown))[::2], "99.9")
    bad = tmp_path / "bad.json"
    bad.write_text('{"3.7": [0, 0, ')
    one_line_error(*run(capsys, "landmarks", "check", str(bad))[::2], "bad.json")
    one_line_error(*run(capsys, "template", "export", "--out", str(tmp_path / "x"), "--level", "9")[::2], "level")
    afile = tmp_path / "afile"
    afile.write_text("x")
    one_line_error(*run(capsys, "template", "export", "--out", str(afile), "--no-preview")[::2], "not a folder")


def test_mesh_check_reports(tmp_path, capsys):
    p = tmp_path / "quad.obj"
    p.write_text("v 0 0 0\nv 10 0 0\nv 10 10 0\nv 0 10 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n")
    code, out, _ = run(capsys, "--json", "mesh", "check", str(p), "--units", "mm")
    d = json.loads(out)
    assert code == 0 and d["face_count"] == 2 and d["boundary_loop_count"] == 1 and d["has_uv"]


def test_console_script_exit_code(tmp_path):
    r = subprocess.run([sys.executable, "-m", "facewarp", "mesh", "check", str(tmp_path / "nope.ply")],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "nope.ply" in r.stderr
