"""A head ready to simulate: anatomy -> solver inputs, the simulation loop and its frames.

:class:`FaceRig` packs everything the solver needs (NumPy, SI) and is what ``facewarp build``
saves (``face_rig.npz``) and ``facewarp simulate`` loads. :class:`FaceSimulator` turns it into a
Model, a Verlet solver with the muscle and jaw stages, and plays an expression
:class:`~facewarp._src.expressions.Timeline` frame by frame; :class:`Frames` is the frame stream
the exporters consume.

Boundary conditions (Sec. 6.2, 6.4): only the frontal face is simulated. Skin nodes on the
frontal region's border (outer and inner sheet) are fixed. Inner-sheet nodes of the regions over
bone (:data:`BONE_REGIONS`: forehead, nose, chin, bottom face) that are not attached to a muscle
are held by stiff springs at their rest position, which the jaw moves for the jaw regions
(Eq. 6.4.9 amounts). Cheeks, lips and lids glide over soft tissue, teeth and eyeballs and are
free, as are the nodes attached to muscles and the whole outer sheet.
"""

from __future__ import annotations

import io
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError
from .expressions import MUSCLES, Timeline
from .fileio import atomic_write
from .jaw import JawKinematic
from .muscle_stage import MuscleRig
from .template import REGIONS

__all__ = ["FaceRig", "FaceSimulator", "Frames", "face_rig_from_anatomy", "load_face_rig", "node_jaw_amounts", "save_face_rig",
           "MUSCLE_STIFFNESS", "BONE_REGIONS", "save_frames_npz"]

MUSCLE_STIFFNESS = 1.0e7
"""Default muscle spring stiffness k_m of Eq. 6.4.1 [N/m] in the solver's unit system (node mass
0.5, Table 6.3), shared by the springs on a node: chosen so that the Table 6.4 presets move the
lip corners and brows by several mm. It is 3-10 times the tissue's own ``k0 / D0^2`` at level 0,
so the inner sheet follows the muscles almost kinematically; 2e6 would spare the thin lip corner
of some scan-adapted heads (ICT identity 002, angry) but leaves the brows of the default head
too weak to rise against an opening jaw (surprise)."""

JAW_SMOOTHING = 0.02
"""Length [m] over which the jaw amount of Eq. 6.4.9 is smoothed across region borders."""

EDGE_DAMPING = 500.0
"""Dashpot along every tet edge [N s/m] (Eq. 6.4.5 on the relative velocity). Table 6.3's
per-substep damping alone leaves the stiff skin ringing for many periods when the jaw moves the
held nodes; about a quarter of the edges' critical damping 2 sqrt(k0 / D0^2 m) calms it without
slowing rigid motion (and stays far below the explicit limit 2 m / dt)."""

BONE_REGIONS = ("nose", "chin", "bottom_face")
"""Regions whose inner sheet lies on bone and is held (unless attached to a muscle)."""


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

    @property
    def jaw(self) -> JawKinematic:
        return JawKinematic(self.jaw_pivot, self.jaw_u, self.jaw_v, self.lip_corners, self.mouth_center)

    @property
    def muscle_names(self) -> list[str]:
        return list(self.rig.names)


