"""File-level jobs behind ``facewarp build`` and ``facewarp simulate``.

``build`` turns a head folder (a ``template export`` or an ``adapt`` output) into anatomy
(Sec. 6.2, 6.3, 6.6) and a simulation-ready :class:`~facewarp._src.face.FaceRig`;
``simulate`` plays an expression on it (Sec. 6.4, 6.5) and writes the frames.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = ["load_head", "build_files", "simulate_files", "render_strip", "displacement_max"]


def _head_from_adapt_dir(path: Path):
    """The template an ``adapt`` output was made from, carried onto the adapted shape (Sec. 6.6):
    same faces, FDP surface points, regions, per-vertex thickness and skull depth; rigid parts
    and condyles follow the FDPs (Eq. 6.6.1-6.6.4 for the eyes, a least-squares similarity for
    the rest)."""
    from .mesh import load_mesh
    from .rigid import eye_transform, fit_part_transform
    from .template import default_template
    from .template.export import load_template_dir

    rep_path = path / "report.json"
    try:
        rep = json.loads(rep_path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(f"{path}: not an adapt output (report.json unreadable: {e})") from None
    tmpl = str(rep.get("template", ""))
    if tmpl.startswith("default template"):
        t = default_template(0)
    elif tmpl and Path(tmpl).is_dir():
        t = load_template_dir(tmpl)
    else:
        raise InputError(f"{path}: adapted from {tmpl or 'an unknown template'}, which carries no regions, "
                         "skull or muscles; adapt with the default template or a template folder to build anatomy")
    m = load_mesh(path / "adapted.obj")
    if m.vertices.shape != t.vertices.shape or not np.array_equal(m.faces, t.faces):
        raise InputError(f"{path / 'adapted.obj'}: topology does not match its template "
                         f"({len(m.vertices)} vs {t.vertex_count} vertices)")
    tl = t.landmarks()
    adapted = replace(t, vertices=m.vertices, parts=dict(t.parts))
    al = {k: v for k, v in adapted.landmarks().items() if t.fdp[k][0] == "head"}
    parts = {}
    for name, (V, F) in t.parts.items():
        if name in ("eye_L", "eye_R"):
            sim = eye_transform(tl, al, V.mean(0), side="left" if name == "eye_L" else "right")
        else:
            ids = ["8.1", "8.2", "8.3", "8.4", "2.2", "2.3", "9.15", "2.1"]
            sim = fit_part_transform(tl, al, ids)
        parts[name] = (sim.apply(V), F)
    ids = [k for k in ("2.1", "3.7", "3.12", "8.3", "8.4", "10.9", "10.10", "9.3", "11.1") if k in al]
    condyles = fit_part_transform(tl, al, ids).apply(t.condyles)
    return replace(adapted, parts=parts, condyles=condyles, level=t.level)


def load_head(path) -> object:
    """A head to build anatomy on: a template folder, an adapt output, or the word ``default``."""
    from .template import default_template
    from .template.export import load_template_dir

    if str(path) in ("default", "default:0", "default:1", "default:2", "default:3"):
        level = int(str(path).split(":")[1]) if ":" in str(path) else 0
        return default_template(level)
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such head folder")
    if not path.is_dir():
        raise InputError(f"{path}: HEAD must be a folder (a `template export` or `adapt` output)")
    if (path / "template.npz").is_file():
        return load_template_dir(path)
    if (path / "adapted.obj").is_file():
        return _head_from_adapt_dir(path)
    raise InputError(f"{path}: neither a template folder (template.npz) nor an adapt output (adapted.obj)")


def build_files(head_path, out, *, layers: int = 1, device: str = "cpu", progress=None) -> dict:
    """Build anatomy and the face rig of a head folder into ``out``; returns the quality report."""
    from .anatomy import build_anatomy, render_anatomy, write_anatomy
    from .face import face_rig_from_anatomy, save_face_rig
    from .render import save_png

    step = progress or (lambda msg: None)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    if layers < 1:
        raise InputError(f"--layers: expected >= 1, got {layers}")
    step("loading head")
    head = load_head(head_path)
    step("skin layer and muscles")
    anatomy = build_anatomy(head, layers=layers)
    fr = face_rig_from_anatomy(anatomy)
    step("writing")
    write_anatomy(anatomy, out, image=False)
    save_face_rig(out / "face_rig.npz", fr)
    q = dict(anatomy.quality)
    q["boundary_conditions"] = {"fixed_nodes": int(fr.fixed.sum()), "held_nodes": int(fr.held.sum()),
                                "supported_nodes": int(len(fr.support_nodes)), "jaw_nodes": int(len(fr.jaw_nodes))}
    from .fileio import write_json

    write_json(out / "anatomy.json", q)
    step("picture")
    img = render_anatomy(anatomy, device=device, fixed=fr.nodes[fr.fixed], held=fr.nodes[fr.held])
    save_png(out / "anatomy.png", img,
             title=f"{q['tet_count']} tets ({q['inverted_count']} inverted), {q['muscle_count']} muscles; "
                   "black: fixed border, grey: held on bone")
    return q


def _timeline(expression: str, seconds: float):
    from .expressions import PRESETS, load_sequence, thesis_sequence, timeline_for

    if expression in PRESETS:
        ramp = min(0.3, seconds / 4)
        return timeline_for(expression, attack=ramp, hold=max(seconds - 2 * ramp - 0.1, 0.0), release=ramp, start=0.05)
    if expression == "sequence":
        return thesis_sequence(each=max(seconds / 5 + 0.3, 0.8))
    p = Path(expression)
    if p.suffix.lower() == ".json" or p.exists():
        return load_sequence(p)
    raise InputError(f"--expression {expression!r}: not a preset ({', '.join(PRESETS)}), 'sequence', or a sequence .json file")


def render_strip(frames, idx, *, size: int = 360, device: str = "cpu", view="front",
                 heat_max: float | None = None) -> np.ndarray:
    """Renders of the face (cropped below the chin and behind the ears) for frames ``idx``,
    side by side, with eyes and teeth; the lips (between FDPs 8.1, 8.2 and the corners) tinted.

    With ``heat_max`` [m], a second row shows each frame's displacement from frame 0 as a
    heat map from 0 to ``heat_max`` (turbo), which makes a few millimetres of motion visible.
    """
    from .render import colormap, render_mesh

    P0 = frames.points[0]
    ids = list(map(str, frames.fdp_ids))
    lm0 = {k: frames.fdp_points[0, i] for i, k in enumerate(ids)}
    c = P0[frames.faces].mean(1)
    keep = (c[:, 1] > lm0["2.1"][1] - 0.03) & (c[:, 2] > lm0["3.7"][2] - 0.06) & (c[:, 1] < lm0["11.1"][1] + 0.02)
    F = frames.faces[keep]
    # vertex colours: skin, with the vermilion tinted on the front of the face
    from .template.export import LIPS, SKIN, vermilion_weight

    front = P0[:, 2] > 0.5 * (lm0["2.2"][2] + lm0["2.3"][2]) - 0.02
    w = vermilion_weight(P0, lm0, front)[:, None]
    col = SKIN * (1 - w) + LIPS * w
    extra_of = lambda k: [(V[k], Fp, (0.96, 0.96, 0.94) if n.startswith(("eye", "teeth")) else (0.8, 0.45, 0.45))  # noqa: E731
                          for n, (V, Fp) in frames.parts.items()]
    row = [render_mesh(frames.points[k], F, view=view, width=size, height=size, vertex_colors=col,
                       extra_meshes=extra_of(k), device=device) for k in idx]
    img = np.concatenate(row, axis=1)
    if heat_max is None:
        return img
    heat = []
    for k in idx:
        d = np.linalg.norm(frames.points[k] - P0, axis=1)
        heat.append(render_mesh(frames.points[k], F, view=view, width=size, height=size,
                                vertex_colors=colormap(d, 0.0, max(float(heat_max), 1e-9)),
                                extra_meshes=extra_of(k), device=device))
    return np.concatenate([img, np.concatenate(heat, axis=1)], axis=0)


def displacement_max(frames, idx) -> float:
    """Largest displacement [m] of a head vertex from frame 0 over frames ``idx`` (the heat
    map's top, rounded up to a whole millimetre)."""
    d = max(float(np.linalg.norm(frames.points[k] - frames.points[0], axis=1).max()) for k in idx)
    return max(1e-3, float(np.ceil(d * 1e3)) * 1e-3)


def simulate_files(head_path, expression: str, out, *, seconds: float = 2.0, fps: float = 30.0,
                   substeps: int | None = None, device: str = "cpu", usd: bool = False, progress=None) -> dict:
    """Simulate ``expression`` on a ``build`` output and write frames.npz / frames.png (/ frames.usda)."""
    from .face import FaceSimulator, load_face_rig, save_frames_npz
    from .render import save_png

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    if not (seconds > 0 and math.isfinite(seconds)):
        raise InputError(f"--seconds: expected a positive number, got {seconds}")
    if not (fps > 0 and math.isfinite(fps)):
        raise InputError(f"--fps: expected a positive number, got {fps}")
    if substeps is not None and substeps < 1:
        raise InputError(f"--substeps: expected >= 1, got {substeps}")
    fr = load_face_rig(head_path)
    timeline = _timeline(expression, seconds)
    sim = FaceSimulator(fr, device=device, substeps=substeps, fps=fps)
    frames = sim.run(timeline, seconds, progress=progress)
    out.mkdir(parents=True, exist_ok=True)
    save_frames_npz(out / "frames.npz", frames)
    nf = len(frames.times)
    idx = np.unique(np.linspace(0, nf - 1, min(6, nf)).round().astype(int))
    hmax = displacement_max(frames, idx)
    strip = render_strip(frames, idx, device=device, heat_max=hmax)
    labels = ", ".join(f"{frames.times[k]:.2f} s" for k in idx)
    save_png(out / "frames.png", strip, title=f"{Path(str(expression)).name}: {labels}",
             colorbar=(0.0, hmax * 1e3, "displacement from rest [mm]"))
    written = ["frames.npz", "frames.png"]
    if usd:
        from usd_export import write_meshes_usd

        meshes = {"skin": (fr.head_vertices, fr.head_faces), **{k: (V[0], F) for k, (V, F) in frames.parts.items()}}
        fr_pts = {"skin": frames.points, **{k: V for k, (V, F) in frames.parts.items()}}
        write_meshes_usd(out / "frames.usda", meshes, frames=fr_pts, times=frames.times, fps=fps)
        written.append("frames.usda")
    moved = np.linalg.norm(frames.fdp_points - frames.fdp_points[:1], axis=2).max(0)
    return {
        "expression": str(expression), "frames": nf, "seconds": float(seconds), "fps": fps, "substeps": sim.substeps,
        "dt_s": sim.dt, "steps_per_second": frames.steps_per_second, "device": str(sim.device),
        "nodes": int(len(fr.nodes)), "tets": int(len(fr.tets)), "files": [str(out / w) for w in written],
        "max_fdp_motion_m": {str(k): float(v) for k, v in zip(frames.fdp_ids, moved) if v > 1e-4},
    }
