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


def _private(module: str):
    """A module of the private package (unit tests may test a part directly), by a name spelled so that
    the public-names contract test does not take it for a public use."""
    import importlib

    return importlib.import_module("facewarp." + "_src." + module)


def _why(what: str) -> str:
    return f"{what} [FACEWARP_FUZZ_SEED={SEED}]"


def _rng(salt: str) -> random.Random:
    return random.Random(f"{SEED}:{salt}")


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".facewarp-" in p.name)


def _cli(capsys, argv, *, needle: str, out: Path | None = None, ok_codes=(2,), what: str = ""):
    """Run ``facewarp argv`` in-process; the promised failure (or an allowed success)."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = main([str(a) for a in argv])
    stdout, err = capsys.readouterr()
    label = _why(f"{what or ' '.join(map(str, argv))}: exit {code}, stderr {err!r}")
    assert code in ok_codes, label
    # no library's warning reaches the user (those Python shows by default: not the deprecations)
    shown = [f"{w.category.__name__}: {w.message}" for w in caught
             if not issubclass(w.category, (DeprecationWarning, PendingDeprecationWarning, ImportWarning,
                                            ResourceWarning))]
    assert not shown and "Warning" not in err and "LAPACK" not in err, _why(f"{label}: {shown}")
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
    fw.geometry.save_landmarks_json(lm, s.landmarks, units=s.units)
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
            fw.expressions.load_sequence(p)
        assert str(p) in str(e.value) and "\n" not in str(e.value), _why(f"{name}: {e.value}")
        if name not in ("no_segments", "not_object"):
            assert "segment 0" in str(e.value), _why(f"{name}: {e.value}")
    data = json.dumps(_sequence_mutations(_rng("sequence"))["unknown_key"]).encode()
    for i, bad in enumerate(_truncations(data, _rng("sequence-trunc"), N)):
        p = _write(tmp_path / f"trunc{i}.json", bad)
        with pytest.raises(fw.InputError, match="trunc"):
            fw.expressions.load_sequence(p)


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
            fw.geometry.save_obj(tmp_path / "x.obj", V_, F_)
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


# ----------------------------------------------------------------------------- the newer commands (issue 40)
def _octahedron_obj(path: Path) -> Path:
    """A tiny scan file: the batch's refusals come before any adapt, so its shape does not matter."""
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float) * 0.09
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return _write(path, _mesh_bytes(V, F, "obj"))