# ------------------------------------------------------------------------------------ building
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
    from .geometry import boundary_vertices

    cut = np.zeros(n, bool)
    cut[boundary_vertices(F, n)] = True
    cut &= neck_v & (head.vertices[:, 1] < np.percentile(head.vertices[neck_v, 1], 20))
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
    head, skin, ms = anatomy.head, anatomy.skin, anatomy.muscles
    lm = head.landmarks()
    jaw = JawKinematic.from_landmarks(head.condyles, lm)
    v_amount = _vertex_region_amounts(head, jaw)

    # --- boundary conditions
    frontal_v = np.zeros(len(head.vertices), bool)
    frontal_v[np.unique(head.faces[head.frontal])] = True
    other_v = np.zeros(len(head.vertices), bool)
    other_v[np.unique(head.faces[~head.frontal])] = True
    border_v = frontal_v & other_v
    src = skin.source_vertex
    fixed = border_v[src]
    inner = skin.layer == skin.layer.max()
    attached = np.zeros(len(skin.vertices), bool)
    for m in ms.muscles:
        if m.attachment is not None:
            attached[m.attachment.nodes] = True
    # over bone: the forehead (frontal bone), nose (nasal bone and cartilage), chin and the bottom
    # face (mandible); the cheeks (buccal space), lips and lids glide freely over soft tissue,
    # teeth and eyeballs
    bone_ids = [REGIONS.index(r) for r in BONE_REGIONS]
    Ff = head.faces.ravel()
    on_bone = np.bincount(Ff, weights=np.repeat(np.isin(head.face_region, bone_ids), 3).astype(float),
                          minlength=len(head.vertices)) / np.maximum(np.bincount(Ff, minlength=len(head.vertices)), 1)
    held = inner & ~attached & ~fixed & (on_bone[src] >= 0.5)
    jaw_amount_node = v_amount[src]
    jaw_nodes = np.where((held | fixed) & (jaw_amount_node > 0))[0]
    support_nodes = np.where(inner & ~held & ~fixed)[0]

    # --- muscles (packed by the anatomy stage, with Eq. 6.4.9 jaw amounts)
    from .anatomy import muscle_rig

    rig = muscle_rig(ms, stiffness=muscle_stiffness, head=head, vertex_amount=v_amount)
    # a node tied to several muscles (the modiolus at the lip corner has five) shares k_m among
    # them, so no node is pulled by more than one muscle's stiffness in total
    per_node = np.bincount(rig.att_node, minlength=len(skin.vertices))
    rig.att_stiffness = rig.att_stiffness / np.maximum(per_node[rig.att_node], 1)

    ids = list(head.fdp)
    parts = dict(getattr(head, "parts", {}) or {})
    part_jaw = {k: (1.0 if k in ("teeth_lower", "tongue") else 0.0) for k in parts}
    layer = (skin.layer > 0).astype(np.int32)
    return FaceRig(
        head_vertices=np.asarray(head.vertices, float), head_faces=np.asarray(head.faces), nodes=skin.vertices,
        tets=skin.tets, layer=layer, surface_vertex=skin.surface_vertex, fixed=fixed, held=held,
        jaw_nodes=jaw_nodes, jaw_amount=jaw_amount_node[jaw_nodes], support_nodes=support_nodes,
        support_normal=skin.direction[support_nodes], support_amount=jaw_amount_node[support_nodes], jaw_pivot=jaw.pivot, jaw_u=jaw.u_axis,
        jaw_v=jaw.v_axis, lip_corners=jaw.lip_corners, mouth_center=jaw.mouth_center, rig=rig,
        fdp_ids=np.array(ids), fdp_part=np.array([head.fdp[i][0] for i in ids]),
        fdp_face=np.array([int(head.fdp[i][1].face[0]) for i in ids]),
        fdp_bary=np.array([head.fdp[i][1].bary[0] for i in ids]), parts=parts, part_jaw=part_jaw,
        vertex_jaw=v_amount,
        level=int(getattr(head, "level", -1)),
    )


_RIG_FIELDS = ("activation_index", "contraction", "center", "center_jaw", "ctrl_rest", "ctrl_muscle", "ctrl_pivot",
               "ctrl_jaw", "curve_ctrl", "curve_weight", "seg_curve", "seg_t", "seg_rest_radii", "anchor_dst",
               "anchor_src", "anchor_weight", "att_node", "att_seg", "att_uv", "att_rest_length", "att_stiffness")
_FACE_FIELDS = ("head_vertices", "head_faces", "nodes", "tets", "layer", "surface_vertex", "fixed", "held", "jaw_nodes",
                "jaw_amount", "support_nodes", "support_normal", "support_amount", "jaw_pivot", "jaw_u", "jaw_v", "lip_corners", "mouth_center", "fdp_ids", "fdp_part",
                "fdp_face", "fdp_bary", "vertex_jaw")


def save_face_rig(path, fr: FaceRig) -> Path:
    """Write ``fr`` to one ``.npz`` file atomically."""
    arrays = {k: getattr(fr, k) for k in _FACE_FIELDS}
    arrays.update({f"rig_{k}": getattr(fr.rig, k) for k in _RIG_FIELDS})
    arrays["rig_names"] = np.array(fr.rig.names)
    arrays["level"] = np.array(fr.level)
    arrays["part_names"] = np.array(list(fr.parts))
    for k, (V, F) in fr.parts.items():
        arrays[f"part_{k}_V"], arrays[f"part_{k}_F"] = V, F
        arrays[f"part_{k}_jaw"] = np.array(fr.part_jaw.get(k, 0.0))
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    with atomic_write(path, "wb", encoding=None) as f:
        f.write(buf.getvalue())
    return Path(path)


