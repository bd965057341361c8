"""Muscles and supports as solver stages (kernel groups), with the NumPy references of the muscles.

:class:`~.muscle_rig.MuscleRig` (:mod:`.muscle_rig`) is the host-side (NumPy, SI) packing of any
set of muscles: control points, (rational) quadratic Bezier curves, ellipsoid segments, anchors
and skin attachments. The anatomy module fills it (:func:`facewarp._src.anatomy.muscle_rig`);
tests build small rigs by hand. :meth:`~facewarp._src.physics.builder.ModelBuilder.finalize` puts
its arrays on the device (:class:`~facewarp._src.physics.muscle_stage.MuscleArrays`,
:class:`~facewarp._src.physics.muscle_stage.SupportArrays`); :class:`MuscleStage` and
:class:`SupportStage` keep references to them (``from_model``; their constructors make the arrays
of a hand-made stage) and follow the solver's stage protocol: each substep they only launch
kernels (no allocation, no host read), so a frame can be captured.
"""

from __future__ import annotations

import numpy as np

from ..core.warp import get_warp
from ..core.errors import InputError
from .arrays import group_indices, head_ids, jaw_axes
from .model import Model
from .springs import Springs
from .muscle_rig import PIVOT_CENTER, PIVOT_FIXED, MuscleRig

__all__ = ["MuscleArrays", "MuscleRig", "MuscleStage", "SupportArrays", "SupportStage", "contraction_curve",
           "ellipsoid_uv", "rig_reference"]

# ---------------------------------------------------------------------------------------- device arrays
# What the stages' kernels read and write, made once by ModelBuilder.finalize (or by a stage's own
# constructor for a hand-made stage); a stage keeps references to them only.


class MuscleArrays:
    """The muscles on the device (:class:`~facewarp._src.physics.muscle_stage.MuscleStage`'s arrays).

    Model (read only), float32 / int32 copies of the rig's fields (:class:`~facewarp.physics.MuscleRig`,
    same names and units): ``ctrl_rest`` (P,) vec3 [m], ``ctrl_muscle``, ``ctrl_pivot`` (P,),
    ``ctrl_jaw`` (P,), ``muscle_activation``, ``muscle_contraction``, ``muscle_saturation``,
    ``muscle_center`` (M,) vec3 [m], ``muscle_center_jaw``, ``muscle_center_normal`` (M,) vec3,
    ``muscle_glide``, ``muscle_glide_center`` (M,) vec3 [m], ``curve_ctrl`` (C,) vec3i,
    ``curve_weight`` (C,) vec3, ``curve_normal`` (C,) vec3 (rest plane normals), ``seg_curve``
    (S,), ``seg_t`` (S,) vec2, ``seg_rest_radii`` (S,) vec3 [m]; anchors grouped (``anchor_count``,
    ``anchor_start`` (A + 1,), ``anchor_ctrl``, ``anchor_passive``); attachments ``att_node``,
    ``att_seg``, ``att_uv`` (K,) vec2, ``att_rest_length`` [m], ``att_stiffness`` [N/m] (after the
    area weights), ``att_jaw_shift`` (node amount less the muscle's), ``att_across`` (K,) int32,
    grouped per node (``att_nodes_unique``, ``att_node_start``, ``att_order``); ``jaw_pivot`` [m],
    ``jaw_u``, ``jaw_v`` (wp.vec3).

    Scratch (rewritten every step): ``ctrl_jawed``, ``ctrl_contracted`` (P,) vec3 [m];
    ``seg_center`` (S,) vec3 [m], ``seg_frame`` (S,) mat33, ``seg_radii`` (S,) vec3 [m];
    ``att_point`` (K,) vec3 [m], ``spring_stiffness`` (K,) [N/m], ``att_force`` (K,) vec3 [N];
    ``springs`` (:class:`Springs` over them).
    """

    def __init__(self, wp, rig, jaw, device, node_amount, weighted_stiffness, attachment_jaw, attachment_across,
                 curve_normals, *, ctrl_head=None, att_head=None, att_jaw_shift=None):
        f32 = lambda a, dt=float: wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=dt, device=device)  # noqa: E731
        i32 = lambda a, dt=wp.int32: wp.array(np.ascontiguousarray(a, dtype=np.int32), dtype=dt, device=device)  # noqa: E731
        self.rig = rig
        self.device = device
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
        self.curve_normal = f32(curve_normals, wp.vec3)
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
        self.att_stiffness = f32(weighted_stiffness)
        shift = np.zeros(len(rig.att_node))
        if att_jaw_shift is not None:
            shift = np.asarray(att_jaw_shift, np.float64)
        elif node_amount is not None and len(rig.att_node):
            shift = np.asarray(node_amount, np.float64)[rig.att_node] - attachment_jaw
        self.att_jaw_shift = f32(shift)
        self.ctrl_head = head_ids(wp, ctrl_head, len(rig.ctrl_rest), device)
        self.att_head = head_ids(wp, att_head, len(rig.att_node), device)
        self.att_across = i32(attachment_across)
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
        self.jaw_pivot, self.jaw_u, self.jaw_v = jaw_axes(wp, jaw, device)


