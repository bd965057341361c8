"""Peers side by side (issue 10): facewarp's implicit solver, Newton's SolverVBD and SolverXPBD and
MuJoCo 4 flex on one problem, on the CPU.

    python -m benchmarks.peers [--preset smile] [--peers-python /work/peers-venv/bin/python]
                               [--skip vbd xpbd mujoco]

The problem (exported from the default head, level 0, through the public API):

* mesh, masses: the tet mesh and facewarp's lumped masses (tissue density 1,100 kg/m^3);
* pinned: the fixed border and the held inner-sheet nodes over bone, at rest (the held nodes'
  springs made rigid);
* supports: the free inner-sheet nodes' sliding supports (a spring along the rest normal,
  ``support_modulus`` x the node's sheet area, as in :class:`facewarp.FaceSimulator`).
  facewarp and MuJoCo get them exactly (facewarp an axis spring; MuJoCo a fixed tendon
  ``n . (x - x0)`` over the vertex's three slide joints); Newton has no axis spring, so it gets a
  spring of rest length ``SUPPORT_LENGTH`` (1 m) to an anchor behind the node along the normal,
  the axis spring to first order; facewarp is also solved with those long springs, Newton's
  static shapes are compared with that, and the difference to the exact supports is reported;
* load: the preset's muscles as constant external forces: the muscle springs' forces of
  Eq. 6.4.1 at facewarp's fully converged preset (muscles, holds, supports; tolerance 1e-7 m),
  applied from t = 0 (a step load). Without the sliding supports the face is a floppy shell on
  which these dead loads have no well-posed static shape (measured: 1 % of the load moves the
  lip corners 5 mm, the full load 46 mm, with the held nodes pinned), so the supports are part
  of the problem; with them facewarp's static shape is the preset's within the held nodes' own
  displacement (``static_shape_vs_preset_mm``);
* material: facewarp's ``physical`` profile. Its three energies have the linear response of an
  isotropic material (:func:`facewarp.physics.isotropic_moduli`); each tet gets the Young's
  modulus and Poisson ratio of the mean of its six edges' distance moduli, given to Newton as
  Lame parameters per tet (its Neo-Hookean FEM); MuJoCo's flex takes one ``young`` / ``poisson``:
  those of the volume-weighted mean Lame parameters (the JSON lists the ranges);
* damping: facewarp's mass-proportional rate alpha [1/s] and Rayleigh beta [s]. MuJoCo: a velocity
  servo ``kv = alpha m`` on each slide joint (it refuses joint damping on flex bodies; the
  ``discrete`` integrator treats both implicitly) and the flex's Rayleigh ``damping`` beta; Newton:
  the force ``-alpha m v`` added each substep, and ``k_damp = beta mu`` per tet.

Solvers and settings: facewarp's default (CPU: L-BFGS on a reused factorisation, tolerance 3e-5 m,
one step per frame); Newton 20 substeps x 10 iterations per 1/30 s frame (its soft-body and cloth
examples: 10 x 10 at 60 fps; VBD also 2 x 10), each with the load as long springs and as ``State.particle_f``
(:data:`NOTES`), XPBD at its default relaxation and at the largest stable one; MuJoCo 4 with its
``discrete`` integrator (the only one that integrates flex elasticity implicitly) at 1 and 10
steps per frame.

Measured per solver, each on its own 30 fps frames from rest:

* wall time per 1/30 s frame (median, after a warm-up frame that compiles the kernels);
* its own converged static shape: facewarp a tight solve (tolerance 1e-7 m, several frames);
  the peers the last frame of the run, with the last frame's change reported;
* time to converge: the first frame from which every node stays within 0.2 mm of that shape,
  in frames, simulated seconds and wall seconds; ratios of per-frame time and wall time to
  converge against facewarp's;
* the static shapes against facewarp's (max / mean node distance [mm]): the material check.

"facewarp implicit, with muscles" is the default face simulator with its real muscles (not the
peer problem), for reference. Newton runs in a separate venv (``--peers-python``) as a subprocess
(:mod:`benchmarks._peers_newton`) on an exported npz; when it is missing the JSON says so.
Writes benchmarks/results/peers_cpu.json and peers_cpu.md.
"""
from __future__ import annotations

