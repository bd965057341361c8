"""A robot with a face: head.xml mounted on the pan/tilt neck of a simple robot body, in MuJoCo.

``scenes/robot.xml`` is the robot (a pedestal, a torso, a neck with ``neck_pan`` about z and
``neck_tilt`` about y, position actuators; Z-up, facing +x). The default head's MJCF with its skin
(:func:`facewarp.head_mjcf` ``skin=``) is attached under the neck's ``head_mount`` body with the
name prefix ``head/`` (``MjSpec`` attach: the robot's options stay). The face plays the Fig. 6.16
sequence (smile, laugh, surprise, angry, sad; the jaw through the MuJoCo hinge,
:class:`facewarp.MujocoJaw`) while the neck turns and nods; each frame :class:`facewarp.MujocoSkin`
moves the skin mesh inside the MuJoCo model and uploads it to MuJoCo's offscreen renderer.

Writes ``robot.png`` (MuJoCo renders of the face camera at rest and at each expression's peak),
``robot_wide.png`` (the whole robot at the smile's peak), ``robot.json`` (per frame: neck and jaw
angles, mouth width, skin-update cost) and ``robot_head.xml`` (the combined model, for
``python -m mujoco.viewer --mjcf OUT/robot_head.xml``; ``--viewer`` runs the scene live in the
viewer instead, where there is a display).

    MUJOCO_GL=egl python -m scenes.robot --device cpu --out out/robot [--each 0.8] [--size 360]

Offscreen rendering needs EGL (a GPU driver's libEGL, or Mesa's libegl1 + libegl-mesa0 on a CPU)
or OSMesa (``apt-get install libosmesa6``, ``MUJOCO_GL=osmesa``). Public names only.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
    import ctypes.util

    # offscreen through EGL, else OSMesa (MUJOCO_GL is read when mujoco is first imported)
    os.environ.setdefault("MUJOCO_GL", "egl" if ctypes.util.find_library("EGL") or
                          not ctypes.util.find_library("OSMesa") else "osmesa")

import numpy as np  # noqa: E402

import facewarp as fw  # noqa: E402

ROBOT_XML = Path(__file__).resolve().with_name("robot.xml")
PREFIX = "head/"


class RobotScene:
    """The face on the robot's neck, stepped one frame per :meth:`step`.

    Args:
        each: Seconds per expression of the Fig. 6.16 sequence.
        level: Template level of the head.
        device: Warp device of the skin.
    """

    def __init__(self, *, each: float = 0.8, level: int = 0, device: str = "cpu"):
        import mujoco

        self.mujoco = mujoco
        self.head = fw.default_template(level)
        self.rig = fw.build_face(self.head)
        self.sim = fw.FaceSimulator(self.rig, device=device)
        spec = mujoco.MjSpec.from_file(str(ROBOT_XML))
        head_spec = mujoco.MjSpec.from_string(
            fw.head_mjcf(self.head, jaw=self.rig.jaw, skin=(self.rig.head_vertices, self.rig.head_faces)))
        # the head's own neck stub ends at its lowest point: stand it on the mount
        lift = -float(np.min(np.asarray(self.head.vertices)[:, 1]))
        spec.body("head_mount").add_frame(pos=[0.0, 0.0, lift]).attach_body(head_spec.body("cranium"), PREFIX, "")
        self.spec = spec
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.coupler = fw.MujocoJaw(self.sim, self.model, self.data)
        self.skin = fw.MujocoSkin(self.sim, self.model)
        self.timeline = fw.thesis_sequence(each=each).for_head(self.rig)
        self.seconds = max(s.start + s.attack + s.hold + s.release for s in self.timeline.segments) + 0.2
        self.act = {self.model.actuator(i).name: i for i in range(self.model.nu)}
        self.qpos = {n: int(self.model.joint(n).qposadr[0]) for n in ("neck_pan", "neck_tilt", PREFIX + "jaw_open")}
        self.frame = 0
        self.log = []
        ids = [str(k) for k in self.rig.fdp_ids]
        self._corners = (ids.index("8.3"), ids.index("8.4"))  # the mouth corners
        self._width0 = self.mouth_width()

    @property
    def time(self) -> float:
        return self.frame / self.sim.fps

    def peaks(self) -> list[tuple[str, int]]:
        """(expression name, frame) at the end of each expression's hold."""
        return [(s.expression.name, int(math.floor((s.start + s.attack + s.hold) * self.sim.fps + 1e-9)))
                for s in self.timeline.segments]

    def mouth_width(self) -> float:
        """Distance between the mouth corners (FDP 8.3, 8.4) [m]."""
        P = self.sim.fdp_points()
        return float(np.linalg.norm(P[self._corners[0]] - P[self._corners[1]]))

    def step(self, *renderers) -> None:
        """One frame: the expression and neck targets, skin + mandible + neck in MuJoCo, the skin
        mesh written into the model and uploaded to ``renderers``."""
        t = self.time
        e = self.timeline.sample(t)
        self.sim.set_activations(e)
        ctrl = {"neck_pan": 0.35 * math.sin(2 * math.pi * 0.2 * t), "neck_tilt": 0.12 * math.sin(2 * math.pi * 0.33 * t),
                PREFIX + "jaw_open": e.jaw_u, PREFIX + "jaw_side": e.jaw_v}
        for name, value in ctrl.items():
            self.data.ctrl[self.act[name]] = value
        self.coupler.step()
        before = sum(self.skin.update_seconds.values())
        self.skin.update(*renderers)
        self.frame += 1
        self.log.append({"t": self.time, **{k: float(self.data.qpos[q]) for k, q in self.qpos.items()},
                         "mouth_width_change_mm": 1e3 * (self.mouth_width() - self._width0),
                         "skin_update_ms": 1e3 * (sum(self.skin.update_seconds.values()) - before)})

    def render(self, renderer, camera: str) -> np.ndarray:
        """MuJoCo's render of the model now from ``camera``, RGB (h, w, 3) uint8."""
        self.mujoco.mj_forward(self.model, self.data)
        renderer.update_scene(self.data, camera=camera)
        return renderer.render().copy()


