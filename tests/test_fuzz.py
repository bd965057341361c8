"""Fuzzing the edges: bad files (random truncation, garbage bytes, NaN, wrong shapes, unknown keys,
headers that lie), bad arguments (huge sizes, wrong types) and bad API calls.

Every case must end as the CLI promises: exit code 2, exactly one stderr line
``facewarp: error: ...`` naming the input, no traceback, nothing written at ``--out`` (or, for
a mutation that left the input legal, exit code 0); in the API an :class:`~facewarp.InputError`
naming the argument. The random seed is printed with every failure; rerun one with
``FACEWARP_FUZZ_SEED=<seed> python -m pytest tests/test_fuzz.py``. Kept fast: small inputs,
level-0 heads, one build per module, most cases in-process (``facewarp.cli.main``).
"""

from __future__ import annotations

import json
import os
import random
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import facewarp as fw
from facewarp.cli import main
from conftest import fresh_build

SEED = int(os.environ.get("FACEWARP_FUZZ_SEED", random.SystemRandom().randrange(2**31)))
N = int(os.environ.get("FACEWARP_FUZZ_CASES", "6"))  # random mutations per file kind


def _why(what: str) -> str:
    return f"{what} [FACEWARP_FUZZ_SEED={SEED}]"


def _rng(salt: str) -> random.Random:
    return random.Random(f"{SEED}:{salt}")


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".facewarp-" in p.name)


def _cli(capsys, argv, *, needle: str, out: Path | None = None, ok_codes=(2,), what: str = ""):
    """Run ``facewarp argv`` in-process; the promised failure (or an allowed success)."""
    code = main([str(a) for a in argv])
    stdout, err = capsys.readouterr()
    label = _why(f"{what or ' '.join(map(str, argv))}: exit {code}, stderr {err!r}")
    assert code in ok_codes, label
    if code == 2:
        lines = err.strip().splitlines()
        assert stdout == "", label
        assert len(lines) == 1 and lines[0].startswith("facewarp: error: "), label
        assert "Traceback" not in err and ".facewarp-partial" not in err, label
        assert needle in lines[0], _why(f"{needle!r} not named: {lines[0]}")
        if out is not None:
            assert not out.exists(), label
    if out is not None:
        assert _leftovers(out.parent) == [], label
    return code


# ----------------------------------------------------------------------------- mutations
def _truncations(data: bytes, rng: random.Random, n: int) -> list[bytes]:
    cuts = {0, 1, len(data) // 2, len(data) - 1} | {rng.randrange(1, max(2, len(data))) for _ in range(n)}
    return [data[:c] for c in sorted(cuts) if c < len(data)]


def _garbage(data: bytes, rng: random.Random, n: int) -> list[bytes]:
    out = []
    for _ in range(n):
        b = bytearray(data)
        at = rng.randrange(len(b))
        k = rng.randint(1, 64)
        b[at:at + k] = bytes(rng.randrange(256) for _ in range(k))
        out.append(bytes(b))
    out.append(bytes(rng.randrange(256) for _ in range(rng.randint(1, 4096))))  # all garbage
    return out


@pytest.fixture(scope="module")
def small_mesh():
    """A closed octahedron (6 vertices, 8 faces), metres."""
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float) * 0.05
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return V, F


def _mesh_bytes(V, F, fmt: str) -> bytes:
    import trimesh

    m = trimesh.Trimesh(V, F, process=False)
    data = _export(m, V, F, fmt)
    return data.encode() if isinstance(data, str) else data


def _export(m, V, F, fmt: str):
    if fmt == "obj":
        return "".join(f"v {x} {y} {z}\n" for x, y, z in V) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F)
    if fmt == "ply_ascii":
        return m.export(file_type="ply", encoding="ascii")
    if fmt == "ply":
        return m.export(file_type="ply")
    if fmt == "stl":
        return m.export(file_type="stl")
    if fmt == "stl_ascii":
        return m.export(file_type="stl_ascii")
    if fmt == "off":
        return m.export(file_type="off")
    raise ValueError(fmt)


