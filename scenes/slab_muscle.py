"""Single linear muscle under a skin slab: the experiments of thesis Figs. 6.9 and 6.10.

A square sheet of skin (n x n grid of triangles) is extruded into a two-layer tet slab; one linear
muscle (a quadratic Bezier fibre with ellipsoid segments) runs under it along +x. Inner-layer nodes
are attached to the muscle where their distance to the nearest segment surface is below lambda and
the angle between the connection and the fibre is below the limit theta (Fig. 6.4); the slab's
border is fixed. Fig. 6.9 varies theta at activation 0.5, Fig. 6.10 varies the activation at
theta = pi/4. Each panel shows the skin surface coloured by displacement after the muscle pulled.

    python scenes/slab_muscle.py --output out/slab [--device cpu] [--grid 24] [--seconds 0.15]

Writes ``slab_angle.png`` (Fig. 6.9), ``slab_activation.png`` (Fig. 6.10) and ``slab.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import warp as wp

from facewarp._src.physics.model import ModelBuilder
from facewarp._src.physics.muscle_stage import MuscleRig, MuscleStage, ellipsoid_point, ellipsoid_uv, segment_frames
from facewarp._src.present.render import colormap, render_mesh, save_png
from facewarp._src.physics.solvers.verlet import SolverVerlet, simulate, stable_dt
from facewarp._src.anatomy.tissue import split_prisms


def make_slab(n: int, size: float, thickness: float):
    """Grid sheet (n x n cells) of side ``size`` [m] extruded by ``thickness`` [m] downward."""
    g = np.stack(np.meshgrid(np.linspace(0, size, n + 1), np.linspace(0, size, n + 1), indexing="ij"), -1).reshape(-1, 2)
    top = np.c_[g, np.zeros(len(g))]
    F = []
    for i in range(n):
        for j in range(n):
            a, b, c, d = i * (n + 1) + j, (i + 1) * (n + 1) + j, (i + 1) * (n + 1) + j + 1, i * (n + 1) + j + 1
            F += [(a, b, c), (a, c, d)]
    F = np.array(F)
    V = np.concatenate([top, top - [0, 0, thickness]])
    T, _ = split_prisms(F, F + len(top))  # Fig. 6.2 split, conforming across prisms
    return V, T, F


def make_rig(V, inner, size, depth, theta_limit, lam, stiffness):
    """One linear muscle along +x under the slab, attached to inner nodes (Fig. 6.4)."""
    y = 0.5 * size
    ctrl = np.array([[0.25 * size, y, -depth], [0.55 * size, y, -depth - 0.002], [0.9 * size, y, -depth]])
    segs = 5
    t = np.linspace(0, 1, segs + 1)
    rig = MuscleRig(
        names=["slab"], activation_index=np.array([0]), contraction=np.array([0.3]), center=np.zeros((1, 3)),
        center_jaw=np.zeros(1), ctrl_rest=ctrl, ctrl_muscle=np.zeros(3, int), ctrl_pivot=np.array([2, 2, -2]),
        ctrl_jaw=np.zeros(3), curve_ctrl=np.array([[0, 1, 2]]), curve_weight=np.ones((1, 3)),
        seg_curve=np.zeros(segs, int), seg_t=np.stack([t[:-1], t[1:]], 1), seg_rest_radii=np.zeros((segs, 3)),
    )
    c, f, r = segment_frames(rig, ctrl)
    taper = np.ones(segs)
    taper[[0, -1]] = 0.6
    rig.seg_rest_radii = np.c_[r[:, 0], 0.003 * taper, 0.003 * taper]
    c, f, r = segment_frames(rig, ctrl)
    P = V[inner]
    # nearest segment and its surface point (u, v)
    d_centre = np.linalg.norm(P[:, None] - c[None], axis=-1)
    seg = np.argmin(d_centre, axis=1)
    uv = ellipsoid_uv(c[seg], f[seg], r[seg], P)
    pm = ellipsoid_point(c[seg], f[seg], r[seg], uv)
    conn = pm - P
    dist = np.linalg.norm(conn, axis=1)
    fibre = f[seg][:, :, 0]
    ang = np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", conn, fibre)) / np.maximum(dist, 1e-12), 0, 1))
    # the angle limit of Fig. 6.9 measured from the fibre's normal plane: theta = 0 attaches only
    # nodes straight above the muscle, pi/2 attaches every node within lambda
    ok = (dist < lam) & (np.pi / 2 - ang < theta_limit + 1e-9)
    rig.att_node, rig.att_seg, rig.att_uv = inner[ok], seg[ok], uv[ok]
    rig.att_rest_length = dist[ok]
    rig.att_stiffness = np.full(int(ok.sum()), stiffness)
    return rig


def run_case(V, T, layer, fixed, rig, activation, seconds, device):
    model = ModelBuilder(V, T, layer=layer, fixed=fixed, muscle_count=1).finalize(device)
    stage = MuscleStage(rig, None, model.device)
    solver = SolverVerlet(model, stages=[stage])
    dt = stable_dt(model)
    steps = max(1, int(round(seconds / dt)))
    control = model.control()
    control.activations.assign(np.array([activation], np.float32))
    state = model.state()
    simulate(model, state, control, dt, steps, solver=solver)
    solver.check(state)
    return state.positions.numpy().astype(np.float64), steps, dt


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--output", type=Path, default=Path("out/slab"))
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--grid", type=int, default=24, help="cells per side of the skin sheet")
    ap.add_argument("--seconds", type=float, default=0.15, help="simulated time per case [s]")
    args = ap.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    size, thick, depth = 0.05, 0.003, 0.007
    V, T, F = make_slab(args.grid, size, thick)
    n_top = (args.grid + 1) ** 2
    layer = np.r_[np.zeros(n_top, int), np.ones(n_top, int)]
    xy = V[:, :2]
    fixed = (np.isclose(xy, 0).any(1) | np.isclose(xy, size).any(1))
    inner = np.where(layer == 1)[0]
    results = {"grid": args.grid, "size_m": size, "thickness_m": thick, "cases": []}
    panels = {}
    with wp.ScopedDevice(args.device):
        for fig, cases in (("angle", [(0.5, a) for a in (np.pi / 12, np.pi / 6, np.pi / 4, np.pi / 3)]),
                           ("activation", [(s, np.pi / 4) for s in (0.25, 0.5, 0.75, 1.0)])):
            imgs = []
            for act, theta in cases:
                rig = make_rig(V, inner, size, depth, theta, lam=0.006, stiffness=4e5)
                t0 = time.perf_counter()
                X, steps, dt = run_case(V, T, layer, fixed, rig, act, args.seconds, args.device)
                disp = np.linalg.norm(X[:n_top] - V[:n_top], axis=1)
                results["cases"].append({"figure": fig, "activation": act, "theta_rad": theta,
                                         "attached": int(len(rig.att_node)), "max_displacement_m": float(disp.max()),
                                         "steps": steps, "dt_s": dt, "seconds": time.perf_counter() - t0})
                img = render_mesh(X[:n_top], F, view=(15.0, 15.0), width=340, height=340,
                                  vertex_colors=colormap(disp * 1e3, 0.0, 3.0), device=args.device)
                label = f"theta={np.degrees(theta):.0f} deg" if fig == "angle" else f"sigma={act:.2f}"
                imgs.append((img, label))
                print(fig, label, f"attached {len(rig.att_node)}, max displacement {disp.max() * 1e3:.2f} mm")
            panels[fig] = imgs
    for fig, imgs in panels.items():
        strip = np.concatenate([im for im, _ in imgs], axis=1)
        labels = ", ".join(lbl for _, lbl in imgs)
        title = ("Fig. 6.9, sigma=0.5: " if fig == "angle" else "Fig. 6.10, theta=45 deg: ") + labels
        save_png(args.output / f"slab_{fig}.png", strip, title=title, colorbar=(0.0, 3.0, "displacement [mm]"))
    (args.output / "slab.json").write_text(json.dumps(results, indent=2))
    print("wrote", args.output)


if __name__ == "__main__":
    main()
