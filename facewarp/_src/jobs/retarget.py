"""``facewarp retarget``: one activation sequence played on several heads (thesis Ch. 7).

Every head gets the same timeline (a sequence file, a preset or ``"sequence"``) and the same
physical parameters (the simulator's defaults: material, muscle stiffness, jaw); only its own
anatomy differs. Each head's animation streams into ``<name>.usdc`` as it is simulated
(:mod:`~facewarp._src.jobs.animation`); ``retarget.png`` shows the heads in rows at rest and at
the peak of each segment (front views), and ``report.json`` the speed and the largest motion of
a few FDPs per head.

Heads are ``facewarp build`` outputs (``face_rig.npz``) or anything :func:`~facewarp.load_head`
takes (template folders, ``adapt`` outputs, ``"default[:LEVEL]"``), whose anatomy is then built
in memory.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np

from ..adapt.transfer import load_head
from ..core.errors import InputError
from ..core.limits import MAX_FPS, MAX_HEADS, MAX_SECONDS, check_amount, check_work, estimate_frames_bytes
from ..core.outputs import destination
from ..core.fileio import write_json
from ..expressions import PRESETS, load_sequence, timeline_from_spec
from ..anatomy.rig import build_face
from ..physics.face_rig import load_face_rig
from ..present.animation import FaceView, label_grid, skin_texture
from ..present.render import save_png
from ..sim.play import _play
from ..sim.simulator import FaceSimulator
from .animation import FdpMotion, UsdAnimation, part_transforms, sim_controls
from .checks import check_apart, check_out_dir, check_some_frames, make_out_dir

__all__ = ["RELAX_SECONDS", "TRACKED_FDPS", "load_rig", "retarget_files"]

RELAX_SECONDS = 0.5
"""Time after a sequence file's last segment in the default length [s]."""

TRACKED_FDPS = ("2.1", "4.1", "4.2", "8.3", "8.4")
"""FDPs whose largest motion the report gives per head: chin, inner brows, lip corners."""


def load_rig(head):
    """The face rig of ``head``: a ``build`` output folder, or a head :func:`~facewarp.load_head`
    takes (anatomy built in memory)."""
    p = Path(str(head))
    if p.is_dir() and (p / "face_rig.npz").is_file():
        return load_face_rig(p)
    return build_face(load_head(head))


def _default_seconds(expression: str) -> float:
    if expression in PRESETS:
        return 2.0
    if expression == "sequence":
        return 8.0
    return load_sequence(expression).duration + RELAX_SECONDS


def _names(heads) -> list[str]:
    """File-safe, unique names of the heads (folder names; ``default:0`` -> ``default_0``)."""
    out: list[str] = []
    for h in heads:
        base = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(str(h).rstrip("/")).name or str(h)).strip("._") or "head"
        name, i = base, 2
        while name.lower() in (o.lower() for o in out):  # one file per head, also where case is ignored
            name, i = f"{base}_{i}", i + 1
        out.append(name)
    return out


class _Tracker(FdpMotion):
    """Largest distance from rest of the tracked FDPs (:data:`TRACKED_FDPS`), and the frames of the strip."""

    def __init__(self, want: set):
        super().__init__(TRACKED_FDPS)
        self.shots = want
        self.frames: dict = {}

    def frame(self, sim, k: int, t: float) -> None:
        super().frame(sim, k, t)
        if k in self.shots:
            self.frames[k] = (sim.surface(), part_transforms(sim.fr, sim_controls(sim)[1]))