import argparse
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import _common
from benchmarks._common import RESULTS, add_case_args, save
from benchmarks._peer_problem import SUPPORT_LENGTH, export_problem

FPS = 30.0
WITHIN = 2e-4  # m: "within 0.2 mm of its own converged shape"
SETTLED = 1e-6  # m: a peer's last frame is its converged shape if no node moved more than this in it
MUJOCO_FRAMES = {1: 300, 10: 90}  # frames per MuJoCo run, by steps per frame (1 step / frame settles slowly)
PEERS_PYTHON = "/work/peers-venv/bin/python"
NEWTON_RUNS = (
    # (label, solver, load, soft_body_relaxation, substeps, iterations, frames): Newton's soft-body and cloth
    # examples use 60 fps with 10 substeps of 10 iterations (dt 1/600 s), here 20 x 10 per 1/30 s frame;
    # VBD (implicit Euler) also at 2 substeps x 10 iterations, 10x cheaper
    ("newton SolverVBD", "vbd", "springs", None, 20, 10, 45),
    ("newton SolverVBD, 2 substeps", "vbd", "springs", None, 2, 10, 150),
    ("newton SolverVBD, load as State.particle_f", "vbd", "force", None, 20, 10, 45),
    ("newton SolverXPBD (default relaxation 0.9)", "xpbd", "springs", 0.9, 20, 10, 45),
    ("newton SolverXPBD (default relaxation 0.9), no load (rest)", "xpbd", "none", 0.9, 20, 10, 45),
    ("newton SolverXPBD (relaxation 0.1)", "xpbd", "springs", 0.1, 20, 10, 45),
    ("newton SolverXPBD (relaxation 0.1), load as State.particle_f", "xpbd", "force", 0.1, 20, 10, 45),
)


# ----------------------------------------------------------------------------------- metrics
def _max_dist(P, Q) -> np.ndarray:
    """Largest node distance [m] of each frame of P (f, n, 3) to Q (n, 3)."""
    return np.linalg.norm(np.asarray(P, np.float64) - Q[None], axis=2).max(axis=1)


def convergence(positions, frame_seconds, converged) -> dict:
    """Frames / seconds until every node stays within WITHIN of ``converged`` (frame 0 = rest)."""
    dist = _max_dist(positions, converged)
    out_ = np.flatnonzero(dist >= WITHIN)
    k = 0 if len(out_) == 0 else int(out_[-1]) + 1  # first frame after the last one outside
    reached = k < len(dist)
    secs = float(np.sum(frame_seconds[:k])) if reached else None
    return {"frames_to_within_0.2mm": k if reached else None,
            "sim_seconds_to_within_0.2mm": round(k / FPS, 4) if reached else None,
            "wall_seconds_to_within_0.2mm": round(secs, 4) if reached else None,
            "distance_mm_per_frame_first_10": [round(float(v) * 1e3, 3) for v in dist[1:11]],
            "final_distance_mm": round(float(dist[-1]) * 1e3, 4)}


def _shape_diff(A, B, free) -> dict:
    d = np.linalg.norm(A[free] - B[free], axis=1)
    return {"max_mm": round(float(d.max()) * 1e3, 3), "mean_mm": round(float(d.mean()) * 1e3, 3)}


# ----------------------------------------------------------------------------------- ours
class _FixedSprings:
    """A solver stage whose springs never change (the supports of the peer problem)."""

    def __init__(self, springs):
        self.springs = springs

    def prepare(self, model, state_in, control, dt, targets) -> None:
        pass


