"""``facewarp batch simulate``: many built heads played together in one :class:`~facewarp.FaceBatch`.

Files in: the ``facewarp build`` folders (one head each, any mix of identities), an expression
for all (or one per head from a ``--per-head`` file). Files out: ``head_KK.usdc`` per head (the
USD animation of :class:`~facewarp.UsdAnimation`, streamed while simulating) and
``report.json`` (per-head status, frames per second, head-frames per second).

:func:`simulate_group_files` is the other use of one :class:`~facewarp.FaceBatch`: the
``simulate`` step of ``facewarp batch run`` for a group of scans, each head's folder written as
:func:`~facewarp._src.jobs.face.simulate_files` writes it alone (``frames.npz``, ``frames.png``).
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fileio import write_json
from ..core.limits import MAX_FPS, MAX_SECONDS, check_work, estimate_frames_bytes
from ..core.outputs import destination
from ..expressions import timeline_from_spec
from ..physics.face_rig import load_face_rig
from .checks import check_apart, check_some_frames

__all__ = ["MAX_CLI_HEADS", "batch_simulate_files", "read_per_head", "simulate_group_files"]

MAX_CLI_HEADS = 10_000
"""Largest number of build folders of one ``facewarp batch simulate``."""


def read_per_head(path, count: int) -> list[str]:
    """The per-head expressions of a ``--per-head`` file: ``{"heads": [SPEC, ...]}`` with one entry
    per head, each a preset name, ``"sequence"``, a sequence file (relative to the file) or
    ``"muscle=value,..."``, or ``{"expression": SPEC}``.

    Raises:
        InputError: an unreadable file, a bad schema, or a count other than the heads'.
    """
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except OSError as e:
        raise InputError(f"per_head {p}: cannot be read ({e.strerror or e})") from None
    except ValueError as e:
        raise InputError(f"per_head {p}: not valid JSON ({' '.join(str(e).split())})") from None
    heads = doc.get("heads") if isinstance(doc, dict) else None
    if not isinstance(heads, list):
        raise InputError(f'per_head {p}: expected {{"heads": [expression, ...]}} with one entry per head')
    if len(heads) != count:
        raise InputError(f"per_head {p}: {len(heads)} entries for {count} heads (one per BUILD_DIR, in order)")
    out = []
    for i, h in enumerate(heads):
        spec = h.get("expression") if isinstance(h, dict) else h
        if not isinstance(spec, str) or not spec.strip():
            raise InputError(f'per_head {p}: heads[{i}]: expected an expression name or {{"expression": NAME}}, got {h!r:.60}')
        if spec.lower().endswith(".json") and not Path(spec).is_absolute():
            spec = str(p.parent / spec)
        out.append(spec)
    return out


def play_batch(batch, timelines, frames: int, fps: float, on_frame, progress=None) -> float:
    """Frames ``0 .. frames - 1`` of every head of ``batch`` (a :class:`~facewarp.FaceBatch` of the
    ``"heads"`` backend): each head's timeline sampled at ``k / fps`` [s] and stepped together;
    ``on_frame(head, simulator, k, t)`` after every frame for each head still live (a frozen head's
    output ends at its last good frame), ``progress(k, frames)`` after each frame. Returns the
    seconds spent stepping (wall)."""
    stepping = 0.0
    for k in range(frames):
        t = k / fps
        if k > 0:
            es = [tl.sample(t) for tl in timelines]
            batch.set_activations(es)
            batch.set_jaw(np.array([[e.jaw_u, e.jaw_v] for e in es]))
            s0 = time.perf_counter()
            batch.step()
            stepping += time.perf_counter() - s0
        for i, sim in enumerate(batch.heads):
            if i not in batch.failed:
                on_frame(i, sim, k, t)
        if progress:
            progress(k, frames)
    return stepping


def batch_simulate_files(heads, expression: str, out, *, per_head=None, seconds: float = 2.0, fps: float = 30.0,
                         device: str = "cpu", jaw: str = "kinematic", stage: str | None = None, progress=None) -> dict:
    """Play ``expression`` (or each head's own from ``per_head``) on every build folder of
    ``heads`` at once (:class:`~facewarp.FaceBatch`) and write ``out/head_KK.usdc`` and
    ``out/report.json``.

    Args:
        heads: ``facewarp build`` folders, one per head.
        expression: What :func:`~facewarp.expressions.timeline_from_spec` reads: a preset, ``"sequence"``, a
            sequence file or ``"muscle=value,..."``, for every head without its own.
        out: Output folder (made here).
        per_head: A ``--per-head`` file (:func:`read_per_head`), or None.
        seconds, fps: Length [s] and frames per second.
        device: Warp device.
        stage: Also ``out/<stage>`` (a ``.usda`` / ``.usdc`` file name): one stage with every head as
            ``/Crowd/head_KK``, referencing its file, the heads side by side along x
            (:func:`usd_export.write_crowd_stage`).
        jaw: ``"kinematic"`` (default: Eq. 6.4.9, inside the batched step) or ``"mujoco"`` (each
            build's ``head.xml`` hinge body, one CPU MuJoCo per head: :meth:`~facewarp.FaceBatch.use_mujoco_jaws`).
        progress: Optional ``progress(k, frame_count)`` after each frame.

    Returns:
        The report (also ``out/report.json``).

    Raises:
        InputError: bad folders, expressions or numbers.
    """
    from ..sim.batch import FaceBatch
    from .animation import UsdAnimation

    if isinstance(heads, (str, bytes, os.PathLike)) or not hasattr(heads, "__iter__"):
        raise InputError(f"heads: expected a list of `facewarp build` folders, got {type(heads).__name__} {heads!r:.60}")
    heads = list(heads)
    bad = next((h for h in heads if not isinstance(h, (str, os.PathLike)) or not str(h).strip()), None)
    if bad is not None:
        raise InputError(f"heads: expected `facewarp build` folder paths, got {type(bad).__name__} {bad!r:.40}")
    heads = [Path(h) for h in heads]
    if not heads:
        raise InputError("BUILD_DIR: give at least one `facewarp build` folder")
    if not isinstance(expression, (str, os.PathLike)) or not str(expression).strip():
        raise InputError(f"expression: expected a preset, 'sequence', a sequence file or 'muscle=value,...', "
                         f"got {expression!r:.60}")
    if per_head is not None and (not isinstance(per_head, (str, os.PathLike)) or not str(per_head).strip()):
        raise InputError(f"per_head: expected a file path or None, got {per_head!r:.60}")
    if not isinstance(out, (str, os.PathLike)) or not str(out).strip():
        raise InputError(f"out: expected a folder path, got {out!r:.60}")
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a callable progress(k, frame_count) or None, got {type(progress).__name__}")
    if len(heads) > MAX_CLI_HEADS:
        raise InputError(f"BUILD_DIR: at most {MAX_CLI_HEADS} heads, got {len(heads)}")
    for key, v, high in (("seconds", seconds, MAX_SECONDS), ("fps", fps, MAX_FPS)):
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0 < v <= high):
            raise InputError(f"{key}: expected a finite number > 0 and <= {high:g}, got {v!r}")
    check_some_frames(float(seconds), float(fps))
    nf = int(round(seconds * fps)) + 1
    width = max(2, len(str(len(heads) - 1)))
    names = [f"head_{i:0{width}d}.usdc" for i in range(len(heads))]
    if stage is not None:
        if not isinstance(stage, str) or Path(stage).name != stage or Path(stage).suffix not in (".usda", ".usdc"):
            raise InputError(f"stage: expected a file name ending in .usda or .usdc (written in the output folder), "
                             f"got {stage!r}")
        taken = {n.lower() for n in names} | {"report.json"}
        if stage.lower() in taken:
            raise InputError(f"stage: {stage!r} is the name of a head's animation file in the output folder "
                             f"(head_00.usdc .. {names[-1]}); choose another name, e.g. crowd.usda")
    if jaw not in ("kinematic", "mujoco"):
        raise InputError(f"jaw: expected kinematic or mujoco, got {jaw!r}")
    if jaw == "mujoco":
        for h in heads:
            if not (h / "head.xml").is_file():
                raise InputError(f"{h}: no head.xml for the MuJoCo jaw (rebuild with `facewarp build`, or use --jaw kinematic)")
    out = Path(out)
    outputs = [("out", out, "dir")] + [("out", out / n, "file") for n in names + ["report.json"]]
    if stage is not None:
        outputs.append(("stage", out / stage, "file"))
    expr_file = Path(str(expression)) if str(expression).lower().endswith(".json") else None
    check_apart(outputs, [("BUILD_DIR", h) for h in heads] + [("per_head", per_head), ("expression", expr_file)])
    specs = read_per_head(per_head, len(heads)) if per_head is not None else [str(expression)] * len(heads)
    timelines = {s: timeline_from_spec(s, float(seconds)) for s in dict.fromkeys(specs)}
    rigs, loaded = [], {}
    for h in heads:  # a folder named twice is one rig (its builder shared)
        key = str(h.resolve())
        if key not in loaded:
            loaded[key] = load_face_rig(h)
        rigs.append(loaded[key])
    V = max(len(fr.head_vertices) for fr in rigs)
    check_work(f"seconds, fps: {len(heads)} heads x {nf} frames", head_frames=len(heads) * (nf - 1), vertex_count=V,
               device=str(device), disk_bytes=len(heads) * estimate_frames_bytes(nf, V), folder=destination(out))
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    batch = FaceBatch(rigs, device=device, fps=fps, backend="heads")  # its heads stream USD
    if jaw == "mujoco":
        batch.use_mujoco_jaws([h / "head.xml" for h in heads])
    build_s = time.perf_counter() - t0
    per = [timelines[s].for_head(fr) for s, fr in zip(specs, rigs)]
    anims = [UsdAnimation(out / n, sim) for n, sim in zip(names, batch.heads)]
    try:
        # a frozen head's animation ends at its last good frame
        stepping = play_batch(batch, per, nf, fps, lambda i, sim, k, t: anims[i].add(sim, t), progress)
        for a in anims:
            a.close()
    except BaseException:
        for a in anims:
            a.abort()
        raise
    stepping = max(stepping, 1e-9)
    files = [str(out / n) for n in names]
    if stage is not None:  # the heads side by side along x, a head's width and a third apart
        from .animation import load_usd_export

        write_crowd_stage = load_usd_export().write_crowd_stage

        width = max(float(np.ptp(fr.head_vertices[:, 0])) for fr in rigs) * 1.3
        placed = []
        for i, n in enumerate(names):
            M = np.eye(4)
            M[3, 0] = (i - 0.5 * (len(names) - 1)) * width
            placed.append((Path(n).stem, out / n, M))
        files.append(str(write_crowd_stage(out / stage, placed)))
    status = batch.status
    rows = [{**s, "build": str(h), "expression": spec, "file": str(out / n)}
            for s, h, spec, n in zip(status, heads, specs, names)]
    rep = {"heads": len(heads), "ok": sum(r["ok"] for r in rows), "failed": sum(not r["ok"] for r in rows),
           "frames": nf, "seconds": float(seconds), "fps": float(fps), "device": str(batch.device), "jaw": jaw,
           "build_seconds": build_s, "simulation_wall_s": stepping,
           "frames_per_second": (nf - 1) / stepping, "head_frames_per_second": (nf - 1) * len(heads) / stepping,
           "rows": rows, "files": files + [str(out / "report.json")]}
    write_json(out / "report.json", rep)
    return rep


def simulate_group_files(heads, expression, outs, *, seconds: float = 2.0, fps: float = 30.0, device: str = "cpu",
                         jaw: str = "mujoco") -> list:
    """Play ``expression`` on every build folder of ``heads`` together in one
    :class:`~facewarp.FaceBatch` (``backend="heads"``: a :class:`~facewarp.FaceSimulator` per head,
    the MuJoCo jaw possible) and write each head's folder of ``outs`` as
    :func:`~facewarp._src.jobs.face.simulate_files` does for one head: ``frames.npz`` and
    ``frames.png``, and the same report.

    A head of the batch is stepped by the same calls as alone (the controls of :func:`~facewarp.play`,
    the MuJoCo jaw's exchange around the skin step), so on the CPU its frames are those of
    :func:`~facewarp._src.jobs.face.simulate_files` bit for bit. Timing: the stepping of the group is
    shared evenly, so a head's ``frames_per_second`` is its frames over (the group's stepping time
    divided by the heads), i.e. the group's head-frames per second.

    Args:
        heads: ``facewarp build`` folders, one per head, N.
        expression: A preset, ``"sequence"``, a sequence file or ``"muscle=value,..."`` (every head).
        outs: N output folders (made here), one per head.
        seconds, fps: Length [s] and frames per second.
        device: Warp device of every head.
        jaw: ``"mujoco"`` (default: each build's ``head.xml``, :meth:`~facewarp.FaceBatch.use_mujoco_jaws`)
            or ``"kinematic"``.

    Returns:
        Per head, in order: its report (the keys of :func:`~facewarp._src.jobs.face.simulate_files`'
        report), or the exception that head met (a bad build folder, a head frozen by a failure:
        :class:`~facewarp.SimulationError` with the error :attr:`~facewarp.FaceBatch.status` gives),
        which :func:`~facewarp._src.jobs.face.simulate_files` would raise for it.

    Raises:
        InputError: options bad for every head (expression, seconds, fps, jaw), or ``outs`` not one per head.
    """
    from ..core.errors import SimulationError
    from ..sim.batch import FaceBatch
    from ..sim.play import FrameRecorder, PlayStats
    from .checks import check_kept_frames, check_out_dir, load_simulated_head, make_out_dir
    from .face import _check_simulate, _simulate_report, _write_frames

    heads, outs = [Path(h) for h in heads], [Path(o) for o in outs]
    if not heads:
        raise InputError("heads: give at least one `facewarp build` folder")
    if len(outs) != len(heads):
        raise InputError(f"outs: expected one output folder per head ({len(heads)}), got {len(outs)}")
    seconds, timeline, name, jaw = _check_simulate(expression, seconds, fps, None, jaw, "physical", None)
    check_kept_frames(seconds, fps)
    results: list = [None] * len(heads)
    loaded = {}
    for i, (h, o) in enumerate(zip(heads, outs)):  # a bad folder fails its head only
        try:
            check_out_dir(o)
            loaded[i] = load_simulated_head(h, seconds, fps, jaw)
            make_out_dir(o)
        except Exception as e:
            results[i] = e
    live = list(loaded)
    if not live:
        return results
    t0 = time.perf_counter()
    batch = FaceBatch([loaded[i][0] for i in live], device=device, fps=fps, backend="heads")
    if jaw == "mujoco":
        batch.use_mujoco_jaws([loaded[i][1] for i in live])
    per = [timeline.for_head(sim.fr) for sim in batch.heads]  # chin drops -> each head's jaw angles, as play does
    nf = int(round(seconds * fps)) + 1
    keep = [FrameRecorder() for _ in live]
    for rec, sim in zip(keep, batch.heads):
        rec.start(sim, nf)
    stepping = play_batch(batch, per, nf, fps, lambda j, sim, k, t: keep[j].frame(sim, k, t))
    wall = time.perf_counter() - t0
    share = max(stepping, 1e-9) / len(live)  # the group's stepping shared evenly between its heads
    for j, i in enumerate(live):
        if j in batch.failed:
            results[i] = SimulationError(batch.failed[j])
            continue
        sim = batch.heads[j]
        events = list(batch._mujoco[j].coupler.events) if batch._mujoco is not None else []
        stats = PlayStats.measured(sim, frames=nf, seconds=seconds, wall_s=wall / len(live), stepping_s=share,
                                   jaw=jaw, mujoco_events=events)
        keep[j].finish(sim, stats)
        try:
            written, moved = _write_frames(outs[i], keep[j].frames, timeline, seconds, fps, name, device)
            results[i] = _simulate_report(name, stats, sim, loaded[i][0], jaw, written, moved)
        except Exception as e:
            results[i] = e
    return results
