"""The ICT-FaceKit neutral head imported as a full template (issue 4, "Transfer and import").

Needs the ICT-FaceKit data (``ict_dir`` fixture: skipped with the reason when it is absent).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from facewarp.geometry import FDP_CATALOGUE, FDP_IDS
from facewarp.heads import (    FRONTAL_REGIONS,
    ICT_FDP_VERTICES,
    ICT_INNER_LIP_VERTICES,
    ICT_PART_RANGES,
    ICT_SKIN_VERTICES,
    REGIONS,
    import_ict,
    load_template_dir)
from facewarp import InputError, build_anatomy, default_template, load_mesh
from facewarp.physics import face_rig_from_anatomy

pytestmark = pytest.mark.slow  # minutes on the 2-core box: the slow tier


@pytest.fixture(scope="module")
def ict(ict_dir):
    rep: dict = {}
    return import_ict(ict_dir, report=rep), rep


@pytest.fixture(scope="module")
def ict_vertices(ict_dir):
    return load_mesh(ict_dir / "generic_neutral_mesh.obj", units="cm").vertices


def _area(V, F):
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)


def test_mesh_and_parts(ict, ict_vertices):
    t, rep = ict
    assert t.level == -1
    assert t.vertex_count == ICT_SKIN_VERTICES
    np.testing.assert_array_equal(t.vertices, ict_vertices[:ICT_SKIN_VERTICES])  # ICT order kept, metres
    assert rep["skin_mesh"]["non_manifold_edge_count"] == 0
    assert rep["skin_mesh"]["boundary_loop_count"] == 4  # neck, mouth, two eyes
    assert set(t.parts) == set(ICT_PART_RANGES)
    for name, (a, b) in ICT_PART_RANGES.items():
        V, F = t.parts[name]
        assert len(V) == b - a and F.min() == 0 and F.max() == len(V) - 1
    assert t.parts["eye_L"][0][:, 0].mean() > 0 > t.parts["eye_R"][0][:, 0].mean()  # left = +x
    assert t.condyles[0, 0] > 0 > t.condyles[1, 0]
    assert np.all((t.thickness > 0) & (t.skull_depth > t.thickness))


def test_fdps(ict, ict_vertices):
    t, _ = ict
    assert list(t.fdp) == list(FDP_IDS) and len(t.fdp) == 84
    lm = t.landmarks()
    assert lm["3.7"][0] > 0 > lm["3.12"][0]
    # the known FDPs sit exactly on their ICT vertices
    for k, i in {**ICT_FDP_VERTICES, **ICT_INNER_LIP_VERTICES}.items():
        assert t.fdp[k][0] == "head"
        np.testing.assert_allclose(lm[k], ict_vertices[i], atol=1e-12, err_msg=k)
    # the internal FDPs on their parts, the pupils in front of their eyeballs
    assert t.fdp["3.5"][0] == "eye_L" and t.fdp["3.6"][0] == "eye_R"
    assert lm["3.5"][0] > 0 > lm["3.6"][0]
    assert {t.fdp[k][0] for k in ("9.8", "9.10")} == {"teeth_upper"}
    assert {t.fdp[k][0] for k in ("9.9", "9.11")} == {"teeth_lower"}
    assert {t.fdp[k][0] for k in ("6.1", "6.2", "6.3", "6.4")} == {"tongue"}
    # crowns: top above the incisal edge (upper), edge above the bottom (lower); the upper
    # incisors overlap the lower ones in front by a small overbite
    assert lm["9.8"][1] > lm["9.10"][1] and lm["9.11"][1] > lm["9.9"][1]
    assert abs(lm["9.10"][1] - lm["9.11"][1]) < 0.004 and lm["9.10"][2] > lm["9.11"][2]
    assert lm["6.1"][2] > lm["6.2"][2] and lm["6.3"][0] > 0 > lm["6.4"][0]
    # upper lid above the pupil above the lower lid
    assert lm["3.1"][1] > lm["3.5"][1] > lm["3.3"][1]
    # left / right FDPs mirror each other (the ICT neutral head is symmetric)
    for k in FDP_IDS:
        if FDP_CATALOGUE[k].side == "center" and t.fdp[k][0] == "head":
            assert abs(lm[k][0]) < 1e-3, k
    for a, b in (("8.7", "8.8"), ("2.11", "2.12"), ("10.1", "10.2"), ("5.3", "5.4"), ("3.13", "3.14")):
        np.testing.assert_allclose(lm[a] * [-1, 1, 1], lm[b], atol=1e-3, err_msg=f"{a}/{b}")


def test_regions_and_frontal(ict):
    t, _ = ict
    counts = np.bincount(t.face_region, minlength=len(REGIONS))
    missing = [r for r, c in zip(REGIONS, counts) if c == 0]
    assert not missing, f"regions without faces: {missing}"
    frontal_ids = [REGIONS.index(r) for r in FRONTAL_REGIONS]
    assert np.isin(t.face_region[t.frontal], frontal_ids).all()
    # the frontal face covers about the same area as the default template's (same head size);
    # what is left out of the frontal regions is the inside of the closed mouth
    d = default_template(0)
    ratio = _area(t.vertices, t.faces)[t.frontal].sum() / _area(d.vertices, d.faces)[d.frontal].sum()
    assert 0.75 < ratio < 1.35, ratio
    # left out of the frontal face: the inside of the closed mouth, the lip-corner creases and
    # the lid margins curling into the eye sockets and the nostril rims; elsewhere only the few
    # border triangles that hung on the frontal face by a vertex
    left_out = np.isin(t.face_region, frontal_ids) & ~t.frontal
    assert left_out.sum() < 0.17 * t.frontal.sum()  # 1,808 of 11,279 (the mouth interior the most)
    C = t.vertices[t.faces[left_out]].mean(1)
    lm = t.landmarks()
    near_mouth = np.abs(C[:, 1] - lm["2.2"][1]) < 0.01
    near_eye = np.minimum(np.linalg.norm(C - lm["3.5"], axis=1), np.linalg.norm(C - lm["3.6"], axis=1)) < 0.03
    near_nostrils = np.linalg.norm(C - lm["9.15"], axis=1) < 0.02
    assert (~(near_mouth | near_eye | near_nostrils)).sum() <= 10
    # the frontal face is one piece joined through edges, each vertex's triangles one fan: a
    # triangle hanging by a vertex extrudes into a hinged flap that stalls the implicit solver
    F = t.faces[t.frontal]
    m = len(F)
    a, b = F.ravel(), F[:, [1, 2, 0]].ravel()
    key = np.minimum(a, b) * len(t.vertices) + np.maximum(a, b)
    o = np.argsort(key, kind="stable")
    i = np.flatnonzero(key[o][1:] == key[o][:-1])
    h1, h2 = o[i], o[i + 1]
    assert connected_components(coo_matrix((np.ones(len(i)), (h1 // 3, h2 // 3)), shape=(m, m)))[0] == 1
    nxt = 3 * (h2 // 3) + (h2 % 3 + 1) % 3
    same = a[h1] == a[h2]  # the corners of one vertex on both faces of an edge are one fan
    c1 = np.r_[h1, 3 * (h1 // 3) + (h1 % 3 + 1) % 3]
    c2 = np.r_[np.where(same, h2, nxt), np.where(same, nxt, h2)]
    fans = connected_components(coo_matrix((np.ones(len(c1)), (c1, c2)), shape=(3 * m, 3 * m)))[1]
    assert len(np.unique(np.stack([a, fans], 1), axis=0)) == len(np.unique(a))


@pytest.fixture(scope="module")
def ict_anatomy(ict):
    return build_anatomy(ict[0], check_intersections=False)


def test_anatomy_builds(ict_anatomy):
    q = ict_anatomy.quality
    assert q["inverted_count"] == 0
    assert q["tet_count"] > 0 and q["conforming"]
    # no sliver sets a tiny stable time step (the default template's flattest tet: ~0.35 mm)
    assert q["min_dihedral_deg"] > 2.0
    assert q["min_depth_m"] > 1e-4
    attached = {k: v["attached_nodes"] for k, v in q["muscles"].items()}
    assert len(attached) == 27
    assert min(attached.values()) >= 5, attached


def test_face_rig_supports_and_openings(ict, ict_anatomy):
    # issue 12: the ICT lips roll into the mouth. A sliding support along each inner node's own
    # normal (up on the lower lip's roll, down on the upper's) held the full smile's lip corners
    # at 8.3 mm instead of the rig's 15.6; the support follows the smoothed deeper surface
    # (before: normals within 12 mm of a corner 81 deg apart, cos 0.13 to their mean; now 0.99)
    t, _ = ict
    fr = face_rig_from_anatomy(ict_anatomy)
    lm = t.landmarks()
    for corner in ("8.3", "8.4"):
        near = np.linalg.norm(fr.nodes[fr.support_nodes] - lm[corner], axis=1) < 0.012
        assert near.sum() > 50, (corner, near.sum())
        n = fr.support_normal[near]
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
        mean = n.mean(0) / np.linalg.norm(n.mean(0))
        assert (n @ mean).min() > 0.9, (corner, (n @ mean).min())
    # the rims of the faces left out of the tet mesh follow the skin: the inner lip corners
    # (FDP 2.4/2.5, on left-out crease faces) fully, no rim vertex by more than all of it
    share = fr.opening_weight.sum(1)
    assert len(fr.opening_vertex) and (fr.opening_weight >= 0).all() and (share > 0).all() and (share <= 1).all()
    assert not np.isin(fr.opening_vertex, fr.surface_vertex[fr.surface_vertex >= 0]).any()
    w = dict(zip(fr.opening_vertex.tolist(), share.tolist()))
    ids = [str(k) for k in fr.fdp_ids]
    for k in ("2.4", "2.5"):
        tri = fr.head_faces[fr.fdp_face[ids.index(k)]]
        assert min(w.get(int(v), 0.0) for v in tri) > 0.9, (k, [w.get(int(v), 0.0) for v in tri])


def test_cli_import(ict_dir, tmp_path, capsys):
    from facewarp.cli import main

    out = tmp_path / "ict"
    assert main(["--json", "template", "import-ict", str(ict_dir), "--out", str(out), "--no-preview"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["vertex_count"] == ICT_SKIN_VERTICES and rep["fdp_count"] == 84 and rep["level"] == -1
    t = load_template_dir(out)
    assert t.level == -1 and len(t.fdp) == 84 and set(t.parts) == set(ICT_PART_RANGES)
    assert not (out / "preview_front.png").exists()


def test_bad_folder(tmp_path, capsys):
    from facewarp.cli import main

    with pytest.raises(InputError, match="no such directory"):
        import_ict(tmp_path / "nope")
    with pytest.raises(InputError, match="generic_neutral_mesh.obj is missing"):
        import_ict(tmp_path)
    assert main(["template", "import-ict", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("facewarp: error:") and "\n" not in err
