"""The packed muscles of a face (:class:`MuscleRig`, host NumPy, SI): what the builder reads to
make the muscles' device arrays (:meth:`~facewarp._src.physics.builder.ModelBuilder.add_muscles`)
and the stage's NumPy references use (:mod:`.muscle_stage`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.errors import InputError

__all__ = ["PIVOT_CENTER", "PIVOT_FIXED", "MuscleRig", "merge_rigs"]

PIVOT_CENTER = -1  # a sphincter point contracts toward its ring centre
PIVOT_FIXED = -2  # a linear muscle's attachment on the bone does not contract


@dataclass
class MuscleRig:
    """Muscles packed for the kernels (all NumPy; positions in metres).

    Attributes:
        names: Muscle instance names (e.g. ``zygomatic_major_L``), length M.
        activation_index: Index into ``Control.activations`` per muscle, shape (M,), int.
        contraction: Largest relative shortening c_max (at activation 1), shape (M,), float.
        center: Ring centre of sphincters (unused for linear muscles) [m], shape (M, 3).
        center_jaw: Jaw amount of the ring centre, shape (M,), float.
        ctrl_rest: Rest positions of all control points [m], shape (P, 3), float.
        ctrl_muscle: Owning muscle of each control point, shape (P,), int.
        ctrl_pivot: Control point each point contracts toward, or -1 (ring centre) / -2
            (attachment, does not contract), shape (P,), int.
        ctrl_jaw: Jaw amount (Eq. 6.4.9) of each control point, shape (P,), float.
        curve_ctrl: Control point indices of each quadratic curve, shape (C, 3), int.
        curve_weight: Rational weights of each curve (1, w, 1), shape (C, 3), float.
        seg_curve: Curve of each segment, shape (S,), int.
        seg_t: Curve parameter range of each segment, shape (S, 2), float.
        seg_rest_radii: Ellipsoid radii at rest (x, y, z) [m], shape (S, 3), float.
        anchor_ctrl: Member control points of the anchors (Fig. 6.3), grouped by anchor,
            shape (A,), int; a control point belongs to at most one anchor.
        anchor_group: Anchor of each member, shape (A,), int.
        anchor_passive: Stiffness of each member at activation 0, relative to the stiffness an
            activation of 1 adds, shape (A,), float, > 0 (``kernels_muscle._muscle_anchors``).
        att_node: Skin node of each attachment, shape (K,), int.
        att_seg: Segment of each attachment, shape (K,), int.
        att_uv: Ellipsoid surface parameters (u along the fibre, v around it), shape (K, 2).
        att_rest_length: Spring rest length l0 [m], shape (K,).
        att_stiffness: Spring stiffness k_m [N/m], shape (K,): a node's stiffness shared equally
            among its attachments (as :func:`~facewarp._src.physics.face_rig.face_rig_from_anatomy`
            and the simulator set it).
        att_weight: Share of the node's sheet area within the muscle's band (Fig. 6.4 by area),
            in (0, 1], shape (K,) (empty = all 1). The stage redistributes a node's stiffness by
            these weights: attachment k of node i gets ``k_i w_k / max(sum_i w, 1)``.
        saturation: Saturation beta of the activation curve
            ``c(a) = c_max (1 - exp(-beta a)) / (1 - exp(-beta))`` per muscle, shape (M,), float,
            >= 0 (0 = linear; empty = all 0).
        center_normal: Unit normal of the plane a sphincter contracts toward (through its
            centre; the lids' palpebral fissure), or 0 for contraction toward the centre point,
            shape (M, 3), float (empty = all 0).
        glide: 1 for a sphincter whose points glide over a sphere (the lids over the eyeball),
            shape (M,), int (empty = none).
        glide_center: Centre of that sphere [m] (on the cranium: not moved by the jaw), shape
            (M, 3), float (empty = none).
    """

    names: list
    activation_index: np.ndarray
    contraction: np.ndarray
    center: np.ndarray
    center_jaw: np.ndarray
    ctrl_rest: np.ndarray
    ctrl_muscle: np.ndarray
    ctrl_pivot: np.ndarray
    ctrl_jaw: np.ndarray
    curve_ctrl: np.ndarray
    curve_weight: np.ndarray
    seg_curve: np.ndarray
    seg_t: np.ndarray
    seg_rest_radii: np.ndarray
    anchor_ctrl: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    anchor_group: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    anchor_passive: np.ndarray = field(default_factory=lambda: np.zeros(0))
    att_node: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    att_seg: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    att_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    att_rest_length: np.ndarray = field(default_factory=lambda: np.zeros(0))
    att_stiffness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    att_weight: np.ndarray = field(default_factory=lambda: np.zeros(0))
    saturation: np.ndarray = field(default_factory=lambda: np.zeros(0))
    center_normal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    glide: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    glide_center: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def __post_init__(self):
        M = len(self.names)
        if len(self.saturation) == 0:
            self.saturation = np.zeros(M)
        if len(self.center_normal) == 0:
            self.center_normal = np.zeros((M, 3))
        if len(self.glide) == 0:
            self.glide = np.zeros(M, np.int64)
        if len(self.glide_center) == 0:
            self.glide_center = np.zeros((M, 3))

    @property
    def muscle_count(self) -> int:
        return len(self.names)

    def attachment_jaw(self) -> np.ndarray:
        """Jaw amount of the muscle at each attachment, shape (K,), float64: the control points'
        amounts blended with the rational Bezier basis of the attachment's curve at the middle of
        its segment (the amount by which that part of the muscle turns with the jaw)."""
        if len(self.att_node) == 0:
            return np.zeros(0)
        seg = np.asarray(self.att_seg)
        c = np.asarray(self.seg_curve)[seg]
        t = np.asarray(self.seg_t, np.float64)[seg].mean(1)
        b = np.stack([(1 - t) ** 2, 2 * t * (1 - t), t * t], 1) * np.asarray(self.curve_weight, np.float64)[c]
        b /= b.sum(1, keepdims=True)
        return np.einsum("kj,kj->k", b, np.asarray(self.ctrl_jaw, np.float64)[np.asarray(self.curve_ctrl)[c]])

    def weighted_stiffness(self) -> np.ndarray:
        """Spring stiffness [N/m] of every attachment after the area weights, shape (K,), float64:
        a node's stiffness (``att_stiffness`` times its attachment count) split by the weights,
        ``k_i w_k / max(sum_i w, 1)``: a node wholly inside one muscle's band keeps all of it,
        one half inside gets half, one inside two bands splits it by their shares."""
        if len(self.att_node) == 0:
            return np.zeros(0)
        node = np.asarray(self.att_node)
        w = np.asarray(self.att_weight, np.float64) if len(self.att_weight) else np.ones(len(node))
        count = np.bincount(node)[node]
        wsum = np.bincount(node, weights=w)[node]
        return np.asarray(self.att_stiffness, np.float64) * count * w / np.maximum(wsum, 1.0)

    def sphincters(self) -> np.ndarray:
        """Whether each muscle is a sphincter (has points contracting toward a centre), (M,) bool."""
        out = np.zeros(len(self.names), bool)
        out[np.asarray(self.ctrl_muscle)[np.asarray(self.ctrl_pivot) == PIVOT_CENTER]] = True
        return out

    def attachment_across(self) -> np.ndarray:
        """1 where an attachment belongs to a sphincter, whose springs pull across the fibre (Eq.
        6.4.1's cosine taken as 1), else 0, shape (K,), int."""
        if len(self.att_node) == 0:
            return np.zeros(0, np.int64)
        first = np.asarray(self.curve_ctrl)[np.asarray(self.seg_curve)[np.asarray(self.att_seg)], 0]
        return self.sphincters()[np.asarray(self.ctrl_muscle)[first]].astype(np.int64)

    def curve_normals(self) -> np.ndarray:
        """Unit normals of each curve's control-point plane at rest, shape (C, 3)."""
        c = self.ctrl_rest[self.curve_ctrl]
        n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
        bad = np.linalg.norm(n, axis=1) < 1e-12
        # a straight curve: any normal perpendicular to it
        t = c[:, 2] - c[:, 0]
        alt = np.cross(t, np.where(np.abs(t[:, [1]]) < 0.9 * np.linalg.norm(t, axis=1, keepdims=True), [0, 1, 0], [1, 0, 0]))
        n = np.where(bad[:, None], alt, n)
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def validate(self) -> None:
        P, M, C, S = len(self.ctrl_rest), len(self.names), len(self.curve_ctrl), len(self.seg_curve)
        checks = [
            (self.ctrl_muscle, M, "ctrl_muscle"), (self.curve_ctrl.ravel(), P, "curve_ctrl"),
            (self.seg_curve, C, "seg_curve"), (self.att_seg, S, "att_seg"),
            (self.anchor_ctrl, P, "anchor_ctrl"),
        ]
        for a, n, name in checks:
            if len(a) and (a.min() < 0 or a.max() >= n):
                raise InputError(f"muscle rig: {name} index out of range 0..{n - 1}")
        A = len(self.anchor_ctrl)
        if len(self.anchor_group) != A or len(self.anchor_passive) != A:
            raise InputError(f"muscle rig: anchor_group and anchor_passive must have shape ({A},) like anchor_ctrl")
        if A and len(np.unique(self.anchor_ctrl)) != A:
            raise InputError("muscle rig: a control point belongs to more than one anchor")
        if A and not (np.isfinite(self.anchor_passive).all() and (np.asarray(self.anchor_passive) > 0).all()):
            raise InputError("muscle rig: anchor_passive must be finite and > 0")
        for a, shape, name in ((self.saturation, (M,), "saturation"), (self.center_normal, (M, 3), "center_normal"),
                               (self.glide, (M,), "glide"), (self.glide_center, (M, 3), "glide_center")):
            if np.shape(a) != shape:
                raise InputError(f"muscle rig: {name} must have shape {shape}, got {np.shape(a)}")
        if not (np.isfinite(self.saturation).all() and (np.asarray(self.saturation) >= 0).all()):
            raise InputError("muscle rig: saturation must be finite and >= 0")
        if len(self.att_weight) == 0:  # attachments given without weights: all 1
            self.att_weight = np.ones(len(self.att_node))
        w = np.asarray(self.att_weight)
        if w.shape != (len(self.att_node),) or not (np.isfinite(w).all() and (w > 0).all() and (w <= 1).all()):
            raise InputError(f"muscle rig: att_weight must have shape ({len(self.att_node)},) with values in (0, 1]")
        piv = self.ctrl_pivot
        if len(piv) and (piv.min() < -2 or piv.max() >= P):
            raise InputError("muscle rig: ctrl_pivot out of range")
        if not np.all(np.isfinite(self.ctrl_rest)):
            raise InputError("muscle rig: non-finite control point")


def merge_rigs(heads: list, node_offsets) -> tuple:
    """The muscle rigs of several heads as one (:class:`MuscleRig`): ``heads`` a list of ``(rig or
    None, node jaw amount (n_h,) or None)`` per head, ``node_offsets`` each head's first node. Rows concatenated,
    indices shifted by the heads' counts (control points, muscles and activations, curves,
    segments, anchors, nodes). Returns ``(rig or None, {"ctrl_head" (P,), "att_head" (K,),
    "att_jaw_shift" (K,)})`` (each control point's and attachment's head; the attachments' jaw
    shift, node amount less the muscle's, as one head's :class:`MuscleArrays` computes it)."""
    rigs = [(h, r, amount) for h, (r, amount) in enumerate(heads) if r is not None]
    if not rigs:
        return None, {}
    cols = {k: [] for k in ("names", "activation_index", "contraction", "center", "center_jaw", "ctrl_rest",
                            "ctrl_muscle", "ctrl_pivot", "ctrl_jaw", "curve_ctrl", "curve_weight", "seg_curve", "seg_t",
                            "seg_rest_radii", "anchor_ctrl", "anchor_group", "anchor_passive", "att_node", "att_seg",
                            "att_uv", "att_rest_length", "att_stiffness", "att_weight", "saturation", "center_normal",
                            "glide", "glide_center")}
    ctrl_head, att_head, shift = [], [], []
    P0 = M0 = A0 = C0 = S0 = G0 = 0
    for h, r, amount in rigs:
        P, M, C, S, K = len(r.ctrl_rest), len(r.names), len(r.curve_ctrl), len(r.seg_curve), len(r.att_node)
        cols["names"] += list(r.names)
        cols["activation_index"].append(np.asarray(r.activation_index, np.int64) + A0)
        for k in ("contraction", "center", "center_jaw", "ctrl_rest", "ctrl_jaw", "curve_weight", "seg_t",
                  "seg_rest_radii", "anchor_passive", "att_uv", "att_rest_length", "att_stiffness", "saturation",
                  "center_normal", "glide", "glide_center"):
            cols[k].append(np.asarray(getattr(r, k)))
        cols["att_weight"].append(np.asarray(r.att_weight, np.float64) if len(r.att_weight) else np.ones(K))
        cols["ctrl_muscle"].append(np.asarray(r.ctrl_muscle, np.int64) + M0)
        piv = np.asarray(r.ctrl_pivot, np.int64)
        cols["ctrl_pivot"].append(np.where(piv >= 0, piv + P0, piv))
        cols["curve_ctrl"].append(np.asarray(r.curve_ctrl, np.int64).reshape(-1, 3) + P0)
        cols["seg_curve"].append(np.asarray(r.seg_curve, np.int64) + C0)
        cols["anchor_ctrl"].append(np.asarray(r.anchor_ctrl, np.int64) + P0)
        ag = np.asarray(r.anchor_group, np.int64)
        cols["anchor_group"].append(ag + G0)
        cols["att_node"].append(np.asarray(r.att_node, np.int64) + int(node_offsets[h]))
        cols["att_seg"].append(np.asarray(r.att_seg, np.int64) + S0)
        ctrl_head.append(np.full(P, h))
        att_head.append(np.full(K, h))
        shift.append(np.asarray(amount, np.float64)[r.att_node] - r.attachment_jaw() if amount is not None and K
                     else np.zeros(K))
        P0, M0, C0, S0 = P0 + P, M0 + M, C0 + C, S0 + S
        A0 += M  # one activation per muscle (ModelBuilder.add_muscles' muscle_count)
        G0 += int(ag.max()) + 1 if len(ag) else 0
    cat = {k: (v if k == "names" else np.concatenate(v, axis=0)) for k, v in cols.items()}
    rig = MuscleRig(**cat)
    return rig, {"ctrl_head": np.concatenate(ctrl_head), "att_head": np.concatenate(att_head),
                 "att_jaw_shift": np.concatenate(shift)}
