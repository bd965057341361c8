"""What every benchmark shares: the case setup, the machine description and the one result schema.

A result file ``benchmarks/results/<name>.json`` is written by :func:`save` only, as::

    {"benchmark": "physics_steps",             # the case (module) that wrote it
     "machine": {"cpu": ..., "cores": ..., "memory_gib": ..., "platform": ...},
     "device": "NVIDIA H100 80GB HBM3",        # the device the case ran on, by name ("cpu" on the CPU)
     "versions": {"python": ..., "facewarp": ..., "warp": ..., "mujoco": ..., "numpy": ..., ...},
     "date": "2026-11-24T21:05:11+00:00",      # UTC, when the file was written
     "command": "python -m benchmarks physics_steps --device cuda",
     "figures": {...}}                          # the measurements: the case's own keys

Case setup (:func:`add_case_args`, :func:`case_template`, :func:`case_face`): the head (``default`` at
a level, an adapted ICT-FaceKit identity ``identityNNN``, or a template / build folder), the level,
the preset(s), the device and the seed, with the same option names in every case.

This module imports no facewarp, warp or numpy at import time (``python -m benchmarks --list`` stays fast).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parent
#: Where results are written: ``$FACEWARP_BENCH_RESULTS`` or benchmarks/results (``python -m benchmarks --results DIR``).
RESULTS = Path(os.environ.get("FACEWARP_BENCH_RESULTS") or BENCHMARKS / "results")
#: The committed results (what the README's tables are generated from).
COMMITTED = BENCHMARKS / "results"
REPO = BENCHMARKS.parent
SCHEMA_KEYS = ("benchmark", "machine", "device", "versions", "date", "command", "figures")

# distribution name -> key in "versions" (absent packages are left out)
_PACKAGES = {"warp-lang": "warp", "mujoco": "mujoco", "numpy": "numpy", "scipy": "scipy", "usd-core": "usd-core",
             "trimesh": "trimesh", "qdldl": "qdldl", "libigl": "libigl", "newton": "newton"}

#: The command line recorded in results; the runner sets it (``python -m benchmarks NAME ...``).
command_line: str | None = None


def shared_dir() -> Path:
    """The shared data folder: ``$FACEWARP_SHARED``, else ``../shared`` beside the repository."""
    env = os.environ.get("FACEWARP_SHARED")
    return Path(env) if env else REPO.parent / "shared"


def limit_threads(n: int) -> None:
    """Limit BLAS / OpenMP threads to ``n`` and pin the process to ``n`` cores (before numpy is imported)."""
    for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS",
              "VECLIB_MAXIMUM_THREADS"):
        os.environ[k] = str(n)
    if hasattr(os, "sched_setaffinity"):
        try:
            cpus = sorted(os.sched_getaffinity(0))
            os.sched_setaffinity(0, set(cpus[:n]))
        except OSError:
            pass


def threads_from_argv(argv: list[str], default: int = 1) -> int:
    """The value of ``--threads N`` in ``argv`` (``default`` without one); for cases pinned before numpy loads."""
    import argparse

    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--threads", type=int, default=default)
    return pre.parse_known_args(argv)[0].threads


# --- the machine, the device, the versions -------------------------------------------------------------------------


def machine(device: str | None = None) -> dict:
    """The host: CPU model, logical cores, cores this process may use, memory [GiB], platform.

    ``device`` is accepted for scripts written before the schema and ignored (the device is the
    result's own key, :func:`save`'s ``device``)."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    memory = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                memory = round(int(line.split()[1]) / 2**20, 1)
                break
    except OSError:
        pass
    info = {"cpu": cpu, "cores": os.cpu_count(), "memory_gib": memory, "platform": platform.platform(),
            "node": platform.node()}
    if hasattr(os, "sched_getaffinity"):
        info["cores_usable"] = len(os.sched_getaffinity(0))
    if hasattr(os, "getloadavg"):
        info["load_average_1_5_15_min"] = [round(v, 2) for v in os.getloadavg()]
    return info


def device_name(device: str = "cpu") -> str:
    """The device by name: the GPU's name for ``cuda[:N]``, ``cpu`` for the CPU."""
    if not str(device).startswith("cuda"):
        return "cpu"
    import warp as wp

    wp.init()
    return wp.get_device(device).name


