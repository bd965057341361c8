"""A simulated face streamed into a USD animation, frame by frame as it is simulated.

:class:`UsdAnimation` wraps :class:`usd_export.AnimationWriter` for one face rig: the whole head
(:meth:`FaceSimulator.surface`: the simulated face written into the template's full mesh, the
rest moved by the jaw), the rigid parts as ``Xform``\\ s with time-sampled transforms (lower teeth
and tongue turn with the jaw by their jaw amount: the jaw transform is the rotation about
``jaw_pivot`` by the jaw angles of Sec. 6.4.3; eyes and upper teeth stay), and the muscles as
``BasisCurves`` with their activations; it is a sink of :func:`~facewarp.play`, which steps a
simulator through a timeline and hands each frame to its sinks, keeping no frames itself.

The file appears only when the animation is complete (``usd_export`` writes to a temporary
folder and renames); an error or Ctrl-C leaves nothing behind.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..coupling.drivers import JAWS, load_mjcf
from ..expressions import Timeline
from ..sim.play import Sink
from ..sim.readout import eye_transforms

__all__ = ["JAWS", "MUSCLE_SAMPLES", "USD_SUFFIXES", "FdpMotion", "UsdAnimation", "check_usd_path", "load_mjcf",
           "load_usd_export", "part_points",
           "part_transforms", "peak_frames", "sim_controls"]

USD_SUFFIXES = (".usda", ".usdc", ".usdz")
"""File types of USD animations: text, binary crate, package."""

MUSCLE_SAMPLES = 24
"""Points per muscle curve in the USD (as in :meth:`FaceSimulator.run`)."""


def check_usd_path(path, name: str = "out") -> Path:
    """``path`` as a Path ending in .usda, .usdc or .usdz whose folder exists, else :class:`InputError`."""
    p = Path(path)
    if p.suffix.lower() not in USD_SUFFIXES:
        raise InputError(f"{name} {p}: expected a file ending in {', '.join(USD_SUFFIXES)}")
    if p.is_dir():
        raise InputError(f"{name} {p}: is a folder, expected a USD file name")
    if not p.parent.is_dir():
        raise InputError(f"{name} {p}: folder {p.parent} does not exist")
    return p


def _rigid_matrix(f) -> np.ndarray:
    """The 4x4 row-vector matrix (``p' = p @ M``) of an affine map ``f`` of (k, 3) points."""
    O = f(np.zeros((1, 3)))[0]
    M = np.eye(4)
    M[:3, :3] = f(np.eye(3)) - O
    M[3, :3] = O
    return M


def part_transforms(fr, jaw_angles, gaze=None) -> dict:
    """Rest-to-current transform of every rigid part of ``fr`` at ``jaw_angles`` (u, v) [rad].

    Returns:
        name -> 4x4 float64 matrix in USD's row-vector convention (``p' = p @ M``): identity for
        parts with jaw amount 0 (eyes, upper teeth), the jaw rotation about ``fr.jaw_pivot``
        scaled by the part's amount for the others (lower teeth and tongue: 1); the eyeballs turned by
        ``gaze`` ((2, 2) [rad], :func:`~facewarp._src.sim.readout.eye_transforms`) when given.
    """
    jaw = fr.jaw
    u, v = float(jaw_angles[0]), float(jaw_angles[1])
    out = {}
    for name in fr.parts:
        a = float(fr.part_jaw.get(name, 0.0))
        if a == 0.0 or (u == 0.0 and v == 0.0):
            out[name] = np.eye(4)
        else:
            out[name] = _rigid_matrix(lambda P, a=a: jaw.apply(P, np.full(len(P), a), u, v))
    for name, (R, c) in eye_transforms(fr, gaze).items():  # eyes turned about their centres: p' = R (p - c) + c
        M = np.eye(4)
        M[:3, :3], M[3, :3] = R.T, c - c @ R.T
        out[name] = M
    return out


def part_points(fr, jaw_angles) -> dict:
    """Vertices [m] of every rigid part of ``fr`` at ``jaw_angles`` (u, v) [rad]: name -> (k, 3)
    float64 (:meth:`FaceRig.part_at` of each part)."""
    return {name: fr.part_at(name, jaw_angles) for name in fr.parts}


def peak_frames(timeline: Timeline, seconds: float, fps: float) -> list[tuple[str, int]]:
    """(name, frame) of the peak of each segment of ``timeline`` that starts within ``seconds``.

    The peak is the end of the segment's hold (the expression at full weight and longest held,
    before its release and before the next segment of a sequence ramps in), or the last frame
    where the run ends earlier; frame ``k`` is at ``k / fps`` s, frame 0 the rest.
    """
    last = int(round(seconds * fps))
    out = []
    for s in timeline.segments:
        if s.start < seconds:
            held = int(np.floor((s.start + s.attack + s.hold) * fps + 1e-9))
            out.append((s.expression.name, min(last, max(1, held))))
    return out or [("end", last)]


def sim_controls(sim) -> tuple[np.ndarray, np.ndarray]:
    """The activations (M,) and jaw angles (2,) [rad] the simulator reached at its last step
    (those :meth:`FaceSimulator.surface` uses)."""
    return np.asarray(sim.activations, np.float32), np.asarray(sim.jaw_angles, np.float64)


def muscle_curves(sim, samples: int = MUSCLE_SAMPLES) -> np.ndarray:
    """Muscle fibre polylines [m] of the simulator's current state, shape (M, samples, 3)."""
    return sim.muscle_curves(samples)


def load_usd_export():
    """The ``usd_export`` package, imported with SIGINT / SIGTERM held back: USD's loader runs
    Python while it loads its libraries, and an interrupt raised there is caught and printed by
    USD (a traceback on stderr) instead of stopping the run; held back, it stops the run right
    after the import (:func:`~facewarp._src.core.outputs.signals_deferred`)."""
    from ..core.outputs import signals_deferred

    with signals_deferred():
        import usd_export
    return usd_export


class UsdAnimation(Sink):
    """Stream a simulator's frames into a USD file (see the module docstring).

    A sink of :func:`~facewarp.play` (``play(sim, timeline, seconds, sinks=[usd])``), or in a
    user's own loop a context manager whose :meth:`add` writes the simulator's current state::

        with UsdAnimation("take.usdc", sim) as usd:
            for k in range(frames):
                sim.step()
                usd.add(sim, (k + 1) / sim.fps)

    Args:
        path: ``.usda``, ``.usdc`` or ``.usdz`` file.
        sim: The :class:`~facewarp.FaceSimulator` (its rig, fps and rest muscles are read).
        muscle_samples: Points per muscle curve.
        tets: Also write the skin's tet layer as a ``TetMesh`` (purpose ``guide``) with
            time-sampled nodes.
        iris_color: Optional iris RGB (3,) in 0..1, linear (default brown-hazel). The file's looks
            (``present.looks``): ``Looks/Sclera``, ``Looks/Iris``, ``Looks/Pupil`` bound through
            GeomSubsets of each eyeball, ``Looks/Lips`` on the skin (without a skin texture),
            ``Looks/Gums`` through a GeomSubset of each tooth row (the rows written split at their
            gum lines, ``present.looks.tooth_mesh``), the parts' own ``Looks/Teeth_Upper``,
            ``Looks/Teeth_Lower``, ``Looks/Tongue``.

    Raises:
        InputError: a bad path (extension, missing folder) or input the writer refuses.
    """

    def __init__(self, path, sim, *, muscle_samples: int = MUSCLE_SAMPLES, tets: bool = False, iris_color=None):
        ue = load_usd_export()
        AnimationWriter, UsdExportError = ue.AnimationWriter, ue.UsdExportError

        from ..present.looks import head_camera, head_looks

        self.path = check_usd_path(path)
        self.fr = fr = sim.fr
        self.samples = int(muscle_samples)
        self.tets = bool(tets)
        self._error = UsdExportError
        looks = head_looks(fr, iris_color=iris_color)
        try:
            self.writer = AnimationWriter(self.path, fps=sim.fps, faces=fr.head_faces, rest_points=fr.head_vertices,
                                          parts=looks["parts"], muscles=list(fr.rig.names),
                                          muscle_samples=self.samples, muscle_rest=muscle_curves(sim, self.samples),
                                          tets=(fr.tets, fr.nodes) if self.tets else None,
                                          part_colors=looks["part_colors"], subsets=looks["subsets"],
                                          camera=head_camera(fr),
                                          lights=True,
                                          **_skin_look(fr))
        except UsdExportError as e:
            raise InputError(str(e)) from None

    @property
    def frame_count(self) -> int:
        return self.writer.frame_count

    def add(self, sim, time_s: float) -> None:
        """Write the simulator's current state as the frame at ``time_s`` [s]."""
        a, j = sim_controls(sim)
        try:
            self.writer.add_frame(time_s, sim.surface(), part_transforms=part_transforms(self.fr, j, sim.eye_gaze),
                                  muscle_points=muscle_curves(sim, self.samples), activations=a,
                                  tet_points=sim.positions() if self.tets else None)
        except self._error as e:
            raise InputError(str(e)) from None

    def frame(self, sim, k: int, t: float) -> None:
        """The sink's frame: :meth:`add` at ``t``."""
        self.add(sim, t)

    def close(self) -> Path:
        return self.writer.close()

    def abort(self) -> None:
        self.writer.abort()

    def __enter__(self) -> UsdAnimation:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.writer.__exit__(exc_type, exc, tb)


def _skin_look(fr) -> dict:
    """The skin's texture coordinates and colour texture for the USD writer, where the rig has them."""
    if getattr(fr, "head_uv", None) is None:
        return {}
    out = {"uv": fr.head_uv, "uv_indices": fr.head_face_uv}
    if getattr(fr, "skin_texture", None):
        out["skin_texture"] = fr.skin_texture
    return out


class FdpMotion(Sink):
    """The largest distance from rest of FDPs over a run [m] (a sink of :func:`~facewarp.play`).

    Args:
        ids: FDP ids to follow (those the head has); default all of them.

    After the run, :attr:`ids` (str) and :attr:`moved` (shape (len(ids),), float64, m) hold the result.
    """

    def __init__(self, ids=None):
        self.want = None if ids is None else [str(k) for k in ids]

    def start(self, sim, frame_count: int) -> None:
        ids = [str(k) for k in sim.fr.fdp_ids]
        self.ids = ids if self.want is None else [k for k in self.want if k in ids]
        self.idx = [ids.index(k) for k in self.ids]
        self.rest = None
        self.moved = np.zeros(len(self.idx))

    def frame(self, sim, k: int, t: float) -> None:
        p = sim.fdp_points()[self.idx]
        if self.rest is None:  # frame 0: the rest
            self.rest = p
        np.maximum(self.moved, np.linalg.norm(p - self.rest, axis=1), out=self.moved)
