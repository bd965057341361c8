"""A driven take as an animation of a baked rig: what plays in an engine without the simulator.

:class:`RigTake` is a sink of the drive loop (:func:`~facewarp.drive`, :func:`~facewarp.play`):
per frame it keeps the rig's controls and measures how far the rig's linear blend lands from the
simulated face of that frame, then :meth:`RigTake.write` writes the rig with the take as its
animation (glTF clip ``take``; UsdSkel: the bound SkelAnimation ``Anim``, blendShapeWeights and the
jaw joint's rotation).

- An ARKit take (``weights``: the track's (T, 52) ARKit weights) plays as the rig's ARKit shapes:
  each frame's weights as they are, the jaw joint at :meth:`BlendshapeRig.arkit_opening`; the rig's
  face is :func:`~facewarp._src.bake.blendshapes.evaluate_arkit`.
- Any other take (markers, a timeline) plays as the rig's muscle shapes: the simulator's
  activations of the baked muscles and its jaw opening each frame; the rig's face is
  :func:`~facewarp._src.bake.blendshapes.evaluate`.

The error is the distance of each skin vertex of the rig's face from the simulated one (head frame)
[m]: :attr:`RigTake.error` (T, 2) holds each frame's p95 and largest, :meth:`RigTake.report`
the take's p95 over every frame's vertices.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..sim.play import Sink

__all__ = ["RigTake"]


class RigTake(Sink):
    """Record a driven take on a baked rig (see the module docstring).

    Args:
        rig: A :class:`~facewarp._src.bake.blendshapes.BlendshapeRig` of the simulator's head
            (``load_rig`` of a ``facewarp rig --out DIR`` folder).
        weights: Optional (T, 52) ARKit weights of the take (:data:`~facewarp.ARKIT_NAMES` order):
            the take plays as ARKit shapes (the rig must have some); None: as muscle shapes.
        fps: Optional frame rate of the clip (default the simulator's).
    """

    def __init__(self, rig, weights=None, *, fps: float | None = None):
        from ..drive.tracks import ARKIT_NAMES

        for attr in ("rest", "names", "shapes", "arkit_jaw"):
            if not hasattr(rig, attr):
                raise InputError(f"rig: expected a baked BlendshapeRig, got {type(rig).__name__}")
        self.rig = rig
        self.weights = None
        if weights is not None:
            W = np.asarray(weights, np.float64)
            if W.ndim != 2 or W.shape[1] != len(ARKIT_NAMES) or not np.isfinite(W).all():
                raise InputError(f"weights: expected (T, {len(ARKIT_NAMES)}) finite ARKit weights, got {W.shape}")
            if not rig.arkit_names:
                raise InputError("rig: an ARKit take needs a rig with ARKit shapes (facewarp rig --shapes arkit|both)")
            self.weights = W
            self._cols = [(list(ARKIT_NAMES).index(n), n) for n in rig.arkit_names]
        elif not rig.muscle_names:
            raise InputError("rig: a muscle take needs a rig with muscle shapes (facewarp rig --shapes muscles|both)")
        self.fps = fps
        self.frames: list = []
        self.error = np.zeros((0, 2))
        self._all: list = []

    def start(self, sim, frame_count: int) -> None:
        if len(sim.fr.head_vertices) != len(self.rig.rest):
            raise InputError(f"rig: {len(self.rig.rest)} skin vertices, the simulator's head has "
                             f"{len(sim.fr.head_vertices)}: not this head's rig")
        if self.weights is not None and frame_count > len(self.weights):
            raise InputError(f"weights: {len(self.weights)} frames for a take of {frame_count}")
        self.fr = sim.fr
        self.fps = float(self.fps or sim.fps)
        self.frames, self._all = [], []
        self.error = np.zeros((frame_count, 2))

    def frame(self, sim, k: int, t: float) -> None:
        rig = self.rig
        if self.weights is not None:
            w = {n: float(np.clip(self.weights[k, i], 0.0, 1.0)) for i, n in self._cols}
            w = {n: v for n, v in w.items() if v}
            self.frames.append((float(t), w))
            V = rig.evaluate_arkit(w)
        else:
            names = list(sim.muscle_names)
            a = np.asarray(sim.activations, np.float64)
            acts = {names[m]: float(a[m]) for m in range(len(names)) if a[m] and names[m] in rig.shapes
                    and names[m] in rig.muscle_names}
            jaw = float(np.asarray(sim.jaw_angles)[0])
            self.frames.append((float(t), acts, jaw))
            V = rig.evaluate(acts, jaw)
        d = np.linalg.norm(V - sim.surface(frame="head"), axis=1)
        if k < len(self.error):
            self.error[k] = (np.percentile(d, 95), d.max())
        self._all.append(d.astype(np.float32))

    def report(self) -> dict:
        """The take on the rig: frames, the clip's kind, and the error of the rig's face against the
        simulated one [mm] (p95 and largest over every frame's vertices, the worst frame's p95)."""
        d = np.concatenate(self._all) if self._all else np.zeros(1)
        return {"frames": len(self.frames), "fps": self.fps, "clip": "arkit" if self.weights is not None else "muscles",
                "shapes": self.rig.arkit_names if self.weights is not None else self.rig.muscle_names,
                "error_mm": {"p95": float(np.percentile(d, 95) * 1e3), "max": float(d.max() * 1e3),
                             "worst_frame_p95": float(self.error[:, 0].max() * 1e3) if len(self.error) else 0.0},
                "error_is": "distance of each skin vertex of the rig's linear blend from the simulated face (head frame)"}

    def write(self, *files, iris_color=None) -> list:
        """Write the rig with the take as its animation (``take``) to each file (``.glb``, ``.usda``,
        ``.usdc``); returns their paths."""
        from ..jobs.rig import write_rig_files

        if not self.frames:
            raise InputError("take: no frames recorded (run the take with this sink first)")
        write_rig_files(self.fr, self.rig, list(files), {"take": self.frames}, iris_color=iris_color)
        return [str(f) for f in files]
