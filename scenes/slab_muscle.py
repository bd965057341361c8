"""Single linear muscle under a skin slab: the experiments of thesis Figs. 6.9 and 6.10.

A square sheet of skin (a grid of ``cells x cells`` squares, two triangles each) is extruded into
a tet slab (:func:`facewarp.anatomy.slab_anatomy`); one straight linear muscle (a quadratic Bezier
fibre cut into ellipsoid segments) runs under it along +x. Inner-sheet nodes attach to the muscle
where their distance to the nearest segment surface is below lambda and the angle between the
connection and the fibre's normal plane is below the limit theta (Fig. 6.4); the slab's border is
fixed. Fig. 6.9 varies theta at activation 0.5, Fig. 6.10 varies the activation at theta = 45 deg.
Each panel shows the skin coloured by its displacement after the muscle pulled.

    python -m scenes.slab_muscle --device cpu --seconds 0.15 --out out/slab [--cells 24] [--size 340]

Writes ``slab_angle.png`` (Fig. 6.9), ``slab_activation.png`` (Fig. 6.10) and ``slab.json``.
Public names only; :class:`SlabMuscle` is one case, stepped a frame at a time.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

import facewarp as fw
from facewarp import anatomy, physics

SIZE = 0.05  # side of the skin sheet [m]
THICKNESS = 0.003  # skin slab [m]
MUSCLE_DEPTH = 0.007  # fibre below the skin [m]
MUSCLE_LENGTH = 0.0325  # [m]
MUSCLE_RADIUS = 0.003  # y/z radius of the segments [m]
LAMBDA = 0.006  # attachment distance [m]
STIFFNESS = 4e5  # muscle spring k_m [N/m]
COLOR_MAX_MM = 3.0  # top of the displacement colour scale

FIGURES = {  # figure -> cases (activation, theta [rad])
    "angle": [(0.5, a) for a in (np.pi / 12, np.pi / 6, np.pi / 4, np.pi / 3)],  # Fig. 6.9
    "activation": [(s, np.pi / 4) for s in (0.25, 0.5, 0.75, 1.0)],  # Fig. 6.10
}


class SlabMuscle:
    """One case of Figs. 6.9/6.10: the slab, its muscle at ``activation`` with angle limit ``theta``.

    Args:
        activation: Muscle activation in [0, 1].
        theta: Attachment angle limit phi of Fig. 6.4 [rad] (0: only nodes right above the fibre).
        cells: Grid squares per side of the skin sheet.
        fps: Frames per second of :meth:`step`.
        device: Warp device, ``"cpu"`` or ``"cuda[:N]"``.
    """

    def __init__(self, *, activation: float = 0.5, theta: float = np.pi / 4, cells: int = 24, fps: float = 60.0,
                 device: str = "cpu"):
        self.activation, self.theta, self.fps = float(activation), float(theta), float(fps)
        self.anatomy = anatomy.slab_anatomy(cells=cells, size=SIZE, thickness=THICKNESS, muscle_depth=MUSCLE_DEPTH,
                                            muscle_length=MUSCLE_LENGTH, radius=MUSCLE_RADIUS, lam=LAMBDA, phi=theta)
        skin = self.anatomy.skin
        self.rest = skin.vertices
        self.top = np.flatnonzero(skin.layer == 0)  # skin-surface nodes, in sheet vertex order
        border = np.isclose(np.abs(skin.vertices[:, :2]), SIZE / 2).any(1)
        rig = physics.muscle_rig(self.anatomy.muscles, stiffness=STIFFNESS)
        self.attached = len(rig.att_node)
        builder = fw.physics.ModelBuilder(skin.vertices, skin.tets, layer=skin.layer, fixed=border)
        builder.add_muscles(rig)  # the muscle's control points are State: the Model knows the muscles
        self.model = builder.finalize(device)
        self.solver = fw.physics.SolverVerlet(self.model, stages=[fw.physics.MuscleStage.from_model(self.model)])
        dt = physics.stable_dt(self.model)
        self.substeps = max(1, math.ceil(1.0 / (self.fps * dt)))
        self.dt = 1.0 / (self.fps * self.substeps)
        self.state = self.model.state()
        self.control = self.model.control()
        self.control.activations.assign(np.array([self.activation], np.float32))
        self.frame = 0

    @property
    def time(self) -> float:
        """Simulated time [s]."""
        return self.frame / self.fps

    def step(self) -> None:
        """One frame (``1 / fps`` s) of Verlet substeps; raises SimulationError on a NaN or an inverted tet."""
        physics.simulate(self.model, self.state, self.control, self.dt, self.substeps, solver=self.solver)
        self.frame += 1

    def displacement(self) -> np.ndarray:
        """Displacement [m] of the skin-surface nodes from rest, shape (n,), float64."""
        X = self.state.positions.numpy().astype(np.float64)[self.top]
        return np.linalg.norm(X - self.rest[self.top], axis=1)

    def render(self, size: int = 340) -> np.ndarray:
        """The skin surface coloured by displacement (0..3 mm), RGB image (size, size, 3) uint8."""
        X = self.state.positions.numpy().astype(np.float64)[self.top]
        colors = fw.render.colormap(self.displacement() * 1e3, 0.0, COLOR_MAX_MM)
        return fw.render_mesh(X, self.anatomy.head.faces, view=(15.0, 15.0), width=size, height=size,
                              vertex_colors=colors, device=str(self.model.device))

    def summary(self) -> dict:
        """JSON-ready numbers of the case."""
        return {"activation": self.activation, "theta_rad": self.theta, "attached": self.attached,
                "max_displacement_m": float(self.displacement().max()), "time_s": self.time,
                "substeps_per_frame": self.substeps, "dt_s": self.dt}


def run_figures(out: Path, *, seconds: float, cells: int, device: str, size: int = 340) -> dict:
    """Run every case of :data:`FIGURES` for ``seconds`` and write the two strips and ``slab.json``."""
    out.mkdir(parents=True, exist_ok=True)
    results = {"cells": cells, "size_m": SIZE, "thickness_m": THICKNESS, "device": device, "cases": []}
    for fig, cases in FIGURES.items():
        panels, labels = [], []
        for activation, theta in cases:
            t0 = time.perf_counter()
            scene = SlabMuscle(activation=activation, theta=theta, cells=cells, device=device)
            for _ in range(max(1, round(seconds * scene.fps))):
                scene.step()
            panels.append(scene.render(size))
            labels.append(f"theta={np.degrees(theta):.0f} deg" if fig == "angle" else f"sigma={activation:.2f}")
            case = {"figure": fig, **scene.summary(), "seconds": time.perf_counter() - t0}
            results["cases"].append(case)
            print(fig, labels[-1], f"attached {case['attached']}, max displacement "
                  f"{case['max_displacement_m'] * 1e3:.2f} mm")
        title = ("Fig. 6.9, sigma=0.5: " if fig == "angle" else "Fig. 6.10, theta=45 deg: ") + ", ".join(labels)
        fw.save_png(out / f"slab_{fig}.png", np.concatenate(panels, axis=1), title=title,
                    colorbar=(0.0, COLOR_MAX_MM, "displacement [mm]"))
    (out / "slab.json").write_text(json.dumps(results, indent=2) + "\n")
    return results


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    ap.add_argument("--seconds", type=float, default=0.15, help="simulated time per case [s]")
    ap.add_argument("--out", type=Path, default=Path("out/slab"), help="output folder")
    ap.add_argument("--cells", type=int, default=24, help="grid squares per side of the skin sheet")
    ap.add_argument("--size", type=int, default=340, help="panel side [px]")
    args = ap.parse_args(argv)
    run_figures(args.out, seconds=args.seconds, cells=args.cells, device=args.device, size=args.size)
    print("wrote", args.out)


if __name__ == "__main__":
    main()
