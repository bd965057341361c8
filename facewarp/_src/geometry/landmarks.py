"""MPEG-4 facial definition points (FDPs), FAP units, and landmark files.

Coordinate convention (MPEG-4 neutral face): x toward the subject's LEFT, y up, z out of
the face. "Left" and "right" are the subject's own: FDP 3.7 is the outer corner of the
subject's left eye, at +x. Sources: ISO/IEC 14496-2 Annex C as reproduced in public MPEG-4
facial-animation code; descriptions ending in "(?)" could not be checked against the
standard's own text.

Landmarks are ``dict[str, np.ndarray]`` mapping an FDP id ("3.7") to a position [m],
shape (3,), float64.

Other schemes: the common 68-point scheme (iBUG 300-W / Multi-PIE order, 0-based: 0-16 jaw line
from the subject's right ear to the left, 17-26 brows, 27-35 nose, 36-47 eyes, 48-67 lips) and
its 51-point inner subset (the 68 without the jaw line, 0-based 17-67 renumbered 0-50) are read by
:func:`load_landmarks` and converted by :func:`landmarks_from_scheme` to the FDPs they share a
point with (:data:`IBUG68_TO_FDP`). A point is in the table when it and the FDP mark the same
place: on the ICT-FaceKit neutral head (whose 68 landmark vertices ICT publishes) the default
template's FDP, adapted there, lies within 1.5 mm of the scheme's point (:data:`IBUG68_FDP_OFFSET_MM`
gives each distance; brows, jaw line, lids and nostrils differ by 5-10 mm between the two schemes'
definitions and are left out).
"""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ..core.errors import InputError
from ..core.fileio import write_json
from .mesh import unit_scale

__all__ = [
    "FDP",
    "FDP_CATALOGUE",
    "FDP_IDS",
    "IBUG68_FDP_OFFSET_MM",
    "IBUG68_TO_FDP",
    "LANDMARK_SCHEMES",
    "LANDMARK_SUFFIXES",
    "fapu",
    "landmarks_from_scheme",
    "load_scheme_points",
    "fdp_sort_key",
    "load_landmarks",
    "save_landmarks_json",
]

LANDMARK_SUFFIXES: tuple[str, ...] = (".json", ".pp", ".pts")
"""File suffixes :func:`load_landmarks` reads: JSON, MeshLab picked points and iBUG ``.pts``."""

LANDMARK_SCHEMES: dict[str, int] = {"fdp": 0, "ibug68": 68, "ibug51": 51}
"""Landmark schemes :func:`load_landmarks` reads -> their point count (0: named FDPs)."""

IBUG68_TO_FDP: dict[int, str] = {
    8: "2.1",  # menton: bottom of the chin
    30: "9.3",  # nose tip
    33: "9.15",  # subnasale: bottom middle edge of the nose
    36: "3.12", 39: "3.8",  # subject's right eye: outer, inner corner
    42: "3.11", 45: "3.7",  # subject's left eye: inner, outer corner
    48: "8.4", 54: "8.3",  # outer lip corners: right, left
    51: "8.1", 57: "8.2",  # outer lip contour: upper, lower middle
    62: "2.2", 66: "2.3",  # inner lip contour: upper, lower middle
}  # fmt: skip
"""0-based point of the 68-point scheme -> the MPEG-4 FDP at the same place (see the module
docstring). The 51-point scheme's point ``i`` is the 68-point scheme's ``i + 17``."""

IBUG68_FDP_OFFSET_MM: dict[int, float] = {8: 1.4, 30: 0.7, 33: 1.1, 36: 1.0, 39: 1.4, 42: 1.4, 45: 1.2, 48: 0.4,
                                          54: 0.5, 51: 1.3, 57: 1.0, 62: 1.3, 66: 1.2}
"""Distance [mm] between each tabled 68-point landmark of the ICT-FaceKit neutral head (ICT's own
vertex) and the default template's FDP adapted to that head with the 12 FDPs of the ICT head:
how far the two definitions of the point lie apart on one face (an upper bound: it includes the
adaptation's own error)."""


