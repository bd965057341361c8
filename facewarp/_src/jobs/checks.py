"""Checks shared by the file-level jobs: output folders, done before any heavy work."""

from __future__ import annotations

import os
from pathlib import Path

from ..core.errors import InputError

__all__ = ["MAX_FRAMES", "check_apart", "check_kept_frames", "check_some_frames", "check_out_dir", "load_simulated_head",
           "make_out_dir"]

MAX_FRAMES = 100_000
"""Most frames one ``simulate`` run keeps in memory (about 1 h at 30 fps; a level-0 head takes
about 60 kB a frame)."""


def check_out_dir(out) -> Path:
    """``out`` as a Path; raises :class:`InputError` when it exists and is not a folder (no side effects)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"out {out}: exists and is not a folder")
    return out


def make_out_dir(out) -> Path:
    """Create the output folder ``out`` (with its parents) and check that it is writable.

    Called after the inputs are read and checked and before the long work, so that a folder
    that cannot be written fails in seconds rather than after the simulation.

    Raises:
        InputError: ``out`` exists and is not a folder, cannot be created (a parent is a
            file, no permission, read-only file system) or is not writable.
    """
    out = check_out_dir(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"out {out}: cannot create the folder ({e.strerror or e})") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"out {out}: the folder is not writable")
    return out


def check_kept_frames(seconds: float, fps: float) -> None:
    """A run whose frames are all kept in memory (a FrameRecorder keeps round(seconds * fps) + 1
    frames) stays under :data:`MAX_FRAMES`."""
    if not seconds * fps < MAX_FRAMES:
        raise InputError(f"seconds, fps: {seconds:g} s at {fps:g} fps is {seconds * fps:.3g} frames, "
                         f"more than {MAX_FRAMES} per run")


def check_some_frames(seconds: float, fps: float) -> None:
    """A run of ``seconds`` at ``fps`` has a frame after its first (the rest pose): round(seconds * fps) >= 1.
    Below that a command would write the rest pose alone and call it the expression."""
    if round(seconds * fps) < 1:
        raise InputError(f"seconds, fps: {seconds:g} s at {fps:g} fps has no frame after the rest pose "
                         "(seconds x fps must be more than 0.5)")


def load_simulated_head(head_path, seconds: float, fps: float, jaw: str):
    """The face rig of a build (checked to fit in memory for ``seconds`` at ``fps``) and its
    ``head.xml`` path (parsed when ``jaw`` is ``"mujoco"``). Here, beside the other checks, so that
    a simulation's job leaves its own module once on the way to the simulator (tests/test_play.py)."""
    from ..core.limits import check_memory, estimate_sim_bytes
    from ..physics.face_rig import load_face_rig
    from .animation import load_mjcf

    check_some_frames(seconds, fps)
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
    return fr, mjcf


def _real(p, parents: dict) -> Path:
    """Where ``p`` ends up, its folder's links resolved (the file itself is replaced, not its link's
    target); ``parents`` caches the folders (10,000 files of one folder resolve it once)."""
    from ..core.outputs import destination

    d = Path(destination(p))
    if d.parent not in parents:
        parents[d.parent] = d.parent.resolve()
    return parents[d.parent] / d.name


def check_apart(outputs, inputs) -> None:
    """Outputs that would replace or write into an input, refused before any work.

    ``outputs``: ``[(name, path, "dir" | "file")]`` what the job writes (a staged path is taken
    where it ends up, :func:`~facewarp._src.core.outputs.destination`); ``inputs``: ``[(name,
    path)]`` the files and folders it reads. Refused: an output that is an input or lies inside an
    input folder (``batch simulate --out BUILD`` would replace the build's ``report.json``), and an
    output folder inside which an input lies where the job writes a file (checked by the file
    outputs). Two outputs that are one path are refused too. One line naming both.
    """
    ins: dict[Path, tuple[str, bool]] = {}
    for q, m in {str(q): m for m, q in reversed(list(inputs)) if q is not None}.items():  # a folder named twice once
        if Path(q).exists():
            ins.setdefault(Path(q).resolve(), (m, Path(q).is_dir()))
    seen: dict[Path, str] = {}
    parents: dict = {}
    for n, p, _ in outputs:  # a set lookup per output and per parent: 10,000 heads' files check at once
        p = _real(p, parents)
        for q in (p, *p.parents):
            if q in ins and (q == p or ins[q][1]):
                m = ins[q][0]
                raise InputError(f"{n} {p}: would {'replace' if q == p else 'write into'} the input {m} {q}; "
                                 "choose an output apart from the inputs")
        if p in seen:
            raise InputError(f"{n} {p}: is also {seen[p]}; choose outputs of their own")
        seen[p] = n