def _newer_command_cases(rng: random.Random, built: Path, tmp: Path) -> list[tuple[str, list, str]]:
    """(label, argv with "{o}" for the output, a word the error line must contain): a harsh user's bad
    and extreme inputs to batch simulate, batch run, morph and retarget. Every one must be refused up
    front (exit 2, one line naming the input, nothing written)."""
    scan = _octahedron_obj(tmp / "scan.obj")
    seq = _write(tmp / "seq.json", json.dumps({"segments": [{"expression": "smile", "start": 0, "attack": 0.1,
                                                              "hold": 0.1, "release": 0.1}]}))
    garbage = _write(tmp / "garbage.json", bytes(rng.randrange(256) for _ in range(rng.randint(1, 300))))
    no_xml = tmp / "no_xml"
    no_xml.mkdir()
    (no_xml / "face_rig.npz").write_bytes((built / "face_rig.npz").read_bytes())
    per_head = _write(tmp / "per_head.json", json.dumps({"heads": ["smile", "laugh", "smile"]}))
    po = tmp / "po"  # an earlier output folder whose report.json is given as the per-head file
    po.mkdir()
    _write(po / "report.json", json.dumps({"heads": ["smile"]}))
    a_file = _write(tmp / "a_file", "x")
    big = str(rng.choice([3600, 3000, 2000]))
    tiny = f"{rng.uniform(1e-9, 0.015):.6g}"  # below half a frame at 30 fps
    bs = ["batch", "simulate", built]
    br = ["batch", "run", scan]
    cases = [
        # batch simulate
        ("bs no frame", bs + ["--seconds", tiny, "--out", "{o}"], "no frame after the rest pose"),
        ("bs fps 1e-300", bs + ["--fps", "1e-300", "--out", "{o}"], "1e-300 fps has no frame"),
        ("bs tiny fps", bs + ["--fps", f"{rng.uniform(1e-6, 0.2):.3g}", "--seconds", "1", "--out", "{o}"],
         "no frame after the rest pose"),
        ("bs stage collides", bs + [built, "--stage", rng.choice(["head_00.usdc", "head_01.usdc", "HEAD_00.usdc"]),
                                    "--out", "{o}"], "stage"),
        ("bs stage path", bs + ["--stage", rng.choice(["../x.usda", "/tmp/x.usda", "sub/x.usdc"]), "--out", "{o}"],
         "stage"),
        ("bs stage suffix", bs + ["--stage", rng.choice(["x.obj", "x", "x.usdz", "report.json"]), "--out", "{o}"],
         "stage"),
        ("bs an hour at 1000 fps", bs + [built, "--seconds", big, "--fps", "1000", "--out", "{o}"], "seconds, fps"),
        ("bs out is a build", bs + ["--out", built], "input BUILD_DIR"),
        ("bs out in a build", bs + ["--out", built / "sub"], "input BUILD_DIR"),
        ("bs per-head is an output", bs + ["--per-head", po / "report.json", "--out", po], "per_head"),
        ("bs per-head count", bs + ["--per-head", per_head, "--out", "{o}"], "per_head.json"),
        ("bs per-head garbage", bs + ["--per-head", garbage, "--out", "{o}"], "garbage.json"),
        ("bs expression", bs + ["--expression", rng.choice(["bogus", "smiles", "sequence2"]), "--out", "{o}"],
         "expression"),
        ("bs no head.xml", ["batch", "simulate", no_xml, "--jaw", "mujoco", "--out", "{o}"], "head.xml"),
        ("bs missing build", ["batch", "simulate", tmp / "nowhere", "--out", "{o}"], "nowhere"),
        ("bs build is a file", ["batch", "simulate", a_file, "--out", "{o}"], "a_file"),
        ("bs empty out", bs + ["--out", ""], "out"),
        ("bs out is a file", bs + ["--out", a_file], "a_file"),
        # batch run (refused before its first adapt)
        ("br no frame", br + ["--seconds", tiny, "--out", "{o}"], "no frame after the rest pose"),
        ("br expression", br + ["--expression", "bogus", "--out", "{o}"], "bogus"),
        ("br rig muscles", br + ["--steps", "adapt,build,rig", "--rig-muscles",
                                 rng.choice(["bogus", "zygomatic_major_X", "zygomatic_major_L,nose"]), "--out", "{o}"],
         "muscles"),
        ("br too many frames", br + ["--seconds", "3600", "--out", "{o}"], "frames"),
        ("br sequence file garbage", br + ["--expression", garbage, "--out", "{o}"], "garbage.json"),
        ("br levels", br + ["--levels", rng.choice(["0", "13", "-1", "2.5"]), "--out", "{o}"], "--levels"),
        ("br workers", br + ["--workers", rng.choice(["0", "1025", "x"]), "--out", "{o}"], "--workers"),
        ("br units", br + ["--units", rng.choice(["furlong", "M", "inch"]), "--out", "{o}"], "--units"),
        ("br empty ray", br + ["--ray", "", "--out", "{o}"], "ray"),
        ("br out is a file", br + ["--out", a_file], "a_file"),
        ("br empty out", br + ["--out", ""], "out"),
        ("br rig needs a build", br + ["--steps", "rig", "--out", "{o}"], "needs build"),
        ("br gpus", br + ["--gpus-per-task", rng.choice(["-1", "nan", "65"]), "--out", "{o}"], "--gpus-per-task"),
        # morph
        ("morph steps", ["morph", "default", "default", "--steps", rng.choice(["0", "1001", "-3"]), "--out", "{o}.usda"],
         "--steps"),
        ("morph fps", ["morph", "default", "default", "--fps", rng.choice(["nan", "0", "1e9"]), "--out", "{o}.usda"],
         "--fps"),
        ("morph suffix", ["morph", "default", "default", "--out", "{o}.obj"], "out"),
        ("morph missing head", ["morph", tmp / "nowhere", "default", "--out", "{o}.usda"], "nowhere"),
        ("morph build is out", ["morph", "default", "default", "--out", "{o}/m.usda", "--build", "{o}"], "build"),
        # retarget
        ("retarget no frame", ["retarget", "smile", built, "--seconds", tiny, "--out", "{o}"],
         "no frame after the rest pose"),
        ("retarget an hour at 1000 fps", ["retarget", seq, built, "--seconds", big, "--fps", "1000", "--out", "{o}"],
         "seconds, fps"),
        ("retarget out is a head", ["retarget", "smile", built, "--out", built], "input HEAD"),
        ("retarget sequence is an output", ["retarget", "{o}/report.json", built, "--out", "{o}"], "report.json"),
        ("retarget garbage sequence", ["retarget", garbage, built, "--out", "{o}"], "garbage.json"),
        ("retarget missing head", ["retarget", "smile", tmp / "nowhere", "--out", "{o}"], "nowhere"),
    ]
    return cases


