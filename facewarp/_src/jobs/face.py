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
                           check_memory, check_steps, estimate_build_bytes)
from ..coupling.mjcf import write_head_mjcf
from ..coupling.drivers import JAWS, jaw_driver
from ..expressions import Expression, Timeline, timeline_from_spec
from ..anatomy.rig import face_rig_from_anatomy
from ..physics.face_rig import load_face_rig, save_face_rig
from ..present.anatomy import render_anatomy
from ..present.render import save_png
from ..present.strips import frames_sheet, sheet_font_size
from ..sim.frames import save_frames_npz
from ..sim.play import FrameRecorder, _play
from ..sim.simulator import FaceSimulator
from .animation import USD_SUFFIXES, FdpMotion, UsdAnimation, check_usd_path, peak_frames
from .checks import MAX_FRAMES, check_kept_frames, check_out_dir, load_simulated_head, make_out_dir

__all__ = ["MAX_FRAMES", "USD_NAME", "build_files", "build_head_files", "simulate_files"]

USD_NAME = "animation.usdc"
"""The USD animation ``simulate --usd`` writes into its output folder."""

def build_files(head_path, out, *, layers: int = 1, device: str = "cpu", progress=None, up: str = "z",
                prefix: str = "") -> dict:
    """Build anatomy and the face rig of a head folder into ``out``; returns the quality report."""
    step = progress or (lambda msg: None)
    out = check_out_dir(out)
    _check_layers(layers)
    _check_mjcf_options(up, prefix)
    step("loading head")
    head = load_head(head_path)
    return build_head_files(head, out, layers=layers, device=device, progress=progress, up=up, prefix=prefix)


def _check_mjcf_options(up, prefix) -> None:
    from ..coupling.mjcf import head_mjcf_options

    head_mjcf_options(up, prefix)


def _check_layers(layers) -> None:
    check_count("layers", layers, high=MAX_LAYERS)


def build_head_files(head, out, *, layers: int = 1, device: str = "cpu", progress=None, up: str = "z",
                     prefix: str = "") -> dict:
    """Build anatomy and the face rig of ``head`` (a :class:`~facewarp.Template`) into ``out``.

    Writes ``tets.npz``, ``muscles.json``, ``anatomy.json``, ``face_rig.npz``, ``head.xml`` (the
    MuJoCo cranium, mandible and skin for a world with ``up`` axis "z" or "y", names after
    ``prefix``; :func:`~facewarp.coupling.write_head_mjcf`), ``scene.xml`` (the standalone scene that
    includes it), ``texture.png`` (the head's skin texture: baked from its scan, else its preview
    colours with the lips) and ``anatomy.png``; returns the quality report.
    """
    step = progress or (lambda msg: None)
    out = check_out_dir(out)
    _check_layers(layers)
    _check_mjcf_options(up, prefix)
    check_memory(estimate_build_bytes(len(head.vertices), len(head.faces), layers),
                 f"layers: {layers} tet layers under {len(head.faces)} skin triangles")
    make_out_dir(out)
    step("skin layer and muscles")
    anatomy = build_anatomy(head, layers=layers)
    fr = face_rig_from_anatomy(anatomy)
    step("writing")
    write_anatomy(anatomy, out)
    save_face_rig(out / "face_rig.npz", fr)
    write_head_mjcf(out / "head.xml", head, jaw=fr.jaw, up=up, prefix=prefix, skin=(fr.head_vertices, fr.head_faces),
                    skin_texture="texture.png" if getattr(head, "uv", None) is not None else None)  # _copy_texture's
    _copy_texture(head, out)
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


