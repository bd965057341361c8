"""File-level jobs behind ``facewarp build`` and ``facewarp simulate``.

``build`` turns a head folder (a ``template export`` or an ``adapt`` output) into anatomy
(Sec. 6.2, 6.3, 6.6) and a simulation-ready :class:`~facewarp._src.physics.face_rig.FaceRig`;
``simulate`` plays an expression on it (Sec. 6.4, 6.5) and writes the frames.
"""

from __future__ import annotations

import contextlib
import math
from pathlib import Path

import numpy as np

from ..adapt.transfer import load_head
from ..anatomy.build import build_anatomy, write_anatomy
from ..core.errors import InputError
from ..core.fileio import write_json
from ..core.limits import (MAX_FPS, MAX_LAYERS, MAX_SECONDS, MAX_SUBSTEPS, check_amount, check_count,
                           check_memory, check_steps, estimate_build_bytes, estimate_sim_bytes)
from ..coupling.mjcf import write_head_mjcf
from ..expressions import timeline_from_spec
from ..physics.face_rig import face_rig_from_anatomy, load_face_rig, save_face_rig
from ..present.anatomy import render_anatomy
from ..present.render import save_png
from ..present.strips import frames_sheet, sheet_font_size
from ..sim.simulator import FaceSimulator, save_frames_npz
from .animation import (JAWS, USD_SUFFIXES, UsdAnimation, check_usd_path, jaw_driver, load_mjcf, peak_frames,
                        play_timeline)
from .checks import check_out_dir, make_out_dir

__all__ = ["MAX_FRAMES", "USD_NAME", "build_files", "build_head_files", "simulate_files"]

USD_NAME = "animation.usdc"
"""The USD animation ``simulate --usd`` writes into its output folder."""

MAX_FRAMES = 100_000
"""Most frames one ``simulate`` run keeps in memory (about 1 h at 30 fps; a level-0 head takes
about 60 kB a frame)."""


def build_files(head_path, out, *, layers: int = 1, device: str = "cpu", progress=None) -> dict:
    """Build anatomy and the face rig of a head folder into ``out``; returns the quality report."""
    step = progress or (lambda msg: None)
    out = check_out_dir(out)
    _check_layers(layers)
    step("loading head")
    head = load_head(head_path)
    return build_head_files(head, out, layers=layers, device=device, progress=progress)


def _check_layers(layers) -> None:
    check_count("layers", layers, high=MAX_LAYERS)


def build_head_files(head, out, *, layers: int = 1, device: str = "cpu", progress=None) -> dict:
    """Build anatomy and the face rig of ``head`` (a :class:`~facewarp.Template`) into ``out``.

    Writes ``tets.npz``, ``muscles.json``, ``anatomy.json``, ``face_rig.npz``, ``head.xml`` (the
    MuJoCo cranium and mandible, :func:`~facewarp.write_head_mjcf`) and ``anatomy.png``; returns
    the quality report.
    """
    step = progress or (lambda msg: None)
    out = check_out_dir(out)
    _check_layers(layers)
    check_memory(estimate_build_bytes(len(head.vertices), len(head.faces), layers),
                 f"layers: {layers} tet layers under {len(head.faces)} skin triangles")
    make_out_dir(out)
    step("skin layer and muscles")
    anatomy = build_anatomy(head, layers=layers)
    fr = face_rig_from_anatomy(anatomy)
    step("writing")
    write_anatomy(anatomy, out)
    save_face_rig(out / "face_rig.npz", fr)
    write_head_mjcf(out / "head.xml", head, jaw=fr.jaw)
    q = dict(anatomy.quality)
    q["boundary_conditions"] = {"fixed_nodes": int(fr.fixed.sum()), "held_nodes": int(fr.held.sum()),
                                "supported_nodes": int(len(fr.support_nodes)), "jaw_nodes": int(len(fr.jaw_nodes))}
    write_json(out / "anatomy.json", q)
    step("picture")
    img = render_anatomy(anatomy, device=device, fixed=fr.nodes[fr.fixed], held=fr.nodes[fr.held])
    save_png(out / "anatomy.png", img,
             title=f"{q['tet_count']} tets ({q['inverted_count']} inverted), {q['muscle_count']} muscles; "
                   "black: fixed border, grey: held on bone")
    return q


