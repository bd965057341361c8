"""Newton's SolverVBD / SolverXPBD on the exported peer problem (run in a venv that has ``newton``).

    python benchmarks/_peers_newton.py PROBLEM.npz OUT.npz --solver vbd|xpbd [--substeps 20]
                                       [--iterations 10] [--frames 90] [--load force|springs|none]
                                       [--relaxation 0.9]

Called by :mod:`benchmarks.peers` in a separate virtual environment (Newton may pin another Warp
than facewarp's); imports numpy, warp and newton only, never facewarp.

``PROBLEM.npz`` (written by ``benchmarks._peer_problem.export_problem``; SI units):

* ``nodes`` (n, 3) [m] rest positions, ``tets`` (k, 4) int, ``mass`` (n,) [kg] (0 for pinned
  nodes), ``k_mu``, ``k_lambda`` (k,) [Pa] Lame parameters per tet, ``k_damp`` (k,) [Pa s];
* ``force`` (n, 3) [N]: the constant external load, given as ``State.particle_f`` (``--load force``)
  or as long pre-stretched springs (``--load springs``, :data:`LOAD_LENGTH`), or left out (``none``);
* ``spring_node`` (s,), ``spring_anchor`` (s, 3) [m], ``spring_k`` (s,) [N/m],
  ``spring_rest`` (s,) [m]: springs from a node to a fixed point (the sliding supports, as long
  springs along the rest normal; Newton has no axis spring);
* ``damping_rate`` [1/s]: mass-proportional damping, applied as the force ``-alpha m v`` added
  to the load every substep (Newton's particles have no such damping of their own).

Writes ``OUT.npz``: ``positions`` (frames + 1, n, 3) float32 [m] (frame 0 at rest), ``frame_seconds``
(frames,) wall time per 1/30 s frame (a run stops early once a node is
``DIVERGED`` from rest), ``warmup_seconds`` (the first frame: kernel compilation),
``device``, ``newton_version``, ``warp_version``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import warp as wp


@wp.kernel
def _load_and_damping(
    # Model:
    force: wp.array(dtype=wp.vec3),
    mass: wp.array(dtype=float),
    alpha: float,
    # State in:
    qd_in: wp.array(dtype=wp.vec3),
    # State out:
    f_out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    f_out[i] = force[i] - alpha * mass[i] * qd_in[i]


DIVERGED = 1.0
"""A run stops once a node is this far [m] from rest (the face is ~0.2 m across): diverged."""

PARTICLE_RADIUS = 1e-5
"""Contact radius [m] of the particles (contacts are off: the problem has none)."""

LOAD_LENGTH = 10.0
"""Length [m] of the springs that carry the load with ``--load springs``: node i is tied to an anchor
at ``x_i + LOAD_LENGTH f_i / |f_i|`` by a spring of rest length 0 and stiffness ``|f_i| / LOAD_LENGTH``,
a force of ``|f_i|`` toward the anchor that changes by ``u / LOAD_LENGTH`` (0.2 % for a 2 cm
displacement u) as the node moves: the dead load, but solved implicitly with the tissue."""


def build(problem: dict, solver: str, iterations: int, load: str = "force", relaxation: float = 0.9):
    import newton

    nodes = problem["nodes"].astype(np.float64)
    tets = problem["tets"].astype(np.int64)
    n = len(nodes)
    b = newton.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    # particles and tets one by one (add_soft_mesh would also add zero-stiffness surface triangles)
    for i in range(n):
        b.add_particle(wp.vec3(*nodes[i]), wp.vec3(0.0), float(problem["mass"][i]), radius=PARTICLE_RADIUS)
    for t, (mu, lam, kd) in zip(tets, zip(problem["k_mu"], problem["k_lambda"], problem["k_damp"])):
        b.add_tetrahedron(int(t[0]), int(t[1]), int(t[2]), int(t[3]), float(mu), float(lam), float(kd))
    # masses: facewarp's lumped masses (rho V / 4 per tet corner); pinned nodes 0 (kinematic)
    for node, anchor, k, rest in zip(problem["spring_node"], problem["spring_anchor"], problem["spring_k"],
                                     problem["spring_rest"]):
        a = b.add_particle(wp.vec3(*anchor), wp.vec3(0.0), 0.0, radius=PARTICLE_RADIUS)
        b.add_spring(int(node), a, float(k), 0.0, 0.0)
        b.spring_rest_length[-1] = float(rest)
    if load == "springs":
        f = np.asarray(problem["force"], np.float64)
        fn = np.linalg.norm(f, axis=1)
        for i in np.flatnonzero(fn > 0.0):
            a = b.add_particle(wp.vec3(*(nodes[i] + LOAD_LENGTH * f[i] / fn[i])), wp.vec3(0.0), 0.0,
                               radius=PARTICLE_RADIUS)
            b.add_spring(int(i), a, float(fn[i] / LOAD_LENGTH), 0.0, 0.0)
            b.spring_rest_length[-1] = 0.0
    if solver == "vbd":
        b.color()
    model = b.finalize(device="cpu")
    # no particle-particle contact (the default radius, 0.1 m, makes every node of the face touch every
    # other in XPBD's contact pass); VBD's self contact is off below
    model.particle_grid = None
    model.particle_max_radius = 0.0
    if solver == "vbd":
        s = newton.solvers.SolverVBD(model, iterations=iterations, particle_enable_self_contact=False,
                                     particle_enable_tile_solve=False)
    else:
        s = newton.solvers.SolverXPBD(model, iterations=iterations, soft_body_relaxation=relaxation)
    return model, s


def run(problem: dict, solver: str, substeps: int, iterations: int, frames: int, fps: float = 30.0,
        load: str = "force", relaxation: float = 0.9) -> dict:
    import newton

    wp.init()
    with wp.ScopedDevice("cpu"):
        model, s = build(problem, solver, iterations, load, relaxation)
        n = len(problem["nodes"])
        count = model.particle_count
        force = np.zeros((count, 3), np.float32)
        if load == "force":
            force[:n] = problem["force"]
        force_wp = wp.array(force, dtype=wp.vec3)
        mass_wp = model.particle_mass
        alpha = float(problem["damping_rate"])
        dt = 1.0 / fps / substeps

        def frame(st):
            s0, s1 = st
            for _ in range(substeps):
                s0.clear_forces()
                wp.launch(_load_and_damping, dim=count, inputs=[force_wp, mass_wp, alpha, s0.particle_qd],
                          outputs=[s0.particle_f])
                s.step(s0, s1, None, None, dt)
                s0, s1 = s1, s0
            return s0, s1

        # warm-up frame (kernel compilation) on throw-away states
        t0 = time.perf_counter()
        frame((model.state(), model.state()))
        wp.synchronize()
        warm = time.perf_counter() - t0
        # the timed run, from rest, with a fresh solver
        model, s = build(problem, solver, iterations, load, relaxation)
        mass_wp = model.particle_mass
        st = (model.state(), model.state())
        out = np.zeros((frames + 1, n, 3), np.float32)
        out[0] = st[0].particle_q.numpy()[:n]
        secs = np.zeros(frames)
        for k in range(frames):
            t0 = time.perf_counter()
            st = frame(st)
            wp.synchronize()
            secs[k] = time.perf_counter() - t0
            q = st[0].particle_q.numpy()[:n]
            out[k + 1] = q
            if not np.isfinite(q).all() or np.abs(q - out[0]).max() > DIVERGED:
                out = out[: k + 2]
                secs = secs[: k + 1]
                break
        return {"positions": out, "frame_seconds": secs, "warmup_seconds": warm, "device": "cpu",
                "newton_version": newton.__version__, "warp_version": wp.__version__}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("problem")
    ap.add_argument("out")
    ap.add_argument("--solver", choices=("vbd", "xpbd"), required=True)
    ap.add_argument("--substeps", type=int, default=20)
    ap.add_argument("--iterations", type=int, default=10)
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--relaxation", type=float, default=0.9, help="SolverXPBD soft_body_relaxation (its default 0.9)")
    ap.add_argument("--load", choices=("force", "springs", "none"), default="force",
                    help="the load as State.particle_f (default), as long springs (LOAD_LENGTH), or none (rest)")
    args = ap.parse_args()
    z = np.load(args.problem)
    problem = {k: z[k] for k in z.files}
    res = run(problem, args.solver, args.substeps, args.iterations, args.frames, load=args.load,
              relaxation=args.relaxation)
    np.savez(args.out, **res)
    print(f"{args.solver}: {len(res['frame_seconds'])} frames, {np.median(res['frame_seconds']) * 1e3:.1f} ms/frame "
          f"(warm-up {res['warmup_seconds']:.1f} s)")


if __name__ == "__main__":
    main()
