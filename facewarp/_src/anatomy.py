"""The anatomy of a head: skin layer (Sec. 6.2) + muscles (Sec. 6.3), built and written together.

:func:`build_anatomy` works on any head with the template's data (vertices, faces, frontal
flags, thickness, skull depth, FDPs): the default template, an exported template folder, or an
adapted head with the template's topology (the tets are re-extruded from the new shape; the
muscles are placed by their FDP rules, or by the skin points of an earlier build).
:func:`write_anatomy` writes ``tets.npz``, ``muscles.json``, ``anatomy.json`` and
``anatomy.png``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError
from .muscles import MuscleSet, build_muscles, muscles_to_json
from .tissue import SkinLayer, build_skin_layer, skin_layer_quality

__all__ = [
    "Anatomy",
    "SlabHead",
    "anatomy_report",
    "build_anatomy",
    "check_head",
    "muscle_rig",
    "render_anatomy",
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
        layers: Tet layers of the skin.
        defs: Muscle definitions (default: the shipped ones).
        placements: Muscle name -> skin :class:`SurfacePoints` to reuse (same topology).
        check_intersections: Include the boundary self-intersection count in the report.

    Returns:
        :class:`Anatomy`.
    """
    check_head(head)
    skin = build_skin_layer(head, layers=layers)
    ms = build_muscles(head, skin, defs=defs, placements=placements)
    return Anatomy(head=head, skin=skin, muscles=ms, quality=anatomy_report(skin, ms, check_intersections=check_intersections))


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
    from .muscles import MuscleSet, make_linear_muscle
    from .tissue import extrude_skin_layer

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
    from .muscles import attach_nodes

    m.attachment = attach_nodes(skin.vertices, m.segments, lam, phi, candidates=skin.inner_nodes)
    ms = MuscleSet(muscles=[m])
    return Anatomy(head=SlabHead(V, F), skin=skin, muscles=ms, quality=anatomy_report(skin, ms, check_intersections=False))


