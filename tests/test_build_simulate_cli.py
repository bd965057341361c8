"""`facewarp build` and `facewarp simulate` end to end, and their one-line errors."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

import facewarp
from facewarp.cli import main
from conftest import fresh_build


@pytest.fixture(scope="module")
def built(tmp_path_factory, default_build_dir):
    return fresh_build(tmp_path_factory, default_build_dir)


def test_build_outputs(built):
    for name in ("tets.npz", "muscles.json", "anatomy.json", "anatomy.png", "face_rig.npz", "head.xml", "scene.xml"):
        assert (built / name).is_file(), name
    q = json.loads((built / "anatomy.json").read_text())
    assert q["inverted_count"] == 0 and q["conforming"] and q["muscle_count"] == 27
    assert q["min_attached_nodes"] >= 5
    z = np.load(built / "tets.npz")
    assert z["vertices"].shape[1] == 3 and z["tets"].shape[1] == 4
    assert set(np.unique(z["layer"])) == {0, 1} and (z["surface_vertex"] >= -1).all()
    m = json.loads((built / "muscles.json").read_text())
    names = set(m["muscles"])
    assert {"zygomatic_major_L", "zygomatic_major_R", "orbicularis_oris", "orbicularis_oculi_L"} <= names


@pytest.mark.slow
def test_simulate_outputs(built, tmp_path, capsys):
    out = tmp_path / "sim"
    code = main(["--json", "simulate", str(built), "--expression", "smile", "--seconds", "0.2", "--fps", "20",
                 "--out", str(out), "--usd"])
    o, err = capsys.readouterr()
    assert code == 0, err
    rep = json.loads(o)
    assert rep["steps_per_second"] > 0 and rep["frames"] == 5
    assert rep["frame_stats"]["frames"] == 4 and rep["mujoco_events"] == []  # 4 steps after the rest frame
    z = np.load(out / "frames.npz")
    assert z["points"].shape[0] == 5 and z["fdp_points"].shape == (5, 84, 3) and z["times"].shape == (5,)
    assert len(z["fdp_ids"]) == 84
    assert (out / "frames.png").is_file() and (out / "animation.usdc").is_file()
    own = tmp_path / "own"  # a user's own expression: muscles and a chin drop
    code = main(["--json", "simulate", str(built), "--activations", "zygomatic_major_L=0.8,jaw_drop_mm=10",
                 "--seconds", "0.15", "--fps", "20", "--out", str(own)])
    assert code == 0, capsys.readouterr().err
    z = np.load(own / "frames.npz")
    assert (own / "frames.png").is_file() and z["points"].shape[0] == 4


def test_simulate_thesis_with_the_mujoco_jaw_is_stable(built, tmp_path, capsys, monkeypatch):
    """Every material profile couples to the MuJoCo jaw (issue 23; it was refused with the thesis
    profile, whose holds threw the mandible off): no MuJoCo warning, the jaw within its range."""
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "thesis"
    code = main(["--json", "simulate", str(built), "--expression", "smile", "--seconds", "0.2", "--material", "thesis",
                 "--jaw", "mujoco", "--out", str(out)])
    o, err = capsys.readouterr()
    assert code == 0, err
    rep = json.loads(o)
    assert rep["jaw"] == "mujoco" and rep["mujoco_events"] == [] and rep["frame_stats"]["frames"] == 6
    jaw = np.load(out / "frames.npz")["jaw"]
    assert np.all(np.abs(jaw[:, 0]) < 0.02) and np.all(np.abs(jaw[:, 1]) <= np.deg2rad(5.0)), jaw
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_errors(built, tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    seq = tmp_path / "seq_blend.json"
    seq.write_text(json.dumps({"segments": [{"expression": {"blend": 3}}]}))
    seq2 = tmp_path / "seq_muscles.json"
    seq2.write_text(json.dumps({"segments": [{"expression": {"muscles": ["zygomatic_major"]}}]}))
    o = str(tmp_path / "o")
    cases = [
        (["build", str(tmp_path / "nope"), "--out", o], "nope"),
        (["build", "default:7", "--out", o], "levels 0..4"),
        (["build", "default", "--out", o, "--prefix", "a b"], "prefix"),
        (["simulate", str(built), "--expression", "grin", "--out", o], "grin"),
        (["simulate", str(built), "--expression", "smile", "--seconds", "-1", "--out", o], "--seconds"),
        (["simulate", str(built), "--expression", "smile", "--seconds", "nan", "--out", o], "--seconds"),
        (["simulate", str(built), "--expression", "smile", "--seconds", "1e9", "--out", o], "<= 3600"),
            (["simulate", str(built), "--expression", "smile", "--seconds", "3000", "--fps", "1000", "--out", o],
             "frames"),
        (["simulate", str(tmp_path), "--expression", "smile", "--out", o], "face_rig"),
        (["simulate", str(built), "--expression", "smile", "--solver", "verlet", "--substeps", "1", "--out", o],
         "substeps"),
        (["simulate", str(built), "--expression", str(seq), "--out", o], "blend"),
        (["simulate", str(built), "--expression", str(seq2), "--out", o], "muscles"),
        (["simulate", str(built), "--expression", "smile", "--out", str(afile)], "not a folder"),
        (["simulate", str(built), "--expression", "smile", "--out", str(afile / "sub")], "cannot create"),
    ]
    for argv, needle in cases:
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2, (argv, err)
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "o").exists()  # every error came before the output folder was made


def test_simulate_activation_errors(built, tmp_path, capsys):
    o = str(tmp_path / "o")
    for argv, needle in [
        (["simulate", str(built), "--out", o], "expression or activations"),
        (["simulate", str(built), "--expression", "smile", "--activations", "corrugator=1", "--out", o], "exactly one"),
        (["simulate", str(built), "--activations", "corrugator=2", "--out", o], "[0, 1]"),
        (["simulate", str(built), "--activations", "nose=0.5", "--out", o], "nose"),
        (["simulate", str(built), "--activations", "smile", "--out", o], "muscle=number"),
    ]:
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2, (argv, err)
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "o").exists()


def test_build_rejects_mismatched_topology(tmp_path, capsys):
    """An adapt output whose adapted.obj does not have its template's topology: one-line error."""
    t = facewarp.default_template(0)
    d = tmp_path / "adapt"
    d.mkdir()
    facewarp.geometry.save_obj(d / "adapted.obj", t.vertices[:-10], t.faces[(t.faces < len(t.vertices) - 10).all(1)])
    (d / "report.json").write_text(json.dumps({"template": "default template (level 0)"}))
    code = main(["build", str(d), "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err
    assert code == 2 and "topology" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(facewarp.InputError, match="topology"):
        facewarp.build_anatomy(replace(t, thickness=t.thickness[:-1]))
