"""Streaming USD animation writer (see the package docstring for the stage layout and conventions).

How frames reach the disk with bounded memory (measured by benchmarks/usd_write.py)
-----------------------------------------------------------------------------------
An Sdf layer keeps every authored time sample in memory until it is saved: ~245 KiB per frame for
a 10,242-vertex head (points + normals), ~700 MiB for 3,000 frames. For a crate (``.usdc``) layer,
``SdfLayer::Save`` appends the new data to the file and from then on serves the saved values
zero-copy from the memory-mapped file. So the writer saves its working layer whenever
``flush_bytes`` (default 32 MiB) of new samples are pending, and its own (anonymous) memory stays
flat however long the take: with the 10k head, 4 parts and 27 muscles, RssAnon peaks ~34 MiB above
the start in both the first and the second half of a 3,000-frame take, and ~38 MiB including
``close()``, for every format; only clean, reclaimable file pages (RssFile) grow with the take.
Each format is therefore streamed into one working ``.usdc`` in a private temporary folder beside
the target, and ``close()`` turns it into the deliverable, always one self-contained file:

* ``.usdc``: the working file itself, renamed.
* ``.usda``: ``SdfLayer::Export`` of the working layer; the text writer reads the samples from the
  mapped file (3,000 frames: +12 MiB RssAnon during the export, 27 s, 2.4 GB of text).
* ``.usdz``: ``UsdUtils.CreateNewUsdzPackage`` stores the working ``.usdc`` (uncompressed,
  64-byte aligned) in the package, streaming from the file (3,000 frames: 3.5 s).

Value clips are therefore not needed: outputs carry none (one file, readable by every USD
consumer, nothing to keep next to it). The price of appending is that every save re-writes the
sample tables (~100 bytes per frame written so far), so the file grows by ~1 % at 10,000 frames of
the 10k head with the default ``flush_bytes`` (245.4 against 243.1 KiB per frame at 3,000 frames),
a fraction that grows linearly with the take (a larger ``flush_bytes`` lowers it). If the process is killed
(SIGKILL, power loss) the hidden ``.<name>.*.tmp`` folder beside the target is left behind.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._arrays import UsdExportError, VertexNormals, extent, float_array, index_array, row_vector_matrix, vertex_normals
from ._pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdLux, UsdShade, UsdUtils, Vt

FORMATS = (".usda", ".usdc", ".usdz")
FLUSH_BYTES = 32 * 2**20  # default: append pending samples to the working file once this many bytes are pending
_SNAP = 1e-4  # time codes this close to an integer (in frames) are snapped to it

# Stage layout below the default prim (read_animation relies on these names).
SKIN, PARTS, MUSCLES, TISSUE, LOOKS = "Skin", "Parts", "Muscles", "Tissue", "Looks"
ROOT = "/Head"
# facewarp's one palette (``facewarp._src.present.looks.COLORS``, linear RGB; a test keeps them equal):
_SKIN_COLOR = (0.87, 0.72, 0.62)  # skin
_WHITE_COLOR = (0.94, 0.93, 0.89)  # sclera: parts without a colour of their own
KEY_INTENSITY = 1.0  # the key DistantLight's irradiance, normalized (inputs:normalize = true)
FILL_INTENSITY = 0.25  # the fill DomeLight's radiance
_RELAXED, _ACTIVE = np.array([0.35, 0.05, 0.05], np.float32), np.array([1.0, 0.85, 0.2], np.float32)


def check_path(path, *, allowed=FORMATS) -> Path:
    """``path`` as a Path whose extension is one of ``allowed``, else :class:`UsdExportError`."""
    p = Path(path)
    if p.suffix.lower() not in allowed:
        raise UsdExportError(f"path: {str(p)!r} has extension {p.suffix!r}; expected one of {', '.join(allowed)}")
    return p


def prim_name(name: str) -> str:
    """A valid USD prim name from ``name`` (other characters become ``_``; a leading digit gets ``_``)."""
    s = "".join(c if (c.isascii() and c.isalnum()) or c == "_" else "_" for c in str(name))
    return s if s and not s[0].isdigit() else f"_{s}"


def part_prim_name(name: str) -> str:
    """The prim name of a rigid part: :func:`prim_name` with each ``_``-separated word capitalised
    (``eye_L`` -> ``Eye_L``, ``teeth_upper`` -> ``Teeth_Upper``, ``tongue`` -> ``Tongue``), the
    name DCC tools (Blender, Maya) give the object they import from the part's Mesh prim."""
    return "_".join(w[:1].upper() + w[1:] for w in prim_name(name).split("_"))


