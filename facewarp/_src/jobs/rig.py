"""File-level job behind ``facewarp rig``: bake a build's blendshape rig once and write it as USD and glTF.

``rig_files(BUILD, OUT, shapes=...)``: the face rig of a ``facewarp build`` folder baked into
blendshapes (:func:`~facewarp._src.bake.blendshapes.bake_blendshapes`, one simulator, one bake):

- ``muscles``: each muscle alone, converged, with in-betweens; the jaw as a joint with a corrective;
- ``arkit``: the 52 ARKit-named shapes, each the converged face of its row of the head's ARKit
  table (:func:`~facewarp.arkit_table`, built once and cached in the build folder); the shapes no
  muscle reaches are left out and listed;
- ``both``: the two sets on one skin.

Every file carries the skin's UVs and the build's texture, normal deltas per target, the parts'
looks from the one palette (``present.looks``), the jaw joint, a camera and lights, and animations:
``sequence`` (the Fig. 6.16 sequence as muscle weights and the jaw, with muscle shapes) and
``arkit_tour`` (each ARKit shape in turn, 0 -> 1 -> 0, with ARKit shapes).

``OUT`` is a folder (``rig.usdc``, ``rig.glb``, ``rig.npz`` and ``report.json`` in it), one file
(``.usda``, ``.usdc``, ``.usdz``: the ``.usdc`` and its texture packaged for Apple's Quick Look, or
``.glb``) or a list of files (one bake written in each). Outputs are written whole or
not at all under a lock per output (:func:`~facewarp._src.core.outputs.staged_outputs`): a second
run on the same output is refused, and a read-only output is refused before the bake.
"""

from __future__ import annotations

import math
import stat
import time
from pathlib import Path

import numpy as np

from ..bake.blendshapes import RIG_SHAPE_SETS, bake_blendshapes
from ..core.errors import InputError

__all__ = ["RIG_FOLDER_FILES", "RIG_SHAPES", "RIG_SUFFIXES", "arkit_tour", "demo_frames", "rig_files",
           "write_rig_files"]

RIG_SUFFIXES = (".usda", ".usdc", ".usdz", ".glb")
RIG_SHAPES = RIG_SHAPE_SETS
"""Shape sets ``facewarp rig`` bakes: ``muscles``, ``arkit`` or ``both``."""
RIG_FOLDER_FILES = ("rig.usdc", "rig.glb", "rig.npz", "report.json")
"""What ``--out DIR`` holds (and ``rig_skin.png``, the texture the USD file names, for a textured head):
the rig as USD and glTF, the baked rig itself (``rig.npz``: ``drive --rig DIR`` puts a take on it),
the report."""
TOUR_SECONDS = 0.6
"""Seconds each ARKit shape takes in the ``arkit_tour`` animation (up and down again)."""


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


def arkit_tour(rig) -> list:
    """Each baked ARKit shape in turn, its weight 0 -> 1 -> 0 over :data:`TOUR_SECONDS` (a sine
    bump), as ARKit frames [(time [s], {ARKit name: weight})] at the rig's fps."""
    names = rig.arkit_names
    per = max(2, int(round(TOUR_SECONDS * rig.fps)))
    out = []
    for i, n in enumerate(names):
        for k in range(per):
            out.append(((i * per + k) / rig.fps, {n: float(math.sin(math.pi * k / per) ** 2)}))
    if out:
        out.append((len(names) * per / rig.fps, {}))
    return out


