"""The face rig of a head: boundary conditions, jaw amounts, muscles and contact geometry packed
for the solver (build time; NumPy, SI).

:func:`face_rig_from_anatomy` packs an :class:`~facewarp._src.anatomy.build.Anatomy` into the
:class:`~facewarp._src.physics.face_rig.FaceRig` that ``facewarp build`` saves and the simulator
loads; :func:`muscle_rig` packs the muscles; :func:`build_face` does both for a head.

Boundary conditions (Sec. 6.2, 6.4): only the frontal face is simulated. Skin nodes on the
frontal region's border (outer and inner sheet) are fixed. Inner-sheet nodes of the regions over
bone (:data:`BONE_REGIONS`: nose, chin, bottom face) whose sheet area lies mostly outside the
muscles' attachment bands are held by stiff springs at their rest position, which the jaw moves
for the jaw regions (Eq. 6.4.9 amounts). Cheeks, lips and lids glide over soft tissue, teeth and
eyeballs: every other inner-sheet node has a sliding support along the normal of that deeper
surface (the skin's inward direction smoothed over :data:`SUPPORT_SMOOTHING`), but the lids'
inner sheet over an eyeball, which glides on the ball itself (:mod:`.contact`). The outer sheet
is free. The contact geometry (:func:`~facewarp._src.anatomy.contact.contact_geometry`) is
computed here, once, and saved with the rig.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..geometry.jaw import JawKinematic
from ..geometry.surface import gaussian_sums
from ..physics.face_rig import FaceRig
from ..physics.muscle_rig import PIVOT_CENTER, PIVOT_FIXED, MuscleRig
from ..template import FRONTAL_REGIONS, REGIONS

__all__ = ["BONE_REGIONS", "MUSCLE_STIFFNESS", "OPENING_FALLOFF", "SUPPORT_SMOOTHING", "build_face",
           "face_rig_from_anatomy", "muscle_rig", "opening_follow", "substrate_normals"]

MUSCLE_STIFFNESS = 1.0e7
"""Default muscle spring stiffness k_m of Eq. 6.4.1 [N/m] in the solver's unit system (node mass
0.5, Table 6.3), shared by the springs on a node: chosen so that the Table 6.4 presets move the
lip corners and brows by several mm. It is 3-10 times the tissue's own ``k0 / D0^2`` at level 0,
so the inner sheet follows the muscles almost kinematically; 2e6 would spare the thin lip corner
of some scan-adapted heads (ICT identity 002, angry) but leaves the brows of the default head
too weak to rise against an opening jaw (surprise)."""

JAW_SMOOTHING = 0.02
"""Length [m] over which the jaw amount of Eq. 6.4.9 is smoothed across region borders."""

BONE_REGIONS = ("nose", "chin", "bottom_face")
"""Regions whose inner sheet lies on bone and is held (unless attached to a muscle)."""

OPENING_FALLOFF = 0.005
"""Length [m] along the skin over which the rim of an opening in the frontal face (a face left
out of the tet mesh) passes from following the simulated skin to the jaw's kinematic motion:
a vertex at mesh distance d from the nearest simulated vertex takes ``exp(-(d / L)^2)`` of that
vertex's displacement (:func:`opening_follow`). Without it the imported ICT head's lip creases
(the inner lip corners, FDP 2.4/2.5) and lid margins stayed at rest while the lips and lids moved
15 mm away: the frame tore there, and the smile's cosine with the rig was 0.644 instead of 0.792."""

SUPPORT_SMOOTHING = 0.01
"""Width [m] of the Gaussian (weights ``exp(-(d / w)^2)`` by inner-sheet area) over which the
skin's inward directions are averaged into the normal of the deeper surface that the inner sheet
glides on (:func:`substrate_normals`). The teeth, gums and buccal fat under the lips and cheeks
are smooth at the centimetre scale; the skin of a finely meshed head is not: the lips of the
imported ICT head roll into the mouth, and a support along each node's own normal there (up on
the lower lip, down on the upper) held the lip corners in place (zygomatic major at 1.0 moved
them 8.3 mm; with the smoothed normal 15.6 mm, the rig's mouthSmile 15.6; the default head's
coarse lips 15.7 and 15.5 mm)."""