def _copy_texture(head, out: Path) -> None:
    """The head's skin texture beside its face rig (``texture.png``, read by :func:`load_face_rig`):
    its own (baked from the scan) or, for a head with UVs but no texture, its preview colours
    (skin, lips, the inside of the mouth) painted over the UVs."""
    import shutil

    src = getattr(head, "texture", None)
    if src and Path(src).is_file() and getattr(head, "uv", None) is not None:
        if Path(src).resolve() != (out / "texture.png").resolve():
            shutil.copyfile(src, out / ".texture.png.tmp")
            (out / ".texture.png.tmp").replace(out / "texture.png")
    elif getattr(head, "uv", None) is not None:
        # no scan colour: the preview skin with tinted lips and a dark mouth inside, as a texture
        from PIL import Image

        from ..adapt.bake import vertex_color_texture
        from ..core.fileio import atomic_write
        from ..present.template import head_colors

        img = vertex_color_texture(head.faces, head.uv, head.face_uv, head_colors(head.vertices, head.landmarks()))
        with atomic_write(out / "texture.png", "wb", encoding=None) as f:
            Image.fromarray(img).save(f, format="PNG")
    elif (out / "texture.png").is_file():
        (out / "texture.png").unlink()  # a texture of an earlier build into this folder


def simulate_files(head_path, expression, out, *, seconds: float = 2.0, fps: float = 30.0,
                   substeps: int | None = None, device: str = "cpu", usd: bool = False, tets: bool = False,
                   progress=None, solver: str = "implicit", material: str = "physical", jaw: str | None = None,
                   name: str | None = None) -> dict:
    """Simulate ``expression`` on a ``build`` output and write its frames.

    ``expression`` is a :class:`~facewarp.Timeline` (what ``facewarp simulate`` builds from its
    ``--expression`` or ``--activations``), an :class:`~facewarp.Expression` (held over the run,
    :meth:`~facewarp.Timeline.held`), or what :func:`~facewarp.expressions.timeline_from_spec` reads: a preset,
    ``"sequence"``, a sequence file, or ``"muscle=value,...,jaw_drop_mm=D"``; ``name`` labels it in
    the report and picture (default: the string, or the expression's name). Chin drops become
    this head's jaw angles by its condyle-to-chin lever, once, where :func:`~facewarp.play` meets
    the head (:meth:`~facewarp.Timeline.for_head`).

    ``solver`` (``"implicit"``, default, or ``"verlet"``) and ``material`` (``"physical"``, default,
    or ``"thesis"``) choose the :class:`~facewarp.FaceSimulator`'s solver and material profile;
    ``--solver verlet --material thesis`` is the simulator before issue 10. ``jaw``: ``"mujoco"``
    (the default with the physical material: the mandible is the hinge body of the build's
    ``head.xml``, two-way coupled to the skin, the expressions' jaw angles its actuator targets) or
    ``"kinematic"`` (Eq. 6.4.9 angles imposed directly; the default with the thesis material, whose
    Table 6.3 masses and hold springs are not physical; the MuJoCo jaw couples it too, through
    the scaled stiff-skin coupling of :mod:`~facewarp._src.coupling.mujoco`).

    ``out`` is a folder (``frames.npz``, ``frames.png``: per expression the whole head at rest and
    at its peak, front and three-quarter, over its displacement heat map; and with ``usd`` the USD animation
    :data:`USD_NAME`, streamed while simulating) or a ``.usda`` / ``.usdc`` / ``.usdz`` file: then
    only that animation is written, streamed frame by frame with no frame kept in memory and no
    frame cap (:mod:`~facewarp._src.jobs.animation`). With ``tets`` the USD also holds the skin's
    tet layer (a ``TetMesh`` of purpose ``guide``).
    """
    seconds, timeline, name, jaw = _check_simulate(expression, seconds, fps, name, jaw, material, substeps)
    usd_out = Path(out).suffix.lower() in USD_SUFFIXES
    out = check_usd_path(out) if usd_out else check_out_dir(out)
    if not usd_out:
        check_kept_frames(seconds, fps)
    fr, mjcf = load_simulated_head(head_path, seconds, fps, jaw)
    sim = FaceSimulator(fr, device=device, substeps=substeps, fps=fps, solver=solver, material=material)
    driver = jaw_driver(sim, jaw, mjcf=mjcf)
    # the sinks: every frame kept (a folder) or only the FDPs' largest motion (a USD file alone)
    keep = None if usd_out else FrameRecorder()
    motion = FdpMotion() if usd_out else None
    usd_path = out if usd_out else (out / USD_NAME if usd else None)
    if not usd_out:
        make_out_dir(out)
    anim = UsdAnimation(usd_path, sim, tets=tets) if usd_path is not None else None
    sinks = [s for s in (keep, motion, anim) if s is not None]
    with anim if anim is not None else contextlib.nullcontext():
        stats = _play(sim, timeline, seconds, sinks, driver, progress)
    if keep is not None:
        written, moved = _write_frames(out, keep.frames, timeline, seconds, fps, name, device)
        written += [usd_path] if usd_path is not None else []
    else:
        written = [out]
        moved = motion.moved
    return _simulate_report(name, stats, sim, fr, jaw, written, moved)