def _support_springs(problem, kind: str):
    import warp as wp
    from facewarp.physics import Springs

    def arr(a, dtype):
        return wp.array(np.ascontiguousarray(a), dtype=dtype, device="cpu")

    sn = problem["support_node"].astype(np.int32)
    k = arr(problem["support_k"].astype(np.float32), float)
    if kind == "axis":
        return Springs(node=arr(sn, wp.int32), point=arr(problem["nodes"][sn].astype(np.float32), wp.vec3),
                       stiffness=k, axis=arr(problem["support_normal"].astype(np.float32), wp.vec3))
    return Springs(node=arr(sn, wp.int32), point=arr(problem["spring_anchor"].astype(np.float32), wp.vec3),
                   stiffness=k, rest_length=arr(problem["spring_rest"].astype(np.float32), float))


def run_ours(problem, frames: int, *, supports: str = "axis", tolerance: float = 3e-5, **kw) -> dict:
    """facewarp's default implicit solver (CPU: L-BFGS) on the peer problem, one step per frame."""
    from facewarp.physics import ModelBuilder, select_solver

    b = ModelBuilder(problem["nodes"], problem["tets"], layer=problem["layer"], fixed=problem["pinned"],
                     material="physical")
    m = b.finalize("cpu")
    stage = _FixedSprings(_support_springs(problem, supports))

    def solver():
        return select_solver(m, stages=[stage], tolerance=tolerance, **kw)

    s = solver()
    st, sc, c = m.state(), m.state(), m.control()
    c.external_force.assign(problem["force"].astype(np.float32))
    s.step(st, sc, c, 1.0 / FPS)  # warm-up: kernels, first factorisation
    s = solver()
    st, sc = m.state(), m.state()
    out = np.zeros((frames + 1, len(problem["nodes"]), 3), np.float32)
    out[0] = problem["nodes"]
    secs = np.zeros(frames)
    iters = []
    for k in range(frames):
        t0 = time.perf_counter()
        s.step(st, sc, c, 1.0 / FPS)
        st, sc = sc, st
        out[k + 1] = st.positions.numpy()
        secs[k] = time.perf_counter() - t0
        iters.append(s.last_iterations)
    return {"positions": out, "frame_seconds": secs, "iterations": iters, "factorizations": s.factorizations,
            "method": s.method}


def run_ours_muscles(fr, preset: str, frames: int) -> dict:
    """Reference: facewarp's face simulator with its muscles (the preset switched on at t = 0)."""
    import facewarp

    out = {}
    for label, kw in (("converged", dict(tolerance=1e-7, solver_options=dict(spring_tolerance=1e-4, max_iterations=500))),
                      ("default", {})):
        sim = facewarp.FaceSimulator(fr, device="cpu", **kw)
        sim.set_activations(facewarp.preset(preset))
        sim.step()  # warm-up
        sim.reset()
        sim.set_activations(facewarp.preset(preset))
        P = [sim.positions()]
        secs = []
        for _ in range(frames):
            t0 = time.perf_counter()
            sim.step()
            secs.append(time.perf_counter() - t0)
            P.append(sim.positions())
        out[label] = (np.array(P), np.array(secs))
    P, secs = out["default"]
    conv = out["converged"][0][-1]
    return {"frame_ms": round(float(np.median(secs)) * 1e3, 2), "frames_per_second": round(1 / float(np.median(secs)), 1),
            **convergence(P, secs, conv)}


