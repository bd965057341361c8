"""File-level job behind ``facewarp rig``: bake a build's blendshape rig and write it as USD or glTF.

``rig_files(BUILD, OUT)``: the face rig of a ``facewarp build`` folder baked into blendshapes
(:func:`~facewarp._src.bake.blendshapes.bake_blendshapes`: each muscle alone, converged, with
in-betweens; the jaw as a joint with a corrective), the Fig. 6.16 sequence as its animation (the
muscle weights the expressions set, the jaw's rotation), the looks of the animation files (lips,
iris, pupil, part colours, camera, lights), written as UsdSkel (``.usda`` / ``.usdc``) or glTF
binary (``.glb``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..bake.blendshapes import bake_blendshapes
from ..core.errors import InputError

__all__ = ["RIG_SHAPES", "RIG_SUFFIXES", "demo_frames", "rig_files"]

RIG_SUFFIXES = (".usda", ".usdc", ".glb")
RIG_SHAPES = ("muscles",)
"""Shape sets ``facewarp rig`` bakes: ``muscles`` (each muscle alone). ARKit-named shapes need the
activation table of the data-driven control (not in this version)."""


def demo_frames(fr, rig, *, seconds: float | None = None, each: float = 0.8) -> list:
    """The Fig. 6.16 sequence as rig frames: [(time [s], {muscle: weight}, jaw [rad])] at the rig's fps,
    muscles not baked left out."""
    from ..expressions import thesis_sequence
    from ..sim.simulator import FaceSimulator

    sim = FaceSimulator(fr)
    timeline = thesis_sequence(each=each).for_head(fr)
    end = max(s.start + s.attack + s.hold + s.release for s in timeline.segments) + 0.2 if seconds is None else seconds
    baked = set(rig.muscle_names)
    out = []
    for k in range(int(round(end * rig.fps)) + 1):
        t = k / rig.fps
        e = timeline.sample(t)
        a = sim.activation_vector(e)
        out.append((t, {m: float(v) for m, v in zip(sim.muscle_names, a) if m in baked and v}, float(e.jaw_u)))
    return out


def rig_files(build, out, *, shapes: str = "muscles", inbetweens: int = 0, muscles=None, device: str = "cpu",
              progress=None, iris_color=None) -> dict:
    """Bake ``build``'s rig and write it to ``out`` (``.usda``, ``.usdc`` or ``.glb``); returns a report.

    Args:
        build: A ``facewarp build`` output folder (``face_rig.npz``).
        out: The rig file, or a list of them (one bake written in each format); their folders must exist.
        shapes: One of :data:`RIG_SHAPES`.
        inbetweens: In-between shapes per muscle (0..8).
        muscles: Optional muscle names to bake (default all): instance names (``corrugator_L``) or Table 6.2
            names, each meaning both sides.
        device: Warp device.
        progress: Optional ``progress(done, total, name)`` per baked shape.
        iris_color: Optional iris RGB (3,) in 0..1, linear, of the files' looks (``present.looks``).
    """
    from ..physics.face_rig import load_face_rig
    from ..present.looks import head_camera, head_looks, iris_rgb

    iris_rgb(iris_color)

    outs = [Path(o) for o in out] if isinstance(out, (list, tuple)) else [Path(out)]
    if not outs:
        raise InputError("--out: no rig file given")
    for out in outs:
        if out.suffix.lower() not in RIG_SUFFIXES:
            raise InputError(f"--out: {str(out)!r} has extension {out.suffix!r}; expected one of "
                             f"{', '.join(RIG_SUFFIXES)}")
        if out.is_dir() or not out.parent.is_dir():
            raise InputError(f"--out: {str(out)!r} is a folder or its folder does not exist")
    if shapes not in RIG_SHAPES:
        raise InputError(f"--shapes: {shapes!r} is not available; expected one of {', '.join(RIG_SHAPES)} "
                         "(ARKit shapes need the data-driven activation table)")
    if not (isinstance(inbetweens, (int, np.integer)) and not isinstance(inbetweens, bool) and 0 <= inbetweens <= 8):
        raise InputError(f"--inbetweens: expected a whole number 0..8, got {inbetweens!r}")
    build = Path(build)
    if not (build / "face_rig.npz").is_file():
        raise InputError(f"{build}: no face_rig.npz (expected a `facewarp build` output folder)")
    fr = load_face_rig(build)
    if muscles is not None:  # a bare name means both sides (expressions.muscle_instances)
        from ..expressions import muscle_instances

        names = [muscles] if isinstance(muscles, str) else list(muscles)
        muscles = list(dict.fromkeys(m for name in names for m in muscle_instances(name, fr.muscle_names)))
    rig = bake_blendshapes(fr, muscles=muscles, inbetweens=inbetweens, device=device, progress=progress)
    frames = demo_frames(fr, rig)
    looks = head_looks(fr, iris_color=iris_color)
    camera = head_camera(fr)
    for out in outs:
        if out.suffix.lower() == ".glb":
            from ..bake.gltf import write_glb

            write_glb(out, rig, frames=frames, looks=looks)
        else:
            _write_usd(out, rig, frames, looks, camera)
    return {"file": str(outs[0]), "files": [str(o) for o in outs], "targets": len(rig.names),
            "muscles": len(rig.muscle_names),
            "inbetweens": int(inbetweens), "vertices": int(len(rig.rest)), "frames": len(frames),
            "seconds": frames[-1][0], "jaw_angle_rad": rig.jaw_angle,
            "bake_frames_max": int(max(max(v) for v in rig.bake_frames.values()))}


def _write_usd(out, rig, frames, looks, camera) -> None:
    from .animation import load_usd_export

    ue = load_usd_export()
    UsdExportError, write_skel_rig = ue.UsdExportError, ue.write_skel_rig

    shapes = [(name, rig.shapes[name][-1][1], [(f, D) for f, D in rig.shapes[name][:-1]]) for name in rig.names]
    times = np.array([f[0] for f in frames])
    W = np.array([[f[1].get(name, 0.0) if name != "jaw_open" else f[2] / rig.jaw_angle for name in rig.names]
                  for f in frames], np.float32)
    Q = np.array([[math.cos(0.5 * f[2]), *(math.sin(0.5 * f[2]) * rig.jaw_axis)] for f in frames], np.float32)
    try:
        write_skel_rig(out, fps=rig.fps, rest_points=rig.rest, faces=rig.faces, shapes=shapes,
                       jaw_pivot=rig.jaw_pivot, jaw_weight=rig.jaw_weight,
                       parts={k: looks["parts"].get(k, v) for k, v in rig.parts.items()}, jaw_parts=rig.jaw_parts,
                       times=times, weights=W, jaw_rotations=Q, part_colors=looks["part_colors"],
                       subsets=looks["subsets"], camera=camera, lights=True)
    except UsdExportError as e:
        raise InputError(str(e)) from None
