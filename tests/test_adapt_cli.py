"""`facewarp adapt` end to end on a synthetic scan: a stretched, posed default head in millimetres."""

from __future__ import annotations

import json

import numpy as np
import pytest

from facewarp import default_template, load_mesh, save_obj
from facewarp.cli import main


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    d = tmp_path_factory.mktemp("scan")
    t = default_template(1)  # a different tessellation than the level-0 template
    a = 0.3
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    S = np.array([1.06, 0.97, 1.0])

    def pose(P):
        return ((P * S) @ R.T + [0.1, 0.2, 0.05]) * 1000.0

    save_obj(d / "scan.obj", pose(t.vertices), t.faces)
    lm = t.landmarks()
    ids = ["2.1", "3.7", "3.12", "3.8", "3.11", "8.3", "8.4", "9.3", "10.9", "10.10"]
    (d / "lm.json").write_text(json.dumps({k: pose(lm[k]).tolist() for k in ids}))
    (d / "markers.json").write_text(json.dumps({k: pose(lm[k]).tolist() for k in ["4.1", "4.2", "2.10"]}))
    return d, pose


def test_adapt_writes_outputs(scan, tmp_path, capsys):
    d, pose = scan
    out = tmp_path / "ad"
    code = main(["--json", "adapt", str(d / "scan.obj"), "--landmarks", str(d / "lm.json"), "--out", str(out),
                 "--units", "mm", "--markers", str(d / "markers.json"), "--levels", "3"])
    o, err = capsys.readouterr()
    assert code == 0, err
    for name in ("adapted.obj", "adapted_scan_frame.obj", "adapted_landmarks.json", "report.json",
                 "error_heatmap.png", "error_curve.png"):
        assert (out / name).is_file(), name
    rep = json.loads((out / "report.json").read_text())
    assert rep["levels"] and "E_d" in rep["levels"][-1] and rep["calibration"]["fdps_used"]
    assert rep["distance_to_scan_m"]["median"] < 1e-3
    # the scan-frame result is in the scan's units and pose: compare with the posed truth
    t = default_template(0)
    truth = pose(t.vertices)
    got = load_mesh(out / "adapted_scan_frame.obj").vertices  # read as metres = file numbers
    err_mm = np.linalg.norm(got - truth, axis=1)
    assert np.median(err_mm) < 3.0, np.median(err_mm)


def test_adapt_bad_inputs(scan, tmp_path, capsys):
    d, _ = scan
    few = tmp_path / "few.json"
    few.write_text(json.dumps({"3.7": [0, 0, 0], "3.12": [1, 0, 0], "9.3": [0, 1, 0]}))
    code = main(["adapt", str(d / "scan.obj"), "--landmarks", str(few), "--out", str(tmp_path / "o"), "--units", "mm"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o" / "adapted.obj").exists()
    code = main(["adapt", str(d / "nope.obj"), "--landmarks", str(d / "lm.json"), "--out", str(tmp_path / "o")])
    assert code == 2 and "nope.obj" in capsys.readouterr().err
