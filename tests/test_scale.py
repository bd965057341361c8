"""`--units auto`: the scan's scale from its FDPs against human proportions, and the refusal of
FDPs far outside them in the given units."""

from __future__ import annotations

import json

import numpy as np
import pytest

import facewarp as fw
from facewarp.cli import main


def _write(folder, scan, metres_per_unit, *, scale=1.0):
    folder.mkdir(parents=True, exist_ok=True)
    fw.geometry.save_obj(folder / "scan.obj", scan.vertices * scale / metres_per_unit, scan.faces)
    lm = {k: (np.asarray(v) * scale / metres_per_unit).tolist() for k, v in scan.landmarks.items()}
    (folder / "lm.json").write_text(json.dumps(lm))
    return folder / "scan.obj", folder / "lm.json"


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("unit", [1e-3, 1e-2, 1.0, "random"])
def test_estimate_scale_recovers_units(seed, unit):
    scan = fw.synthetic_scan(seed)
    f = float(np.random.default_rng(seed).uniform(0.002, 0.05)) if unit == "random" else unit
    est = fw.adaptation.estimate_scale({k: np.asarray(v) / f for k, v in scan.landmarks.items()})
    assert est.metres_per_unit == pytest.approx(f, rel=0.05)


def test_template_measures_are_human():
    REFERENCE_M = fw.adaptation.SCALE_REFERENCE_M
    m = fw.adaptation.face_measures(fw.default_template(1).landmarks())
    for k, (lo, hi) in fw.adaptation.HUMAN_RANGES_M.items():
        assert lo <= m[k] <= hi, (k, m[k])
        assert m[k] == pytest.approx(REFERENCE_M[k], abs=1e-4), k


def test_one_bad_fdp_pair_takes_the_median():
    scan = fw.synthetic_scan(2)
    lm = {k: np.asarray(v) * 1e3 for k, v in scan.landmarks.items()}
    lm["9.3"] = lm["9.3"] + (lm["9.3"] - 0.5 * (lm["3.7"] + lm["3.12"])) * 0.6  # the nose tip far off
    est = fw.adaptation.estimate_scale(lm)
    assert est.estimator == "median" and est.metres_per_unit == pytest.approx(1e-3, rel=0.05)


def test_half_scale_scan_stops_with_one_line(tmp_path, capsys):
    scan = fw.synthetic_scan(0)
    s, lm = _write(tmp_path / "half", scan, 1e-3, scale=0.5)
    code = main(["adapt", str(s), "--landmarks", str(lm), "--units", "mm", "--out", str(tmp_path / "o")])
    _, err = capsys.readouterr()
    assert code == 2
    line = err.strip()
    assert "\n" not in line and "eyes" in line and "mm apart" in line and "likely factor" in line, line
    factor = float(line.split("likely factor ")[1].split()[0])
    assert 1.9 <= factor <= 2.1, line
    assert not (tmp_path / "o").exists()


def test_auto_units_end_to_end(tmp_path, capsys):
    """A scan in an arbitrary unit (1 unit = 13.7 mm) adapts with the default units (its extent is
    no head in metres, so auto) and lands in the scan's frame and units."""
    scan = fw.synthetic_scan(1)
    f = 0.0137
    s, lm = _write(tmp_path / "any", scan, f)
    out = tmp_path / "o"
    code = main(["adapt", str(s), "--landmarks", str(lm), "--out", str(out), "--levels", "1"])
    o, err = capsys.readouterr()
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert rep["scale"]["units"] == "auto" and rep["scale"]["given"] is None
    assert rep["scale_to_metres"] == pytest.approx(f, rel=0.05)
    assert "scale: auto from the FDPs" in o
    # in the scan's units: close to the truth scaled by the same estimate
    got = fw.load_mesh(out / "adapted_scan_frame.obj").vertices
    k = rep["scale_to_metres"] / f
    center = scan.truth.mean(0) / f
    err = np.linalg.norm((got - center) * k - (scan.truth / f - center), axis=1) * f
    assert np.median(err) < 3e-3, np.median(err)