def simulate_files(head_path, expression: str, out, *, seconds: float = 2.0, fps: float = 30.0,
                   substeps: int | None = None, device: str = "cpu", usd: bool = False, tets: bool = False,
                   progress=None, solver: str = "implicit", material: str = "physical", jaw: str = "mujoco") -> dict:
    """Simulate ``expression`` on a ``build`` output and write its frames.

    ``expression`` is what :func:`~facewarp.timeline_from_spec` reads: a preset, ``"sequence"``,
    a sequence file, or a user's own ``"muscle=value,...,jaw_drop_mm=D"``; chin drops become this
    head's jaw angles by its condyle-to-chin lever (:meth:`~facewarp.Timeline.for_head`).

    ``solver`` (``"implicit"``, default, or ``"verlet"``) and ``material`` (``"physical"``, default,
    or ``"thesis"``) choose the :class:`~facewarp.FaceSimulator`'s solver and material profile;
    ``--solver verlet --material thesis`` is the simulator before issue 10. ``jaw``: ``"mujoco"``
    (default: the mandible is the hinge body of the build's ``head.xml``, two-way coupled to the
    skin, the expressions' jaw angles its actuator targets) or ``"kinematic"`` (Eq. 6.4.9 angles
    imposed directly).

    ``out`` is a folder (``frames.npz``, ``frames.png``: per expression the whole head at rest and
    at its peak, front and three-quarter, over its displacement heat map; and with ``usd`` the USD animation
    :data:`USD_NAME`, streamed while simulating) or a ``.usda`` / ``.usdc`` / ``.usdz`` file: then
    only that animation is written, streamed frame by frame with no frame kept in memory and no
    frame cap (:mod:`~facewarp._src.jobs.animation`). With ``tets`` the USD also holds the skin's
    tet layer (a ``TetMesh`` of purpose ``guide``).
    """
    usd_out = Path(out).suffix.lower() in USD_SUFFIXES
    out = check_usd_path(out) if usd_out else check_out_dir(out)
    for name, v in (("seconds", seconds), ("fps", fps)):
        if not (isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
                and math.isfinite(v) and v > 0):
            raise InputError(f"{name}: expected a finite number > 0, got {v!r}")
    if substeps is not None and not (isinstance(substeps, (int, np.integer)) and not isinstance(substeps, bool)
                                     and substeps >= 1):
        raise InputError(f"substeps: expected a whole number >= 1, got {substeps!r}")
    if not usd_out and not seconds * fps < MAX_FRAMES:  # FaceSimulator.run keeps round(seconds * fps) + 1 frames
        raise InputError(f"seconds, fps: {seconds:g} s at {fps:g} fps is {seconds * fps:.3g} frames, "
                         f"more than {MAX_FRAMES} per run")
    if jaw not in JAWS:
        raise InputError(f"jaw: expected one of {', '.join(JAWS)}, got {jaw!r}")
    check_amount("seconds", seconds, high=MAX_SECONDS)
    check_amount("fps", fps, high=MAX_FPS)
    if substeps is not None:
        check_count("substeps", substeps, high=MAX_SUBSTEPS)
    check_steps(seconds, fps, substeps)
    fr = load_face_rig(head_path)
    frames = round(seconds * fps) + 1  # kept in memory (a folder) or as USD time samples (a USD file)
    check_memory(estimate_sim_bytes(len(fr.nodes), len(fr.tets), frames, len(fr.head_vertices)),
                 f"seconds, fps: {frames} frames of a head of {len(fr.nodes)} nodes and {len(fr.tets)} tets")
    mjcf = (Path(head_path) if Path(head_path).is_dir() else Path(head_path).parent) / "head.xml"
    if jaw == "mujoco" and not mjcf.is_file():
        raise InputError(f"{head_path}: no head.xml for the MuJoCo jaw (rebuild with `facewarp build`, "
                         "or simulate with the kinematic jaw)")
    if jaw == "mujoco":
        load_mjcf(mjcf)  # a broken head.xml fails before the simulator is made
    timeline = timeline_from_spec(expression, seconds).for_head(fr)  # chin drops -> this head's angles
    sim = FaceSimulator(fr, device=device, substeps=substeps, fps=fps, solver=solver, material=material)
    if usd_out:
        return _simulate_to_usd(sim, timeline, seconds, out, expression, progress, tets=tets, jaw=jaw, mjcf=mjcf)
    make_out_dir(out)
    anim = UsdAnimation(out / USD_NAME, sim, tets=tets) if usd else None

    def on_frame(k: int, n: int) -> None:  # the USD is written as the frames are simulated
        if anim is not None:
            anim.add(sim, k / sim.fps)
        if progress:
            progress(k, n)

    with anim if anim is not None else contextlib.nullcontext():
        frames = sim.run(timeline, seconds, progress=on_frame,
                         jaw=jaw_driver(sim, jaw, mjcf=mjcf) if jaw == "mujoco" else None)
    save_frames_npz(out / "frames.npz", frames)
    nf = len(frames.times)
    sheet, hmax = frames_sheet(frames, peak_frames(timeline, seconds, fps), device=device)
    save_png(out / "frames.png", sheet, title=f"{Path(str(expression)).name}: rest and peak",
             colorbar=(0.0, hmax * 1e3, "displacement from rest [mm]"), font_size=sheet_font_size(sheet))
    written = ["frames.npz", "frames.png"]
    if usd:
        written.append(USD_NAME)
    moved = np.linalg.norm(frames.fdp_points - frames.fdp_points[:1], axis=2).max(0)
    return {
        "expression": str(expression), "frames": nf, "seconds": float(seconds), "fps": fps, "substeps": sim.substeps,
        "dt_s": sim.dt, "steps_per_second": frames.steps_per_second, "device": str(sim.device),
        "solver": sim.solver_name, "material": sim.material.name, "jaw": jaw, "frames_per_second": frames.frames_per_second,
        "realtime_factor": frames.realtime_factor,
        "nodes": int(len(fr.nodes)), "tets": int(len(fr.tets)), "files": [str(out / w) for w in written],
        "max_fdp_motion_m": {str(k): float(v) for k, v in zip(frames.fdp_ids, moved) if v > 1e-4},
    }


