"""Upper bounds of every size argument, and memory estimates checked before the heavy work.

Each bound is far above what a real run asks for (the thesis uses one skin layer, five
refinement levels, seconds of animation) and low enough that a typo (``--layers 1000000``)
is refused at once instead of running for minutes and filling the memory. The CLI and the
API functions that take these sizes check them with :func:`check_count` / :func:`check_amount`.

Disk estimates (the USD and frame files a run streams out) are compared with the free space of
the output's file system (``FACEWARP_DISK_LIMIT`` lowers it, as the memory's variable does), and
time estimates (head-frames at a measured rate, :data:`SECONDS_PER_HEAD_FRAME`) with
:data:`MAX_ESTIMATED_SECONDS`; a refusal states the estimates (:func:`check_work`).

Memory estimates are made from counts known before the work (nodes, tets, frames, vertices)
and compared with the memory this process may still take: ``MemAvailable`` of
``/proc/meminfo``, or less under a cgroup limit; the environment variable
``FACEWARP_MEMORY_LIMIT`` (bytes, or with a suffix ``K``, ``M``, ``G``) lowers it further
(tests use it to see the check refuse). The per-item costs below were measured on level-0 and
level-1 heads (peak resident memory over the baseline) and rounded up about 2x.
"""

from __future__ import annotations

import math
import numbers
import os

from .errors import InputError

__all__ = [
    "BATCH_BYTES_PER_NODE", "BATCH_BYTES_PER_TET", "BUILD_BYTES_PER_NODE", "BUILD_BYTES_PER_TET", "BYTES_PER_FRAME_VERTEX", "BYTES_PER_NODE", "BYTES_PER_TET", "MAX_ADAPT_LEVELS", "MAX_ADVANCE_FRAMES", "MAX_FPS", "MAX_HEADS",
    "MAX_LAYERS", "MAX_MORPH_STEPS", "MAX_SECONDS", "MAX_SEED", "MAX_STEPS", "MAX_SUBSTEPS", "available_memory",
    "check_amount", "check_count", "check_disk", "check_memory", "check_steps", "check_work", "estimate_batch_bytes", "estimate_build_bytes",
    "estimate_frames_bytes", "estimate_sim_bytes", "estimate_seconds", "free_disk", "describe_seconds",
]

MAX_LAYERS = 16
"""Most tet layers through the skin (``build --layers``; the thesis uses 1)."""
MAX_ADAPT_LEVELS = 12
"""Most refinement levels of the adaptation (``adapt --levels``); past about 8 the CSRBF support
(halved per level) is below the template's edge length and a level adds nothing."""
MAX_SUBSTEPS = 10_000
"""Most solver steps per frame (``simulate --substeps``; the explicit reference needs about 1,000)."""
MAX_SECONDS = 3600.0
"""Longest animation [s] (``simulate/demo/retarget --seconds``)."""
MAX_FPS = 1000.0
"""Most frames per second (``--fps``)."""
MAX_ADVANCE_FRAMES = int(MAX_SECONDS * MAX_FPS)
"""Most frames one :meth:`~facewarp.FaceSimulator.advance` takes (an hour at the highest frame rate)."""
MAX_STEPS = 20_000_000
"""Most solver steps of one run (frames x substeps): about a day of CPU time at level 0."""
MAX_MORPH_STEPS = 1000
"""Most in-between heads of ``morph --steps``."""
MAX_HEADS = 64
"""Most heads one ``retarget`` plays on."""
MAX_SEED = 2**32 - 1
"""Largest ``demo --seed`` (NumPy seeds are 32-bit here)."""

BYTES_PER_TET = 16384
"""Memory per tetrahedron while simulating (tables, solver matrices, Warp arrays). Measured: a
level-0 head with 8 layers (53,904 tets, 11,016 nodes) peaks 625 MB above the 1-layer head
(6,738 tets, 2,448 nodes) over a 1 s run; these two constants give 843 MB for the difference."""
BYTES_PER_NODE = 8192
"""Memory per simulation node (state, solver vectors, contact)."""
BUILD_BYTES_PER_TET = 2048
"""Memory per tetrahedron while building (measured about 0.5 kB: 16 layers of the level-0 head)."""
BUILD_BYTES_PER_NODE = 1024
"""Memory per node while building."""
BATCH_BYTES_PER_TET = 2048
"""Memory per tetrahedron of each further head of one rig in a :class:`~facewarp.FaceBatch` (the
heads share the rig's builder; a head's own Model arrays, State, Control and solver buffers).
Measured: a level-0 head (6,738 tets, 2,448 nodes) adds about 17.7 MB; these constants give 18.8 MB."""
BATCH_BYTES_PER_NODE = 2048
"""Memory per node of each further head of one rig in a :class:`~facewarp.FaceBatch`."""
BYTES_PER_FRAME_VERTEX = 24
"""Memory per kept frame and vertex (positions in float32, the USD layer's copy)."""
BYTES_PER_FRAME = 16384
"""Memory per kept frame besides the vertices (FDPs, muscle curves, activations)."""