def _label(img: np.ndarray, text: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    im = Image.fromarray(img)
    ImageDraw.Draw(im).text((8, 6), text, fill=(255, 255, 255))
    return np.asarray(im)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--each", type=float, default=0.8, help="seconds per expression of the sequence")
    ap.add_argument("--size", type=int, default=360, help="pixels of each face render")
    ap.add_argument("--frames", type=int, default=None, help="stop after this many frames (default: the sequence)")
    ap.add_argument("--viewer", action="store_true", help="run live in MuJoCo's viewer (needs a display)")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    if not (math.isfinite(a.each) and a.each > 0):
        ap.error(f"--each: expected a positive number, got {a.each}")
    if a.size < 16:
        ap.error(f"--size: expected at least 16 pixels, got {a.size}")
    scene = RobotScene(each=a.each, device=a.device)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "robot_head.xml").write_text(scene.spec.to_xml())
    frames = int(round(scene.seconds * scene.sim.fps)) if a.frames is None else max(1, a.frames)
    if a.viewer:
        import time

        import mujoco.viewer

        with mujoco.viewer.launch_passive(scene.model, scene.data) as handle:
            for _ in range(frames):
                if not handle.is_running():
                    break
                t0 = time.perf_counter()
                with handle.lock():
                    scene.step()
                scene.skin.update(handle)
                handle.sync()
                time.sleep(max(0.0, 1.0 / scene.sim.fps - (time.perf_counter() - t0)))
        return 0
    import mujoco

    face = mujoco.Renderer(scene.model, a.size, a.size)
    wide = mujoco.Renderer(scene.model, 480, 640)
    picks = {0: "rest"}
    for name, k in scene.peaks():
        if k <= frames:
            picks.setdefault(k, f"{name} (t={k / scene.sim.fps:.2f} s)")
    images = [_label(scene.render(face, "face"), picks[0])]
    wide_img = None
    for k in range(1, frames + 1):
        scene.step(face, wide)
        if k in picks:
            images.append(_label(scene.render(face, "face"), picks[k]))
            if picks[k].startswith("smile"):
                wide_img = scene.render(wide, "wide")
    fw.save_png(a.out / "robot.png", np.concatenate(images, axis=1),
                title="MuJoCo's renderer: the simulated face on a pan/tilt neck, rest and each expression's peak")
    if wide_img is not None:
        fw.save_png(a.out / "robot_wide.png", wide_img, title="the robot at the smile's peak (MuJoCo renderer)")
    cost = [r["skin_update_ms"] for r in scene.log[1:]] or [0.0]
    peak_w = max((r["mouth_width_change_mm"] for r in scene.log), default=0.0)
    (a.out / "robot.json").write_text(json.dumps({"peaks": scene.peaks(), "frames": scene.log,
                                                  "skin_update_ms_median": float(np.median(cost))}, indent=1))
    print(f"robot: {frames} frames, mouth {peak_w:+.1f} mm wider at most, skin update {np.median(cost):.1f} ms/frame "
          f"(median); wrote {a.out}/robot.png, robot_wide.png, robot.json, robot_head.xml")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