@dataclass(frozen=True)
class FDP:
    """One MPEG-4 facial definition point.

    Attributes:
        id: "group.index", e.g. "3.7".
        group: The group number (2..11).
        description: What the point marks; "(?)" when unverified.
        side: "left" (subject's left, +x), "right" (-x) or "center".
    """

    id: str
    group: int
    description: str
    side: Literal["left", "right", "center"]


L, R, C = "left", "right", "center"

# (id, side, description), from /work/shared/docs/MPEG4_FDP.md
_TABLE: tuple[tuple[str, str, str], ...] = (
    # 2: chin, inner lip, jaw
    ("2.1", C, "bottom of the chin"),
    ("2.2", C, "middle of inner upper lip contour"),
    ("2.3", C, "middle of inner lower lip contour"),
    ("2.4", L, "left corner of inner lip contour"),
    ("2.5", R, "right corner of inner lip contour"),
    ("2.6", L, "inner upper lip, midpoint of 2.2-2.4"),
    ("2.7", R, "inner upper lip, midpoint of 2.2-2.5"),
    ("2.8", L, "inner lower lip, midpoint of 2.3-2.4"),
    ("2.9", R, "inner lower lip, midpoint of 2.3-2.5"),
    ("2.10", C, "chin boss"),
    ("2.11", L, "chin left corner"),
    ("2.12", R, "chin right corner"),
    ("2.13", L, "left corner of jaw bone"),
    ("2.14", R, "right corner of jaw bone"),
    # 3: eyes
    ("3.1", L, "centre of upper inner left eyelid"),
    ("3.2", R, "centre of upper inner right eyelid"),
    ("3.3", L, "centre of lower inner left eyelid"),
    ("3.4", R, "centre of lower inner right eyelid"),
    ("3.5", L, "centre of left pupil"),
    ("3.6", R, "centre of right pupil"),
    ("3.7", L, "left eye, outer corner"),
    ("3.8", R, "right eye, inner corner"),
    ("3.9", L, "centre of lower outer left eyelid"),
    ("3.10", R, "centre of lower outer right eyelid"),
    ("3.11", L, "left eye, inner corner"),
    ("3.12", R, "right eye, outer corner"),
    ("3.13", L, "centre of upper outer left eyelid"),
    ("3.14", R, "centre of upper outer right eyelid"),
    # 4: eyebrows
    ("4.1", L, "inner corner of left eyebrow"),
    ("4.2", R, "inner corner of right eyebrow"),
    ("4.3", L, "uppermost point of left eyebrow"),
    ("4.4", R, "uppermost point of right eyebrow"),
    ("4.5", L, "outer corner of left eyebrow"),
    ("4.6", R, "outer corner of right eyebrow"),
    # 5: cheeks
    ("5.1", L, "centre of left cheek"),
    ("5.2", R, "centre of right cheek"),
    ("5.3", L, "left cheek bone"),
    ("5.4", R, "right cheek bone"),
    # 6: tongue
    ("6.1", C, "tip of the tongue"),
    ("6.2", C, "centre of the tongue body"),
    ("6.3", L, "left border of the tongue"),
    ("6.4", R, "right border of the tongue"),
    # 7: spine
    ("7.1", C, "top of spine (centre of head rotation)"),
    # 8: outer lips
    ("8.1", C, "middle of outer upper lip contour"),
    ("8.2", C, "middle of outer lower lip contour"),
    ("8.3", L, "left corner of outer lip contour"),
    ("8.4", R, "right corner of outer lip contour"),
    ("8.5", L, "outer upper lip, midpoint of 8.3-8.1"),
    ("8.6", R, "outer upper lip, midpoint of 8.4-8.1"),
    ("8.7", L, "outer lower lip, midpoint of 8.3-8.2"),
    ("8.8", R, "outer lower lip, midpoint of 8.4-8.2"),
    ("8.9", R, "right high point of the Cupid's bow (?)"),
    ("8.10", L, "left high point of the Cupid's bow (?)"),
    # 9: nose, teeth
    ("9.1", L, "left nostril border"),
    ("9.2", R, "right nostril border"),
    ("9.3", C, "nose tip"),
    ("9.4", R, "bottom right edge of nose"),
    ("9.5", L, "bottom left edge of nose"),
    ("9.6", R, "right upper edge of nose bone"),
    ("9.7", L, "left upper edge of nose bone"),
    ("9.8", C, "top of upper teeth"),
    ("9.9", C, "bottom of lower teeth"),
    ("9.10", C, "bottom of upper teeth"),
    ("9.11", C, "top of lower teeth"),
    ("9.12", C, "middle lower edge of nose bone"),
    ("9.13", L, "left lower edge of nose bone"),
    ("9.14", R, "right lower edge of nose bone"),
    ("9.15", C, "bottom middle edge of nose"),
    # 10: ears
    ("10.1", L, "top of left ear"),
    ("10.2", R, "top of right ear"),
    ("10.3", L, "back of left ear"),
    ("10.4", R, "back of right ear"),
    ("10.5", L, "bottom of left ear lobe"),
    ("10.6", R, "bottom of right ear lobe"),
    ("10.7", L, "lower contact point between left lobe and face"),
    ("10.8", R, "lower contact point between right lobe and face"),
    ("10.9", L, "upper contact point between left ear and face"),
    ("10.10", R, "upper contact point between right ear and face"),
    # 11: hairline, skull
    ("11.1", C, "middle border between hair and forehead"),
    ("11.2", R, "right border between hair and forehead (?)"),
    ("11.3", L, "left border between hair and forehead (?)"),
    ("11.4", C, "top of skull"),
    ("11.5", C, "hair thickness over 11.4 (?)"),
    ("11.6", C, "back of skull (?)"),
)
del L, R, C