def _simulate_to_usd(sim, timeline, seconds: float, path: Path, expression, progress, *, tets: bool = False,
                     jaw: str = "kinematic", mjcf=None) -> dict:
    """Stream ``seconds`` of ``timeline`` into the USD file ``path``; the report of :func:`simulate_files`."""
    fr = sim.fr
    rest = sim.fdp_points()
    moved = np.zeros(len(rest))

    def track(s, k: int, t: float) -> None:
        np.maximum(moved, np.linalg.norm(s.fdp_points() - rest, axis=1), out=moved)

    with UsdAnimation(path, sim, tets=tets) as anim:
        stats = play_timeline(sim, timeline, seconds, on_frame=(lambda s, k, t: anim.add(s, t), track),
                              progress=progress, jaw=jaw, mjcf=mjcf)
    return {
        "expression": str(expression), "frames": stats["frames"], "seconds": float(seconds), "fps": sim.fps,
        "substeps": sim.substeps, "dt_s": sim.dt, "steps_per_second": stats["steps_per_second"],
        "frames_per_second": stats["frames_per_second"], "realtime_factor": stats["frames_per_second"] / sim.fps,
        "solver": sim.solver_name, "material": sim.material.name, "jaw": jaw,
        "device": str(sim.device), "nodes": int(len(fr.nodes)),
        "tets": int(len(fr.tets)), "files": [str(path)],
        "max_fdp_motion_m": {str(k): float(v) for k, v in zip(fr.fdp_ids, moved) if v > 1e-4},
    }