# ----------------------------------------------------------------------------------- Newton
def run_newton(problem, solver: str, frames: int, python: str, tmp: Path, load: str = "springs",
               relaxation: float | None = None, substeps: int = 20, iterations: int = 10) -> dict:
    """One Newton run in the peers venv (:mod:`benchmarks._peers_newton`), or why it was skipped."""
    if not Path(python).exists():
        return {"skipped": f"no Python at {python} (make a venv with `pip install newton`)"}
    check = subprocess.run([python, "-c", "import newton, warp; print(newton.__version__)"], capture_output=True, text=True)
    if check.returncode != 0:
        return {"skipped": f"newton is not importable by {python}: {check.stderr.strip().splitlines()[-1:]}"}
    src = tmp / "problem.npz"
    if not src.exists():
        np.savez(src, **{k: problem[k] for k in ("nodes", "tets", "mass", "k_mu", "k_lambda", "k_damp", "force",
                                                "spring_node", "spring_anchor", "spring_k", "spring_rest",
                                                "damping_rate")})
    dst = tmp / f"{solver}_{load}_{relaxation}_{substeps}_{iterations}.npz"
    script = Path(__file__).resolve().parent / "_peers_newton.py"
    cmd = [python, str(script), str(src), str(dst), "--solver", solver, "--substeps", str(substeps),
           "--iterations", str(iterations), "--frames", str(frames), "--load", load]
    if relaxation is not None:
        cmd += ["--relaxation", str(relaxation)]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        return {"error": (r.stderr or r.stdout).strip()[-2000:]}
    z = np.load(dst)
    settings = {"substeps": substeps, "iterations": iterations, "load": load, "dt_s": 1 / FPS / substeps}
    if relaxation is not None:
        settings["soft_body_relaxation"] = relaxation
    return {"positions": z["positions"], "frame_seconds": z["frame_seconds"], "warmup_seconds": float(z["warmup_seconds"]),
            "settings": settings, "newton_version": str(z["newton_version"]), "warp_version": str(z["warp_version"]),
            "device": str(z["device"]), "subprocess_seconds": round(time.perf_counter() - t0, 1)}


# ----------------------------------------------------------------------------------- MuJoCo
def mujoco_xml(problem, timestep: float, integrator: str = "discrete") -> str:
    """MJCF of the peer problem (MuJoCo 4): a body with three slide joints (x, y, z) per free node carrying
    its mass, pinned nodes on the world body, one ``<flex dim="3">``
    over our tets with ``<elasticity young poisson damping>``, and each sliding support a fixed
    tendon ``n . (x - x0)`` over the node's slide joints with the support's stiffness. MuJoCo refuses
    joint damping on flex vertex bodies, so the mass damping ``-alpha m v`` is a velocity servo
    (``kv = alpha m``, control 0) on each slide joint, implicit under the ``discrete`` integrator."""
    X, T = problem["nodes"], problem["tets"]
    pinned, m = problem["pinned"], problem["mass_all"]
    bodies, names, verts = [], [], []
    for i, p in enumerate(X):
        if pinned[i]:
            names.append("world")
            verts.append(f"{p[0]:.9g} {p[1]:.9g} {p[2]:.9g}")
            continue
        names.append(f"v{i}")
        verts.append("0 0 0")
        joints = "".join(f'<joint name="v{i}{a}" type="slide" axis="{ax}"/>' for a, ax in (("x", "1 0 0"), ("y", "0 1 0"), ("z", "0 0 1")))
        bodies.append(f'<body name="v{i}" pos="{p[0]:.9g} {p[1]:.9g} {p[2]:.9g}">{joints}'
                      f'<inertial pos="0 0 0" mass="{m[i]:.6g}" diaginertia="1e-12 1e-12 1e-12"/></body>')
    # mass damping alpha m on each slide joint: velocity servos (ctrl 0) that the discrete integrator
    # treats implicitly (MuJoCo refuses joint damping on flex vertex bodies)
    alpha = float(problem["damping_rate"])
    servos = "".join(f'<velocity joint="v{i}{a}" kv="{alpha * m[i]:.6g}"/>' for i in np.flatnonzero(~pinned)
                     for a in "xyz")
    tendons = []
    for j, (i, n, k) in enumerate(zip(problem["support_node"], problem["support_normal"], problem["support_k"])):
        coefs = "".join(f'<joint joint="v{i}{a}" coef="{c:.9g}"/>' for a, c in zip("xyz", n))
        tendons.append(f'<fixed name="s{j}" stiffness="{k:.6g}" springlength="0">{coefs}</fixed>')
    elements = " ".join(" ".join(map(str, t)) for t in T)
    return f"""<mujoco model="facewarp peer problem">
  <option timestep="{timestep:.6g}" gravity="0 0 0" integrator="{integrator}"/>
  <worldbody>{''.join(bodies)}</worldbody>
  <deformable>
    <flex name="skin" dim="3" radius="0.0002" body="{' '.join(names)}" vertex="{' '.join(verts)}" element="{elements}">
      <elasticity young="{float(problem['young_mean']):.6g}" poisson="{float(problem['poisson_mean']):.6g}" damping="{float(problem['stiffness_damping']):.6g}"/>
      <contact contype="0" conaffinity="0" selfcollide="none"/>
    </flex>
  </deformable>
  <tendon>{''.join(tendons)}</tendon>
  <actuator>{servos}</actuator>
</mujoco>
"""


