"""A head packed for the solver (NumPy, SI): :class:`FaceRig`, what ``facewarp build`` saves
(``face_rig.npz``, :func:`save_face_rig`) and ``facewarp simulate`` loads (:func:`load_face_rig`).

The rig is made at build time by :func:`facewarp._src.anatomy.rig.face_rig_from_anatomy`
(boundary conditions, jaw amounts, muscles, contact geometry); the physics only reads it
(:meth:`~facewarp._src.physics.builder.ModelBuilder.add_face`).
"""

from __future__ import annotations

import io
import os
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.checks import check_array, check_indices
from ..core.errors import InputError
from ..core.fileio import atomic_write
from ..geometry.jaw import JawKinematic
from .contact import ContactGeometry, contact_from_arrays, contact_to_arrays
from .muscle_rig import MuscleRig

__all__ = ["FaceRig", "check_face_rig", "load_face_rig", "node_jaw_amounts", "save_face_rig"]


@dataclass
class FaceRig:
    """Solver inputs of one head (NumPy; metres).

    Attributes:
        head_vertices (n, 3), head_faces (m, 3): the skin mesh of the head.
        nodes (p, 3), tets (k, 4), layer (p,) 0 outer / 1 inner, surface_vertex (p,): tet mesh.
        fixed (p,) bool, held (p,) bool: boundary conditions (see the module doc).
        jaw_nodes (j,), jaw_amount (j,): held nodes carried by the jaw and their amount.
        support_nodes (s,), support_normal (s, 3), support_amount (s,): free inner-sheet nodes
            with a sliding support along their rest normal, and their jaw amount.
        jaw_pivot (3,), jaw_u (3,), jaw_v (3,), lip_corners (2, 3), mouth_center (3,).
        rig: the packed muscles; muscle_names (M,) instance names.
        fdp_ids (84,), fdp_part (84,), fdp_face (84,), fdp_bary (84, 3): FDP surface points.
        vertex_jaw (n,): jaw amount of every head vertex; the head vertices outside the tet mesh
            follow the jaw kinematically with it (the neck under the chin).
        parts: rigid part name -> (V, F); part_jaw: name -> jaw amount (1 lower teeth, tongue).
        level: template level (or -1).
        opening_vertex (q,), opening_node (q, c), opening_weight (q, c): head vertices of the
            openings in the frontal face (frontal-region faces left out of the tet mesh: an
            imported head's lip creases, mouth interior, lid margins), the outer nodes each
            follows and how much of each node's displacement it takes (the rest of 1: the jaw's
            kinematic motion); :func:`~facewarp._src.anatomy.rig.opening_follow`. None or empty: no openings.
        contact: The contact geometry (:class:`~facewarp._src.physics.contact.ContactGeometry`,
            computed at build time by :func:`~facewarp._src.anatomy.contact.contact_geometry`); None
            for a rig made by hand.
        head_uv (k, 2), head_face_uv (m, 3): the skin's texture coordinates per corner (the
            template's UV layout), or None.
        skin_texture: path of the skin's colour texture (``texture.png`` beside the rig file,
            set by :func:`load_face_rig`), or None.
    """

    head_vertices: np.ndarray
    head_faces: np.ndarray
    nodes: np.ndarray
    tets: np.ndarray
    layer: np.ndarray
    surface_vertex: np.ndarray
    fixed: np.ndarray
    held: np.ndarray
    jaw_nodes: np.ndarray
    jaw_amount: np.ndarray
    support_nodes: np.ndarray
    support_normal: np.ndarray
    support_amount: np.ndarray
    jaw_pivot: np.ndarray
    jaw_u: np.ndarray
    jaw_v: np.ndarray
    lip_corners: np.ndarray
    mouth_center: np.ndarray
    rig: MuscleRig
    fdp_ids: np.ndarray
    fdp_part: np.ndarray
    fdp_face: np.ndarray
    fdp_bary: np.ndarray
    vertex_jaw: np.ndarray | None = None
    parts: dict = field(default_factory=dict)
    part_jaw: dict = field(default_factory=dict)
    level: int = -1
    opening_vertex: np.ndarray | None = None
    opening_node: np.ndarray | None = None
    opening_weight: np.ndarray | None = None
    contact: ContactGeometry | None = None
    head_uv: np.ndarray | None = None
    head_face_uv: np.ndarray | None = None
    skin_texture: str | None = None

    jaw: JawKinematic = field(init=False, repr=False, compare=False)
    """The kinematic jaw of ``jaw_pivot``, ``jaw_u``, ``jaw_v``, ``lip_corners`` and ``mouth_center``
    (made with the rig: a plain attribute)."""

    def __post_init__(self):
        self.jaw = JawKinematic(self.jaw_pivot, self.jaw_u, self.jaw_v, self.lip_corners, self.mouth_center)

    def part_at(self, name: str, jaw_angles=(0.0, 0.0)) -> np.ndarray:
        """Vertices [m] of rigid part ``name`` in the head frame at ``jaw_angles`` (u, v) [rad],
        shape (k, 3), float64: turned by the jaw with the part's amount (lower teeth and
        tongue 1, eyes and upper teeth 0)."""
        V = np.asarray(self.parts[name][0], np.float64)
        amt = float(self.part_jaw.get(name, 0.0))
        u, v = float(jaw_angles[0]), float(jaw_angles[1])
        if amt == 0.0 or (u == 0.0 and v == 0.0):
            return V
        return self.jaw.apply(V, np.full(len(V), amt), u, v)

    @property
    def muscle_names(self) -> list[str]:
        return list(self.rig.names)


