"""``facewarp batch simulate``: many built heads played together in one :class:`~facewarp.FaceBatch`.

Files in: the ``facewarp build`` folders (one head each, any mix of identities), an expression
for all (or one per head from a ``--per-head`` file). Files out: ``head_KK.usdc`` per head (the
USD animation of :class:`~facewarp.UsdAnimation`, streamed while simulating) and
``report.json`` (per-head status, frames per second, head-frames per second).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fileio import write_json
from ..core.limits import MAX_FPS, MAX_SECONDS
from ..expressions import timeline_from_spec
from ..physics.face_rig import load_face_rig

__all__ = ["MAX_CLI_HEADS", "batch_simulate_files", "read_per_head"]

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
        raise InputError(f"{p}: cannot be read ({e.strerror or e})") from None
    except ValueError as e:
        raise InputError(f"{p}: not valid JSON ({e})") from None
    heads = doc.get("heads") if isinstance(doc, dict) else None
    if not isinstance(heads, list):
        raise InputError(f'{p}: expected {{"heads": [expression, ...]}} with one entry per head')
    if len(heads) != count:
        raise InputError(f"{p}: {len(heads)} entries for {count} heads (one per BUILD_DIR, in order)")
    out = []
    for i, h in enumerate(heads):
        spec = h.get("expression") if isinstance(h, dict) else h
        if not isinstance(spec, str) or not spec.strip():
            raise InputError(f'{p}: heads[{i}]: expected an expression name or {{"expression": NAME}}, got {h!r:.60}')
        if spec.lower().endswith(".json") and not Path(spec).is_absolute():
            spec = str(p.parent / spec)
        out.append(spec)
    return out


def batch_simulate_files(heads, expression: str, out, *, per_head=None, seconds: float = 2.0, fps: float = 30.0,
                         device: str = "cpu", jaw: str = "kinematic", stage: str | None = None, progress=None) -> dict:
    """Play ``expression`` (or each head's own from ``per_head``) on every build folder of
    ``heads`` at once (:class:`~facewarp.FaceBatch`) and write ``out/head_KK.usdc`` and
    ``out/report.json``.

    Args:
        heads: ``facewarp build`` folders, one per head.
        expression: What :func:`~facewarp.timeline_from_spec` reads: a preset, ``"sequence"``, a
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

    heads = [Path(h) for h in heads]
    if not heads:
        raise InputError("BUILD_DIR: give at least one `facewarp build` folder")
    if len(heads) > MAX_CLI_HEADS:
        raise InputError(f"BUILD_DIR: at most {MAX_CLI_HEADS} heads, got {len(heads)}")
    for key, v, high in (("seconds", seconds, MAX_SECONDS), ("fps", fps, MAX_FPS)):
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0 < v <= high):
            raise InputError(f"{key}: expected a finite number > 0 and <= {high:g}, got {v!r}")
    if stage is not None and (Path(stage).name != str(stage) or Path(stage).suffix not in (".usda", ".usdc")):
        raise InputError(f"stage: expected a file name ending in .usda or .usdc (written in the output folder), got {stage!r}")
    if jaw not in ("kinematic", "mujoco"):
        raise InputError(f"jaw: expected kinematic or mujoco, got {jaw!r}")
    if jaw == "mujoco":
        for h in heads:
            if not (h / "head.xml").is_file():
                raise InputError(f"{h}: no head.xml for the MuJoCo jaw (rebuild with `facewarp build`, or use --jaw kinematic)")
    specs = read_per_head(per_head, len(heads)) if per_head is not None else [str(expression)] * len(heads)
    timelines = {s: timeline_from_spec(s, float(seconds)) for s in dict.fromkeys(specs)}
    rigs, loaded = [], {}
    for h in heads:  # a folder named twice is one rig (its builder shared)
        key = str(h.resolve())
        if key not in loaded:
            loaded[key] = load_face_rig(h)
        rigs.append(loaded[key])
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    batch = FaceBatch(rigs, device=device, fps=fps, backend="heads")  # its heads stream USD
    if jaw == "mujoco":
        batch.use_mujoco_jaws([h / "head.xml" for h in heads])
    build_s = time.perf_counter() - t0
    per = [timelines[s].for_head(fr) for s, fr in zip(specs, rigs)]
    nf = int(round(seconds * fps)) + 1
    width = max(2, len(str(len(heads) - 1)))
    names = [f"head_{i:0{width}d}.usdc" for i in range(len(heads))]
    anims = [UsdAnimation(out / n, sim) for n, sim in zip(names, batch.heads)]
    stepping = 0.0
    try:
        for k in range(nf):
            t = k / fps
            if k > 0:
                es = [tl.sample(t) for tl in per]
                batch.set_activations(es)
                batch.set_jaw(np.array([[e.jaw_u, e.jaw_v] for e in es]))
                s0 = time.perf_counter()
                batch.step()
                stepping += time.perf_counter() - s0
            for i, (a, sim) in enumerate(zip(anims, batch.heads)):
                if i not in batch.failed:  # a frozen head's animation ends at its last good frame
                    a.add(sim, t)
            if progress:
                progress(k, nf)
        for a in anims:
            a.close()
    except BaseException:
        for a in anims:
            a.abort()
        raise
    stepping = max(stepping, 1e-9)
    files = [str(out / n) for n in names]
    if stage is not None:  # the heads side by side along x, a head's width and a third apart
        from usd_export import write_crowd_stage

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
