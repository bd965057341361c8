"""The jaw as a MuJoCo hinge body under position control, with the simulated skin attached.

The default head's ``head.xml`` (cranium, mandible on the ``jaw_open`` / ``jaw_side`` hinges) is
loaded in MuJoCo and coupled two-way to the face (:class:`facewarp.MujocoJaw`): the position
actuator opens the jaw to ``--angle`` and closes it again, the skin follows the mandible and
pushes back. Writes ``jaw.png`` (the face at rest, open and closed again, over displacement heat
maps) and ``jaw.json`` (angle, skin torque and chin path per frame).

    python -m scenes.jaw --device cpu --seconds 2 --out out/jaw [--angle 0.3]

Public names only.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

import facewarp as fw


class JawScene:
    """Open and close the jaw of the default head under MuJoCo position control.

    Args:
        angle: Opening target [rad] reached in the first half, released in the second.
        seconds: Length of the scene [s] (the opening lasts the first half).
        level: Template level.
        device: Warp device of the skin.
    """

    def __init__(self, *, angle: float = 0.3, seconds: float = 2.0, level: int = 0, device: str = "cpu"):
        import mujoco

        self.mujoco = mujoco
        self.head = fw.default_template(level)
        self.rig = fw.build_face(self.head)
        self.sim = fw.FaceSimulator(self.rig, device=device)
        self.model = mujoco.MjModel.from_xml_string(fw.head_mjcf(self.head))
        self.data = mujoco.MjData(self.model)
        self.coupler = fw.MujocoJaw(self.sim, self.model, self.data)
        self.angle, self.seconds = float(angle), float(seconds)
        self.frame = 0
        self.rest = self.sim.surface()
        self.log = []
        landmarks = dict(zip((str(k) for k in self.rig.fdp_ids), self.sim.fdp_points()))
        self._landmarks, self._rest_head, self._views = landmarks, self.rest, {}

    @property
    def time(self) -> float:
        return self.frame / self.sim.fps

    def step(self) -> None:
        """One frame: the actuator target (open in the first half, closed after), then skin and
        mandible together."""
        self.data.ctrl[0] = self.angle if self.time < 0.5 * self.seconds else 0.0
        self.coupler.step()
        self.frame += 1
        self.log.append({"t": self.time, "angle_rad": float(self.data.qpos[0]),
                         "skin_torque_Nm": float(self.coupler.torque[0]),
                         "chin_m": self.sim.fdp("2.1").tolist()})

    def view(self, size: int):
        """The fixed camera of ``size``-pixel renders on the whole head (eyes, teeth, tongue)."""
        if size not in self._views:
            self._views[size] = fw.render.FaceView(self._rest_head, self.rig.head_faces, self._landmarks,
                                                   self.rig.parts, view="three_quarter", size=size, aspect=1.0,
                                                   reach=0.01, device=self.sim.device)
        return self._views[size]

    def render(self, *, size: int = 320) -> np.ndarray:
        """The face now beside its displacement heat map, RGB (size, 2 size, 3) uint8."""
        V = self.sim.surface()
        d = np.linalg.norm(V - self.rest, axis=1)
        view, parts = self.view(int(size)), self.sim.part_points()
        face = view.render(V, part_points=parts)
        heat = view.render(V, part_points=parts, heat=d, heat_max=0.03)
        return np.concatenate([face, heat], axis=1)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--angle", type=float, default=0.3, help="opening target [rad]")
    ap.add_argument("--size", type=int, default=320)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    if not (math.isfinite(a.seconds) and a.seconds > 0):
        ap.error(f"--seconds: expected a positive number, got {a.seconds}")
    scene = JawScene(angle=a.angle, seconds=a.seconds, device=a.device)
    frames = max(2, int(round(a.seconds * scene.sim.fps)))
    picks = {0, frames // 2, frames}
    images = [scene.render(size=a.size)]
    for k in range(1, frames + 1):
        scene.step()
        if k in picks:
            images.append(scene.render(size=a.size))
    a.out.mkdir(parents=True, exist_ok=True)
    fw.save_png(a.out / "jaw.png", np.concatenate(images, axis=0),
                title=f"jaw: rest, open ({scene.angle:.2f} rad target), closed again")
    (a.out / "jaw.json").write_text(json.dumps({"frames": scene.log}, indent=1))
    peak = max(r["angle_rad"] for r in scene.log)
    print(f"jaw scene: {frames} frames, largest opening {peak:.3f} rad, wrote {a.out}/jaw.png, jaw.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