def _read_only(p: Path) -> bool:
    """A file nobody may write (its mode has no write bit): refused even for root, who could."""
    try:
        return p.is_file() and not (p.stat().st_mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
    except OSError:
        return False


def _targets(out) -> tuple[list[tuple[str, Path, str]], list[Path], bool]:
    """(staged_outputs targets, the files the job writes (destination paths), out is a folder)."""
    if isinstance(out, (list, tuple)):
        outs = [Path(o) for o in out]
        if not outs:
            raise InputError("--out: no rig file given")
        folder = False
    else:
        if isinstance(out, bytes) or not isinstance(out, (str, Path)) or not str(out).strip():
            raise InputError(f"--out: expected a folder or a .usda, .usdc or .glb file, got {out!r:.80}")
        p = Path(out)
        folder = p.is_dir() or p.suffix == ""
        outs = [p / n for n in RIG_FOLDER_FILES[:3]] if folder else [p]
    for o in outs if not folder else []:
        if o.suffix.lower() not in RIG_SUFFIXES:
            raise InputError(f"--out: {str(o)!r} has extension {o.suffix!r}; expected one of "
                             f"{', '.join(RIG_SUFFIXES)} (or a folder)")
        if o.is_dir() or not o.parent.is_dir():
            raise InputError(f"--out: {str(o)!r} is a folder or its folder does not exist")
    seen = set()
    for o in outs:
        key = str(o.resolve())
        if key in seen:
            raise InputError(f"--out: {str(o)!r} given twice")
        seen.add(key)
    if folder:
        p = Path(out)
        if p.exists() and not p.is_dir():
            raise InputError(f"--out: {str(p)!r} exists and is not a folder")
        for name in RIG_FOLDER_FILES:
            if _read_only(p / name):
                raise InputError(f"--out: {str(p / name)!r} is read-only")
        return [("out", p, "dir")], outs, True
    for o in outs:
        if _read_only(o):
            raise InputError(f"--out: {str(o)!r} is read-only")
    return [(f"out{i}" if i else "out", o, "file") for i, o in enumerate(outs)], outs, False


def rig_files(build, out, *, shapes: str = "muscles", inbetweens: int = 0, muscles=None, device: str = "cpu",
              progress=None, iris_color=None, table=None) -> dict:
    """Bake ``build``'s rig once and write it to ``out``; returns a report (also ``report.json`` in a folder).

    Args:
        build: A ``facewarp build`` output folder (``face_rig.npz``).
        out: A folder (``rig.usdc``, ``rig.glb``, ``rig.npz``, ``report.json``), a rig file (``.usda``, ``.usdc``
            or ``.glb``) or a list of rig files; a file's folder must exist.
        shapes: One of :data:`RIG_SHAPES`.
        inbetweens: In-between shapes per muscle (0..8).
        muscles: Optional muscle names to bake (default all; none twice): instance names
            (``corrugator_L``) or Table 6.2 names, each meaning both sides.
        device: Warp device.
        progress: Optional ``progress(done, total, name)`` per baked shape (and per ARKit table step).
        iris_color: Optional iris RGB (3,) in 0..1, linear, of the files' looks (``present.looks``).
        table: Optional :class:`~facewarp.takes.ArkitTable` of this head (default: the build's cached
            ``arkit_table.npz``, built when missing).

    Raises:
        InputError: bad arguments (checked before the bake), a read-only output, an output another
            run is writing.
    """
    from ..core.outputs import staged_outputs
    from ..physics.face_rig import load_face_rig
    from ..present.looks import iris_rgb

    iris_rgb(iris_color)
    if shapes not in RIG_SHAPES:
        raise InputError(f"--shapes: {shapes!r} is not a shape set; expected one of {', '.join(RIG_SHAPES)}")
    if not (isinstance(inbetweens, (int, np.integer)) and not isinstance(inbetweens, bool) and 0 <= inbetweens <= 8):
        raise InputError(f"--inbetweens: expected a whole number 0..8, got {inbetweens!r}")
    if muscles is not None:
        muscles = [str(m) for m in muscles]
        twice = sorted({m for m in muscles if muscles.count(m) > 1})
        if twice:
            raise InputError(f"--muscles: {', '.join(twice)} given twice (each muscle is one shape)")
        if shapes == "arkit":
            raise InputError("--muscles: the ARKit shapes take every muscle; give --shapes muscles or both")
    targets, outs, folder = _targets(out)
    build = Path(build)
    if not (build / "face_rig.npz").is_file():
        raise InputError(f"{build}: no face_rig.npz (expected a `facewarp build` output folder)")
    fr = load_face_rig(build)
    if muscles is not None:  # a bare name means both sides (expressions.muscle_instances)
        from ..expressions import muscle_instances

        if not muscles:
            raise InputError("--muscles: none given")
        expanded = [m for name in muscles for m in muscle_instances(name, fr.muscle_names, what="--muscles")]
        twice = sorted({m for m in expanded if expanded.count(m) > 1})
        if twice:
            raise InputError(f"--muscles: {', '.join(twice)} named twice (a Table 6.2 name means both sides; "
                             "each muscle is one shape)")
        muscles = expanded
    with staged_outputs(targets) as staging:
        if folder:
            root = staging.path("out")
            files = [root / n for n in RIG_FOLDER_FILES[:3]]
        else:
            files = [staging.path(name) for name, _, _ in targets]
        rep = _bake_and_write(fr, build, files, shapes=shapes, inbetweens=inbetweens, muscles=muscles,
                              device=device, progress=progress, iris_color=iris_color, table=table)
        rep["file"], rep["files"] = str(outs[0]), [str(o) for o in outs]
        if folder:
            from ..core.fileio import write_json

            rep["report"] = str(Path(out) / "report.json")
            write_json(root / "report.json", rep)
    return rep


def _arkit(fr, build: Path, device, progress, table):
    """The head's ARKit table: ``table``, else the build's cache (built and cached when missing; a
    build folder that cannot be written is not cached into)."""
    import os

    from ..drive.arkit import arkit_table
    from ..sim.simulator import FaceSimulator

    if table is not None:
        return table, 0.0
    t0 = time.perf_counter()
    cache = build if os.access(build, os.W_OK) else None
    sim = FaceSimulator(fr, device=device)
    t = arkit_table(sim, cache=cache, progress=progress)
    return t, (0.0 if t.info.get("from_cache") else time.perf_counter() - t0)


def write_rig_files(fr, rig, files, clips: dict, *, iris_color=None) -> None:
    """Write a baked rig with its animations ``clips`` (name -> frames, :func:`~facewarp._src.bake.gltf.clip_arrays`;
    the first is USD's bound clip) to each of ``files`` (``.glb``, ``.usda``, ``.usdc``), with the
    looks of ``fr``'s head."""
    from ..present.looks import head_camera, head_looks

    looks = head_looks(fr, iris_color=iris_color)
    camera = head_camera(fr)
    for f in files:
        if Path(f).suffix.lower() == ".glb":
            from ..bake.gltf import write_glb

            write_glb(f, rig, looks=looks, clips=clips)
        elif Path(f).suffix.lower() == ".usdz":
            _write_usdz(Path(f), rig, clips, looks, camera)
        else:
            _write_usd(f, rig, clips, looks, camera)


def _write_usdz(out: Path, rig, clips, looks, camera) -> None:
    """The UsdSkel rig as a USDZ package for Apple's Quick Look (``UsdUtils.CreateNewARKitUsdzPackage``:
    the ``.usdc`` and its texture in one file), written in a private folder beside ``out`` and renamed."""
    import os
    import shutil
    import tempfile

    from .animation import load_usd_export

    load_usd_export()
    from pxr import Sdf, UsdUtils

    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.", suffix=".tmp"))
    try:
        usdc = tmp / f"{out.stem}.usdc"
        _write_usd(usdc, rig, clips, looks, camera)
        package = tmp / out.name
        if not UsdUtils.CreateNewARKitUsdzPackage(Sdf.AssetPath(str(usdc)), str(package)) or not package.is_file():
            raise InputError(f"--out: {out}: USD could not make the USDZ package")
        os.replace(package, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _bake_and_write(fr, build, files, *, shapes, inbetweens, muscles, device, progress, iris_color, table) -> dict:
    t0 = time.perf_counter()
    table_s = 0.0
    if shapes != "muscles":
        table, table_s = _arkit(fr, build, device, progress, table)
    rig = bake_blendshapes(fr, muscles=muscles, inbetweens=inbetweens, shapes=shapes, arkit=table, device=device,
                           progress=progress)
    t1 = time.perf_counter()
    clips = {}
    if rig.muscle_names:
        clips["sequence"] = demo_frames(fr, rig)
    if rig.arkit_names:
        clips["arkit_tour"] = arkit_tour(rig)
    write_rig_files(fr, rig, [f for f in files if f.suffix != ".npz"], clips, iris_color=iris_color)
    for f in files:
        if f.suffix == ".npz":
            from ..bake.blendshapes import save_rig

            save_rig(f, rig, texture_name=f"{f.parent / 'rig'}_skin.png" if rig.texture else None)
    t2 = time.perf_counter()
    first = next(iter(clips.values()))
    return {
        "shapes": shapes, "targets": len(rig.names), "muscles": len(rig.muscle_names), "arkit": len(rig.arkit_names),
        "inbetweens": int(inbetweens), "vertices": int(len(rig.rest)), "textured": bool(rig.texture),
        "clips": {k: {"frames": len(v), "seconds": v[-1][0]} for k, v in clips.items()},
        "frames": len(first), "seconds": first[-1][0], "jaw_angle_rad": rig.jaw_angle,
        "bake_frames_max": int(max(max(v) for v in rig.bake_frames.values())),
        "shape_report": {n: {"set": "jaw" if n == "jaw_open" else "arkit" if n in rig.arkit_jaw else "muscle",
                             "largest_motion_mm": round(1e3 * rig.largest_motion(n), 3),
                             "bake_frames": rig.bake_frames[n], **({"jaw_deg": round(math.degrees(rig.arkit_jaw[n]), 2)}
                                                                     if n in rig.arkit_jaw else {})}
                         for n in rig.names},
        "left_out": dict(rig.left_out),
        "timings_s": {"arkit_table": round(table_s, 2), "bake": round(t1 - t0 - table_s, 2),
                      "static_shapes": round(rig.bake_seconds, 2), "write": round(t2 - t1, 2),
                      "total": round(t2 - t0, 2)},
    }


def _write_usd(out, rig, clips, looks, camera) -> None:
    from ..bake.blendshapes import normal_offsets
    from ..bake.gltf import clip_arrays
    from ..present.looks import COLORS
    from .animation import load_usd_export

    ue = load_usd_export()
    UsdExportError, write_skel_rig = ue.UsdExportError, ue.write_skel_rig

    shapes = [(name, rig.shapes[name][-1][1], [(f, D) for f, D in rig.shapes[name][:-1]]) for name in rig.names]
    normals = {}
    for name in rig.names:
        normals[name] = normal_offsets(rig, rig.shapes[name][-1][1])
        if len(rig.shapes[name]) > 1:
            normals[name + "@"] = [(f, normal_offsets(rig, D)) for f, D in rig.shapes[name][:-1]]

    def arrays(frames):
        t, _, jaw = clip_arrays(rig, frames)
        W = np.zeros((len(frames), len(rig.names)), np.float32)
        for k, f in enumerate(frames):
            for i, name in enumerate(rig.names):
                if name == "jaw_open":
                    W[k, i] = 0.0 if len(f) == 2 else f[2] / rig.jaw_angle
                elif len(f) == 2:
                    W[k, i] = f[1].get(name, 0.0) if name in rig.arkit_jaw else 0.0
                else:
                    W[k, i] = f[1].get(name, 0.0) if name not in rig.arkit_jaw else 0.0
        Q = np.array([[math.cos(0.5 * a), *(math.sin(0.5 * a) * rig.jaw_axis)] for a in jaw], np.float32)
        return t, W, Q

    items = list(clips.items())
    t, W, Q = arrays(items[0][1])
    extra = {"".join(w.capitalize() for w in k.split("_")): arrays(v) for k, v in items[1:]}
    uv = {} if rig.uv is None else {"uv": rig.uv, "uv_indices": rig.face_uv,
                                    "skin_texture": rig.texture if rig.texture else None}
    try:
        write_skel_rig(out, fps=rig.fps, rest_points=rig.rest, faces=rig.faces, shapes=shapes,
                       jaw_pivot=rig.jaw_pivot, jaw_weight=rig.jaw_weight,
                       parts={k: looks["parts"].get(k, v) for k, v in rig.parts.items()}, jaw_parts=rig.jaw_parts,
                       times=t, weights=W, jaw_rotations=Q, part_colors=looks["part_colors"],
                       subsets=looks["subsets"], camera=camera, lights=True, normal_offsets=normals,
                       skin_color=COLORS["skin"], clips=extra, **uv)
    except UsdExportError as e:
        raise InputError(str(e)) from None
