"""`facewarp rig`: a small blendshape rig (two muscles, one in-between, the jaw joint) of the
default level-0 head, written as UsdSkel and glTF; both files deform the skin exactly as the
linear rig says (UsdSkel's own skinning; a NumPy reading of the glTF), USD's checks pass, and the
Khronos glTF validator (where node and the npm package are installed) reports no errors."""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

import facewarp as fw
from facewarp.cli import main

MUSCLES = ["zygomatic_major_L", "zygomatic_major_R"]
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("rig")
    assert main(["--json", "build", "default", "--out", str(d / "build")]) == 0
    for ext in ("glb", "usda"):
        assert main(["--json", "rig", str(d / "build"), "--out", str(d / f"rig.{ext}"), "--muscles", ",".join(MUSCLES),
                     "--inbetweens", "1"]) == 0
    rig = fw.blendshapes.bake_blendshapes(fw.load_face_rig(d / "build"), muscles=MUSCLES, inbetweens=1)
    return d, rig


def _frame(rig, k_weights: dict, jaw: float) -> np.ndarray:
    return rig.evaluate(k_weights, jaw)


def test_usdskel_deforms_as_the_linear_rig(made):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdSkel, Vt

    import usd_export

    d, rig = made
    path = d / "rig.usda"
    assert usd_export.validate_usd(path) == []
    stage = Usd.Stage.Open(str(path))
    cache = UsdSkel.Cache()
    root = UsdSkel.Root(stage.GetPrimAtPath("/Rig"))
    cache.Populate(root, Usd.TraverseInstanceProxies())
    skel = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath("/Rig/Skeleton")))
    skin_prim = stage.GetPrimAtPath("/Rig/Skin")
    skin = cache.GetSkinningQuery(skin_prim)
    anim = skel.GetAnimQuery()
    names = list(anim.GetBlendShapeOrder())
    assert names == MUSCLES + ["jaw_open"]
    assert {p.GetName() for p in stage.GetPrimAtPath("/Rig/Parts").GetChildren()} >= {"Eye_L", "Teeth_Lower", "Tongue"}
    jaw_angle = rig.jaw_angle
    checked = 0
    for code in (0.0, 21.0, 36.0):  # rest, the smile's and the laugh's peaks (the laugh opens the jaw)
        t = Usd.TimeCode(code)
        w = np.array(anim.ComputeBlendShapeWeights(t))
        q = anim.ComputeJointLocalTransforms(t)[0]  # root/jaw
        R = np.array(q)[:3, :3].T  # row-vector matrix -> column rotation
        jaw = float(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))) * (1 if w[-1] >= 0 else -1)
        np.testing.assert_allclose(jaw, w[-1] * jaw_angle, atol=1e-5)
        points = Vt.Vec3fArray(skin_prim.GetAttribute("points").Get())
        bsq = UsdSkel.BlendShapeQuery(UsdSkel.BindingAPI(skin_prim))
        mapped = skin.GetBlendShapeMapper().Remap(Vt.FloatArray(list(map(float, w))))
        sub_w, bs_idx, sub_idx = bsq.ComputeSubShapeWeights(mapped)
        bsq.ComputeDeformedPoints(sub_w, bs_idx, sub_idx, bsq.ComputeBlendShapePointIndices(),
                                  bsq.ComputeSubShapePointOffsets(), points)
        skin.ComputeSkinnedPoints(skel.ComputeSkinningTransforms(t), points, t)
        want = rig.evaluate(dict(zip(MUSCLES, w[:2])), jaw)
        np.testing.assert_allclose(np.array(points), want, atol=2e-6)
        checked += bool(w[:2].any() or jaw)
    assert checked >= 2


def _glb(path):
    raw = Path(path).read_bytes()
    magic, version, total = struct.unpack_from("<4sII", raw, 0)
    assert magic == b"glTF" and version == 2 and total == len(raw)
    n = struct.unpack_from("<I", raw, 12)[0]
    doc = json.loads(raw[20:20 + n])
    binary = raw[20 + n + 8:]
    types = {5126: np.float32, 5121: np.uint8, 5125: np.uint32}
    widths = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}

    def acc(i):
        a = doc["accessors"][i]
        v = doc["bufferViews"][a["bufferView"]]
        arr = np.frombuffer(binary, types[a["componentType"]], a["count"] * widths[a["type"]], v["byteOffset"])
        return arr.reshape(a["count"], widths[a["type"]]) if widths[a["type"]] > 1 else arr

    return doc, acc