MESH_FORMATS = {"obj": ".obj", "ply_ascii": ".ply", "ply": ".ply", "stl": ".stl", "stl_ascii": ".stl", "off": ".off"}


@pytest.mark.parametrize("fmt", list(MESH_FORMATS))
def test_mesh_files_truncated_or_garbled(fmt, small_mesh, tmp_path, capsys):
    """`mesh check` on random truncations and garbage: a legal leftover loads, anything else is
    exit 2 naming the file; never an internal error."""
    rng = _rng(f"mesh-{fmt}")
    data = _mesh_bytes(*small_mesh, fmt)
    assert _cli(capsys, ["mesh", "check", _write(tmp_path / f"ok{MESH_FORMATS[fmt]}", data)], needle="", ok_codes=(0,)) == 0
    for i, bad in enumerate(_truncations(data, rng, N) + _garbage(data, rng, N)):
        p = _write(tmp_path / f"m{i}{MESH_FORMATS[fmt]}", bad)
        _cli(capsys, ["mesh", "check", p], needle=p.name, ok_codes=(0, 2), what=f"{fmt} mutation {i}")


def _write(path: Path, data: bytes | str) -> Path:
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


def test_mesh_values_that_must_be_refused(small_mesh, tmp_path, capsys):
    V, F = small_mesh
    rng = _rng("mesh-values")
    obj = _mesh_bytes(V, F, "obj").decode()
    cases = {
        "nan.obj": obj.replace("v 0.05 0.0 0.0", "v nan 0.0 0.0"),
        "inf.obj": obj.replace("v 0.05 0.0 0.0", "v inf 0.0 0.0"),
        "index.obj": obj + f"f 1 2 {rng.randint(7, 10**9)}\n",
        "zero.obj": obj + "f 0 1 2\n",
        "text.obj": obj.replace("v 0.05 0.0 0.0", "v a b c"),
        "nofaces.obj": "".join(ln + "\n" for ln in obj.splitlines() if ln.startswith("v")),
        "empty.stl": "",
    }
    ply = _mesh_bytes(V, F, "ply_ascii").decode()
    cases["more_vertices.ply"] = ply.replace("element vertex 6", f"element vertex {6 + rng.randint(1, 1000)}")
    cases["more_faces.ply"] = ply.replace("element face 8", f"element face {8 + rng.randint(1, 1000)}")
    for name, text in cases.items():
        p = _write(tmp_path / name, text)
        _cli(capsys, ["mesh", "check", p], needle=name)


@pytest.mark.slow
def test_stl_of_the_demo_scan_adapts(tmp_path, capsys):
    """A binary STL with three copies of every vertex (trimesh's export of the demo scan) adapts."""
    import trimesh

    s = fw.synthetic_scan(_rng("scan").randrange(100))
    scan = tmp_path / "scan.stl"
    scan.write_bytes(trimesh.Trimesh(s.vertices * 1e3, s.faces, process=False).export(file_type="stl"))
    lm = tmp_path / "lm.json"
    fw.save_landmarks_json(lm, s.landmarks, units=s.units)
    out = tmp_path / "a"
    code = main(["--json", "adapt", str(scan), "--landmarks", str(lm), "--units", "mm", "--levels", "1",
                 "--out", str(out)])
    _, err = capsys.readouterr()
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert rep["distance_to_scan_m"]["median"] < 1e-3