def fdp_sort_key(fdp_id: str) -> tuple[int, int]:
    """Numeric sort key of an FDP id: "3.12" -> (3, 12), so 3.2 < 3.12 < 4.1."""
    group, index = fdp_id.split(".")
    return int(group), int(index)


FDP_CATALOGUE: dict[str, FDP] = {
    i: FDP(id=i, group=fdp_sort_key(i)[0], description=d, side=s)  # type: ignore[arg-type]
    for i, s, d in sorted(_TABLE, key=lambda row: fdp_sort_key(row[0]))
}
"""All 84 MPEG-4 FDPs by id, in :data:`FDP_IDS` order."""

FDP_IDS: tuple[str, ...] = tuple(FDP_CATALOGUE)
"""The FDP ids sorted numerically by group, then index: ("2.1", "2.2", ..., "2.14", "3.1", ...)."""


# ----------------------------------------------------------------------------------------
# FAP units


def fapu(landmarks: dict[str, np.ndarray]) -> dict[str, float]:
    """MPEG-4 facial animation parameter units of a neutral face.

    The distances are coordinate differences in the MPEG-4 frame (x to the subject's left,
    y up)::

        ES0    = 3.5.x - 3.6.x     eye separation (pupil to pupil)
        IRISD0 = 3.1.y - 3.3.y     iris diameter (upper to lower left eyelid)
        ENS0   = 3.5.y - 9.15.y    eye to nose separation
        MNS0   = 9.15.y - 2.2.y    mouth to nose separation
        MW0    = 8.3.x - 8.4.x     mouth width

    and each unit is its distance / 1024 (ES = ES0 / 1024, ...); AU = 1e-5 rad.

    Args:
        landmarks: FDP id -> position [m], shape (3,), float64; must contain 3.1, 3.3,
            3.5, 3.6, 9.15, 2.2, 8.3, 8.4.

    Returns:
        ``{"ES0", "IRISD0", "ENS0", "MNS0", "MW0"}``: the distances [m];
        ``{"ES", "IRISD", "ENS", "MNS", "MW"}``: the units (distance / 1024) [m];
        ``"AU"``: 1e-5 [rad].

    Raises:
        InputError: An FDP is missing (named), or a distance is not positive (the landmarks
            are not in the MPEG-4 frame).
    """
    from ..core.checks import check_landmark_dict

    check_landmark_dict("landmarks", landmarks)
    definitions = {
        "ES0": ("3.5", "3.6", 0),
        "IRISD0": ("3.1", "3.3", 1),
        "ENS0": ("3.5", "9.15", 1),
        "MNS0": ("9.15", "2.2", 1),
        "MW0": ("8.3", "8.4", 0),
    }
    out: dict[str, float] = {}
    for name, (a, b, axis) in definitions.items():
        for fdp_id in (a, b):
            if fdp_id not in landmarks:
                raise InputError(f"landmarks: FDP {fdp_id} is missing, needed for {name}")
        pa = np.asarray(landmarks[a], dtype=np.float64).reshape(3)
        pb = np.asarray(landmarks[b], dtype=np.float64).reshape(3)
        d = float(pa[axis] - pb[axis])
        if not d > 0.0:
            raise InputError(
                f"landmarks: {name} = {a}.{'xy'[axis]} - {b}.{'xy'[axis]} = {d:.6g} m is not positive; "
                "landmarks must be in the MPEG-4 frame (x to the subject's left, y up)"
            )
        out[name] = d
        out[name[:-1]] = d / 1024.0
    out["AU"] = 1e-5
    return out


