"""Mesh import/export, validation, a topology report, and points stored on a surface.

Everything inside facewarp is in metres; ``units`` converts at the file boundary.

OBJ files are read by our own reader, which keeps the vertices exactly in file order (the
``v`` lines), so that vertex indices published for a model (landmarks, regions) stay valid.
trimesh's OBJ loader splits vertices at UV seams and reorders them, so it is not used for
OBJ. Other formats (PLY, STL, OFF, GLB, GLTF) go through ``trimesh.load(process=False)``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fileio import atomic_write

__all__ = [
    "MESH_SUFFIXES",
    "UNITS",
    "Mesh",
    "SurfacePoints",
    "closest_surface_points",
    "load_mesh",
    "mesh_report",
    "save_glb",
    "save_obj",
    "unit_scale",
]

UNITS: dict[str, float] = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}
"""Length of one file unit in metres."""

MESH_SUFFIXES: tuple[str, ...] = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")
"""File suffixes :func:`load_mesh` reads."""

DEGENERATE_AREA = 1e-14
"""Triangles smaller than this [m^2] are counted as degenerate by :func:`mesh_report`."""


def unit_scale(units: str) -> float:
    """Metres per file unit: 1e-3 for "mm", 1e-2 for "cm", 1.0 for "m".

    Raises:
        InputError: ``units`` is not one of :data:`UNITS`.
    """
    try:
        return UNITS[units]
    except (KeyError, TypeError):
        raise InputError(f"units: unknown unit {units!r}, expected one of {', '.join(UNITS)}") from None


@dataclass
class Mesh:
    """A triangle mesh in metres.

    Attributes:
        vertices: Vertex positions [m], shape (n, 3), float64; in file order for OBJ.
        faces: Triangles (polygons fan-triangulated), shape (m, 3), int64.
        uv: Per-vertex texture coordinates, shape (n, 2), float64 (dimensionless), or None
            when the file has none or a vertex carries several (UV seams).
        name: A label, by default the file's stem.
        corner_uv: Texture coordinates of every triangle corner, shape (m, 3, 2), float64, or
            None (kept at UV seams too).
        colors: Per-vertex colour, shape (n, 3), float64 in [0, 1] (sRGB values as stored), or None.
        texture: The base-colour image, shape (h, w, 3), float64 in [0, 1] (row 0 at the top,
            so v = 1 is row 0), or None: OBJ ``map_Kd`` of its MTL, glTF ``baseColorTexture``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    name: str = ""
    corner_uv: np.ndarray | None = None
    colors: np.ndarray | None = None
    texture: np.ndarray | None = None

    @property
    def has_color(self) -> bool:
        """Whether the mesh carries colour: vertex colours, or a texture with corner UVs."""
        return self.colors is not None or (self.texture is not None and self.corner_uv is not None)

    def __post_init__(self):
        """Checks the arrays: finite (n, 3) vertices, (m, 3) whole-number faces indexing them,
        (n, 2) finite UVs or None (an :class:`InputError` naming the field otherwise)."""
        from ..core.checks import check_array, check_indices

        self.vertices = check_array("Mesh vertices", self.vertices, shape=(None, 3))
        self.faces = check_indices("Mesh faces", self.faces, len(self.vertices), shape=(None, 3))
        if self.uv is not None:
            self.uv = check_array("Mesh uv", self.uv, shape=(len(self.vertices), 2))
        if not isinstance(self.name, str):
            raise InputError(f"Mesh name: expected a string, got {type(self.name).__name__}")

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    @property
    def face_count(self) -> int:
        return len(self.faces)


# ----------------------------------------------------------------------------------------
# loading


def _check_file(path: Path) -> None:
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file")
    try:
        size = path.stat().st_size
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror})") from None
    if size == 0:
        raise InputError(f"{path}: file is empty")


