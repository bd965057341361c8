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
  columns (the ARKit names with a capital first letter, any order), weights in [0, 1]. The
  timecode is ``HH:MM:SS:FF.fff`` (``;`` also accepted): the frame field ``FF`` with its
  sub-frame fraction counts at the timecode rate, read as the smallest of 24, 25, 30, 48, 50, 60,
  100, 120 that exceeds the largest frame number seen before a whole second turns over; the
  take's fps is 1 / the median step of the times so made (``fps=`` when the take does not cross
  a whole second). HeadYaw, HeadPitch and HeadRoll are radians; eye rotation columns are read
  and ignored (gaze is beyond the muscle model).
- MediaPipe Face Landmarker JSON: a list of frames as the Tasks API's results are dumped,
  ``[{"timestamp_ms": 0, "face_blendshapes": [[{"category_name": "_neutral", "score": 0.0},
  {"category_name": "browDownLeft", "score": 0.01}, ...]]}, ...]`` (or the same under
  ``{"frames": [...]}``); the JavaScript spellings ``timestampMs``, ``faceBlendshapes``,
  ``categoryName`` and a face given as ``{"categories": [...]}`` are accepted too. Per frame the
  first face is used; it must have all 52 ARKit categories (``_neutral`` is ignored). A frame with
  no face (an empty ``face_blendshapes``) holds the previous frame's weights (zero before the
  first face). fps = 1000 / the median step of ``timestamp_ms`` (``fps=`` when the frames have
  no timestamps).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
from pathlib import Path

import numpy as np

from ..core.checks import check_number, check_path, describe
from ..core.errors import InputError
from ..core.fileio import atomic_write, write_json
from ..geometry.landmarks import FDP_CATALOGUE
from ..geometry.mesh import unit_scale
from .tracks import ARKIT_NAMES, ArkitTrack, MarkerTrack

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
def load_markers(path, *, map=None, units: str | None = None, fps: float | None = None) -> MarkerTrack:  # noqa: A002
    """Read a marker take (JSON, CSV or C3D; formats in this module's docstring) as a :class:`MarkerTrack`.

    Args:
        path: The file; the format is chosen by its suffix (:data:`MARKER_SUFFIXES`).
        map: A map file (path) or dict from the take's labels to FDP ids / ``"v<index>"``;
            needed when the labels are not point names themselves. Unmapped labels are dropped.
        units: Units of the file's coordinates, ``"mm"``, ``"cm"`` or ``"m"``: for CSV (default
            ``"m"``) and for JSON and C3D files that do not say (if the file says, it must agree).
        fps: Frames per second, for a CSV with a ``frame`` column (other files carry it; if given
            it must agree with them within 0.5 %).

    Returns:
        The track, positions (T, K, 3) float64 [m], NaN where a marker is missing.

    Raises:
        InputError: one line naming the file and what is wrong (empty, truncated, malformed,
        unknown columns or labels, a marker with the wrong number of frames, NaN in JSON, a
        partly missing point, uneven time steps, units that do not give a head-sized take).
    """
    mapping = None
    if map is not None:
        mapping = load_map(map) if isinstance(map, (str, os.PathLike)) else dict(map)
        for label, name in mapping.items():
            check_point_name(name, f"map: label {label!r}")
    if units is not None:
        unit_scale(units)
    if fps is not None:
        fps = check_number("fps", fps, low=0.0, high=10_000.0, low_open=True)
    path, text = _open_text(path, MARKER_SUFFIXES, "marker")
    suffix = path.suffix.lower()
    if suffix == ".json":
        labels, P, file_fps, file_units = _markers_json(path, text)
    elif suffix == ".csv":
        labels, P, file_fps, file_units = _markers_csv(path, text)
    else:
        labels, P, file_fps, file_units = _markers_c3d(path)
    if file_units is not None and units is not None and file_units != units:
        raise InputError(f"{path}: the file says units {file_units!r}, but units {units!r} were given")
    u = file_units or units or "m"
    P = P * _units(path, u)
    if file_fps is None and fps is None:
        raise InputError(f"{path}: the frame rate is not in the file (a 'frame' column, or a single frame); give fps")
    if file_fps is not None and fps is not None and abs(file_fps - fps) > 0.005 * fps:
        raise InputError(f"{path}: the file's frame rate is {file_fps:g}, but fps {fps:g} was given")
    rate = file_fps if file_fps is not None else fps
    names, P = _apply_map(path, labels, P, mapping)
    _check_span(path, P, u)
    try:
        return MarkerTrack(rate, names, P, source=str(path))
    except InputError as e:
        raise InputError(f"{path}: {e}") from None


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
    return labels, P, rate, units


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


