"""Writing a template (or any head with the template's data) to a folder, and reading it back.

A template folder holds:

- ``template.obj``: the skin mesh [m];
- ``landmarks.json``: FDP id -> [x, y, z] [m];
- ``regions.json``: the region names, the region of every face and the frontal-face flag;
- ``template.json``: counts, level, units, thickness factor, bounding box;
- ``template.npz``: per-vertex ``thickness`` [m] and ``skull_depth`` [m], ``condyles`` (2, 3) [m],
  FDP surface points (``fdp_ids``, ``fdp_part``, ``fdp_face``, ``fdp_bary``), the rigid parts;
- ``skull.obj``, ``parts/<name>.obj``: the skull surface and the rigid parts [m];
- ``preview_front.png``, ``preview_side.png``: renders of the head with its eyes and teeth.
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..fileio import atomic_write, write_json
from ..landmarks import save_landmarks_json
from ..mesh import SurfacePoints, load_mesh, mesh_report, save_obj
from .head import REGIONS, Template

__all__ = ["export_template", "load_template_dir", "render_previews", "template_summary"]


def template_summary(t: Template) -> dict:
    """Counts, level, units and bounding box of a template as a JSON-ready dict."""
    rep = mesh_report(t.vertices, t.faces)
    counts = np.bincount(t.face_region, minlength=len(REGIONS))
    return {
        "level": t.level,
        "units": "m",
        "vertex_count": t.vertex_count,
        "face_count": t.face_count,
        "frontal_face_count": int(t.frontal.sum()),
        "fdp_count": len(t.fdp),
        "thickness_factor": t.thickness_factor,
        "regions": {r: int(c) for r, c in zip(REGIONS, counts)},
        "bounding_box_m": t.bounding_box().tolist(),
        "boundary_loops": rep["boundary_loop_count"],
        "non_manifold_edges": rep["non_manifold_edge_count"],
        "parts": {k: len(v[0]) for k, v in t.parts.items()},
    }


SKIN = np.array([0.87, 0.72, 0.62])
LIPS = np.array([0.78, 0.47, 0.45])
TEETH = np.array([0.97, 0.95, 0.85])
TONGUE = np.array([0.8, 0.42, 0.42])


def vermilion_weight(V, lm: dict, mask=None) -> np.ndarray:
    """Lip tint weight in [0, 1] per vertex of V (n, 3) [m]: an ellipse through the lip corners
    (8.3, 8.4) and the lip midpoints (8.1, 8.2) around the stomion (mean of 2.2, 2.3), with a
    soft edge; ``mask`` (n,) bool limits it to some vertices."""
    sto = 0.5 * (lm["2.2"] + lm["2.3"])
    half_w = 0.5 * abs(lm["8.3"][0] - lm["8.4"][0])
    up, dn = lm["8.1"][1] - sto[1], sto[1] - lm["8.2"][1]
    dy = V[:, 1] - sto[1]
    e = ((V[:, 0] - sto[0]) / half_w) ** 2 + (dy / np.where(dy > 0, up, dn)) ** 2
    w = np.clip((1.15 - e) / 0.3, 0.0, 1.0)
    return w if mask is None else w * mask


def colored_scene(t: Template) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Skin and rigid parts merged into one mesh with per-vertex colours for previews.

    Lips are tinted, eyeballs get a sclera, iris (6 mm) and pupil (2 mm) facing +z.
    Returns V (n, 3) [m], F (m, 3), colours (n, 3) in [0, 1].
    """
    Vs, Fs, Cs = [t.vertices], [t.faces], []
    col = np.tile(SKIN, (t.vertex_count, 1))
    lip_ids = [REGIONS.index(r) for r in ("upper_lip", "lower_lip", "lip_corner_L", "lip_corner_R")]
    on_lips = np.zeros(t.vertex_count, bool)
    on_lips[np.unique(t.faces[np.isin(t.face_region, lip_ids)])] = True
    wgt = vermilion_weight(t.vertices, t.landmarks(), on_lips)
    col = col * (1 - wgt[:, None]) + LIPS * wgt[:, None]
    Cs.append(col)
    off = t.vertex_count
    for name, (V, F) in t.parts.items():
        if name.startswith("eye"):
            c = V.mean(0)
            d = V - c
            ang = np.arccos(np.clip(d[:, 2] / np.linalg.norm(d, axis=1), -1, 1))
            r = np.linalg.norm(d, axis=1).mean()
            pc = np.where(ang < np.arcsin(2.0e-3 / r), 0.0, np.where(ang < np.arcsin(6.0e-3 / r), 1.0, 2.0))
            pal = np.array([[0.05, 0.05, 0.05], [0.33, 0.24, 0.16], [0.96, 0.95, 0.93]])
            Cs.append(pal[pc.astype(int)])
        else:
            Cs.append(np.tile(TEETH if name.startswith("teeth") else TONGUE, (len(V), 1)))
        Vs.append(V)
        Fs.append(F + off)
        off += len(V)
    return np.concatenate(Vs), np.concatenate(Fs), np.concatenate(Cs)


