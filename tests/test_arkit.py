"""ARKit shapes on a head: the ICT-FaceKit transfer, the shipped basis, the per-head table, its
cache, weights -> controls, eye gaze, and the drive with no external data.

The transfer tests use the five ICT-FaceKit shapes of the shared data folder (jawOpen,
mouthSmile_L/R, browInnerUp_L/R) and are skipped where that data is absent; the shipped-basis tests
hide every ICT folder. Tables are built on the level-0 head with a few shapes and one refinement
round (the full table is benchmarks/arkit_basis.py's).
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
    D = fw.takes.load_ict_displacements(["mouthSmileLeft", "jawOpen"], ict_dir=ict)
    assert set(D) == {"mouthSmileLeft", "jawOpen"}
    V = fw.load_mesh(ict / "generic_neutral_mesh.obj", units="cm").vertices[: fw.heads.ICT_SKIN_VERTICES]
    lm = {k: V[i] for k, i in {**fw.heads.ICT_FDP_VERTICES, **fw.heads.ICT_INNER_LIP_VERTICES}.items()}
    pick = np.array([5708, 6213, 966, 4163, 3000, 1507])  # lip corners, chin, a lid, cheek, eye corner
    out = fw.takes.transfer_ict_displacements(D, V[pick], lm, ict_dir=ict)
    for n in D:
        np.testing.assert_allclose(out[n], D[n][pick], atol=2e-5)
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = {k: 1.1 * R @ p + np.array([0.1, 0.2, -0.3]) for k, p in lm.items()}
    out2 = fw.takes.transfer_ict_displacements(D, 1.1 * V[pick] @ R.T + np.array([0.1, 0.2, -0.3]), moved, ict_dir=ict)
    for n in D:
        np.testing.assert_allclose(out2[n], 1.1 * D[n][pick] @ R.T, atol=3e-5)


def test_transfer_onto_template_head(ict, sim):
    """On the default head, the left smile lifts the lip corner at +x (the subject's left, as in
    ICT) by millimetres to centimetres and leaves the hairline still."""
    ids, P = _head_fdps(sim.fr)
    D = fw.takes.load_ict_displacements(["mouthSmileLeft"], ict_dir=ict)
    rep = {}
    out = fw.takes.transfer_ict_displacements(D, P, dict(zip(ids, P)), point_ids=ids, ict_dir=ict, report=rep)
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
    assert "no ICT-FaceKit shape data" in t.reasons["mouthSmileLeft"] and t.info["source"] == "ict"
    assert "tongue" in t.reasons["tongueOut"] and "not solved" not in str(t.reasons)
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
    t3 = fw.takes.load_arkit_table(cache)  # the file round trip
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
    W[3:, fw.ARKIT_NAMES.index("tongueOut")] = 0.4
    rot = np.zeros((T, 3))
    rot[:, 0] = np.linspace(0.0, 0.05, T)  # yaw
    track = fw.takes.ArkitTrack(30.0, W, rot, "test")
    rec = fw.FrameRecorder()
    r = fw.drive(sim, track, table=t, sinks=[rec])
    A, J = t.controls(W)
    np.testing.assert_allclose(r.activations, A, atol=1e-6)
    np.testing.assert_allclose(r.jaw, J, atol=1e-6)
    assert r.error.shape == (T, len(t.fdp_ids)) and np.isfinite(r.rms).all() and r.rms[0] < 1e-4
    # tongueOut is a warning naming it (never a silent zero); eyeLookUpLeft turns the left eye up 0.5 x 25 deg
    assert [w.split(":")[0] for w in r.warnings] == ["tongueOut"] and "weight up to 0.40" in r.warnings[0]
    assert r.warnings[0] in r.unreachable
    np.testing.assert_allclose(r.gaze[-1], [[0.0, np.radians(12.5)], [0.0, 0.0]], atol=1e-9)
    np.testing.assert_allclose(sim.eye_gaze, r.gaze[-1], atol=1e-6)
    R = sim.head_pose[0]
    np.testing.assert_allclose(R, [[np.cos(0.05), 0, np.sin(0.05)], [0, 1, 0], [-np.sin(0.05), 0, np.cos(0.05)]],
                               atol=1e-9)
    np.testing.assert_allclose(r.head_poses[-1, :3, :3], R, atol=1e-12)
    assert len(rec.points) == T
    r2 = fw.drive(sim, fw.takes.ArkitTrack(30.0, W[:3]), table=t, refine=True)
    assert r2.mode == "arkit-tracker" and r2.activations.shape == (3, len(t.muscle_names))
    assert np.isfinite(r2.rms).all() and r2.head_poses is None
    with pytest.raises(fw.InputError, match="table: an ArkitTrack is driven through the head's ARKit table"):
        fw.drive(sim, track)
    with pytest.raises(fw.InputError, match="smoothness: a Tracker option, only with refine=True"):
        fw.drive(sim, track, table=t, smoothness=0.1)
    with pytest.raises(fw.InputError, match="track: 25 frames/s"):
        fw.drive(sim, fw.takes.ArkitTrack(25.0, W), table=t)


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
        fw.takes.load_arkit_table(tmp_path)
    with pytest.raises(fw.InputError, match="names: 'nope'"):
        fw.takes.load_ict_displacements(["nope"])
    with pytest.raises(fw.InputError, match="ict_dir: .* holds no ICT-FaceKit"):
        fw.takes.load_ict_displacements(["jawOpen"], ict_dir=tmp_path)
    t = fw.arkit_table(sim, shapes=[], ict_dir=ict, max_frames=3)  # no shapes: every entry zero, with reasons
    assert not t.solved.any() and len(t.reasons) == 52
    with pytest.raises(fw.InputError, match="sim: not the head"):
        t.refine(fw.FaceSimulator(sim.fr, material="thesis"), np.zeros(52))
    for bad, msg in ((np.zeros((2, 51)), "weights"), (np.full(52, 1.5), r"weights: ARKit weights lie in \[0, 1\]"),
                     (np.full(52, np.nan), "weights")):
        with pytest.raises(fw.InputError, match=msg):
            t.controls(bad)




# ------------------------------------------------------------------ the shipped basis, no external data
@pytest.fixture
def no_ict(monkeypatch, tmp_path):
    """No ICT-FaceKit folder anywhere, as on a fresh install without the shared folder:
    FACEWARP_SHARED and FACEWARP_ICT_SHAPES unset and HOME empty, so the lookup finds nothing."""
    monkeypatch.delenv("FACEWARP_SHARED", raising=False)
    monkeypatch.delenv("FACEWARP_ICT_SHAPES", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert fw.takes.ict_shape_dirs() == []


def test_shipped_basis_file_and_licence():
    """The basis ships inside the package (package data, under 5 MB, the MIT notice beside it):
    the 51 ICT shapes (no tongueOut) on the level-1 template skin and its head FDPs."""
    from pathlib import Path

    b = fw.takes.load_arkit_basis()
    f = b.file
    assert f.name == "arkit_basis.npz" and f.parent.parent.parent.parent == Path(fw.__file__).parent
    assert f.stat().st_size < 5e6
    licence = b.licence_file.read_text()
    assert "MIT License" in licence and "Permission is hereby granted" in licence
    pyproject = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
    assert "_src/importers/data/arkit_basis.npz" in pyproject and "ICT-FaceKit-LICENSE.txt" in pyproject
    assert set(b.names) == {n for n, stems in fw.takes.ICT_ARKIT_SHAPES.items() if stems} and "tongueOut" not in b.names
    t = fw.default_template(b.level)
    assert b.vertices.shape == (t.vertex_count, 3) and len(b.fdp_ids) >= 60
    np.testing.assert_allclose(b.vertices, t.vertices, atol=1e-6)  # still the template it was made on
    # sizes: the jaw opens centimetres, a blink moves the lids millimetres, a smile lifts the lip corner
    ids = list(b.fdp_ids)
    assert np.linalg.norm(b.fdp["jawOpen"][ids.index("2.1")]) > 0.01
    assert 1e-3 < np.linalg.norm(b.fdp["eyeBlinkLeft"][ids.index("3.1")]) < 0.02
    corner = "8.4" if b.fdp_points[ids.index("8.4"), 0] > 0 else "8.3"
    assert b.fdp["mouthSmileLeft"][ids.index(corner), 1] > 2e-3
    assert np.linalg.norm(b.fdp["mouthSmileLeft"][ids.index("11.1")]) < 5e-4  # hairline: still


def test_basis_transfer_identity_and_scaling():
    """Carried onto the template itself the basis comes back (FDPs exactly, other points by the skin);
    onto a copy scaled by 1.1, turned and moved, it comes back scaled and turned."""
    b = fw.takes.load_arkit_basis()
    lm = dict(zip(b.fdp_ids, b.fdp_points))
    names = ["jawOpen", "mouthSmileLeft", "eyeBlinkRight"]
    out = b.transfer(b.fdp_points, lm, names=names, point_ids=b.fdp_ids)
    for n in names:
        np.testing.assert_allclose(out[n], b.fdp[n], atol=1e-9)
    pick = np.array([100, 2000, 5000, 9000])
    free = b.transfer(b.vertices[pick], lm, names=names)
    for n in names:
        np.testing.assert_allclose(free[n], b.skin[n][pick], atol=1e-6)
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = {k: 1.1 * R @ p + np.array([0.1, 0.2, -0.3]) for k, p in lm.items()}
    P = 1.1 * b.fdp_points @ R.T + np.array([0.1, 0.2, -0.3])
    out2 = b.transfer(P, moved, names=names, point_ids=b.fdp_ids)
    for n in names:
        np.testing.assert_allclose(out2[n], 1.1 * b.fdp[n] @ R.T, atol=1e-8)
    with pytest.raises(fw.InputError, match="names: the ARKit basis has no shape 'tongueOut'"):
        b.transfer(P, moved, names=["tongueOut"])


def test_basis_matches_the_kit(ict):
    """The shipped shapes agree with the kit's own OBJs carried onto the template directly (the
    five shapes the shared folder holds): within the 2 um quantization at the FDPs."""
    b = fw.takes.load_arkit_basis()
    D = fw.takes.load_ict_displacements(["jawOpen", "mouthSmileLeft", "browInnerUp"], ict_dir=ict)
    direct = fw.takes.transfer_ict_displacements(D, b.fdp_points, dict(zip(b.fdp_ids, b.fdp_points)),
                                           point_ids=b.fdp_ids, ict_dir=ict)
    for n in D:
        np.testing.assert_allclose(b.fdp[n], direct[n], atol=b.step_m)
    with pytest.raises(fw.InputError, match="lacks 4[0-9] ARKit shapes"):  # the regenerator wants the whole rig
        b.make(ict, "unused.npz")


def test_eye_gaze_turns_the_eyeballs(sim):
    """set_eye_gaze turns each eyeball about its centre at the next step: the gaze axis follows
    Ry(yaw) Rx(-pitch), the eye FDPs move with it, reset straightens."""
    def eye_gaze_rotation(yaw, pitch):  # the oracle: Ry(yaw) Rx(-pitch)
        cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
        return np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]]) @ np.array([[1, 0, 0], [0, cp, sp], [0, -sp, cp]])

    sim.reset()
    rest = sim.part_points(frame="head")
    eye_fdp = [i for i, p in enumerate(sim.fr.fdp_part) if str(p) == "eye_L"]
    assert eye_fdp  # the pupil FDPs sit on the eyeballs
    fdp0 = sim.fdp_points()[eye_fdp]
    g = np.array([[0.3, 0.0], [-0.2, 0.25]])
    sim.set_eye_gaze(g)
    np.testing.assert_array_equal(sim.eye_gaze, 0)  # reached at the end of the next step
    sim.step()
    np.testing.assert_allclose(sim.eye_gaze, g, atol=1e-7)
    now = sim.part_points(frame="head")
    for e, name in enumerate(("eye_L", "eye_R")):
        c = rest[name].mean(axis=0)
        R = eye_gaze_rotation(*g[e])
        np.testing.assert_allclose(now[name], (rest[name] - c) @ R.T + c, atol=1e-6)
    np.testing.assert_allclose(rest["teeth_upper"], now["teeth_upper"])
    c = rest["eye_L"].mean(axis=0)
    np.testing.assert_allclose(sim.fdp_points()[eye_fdp], (fdp0 - c) @ eye_gaze_rotation(0.3, 0.0).T + c, atol=1e-5)
    d = eye_gaze_rotation(0.3, 0.0) @ [0.0, 0.0, 1.0]
    assert d[0] > 0.29 and abs(d[1]) < 1e-12  # yaw > 0 looks towards +x (the subject's left)
    assert eye_gaze_rotation(0.0, 0.2)[1, 2] > 0.19  # pitch > 0 looks up
    sim.reset()
    np.testing.assert_array_equal(sim.eye_gaze, 0)
    with pytest.raises(fw.InputError, match="gaze"):
        sim.set_eye_gaze(np.zeros(3))
    with pytest.raises(fw.InputError, match="within"):
        sim.set_eye_gaze(np.full((2, 2), 2.0))


def test_face_that_cannot_move_is_an_error(sim, no_ict):
    """A take of which nothing maps onto the head is an InputError with one line; a take that only
    looks around turns the eyes (and is driven)."""
    t = fw.arkit_table(sim, shapes=[], max_frames=3)  # no data: no probes, no solve
    W = np.zeros((3, 52))
    W[:, fw.ARKIT_NAMES.index("tongueOut")] = 0.7
    W[:, fw.ARKIT_NAMES.index("cheekPuff")] = 0.2
    with pytest.raises(fw.InputError, match=r"^tongue.csv: the face cannot move: none of the 2 ARKit shapes it uses "
                                            r"\(cheekPuff, tongueOut\) is mapped") as e:
        fw.drive(sim, fw.takes.ArkitTrack(30.0, W, None, "tongue.csv"), table=t)
    assert "\n" not in str(e.value)
    with pytest.raises(fw.InputError, match="every ARKit weight is 0"):
        fw.drive(sim, fw.takes.ArkitTrack(30.0, np.zeros((3, 52))), table=t)
    W[:, fw.ARKIT_NAMES.index("eyeLookOutRight")] = 1.0
    r = fw.drive(sim, fw.takes.ArkitTrack(30.0, W), table=t)
    np.testing.assert_allclose(r.gaze[-1, 1], [-np.radians(30.0), 0.0])  # the right eye looks out, to -x
    assert sorted(w.split(":")[0] for w in r.warnings) == ["cheekPuff", "tongueOut"]
    # recorded eye angles (Live Link Face's eye yaw / pitch, as a loader gives them) win over the weights
    tr = fw.takes.ArkitTrack(30.0, W)
    tr.eye_rotation = np.tile([[0.1, -0.05], [0.12, -0.05]], (3, 1, 1))
    r = fw.drive(sim, tr, table=t)
    np.testing.assert_allclose(r.gaze, tr.eye_rotation)
    np.testing.assert_allclose(sim.eye_gaze, tr.eye_rotation[-1], atol=1e-7)
    tr.eye_rotation = np.zeros((2, 2, 2))
    with pytest.raises(fw.InputError, match=r"track.eye_rotation"):
        fw.drive(sim, tr, table=t)


def test_cache_that_cannot_be_written(sim, no_ict, tmp_path, monkeypatch):
    """Issue 40: a cache that cannot be written is skipped with a note, leaving no temporary file;
    a folder in the table's place is refused before any work."""
    import os

    cache = tmp_path / "build"
    cache.mkdir()
    (cache / "arkit_table.npz").mkdir()
    with pytest.raises(fw.InputError, match=r"cache: .*arkit_table.npz is not a file \(a folder"):
        fw.arkit_table(sim, shapes=[], cache=cache, max_frames=3)
    (cache / "arkit_table.npz").rmdir()

    def no_space(path, **arrays):
        with open(path, "wb") as f:
            f.write(b"partial")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez_compressed", no_space)
    t = fw.arkit_table(sim, shapes=[], cache=cache, max_frames=3)
    assert "not cached" in t.info["cache_note"] and "No space left on device" in t.info["cache_note"]
    assert os.listdir(cache) == []
    monkeypatch.undo()
    if os.geteuid() != 0:  # a read-only folder (root writes anyway)
        cache.chmod(0o555)
        try:
            t = fw.arkit_table(sim, shapes=[], cache=cache, max_frames=3)
            assert "cannot be written" in t.info["cache_note"] and os.listdir(cache) == []
        finally:
            cache.chmod(0o755)