def _whole(v) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _real(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool)


def check_count(name: str, value, *, low: int = 1, high: int) -> int:
    """``value`` as an int when it is a whole number in ``low..high``, else :class:`InputError`
    naming ``name``."""
    if not _whole(value) or not low <= value <= high:
        raise InputError(f"{name}: expected a whole number {low}..{high}, got {value!r}")
    return int(value)


def check_amount(name: str, value, *, high: float, low_exclusive: float = 0.0) -> float:
    """``value`` as a float when finite, > ``low_exclusive`` and <= ``high``, else :class:`InputError`."""
    if not _real(value) or not math.isfinite(value) or not low_exclusive < value <= high:
        raise InputError(f"{name}: expected a finite number > {low_exclusive:g} and <= {high:g}, got {value!r}")
    return float(value)


def check_steps(seconds: float, fps: float, substeps: int | None, *, what: str = "seconds, fps, substeps") -> None:
    """Refuse a run of more than :data:`MAX_STEPS` solver steps (frames x substeps)."""
    steps = (round(seconds * fps) + 1) * (substeps or 1)
    if steps > MAX_STEPS:
        raise InputError(f"{what}: {seconds:g} s at {fps:g} fps x {substeps or 1} substeps is {steps:.3g} solver "
                         f"steps, more than {MAX_STEPS:.3g} per run")


# ----------------------------------------------------------------------------- memory
def _parse_bytes(text: str) -> int | None:
    t = text.strip().upper()
    mult = 1
    for suffix, m in (("K", 1 << 10), ("M", 1 << 20), ("G", 1 << 30), ("T", 1 << 40)):
        if t.endswith(suffix) or t.endswith(suffix + "B"):
            t, mult = t[: t.rindex(suffix)], m
            break
    try:
        v = float(t) * mult
    except ValueError:
        return None
    return int(v) if math.isfinite(v) and v >= 0 else None


def _meminfo_available() -> int | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _cgroup_available() -> int | None:
    for limit_f, usage_f in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                             ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                              "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            with open(limit_f) as f:
                limit = f.read().strip()
            if limit == "max":
                return None
            with open(usage_f) as f:
                usage = int(f.read().strip())
            limit_b = int(limit)
            if limit_b >= 1 << 60:  # "unlimited" in cgroup v1
                return None
            return max(limit_b - usage, 0)
        except (OSError, ValueError):
            continue
    return None


def available_memory() -> int | None:
    """Bytes this process may still allocate (the least of MemAvailable, the cgroup's room and
    ``FACEWARP_MEMORY_LIMIT``), or None when nothing can be read."""
    found = [v for v in (_meminfo_available(), _cgroup_available()) if v is not None]
    env = os.environ.get("FACEWARP_MEMORY_LIMIT")
    if env:
        v = _parse_bytes(env)
        if v is not None:
            found.append(v)
    return min(found) if found else None


def _gb(n: float) -> str:
    if n >= 1e12:
        return f"{n / 1e12:.3g} TB"
    return f"{n / 1e9:.3g} GB" if n >= 1e8 else f"{n / 1e6:.3g} MB"


def check_memory(need_bytes: float, what: str) -> None:
    """Refuse with :class:`InputError` naming ``what`` when the run would need more memory than
    :func:`available_memory`."""
    avail = available_memory()
    if avail is not None and need_bytes > avail:
        raise InputError(f"{what}: needs about {_gb(need_bytes)} of memory, {_gb(avail)} available on this machine "
                         "(ask for less)")


def estimate_build_bytes(vertex_count: int, face_count: int, layers: int) -> float:
    """Memory to build ``layers`` tet layers under a skin of ``face_count`` triangles (about one
    tet per triangle and layer: each prism's three tets are shared out over the layer's
    triangles' wedges, 6,738 tets under the level-0 skin's 6,742 triangles) and the face rig."""
    tets = 1.1 * face_count * layers
    nodes = float(vertex_count) * (layers + 1)
    return tets * BUILD_BYTES_PER_TET + nodes * BUILD_BYTES_PER_NODE


def estimate_batch_bytes(node_count: int, tet_count: int, heads: int) -> float:
    """Memory of ``heads`` heads of one rig of ``node_count`` nodes and ``tet_count`` tets in a
    :class:`~facewarp.FaceBatch`: the first as a simulator alone (:func:`estimate_sim_bytes`), each
    further one a replica sharing its builder (:data:`BATCH_BYTES_PER_TET`, :data:`BATCH_BYTES_PER_NODE`)."""
    first = estimate_sim_bytes(node_count, tet_count)
    return first + max(int(heads) - 1, 0) * (float(tet_count) * BATCH_BYTES_PER_TET
                                             + float(node_count) * BATCH_BYTES_PER_NODE)


def estimate_frames_bytes(frames: float, vertex_count: int) -> float:
    """Memory of ``frames`` kept frames (or USD time samples) of a head of ``vertex_count`` vertices."""
    return float(frames) * (vertex_count * BYTES_PER_FRAME_VERTEX + BYTES_PER_FRAME)