def load_mesh(path: str | os.PathLike, *, units: str = "m") -> Mesh:
    """Read a triangle mesh and convert it to metres.

    OBJ: vertices in ``v``-line order; polygons fan-triangulated in file order (polygon
    ``(a, b, c, d)`` becomes ``(a, b, c), (a, c, d)``); negative (relative) indices
    resolved; ``vt`` kept as per-vertex UV when every vertex uses a single UV value, else
    ``uv=None`` (vertices in no face then get UV (0, 0)). Lines other than ``v``, ``vt`` and
    ``f`` are ignored. PLY, STL, OFF, GLB, GLTF: ``trimesh.load(..., process=False,
    force="mesh")``; a scene with several geometries is concatenated (transforms applied); a
    textured mesh (glTF splits its vertices along UV seams) and an STL (a triangle soup) have
    equal positions welded into one vertex (a textured mesh's UVs kept per corner, ``corner_uv``). An ASCII PLY must hold the lines
    its header promises.

    Args:
        path: Mesh file; the format is chosen by its suffix (:data:`MESH_SUFFIXES`).
        units: Unit of the file's coordinates: "mm", "cm" or "m".

    Returns:
        The :class:`Mesh`, vertices in metres.

    Raises:
        InputError: Missing path, a folder, an empty file, an unsupported or unreadable
            file, a non-finite coordinate, no faces, or a face index out of range. The
            one-line message starts with the path.
    """
    from ..core.checks import check_path

    check_path("path", path)
    scale = unit_scale(units)
    path = Path(path)
    _check_file(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        expected = ", ".join(MESH_SUFFIXES)
        raise InputError(f"{path}: unsupported mesh format {suffix or '(no suffix)'!r}, expected one of {expected}")
    look: dict = {}
    if suffix == ".obj":
        V, F, uv = _read_obj(path, look)
    else:
        V, F, uv = _read_trimesh(path, look)
    _validate(path, V, F)
    if uv is not None and (uv.shape != (len(V), 2) or not np.isfinite(uv).all()):
        uv = None
    cuv = look.get("corner_uv")
    if cuv is not None and (cuv.shape != (len(F), 3, 2) or not np.isfinite(cuv).all()):
        cuv = None
    col = look.get("colors")
    if col is not None and (col.shape != (len(V), 3) or not np.isfinite(col).all()):
        col = None
    return Mesh(vertices=V * scale, faces=F, uv=uv, name=path.stem, corner_uv=cuv, colors=col,
                texture=look.get("texture"))


def _as_unit_colors(C) -> np.ndarray:
    """Colours as float64 in [0, 1]: 0-255 values (integers, or any value above 1) divided by 255."""
    C = np.asarray(C)
    if np.issubdtype(C.dtype, np.integer) or (C.size and float(np.nanmax(C)) > 1.0):
        return np.clip(C.astype(np.float64) / 255.0, 0.0, 1.0)
    return np.clip(C.astype(np.float64), 0.0, 1.0)


def _image_rgb(img) -> np.ndarray | None:
    """A PIL image or array as (h, w, 3) float64 in [0, 1], or None."""
    if img is None:
        return None
    a = np.asarray(img.convert("RGB") if hasattr(img, "convert") else img)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] < 3 or a.shape[0] < 1 or a.shape[1] < 1:
        return None
    return _as_unit_colors(a[..., :3])


def _read_mtl_texture(path: Path, mtllibs: list[str], material: str | None) -> np.ndarray | None:
    """The ``map_Kd`` image of ``material`` (else the first material with one) in the OBJ's MTL files."""
    from PIL import Image

    maps: dict[str, str] = {}
    for lib in mtllibs:
        mp = path.parent / lib
        if not mp.is_file():
            continue
        current = None
        for line in mp.read_text(encoding="utf-8", errors="replace").splitlines():
            parts = line.strip().split()
            if not parts:
                continue
            if parts[0] == "newmtl" and len(parts) > 1:
                current = parts[1]
            elif parts[0] == "map_Kd" and len(parts) > 1 and current is not None:
                maps.setdefault(current, parts[-1])  # options (-s ...) come before the file name
    name = maps.get(material) if material in maps else next(iter(maps.values()), None)
    if name is None:
        return None
    ip = path.parent / name
    try:
        with Image.open(ip) as img:
            return _image_rgb(img)
    except OSError as e:
        raise InputError(f"{path}: cannot read its texture {ip} ({e})") from None


def _validate(path: Path, V: np.ndarray, F: np.ndarray) -> None:
    if len(V) == 0:
        raise InputError(f"{path}: no vertices")
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise InputError(f"{path}: vertex {int(np.flatnonzero(bad)[0])} has a non-finite coordinate")
    if len(F) == 0:
        raise InputError(f"{path}: no faces")
    out = (F < 0) | (F >= len(V))
    if out.any():
        f = int(np.flatnonzero(out.any(axis=1))[0])
        v = int(F[f][out[f]][0])
        raise InputError(f"{path}: face {f} refers to vertex {v}, but there are {len(V)} vertices (0-based)")


def _parse_floats(path: Path, lines: list[str], what: str, width: int) -> np.ndarray:
    """Parse the first ``width`` numbers of each line into an (len(lines), width) array."""
    if not lines:
        return np.zeros((0, width))
    rows = [s.split() for s in lines]
    lengths = np.fromiter((len(r) for r in rows), dtype=np.int64, count=len(rows))
    try:
        if (lengths == width).all():
            return np.array([x for r in rows for x in r], dtype=np.float64).reshape(-1, width)
        short = np.flatnonzero(lengths < width)
        if len(short) and not (what == "vt" and lengths[short].min() >= 1):
            line, got = int(short[0]) + 1, int(lengths[short[0]])
            raise InputError(f"{path}: {what} line {line} has {got} numbers, expected {width}")
        return np.array([(r + ["0"] * width)[:width] for r in rows], dtype=np.float64)
    except ValueError as e:
        if isinstance(e, InputError):
            raise
        raise InputError(f"{path}: could not parse a {what} line ({e})") from None