# ----------------------------------------------------------------------------------------
# files


def _position(source: Path, fdp_id: str, value) -> np.ndarray:
    if (
        not isinstance(value, (list, tuple))
        or len(value) != 3
        or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)
        or not all(np.isfinite(float(x)) for x in value)
    ):
        raise InputError(f"{source}: landmark {fdp_id!r} must be 3 finite numbers, got {json.dumps(value)[:60]}")
    return np.array(value, dtype=np.float64)


def _check_id(source: Path, fdp_id: str) -> None:
    if fdp_id not in FDP_CATALOGUE:
        raise InputError(f"{source}: unknown FDP id {fdp_id!r} (expected MPEG-4 ids such as '3.7')")


def _read_json(path: Path, text: str) -> dict[str, np.ndarray]:
    def pairs_hook(pairs):
        seen = set()
        for key, _ in pairs:
            if key in seen:
                raise InputError(f"{path}: landmark {key!r} appears more than once")
            seen.add(key)
        return dict(pairs)

    try:
        data = json.loads(text, object_pairs_hook=pairs_hook)  # NaN/Infinity parse; rejected below
    except json.JSONDecodeError as e:
        raise InputError(f"{path}: malformed JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object mapping FDP ids to [x, y, z], got {type(data).__name__}")
    out = {}
    for key, value in data.items():
        _check_id(path, key)
        out[key] = _position(path, key, value)
    return out


def landmarks_from_scheme(points, scheme: str = "auto", *, what: str = "landmarks") -> dict[str, np.ndarray]:
    """FDP landmarks from the points of a numbered scheme (:data:`LANDMARK_SCHEMES`).

    Args:
        points: The scheme's points in order [any length unit], shape (68, 3) or (51, 3), float.
        scheme: "ibug68", "ibug51" or "auto" (by the point count).
        what: The name used in error messages.

    Returns:
        FDP id -> position (the input's unit), shape (3,), float64; the FDPs of
        :data:`IBUG68_TO_FDP`, in FDP order.

    Raises:
        InputError: Not an (n, 3) array of finite numbers, a count that fits no scheme, or a
            count that is not the given scheme's.
    """
    try:
        P = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected a list of [x, y, z] points") from None
    if P.ndim != 2 or P.shape[1] != 3:
        cols = P.shape[1] if P.ndim == 2 else None
        hint = " (2D image landmarks: the adaptation needs 3D points on the scan)" if cols == 2 else ""
        raise InputError(f"{what}: expected points of shape (n, 3), got {P.shape}{hint}")
    if scheme == "auto":
        scheme = {68: "ibug68", 51: "ibug51"}.get(len(P), "")
        if not scheme:
            raise InputError(f"{what}: {len(P)} points fit no landmark scheme (expected a JSON object of named "
                              "FDPs, or a list of the 68 or 51 points of the 68-point scheme)")
    if scheme not in LANDMARK_SCHEMES or scheme == "fdp":
        raise InputError(f"{what}: unknown point scheme {scheme!r}, expected ibug68, ibug51 or auto")
    if len(P) != LANDMARK_SCHEMES[scheme]:
        raise InputError(f"{what}: the {scheme} scheme has {LANDMARK_SCHEMES[scheme]} points, got {len(P)}")
    if not np.isfinite(P).all():
        bad = int(np.flatnonzero(~np.isfinite(P).all(axis=1))[0])
        raise InputError(f"{what}: point {bad} is not 3 finite numbers")
    first = 0 if scheme == "ibug68" else 17
    out = {fdp: P[i - first].copy() for i, fdp in IBUG68_TO_FDP.items() if i >= first}
    return {k: out[k] for k in sorted(out, key=fdp_sort_key)}


