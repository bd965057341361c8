"""An animatronic head: the face on a 2-DOF neck (pan, tilt) in MuJoCo, talking and smiling.

The default head's MJCF with a neck (:func:`facewarp.head_mjcf` ``neck=True``): the neck's
position actuators nod and turn the head, the jaw actuator follows a speaking-like rhythm (4-6
openings per second, up to ``--jaw`` rad), and the zygomatic major smiles in the second half. The
face rides the cranium body (:meth:`facewarp.FaceSimulator.set_head_pose` through
:class:`facewarp.MujocoJaw`) and is simulated throughout. Writes ``robot_head.png`` (frames) and
``robot_head.json`` (neck and jaw angles, chin path in the world and in the head frame).

    python -m scenes.robot_head --device cpu --seconds 3 --out out/robot [--jaw 0.15]

Public names only.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

import facewarp as fw


class RobotHead:
    """The face on a pan-tilt neck, driven by MuJoCo actuators each :meth:`step`.

    Args:
        jaw: Largest jaw opening of the speaking rhythm [rad].
        seconds: Length of the scene [s]; the smile comes in the second half.
        device: Warp device of the skin.
    """

    def __init__(self, *, jaw: float = 0.15, seconds: float = 3.0, device: str = "cpu"):
        import mujoco

        self.head = fw.default_template(0)
        self.rig = fw.build_face(self.head)
        self.sim = fw.FaceSimulator(self.rig, device=device)
        self.model = mujoco.MjModel.from_xml_string(fw.head_mjcf(self.head, neck=True))
        self.data = mujoco.MjData(self.model)
        self.coupler = fw.MujocoJaw(self.sim, self.model, self.data)
        self.act = {self.model.actuator(i).name: i for i in range(self.model.nu)}
        self.jaw, self.seconds = float(jaw), float(seconds)
        self.frame = 0
        self.log = []
        landmarks = dict(zip((str(k) for k in self.rig.fdp_ids), self.sim.fdp_points()))
        rest = self.sim.surface()
        self._landmarks, self._rest_head, self._views = landmarks, rest, {}

    @property
    def time(self) -> float:
        return self.frame / self.sim.fps

    def controls(self, t: float) -> dict:
        """Actuator targets at time ``t`` [s]: neck pan/tilt sweeps, a speaking jaw rhythm."""
        talk = 0.5 * (1.0 - math.cos(2 * math.pi * 2.5 * t)) * (0.6 + 0.4 * math.sin(2 * math.pi * 0.7 * t))
        return {"neck_pan": 0.5 * math.sin(2 * math.pi * 0.25 * t), "neck_tilt": 0.2 * math.sin(2 * math.pi * 0.4 * t),
                "jaw_open": self.jaw * talk, "jaw_side": 0.0}

    def step(self) -> None:
        """One frame: actuator targets, the smile, then skin, mandible and neck together."""
        for name, value in self.controls(self.time).items():
            self.data.ctrl[self.act[name]] = value
        smile = min(1.0, max(0.0, (self.time - 0.5 * self.seconds) / 0.3))
        self.sim.set_activations({"zygomatic_major": 0.6 * smile})
        self.coupler.step()
        self.frame += 1
        R, t = self.sim.head_pose
        chin = self.sim.fdp("2.1")
        self.log.append({"t": self.time, "neck_pan": float(self.data.qpos[0]), "neck_tilt": float(self.data.qpos[1]),
                         "jaw": float(self.data.qpos[2]), "chin_world_m": chin.tolist(),
                         "chin_head_m": (R.T @ (chin - t)).tolist()})

    def view(self, size: int):
        """The fixed world camera of ``size``-pixel renders on the whole head (room to nod and turn)."""
        if size not in self._views:
            self._views[size] = fw.render.FaceView(self._rest_head, self.rig.head_faces, self._landmarks,
                                                   self.rig.parts, view="front", size=size, aspect=1.0, reach=0.06,
                                                   device=self.sim.device)
        return self._views[size]

    def render(self, *, size: int = 320) -> np.ndarray:
        """The head in the world, front view, RGB (size, size, 3) uint8."""
        return self.view(int(size)).render(self.sim.surface(), part_points=self.sim.part_points())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--jaw", type=float, default=0.15, help="largest jaw opening [rad]")
    ap.add_argument("--size", type=int, default=280)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    if not (math.isfinite(a.seconds) and a.seconds > 0):
        ap.error(f"--seconds: expected a positive number, got {a.seconds}")
    scene = RobotHead(jaw=a.jaw, seconds=a.seconds, device=a.device)
    frames = max(1, int(round(a.seconds * scene.sim.fps)))
    picks = set(np.linspace(0, frames, 6).round().astype(int).tolist())
    images = [scene.render(size=a.size)]
    for k in range(1, frames + 1):
        scene.step()
        if k in picks:
            images.append(scene.render(size=a.size))
    a.out.mkdir(parents=True, exist_ok=True)
    fw.save_png(a.out / "robot_head.png", np.concatenate(images, axis=1),
                title="animatronic head: neck pan/tilt, speaking jaw, smile in the second half")
    (a.out / "robot_head.json").write_text(json.dumps({"frames": scene.log}, indent=1))
    print(f"robot head: {frames} frames, wrote {a.out}/robot_head.png, robot_head.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
