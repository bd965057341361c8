"""The inputs of a batch and its manifest ``DIR/manifest.json``.

A scan is known by the content of its files, not by their names: its key is the SHA-256 of the
scan's bytes, its landmark file's bytes (if any) and its units. Two paths to the same bytes (a
renamed copy, a second folder) are one scan, done once. The manifest is rewritten atomically
(temporary file, then rename) after every finished step, so it is valid at every moment, also
after a Ctrl-C or a killed driver.

Manifest layout (``"fleet": 1``)::

    {"fleet": 1, "updated": ISO time, "out": DIR,
     "scans": {KEY: {"name": ..., "folder": "scans/NAME-KEY12",
                     "inputs": {"scan": {"path", "size", "sha256"}, "landmarks": {...} | null, "units": "mm" | ... | null},
                     "paths": [every scan path seen with this content],
                     "steps": {STEP: {"status": "done" | "failed" | "skipped", "error": one line | null,
                                      "params": {...}, "outputs": [files, relative to DIR],
                                      "seconds": s, "cpu_seconds": s, "attempts": n,
                                      "worker": {"pid", "host", "peak_rss_mib"},
                                      "summary": {...}}}}}}
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from ..core.errors import InputError
from ..core.fileio import write_json

__all__ = ["GPU_STEPS", "NEEDS", "STEPS", "UNITS", "check_units", "Manifest", "ScanInput", "depends", "file_record", "plain", "read_input_list",
           "scans_from_paths"]

STEPS = ("adapt", "build", "simulate", "rig")
"""The per-scan steps, in the order they run per scan."""

NEEDS = {"adapt": None, "build": "adapt", "simulate": "build", "rig": "build"}
"""The step whose output each step reads: ``simulate`` and ``rig`` both read the ``build``."""

GPU_STEPS = ("simulate", "rig")
"""The physics steps (a simulation, the rig's bake), which run on a GPU where the batch has one."""


def depends(step: str, on: str) -> bool:
    """Whether ``step`` reads (directly or through others) the output of ``on``."""
    s = NEEDS[step]
    while s is not None:
        if s == on:
            return True
        s = NEEDS[s]
    return False

FORMAT = 1
"""Version of the manifest layout."""

_LANDMARK_NAMES = ("{stem}_landmarks.json", "{stem}.landmarks.json", "{stem}.json", "{stem}.pp", "landmarks.json")
"""Landmark files looked for beside a scan given on the command line, first found wins."""

_CHUNK = 1 << 20


def sha256_file(path: Path) -> str:
    """SHA-256 of a file's bytes, hex."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(_CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def file_record(path: Path) -> dict:
    """``{"path", "size", "sha256"}`` of an existing file (size in bytes)."""
    path = Path(path).absolute()  # the workers (other processes, other nodes) have other working folders
    return {"path": str(path), "size": path.stat().st_size, "sha256": sha256_file(path)}


def plain(obj):
    """``obj`` made strict JSON: NumPy values as Python numbers and lists, paths as strings,
    NaN and infinity as None."""
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain(v) for v in obj]
    if isinstance(obj, bool) or obj is None or isinstance(obj, (int, str)):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if hasattr(obj, "tolist"):
        return plain(obj.tolist())
    return str(obj)


@dataclass(frozen=True)
class ScanInput:
    """One scan of a batch: its mesh, its landmarks (None: found on the scan by ``adapt``), its units.

    ``name`` is the name its output folder starts with (the scan file's stem unless given).
    ``units``: ``"mm"``, ``"cm"``, ``"m"``, ``"auto"`` or None (default: as ``facewarp adapt``
    reads a scan without ``--units``: metres when the scan's extent is a plausible head in
    metres, else the scale from the FDPs).
    """

    scan: Path
    landmarks: Path | None = None
    units: str | None = None
    name: str = ""

    def records(self) -> dict:
        """The ``inputs`` block of the manifest (hashes the files)."""
        return {"scan": file_record(self.scan),
                "landmarks": file_record(self.landmarks) if self.landmarks is not None else None,
                "units": self.units}


def scan_key(inputs: dict) -> str:
    """The content key of a scan: SHA-256 over the scan's hash, the landmarks' hash and the units."""
    lm = inputs["landmarks"]["sha256"] if inputs["landmarks"] else "-"
    return hashlib.sha256(f"{inputs['scan']['sha256']}:{lm}:{inputs['units']}".encode()).hexdigest()


def _landmarks_beside(scan: Path) -> Path | None:
    for pattern in _LANDMARK_NAMES:
        p = scan.with_name(pattern.format(stem=scan.stem))
        if p.is_file() and p != scan:
            return p
    return None


def _check_file(path: Path, what: str) -> Path:
    if not path.exists():
        raise InputError(f"{what} {path}: no such file")
    if not path.is_file():
        raise InputError(f"{what} {path}: is not a file")
    return path


UNITS = ("mm", "cm", "m", "auto")
"""Units a scan of a batch may be given in (None: ``adapt``'s default, :class:`ScanInput`)."""


def check_units(units, what: str = "units") -> str | None:
    """``units`` if it is one of :data:`UNITS` or None, else :class:`InputError` naming ``what``."""
    if units is not None and units not in UNITS:
        raise InputError(f"{what}: expected one of {', '.join(UNITS)} (or none: as adapt reads it), got {units!r}")
    return units


def scans_from_paths(paths, *, units: str | None = None) -> list[ScanInput]:
    """Scans given on the command line; each one's landmarks are looked for beside it
    (``NAME_landmarks.json``, ``NAME.landmarks.json``, ``NAME.json``, ``NAME.pp``, ``landmarks.json``)."""
    check_units(units)
    return [ScanInput(_check_file(Path(p), "scan"), _landmarks_beside(Path(p)), units, Path(p).stem) for p in paths]


def read_input_list(path, *, units: str | None = None) -> list[ScanInput]:
    """The scans of an input manifest ``IN.json``.

    ``{"scans": [ITEM, ...]}`` or a bare list, each ITEM a scan path or
    ``{"scan": PATH, "landmarks": PATH, "units": "mm", "name": NAME}`` (all but ``scan`` optional;
    without ``landmarks`` they are looked for beside the scan as for paths on the command line).
    Relative paths are relative to the file's folder. A batch's own ``manifest.json`` is accepted
    too (its scans' input paths).
    """
    check_units(units)
    path = _check_file(Path(path), "manifest")
    try:
        doc = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"manifest {path}: not valid JSON ({e})") from None
    base = path.parent
    if isinstance(doc, dict) and doc.get("fleet") is not None and isinstance(doc.get("scans"), dict):
        items = [{"scan": s["inputs"]["scan"]["path"],
                  "landmarks": (s["inputs"]["landmarks"] or {}).get("path"),
                  "units": s["inputs"].get("units", units), "name": s.get("name")} for s in doc["scans"].values()]
    else:
        items = doc.get("scans") if isinstance(doc, dict) else doc
    if not isinstance(items, list):
        raise InputError(f"manifest {path}: expected {{\"scans\": [...]}} or a list of scans")
    out = []
    for k, item in enumerate(items):
        if isinstance(item, str):
            item = {"scan": item}
        if not isinstance(item, dict) or not isinstance(item.get("scan"), str):
            raise InputError(f"manifest {path}: scans[{k}]: expected a path or {{\"scan\": PATH, ...}}, got {item!r}")
        unknown = sorted(set(item) - {"scan", "landmarks", "units", "name"})
        if unknown:
            raise InputError(f"manifest {path}: scans[{k}]: unknown keys {', '.join(unknown)}")
        u = item.get("units") or units
        check_units(u, f"manifest {path}: scans[{k}]: units")
        scan = _check_file(base / item["scan"], f"manifest {path}: scans[{k}]: scan")
        lm = item.get("landmarks")
        lm = _check_file(base / lm, f"manifest {path}: scans[{k}]: landmarks") if lm else _landmarks_beside(scan)
        out.append(ScanInput(scan, lm, u, str(item.get("name") or scan.stem)))
    return out


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "scan"


class Manifest:
    """``DIR/manifest.json`` in memory; :meth:`save` writes it atomically."""

    def __init__(self, out: Path):
        self.out = Path(out)
        self.path = self.out / "manifest.json"
        self.scans: dict[str, dict] = {}
        if self.path.exists():
            try:
                doc = json.loads(self.path.read_text())
            except (UnicodeDecodeError, json.JSONDecodeError) as e:
                raise InputError(f"out {self.out}: manifest.json is not valid JSON ({e}); "
                                 "move it away to start afresh") from None
            if not isinstance(doc, dict) or doc.get("fleet") != FORMAT or not isinstance(doc.get("scans"), dict):
                raise InputError(f"out {self.out}: manifest.json is not a facewarp batch manifest (format {FORMAT})")
            self.scans = doc["scans"]

    def add(self, scan: ScanInput) -> str:
        """Register a scan (hashing its files); returns its key. A scan already known by content
        keeps its entry and steps; the new path is added to its ``paths``."""
        inputs = scan.records()
        key = scan_key(inputs)
        entry = self.scans.get(key)
        if entry is None:
            name = _safe_name(scan.name or scan.scan.stem)
            entry = {"name": name, "folder": f"scans/{name}-{key[:12]}", "inputs": inputs, "paths": [], "steps": {}}
            self.scans[key] = entry
        if inputs["scan"]["path"] not in entry["paths"]:
            entry["paths"].append(inputs["scan"]["path"])
        return key

    def folder(self, key: str) -> Path:
        """The output folder of a scan."""
        return self.out / self.scans[key]["folder"]

    def step(self, key: str, step: str) -> dict | None:
        return self.scans[key]["steps"].get(step)

    def set_step(self, key: str, step: str, record: dict) -> None:
        self.scans[key]["steps"][step] = plain(record)

    def save(self) -> None:
        """Write the manifest atomically (a reader never sees half a file)."""
        self.out.mkdir(parents=True, exist_ok=True)
        doc = {"fleet": FORMAT, "updated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
               "out": str(self.out), "scans": self.scans}
        write_json(self.path, doc, indent=1)