def _read_pts(path: Path, text: str) -> np.ndarray:
    """The points of an iBUG ``.pts`` file (``version: 1``, ``n_points: 68``, ``{``, one point a
    line, ``}``), shape (n, d)."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    try:
        start, end = lines.index("{"), lines.index("}")
    except ValueError:
        raise InputError(f"{path}: expected an iBUG .pts file (n_points: N, then the points between {{ and }})") from None
    header = dict(ln.split(":", 1) for ln in lines[:start] if ":" in ln)
    try:
        rows = [[float(x) for x in ln.split()] for ln in lines[start + 1:end]]
        P = np.array(rows, dtype=np.float64)
    except ValueError:
        raise InputError(f"{path}: a point line is not numbers") from None
    n = header.get("n_points", "").strip()
    if n and n.isdigit() and int(n) != len(P):
        raise InputError(f"{path}: n_points says {n} but the file has {len(P)} points")
    return P


def _read_points(path: Path, text: str, suffix: str):
    """The list of points of a numbered-scheme file (``.pts``, or a JSON list), or None for named FDPs."""
    if suffix == ".pts":
        return _read_pts(path, text)
    if suffix == ".json" and text.lstrip().startswith("["):
        try:
            return json.loads(text)
        except json.JSONDecodeError as e:
            raise InputError(f"{path}: malformed JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
    return None


def load_scheme_points(path: str | os.PathLike, *, units: str = "m", scheme: str = "auto"):
    """The points of a 68- or 51-point landmark file in their order, or None for a file of named FDPs.

    Args:
        path: A file :func:`load_landmarks` reads.
        units: Unit of the file's coordinates: "mm", "cm" or "m".
        scheme: As in :func:`load_landmarks`.

    Returns:
        None, or (scheme "ibug68" / "ibug51", points [m] shape (68, 3) or (51, 3) float64).

    Raises:
        InputError: As :func:`load_landmarks`.
    """
    load_landmarks(path, units=units, scheme=scheme)  # every check, one message
    path = Path(path)
    points = _read_points(path, path.read_text(encoding="utf-8"), path.suffix.lower())
    if points is None:
        return None
    P = np.asarray(points, dtype=np.float64) * unit_scale(units)
    return ("ibug68" if len(P) == 68 else "ibug51"), P


def _read_pp(path: Path, text: str) -> dict[str, np.ndarray]:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise InputError(f"{path}: malformed XML ({e})") from None
    if root.tag != "PickedPoints":
        raise InputError(f"{path}: expected a MeshLab <PickedPoints> document, got <{root.tag}>")
    out: dict[str, np.ndarray] = {}
    for n, point in enumerate(root.iter("point")):
        name = point.get("name")
        if name is None:
            raise InputError(f"{path}: <point> number {n + 1} has no name")
        name = name.strip()
        if point.get("active", "1").strip() in ("0", "false", "False"):
            continue  # unchecked in MeshLab's picked-points list
        _check_id(path, name)
        if name in out:
            raise InputError(f"{path}: landmark {name!r} appears more than once")
        try:
            xyz = [float(point.get(axis)) for axis in "xyz"]
        except (TypeError, ValueError):
            raise InputError(f"{path}: landmark {name!r} must have numeric x, y, z attributes") from None
        out[name] = _position(path, name, xyz)
    return out


def load_landmarks(path: str | os.PathLike, *, units: str = "m", scheme: str = "auto") -> dict[str, np.ndarray]:
    """Read FDP landmarks from JSON, a MeshLab picked-points (``.pp``) or an iBUG ``.pts`` file.

    JSON: ``{"3.7": [x, y, z], ...}`` (named FDPs), or a list of 68 or 51 ``[x, y, z]`` points
    (the 68-point scheme or its 51 inner points, converted by :func:`landmarks_from_scheme`).
    ``.pp``: ``<point x=".." y=".." z=".." name="3.7" active="1"/>`` elements; points with
    ``active="0"`` are skipped. ``.pts``: the iBUG point file with 3 numbers a point.

    Args:
        path: The file; format chosen by its suffix (:data:`LANDMARK_SUFFIXES`).
        units: Unit of the file's coordinates: "mm", "cm" or "m".
        scheme: "auto" (by the file's content), "fdp", "ibug68" or "ibug51"
            (:data:`LANDMARK_SCHEMES`): a file of another scheme is an error.

    Returns:
        FDP id -> position [m], shape (3,), float64; in :data:`FDP_IDS` order.

    Raises:
        InputError: Missing/empty/unreadable file, malformed JSON or XML, a JSON value that
            is not an object, an unknown FDP id, a position that is not 3 finite numbers, a
            duplicate id, a list of points that fits no scheme (or not the given one), or no
            landmarks at all. The one-line message starts with the path.
    """
    from ..core.checks import check_path

    check_path("path", path)
    scale = unit_scale(units)
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file")
    if scheme != "auto" and scheme not in LANDMARK_SCHEMES:
        raise InputError(f"scheme: expected auto, {', '.join(LANDMARK_SCHEMES)}, got {scheme!r}")
    suffix = path.suffix.lower()
    if suffix not in LANDMARK_SUFFIXES:
        raise InputError(f"{path}: unsupported landmark format {suffix or '(no suffix)'!r}, expected .json, .pp or .pts")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    if not text.strip():
        raise InputError(f"{path}: file is empty")
    points = _read_points(path, text, suffix)
    if points is not None:
        if scheme == "fdp":
            raise InputError(f"{path}: holds a list of points, not named FDPs (scheme 'fdp')")
        lm = landmarks_from_scheme(points, scheme, what=str(path))
    else:
        if scheme not in ("auto", "fdp"):
            raise InputError(f"{path}: holds named FDPs, not the {scheme} scheme's list of points")
        lm = _read_json(path, text) if suffix == ".json" else _read_pp(path, text)
    if not lm:
        raise InputError(f"{path}: contains no landmarks")
    return {k: lm[k] * scale for k in sorted(lm, key=fdp_sort_key)}


def save_landmarks_json(path: str | os.PathLike, lm: dict[str, np.ndarray], *, units: str = "m") -> None:
    """Write landmarks as JSON ``{"3.7": [x, y, z], ...}``, atomically, in FDP order.

    Args:
        path: Destination ``.json`` file.
        lm: FDP id -> position [m], shape (3,), float64.
        units: Unit of the written coordinates: "mm", "cm" or "m".

    Raises:
        InputError: An unknown FDP id or a position that is not 3 finite numbers.
    """
    from ..core.checks import check_landmark_dict, check_path

    check_path("path", path)
    check_landmark_dict("lm", lm)
    scale = unit_scale(units)
    out = {}
    for key in sorted(lm, key=lambda k: fdp_sort_key(k) if k in FDP_CATALOGUE else (1 << 30, 0)):
        if key not in FDP_CATALOGUE:
            raise InputError(f"landmarks: unknown FDP id {key!r}")
        p = np.asarray(lm[key], dtype=np.float64)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise InputError(f"landmarks: {key!r} must be 3 finite numbers, got shape {p.shape}")
        out[key] = (p / scale).tolist()
    write_json(path, out)