def muscle_rig(muscles: MuscleSet, *, stiffness: float = 4.0e5, jaw=None, head=None, activation_index=None,
               vertex_amount=None):
    """Pack muscles for the solver (:class:`facewarp._src.muscle_stage.MuscleRig`).

    Control points are numbered muscle by muscle in ``muscles.muscles`` order. Linear muscles:
    the insertion and the middle point contract toward the attachment, which stays on the bone
    (Sec. 6.4.1); sphincters contract toward their ring centre (mean of the 4 on-curve points).
    Each anchor (Fig. 6.3) moves its sphincter control point by the mean displacement of its
    linear insertions.

    Args:
        muscles: Built muscles (with segments and attachments).
        stiffness: Muscle spring stiffness k_m of every attachment [N/m] (Eq. 6.4.1).
        jaw: A :class:`facewarp._src.jaw.JawKinematic`; with ``head`` (its ``face_region``),
            gives every control point the jaw amount (Eq. 6.4.9) of the region of its skin point
            (a ring centre takes the mean of its ring). Without it all amounts are 0.
        head: The head the muscles were built on (needed with ``jaw`` and ``vertex_amount``).
        vertex_amount: Jaw amount per head vertex, shape (n,), float64 (the smoothed field
            the skin nodes use, :func:`facewarp._src.face.face_rig_from_anatomy`); when given,
            a control point takes the amount interpolated at its skin point instead of its
            region's, so the muscles and the skin they pull turn with the jaw together.
        activation_index: Index into ``Control.activations`` per muscle (default 0..M-1).

    Returns:
        A validated ``MuscleRig``.
    """
    from .muscle_stage import PIVOT_CENTER, PIVOT_FIXED, MuscleRig
    from .muscles import MuscleKind

    ms = muscles.muscles
    M = len(ms)
    offs = np.cumsum([0] + [len(m.control_points) for m in ms])
    coffs = np.cumsum([0] + [len(m.curves) for m in ms])
    soffs = np.cumsum([0] + [len(m.segments) for m in ms])
    ctrl = np.concatenate([m.control_points for m in ms]) if M else np.zeros((0, 3))
    ctrl_muscle = np.repeat(np.arange(M), np.diff(offs))
    pivot = np.empty(len(ctrl), dtype=np.int64)
    center = np.zeros((M, 3))
    for i, m in enumerate(ms):
        o = offs[i]
        if m.kind is MuscleKind.LINEAR:
            pivot[o : o + 3] = [o + 2, o + 2, PIVOT_FIXED]
        else:
            pivot[o : offs[i + 1]] = PIVOT_CENTER
            center[i] = m.control_points[0::2].mean(0)
    ctrl_jaw = np.zeros(len(ctrl))
    center_jaw = np.zeros(M)
    if vertex_amount is not None:
        if head is None:
            raise InputError("muscle_rig: vertex_amount needs the head (its faces)")
        va = np.asarray(vertex_amount, dtype=np.float64)
        if va.shape != (len(head.vertices),):
            raise InputError(f"muscle_rig: vertex_amount must have shape ({len(head.vertices)},), got {va.shape}")
        for i, m in enumerate(ms):
            sp_ = m.skin_points
            ctrl_jaw[offs[i] : offs[i + 1]] = np.einsum("kj,kj->k", sp_.bary, va[np.asarray(head.faces)[sp_.face]])
            if m.kind is not MuscleKind.LINEAR:
                center_jaw[i] = ctrl_jaw[offs[i] : offs[i + 1]].mean()
    elif jaw is not None:
        if head is None:
            raise InputError("muscle_rig: jaw amounts need the head (its face regions)")
        from .template import REGIONS

        for i, m in enumerate(ms):
            regions = [REGIONS[r] for r in np.asarray(head.face_region)[m.skin_points.face]]
            ctrl_jaw[offs[i] : offs[i + 1]] = jaw.amounts(m.skin_points.positions(head.vertices, head.faces), regions)
            if m.kind is not MuscleKind.LINEAR:
                center_jaw[i] = ctrl_jaw[offs[i] : offs[i + 1]].mean()
    curve_ctrl = np.concatenate([m.curves + offs[i] for i, m in enumerate(ms)]) if M else np.zeros((0, 3), int)
    curve_weight = np.concatenate([m.weights[m.curves] for m in ms]) if M else np.zeros((0, 3))
    seg_curve = np.concatenate([m.segments.curve + coffs[i] for i, m in enumerate(ms)]) if M else np.zeros(0, int)
    seg_t = np.concatenate([m.segments.t for m in ms]) if M else np.zeros((0, 2))
    seg_radii = np.concatenate([m.segments.radii for m in ms]) if M else np.zeros((0, 3))
    by = {m.name: i for i, m in enumerate(ms)}
    dst, src, wgt = [], [], []
    for a in muscles.anchors:
        (sph, k), *ins = a.members
        for name, j in ins:
            dst.append(offs[by[sph]] + k)
            src.append(offs[by[name]] + j)
            wgt.append(1.0 / len(ins))
    att = [m.attachment for m in ms]
    if any(a is None for a in att):
        raise InputError("muscle_rig: build the muscles with a skin layer first (no attachments)")
    rig = MuscleRig(
        names=[m.name for m in ms],
        activation_index=np.arange(M) if activation_index is None else np.asarray(activation_index, dtype=np.int64),
        contraction=np.array([m.contraction for m in ms], dtype=np.float64),
        center=center,
        center_jaw=center_jaw,
        ctrl_rest=ctrl,
        ctrl_muscle=ctrl_muscle,
        ctrl_pivot=pivot,
        ctrl_jaw=ctrl_jaw,
        curve_ctrl=curve_ctrl.astype(np.int64),
        curve_weight=curve_weight,
        seg_curve=seg_curve.astype(np.int64),
        seg_t=seg_t,
        seg_rest_radii=seg_radii,
        anchor_dst=np.asarray(dst, dtype=np.int64),
        anchor_src=np.asarray(src, dtype=np.int64),
        anchor_weight=np.asarray(wgt, dtype=np.float64),
        att_node=np.concatenate([a.nodes for a in att]).astype(np.int64) if M else np.zeros(0, int),
        att_seg=np.concatenate([a.segment + soffs[i] for i, a in enumerate(att)]).astype(np.int64) if M else np.zeros(0, int),
        att_uv=np.concatenate([a.uv for a in att]) if M else np.zeros((0, 2)),
        att_rest_length=np.concatenate([a.rest_length for a in att]) if M else np.zeros(0),
        att_stiffness=np.full(sum(len(a) for a in att), float(stiffness)),
    )
    rig.validate()
    return rig