def _quat_matrix(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_gltf_deforms_as_the_linear_rig(made):
    d, rig = made
    doc, acc = _glb(d / "rig.glb")
    mesh = doc["meshes"][0]
    names = mesh["extras"]["targetNames"]
    assert names == ["zygomatic_major_L@0.50", "zygomatic_major_L", "zygomatic_major_R@0.50", "zygomatic_major_R",
                     "jaw_open"]
    prim = mesh["primitives"][0]
    P = acc(prim["attributes"]["POSITION"]).astype(np.float64)
    J, W = acc(prim["attributes"]["JOINTS_0"]), acc(prim["attributes"]["WEIGHTS_0"])
    D = np.stack([acc(t["POSITION"]) for t in prim["targets"]]).astype(np.float64)
    # the skin's vertices are split at the UV seams: each glTF vertex is a rest vertex (same float32 position)
    index = {r.tobytes(): i for i, r in enumerate(rig.rest.astype(np.float32))}
    src = np.array([index[r.tobytes()] for r in P.astype(np.float32)])
    assert len(P) > len(rig.rest) and set(src) == set(range(len(rig.rest)))
    uv = acc(prim["attributes"]["TEXCOORD_0"])
    assert uv.shape == (len(P), 2) and 0 <= uv.min() and uv.max() <= 1
    # normal deltas per target: the change of the unit normals of the full target
    from facewarp.blendshapes import normal_offsets

    ND = acc(prim["targets"][1]["NORMAL"]).astype(np.float64)
    np.testing.assert_allclose(ND, normal_offsets(rig, rig.shapes[MUSCLES[0]][-1][1])[src], atol=1e-6)
    assert np.abs(ND).max() > 1e-3
    skin = doc["skins"][0]
    ibm = acc(skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
    jaw_node = doc["nodes"][skin["joints"][1]]
    anim = doc["animations"][0]
    rot = {c["target"]["path"]: anim["samplers"][c["sampler"]] for c in anim["channels"]}
    Q = acc(rot["rotation"]["output"])
    MW = acc(rot["weights"]["output"]).reshape(len(Q), len(names))
    for k in (0, 21, 36):
        jaw_world = np.eye(4)
        jaw_world[:3, :3] = _quat_matrix(Q[k])
        jaw_world[:3, 3] = jaw_node["translation"]
        mats = [np.eye(4) @ ibm[0], jaw_world @ ibm[1]]
        morphed = P + np.einsum("t,tnd->nd", MW[k], D)
        h = np.c_[morphed, np.ones(len(P))]
        out = np.zeros_like(P)
        for j in range(4):
            for jid in (0, 1):
                m = (J[:, j] == jid) & (W[:, j] > 0)
                out[m] += W[m, j, None] * (h[m] @ mats[jid].T)[:, :3]
        jaw = 2 * np.arctan2(np.linalg.norm(Q[k][:3]), Q[k][3])
        # the muscle weights back from the in-between mapping: w = f t (first piece), f + (1 - f) t after
        acts = {}
        for i, m in enumerate(MUSCLES):
            half, full = MW[k][2 * i], MW[k][2 * i + 1]
            acts[m] = 0.5 + 0.5 * full if full > 0 else 0.5 * half
        np.testing.assert_allclose(out, rig.evaluate(acts, jaw)[src], atol=2e-6)
        np.testing.assert_allclose(MW[k][-1], jaw / rig.jaw_angle, atol=1e-5)


def test_gltf_has_the_looks_of_eyes_teeth_gums_tongue(made):
    d, rig = made
    doc, acc = _glb(d / "rig.glb")
    mats = {m["name"]: m["pbrMetallicRoughness"]["baseColorFactor"][:3] for m in doc["materials"]}
    for look in ("Skin", "Sclera", "Iris", "Pupil", "Teeth_Upper", "Teeth_Lower", "Gums", "Tongue"):
        assert look in mats, (look, sorted(mats))
    assert max(mats["Pupil"]) < 0.1 and min(mats["Sclera"]) > 0.8 and mats["Iris"][0] > mats["Iris"][2]
    assert mats["Tongue"][0] > mats["Tongue"][1] and min(mats["Teeth_Upper"]) > 0.8
    assert "Lips" not in mats  # a build folder has a skin texture (texture.png): the lips are the texture's
    names = [m["name"] for m in doc["materials"]]
    for part, name in (("Eye_L", "eye_L"), ("Eye_R", "eye_R")):
        mesh = next(m for m in doc["meshes"] if m["name"] == part)
        assert sorted(names[p["material"]] for p in mesh["primitives"]) == ["Iris", "Pupil", "Sclera"]
        faces = np.concatenate([acc(p["indices"]).reshape(-1, 3) for p in mesh["primitives"]])
        assert len(faces) == len(rig.parts[name][1])  # each face of the ball in one primitive
    # the tooth rows: pink gums at the root end (top of the upper row, bottom of the lower), ivory crowns
    assert mats["Gums"][0] > 0.5 and mats["Gums"][0] > mats["Gums"][1] + 0.2 and mats["Gums"][0] > mats["Gums"][2] + 0.2
    for part, name, root in (("Teeth_Upper", "teeth_upper", 1.0), ("Teeth_Lower", "teeth_lower", -1.0)):
        mesh = next(m for m in doc["meshes"] if m["name"] == part)
        prims = {names[p["material"]]: p for p in mesh["primitives"]}
        assert sorted(prims) == sorted(["Gums", part])
        P = acc(prims["Gums"]["attributes"]["POSITION"]).astype(np.float64)
        V0 = np.asarray(rig.parts[name][0], np.float64)
        end = root * (V0[:, 1].max() if root > 0 else V0[:, 1].min())
        gum, teeth = (P[acc(prims[k]["indices"]).reshape(-1, 3)].mean(1) for k in ("Gums", part))
        assert len(gum) and (root * gum[:, 1] > end - 3.0e-3).all() and (root * teeth[:, 1] < end - 1.0e-3).all()
        assert gum[:, 2].max() > V0[:, 2].max() - 1.0e-3  # on the front of the row too, where it shows


def test_usdskel_rig_has_the_gums(made):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom, UsdShade

    d, rig = made
    stage = Usd.Stage.Open(str(d / "rig.usda"))
    for part, name, root in (("Teeth_Upper", "teeth_upper", 1.0), ("Teeth_Lower", "teeth_lower", -1.0)):
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(f"/Rig/Parts/{part}"))
        P = np.array(mesh.GetPointsAttr().Get(), np.float64)
        F = np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
        sub = UsdGeom.Subset(stage.GetPrimAtPath(f"/Rig/Parts/{part}/Gums"))
        mat = UsdShade.MaterialBindingAPI(sub.GetPrim()).GetDirectBinding().GetMaterial()
        assert mat.GetPath() == "/Rig/Looks/Gums"
        rgb = np.array(UsdShade.Shader(stage.GetPrimAtPath("/Rig/Looks/Gums/PreviewSurface"))
                       .GetInput("diffuseColor").Get())
        assert rgb[0] > rgb[1] + 0.2 and rgb[0] > rgb[2] + 0.2  # pink
        V0 = np.asarray(rig.parts[name][0], np.float64)
        end = root * (V0[:, 1].max() if root > 0 else V0[:, 1].min())
        h = root * P[F[np.array(sub.GetIndicesAttr().Get())]].mean(1)[:, 1]
        assert len(h) and (h > end - 3.0e-3).all()


def test_gltf_validator_reports_no_errors(made):
    node = shutil.which("node")
    script = ROOT / "benchmarks" / "gltf_validate.js"
    env = dict(os.environ)
    if not node:
        pytest.skip("node is not installed")
    run = subprocess.run([node, str(script), str(made[0] / "rig.glb")], capture_output=True, text=True, env=env,
                         timeout=120)
    if "Cannot find module 'gltf-validator'" in run.stderr:
        pytest.skip("the npm package gltf-validator is not installed (npm install gltf-validator; NODE_PATH)")
    assert run.returncode == 0, run.stderr[-2000:]
    rep = json.loads(run.stdout)
    assert rep["numErrors"] == 0 and rep["numWarnings"] == 0, rep


def test_inbetween_weights_hit_the_baked_shapes(made):
    _, rig = made
    m = MUSCLES[0]
    for f, D in rig.shapes[m]:
        np.testing.assert_allclose(rig.evaluate({m: f}), rig.rest + D, atol=1e-12)
    mid = rig.evaluate({m: 0.75})
    np.testing.assert_allclose(mid, rig.rest + 0.5 * (rig.shapes[m][0][1] + rig.shapes[m][1][1]), atol=1e-12)
    assert np.abs(rig.shapes[m][-1][1]).max() > 2e-3  # the muscle moves the skin by millimetres


def test_rig_errors(made, tmp_path, capsys):
    d, _ = made
    b = str(d / "build")
    for argv, needle in [
        (["rig", b, "--out", str(tmp_path / "r.fbx")], "extension"),
        (["rig", b, "--out", str(tmp_path / "r.glb"), "--inbetweens", "9"], "inbetweens"),
        (["rig", b, "--out", str(tmp_path / "r.glb"), "--muscles", "nose"], "nose"),
        (["rig", str(tmp_path), "--out", str(tmp_path / "r.glb")], "face_rig"),
        (["rig", b, "--out", str(tmp_path / "no" / "r.glb")], "folder"),
    ]:
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2, (argv, err)
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1 and needle in err, err
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------------------------------------- ARKit, one bake
def _table(fr, rows: dict):
    """A small ARKit table of this head: ARKit name -> ({muscle: activation}, (opening, side) [rad])."""
    from facewarp.takes import ArkitTable

    names = list(fw.ARKIT_NAMES)
    muscles = list(fw.FaceSimulator(fr).muscle_names)
    A = np.zeros((len(names), len(muscles)), np.float32)
    J = np.zeros((len(names), 2), np.float32)
    solved = np.zeros(len(names), bool)
    for n, (acts, jaw) in rows.items():
        i = names.index(n)
        for m, a in acts.items():
            A[i, muscles.index(m)] = a
        J[i] = jaw
        solved[i] = True
    z = np.zeros((len(names), 1, 3))
    return ArkitTable(names=tuple(names), muscle_names=muscles, activations=A, jaw=J, solved=solved,
                      residual_m=np.zeros(len(names)), target_rms_m=np.zeros(len(names)), fdp_ids=["2.1"],
                      rest_fdp=np.zeros((1, 3)), targets=z, reached=z, basis=np.zeros((3, len(muscles) + 2)),
                      reasons={"cheekPuff": "air pressure"})


ROWS = {"mouthSmileLeft": ({"zygomatic_major_L": 0.8}, (0.0, 0.0)),
        "jawOpen": ({}, (0.25, 0.0)),
        "mouthSmileRight": ({"zygomatic_major_R": 0.8}, (0.05, 0.01))}


@pytest.fixture(scope="module")
def arkit_made(made):
    from facewarp.blendshapes import rig_files

    d, _ = made
    fr = fw.load_face_rig(d / "build")
    rep = rig_files(d / "build", d / "both", shapes="both", muscles=["zygomatic_major_L"], table=_table(fr, ROWS))
    return d / "both", rep, fr


@pytest.mark.slow
def test_one_bake_writes_usd_gltf_and_report_with_arkit_names(arkit_made):
    out, rep, fr = arkit_made
    assert sorted(p.name for p in out.iterdir()) == ["report.json", "rig.glb", "rig.npz", "rig.usdc", "rig_skin.png"]
    disk = json.loads((out / "report.json").read_text())
    assert disk["arkit"] == 3 and disk["muscles"] == 1 and disk["shapes"] == "both"
    assert set(disk["shape_report"]) == {"zygomatic_major_L", "jaw_open", *ROWS}
    assert disk["shape_report"]["jawOpen"]["largest_motion_mm"] > 3.0
    assert len(disk["left_out"]) == 52 - 3 and disk["left_out"]["cheekPuff"] == "air pressure"
    assert set(disk["timings_s"]) >= {"bake", "write", "total"}
    doc, acc = _glb(out / "rig.glb")
    names = doc["meshes"][0]["extras"]["targetNames"]
    assert names == ["zygomatic_major_L", "jaw_open"] + [n for n in fw.ARKIT_NAMES if n in ROWS]
    assert [a["name"] for a in doc["animations"]] == ["sequence", "arkit_tour"]
    pytest.importorskip("pxr")
    from pxr import Usd

    import usd_export

    assert usd_export.validate_usd(out / "rig.usdc") == []
    stage = Usd.Stage.Open(str(out / "rig.usdc"))
    assert stage.GetPrimAtPath("/Rig/Skeleton/ArkitTour").IsValid()
    assert stage.GetPrimAtPath("/Rig/Skin/mouthSmileLeft").GetAttribute("normalOffsets").HasAuthoredValue()


@pytest.mark.slow
def test_arkit_shapes_land_the_converged_face(arkit_made, made):
    """Each ARKit shape at weight 1, through the jaw joint at its opening, is the simulator's
    converged face of its row's controls; the glTF clip's jaw follows the weights."""
    from facewarp.blendshapes import static_surface

    out, rep, fr = arkit_made
    rig = fw.blendshapes.bake_blendshapes(fr, shapes="arkit", arkit=_table(fr, ROWS))
    assert rig.arkit_names == [n for n in fw.ARKIT_NAMES if n in ROWS] and rig.muscle_names == []
    sim = fw.FaceSimulator(fr)
    for n, (acts, jaw) in ROWS.items():
        V, _ = static_surface(sim, acts, jaw)
        np.testing.assert_allclose(rig.evaluate_arkit({n: 1.0}), V, atol=2e-6)
    assert rig.arkit_opening({"jawOpen": 0.5, "mouthSmileRight": 1.0}) == pytest.approx(0.175, abs=1e-6)


def test_one_palette_and_the_texture_in_both_formats(made):
    from facewarp.render import COLORS

    d, _ = made
    doc, _ = _glb(d / "rig.glb")
    skin = next(m for m in doc["materials"] if m["name"] == "Skin")
    assert skin["pbrMetallicRoughness"]["baseColorTexture"]["index"] == 0  # the build's texture
    assert doc["images"][0]["mimeType"] == "image/png"
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom, UsdShade

    import usd_export._writer as uw

    assert uw._SKIN_COLOR == COLORS["skin"] and uw._WHITE_COLOR == COLORS["sclera"]
    stage = Usd.Stage.Open(str(d / "rig.usda"))
    rgb = UsdShade.Shader(stage.GetPrimAtPath("/Rig/Looks/Skin/PreviewSurface")).GetInput("diffuseColor").Get()
    np.testing.assert_allclose(rgb, COLORS["skin"], atol=1e-6)
    skin_prim = stage.GetPrimAtPath("/Rig/Skin")
    mat = UsdShade.MaterialBindingAPI(skin_prim).GetDirectBinding().GetMaterial()
    assert mat.GetPath() == "/Rig/Looks/SkinTexture" and (d / "rig_skin.png").is_file()
    st = UsdGeom.PrimvarsAPI(skin_prim).GetPrimvar("st")
    assert st.GetInterpolation() == "faceVarying" and len(st.GetIndices()) == 3 * len(made[1].faces)


def test_rig_refuses_up_front(made, tmp_path, capsys):
    import fcntl

    d, _ = made
    b = str(d / "build")
    ro = tmp_path / "ro.glb"
    ro.write_bytes(b"old")
    ro.chmod(0o444)
    take = tmp_path / "take.csv"
    from facewarp.takes import save_livelink_csv

    save_livelink_csv(fw.takes.ArkitTrack(30.0, np.zeros((40, len(fw.ARKIT_NAMES)))), take)
    lock = tmp_path / ".held.glb.facewarp-lock"
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    try:
        for argv, needle in [
            (["rig", b, "--out", str(tmp_path / "r.glb"), "--muscles", "zygomatic_major_L,zygomatic_major_L"],
             "twice"),
            (["rig", b, "--out", str(ro)], "read-only"),
            (["rig", b, "--out", str(tmp_path / "held.glb"), "--muscles", "zygomatic_major_L"], "another facewarp"),
            (["drive", b, "--arkit", str(take), "--rig", str(tmp_path), "--out", str(tmp_path / "t.usdc")], "--rig"),
            (["drive", b, "--arkit", str(take), "--rig", str(tmp_path / "none"), "--out", str(tmp_path / "t")],
             "rig.npz"),
        ]:
            code = main(argv)
            err = capsys.readouterr().err
            assert code == 2, (argv, err)
            assert "Traceback" not in err and len(err.strip().splitlines()) == 1 and needle in err, err
    finally:
        os.close(fd)
    assert ro.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".held.glb.facewarp-lock", "ro.glb", "take.csv"]