def _vertex_region_amounts(head, jaw: JawKinematic) -> np.ndarray:
    """Jaw amount per head vertex (Eq. 6.4.9).

    On the frontal face: the mean over the vertex's incident faces of their region's amount.
    The neck below the mandible is not simulated but must follow an opening jaw, or the skin
    under the chin would be crushed against a still neck: there the amount is the harmonic
    (uniform-Laplacian) interpolation between the frontal face's values and 0 on the rest of
    the head (scalp, ears, the neck cut).
    """
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    F = head.faces
    n = len(head.vertices)
    names = np.asarray(REGIONS)[head.face_region]
    P = head.vertices[F].reshape(-1, 3)
    amt = jaw.amounts(P, np.repeat(names, 3))
    s = np.bincount(F.ravel(), weights=amt, minlength=n)
    c = np.bincount(F.ravel(), minlength=n)
    out = s / np.maximum(c, 1)
    neck_faces = names == "neck"
    neck_v = np.zeros(n, bool)
    neck_v[np.unique(F[neck_faces])] = True
    known = np.zeros(n, bool)
    known[np.unique(F[~neck_faces])] = True  # frontal face keeps its values; scalp/ears are 0
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(float)
    deg = np.asarray(A.sum(1)).ravel()
    L = sp.diags(deg) - A
    from ..geometry.surface import boundary_vertices

    cut = np.zeros(n, bool)
    cut[boundary_vertices(F, n)] = True
    cut &= neck_v  # the whole neck cut stays with the body, however tilted (an adapted or imported neck)
    out[cut] = 0.0
    # the neck faces took 0 in the mean above: border vertices keep only the frontal values
    frontal_only = np.bincount(F[~neck_faces].ravel(), weights=amt.reshape(-1, 3)[~neck_faces].ravel(), minlength=n)
    cf = np.bincount(F[~neck_faces].ravel(), minlength=n)
    border = known & neck_v
    out[border] = frontal_only[border] / np.maximum(cf[border], 1)
    free = neck_v & ~known & ~cut
    if free.any():
        fixed_idx = np.where(~free)[0]
        free_idx = np.where(free)[0]
        rhs = -L[free_idx][:, fixed_idx] @ out[fixed_idx]
        out[free_idx] = spla.spsolve(L[free_idx][:, free_idx].tocsc(), rhs)
    # Region borders make the amounts jump by up to 1 across one edge, which would shear the
    # thin skin layer when the jaw turns by tens of degrees. One implicit diffusion step
    # (I + t L) u = u0 with t = (smoothing length / mean edge length)^2 spreads each jump over
    # about JAW_SMOOTHING metres, whatever the mesh resolution.
    h = float(np.mean(np.linalg.norm(head.vertices[E[:, 0]] - head.vertices[E[:, 1]], axis=1)))
    t = (JAW_SMOOTHING / h) ** 2
    keep = cut
    M = (sp.identity(n) + t * L).tolil()
    for i in np.where(keep)[0]:
        M.rows[i], M.data[i] = [i], [1.0]
    out = spla.spsolve(M.tocsc(), out)
    return np.clip(out, 0.0, 1.0)