class AnimationWriter:
    """Write an animated head to one ``.usda``, ``.usdc`` or ``.usdz`` file, frame by frame.

    Use as a context manager; the file appears at ``path`` only when the block ends without an
    exception (an exception, KeyboardInterrupt included, leaves neither the file nor temporaries)::

        with AnimationWriter("take.usdc", fps=30, faces=F, rest_points=V) as w:
            for k, P in enumerate(frames):
                w.add_frame(k / 30, P)

    Args:
        path: Output file; ``.usda`` (text), ``.usdc`` (binary) or ``.usdz`` (package). Written
            in a temporary folder beside it and renamed at :meth:`close`.
        fps: Frames per second (> 0); the stage's ``timeCodesPerSecond`` and ``framesPerSecond``.
            Time code = ``time_s * fps`` (the frame index for frames at ``k / fps``).
        faces: F (m, 3) int triangles of the head, counter-clockwise seen from outside.
        rest_points: V (n, 3) float rest positions of the head [scene units, metres by default].
        uv: Optional texture coordinates, written as ``primvars:st``: (n, 2) float per vertex, or
            (k, 2) float with ``uv_indices`` (m, 3) int (face-varying, indexed).
        uv_indices: (m, 3) int, index into ``uv`` per face corner; only with ``uv``.
        parts: name -> (V (k, 3) float rest positions, F (l, 3) int) rigid parts (eyes, teeth,
            tongue, mandible, ...): an ``Xform`` with a child ``Mesh`` at rest, moved by
            ``part_transforms`` in :meth:`add_frame`.
        muscles: Muscle names, one linear ``BasisCurves`` curve each.
        muscle_samples: Points per muscle curve (>= 2); required with ``muscles``.
        muscle_rest: Optional (M, muscle_samples, 3) float rest polylines (the curves' default
            points); without it the curves have points only at frames that give ``muscle_points``.
        muscle_width: Curve width for display [scene units] (> 0); default 2 mm.
        tets: Optional (T (k, 4) int, rest nodes (p, 3) float): a ``TetMesh`` (purpose ``guide``,
            hidden in viewports by default) animated by ``tet_points``. Rest tets must not be
            inverted: ``(x1 - x0) . ((x2 - x0) x (x3 - x0)) >= 0`` (facewarp's convention), for which
            USD's ``rightHanded`` surface faces point outwards.
        up_axis: ``"Y"`` or ``"Z"``, the stage's ``upAxis`` (coordinates are not rotated).
        meters_per_unit: The stage's ``metersPerUnit`` (> 0): the length unit of all coordinates
            you pass (values are not rescaled).
        flush_bytes: Memory bound: once this many bytes of new samples are pending they are
            appended to the working file and released (default 32 MiB, ~130 frames of a
            10k-vertex head). Smaller saves memory; larger writes less metadata (each flush
            re-appends the sample tables, ~100 bytes per frame written so far).
        part_colors: Optional part name -> RGB (3,) float in 0..1: the part's own material
            ``Looks/<PartPrimName>`` (a ``UsdPreviewSurface`` of that diffuse colour) instead of the
            default white (tongue: skin).
        subsets: Optional mesh -> {subset name: (face indices (k,) int, RGB (3,) float)}, the mesh
            ``"Skin"`` or a part name: ``GeomSubset`` s (family ``materialBind``) of those faces
            bound to a material ``Looks/<subset name>`` of that colour (lips on the skin, iris and
            pupil on an eye), and a subset ``Rest`` of the other faces bound to the mesh's own
            material (a partition). One name, one colour. With ``skin_texture`` the skin's subsets
            are bound to the texture's material too (the person's own lip colour, as the package's
            renders show it; Blender gives each subset a material slot, so a tint would hide it).
        camera: Optional ``{"position": (3,), "target": (3,), "up": (3,)}`` [scene units] and
            optionally ``"focal_length_mm"`` (default 50): a ``Camera`` ``/Camera`` beside the head
            looking from ``position`` at ``target``, so the file opens framed.
        lights: Add ``/Lights`` beside the head: a key ``DistantLight`` from the camera's side
            (from +z without a camera) and a dim ``DomeLight``.
        skin_texture: Optional colour texture of the skin (a ``.png`` / ``.jpg`` file; needs
            ``uv``): copied beside the file as ``<stem>_skin.png`` (inside a ``.usdz``) and bound
            to the skin as ``Looks/SkinTexture`` (UsdPreviewSurface <- UsdUVTexture <-
            UsdPrimvarReader_float2 of ``st``).

    Raises:
        UsdExportError: a bad path extension or argument (one-line message naming it).
    """

    def __init__(self, path, *, fps: float, faces, rest_points, uv=None, uv_indices=None, parts: dict | None = None,
                 muscles=(), muscle_samples: int | None = None, muscle_rest=None, muscle_width: float | None = None,
                 tets=None, up_axis: str = "Y", meters_per_unit: float = 1.0, flush_bytes: int = FLUSH_BYTES,
                 part_colors: dict | None = None, subsets: dict | None = None, camera: dict | None = None,
                 lights: bool = False, skin_texture=None):
        self.path = check_path(path)
        if self.path.is_dir():
            raise UsdExportError(f"path: {str(self.path)!r} is a folder; expected a file name")
        if not self.path.parent.is_dir():
            raise UsdExportError(f"path: folder {str(self.path.parent)!r} does not exist")
        self.fps = _positive("fps", fps)
        self._flush_bytes = _positive("flush_bytes", flush_bytes)
        spec = _check_spec(faces, rest_points, uv, uv_indices, parts, muscles, muscle_samples, muscle_rest,
                           muscle_width, tets, up_axis, _positive("meters_per_unit", meters_per_unit))
        self._texture = _check_texture(skin_texture, spec, self.path)
        self._spec = spec
        looks = _check_looks(spec, part_colors, subsets, camera)
        self._frame_count, self._first_code, self._last_code = 0, 0.0, -math.inf
        self._pending_bytes = 0
        self._tmpdir = Path(tempfile.mkdtemp(dir=self.path.parent, prefix=f".{self.path.name}.", suffix=".tmp"))
        self._cleanup = weakref.finalize(self, shutil.rmtree, str(self._tmpdir), True)
        try:
            self._layer = _build_stage(self._tmpdir / "work.usdc", spec, self.fps,
                                       None if self._texture is None else self._texture[1])
            _dress_stage(self._layer, spec, looks, lights=bool(lights))
        except BaseException:
            self._cleanup()
            raise
        self._closed = False

    # ------------------------------------------------------------------ public
    @property
    def frame_count(self) -> int:
        """Frames added so far."""
        return self._frame_count

    def add_frame(self, time_s: float, points, *, part_transforms: dict | None = None, muscle_points=None,
                  activations=None, tet_points=None) -> None:
        """Append one frame at ``time_s`` [s] (strictly after the previous frame).

        Args:
            time_s: Frame time [s]; its time code is ``time_s * fps`` (snapped to the nearest
                integer when within 1e-4 frames of it).
            points: (n, 3) float head vertex positions. Normals (area-weighted) and extent
                are computed and written with them.
            part_transforms: Optional name -> 4x4 float rest-to-current transform of a rigid part,
                in USD's row-vector convention: ``p' = p @ M``, rotation in ``M[:3, :3]``,
                translation in ``M[3, :3]``, last column ``(0, 0, 0, 1)``. (A column-vector matrix
                ``p' = M @ p`` must be transposed: pass ``M.T``.) Parts left out keep their
                previous sample (USD holds/interpolates between authored samples).
            muscle_points: Optional (M, muscle_samples, 3) float muscle polylines.
            activations: Optional (M,) float muscle activations (nominally 0..1), written as the
                per-curve ``primvars:activation`` and a dark-red-to-yellow ``displayColor``.
            tet_points: Optional (p, 3) float tet-mesh node positions (needs ``tets``).
        """
        if self._closed:
            raise UsdExportError("add_frame: the writer is closed")
        code = self._time_code(time_s)
        s = self._spec
        samples = _frame_samples(s, float_array("points", points, (s.vertex_count, 3)),
                                 self._checked_parts(part_transforms), muscle_points, activations, tet_points)
        layer = self._layer
        with Sdf.ChangeBlock():
            for attr_path, value in samples:
                layer.SetTimeSample(attr_path, code, value)
        if not self._frame_count:
            self._first_code = code
        self._last_code = code
        self._frame_count += 1
        self._pending_bytes += s.frame_bytes
        if self._pending_bytes >= self._flush_bytes:
            layer.Save()
            self._pending_bytes = 0

    def close(self) -> Path:
        """Finish the file and move it to ``path`` (atomically replacing any file there); returns ``path``.

        Closing twice is harmless. On failure nothing is left at ``path`` or beside it.
        """
        if self._closed:
            return self.path
        try:
            out = self._finish()
            if self._texture is not None and self.path.suffix.lower() != ".usdz":
                # the texture beside the file, under the name the material's asset path gives
                shutil.copyfile(self._texture[0], self._tmpdir / "texture.tmp")
                os.replace(self._tmpdir / "texture.tmp", self.path.parent / self._texture[1])
            os.replace(out, self.path)
        finally:
            self._layer = None
            self._closed = True
            self._cleanup()
        return self.path

    def abort(self) -> None:
        """Drop everything written so far: no file at ``path``, no temporaries. Idempotent."""
        self._layer = None
        self._closed = True
        self._cleanup()

    def __enter__(self) -> AnimationWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    # ------------------------------------------------------------------ private
    def _time_code(self, time_s) -> float:
        t = np.asarray(time_s)
        if t.ndim != 0 or not (np.issubdtype(t.dtype, np.floating) or np.issubdtype(t.dtype, np.integer)):
            raise UsdExportError(f"time_s: expected a real number, got {time_s!r}")
        t = float(t)
        if not math.isfinite(t):
            raise UsdExportError(f"time_s: expected a finite time, got {t}")
        code = t * self.fps
        if abs(code - round(code)) < _SNAP:
            code = float(round(code))
        if code <= self._last_code:
            raise UsdExportError(f"time_s: expected a time after the previous frame's "
                                 f"{self._last_code / self.fps:.6g} s, got {t:.6g} s")
        return code

    def _checked_parts(self, part_transforms) -> dict:
        if not part_transforms:
            return {}
        out = {}
        for name, M in part_transforms.items():
            if name not in self._spec.part_paths:
                raise UsdExportError(f"part_transforms: unknown part {name!r}; "
                                     f"parts are {sorted(self._spec.part_paths)}")
            out[name] = row_vector_matrix(f"part_transforms[{name!r}]", M)
        return out

    def _finish(self) -> Path:
        layer = self._layer
        if self._frame_count:
            layer.startTimeCode, layer.endTimeCode = self._first_code, self._last_code
        else:
            layer.startTimeCode = layer.endTimeCode = 0.0
        layer.Save()
        work = Path(layer.realPath)
        self._layer = layer = None  # release the layer (and its file mapping) before converting/renaming
        suffix = self.path.suffix.lower()
        if suffix == ".usdc":
            return work
        out = self._tmpdir / f"out{suffix}"
        if suffix == ".usda":
            if not Sdf.Layer.OpenAsAnonymous(str(work)).Export(str(out)):
                raise UsdExportError(f"path: could not write {str(self.path)!r} as text USD")
        else:
            inner = self._tmpdir / f"{prim_name(self.path.stem)}.usdc"  # the layer's name inside the package
            os.replace(work, inner)
            if self._texture is not None:  # packaged beside the layer, as its asset path says
                shutil.copyfile(self._texture[0], self._tmpdir / self._texture[1])
            if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(inner)), str(out), inner.name):
                raise UsdExportError(f"path: could not package {str(self.path)!r} as usdz")
        return out


