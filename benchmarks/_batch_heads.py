"""Shared by the batch benchmarks (batch, batch_profile): the heads of a batch, its planned controls and timed
frames, and Newton VBD's replicate."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from benchmarks._common import case_face, head_tag


def scaled_head(level: int = 0, scale=(1.06, 0.95, 1.03)):
    """The default head stretched anisotropically (another rest shape, the same topology): a stand-in identity."""
    import facewarp as fw

    t = fw.default_template(level)
    s = np.asarray(scale, np.float64)
    parts = {k: (V * s, F) for k, (V, F) in t.parts.items()}
    return fw.build_face(replace(t, vertices=t.vertices * s, condyles=t.condyles * s, parts=parts))


def make_rigs(specs: list[str], level: int) -> tuple[list, list[str], list[str]]:
    """The face rigs of the head specs (``default``, ``identityNNN``, ``scaled``, a build folder)."""
    rigs, names, notes = [], [], []
    for spec in specs:
        try:
            fr = scaled_head(level) if spec == "scaled" else case_face(spec, level)
            names.append(spec if spec in ("scaled", "default") else head_tag(spec))  # a build folder: its head's name
        except Exception as e:  # no ICT data, or the adaptation failed here: a stand-in identity
            notes.append(f"{spec}: not available ({type(e).__name__}: {e}); the scaled default head instead")
            fr, spec = scaled_head(level), "scaled"
            names.append(spec)
        rigs.append(fr)
    return rigs, names, notes


def newton_replicated(problem: dict, n: int, device: str, frames: int, substeps: int = 10, iterations: int = 10):
    """Newton's SolverVBD on the peer problem's tets replicated ``n`` times: seconds per frame, or why not."""
    try:
        import newton
        import warp as wp
    except Exception as e:
        return {"skipped": f"newton not importable here ({type(e).__name__}: {e}); pip install newton to compare"}
    try:
        from benchmarks._peers_newton import PARTICLE_RADIUS

        nodes, tets = problem["nodes"], problem["tets"]
        one = newton.ModelBuilder(gravity=(0.0, 0.0, 0.0))
        for i in range(len(nodes)):
            one.add_particle(wp.vec3(*nodes[i]), wp.vec3(0.0), float(problem["mass"][i]), radius=PARTICLE_RADIUS)
        for t, mu, lam, kd in zip(tets, problem["k_mu"], problem["k_lambda"], problem["k_damp"]):
            one.add_tetrahedron(int(t[0]), int(t[1]), int(t[2]), int(t[3]), float(mu), float(lam), float(kd))
        one.color()  # one head's colouring, carried by replicate to every copy (the copies share no particle);
        b = newton.ModelBuilder(gravity=(0.0, 0.0, 0.0))  # colouring the replicated graph took ~60 s at N = 100
        b.replicate(one, n)
        with wp.ScopedDevice(device):
            model = b.finalize(device=device)
            model.particle_grid = None
            model.particle_max_radius = 0.0
            s = newton.solvers.SolverVBD(model, iterations=iterations, particle_enable_self_contact=False,
                                         particle_enable_tile_solve=False)
            s0, s1 = model.state(), model.state()
            force = np.tile(np.asarray(problem["force"], np.float32), (n, 1))
            f = wp.array(force, dtype=wp.vec3, device=device)
            dt = 1.0 / 30.0 / substeps

            def frame(s0, s1):
                for _ in range(substeps):
                    s0.clear_forces()
                    wp.copy(s0.particle_f, f)
                    s.step(s0, s1, None, None, dt)
                    s0, s1 = s1, s0
                return s0, s1

            s0, s1 = frame(s0, s1)  # warm-up
            wp.synchronize()
            t0 = time.perf_counter()
            for _ in range(frames):
                s0, s1 = frame(s0, s1)
            wp.synchronize()
            sec = (time.perf_counter() - t0) / frames
        return {"seconds_per_frame": sec, "head_frames_per_second": n / sec, "substeps": substeps,
                "iterations": iterations, "newton_version": newton.__version__,
                "note": "tissue only (the peer problem's dead load in place of the muscles, no jaw, no contact)"}
    except Exception as e:
        return {"error": f"{type(e).__name__}: {e}"}

def plan(batch, timelines, frames: int) -> list:
    """The controls of frames 0 .. frames: per frame the activations (N, M) float32 and jaw angles (N, 2)
    [rad] of every head (the timelines sampled once, before any timing). ``batch``: a FaceBatch of either
    backend (its heads' activation vectors)."""
    fps = batch.fps
    vec = ((lambda i, e: batch.heads[i].activation_vector(e)) if batch.backend == "heads"
           else batch.activation_vector)
    out = [None]
    for k in range(1, frames + 1):
        es = [tl.sample(k / fps) for tl in timelines]
        A = np.stack([vec(i, e) for i, e in enumerate(es)])
        J = np.array([[e.jaw_u, e.jaw_v] for e in es])
        out.append((A, J))
    return out


def drive(batch_or_heads, controls: list, frames: int, start: int, *, naive: bool = False) -> float:
    """Frames ``start .. start + frames - 1`` of the planned controls (:func:`plan`); returns the wall
    seconds (synchronised)."""
    import warp as wp

    heads = batch_or_heads if naive else None  # the model backend has no per-head simulators
    t0 = time.perf_counter()
    for k in range(start, start + frames):
        A, J = controls[k]
        if naive:
            for i, h in enumerate(heads):
                h.set_activations(A[i])
                h.set_jaw(J[i, 0], J[i, 1])
                h.step()
        else:
            batch_or_heads.set_activations(A)
            batch_or_heads.set_jaw(J)
            batch_or_heads.step()
    wp.synchronize()
    return time.perf_counter() - t0