def estimate_sim_bytes(node_count: int, tet_count: int, frames_kept: float = 0, vertex_count: int = 0) -> float:
    """Memory of a simulator on ``node_count`` nodes and ``tet_count`` tets keeping ``frames_kept``
    frames of ``vertex_count`` surface vertices."""
    return (float(tet_count) * BYTES_PER_TET + float(node_count) * BYTES_PER_NODE
            + estimate_frames_bytes(frames_kept, vertex_count or node_count))


# ----------------------------------------------------------------------------- disk and time
SECONDS_PER_HEAD_FRAME = {"cpu": 1.0, "cuda": 0.01}
"""Wall time of one frame of one level-0 head [s], by device kind. CPU: the soak measured 1.01-1.16
frames/s a head of process time (the default L-BFGS solver, 2 jobs on the 2-core box); CUDA: the
batch benchmark's order of magnitude for many heads in one graph (100 head-frames/s and more).
A level-L head costs about 4^L times as much (a level has 4x the triangles)."""

MAX_ESTIMATED_SECONDS = 7 * 24 * 3600.0
"""Longest run a command starts [s of estimated wall time]: a week at the rate above; longer is
a typo (``--seconds 3600 --fps 1000``) or work to split into a batch of its own."""


def describe_seconds(s: float) -> str:
    """``s`` seconds as a short text: ``"40 s"``, ``"12 min"``, ``"34 h"``, ``"3.2 days"``."""
    if s < 120:
        return f"{s:.0f} s"
    if s < 3 * 3600:
        return f"{s / 60:.0f} min"
    if s < 3 * 86400:
        return f"{s / 3600:.0f} h"
    return f"{s / 86400:.2g} days"


def estimate_seconds(head_frames: float, device: str = "cpu", vertex_count: int = 3415) -> float:
    """Wall time of ``head_frames`` simulated frames (frames x heads) of heads of ``vertex_count``
    surface vertices (the level-0 head has 3,415) on ``device`` [s] (:data:`SECONDS_PER_HEAD_FRAME`)."""
    rate = SECONDS_PER_HEAD_FRAME["cuda" if str(device).startswith("cuda") else "cpu"]
    return float(head_frames) * rate * max(vertex_count / 3415.0, 1.0)


def free_disk(folder) -> int | None:
    """Free bytes on the file system of ``folder`` (its nearest existing parent), the least of that
    and ``FACEWARP_DISK_LIMIT``; None when nothing can be read."""
    import shutil
    from pathlib import Path

    p = Path(folder).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    found = []
    try:
        found.append(shutil.disk_usage(p).free)
    except OSError:
        pass
    env = os.environ.get("FACEWARP_DISK_LIMIT")
    if env:
        v = _parse_bytes(env)
        if v is not None:
            found.append(v)
    return min(found) if found else None


def check_disk(need_bytes: float, folder, what: str, *, seconds: float | None = None) -> None:
    """Refuse with :class:`InputError` naming ``what`` when ``need_bytes`` of output would not fit
    on the file system of ``folder`` (:func:`free_disk`); the time estimate ``seconds`` [s] is stated too."""
    free = free_disk(folder)
    if free is not None and need_bytes > free:
        extra = f" and about {describe_seconds(seconds)}" if seconds is not None else ""
        raise InputError(f"{what}: would write about {_gb(need_bytes)} of files{extra}, {_gb(free)} free on the "
                         f"disk of {folder} (ask for less)")


def check_work(what: str, *, head_frames: float, vertex_count: int, device: str, memory_bytes: float = 0.0,
               disk_bytes: float = 0.0, folder=None) -> dict:
    """The estimates of a run of ``head_frames`` frames x heads checked against this machine before
    it starts: memory (:func:`check_memory`), disk (:func:`check_disk` on ``folder``) and time
    (:func:`estimate_seconds` against :data:`MAX_ESTIMATED_SECONDS`); each refusal is one line
    naming ``what`` and stating the estimates. Returns ``{"seconds", "memory_bytes", "disk_bytes"}``."""
    seconds = estimate_seconds(head_frames, device, vertex_count)
    if memory_bytes:
        avail = available_memory()
        if avail is not None and memory_bytes > avail:
            raise InputError(f"{what}: needs about {_gb(memory_bytes)} of memory (and about {describe_seconds(seconds)}), "
                             f"{_gb(avail)} available on this machine (ask for less)")
    if disk_bytes and folder is not None:
        check_disk(disk_bytes, folder, what, seconds=seconds)
    if seconds > MAX_ESTIMATED_SECONDS:
        raise InputError(f"{what}: {head_frames:.3g} head-frames would take about {describe_seconds(seconds)} on "
                         f"{device}" + (f" and write about {_gb(disk_bytes)}" if disk_bytes else "")
                         + f", more than {describe_seconds(MAX_ESTIMATED_SECONDS)} per run (ask for less)")
    return {"seconds": seconds, "memory_bytes": float(memory_bytes), "disk_bytes": float(disk_bytes)}
