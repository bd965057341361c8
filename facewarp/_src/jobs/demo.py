"""``facewarp demo``: the whole main job on embedded defaults, from a scan to a USD animation.

1. the default template (level 0);
2. a synthetic scan of another face made by the package (:mod:`~facewarp._src.template.synthetic`:
   other proportions, millimetres, noise, holes, a random pose) with its FDPs
   -> ``scan/scan.obj``, ``scan/landmarks.json``, ``scan/markers.json`` (held-out FDPs);
3. adaptation of the template to the scan (:func:`~facewarp._src.jobs.adapt.adapt_files`)
   -> ``adapt/``; its vertex error E_v is measured against the scan's known truth;
4. anatomy (:func:`~facewarp._src.jobs.face.build_head_files`) -> ``build/`` and ``head.xml``
   (the MuJoCo cranium and mandible of the adapted head);
5. the Fig. 6.16 sequence (smile, laugh, surprise, angry, sad; :func:`~facewarp.thesis_sequence`,
   8 s with the relaxation after it, or squeezed into ``seconds``), simulated and streamed into
   ``animation.usdc`` frame by frame;
6. pictures: ``adapted_head.png`` (the adapted head coloured by its vertex error), ``expressions.png``
   (per expression the whole head at rest and at its peak, front and three-quarter views, over a
   displacement heat map; :func:`~facewarp.render.expression_sheet`), ``sequence.gif`` (the whole
   sequence, the whole head from the front, 15 fps);
7. ``report.json``: adaptation errors, anatomy quality, simulation speed, timings, files.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..adapt.transfer import load_head
from ..core.errors import InputError
from ..core.limits import (MAX_FPS, MAX_SECONDS, MAX_SEED, check_amount, check_count, check_memory,
                           estimate_build_bytes, estimate_frames_bytes)
from ..core.fileio import atomic_write, write_json
from ..coupling.drivers import JAWS, jaw_driver
from ..expressions import Timeline, thesis_sequence
from ..geometry.landmarks import save_landmarks_json
from ..geometry.mesh import load_mesh, save_obj
from ..physics.face_rig import load_face_rig
from ..present.animation import FaceView, label_grid, save_gif, skin_texture
from ..present.render import colormap, render_mesh, save_png
from ..present.strips import expression_sheet, sheet_font_size
from ..present.template import colored_scene
from ..sim.play import Sink, _play
from ..sim.simulator import FaceSimulator
from ..template.head import FRONTAL_REGIONS, REGIONS, default_template
from ..template.synthetic import synthetic_scan
from .adapt import adapt_files
from .animation import UsdAnimation, part_points, part_transforms, peak_frames, sim_controls
from .checks import check_out_dir, make_out_dir
from .face import build_head_files

__all__ = ["DEMO_STAGES", "QUICK_SECONDS", "demo_files", "demo_timeline"]

RELAX_SECONDS = 1.0
"""Time after the last expression of the sequence in which the face relaxes to rest [s]."""

QUICK_SECONDS = 0.2
"""Length of the sequence with ``quick`` [s] (7 frames at 30 fps)."""

GIF_FPS = 15.0
"""Frames per second of ``sequence.gif`` (every other simulated frame at 30 fps)."""

GIF_FACE_HEIGHT = 220
"""Height [px] of the face (hairline to chin) in ``sequence.gif`` (the whole head is about 1.8 times that)."""

DEMO_STAGES = ("template", "scan", "adapt", "anatomy", "simulate", "pictures", "report")
"""The steps ``progress`` is called with, in order."""


def demo_timeline(seconds: float | None = None) -> tuple[Timeline, float]:
    """The Fig. 6.16 sequence and its length [s].

    Without ``seconds``: :func:`~facewarp.thesis_sequence` and :data:`RELAX_SECONDS` after it
    (8 s). With ``seconds`` shorter than that, the whole sequence squeezed in time to fit (every
    start, attack, hold and release scaled alike), so a short run still shows every expression.
    """
    full = thesis_sequence()
    total = round(full.duration + RELAX_SECONDS, 9)
    if seconds is None:
        return full, total
    if not (isinstance(seconds, (int, float)) and not isinstance(seconds, bool) and math.isfinite(seconds)
            and seconds > 0):
        raise InputError(f"seconds: expected a finite number > 0, got {seconds!r}")
    if seconds >= total:
        return full, float(seconds)
    k = seconds / total
    return Timeline([replace(s, start=s.start * k, attack=s.attack * k, hold=s.hold * k, release=s.release * k)
                     for s in full.segments]), float(seconds)


def _stats_mm(e: np.ndarray) -> dict:
    e = np.asarray(e, dtype=np.float64) * 1e3
    return {"median": float(np.median(e)), "rms": float(np.sqrt(np.mean(e**2))), "p95": float(np.percentile(e, 95)),
            "max": float(e.max())}


def _write_scan(scan, folder: Path) -> dict:
    make_out_dir(folder)
    save_obj(folder / "scan.obj", scan.vertices, scan.faces, units=scan.units, colors=scan.colors)
    save_landmarks_json(folder / "landmarks.json", scan.landmarks, units=scan.units)
    save_landmarks_json(folder / "markers.json", scan.markers, units=scan.units)
    return {"scan": folder / "scan.obj", "landmarks": folder / "landmarks.json", "markers": folder / "markers.json"}


def _adaptation_errors(scan, adapt_dir: Path, template) -> tuple[dict, np.ndarray]:
    """E_v against the scan's truth (scan frame, mm) and the held-out markers' error; per-vertex E_v [m]."""
    m = load_mesh(adapt_dir / "adapted_scan_frame.obj", units=scan.units)
    e = np.linalg.norm(m.vertices - scan.truth, axis=1)
    frontal = np.isin(template.face_region, [REGIONS.index(r) for r in FRONTAL_REGIONS])
    face_v = np.unique(template.faces[frontal])
    marker = []
    for fid, p in scan.markers.items():
        part, sp = template.fdp[fid]
        if part == "head":
            marker.append(float(np.linalg.norm(sp.positions(m.vertices, template.faces)[0] - p)))
    return {"E_v_mm": _stats_mm(e), "E_v_face_mm": _stats_mm(e[face_v]),
            "marker_error_mm": _stats_mm(np.array(marker)) if marker else None,
            "marker_count": len(marker)}, e


def _adapted_picture(head, error: np.ndarray, path: Path, *, device: str, size: int) -> None:
    """The adapted head (template frame) coloured by its vertex error, front and three-quarter views."""
    top = max(1.0, float(np.ceil(np.percentile(error * 1e3, 98))))
    V, F, C = colored_scene(head)
    n = head.vertex_count
    C = C.copy()
    C[:n] = colormap(error * 1e3, 0.0, top)
    views = [render_mesh(V, F, view=v, width=size, height=size, vertex_colors=C, device=device)
             for v in ("front", "three_quarter")]
    grid = label_grid([views], column_labels=["front", "three-quarter"])
    save_png(path, grid, title=f"adapted head: error E_v, median {np.median(error) * 1e3:.2f} mm",
             colorbar=(0.0, top, "distance to the true point [mm]"))


def _likeness_picture(scan, adapt_dir: Path, template, path: Path, *, device: str, size: int) -> dict:
    """``likeness.png``: the adapted head with its baked texture beside the scan with its own colour,
    from the same cameras (front, three-quarter), and the CIELAB figures of
    :func:`~facewarp._src.present.compare.likeness_views` in the title; returns the figures."""
    from PIL import Image

    from ..present.compare import likeness_views

    m = load_mesh(adapt_dir / "adapted_scan_frame.obj", units=scan.units)
    with Image.open(adapt_dir / "texture.png") as img:
        tex = np.asarray(img.convert("RGB"))

    def to_template(X):  # undo the scan's pose: both seen from the template's front
        return (np.asarray(X) - scan.translation) @ scan.rotation

    res = likeness_views(to_template(m.vertices), template.faces, tex, template.uv[template.face_uv],
                         template.frontal, to_template(scan.vertices), scan.faces, scan_colors=scan.colors,
                         size=size, device=device)
    rows = [[head, sc] for head, sc, _ in res["images"].values()]
    grid = label_grid(rows, column_labels=["adapted head, baked texture", "scan"])
    mean = res["mean"]
    save_png(path, grid, title=f"likeness: Delta E {mean['delta_e_mean']['textured']:.2f} (flat colour "
                               f"{mean['delta_e_mean']['flat']:.2f}), L* correlation "
                               f"{mean['lightness_correlation']['textured']:.2f}")
    return {k: v for k, v in res.items() if k != "images"}


class _KeyFrames(Sink):
    """Keeps the surface and part vertices of a few frames (the expression sheet)."""

    def __init__(self, fr, frames: dict):
        self.fr, self.want = fr, frames
        self.points: dict = {}
        self.parts: dict = {}

    def frame(self, sim, k: int, t: float) -> None:
        if k in self.want.values():
            self.points[k] = sim.surface()
            self.parts[k] = part_points(self.fr, sim_controls(sim)[1])


class _GifFrames(Sink):
    """Renders every ``every``-th frame with a fixed camera."""

    def __init__(self, view: FaceView, fr, every: int):
        self.view, self.fr, self.every = view, fr, max(1, int(every))
        self.images: list = []

    def frame(self, sim, k: int, t: float) -> None:
        if k % self.every == 0:
            self.images.append(self.view.render(sim.surface(), part_transforms(self.fr, sim_controls(sim)[1])))


def _jaw_bounds(fr, timeline: Timeline, seconds: float, fps: float) -> list:
    """The head at rest and with the jaw at the widest opening of ``timeline`` (converted for
    ``fr``, :meth:`~facewarp.Timeline.for_head`; moved kinematically by its Eq. 6.4.9 amounts):
    what the GIF's fixed camera frames."""
    times = np.arange(int(round(seconds * fps)) + 1) / fps
    e = max((timeline.sample(float(t)) for t in times), key=lambda x: x.jaw_u)
    V = fr.head_vertices
    opened = fr.jaw.apply(V, fr.vertex_jaw, e.jaw_u, e.jaw_v) if fr.vertex_jaw is not None else V
    return [V, opened]


