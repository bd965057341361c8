"""Many heads stepped together: :class:`FaceBatch`, N personalized faces, one step for all.

One class, two backends chosen by :func:`batch_backend` (no base class builds its subclass):
``"heads"`` (:class:`~.batch_heads.BatchHeads`, described below) and ``"model"``
(:class:`~.batch_model.BatchModel`: N faces in one Model, one solver). :class:`FaceBatch` holds
the backend and forwards its API.

What a head is
--------------
Each head is a :class:`~facewarp.FaceSimulator` of its own rig (its rest shape, material and
muscle rig): its own :class:`~facewarp.physics.Model`, State, Control and solver, made by the
same code path as a single head (:func:`.stepper.build_face`; heads that play one rig share its
:class:`~facewarp.physics.ModelBuilder`, so the per-head cost of a replicated rig is the
``finalize`` and the solver's buffers, not the builder's geometry). Different topologies need
nothing special: a head's arrays index its own nodes.

One step for all
----------------
:meth:`FaceBatch.step` takes one frame of every live head. The controls of all heads live in
one device array (each head's ``Control.activations`` and ``jaw_angles`` are views into it), so
a frame's controls go up in one copy per ramp piece; on CUDA the frame of every head — the
start-of-frame save of the rollback (:mod:`.rollback`), the solver's substeps (the adaptive
Newton-PCG loop of each head a conditional graph node) and the end-of-frame checks — is one
captured CUDA graph, replayed every frame, and the checks come back in one read. On the CPU the
heads run one after another through the same calls. A level-0 head's kernels are small (a few
thousand threads each), so one graph of N heads runs them one after another; with ``streams=K``
the heads are split into K groups, each group's frame its own graph on its own stream, launched
side by side after the controls' upload and joined before the checks are read, so K heads'
kernels share the GPU at a time. Each head converges on its own: its own
solver decides its iteration count (the Newton-PCG loop on CUDA stops per head on its own
residual; the CPU L-BFGS factorises and iterates per head), so a head at rest costs few
iterations whatever the others do.

A head that fails
-----------------
After the frame the checks of every head are read (NaN or inverted tet: the solver's guard;
every tet above :data:`~facewarp.physics.VOLUME_FLOOR` of its rest volume; the CPU solve
converged). A head that fails is rolled back to its frame start and taken again alone with
sub-stepping (:func:`.rollback.step_frame`, exactly the single-head path); one that still fails
at the bound (a NaN or an inverted tet) is *frozen*: kept at its last good frame, reported in
:attr:`FaceBatch.status` with its index and the error, and skipped by later steps; the other
heads go on untouched (no array is shared between heads but read-only model data).

Where the heads are
-------------------
Every head is simulated in its own head frame, as a single head is: the physics does not
depend on where the head stands. A head's *placement* (``placements``: rotation and translation,
fixed) and its *head pose* (:meth:`FaceBatch.set_head_pose`: moving, its accelerations load the
tissue as :meth:`~facewarp.FaceSimulator.set_head_pose` does) are applied at read-out:
:meth:`FaceBatch.surface` and :meth:`FaceBatch.fdp_points` answer in the world frame,
``x_world = R_place (R_pose x + t_pose) + t_place``.

The jaws
--------
The kinematic jaw (Eq. 6.4.9) of every head is its Control's ``jaw_angles`` (:meth:`FaceBatch.set_jaw`),
stepped inside the batched frame. The MuJoCo jaw (:meth:`FaceBatch.use_mujoco_jaws`) is one CPU
MuJoCo model per head (the ``head.xml`` of its build), stepped in a loop around the batched skin
step: before it, each head's MuJoCo angles and head pose are set on its skin; after it, the skin's
torque on the hinge is read back (a host read of the jaw nodes per head) and MuJoCo takes its
steps to the frame's end. Its cost grows with N on the host whatever the device
(``benchmarks/batch.py --mujoco`` measures it); MuJoCo Warp (``mujoco-warp``, one Model with
``nworld`` worlds on the GPU) would keep it on the device and is not used yet.
"""


from __future__ import annotations

import numpy as np

from ..core.checks import check_choice
from .batch_common import BACKENDS, MAX_BATCH_HEADS
from .batch_heads import BatchHeads
from .batch_model import BatchModel, model_backend_reason

