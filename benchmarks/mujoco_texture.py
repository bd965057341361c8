"""MuJoCo shows the person: a head's head.xml with its skin texture, rendered offscreen, against the texture.

A head (an ``adapt`` output folder, or ``default``) and its ``build`` folder: head.xml is written
with the skin's texture coordinates and ``texture.png`` (``fw.coupling.write_head_mjcf(skin=(V, F, uv,
face_uv), skin_texture=...)``) and scene.xml's camera renders it (MUJOCO_GL, egl by default) lit,
as a user sees it (the picture), and unlit (lights and headlight off, the skin's material
emissive: a pixel is the colour MuJoCo samples from the texture), plus a depth image. Each skin
vertex the camera sees (projected with the camera's pose and field of view, facing it, not hidden
per the depth image) is compared at its pixel with the texture's colour at the vertex's own UV
(bilinear): CIE76 Delta E (sRGB D65 -> CIELAB), mean / median / p95, for the unlit render (the
texture lands where the UVs put it) and the lit one (the light's shading included); and, for
scale, what a texture flipped upside down would give. Results: benchmarks/results/mujoco_texture.json
and the lit picture.

    MUJOCO_GL=egl python -m benchmarks mujoco_texture --head DEMO/adapt --build DEMO/build
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

import facewarp as fw  # noqa: E402
from benchmarks._common import RESULTS, save  # noqa: E402


def srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (D65) of sRGB colours in 0..1, shape (..., 3)."""
    c = np.asarray(rgb, np.float64)
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    M = np.array([[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750],
                  [0.0193339, 0.1191920, 0.9503041]])
    xyz = lin @ M.T / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], -1)


def _bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Texture colours (k, 3) in 0..1 at UVs (k, 2) (v up, as the mesh's UVs), bilinear."""
    h, w = img.shape[:2]
    x = np.clip(uv[:, 0] * w - 0.5, 0, w - 1)
    y = np.clip((1.0 - uv[:, 1]) * h - 0.5, 0, h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    f = img.astype(np.float64) / 255.0
    return (f[y0, x0] * (1 - fx) * (1 - fy) + f[y0, x1] * fx * (1 - fy) + f[y1, x0] * (1 - fx) * fy
            + f[y1, x1] * fx * fy)[:, :3]


def run(head_dir: str, build: Path, size: int, picture: Path | None) -> dict:
    import mujoco
    from PIL import Image

    head = fw.load_head(head_dir)
    fr = fw.load_face_rig(build)
    tex = build / "texture.png"
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        shutil.copyfile(tex, tmp / "texture.png")
        skin = (fr.head_vertices, fr.head_faces, fr.head_uv, fr.head_face_uv)
        fw.coupling.write_head_mjcf(tmp / "head.xml", head, jaw=fr.jaw, skin=skin, skin_texture="texture.png")
        m = mujoco.MjModel.from_xml_path(str(tmp / "scene.xml"))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    r = mujoco.Renderer(m, size, size)
    r.update_scene(d, camera=0)
    lit = r.render().copy()
    mat = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_MATERIAL, "skin")
    m.mat_emission[mat] = 1.0  # unlit: a skin pixel is the colour MuJoCo samples from the texture
    m.mat_specular[mat] = 0.0
    m.light_active[:] = 0
    m.vis.headlight.active = 0
    r.update_scene(d, camera=0)
    unlit = r.render().copy()
    r.enable_depth_rendering()
    r.update_scene(d, camera=0)
    depth = r.render().copy()
    r.close()
    # each skin vertex (the seams' copies too) where the camera sees it: its pixel, and its own texture colour
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "skin")
    i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_MESH, "skin")
    sl = slice(int(m.mesh_vertadr[i]), int(m.mesh_vertadr[i] + m.mesh_vertnum[i]))
    Vw = m.mesh_vert[sl].astype(np.float64) @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
    Nw = m.mesh_normal[sl].astype(np.float64) @ d.geom_xmat[g].reshape(3, 3).T
    from facewarp.coupling import skin_vertex_split

    _, src, uvi = skin_vertex_split(fr.head_faces, fr.head_face_uv)
    uv = np.asarray(fr.head_uv, np.float64)[uvi]
    R, c = d.cam_xmat[0].reshape(3, 3), d.cam_xpos[0]
    P = (Vw - c) @ R  # camera frame: x right, y up, looking along -z
    z = -P[:, 2]
    f = 0.5 * size / np.tan(np.radians(m.cam_fovy[0]) / 2)
    px = np.round(size / 2 + f * P[:, 0] / z - 0.5).astype(int)
    py = np.round(size / 2 - f * P[:, 1] / z - 0.5).astype(int)
    inside = (z > 0) & (px >= 0) & (px < size) & (py >= 0) & (py < size)
    facing = np.einsum("kd,kd->k", Nw, (c - Vw) / np.linalg.norm(c - Vw, axis=1, keepdims=True)) > 0.3
    seen = inside & facing
    seen[seen] = np.abs(depth[py[seen], px[seen]] - z[seen]) < 1.5e-3
    texture = np.asarray(Image.open(tex).convert("RGB"))
    want = srgb_to_lab(_bilinear(texture, uv[seen]))
    got = srgb_to_lab(unlit[py[seen], px[seen], :3] / 255.0)
    shaded = srgb_to_lab(lit[py[seen], px[seen], :3] / 255.0)
    de = np.linalg.norm(got - want, axis=1)
    de_lit = np.linalg.norm(shaded - want, axis=1)
    # a flipped or mirrored texture lands other colours on the same points: its Delta E, for scale
    flipped = uv[seen].copy()
    flipped[:, 1] = 1.0 - flipped[:, 1]
    de_flip = np.linalg.norm(got - srgb_to_lab(_bilinear(texture, flipped)), axis=1)
    if picture is not None:
        Image.fromarray(lit).save(picture, optimize=True)
    stats = (lambda e: {"mean": float(e.mean()), "median": float(np.median(e)), "p95": float(np.percentile(e, 95))})
    return {"head": str(head_dir), "build": str(build), "size_px": size, "skin_vertices": int(len(fr.head_vertices)),
            "mesh_vertices_split_at_seams": int(m.mesh_vertnum[i]), "vertices_compared": int(seen.sum()),
            "delta_e_unlit": stats(de), "delta_e_lit": stats(de_lit), "delta_e_if_v_flipped": stats(de_flip),
            "texture_lab_mean": want.mean(0).tolist(), "unlit_lab_mean": got.mean(0).tolist(),
            "lit_lab_mean": shaded.mean(0).tolist(), "mujoco_gl": os.environ.get("MUJOCO_GL")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--head", default="default", help="an adapt output folder (or default)")
    ap.add_argument("--build", required=True, type=Path, help="its build folder (face_rig.npz, texture.png)")
    ap.add_argument("--size", type=int, default=480)
    ap.add_argument("--picture", type=Path, default=RESULTS / "mujoco_texture.png")
    ap.add_argument("--name", default="mujoco_texture")
    a = ap.parse_args(argv)
    import mujoco

    rep = run(a.head, a.build, a.size, a.picture)
    print(f"Delta E at {rep['vertices_compared']} visible skin vertices: unlit mean {rep['delta_e_unlit']['mean']:.2f} "
          f"p95 {rep['delta_e_unlit']['p95']:.2f}; lit mean {rep['delta_e_lit']['mean']:.2f}; "
          f"a v-flipped texture would give {rep['delta_e_if_v_flipped']['mean']:.2f}")
    save(a.name, rep, machine_extra={"mujoco": mujoco.__version__})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