def versions() -> dict:
    """Python, facewarp (version and git commit) and the installed packages a benchmark may use."""
    out = {"python": platform.python_version()}
    try:
        out["facewarp"] = metadata.version("facewarp")
    except metadata.PackageNotFoundError:
        out["facewarp"] = None
    try:
        commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
        if commit:
            out["facewarp_commit"] = commit + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        pass
    for dist, key in _PACKAGES.items():
        try:
            out[key] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


def _command(benchmark: str) -> str:
    if command_line:
        return command_line
    return " ".join(["python -m benchmarks", benchmark, *sys.argv[1:]])


# --- the one writer and reader --------------------------------------------------------------------------------------


def _plain(obj):
    """JSON form of NumPy arrays and scalars (``tolist``) and of paths (``str``)."""
    return obj.tolist() if hasattr(obj, "tolist") else str(obj)


def result(benchmark: str, figures: dict, *, device: str = "cpu", machine_extra: dict | None = None) -> dict:
    """The result document of ``benchmark`` (schema in the module docstring) around ``figures``."""
    if not isinstance(figures, dict):
        raise TypeError(f"figures must be a dict, got {type(figures).__name__}")
    host = machine()
    host.update(machine_extra or {})
    return {"benchmark": benchmark, "machine": host, "device": device_name(device), "versions": versions(),
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "command": _command(benchmark),
            "figures": figures}


def save(name: str, figures: dict, *, device: str = "cpu", benchmark: str | None = None,
         machine_extra: dict | None = None, folder: Path | str | None = None) -> Path:
    """Write ``benchmarks/results/<name>.json`` in the one schema; returns its path.

    ``figures`` are the case's measurements (any JSON-able dict; NumPy values become lists, NaN and
    infinity are refused). ``benchmark`` defaults to the calling module's file name. The file is
    replaced atomically, so a failed run leaves the old result.
    """
    if benchmark is None:
        benchmark = Path(sys._getframe(1).f_globals.get("__file__", name)).stem
    if isinstance(figures, dict) and isinstance(figures.get("machine"), dict):
        # a script written before the schema put machine(device) among its figures: it belongs outside
        figures = dict(figures)
        old = figures.pop("machine")
        if device == "cpu" and str(old.get("device", "cpu")).startswith("cuda"):
            device = old["device"]
    doc = result(benchmark, figures, device=device, machine_extra=machine_extra)
    out = Path(folder) if folder is not None else RESULTS
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.json"
    text = json.dumps(doc, indent=2, default=_plain, allow_nan=False) + "\n"
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


def load(name: str | Path) -> dict:
    """A result document by name (``physics_steps_cpu``) or path; ``KeyError`` naming a missing schema key."""
    path = Path(name)
    if path.suffix != ".json":
        path = RESULTS / f"{name}.json"
    doc = json.loads(path.read_text())
    missing = [k for k in SCHEMA_KEYS if k not in doc]
    if missing:
        raise KeyError(f"{path}: not a benchmark result (missing {', '.join(missing)})")
    return doc


def machine_line(doc: dict) -> str:
    """One line naming where a result was measured (for the Markdown reports)."""
    m, v = doc["machine"], doc["versions"]
    return (f"Machine: {m.get('cpu')}, {m.get('cores')} cores, {m.get('memory_gib')} GiB; device {doc['device']}; "
            f"python {v.get('python')}, warp {v.get('warp')}, numpy {v.get('numpy')}; {doc['date']}")


# --- case setup ------------------------------------------------------------------------------------------------------


_UNSET = object()


def add_case_args(ap, *, device=_UNSET, head=_UNSET, level=_UNSET, levels=_UNSET, preset=_UNSET, presets=_UNSET,
                  seed=_UNSET) -> None:
    """Add the shared case options to an ``argparse`` parser, each only when its default is given.

    ``--device cpu|cuda[:N]``, ``--head default|identityNNN|DIR`` (:func:`case_face`), ``--level N``,
    ``--levels N ...``, ``--preset NAME``, ``--presets NAME ...``, ``--seed S`` (``seed=None``: a new
    seed per run, recorded in the figures).
    """
    if device is not _UNSET:
        ap.add_argument("--device", default=device, help=f"cpu or cuda[:N] (default {device})")
    if head is not _UNSET:
        ap.add_argument("--head", default=head,
                        help="default (the built-in template at --level), identityNNN (the default template adapted "
                             "to that ICT-FaceKit identity, made on first use) or a template / build folder")
    if level is not _UNSET:
        ap.add_argument("--level", type=int, default=level, help=f"template level (default {level})")
    if levels is not _UNSET:
        ap.add_argument("--levels", type=int, nargs="+", default=list(levels), help="template levels")
    if preset is not _UNSET:
        ap.add_argument("--preset", default=preset, help=f"expression preset (default {preset})")
    if presets is not _UNSET:
        ap.add_argument("--presets", nargs="+", default=list(presets), help="expression presets")
    if seed is not _UNSET:
        ap.add_argument("--seed", type=int, default=seed,
                        help="random seed (default: a new one per run)" if seed is None else f"random seed (default {seed})")


