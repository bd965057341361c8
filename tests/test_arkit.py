"""ARKit shapes on a head: the ICT-FaceKit transfer, the per-head table, its cache, weights -> controls.

Uses the five ICT-FaceKit shapes of the shared data folder (jawOpen, mouthSmile_L/R,
browInnerUp_L/R); skipped where that data is absent. The table is built on the level-0 head with
a few shapes and one refinement round (the full table is benchmarks/arkit_shapes.py's).
"""

from __future__ import annotations

import numpy as np
import pytest

import facewarp as fw


@pytest.fixture(scope="module")
def ict(ict_dir):
    if not (ict_dir / "jawOpen.obj").is_file() or not (ict_dir / "mouthSmile_L.obj").is_file():
        pytest.skip(f"ICT-FaceKit shapes not found in {ict_dir} (jawOpen.obj, mouthSmile_L.obj)")
    return ict_dir


@pytest.fixture(scope="module")
def sim():
    return fw.FaceSimulator(fw.build_face(fw.default_template(0)))


SHAPES = ["jawOpen", "browInnerUp"]


@pytest.fixture(scope="module")
def built(ict, sim, tmp_path_factory):
    """A small table (two shapes, one refinement round) and its cache folder."""
    cache = tmp_path_factory.mktemp("arkit")
    return fw.arkit_table(sim, shapes=SHAPES, cache=cache, ict_dir=ict, refine=1, max_frames=25), cache


def _head_fdps(fr):
    idx = [i for i, p in enumerate(fr.fdp_part) if str(p) == "head"]
    V, F = np.asarray(fr.head_vertices, float), np.asarray(fr.head_faces)
    P = np.einsum("kc,kcd->kd", np.asarray(fr.fdp_bary, float)[idx], V[F[np.asarray(fr.fdp_face)[idx]]])
    return [str(fr.fdp_ids[i]) for i in idx], P


def test_transfer_identity_and_scaling(ict):
    """On the ICT neutral itself (its own FDPs as the head's), the transfer gives the ICT
    displacement back at the ICT vertices; on a copy scaled by 1.1 and moved, the displacement
    is scaled by 1.1 (the head's proportions), not copied."""
    D = fw.load_ict_displacements(["mouthSmileLeft", "jawOpen"], ict_dir=ict)
    assert set(D) == {"mouthSmileLeft", "jawOpen"}
    V = fw.load_mesh(ict / "generic_neutral_mesh.obj", units="cm").vertices[: fw.ICT_SKIN_VERTICES]
    lm = {k: V[i] for k, i in {**fw.ICT_FDP_VERTICES, **fw.ICT_INNER_LIP_VERTICES}.items()}
    pick = np.array([5708, 6213, 966, 4163, 3000, 1507])  # lip corners, chin, a lid, cheek, eye corner
    out = fw.transfer_ict_displacements(D, V[pick], lm, ict_dir=ict)
    for n in D:
        np.testing.assert_allclose(out[n], D[n][pick], atol=2e-5)
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = {k: 1.1 * R @ p + np.array([0.1, 0.2, -0.3]) for k, p in lm.items()}
    out2 = fw.transfer_ict_displacements(D, 1.1 * V[pick] @ R.T + np.array([0.1, 0.2, -0.3]), moved, ict_dir=ict)
    for n in D:
        np.testing.assert_allclose(out2[n], 1.1 * D[n][pick] @ R.T, atol=3e-5)


def test_transfer_onto_template_head(ict, sim):
    """On the default head, the left smile lifts the lip corner at +x (the subject's left, as in
    ICT) by millimetres to centimetres and leaves the hairline still."""
    ids, P = _head_fdps(sim.fr)
    D = fw.load_ict_displacements(["mouthSmileLeft"], ict_dir=ict)
    rep = {}
    out = fw.transfer_ict_displacements(D, P, dict(zip(ids, P)), point_ids=ids, ict_dir=ict, report=rep)
    d = out["mouthSmileLeft"]
    corner = d[ids.index("8.4")] if P[ids.index("8.4"), 0] > 0 else d[ids.index("8.3")]
    assert corner[1] > 2e-3 and 5e-3 < np.linalg.norm(corner) < 3e-2
    assert np.linalg.norm(d[ids.index("11.1")]) < 5e-4  # hairline: still
    assert max(rep["warp_fdp_residual_m"]) < 1e-9  # the warp interpolates the shared FDPs