def run_mujoco(problem, frames: int, steps_per_frame: int) -> dict:
    """MuJoCo 4 flex (``discrete`` integrator: the effective metric M + hD + h^2 K, default Newton
    solver and iterations) on the peer problem, ``steps_per_frame`` steps per 1/30 s frame."""
    try:
        import mujoco
    except ImportError as e:  # pragma: no cover - mujoco is a facewarp dependency
        return {"skipped": f"mujoco is not installed ({e})"}
    h = 1.0 / FPS / steps_per_frame
    try:
        m = mujoco.MjModel.from_xml_string(mujoco_xml(problem, h))
    except ValueError as e:
        return {"error": str(e)}
    d = mujoco.MjData(m)
    free = np.flatnonzero(~problem["pinned"])
    jid = np.array([[m.joint(f"v{i}{a}").id for a in "xyz"] for i in free])
    dof = m.jnt_dofadr[jid].ravel()
    qadr = m.jnt_qposadr[jid]
    d.qfrc_applied[dof] = problem["force"][free].ravel()
    X0 = problem["nodes"]

    def frame():
        for _ in range(steps_per_frame):
            mujoco.mj_step(m, d)

    t0 = time.perf_counter()
    frame()  # warm-up
    warm = time.perf_counter() - t0
    mujoco.mj_resetData(m, d)
    d.qfrc_applied[dof] = problem["force"][free].ravel()
    out = np.zeros((frames + 1, len(X0), 3), np.float32)
    out[:] = X0
    secs = np.zeros(frames)
    for k in range(frames):
        t0 = time.perf_counter()
        frame()
        secs[k] = time.perf_counter() - t0
        out[k + 1, free] = X0[free] + d.qpos[qadr]
        if not np.isfinite(out[k + 1]).all() or np.abs(out[k + 1] - X0).max() > 1.0:
            out, secs = out[: k + 2], secs[: k + 1]
            break
    warnings = {int(i): int(w.number) for i, w in enumerate(d.warning) if w.number}
    return {"positions": out, "frame_seconds": secs, "warmup_seconds": round(warm, 3),
            "settings": {"integrator": "discrete", "solver": ["PGS", "CG", "Newton"][m.opt.solver],
                         "iterations": int(m.opt.iterations), "steps_per_frame": steps_per_frame, "dt_s": h},
            "mujoco_version": mujoco.__version__, "warning_counts": warnings,
            "dofs": int(m.nv), "support_tendons": int(m.ntendon)}