def load_face_rig(path) -> FaceRig:
    """Read a file written by :func:`save_face_rig` (a ``facewarp build`` output)."""
    path = Path(path)
    if path.is_dir():
        path = path / "face_rig.npz"
    if not path.is_file():
        raise InputError(f"{path}: not found (HEAD must be a `facewarp build` output folder)")
    try:
        z = np.load(path, allow_pickle=False)
        rig = MuscleRig(names=[str(n) for n in z["rig_names"]], **{k: z[f"rig_{k}"] for k in _RIG_FIELDS})
        parts = {str(k): (z[f"part_{k}_V"], z[f"part_{k}_F"]) for k in z["part_names"]}
        part_jaw = {str(k): float(z[f"part_{k}_jaw"]) for k in z["part_names"]}
        return FaceRig(rig=rig, parts=parts, part_jaw=part_jaw, level=int(z["level"]),
                       **{k: z[k] for k in _FACE_FIELDS})
    except (KeyError, ValueError, OSError) as e:
        raise InputError(f"{path}: not a facewarp face rig ({e})") from None


# ------------------------------------------------------------------------------------ frames
@dataclass
class Frames:
    """The frame stream of a simulation (what exporters consume).

    Attributes:
        times: Frame times [s], shape (f,).
        points: Head surface vertices [m], shape (f, n, 3), float32.
        faces: Head triangles, shape (m, 3).
        fdp_ids: FDP ids, shape (84,).
        fdp_points: FDP positions [m], shape (f, 84, 3).
        parts: Rigid part name -> (frames (f, k, 3), faces (l, 3)).
        muscle_names: Muscle instance names (M,).
        muscle_curves: Muscle fibre polylines [m], shape (f, M, samples, 3) (closed rings for
            sphincters repeat their first point).
        activations: Activations per frame, shape (f, M); jaw: (f, 2) [rad].
        steps_per_second: Simulated substeps per wall-clock second.
    """

    times: np.ndarray
    points: np.ndarray
    faces: np.ndarray
    fdp_ids: np.ndarray
    fdp_points: np.ndarray
    parts: dict
    muscle_names: list
    muscle_curves: np.ndarray
    activations: np.ndarray
    jaw: np.ndarray
    steps_per_second: float = 0.0
    substeps: int = 0
    dt: float = 0.0


def _activation_vector(names: list[str], expr) -> np.ndarray:
    out = np.zeros(len(names), np.float32)
    for i, n in enumerate(names):
        side = n[-1] if n.endswith(("_L", "_R")) else None
        base = n[:-2] if side else n
        out[i] = expr.activation(base, side) if base in MUSCLES else 0.0
    return out