# ============================================================================ checked inputs
def _positive(name: str, x) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise UsdExportError(f"{name}: expected a positive number, got {x!r}") from None
    if not (v > 0 and math.isfinite(v)):
        raise UsdExportError(f"{name}: expected a positive finite number, got {x!r}")
    return v


@dataclass(frozen=True)
class _Spec:
    """Checked writer inputs (lengths in scene units) and per-frame constants."""

    rest: np.ndarray  #: Head rest positions, shape (n, 3), float32.
    faces: np.ndarray  #: Head triangles, shape (m, 3), int32.
    normals: VertexNormals  #: Area-weighted vertex normals of ``faces``, called per frame.
    uv: np.ndarray | None  #: Texture coordinates, shape (n, 2) or (k, 2), float32.
    uv_indices: np.ndarray | None  #: Face-varying uv indices, shape (m, 3), int32.
    parts: dict  #: name -> (rest positions (k, 3) float32, triangles (l, 3) int32).
    part_paths: dict  #: name -> Sdf.Path of the part's Xform.
    part_ops: dict  #: name -> Sdf.Path of the part's ``xformOp:transform``.
    muscle_names: list  #: M muscle names.
    muscle_samples: int | None  #: Points per muscle curve, s.
    muscle_rest: np.ndarray | None  #: Muscle rest polylines, shape (M, s, 3), float32.
    muscle_width: float  #: Curve width.
    tets: np.ndarray | None  #: Tetrahedra, shape (k, 4), int32.
    tet_rest: np.ndarray | None  #: Tet-mesh rest nodes, shape (p, 3), float32.
    up_axis: str  #: "Y" or "Z".
    meters_per_unit: float  #: Metres per scene unit.

    @property
    def vertex_count(self) -> int:
        return len(self.rest)

    @property
    def frame_bytes(self) -> int:
        """Bytes of time samples one frame adds (points, normals, curve and tet points, matrices)."""
        M = len(self.muscle_names)
        nodes = 0 if self.tet_rest is None else len(self.tet_rest)
        vec3 = 2 * self.vertex_count + M * (self.muscle_samples or 0) + nodes
        return 12 * vec3 + 128 * len(self.parts) + 16 * M + 64