def _expression_sheet(fr, landmarks, keys: _KeyFrames, labels: list, path: Path, *, device: str,
                      face_height: int, fps: float, texture=None) -> float:
    """``expressions.png``: per expression rest | peak, front and three-quarter over the displacement
    heat map (:func:`~facewarp.render.expression_sheet`); returns the heat top [m]."""
    shots = [(name, keys.points[k], keys.parts[k], f"peak, {k / fps:.2f} s") for name, k in labels]
    sheet, top = expression_sheet(fr.head_vertices, fr.head_faces, landmarks, dict(fr.parts), shots,
                                  face_height=face_height, columns=3, device=device, texture=texture)
    save_png(path, sheet, title="Fig. 6.16 sequence: rest and peak of each expression",
             colorbar=(0.0, top * 1e3, "displacement from rest [mm]"), font_size=sheet_font_size(sheet))
    return top


def demo_files(out, *, seconds: float | None = None, quick: bool = False, device: str = "cpu",
               jaw: str = "mujoco", seed: int = 0, fps: float = 30.0, progress=None, frame_progress=None) -> dict:
    """Run the demo into the folder ``out`` (see the module docstring); returns the report.

    Args:
        out: Output folder (created; files in it are replaced).
        seconds: Length of the sequence [s] (> 0); default the full sequence (8 s), shorter
            squeezes it (:func:`demo_timeline`).
        quick: A smoke run: :data:`QUICK_SECONDS` of sequence (unless ``seconds`` is given), two
            refinement levels of the adaptation instead of five, smaller pictures.
        device: Warp device for adaptation queries, simulation and pictures.
        jaw: ``"mujoco"`` (default: the hinge body of ``head.xml``, two-way coupled) or ``"kinematic"``.
        seed: Seed of the synthetic scan (face proportions, noise, holes, pose).
        fps: Frames per second of the animation.
        progress: Optional ``progress(stage)`` with the names of :data:`DEMO_STAGES`.
        frame_progress: Optional ``frame_progress(k, frame_count)`` while simulating.
    """
    t_start = time.perf_counter()
    step = progress or (lambda msg: None)
    out = check_out_dir(out)
    if jaw not in JAWS:
        raise InputError(f"jaw: expected one of {', '.join(JAWS)}, got {jaw!r}")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise InputError(f"fps: expected a finite number > 0, got {fps!r}")
    timeline, seconds = demo_timeline(QUICK_SECONDS if quick and seconds is None else seconds)
    check_amount("seconds", seconds, high=MAX_SECONDS)
    check_amount("fps", fps, high=MAX_FPS)
    check_count("seed", seed, low=0, high=MAX_SEED)
    frames = round(seconds * fps) + 1  # USD time samples (held until the file is saved) and GIF pictures
    level0 = default_template(0)
    check_memory(estimate_build_bytes(len(level0.vertices), len(level0.faces), 1)
                 + estimate_frames_bytes(frames, 2 * len(level0.vertices)),
                 f"seconds: {frames} frames of the demo's head")
    size = 200 if quick else 360
    face_height = 160 if quick else 400
    make_out_dir(out)
    timings: dict = {}

    def lap(name: str, t0: float) -> float:
        now = time.perf_counter()
        timings[name] = round(now - t0, 3)
        return now

    t = time.perf_counter()
    step("template")
    template = default_template(0)
    t = lap("template", t)

    step("scan")
    scan = synthetic_scan(seed, level=template.level)
    files = _write_scan(scan, out / "scan")
    t = lap("scan", t)

    step("adapt")
    adapt_dir = out / "adapt"
    adapt_report = adapt_files(files["scan"], files["landmarks"], adapt_dir, markers=files["markers"],
                               units=scan.units, levels=2 if quick else 5, device=device,
                               texture_size=1024 if quick else 2048)
    errors, e_v = _adaptation_errors(scan, adapt_dir, template)
    t = lap("adapt", t)

    step("anatomy")
    head = load_head(adapt_dir)
    build_dir = out / "build"
    quality = build_head_files(head, build_dir, device=device)
    for name in ("head.xml", "scene.xml"):  # the head body tree and its standalone scene
        with atomic_write(out / name, "w") as f:
            f.write((build_dir / name).read_text())
    if (build_dir / "texture.png").is_file():  # the skin texture head.xml names (beside it)
        with atomic_write(out / "texture.png", "wb", encoding=None) as f:
            f.write((build_dir / "texture.png").read_bytes())
    t = lap("anatomy", t)

    step("simulate")
    fr = load_face_rig(build_dir)
    timeline = timeline.for_head(fr)  # chin drops -> this head's jaw angles, once (play keeps it)
    sim = FaceSimulator(fr, device=device, fps=fps)
    landmarks = dict(zip((str(k) for k in fr.fdp_ids), sim.fdp_points()))
    labels = peak_frames(timeline, seconds, fps)
    keys = _KeyFrames(fr, dict(labels))
    skin = skin_texture(fr)
    gif_view = FaceView(fr.head_vertices, fr.head_faces, landmarks, fr.parts,
                        face_height=100 if quick else GIF_FACE_HEIGHT, bounds=_jaw_bounds(fr, timeline, seconds, fps),
                        supersample=1, device=device, texture=skin)
    gif = _GifFrames(gif_view, fr, int(round(fps / GIF_FPS)))
    driver = jaw_driver(sim, jaw, mjcf=out / "head.xml")
    with UsdAnimation(out / "animation.usdc", sim) as usd:
        sim_stats = _play(sim, timeline, seconds, [usd, keys, gif], driver, frame_progress).to_dict()
    t = lap("simulate", t)

    step("pictures")
    _adapted_picture(head, e_v, out / "adapted_head.png", device=device, size=size)
    likeness = None
    if skin is not None:
        likeness = _likeness_picture(scan, adapt_dir, template, out / "likeness.png", device=device, size=size)
    labels = [(name, k) for name, k in labels if k in keys.points]
    heat_top = _expression_sheet(fr, landmarks, keys, labels, out / "expressions.png", device=device,
                                 face_height=face_height, fps=fps, texture=skin)
    save_gif(out / "sequence.gif", gif.images, fps=fps / gif.every)
    t = lap("pictures", t)

    step("report")
    d = adapt_report["distance_to_scan_m"]
    report = {
        "demo": {"seed": int(seed), "seconds": seconds, "fps": float(fps), "device": device, "jaw": jaw,
                 "quick": bool(quick), "sequence": [name for name, _ in labels]},
        "scan": {"vertex_count": int(len(scan.vertices)), "face_count": int(len(scan.faces)), "units": scan.units,
                 "landmark_count": len(scan.landmarks), "marker_count": len(scan.markers),
                 "pose": {"rotation_deg": float(np.degrees(np.arccos(np.clip((np.trace(scan.rotation) - 1) / 2, -1, 1)))),
                          "translation_mm": (scan.translation * 1e3).tolist()},
                 "proportions": scan.proportions.to_dict()},
        "adaptation": {"seconds": adapt_report["seconds"], "method": adapt_report["method"],
                       "fp_count": adapt_report["fp_count"], "levels": len(adapt_report["levels"]),
                       "distance_to_scan_mm": {k: v * 1e3 for k, v in d.items()}, **errors},
        "anatomy": {k: quality.get(k) for k in ("tet_count", "inverted_count", "min_dihedral_deg", "max_dihedral_deg",
                                                "conforming", "boundary_intersection_count", "muscle_count",
                                                "min_attached_nodes")},
        "simulation": {**sim_stats, "nodes": int(len(fr.nodes)), "tets": int(len(fr.tets)),
                       "head_vertices": int(len(fr.head_vertices)), "usd_frames": usd.frame_count,
                       "realtime_factor": sim_stats["frames_per_second"] / float(fps),
                       "max_displacement_mm": heat_top * 1e3},
        "likeness": likeness and {"views": likeness["views"], "mean": likeness["mean"],
                                  "texture": adapt_report.get("texture")},
        "timings_s": timings,
        "files": sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() and not p.name.startswith(".")),
    }
    report["timings_s"]["total"] = round(time.perf_counter() - t_start, 3)
    report["files"] = sorted(set(report["files"]) | {"report.json"})
    write_json(out / "report.json", report)
    return report
