"""Muscles and jaw as solver stages: packed arrays on the device and the kernels that use them.

:class:`MuscleRig` is the host-side (NumPy, SI) packing of any set of muscles: control points,
(rational) quadratic Bezier curves, ellipsoid segments, anchors and skin attachments. The
anatomy module fills it (:func:`facewarp._src.anatomy.muscle_rig`); tests build small rigs by
hand. :class:`MuscleStage` and :class:`JawStage` follow the solver's stage protocol: each
substep they only launch kernels (no allocation, no host read), so a frame can be captured.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.warp import get_warp
from ..core.errors import InputError
from .model import Model, Springs, group_indices

__all__ = ["MuscleRig", "MuscleStage", "SupportStage", "contraction_curve", "ellipsoid_uv", "rig_reference"]

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


# ---------------------------------------------------------------------------------------- host math
def _bezier_np(c, w, t):
    t = np.asarray(t, dtype=np.float64)[..., None]
    b0 = (1 - t) ** 2 * w[..., 0:1]
    b1 = 2 * t * (1 - t) * w[..., 1:2]
    b2 = t**2 * w[..., 2:3]
    return (c[..., 0, :] * b0 + c[..., 1, :] * b1 + c[..., 2, :] * b2) / (b0 + b1 + b2)


def segment_frames(rig: MuscleRig, ctrl: np.ndarray):
    """NumPy reference of ``_muscle_segments``: centres (S, 3), frames (S, 3, 3) with columns
    x, y, z, radii (S, 3) for control point positions ``ctrl`` (P, 3)."""
    c = ctrl[rig.curve_ctrl[rig.seg_curve]]
    w = rig.curve_weight[rig.seg_curve]
    a = _bezier_np(c, w, rig.seg_t[:, 0])
    b = _bezier_np(c, w, rig.seg_t[:, 1])
    chord = b - a
    length = np.linalg.norm(chord, axis=1)
    x = chord / np.maximum(length, 1e-12)[:, None]
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    small = np.linalg.norm(n, axis=1) < 1e-12 * (np.linalg.norm(c[:, 1] - c[:, 0], axis=1) * np.linalg.norm(c[:, 2] - c[:, 0], axis=1) + 1e-30)
    n = np.where(small[:, None], rig.curve_normals()[rig.seg_curve], n)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    y = np.cross(n, x)
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    z = np.cross(x, y)
    rx = 0.525 * length
    r0 = rig.seg_rest_radii
    s = np.sqrt(r0[:, 0] / np.maximum(rx, 1e-12))
    radii = np.stack([rx, r0[:, 1] * s, r0[:, 2] * s], 1)
    return 0.5 * (a + b), np.stack([x, y, z], axis=2), radii


def ellipsoid_point(center, frame, radii, uv):
    u, v = uv[..., 0], uv[..., 1]
    local = np.stack([radii[..., 0] * np.cos(u), radii[..., 1] * np.sin(u) * np.cos(v), radii[..., 2] * np.sin(u) * np.sin(v)], -1)
    return center + np.einsum("...ij,...j->...i", frame, local)


def ellipsoid_uv(center, frame, radii, P):
    """Surface parameters (u, v) of the ellipsoid point nearest (approximately: along the
    scaled radial line) to P (k, 3); returns (k, 2)."""
    local = np.einsum("...ji,...j->...i", frame, P - center) / radii
    local /= np.maximum(np.linalg.norm(local, axis=-1, keepdims=True), 1e-12)
    u = np.arccos(np.clip(local[..., 0], -1, 1))
    v = np.arctan2(local[..., 2], local[..., 1])
    return np.stack([u, v], -1)


def contraction_curve(activation, contraction, saturation):
    """The saturating activation curve of the muscles (``kernels_muscle._contraction``):
    ``c(a) = c_max (1 - exp(-beta a)) / (1 - exp(-beta))``, ``a`` clamped to [0, 1], linear
    ``c_max a`` for ``beta`` -> 0. Broadcasting arrays; returns the contraction fraction."""
    a = np.clip(np.asarray(activation, np.float64), 0.0, 1.0)
    c = np.asarray(contraction, np.float64)
    b = np.asarray(saturation, np.float64)
    bs = np.where(b < 1e-4, 1.0, b)
    return np.where(b < 1e-4, c * a, c * -np.expm1(-bs * a) / -np.expm1(-bs))


def rig_reference(rig: MuscleRig, activations, jaw=None, jaw_angles=(0.0, 0.0)):
    """NumPy reference of the whole muscle stage: (control points (P, 3), attachment points
    (K, 3)). ``jaw`` is a :class:`facewarp._src.jaw.JawKinematic` or None."""
    from ..geometry.jaw import jaw_rotation

    acts = np.asarray(activations, dtype=np.float64)
    if jaw is not None:
        jawed = jaw_rotation(rig.ctrl_rest, rig.ctrl_jaw, jaw.pivot, jaw.u_axis, jaw.v_axis, *jaw_angles)
        centers = jaw_rotation(rig.center, rig.center_jaw, jaw.pivot, jaw.u_axis, jaw.v_axis, *jaw_angles)
    else:
        jawed, centers = rig.ctrl_rest.copy(), rig.center.copy()
    act = np.clip(acts[rig.activation_index], 0, 1)  # (M,)
    a = contraction_curve(act, rig.contraction, rig.saturation)[rig.ctrl_muscle]
    piv = rig.ctrl_pivot
    target = np.where((piv == PIVOT_CENTER)[:, None], centers[rig.ctrl_muscle], jawed[np.maximum(piv, 0)])
    normal = np.asarray(rig.center_normal, np.float64)
    if jaw is not None:
        normal = jaw_rotation(normal, rig.center_jaw, np.zeros(3), jaw.u_axis, jaw.v_axis, *jaw_angles)
    n = normal[rig.ctrl_muscle]
    plane = (piv == PIVOT_CENTER) & (np.linalg.norm(n, axis=1) > 0)
    target[plane] = jawed[plane] - n[plane] * np.einsum("ij,ij->i", jawed[plane] - target[plane], n[plane])[:, None]
    out = np.where((piv == PIVOT_FIXED)[:, None], jawed, jawed + a[:, None] * (target - jawed))
    glide = (np.asarray(rig.glide)[rig.ctrl_muscle] != 0) & (piv != PIVOT_FIXED)
    if glide.any():
        g = np.asarray(rig.glide_center, np.float64)[rig.ctrl_muscle[glide]]
        q = out[glide] - g
        out[glide] = g + q * (np.linalg.norm(jawed[glide] - g, axis=1) / np.linalg.norm(q, axis=1))[:, None]
    contracted = out.copy()
    for k in np.unique(rig.anchor_group):
        mem = np.flatnonzero(np.asarray(rig.anchor_group) == k)
        p = np.asarray(rig.anchor_ctrl)[mem]
        w = np.asarray(rig.anchor_passive, np.float64)[mem] + act[rig.ctrl_muscle[p]]
        D = (w[:, None] * (contracted[p] - jawed[p])).sum(0) / w.sum()
        out[p] = jawed[p] + D
    c, f, r = segment_frames(rig, out)
    pts = ellipsoid_point(c[rig.att_seg], f[rig.att_seg], r[rig.att_seg], rig.att_uv)
    return out, pts


# ---------------------------------------------------------------------------------------- stages
class MuscleStage:
    """The muscle springs of Eq. 6.4.1 (solver stage).

    Explicit solvers call :meth:`apply` every substep (forces of Eq. 6.4.1 as printed, the fibre
    cosine at the current positions); implicit solvers call :meth:`prepare` once per step, which
    fills :attr:`springs` with the energy terms ``1/2 k_m w (|p_m - x| - l0)^2`` with the cosine
    ``w`` taken at the step's start (see ``kernels_muscle._muscle_springs``). A sphincter's springs
    take ``w = 1``: its ring squeezes across its fibres (:meth:`MuscleRig.attachment_across`).
    Control points contract along the saturating activation curve (:func:`contraction_curve`)
    and anchors tie their members two-way (``kernels_muscle._muscle_anchors``).

    The control points of the step's controls are State (``State.muscle_ctrl``, written in place
    in ``state_in`` at the step's start); the stage's own arrays are the model's muscles on the
    device and scratch that every step recomputes from State and Control before use.

    Attributes (device scratch, written every substep, readable between frames):
        seg_center, seg_frame, seg_radii: Current ellipsoids.
        att_point: Current attachment points on the ellipsoids [m], shape (K,), wp.vec3.
        springs: The springs of the current implicit step (:class:`~facewarp._src.physics.model.Springs`).
    """

    def __init__(self, rig: MuscleRig, jaw, device, node_amount=None):
        """``node_amount`` (vertex_count,): the jaw amount (Eq. 6.4.9) of every tet node; with it,
        each spring's muscle end turns with the jaw by its node's amount rather than by the
        muscle's (:meth:`MuscleRig.attachment_jaw`), so opening the jaw alone pulls no node."""
        wp = get_warp()
        from . import kernels_muscle as km
        from . import kernels_tissue as kt

        rig.validate()
        self.km = km
        self.kt = kt
        self.rig = rig
        self.device = device
        f32 = lambda a, dt=float: wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=dt, device=device)  # noqa: E731
        i32 = lambda a, dt=wp.int32: wp.array(np.ascontiguousarray(a, dtype=np.int32), dtype=dt, device=device)  # noqa: E731
        self.ctrl_rest = f32(rig.ctrl_rest, wp.vec3)
        self.ctrl_muscle = i32(rig.ctrl_muscle)
        self.ctrl_pivot = i32(rig.ctrl_pivot)
        self.ctrl_jaw = f32(rig.ctrl_jaw)
        self.muscle_activation = i32(rig.activation_index)
        self.muscle_contraction = f32(rig.contraction)
        self.muscle_saturation = f32(rig.saturation)
        self.muscle_center_normal = f32(rig.center_normal, wp.vec3)
        self.muscle_glide = i32(rig.glide)
        self.muscle_glide_center = f32(rig.glide_center, wp.vec3)
        self.muscle_center = f32(rig.center, wp.vec3)
        self.muscle_center_jaw = f32(rig.center_jaw)
        self.curve_ctrl = i32(rig.curve_ctrl, wp.vec3i)
        self.curve_weight = f32(rig.curve_weight, wp.vec3)
        self.curve_normal = f32(rig.curve_normals(), wp.vec3)
        self.seg_curve = i32(rig.seg_curve)
        self.seg_t = f32(rig.seg_t, wp.vec2)
        self.seg_rest_radii = f32(rig.seg_rest_radii, wp.vec3)
        groups, a_start, a_order = group_indices(rig.anchor_group)
        self.anchor_count = len(groups)
        self.anchor_start = i32(a_start)
        self.anchor_ctrl = i32(np.asarray(rig.anchor_ctrl)[a_order])
        self.anchor_passive = f32(np.asarray(rig.anchor_passive)[a_order])
        self.att_node = i32(rig.att_node)
        self.att_seg = i32(rig.att_seg)
        self.att_uv = f32(rig.att_uv, wp.vec2)
        self.att_rest_length = f32(rig.att_rest_length)
        self.att_stiffness = f32(rig.weighted_stiffness())
        shift = np.zeros(len(rig.att_node))
        if node_amount is not None and len(rig.att_node):
            shift = np.asarray(node_amount, np.float64)[rig.att_node] - rig.attachment_jaw()
        self.att_jaw_shift = f32(shift)
        self.att_across = i32(rig.attachment_across())
        nodes_u, n_start, order = group_indices(rig.att_node)
        self.att_nodes_unique = i32(nodes_u)
        self.att_node_start = i32(n_start)
        self.att_order = i32(order)
        self.att_force = wp.zeros(len(order), dtype=wp.vec3, device=device)
        P, S, K = len(rig.ctrl_rest), len(rig.seg_curve), len(rig.att_node)
        self.ctrl_jawed = wp.zeros(P, dtype=wp.vec3, device=device)
        self.ctrl_contracted = wp.zeros(P, dtype=wp.vec3, device=device)
        self.seg_center = wp.zeros(S, dtype=wp.vec3, device=device)
        self.seg_frame = wp.zeros(S, dtype=wp.mat33, device=device)
        self.seg_radii = wp.zeros(S, dtype=wp.vec3, device=device)
        self.att_point = wp.zeros(K, dtype=wp.vec3, device=device)
        self.spring_stiffness = wp.zeros(K, dtype=float, device=device)
        self.springs = Springs(node=self.att_node, point=self.att_point, stiffness=self.spring_stiffness,
                               rest_length=self.att_rest_length)
        if jaw is not None:
            self.jaw_pivot, self.jaw_u, self.jaw_v = (wp.vec3(*map(float, a)) for a in (jaw.pivot, jaw.u_axis, jaw.v_axis))
        else:
            self.jaw_pivot, self.jaw_u, self.jaw_v = wp.vec3(0.0), wp.vec3(1.0, 0.0, 0.0), wp.vec3(0.0, 1.0, 0.0)

    @classmethod
    def from_model(cls, model: Model) -> MuscleStage:
        """The stage of ``model.muscles`` (:meth:`~facewarp._src.physics.model.ModelBuilder.add_muscles`)."""
        m = model.muscles
        joint = model.jaw.joint if model.jaw is not None else None
        return cls(m.rig, joint, model.device, node_amount=m.node_amount)

    def update_geometry(self, control, state) -> None:
        """Control points for ``control`` into ``state.muscle_ctrl`` and the ellipsoids (kernels
        1-3 of the module doc)."""
        wp = get_warp()
        km = self.km
        P = len(self.rig.ctrl_rest)
        if P == 0:
            return
        ctrl = state.muscle_ctrl
        if ctrl is None or ctrl.shape[0] != P:
            raise InputError(f"state.muscle_ctrl: expected {P} control points, got "
                             f"{0 if ctrl is None else ctrl.shape[0]} (make the State from a Model with these "
                             "muscles: ModelBuilder.add_muscles)")
        wp.launch(km._muscle_controls, dim=P,
                  inputs=[self.ctrl_rest, self.ctrl_muscle, self.ctrl_pivot, self.ctrl_jaw, self.muscle_activation,
                          self.muscle_contraction, self.muscle_saturation, self.muscle_center, self.muscle_center_jaw,
                          self.muscle_center_normal, self.muscle_glide, self.muscle_glide_center, self.jaw_pivot,
                          self.jaw_u, self.jaw_v,
                          control.activations, control.jaw_angles],
                  outputs=[self.ctrl_jawed, self.ctrl_contracted], device=self.device)
        wp.copy(ctrl, self.ctrl_contracted)
        if self.anchor_count:
            wp.launch(km._muscle_anchors, dim=self.anchor_count,
                      inputs=[self.anchor_start, self.anchor_ctrl, self.anchor_passive, self.ctrl_muscle,
                              self.muscle_activation, control.activations, self.ctrl_jawed, self.ctrl_contracted],
                      outputs=[ctrl], device=self.device)
        if len(self.rig.seg_curve):
            wp.launch(km._muscle_segments, dim=len(self.rig.seg_curve),
                      inputs=[self.curve_ctrl, self.curve_weight, self.curve_normal, self.seg_curve, self.seg_t,
                              self.seg_rest_radii, ctrl],
                      outputs=[self.seg_center, self.seg_frame, self.seg_radii], device=self.device)

    def apply(self, model: Model, state_in, control, dt, forces, targets) -> None:
        wp = get_warp()
        self.update_geometry(control, state_in)
        if len(self.rig.att_node):
            wp.launch(self.km._muscle_forces, dim=len(self.rig.att_node),
                      inputs=[self.att_node, self.att_seg, self.att_uv, self.att_rest_length, self.att_stiffness,
                              self.att_jaw_shift, self.att_across, self.jaw_pivot, self.jaw_u, self.jaw_v,
                              control.jaw_angles,
                              self.seg_center, self.seg_frame, self.seg_radii, state_in.positions],
                      outputs=[self.att_point, self.att_force], device=self.device)
            wp.launch(self.kt._gather, dim=len(self.att_nodes_unique),
                      inputs=[self.att_nodes_unique, self.att_node_start, self.att_order, self.att_force],
                      outputs=[forces], device=self.device)


    def prepare(self, model: Model, state_in, control, dt, targets) -> None:
        """Muscle geometry for ``control`` and the step's springs (attachment points, ``k_m w``)."""
        self.update_geometry(control, state_in)
        self.refresh(model, state_in.positions, control)

    def refresh(self, model: Model, positions, control) -> None:
        """The springs' fibre cosine ``w`` (and attachment points) at ``positions`` [m], (n,) wp.vec3.

        Implicit solvers call it after a solve so that the step ends with Eq. 6.4.1's cosine at
        its own end positions (a fixed point), not the start's.
        """
        if len(self.rig.att_node):
            get_warp().launch(self.km._muscle_springs, dim=len(self.rig.att_node),
                              inputs=[self.att_node, self.att_seg, self.att_uv, self.att_stiffness,
                                      self.att_jaw_shift, self.att_across, self.jaw_pivot, self.jaw_u, self.jaw_v,
                                      control.jaw_angles, self.seg_center, self.seg_frame, self.seg_radii,
                                      positions],
                              outputs=[self.att_point, self.spring_stiffness], device=self.device)


