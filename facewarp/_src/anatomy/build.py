"""The anatomy of a head: skin layer (Sec. 6.2) + muscles (Sec. 6.3), built and written together.

:func:`build_anatomy` works on any head with the template's data (vertices, faces, frontal
flags, thickness, skull depth, FDPs): the default template, an exported template folder, or an
adapted head with the template's topology (the tets are re-extruded from the new shape; the
muscles are placed by their FDP rules, or by the skin points of an earlier build).
:func:`write_anatomy` writes ``tets.npz``, ``muscles.json``, ``anatomy.json`` and
the picture comes from
:mod:`facewarp._src.present.anatomy`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from .attach import attach_nodes
from .lips import separate_skin_lips
from .muscles import MuscleSet, build_muscles, make_linear_muscle, muscles_to_json
from .tissue import SkinLayer, build_skin_layer, extrude_skin_layer, skin_layer_quality

__all__ = [
    "Anatomy",
    "SlabHead",
    "anatomy_report",
    "build_anatomy",
    "check_head",
    "slab_anatomy",
    "write_anatomy",
]


@dataclass
class Anatomy:
    """Skin layer and muscles of one head.

    Attributes:
        head: The head they were built on (a :class:`facewarp.Template` or alike).
        skin: The tetrahedral skin layer.
        muscles: The muscles, anchors and attachments.
        quality: :func:`anatomy_report` (JSON-ready).
    """

    head: object
    skin: SkinLayer
    muscles: MuscleSet
    quality: dict


def check_head(head) -> None:
    """Check that a head carries consistent per-vertex / per-face data.

    Raises:
        InputError: naming the array whose shape does not match the mesh.
    """
    V = np.asarray(head.vertices)
    F = np.asarray(head.faces)
    if V.ndim != 2 or V.shape[1] != 3:
        raise InputError(f"head vertices: expected shape (n, 3), got {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or (F.size and (F.min() < 0 or F.max() >= len(V))):
        raise InputError(f"head faces: expected (m, 3) indices into {len(V)} vertices, got shape {F.shape}")
    for name, n in (("frontal", len(F)), ("face_region", len(F)), ("thickness", len(V)), ("skull_depth", len(V))):
        a = getattr(head, name, None)
        if a is None:
            raise InputError(f"head lacks '{name}'")
        if np.shape(a) != (n,):
            raise InputError(f"head {name}: expected shape ({n},) for this mesh, got {np.shape(a)} (topology mismatch?)")
    if not np.asarray(head.frontal).any():
        raise InputError("head has no frontal faces to build a skin layer on")
    for fid, (part, sp) in getattr(head, "fdp", {}).items():
        if part == "head" and len(sp.face) and (sp.face.max() >= len(F)):
            raise InputError(f"FDP {fid}: face {int(sp.face.max())} out of range for {len(F)} faces (topology mismatch)")


def anatomy_report(skin: SkinLayer, muscles: MuscleSet, *, check_intersections: bool = True) -> dict:
    """Quality report: tet quality (Sec. 6.2) and per-muscle attachment counts (Sec. 6.3)."""
    rep = skin_layer_quality(skin, check_intersections=check_intersections)
    rep["muscle_count"] = len(muscles.muscles)
    rep["muscles"] = {
        m.name: {
            "kind": m.kind.value,
            "segments": len(m.segments),
            "attached_nodes": 0 if m.attachment is None else len(m.attachment),
            "length_m": m.length(),
        }
        for m in muscles.muscles
    }
    counts = [v["attached_nodes"] for v in rep["muscles"].values()]
    rep["min_attached_nodes"] = int(min(counts)) if counts else 0
    rep["anchors"] = [a.name for a in muscles.anchors]
    return rep


def build_anatomy(head, *, layers: int = 1, defs=None, placements=None, check_intersections: bool = True) -> Anatomy:
    """Build the skin layer and the muscles of a head.

    Args:
        head: A :class:`facewarp.Template` (or any object with its fields and ``landmarks()``).
        layers: Tet layers of the skin, 1..16 (:data:`~facewarp._src.core.limits.MAX_LAYERS`); the memory
            they need is checked against the machine's first.
        defs: Muscle definitions (default: the shipped ones).
        placements: Muscle name -> skin :class:`SurfacePoints` to reuse (same topology).
        check_intersections: Include the boundary self-intersection count in the report.

    Returns:
        :class:`Anatomy`.
    """
    from ..core.checks import check_head_arg

    check_head_arg("head", head)
    from ..core.limits import MAX_LAYERS, check_count, check_memory, estimate_build_bytes

    check_count("layers", layers, high=MAX_LAYERS)
    if hasattr(head, "faces") and hasattr(head, "vertices"):
        check_memory(estimate_build_bytes(len(head.vertices), len(head.faces), layers),
                     f"layers: {layers} tet layers under {len(head.faces)} skin triangles")
    check_head(head)
    skin = build_skin_layer(head, layers=layers)
    lips = separate_skin_lips(head, skin)  # lips that cross at rest moved apart (anatomy/lips.py)
    ms = build_muscles(head, skin, defs=defs, placements=placements)
    quality = anatomy_report(skin, ms, check_intersections=check_intersections)
    quality["lip_separation"] = lips
    return Anatomy(head=head, skin=skin, muscles=ms, quality=quality)


@dataclass
class SlabHead:
    """A flat skin sheet standing in for a head (see :func:`slab_anatomy`).

    Attributes:
        vertices: Sheet vertices [m], shape (n, 3), z = 0, outward normal +z.
        faces: Triangles, shape (m, 3), int64.
    """

    vertices: np.ndarray
    faces: np.ndarray


def slab_anatomy(
    *,
    cells: int = 50,
    size: float = 0.05,
    thickness: float = 0.003,
    layers: int = 1,
    muscle_depth: float = 0.006,
    muscle_length: float = 0.04,
    radius: float = 0.0015,
    lam: float = 0.006,
    phi: float = np.deg2rad(60.0),
    segments: int = 5,
) -> Anatomy:
    """The slab scene for the solver experiments (thesis Fig. 6.9/6.10).

    A ``cells x cells`` grid of square cells (2 triangles each) of side ``size`` in the z = 0
    plane, extruded down by ``thickness`` into a conforming tet slab, with one straight linear
    muscle along x under its centre line at ``muscle_depth`` below the skin, attached to the
    inner-layer nodes by the Fig. 6.4 search.

    Returns:
        :class:`Anatomy` whose ``head`` is a :class:`SlabHead`; its muscle is named ``"muscle"``
        with the insertion at -x and the attachment at +x.
    """
    n = int(cells) + 1
    if n < 2:
        raise InputError(f"cells: expected >= 1, got {cells}")
    x, y = np.meshgrid(np.linspace(-size / 2, size / 2, n), np.linspace(-size / 2, size / 2, n), indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a, b, c, d = (i * n + j).ravel(), ((i + 1) * n + j).ravel(), ((i + 1) * n + j + 1).ravel(), (i * n + j + 1).ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    skin = extrude_skin_layer(V, F, np.full(len(V), float(thickness)), layers=layers, probe=0.0)
    h = muscle_length / 2
    P = np.array([[-h, 0.0, -muscle_depth], [0.0, 0.0, -muscle_depth], [h, 0.0, -muscle_depth]])
    m = make_linear_muscle("muscle", P, radius=radius, lam=lam, phi=phi, segments=segments, depth=np.full(3, muscle_depth))
    m.attachment = attach_nodes(skin.vertices, m.segments, lam, phi, candidates=skin.inner_nodes)
    ms = MuscleSet(muscles=[m])
    return Anatomy(head=SlabHead(V, F), skin=skin, muscles=ms, quality=anatomy_report(skin, ms, check_intersections=False))


def write_anatomy(anatomy: Anatomy, out_dir: str | os.PathLike) -> list[Path]:
    """Write ``tets.npz``, ``muscles.json`` and ``anatomy.json`` into out_dir (the picture,
    ``anatomy.png``, is :func:`facewarp._src.present.anatomy.render_anatomy`).

    ``tets.npz``: ``vertices`` (n, 3) float64 [m], ``tets`` (k, 4) int64, ``layer`` (n,) int32
    (0 outer ... inner), ``surface_vertex`` (n,) int64 (head vertex or -1), plus
    ``source_vertex`` (n,), ``depth`` (n,) [m] and ``tet_face`` (k,) (head triangle of each tet).

    Returns:
        The written paths.
    """
    from ..core.checks import check_has, check_path

    check_has("anatomy", anatomy, ("head", "skin", "muscles"), "an Anatomy (build_anatomy)")
    check_path("out_dir", out_dir)
    from ..core.fileio import atomic_write, write_json

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    s = anatomy.skin
    paths = [out / "tets.npz", out / "muscles.json", out / "anatomy.json"]
    with atomic_write(paths[0], "wb") as f:
        np.savez_compressed(
            f,
            vertices=s.vertices,
            tets=s.tets,
            layer=s.layer,
            surface_vertex=s.surface_vertex,
            source_vertex=s.source_vertex,
            depth=s.depth,
            tet_face=s.tet_face,
        )
    write_json(paths[1], muscles_to_json(anatomy.muscles))
    write_json(paths[2], anatomy.quality)
    return paths