@pytest.mark.slow
def test_shipped_table_on_demand(sim, no_ict, tmp_path):
    """With no ICT folder the table comes from the shipped basis: the shapes asked for are solved
    (the smile reached by muscles, the jaw by the jaw), the others wait; a later call adds shapes to
    the cached table without probing again."""
    cache = tmp_path / "build"
    t = fw.arkit_table(sim, solve=["jawOpen", "mouthSmileLeft"], cache=cache, refine=1, max_frames=25)
    assert t.info["source"] == "shipped" and "ICT-FaceKit" in t.info["source_note"]
    i_jaw, i_smile, i_blink = (fw.ARKIT_NAMES.index(n) for n in ("jawOpen", "mouthSmileLeft", "eyeBlinkLeft"))
    assert t.solved[i_jaw] and t.solved[i_smile] and not t.solved[i_blink]
    assert "not solved yet" in t.reasons["eyeBlinkLeft"] and np.isfinite(t.target_rms_m[i_blink])
    reach = {r["name"]: r for r in t.reach()}
    assert reach["jawOpen"]["by"].endswith("jaw") and "muscles" in reach["mouthSmileLeft"]["by"]
    assert reach["mouthSmileLeft"]["residual_mm"] < 0.8 * reach["mouthSmileLeft"]["target_mm"]
    assert reach["eyeLookUpLeft"]["by"] == "eyes" and reach["eyeLookUpLeft"]["gaze_deg"][0] == [0.0, 25.0]
    assert reach["tongueOut"]["by"] == "not reached" and reach["tongueOut"]["target_mm"] is None
    statics = t.info["statics"]
    t2 = fw.arkit_table(sim, solve=["jawOpen", "eyeBlinkLeft"], cache=cache, refine=1, max_frames=25)
    assert t2.solved[i_blink] and t2.solved[i_smile] and not t2.info["from_cache"]
    assert t2.info["statics"] - statics <= 3  # the blink alone: no probes again
    np.testing.assert_array_equal(t2.activations[i_smile], t.activations[i_smile])
    t3 = fw.arkit_table(sim, solve=["eyeBlinkLeft", "mouthSmileLeft"], cache=cache, refine=1, max_frames=25)
    assert t3.info["from_cache"]
    # a track using these moves the face; the blink closes the left lids a little (muscles)
    W = np.zeros((4, 52))
    W[:, i_smile] = [0.0, 0.5, 1.0, 1.0]
    W[:, i_blink] = [0.0, 0.5, 1.0, 1.0]
    r = fw.drive(sim, fw.takes.ArkitTrack(30.0, W), table=t3)
    assert r.warnings == [] and r.activations[-1].max() > 0.3