# ----------------------------------------------------------------------------- landmarks
def test_landmark_files(tmp_path, capsys):
    rng = _rng("landmarks")
    good = {"3.7": [0.03, 0.0, 0.08], "3.12": [-0.03, 0.0, 0.08], "9.3": [0.0, -0.03, 0.1]}
    text = json.dumps(good)
    cases = {f"trunc{i}.json": t.decode() for i, t in enumerate(_truncations(text.encode(), rng, N)) if t}
    cases.update({
        "nan.json": text.replace("0.03", "NaN", 1),
        "shape.json": json.dumps({"3.7": [0.0, 1.0]}),
        "type.json": json.dumps({"3.7": "here"}),
        "list.json": json.dumps([1, 2, 3]),
        "unknown.json": json.dumps({"99.99": [0, 0, 0]}),
        "huge.json": json.dumps({"3.7": [1e308 * 10, 0, 0]}).replace("Infinity", "1e999"),
    })
    for name, t in cases.items():
        p = _write(tmp_path / name, t)
        _cli(capsys, ["landmarks", "check", p], needle=name, ok_codes=(0, 2))
    for name in ("nan.json", "shape.json", "type.json", "list.json", "unknown.json", "huge.json"):
        _cli(capsys, ["landmarks", "check", tmp_path / name], needle=name)


# ----------------------------------------------------------------------------- heads and face rigs
@pytest.fixture(scope="module")
def built(tmp_path_factory, default_build_dir):
    return fresh_build(tmp_path_factory, default_build_dir)


@pytest.fixture(scope="module")
def template_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("fuzz") / "template"
    assert main(["--json", "template", "export", "--out", str(out), "--no-preview"]) == 0
    return out


def _copy_build(built: Path, to: Path) -> Path:
    to.mkdir()
    for f in built.iterdir():
        (to / f.name).write_bytes(f.read_bytes())
    return to


def test_face_rig_truncated_or_garbled(built, tmp_path, capsys):
    rng = _rng("face_rig")
    data = (built / "face_rig.npz").read_bytes()
    out = tmp_path / "o"
    for i, bad in enumerate(_truncations(data, rng, N) + _garbage(data, rng, 2)):
        p = _write(tmp_path / f"rig{i}.npz", bad)
        _cli(capsys, ["simulate", p, "--expression", "smile", "--jaw", "kinematic", "--seconds", "0.05",
                      "--out", out], needle=p.name, out=out, ok_codes=(0, 2), what=f"face rig mutation {i}")
        if out.exists():  # a garbled byte the zip's checksum did not cover: legal, and it ran
            shutil.rmtree(out)


def _rig_arrays(built: Path) -> dict:
    with np.load(built / "face_rig.npz") as z:
        return {k: z[k] for k in z.files}


def test_face_rig_corrupt_arrays(built, tmp_path, capsys):
    rng = _rng("face_rig_arrays")
    base = _rig_arrays(built)
    p_nodes = len(base["nodes"])
    corruptions = {
        "nodes_nan": lambda z: z["nodes"].__setitem__((rng.randrange(p_nodes), rng.randrange(3)), np.nan),
        "nodes_shape": lambda z: z.__setitem__("nodes", z["nodes"][:, :2]),
        "tets_range": lambda z: z["tets"].__setitem__((rng.randrange(len(z["tets"])), rng.randrange(4)),
                                                       p_nodes + rng.randint(0, 10**6)),
        "tets_negative": lambda z: z["tets"].__setitem__((0, 0), -rng.randint(1, 100)),
        "faces_range": lambda z: z["head_faces"].__setitem__((0, 1), 10**7),
        "fixed_short": lambda z: z.__setitem__("fixed", z["fixed"][:-1]),
        "att_node": lambda z: z["rig_att_node"].__setitem__(0, p_nodes + 5),
        "fdp_face": lambda z: z["fdp_face"].__setitem__(0, 10**6),
        "missing": lambda z: z.pop("tets"),
        "strings": lambda z: z.__setitem__("jaw_pivot", np.array(["a", "b", "c"])),
    }
    out = tmp_path / "o"
    for name, corrupt in corruptions.items():
        z = {k: v.copy() for k, v in base.items()}
        corrupt(z)
        p = tmp_path / f"{name}.npz"
        np.savez(p, **z)
        _cli(capsys, ["simulate", p, "--expression", "smile", "--jaw", "kinematic", "--out", out],
             needle=p.name, out=out)