def _check_spec(faces, rest_points, uv, uv_indices, parts, muscles, muscle_samples, muscle_rest, muscle_width, tets,
                up_axis, meters_per_unit) -> _Spec:
    rest = float_array("rest_points", rest_points, (None, 3))
    n = len(rest)
    if n == 0:
        raise UsdExportError("rest_points: expected at least one vertex, got shape (0, 3)")
    F = index_array("faces", faces, (None, 3), upper=n)
    if len(F) == 0:
        raise UsdExportError("faces: expected at least one triangle, got shape (0, 3)")
    st, st_indices = _check_uv(uv, uv_indices, n, len(F))
    part_meshes, part_paths = _check_parts(parts)
    names, samples, curves_rest = _check_muscles(muscles, muscle_samples, muscle_rest)
    width = _positive("muscle_width", 0.002 / meters_per_unit if muscle_width is None else muscle_width)
    T, nodes = _check_tets(tets)
    if up_axis not in ("Y", "Z"):
        raise UsdExportError(f"up_axis: expected 'Y' or 'Z', got {up_axis!r}")
    return _Spec(rest=rest, faces=F, normals=VertexNormals(F, n), uv=st, uv_indices=st_indices, parts=part_meshes,
                 part_paths=part_paths,
                 part_ops={k: p.AppendProperty("xformOp:transform") for k, p in part_paths.items()},
                 muscle_names=names, muscle_samples=samples, muscle_rest=curves_rest, muscle_width=width, tets=T,
                 tet_rest=nodes, up_axis=up_axis, meters_per_unit=meters_per_unit)


def _check_uv(uv, uv_indices, n: int, m: int):
    if uv is None:
        if uv_indices is not None:
            raise UsdExportError("uv_indices: given without uv")
        return None, None
    if uv_indices is None:
        return float_array("uv", uv, (n, 2)), None
    st = float_array("uv", uv, (None, 2))
    return st, index_array("uv_indices", uv_indices, (m, 3), upper=len(st))


def _check_parts(parts):
    out, paths = {}, {}
    for name, value in (parts or {}).items():
        if not (isinstance(value, (tuple, list)) and len(value) == 2):
            raise UsdExportError(f"parts[{name!r}]: expected a pair (V (k, 3), F (l, 3))")
        V = float_array(f"parts[{name!r}] V", value[0], (None, 3))
        F = index_array(f"parts[{name!r}] F", value[1], (None, 3), upper=len(V))
        if len(V) == 0 or len(F) == 0:
            raise UsdExportError(f"parts[{name!r}]: expected a non-empty mesh, got {len(V)} vertices, {len(F)} faces")
        pname = part_prim_name(name)
        clash = [k for k, p in paths.items() if p.name == pname]
        if clash:
            raise UsdExportError(f"parts: names {clash[0]!r} and {name!r} map to the same prim name {pname!r}")
        out[name] = (V, F)
        paths[name] = Sdf.Path(f"{ROOT}/{PARTS}/{pname}")
    return out, paths


