"""FDP catalogue, FAP units, and landmark files (JSON and MeshLab .pp)."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from facewarp.geometry import FDP_CATALOGUE, FDP_IDS, fapu, load_landmarks, save_landmarks_json
from facewarp import InputError, load_mesh

# ----------------------------------------------------------------------------------------
# catalogue


def test_catalogue_has_84_points_in_numeric_order():
    assert len(FDP_CATALOGUE) == 84 and len(FDP_IDS) == 84
    counts = Counter(f.group for f in FDP_CATALOGUE.values())
    assert counts == {2: 14, 3: 14, 4: 6, 5: 4, 6: 4, 7: 1, 8: 10, 9: 15, 10: 10, 11: 6}
    keys = [tuple(int(x) for x in i.split(".")) for i in FDP_IDS]
    assert keys == sorted(keys)
    assert FDP_IDS[:3] == ("2.1", "2.2", "2.3") and FDP_IDS.index("2.10") == 9 and FDP_IDS[-1] == "11.6"
    for fdp_id, fdp in FDP_CATALOGUE.items():
        assert fdp.id == fdp_id and fdp.group == int(fdp_id.split(".")[0])
        assert fdp.side in ("left", "right", "center") and fdp.description


def test_catalogue_sides():
    side = {i: f.side for i, f in FDP_CATALOGUE.items()}
    assert side["3.7"] == "left" and side["3.12"] == "right"  # outer eye corners
    assert side["3.11"] == "left" and side["3.8"] == "right"  # inner eye corners
    assert side["8.3"] == "left" and side["8.4"] == "right"
    assert side["10.9"] == "left" and side["10.10"] == "right"
    assert side["2.1"] == side["11.1"] == side["9.3"] == side["7.1"] == "center"
    # every left point in groups 3, 4, 5, 10 has a right partner
    for g in (3, 4, 5, 10):
        sides = Counter(f.side for f in FDP_CATALOGUE.values() if f.group == g)
        assert sides["left"] == sides["right"], g


# ----------------------------------------------------------------------------------------
# FAP units


def neutral_landmarks():
    return {
        "3.5": np.array([0.032, 0.0, 0.0]),
        "3.6": np.array([-0.032, 0.0, 0.0]),
        "3.1": np.array([0.032, 0.006, 0.0]),
        "3.3": np.array([0.032, -0.004, 0.0]),
        "9.15": np.array([0.0, -0.045, 0.02]),
        "2.2": np.array([0.0, -0.065, 0.01]),
        "8.3": np.array([0.025, -0.07, 0.0]),
        "8.4": np.array([-0.025, -0.07, 0.0]),
    }


def test_fapu():
    u = fapu(neutral_landmarks())
    np.testing.assert_allclose(
        [u["ES0"], u["IRISD0"], u["ENS0"], u["MNS0"], u["MW0"]], [0.064, 0.010, 0.045, 0.020, 0.050], atol=1e-15
    )
    for name in ("ES", "IRISD", "ENS", "MNS", "MW"):
        assert u[name] == u[name + "0"] / 1024
    assert u["AU"] == 1e-5


def test_fapu_missing_and_mirrored():
    lm = neutral_landmarks()
    del lm["9.15"]
    with pytest.raises(InputError, match="FDP 9.15 is missing"):
        fapu(lm)
    lm = neutral_landmarks()
    lm["3.5"], lm["3.6"] = lm["3.6"], lm["3.5"]
    with pytest.raises(InputError, match="ES0 .* is not positive"):
        fapu(lm)


def test_fapu_ict(ict_dir):
    # ICT indices from MPEG4_FDP.md; pupils and eyelids are not listed, so ES0 from eye corners
    V = load_mesh(ict_dir / "generic_neutral_mesh.obj", units="cm").vertices
    lm = {"3.5": (V[3721] + V[3742]) / 2, "3.6": (V[1507] + V[1528]) / 2, "3.1": V[3721] + [0, 0.005, 0],
          "3.3": V[3721], "9.15": V[4857], "2.2": V[5533], "8.3": V[6213], "8.4": V[5708]}
    u = fapu(lm)
    assert 0.05 < u["ES0"] < 0.08 and 0.04 < u["MW0"] < 0.07


# ----------------------------------------------------------------------------------------
# files


def test_json_roundtrip_with_units(tmp_path):
    p = tmp_path / "lm.json"
    p.write_text(json.dumps({"3.12": [-4.4, 3.4, 8.6], "3.7": [4.45898, 3.4321, 8.60292], "2.1": [0, -9, 9]}))
    lm = load_landmarks(p, units="cm")
    assert list(lm) == ["2.1", "3.7", "3.12"]  # FDP order
    np.testing.assert_allclose(lm["3.7"], [0.0445898, 0.034321, 0.0860292])
    out = tmp_path / "out.json"
    save_landmarks_json(out, lm, units="mm")
    assert json.loads(out.read_text())["3.7"] == pytest.approx([44.5898, 34.321, 86.0292])
    back = load_landmarks(out, units="mm")
    for k in lm:
        np.testing.assert_allclose(back[k], lm[k], rtol=1e-12)


def test_pp_file(tmp_path):
    p = tmp_path / "picked.pp"
    p.write_text(
        '<!DOCTYPE PickedPoints>\n<PickedPoints>\n <DocumentData>\n  <DataFileName name="head.ply"/>\n'
        " </DocumentData>\n"
        ' <point x="44.5" y="34.3" z="86.0" name="3.7" active="1"/>\n'
        ' <point x="-44.5" y="34.3" z="86.0" name="3.12" active="1"/>\n'
        ' <point x="0" y="0" z="0" name="9.3" active="0"/>\n'
        "</PickedPoints>\n"
    )
    lm = load_landmarks(p, units="mm")
    assert list(lm) == ["3.7", "3.12"]
    np.testing.assert_allclose(lm["3.12"], [-0.0445, 0.0343, 0.086])


def assert_one_line(excinfo, path, *words):
    msg = str(excinfo.value)
    assert "\n" not in msg and msg.startswith(str(path)), msg
    for w in words:
        assert w in msg, msg


@pytest.mark.parametrize(
    "name, text, words",
    [
        ("empty.json", "", ["empty"]),
        ("bad.json", '{"3.7": [1, 2, 3],', ["malformed JSON", "line 1"]),
        ("list.json", "[[1, 2, 3]]", ["expected a JSON object", "1 points fit no landmark scheme"]),
        ("unknown.json", '{"3.7": [1, 2, 3], "3.99": [1, 2, 3]}', ["unknown FDP id", "'3.99'"]),
        ("nan.json", '{"3.7": [1, NaN, 3]}', ["'3.7'", "3 finite numbers"]),
        ("two.json", '{"3.7": [1, 2]}', ["'3.7'", "3 finite numbers"]),
        ("text.json", '{"3.7": [1, "2", 3]}', ["'3.7'", "3 finite numbers"]),
        ("bool.json", '{"3.7": [1, true, 3]}', ["'3.7'", "3 finite numbers"]),
        ("dup.json", '{"3.7": [1, 2, 3], "3.7": [1, 2, 4]}', ["'3.7'", "more than once"]),
        ("none.json", "{}", ["no landmarks"]),
        ("bad.pp", "<PickedPoints><point x='1' y='2' z='3' name='3.7'/>", ["malformed XML"]),
        ("unknown.pp", "<PickedPoints><point x='1' y='2' z='3' name='1.1'/></PickedPoints>", ["'1.1'"]),
        ("dup.pp", "<PickedPoints><point x='1' y='2' z='3' name='3.7'/><point x='1' y='2' z='3' name='3.7'/>"
         "</PickedPoints>", ["'3.7'", "more than once"]),
        ("nan.pp", "<PickedPoints><point x='1' y='nan' z='3' name='3.7'/></PickedPoints>", ["'3.7'", "finite"]),
        ("noz.pp", "<PickedPoints><point x='1' y='2' name='3.7'/></PickedPoints>", ["'3.7'", "numeric"]),
        ("lm.txt", "3.7 1 2 3", ["unsupported landmark format"]),
    ],
)
def test_bad_landmark_files(tmp_path, name, text, words):
    p = tmp_path / name
    p.write_text(text)
    with pytest.raises(InputError) as e:
        load_landmarks(p)
    assert_one_line(e, p, *words)


def test_missing_landmark_file(tmp_path):
    p = tmp_path / "nope.json"
    with pytest.raises(InputError) as e:
        load_landmarks(p)
    assert_one_line(e, p, "no such file")


def test_save_rejects_bad_landmarks(tmp_path):
    with pytest.raises(InputError, match="unknown FDP id '99.1'"):
        save_landmarks_json(tmp_path / "x.json", {"99.1": np.zeros(3)})
    with pytest.raises(InputError, match="'3.7' must be 3 finite"):
        save_landmarks_json(tmp_path / "x.json", {"3.7": np.array([0, np.nan, 0])})
    assert not (tmp_path / "x.json").exists()


# ----------------------------------------------------------------------------------------
# the 68- and 51-point schemes


def _ict_68(ict_dir):
    """The ICT-FaceKit neutral head [m] and its 68 landmark vertex indices (ICT's own file)."""
    idx = json.loads((ict_dir / "vertex_indices.json").read_text())["idx_to_landmark_verts"]
    V = load_mesh(ict_dir / "generic_neutral_mesh.obj", units="cm").vertices
    return V, np.asarray(idx)


def test_ibug68_round_trip_on_the_ict_head(ict_dir, tmp_path):
    """68 points taken from a known head (ICT's landmark vertices) written as a JSON list and as
    an iBUG .pts file (mm) come back as the FDPs at the same vertices (the ICT FDP map)."""
    from facewarp.heads import ICT_FDP_VERTICES
    from facewarp.geometry import IBUG68_TO_FDP, landmarks_from_scheme

    V, idx = _ict_68(ict_dir)
    P_mm = V[idx] * 1e3
    (tmp_path / "lm68.json").write_text(json.dumps(P_mm.tolist()))
    pts = "version: 1\nn_points: 68\n{\n" + "".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in P_mm) + "}\n"
    (tmp_path / "lm68.pts").write_text(pts)
    for name in ("lm68.json", "lm68.pts"):
        lm = load_landmarks(tmp_path / name, units="mm")
        assert set(lm) == set(IBUG68_TO_FDP.values())
        for fdp, vi in ICT_FDP_VERTICES.items():  # ICT's own FDP vertices, from docs/MPEG4_FDP.md
            np.testing.assert_allclose(lm[fdp], V[vi], atol=1e-9, err_msg=f"{name} {fdp}")
    # the 51 inner points: the same FDPs less the chin (2.1 is jaw-line point 8)
    (tmp_path / "lm51.json").write_text(json.dumps(P_mm[17:].tolist()))
    lm51 = load_landmarks(tmp_path / "lm51.json", units="mm")
    assert set(lm51) == set(IBUG68_TO_FDP.values()) - {"2.1"}
    lm68 = landmarks_from_scheme(V[idx])
    for k in lm51:
        np.testing.assert_allclose(lm51[k], lm68[k], atol=1e-12)