def _even_steps(path: Path, t: np.ndarray, what: str) -> float | None:
    """fps of increasing, evenly spaced times ``t`` [s]: frames over the whole span (which the
    rounding of the printed times barely touches), a whole number when within 0.2 % of one; None
    for a single frame."""
    d = np.diff(t)
    if len(d) == 0:
        return None
    if (d <= 0).any():
        k = int(np.argmax(d <= 0))
        raise InputError(f"{path}: {what} do not increase (row {k + 3})")
    step = float(np.median(d))
    bad = np.abs(d - step) > 0.1 * step
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"{path}: uneven {what}: step {d[k]:.4g} s at row {k + 3}, median {step:.4g} s")
    rate = len(d) / float(t[-1] - t[0])
    return float(round(rate)) if abs(rate - round(rate)) < 0.002 * rate else rate


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
    rate = _even_steps(path, first_col, "times") if first == "time" else None
    if first == "frame":
        _even_steps(path, first_col, "frame numbers")
    return labels, P, rate, None


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
    if not labels or len(labels) != frames[0].shape[0]:
        raise InputError(f"{path}: the C3D file has {frames[0].shape[0]} points but {len(labels)} labels")
    if len(set(labels)) != len(labels):
        raise InputError(f"{path}: a C3D label appears twice")
    if units is not None and units not in ("mm", "cm", "m"):
        raise InputError(f"{path}: POINT:UNITS is {units!r}, expected mm, cm or m")
    if not math.isfinite(rate) or rate <= 0:
        raise InputError(f"{path}: the C3D point rate is {rate!r}")
    return labels, np.stack(frames), rate, units


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
def load_arkit(path, *, fps: float | None = None) -> ArkitTrack:
    """Read ARKit blendshape curves: a Live Link Face CSV or a MediaPipe Face Landmarker JSON
    (formats in this module's docstring) as an :class:`ArkitTrack`.

    Args:
        path: ``.csv`` (Live Link Face) or ``.json`` (MediaPipe).
        fps: Frames per second, needed only when the file cannot tell (a Live Link take that does
            not cross a whole second, MediaPipe frames without timestamps).

    Returns:
        The track: weights (T, 52) in :data:`~facewarp.ARKIT_NAMES` order; head_rotation (T, 3)
        [rad] yaw, pitch, roll from Live Link's head columns, None for MediaPipe.

    Raises:
        InputError: one line naming the file and what is wrong (empty, truncated, malformed,
        missing or unknown columns or categories, weights outside [0, 1], bad timecodes).
    """
    if fps is not None:
        fps = check_number("fps", fps, low=0.0, high=10_000.0, low_open=True)
    path, text = _open_text(path, ARKIT_SUFFIXES, "ARKit")
    if path.suffix.lower() == ".csv":
        return _livelink_csv(path, text, fps)
    return _mediapipe_json(path, text, fps)


def _timecodes(path: Path, cells: list[str], fps: float | None) -> float:
    """The take's fps from its Live Link timecodes (see the module docstring)."""
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
        return fps
    top = max(int(frame[i]) for i in turns) + 1
    rate = next((r for r in TIMECODE_RATES if r >= top), None)
    if rate is None or frame.max() >= rate:
        raise InputError(f"{path}: timecode frame numbers up to {int(frame.max())} fit no timecode rate "
                         f"({', '.join(map(str, TIMECODE_RATES))})")
    t = whole + frame / rate
    found = _even_steps(path, t, "timecodes")
    if fps is not None and abs(found - fps) > 0.005 * fps:
        raise InputError(f"{path}: the timecodes give {found:g} fps, but fps {fps:g} was given")
    return found


def _livelink_csv(path: Path, text: str, fps: float | None) -> ArkitTrack:
    rows = _cells(path, text)
    head = [h.strip() for h in rows[0]]
    if not head or head[0].lower() != "timecode":
        raise InputError(f"{path}: not a Live Link Face CSV: the first column must be 'Timecode', got {head[0]!r}")
    known = {_cap(n): i for i, n in enumerate(ARKIT_NAMES)}
    where = {}
    for j, h in enumerate(head[1:], start=1):
        if h in where:
            raise InputError(f"{path}: column {h!r} appears twice")
        if h not in known and h not in LIVELINK_HEAD and h not in LIVELINK_EYES and h != "BlendShapeCount":
            raise InputError(f"{path}: unknown column {h!r} (expected Live Link Face's Timecode, BlendShapeCount, "
                             "the 52 ARKit names such as EyeBlinkLeft, HeadYaw/Pitch/Roll, eye angles)")
        where[h] = j
    missing = [n for n in known if n not in where]
    if missing:
        raise InputError(f"{path}: no column {missing[0]!r} ({len(missing)} of the 52 ARKit blendshapes missing)")
    heads = [h for h in LIVELINK_HEAD if h in where]
    if heads and len(heads) != 3:
        raise InputError(f"{path}: head rotation needs HeadYaw, HeadPitch and HeadRoll, got only {', '.join(heads)}")
    T = len(rows) - 1
    W = np.empty((T, 52))
    H = np.empty((T, 3)) if heads else None
    for t, r in enumerate(rows[1:]):
        for name, i in known.items():
            W[t, i] = _float(path, r[where[name]], t + 2, name)
        if H is not None:
            H[t] = [_float(path, r[where[h]], t + 2, h) for h in LIVELINK_HEAD]
    bad = (W < -1e-3) | (W > 1 + 1e-3)
    if bad.any():
        t, i = map(int, np.argwhere(bad)[0])
        raise InputError(f"{path}: row {t + 2} column {_cap(ARKIT_NAMES[i])!r}: weight {W[t, i]:g} is outside [0, 1]")
    if H is not None and (np.abs(H) > math.pi).any():
        t, i = map(int, np.argwhere(np.abs(H) > math.pi)[0])
        raise InputError(f"{path}: row {t + 2} column {LIVELINK_HEAD[i]!r}: {H[t, i]:g} rad is beyond +-pi "
                         "(head angles are radians)")
    rate = _timecodes(path, [r[0] for r in rows[1:]], fps)
    if rate is None:
        rate = 30.0 if fps is None else fps  # a single frame: its rate does not matter
    return ArkitTrack(rate, W, H, source=str(path))