def node_jaw_amounts(fr: FaceRig) -> np.ndarray:
    """Eq. 6.4.9 jaw amount of every tet node, shape (p,), float64: that of the head vertex the
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


class FaceSimulator:
    """Model + Verlet solver + muscle and jaw stages for one :class:`FaceRig` on one device.

    Controls (activations, jaw angles) are sampled from the timeline once per frame and ramped
    linearly over the frame in :attr:`CONTROL_CHUNKS` pieces, each a run of substeps with no
    host round trip inside.
    """

    CONTROL_CHUNKS = 16

    def __init__(self, fr: FaceRig, *, device: str = "cpu", dt: float | None = None, substeps: int | None = None,
                 fps: float = 30.0, support_stiffness: float | None = None, edge_damping: float = EDGE_DAMPING,
                 mass_scaling: bool = True):
        import warp as wp

        from .model import ModelBuilder
        from .muscle_stage import CarryStage, JawStage, MuscleStage, SupportStage
        from .solver import MASS_SCALING_QUANTILE, SolverVerlet, scale_masses

        self.fr = fr
        self.fps = float(fps)
        builder = ModelBuilder(fr.nodes, fr.tets, layer=fr.layer, fixed=fr.fixed, held=fr.held,
                               muscle_count=len(fr.rig.names), edge_damping=edge_damping)
        # the substep: the 2 % of nodes with the smallest own limit (short edges, flat tets in
        # creases of adapted heads) get the mass that lifts them to it (selective mass scaling)
        dt_safe, self.added_mass_fraction = scale_masses(
            builder, quantile=MASS_SCALING_QUANTILE if mass_scaling else 0.0)
        frame_dt = 1.0 / self.fps
        if substeps is None:
            substeps = int(np.ceil(frame_dt / (dt or dt_safe)))
        self.substeps = int(substeps)
        self.dt = frame_dt / self.substeps
        if self.dt > 2.0 * dt_safe:
            raise InputError(f"--substeps {substeps}: dt {self.dt:.2e} s is above twice the stable step "
                             f"{dt_safe:.2e} s; use at least {int(np.ceil(frame_dt / (2 * dt_safe)))} substeps")
        self.model = builder.finalize(device)
        self.device = self.model.device
        self.jaw = fr.jaw
        self.jaw_stage = JawStage(self.jaw, fr.jaw_nodes, fr.jaw_amount, self.model.rest_positions, self.device)
        k_support = float(self.model.vertex_hold_stiffness.numpy().max()) if fr.held.any() else 0.0
        self.support = SupportStage(self.jaw, fr.support_nodes, fr.support_normal, fr.support_amount,
                                    support_stiffness if support_stiffness is not None else k_support,
                                    self.model.rest_positions, self.device)
        node_jaw = node_jaw_amounts(fr)
        self.muscles = MuscleStage(fr.rig, self.jaw, self.device, node_amount=node_jaw)
        carried = np.flatnonzero((node_jaw > 0) & ~fr.fixed)
        self.carry = CarryStage(self.jaw, carried, node_jaw[carried], self.device)
        self.solver = SolverVerlet(self.model, stages=[self.carry, self.jaw_stage, self.support, self.muscles])
        self.state = self.model.state()
        self.scratch = self.model.state()
        self.control = self.model.control()
        self.use_graph = bool(self.device.is_cuda)
        self._graphs: dict[int, object] = {}
        self._wp = wp
        # head surface <- outer nodes
        sv = fr.surface_vertex
        self.node_of_vertex = np.where(sv >= 0)[0]
        self.vertex_of_node = sv[self.node_of_vertex]

    def _substeps(self, n: int) -> None:
        for s in range(n):
            src, dst = (self.state, self.scratch) if s % 2 == 0 else (self.scratch, self.state)
            self.solver.step(src, dst, self.control, self.dt)
        if n % 2 == 1:
            self.state.assign(self.scratch)

    def advance(self, n: int) -> None:
        """Run ``n`` substeps with the current control; on CUDA as a replayed graph (one per n)."""
        if n <= 0:
            return
        if not self.use_graph:
            self._substeps(n)
            return
        g = self._graphs.get(n)
        if g is None:
            wp = self._wp
            with wp.ScopedCapture(device=self.device) as cap:
                self._substeps(n)
            g = self._graphs[n] = cap.graph
        self._wp.capture_launch(g)

    def surface(self, X: np.ndarray, jaw_angles=(0.0, 0.0)) -> np.ndarray:
        """Head vertices [m] (n, 3): the simulated outer nodes X (p, 3) written in, the rest of
        the head moved kinematically by the jaw (its per-vertex amount)."""
        fr = self.fr
        V = fr.head_vertices.copy()
        if fr.vertex_jaw is not None and (jaw_angles[0] or jaw_angles[1]):
            m = fr.vertex_jaw > 0
            V[m] = self.jaw.apply(V[m], fr.vertex_jaw[m], float(jaw_angles[0]), float(jaw_angles[1]))
        V[self.vertex_of_node] = X[self.node_of_vertex]
        return V

    def run(self, timeline: Timeline, seconds: float, *, progress=None, curve_samples: int = 24) -> Frames:
        """Simulate ``seconds`` of ``timeline``; one frame every 1/fps s (frame 0 at rest)."""
        fr = self.fr
        nf = int(round(seconds * self.fps)) + 1
        times = np.arange(nf) / self.fps
        names = fr.rig.names
        pts = np.zeros((nf, len(fr.head_vertices), 3), np.float32)
        acts = np.zeros((nf, len(names)), np.float32)
        jaws = np.zeros((nf, 2), np.float32)
        curves = np.zeros((nf, len(names), curve_samples, 3), np.float32)
        parts_frames = {k: np.zeros((nf, len(V), 3), np.float32) for k, (V, _) in fr.parts.items()}
        t0 = time.perf_counter()
        steps = 0
        prev_a = _activation_vector(names, timeline.sample(0.0))
        e0 = timeline.sample(0.0)
        prev_j = np.array([e0.jaw_u, e0.jaw_v], np.float32)
        chunks = max(1, min(self.substeps, self.CONTROL_CHUNKS))
        bounds = np.linspace(0, self.substeps, chunks + 1).round().astype(int)
        for k, t in enumerate(times):
            e = timeline.sample(float(t))
            a = _activation_vector(names, e)
            j = np.array([e.jaw_u, e.jaw_v], np.float32)
            if k > 0:
                # controls ramp linearly across the frame (a step would jolt the held nodes)
                for c in range(chunks):
                    w = (c + 1) / chunks
                    self.control.activations.assign((1 - w) * prev_a + w * a)
                    self.control.jaw_angles.assign((1 - w) * prev_j + w * j)
                    self.advance(int(bounds[c + 1] - bounds[c]))
                steps += self.substeps
                self.solver.check(self.state)
            prev_a, prev_j = a, j
            X = self.state.positions.numpy().astype(np.float64)
            pts[k] = self.surface(X, j)
            acts[k], jaws[k] = a, j
            curves[k] = self._curves(curve_samples)
            for name, (V, _) in fr.parts.items():
                amt = fr.part_jaw.get(name, 0.0)
                parts_frames[name][k] = self.jaw.apply(V, np.full(len(V), amt), float(j[0]), float(j[1])) if amt else V
            if progress:
                progress(k, nf)
        wall = time.perf_counter() - t0
        fdp = self._fdp_points(pts, parts_frames)
        return Frames(times, pts, fr.head_faces, fr.fdp_ids, fdp,
                      {k: (v, fr.parts[k][1]) for k, v in parts_frames.items()}, list(names), curves, acts, jaws,
                      steps / max(wall, 1e-9), self.substeps, self.dt)

    def _curves(self, samples: int) -> np.ndarray:
        from .muscle_stage import _bezier_np

        rig = self.fr.rig
        ctrl = self.muscles.ctrl.numpy().astype(np.float64)
        out = np.zeros((len(rig.names), samples, 3))
        curve_m = rig.ctrl_muscle[rig.curve_ctrl[:, 0]]
        for m in range(len(rig.names)):
            cs = np.where(curve_m == m)[0]
            per = max(2, samples // len(cs))
            seq = [_bezier_np(ctrl[rig.curve_ctrl[c]][None], rig.curve_weight[c][None], np.linspace(0, 1, per)) for c in cs]
            P = np.concatenate(seq)
            idx = np.linspace(0, len(P) - 1, samples).round().astype(int)
            out[m] = P[idx]
        return out

    def _fdp_points(self, pts, parts_frames) -> np.ndarray:
        fr = self.fr
        out = np.zeros((len(pts), len(fr.fdp_ids), 3), np.float32)
        for i, (part, f, b) in enumerate(zip(fr.fdp_part, fr.fdp_face, fr.fdp_bary)):
            if part == "head":
                tri = fr.head_faces[f]
                out[:, i] = np.einsum("k,fkd->fd", b, pts[:, tri])
            else:
                V = parts_frames[str(part)]
                tri = fr.parts[str(part)][1][f]
                out[:, i] = np.einsum("k,fkd->fd", b, V[:, tri])
        return out


def save_frames_npz(path, frames: Frames) -> Path:
    """``frames.npz``: points (f, n, 3) [m], times (f,), fdp_ids (84,), fdp_points (f, 84, 3), faces,
    activations (f, M), muscle_names (M,), jaw (f, 2) [rad], muscle_curves (f, M, s, 3)."""
    buf = io.BytesIO()
    np.savez_compressed(buf, points=frames.points, times=frames.times, fdp_ids=frames.fdp_ids,
                        fdp_points=frames.fdp_points, faces=frames.faces, activations=frames.activations,
                        muscle_names=np.array(frames.muscle_names), jaw=frames.jaw, muscle_curves=frames.muscle_curves)
    with atomic_write(path, "wb", encoding=None) as f:
        f.write(buf.getvalue())
    return Path(path)