# ----------------------------------------------------------------------------------- report
def summarize(r: dict, ours: dict | None, ref_shape, free, converged=None) -> dict:
    """Per-frame time, time to converge and the static shape against facewarp's (``ref_shape``), for
    one run; ``converged``: the run's converged shape (default: its last frame)."""
    if "positions" not in r:
        return {k: v for k, v in r.items()}
    P, secs = r["positions"], np.asarray(r["frame_seconds"])
    frames = len(secs)
    diverged = frames > 0 and (not np.isfinite(P[-1]).all() or np.abs(P[-1] - P[0]).max() > 1.0)
    out = {k: v for k, v in r.items() if k not in ("positions", "frame_seconds")}
    out.update({"frames_run": frames, "frame_ms": round(float(np.median(secs)) * 1e3, 2),
                "frames_per_second": round(1.0 / float(np.median(secs)), 2),
                "realtime_factor": round(1.0 / FPS / float(np.median(secs)), 4)})
    if diverged:
        out["diverged"] = (f"after {frames} frames a node is {np.abs(P[-1] - P[0]).max():.3g} m from rest "
                           "(the face is ~0.2 m across)")
        return out
    conv = P[-1].astype(np.float64) if converged is None else converged
    change = float(np.linalg.norm(P[-1] - P[-2], axis=1).max())
    out["frame_ms_mean_first_10"] = round(float(np.mean(secs[:10])) * 1e3, 2)
    out["last_frame_change_mm"] = round(change * 1e3, 5)
    out["max_displacement_mm"] = round(float(np.linalg.norm(conv - P[0], axis=1).max()) * 1e3, 3)
    out.update(convergence(P, secs, conv))
    if converged is None and change > SETTLED:
        out["not_settled"] = (f"the last of {frames} frames still moved a node {change * 1e3:.3f} mm: no converged "
                              "shape within the run, so no time to 0.2 mm")
        for k in ("frames_to_within_0.2mm", "sim_seconds_to_within_0.2mm", "wall_seconds_to_within_0.2mm"):
            out[k] = None
    if ref_shape is not None:
        out["static_shape_vs_ours"] = _shape_diff(conv, ref_shape, free)
    if ours is not None:
        out["frame_time_ratio_vs_ours"] = round(out["frame_ms"] / ours["frame_ms"], 2)
        a, b = out.get("wall_seconds_to_within_0.2mm"), ours.get("wall_seconds_to_within_0.2mm")
        out["converge_time_ratio_vs_ours"] = round(a / b, 2) if a is not None and b else None
    return out


def pairwise(shapes: dict, solvers: dict, free) -> dict:
    """Max / mean node distance [mm] between every two settled solvers' static shapes."""
    ok = [k for k, v in shapes.items() if v is not None and "diverged" not in solvers.get(k, {})
          and "not_settled" not in solvers.get(k, {})]
    return {f"{a} | {b}": _shape_diff(np.asarray(shapes[a], np.float64), np.asarray(shapes[b], np.float64), free)
            for i, a in enumerate(ok) for b in ok[i + 1:]}