def _get(d: dict, *keys):
    for k in keys:
        if k in d:
            return d[k]
    return None


def _mediapipe_json(path: Path, text: str, fps: float | None) -> ArkitTrack:
    data = _json(path, text)
    if isinstance(data, dict) and "frames" in data:
        data = data["frames"]
    if not isinstance(data, list) or not data:
        raise InputError(f"{path}: expected a list of frames [{{\"timestamp_ms\": .., \"face_blendshapes\": "
                         f"[[{{\"category_name\": .., \"score\": ..}}, ...]]}}, ...], got {describe(data)}")
    index = {n: i for i, n in enumerate(ARKIT_NAMES)}
    W = np.zeros((len(data), 52))
    stamps = []
    empty = 0
    for t, fr in enumerate(data):
        if not isinstance(fr, dict):
            raise InputError(f"{path}: frame {t}: expected an object, got {describe(fr)}")
        faces = _get(fr, "face_blendshapes", "faceBlendshapes")
        if not isinstance(faces, list):
            raise InputError(f"{path}: frame {t}: no 'face_blendshapes' list")
        ts = _get(fr, "timestamp_ms", "timestampMs")
        if ts is not None:
            if isinstance(ts, bool) or not isinstance(ts, (int, float)) or not math.isfinite(ts):
                raise InputError(f"{path}: frame {t}: timestamp_ms must be a number, got {describe(ts)}")
            stamps.append(float(ts))
        if not faces:
            W[t] = W[t - 1] if t else 0.0
            empty += 1
            continue
        cats = faces[0]
        if isinstance(cats, dict):
            cats = cats.get("categories")
        if not isinstance(cats, list):
            raise InputError(f"{path}: frame {t}: a face must be a list of categories, got {describe(faces[0])}")
        seen = set()
        for c in cats:
            name = _get(c, "category_name", "categoryName") if isinstance(c, dict) else None
            score = c.get("score") if isinstance(c, dict) else None
            if not isinstance(name, str):
                raise InputError(f"{path}: frame {t}: a category without 'category_name': {json.dumps(c)[:60]}")
            if name == "_neutral":
                continue
            if name not in index:
                raise InputError(f"{path}: frame {t}: unknown category {name!r} (expected the 52 ARKit names)")
            if isinstance(score, bool) or not isinstance(score, (int, float)) or not math.isfinite(score):
                raise InputError(f"{path}: frame {t}: category {name!r} score must be a number, got {describe(score)}")
            if not -1e-3 <= score <= 1 + 1e-3:
                raise InputError(f"{path}: frame {t}: category {name!r} score {score:g} is outside [0, 1]")
            W[t, index[name]] = score
            seen.add(name)
        if len(seen) != 52:
            miss = [n for n in ARKIT_NAMES if n not in seen]
            raise InputError(f"{path}: frame {t}: no category {miss[0]!r} ({len(miss)} of the 52 missing)")
    if empty == len(data):
        raise InputError(f"{path}: no frame has a face")
    if stamps and len(stamps) != len(data):
        raise InputError(f"{path}: some frames have timestamp_ms and some do not")
    rate = fps
    if len(stamps) > 1:
        d = np.diff(stamps)
        if (d <= 0).any():
            raise InputError(f"{path}: timestamp_ms do not increase (frame {int(np.argmax(d <= 0)) + 1})")
        rate = 1000.0 / float(np.median(d))
        if fps is not None and abs(rate - fps) > 0.005 * fps:
            raise InputError(f"{path}: the timestamps give {rate:g} fps, but fps {fps:g} was given")
    elif rate is None:
        if len(data) > 1:
            raise InputError(f"{path}: the frames have no timestamp_ms; give fps")
        rate = 30.0
    return ArkitTrack(rate, W, None, source=str(path))


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