_RIG_FIELDS = ("activation_index", "contraction", "center", "center_jaw", "ctrl_rest", "ctrl_muscle", "ctrl_pivot",
               "ctrl_jaw", "curve_ctrl", "curve_weight", "seg_curve", "seg_t", "seg_rest_radii", "anchor_ctrl",
               "anchor_group", "anchor_passive", "att_node", "att_seg", "att_uv", "att_rest_length", "att_stiffness",
               "att_weight", "saturation", "center_normal", "glide", "glide_center")
_FACE_FIELDS = ("head_vertices", "head_faces", "nodes", "tets", "layer", "surface_vertex", "fixed", "held", "jaw_nodes",
                "jaw_amount", "support_nodes", "support_normal", "support_amount", "jaw_pivot", "jaw_u", "jaw_v", "lip_corners", "mouth_center", "fdp_ids", "fdp_part",
                "fdp_face", "fdp_bary", "vertex_jaw")


def save_face_rig(path, fr: FaceRig) -> Path:
    """Write ``fr`` to one ``.npz`` file atomically."""
    from ..core.checks import check_has, check_path

    check_path("path", path)
    check_has("fr", fr, ("nodes", "tets", "rig"), "a FaceRig")
    arrays = {k: getattr(fr, k) for k in _FACE_FIELDS}
    arrays.update({f"rig_{k}": getattr(fr.rig, k) for k in _RIG_FIELDS})
    arrays["rig_names"] = np.array(fr.rig.names)
    arrays["level"] = np.array(fr.level)
    if fr.opening_vertex is not None:
        arrays.update(opening_vertex=fr.opening_vertex, opening_node=fr.opening_node, opening_weight=fr.opening_weight)
    if fr.head_uv is not None:
        arrays.update(head_uv=fr.head_uv, head_face_uv=fr.head_face_uv)
    arrays["part_names"] = np.array(list(fr.parts))
    for k, (V, F) in fr.parts.items():
        arrays[f"part_{k}_V"], arrays[f"part_{k}_F"] = V, F
        arrays[f"part_{k}_jaw"] = np.array(fr.part_jaw.get(k, 0.0))
    if fr.contact is not None:
        arrays.update(contact_to_arrays(fr.contact))
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    with atomic_write(path, "wb", encoding=None) as f:
        f.write(buf.getvalue())
    return Path(path)