class SupportStage:
    """Sliding support of free inner-sheet nodes along their rest normal (solver stage).

    The inner sheet of the skin lies on deeper tissue: it may glide along it but not sink into
    it or lift off it. Each node gets a spring of ``stiffness`` [N/m] (one value, or one per
    node) acting only along its rest normal (the extrusion direction), moved with the jaw by its
    Eq. 6.4.9 amount: ``E = 1/2 k ((x - p0) . n)^2``. :meth:`apply` adds its forces (explicit
    solvers), :meth:`prepare` fills :attr:`springs` (implicit solvers).
    """

    @classmethod
    def from_model(cls, model: Model) -> SupportStage:
        """The stage of ``model.supports`` (:meth:`~facewarp._src.physics.model.ModelBuilder.add_supports`)."""
        s = model.supports
        return cls(model.jaw.joint, s.nodes, s.normals, s.amounts, s.stiffness, model.rest_positions, model.device)

    def __init__(self, jaw, nodes, normals, amounts, stiffness, rest_positions, device):
        wp = get_warp()
        from . import kernels_muscle as km

        self.km = km
        self.device = device
        self.count = len(nodes)
        self.nodes = wp.array(np.asarray(nodes, np.int32), dtype=wp.int32, device=device)
        n = np.asarray(normals, np.float64).reshape(-1, 3)
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        self.normals = wp.array(n.astype(np.float32), dtype=wp.vec3, device=device)
        self.amounts = wp.array(np.asarray(amounts, np.float32), dtype=float, device=device)
        k = np.broadcast_to(np.asarray(stiffness, np.float64), (self.count,))
        if not (np.isfinite(k).all() and (k >= 0).all()):
            raise InputError(f"support stiffness must be finite and >= 0 [N/m], got min {k.min() if len(k) else 0}")
        self.stiffness = wp.array(k.astype(np.float32), dtype=float, device=device)
        self.rest = rest_positions
        self.pivot, self.u, self.v = (wp.vec3(*map(float, a)) for a in (jaw.pivot, jaw.u_axis, jaw.v_axis))
        self.point = wp.zeros(self.count, dtype=wp.vec3, device=device)
        self.axis = wp.zeros(self.count, dtype=wp.vec3, device=device)
        self.springs = Springs(node=self.nodes, point=self.point, stiffness=self.stiffness, axis=self.axis)

    def apply(self, model: Model, state_in, control, dt, forces, targets) -> None:
        if self.count == 0:
            return
        get_warp().launch(self.km._support_forces, dim=self.count,
                     inputs=[self.nodes, self.normals, self.amounts, self.stiffness, self.rest, self.pivot, self.u,
                             self.v, control.jaw_angles, state_in.positions],
                     outputs=[forces], device=self.device)

    def prepare(self, model: Model, state_in, control, dt, targets) -> None:
        """The step's springs: jaw-moved anchors and axes."""
        if self.count == 0:
            return
        get_warp().launch(self.km._support_springs, dim=self.count,
                          inputs=[self.nodes, self.normals, self.amounts, self.rest, self.pivot, self.u, self.v,
                                  control.jaw_angles],
                          outputs=[self.point, self.axis], device=self.device)