def markdown(result: dict, doc: dict) -> str:
    rows = ["| solver | settings | ms / frame (median; mean of first 10) | x ours | frames to 0.2 mm | "
            "wall s to 0.2 mm | x ours | max displacement [mm] | static shape vs ours max / mean [mm] |",
            "|---|---|---|---|---|---|---|---|---|"]
    for name, r in result["solvers"].items():
        if "frame_ms" not in r:
            rows.append(f"| {name} | | {r.get('skipped') or r.get('error', '')[:120]} | | | | | | |")
            continue
        cfg = ", ".join(f"{k} {v}" for k, v in r.get("settings", {}).items() if k != "dt_s")
        ms = f"{r['frame_ms']}" + (f"; {r['frame_ms_mean_first_10']}" if "frame_ms_mean_first_10" in r else "")
        if "diverged" in r:
            rows.append(f"| {name} | {cfg} | {ms} | {r.get('frame_time_ratio_vs_ours', '')} | diverged: "
                        f"{r['diverged']} | | | | |")
            continue
        sv = r.get("static_shape_vs_ours")
        shape = f"{sv['max_mm']} / {sv['mean_mm']}" if sv else "-"
        fr = r.get("frames_to_within_0.2mm")
        fr = fr if fr is not None else ("not settled in %d frames" % r["frames_run"] if "not_settled" in r else "-")
        rows.append(f"| {name} | {cfg} | {ms} | {r.get('frame_time_ratio_vs_ours', '-')} | {fr} | "
                    f"{r.get('wall_seconds_to_within_0.2mm') or '-'} | {r.get('converge_time_ratio_vs_ours') or '-'} | "
                    f"{r.get('max_displacement_mm', '-')} | {shape} |")
    pw = result.get("static_shapes_pairwise_mm", {})
    if pw:
        rows += ["", "Static shapes of the settled solvers, pairwise (max / mean node distance [mm]):", "",
                 "| pair | max | mean |", "|---|---|---|"]
        rows += [f"| {k} | {v['max_mm']} | {v['mean_mm']} |" for k, v in pw.items()]
    p = result["problem"]
    head = (f"# Peers side by side (CPU, {doc['machine']['cores']} cores)\n\n"
            f"Default head level 0 ({p['nodes']} nodes, {p['tets']} tets, {p['pinned']} pinned, "
            f"{p['supports']} sliding supports); load: {p['load']}; material: E {p['young_range_pa'][0]:.0f}-"
            f"{p['young_range_pa'][1]:.0f} Pa, nu {p['poisson_range'][0]:.3f}-{p['poisson_range'][1]:.3f} per tet "
            f"(MuJoCo one flex: E {p['young_mean_pa']:.0f} Pa, nu {p['poisson_mean']:.3f}). "
            "Generated by `python -m benchmarks.peers`; details in peers_cpu.json.\n\n")
    notes = "\n".join(f"- {n}" for n in result.get("notes", []))
    return head + "\n".join(rows) + "\n\n" + notes + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_case_args(ap, preset="smile")
    ap.add_argument("--peers-python", default=PEERS_PYTHON, help="a Python whose environment has newton")
    ap.add_argument("--skip", nargs="*", default=[], choices=["vbd", "xpbd", "mujoco"])
    args = ap.parse_args(argv)
    import facewarp

    t_all = time.perf_counter()
    fr = facewarp.build_face(facewarp.default_template(0))
    problem = export_problem(fr, args.preset)
    free = ~problem["pinned"]
    result = {"preset": args.preset, "within_m": WITHIN, "fps": FPS}
    result["problem"] = {
        "nodes": int(len(problem["nodes"])), "tets": int(len(problem["tets"])), "pinned": int(problem["pinned"].sum()),
        "supports": int(len(problem["support_node"])),
        "load": (f"the {args.preset} preset's muscle-spring forces at facewarp's converged shape, constant from t = 0 "
                 f"({np.linalg.norm(problem['force'], axis=1).sum():.1f} N summed over "
                 f"{int((np.linalg.norm(problem['force'], axis=1) > 0).sum())} nodes, largest "
                 f"{np.linalg.norm(problem['force'], axis=1).max():.2f} N)"),
        "young_range_pa": [float(problem["young"].min()), float(problem["young"].max())],
        "poisson_range": [float(problem["poisson"].min()), float(problem["poisson"].max())],
        "young_mean_pa": float(problem["young_mean"]), "poisson_mean": float(problem["poisson_mean"]),
        "damping_rate_per_s": float(problem["damping_rate"]), "stiffness_damping_s": float(problem["stiffness_damping"]),
        "support_spring_length_newton_m": SUPPORT_LENGTH}
    solvers = {}
    shapes = {}  # converged static shapes, for the pairwise comparison

    # ours: the converged shape (tight), then the default solver
    tight = run_ours(problem, 8, tolerance=1e-7, max_iterations=500)
    ours_shape = tight["positions"][-1].astype(np.float64)
    r = run_ours(problem, 30)
    r["settings"] = {"method": r.pop("method"), "steps_per_frame": 1, "tolerance_m": 3e-5}
    r["iterations_per_frame_first_10"] = r.pop("iterations")[:10]
    ours = summarize(r, None, None, free, converged=ours_shape)  # time to converge: to the tight solve
    shapes["facewarp implicit (ours)"] = ours_shape
    ours["static_shape_vs_tight_mm"] = _shape_diff(r["positions"][-1].astype(np.float64), ours_shape, free)
    ours["static_shape_vs_preset_mm"] = _shape_diff(ours_shape, problem["preset_shape"], free)
    solvers["facewarp implicit (ours)"] = ours
    print("ours", ours, flush=True)
    long = run_ours(problem, 8, supports="long", tolerance=1e-7, max_iterations=500)
    ours_long = long["positions"][-1].astype(np.float64)
    shapes["facewarp implicit, Newton's long support springs"] = ours_long
    result["support_approximation"] = {
        "what": "facewarp's static shape with Newton's long support springs against the exact axis springs",
        **_shape_diff(ours_long, ours_shape, free)}
    solvers["facewarp implicit, with muscles (reference, not the peer problem)"] = run_ours_muscles(fr, args.preset, 30)
    save("peers_cpu", {**result, "solvers": solvers})

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name, solver, load, relaxation, substeps, iterations, frames in NEWTON_RUNS:
            if solver in args.skip:
                continue
            r = run_newton(problem, solver, frames, args.peers_python, tmp, load, relaxation, substeps, iterations)
            shapes[name] = r.get("positions", [None])[-1]
            # Newton's supports are the long springs: compare with facewarp on the same springs
            solvers[name] = summarize(r, ours, ours_long, free)
            print(name, {k: v for k, v in solvers[name].items() if k != "distance_mm_per_frame_first_10"}, flush=True)
            save("peers_cpu", {**result, "solvers": solvers})
    if "mujoco" not in args.skip:
        for spf in (1, 10):
            name = f"mujoco flex ({spf} step{'s' if spf > 1 else ''} / frame)"
            r = run_mujoco(problem, MUJOCO_FRAMES[spf], spf)
            shapes[name] = r.get("positions", [None])[-1]
            solvers[name] = summarize(r, ours, ours_shape, free)
            print(name, solvers[name], flush=True)
            save("peers_cpu", {**result, "solvers": solvers})
    result["solvers"] = solvers
    result["static_shapes_pairwise_mm"] = pairwise(shapes, solvers, free)
    result["notes"] = NOTES
    result["total_seconds"] = round(time.perf_counter() - t_all, 1)
    path = save("peers_cpu", result)
    print("wrote", path)
    (RESULTS / "peers_cpu.md").write_text(markdown(result, _common.load(path)))