def render_previews(t: Template, out: Path, *, size: int = 800, device: str = "cpu") -> list[Path]:
    """Render ``preview_front.png`` and ``preview_side.png`` of the head into ``out``."""
    from ..render import render_mesh, save_png

    V, F, C = colored_scene(t)
    paths = []
    for view in ("front", "side"):
        img = render_mesh(V, F, view=view, width=size, height=size, vertex_colors=C, device=device)
        p = out / f"preview_{view}.png"
        what = f"facewarp default template, level {t.level}" if t.level >= 0 else "facewarp imported template"
        save_png(p, img, title=f"{what} ({t.vertex_count} vertices)")
        paths.append(p)
    return paths


def export_template(t: Template, out: str | os.PathLike, *, previews: bool = True, device: str = "cpu", progress=None) -> list[Path]:
    """Write ``t`` into the folder ``out`` (created if needed). Returns the written paths."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    (out / "parts").mkdir(exist_ok=True)
    step = progress or (lambda msg: None)
    written = []
    step("mesh")
    save_obj(out / "template.obj", t.vertices, t.faces)
    save_obj(out / "skull.obj", t.skull_vertices(), t.faces)
    written += [out / "template.obj", out / "skull.obj"]
    for name, (V, F) in t.parts.items():
        save_obj(out / "parts" / f"{name}.obj", V, F)
        written.append(out / "parts" / f"{name}.obj")
    step("landmarks")
    save_landmarks_json(out / "landmarks.json", t.landmarks())
    write_json(out / "regions.json", {
        "regions": list(REGIONS),
        "face_region": [REGIONS[i] for i in t.face_region],
        "frontal": t.frontal.astype(int).tolist(),
    }, indent=None)
    write_json(out / "template.json", template_summary(t))
    ids = list(t.fdp)
    arrays = {
        "thickness": t.thickness,
        "skull_depth": t.skull_depth,
        "condyles": t.condyles,
        "face_region": t.face_region,
        "frontal": t.frontal,
        "fdp_ids": np.array(ids),
        "fdp_part": np.array([t.fdp[i][0] for i in ids]),
        "fdp_face": np.array([int(t.fdp[i][1].face[0]) for i in ids]),
        "fdp_bary": np.array([t.fdp[i][1].bary[0] for i in ids]),
        "level": np.array(t.level),
        "thickness_factor": np.array(t.thickness_factor),
        "part_names": np.array(list(t.parts)),
    }
    for name, (V, F) in t.parts.items():
        arrays[f"part_{name}_V"] = V
        arrays[f"part_{name}_F"] = F
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    with atomic_write(out / "template.npz", "wb", encoding=None) as f:
        f.write(buf.getvalue())
    written += [out / n for n in ("landmarks.json", "regions.json", "template.json", "template.npz")]
    if previews:
        step("previews")
        written += render_previews(t, out, device=device)
    return written


def load_template_dir(path: str | os.PathLike) -> Template:
    """Read a folder written by :func:`export_template` back into a :class:`Template`."""
    path = Path(path)
    if not path.is_dir():
        raise InputError(f"{path}: not a template folder (no such directory)")
    for name in ("template.obj", "template.npz"):
        if not (path / name).is_file():
            raise InputError(f"{path}: not a template folder ({name} is missing)")
    mesh = load_mesh(path / "template.obj")
    try:
        z = np.load(path / "template.npz", allow_pickle=False)
        n = len(mesh.vertices)
        if z["thickness"].shape != (n,) or z["face_region"].shape != (len(mesh.faces),):
            raise InputError(f"{path}: template.npz does not match template.obj ({n} vertices)")
        fdp = {}
        for fid, part, face, bary in zip(z["fdp_ids"], z["fdp_part"], z["fdp_face"], z["fdp_bary"]):
            fdp[str(fid)] = (str(part), SurfacePoints(np.array([int(face)]), np.asarray(bary, float)[None]))
        parts = {str(k): (z[f"part_{k}_V"], z[f"part_{k}_F"]) for k in z["part_names"]}
        return Template(
            vertices=mesh.vertices, faces=mesh.faces, face_region=z["face_region"].astype(np.int16),
            frontal=z["frontal"].astype(bool), thickness=z["thickness"], skull_depth=z["skull_depth"],
            condyles=z["condyles"], fdp=fdp, parts=parts, level=int(z["level"]),
            thickness_factor=float(z["thickness_factor"]),
        )
    except (KeyError, ValueError, OSError) as e:
        raise InputError(f"{path}: template.npz is unreadable ({e})") from None