def test_template_npz_truncated(template_dir, tmp_path, capsys):
    rng = _rng("template")
    data = (template_dir / "template.npz").read_bytes()
    out = tmp_path / "o"
    for i, bad in enumerate(_truncations(data, rng, 3)):
        t = tmp_path / f"t{i}"
        shutil.copytree(template_dir, t)
        (t / "template.npz").write_bytes(bad)
        _cli(capsys, ["build", t, "--out", out], needle="template.npz", out=out)


def test_head_xml_broken(built, tmp_path, capsys):
    rng = _rng("head.xml")
    data = (built / "head.xml").read_bytes()
    out = tmp_path / "o"
    bads = [data[:rng.randrange(1, len(data) // 2)], b"<mujoco><worldbody><body name='x'>", b"\x00\xff garbage",
            data.replace(b"<worldbody>", b"<worldbody><geom type='nonsense'/>", 1)]
    for i, bad in enumerate(bads):
        b = _copy_build(built, tmp_path / f"b{i}")
        (b / "head.xml").write_bytes(bad)
        _cli(capsys, ["simulate", b, "--expression", "smile", "--seconds", "0.05", "--out", out],
             needle="head.xml", out=out)


# ----------------------------------------------------------------------------- sequence files
def _sequence_mutations(rng: random.Random) -> dict[str, object]:
    seg = {"expression": "smile", "start": 0.0, "attack": 0.3, "hold": 1.0, "release": 0.3, "weight": 1.0}
    key = "".join(rng.choice("abcdefghij") for _ in range(6))
    return {
        "unknown_key": {"segments": [{**seg, key: 1}]},
        "unknown_expr_key": {"segments": [{"expression": {"muscles": {"zygomatic_major": 0.5}, key: 2}}]},
        "unknown_preset": {"segments": [{**seg, "expression": "grin"}]},
        "unknown_muscle": {"segments": [{"expression": {"muscles": {key: 0.5}}}]},
        "nan_time": {"segments": [{**seg, "start": float("nan")}]},
        "negative_time": {"segments": [{**seg, "hold": -rng.random()}]},
        "string_time": {"segments": [{**seg, "attack": "soon"}]},
        "activation_range": {"segments": [{"expression": {"muscles": {"zygomatic_major": 1 + rng.random()}}}]},
        "jaw_range": {"segments": [{"expression": {"muscles": {}, "jaw_deg": 61 + rng.random() * 100}}]},
        "blend_type": {"segments": [{"expression": {"blend": [1, 2]}}]},
        "no_segments": {"segments": []},
        "not_object": [seg],
        "segment_list": {"segments": [[1, 2]]},
    }


def test_sequence_files_api(tmp_path):
    """load_sequence: each bad file is an InputError naming the file (and the segment)."""
    for name, spec in _sequence_mutations(_rng("sequence")).items():
        p = _write(tmp_path / f"{name}.json", json.dumps(spec))
        with pytest.raises(fw.InputError) as e:
            fw.load_sequence(p)
        assert str(p) in str(e.value) and "\n" not in str(e.value), _why(f"{name}: {e.value}")
        if name not in ("no_segments", "not_object"):
            assert "segment 0" in str(e.value), _why(f"{name}: {e.value}")
    data = json.dumps(_sequence_mutations(_rng("sequence"))["unknown_key"]).encode()
    for i, bad in enumerate(_truncations(data, _rng("sequence-trunc"), N)):
        p = _write(tmp_path / f"trunc{i}.json", bad)
        with pytest.raises(fw.InputError, match="trunc"):
            fw.load_sequence(p)


def test_sequence_files_cli(built, tmp_path, capsys):
    out = tmp_path / "o"
    for name in ("unknown_key", "unknown_preset", "nan_time"):
        spec = _sequence_mutations(_rng("sequence"))[name]
        p = _write(tmp_path / f"{name}.json", json.dumps(spec))
        _cli(capsys, ["simulate", built, "--expression", p, "--out", out], needle=f"{name}.json: segment 0", out=out)


# ----------------------------------------------------------------------------- sizes
HUGE = ["1e9", "99999999", "1000000", str(2**63), "inf", "nan", "-1", "0", "1.5", "x"]


SIZES = [
    ("build", ["build", "default", "--out", "{o}"], "--layers"),
    ("simulate", ["simulate", "H", "--expression", "smile", "--out", "{o}"], "--substeps"),
    ("simulate", ["simulate", "H", "--expression", "smile", "--out", "{o}"], "--seconds"),
    ("simulate", ["simulate", "H", "--expression", "smile", "--out", "{o}"], "--fps"),
    ("adapt", ["adapt", "S", "--out", "{o}"], "--levels"),
    ("demo", ["demo", "--out", "{o}"], "--seconds"),
    ("demo", ["demo", "--out", "{o}"], "--seed"),
    ("morph", ["morph", "A", "B", "--out", "{o}.usda"], "--steps"),
    ("retarget", ["retarget", "smile", "H", "--out", "{o}"], "--seconds"),
    ("template info", ["template", "info"], "--level"),
]


@pytest.mark.parametrize("command, argv, flag", SIZES, ids=[f"{c} {f}" for c, _, f in SIZES])
def test_size_arguments_are_bounded(command, argv, flag, tmp_path, capsys):
    """Huge, non-finite, negative and malformed sizes are refused while parsing (before any
    file is looked at: the paths here do not exist); 1e9 is out of every size's range."""
    from facewarp.cli import build_parser

    p = build_parser()
    for word in command.split():
        p = next(a for a in p._actions if hasattr(a, "choices") and isinstance(a.choices, dict)).choices[word]
    action = next(a for a in p._actions if flag in a.option_strings)
    with pytest.raises(Exception):
        action.type("1e9")
    rng = _rng(f"size {command} {flag}")
    out = tmp_path / "o"
    for v in rng.sample(HUGE, 5) + ["1e9"]:
        try:
            action.type(v)
            continue  # a legal value of this flag (e.g. --seed 1000000)
        except Exception:
            pass
        args = [a.replace("{o}", str(out)) for a in argv] + [flag, v]
        _cli(capsys, args, needle=flag, out=out, what=f"{command} {flag} {v}")


def test_memory_estimate_refuses(built, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("FACEWARP_MEMORY_LIMIT", "1M")
    out = tmp_path / "o"
    _cli(capsys, ["build", "default", "--out", out, "--layers", "16"], needle="needs about", out=out)
    _cli(capsys, ["simulate", built, "--expression", "smile", "--seconds", "600", "--out", out], needle="needs about",
         out=out)
    _cli(capsys, ["demo", "--out", out, "--seconds", "3000"], needle="needs about", out=out)
    usd = tmp_path / "o.usdc"
    _cli(capsys, ["simulate", built, "--expression", "smile", "--seconds", "3000", "--fps", "100", "--substeps", "100",
                  "--out", usd], needle="solver steps", out=usd)


# ----------------------------------------------------------------------------- the Python API
@pytest.fixture(scope="module")
def sim(built):
    return fw.FaceSimulator(fw.load_face_rig(built))


def _junk(rng: random.Random, m: int) -> list:
    return [None, "a", ["a"] * m, [0.1] * (m + 1), np.full(m, np.nan), np.zeros((m, 2)), {"a": 1}, object(), b"x",
            np.array([0.1, 0.2]), float("nan"), float("inf"), -1.0, 10**9, True, [[0.1]], rng.uniform(1e4, 1e6),
            np.array(["x"] * m)]


def test_simulator_methods_refuse_junk(sim):
    rng = _rng("api")
    m = len(sim.muscle_names)
    calls = {
        "activations": lambda v: sim.set_activations(v),
        "jaw opening": lambda v: sim.set_jaw(v),
        "jaw side": lambda v: sim.set_jaw(0.0, v),
        "dt": lambda v: sim.step(v),
        "frames": lambda v: sim.advance(v),
        "X": lambda v: sim.surface(v),
        "fdp_id": lambda v: sim.fdp(v),
        "samples": lambda v: sim.muscle_curves(v),
        "R": lambda v: sim.set_head_pose(v, np.zeros(3)),
        "t": lambda v: sim.set_head_pose(np.eye(3), v),
        "timeline": lambda v: sim.run(v, 0.1),
        "seconds": lambda v: sim.run(fw.timeline_for("smile"), v),
    }
    for name, call in calls.items():
        for v in _junk(rng, m):
            if v is None and name in ("dt", "X"):
                continue  # None: one frame / the current state
            try:
                call(v)
            except fw.InputError as e:
                assert "\n" not in str(e), _why(f"{name}={v!r}: {e}")
                assert name in str(e) or name.split()[0] in str(e), _why(f"{name}={type(v).__name__}: {e}")
            except Exception as e:  # anything else is the bug this suite looks for
                pytest.fail(_why(f"{name}={v!r}: {type(e).__name__}: {e}"))
            else:
                if name == "frames" and isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 3:
                    continue
                if name == "seconds" or name == "frames" or name == "samples":
                    # a legal size (a random small number): the call ran
                    if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0:
                        continue
                pytest.fail(_why(f"{name}={v!r} was accepted"))
    sim.reset()


def test_simulator_constructor_refuses_junk(built):
    rig = fw.load_face_rig(built)
    for kwargs, needle in [({"device": "tpu"}, "device"), ({"device": 3}, "device"), ({"device": "cuda:99"}, "device"),
                           ({"substeps": 99999999}, "substeps"), ({"substeps": 2.5}, "substeps"),
                           ({"fps": float("nan")}, "fps"), ({"fps": 1e9}, "fps"), ({"dt": -1.0}, "dt"),
                           ({"solver": "euler"}, "solver"), ({"contact": "yes"}, "contact"),
                           ({"solver_options": [1]}, "solver_options"), ({"iterations": 0}, "iterations")]:
        with pytest.raises(fw.InputError, match=needle):
            fw.FaceSimulator(rig, **kwargs)
    with pytest.raises(fw.InputError, match="fr"):
        fw.FaceSimulator("face_rig.npz")


def test_step_advances_exactly_dt(sim):
    sim.reset()
    sim.step(2 * sim.dt)
    assert sim.time == pytest.approx(2 * sim.dt, rel=1e-12)
    for dt in (1e-12, 0.001, 1.5 * sim.dt):
        with pytest.raises(fw.InputError, match="whole number of the solver's steps"):
            sim.step(dt)
    assert sim.time == pytest.approx(2 * sim.dt, rel=1e-12)
    sim.reset()


def test_mesh_and_obj_refuse_bad_arrays(tmp_path):
    rng = _rng("Mesh")
    V = np.zeros((4, 3))
    F = np.array([[0, 1, 2], [0, 2, 3]])
    bad_V = V.copy()
    bad_V[rng.randrange(4), rng.randrange(3)] = rng.choice([np.nan, np.inf, -np.inf])
    for kwargs, needle in [({"vertices": bad_V, "faces": F}, "vertices"),
                           ({"vertices": V, "faces": F + rng.randint(2, 100)}, "faces"),
                           ({"vertices": V, "faces": -F - 1}, "faces"),
                           ({"vertices": V[:, :2], "faces": F}, "vertices"),
                           ({"vertices": V, "faces": F.astype(float) + 0.5}, "faces"),
                           ({"vertices": [["a"] * 3] * 4, "faces": F}, "vertices")]:
        with pytest.raises(fw.InputError, match=needle):
            fw.Mesh(**kwargs)
    for V_, F_ in [(bad_V, F), (V, F + 10)]:
        with pytest.raises(fw.InputError):
            fw.save_obj(tmp_path / "x.obj", V_, F_)
    assert not (tmp_path / "x.obj").exists() and list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- real processes
def _process(*argv, cwd=None):
    env = {k: v for k, v in os.environ.items() if k != "FACEWARP_VERBOSE"}
    return subprocess.run([sys.executable, "-m", "facewarp", *map(str, argv)], capture_output=True, text=True,
                          env=env, cwd=cwd)


def test_processes_one_line_no_traceback(built, small_mesh, tmp_path):
    """A few cases through a real process: stderr exactly one line, exit 2, nothing written."""
    rng = _rng("process")
    stl = _mesh_bytes(*small_mesh, "stl")
    corrupt = _write(tmp_path / "corrupt.stl", stl[:84] + bytes(rng.randrange(256) for _ in range(200)))
    rig = _write(tmp_path / "rig.npz", (built / "face_rig.npz").read_bytes()[:rng.randrange(10, 2000)])
    out = tmp_path / "o"
    for argv, needle in [(["mesh", "check", corrupt], "corrupt.stl"),
                         (["adapt", corrupt, "--out", out], "corrupt.stl"),
                         (["simulate", rig, "--expression", "smile", "--out", out], "rig.npz"),
                         (["build", "default", "--out", out, "--layers", "1000000"], "--layers")]:
        r = _process(*argv)
        label = _why(f"{argv}: {r.returncode} {r.stderr!r}")
        assert r.returncode == 2 and "Traceback" not in r.stderr, label
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and needle in lines[0] and "charset_normalizer" not in lines[0], label
        assert not out.exists() and _leftovers(tmp_path) == [], label


def test_api_sizes_are_bounded(built):
    """The API's size arguments have the CLI's bounds."""
    head = fw.default_template(0)
    for layers in (0, 17, 10**6, 2.0, True):
        with pytest.raises(fw.InputError, match="layers"):
            fw.build_anatomy(head, layers=layers)
    for levels in (-1, 13, 10**6, 1.5):
        with pytest.raises(fw.InputError, match="levels"):
            fw.AdaptOptions(levels=levels).checked()
    rig = fw.load_face_rig(built)
    for kwargs in ({"substeps": 10**8}, {"fps": 1e6}):
        with pytest.raises(fw.InputError, match=next(iter(kwargs))):
            fw.FaceSimulator(rig, **kwargs)


# ----------------------------------------------------------------------------- found by hand since
def test_runs_without_a_frame_after_the_rest_pose(built, tmp_path, capsys):
    """seconds x fps <= 0.5: no frame after the rest pose; refused (the rest pose alone was written and
    reported as the expression)."""
    out = tmp_path / "o"
    _cli(capsys, ["simulate", built, "--expression", "smile", "--fps", "0.001", "--out", out],
         needle="no frame after the rest pose", out=out)
    _cli(capsys, ["simulate", built, "--expression", "smile", "--seconds", "0.01", "--out", out],
         needle="0.01 s at 30 fps", out=out)
    _cli(capsys, ["retarget", "smile", built, "--fps", "0.001", "--out", out],
         needle="no frame after the rest pose", out=out)


def test_marker_beyond_any_capture_volume(built, tmp_path, capsys):
    """A single marker at 1e30 mm passed the per-frame span check (one marker spans nothing) and the
    drive reported a 1e30 mm miss with exit 0; a point beyond 1 km is a unit or export error."""
    rng = np.random.default_rng(_rng("far-marker").randrange(2**32))
    far = float(10.0 ** rng.uniform(6.5, 30))  # [mm]: beyond 1,000 m
    p = _write(tmp_path / "far.json", json.dumps({"fps": 30, "units": "mm",
                                                  "markers": {"2.1": [[far, 0.0, 0.0], None]}}))
    out = tmp_path / "o"
    _cli(capsys, ["drive", built, "--markers", p, "--out", out], needle="far.json", out=out)
    with pytest.raises(fw.InputError, match="'2.1' in frame 1 .* from the origin"):
        fw.MarkerTrack(30.0, ["2.1"], np.array([[[0.0, 0.0, 0.0]], [[0.0, far * 1e-3, 0.0]]]))
    track = fw.MarkerTrack(30.0, ["2.1"], np.array([[[999.0, 0.0, 0.0]], [[np.nan] * 3]]))  # a big hall: fine
    assert track.frames == 2