NOTES = [
    "Per-frame time is the median wall time of one 1/30 s frame after a warm-up frame (kernel compilation) on the "
    "2-core CPU box, with other jobs on the machine; Warp's CPU kernels run on one thread.",
    "Time to 0.2 mm: the first frame from which every node stays within 0.2 mm of the solver's own converged shape "
    "(facewarp: a tight solve, tolerance 1e-7 m; peers: the last frame of their run, whose change is reported). "
    "Wall seconds = that many frames of that solver.",
    "Newton gets the load as long pre-stretched springs (rest length 0, anchor 10 m away along the force, "
    "stiffness |f| / 10 m: the dead load within 0.2 %), which it integrates implicitly; the same load as "
    "State.particle_f enters only VBD's / XPBD's inertial prediction x + h v + h^2 f / m, which puts the light "
    "nodes (2e-6 kg and up) metres away in the first substep: that run is reported too.",
    "Newton's sliding supports are springs of rest length 1 m along the rest normal; its static shape is compared "
    "with facewarp on those same springs (support_approximation gives the difference to the exact axis springs).",
    "Newton's SolverXPBD solves the tets in parallel (Jacobi) and at its default soft_body_relaxation 0.9 "
    "diverges on this mesh even with no load (float32 round-off at rest grows); 0.1 is the largest of "
    "0.9 / 0.5 / 0.2 / 0.1 that stays at rest, and with it the iterations stop far from the elastic "
    "equilibrium (the static shape is much softer and depends on the relaxation: 0.05 gave 135 mm).",
    "Newton's particles get a 1e-5 m radius and no particle-particle contact (model.particle_max_radius 0): "
    "with the default 0.1 m radius every node of the face 'touches' every other in XPBD's contact pass.",
    "MuJoCo 4 flex: 3D elasticity is StVK, one young / poisson per flex (the volume-weighted mean Lame parameters), "
    "integrated implicitly only by the 'discrete' integrator; its M + h^2 K solve warns 'under-converged' on this "
    "thin mesh every step (warning_counts), and its settled shapes at 1 and 10 steps per frame differ "
    "(static_shapes_pairwise_mm): not a converged equilibrium at either step.",
    "facewarp's median frame is the steady state of a constant load (one L-BFGS iteration); the mean of the "
    "first 10 frames includes the cold start (a fresh factorisation and 15-20 iterations in frame 1: "
    "iterations_per_frame_first_10).",
]


if __name__ == "__main__":
    raise SystemExit(main())
