"""FaceBatch: N heads stepped together give each head what it gets alone; bad inputs are one line."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import facewarp as fw
from conftest import step_together
from conftest import fresh_build

FRAMES = 12  # 0.4 s at 30 fps: the laugh ramping in with its jaw


@pytest.fixture(scope="module")
def rigs():
    t = fw.default_template(0)
    s = np.array([1.06, 0.95, 1.03])  # another person: the default head stretched (same topology, new rest shape)
    other = replace(t, vertices=t.vertices * s, condyles=t.condyles * s,
                    parts={k: (V * s, F) for k, (V, F) in t.parts.items()})
    return fw.build_face(t), fw.build_face(other)


def _controls(rig, k):
    tl = fw.timeline_for("laugh", attack=0.3, hold=1.0, release=0.1, start=0.0).for_head(rig)
    return tl.sample(k / 30.0)


def test_batch_gives_each_head_its_own_answer(rigs, device):
    a, b = rigs
    heads = [a, b, a]
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    batch = fw.FaceBatch(heads, device=device, placements=(np.stack([np.eye(3), R, np.eye(3)]),
                                                            np.array([[0, 0, 0], [1.0, 0, 0], [0, 2.0, 0]])),
                         streams=2, backend="heads")  # CUDA: two groups of heads, each a graph on its own stream (the CPU ignores it)
    alone = [fw.FaceSimulator(fr, device=device) for fr in (a, b)]
    for k in range(1, FRAMES + 1):
        es = [_controls(fr, k) for fr in heads]
        es[2] = fw.Expression("quiet", {}, 0.0, 0.0)  # head 2: the same rig as head 0, other controls
        if k % 2:  # a list of expressions, or one (N, M) array
            batch.set_activations(es)
        else:
            batch.set_activations(np.stack([h.activation_vector(e) for h, e in zip(batch.heads, es)]))
        batch.set_jaw(np.array([[e.jaw_u, e.jaw_v] for e in es]))
        c, s_ = np.cos(0.003 * k), np.sin(0.003 * k)  # head 1 nods and rises: the loads of a moving head
        Rk, tk = np.array([[1.0, 0, 0], [0, c, -s_], [0, s_, c]]), np.array([0.0, 0.0005 * k, 0.0])
        batch.set_head_pose(np.stack([np.eye(3), Rk, np.eye(3)]), np.stack([np.zeros(3), tk, np.zeros(3)]))
        alone[1].set_head_pose(Rk, tk)
        batch.step()
        for sim, e in zip(alone, es):
            sim.set_activations(e)
            sim.set_jaw(e.jaw_u, e.jaw_v)
            sim.step()
    for i, sim in enumerate(alone):
        np.testing.assert_allclose(batch.positions(i), sim.positions(), atol=1e-6, rtol=0, err_msg=f"head {i}")
    moved = np.abs(batch.positions(0) - a.nodes).max()
    assert moved > 1e-3, moved  # the laugh moved the face
    assert np.abs(batch.positions(2) - a.nodes).max() < 1e-4  # head 2 kept its rest: no cross-talk
    # placements apply at read-out: head 1's FDPs are its alone FDPs rotated and shifted
    np.testing.assert_allclose(batch.fdp_points(1), alone[1].fdp_points() @ R.T + [1.0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(batch.positions(1, frame="world"), (alone[1].positions() @ Rk.T + tk) @ R.T + [1.0, 0, 0],
                               atol=1e-6)
    np.testing.assert_allclose(batch.surface(0), alone[0].surface(), atol=1e-6)
    st = batch.status
    assert [s["ok"] for s in st] == [True] * 3 and st[1]["frames"] == FRAMES
    assert st[2]["iterations"] < st[0]["iterations"], st  # per-head convergence: the head at rest iterates less
    batch.reset(heads=[0])
    np.testing.assert_allclose(batch.positions(0), a.nodes, atol=1e-6)
    assert np.abs(batch.positions(1) - b.nodes).max() > 1e-3  # the others kept their state


@pytest.mark.slow
def test_batch_same_answer_over_a_two_second_preset(rigs, device):
    """The issue's same-answer target: two different heads and a third playing other controls, 2 s of
    laugh (attack, hold, release) at 30 fps, each head within 1e-6 m of the same head alone, every 10th frame."""
    a, b = rigs
    heads = [a, b, b]
    batch = fw.FaceBatch(heads, device=device, backend="heads")
    alone = [fw.FaceSimulator(fr, device=device) for fr in heads]
    tl = fw.timeline_for("laugh", attack=0.3, hold=1.2, release=0.3, start=0.0)
    smile = fw.preset("smile")
    worst = played = 0.0
    for k in range(1, 61):
        es = [tl.for_head(fr).sample(k / 30.0) for fr in heads[:2]]
        es.append(fw.Expression("smile_half", {m: 0.5 * v for m, v in smile.activations.items()},
                                0.15 * np.sin(np.pi * k / 30.0) ** 2, 0.0))  # its jaw opens and closes
        step_together(batch, alone, es)
        if k % 10 == 0:
            for i, sim in enumerate(alone):
                worst = max(worst, float(np.abs(batch.positions(i) - sim.positions()).max()))
            played = max(played, float(np.abs(batch.positions(0) - a.nodes).max()))
    assert worst <= 1e-6, worst
    assert played > 1e-3, played  # the laugh moved the face


def test_failing_head_is_frozen_and_reported(rigs, device):
    a, _ = rigs
    batch = fw.FaceBatch(a, 2, device=device, backend="heads")
    batch.heads[1].max_refinement = 0  # no retries for the poisoned head
    X = batch.heads[1].state.positions.numpy()
    X[int(np.flatnonzero(~a.fixed & ~a.held)[0])] = np.nan  # a NaN in a free node of head 1 (a fixed one is reset)
    batch.heads[1].state.positions.assign(X)
    batch.heads[1].state.prev_positions.assign(X)
    e = _controls(a, 5)
    batch.set_activations([e, e])
    batch.step()
    st = batch.status
    assert st[0]["ok"] and not st[1]["ok"] and ("non-finite" in st[1]["error"] or "NaN" in st[1]["error"])
    assert batch.live == [0]
    ok = batch.positions(0)
    assert np.isfinite(ok).all() and np.abs(ok - a.nodes).max() > 0  # head 0 went on
    batch.step()
    assert batch.status[0]["frames"] == 2 and batch.status[1]["frames"] == 0


def test_bad_inputs_are_input_errors(rigs):
    a, b = rigs
    with pytest.raises(fw.InputError, match="rigs"):
        fw.FaceBatch([], device="cpu")
    with pytest.raises(fw.InputError, match="rigs\\[1\\]"):
        fw.FaceBatch([a, "b"], device="cpu")
    with pytest.raises(fw.InputError, match="count"):
        fw.FaceBatch([a, b], count=3, device="cpu")
    with pytest.raises(fw.InputError, match="count"):
        fw.FaceBatch(a, 0, device="cpu")
    with pytest.raises(fw.InputError, match="placements"):
        fw.FaceBatch(a, 2, device="cpu", placements=(np.ones((2, 3, 3)), np.zeros((2, 3))))
    with pytest.raises(fw.InputError, match="speed"):
        fw.FaceBatch(a, 2, device="cpu", speed=3)
    batch = fw.FaceBatch([a, b], device="cpu")
    with pytest.raises(fw.InputError, match="activations"):
        batch.set_activations(np.zeros((3, len(a.rig.names))))
    with pytest.raises(fw.InputError, match="head 1"):
        batch.set_activations([{}, {"no_such_muscle": 1.0}])
    with pytest.raises(fw.InputError, match="angles"):
        batch.set_jaw(np.zeros((2, 3)))
    with pytest.raises(fw.InputError, match="head 1"):
        batch.set_activations(np.stack([np.zeros(len(a.rig.names)), np.full(len(a.rig.names), 1.5)]))
    with pytest.raises(fw.InputError, match="angles of head 0"):
        batch.set_jaw(np.array([[2.0, 0.0], [0.0, 0.0]]))
    with pytest.raises(fw.InputError, match="head"):
        batch.surface(2)
    with pytest.raises(fw.InputError, match="heads"):
        batch.reset(heads=[5])
    with pytest.raises(fw.InputError, match="head pose"):
        batch.set_head_pose(np.eye(3), np.zeros((3, 3)))


@pytest.fixture(scope="module")
def build_dir(tmp_path_factory, default_build_dir):
    return fresh_build(tmp_path_factory, default_build_dir)


def test_batch_mujoco_jaws_match_the_single_head_driver(build_dir):
    from facewarp.coupling import MujocoJawDriver

    fr = fw.load_face_rig(build_dir)
    mjcf = build_dir / "head.xml"
    batch = fw.FaceBatch(fr, 2)
    batch.use_mujoco_jaws(mjcf)
    alone = fw.FaceSimulator(fr)
    driver = MujocoJawDriver(alone, mjcf)
    quiet = fw.Expression("quiet", {}, 0.0, 0.0)
    for k in range(1, 9):
        e = _controls(fr, k)
        batch.set_activations([e, quiet])
        batch.set_jaw(np.array([[e.jaw_u, e.jaw_v], [0.0, 0.0]]))
        batch.step()
        alone.set_activations(e)
        driver.step(e)
    np.testing.assert_allclose(batch.positions(0), alone.positions(), atol=1e-6, rtol=0)
    assert batch.heads[0].jaw_angles[0] > 0.005 and abs(batch.heads[1].jaw_angles[0]) < 1e-3
    assert all(s["ok"] for s in batch.status)


def test_batch_simulate_cli(build_dir, tmp_path, capsys):
    from facewarp.cli import main

    per = tmp_path / "per.json"
    per.write_text('{"heads": ["smile", {"expression": "laugh"}]}')
    b = str(build_dir)
    capsys.readouterr()
    assert main(["--json", "batch", "simulate", b, b, "--per-head", str(per), "--seconds", "0.2", "--jaw", "mujoco",
                 "--stage", "crowd.usda",
                 "--out", str(tmp_path / "o")]) == 0
    import json

    rep = json.loads(capsys.readouterr().out)
    assert rep["heads"] == 2 and rep["ok"] == 2 and rep["frames"] == 7 and rep["jaw"] == "mujoco" and rep["head_frames_per_second"] > 0
    assert [r["expression"] for r in rep["rows"]] == ["smile", "laugh"]
    for f in ("head_00.usdc", "head_01.usdc", "report.json", "crowd.usda"):
        assert (tmp_path / "o" / f).is_file(), f
    from pxr import Usd, UsdGeom

    st = Usd.Stage.Open(str(tmp_path / "o" / "crowd.usda"))  # the crowd: both heads, referenced, placed apart
    skins = [UsdGeom.Mesh(st.GetPrimAtPath(f"/Crowd/head_0{i}/Skin")) for i in range(2)]
    assert all(s_ for s_ in skins)
    x = [UsdGeom.Xformable(st.GetPrimAtPath(f"/Crowd/head_0{i}")).ComputeLocalToWorldTransform(0).ExtractTranslation()[0]
         for i in range(2)]
    assert x[1] - x[0] > 0.1
    n_frames = len(skins[0].GetPointsAttr().GetTimeSamples())
    assert n_frames == 7
    # bad input: one line, exit 2, nothing written
    per.write_text('{"heads": ["smile"]}')
    assert main(["batch", "simulate", b, b, "--per-head", str(per), "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert "1 entries for 2 heads" in err and err.count("\n") == 1
    assert not (tmp_path / "o2").exists()


def _box(nx, ny, nz, h):
    g = np.stack(np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij"), -1)
    V = g.transpose(2, 1, 0, 3).reshape(-1, 3).astype(np.float64) * h

    def vid(i, j, k):
        return (k * (ny + 1) + j) * (nx + 1) + i

    T = []
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                c = [vid(i + a, j + b, k + d) for d in (0, 1) for b in (0, 1) for a in (0, 1)]
                for tet in ((0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)):
                    T.append([c[q] for q in tet])
    T = np.array(T)
    x = V[T]
    vol = np.einsum("ij,ij->i", x[:, 1] - x[:, 0], np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]))
    T[vol < 0] = T[vol < 0][:, [0, 2, 1, 3]]
    return V, T


def test_replicated_tissue_model_steps_each_head_as_alone(device):
    """ModelBuilder.add_builder / replicate: N tissues in one Model, each placed by its transform,
    stepped by one solver: each head moves as it does alone (in its own frame)."""
    from facewarp.physics import ModelBuilder, SolverVerlet

    heads = []
    for dims, h in (((3, 2, 1), 0.01), ((2, 2, 2), 0.012)):
        V, T = _box(*dims, h)
        fixed = V[:, 2] < 1e-9
        heads.append(ModelBuilder(V, T, fixed=fixed, material="physical"))
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    big = ModelBuilder()
    big.add_builder(heads[0])
    big.replicate(heads[1], 2, xforms=[(R, [0.05, 0.0, 0.0]), np.eye(4)])
    m = big.finalize(device)
    n0, n1 = heads[0].vertex_count, heads[1].vertex_count
    assert m.head_count == 3 and m.head_node_start.tolist() == [0, n0, n0 + n1, n0 + 2 * n1]
    assert m.head_tet_start[-1] == m.tet_count == len(heads[0].tets) + 2 * len(heads[1].tets)

    def run(model, force):
        solver = SolverVerlet(model)
        st, sc, ctl = model.state(), model.state(), model.control()
        ctl.external_force.assign(force.astype(np.float32))
        for _ in range(40):
            solver.step(st, sc, ctl, 1e-4)
            st, sc = sc, st
        return st.positions.numpy().astype(np.float64)

    rng = np.random.default_rng(0)
    f0, f1 = rng.normal(0, 0.05, (n0, 3)), rng.normal(0, 0.05, (n1, 3))
    alone0 = run(heads[0].finalize(device), f0)
    alone1 = run(heads[1].finalize(device), f1)
    X = run(m, np.concatenate([f0, f1 @ R.T, f1]))  # head 1's load turned with it
    assert np.abs(alone1 - heads[1].vertices).max() > 1e-5  # the load moved it
    np.testing.assert_allclose(X[:n0], alone0, atol=1e-6, rtol=0)
    np.testing.assert_allclose(X[n0:n0 + n1], alone1 @ R.T + [0.05, 0.0, 0.0], atol=1e-6, rtol=0)
    np.testing.assert_allclose(X[n0 + n1:], alone1, atol=1e-6, rtol=0)


def test_replicate_refuses_what_it_cannot_merge(rigs):
    from facewarp.physics import ModelBuilder

    V, T = _box(1, 1, 1, 0.01)
    tissue = ModelBuilder(V, T)
    face = ModelBuilder()
    face.add_face(rigs[0])
    with pytest.raises(fw.InputError, match="FaceBatch"):
        ModelBuilder().add_builder(face)
    with pytest.raises(fw.InputError, match="no head"):
        ModelBuilder().add_builder(ModelBuilder())
    with pytest.raises(fw.InputError, match="count"):
        ModelBuilder().replicate(tissue, 0)
    with pytest.raises(fw.InputError, match="xforms\\[0\\]"):
        ModelBuilder().replicate(tissue, 1, xforms=[np.ones((4, 4))])
    with pytest.raises(fw.InputError, match="damping rate"):
        b = ModelBuilder()
        b.add_builder(tissue)
        b.add_builder(ModelBuilder(V, T, damping_rate=3.0))


def test_substeps_ramp_in_pieces_as_alone(rigs):
    """Several substeps per frame: the controls ramp in pieces, each piece one upload for all heads."""
    a, _ = rigs
    batch = fw.FaceBatch(a, 2, substeps=3)
    alone = fw.FaceSimulator(a, substeps=3)
    for k in range(1, 4):
        e = _controls(a, 3 * k)
        batch.set_activations([e, e])
        batch.set_jaw(np.array([[e.jaw_u, e.jaw_v]] * 2))
        batch.step()
        alone.set_activations(e)
        alone.set_jaw(e.jaw_u, e.jaw_v)
        alone.step()
    for i in range(2):
        np.testing.assert_allclose(batch.positions(i), alone.positions(), atol=1e-6, rtol=0)