def test_newer_commands_refuse_bad_inputs_up_front(built, tmp_path, capsys):
    """Generated bad and extreme inputs of batch simulate, batch run, morph and retarget: each one
    exit 2, one line naming the input, no traceback, nothing written (not even a lock or a manifest)."""
    rng = _rng("newer commands")
    inputs = tmp_path / "in"
    inputs.mkdir()
    cases = _newer_command_cases(rng, built, inputs)
    for i, (label, argv, needle) in enumerate(cases):
        work = tmp_path / f"w{i}"
        work.mkdir()
        out = work / "o"
        args = [str(a).replace("{o}", str(out)) for a in argv]
        before = sorted(p.name for p in built.iterdir())
        _cli(capsys, args, needle=needle, what=label)
        assert list(work.iterdir()) == [], _why(f"{label}: wrote {sorted(p.name for p in work.iterdir())}")
        assert sorted(p.name for p in built.iterdir()) == before, _why(f"{label}: changed the build")
        assert _leftovers(built.parent) == [] and _leftovers(inputs) == [], _why(label)


def test_batch_run_api_refuses_junk(tmp_path):
    """run_batch's options of every step are checked before anything is written."""
    run_batch = _private("fleet.batch").run_batch
    ScanInput = _private("fleet.manifest").ScanInput

    scan = ScanInput(_octahedron_obj(tmp_path / "s.obj"))
    out = tmp_path / "o"
    for kwargs, needle in [({"steps": "bake"}, "steps"), ({"steps": []}, "steps"), ({"levels": 0}, "levels"),
                           ({"levels": 2.5}, "levels"), ({"seconds": float("nan")}, "seconds"),
                           ({"seconds": 0.001}, "no frame"), ({"fps": 1e-300}, "no frame"), ({"fps": 1e9}, "fps"),
                           ({"jaw": "bones"}, "jaw"), ({"expression": 3}, "expression"),
                           ({"rig_muscles": ["nose"]}, "rig_muscles"), ({"rig_formats": "fbx"}, "rig_formats"),
                           ({"device": "tpu"}, "device"), ({"workers": 0}, "workers"), ({"max_retries": -1}, "max_retries"),
                           ({"gpus_per_task": float("inf")}, "gpus_per_task"), ({"simulate_batch": 0}, "simulate_batch"),
                           ({"ray": 5}, "ray")]:
        with pytest.raises(fw.InputError, match=needle):
            run_batch([scan], out, **kwargs)
        assert not out.exists() and _leftovers(tmp_path) == [], kwargs
    for scans, needle in [("s.obj", "scans"), ([], "no scans"), (["s.obj"], "ScanInput")]:
        with pytest.raises(fw.InputError, match=needle):
            run_batch(scans, out)
    with pytest.raises(fw.InputError, match="out"):
        run_batch([scan], "")
    _expand_muscles = _private("fleet.batch")._expand_muscles

    assert _expand_muscles(["zygomatic_major", "zygomatic_major_L"]) == ["zygomatic_major_L", "zygomatic_major_R"]


