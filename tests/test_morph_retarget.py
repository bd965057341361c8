"""`facewarp morph` and `facewarp retarget` (thesis Ch. 7): outputs and one-line errors."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

import facewarp
import usd_export
from facewarp.cli import main

PART_MOVE = facewarp.geometry.Similarity(1.04, np.array([[np.cos(0.05), 0, np.sin(0.05)], [0, 1, 0],
                                                [-np.sin(0.05), 0, np.cos(0.05)]]), [0.001, -0.002, 0.003])


@pytest.fixture(scope="module")
def head_b(tmp_path_factory):
    """A second head of the default template's topology: a smoothly reshaped skin, parts moved by a similarity."""
    t = facewarp.default_template(0)
    V = t.vertices * [1.05, 0.98, 1.0] + 0.004 * np.exp(-np.sum((t.vertices - t.landmarks()["9.3"]) ** 2, 1) / 2e-4)[:, None] * [0, 0, 1]
    parts = {k: (PART_MOVE.apply(P), F) for k, (P, F) in t.parts.items()}
    out = tmp_path_factory.mktemp("heads") / "B"
    facewarp.heads.save_template(replace(t, vertices=V, parts=parts), out)
    return out


def run(argv, capsys):
    code = main(["--json", *argv])
    captured = capsys.readouterr()
    return code, (json.loads(captured.out) if code == 0 else None), captured.err


def test_morph_blends_skin_and_parts(head_b, tmp_path, capsys):
    out = tmp_path / "m.usdc"
    code, rep, err = run(["morph", "default", str(head_b), "--steps", "3", "--out", str(out)], capsys)
    assert code == 0, err
    assert rep["samples"] == 5 and all(p["rigid"] for p in rep["parts"].values())
    assert out.with_suffix(".png").is_file() and usd_export.validate_usd(out) == []
    a = usd_export.read_animation(out)
    A, B = facewarp.default_template(0), facewarp.load_head(head_b)
    np.testing.assert_array_equal(a["time_codes"], np.arange(5))
    for k, s in enumerate(np.arange(5) / 4):
        np.testing.assert_allclose(a["points"][k], (1 - s) * A.vertices + s * B.vertices, atol=1e-6)
    for name, (V, _) in A.parts.items():
        M = a["part_transforms"][name]
        np.testing.assert_allclose(V @ M[-1, :3, :3] + M[-1, 3, :3], B.parts[name][0], atol=1e-6, err_msg=name)
        half = V @ M[2, :3, :3] + M[2, 3, :3]  # s = 0.5: a similarity, so distances scale alike
        ratio = np.linalg.norm(half[1:] - half[0], axis=1) / np.linalg.norm(V[1:] - V[0], axis=1)
        np.testing.assert_allclose(ratio, np.sqrt(1.04), rtol=1e-5, err_msg=name)


@pytest.mark.slow
def test_morph_builds_simulatable_heads(head_b, tmp_path, capsys):
    out, build = tmp_path / "m.usda", tmp_path / "heads"
    code, rep, err = run(["morph", "default", str(head_b), "--steps", "1", "--out", str(out), "--build", str(build)],
                         capsys)
    assert code == 0, err
    assert [h["inverted_count"] for h in rep["heads"]] == [0, 0, 0]
    for k in range(3):
        assert (build / f"head_{k:02d}" / "template.npz").is_file() and (build / f"head_{k:02d}" / "build" / "head.xml").is_file()
    f = tmp_path / "mid.usdc"
    code, sim, err = run(["simulate", str(build / "head_01" / "build"), "--expression", "smile", "--seconds", "0.04",
                          "--out", str(f)], capsys)
    assert code == 0 and sim["frames"] == 2, err


def test_retarget_one_sequence_on_several_heads(head_b, tmp_path, capsys):
    seq = tmp_path / "seq.json"
    seq.write_text(json.dumps({"segments": [{"expression": "laugh", "start": 0.0, "attack": 0.03, "hold": 0.05}]}))
    out = tmp_path / "rt"
    code, rep, err = run(["retarget", str(seq), "default", str(head_b), "--seconds", "0.07", "--out", str(out)], capsys)
    assert code == 0, err
    assert [h["name"] for h in rep["heads"]] == ["default", "B"]
    assert (out / "retarget.png").is_file() and (out / "report.json").is_file()
    takes = [usd_export.read_animation(out / f"{n}.usdc") for n in ("default", "B")]
    for a in takes:
        assert len(a["time_codes"]) == 3 and np.abs(a["points"][-1] - a["points"][0]).max() > 1e-3
    np.testing.assert_array_equal(takes[0]["activations"], takes[1]["activations"])  # the same sequence
    assert not np.array_equal(takes[0]["points"], takes[1]["points"])  # on different heads


@pytest.mark.parametrize("argv, needle", [
    (["morph", "default:0", "default:1", "--out", "{tmp}/m.usdc"], "different topology"),
    (["morph", "default", "{tmp}/nope", "--out", "{tmp}/m.usdc"], "no such head folder"),
    (["morph", "default", "{B}", "--out", "{tmp}/m.obj"], "expected a file ending in .usda"),
    (["morph", "default", "{B}", "--out", "{tmp}/no/m.usdc"], "does not exist"),
    (["morph", "default", "{B}", "--steps", "0", "--out", "{tmp}/m.usdc"], "--steps"),
    (["retarget", "{tmp}/nope.json", "default", "--out", "{tmp}/r"], "no such sequence file"),
    (["retarget", "smile", "default", "{tmp}/nope", "--out", "{tmp}/r"], "no such head folder"),
    (["retarget", "{tmp}/bad.json", "default", "--out", "{tmp}/r"], "not valid JSON"),
    (["retarget", "smile", "default", "--seconds", "0", "--out", "{tmp}/r"], "--seconds"),
])
def test_bad_inputs(head_b, tmp_path, capsys, argv, needle):
    (tmp_path / "bad.json").write_text("{")
    argv = [a.format(tmp=tmp_path, B=head_b) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("facewarp: error:") and "\n" not in err and needle in err, err
    assert not (tmp_path / "r").exists() and not list(tmp_path.glob("*.usd*"))