def heads_dir() -> Path:
    """Where adapted heads are kept between runs: ``$FACEWARP_BENCH_HEADS`` or ``/tmp/facewarp_heads``."""
    return Path(os.environ.get("FACEWARP_BENCH_HEADS", "/tmp/facewarp_heads"))


def case_head_dir(head: str) -> Path | None:
    """The folder of a head spec: ``identityNNN`` (made on first use), a folder, or None for ``default``."""
    if head == "default":
        return None
    if head.startswith("identity") and head[8:].isdigit() and not Path(head).exists():
        from benchmarks._ict import adapted_identity

        return adapted_identity(int(head[8:]), heads_dir())["dir"] / "build"
    return Path(head)


def case_template(head: str = "default", level: int = 0):
    """The head of a case as a template: the built-in one at ``level``, an adapted identity or a folder."""
    import facewarp as fw

    folder = case_head_dir(head)
    if folder is None:
        return fw.default_template(level)
    return fw.load_head(str(folder))


def case_face(head: str = "default", level: int = 0):
    """The face rig of a case: a build folder's ``face_rig.npz`` as saved, else built from :func:`case_template`."""
    import facewarp as fw

    folder = case_head_dir(head)
    if folder is not None and (folder / "face_rig.npz").is_file():
        return fw.load_face_rig(str(folder))
    return fw.build_face(case_template(head, level))


def head_tag(head: str) -> str:
    """The name of a head in output file names: '' for default, ``identityNNN`` for an identity or its build folder."""
    if head == "default":
        return ""
    p = Path(head).resolve()
    return p.parent.name if p.name == "build" else p.name


# --- materials and static shapes (solver_accuracy, level_maps) ------------------------------------------------------


def material_label(material) -> str:
    """A profile's name in the results: its name, or ``physical+shear<mu>[+volume<K>]`` for the shear variant."""
    if isinstance(material, str):
        return material
    if not getattr(material, "shear_modulus", 0):
        return material.name
    from facewarp.physics import MaterialPhysical

    label = f"{material.name}+shear{material.shear_modulus:g}"
    same = material.volume_modulus == MaterialPhysical().volume_modulus
    return label if same else label + f"+volume{material.volume_modulus:g}"


def shear_material(mu: float, volume_modulus: float | None = None):
    """The physical profile with the shear term (``mu`` [Pa]) in place of the distance and area
    energies (and, if given, another volume modulus [Pa])."""
    from facewarp.physics import MaterialPhysical

    kw = {} if volume_modulus is None else {"volume_modulus": volume_modulus}
    return MaterialPhysical(distance_modulus=(0.0, 0.0, 0.0), area_modulus=0.0, shear_modulus=mu, **kw)


def run_timeline(fr, timeline, seconds: float, **kw):
    """A fresh simulator on ``fr`` (keywords to ``FaceSimulator``) run over ``timeline``: (Frames, simulator)."""
    import facewarp as fw

    sim = fw.FaceSimulator(fr, **kw)
    return sim.run(timeline, seconds), sim


def static_shape(fr, preset: str, material, device: str, **kw):
    """A preset ramped in over 0.3 s and held (0.8 s in all): FDPs at the end and at rest (84, 3) [m], the simulator."""
    import numpy as np

    import facewarp as fw

    tl = fw.timeline_for(preset, attack=0.3, hold=10.0, release=0.3, start=0.0)
    frames, sim = run_timeline(fr, tl, 0.8, device=device, material=material, **kw)
    return frames.fdp_points[-1].astype(np.float64), frames.fdp_points[0].astype(np.float64), sim