__all__ = ["BACKENDS", "MAX_BATCH_HEADS", "FaceBatch", "batch_backend"]


def batch_backend(backend: str, device, options: dict) -> type:
    """The backend class of :class:`FaceBatch`: :class:`~.batch_model.BatchModel` for ``"model"``
    (and for ``"auto"`` on CUDA with options one Model can step), else :class:`~.batch_heads.BatchHeads`.

    Raises:
        InputError: an unknown backend.
    """
    check_choice("backend", backend, BACKENDS)
    auto = str(device).startswith("cuda") and model_backend_reason(options) is None
    return BatchModel if backend == "model" or (backend == "auto" and auto) else BatchHeads


class FaceBatch:
    """N simulated faces, each its own person, stepped together (module doc).

    Args:
        rigs: One :class:`~facewarp.FaceRig` (replicated ``count`` times) or a list of them (one
            per head, any mix of identities and topologies).
        count: Number of heads with one rig (default 1); with a list, None or its length.
        device: Warp device, ``"cpu"`` or ``"cuda[:N]"``, for every head.
        fps: Frames per second of :meth:`step`.
        placements: Each head's fixed place in the world: ``(R, t)`` with R (3, 3) or (N, 3, 3)
            rotations and t (3,) or (N, 3) translations [m] (default: all at the origin).
        streams: CUDA only: the heads split into this many groups, each group's frame one graph
            on its own stream, the groups run side by side (default 1: one graph for all heads;
            module doc). The CPU ignores it.
        backend: :data:`BACKENDS`: ``"model"`` (every head in one Model, one solver; the fast path on
            a GPU: :class:`~facewarp._src.sim.batch_model.BatchModel`), ``"heads"`` (one
            :class:`~facewarp.FaceSimulator` per head: any solver, moving head poses, the MuJoCo
            jaw, per-head convergence) or ``"auto"`` (default: ``"model"`` on CUDA with the
            implicit solver, else ``"heads"``).
        **options: :class:`~facewarp.FaceSimulator`'s keywords (``solver``, ``material``, ``dt``,
            ``substeps``, ``iterations``, ``tolerance``, ``method``, ``solver_options``,
            ``support_stiffness``, ``edge_damping``, ``mass_scaling``, ``contact``,
            ``contact_modulus``), the same for every head.

    Attributes:
        backend: ``"heads"`` or ``"model"`` (the backend chosen).
        impl: The backend object (:class:`~.batch_heads.BatchHeads` or :class:`~.batch_model.BatchModel`);
            its other attributes read through the batch too (``heads``: the heads'
            :class:`~facewarp.FaceSimulator` objects of the ``"heads"`` backend, read them, do not
            step them alone; ``model``: the one Model of the ``"model"`` backend).
        count: Number of heads N.
        step_seconds: Wall-clock time spent in :meth:`step` [s].

    Raises:
        InputError: bad rigs, count, placements or simulator options.
    """

    def __init__(self, rigs, count: int | None = None, *, device: str = "cpu", fps: float = 30.0,
                 placements=None, streams: int = 1, backend: str = "auto", **options):
        cls = batch_backend(backend, device, options)
        self.impl = cls(rigs, count, device=device, fps=fps, placements=placements, streams=streams, **options)

    def __getattr__(self, name: str):
        # the backend's own attributes (heads, model, count, fps, device, failed, frames, step_seconds, ...)
        if name == "impl":
            raise AttributeError(name)
        return getattr(self.impl, name)

    @property
    def backend(self) -> str:
        """``"heads"`` or ``"model"``: the backend chosen."""
        return self.impl.backend

    @property
    def streams(self) -> int:
        """CUDA streams the heads' frames are spread over (module doc; 1: one graph for all; the CPU ignores it)."""
        return self.impl.streams

    @streams.setter
    def streams(self, value: int) -> None:
        self.impl.streams = value

    # ------------------------------------------------------------------------------ controls
    def set_activations(self, activations) -> None:
        """Set every head's muscle activations reached at the end of the next :meth:`step` (they
        ramp linearly over it from the current ones).

        Args:
            activations: An array (N, M) in [0, 1] (M the heads' muscle count, the order of
                ``heads[i].muscle_names``; heads with different rigs: a list instead), or a list of N
                entries, each what :meth:`~facewarp.FaceSimulator.set_activations` takes (a dict
                name -> value, an :class:`~facewarp.Expression`, an (M,) array).
        """
        self.impl.set_activations(activations)

    def set_jaw(self, angles) -> None:
        """Set every head's jaw angles [rad] reached at the end of the next :meth:`step`.

        Args:
            angles: (N, 2) (opening 0..60 deg, side +-5 deg in radians, as
                :meth:`~facewarp.FaceSimulator.set_jaw`), or (N,) openings with no side turn.
        """
        self.impl.set_jaw(angles)

    def set_head_pose(self, R, t) -> None:
        """Set every head's pose (in its placement) reached at the end of the next :meth:`step`:
        R (3, 3) or (N, 3, 3) rotations, t (3,) or (N, 3) translations [m]. As
        :meth:`~facewarp.FaceSimulator.set_head_pose`: the head, simulated in its own frame,
        feels the loads of the accelerating frame."""
        self.impl.set_head_pose(R, t)

    def use_mujoco_jaws(self, mjcf) -> None:
        """Drive every head's jaw by the MuJoCo hinge body of its ``head.xml`` (written by ``facewarp
        build``), two-way coupled as :class:`~facewarp.coupling.MujocoJawDriver` does for one head:
        :meth:`set_jaw`'s angles become the actuator targets, MuJoCo's angles and head pose go onto
        the skin before each batched step and the skin's torque back after it. One CPU MuJoCo model
        per head, stepped in a loop (module doc).

        Args:
            mjcf: One ``head.xml`` path for every head, or a list of N (one per head).

        Raises:
            InputError: a missing or broken file, a list of the wrong length, or no ``mujoco``.
        """
        self.impl.use_mujoco_jaws(mjcf)

    def reset(self, heads=None) -> None:
        """Back to rest, all heads (default) or the listed ones: each head's
        :meth:`~facewarp.FaceSimulator.reset` (and its MuJoCo jaw's model made again); a frozen
        head is live again."""
        self.impl.reset(heads)

    # ------------------------------------------------------------------------------ stepping
    def step(self) -> None:
        """One frame (``1 / fps``) of every live head, the controls set since the last step
        ramping across it (module doc: one CUDA graph on CUDA; a failing head is rolled back,
        taken again alone with more substeps, and frozen if it still fails).

        Raises:
            InputError: a head pose jump beyond a head's motion (nothing changed).
        """
        self.impl.step()

    def advance(self, frames: int = 1) -> None:
        """Advance ``frames`` frames with the current controls."""
        self.impl.advance(frames)

    # ------------------------------------------------------------------------------ results
    @property
    def live(self) -> list[int]:
        """Heads that step (not frozen by a failure), ascending."""
        return self.impl.live

    @property
    def status(self) -> list[dict]:
        """Per head: ``head`` (index), ``ok`` (False: frozen by a failure), ``error`` (the failure, or
        None), ``frames``, ``substepped_frames``, ``retries``, ``frames_below_floor``,
        ``unconverged_frames``, ``min_volume_ratio`` (:class:`~facewarp._src.sim.rollback.FrameStats`)
        and ``iterations`` (the backend's doc says whose: each head's own, or the one Model's)."""
        return self.impl.status

    def positions(self, head: int | None = None, *, frame: str = "head"):
        """Tet node positions [m], float64: of one head (p, 3), or of every head (a list of N
        arrays (p_i, 3)); in the head's own frame (``"head"``, default: what a
        :class:`~facewarp.FaceSimulator` of the rig gives alone) or the ``"world"`` frame
        (placement and head pose applied)."""
        return self.impl.positions(head, frame=frame)

    def surface(self, head: int) -> np.ndarray:
        """Head vertices of head ``head`` [m], (n, 3), float64, world frame (module doc)."""
        return self.impl.surface(head)

    def fdp_points(self, head: int) -> np.ndarray:
        """The FDPs of head ``head`` [m], (84, 3), float64, world frame (order ``rig.fdp_ids``)."""
        return self.impl.fdp_points(head)

    @property
    def placements(self) -> tuple[np.ndarray, np.ndarray]:
        """The heads' placements: rotations (N, 3, 3) and translations (N, 3) [m]."""
        return self.impl.placements