def _check_simulate(expression, seconds, fps, name, jaw, material, substeps) -> tuple[float, Timeline, str, str]:
    """The checks of :func:`simulate_files` that need no head: (seconds [s], timeline, label, jaw)."""
    for key, v in (("seconds", seconds), ("fps", fps)):
        if not (isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
                and math.isfinite(v) and v > 0):
            raise InputError(f"{key}: expected a finite number > 0, got {v!r}")
    seconds = float(seconds)
    timeline, name = _timeline(expression, seconds, name)
    if jaw is None:
        jaw = "kinematic" if material == "thesis" else "mujoco"
    if jaw not in JAWS:
        raise InputError(f"jaw: expected one of {', '.join(JAWS)}, got {jaw!r}")
    check_amount("seconds", seconds, high=MAX_SECONDS)
    check_amount("fps", fps, high=MAX_FPS)
    if substeps is not None:
        check_count("substeps", substeps, high=MAX_SUBSTEPS)
    check_steps(seconds, fps, substeps)
    return seconds, timeline, name, jaw


def _write_frames(out: Path, frames, timeline: Timeline, seconds: float, fps: float, name: str,
                  device: str) -> tuple[list, np.ndarray]:
    """``out/frames.npz`` and ``out/frames.png`` of the recorded :class:`~facewarp.Frames`; returns
    the files written and each FDP's largest motion from rest [m], shape (84,)."""
    save_frames_npz(out / "frames.npz", frames)
    sheet, hmax = frames_sheet(frames, peak_frames(timeline, seconds, fps), device=device)
    save_png(out / "frames.png", sheet, title=f"{Path(name).name}: rest and peak",
             colorbar=(0.0, hmax * 1e3, "displacement from rest [mm]"), font_size=sheet_font_size(sheet))
    moved = np.linalg.norm(frames.fdp_points - frames.fdp_points[:1], axis=2).max(0)
    return [out / "frames.npz", out / "frames.png"], moved


def _simulate_report(name: str, stats, sim, fr, jaw: str, written: list, moved) -> dict:
    """The report of :func:`simulate_files` from the run's :class:`~facewarp._src.sim.play.PlayStats`."""
    return {
        "expression": name, "frames": stats.frames, "seconds": stats.seconds, "fps": sim.fps,
        "substeps": stats.substeps, "dt_s": stats.dt_s, "steps_per_second": stats.steps_per_second,
        "device": stats.device, "solver": sim.solver_name, "material": sim.material.name, "jaw": jaw,
        "frames_per_second": stats.frames_per_second, "realtime_factor": stats.realtime_factor,
        "nodes": int(len(fr.nodes)), "tets": int(len(fr.tets)), "files": [str(w) for w in written],
        "max_fdp_motion_m": {str(k): float(v) for k, v in zip(fr.fdp_ids, moved) if v > 1e-4},
        "frame_stats": stats.frame_stats, "mujoco_events": stats.mujoco_events,
    }


def _timeline(expression, seconds: float, name: str | None) -> tuple[Timeline, str]:
    """The timeline of ``expression`` (a Timeline, an Expression or a spec string) and its label."""
    if isinstance(expression, Timeline):
        return expression, name or "timeline"
    if isinstance(expression, Expression):
        return Timeline.held(expression, seconds), name or expression.name
    if isinstance(expression, (str, Path)):
        return timeline_from_spec(str(expression), seconds), name or str(expression)
    raise InputError(f"expression: expected a Timeline, an Expression or a preset / sequence / file name, "
                     f"got {type(expression).__name__}")