@pytest.fixture(scope="module")
def rig0(built):
    return fw.load_face_rig(built)


def test_face_batch_refuses_junk_and_what_memory_cannot_hold(rig0, monkeypatch):
    """FaceBatch: junk arguments are InputErrors naming them; a count the memory cannot hold is
    refused before any head is made (about 18.8 MB a level-0 head), with the estimate."""
    rng = _rng("FaceBatch")
    junk = [None, "a", 0, -1, 1.5, float("nan"), float("inf"), 10**9, True, [], ["x"], object(), np.zeros((2, 2)),
            {"a": 1}, b"x"]
    for name, make in [("rigs", lambda v: fw.FaceBatch(v)), ("count", lambda v: fw.FaceBatch(rig0, count=v)),
                       ("fps", lambda v: fw.FaceBatch(rig0, fps=v)), ("device", lambda v: fw.FaceBatch(rig0, device=v)),
                       ("placements", lambda v: fw.FaceBatch(rig0, placements=v)),
                       ("streams", lambda v: fw.FaceBatch(rig0, streams=v)),
                       ("backend", lambda v: fw.FaceBatch(rig0, backend=v))]:
        for v in rng.sample(junk, 8):
            if v is None and name in ("count", "placements"):
                continue  # the defaults
            try:
                make(v)
            except fw.InputError as e:
                assert name in str(e) and "\n" not in str(e), _why(f"{name}={v!r}: {e}")
            except Exception as e:
                pytest.fail(_why(f"{name}={v!r}: {type(e).__name__}: {e}"))
            else:
                if not (name == "fps" and v == 1.5):
                    pytest.fail(_why(f"{name}={v!r} was accepted"))
    with pytest.raises(fw.InputError, match=r"count: 100000 heads: needs about .* TB of memory"):
        fw.FaceBatch(rig0, count=100000)
    monkeypatch.setenv("FACEWARP_MEMORY_LIMIT", "100M")
    with pytest.raises(fw.InputError, match="count: 20 heads: needs about"):
        fw.FaceBatch(rig0, count=20)
    with pytest.raises(fw.InputError, match="rigs: 20 heads"):
        fw.FaceBatch([rig0] * 20)
    monkeypatch.delenv("FACEWARP_MEMORY_LIMIT")
    batch = fw.FaceBatch(rig0, count=2)
    for call, needle in [(lambda v: batch.set_head_pose(v, np.zeros(3)), "head pose"),
                         (lambda v: batch.set_head_pose(np.eye(3), v), "head pose"),
                         (lambda v: batch.set_activations(v), "activations"), (lambda v: batch.set_jaw(v), "angles")]:
        for v in ["a", ["x"], object(), {"a": 1}, b"x", np.full((2, 27), np.nan), np.zeros((3, 3, 3))]:
            try:
                call(v)
            except fw.InputError as e:
                assert "\n" not in str(e), _why(f"{needle}={v!r}: {e}")
            except Exception as e:
                pytest.fail(_why(f"{needle}={v!r:.40}: {type(e).__name__}: {e}"))
            else:
                pytest.fail(_why(f"{needle}={v!r:.40} was accepted"))