def _check_muscles(muscles, muscle_samples, muscle_rest):
    names = [str(m) for m in (muscles or ())]
    if not names:
        if muscle_rest is not None:
            raise UsdExportError("muscle_rest: given without muscles")
        return [], None, None
    if len(set(names)) != len(names):
        dup = next(x for x in names if names.count(x) > 1)
        raise UsdExportError(f"muscles: duplicate name {dup!r}")
    if not isinstance(muscle_samples, (int, np.integer)) or isinstance(muscle_samples, bool) or muscle_samples < 2:
        raise UsdExportError(f"muscle_samples: expected an integer >= 2 with muscles, got {muscle_samples!r}")
    s = int(muscle_samples)
    rest = None if muscle_rest is None else float_array("muscle_rest", muscle_rest, (len(names), s, 3))
    return names, s, rest


def _check_tets(tets):
    if tets is None:
        return None, None
    if not (isinstance(tets, (tuple, list)) and len(tets) == 2):
        raise UsdExportError("tets: expected a pair (T (k, 4) int, rest nodes (p, 3) float)")
    if not hasattr(UsdGeom, "TetMesh"):  # pragma: no cover - usd-core < 24.03
        raise UsdExportError(f"tets: UsdGeom.TetMesh needs usd-core >= 24.03 (this is {Usd.GetVersion()}); "
                             "pip install -U usd-core, or leave tets out")
    nodes = float_array("tets nodes", tets[1], (None, 3))
    T = index_array("tets T", tets[0], (None, 4), upper=len(nodes))
    if len(T) == 0:
        raise UsdExportError("tets T: expected at least one tetrahedron, got shape (0, 4)")
    x0, x1, x2, x3 = (nodes[T[:, c]].astype(np.float64) for c in range(4))
    vol = np.einsum("ij,ij->i", x1 - x0, np.cross(x2 - x0, x3 - x0)) / 6.0
    if (vol < 0).any():
        k = int(np.argmin(vol))
        raise UsdExportError(f"tets T: tet {k} {T[k].tolist()} is inverted at rest (signed volume {vol[k]:.3g}); "
                             "expected (x1 - x0) . ((x2 - x0) x (x3 - x0)) >= 0")
    return T, nodes


# ============================================================================ per frame
_SKIN_POINTS, _SKIN_NORMALS, _SKIN_EXTENT = (Sdf.Path(f"{ROOT}/{SKIN}.{a}") for a in ("points", "normals", "extent"))
_MUSCLE_POINTS, _MUSCLE_EXTENT, _MUSCLE_ACTIVATION, _MUSCLE_COLOR = (
    Sdf.Path(f"{ROOT}/{MUSCLES}.{a}") for a in ("points", "extent", "primvars:activation", "primvars:displayColor"))
_TET_POINTS, _TET_EXTENT = (Sdf.Path(f"{ROOT}/{TISSUE}.{a}") for a in ("points", "extent"))


def _frame_samples(s: _Spec, P, part_M: dict, muscle_points, activations, tet_points) -> list:
    """(attribute path, Vt/Gf value) pairs of one frame; inputs other than ``P`` still unchecked."""
    out = [(_SKIN_POINTS, Vt.Vec3fArray.FromNumpy(P)), (_SKIN_NORMALS, Vt.Vec3fArray.FromNumpy(s.normals(P))),
           (_SKIN_EXTENT, Vt.Vec3fArray.FromNumpy(extent(P)))]
    for name, M in part_M.items():
        out.append((s.part_ops[name], Gf.Matrix4d(M.tolist())))
    n_muscles = len(s.muscle_names)
    if muscle_points is not None:
        if not n_muscles:
            raise UsdExportError("muscle_points: the writer has no muscles")
        C = float_array("muscle_points", muscle_points, (n_muscles, s.muscle_samples, 3)).reshape(-1, 3)
        out += [(_MUSCLE_POINTS, Vt.Vec3fArray.FromNumpy(C)),
                (_MUSCLE_EXTENT, Vt.Vec3fArray.FromNumpy(extent(C, s.muscle_width / 2)))]
    if activations is not None:
        if not n_muscles:
            raise UsdExportError("activations: the writer has no muscles")
        a = float_array("activations", activations, (n_muscles,))
        out += [(_MUSCLE_ACTIVATION, Vt.FloatArray.FromNumpy(a)), (_MUSCLE_COLOR, Vt.Vec3fArray.FromNumpy(_heat(a)))]
    if tet_points is not None:
        if s.tets is None:
            raise UsdExportError("tet_points: the writer has no tets")
        X = float_array("tet_points", tet_points, (len(s.tet_rest), 3))
        out += [(_TET_POINTS, Vt.Vec3fArray.FromNumpy(X)), (_TET_EXTENT, Vt.Vec3fArray.FromNumpy(extent(X)))]
    return out