class SupportArrays:
    """The sliding supports on the device (:class:`~facewarp._src.physics.muscle_stage.SupportStage`'s arrays).

    Model: ``count``; ``nodes`` (s,) int32; ``normals`` (s,) vec3 (unit rest normals); ``amounts``
    (s,) float32 (jaw amounts); ``stiffness`` (s,) float32 [N/m]; ``rest`` (vertex_count,) vec3 [m]
    (the Model's rest positions); ``pivot``, ``u``, ``v`` (wp.vec3: the jaw). Scratch: ``point``,
    ``axis`` (s,) vec3 (the step's anchors [m] and axes) and ``springs`` over them.
    """

    def __init__(self, wp, jaw, nodes, normals, amounts, stiffness, rest_positions, device, head=None):
        self.device = device
        self.count = len(nodes)
        self.head = head_ids(wp, head, self.count, device)
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
        self.pivot, self.u, self.v = jaw_axes(wp, jaw, device)
        self.point = wp.zeros(self.count, dtype=wp.vec3, device=device)
        self.axis = wp.zeros(self.count, dtype=wp.vec3, device=device)
        self.springs = Springs(node=self.nodes, point=self.point, stiffness=self.stiffness, axis=self.axis)



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
        springs: The springs of the current implicit step (:class:`~facewarp._src.physics.springs.Springs`).
    """

    def __init__(self, rig: MuscleRig, jaw, device, node_amount=None):
        """``node_amount`` (vertex_count,): the jaw amount (Eq. 6.4.9) of every tet node; with it,
        each spring's muscle end turns with the jaw by its node's amount rather than by the
        muscle's (:meth:`MuscleRig.attachment_jaw`), so opening the jaw alone pulls no node."""
        rig.validate()
        self._bind(MuscleArrays(get_warp(), rig, jaw, device, node_amount, rig.weighted_stiffness(), rig.attachment_jaw(),
                                rig.attachment_across(), rig.curve_normals()))

    def _bind(self, arrays: MuscleArrays) -> None:
        """Keep references to the muscles' device arrays (no copy) and the kernels."""
        from . import kernels_muscle as km
        from . import kernels_tissue as kt

        self.km, self.kt = km, kt
        vars(self).update(vars(arrays))

    @classmethod
    def from_model(cls, model: Model) -> MuscleStage:
        """The stage of ``model.muscles`` (:meth:`~facewarp._src.physics.builder.ModelBuilder.add_muscles`): references to
        the arrays :meth:`~facewarp._src.physics.builder.ModelBuilder.finalize` made."""
        st = cls.__new__(cls)
        st._bind(model.muscles.arrays)
        return st

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
                          self.muscle_center_normal, self.muscle_glide, self.muscle_glide_center, self.ctrl_head,
                          self.jaw_pivot,
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
                              self.att_jaw_shift, self.att_across, self.att_head, self.jaw_pivot, self.jaw_u, self.jaw_v,
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
                                      self.att_jaw_shift, self.att_across, self.att_head, self.jaw_pivot, self.jaw_u, self.jaw_v,
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
        """The stage of ``model.supports`` (:meth:`~facewarp._src.physics.builder.ModelBuilder.add_supports`):
        references to the arrays :meth:`~facewarp._src.physics.builder.ModelBuilder.finalize` made."""
        st = cls.__new__(cls)
        st._bind(model.supports.arrays)
        return st

    def __init__(self, jaw, nodes, normals, amounts, stiffness, rest_positions, device):
        self._bind(SupportArrays(get_warp(), jaw, nodes, normals, amounts, stiffness, rest_positions, device))

    def _bind(self, arrays: SupportArrays) -> None:
        """Keep references to the supports' device arrays (no copy) and the kernels."""
        from . import kernels_muscle as km

        self.km = km
        vars(self).update(vars(arrays))

    def apply(self, model: Model, state_in, control, dt, forces, targets) -> None:
        if self.count == 0:
            return
        get_warp().launch(self.km._support_forces, dim=self.count,
                     inputs=[self.nodes, self.normals, self.amounts, self.stiffness, self.rest, self.head, self.pivot, self.u,
                             self.v, control.jaw_angles, state_in.positions],
                     outputs=[forces], device=self.device)

    def prepare(self, model: Model, state_in, control, dt, targets) -> None:
        """The step's springs: jaw-moved anchors and axes."""
        if self.count == 0:
            return
        get_warp().launch(self.km._support_springs, dim=self.count,
                          inputs=[self.nodes, self.normals, self.amounts, self.rest, self.head, self.pivot, self.u, self.v,
                                  control.jaw_angles],
                          outputs=[self.point, self.axis], device=self.device)