@pytest.mark.slow
def test_a_driven_take_plays_on_the_rig(arkit_made, tmp_path):
    """The baked rig read back from its folder (rig.npz), a held ARKit take recorded on it by the
    RigTake sink: the take's last frames match the simulated face (the shape is that converged
    face), and the rig with the take as its animation is written as glTF and UsdSkel."""
    from facewarp.blendshapes import RigTake, load_rig

    out, rep, fr = arkit_made
    rig = load_rig(out)
    assert rig.names == list(rep["shape_report"]) and rig.texture and Path(rig.texture).is_file()
    table = _table(fr, ROWS)
    T = 24
    W = np.zeros((T, len(fw.ARKIT_NAMES)))
    W[:, list(fw.ARKIT_NAMES).index("mouthSmileLeft")] = 1.0
    take = RigTake(rig, W)
    sim = fw.FaceSimulator(fr)
    sim.reset()
    take.start(sim, T)
    A, J = table.controls(W)
    for k in range(T):
        sim.set_activations(A[k])
        sim.set_jaw(float(J[k, 0]), float(J[k, 1]))
        sim.step()
        take.frame(sim, k, k / sim.fps)
    r = take.report()
    assert r["clip"] == "arkit" and r["frames"] == T
    assert (take.error[-4:, 1] < 0.2e-3).all()  # the held shape is the baked one: the rig lands the simulated face
    assert r["error_mm"]["p95"] < 0.2 and r["error_mm"]["max"] >= r["error_mm"]["p95"]
    files = take.write(tmp_path / "take.glb", tmp_path / "take.usda")
    doc, acc = _glb(files[0])
    anim = doc["animations"][0]
    assert anim["name"] == "take"
    names = doc["meshes"][0]["extras"]["targetNames"]
    MW = acc(next(anim["samplers"][c["sampler"]] for c in anim["channels"] if c["target"]["path"] == "weights")
             ["output"]).reshape(T, len(names))
    np.testing.assert_allclose(MW[:, names.index("mouthSmileLeft")], 1.0)
    pytest.importorskip("pxr")
    import usd_export

    assert usd_export.validate_usd(files[1]) == []