def _heat(a: np.ndarray) -> np.ndarray:
    """(M, 3) float32 display colours: dark red at activation 0 to yellow at 1 (clamped)."""
    t = np.clip(a, 0.0, 1.0)[:, None]
    return np.ascontiguousarray(_RELAXED + t * (_ACTIVE - _RELAXED), dtype=np.float32)


# ============================================================================ static stage
def _build_stage(work: Path, s: _Spec, fps: float, texture_name: str | None = None):
    """Author everything but the time samples into a new crate layer at ``work``; returns the layer."""
    layer = Sdf.Layer.CreateNew(str(work))
    if layer is None:  # pragma: no cover - USD reports the reason as a warning
        raise UsdExportError(f"path: could not create a USD layer in {str(work.parent)!r}")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if s.up_axis == "Y" else UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, s.meters_per_unit)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    head = UsdGeom.Xform.Define(stage, ROOT)
    stage.SetDefaultPrim(head.GetPrim())
    Usd.ModelAPI(head).SetKind(Kind.Tokens.component)
    UsdGeom.Scope.Define(stage, f"{ROOT}/{LOOKS}")
    skin_mat = _preview_material(stage, f"{ROOT}/{LOOKS}/Skin", _SKIN_COLOR, roughness=0.55)
    white_mat = _preview_material(stage, f"{ROOT}/{LOOKS}/White", _WHITE_COLOR, roughness=0.3)
    skin = _mesh(stage, f"{ROOT}/{SKIN}", s.rest, s.faces, skin_mat)
    if s.uv is not None:
        _uv_primvar(skin, s.uv, s.uv_indices)
    if texture_name is not None:
        _bind_skin_texture(stage, skin, texture_name)
    if s.parts:
        _parts(stage, s, skin_mat, white_mat)
    if s.muscle_names:
        _muscles(stage, s)
    if s.tets is not None:
        _tet_mesh(stage, s)
    layer.Save()
    return layer


def _preview_material(stage, path: str, color, *, roughness: float):
    mat = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return mat