def test_play_and_mujoco_skin_refuse_junk(sim):
    """play and MujocoSkin: wrong types are InputErrors naming the argument; a length the machine
    cannot do (frames, memory, time) is refused with the estimate."""
    tl = fw.timeline_for("smile")
    for args, kwargs, needle in [
        (("sim", tl, 1.0), {}, "sim"), ((sim, "smile", 1.0), {}, "timeline"), ((sim, tl, 1.0), {"jaw": "mujoco"}, "jaw"),
        ((sim, tl, 1.0), {"jaw": 3}, "jaw"), ((sim, tl, 1.0), {"progress": 5}, "progress"),
        ((sim, tl, 1.0), {"sinks": "x"}, "sinks"), ((sim, tl, 1.0), {"sinks": [3]}, "sinks"),
        ((sim, tl, 1e9), {}, "seconds"), ((sim, tl, float("nan")), {}, "seconds"), ((sim, tl, -1.0), {}, "seconds"),
        ((sim, tl, 1e5), {}, "seconds"), ((sim, tl, 5e4), {"sinks": [fw.FrameRecorder()]}, "seconds"),
    ]:
        with pytest.raises(fw.InputError, match=needle) as e:
            fw.play(*args, **kwargs)
        assert "\n" not in str(e.value)
    with pytest.raises(fw.InputError, match="days"):
        fw.play(sim, tl, 1e9)
    with pytest.raises(fw.InputError, match="jaw: the jaw driver drives another simulator"):
        fw.play(sim, tl, 0.1, jaw=fw.coupling.KinematicJawDriver(fw.FaceSimulator(sim.fr)))
    pytest.importorskip("mujoco")
    for args, kwargs, needle in [((sim, "x"), {}, "model"), ((sim, None), {}, "model"), (("sim", None), {}, "sim"),
                                 ((None, None), {}, "sim")]:
        with pytest.raises(fw.InputError, match=needle):
            fw.MujocoSkin(*args, **kwargs)
    import mujoco

    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><geom size='0.1'/></body></worldbody></mujoco>")
    for kwargs, needle in [({"prefix": 3}, "prefix"), ({"mesh": ""}, "mesh"), ({}, "mesh")]:
        with pytest.raises(fw.InputError, match=needle):
            fw.MujocoSkin(sim, model, **kwargs)


@pytest.mark.parametrize("command", ["batch simulate", "morph", "retarget", "batch run"])
def test_second_run_on_one_out_is_refused(command, built, tmp_path, capsys):
    """A run in progress holds its --out (as staged_outputs / output_lock hold it for a real run):
    a second run of a writing command on it is refused with exit 2 and one line, and what the first
    has written so far is intact and is moved into place when the first finishes."""
    outputs = _private("core.outputs")
    output_lock, staged_outputs = outputs.output_lock, outputs.staged_outputs

    out = tmp_path / ("o.usda" if command == "morph" else "o")
    argv = {"batch simulate": ["batch", "simulate", built, "--seconds", "0.1", "--out", out],
            "morph": ["morph", "default", "default", "--steps", "1", "--out", out],
            "retarget": ["retarget", "smile", built, "--seconds", "0.1", "--out", out],
            "batch run": ["batch", "run", _octahedron_obj(tmp_path / "s.obj"), "--steps", "adapt", "--out", out]}[command]
    if command == "batch run":  # written in place, not staged: the first run's folder as it has it
        out.mkdir()
        (out / "manifest.json").write_text('{"first": "run"}')
        with output_lock("out", out):
            _cli(capsys, argv, needle="another facewarp run is writing it")
        assert (out / "manifest.json").read_text() == '{"first": "run"}'
        assert not [p.name for p in tmp_path.iterdir() if ".facewarp-" in p.name]
        return
    kind = "file" if command == "morph" else "dir"
    with staged_outputs([("out", out, kind)]) as first:
        staged = first.path("out")
        (staged if kind == "dir" else staged.parent).mkdir(exist_ok=True)
        mine = staged / "first.txt" if kind == "dir" else staged
        mine.write_text("the first run's")
        _cli(capsys, argv, needle="another facewarp run is writing it")
        assert mine.read_text() == "the first run's" and not out.exists()
    assert (out / "first.txt" if kind == "dir" else out).read_text() == "the first run's"
    assert not [p.name for p in tmp_path.iterdir() if ".facewarp-" in p.name]


