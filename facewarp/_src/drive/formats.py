"""Performance files in and out: marker takes (JSON, CSV, C3D) as a :class:`MarkerTrack`, ARKit
curves (Live Link Face CSV, MediaPipe Face Landmarker JSON) as an :class:`ArkitTrack`, and the
writers that make such files from the package's own data.

Every loader converts to SI (metres, seconds, radians) at the edge and refuses a bad file with one
:class:`~facewarp.InputError` line that starts with the file's path and says what is wrong.

Point names. A marker is named by an MPEG-4 FDP id (``"2.1"``; see ``docs/concepts``) or by
``"v<index>"``, a vertex of the head's skin mesh (checked against the head where the track is
used). A take whose labels are neither (a motion-capture marker set) needs a *map file*: a JSON
object from the take's labels to point names, ``{"LBRO": "4.1", "NOSE": "9.3", "CHIN": "v966"}``;
labels the map does not name are left out (body markers, reference markers).

Marker formats (:func:`load_markers`):

- JSON: ``{"fps": 30, "units": "mm", "markers": {"2.1": [[x, y, z], null, ...], "v123": [...]}}``;
  every marker has one entry per frame, ``null`` where it is missing; ``units`` is ``"mm"``,
  ``"cm"`` or ``"m"`` (default ``"m"``).
- CSV: a header row, then one row per frame. The first column is ``time`` (seconds, increasing,
  evenly spaced; fps = 1 / the median step) or ``frame`` (frame numbers; then ``fps=`` is needed);
  then three columns per marker, ``NAME_x, NAME_y, NAME_z``. An empty cell (or ``nan``) is a
  missing marker; all three of a marker go missing together. Units: ``units=`` (default ``"m"``).
- C3D: read with the ``c3d`` package (``pip install 'facewarp[mocap]'``); the point rate is the
  fps, ``POINT:UNITS`` the units (``units=`` when the file has none), labels from
  ``POINT:LABELS``; a point whose residual is negative is missing.

A take's points must look like a head in the units given: within any frame they span at most
1 m and, with three or more points present, at least 5 mm; else the units are wrong and the
loader says so.

ARKit formats (:func:`load_arkit`):

- Live Link Face CSV (Epic's iPhone app): ``Timecode, BlendShapeCount, EyeBlinkLeft, ...,
  TongueOut, HeadYaw, HeadPitch, HeadRoll, LeftEyeYaw, ..., RightEyeRoll``; all 52 blendshape
  columns (ARKit's names, any order, matched without case: exports spell ``BlendshapeCount`` too).
  The timecode is ``HH:MM:SS:FF.fff`` (``;`` also accepted): the frame field ``FF`` with its
  sub-frame fraction counts at the timecode rate, read as the smallest of 24, 25, 30, 48, 50, 60,
  100, 120 that exceeds the largest frame number seen before a whole second turns over
  (``fps=`` when the take does not cross a whole second). HeadYaw, HeadPitch, HeadRoll and the
  eye angles are radians.
- MediaPipe Face Landmarker JSON: the Tasks API's results as dumped, ``[{"timestamp_ms": 0,
  "face_blendshapes": [[{"category_name": "_neutral", "score": 0.0}, {"category_name":
  "browDownLeft", "score": 0.01}, ...]]}, ...]`` (or under ``{"frames": [...]}``), and what other
  exporters write: the JavaScript spellings (``timestampMs``, ``faceBlendshapes``,
  ``categoryName``, a face as ``{"categories": [...]}``), ``{"people": [[{"name", "score"}]]}``
  per frame, a flat list of categories per frame (``"blendshapes"``, or the frame itself: then
  ``fps=``), scores as numbers or strings, ``timestamp_us``. The model's 52 categories are
  ``_neutral`` (ignored) and 51 ARKit names without ``tongueOut`` (read as 0, said in the notes);
  another missing name is an error. Per frame the first face is used; a frame with no face
  holds the previous frame's weights (zero before the first face).

Real takes (both formats and marker CSVs): the take's rate is the median step of its times, every
step a whole number of it (a 30 fps take on a 60 fps timecode that drops frames steps by 2 to 8
timecode frames); the frames skipped are interpolated at their real times, counted and said
(:data:`MAX_GAP_S` at most), and the rate is the frames over the span, snapped to a whole or NTSC
rate within the times' rounding (MediaPipe's whole milliseconds give 30 fps, not 30.303). A rate
outside :data:`~facewarp._src.drive.tracks.MIN_TAKE_FPS`..``MAX_TAKE_FPS`` is an error, except
MediaPipe ``timestamp_ms`` steps that are microseconds (:data:`VIDEO_FPS`). ARKit weights up to
:data:`WEIGHT_SLACK` beyond [0, 1] are clamped and counted per shape (Live Link Face writes
EyeLookIn up to about 1.05); farther is an error naming the row (frame) and column (category).
``start=`` / ``end=`` keep a part of a take.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import warnings
from pathlib import Path

import numpy as np

from ..core.checks import check_number, check_path, describe
from ..core.errors import InputError
from ..core.fileio import atomic_write, write_json
from ..geometry.landmarks import FDP_CATALOGUE
from ..geometry.mesh import unit_scale
from .tracks import ARKIT_NAMES, MAX_TAKE_FPS, MIN_TAKE_FPS, ArkitTrack, MarkerTrack

__all__ = ["MARKER_SUFFIXES", "check_point_name", "load_arkit", "load_map", "load_markers", "markers_from_frames",
           "save_livelink_csv", "save_markers_json"]

MARKER_SUFFIXES = (".json", ".csv", ".c3d")
"""File suffixes :func:`load_markers` reads."""

ARKIT_SUFFIXES = (".csv", ".json")
"""File suffixes :func:`load_arkit` reads: Live Link Face CSV, MediaPipe JSON."""

MAX_HEAD_SPAN_M = 1.0
"""Largest extent [m] of one frame's points that is still a head (beyond it the units are wrong)."""

MIN_HEAD_SPAN_M = 0.005
"""Smallest extent [m] of one frame's points (three or more present) that is still a face."""

TIMECODE_RATES = (24, 25, 30, 48, 50, 60, 100, 120)
"""Timecode frame rates a Live Link Face CSV may count its frame field at."""

LIVELINK_HEAD = ("HeadYaw", "HeadPitch", "HeadRoll")
LIVELINK_EYES = ("LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw", "RightEyePitch", "RightEyeRoll")
_VERTEX = re.compile(r"^v(0|[1-9][0-9]*)$")
_TIMECODE = re.compile(r"^\s*(\d+)[:;](\d{1,2})[:;](\d{1,2})[:;](\d+)(\.\d+)?\s*$")


