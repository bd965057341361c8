"""Contact of the skin with itself and the rigid parts: lips, teeth, eyeballs (solver stage).

The upper and lower lip may touch but never cross; lips and cheeks stay outside the teeth; lids
stay outside the eyeball. :class:`ContactStage` keeps these with one-sided penalty springs
(:class:`~facewarp._src.physics.springs.Springs` with ``one_sided``; their energy, gradient and
Hessian are in the solvers' kernels and in :mod:`.potential`):

* lip on lip: every node of one lip (:mod:`facewarp._src.anatomy.lips`: the skin within
  ``LIP_REACH`` of the mouth slit) against the closed surface of the other lip's tet region, a
  ``wp.Mesh`` refit to the current positions at every detection; a node within ``LIP_REACH_M``
  of it gets the half-space spring of its closest point (``kernels_contact._surface_contacts``);
* lip and cheek on teeth: inner-sheet nodes that are free and lie within ``TEETH_NEAR_M`` of a
  dental arch at rest, against that arch (a closed mesh; the upper teeth ride the cranium, the
  lower teeth turn with the jaw by the part's Eq. 6.4.9 amount);
* lid on eyeball: free nodes within ``EYE_NEAR_M`` of an eyeball's sphere, pushed out of the ball
  ``|x - c| >= r`` (analytic, static springs). The lids' inner sheet there glides on the eyeball
  (:func:`~facewarp._src.anatomy.contact.eyeball_sheet_nodes`): it has no planar sliding support
  (``face_rig``) but a two-sided spring of the support's stiffness that keeps each node on its glide
  sphere, and a one-sided floor there at the contact's stiffness (besides its one-sided contact), so
  the lid slides over the ball and neither sinks into it nor lifts off. The glide sphere
  (:func:`~facewarp._src.anatomy.contact.glide_spheres`) runs through the node's rest position and
  meets the fissure plane on the eyeball's surface: the two lids close at one depth, on the ball,
  whatever their depths at rest (a sphere about the eyeball's centre kept each at its rest depth: on
  the ICT-adapted heads the lower lid's inner sheet lies 0.5-1.5 mm deeper than the upper one's, up
  to 1 mm inside the ball's sphere, and the closed upper margin stayed up to 1.2 mm in front of the
  lower one; the floor: the ring pulls the lids into the ball with ~2.5 N, and on the support's
  stiffness alone the lower lid stopped 0.5 mm short of its sphere). A plane tangent at rest, as the
  sliding support of the cheeks, holds a node that slides 4-5 mm down a 12 mm ball against the
  ball's push (20-25 degrees off the plane): pulled back along the plane's normal, smoothed over 1
  cm and tilted laterally, the default head's upper lid went medially as it closed (with the ring's
  lopsided attachments, :func:`~facewarp._src.anatomy.attach.attach_by_area`: FDP 3.1 2.6 mm), and
  at level 1 the lid lifted off the ball (its margin 0.9 mm off, rolled forward in front of the
  lower one);
* lid on lid: the orbicularis oculi closes the lids toward the plane of the palpebral fissure
  (a sphincter with ``to_plane``: the plane through its centre with normal ``center_normal``,
  between its two fixed corners; :mod:`.kernels_muscle`), where the two lid margins meet. Every
  free node of the lids (between the corners, within twice the ring's height of the plane) keeps
  to its side of that plane: a static half-space spring ``gap / 2`` short of it, so the margins
  close to ``gap`` apart and stop there, however strongly the ring drives them (without it the
  upper lid slid past the lower one on the level-1 head; ``lid_contact_geometry``). The plane
  is static: a lid stops there even while the other is open (the presets move the lids that far
  only by the orbicularis oculi, which closes both). Along the fissure the closing margins meet
  point to point (``kernels_contact._lid_ties``): a lid node and its partner (the other lid's
  node nearest along the plane at rest), both within ``LID_TIE_REACH_M`` of their springs, are
  drawn together along the corner chord, their rest offset there shrinking with the gap between
  them (no force at rest, aligned when closed), at the glide stiffness. Without it the lids
  slid past each other along the plane once the ring pressed them together (the overshoot of
  its contraction 1.5): on the adapted heads the right upper lid ended 0.5-1.2 mm lateral of
  the lower one, the slide starting when the lids met (the right lower margin node 1.5 mm
  medially, its upper partner 0.45 mm; with the ring driven only to the plane, contraction 1.0,
  0.2 mm, but the lids stayed 2 mm open). At the contact's stiffness the ties stalled the CPU
  L-BFGS on the level-1 head (the lids stuck 1 mm apart).

The half-space springs sit ``gap`` (0.25 mm) outside the other surface, so a node that touches
with a force F stays ``gap - F / k`` outside it: the lips close without crossing as long as the
force per node stays below ``k gap``. Two lips in contact are held at their mid-plane (see
``kernels_contact._surface_contacts``). Detection runs in ``prepare`` (the step's start) and
again in ``refresh``: the CPU solvers call it at each solution and solve again while a contact
closed further (``SolverImplicit.contact_tolerance``), the device method before each Newton
iteration. It is kernels only (mesh refit and queries included): no host read, so a frame can be
captured in a CUDA graph. (Not run on a GPU yet: every kernel and the ``newton-pcg`` method with
contact were run on the CPU device.)

Stiffness (physical units): a node's spring is ``CONTACT_MODULUS * area + CONTACT_MUSCLE_RATIO *
k_m`` [N/m], with the node's sheet area (:func:`~facewarp._src.physics.tissue.sheet_areas`; the
median of its set for a node on no sheet) and k_m the muscle springs on the node (Eq. 6.4.1).
The area term (2e9 N/m^3, 50 times the muscles' modulus 4e7; ~2e4 N/m on a level-0 lip node,
about 20 times its edges' ``k0 / D0^2``) holds the skin that tissue pushes into contact (a lid
closing over the eyeball: 5e8 left 0.17 mm on ICT identity 002's blink, 2e9 0.08 mm); the muscle
term holds a node that its own muscle pulls into the obstacle (the orbicularis oculi pulls the
lids toward its ring centre, inside the eyeball; the orbicularis oris presses the lips together):
a muscle target d beyond the surface leaves ``d / 50`` of penetration, 0.1 mm for 5 mm. Stiffer
contact costs the CPU L-BFGS more iterations (its factorised model meets the contacts only at a
renewal); the gap keeps the real surface uncrossed while ``F / k`` stays below it. With the
thesis profile the base term is its hold stiffness; its muscles (1e7 N/m a node) pull the lips
through each other at the nodes next to the attached ones (a limitation, measured on pucker).
A lid-on-lid spring is ``LID_STIFFNESS_RATIO`` (4) times its node's: the lid margins are pressed
together by the ring's whole drive past the plane, mostly through tissue (the outer nodes carry
no muscle spring of their own), and at 1x the level-1 head's blink left 3 nodes 0.16 mm across.

:func:`contact_crossings` counts what the springs prevent, on any node positions: lip nodes
inside a tet of the other lip, nodes inside a dental arch, nodes inside an eyeball, lid nodes on
the other lid's side of the fissure plane.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.errors import InputError
from ..core.warp import get_warp
from .materials import CONTACT_MODULUS, CONTACT_MUSCLE_RATIO
from ..geometry.surface import winding_numbers
from ..geometry.tets import lip_crossings
from .arrays import head_ids, jaw_axes
from .springs import Springs

__all__ = ["CONTACT_GAP", "CONTACT_MODULUS", "CONTACT_MUSCLE_RATIO", "LIP_REACH_M", "TEETH_REACH_M", "ContactArrays",
           "ContactGeometry", "ContactStage", "ContactSurface", "contact_crossings", "contact_from_arrays", "contact_to_arrays"]

CONTACT_GAP = 2.5e-4
"""Distance [m] outside the other surface at which a half-space contact spring starts to push."""
LIP_REACH_M = 3.0e-3
"""Nodes within this distance [m] of the other lip's surface (inside or out) get a contact spring
(more than the lips' thickness, so a node anywhere inside is found)."""
TEETH_REACH_M = 4.0e-3
"""Candidates within this distance [m] of the arch (inside or out) get a contact spring."""
EYE_REST_SLACK_M = 5.0e-5
"""A lid node inside the eyeball's sphere (or within the gap of it) at rest may sink this much
[m] deeper before its spring pushes: an active set that starts exactly at rest would flicker
with every step of the solver (measured: 2x the iterations of laugh at level 0)."""
LID_STIFFNESS_RATIO = 4.0
"""A lid-on-lid spring is this many times the node's contact stiffness (module doc)."""
LID_TIE_REACH_M = 1.0e-3
"""A lid node and its partner across the fissure are tied along it while both lie within this
distance [m] of their half-space springs' planes (``kernels_contact._lid_ties``)."""
_ROUNDING_M = 1.0e-6  # float32 positions of ~0.1 m: a node "deeper than at rest" by less is rounding


@dataclass
class ContactGeometry:
    """What the contact stage needs of a face rig (host, NumPy; metres).

    Attributes:
        node_side: Lip of every tet node, +1 upper / -1 lower / 0 neither, shape (p,), int8.
        lip_faces: The closed surfaces of the upper and the lower lip's tet regions, outward
            triangles over tet nodes, shapes (b, 3), int64 (``[upper, lower]``).
        lip_nodes: Candidates against ``lip_faces[0]`` (lower-lip nodes) and ``lip_faces[1]``
            (upper-lip nodes), shape (c,), int64 each.
        teeth: ``[(name, V (t, 3), F (f, 3), jaw amount, candidate nodes (c,))]``.
        eyes: ``(centers (e, 3), radii (e,))``; eye_nodes (c,), eye_of_node (c,) index into eyes.
        eye_glide: Which of ``eye_nodes`` glide on their eyeball (inner-sheet nodes without a
            planar support, :func:`~facewarp._src.anatomy.contact.eyeball_sheet_nodes`), shape (c,), bool.
        glide_centers, glide_radii: The sphere each of ``eye_nodes`` glides on (used where
            ``eye_glide``): centre [m], shape (c, 3), and radius [m], shape (c,), float64
            (:func:`~facewarp._src.anatomy.contact.glide_spheres`; empty: the sphere about its
            eyeball's centre through its rest position).
        excluded: Candidates left out because they already touch or cross at rest, per kind
            (``{"lip_lip": n, "lip_teeth": n}``; a separated build has 0), and
            ``lid_eye_inside_at_rest``: lid nodes inside the eyeball's sphere at rest (kept, with
            their rest distance as the radius they may not go below); ``lid_lid``: lid nodes
            within ``2 gap`` of a fissure plane at rest (the lids' corners: no side to keep).
        lid_planes: The fissure planes, (point [m], unit normal) each, shape (l, 2, 3), float64.
        lid_nodes: Lid nodes kept to their side of a plane, shape (c,), int64.
        lid_plane: Their plane (index into ``lid_planes``), shape (c,), int64.
        lid_side: Their side at rest, +1 along the plane's normal, -1 against it, shape (c,), int8.
        lid_tangent: The fissure's unit direction in each lid node's plane (the corner chord
            without its normal part), shape (c, 3), float64.
        lid_partner: Each lid node's partner across the fissure (index into ``lid_nodes``: the
            other lid's node of its plane nearest to it along the plane at rest; -1 none),
            shape (c,), int64.
    """

    node_side: np.ndarray
    lip_faces: list
    lip_nodes: list
    teeth: list
    eye_centers: np.ndarray
    eye_radii: np.ndarray
    eye_nodes: np.ndarray
    eye_of_node: np.ndarray
    excluded: dict
    lid_planes: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    lid_nodes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    lid_plane: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    lid_side: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    eye_glide: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    lid_tangent: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    lid_partner: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    glide_centers: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    glide_radii: np.ndarray = field(default_factory=lambda: np.zeros(0))



_CONTACT_ARRAYS = ("node_side", "eye_centers", "eye_radii", "eye_nodes", "eye_of_node", "lid_planes", "lid_nodes",
                   "lid_plane", "lid_side", "eye_glide", "lid_tangent", "lid_partner", "glide_centers", "glide_radii")


def contact_to_arrays(g: ContactGeometry) -> dict:
    """The arrays of ``g`` for an ``.npz`` file, keys ``contact_*`` (:func:`contact_from_arrays`)."""
    out = {f"contact_{k}": np.asarray(getattr(g, k)) for k in _CONTACT_ARRAYS}
    for i, (S, nodes) in enumerate(zip(g.lip_faces, g.lip_nodes)):
        out[f"contact_lip_faces_{i}"] = np.asarray(S, np.int64)
        out[f"contact_lip_nodes_{i}"] = np.asarray(nodes, np.int64)
    out["contact_lip_count"] = np.array(len(g.lip_faces))
    out["contact_teeth_names"] = np.array([t[0] for t in g.teeth], dtype=str)
    for i, (_, TV, TF, amount, nodes) in enumerate(g.teeth):
        out[f"contact_teeth_{i}_V"], out[f"contact_teeth_{i}_F"] = np.asarray(TV, np.float64), np.asarray(TF, np.int64)
        out[f"contact_teeth_{i}_jaw"] = np.array(float(amount))
        out[f"contact_teeth_{i}_nodes"] = np.asarray(nodes, np.int64)
    out["contact_excluded_names"] = np.array(list(g.excluded), dtype=str)
    out["contact_excluded_counts"] = np.array([int(v) for v in g.excluded.values()], np.int64)
    return out


def contact_from_arrays(z) -> ContactGeometry:
    """The :class:`ContactGeometry` stored by :func:`contact_to_arrays` in ``z`` (a mapping of arrays)."""
    a = {k: np.asarray(z[f"contact_{k}"]) for k in _CONTACT_ARRAYS}
    lips = int(z["contact_lip_count"])
    teeth = [(str(name), np.asarray(z[f"contact_teeth_{i}_V"]), np.asarray(z[f"contact_teeth_{i}_F"]),
              float(z[f"contact_teeth_{i}_jaw"]), np.asarray(z[f"contact_teeth_{i}_nodes"]))
             for i, name in enumerate(z["contact_teeth_names"])]
    excluded = {str(k): int(v) for k, v in zip(z["contact_excluded_names"], z["contact_excluded_counts"])}
    return ContactGeometry(
        a["node_side"], [np.asarray(z[f"contact_lip_faces_{i}"]) for i in range(lips)],
        [np.asarray(z[f"contact_lip_nodes_{i}"]) for i in range(lips)], teeth, a["eye_centers"], a["eye_radii"],
        a["eye_nodes"], a["eye_of_node"], excluded, a["lid_planes"], a["lid_nodes"], a["lid_plane"], a["lid_side"],
        a["eye_glide"], a["lid_tangent"], a["lid_partner"], a["glide_centers"], a["glide_radii"])


def _geometry_of(fr, geometry):
    g = geometry if geometry is not None else getattr(fr, "contact", None)
    if g is None:
        raise InputError("geometry: the face rig has no contact geometry (made by facewarp.build_face or "
                         "`facewarp build`; an older build: rebuild it with `facewarp build`)")
    return g

def contact_crossings(fr, X=None, jaw_angles=(0.0, 0.0), *, geometry: ContactGeometry | None = None) -> dict:
    """Count the crossings the contact prevents, at node positions X.

    Args:
        fr: The :class:`~facewarp._src.physics.face_rig.FaceRig`.
        X: Tet node positions [m], shape (p, 3) (default the rest positions), head frame.
        jaw_angles: Jaw angles (u, v) [rad] of the lower teeth.
        geometry: The :class:`ContactGeometry` (default: ``fr.contact``, the rig's, computed at build time).

    Returns:
        ``{"lip_lip": nodes of one lip inside a tet of the other, "lip_lip_depth_m": the deepest,
        "lip_teeth": free nodes inside a dental arch, "lip_teeth_depth_m": the deepest, "lid_eye":
        free nodes inside an eyeball's sphere (deeper than at rest), "lid_eye_depth_m": the
        deepest, "lid_lid": lid nodes on the other side of their fissure plane (where the other
        lid closes to), "lid_lid_depth_m": the farthest}``.
    """
    from ..geometry.surface import closest_point

    Xr = np.asarray(fr.nodes, np.float64)
    X = Xr if X is None else np.asarray(X, np.float64)
    if X.shape != Xr.shape or not np.isfinite(X).all():
        raise InputError(f"X: expected finite node positions of shape {Xr.shape}, got {X.shape}")
    g = _geometry_of(fr, geometry)
    free = ~np.asarray(fr.fixed, bool)
    lip = lip_crossings(X, fr.tets, g.node_side, movable=free)
    teeth, teeth_depth = 0, 0.0
    for name, TV, TF, _, _ in g.teeth:
        TVj = fr.part_at(name, jaw_angles)
        lo, hi = TVj.min(0), TVj.max(0)
        cand = np.flatnonzero(free & (X >= lo).all(1) & (X <= hi).all(1))
        inside = cand[winding_numbers(TVj, TF, X[cand]) > 0.5]
        teeth += len(inside)
        if len(inside):
            teeth_depth = max(teeth_depth, float(closest_point(TVj, TF, X[inside]).dist.max()))
    eye, eye_depth = 0, 0.0
    if len(g.eye_centers):
        D = np.linalg.norm(X[:, None] - g.eye_centers[None], axis=2) - g.eye_radii[None]
        D0 = np.linalg.norm(Xr[:, None] - g.eye_centers[None], axis=2) - g.eye_radii[None]
        # deeper than at rest (a lid's inner sheet may start inside), beyond float32 rounding
        depth = np.maximum(np.minimum(D0, 0.0) - D - _ROUNDING_M, 0.0).max(axis=1) * free
        eye, eye_depth = int((depth > 0.0).sum()), float(depth.max(initial=0.0))
    lid, lid_depth = 0, 0.0
    if len(g.lid_nodes):
        C, N = g.lid_planes[g.lid_plane, 0], g.lid_planes[g.lid_plane, 1]
        depth = np.maximum(-g.lid_side * np.einsum("ij,ij->i", X[g.lid_nodes] - C, N) - _ROUNDING_M, 0.0)
        lid, lid_depth = int((depth > 0.0).sum()), float(depth.max())
    return {"lip_lip": lip["count"], "lip_lip_depth_m": float(lip["depth"].max(initial=0.0)),
            "lip_teeth": teeth, "lip_teeth_depth_m": teeth_depth, "lid_eye": eye, "lid_eye_depth_m": eye_depth,
            "lid_lid": lid, "lid_lid_depth_m": lid_depth}


class ContactStage:
    """Lip, teeth and eyeball contact as one-sided penalty springs (solver stage; module doc).

    Args:
        fr: The :class:`~facewarp._src.physics.face_rig.FaceRig` (or anything with ``nodes``
            (p, 3) [m] and, for the lower teeth, ``jaw``; with ``geometry`` given, e.g. by
            :func:`~facewarp._src.anatomy.contact.lip_contact_geometry`).
        node_stiffness: Contact stiffness of every tet node [N/m], shape (p,) (the simulator:
            ``CONTACT_MODULUS`` times the node's sheet area).
        device: Warp device.
        gap: Distance [m] outside a surface at which the half-space springs start to push.
        lips, teeth, eyes, lids: Which contacts to keep (all by default; ``eyes``: lid on eyeball,
            the gliding inner lid sheet included; ``lids``: lid on lid).
        ties: With ``lids``, tie the closing lid margins along the fissure
            (``kernels_contact._lid_ties``; default True).
        geometry: The :class:`ContactGeometry` (default: ``fr.contact``, the rig's, computed at build time).
        glide_stiffness: Stiffness of the two-sided spring that keeps a gliding inner lid node on
            its glide sphere [N/m], shape (p,) (the simulator: the sliding support's,
            ``support_modulus`` times the node's sheet area; default ``node_stiffness``), and of
            the lid ties. Its floor there and its one-sided eyeball contact have the node's
            ``node_stiffness``.

    Attributes:
        springs: The spring sets (a tuple of :class:`~facewarp._src.physics.springs.Springs`, all
            one-sided but the gliding lid sheet's and the ties): lower lip on upper, upper lip on
            lower, each dental arch, the eyeballs, the inner lid sheet gliding on them (two-sided)
            and its floor, the lids at their fissure planes, the lid ties along the fissures
            (two-sided axis springs).
        geometry: The :class:`ContactGeometry`.
    """

    allocates_on_refresh = True
    """:meth:`refresh` refits ``wp.Mesh`` BVHs, which allocates (an edge-length scan): the device
    solver refreshes this stage between the rounds of its Newton loop, not inside the loop (a
    conditional node of a CUDA graph may not allocate)."""

    def __init__(self, fr, node_stiffness, device, *, gap: float = CONTACT_GAP, lips: bool = True,
                 teeth: bool = True, eyes: bool = True, lids: bool = True, ties: bool = True,
                 geometry: ContactGeometry | None = None, glide_stiffness=None):
        from . import kernels_contact as kc

        self.kc = kc
        g = _geometry_of(fr, geometry)
        self._bind(ContactArrays(get_warp(), fr.nodes, node_stiffness, device, gap=gap, lips=lips, teeth=teeth, eyes=eyes,
                                 lids=lids, ties=ties, geometry=g, glide_stiffness=glide_stiffness,
                                 jaw=getattr(fr, "jaw", None)))

    def _bind(self, arrays: ContactArrays) -> None:
        """Keep references to the contact's device arrays (no copy)."""
        vars(self).update(vars(arrays))

    @classmethod
    def from_model(cls, model) -> ContactStage:
        """The contact of ``model.contact`` (:meth:`~facewarp._src.physics.builder.ModelBuilder.add_contacts`): references
        to the arrays :meth:`~facewarp._src.physics.builder.ModelBuilder.finalize` made."""
        from . import kernels_contact as kc

        st = cls.__new__(cls)
        st.kc = kc
        st._bind(model.contact.arrays)
        return st

    @property
    def counts(self) -> dict:
        """Candidate nodes per contact kind (host ints)."""
        g = self.geometry
        lips = sum(s.count for s in self.surfaces if s.follows is not None)
        teeth = sum(s.count for s in self.surfaces if s.rigid is not None)
        return {"lip_lip": lips, "lip_teeth": teeth, "lid_eye": self.eye_count, "lid_glide": self.glide_count,
                "lid_lid": self.lid_count, "lid_tie": self.tie_count, "excluded": dict(g.excluded)}

    def _move_rigid(self, control) -> None:
        wp = get_warp()
        for s in self.surfaces:
            if s.rigid is not None and s.amount != 0.0:
                wp.launch(self.kc._rigid_points, dim=len(s.rest),
                          inputs=[s.rest, s.amounts, s.point_head, s.head_shift, self.pivot, self.u, self.v,
                                  control.jaw_angles],
                          outputs=[s.points], device=self.device)
                s.mesh.refit()

    def refresh(self, model, positions, control) -> None:
        """Contacts at ``positions`` [m], (p,) wp.vec3: the lips' surfaces refit to them, every
        candidate's closest point and direction (the active set between implicit iterations)."""
        wp = get_warp()
        kc = self.kc
        for s in self.surfaces:
            if s.count == 0:
                continue
            if s.follows is not None:
                wp.launch(kc._gather_points, dim=len(s.follow), inputs=[s.follow, s.point_head, s.head_shift, positions],
                          outputs=[s.points], device=self.device)
                s.mesh.refit()
            sp = s.springs
            wp.launch(kc._surface_contacts, dim=s.count,
                      inputs=[s.mesh.id, s.reach, s.gap, int(s.follows is not None), s.nodes, s.k, s.node_head,
                              s.head_shift, positions],
                      outputs=[sp.point, sp.axis, sp.stiffness], device=self.device)
        if self.tie_count:
            sp, st = self.lid_springs, self.tie_springs
            wp.launch(kc._lid_ties, dim=self.tie_count,
                      inputs=[sp.node, self.tie_partner, self.tie_offset, self.tie_rest, sp.point, sp.axis,
                              LID_TIE_REACH_M, self.tie_stiffness, positions],
                      outputs=[st.point, st.stiffness], device=self.device)

    def prepare(self, model, state_in, control, dt, targets) -> None:
        """Implicit solvers: the teeth at the step's jaw angles, contacts at the step's start."""
        self._move_rigid(control)
        self.refresh(model, state_in.positions, control)

    def apply(self, model, state_in, control, dt, forces, targets) -> None:
        """Explicit solvers: detect at ``state_in`` and add the one-sided spring forces."""
        wp = get_warp()
        self.prepare(model, state_in, control, dt, targets)
        for s in self.surfaces:
            if s.count:
                sp = s.springs
                wp.launch(self.kc._half_space_forces, dim=s.count,
                          inputs=[sp.node, sp.point, sp.axis, sp.stiffness, 1, state_in.positions], outputs=[forces],
                          device=self.device)
        for count, sp, one in ((self.eye_count, getattr(self, "eye_springs", None), 1),
                               (self.glide_count, getattr(self, "glide_springs", None), 0),
                               (self.glide_count, getattr(self, "floor_springs", None), 1)):
            if count:
                wp.launch(self.kc._sphere_forces, dim=count,
                          inputs=[sp.node, sp.point, sp.rest_length, sp.stiffness, one, state_in.positions],
                          outputs=[forces], device=self.device)
        # a lid node lies on one plane only: one spring per node in the set; the ties' points were
        # detected in prepare (two-sided)
        for count, sp, one in ((self.lid_count, getattr(self, "lid_springs", None), 1),
                               (self.tie_count, getattr(self, "tie_springs", None), 0)):
            if count:
                wp.launch(self.kc._half_space_forces, dim=count,
                          inputs=[sp.node, sp.point, sp.axis, sp.stiffness, one, state_in.positions],
                          outputs=[forces], device=self.device)


# ---------------------------------------------------------------------------------------- device arrays
# The contact's host-side assembly (each head's candidates and springs, then every head's rows in one set)
# and its device arrays, made once by ModelBuilder.finalize; ContactStage keeps references to them.


class ContactSurface:
    """Candidate nodes against one closed surface: its ``wp.Mesh`` and the nodes' springs (contact scratch).

    With several heads the surface of every head is one mesh: head h's points are moved by its
    query shift ``head_shift[h]`` (``kernels_contact._gather_points``), so a node (moved by its
    head's shift for the query) finds only its own head's surface; head 0's shift is 0."""

    def __init__(self, wp, nodes, k, surface_points, faces, device, reach, gap, *, follows=None, rigid=None,
                 node_head=None, point_head=None, head_shift=None):
        self.count = len(nodes)
        self.reach, self.gap = float(reach), float(gap)
        self.follows = follows  # node indices the surface points are (a lip), or None
        self.rigid = rigid  # (rest points, jaw amount per point) of a rigid part, or None
        self.nodes = wp.array(np.asarray(nodes, np.int32), dtype=wp.int32, device=device)
        self.k = wp.array(np.asarray(k, np.float32), dtype=float, device=device)
        npt = len(surface_points)
        ph = np.zeros(npt, np.int32) if point_head is None else np.asarray(point_head, np.int32)
        shift = np.zeros((1, 3), np.float64) if head_shift is None else np.asarray(head_shift, np.float64)
        self.node_head = head_ids(wp, node_head, self.count, device)
        self.point_head = head_ids(wp, ph, npt, device)
        self.head_shift = wp.array(shift.astype(np.float32), dtype=wp.vec3, device=device)
        P = np.asarray(surface_points, np.float32)
        if head_shift is not None and np.any(shift):  # the points in the query space (as the kernels move them)
            P = (P + shift.astype(np.float32)[ph]).astype(np.float32)
        self.points = wp.array(P, dtype=wp.vec3, device=device)
        if rigid is not None:
            self.rest = wp.array(np.asarray(rigid[0], np.float32), dtype=wp.vec3, device=device)
            amt = np.broadcast_to(np.asarray(rigid[1], np.float64), (npt,))
            self.amount = float(np.abs(amt).max(initial=0.0))  # 0: the part never moves
            self.amounts = wp.array(amt.astype(np.float32), dtype=float, device=device)
        if follows is not None:
            self.follow = wp.array(np.asarray(follows, np.int32), dtype=wp.int32, device=device)
        self.mesh = wp.Mesh(points=self.points, indices=wp.array(np.asarray(faces, np.int32).ravel(), dtype=wp.int32,
                                                                   device=device))
        self.springs = Springs(node=self.nodes, point=wp.zeros(self.count, dtype=wp.vec3, device=device),
                               stiffness=wp.zeros(self.count, dtype=float, device=device),
                               axis=wp.zeros(self.count, dtype=wp.vec3, device=device), one_sided=True)


def _contact_head(g, X, kn, kg, gap, *, lips, teeth, eyes, lids, ties) -> dict:
    """One head's contact on the host (float64, its own node indices): the surfaces' candidates,
    the eyeball, glide, floor, lid and tie springs (:class:`ContactArrays`)."""
    def stiff(nodes):
        k = kn[nodes]
        pos = k[k > 0]
        return np.where(k > 0, k, np.median(pos) if len(pos) else 0.0)

    out = {"surfaces": []}
    if lips:
        for S, nodes in zip(g.lip_faces, g.lip_nodes):
            if len(S) == 0 or len(nodes) == 0:
                continue
            used, local = np.unique(S, return_inverse=True)
            out["surfaces"].append(dict(kind="lip", nodes=np.asarray(nodes, np.int64), k=stiff(nodes), points=X[used],
                                        faces=local.reshape(-1, 3), reach=LIP_REACH_M, follows=used))
    if teeth:
        for name, TV, TF, amount, nodes in g.teeth:
            if len(nodes):
                out["surfaces"].append(dict(kind=f"teeth:{name}", nodes=np.asarray(nodes, np.int64), k=stiff(nodes),
                                            points=np.asarray(TV, np.float64), faces=np.asarray(TF),
                                            reach=TEETH_REACH_M, amount=float(amount)))
    glide = np.asarray(g.eye_glide, bool)
    if len(glide) != len(g.eye_nodes):
        glide = np.zeros(len(g.eye_nodes), bool)
    en = np.asarray(g.eye_nodes, np.int64)
    d_rest = np.linalg.norm(X[en] - g.eye_centers[g.eye_of_node], axis=1) if len(en) else np.zeros(0)
    if eyes and len(en):
        # a node inside the ball (or within the gap) at rest gets its rest distance less
        # EYE_REST_SLACK_M: no force at rest, and it may not sink deeper
        r = np.minimum(g.eye_radii[g.eye_of_node] + gap, d_rest - EYE_REST_SLACK_M)
        out["eye"] = (en, g.eye_centers[g.eye_of_node], stiff(en), r)
    if eyes and glide.any():
        # the inner lid sheet glides on the eyeball: on its glide sphere (glide_spheres; about
        # the eyeball's centre through its rest position where none is given), two-sided at
        # the sliding support's stiffness, and it may not sink below that sphere (one-sided at
        # its contact stiffness, EYE_REST_SLACK_M short of it); the contact above keeps it out
        # of the ball
        if len(g.glide_centers) == len(en) and len(g.glide_radii) == len(en):
            gc, gr = np.asarray(g.glide_centers, np.float64), np.asarray(g.glide_radii, np.float64)
        else:
            gc, gr = g.eye_centers[g.eye_of_node], d_rest
        out["glide"] = (en[glide], gc[glide], kg[en[glide]], gr[glide])
        out["floor"] = (en[glide], gc[glide], stiff(en)[glide], (gr - EYE_REST_SLACK_M)[glide])
    if lids and len(g.lid_nodes):
        ln = np.asarray(g.lid_nodes, np.int64)
        c, n = g.lid_planes[g.lid_plane, 0], g.lid_planes[g.lid_plane, 1]
        a = g.lid_side[:, None] * n  # toward the node's own side
        # the plane gap / 2 short of the fissure plane (the two margins stop gap apart; a
        # node nearer at rest, with a geometry made for a smaller gap, keeps its rest distance)
        r = np.minimum(0.5 * gap, np.einsum("ij,ij->i", X[ln] - c, a))
        out["lid"] = (ln, c + r[:, None] * a, LID_STIFFNESS_RATIO * stiff(ln), a)
        partner = np.asarray(g.lid_partner, np.int64)
        if ties and len(partner) == len(ln) and len(g.lid_tangent) == len(ln) and (partner >= 0).any():
            # margins that close meet point to point along the fissure (kernels_contact._lid_ties),
            # held as firmly as the inner sheet on its support (the glide stiffness: the
            # contact's stiffness there stalled the CPU L-BFGS on the level-1 head)
            mate = np.maximum(partner, 0)
            off = 0.5 * (X[ln] - X[ln[mate]])
            above = np.einsum("ij,ij->i", X[ln] - c, a) - r  # from the node's spring plane at rest
            out["ties"] = (partner, above + above[mate], off, kg[ln], np.asarray(g.lid_tangent, np.float64))
    return out


def _query_shifts(points: list, reach: float) -> np.ndarray:
    """Each head's shift into its own cell of the contact query space [m], (H, 3), float64:
    head h at cell (i, j, k) of a cube grid (head 0 at the origin, unshifted), the cells wider
    than every head's contact points and twice the reach, so no head's query reaches another's."""
    H = len(points)
    if H == 1:
        return np.zeros((1, 3))
    allp = np.concatenate([np.asarray(p, np.float64).reshape(-1, 3) for p in points if len(p)] or [np.zeros((1, 3))])
    lo, hi = allp.min(0), allp.max(0)
    cell = float((hi - lo).max()) + 2.0 * reach + 0.01
    side = int(np.ceil(H ** (1.0 / 3.0) - 1e-9))
    h = np.arange(H)
    return np.stack([h % side, (h // side) % side, h // (side * side)], 1) * cell


class ContactArrays:
    """The contact on the device (:class:`~facewarp._src.physics.contact.ContactStage`'s arrays;
    the arguments are the stage's, with ``nodes`` the rest positions [m], (p, 3), and ``jaw`` the
    joint the lower teeth turn with, or None). Several heads: ``nodes``, ``node_stiffness``,
    ``geometry``, ``glide_stiffness`` and ``jaw`` lists of one per head, ``node_offsets`` (H,)
    each head's first node in the Model (the heads' surfaces must be alike: the same lips and
    teeth in the same order, e.g. heads of one template).

    Model: ``geometry`` (the :class:`~facewarp._src.physics.contact.ContactGeometry`; the first
    head's), ``pivot``, ``u``, ``v`` (wp.array (H,) of wp.vec3: the jaws); per obstacle surface a
    :class:`ContactSurface` in ``surfaces`` (its candidate nodes, stiffness [N/m], points [m] and
    ``wp.Mesh``, every head's in one); counts ``eye_count``, ``glide_count``, ``lid_count``,
    ``tie_count``; the lid ties' ``tie_rest`` [m], ``tie_partner``, ``tie_offset`` [m],
    ``tie_stiffness`` [N/m]. The spring sets (``eye_springs``, ``glide_springs``,
    ``floor_springs``, ``lid_springs``, ``tie_springs``; all in ``springs``): fixed nodes and
    stiffness, their points, axes and stiffness the detection's scratch.
    """

    def __init__(self, wp, nodes, node_stiffness, device, *, gap=None, lips=True, teeth=True, eyes=True, lids=True,
                 ties=True, geometry=None, glide_stiffness=None, jaw=None, node_offsets=None):
        gap = CONTACT_GAP if gap is None else gap
        self.device = device
        if not (np.isfinite(gap) and gap >= 0.0):
            raise InputError(f"gap: expected a finite distance >= 0 [m], got {gap!r}")
        multi = isinstance(geometry, (list, tuple))
        geos = list(geometry) if multi else [geometry]
        H = len(geos)
        Xs = list(nodes) if multi else [nodes]
        kns = list(node_stiffness) if multi else [node_stiffness]
        kgs = list(glide_stiffness) if multi else [glide_stiffness]
        jaws = list(jaw) if multi else [jaw]
        offs = np.zeros(1, np.int64) if node_offsets is None else np.asarray(node_offsets, np.int64)
        heads, seen = [], {}
        for h in range(H):
            key = (id(geos[h]), id(Xs[h]), id(kns[h]), id(kgs[h]))  # heads of one rig: computed once
            if key in seen:
                heads.append(seen[key])
                continue
            X = np.asarray(Xs[h], np.float64)
            kn = np.asarray(kns[h], np.float64)
            if kn.shape != (len(X),) or not (np.isfinite(kn).all() and (kn >= 0).all()):
                raise InputError(f"node_stiffness: expected finite values >= 0 of shape ({len(X)},) [N/m]")
            kg = kn if kgs[h] is None else np.asarray(kgs[h], np.float64)
            if kg.shape != (len(X),) or not (np.isfinite(kg).all() and (kg >= 0).all()):
                raise InputError(f"glide_stiffness: expected finite values >= 0 of shape ({len(X)},) [N/m]")
            heads.append(_contact_head(geos[h], X, kn, kg, gap, lips=lips, teeth=teeth, eyes=eyes, lids=lids,
                                       ties=ties))
            seen[key] = heads[-1]
        g = geos[0]
        self.geometry = g
        self.geometries = geos
        self.pivot, self.u, self.v = jaw_axes(wp, jaws if multi else jaw, device)

        # the surfaces: the k-th of every head in one mesh (the heads shifted apart for the queries)
        kinds = [tuple(s["kind"] for s in hd["surfaces"]) for hd in heads]
        if any(k != kinds[0] for k in kinds):
            bad = next(h for h, k in enumerate(kinds) if k != kinds[0])
            raise InputError(f"contact of head {bad}: its lip and teeth surfaces {list(kinds[bad])} differ from head "
                             f"0's {list(kinds[0])}; heads of one Model need alike contact surfaces")
        reach = max([s["reach"] for hd in heads for s in hd["surfaces"]] or [0.0])
        shift = _query_shifts([np.concatenate([s["points"] for s in hd["surfaces"]] or [np.zeros((0, 3))])
                               for hd in heads], reach)
        self.head_shift = shift
        self.surfaces: list[ContactSurface] = []
        for j in range(len(kinds[0])):
            parts = [hd["surfaces"][j] for hd in heads]
            s0 = parts[0]
            pts, fcs, nds, ks, nh, ph, fol, amt = [], [], [], [], [], [], [], []
            p0 = 0
            for h, s in enumerate(parts):
                npt = len(s["points"])
                pts.append(s["points"])
                fcs.append(np.asarray(s["faces"], np.int64) + p0)
                nds.append(s["nodes"] + offs[h])
                ks.append(s["k"])
                nh.append(np.full(len(s["nodes"]), h))
                ph.append(np.full(npt, h))
                if s0["kind"] == "lip":
                    fol.append(s["follows"] + offs[h])
                else:
                    amt.append(np.full(npt, s["amount"]))
                p0 += npt
            cat = np.concatenate
            lip = s0["kind"] == "lip"
            self.surfaces.append(ContactSurface(
                wp, cat(nds), cat(ks), cat(pts), cat(fcs), device, s0["reach"], gap,
                follows=cat(fol) if lip else None, rigid=None if lip else (cat(pts), cat(amt)),
                node_head=cat(nh), point_head=cat(ph), head_shift=shift))
        sets = [s.springs for s in self.surfaces]

        def gather(key, n_items):
            """The heads' rows of one set, node indices shifted; None when no head has it."""
            rows = [(h, hd[key]) for h, hd in enumerate(heads) if key in hd]
            if not rows:
                return None
            out = []
            for i in range(n_items):
                out.append(np.concatenate([r[i] + (offs[h] if i == 0 else 0) for h, r in rows]))
            return out

        def sphere_set(parts, one_sided):
            en, c, k, r = parts
            return Springs(node=wp.array(en.astype(np.int32), dtype=wp.int32, device=device),
                           point=wp.array(c.astype(np.float32), dtype=wp.vec3, device=device),
                           stiffness=wp.array(k.astype(np.float32), dtype=float, device=device),
                           rest_length=wp.array(r.astype(np.float32), dtype=float, device=device),
                           one_sided=one_sided)

        eye, glide, floor = gather("eye", 4), gather("glide", 4), gather("floor", 4)
        self.eye_count = 0 if eye is None else len(eye[0])
        self.glide_count = 0 if glide is None else len(glide[0])
        if self.eye_count:
            self.eye_springs = sphere_set(eye, True)
            sets.append(self.eye_springs)
        if self.glide_count:
            self.glide_springs = sphere_set(glide, False)
            self.floor_springs = sphere_set(floor, True)
            sets += [self.glide_springs, self.floor_springs]
        lid = gather("lid", 4)
        self.lid_count = 0 if lid is None else len(lid[0])
        self.tie_count = 0
        if self.lid_count:
            ln, point, k, a = lid
            self.lid_springs = Springs(
                node=wp.array(ln.astype(np.int32), dtype=wp.int32, device=device),
                point=wp.array(point.astype(np.float32), dtype=wp.vec3, device=device),
                stiffness=wp.array(k.astype(np.float32), dtype=float, device=device),
                axis=wp.array(a.astype(np.float32), dtype=wp.vec3, device=device), one_sided=True)
            sets.append(self.lid_springs)
            if any("ties" in hd for hd in heads):
                # every head's lid rows, its partners shifted by its first lid row (none: no partner)
                partner, rest, off, kt, tan = [], [], [], [], []
                l0 = 0
                for hd in heads:
                    if "lid" not in hd:
                        continue
                    m = len(hd["lid"][0])
                    if "ties" in hd:
                        p, r, o, k_, t = hd["ties"]
                        partner.append(np.where(p >= 0, p + l0, -1))
                        rest += [r]
                        off += [o]
                        kt += [k_]
                        tan += [t]
                    else:
                        partner.append(np.full(m, -1))
                        rest += [np.zeros(m)]
                        off += [np.zeros((m, 3))]
                        kt += [np.zeros(m)]
                        tan += [np.zeros((m, 3))]
                    l0 += m
                cat = np.concatenate
                self.tie_count = self.lid_count
                self.tie_rest = wp.array(cat(rest).astype(np.float32), dtype=float, device=device)
                self.tie_partner = wp.array(cat(partner).astype(np.int32), dtype=wp.int32, device=device)
                self.tie_offset = wp.array(cat(off).astype(np.float32), dtype=wp.vec3, device=device)
                self.tie_stiffness = wp.array(cat(kt).astype(np.float32), dtype=float, device=device)
                self.tie_springs = Springs(
                    node=self.lid_springs.node, point=wp.zeros(self.lid_count, dtype=wp.vec3, device=device),
                    stiffness=wp.zeros(self.lid_count, dtype=float, device=device),
                    axis=wp.array(cat(tan).astype(np.float32), dtype=wp.vec3, device=device))
                sets.append(self.tie_springs)
        self.springs = tuple(sets)