def test_ibug68_table_matches_the_template_fdps_on_the_ict_head(ict_dir):
    """The documented correspondence: the default template adapted to the ICT head with its 12
    ICT FDPs puts each tabled FDP within IBUG68_FDP_OFFSET_MM (+0.3 mm) of ICT's 68-point vertex."""
    from facewarp.heads import ICT_FDP_VERTICES
    from facewarp.geometry import closest_surface_points
    from facewarp import default_template
    from facewarp.geometry import IBUG68_FDP_OFFSET_MM, IBUG68_TO_FDP
    from facewarp import adapt

    V, idx = _ict_68(ict_dir)
    n = 11248
    ict = load_mesh(ict_dir / "generic_neutral_mesh.obj", units="cm")
    F = ict.faces[(ict.faces < n).all(axis=1)]
    t = default_template(0)
    tl = t.landmarks()
    res = adapt(t.vertices, t.faces, {k: tl[k] for k in ICT_FDP_VERTICES}, V[:n], F,
                {k: V[i] for k, i in ICT_FDP_VERTICES.items()})
    ids = list(IBUG68_TO_FDP.values())
    sp = closest_surface_points(t.vertices, t.faces, np.array([tl[k] for k in ids]))
    P = sp.positions(res.vertices_scan_frame, t.faces)
    for (i, fdp), p in zip(IBUG68_TO_FDP.items(), P):
        d = float(np.linalg.norm(p - V[idx[i]])) * 1e3
        assert d <= IBUG68_FDP_OFFSET_MM[i] + 0.3, f"68-point {i} vs FDP {fdp}: {d:.2f} mm"