def load_face_rig(path) -> FaceRig:
    """Read a file written by :func:`save_face_rig` (a ``facewarp build`` output)."""
    # the path checked here, not by core.checks, which the checks of the rig itself enter once
    if isinstance(path, bytes) or not isinstance(path, (str, os.PathLike)) or not str(path).strip():
        raise InputError(f"path: expected a file or folder path, got {path!r:.80}")
    path = Path(path)
    if path.is_dir():
        path = path / "face_rig.npz"
    if not path.is_file():
        raise InputError(f"{path}: not found (HEAD must be a `facewarp build` output folder)")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: the file is empty (not a facewarp face rig)")
    try:
        z = np.load(path, allow_pickle=False)
        if "rig_anchor_ctrl" not in z:
            raise InputError(f"{path}: a face rig of an older facewarp (one-way anchors); run `facewarp build` again")
        if "contact_node_side" not in z:
            raise InputError(f"{path}: a face rig of an older facewarp (no contact geometry); rebuild it with "
                             "`facewarp build`")
        # every field read first, then the parts made in one pass (the muscles, the contact, the rig)
        names = [str(n) for n in z["rig_names"]]
        rig_fields = {k: z[f"rig_{k}"] for k in _RIG_FIELDS}
        parts = {str(k): (z[f"part_{k}_V"], z[f"part_{k}_F"]) for k in z["part_names"]}
        part_jaw = {str(k): float(z[f"part_{k}_jaw"]) for k in z["part_names"]}
        opening = {k: z[k] for k in ("opening_vertex", "opening_node", "opening_weight", "head_uv", "head_face_uv")
                   if k in z}
        face = {k: z[k] for k in _FACE_FIELDS}
        texture = path.parent / "texture.png"
        texture = str(texture) if texture.is_file() else None
        rig = MuscleRig(names=names, **rig_fields)
        contact = contact_from_arrays(z)
        fr = FaceRig(rig=rig, parts=parts, part_jaw=part_jaw, level=int(z["level"]), skin_texture=texture, **face,
                     **opening, contact=contact)
    except InputError:
        raise
    except (KeyError, ValueError, TypeError, IndexError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        raise InputError(f"{path}: not a facewarp face rig ({_first_line(e)})") from None
    check_face_rig(fr, str(path))
    return fr


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


def node_jaw_amounts(fr) -> np.ndarray:
    """Eq. 6.4.9 jaw amount of every tet node of a face rig (:class:`~facewarp.FaceRig`), shape (p,), float64: that of the head vertex the
    node lies on or under (sheets are stored one after another, node ``l * q + i`` below outer
    node ``i``). Rigs without ``vertex_jaw`` give the held and supported nodes' amounts only."""
    n = len(fr.nodes)
    out = np.zeros(n)
    q = int((fr.layer == 0).sum())
    if fr.vertex_jaw is not None and q and n % q == 0 and (fr.surface_vertex[:q] >= 0).all():
        out = np.asarray(fr.vertex_jaw, np.float64)[fr.surface_vertex[np.arange(n) % q]]
    else:
        out[fr.jaw_nodes] = fr.jaw_amount
        out[fr.support_nodes] = fr.support_amount
    return out


def check_face_rig(fr, source: str) -> None:
    """The arrays of a face rig agree with each other: shapes, finite positions, indices in
    range. ``source`` (the file) starts the message of the :class:`InputError`."""
    try:
        nodes = check_array("nodes", fr.nodes, shape=(None, 3))
        p = len(nodes)
        check_indices("tets", fr.tets, p, shape=(None, 4))
        hv = check_array("head_vertices", fr.head_vertices, shape=(None, 3))
        check_indices("head_faces", fr.head_faces, len(hv), shape=(None, 3))
        check_indices("surface_vertex", fr.surface_vertex, len(hv), allow=-1)
        for nm in ("layer", "surface_vertex"):
            if len(getattr(fr, nm)) != p:
                raise InputError(f"{nm}: {len(getattr(fr, nm))} entries for {p} nodes")
        for nm in ("fixed", "held"):
            a = check_array(nm, getattr(fr, nm), shape=(p,), kind="b")
            del a
        check_indices("jaw_nodes", fr.jaw_nodes, p)
        check_array("jaw_amount", fr.jaw_amount, shape=(len(fr.jaw_nodes),))
        check_indices("support_nodes", fr.support_nodes, p)
        check_array("support_normal", fr.support_normal, shape=(len(fr.support_nodes), 3))
        check_array("support_amount", fr.support_amount, shape=(len(fr.support_nodes),))
        for nm in ("jaw_pivot", "jaw_u", "jaw_v"):
            check_array(nm, getattr(fr, nm), shape=(3,))
        check_indices("fdp_face", fr.fdp_face, len(fr.head_faces))
        check_array("fdp_bary", fr.fdp_bary, shape=(len(fr.fdp_face), 3))
        rig = fr.rig
        check_indices("rig att_node", rig.att_node, p)
        for nm in ("ctrl_rest", "att_rest_length", "att_stiffness", "att_weight", "contraction"):
            a = getattr(rig, nm, None)
            if a is not None:
                check_array(f"rig {nm}", a, shape=(None,) * np.ndim(a))
        for k, (V, F) in fr.parts.items():
            Vp = check_array(f"part {k} vertices", V, shape=(None, 3))
            check_indices(f"part {k} faces", F, len(Vp), shape=(None, 3))
    except InputError as e:
        raise InputError(f"{source}: corrupt face rig ({e})") from None
