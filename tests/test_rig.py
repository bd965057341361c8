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
    widths = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}

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
        np.testing.assert_allclose(out, rig.evaluate(acts, jaw), atol=2e-6)
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