def _mesh(stage, path, V: np.ndarray, F: np.ndarray, material):
    """A triangle mesh at rest: topology, points, vertex normals, extent, no subdivision, a material."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(F), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(F.ravel()))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(V))
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(vertex_normals(V, F)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(extent(V)))
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def _parts(stage, s: _Spec, skin_mat, white_mat) -> None:
    """Each rigid part: its rest Mesh, named after the part (:func:`part_prim_name`, so an importer
    names the object so), with an identity ``xformOp:transform`` animated per frame."""
    UsdGeom.Scope.Define(stage, f"{ROOT}/{PARTS}")
    for name, (V, F) in s.parts.items():
        material = skin_mat if "tongue" in str(name).lower() else white_mat
        mesh = _mesh(stage, s.part_paths[name], V, F, material)
        mesh.AddTransformOp().Set(Gf.Matrix4d(1.0))
        if s.part_paths[name].name != name:
            mesh.GetPrim().SetDisplayName(str(name))  # the part's own name, read back by read_animation


def _check_texture(skin_texture, s: _Spec, path: Path):
    """(source PNG/JPEG path, file name beside the USD) of the skin texture, or None."""
    if skin_texture is None:
        return None
    src = Path(skin_texture)
    if src.suffix.lower() not in (".png", ".jpg", ".jpeg") or not src.is_file():
        raise UsdExportError(f"skin_texture: expected an existing .png or .jpg file, got {str(src)!r}")
    if s.uv is None:
        raise UsdExportError("skin_texture: given without uv (the skin needs texture coordinates)")
    return src, f"{path.stem}_skin{src.suffix.lower()}"


def _bind_skin_texture(stage, skin, texture_name: str, looks: str = f"{ROOT}/{LOOKS}") -> None:
    """The skin's own material ``Looks/SkinTexture``: a UsdPreviewSurface whose diffuse colour
    is a UsdUVTexture (sRGB) of ``./texture_name`` read at ``primvars:st``
    (UsdPrimvarReader_float2), bound to the skin mesh."""
    path = f"{looks}/SkinTexture"
    mat = UsdShade.Material.Define(stage, path)
    surf = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    surf.CreateIdAttr("UsdPreviewSurface")
    surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.55)
    surf.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    reader = UsdShade.Shader.Define(stage, f"{path}/StReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    st_name = mat.CreateInput("frame:stPrimvarName", Sdf.ValueTypeNames.String)
    st_name.Set("st")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).ConnectToSource(st_name)
    tex = UsdShade.Shader.Define(stage, f"{path}/DiffuseTexture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(f"./{texture_name}"))
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(skin.GetPrim()).Bind(mat)


def _uv_primvar(mesh, uv: np.ndarray, uv_indices) -> None:
    interp = UsdGeom.Tokens.vertex if uv_indices is None else UsdGeom.Tokens.faceVarying
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, interp)
    pv.Set(Vt.Vec2fArray.FromNumpy(uv))
    if uv_indices is not None:
        pv.SetIndices(Vt.IntArray.FromNumpy(uv_indices.ravel()))


def _muscles(stage, s: _Spec) -> None:
    M = len(s.muscle_names)
    curves = UsdGeom.BasisCurves.Define(stage, f"{ROOT}/{MUSCLES}")
    curves.CreateTypeAttr(UsdGeom.Tokens.linear)
    curves.CreateCurveVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(M, s.muscle_samples, np.int32)))
    curves.CreateWidthsAttr(Vt.FloatArray([s.muscle_width]))
    curves.SetWidthsInterpolation(UsdGeom.Tokens.constant)
    points, ext = curves.CreatePointsAttr(), curves.CreateExtentAttr()  # specs for the time samples
    if s.muscle_rest is not None:
        C = s.muscle_rest.reshape(-1, 3)
        points.Set(Vt.Vec3fArray.FromNumpy(C))
        ext.Set(Vt.Vec3fArray.FromNumpy(extent(C, s.muscle_width / 2)))
    pv = UsdGeom.PrimvarsAPI(curves)
    pv.CreatePrimvar("activation", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.uniform).Set(
        Vt.FloatArray.FromNumpy(np.zeros(M, np.float32)))
    relaxed = _heat(np.zeros(M, np.float32))
    curves.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set(Vt.Vec3fArray.FromNumpy(relaxed))
    curves.GetPrim().CreateAttribute("muscleNames", Sdf.ValueTypeNames.StringArray, custom=True,
                                     variability=Sdf.VariabilityUniform).Set(Vt.StringArray(s.muscle_names))


def _tet_mesh(stage, s: _Spec) -> None:
    tm = UsdGeom.TetMesh.Define(stage, f"{ROOT}/{TISSUE}")
    tm.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(s.tet_rest))
    tm.CreateTetVertexIndicesAttr(Vt.Vec4iArray.FromNumpy(s.tets))
    tm.CreateSurfaceFaceVertexIndicesAttr(UsdGeom.TetMesh.ComputeSurfaceFaces(tm))
    tm.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(extent(s.tet_rest)))
    tm.CreatePurposeAttr(UsdGeom.Tokens.guide)


# ============================================================================ names, colours, camera, lights
@dataclass(frozen=True)
class _Looks:
    """Checked part colours, face subsets and camera of a stage."""

    part_colors: dict  #: part name -> RGB (3,) float.
    subsets: dict  #: mesh path -> [(subset name, face indices (k,) int32, RGB (3,))].
    camera: dict | None  #: position, target, up (3,) float64 and focal_length_mm.


def _rgb(name: str, value) -> tuple:
    c = float_array(name, value, (3,))
    if (c < 0).any() or (c > 1).any():
        raise UsdExportError(f"{name}: expected an RGB colour in 0..1, got {c.tolist()}")
    return tuple(float(v) for v in c)


def _check_looks(s: _Spec, part_colors, subsets, camera) -> _Looks:
    colors = {}
    for name, rgb in (part_colors or {}).items():
        if name not in s.parts:
            raise UsdExportError(f"part_colors: unknown part {name!r}; parts are {sorted(s.parts)}")
        colors[name] = _rgb(f"part_colors[{name!r}]", rgb)
    out, seen = {}, {}
    for mesh, groups in (subsets or {}).items():
        if mesh == SKIN:
            path, m = Sdf.Path(f"{ROOT}/{SKIN}"), len(s.faces)
        elif mesh in s.parts:
            path, m = s.part_paths[mesh], len(s.parts[mesh][1])
        else:
            raise UsdExportError(f"subsets: unknown mesh {mesh!r}; expected {SKIN!r} or a part ({sorted(s.parts)})")
        used = np.zeros(m, bool)
        rows = []
        for sub, value in groups.items():
            if not (isinstance(value, (tuple, list)) and len(value) == 2):
                raise UsdExportError(f"subsets[{mesh!r}][{sub!r}]: expected (face indices, RGB)")
            idx = index_array(f"subsets[{mesh!r}][{sub!r}] faces", np.asarray(value[0]).reshape(-1, 1), (None, 1),
                              upper=m).ravel()
            rgb = _rgb(f"subsets[{mesh!r}][{sub!r}] colour", value[1])
            if prim_name(sub) != sub:
                raise UsdExportError(f"subsets[{mesh!r}]: {sub!r} is not a valid prim name")
            if sub in ("Skin", "White", "Rest") or sub in {p.name for p in s.part_paths.values()}:
                raise UsdExportError(f"subsets[{mesh!r}]: {sub!r} is the name of another material")
            if seen.setdefault(sub, rgb) != rgb:
                raise UsdExportError(f"subsets: {sub!r} has two colours, {seen[sub]} and {rgb}")
            if used[idx].any() or len(np.unique(idx)) != len(idx):
                raise UsdExportError(f"subsets[{mesh!r}][{sub!r}]: faces overlap another subset's (or repeat)")
            used[idx] = True
            if len(idx):
                rows.append((sub, np.sort(idx).astype(np.int32), rgb))
        out[path] = rows
    cam = None
    if camera is not None:
        try:
            cam = {k: float_array(f"camera[{k!r}]", camera[k], (3,)).astype(np.float64) for k in ("position", "target",
                                                                                                  "up")}
        except (KeyError, TypeError):
            raise UsdExportError("camera: expected a dict with position, target and up (3,) each") from None
        cam["focal_length_mm"] = _positive("camera focal_length_mm", camera.get("focal_length_mm", 50.0))
        if np.linalg.norm(np.cross(cam["target"] - cam["position"], cam["up"])) < 1e-12:
            raise UsdExportError("camera: position == target, or up along the view direction")
    return _Looks(part_colors=colors, subsets=out, camera=cam)


def _dress_stage(layer, s: _Spec, looks: _Looks, *, lights: bool) -> None:
    """Author the part colours, face subsets, camera and lights on the built stage; saves the layer."""
    if not (looks.part_colors or looks.subsets or looks.camera or lights):
        return
    stage = Usd.Stage.Open(layer)
    for name, rgb in looks.part_colors.items():
        mat = _preview_material(stage, f"{ROOT}/{LOOKS}/{s.part_paths[name].name}", rgb, roughness=0.35)
        UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath(s.part_paths[name])).Bind(mat)
    textured = stage.GetPrimAtPath(f"{ROOT}/{LOOKS}/SkinTexture").IsValid()
    for path, rows in looks.subsets.items():
        # a textured skin's subsets show the texture (the scan's own lip colour), not a flat tint
        _material_subsets(stage, path, rows, own_only=textured and str(path) == f"{ROOT}/{SKIN}")
    if looks.camera is not None:
        _camera(stage, looks.camera)
    if lights:
        _lights(stage, looks.camera)
    layer.Save()


def _material_subsets(stage, path, rows, looks: str = f"{ROOT}/{LOOKS}", *, own_only: bool = False) -> None:
    """Face subsets of the mesh at ``path`` bound to one material per subset name, and a subset
    ``Rest`` of the other faces bound to the mesh's own material: the subsets partition the mesh
    (importers that give each subset a material slot, as Blender's, otherwise leave the rest bare).
    ``own_only``: every subset keeps its name but binds the mesh's own material (a textured skin)."""
    if not rows:
        return
    prim = stage.GetPrimAtPath(path)
    mesh = UsdGeom.Mesh(prim)
    binding = UsdShade.MaterialBindingAPI.Apply(prim)
    own = binding.GetDirectBinding().GetMaterial()
    used = np.zeros(len(mesh.GetFaceVertexCountsAttr().Get()), bool)
    for sub, idx, rgb in rows:
        mat_path = f"{looks}/{sub}"
        if own_only and own:
            mat = own
        elif stage.GetPrimAtPath(mat_path):
            mat = UsdShade.Material(stage.GetPrimAtPath(mat_path))
        else:
            mat = _preview_material(stage, mat_path, rgb, roughness=0.4)
        subset = binding.CreateMaterialBindSubset(sub, Vt.IntArray.FromNumpy(idx), UsdGeom.Tokens.face)
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(mat)
        used[idx] = True
    rest = np.flatnonzero(~used).astype(np.int32)
    if len(rest) and own:
        subset = binding.CreateMaterialBindSubset("Rest", Vt.IntArray.FromNumpy(rest), UsdGeom.Tokens.face)
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(own)
    binding.SetMaterialBindSubsetsFamilyType(UsdGeom.Tokens.partition)


def _camera(stage, cam: dict) -> None:
    """``/Camera`` at ``position`` looking at ``target`` (a USD camera looks along its -z, up +y)."""
    c = UsdGeom.Camera.Define(stage, "/Camera")
    view = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*cam["position"]), Gf.Vec3d(*cam["target"]), Gf.Vec3d(*cam["up"]))
    c.AddTransformOp().Set(view.GetInverse())
    c.CreateFocalLengthAttr(float(cam["focal_length_mm"]))
    dist = float(np.linalg.norm(cam["target"] - cam["position"]))
    c.CreateClippingRangeAttr(Gf.Vec2f(0.01 * dist, 100.0 * dist))
    c.CreateFocusDistanceAttr(dist)