def face_rig_from_anatomy(anatomy, *, muscle_stiffness: float = MUSCLE_STIFFNESS) -> FaceRig:
    """Pack an :class:`~facewarp._src.anatomy.Anatomy` for the solver."""
    from ..core.checks import check_has

    check_has("anatomy", anatomy, ("head", "skin", "muscles"), "an Anatomy (build_anatomy)")
    head, skin, ms = anatomy.head, anatomy.skin, anatomy.muscles
    lm = head.landmarks()
    jaw = JawKinematic.from_landmarks(head.condyles, lm)
    v_amount = _vertex_region_amounts(head, jaw)

    # --- boundary conditions
    # the border of the simulation domain is fixed where it meets the skin that rides the skull
    # (scalp, ears, neck: the regions outside FRONTAL_REGIONS). Faces of frontal regions left out
    # of the domain (an imported head's mouth interior behind the inner lip contour, the lip
    # creases at the corners, the lid margins and nostril rims, where no skin layer could be
    # extruded) are openings, not attachments: their border stays free, as the default
    # template's open mouth is (measured on the imported ICT head: with that border fixed, the
    # lip corner sat 1.8 mm from a fixed node and the full smile moved it 0.5 mm instead of 15)
    frontal_v = np.zeros(len(head.vertices), bool)
    frontal_v[np.unique(head.faces[head.frontal])] = True
    outer_region = ~np.isin(head.face_region, [REGIONS.index(r) for r in FRONTAL_REGIONS])
    other_v = np.zeros(len(head.vertices), bool)
    other_v[np.unique(head.faces[~head.frontal & outer_region])] = True
    border_v = frontal_v & other_v
    src = skin.source_vertex
    fixed = border_v[src]
    inner = skin.layer == skin.layer.max()
    # a node counts as attached when most of its sheet area lies within the muscles' bands (the
    # sum of its attachment weights, Fig. 6.4 by area, >= 1/2), the same midpoint rule as the
    # bone regions' below: where any attachment freed the node (weights down to 0.05), a band
    # freed half an element more bone on either side, twice as much on level 0 as on level 1
    # (held inner sheet 87.5 vs 101.3 cm^2 of the default head; with the rule 105.7 vs 109.7)
    share = np.zeros(len(skin.vertices))
    for m in ms.muscles:
        if m.attachment is not None and len(m.attachment):
            np.add.at(share, m.attachment.nodes, m.attachment.weight)
    attached = share >= 0.5
    # over bone: the nose (nasal bone and cartilage), chin and the bottom face (mandible); the
    # cheeks (buccal space), lips and lids glide freely over soft tissue, teeth and eyeballs
    bone_ids = [REGIONS.index(r) for r in BONE_REGIONS]
    Ff = head.faces.ravel()
    on_bone = np.bincount(Ff, weights=np.repeat(np.isin(head.face_region, bone_ids), 3).astype(float),
                          minlength=len(head.vertices)) / np.maximum(np.bincount(Ff, minlength=len(head.vertices)), 1)
    held = inner & ~attached & ~fixed & (on_bone[src] >= 0.5)
    jaw_amount_node = v_amount[src]
    jaw_nodes = np.where((held | fixed) & (jaw_amount_node > 0))[0]
    # the lids' inner sheet over an eyeball glides on the ball, not on a plane (contact stage)
    from .contact import contact_geometry, eyeball_sheet_nodes

    on_eye = eyeball_sheet_nodes(skin.vertices, getattr(head, "parts", None))
    support_nodes = np.where(inner & ~held & ~fixed & ~on_eye)[0]
    p = int((skin.layer == 0).sum())
    inner_faces = np.asarray(skin.skin_faces) + int(skin.layer.max()) * p  # the inner sheet's triangles
    support_normal = substrate_normals(skin.vertices, inner_faces, skin.direction, support_nodes)

    # --- muscles (packed by the anatomy stage, with Eq. 6.4.9 jaw amounts)
    rig = muscle_rig(ms, stiffness=muscle_stiffness, head=head, vertex_amount=v_amount)
    # a node tied to several muscles (the modiolus at the lip corner has five) shares k_m among
    # them, so no node is pulled by more than one muscle's stiffness in total (the muscle stage
    # splits it by the attachments' area weights, MuscleRig.weighted_stiffness)
    per_node = np.bincount(rig.att_node, minlength=len(skin.vertices))
    rig.att_stiffness = rig.att_stiffness / np.maximum(per_node[rig.att_node], 1)

    outer_nodes = np.flatnonzero(skin.layer == 0)
    opening_faces = head.faces[~np.asarray(head.frontal, bool) & ~outer_region]
    o_vertex, o_node, o_weight = opening_follow(head.vertices, head.faces, opening_faces, src[outer_nodes], outer_nodes)

    ids = list(head.fdp)
    parts = dict(getattr(head, "parts", {}) or {})
    part_jaw = {k: (1.0 if k in ("teeth_lower", "tongue") else 0.0) for k in parts}
    layer = (skin.layer > 0).astype(np.int32)
    fr = FaceRig(
        head_vertices=np.asarray(head.vertices, float), head_faces=np.asarray(head.faces), nodes=skin.vertices,
        tets=skin.tets, layer=layer, surface_vertex=skin.surface_vertex, fixed=fixed, held=held,
        jaw_nodes=jaw_nodes, jaw_amount=jaw_amount_node[jaw_nodes], support_nodes=support_nodes,
        support_normal=support_normal, support_amount=jaw_amount_node[support_nodes], jaw_pivot=jaw.pivot, jaw_u=jaw.u_axis,
        jaw_v=jaw.v_axis, lip_corners=jaw.lip_corners, mouth_center=jaw.mouth_center, rig=rig,
        fdp_ids=np.array(ids), fdp_part=np.array([head.fdp[i][0] for i in ids]),
        fdp_face=np.array([int(head.fdp[i][1].face[0]) for i in ids]),
        fdp_bary=np.array([head.fdp[i][1].bary[0] for i in ids]), parts=parts, part_jaw=part_jaw,
        vertex_jaw=v_amount,
        level=int(getattr(head, "level", -1)),
        opening_vertex=o_vertex, opening_node=o_node, opening_weight=o_weight,
        head_uv=getattr(head, "uv", None), head_face_uv=getattr(head, "face_uv", None),
    )
    fr.contact = contact_geometry(fr)  # build-time work, saved with the rig
    return fr