_PALETTE = np.array(
    [
        [0.85, 0.10, 0.10], [0.10, 0.45, 0.85], [0.10, 0.65, 0.20], [0.85, 0.50, 0.05], [0.55, 0.15, 0.70],
        [0.05, 0.65, 0.65], [0.75, 0.20, 0.45], [0.45, 0.35, 0.10], [0.20, 0.20, 0.60], [0.60, 0.60, 0.05],
        [0.95, 0.35, 0.60], [0.30, 0.55, 0.35], [0.70, 0.05, 0.05], [0.05, 0.30, 0.50],
    ]
)


def render_anatomy(anatomy: Anatomy, *, size: int = 900, device: str = "cpu", fixed=None, held=None) -> np.ndarray:
    """Front view of the head with the muscle fibres (by Table 6.2 number) and attached nodes;
    optionally the fixed (black) and held (grey) nodes of the boundary conditions."""
    from .render import render_mesh

    head = anatomy.head
    lines, pts, cols = [], [], []
    for P, c in ((fixed, (0.05, 0.05, 0.05)), (held, (0.55, 0.55, 0.55))):
        if P is not None and len(P):
            pts.append(np.asarray(P))
            cols.append(np.tile(c, (len(P), 1)))
    for m in anatomy.muscles.muscles:
        c = _PALETTE[(m.number - 1) % len(_PALETTE)]
        lines.append((m.curve_points(48), c))
        if m.attachment is not None and len(m.attachment):
            pts.append(anatomy.skin.vertices[m.attachment.nodes])
            cols.append(np.tile(c * 0.6 + 0.4, (len(m.attachment), 1)))
    return render_mesh(
        head.vertices,
        head.faces,
        view="front",
        width=size,
        height=size,
        polylines=lines,
        points=np.concatenate(pts) if pts else None,
        point_color=np.concatenate(cols) if cols else (0.85, 0.1, 0.1),
        point_radius=max(1.5, size * 0.003),
        line_width=max(1.5, size * 0.004),
        depth_tolerance=float("inf"),
        device=device,
    )


def write_anatomy(anatomy: Anatomy, out_dir: str | os.PathLike, *, image: bool = True, device: str = "cpu") -> list[Path]:
    """Write ``tets.npz``, ``muscles.json``, ``anatomy.json`` (and ``anatomy.png``) into out_dir.

    ``tets.npz``: ``vertices`` (n, 3) float64 [m], ``tets`` (k, 4) int64, ``layer`` (n,) int32
    (0 outer ... inner), ``surface_vertex`` (n,) int64 (head vertex or -1), plus
    ``source_vertex`` (n,), ``depth`` (n,) [m] and ``tet_face`` (k,) (head triangle of each tet).

    Returns:
        The written paths.
    """
    from .fileio import atomic_write, write_json

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
    if image:
        from .render import save_png

        img = render_anatomy(anatomy, device=device)
        q = anatomy.quality
        title = f"{q['tet_count']} tets, {q['inverted_count']} inverted; {q['muscle_count']} muscles"
        paths.append(Path(save_png(out / "anatomy.png", img, title=title)))
    return paths