@pytest.mark.slow
def test_threejs_plays_the_arkit_rig_by_name(arkit_made, tmp_path):
    """three.js (GLTFLoader, AnimationMixer) in headless Chromium: the ARKit names are morph targets,
    the clip arkit_tour plays by name and at jawOpen's peak sets its influence and opens the face.
    Skipped without Chromium or the three npm package (NODE_PATH / FACEWARP_THREE)."""
    import sys

    sys.path.insert(0, str(ROOT))
    from benchmarks.threejs_play import find_chromium, find_three, play

    if find_chromium() is None or find_three() is None:
        pytest.skip("needs Chromium (apt install chromium) and the three npm package (NODE_PATH)")
    out, rep, fr = arkit_made
    arkit = [n for n in rep["shape_report"] if rep["shape_report"][n]["set"] == "arkit"]
    per = round(0.6 * 30)
    t = (arkit.index("jawOpen") * per + per / 2) / 30
    r = play(out / "rig.glb", clip="arkit_tour", t=t, shape="jawOpen", picture=tmp_path / "three.png")
    assert r["ok"], r
    assert set(ROWS) <= set(r["targets"]) and r["clip"] == "arkit_tour" and r["joints"] == ["root", "jaw"]
    assert r["influence"] > 0.95 and r["moved_m"] > 3e-3 and r["textured"]
    assert (tmp_path / "three.png").stat().st_size > 1000


@pytest.mark.slow
def test_gltf_validator_passes_the_textured_arkit_rig(arkit_made):
    """The ARKit + muscle rig (texture embedded, normal deltas, two clips): Khronos glTF-Validator
    0 errors, 0 warnings (skipped without node and the npm package)."""
    node = shutil.which("node")
    if not node:
        pytest.skip("node is not installed")
    run = subprocess.run([node, str(ROOT / "benchmarks" / "gltf_validate.js"), str(arkit_made[0] / "rig.glb")],
                         capture_output=True, text=True, timeout=120)
    if "Cannot find module 'gltf-validator'" in run.stderr:
        pytest.skip("the npm package gltf-validator is not installed (npm install gltf-validator; NODE_PATH)")
    assert run.returncode == 0, run.stderr[-2000:]
    rep = json.loads(run.stdout)
    assert rep["numErrors"] == 0 and rep["numWarnings"] == 0, rep
    assert rep["info"]["hasTextures"] and rep["info"]["animationCount"] == 2