@pytest.mark.slow
def test_table_build_cache_and_controls(ict, sim, built):
    t, cache = built
    assert (cache / "arkit_table.npz").is_file() and not t.info["from_cache"]
    i_jaw, i_brow, i_smile = (fw.ARKIT_NAMES.index(n) for n in ("jawOpen", "browInnerUp", "mouthSmileLeft"))
    assert t.solved[i_jaw] and t.solved[i_brow] and not t.solved[i_smile]
    assert "no ICT-FaceKit shape data" in t.reasons["mouthSmileLeft"]
    assert "eye gaze" in t.reasons["eyeLookUpLeft"] and "tongueOut" in t.reasons
    assert t.jaw[i_jaw, 0] > 0.15  # jawOpen opens the jaw (rad)
    brow = dict(zip(t.muscle_names, t.activations[i_brow]))
    assert brow["frontalis_inner_L"] > 0.3 and brow["frontalis_inner_R"] > 0.3
    assert t.residual_m[i_brow] < 0.75 * t.target_rms_m[i_brow]  # closer than the rest face (residual = target)
    # the second call reads the cache (same key); another setting rebuilds
    t2 = fw.arkit_table(sim, shapes=SHAPES, cache=cache, ict_dir=ict, refine=1, max_frames=25)
    assert t2.info["from_cache"] and t2.key == t.key
    np.testing.assert_array_equal(t2.activations, t.activations)
    # weights -> controls: blend in activation space, clamp
    W = np.zeros((3, 52))
    W[0, i_jaw] = 1.0
    W[1, i_jaw], W[1, i_brow] = 0.5, 0.5
    W[2, :] = 1.0
    A, J = t2.controls(W)
    assert A.shape == (3, len(t.muscle_names)) and J.shape == (3, 2) and A.dtype == np.float32
    np.testing.assert_allclose(A[0], t.activations[i_jaw], atol=1e-6)
    np.testing.assert_allclose(A[1], np.clip(0.5 * t.activations[i_jaw] + 0.5 * t.activations[i_brow], 0, 1), atol=1e-6)
    np.testing.assert_allclose(J[1], 0.5 * t.jaw[i_jaw] + 0.5 * t.jaw[i_brow], atol=1e-6)
    assert A.max() <= 1.0 and A.min() >= 0.0 and 0.0 <= J[2, 0] <= np.radians(60) and abs(J[2, 1]) <= np.radians(5)
    np.testing.assert_allclose(t2.targets_for(W[0])[0], t.rest_fdp + t.targets[i_jaw])
    a1, j1 = t2.controls(W[1])  # one frame (52,) works too
    np.testing.assert_array_equal(a1[0], A[1])
    t3 = fw.load_arkit_table(cache)  # the file round trip
    np.testing.assert_array_equal(t3.basis, t.basis)
    np.testing.assert_array_equal(t3.reached, t.reached)
    assert t3.reasons == t.reasons and t3.key == t.key