def test_scheme_errors(tmp_path):
    from facewarp.geometry import landmarks_from_scheme

    (tmp_path / "a.json").write_text(json.dumps([[0.0, 0.0, 0.0]] * 30))
    with pytest.raises(InputError, match="30 points fit no landmark scheme"):
        load_landmarks(tmp_path / "a.json")
    (tmp_path / "b.json").write_text(json.dumps([[0.0, 0.0]] * 68))
    with pytest.raises(InputError, match="2D image landmarks"):
        load_landmarks(tmp_path / "b.json")
    (tmp_path / "c.json").write_text(json.dumps([[0.0, 0.0, 0.0]] * 51))
    with pytest.raises(InputError, match="the ibug68 scheme has 68 points, got 51"):
        load_landmarks(tmp_path / "c.json", scheme="ibug68")
    with pytest.raises(InputError, match="not named FDPs"):
        load_landmarks(tmp_path / "c.json", scheme="fdp")
    (tmp_path / "d.json").write_text(json.dumps({"3.7": [0, 0, 0]}))
    with pytest.raises(InputError, match="not the ibug51 scheme"):
        load_landmarks(tmp_path / "d.json", scheme="ibug51")
    (tmp_path / "e.pts").write_text("version: 1\nn_points: 68\n{\n1 2 3\n}\n")
    with pytest.raises(InputError, match="n_points says 68 but the file has 1 points"):
        load_landmarks(tmp_path / "e.pts")
    P = np.zeros((68, 3))
    P[40, 1] = np.nan
    with pytest.raises(InputError, match="point 40 is not 3 finite numbers"):
        landmarks_from_scheme(P)
    with pytest.raises(InputError, match="scheme"):
        load_landmarks(tmp_path / "d.json", scheme="ibug49")
