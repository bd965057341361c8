"""Writing a template (or any head with the template's data) to a folder, and reading it back.

A template folder holds:

- ``template.obj``: the skin mesh [m] with its texture coordinates (``vt``, ``f v/vt``);
- ``landmarks.json``: FDP id -> [x, y, z] [m];
- ``regions.json``: the region names, the region of every face and the frontal-face flag;
- ``template.json``: counts, level, units, thickness factor, bounding box;
- ``template.npz``: per-vertex ``thickness`` [m] and ``skull_depth`` [m], ``condyles`` (2, 3) [m],
  FDP surface points (``fdp_ids``, ``fdp_part``, ``fdp_face``, ``fdp_bary``), the rigid parts;
- ``skull.obj``, ``parts/<name>.obj``: the skull surface and the rigid parts [m];
- and, written by :func:`facewarp.heads.export_template`, ``preview_front.png`` and
  ``preview_side.png``: renders of the head with its eyes and teeth.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fileio import atomic_write, write_json
from ..geometry.landmarks import save_landmarks_json
from ..geometry.mesh import SurfacePoints, load_mesh, mesh_report, save_obj
from .head import REGIONS, Template

__all__ = ["load_template_dir", "save_template", "template_summary"]


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


def save_template(t: Template, out: str | os.PathLike, *, progress=None) -> list[Path]:
    """Write ``t``'s files (no pictures) into the folder ``out`` (created if needed).

    Returns:
        The written paths.
    """
    from ..core.checks import check_head_arg, check_path

    check_head_arg("t", t)
    check_path("out", out)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"out {out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    (out / "parts").mkdir(exist_ok=True)
    step = progress or (lambda msg: None)
    written = []
    step("mesh")
    save_obj(out / "template.obj", t.vertices, t.faces, uv=t.uv, face_uv=t.face_uv)
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
    if t.uv is not None:
        arrays["uv"], arrays["face_uv"] = t.uv, t.face_uv
    for name, (V, F) in t.parts.items():
        arrays[f"part_{name}_V"] = V
        arrays[f"part_{name}_F"] = F
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    with atomic_write(out / "template.npz", "wb", encoding=None) as f:
        f.write(buf.getvalue())
    written += [out / n for n in ("landmarks.json", "regions.json", "template.json", "template.npz")]
    return written


def load_template_dir(path: str | os.PathLike) -> Template:
    """Read a folder written by :func:`save_template` back into a :class:`Template`."""
    from ..core.checks import check_path

    check_path("path", path)
    path = Path(path)
    if not path.is_dir():
        raise InputError(f"{path}: not a template folder (no such directory)")
    for name in ("template.obj", "template.npz"):
        if not (path / name).is_file():
            raise InputError(f"{path}: not a template folder ({name} is missing)")
    mesh = load_mesh(path / "template.obj")
    if (path / "template.npz").stat().st_size == 0:
        raise InputError(f"{path / 'template.npz'}: the file is empty")
    try:
        z = np.load(path / "template.npz", allow_pickle=False)
        n = len(mesh.vertices)
        if z["thickness"].shape != (n,) or z["face_region"].shape != (len(mesh.faces),):
            raise InputError(f"{path}: template.npz does not match template.obj ({n} vertices)")
        fdp = {}
        for fid, part, face, bary in zip(z["fdp_ids"], z["fdp_part"], z["fdp_face"], z["fdp_bary"]):
            fdp[str(fid)] = (str(part), SurfacePoints(np.array([int(face)]), np.asarray(bary, float)[None]))
        parts = {str(k): (z[f"part_{k}_V"], z[f"part_{k}_F"]) for k in z["part_names"]}
        uv = face_uv = None
        if "uv" in z.files:
            uv, face_uv = z["uv"].astype(np.float64), z["face_uv"].astype(np.int64)
            if face_uv.shape != mesh.faces.shape or face_uv.min() < 0 or face_uv.max() >= len(uv):
                raise InputError(f"{path}: template.npz's face_uv does not match template.obj's faces")
        return Template(
            vertices=mesh.vertices, faces=mesh.faces, face_region=z["face_region"].astype(np.int16),
            frontal=z["frontal"].astype(bool), thickness=z["thickness"], skull_depth=z["skull_depth"],
            condyles=z["condyles"], fdp=fdp, parts=parts, level=int(z["level"]),
            thickness_factor=float(z["thickness_factor"]), uv=uv, face_uv=face_uv,
        )
    except InputError:
        raise
    except (KeyError, ValueError, TypeError, IndexError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        text = str(e).strip()
        raise InputError(f"{path / 'template.npz'}: unreadable ({text.splitlines()[0] if text else type(e).__name__})"
                         ) from None