def retarget_files(expression, heads, out, *, seconds: float | None = None, fps: float = 30.0, device: str = "cpu",
                   size: int = 280, progress=None, frame_progress=None) -> dict:
    """Play ``expression`` on every head of ``heads`` into ``out`` (see the module docstring).

    Args:
        expression: A sequence ``.json`` file, a preset name or ``"sequence"``.
        heads: At least one head (see the module docstring).
        out: Output folder.
        seconds: Length [s] (> 0); default a sequence file's length plus :data:`RELAX_SECONDS`,
            2 s for a preset, 8 s for ``"sequence"``.
        fps: Frames per second.
        device: Warp device.
        size: Height and width of each picture in the strip [px].
        progress: Optional ``progress(message)``; ``frame_progress(k, frame_count)`` while simulating.

    Returns:
        The report (also written as ``report.json``).

    Raises:
        InputError: a missing or bad sequence file or head, a bad number.
    """
    step = progress or (lambda msg: None)
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a callable progress(message) or None, got {type(progress).__name__}")
    if frame_progress is not None and not callable(frame_progress):
        raise InputError(f"frame_progress: expected a callable frame_progress(k, frame_count) or None, got "
                         f"{type(frame_progress).__name__}")
    if not isinstance(expression, (str, os.PathLike)) or not str(expression).strip():
        raise InputError(f"expression: expected a sequence file, a preset name or 'sequence', got {expression!r:.60}")
    if not isinstance(out, (str, os.PathLike)) or not str(out).strip():
        raise InputError(f"out: expected a folder path, got {out!r:.60}")
    if isinstance(heads, (str, bytes, os.PathLike)) or not hasattr(heads, "__iter__"):
        raise InputError(f"heads: expected a list of heads (build folders, template folders, 'default[:LEVEL]'), "
                         f"got {type(heads).__name__} {heads!r:.60}")
    if not (isinstance(size, int) and not isinstance(size, bool) and 32 <= size <= 4096):
        raise InputError(f"size: expected a whole number of pixels 32..4096, got {size!r}")
    out = check_out_dir(out)
    heads = list(heads)
    bad = next((h for h in heads if not isinstance(h, (str, os.PathLike))), None)
    if bad is not None:
        raise InputError(f"heads: expected head paths or 'default[:LEVEL]', got {type(bad).__name__} {bad!r:.40}")
    if not heads:
        raise InputError("heads: expected at least one head")
    if len(heads) > MAX_HEADS:
        raise InputError(f"heads: at most {MAX_HEADS} heads per run, got {len(heads)}")
    check_amount("fps", fps, high=MAX_FPS)
    if seconds is not None:
        check_amount("seconds", seconds, high=MAX_SECONDS)
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise InputError(f"fps: expected a finite number > 0, got {fps!r}")
    expression = str(expression)
    if seconds is None:
        seconds = _default_seconds(expression)
    timeline = timeline_from_spec(expression, seconds)  # checks seconds and reads the file
    check_some_frames(seconds, fps)
    for h in heads:  # missing heads fail before any simulation
        p = Path(str(h))
        if not (str(h) == "default" or str(h).startswith("default:")) and not p.exists():
            raise InputError(f"{h}: no such head folder")
    names = _names(heads)
    expr_file = Path(expression) if expression.lower().endswith(".json") else None
    check_apart([("out", out, "dir")] + [("out", out / f"{n}.usdc", "file") for n in names]
                + [("out", out / "retarget.png", "file"), ("out", out / "report.json", "file")],
                [("HEAD", h) for h in heads if not str(h).startswith("default")] + [("SEQUENCE", expr_file)])
    nf = int(round(seconds * fps)) + 1
    V = 3415  # the level-0 head's surface: the least a head has (its rig is read later)
    check_work(f"seconds, fps: {len(heads)} heads x {nf} frames", head_frames=len(heads) * (nf - 1), vertex_count=V,
               device=str(device), disk_bytes=len(heads) * estimate_frames_bytes(nf, V), folder=destination(out))
    labels = [("rest", 0)] + [(s.expression.name, int(round((s.start + s.attack + 0.5 * s.hold) * fps)))
                              for s in timeline.segments if s.start + s.attack + 0.5 * s.hold <= seconds][:6]
    make_out_dir(out)
    rows, per_head = [], []
    for i, (head, name) in enumerate(zip(heads, names)):
        step(f"{name} ({i + 1}/{len(heads)}): anatomy")
        fr = load_rig(head)
        sim = FaceSimulator(fr, device=device, fps=fps)
        track = _Tracker({k for _, k in labels})
        lm = dict(zip((str(k) for k in fr.fdp_ids), sim.fdp_points()))
        step(f"{name} ({i + 1}/{len(heads)}): simulating")
        with UsdAnimation(out / f"{name}.usdc", sim) as usd:
            stats = _play(sim, timeline, seconds, [usd, track], None, frame_progress)  # the kinematic jaw
        view = FaceView(fr.head_vertices, fr.head_faces, lm, fr.parts, size=size, device=device)
        used = np.concatenate([P[view.used] for P, _ in track.frames.values()])
        view = FaceView(fr.head_vertices, fr.head_faces, lm, fr.parts, size=size, aspect=0.6, device=device,
                        bounds=np.stack([used.min(0) - 0.004, used.max(0) + 0.004]), texture=skin_texture(fr))
        rows.append([view.render(*track.frames[k]) for _, k in labels if k in track.frames])
        per_head.append({
            "head": str(head), "name": name, "usd": str(out / f"{name}.usdc"), "vertex_count": int(len(fr.head_vertices)),
            "tets": int(len(fr.tets)), "frames": stats.frames, "frames_per_second": stats.frames_per_second,
            "steps_per_second": stats.steps_per_second, "substeps": stats.substeps,
            "max_fdp_motion_mm": {k: float(v * 1e3) for k, v in zip(track.ids, track.moved)},
        })
    step("picture")
    grid = label_grid(rows, column_labels=[n for n, k in labels], row_labels=names)
    save_png(out / "retarget.png", grid, title=f"{Path(expression).name} on {len(heads)} heads")
    report = {"expression": expression, "seconds": float(seconds), "fps": float(fps), "device": device,
              "heads": per_head, "files": [h["usd"] for h in per_head] + [str(out / "retarget.png"),
                                                                         str(out / "report.json")]}
    write_json(out / "report.json", report)
    return report