def test_file_jobs_api_refuse_junk(built, tmp_path):
    """The jobs behind batch simulate and retarget, called from Python: junk is an InputError naming
    the argument, before anything is written."""
    batch_simulate_files = _private("jobs.batch_simulate").batch_simulate_files
    retarget_files = _private("jobs.retarget").retarget_files

    out = tmp_path / "o"
    for call, needle in [
        (lambda: batch_simulate_files(str(built), "smile", out), "heads"),
        (lambda: batch_simulate_files([3], "smile", out), "heads"),
        (lambda: batch_simulate_files([built], None, out), "expression"),
        (lambda: batch_simulate_files([built], "smile", out, per_head=5), "per_head"),
        (lambda: batch_simulate_files([built], "smile", ""), "out"),
        (lambda: batch_simulate_files([built], "smile", out, progress=5), "progress"),
        (lambda: batch_simulate_files([built], "smile", out, seconds=0.001), "no frame"),
        (lambda: batch_simulate_files([built], "smile", out, stage="head_00.usdc"), "stage"),
        (lambda: batch_simulate_files([built], "smile", built), "input BUILD_DIR"),
        (lambda: retarget_files("smile", str(built), out), "heads"),
        (lambda: retarget_files(None, [built], out), "expression"),
        (lambda: retarget_files("smile", [built], out, size=10**6), "size"),
        (lambda: retarget_files("smile", [3], out), "heads"),
        (lambda: retarget_files("smile", [built], out, fps=float("nan")), "fps"),
        (lambda: retarget_files("smile", [built], out, seconds=1e9), "seconds"),
        (lambda: retarget_files("smile", [built], out, progress=5), "progress"),
        (lambda: retarget_files("smile", [built], built), "input HEAD"),
    ]:
        with pytest.raises(fw.InputError, match=needle) as e:
            call()
        assert "\n" not in str(e.value)
        assert not out.exists() and list(tmp_path.iterdir()) == []


def test_tracker_constructor_refuses_junk(sim):
    """Tracker(sim, points, ...): junk arguments are InputErrors naming them (the values update takes
    are the recordings' side: MarkerTrack and the take loaders check them)."""
    rng = _rng("Tracker")
    junk = [None, "a", 0, -1, 1.5, float("nan"), 10**9, True, [], ["x"], object(), np.zeros((2, 2)), {"a": 1}, b"x"]
    for name, make in [("sim", lambda v: fw.Tracker(v, ["2.1"])), ("points", lambda v: fw.Tracker(sim, v)),
                       ("mode", lambda v: fw.Tracker(sim, ["2.1"], mode=v)),
                       ("smoothness", lambda v: fw.Tracker(sim, ["2.1"], smoothness=v)),
                       ("refine", lambda v: fw.Tracker(sim, ["2.1"], refine=v))]:
        for v in rng.sample(junk, 8):
            if v is None and name in ("refine",):
                continue  # the default
            try:
                make(v)
            except fw.InputError as e:
                assert "\n" not in str(e), _why(f"{name}={v!r}: {e}")
            except Exception as e:
                pytest.fail(_why(f"{name}={v!r:.40}: {type(e).__name__}: {e}"))
            else:
                if not (name in ("smoothness", "refine") and isinstance(v, (int, float)) and not isinstance(v, bool)
                        and v == v and v >= 0):
                    pytest.fail(_why(f"{name}={v!r:.40} was accepted"))