def _lights(stage, cam: dict | None) -> None:
    """``/Lights``: a key DistantLight (shining along its -z) from above the camera's side, a dim dome."""
    UsdGeom.Xform.Define(stage, "/Lights")
    key = UsdLux.DistantLight.Define(stage, "/Lights/Key")
    if cam is not None:
        d = cam["position"] - cam["target"]
        up = cam["up"] / np.linalg.norm(cam["up"])
        side = np.cross(up, d)
        src = cam["target"] + d + 0.6 * np.linalg.norm(d) * up + 0.4 * np.linalg.norm(d) * side / np.linalg.norm(side)
        view = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*src), Gf.Vec3d(*cam["target"]), Gf.Vec3d(*up))
        key.AddTransformOp().Set(view.GetInverse())
    # inputs:normalize: the key's intensity is its irradiance whatever its angular size (UsdLux's rule
    # without it scales the power by the 0.53 deg disc's solid angle, which Blender 5 follows: a black
    # render; Blender 4.2 ignores the flag and renders the same either way)
    key.CreateIntensityAttr(KEY_INTENSITY)
    key.CreateAngleAttr(0.53)  # the sun's angular diameter: sharp shadows, no noise
    key.CreateNormalizeAttr(True)
    key.CreateColorAttr(Gf.Vec3f(1.0, 1.0, 1.0))
    # the fill: a dome of one colour; its colour authored, as importers that make a world of it (Blender's)
    # read the colour (or a texture) and skip a dome that has neither
    dome = UsdLux.DomeLight.Define(stage, "/Lights/Fill")
    dome.CreateIntensityAttr(FILL_INTENSITY)
    dome.CreateColorAttr(Gf.Vec3f(1.0, 1.0, 1.0))
    dome.CreateNormalizeAttr(True)