def opening_follow(V, F, opening_faces, sim_vertex, sim_node, *, falloff: float = OPENING_FALLOFF, count: int = 8):
    """How the rims of the openings in a frontal face follow the simulated skin.

    Each vertex of ``opening_faces`` that is not simulated follows the ``count`` simulated
    vertices nearest to it along the mesh edges (Shepard weights ``1 / d^2``; along the mesh, so
    a vertex of the upper lip's inner roll follows the upper lip, not the lower one across the
    lip gap, and one in the crease at the lip corner both lips), by the share
    ``exp(-(d_min / falloff)^2)`` of their displacement, d_min the mesh distance to the nearest.

    Args:
        V: Head vertices [m], shape (n, 3), float.
        F: Head triangles, shape (m, 3), int.
        opening_faces: The openings' triangles, shape (o, 3), int.
        sim_vertex: Head vertex of each simulated outer node, shape (s,), int.
        sim_node: Those nodes, shape (s,), int.
        falloff: Length [m], > 0.
        count: Simulated vertices each rim vertex follows, >= 1.

    Returns:
        ``(vertex (q,) int64, node (q, count) int64, weight (q, count) float64)``: each row's
        weights sum to the share (unused slots: node 0, weight 0); empty when there are no openings.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    if not (np.isfinite(falloff) and falloff > 0):
        raise InputError(f"falloff: expected a positive length [m], got {falloff!r}")
    if not (isinstance(count, (int, np.integer)) and count >= 1):
        raise InputError(f"count: expected a whole number >= 1, got {count!r}")
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    sim_vertex = np.asarray(sim_vertex, np.int64)
    node_of_vertex = np.full(len(V), -1, np.int64)
    node_of_vertex[sim_vertex] = np.asarray(sim_node, np.int64)
    verts = np.unique(np.asarray(opening_faces, np.int64).ravel()) if len(opening_faces) else np.zeros(0, np.int64)
    verts = verts[node_of_vertex[verts] < 0]
    out_v, out_n, out_w = [], [], []
    if len(verts) and len(sim_vertex):
        E = np.unique(np.sort(F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
        L = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
        G = coo_matrix((L, (E[:, 0], E[:, 1])), shape=(len(V), len(V))).tocsr()
        for start in range(0, len(verts), 256):  # rows of at most 256 x n distances at a time
            chunk = verts[start:start + 256]
            D = dijkstra(G, directed=False, indices=chunk, limit=4.0 * falloff)[:, sim_vertex]
            near = np.argsort(D, axis=1)[:, :count]
            d = np.take_along_axis(D, near, axis=1)
            ok = np.isfinite(d[:, 0])
            w = np.where(np.isfinite(d), 1.0 / np.maximum(d, 1e-5) ** 2, 0.0)
            w *= (np.exp(-((d[:, 0] / falloff) ** 2)) / w.sum(1))[:, None]
            pad = np.zeros((len(chunk), count), np.int64)
            pad[:, : near.shape[1]] = node_of_vertex[sim_vertex[near]]
            wpad = np.zeros((len(chunk), count))
            wpad[:, : near.shape[1]] = w
            out_v.append(chunk[ok])
            out_n.append(pad[ok])
            out_w.append(wpad[ok])
    if not out_v:
        return np.zeros(0, np.int64), np.zeros((0, count), np.int64), np.zeros((0, count))
    return np.concatenate(out_v), np.concatenate(out_n), np.concatenate(out_w)


def substrate_normals(X, F, directions, nodes, *, width: float = SUPPORT_SMOOTHING) -> np.ndarray:
    """Normals of the deeper surface under a skin sheet: the sheet's inward directions averaged
    around each node with Gaussian weights ``exp(-(d / width)^2)`` times each node's share of the
    sheet area (so the average does not depend on how finely the sheet is meshed).

    Args:
        X: Node positions [m], shape (p, 3), float.
        F: The sheet's triangles, shape (m, 3), int (indices into X).
        directions: Unit inward direction of every node, shape (p, 3), float.
        nodes: Nodes of the sheet to give a normal, shape (s,), int.
        width: Gaussian width [m], > 0.

    Returns:
        Unit normals, shape (s, 3), float64.
    """
    if not (np.isfinite(width) and width > 0):
        raise InputError(f"width: expected a positive length [m], got {width!r}")
    X = np.asarray(X, np.float64)
    F = np.asarray(F, np.int64)
    D = np.asarray(directions, np.float64)
    nodes = np.asarray(nodes, np.int64)
    tri = X[F]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    node_area = np.bincount(F.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(X))
    sheet = np.flatnonzero(node_area > 0)
    v, _ = gaussian_sums(X[nodes], X[sheet], D[sheet], width, node_area[sheet])
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(n > 1e-12, v / np.maximum(n, 1e-300), D[nodes])


def muscle_rig(muscles: MuscleSet, *, stiffness: float = 4.0e5, jaw=None, head=None, activation_index=None,
               vertex_amount=None):
    """Pack muscles for the solver (:class:`facewarp._src.muscle_stage.MuscleRig`).

    Control points are numbered muscle by muscle in ``muscles.muscles`` order. Linear muscles:
    the insertion and the middle point contract toward the attachment, which stays on the bone
    (Sec. 6.4.1); sphincters contract toward their ring centre (the muscle's ``center``, by
    default the mean of the 4 on-curve points), but for their ``fixed`` points. Each anchor
    (Fig. 6.3) ties its sphincter control point and linear insertions two-way (every member moves
    by their stiffness-weighted mean displacement, ``kernels_muscle._muscle_anchors``).

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
            pivot[o + np.asarray(m.fixed, dtype=np.int64)] = PIVOT_FIXED
            center[i] = m.control_points[0::2].mean(0) if m.center is None else m.center
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
        from ..template import REGIONS

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
    a_ctrl, a_group, a_passive = [], [], []
    for g, a in enumerate(muscles.anchors):
        for name, j in a.members:
            a_ctrl.append(offs[by[name]] + j)
            a_group.append(g)
            a_passive.append(float(getattr(a, "passive", 0.1)))
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
        anchor_ctrl=np.asarray(a_ctrl, dtype=np.int64),
        anchor_group=np.asarray(a_group, dtype=np.int64),
        anchor_passive=np.asarray(a_passive, dtype=np.float64),
        att_node=np.concatenate([a.nodes for a in att]).astype(np.int64) if M else np.zeros(0, int),
        att_seg=np.concatenate([a.segment + soffs[i] for i, a in enumerate(att)]).astype(np.int64) if M else np.zeros(0, int),
        att_uv=np.concatenate([a.uv for a in att]) if M else np.zeros((0, 2)),
        att_rest_length=np.concatenate([a.rest_length for a in att]) if M else np.zeros(0),
        att_stiffness=np.full(sum(len(a) for a in att), float(stiffness)),
        att_weight=np.concatenate([a.weight for a in att]) if M else np.zeros(0),
        saturation=np.array([getattr(m, "saturation", 0.0) for m in ms], dtype=np.float64),
        center_normal=np.array([np.zeros(3) if getattr(m, "center_normal", None) is None else m.center_normal
                                for m in ms], dtype=np.float64).reshape(M, 3),
        glide=np.array([getattr(m, "glide_center", None) is not None for m in ms], dtype=np.int64),
        glide_center=np.array([np.zeros(3) if getattr(m, "glide_center", None) is None else m.glide_center
                               for m in ms], dtype=np.float64).reshape(M, 3),
    )
    rig.validate()
    return rig


def build_face(head, *, layers: int = 1, muscle_stiffness: float = MUSCLE_STIFFNESS) -> FaceRig:
    """Anatomy (skin tets, muscles; Sec. 6.2-6.3) and solver inputs of a head in one call.

    Args:
        head: A :class:`~facewarp.Template` (:func:`~facewarp.default_template`,
            :func:`~facewarp.load_head`) or anything with the template's data.
        layers: Tet layers through the skin, >= 1.
        muscle_stiffness: Muscle spring stiffness k_m of Eq. 6.4.1 [N/m].

    Returns:
        The :class:`FaceRig`, ready for :class:`~facewarp.FaceSimulator`.
    """
    from ..core.checks import check_head_arg

    check_head_arg("head", head)
    from .build import build_anatomy

    if not (isinstance(muscle_stiffness, (int, float)) and np.isfinite(muscle_stiffness) and muscle_stiffness > 0):
        raise InputError(f"muscle_stiffness: expected a positive number [N/m], got {muscle_stiffness!r}")
    return face_rig_from_anatomy(build_anatomy(head, layers=layers), muscle_stiffness=muscle_stiffness)