def test_drive_arkit_track(sim, built):
    """fw.drive plays an ArkitTrack through the table: the controls are the table's blend, the
    head rotation drives the head pose, shapes out of reach are noted; refine=True tracks the
    blended targets with fw.Tracker."""
    t, _ = built
    T = 6
    W = np.zeros((T, 52))
    W[:, fw.ARKIT_NAMES.index("jawOpen")] = np.linspace(0.0, 0.5, T)
    W[:, fw.ARKIT_NAMES.index("browInnerUp")] = np.linspace(0.0, 1.0, T)
    W[2:, fw.ARKIT_NAMES.index("eyeLookUpLeft")] = 0.5
    rot = np.zeros((T, 3))
    rot[:, 0] = np.linspace(0.0, 0.05, T)  # yaw
    track = fw.ArkitTrack(30.0, W, rot, "test")
    rec = fw.FrameRecorder()
    r = fw.drive(sim, track, table=t, sinks=[rec])
    A, J = t.controls(W)
    np.testing.assert_allclose(r.activations, A, atol=1e-6)
    np.testing.assert_allclose(r.jaw, J, atol=1e-6)
    assert r.error.shape == (T, len(t.fdp_ids)) and np.isfinite(r.rms).all() and r.rms[0] < 1e-4
    assert any(n.startswith("eyeLookUpLeft: out of reach") for n in r.unreachable)
    R = sim.head_pose[0]
    np.testing.assert_allclose(R, [[np.cos(0.05), 0, np.sin(0.05)], [0, 1, 0], [-np.sin(0.05), 0, np.cos(0.05)]],
                               atol=1e-9)
    np.testing.assert_allclose(r.head_poses[-1, :3, :3], R, atol=1e-12)
    assert len(rec.points) == T
    r2 = fw.drive(sim, fw.ArkitTrack(30.0, W[:3]), table=t, refine=True)
    assert r2.mode == "arkit-tracker" and r2.activations.shape == (3, len(t.muscle_names))
    assert np.isfinite(r2.rms).all() and r2.head_poses is None
    with pytest.raises(fw.InputError, match="table: an ArkitTrack is driven through the head's ARKit table"):
        fw.drive(sim, track)
    with pytest.raises(fw.InputError, match="smoothness: a Tracker option, only with refine=True"):
        fw.drive(sim, track, table=t, smoothness=0.1)
    with pytest.raises(fw.InputError, match="track: 25 frames/s"):
        fw.drive(sim, fw.ArkitTrack(25.0, W), table=t)


def test_bad_inputs(ict, sim, tmp_path):
    with pytest.raises(fw.InputError, match="shapes: 'smile' is not an ARKit"):
        fw.arkit_table(sim, shapes=["smile"], ict_dir=ict)
    with pytest.raises(fw.InputError, match=r"shapes\['jawOpen'\]: expected an ICT-skin displacement"):
        fw.arkit_table(sim, shapes={"jawOpen": np.zeros((10, 3))})
    with pytest.raises(fw.InputError, match="sim: expected a FaceSimulator"):
        fw.arkit_table("head")
    with pytest.raises(fw.InputError, match="refine"):
        fw.arkit_table(sim, shapes=[], refine=-1)
    (tmp_path / "file").write_text("x")
    with pytest.raises(fw.InputError, match="cache: .* is not a folder"):
        fw.arkit_table(sim, shapes=[], cache=tmp_path / "file")
    (tmp_path / "arkit_table.npz").write_bytes(b"not a table")
    with pytest.raises(fw.InputError, match="not a facewarp ARKit table"):
        fw.load_arkit_table(tmp_path)
    with pytest.raises(fw.InputError, match="names: 'nope'"):
        fw.load_ict_displacements(["nope"])
    with pytest.raises(fw.InputError, match="ict_dir: .* holds no ICT-FaceKit"):
        fw.load_ict_displacements(["jawOpen"], ict_dir=tmp_path)
    t = fw.arkit_table(sim, shapes=[], ict_dir=ict, max_frames=3)  # no shapes: every entry zero, with reasons
    assert not t.solved.any() and len(t.reasons) == 52
    with pytest.raises(fw.InputError, match="sim: not the head"):
        t.refine(fw.FaceSimulator(sim.fr, material="thesis"), np.zeros(52))
    for bad, msg in ((np.zeros((2, 51)), "weights"), (np.full(52, 1.5), r"weights: ARKit weights lie in \[0, 1\]"),
                     (np.full(52, np.nan), "weights")):
        with pytest.raises(fw.InputError, match=msg):
            t.controls(bad)


def test_docs_list_the_shapes_out_of_reach():
    """docs/concepts/arkit.md's table is fw.ARKIT_OUT_OF_REACH: every name with its reason."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "concepts" / "arkit.md").read_text()
    rows = [r for r in text.splitlines() if r.startswith("| `")]
    listed = {}
    for r in rows:
        names, reason = r.strip("|").split("|")[:2]
        for n in names.split(","):
            listed[n.strip().strip("`")] = reason.strip()
    assert listed == fw.ARKIT_OUT_OF_REACH
    assert set(fw.ARKIT_OUT_OF_REACH) <= set(fw.ARKIT_NAMES)