def _cap(name: str) -> str:
    return name[0].upper() + name[1:]


# ----------------------------------------------------------------------------- shared checks
def check_point_name(name: str, where: str = "name") -> str:
    """``name`` when it is an FDP id (``"2.1"``) or a vertex name ``"v<index>"``, else InputError."""
    if not isinstance(name, str) or not (name in FDP_CATALOGUE or _VERTEX.match(name)):
        raise InputError(f"{where}: {name!r} is neither an FDP id (such as '2.1') nor a vertex 'v<index>' "
                         "(name the take's labels with a map file)")
    return name


def _open_text(path, suffixes, what: str) -> tuple[Path, str]:
    path = check_path("path", path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a {what} file")
    if path.suffix.lower() not in suffixes:
        raise InputError(f"{path}: unsupported {what} format {path.suffix or '(no suffix)'!r}, expected "
                         + ", ".join(suffixes))
    if path.suffix.lower() == ".c3d":
        return path, ""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read as text ({getattr(e, 'strerror', None) or e})") from None
    if not text.strip():
        raise InputError(f"{path}: file is empty")
    return path, text


def _json(path: Path, text: str):
    def no_constants(c):
        raise InputError(f"{path}: {c} is not JSON (write null for a missing value)")

    try:
        return json.loads(text, parse_constant=no_constants)
    except json.JSONDecodeError as e:
        raise InputError(f"{path}: malformed JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
    except RecursionError:
        raise InputError(f"{path}: JSON nested too deeply") from None


def _fps(path: Path, value, what: str) -> float:
    try:
        return check_number(what, value, low=0.0, high=10_000.0, low_open=True)
    except InputError as e:
        raise InputError(f"{path}: {e}") from None


def _units(path: Path, units) -> float:
    try:
        return unit_scale(units)
    except InputError as e:
        raise InputError(f"{path}: {e}") from None


def _check_span(path: Path, P: np.ndarray, units: str) -> None:
    """Refuse a take whose points cannot be a head in ``units`` (P (T, K, 3) [m], NaN missing)."""
    ok = np.isfinite(P).all(axis=2)
    if not ok.any():
        raise InputError(f"{path}: no marker is present in any frame")
    lo = np.where(ok[..., None], P, np.inf).min(axis=1)
    hi = np.where(ok[..., None], P, -np.inf).max(axis=1)
    with np.errstate(over="ignore", invalid="ignore"):  # a number near 1e308 in the file: an infinite span
        span = np.where(ok.any(axis=1), np.linalg.norm(hi - lo, axis=1), np.nan)
    big = np.nanmax(span)
    if big > MAX_HEAD_SPAN_M:
        raise InputError(f"{path}: one frame's markers span {big:.3g} m, more than a head ({MAX_HEAD_SPAN_M:g} m); "
                         f"are the units right (read as {units})?")
    many = ok.sum(axis=1) >= 3
    if many.any() and np.nanmedian(span[many]) < MIN_HEAD_SPAN_M:
        raise InputError(f"{path}: the markers span only {np.nanmedian(span[many]) * 1e3:.3g} mm, less than a face; "
                         f"are the units right (read as {units})?")


def load_map(path) -> dict:
    """Read a map file: a JSON object from a take's marker labels to point names (an FDP id or
    ``"v<index>"``). Two labels may not name the same point.

    Returns:
        label -> point name (str -> str).

    Raises:
        InputError: a missing or malformed file, a value that is not a point name, or a point named twice.
    """
    path, text = _open_text(path, (".json",), "map")
    data = _json(path, text)
    if not isinstance(data, dict) or not data:
        raise InputError(f"{path}: expected a JSON object from marker labels to FDP ids or 'v<index>', "
                         f"got {describe(data)}")
    seen = {}
    for label, name in data.items():
        check_point_name(name, f"{path}: label {label!r}")
        if name in seen:
            raise InputError(f"{path}: labels {seen[name]!r} and {label!r} both map to {name!r}")
        seen[name] = label
    return {str(k): str(v) for k, v in data.items()}


def _apply_map(path: Path, labels: list, positions: np.ndarray, mapping: dict | None) -> tuple[list, np.ndarray]:
    """The take's labels renamed by ``mapping`` (unmapped labels dropped), or checked as point names."""
    if mapping is None:
        for lab in labels:
            check_point_name(lab, f"{path}: marker")
        return list(labels), positions
    keep = [i for i, lab in enumerate(labels) if lab in mapping]
    if not keep:
        raise InputError(f"{path}: none of the take's labels ({', '.join(labels[:6])}"
                         f"{', ...' if len(labels) > 6 else ''}) is in the map")
    return [mapping[labels[i]] for i in keep], positions[:, keep]


# ----------------------------------------------------------------------------- markers
def load_markers(path, *, map=None, units: str | None = None, fps: float | None = None,  # noqa: A002
                 neutral=None, start: float | None = None, end: float | None = None) -> MarkerTrack:
    """Read a marker take (JSON, CSV or C3D; formats in this module's docstring) as a :class:`MarkerTrack`.

    Args:
        path: The file; the format is chosen by its suffix (:data:`MARKER_SUFFIXES`).
        map: A map file (path) or dict from the take's labels to FDP ids / ``"v<index>"``;
            needed when the labels are not point names themselves. Unmapped labels are dropped.
        units: Units of the file's coordinates, ``"mm"``, ``"cm"`` or ``"m"``: for CSV (default
            ``"m"``) and for JSON and C3D files that do not say (if the file says, it must agree).
        fps: Frames per second, for a CSV with a ``frame`` column (other files carry it; if given
            it must agree with them within 0.5 %).
        neutral: The actor's face at rest, for retargeting: ``(START, END)`` seconds of the take
            (its mean over those frames, each point over the frames it is present) or a time in
            seconds (that frame); default None, the first frame. Read before ``start``/``end`` cut.
        start, end: Keep the part of the take from ``start`` to ``end`` seconds (from its first frame).

    Returns:
        The track, positions (T, K, 3) float64 [m], NaN where a marker is missing; rows a CSV's
        times skipped are interpolated (``notes``).

    Raises:
        InputError: one line naming the file and what is wrong (empty, truncated, malformed,
        unknown columns or labels, a marker with the wrong number of frames, NaN in JSON, a
        partly missing point, times that go back or are not whole steps, a frame rate outside
        1..1000 frames/s, units that do not give a head-sized take).
    """
    mapping = None
    if map is not None:
        mapping = load_map(map) if isinstance(map, (str, os.PathLike)) else dict(map)
        for label, name in mapping.items():
            check_point_name(name, f"map: label {label!r}")
    if units is not None:
        unit_scale(units)
    if fps is not None:
        fps = check_number("fps", fps, low=MIN_TAKE_FPS, high=MAX_TAKE_FPS)
    span = _check_neutral(neutral)
    start, end = _check_cut(start, end)
    path, text = _open_text(path, MARKER_SUFFIXES, "marker")
    suffix = path.suffix.lower()
    if suffix == ".json":
        labels, P, file_fps, file_units, gaps = _markers_json(path, text)
    elif suffix == ".csv":
        labels, P, file_fps, file_units, gaps = _markers_csv(path, text)
    else:
        labels, P, file_fps, file_units, gaps = _markers_c3d(path)
    if file_units is not None and units is not None and file_units != units:
        raise InputError(f"{path}: the file says units {file_units!r}, but units {units!r} were given")
    u = file_units or units or "m"
    P = P * _units(path, u)
    if file_fps is None and fps is None:
        raise InputError(f"{path}: the frame rate is not in the file (a 'frame' column, or a single frame); give fps")
    if file_fps is not None and fps is not None and abs(file_fps - fps) > 0.005 * fps:
        raise InputError(f"{path}: the file's frame rate is {file_fps:g}, but fps {fps:g} was given")
    rate = file_fps if file_fps is not None else fps
    _check_rate(path, rate, "file's frame rate")
    names, P = _apply_map(path, labels, P, mapping)
    _check_span(path, P, u)
    notes = _gap_note(gaps, rate) if gaps else []
    info = dict(gaps or {}, frames_read=int(len(P) - (gaps or {}).get("frames_filled", 0)))
    rest = None
    if span is not None:
        if span[0] == span[1]:  # one time: the nearest frame
            a = int(round(span[0] * rate))
            if a >= len(P):
                raise InputError(f"{path}: neutral {span[0]:g} s is beyond the take's {(len(P) - 1) / rate:.4g} s")
            b = a + 1
        else:
            a, b = _cut_range(path, len(P), rate, span[0], span[1])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a point never seen in the span: NaN
            rest = np.nanmean(P[a:b], axis=0)
        info["neutral_frames"] = [a, b - 1]
        notes.append(f"neutral: frames {a}..{b - 1} ({a / rate:.3f}-{(b - 1) / rate:.3f} s)")
    if start is not None or end is not None:
        a, b = _cut_range(path, len(P), rate, start, end)
        if rest is None:  # the actor's rest stays the take's first frame
            rest = P[0].copy()
        P = P[a:b]
        info.update(start_s=a / rate, end_s=(b - 1) / rate, frames_in_take=int(len(P)))
        notes.append(f"frames {a}..{b - 1} kept ({a / rate:.3f}-{(b - 1) / rate:.3f} s of the take)")
    try:
        return MarkerTrack(rate, names, P, source=str(path), neutral=rest, notes=notes, info=info)
    except InputError as e:
        raise InputError(f"{path}: {e}") from None


def _check_neutral(neutral):
    """``neutral=`` as ``(start, end)`` seconds (a single time: that frame), or None."""
    if neutral is None:
        return None
    if isinstance(neutral, str):
        parts = neutral.split(":")
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise InputError(f"neutral: expected START:END seconds (or one time), got {neutral!r}") from None
    elif isinstance(neutral, (tuple, list)):
        vals = list(neutral)
    else:
        vals = [neutral]
    if len(vals) not in (1, 2):
        raise InputError(f"neutral: expected START:END seconds (or one time), got {neutral!r}")
    a = check_number("neutral", vals[0], low=0.0)
    b = check_number("neutral", vals[-1], low=0.0)
    if b < a:
        raise InputError(f"neutral: end {b:g} s is before start {a:g} s")
    return a, b


def _markers_json(path: Path, text: str):
    data = _json(path, text)
    if not isinstance(data, dict) or "markers" not in data:
        raise InputError(f"{path}: expected a JSON object {{\"fps\": ..., \"units\": ..., \"markers\": {{...}}}}, "
                         f"got {describe(data)}")
    unknown = sorted(set(data) - {"fps", "units", "markers"})
    if unknown:
        raise InputError(f"{path}: unknown key {unknown[0]!r} (expected fps, units, markers)")
    if "fps" not in data:
        raise InputError(f"{path}: no 'fps' (frames per second)")
    rate = _fps(path, data["fps"], "fps")
    units = data.get("units")
    if units is not None:
        _units(path, units)
    markers = data["markers"]
    if not isinstance(markers, dict) or not markers:
        raise InputError(f"{path}: 'markers' must be an object from names to per-frame [x, y, z] lists, "
                         f"got {describe(markers)}")
    labels = list(markers)
    T = None
    P = None
    for k, (label, frames) in enumerate(markers.items()):
        if not isinstance(frames, list):
            raise InputError(f"{path}: marker {label!r} must be a list of [x, y, z] or null per frame, "
                             f"got {describe(frames)}")
        if T is None:
            T = len(frames)
            if T == 0:
                raise InputError(f"{path}: marker {label!r} has no frames")
            P = np.full((T, len(labels), 3), np.nan)
        elif len(frames) != T:
            raise InputError(f"{path}: marker {label!r} has {len(frames)} frames, {labels[0]!r} has {T}")
        for t, v in enumerate(frames):
            if v is None:
                continue
            if (not isinstance(v, list) or len(v) != 3
                    or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)):
                raise InputError(f"{path}: marker {label!r} frame {t}: expected [x, y, z] or null, "
                                 f"got {json.dumps(v)[:40]}")
            P[t, k] = v
    return labels, P, rate, units, None


def _cells(path: Path, text: str) -> list[list[str]]:
    rows = [r for r in csv.reader(io.StringIO(text)) if any(c.strip() for c in r)]
    if not rows:
        raise InputError(f"{path}: file is empty")
    width = len(rows[0])
    for n, r in enumerate(rows[1:], start=2):
        if len(r) != width:
            raise InputError(f"{path}: row {n} has {len(r)} cells, the header has {width} (a truncated file?)")
    if len(rows) < 2:
        raise InputError(f"{path}: a header but no frames")
    return rows


def _float(path: Path, cell: str, row: int, column: str, *, missing: bool = False) -> float:
    c = cell.strip()
    if missing and (c == "" or c.lower() == "nan"):
        return math.nan
    try:
        v = float(c)
    except ValueError:
        raise InputError(f"{path}: row {row} column {column!r}: expected a number, got {cell!r}") from None
    if not math.isfinite(v):
        raise InputError(f"{path}: row {row} column {column!r}: expected a finite number, got {cell!r}")
    return v


def _markers_csv(path: Path, text: str):
    rows = _cells(path, text)
    head = [h.strip() for h in rows[0]]
    first = head[0].lower()
    if first not in ("time", "frame"):
        raise InputError(f"{path}: the first column must be 'time' (seconds) or 'frame', got {head[0]!r}")
    cols = head[1:]
    if not cols or len(cols) % 3:
        raise InputError(f"{path}: expected three columns NAME_x, NAME_y, NAME_z per marker after {head[0]!r}, "
                         f"got {len(cols)} columns")
    labels = []
    for i in range(0, len(cols), 3):
        trio = cols[i:i + 3]
        base = trio[0][:-2]
        want = [f"{base}_{a}" for a in "xyz"]
        if not trio[0].lower().endswith("_x") or [c.lower() for c in trio] != [w.lower() for w in want]:
            expected = ", ".join(want) if base else "NAME_x, NAME_y, NAME_z"
            raise InputError(f"{path}: columns {', '.join(trio)}: expected {expected}")
        if base in labels:
            raise InputError(f"{path}: marker {base!r} appears twice")
        labels.append(base)
    T = len(rows) - 1
    P = np.empty((T, len(labels), 3))
    first_col = np.empty(T)
    for t, r in enumerate(rows[1:]):
        first_col[t] = _float(path, r[0], t + 2, head[0])
        vals = [_float(path, c, t + 2, head[1 + j], missing=True) for j, c in enumerate(r[1:])]
        P[t] = np.reshape(vals, (-1, 3))
    part = np.isnan(P).any(axis=2) & ~np.isnan(P).all(axis=2)
    if part.any():
        t, k = map(int, np.argwhere(part)[0])
        raise InputError(f"{path}: row {t + 2}: marker {labels[k]!r} has some of x, y, z missing (all or none)")
    if first == "time":
        rate, index, gaps = _grid(path, first_col, "times", resolution=_printed_resolution(rows[1:]))
        if rate is not None:
            _check_rate(path, rate, "times")
    else:
        rate = None
        if (first_col != np.round(first_col)).any():
            raise InputError(f"{path}: frame numbers must be whole numbers")
        _, index, gaps = _grid(path, first_col, "frame numbers", unit="frames")
    return labels, _fill(P, index), rate, None, gaps


def _printed_resolution(rows) -> float:
    """The resolution [s] of a time column as printed (``0.033`` -> 1e-3)."""
    digits = 0
    for r in rows[:50]:
        c = r[0].strip()
        if "." in c and "e" not in c.lower():
            digits = max(digits, len(c.split(".")[1]))
    return 0.5 * 10.0 ** (-digits)


def _markers_c3d(path: Path):
    try:
        import c3d
    except ImportError:
        raise InputError(f"{path}: reading C3D needs the c3d package: pip install 'facewarp[mocap]'") from None
    import warnings

    try:
        with open(path, "rb") as f, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reader = c3d.Reader(f)
            rate = float(reader.point_rate)
            labels = [str(s).strip() for s in reader.point_labels]
            grp = reader.get("POINT")
            units = None
            if grp is not None and grp.get("UNITS") is not None:
                units = grp.get("UNITS").string_value.strip().lower() or None
            expected = int(reader.last_frame) - int(reader.first_frame) + 1
            frames = []
            for _, points, _ in reader.read_frames():
                p = np.array(points[:, :3], dtype=np.float64)
                p[points[:, 3] < 0] = np.nan
                frames.append(p)
    except InputError:
        raise
    except Exception as e:  # the reader's own errors on a broken file
        raise InputError(f"{path}: not a readable C3D file ({type(e).__name__}: {e})") from None
    if not frames:
        raise InputError(f"{path}: the C3D file has no frames")
    if len(frames) != expected:
        raise InputError(f"{path}: the C3D header says {expected} frames, the file holds {len(frames)} "
                         "(a truncated file?)")
    if not labels or len(labels) != frames[0].shape[0]:
        raise InputError(f"{path}: the C3D file has {frames[0].shape[0]} points but {len(labels)} labels")
    if len(set(labels)) != len(labels):
        raise InputError(f"{path}: a C3D label appears twice")
    if units is not None and units not in ("mm", "cm", "m"):
        raise InputError(f"{path}: POINT:UNITS is {units!r}, expected mm, cm or m")
    if not math.isfinite(rate) or rate <= 0:
        raise InputError(f"{path}: the C3D point rate is {rate!r}")
    return labels, np.stack(frames), rate, units, None


def save_markers_json(track: MarkerTrack, path, *, units: str = "mm") -> Path:
    """Write ``track`` as a markers JSON (this module's format; ``null`` for a missing marker),
    atomically, in ``units`` ("mm", default, "cm" or "m"); :func:`load_markers` reads it back."""
    if not isinstance(track, MarkerTrack):
        raise InputError(f"track: expected a MarkerTrack, got {describe(track)}")
    path = check_path("path", path)
    scale = unit_scale(units)
    P = track.positions / scale
    ok = track.visible()
    markers = {n: [P[t, k].tolist() if ok[t, k] else None for t in range(track.frames)]
               for k, n in enumerate(track.names)}
    write_json(path, {"fps": track.fps, "units": units, "markers": markers}, indent=None)
    return path


def markers_from_frames(frames, names, *, fps: float | None = None) -> MarkerTrack:
    """The skin points ``names`` (FDP ids or ``"v<index>"``) of a simulated run as a :class:`MarkerTrack`.

    Args:
        frames: A :class:`~facewarp.Frames` (``FaceSimulator.run``, a ``FrameRecorder``).
        names: Point names, e.g. ``["2.1", "8.3", "v120"]``.
        fps: Frames per second; default from the frames' times (at least two frames needed then).

    Returns:
        The track, positions (T, K, 3) float64 [m], source ``"simulated frames"``.
    """
    for k in ("times", "points", "fdp_ids", "fdp_points"):
        if not hasattr(frames, k):
            raise InputError(f"frames: expected Frames (FaceSimulator.run, FrameRecorder), got {describe(frames)}")
    if isinstance(names, str) or not hasattr(names, "__iter__"):
        raise InputError(f"names: expected a list of FDP ids or 'v<index>', got {describe(names)}")
    names = [check_point_name(n, "names") for n in names]
    if not names:
        raise InputError("names: expected at least one point name")
    ids = [str(i) for i in np.asarray(frames.fdp_ids)]
    n_vert = frames.points.shape[1]
    cols = []
    for n in names:
        if _VERTEX.match(n):
            i = int(n[1:])
            if i >= n_vert:
                raise InputError(f"names: {n!r} is beyond the head's {n_vert} vertices")
            cols.append(np.asarray(frames.points[:, i], dtype=np.float64))
        elif n in ids:
            cols.append(np.asarray(frames.fdp_points[:, ids.index(n)], dtype=np.float64))
        else:
            raise InputError(f"names: the frames have no FDP {n!r}")
    if fps is None:
        t = np.asarray(frames.times, dtype=np.float64)
        if len(t) < 2 or not (np.diff(t) > 0).all():
            raise InputError("frames: need two or more frames at increasing times to know the fps (or give fps)")
        fps = 1.0 / float(np.median(np.diff(t)))
    return MarkerTrack(fps, names, np.stack(cols, axis=1), source="simulated frames")


# ----------------------------------------------------------------------------- ARKit
def load_arkit(path, *, fps: float | None = None, start: float | None = None, end: float | None = None) -> ArkitTrack:
    """Read ARKit blendshape curves: a Live Link Face CSV or a MediaPipe Face Landmarker JSON
    (formats in this module's docstring) as an :class:`ArkitTrack`.

    Args:
        path: ``.csv`` (Live Link Face) or ``.json`` (MediaPipe).
        fps: Frames per second, needed only when the file cannot tell (a Live Link take that does
            not cross a whole second, MediaPipe frames without timestamps).
        start, end: Keep the part of the take from ``start`` to ``end`` seconds (from its first
            frame; default the whole take).

    Returns:
        The track: weights (T, 52) in :data:`~facewarp.ARKIT_NAMES` order, on a uniform grid at the
        take's own rate (frames the recording dropped interpolated, and said in ``notes``);
        head_rotation (T, 3) [rad] yaw, pitch, roll and eye_rotation (T, 2, 2) [rad] yaw, pitch from Live
        Link's columns, None for MediaPipe.

    Raises:
        InputError: one line naming the file and what is wrong (empty, truncated, malformed,
        missing or unknown columns or categories, a weight beyond [-0.1, 1.1] with its row and
        column, times that go back or cannot be a take's frame rate).
    """
    if fps is not None:
        fps = check_number("fps", fps, low=MIN_TAKE_FPS, high=MAX_TAKE_FPS)
    start, end = _check_cut(start, end)
    path, text = _open_text(path, ARKIT_SUFFIXES, "ARKit")
    if path.suffix.lower() == ".csv":
        track = _livelink_csv(path, text, fps)
    else:
        track = _mediapipe_json(path, text, fps)
    return _cut_arkit(path, track, start, end)


# ---------------------------------------------------------------- times of real takes
def _check_cut(start, end) -> tuple[float | None, float | None]:
    start = check_number("start", start, low=0.0, allow_none=True)
    end = check_number("end", end, low=0.0, low_open=True, allow_none=True)
    if start is not None and end is not None and end <= start:
        raise InputError(f"end: {end:g} s is not after start {start:g} s")
    return start, end


def _cut_range(path: Path, frames: int, fps: float, start, end) -> tuple[int, int]:
    """Frames ``[a, b)`` of a take of ``frames`` at ``fps`` from ``start`` to ``end`` seconds."""
    length = (frames - 1) / fps
    a = 0 if start is None else int(math.ceil(start * fps - 1e-6))
    b = frames if end is None else min(frames, int(math.floor(end * fps + 1e-6)) + 1)
    if start is not None and a >= frames:
        raise InputError(f"{path}: start {start:g} s is beyond the take's {length:.4g} s")
    if b - a < 1:
        raise InputError(f"{path}: no frame between start {start or 0:g} s and end {end or length:g} s")
    return a, b


def _cut_arkit(path: Path, track: ArkitTrack, start, end) -> ArkitTrack:
    if start is None and end is None:
        return track
    a, b = _cut_range(path, track.frames, track.fps, start, end)
    notes = list(track.notes) + [f"frames {a}..{b - 1} of {track.frames} kept ({a / track.fps:.3f}-"
                                 f"{(b - 1) / track.fps:.3f} s of the take)"]
    info = dict(track.info, start_s=a / track.fps, end_s=(b - 1) / track.fps, frames_in_take=track.frames)
    return ArkitTrack(track.fps, track.weights[a:b],
                      None if track.head_rotation is None else track.head_rotation[a:b], source=track.source,
                      eye_rotation=None if track.eye_rotation is None else track.eye_rotation[a:b], notes=notes,
                      info=info)


MAX_GAP_S = 2.0
"""Longest stretch [s] of a take without a frame that is filled in (interpolated); longer is an error."""

_NAMED_RATES = (24000 / 1001, 30000 / 1001, 60000 / 1001)
"""Video rates that are not whole numbers (23.976, 29.97, 59.94 frames/s)."""


def _snap_rate(rate: float, tolerance: float) -> float:
    """``rate`` as a whole number or an NTSC rate when within ``tolerance`` [1/s] of one."""
    for r in (float(round(rate)), *_NAMED_RATES):
        if r > 0 and abs(rate - r) <= tolerance:
            return r
    return rate


def _grid(path: Path, t: np.ndarray, what: str, *, resolution: float = 0.0, row0: int = 2,
          unit: str = "s") -> tuple[float | None, np.ndarray, dict]:
    """The take's frame rate and each sample's frame on it, from sample times ``t`` [s] that may
    skip frames (a 30 fps take on a 60 fps timecode drops frames: steps of 2, 4, 6 ... timecode
    frames).

    The rate's step is the median step; every step must be a whole number of it (within a
    quarter: jitter of rounded timestamps), and the rate is the frames so counted over the span
    (the times' rounding, ``resolution`` [s], barely touches it), snapped to a whole number or an
    NTSC rate when within the rounding's reach or 0.2 %.

    Returns:
        ``(rate, index, info)``: rate [1/s] (None for one sample); index (n,) int64, each sample's
        frame; info: ``frames_filled`` (frames the take skipped), ``gaps``, ``longest_gap_frames``.
    """
    n = len(t)
    if n < 2:
        return None, np.zeros(n, np.int64), {"frames_filled": 0, "gaps": 0, "longest_gap_frames": 0}
    d = np.diff(t)
    if (d <= 0).any():
        k = int(np.argmax(d <= 0))
        raise InputError(f"{path}: {what} do not increase (row {k + row0 + 1}: {t[k + 1]:.6g} {unit} after "
                         f"{t[k]:.6g})")
    step = float(np.median(d))
    m = d / step
    k = np.rint(m)
    off = np.abs(m - k) > 0.25
    if off.any():
        i = int(np.argmax(off))
        raise InputError(f"{path}: uneven {what}: step {d[i]:.4g} {unit} at row {i + row0 + 1} is not a whole number "
                         f"of the median step {step:.4g} {unit}")
    k = k.astype(np.int64)
    if unit == "s" and (d > MAX_GAP_S).any():
        i = int(np.argmax(d > MAX_GAP_S))
        raise InputError(f"{path}: uneven {what}: a gap of {d[i]:.4g} s at row {i + row0 + 1}, more than "
                         f"{MAX_GAP_S:g} s without a frame (two takes joined?)")
    count = int(k.sum())
    span = float(t[-1] - t[0])
    rate = count / span
    rate = _snap_rate(rate, max(0.002 * rate, 1.5 * rate * resolution / span))
    index = np.concatenate([[0], np.cumsum(k)])
    info = {"frames_filled": int(count - (n - 1)), "gaps": int((k > 1).sum()), "longest_gap_frames": int(k.max() - 1)}
    return rate, index, info


def _check_rate(path: Path, rate: float, what: str) -> float:
    if not MIN_TAKE_FPS <= rate <= MAX_TAKE_FPS:
        raise InputError(f"{path}: the {what} give {rate:.6g} frames/s, outside a take's {MIN_TAKE_FPS:g}.."
                         f"{MAX_TAKE_FPS:g} (are the timestamps' units right?)")
    return rate


def _fill(values: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Samples ``values`` (n, ...) at frames ``index`` (n,) on the full grid 0..index[-1], linear
    between samples (a NaN sample stays missing: frames between it and its neighbours are NaN)."""
    if index[-1] == len(index) - 1:
        return values
    shape = values.shape[1:]
    V = values.reshape(len(values), -1)
    grid = np.arange(index[-1] + 1)
    out = np.empty((len(grid), V.shape[1]))
    seg = np.clip(np.searchsorted(index, grid, side="right") - 1, 0, len(index) - 2)
    w = (grid - index[seg]) / (index[seg + 1] - index[seg])
    out[:] = V[seg] * (1.0 - w[:, None]) + V[seg + 1] * w[:, None]
    exact = np.isin(grid, index)
    out[exact] = V[np.searchsorted(index, grid[exact])]
    return out.reshape(len(grid), *shape)


def _gap_note(info: dict, rate: float) -> list:
    if not info.get("frames_filled"):
        return []
    return [f"{info['frames_filled']} frame(s) the take skipped ({info['gaps']} gap(s), the longest "
            f"{info['longest_gap_frames'] / rate:.3f} s) interpolated at {rate:g} frames/s"]


WEIGHT_SLACK = 0.1
"""ARKit weights up to this beyond [0, 1] are clamped (Live Link Face writes EyeLookIn up to about
1.05) and counted; farther is an error."""


def _clamp(path: Path, W: np.ndarray, where) -> tuple[np.ndarray, dict, list]:
    """Weights W (T, 52) clamped to [0, 1]; beyond :data:`WEIGHT_SLACK` an error naming
    ``where(t, i)``; the count of clamped values per shape."""
    bad = (W < -WEIGHT_SLACK) | (W > 1.0 + WEIGHT_SLACK)
    if bad.any():
        t, i = map(int, np.argwhere(bad)[0])
        raise InputError(f"{path}: {where(t, i)}: weight {W[t, i]:g} is outside [0, 1] by more than "
                         f"{WEIGHT_SLACK:g}")
    over = (W > 1.0) | (W < 0.0)
    counts = {ARKIT_NAMES[i]: int(c) for i, c in enumerate(over.sum(axis=0)) if c}
    notes = []
    if counts:
        top = max(counts, key=counts.get)
        notes.append(f"{int(over.sum())} weight(s) beyond [0, 1] clamped (largest {W.max():.3f}; "
                     f"most in {top}: {counts[top]})")
    return np.clip(W, 0.0, 1.0), counts, notes


def _timecodes(path: Path, cells: list[str], fps: float | None) -> tuple[float | None, np.ndarray, dict]:
    """The take's fps and each row's frame from its Live Link timecodes (module docstring)."""
    whole = np.empty(len(cells))
    frame = np.empty(len(cells))
    for n, c in enumerate(cells):
        m = _TIMECODE.match(c)
        if not m:
            raise InputError(f"{path}: row {n + 2}: timecode {c!r} is not HH:MM:SS:FF.fff")
        h, mi, s, ff = (int(m.group(i)) for i in range(1, 5))
        if mi > 59 or s > 59:
            raise InputError(f"{path}: row {n + 2}: timecode {c!r} has minutes or seconds above 59")
        whole[n] = h * 3600 + mi * 60 + s
        frame[n] = ff + (float(m.group(5)) if m.group(5) else 0.0)
    turns = np.nonzero(np.diff(whole) != 0)[0]
    if len(turns) == 0:
        if fps is None and len(cells) > 1:
            raise InputError(f"{path}: the take does not cross a whole second, so its frame rate cannot be read "
                             "from the timecodes; give fps")
        _, index, info = _grid(path, frame, "timecodes", unit="frames")  # fps given: the steps still count
        return fps, index, info
    top = max(int(frame[i]) for i in turns) + 1
    rate = next((r for r in TIMECODE_RATES if r >= top), None)
    if rate is None or frame.max() >= rate:
        raise InputError(f"{path}: timecode frame numbers up to {int(frame.max())} fit no timecode rate "
                         f"({', '.join(map(str, TIMECODE_RATES))})")
    t = whole + frame / rate
    found, index, info = _grid(path, t, "timecodes", resolution=0.5e-3 / rate)
    _check_rate(path, found, "timecodes")
    if fps is not None and abs(found - fps) > 0.005 * fps:
        raise InputError(f"{path}: the timecodes give {found:g} fps, but fps {fps:g} was given")
    return found, index, info


def _livelink_csv(path: Path, text: str, fps: float | None) -> ArkitTrack:
    rows = _cells(path, text)
    head = [h.strip() for h in rows[0]]
    if not head or head[0].lower() != "timecode":
        raise InputError(f"{path}: not a Live Link Face CSV: the first column must be 'Timecode', got {head[0]!r}")
    known = {n.lower(): i for i, n in enumerate(ARKIT_NAMES)}
    extra = {n.lower(): n for n in (*LIVELINK_HEAD, *LIVELINK_EYES, "BlendShapeCount")}
    where = {}
    for j, h in enumerate(head[1:], start=1):
        key = h.lower()
        if key in where:
            raise InputError(f"{path}: column {h!r} appears twice (column names are read without case)")
        if key not in known and key not in extra:
            raise InputError(f"{path}: unknown column {h!r} (expected Live Link Face's Timecode, BlendShapeCount, "
                             "the 52 ARKit names such as EyeBlinkLeft, HeadYaw/Pitch/Roll, eye angles)")
        where[key] = j
    missing = [_cap(ARKIT_NAMES[i]) for n, i in known.items() if n not in where]
    if missing:
        raise InputError(f"{path}: no column {missing[0]!r} ({len(missing)} of the 52 ARKit blendshapes missing)")
    heads = [h for h in LIVELINK_HEAD if h.lower() in where]
    if heads and len(heads) != 3:
        raise InputError(f"{path}: head rotation needs HeadYaw, HeadPitch and HeadRoll, got only {', '.join(heads)}")
    eyes = [h for h in LIVELINK_EYES if h.lower() in where]
    if eyes and len(eyes) != 6:
        raise InputError(f"{path}: eye rotation needs all six of {', '.join(LIVELINK_EYES)}, got {len(eyes)}")
    T = len(rows) - 1
    W = np.empty((T, 52))
    H = np.empty((T, 3)) if heads else None
    E = np.empty((T, 6)) if eyes else None
    cols = [(where[n], i, _cap(ARKIT_NAMES[i])) for n, i in known.items()]
    for t, r in enumerate(rows[1:]):
        for j, i, name in cols:
            W[t, i] = _float(path, r[j], t + 2, name)
        if H is not None:
            H[t] = [_float(path, r[where[h.lower()]], t + 2, h) for h in LIVELINK_HEAD]
        if E is not None:
            E[t] = [_float(path, r[where[h.lower()]], t + 2, h) for h in LIVELINK_EYES]
    W, counts, notes = _clamp(path, W, lambda t, i: f"row {t + 2} column {head[where[ARKIT_NAMES[i].lower()]]!r}")
    for A, names in ((H, LIVELINK_HEAD), (E, LIVELINK_EYES)):
        if A is not None and (np.abs(A) > math.pi).any():
            t, i = map(int, np.argwhere(np.abs(A) > math.pi)[0])
            raise InputError(f"{path}: row {t + 2} column {names[i]!r}: {A[t, i]:g} rad is beyond +-pi "
                             "(head and eye angles are radians)")
    rate, index, gaps = _timecodes(path, [r[0] for r in rows[1:]], fps)
    if rate is None:
        rate = 30.0 if fps is None else fps  # a single frame: its rate does not matter
    W = np.clip(_fill(W, index), 0.0, 1.0)
    H = None if H is None else _fill(H, index)
    E = None if E is None else _fill(E, index).reshape(-1, 2, 3)[:, :, :2]  # yaw, pitch (the eyes do not roll)
    if E is not None and not np.any(E):
        E = None  # a writer that records no gaze (all zero): the eyeLook* weights say where the eyes look
    info = {"clamped": counts, **gaps, "frames_read": T}
    return ArkitTrack(rate, W, H, source=str(path), eye_rotation=E, notes=notes + _gap_note(gaps, rate), info=info)


def _get(d: dict, *keys):
    for k in keys:
        if k in d:
            return d[k]
    return None


_FACE_KEYS = ("face_blendshapes", "faceBlendshapes", "blendshapes", "blendShapes", "people", "faces")
_NAME_KEYS = ("category_name", "categoryName", "name", "display_name", "displayName")
_MS_KEYS = ("timestamp_ms", "timestampMs", "time_ms")
_US_KEYS = ("timestamp_us", "timestampUs", "time_us")
VIDEO_FPS = (10.0, 240.0)
"""Frame rates [1/s] of video a face tracker runs on: ``timestamp_ms`` steps that give under 1 fps
in milliseconds but a rate in this range in microseconds are read as microseconds."""

MEDIAPIPE_MISSING_OK = ("tongueOut",)
"""ARKit shapes a MediaPipe take may lack: the Face Landmarker's 52 categories are ``_neutral``
and 51 ARKit names, without ``tongueOut`` (read as 0, and said in the track's notes)."""


def _is_category(c) -> bool:
    return isinstance(c, dict) and any(k in c for k in _NAME_KEYS) and ("score" in c or "value" in c)


def _mediapipe_frames(path: Path, data) -> list:
    """The file's frames as dicts ``{"faces": [...], "ms": .., "us": ..}`` in any of the layouts exporters write."""
    if isinstance(data, dict) and "frames" in data:
        data = data["frames"]
    elif isinstance(data, dict) and (any(k in data for k in _FACE_KEYS) or _is_category(data)):
        data = [data]  # one frame
    if not isinstance(data, list) or not data:
        raise InputError(f"{path}: expected a list of frames [{{\"timestamp_ms\": .., \"face_blendshapes\": "
                         f"[[{{\"category_name\": .., \"score\": ..}}, ...]]}}, ...], got {describe(data)}")
    if all(_is_category(c) for c in data):
        data = [data]  # a flat list of categories: one frame
    out = []
    for t, fr in enumerate(data):
        if isinstance(fr, list):  # a frame given as its categories (or as its faces)
            out.append({"faces": [fr] if not fr or _is_category(fr[0]) else fr, "ms": None, "us": None})
            continue
        if not isinstance(fr, dict):
            raise InputError(f"{path}: frame {t}: expected an object or a list of categories, got {describe(fr)}")
        faces = _get(fr, *_FACE_KEYS)
        if faces is None and _is_category(fr):
            raise InputError(f"{path}: frame {t}: a lone category; expected a list of categories per frame")
        if not isinstance(faces, list):
            raise InputError(f"{path}: frame {t}: no 'face_blendshapes' list (or 'blendshapes', 'people')")
        if faces and (_is_category(faces[0])):
            faces = [faces]  # one face, its categories flat
        out.append({"faces": faces, "ms": _get(fr, *_MS_KEYS), "us": _get(fr, *_US_KEYS)})
    return out


def _score(path: Path, t: int, name: str, score) -> float:
    if isinstance(score, str):
        try:
            score = float(score.strip())
        except ValueError:
            raise InputError(f"{path}: frame {t}: category {name!r} score must be a number, got {score!r}") from None
    if isinstance(score, bool) or not isinstance(score, (int, float)) or not math.isfinite(score):
        raise InputError(f"{path}: frame {t}: category {name!r} score must be a number, got {describe(score)}")
    return float(score)


def _stamp(path: Path, t: int, value, key: str) -> float:
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{path}: frame {t}: {key} must be a number, got {describe(value)}")
    return float(value)


def _mediapipe_json(path: Path, text: str, fps: float | None) -> ArkitTrack:
    frames = _mediapipe_frames(path, _json(path, text))
    index = {n.lower(): i for i, n in enumerate(ARKIT_NAMES)}
    T = len(frames)
    W = np.zeros((T, 52))
    ms, us = [], []
    empty = 0
    lacking: set = set()
    for t, fr in enumerate(frames):
        if fr["ms"] is not None:
            ms.append(_stamp(path, t, fr["ms"], "timestamp_ms"))
        if fr["us"] is not None:
            us.append(_stamp(path, t, fr["us"], "timestamp_us"))
        if not fr["faces"]:
            W[t] = W[t - 1] if t else 0.0
            empty += 1
            continue
        cats = fr["faces"][0]
        if isinstance(cats, dict):
            cats = cats.get("categories")
        if not isinstance(cats, list):
            raise InputError(f"{path}: frame {t}: a face must be a list of categories, got {describe(fr['faces'][0])}")
        seen = set()
        for c in cats:
            name = _get(c, *_NAME_KEYS) if isinstance(c, dict) else None
            if not isinstance(name, str):
                raise InputError(f"{path}: frame {t}: a category without 'category_name': {json.dumps(c)[:60]}")
            if name.strip().lower() == "_neutral":
                continue
            i = index.get(name.strip().lower())
            if i is None:
                raise InputError(f"{path}: frame {t}: unknown category {name!r} (expected the 52 ARKit names)")
            if i in seen:
                raise InputError(f"{path}: frame {t}: category {name!r} appears twice")
            W[t, i] = _score(path, t, name, _get(c, "score", "value"))
            seen.add(i)
        miss = [ARKIT_NAMES[i] for i in range(52) if i not in seen]
        hard = [n for n in miss if n not in MEDIAPIPE_MISSING_OK]
        if hard:
            raise InputError(f"{path}: frame {t}: no category {hard[0]!r} ({len(miss)} of the 52 ARKit names missing)")
        lacking.update(miss)
    if empty == T:
        raise InputError(f"{path}: no frame has a face")
    W, counts, notes = _clamp(path, W, lambda t, i: f"frame {t} category {ARKIT_NAMES[i]!r}")
    if lacking:
        notes.append(f"no {', '.join(sorted(lacking))} in the take (MediaPipe's Face Landmarker has none): read as 0")
    if empty:
        notes.append(f"{empty} frame(s) without a face hold the weights before them")
    if ms and us:
        raise InputError(f"{path}: frames have both timestamp_ms and timestamp_us")
    stamps = ms or us
    if stamps and len(stamps) != T:
        raise InputError(f"{path}: some frames have a timestamp and some do not")
    rate, idx, gaps = fps, np.arange(T), {"frames_filled": 0, "gaps": 0, "longest_gap_frames": 0}
    info = {"clamped": counts, "missing": sorted(lacking), "frames_without_face": empty, "frames_read": T}
    if len(stamps) > 1:
        x = np.asarray(stamps)
        unit = 1e-6 if us else 1e-3
        step = float(np.median(np.diff(x))) * unit
        if ms and step > 0 and 1.0 / step < MIN_TAKE_FPS and VIDEO_FPS[0] <= 1.0 / (step * 1e-3) <= VIDEO_FPS[1]:
            unit = 1e-6  # microseconds under a millisecond key (MediaPipe's C++ and graph timestamps)
            notes.append(f"timestamp_ms read as microseconds: in milliseconds the take would be {1.0 / step:.3g} "
                         "frames/s")
            info["timestamps_in_microseconds"] = True
        rate, idx, gaps = _grid(path, x * unit, "timestamps", resolution=unit, row0=0,
                                unit="s")
        _check_rate(path, rate, "timestamps")
        if fps is not None and abs(rate - fps) > 0.005 * fps:
            raise InputError(f"{path}: the timestamps give {rate:g} fps, but fps {fps:g} was given")
    elif rate is None:
        if T > 1:
            raise InputError(f"{path}: the frames have no timestamp_ms; give fps")
        rate = 30.0
    W = np.clip(_fill(W, idx), 0.0, 1.0)
    info.update(gaps)
    return ArkitTrack(rate, W, None, source=str(path), notes=notes + _gap_note(gaps, rate), info=info)


def save_livelink_csv(track: ArkitTrack, path) -> Path:
    """Write ``track`` as a Live Link Face CSV (the columns Epic's app writes), atomically.

    Timecodes start at 00:00:00:00 and count frames at the smallest of :data:`TIMECODE_RATES` at
    or above the track's fps, with the sub-frame fraction after the dot; head angles are the
    track's (zero when it has none); eye angles are zero (an :class:`ArkitTrack` has no gaze).
    :func:`load_arkit` reads it back.
    """
    if not isinstance(track, ArkitTrack):
        raise InputError(f"track: expected an ArkitTrack, got {describe(track)}")
    path = check_path("path", path)
    rate = next((r for r in TIMECODE_RATES if r >= track.fps - 1e-9), None)
    if rate is None:
        raise InputError(f"track: fps {track.fps:g} is above the fastest timecode rate {TIMECODE_RATES[-1]}")
    H = track.head_rotation if track.head_rotation is not None else np.zeros((track.frames, 3))
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["Timecode", "BlendShapeCount", *map(_cap, ARKIT_NAMES), *LIVELINK_HEAD, *LIVELINK_EYES])
    count = len(ARKIT_NAMES) + len(LIVELINK_HEAD) + len(LIVELINK_EYES)
    for k in range(track.frames):
        ms = round(k * 1000.0 * rate / track.fps)  # thousandths of a timecode frame
        f_all, sub = divmod(ms, 1000)
        secs, ff = divmod(f_all, rate)
        tc = f"{secs // 3600:02d}:{secs // 60 % 60:02d}:{secs % 60:02d}:{ff:02d}.{sub:03d}"
        w.writerow([tc, count, *(f"{v:.6g}" for v in track.weights[k]), *(f"{v:.6g}" for v in H[k]),
                    *(["0"] * len(LIVELINK_EYES))])
    with atomic_write(path, "w") as f:
        f.write(out.getvalue())
    return path