_DIGIT_OR_BLANK = np.zeros(256, dtype=bool)
_DIGIT_OR_BLANK[[9, 10, 32, *range(48, 58)]] = True


def _read_plain_obj(path: Path, text: str, look: dict | None):
    """The common OBJ, read with whole-array NumPy passes instead of a Python loop over its
    lines (~0.19 s -> ~0.08 s for a 30,000-vertex, 60,000-triangle scan): ASCII, every line ``v x y z`` or
    ``v x y z r g b`` (all alike), ``f i j k`` (positive indices), a comment or blank. The
    same arrays as the general reader (the same strings converted by NumPy); None for any other
    file, which the general reader then reads (with its error messages)."""
    if not text.isascii() or any(c in text for c in "\r\v\f\x1c\x1d\x1e"):  # more line breaks for str.splitlines
        return None
    b = np.frombuffer((text if text.endswith("\n") else text + "\n").encode("ascii"), dtype=np.uint8)
    nl = b == 10
    ends = np.flatnonzero(nl)
    starts = np.concatenate([[0], ends[:-1] + 1])
    first = b[starts]
    second = b[np.minimum(starts + 1, len(b) - 1)]
    empty = starts == ends
    is_v = (first == ord("v")) & (second == 32) & ~empty
    is_f = (first == ord("f")) & (second == 32) & ~empty
    if not (is_v | is_f | empty | (first == ord("#"))).all() or not is_v.any() or not is_f.any():
        return None
    line = np.cumsum(nl) - nl  # line of each byte (its newline included)
    blank = nl | (b == 32) | (b == 9)
    tok = ~blank
    tok[1:] &= blank[:-1]  # first byte of each token
    count = np.bincount(line[tok], minlength=len(starts))  # tokens per line, the key included
    width = int(count[np.argmax(is_v)]) - 1
    if width not in (3, 6) or not (count[is_v] == width + 1).all() or not (count[is_f] == 4).all():
        return None
    body = np.ones(len(b), dtype=bool)
    body[starts] = False  # drop the keys
    in_v = is_v[line] & body
    in_f = is_f[line] & body
    f_bytes = b[in_f]
    if not _DIGIT_OR_BLANK[f_bytes].all():
        return None
    try:
        A = np.array(b[in_v].tobytes().decode("ascii").split(), dtype=np.float64).reshape(-1, width)
        vi = np.array(f_bytes.tobytes().decode("ascii").split(), dtype=np.int64)
    except (ValueError, OverflowError):
        return None
    V = np.ascontiguousarray(A[:, :3])
    if width == 6 and look is not None:
        look["colors"] = _as_unit_colors(np.ascontiguousarray(A[:, 3:]))
    poly = np.repeat(np.arange(len(vi) // 3), 3)
    vi = _resolve(path, vi, np.full(len(vi), len(V), dtype=np.int64), len(V), "vertex", poly)
    return V, vi.reshape(-1, 3), None


def _read_obj(path: Path, look: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror})") from None
    plain = _read_plain_obj(path, text, look)
    if plain is not None:
        return plain

    v_lines: list[str] = []
    vt_lines: list[str] = []
    f_lines: list[str] = []
    f_v_seen: list[int] = []  # vertices declared before each face (for negative indices)
    f_vt_seen: list[int] = []
    mtllibs: list[str] = []
    material = None
    for line in text.splitlines():
        if line.startswith("mtllib "):
            mtllibs.append(line[7:].strip())
            continue
        if line.startswith("usemtl ") and material is None:
            material = line[7:].strip()
            continue
        if not line or line[0] not in "vf \t":
            continue
        parts = line.split(None, 1)
        if not parts:
            continue
        key = parts[0]
        rest = parts[1] if len(parts) > 1 else ""
        if key == "v":
            v_lines.append(rest)
        elif key == "vt":
            vt_lines.append(rest)
        elif key == "f":
            f_lines.append(rest)
            f_v_seen.append(len(v_lines))
            f_vt_seen.append(len(vt_lines))

    V = _parse_floats(path, v_lines, "v", 3)
    VT = _parse_floats(path, vt_lines, "vt", 2)
    if look is not None and v_lines and all(len(r.split()) == 6 for r in v_lines[:1000]) and all(
            len(r.split()) == 6 for r in v_lines):
        look["colors"] = _as_unit_colors(_parse_floats(path, [r.split(None, 3)[3] for r in v_lines], "v colour", 3))
    if len(V) == 0:
        raise InputError(f"{path}: no vertices (not an OBJ file?)")
    if not f_lines:
        raise InputError(f"{path}: no faces")

    face_tokens = [s.split() for s in f_lines]
    counts = np.fromiter((len(t) for t in face_tokens), dtype=np.int64, count=len(face_tokens))
    if (counts < 3).any():
        p = int(np.flatnonzero(counts < 3)[0])
        raise InputError(f"{path}: face {p} has {int(counts[p])} vertices, expected at least 3")
    tokens = [t for ts in face_tokens for t in ts]
    try:
        if not any("/" in t for t in tokens):
            vi = np.array(tokens, dtype=np.int64)
            ti = None
        else:
            split = [t.split("/") for t in tokens]
            vi = np.array([s[0] for s in split], dtype=np.int64)
            if all(len(s) > 1 and s[1] for s in split):
                ti = np.array([s[1] for s in split], dtype=np.int64)
            else:
                ti = None
    except ValueError as e:
        raise InputError(f"{path}: could not parse a face line ({e})") from None

    poly = np.repeat(np.arange(len(counts)), counts)  # polygon of each corner
    vi = _resolve(path, vi, np.asarray(f_v_seen, np.int64)[poly], len(V), "vertex", poly)
    if ti is not None:
        ti = _resolve(path, ti, np.asarray(f_vt_seen, np.int64)[poly], len(VT), "texture coordinate", poly)

    # fan triangulation, triangles in polygon order
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ntri = counts - 2
    tri_poly = np.repeat(np.arange(len(counts)), ntri)
    local = np.arange(ntri.sum()) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1
    c0 = start[tri_poly]
    c1 = c0 + local
    corners = np.stack([c0, c1, c1 + 1], axis=1)
    F = vi[corners]

    uv = None
    if ti is not None and len(VT) and look is not None:
        look["corner_uv"] = VT[ti][corners]
        if mtllibs:
            look["texture"] = _read_mtl_texture(path, mtllibs, material)
    if ti is not None and len(VT):
        uv_v = np.zeros((len(V), 2))
        uv_v[vi] = VT[ti]
        if np.array_equal(uv_v[vi], VT[ti]):
            uv = uv_v
    return V, F, uv


def _resolve(path: Path, idx: np.ndarray, seen: np.ndarray, total: int, what: str, poly: np.ndarray) -> np.ndarray:
    """OBJ indices -> 0-based: positive ones are 1-based over the whole file, negative ones
    count back from the last element declared before the face."""
    out = np.where(idx > 0, idx - 1, seen + idx)
    bad = (idx == 0) | (out < 0) | (out >= total)
    if bad.any():
        c = int(np.flatnonzero(bad)[0])
        avail = f"{total} in the file" if idx[c] >= 0 else f"{int(seen[c])} declared before it"
        raise InputError(f"{path}: face {int(poly[c])} refers to {what} {int(idx[c])}, but there are {avail}")
    return out


def _read_trimesh(path: Path, look: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    import warnings

    import trimesh

    try:
        with warnings.catch_warnings():  # NumPy's cast warnings on a damaged file: its values are checked below
            warnings.simplefilter("ignore", RuntimeWarning)
            loaded = trimesh.load(str(path), process=False, force="mesh")
    except Exception as e:  # trimesh raises many types for bad files
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        if isinstance(e, ImportError):  # trimesh fell back to a text decoder it cannot import: not this format
            msg = f"the file is damaged or not a {path.suffix.lower()[1:].upper()} file"
        raise InputError(f"{path}: cannot read as {path.suffix.lower()[1:].upper()} ({msg})") from None
    if isinstance(loaded, trimesh.Scene):  # force="mesh" on an empty scene
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
        if not geoms:
            raise InputError(f"{path}: no faces")
        loaded = trimesh.util.concatenate(geoms)
    if not isinstance(loaded, trimesh.Trimesh):
        raise InputError(f"{path}: no faces (got a {type(loaded).__name__})")
    V = np.asarray(loaded.vertices, dtype=np.float64).reshape(-1, 3)
    F = np.asarray(loaded.faces, dtype=np.int64).reshape(-1, 3)
    if len(F) == 0:
        raise InputError(f"{path}: no faces")
    if path.suffix.lower() == ".ply":
        _check_ply_counts(path, len(V), len(F))
    visual = getattr(loaded, "visual", None)
    kind = getattr(visual, "kind", None) if visual is not None else None
    tuv = None  # per-vertex UVs of a textured mesh, read before the copies are merged
    if kind == "texture" and getattr(visual, "uv", None) is not None:
        tuv = np.asarray(visual.uv, dtype=np.float64)
        if tuv.shape != (len(V), 2):
            tuv = None
    vc = None
    if kind == "vertex" and look is not None:
        vc = np.asarray(visual.vertex_colors)
        if not (vc.ndim == 2 and vc.shape[0] == len(V) and vc.shape[1] >= 3):
            vc = None
    if tuv is not None and look is not None:
        # the UVs stay per corner (glTF splits its vertices along the UV seams; they are merged below)
        look["corner_uv"] = tuv[F]
        mat = getattr(visual, "material", None)
        img = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        look["texture"] = _image_rgb(img)
    merged = False
    if np.isfinite(V).all() and len(V) <= 3 * len(F) and ((F >= 0) & (F < len(V))).all():
        # STL stores three corners per triangle, never shared, and other exporters (trimesh's
        # own, GLB at UV seams) may write copies too: merge the copies of each vertex (kept in
        # order of first appearance), or triangles are islands (no normals, no curvature)
        _, first, inv = np.unique(V, axis=0, return_index=True, return_inverse=True)
        if len(first) < len(V):
            order = np.argsort(first)
            rank = np.empty_like(order)
            rank[order] = np.arange(len(order))
            keep = np.sort(first)
            V, F, merged = V[keep], rank[inv.reshape(-1)][F], True
            if vc is not None:
                vc = vc[keep]
    if vc is not None:
        look["colors"] = _as_unit_colors(vc[:, :3])
    uv = tuv.copy() if tuv is not None and not merged and look is None else None
    return V, F, uv


def _check_ply_counts(path: Path, vertex_count: int, face_count: int) -> None:
    """An ASCII PLY must hold as many data lines as its header's elements promise (trimesh reads
    face lines as vertices when the header promises too many)."""
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    end = head.find(b"end_header")
    if end < 0:
        raise InputError(f"{path}: PLY header has no end_header line")
    header = head[:end].decode("ascii", "replace").splitlines()
    if not any(line.strip().startswith("format ascii") for line in header):
        return  # binary: trimesh checks the length itself
    counts = {}
    for line in header:
        w = line.split()
        if len(w) == 3 and w[0] == "element":
            try:
                counts[w[1]] = int(w[2])
            except ValueError:
                raise InputError(f"{path}: PLY header line {line.strip()!r} has no element count") from None
    with open(path, "rb") as f:
        data = f.read()
    body = data[data.find(b"end_header") + len(b"end_header"):].split(b"\n", 1)[-1]
    lines = sum(1 for line in body.splitlines() if line.strip())
    promised = sum(counts.values())
    if lines != promised:
        what = ", ".join(f"{n} {k}" for k, n in counts.items())
        raise InputError(f"{path}: the PLY header promises {what} ({promised} lines) but the file holds {lines} "
                         "data lines (truncated or a wrong header)")
    if counts.get("vertex", vertex_count) != vertex_count or counts.get("face", face_count) < face_count:
        raise InputError(f"{path}: the PLY header promises {counts.get('vertex')} vertices and {counts.get('face')} "
                         f"faces, read {vertex_count} and {face_count}")


# ----------------------------------------------------------------------------------------
# report


def mesh_report(V, F) -> dict:
    """Topology and quality figures of a triangle mesh, for reporting (nothing fails).

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.

    Returns:
        A JSON-serialisable dict:

        - ``vertex_count``, ``face_count``, ``edge_count`` (undirected edges);
        - ``unreferenced_vertex_count``: vertices in no triangle;
        - ``degenerate_face_count``: triangles with area < 1e-14 m^2 (or a repeated vertex);
        - ``non_manifold_edge_count``: edges used by more than two triangles;
        - ``boundary_edge_count``: edges used by exactly one triangle;
        - ``boundary_loop_count``: closed loops of boundary edges, counted as the cycle rank
          ``E - V + C`` of the boundary-edge graph (a loop through a vertex twice, as at a
          bow-tie vertex, counts as two loops);
        - ``component_count``: connected components of triangles sharing vertices;
        - ``consistently_oriented``: every directed edge occurs at most once (neighbouring
          triangles list their shared edge in opposite directions);
        - ``bbox_min``, ``bbox_max``: bounding box corners [m], lists of 3 floats, over all
          vertices.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from .surface import _check_VF, face_areas

    V, F = _check_VF(V, F)
    n = len(V)
    report: dict = {"vertex_count": n, "face_count": len(F)}

    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    directed = directed[directed[:, 0] != directed[:, 1]]  # collapsed edges of degenerate faces
    undirected = np.sort(directed, axis=1)
    edges, edge_use = np.unique(undirected, axis=0, return_counts=True)
    report["edge_count"] = len(edges)

    referenced = np.zeros(n, dtype=bool)
    referenced[F.ravel()] = True
    report["unreferenced_vertex_count"] = int((~referenced).sum())

    repeated = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    report["degenerate_face_count"] = int(((face_areas(V, F) < DEGENERATE_AREA) | repeated).sum())
    report["non_manifold_edge_count"] = int((edge_use > 2).sum())

    boundary = edges[edge_use == 1]
    report["boundary_edge_count"] = len(boundary)
    if len(boundary):
        bv, inverse = np.unique(boundary.ravel(), return_inverse=True)
        inverse = inverse.reshape(-1, 2)
        g = coo_matrix((np.ones(len(boundary)), (inverse[:, 0], inverse[:, 1])), shape=(len(bv), len(bv)))
        c, _ = connected_components(g, directed=False)
        report["boundary_loop_count"] = int(len(boundary) - len(bv) + c)
    else:
        report["boundary_loop_count"] = 0

    if len(edges):
        g = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
        _, labels = connected_components(g, directed=False)
        report["component_count"] = len(np.unique(labels[referenced]))
    else:
        report["component_count"] = int(len(np.unique(F[:, 0]))) if len(F) else 0

    report["consistently_oriented"] = bool(len(np.unique(directed, axis=0)) == len(directed))
    if n:
        report["bbox_min"] = V.min(axis=0).tolist()
        report["bbox_max"] = V.max(axis=0).tolist()
    else:
        report["bbox_min"] = report["bbox_max"] = None
    return report


# ----------------------------------------------------------------------------------------
# writing


def save_obj(path: str | os.PathLike, V, F, *, uv=None, face_uv=None, units: str = "m", mtl: str | None = None,
             colors=None) -> None:
    """Write a triangle mesh as OBJ, atomically (temporary file, then rename).

    Args:
        path: Destination ``.obj`` file; its folder must exist.
        V: Vertex positions [m], shape (n, 3), float64; written divided by the unit.
        F: Triangles, shape (m, 3), int64 (0-based; written 1-based).
        uv: Optional texture coordinates, float64: per vertex, shape (n, 2), written as one
            ``vt`` per vertex, faces as ``f a/a b/b c/c``; or per corner with ``face_uv``.
        face_uv: Optional per triangle corner an index into ``uv``, shape (m, 3), int64 (UV
            seams: a vertex may take a different UV in each triangle); faces ``f a/i b/j c/k``.
        units: Unit of the written coordinates: "mm", "cm" or "m".
        mtl: Optional material library file name (beside the OBJ) with a material ``skin``:
            written as ``mtllib`` / ``usemtl`` lines.
        colors: Optional per-vertex colour, shape (n, 3), float in [0, 1]: ``v x y z r g b``.
    """
    from .surface import _check_VF

    from ..core.checks import check_array

    scale = unit_scale(units)
    V, F = _check_VF(V, F)
    check_array("V", V, shape=(None, 3))  # finite: an OBJ has no NaN
    if uv is not None:
        uv = np.asarray(uv, dtype=np.float64)
        if face_uv is None and uv.shape != (len(V), 2):
            raise InputError(f"uv must have shape ({len(V)}, 2), got {uv.shape}")
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise InputError(f"uv must have shape (k, 2), got {uv.shape}")
    if face_uv is not None:
        if uv is None:
            raise InputError("face_uv needs uv")
        face_uv = np.asarray(face_uv, dtype=np.int64)
        if face_uv.shape != F.shape or face_uv.min() < 0 or face_uv.max() >= len(uv):
            raise InputError(f"face_uv must have shape {F.shape} with indices into uv ({len(uv)}), got {face_uv.shape}")
    with atomic_write(path, "w") as f:
        f.write(f"# facewarp OBJ: {len(V)} vertices, {len(F)} triangles, units {units}\n")
        if mtl is not None:
            f.write(f"mtllib {mtl}\n")
        if colors is None:
            _write_rows(f, V / scale, "v %.10g %.10g %.10g")
        else:
            C = np.asarray(colors, dtype=np.float64)
            if C.shape != V.shape or not np.isfinite(C).all():
                raise ValueError(f"colors must have shape {V.shape} and be finite, got {C.shape}")
            _write_rows(f, np.hstack([V / scale, np.clip(C, 0.0, 1.0)]), "v %.10g %.10g %.10g %.5g %.5g %.5g")
        if uv is None:
            _write_rows(f, F + 1, "f %d %d %d")
        else:
            _write_rows(f, uv, "vt %.10g %.10g")
            if mtl is not None:
                f.write("usemtl skin\n")
            T = F if face_uv is None else face_uv
            G = np.stack([F + 1, T + 1], axis=2).reshape(len(F), 6)
            _write_rows(f, G, "f %d/%d %d/%d %d/%d")


def _write_rows(f, A: np.ndarray, fmt: str, chunk: int = 65536) -> None:
    """``np.savetxt(f, A, fmt=fmt)`` for a 2D array (one line ``fmt % row`` per row, the same
    text), formatted by one ``%`` per block of rows instead of one per row (3-7x faster)."""
    A = np.asarray(A)
    for start in range(0, len(A), chunk):
        block = A[start:start + chunk]
        f.write(((fmt + "\n") * len(block)) % tuple(block.ravel().tolist()))


def save_glb(path: str | os.PathLike, V, F, uv, face_uv, *, texture=None) -> None:
    """Write a textured triangle mesh as binary glTF (``.glb``, metres, +y up), atomically.

    glTF has one UV per vertex, so every vertex is split into one copy per distinct UV it takes
    (the seams of a per-corner layout).

    Args:
        path: Destination ``.glb`` file; its folder must exist.
        V: Vertex positions [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.
        uv: Texture coordinates, shape (k, 2), float64 (v up).
        face_uv: Per triangle corner an index into ``uv``, shape (m, 3), int64.
        texture: Optional base-colour image, shape (h, w, 3), uint8 (row 0 at v = 1), or a
            path of an image file; without it the material is a plain skin colour.
    """
    png = None
    if texture is not None:
        import io

        from PIL import Image

        img = Image.open(texture).convert("RGB") if isinstance(texture, (str, os.PathLike)) else \
            Image.fromarray(np.asarray(texture, dtype=np.uint8))
        with io.BytesIO() as buf:
            img.save(buf, format="png")
            png = buf.getvalue()
    _save_glb(path, V, F, uv, face_uv, png)


def _save_glb(path, V, F, uv, face_uv, png: bytes | None) -> None:
    """:func:`save_glb` with the texture already encoded as PNG (``png``: bytes of a PNG file
    whose pixels PIL's default PNG encoder turned into exactly these bytes; None: untextured)."""
    from .surface import _check_VF

    V, F = _check_VF(V, F)
    uv = np.asarray(uv, dtype=np.float64)
    face_uv = np.asarray(face_uv, dtype=np.int64)
    if face_uv.shape != F.shape or uv.ndim != 2 or uv.shape[1] != 2 or face_uv.min() < 0 or face_uv.max() >= len(uv):
        raise ValueError(f"uv (k, 2) and face_uv {F.shape} with indices into uv expected, got {uv.shape}, {face_uv.shape}")
    pairs, inverse = np.unique(np.stack([F.ravel(), face_uv.ravel()], 1), axis=0, return_inverse=True)
    data = _glb_bytes(V[pairs[:, 0]], inverse.reshape(-1, 3), uv[pairs[:, 1]], png)
    with atomic_write(path, "wb", encoding=None) as f:
        f.write(data)


_GLB_SKIN = [204, 158, 133, 255]  # the untextured material's base colour (RGBA, 0-255)


def _glb_bytes(V, F, uv, png: bytes | None = None) -> bytes:
    """Binary glTF of one mesh with per-vertex UVs: byte for byte what trimesh's exporter
    writes for ``trimesh.Trimesh(V, F, process=False, visual=TextureVisuals(uv, material))``
    with ``material = PBRMaterial(baseColorFactor=_GLB_SKIN)``, or with ``png`` (the texture
    encoded as PNG, as trimesh encodes a PIL image: ``save(format="png")``) ``PBRMaterial(
    baseColorTexture=..., metallicFactor=0.0, roughnessFactor=0.6)`` (trimesh 4-5; a test
    compares them). Written here in milliseconds without importing trimesh (save_glb took
    0.2-0.4 s of ``facewarp adapt``), and the texture is not encoded a second time.

    Layout: a JSON chunk (compact, padded with spaces to 4 bytes), then one BIN chunk holding
    the indices (uint32), the positions (float32), the PNG if any, and the UVs (float32, v
    flipped: glTF's v points down), each a buffer view padded to 4 bytes; accessors carry
    their min / max.
    """
    import json
    import struct

    idx = np.ascontiguousarray(F, dtype=np.uint32)
    pos = np.ascontiguousarray(V, dtype=np.float32)
    tc = np.array(uv, dtype=np.float64)[:, :2]
    tc[:, 1] = 1.0 - tc[:, 1]
    tc = np.ascontiguousarray(tc, dtype=np.float32)
    blobs = [idx.tobytes(), pos.tobytes()] + ([] if png is None else [bytes(png)]) + [tc.tobytes()]
    blobs = [b + bytes(-len(b) % 4) for b in blobs]
    accessors = [
        {"componentType": 5125, "type": "SCALAR", "bufferView": 0, "count": int(idx.size),
         "max": [int(idx.max())], "min": [int(idx.min())]},
        {"componentType": 5126, "type": "VEC3", "byteOffset": 0, "bufferView": 1, "count": len(pos),
         "max": pos.max(axis=0).tolist(), "min": pos.min(axis=0).tolist()},
        {"componentType": 5126, "type": "VEC2", "byteOffset": 0, "bufferView": len(blobs) - 1, "count": len(tc),
         "max": tc.max(axis=0).tolist(), "min": tc.min(axis=0).tolist()},
    ]
    views, at = [], 0
    for b in blobs:
        views.append({"buffer": 0, "byteOffset": at, "byteLength": len(b)})
        at += len(b)
    tree = {
        "scene": 0, "scenes": [{"nodes": [0]}],
        "asset": {"version": "2.0", "generator": "https://github.com/mikedh/trimesh"},
        "accessors": accessors,
        "meshes": [{"name": "geometry_0", "extras": {}, "primitives": [
            {"attributes": {"POSITION": 1, "TEXCOORD_0": 2}, "indices": 0, "mode": 4, "material": 0}]}],
    }
    if png is None:
        pbr = {"baseColorFactor": (np.array(_GLB_SKIN, np.uint8) / 255.0).tolist()}
    else:
        tree["images"] = [{"bufferView": 2, "mimeType": "image/png"}]
        tree["textures"] = [{"source": 0}]
        pbr = {"baseColorTexture": {"index": 0}, "roughnessFactor": 0.6, "metallicFactor": 0.0}
    tree.update({
        "materials": [{"pbrMetallicRoughness": pbr, "doubleSided": False}],
        "nodes": [{"name": "geometry_0", "mesh": 0}],
        "buffers": [{"byteLength": at}],
        "bufferViews": views,
    })
    content = json.dumps(tree, separators=(",", ":"))
    content = (content + (4 - (len(content) + 20) % 4) * " ").encode("utf-8")
    head = struct.pack("<5I", 0x46546C67, 2, len(content) + at + 28, len(content), 0x4E4F534A)
    return b"".join([head, content, struct.pack("<2I", at, 0x004E4942), *blobs])


# ----------------------------------------------------------------------------------------
# points on a surface


@dataclass
class SurfacePoints:
    """Points stored on a triangle mesh as (face, barycentric weights).

    They follow the surface when it deforms (same topology): :meth:`positions` evaluates
    them on any vertex positions.

    Attributes:
        face: Triangle index of each point, shape (k,), int64.
        bary: Barycentric weights for ``F[face]``'s three vertices in that order, summing to
            1, shape (k, 3), float64 (dimensionless).
    """

    face: np.ndarray
    bary: np.ndarray

    def __post_init__(self):
        from ..core.checks import check_array

        self.face = check_array("face", np.reshape(self.face, -1) if np.ndim(self.face) == 0 else self.face,
                                shape=(None,), kind="i")
        self.bary = check_array("bary", self.bary, shape=(None, 3) if np.ndim(self.bary) == 2 else (3,))
        self.bary = self.bary.reshape(-1, 3)
        if len(self.face) != len(self.bary):
            raise InputError(f"face and bary must have the same length, got {len(self.face)} and {len(self.bary)}")

    def __len__(self) -> int:
        return len(self.face)

    def positions(self, V, F) -> np.ndarray:
        """Positions of the points on the mesh (V, F).

        Args:
            V: Vertex positions [m], shape (n, 3), float64.
            F: Triangles, shape (m, 3), int64.

        Returns:
            Positions [m], shape (k, 3), float64.
        """
        V = np.asarray(V, dtype=np.float64)
        F = np.asarray(F, dtype=np.int64)
        if len(self.face) and (self.face.min() < 0 or self.face.max() >= len(F)):
            raise ValueError(f"face indices {self.face.min()}..{self.face.max()} out of range for {len(F)} faces")
        return np.einsum("kc,kcd->kd", self.bary, V[F[self.face]])

    def to_dict(self) -> dict:
        """Plain dict ``{"face": [int, ...], "bary": [[w0, w1, w2], ...]}`` (JSON-ready)."""
        return {"face": self.face.tolist(), "bary": self.bary.tolist()}

    @classmethod
    def from_dict(cls, d, *, source: str = "surface points") -> SurfacePoints:
        """Inverse of :meth:`to_dict`.

        Args:
            d: ``{"face": [...], "bary": [[w0, w1, w2], ...]}``.
            source: Name of the input for error messages (e.g. the file path).

        Raises:
            InputError: Missing keys, wrong shapes, non-integer faces, negative faces, or
                non-finite weights.
        """
        if not isinstance(d, dict) or "face" not in d or "bary" not in d:
            raise InputError(f"{source}: expected an object with 'face' and 'bary'")
        try:
            face_raw = np.asarray(d["face"])
            bary = np.asarray(d["bary"], dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"{source}: 'face' must be integers and 'bary' rows of 3 numbers") from None
        if face_raw.ndim != 1 or (face_raw.size and not np.issubdtype(face_raw.dtype, np.integer)):
            raise InputError(f"{source}: 'face' must be a list of integers")
        if bary.shape != (len(face_raw), 3):
            raise InputError(f"{source}: 'bary' must have shape ({len(face_raw)}, 3), got {bary.shape}")
        if face_raw.size and face_raw.min() < 0:
            raise InputError(f"{source}: face index {int(face_raw.min())} is negative")
        if not np.isfinite(bary).all():
            raise InputError(f"{source}: 'bary' has a non-finite weight")
        return cls(face=face_raw.astype(np.int64), bary=bary)


def closest_surface_points(V, F, P, *, device: str = "cpu") -> SurfacePoints:
    """Project points onto the mesh: the closest surface point of each (see geometry.closest_point).

    Args:
        V: Vertex positions [m], shape (n, 3), float64.
        F: Triangles, shape (m, 3), int64.
        P: Points [m], shape (k, 3), float64.
        device: Warp device for the BVH query.

    Returns:
        :class:`SurfacePoints` of the k closest points.
    """
    from .surface import closest_point

    res = closest_point(V, F, P, device=device)
    if (res.face < 0).any():  # only possible if every face is degenerate
        raise ValueError("no closest point found (all triangles degenerate?)")
    return SurfacePoints(face=res.face, bary=res.bary)