GUIDE_TAKE = '''
import numpy as np
import facewarp as fw

t = np.arange(45) / 30.0                                       # 1.5 s at 30 fps
w = np.zeros((len(t), 52))
w[:, fw.ARKIT_NAMES.index("mouthSmileLeft")] = 0.5 * (1 - np.cos(2 * np.pi * t / 1.5))
w[:, fw.ARKIT_NAMES.index("mouthSmileRight")] = w[:, fw.ARKIT_NAMES.index("mouthSmileLeft")]
w[:, fw.ARKIT_NAMES.index("jawOpen")] = 0.3 * np.sin(np.pi * t / 1.5)
head = np.stack([0.1 * np.sin(2 * np.pi * t / 1.5), 0 * t, 0 * t], axis=1)   # yaw, pitch, roll [rad]
fw.takes.save_livelink_csv(fw.takes.ArkitTrack(30.0, w, head), "smile_livelink.csv")
'''


@pytest.mark.slow
def test_guide_arkit_example_without_shared_data(no_ict, tmp_path, monkeypatch, capsys):
    """The driving guide's ARKit example on a fresh install (no shared folder, no ICT OBJs anywhere):
    `facewarp drive build --arkit smile_livelink.csv` moves the face and reports each shape's reach;
    issue 40: a folder in the table's place is refused up front (exit 2, one line, nothing left in
    the build), and a build whose cache cannot be written drives with a note."""
    import json
    import os
    import shutil

    from facewarp.cli import main

    monkeypatch.chdir(tmp_path)
    exec(compile(GUIDE_TAKE, "guide", "exec"), {})
    assert main(["build", "default", "--out", "build"]) == 0
    # a folder where the table goes: refused before any work, nothing written into the build
    bad = tmp_path / "bad_build"
    shutil.copytree("build", bad)
    (bad / "arkit_table.npz").mkdir()
    before = sorted(os.listdir(bad))
    capsys.readouterr()
    assert main(["drive", str(bad), "--arkit", "smile_livelink.csv", "--out", "bad_out"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "arkit_table.npz is not a file" in err
    assert sorted(os.listdir(bad)) == before and not (tmp_path / "bad_out").exists()
    # the guide's command
    assert main(["drive", "build", "--arkit", "smile_livelink.csv", "--out", "driven_arkit"]) == 0
    out = capsys.readouterr().out
    assert "RMS 0.00 mm" not in out and "(built now, cached for later runs)" in out
    rep = json.loads((tmp_path / "driven_arkit" / "report.json").read_text())
    reach = {r["name"]: r for r in rep["reach"]}
    assert set(reach) == {"mouthSmileLeft", "mouthSmileRight", "jawOpen"} and rep["warnings"] == []
    for r in reach.values():
        assert r["by"] != "not reached" and 0 < r["residual_mm"] < r["target_mm"]
    assert 0.1 < rep["error_mm"]["rms"] < 10.0
    z = np.load(tmp_path / "driven_arkit" / "frames.npz")
    ids = [str(i) for i in z["fdp_ids"]]
    corner = z["fdp_points"][:, ids.index("8.3")]
    chin = z["fdp_points"][:, ids.index("2.1")]
    assert np.linalg.norm(corner - corner[0], axis=1).max() > 3e-3 and np.linalg.norm(chin - chin[0], axis=1).max() > 3e-3
    # a take needing one more shape on a build whose cache cannot be written: solved, driven, a note
    ro = tmp_path / "ro_build"
    shutil.copytree("build", ro)
    take = fw.load_arkit("smile_livelink.csv")
    take.weights[:, fw.ARKIT_NAMES.index("eyeBlinkLeft")] = take.weights[:, fw.ARKIT_NAMES.index("jawOpen")]
    fw.takes.save_livelink_csv(take, "blink_livelink.csv")

    real = np.savez_compressed

    def denied(path, **arrays):  # the table's file only (root writes into a read-only folder anyway)
        if "arkit_table" in str(path):
            raise PermissionError(13, "Permission denied", str(path))
        return real(path, **arrays)

    monkeypatch.setattr(np, "savez_compressed", denied)
    before = (ro / "arkit_table.npz").read_bytes()
    assert main(["drive", str(ro), "--arkit", "blink_livelink.csv", "--out", "ro_out"]) == 0
    out = capsys.readouterr().out
    assert "not cached" in out and "Permission denied" in out
    assert sorted(os.listdir(ro)) == sorted(os.listdir("build")) and (ro / "arkit_table.npz").read_bytes() == before
    rep = json.loads((tmp_path / "ro_out" / "report.json").read_text())
    assert "eyeBlinkLeft" in {r["name"] for r in rep["reach"]} and any("not cached" in n for n in rep["notes"])


def test_docs_reach_table_lists_every_shape():
    """docs/concepts/arkit.md's reach table (generated from benchmarks/results/arkit_basis.json) has a
    row per ARKit shape in fw.ARKIT_NAMES order; the shapes not reached are fw.takes.ARKIT_OUT_OF_REACH's,
    each with its reason, and the eyeLook shapes turn the eyes."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "concepts" / "arkit.md").read_text()
    block = text.split("<!-- table:arkit_reach -->")[1].split("<!-- /table:arkit_reach -->")[0]
    rows = [[c.strip() for c in r.strip().strip("|").split("|")] for r in block.splitlines() if r.startswith("| `")]
    assert [r[0].strip("`") for r in rows] == list(fw.ARKIT_NAMES)
    not_reached = {r[0].strip("`"): r[-1] for r in rows if r[1] == "not reached"}
    assert not_reached == fw.takes.ARKIT_OUT_OF_REACH
    assert all("eyes" in r[1] for r in rows if r[0].startswith("`eyeLook"))


@pytest.mark.slow
def test_regenerating_the_basis_reproduces_it(tmp_path):
    """make_arkit_basis on the whole ICT-FaceKit rig ($FACEWARP_ICT_SHAPES: the kit's FaceXModel
    folder) writes the shipped file's arrays again."""
    import os
    from pathlib import Path

    d = os.environ.get("FACEWARP_ICT_SHAPES")
    if not d or not (Path(d) / "eyeBlink_L.obj").is_file():
        pytest.skip("FACEWARP_ICT_SHAPES does not name the ICT-FaceKit FaceXModel folder (all expression OBJs)")
    b = fw.takes.load_arkit_basis()
    out = b.make(d, tmp_path / "basis.npz")
    new, shipped = np.load(out), np.load(b.file)
    for k in ("names", "fdp_ids", "skin", "fdp", "faces"):
        np.testing.assert_array_equal(new[k], shipped[k])
    np.testing.assert_allclose(new["vertices"], shipped["vertices"])


def test_no_import_cycle_among_the_drive_modules():
    """Issue 35: drive/inverse and drive/arkit no longer import each other (DriveResult has its own
    module); no import among the drive modules, at module level or inside functions, closes a cycle."""
    import ast
    from pathlib import Path

    folder = Path(fw.__file__).parent / "_src" / "drive"
    edges = {}
    for p in folder.glob("*.py"):
        deps = set()
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
                deps.add(node.module.split(".")[0])
        edges[p.stem] = deps & {q.stem for q in folder.glob("*.py")}
    assert "inverse" not in edges["arkit"] and "result" in edges["arkit"] and "result" in edges["inverse"]

    def reach(a, seen):
        for b in edges.get(a, ()):
            if b not in seen:
                seen.add(b)
                reach(b, seen)
        return seen

    assert not [m for m in edges if m in reach(m, set())], edges
