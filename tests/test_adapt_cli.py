"""`facewarp adapt` end to end on a synthetic scan (a stretched, posed default head in millimetres),
and its input checks on a sphere scan: each bad input is one line within seconds, before the
adaptation and before the output folder is made."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from facewarp import default_template, load_mesh
from facewarp.geometry import save_obj
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
    code = main(["adapt", str(d / "scan.obj"), "--landmarks", str(d / "lm.json"), "--out", str(out),
                 "--units", "mm", "--markers", str(d / "markers.json"), "--levels", "3"])
    o, err = capsys.readouterr()
    assert code == 0, err
    for name in ("adapted.obj", "adapted_scan_frame.obj", "adapted_landmarks.json", "report.json",
                 "error_heatmap.png", "error_curve.png"):
        assert (out / name).is_file(), name
    rep = json.loads((out / "report.json").read_text())
    assert rep["levels"] and "E_d" in rep["levels"][-1] and rep["calibration"]["fdps_used"]
    assert rep["distance_to_scan_m"]["median"] < 1e-3
    # --levels counts the refinement levels after the FDP level: report levels 2..N+1 at most
    refine = [r for r in rep["levels"] if r["kind"] in ("rbf", "csrbf") and r["level"] >= 2]
    assert 1 <= len(refine) <= 3 and max(r["level"] for r in refine) <= 4
    assert "of 3 refinement levels" in o, o
    # the scan-frame result is in the scan's units and pose: compare with the posed truth
    t = default_template(0)
    truth = pose(t.vertices)
    got = load_mesh(out / "adapted_scan_frame.obj").vertices  # read as metres = file numbers
    err_mm = np.linalg.norm(got - truth, axis=1)
    assert np.median(err_mm) < 3.0, np.median(err_mm)


@pytest.fixture(scope="module")
def sphere(tmp_path_factory):
    """A 10 cm sphere 'scan' around the template's centre and landmark files of several faults
    (landmarks: the template's FDPs pushed radially onto the sphere)."""
    import trimesh

    d = tmp_path_factory.mktemp("sphere")
    t = default_template(0)
    lm = t.landmarks()
    c = t.vertices.mean(0)
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    save_obj(d / "sphere.obj", np.asarray(s.vertices) + c, np.asarray(s.faces))

    def on_sphere(k):
        v = lm[k] - c
        return c + 0.1 * v / np.linalg.norm(v)

    ids = ["2.1", "3.7", "3.12", "8.3", "8.4", "9.3", "11.1", "10.9", "10.10"]
    good = {k: on_sphere(k) for k in ids}
    cases = {
        "few": {k: good[k] for k in ids[:3]},
        "coplanar": {k: np.array([good[k][0], good[k][1], c[2]]) for k in ("2.1", "3.7", "3.12", "8.3", "8.4")},
        "far": {**good, "9.3": good["9.3"] + [0.0, 0.0, 0.08]},
        "mm": {k: v * 1000.0 for k, v in good.items()},  # landmarks in mm, the scan in m
    }
    for name, pts in cases.items():
        (d / f"{name}.json").write_text(json.dumps({k: np.asarray(v).tolist() for k, v in pts.items()}))
    (d / "good.json").write_text(json.dumps({k: v.tolist() for k, v in good.items()}))
    return d


@pytest.mark.parametrize("case, needles", [
    ("few", ["at least 4 FDPs", "got 3"]),
    ("coplanar", ["coplanar"]),
    ("far", ["far.json", "FDP 9.3", "mm off"]),
    ("mm", ["mm.json", "different units"]),
])
def test_adapt_checks_inputs_first(sphere, case, needles, tmp_path, capsys):
    out = tmp_path / "o"
    t0 = time.perf_counter()
    code = main(["adapt", str(sphere / "sphere.obj"), "--landmarks", str(sphere / f"{case}.json"), "--out", str(out)])
    seconds = time.perf_counter() - t0
    o, err = capsys.readouterr()
    assert code == 2 and o == "" and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err
    for n in needles:
        assert n in err, (n, err)
    assert not out.exists()  # failed before the output folder was made
    assert seconds < 10.0, seconds  # loose: the checks come before the adaptation (benchmarks/cli_startup.py)


def test_adapt_bad_arguments(scan, sphere, tmp_path, capsys):
    d, _ = scan
    cases = [
        (["adapt", str(d / "nope.obj"), "--landmarks", str(d / "lm.json"), "--out", str(tmp_path / "o")], "nope.obj"),
        (["adapt", str(d / "scan.obj"), "--landmarks", str(d / "lm.json"), "--out", str(tmp_path / "o"),
          "--template-mesh", str(d / "scan.obj")], "--template-landmarks"),
        (["adapt", str(d / "scan.obj"), "--landmarks", str(d / "lm.json"), "--out", str(tmp_path / "o"),
          "--template", str(tmp_path), "--template-mesh", str(d / "scan.obj"), "--template-landmarks",
          str(d / "lm.json")], "not both"),
        (["adapt", str(d / "scan.obj"), "--landmarks", str(d / "lm.json"), "--out", str(tmp_path / "o"),
          "--template", str(tmp_path)], "template"),
    ]
    for argv, needle in cases:
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
        assert needle in err, (needle, err)
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_adapt_takes_68_point_landmarks(ict_dir, tmp_path, capsys):
    """Round trip through the command: a known head (the ICT neutral, mm) with its 68 landmarks
    (ICT's own vertices) as an iBUG .pts file: every FDP and every other point of the scheme is
    used (report), and the adapted template's 68 places land on the head's 68 points."""
    from facewarp.heads import IBUG68_TEMPLATE
    from facewarp.geometry import IBUG68_TO_FDP, closest_surface_points
    from facewarp import default_template

    n = 11248
    ict = load_mesh(ict_dir / "generic_neutral_mesh.obj", units="cm")
    V, F = ict.vertices[:n], ict.faces[(ict.faces < n).all(axis=1)]
    save_obj(tmp_path / "scan.obj", V, F, units="mm")
    idx = json.loads((ict_dir / "vertex_indices.json").read_text())["idx_to_landmark_verts"]
    P = V[idx] * 1e3
    (tmp_path / "lm68.pts").write_text("version: 1\nn_points: 68\n{\n" + "".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in P)
                                       + "}\n")
    out = tmp_path / "out"
    assert main(["adapt", str(tmp_path / "scan.obj"), "--landmarks", str(tmp_path / "lm68.pts"), "--out", str(out),
                 "--units", "mm", "--levels", "1", "--landmark-scheme", "ibug68"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["landmark_scheme"]["fdps"] == sorted(IBUG68_TO_FDP.values())
    assert rep["landmark_scheme"]["other_points"] == 68 - len(IBUG68_TO_FDP)
    assert rep["distance_to_scan_m"]["median"] < 0.5e-3
    head = load_mesh(out / "adapted_scan_frame.obj", units="mm")
    t = default_template(0)
    sp = closest_surface_points(t.vertices, t.faces, IBUG68_TEMPLATE)
    err = np.linalg.norm(sp.positions(head.vertices, head.faces) - V[idx], axis=1) * 1e3
    # within a millimetre but at the lids and the inner lips, which lie in the template's openings (<= 2.8 mm apart)
    assert np.median(err) < 1.0 and err.max() < 3.5, np.round(err, 2)
    capsys.readouterr()
    # the wrong scheme named: one line, exit 2, nothing written
    assert main(["adapt", str(tmp_path / "scan.obj"), "--landmarks", str(tmp_path / "lm68.pts"), "--out",
                 str(tmp_path / "bad"), "--units", "mm", "--landmark-scheme", "ibug51"]) == 2
    err = capsys.readouterr().err
    assert "the ibug51 scheme has 51 points, got 68" in err and err.count("\n") == 1
    assert not (tmp_path / "bad").exists()
