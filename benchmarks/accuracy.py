"""The accuracy contract (issue 37): every solver mode and stream against its tightly converged reference, per frame.

    python -m benchmarks accuracy [--quick] [--streams presets sequence switching drive]
                                  [--modes default interactive:3 newton] [--seconds S] [--seed 1]
                                  [--name accuracy_cpu]

The contract (docs/concepts/physics.md): a frame is right when every FDP is within 0.5 mm, and the
skin's RMS within 0.2 mm, of the same stream simulated with the solver converged tightly (Newton
to 1e-7 m, the muscles' fibre cosine to 1e-4) from rest under the same controls. Streams (default
head, level 0, CPU, 30 frames/s, from rest):

* ``presets``: each of smile, laugh, surprise, angry, sad (attack 0.3 s, hold 0.5 s, release 0.3 s
  from 0.1 s, then 0.1 s of rest; ``--quick``: smile and laugh).
* ``sequence``: the Fig. 6.16 sequence (``facewarp.thesis_sequence()``; ``--seconds`` of it).
* ``switching``: the soak's stream, new random activations, jaw and head spin every frame
  (``benchmarks/_streams.py``, the stream of ``benchmarks/switching.py``).
* ``drive``: a smooth random performance like the one ``benchmarks/drive.py`` simulates and drives
  (activations and jaw through random knots every 0.5 s; ``benchmarks/_streams.py``).

Modes: ``default`` (``FaceSimulator()``: L-BFGS on a reused factorisation to its convergence step),
``interactive:K`` (``iterations=K``: K L-BFGS iterations a frame whatever the residual, a mode
that does not claim the contract) and ``newton`` (``method="newton"`` at the default tolerance);
``tol:T`` is the default mode with ``tolerance=T`` [m] (to measure error against tolerance).

Per stream and mode: per frame the largest FDP distance [mm] and the skin's RMS distance [mm] to
the reference (``surface()``, the skin in the world frame), their max and 99th percentile over
frames, the frames that keep the contract, frames/s (process CPU time and wall time: the box may
be shared), L-BFGS / Newton iterations, factorisations and line-search trials a frame, and the
solver's own timings. Writes benchmarks/results/<name>.json (default ``accuracy_cpu``;
``--quick``: ``accuracy_cpu_quick``).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks._common import save

THREADS = 1

FDP_MAX_M = 5.0e-4
"""The contract: every FDP within this distance [m] of the reference frame."""
SKIN_RMS_M = 2.0e-4
"""The contract: the skin's RMS distance [m] to the reference frame at most this."""
REFERENCE = {"method": "newton", "tolerance": 1e-7, "solver_options": {"max_iterations": 500, "spring_tolerance": 1e-4}}
"""The reference solver's :class:`facewarp.FaceSimulator` keywords: Newton to 1e-7 m."""
PRESETS = ("smile", "laugh", "surprise", "angry", "sad")
MODES = ("default", "interactive:3", "newton")


def mode_options(spec: str) -> dict:
    """The :class:`facewarp.FaceSimulator` keywords of a mode (module doc); ValueError if unknown."""
    name, _, arg = spec.partition(":")
    if name == "default" and not arg:
        return {}
    if name == "reference" and not arg:
        return {**REFERENCE}
    if name == "interactive" and arg.isdigit() and int(arg) >= 1:
        return {"iterations": int(arg)}
    if name == "newton" and not arg:
        return {"method": "newton"}
    if name == "tol" and arg:
        return {"tolerance": float(arg)}
    raise ValueError(spec)


# ---------------------------------------------------------------------------------------- streams
def timeline_controls(sim, timeline, seconds: float):
    """Per-frame controls of ``seconds`` of a Timeline at ``sim.fps`` (frame 0, the rest, left out):
    ``(A (F, M) activations, J (F, 2) jaw [rad], None)``, as :func:`facewarp.play` sets them."""
    tl = timeline.for_head(sim.fr)
    nf = round(seconds * sim.fps)
    A, J = [], []
    for k in range(1, nf + 1):
        e = tl.sample(k / sim.fps)
        A.append(sim.activation_vector(e))
        J.append((e.jaw_u, e.jaw_v))
    return np.asarray(A, np.float32), np.asarray(J, np.float64), None


def switching_controls(sim, frames: int, seed: int):
    """``frames`` frames of the soak's every-frame switching stream (with the head's spin)."""
    from benchmarks._streams import control_stream

    stream = control_stream(np.random.default_rng(seed), len(sim.muscle_names), sim.fps)
    A, J, R = [], [], []
    for _ in range(frames):
        a, u, v, dR = next(stream)
        A.append(a)
        J.append((u, v))
        R.append(dR)
    return np.asarray(A, np.float32), np.asarray(J), np.asarray(R)


def drive_controls(sim, frames: int, seed: int):
    """``frames`` frames of a smooth random performance like the one ``benchmarks/drive.py`` drives."""
    from benchmarks._streams import smooth_performance

    A, J = smooth_performance(np.random.default_rng(seed), frames + 1, sim.fps, len(sim.muscle_names))
    return A[1:], J[1:], None


def stream_controls(sim, stream: str, *, quick: bool, seconds: float | None, seed: int) -> dict:
    """The named stream as ``{label: controls}`` (one entry per preset for ``presets``)."""
    import facewarp as fw

    if stream == "presets":
        names = PRESETS[:2] if quick else PRESETS
        length = seconds or (0.1 + 0.3 + 0.5 + 0.3 + 0.1)
        return {f"preset_{n}": timeline_controls(sim, fw.timeline_for(n, attack=0.3, hold=0.5, release=0.3,
                                                                      start=0.1), length) for n in names}
    if stream == "sequence":
        return {"sequence": timeline_controls(sim, fw.thesis_sequence(), seconds or (1.0 if quick else 8.0))}
    frames = round((seconds or (0.3 if quick else 1.0)) * sim.fps)
    if stream == "switching":
        return {"switching": switching_controls(sim, frames, seed)}
    if stream == "drive":
        return {"drive": drive_controls(sim, round((seconds or (0.7 if quick else 3.0)) * sim.fps), seed)}
    raise ValueError(stream)


# ---------------------------------------------------------------------------------------- playing
def play(sim, controls) -> dict:
    """Play ``controls`` (A, J, R) on ``sim`` from rest; per frame FDPs (F, 84, 3) and skin (F, v, 3)
    [m], and the solver's per-frame counts and times."""
    A, J, R = controls
    sim.reset()
    solver = sim.solver
    fdp, skin = [], []
    rows = {"cpu_s": [], "wall_s": [], "iterations": [], "factorizations": [], "line_search_trials": []}
    timings0 = dict(solver.timings)
    for k in range(len(A)):
        sim.set_activations(A[k])
        if R is not None:
            sim.set_head_pose(R[k] @ sim.head_pose[0], np.zeros(3))
        sim.set_jaw(*J[k])
        f0 = solver.factorizations
        l0 = getattr(solver, "line_search_trials", 0)
        c0, w0 = time.process_time(), time.perf_counter()
        sim.step()
        rows["cpu_s"].append(time.process_time() - c0)
        rows["wall_s"].append(time.perf_counter() - w0)
        rows["iterations"].append(int(solver.last_iterations))
        rows["factorizations"].append(int(solver.factorizations - f0))
        rows["line_search_trials"].append(int(getattr(solver, "line_search_trials", 0) - l0))
        fdp.append(sim.fdp_points())
        skin.append(sim.surface())
    timings = {k: float(v - timings0.get(k, 0.0)) for k, v in solver.timings.items()}
    return {"fdp": np.asarray(fdp), "skin": np.asarray(skin), "rows": rows, "timings_s": timings,
            "retries": int(sim.stats.as_dict()["retries"])}


def errors(run: dict, ref: dict) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: the largest FDP distance [m] and the skin's RMS distance [m] of ``run`` to ``ref``."""
    fdp = np.linalg.norm(run["fdp"] - ref["fdp"], axis=2).max(axis=1)
    skin = np.sqrt((np.linalg.norm(run["skin"] - ref["skin"], axis=2) ** 2).mean(axis=1))
    return fdp, skin


def figures(run: dict, ref: dict) -> dict:
    """The contract's figures of ``run`` against ``ref`` and its cost (module doc)."""
    fdp, skin = errors(run, ref)
    rows = run["rows"]
    frames = len(fdp)
    keeps = (fdp <= FDP_MAX_M) & (skin <= SKIN_RMS_M)
    return {
        "frames": frames,
        "fdp_max_mm": round(float(fdp.max()) * 1e3, 4),
        "fdp_p99_mm": round(float(np.percentile(fdp, 99)) * 1e3, 4),
        "skin_rms_max_mm": round(float(skin.max()) * 1e3, 4),
        "skin_rms_p99_mm": round(float(np.percentile(skin, 99)) * 1e3, 4),
        "frames_keeping_contract": int(keeps.sum()),
        "keeps_contract": bool(keeps.all()),
        "frames_per_second_cpu": round(frames / max(sum(rows["cpu_s"]), 1e-9), 2),
        "frames_per_second_wall": round(frames / max(sum(rows["wall_s"]), 1e-9), 2),
        "per_frame_mean": {k: round(float(np.mean(v)), 4) for k, v in rows.items()},
        "per_frame_max": {k: round(float(np.max(v)), 4) for k, v in rows.items()},
        "timings_s": {k: round(v, 3) for k, v in run["timings_s"].items()},
        "retries": run["retries"],
        "fdp_per_frame_mm": [round(float(x) * 1e3, 4) for x in fdp],
        "skin_rms_per_frame_mm": [round(float(x) * 1e3, 4) for x in skin],
    }


def simulator(rig, spec: str):
    import facewarp as fw

    return fw.FaceSimulator(rig, device="cpu", **mode_options(spec))


def main(argv=None) -> dict:
    import facewarp as fw
    from facewarp.physics import factorization_backend

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", 
                    help="short streams (estimated 5 minutes of one core: the references run at about 1 frame/s)")
    ap.add_argument("--streams", nargs="+", default=["presets", "sequence", "switching", "drive"],
                    choices=["presets", "sequence", "switching", "drive"])
    ap.add_argument("--modes", nargs="+", default=list(MODES),
                    help="default, interactive:K, newton, tol:T (module doc)")
    ap.add_argument("--seconds", type=float, default=None, help="length of every stream [s] (default per stream)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--name", default=None)
    args = ap.parse_args(argv)
    for m in args.modes:
        try:
            mode_options(m)
        except ValueError:
            ap.error(f"--modes: unknown mode {m!r} (default, interactive:K, newton or tol:T)")
    if args.seconds is not None and not args.seconds > 0:
        ap.error("--seconds must be > 0")
    name = args.name or ("accuracy_cpu_quick" if args.quick else "accuracy_cpu")
    rig = fw.build_face(fw.default_template(0))
    sims = {m: simulator(rig, m) for m in ["reference", *args.modes]}
    result = {"head": "default_level0", "nodes": len(rig.nodes), "tets": len(rig.tets),
              "factorization_backend": factorization_backend(), "seed": args.seed,
              "contract": {"fdp_max_mm": FDP_MAX_M * 1e3, "skin_rms_max_mm": SKIN_RMS_M * 1e3,
                           "reference": {k: v for k, v in REFERENCE.items()}},
              "modes": {m: mode_options(m) for m in args.modes}, "streams": {}}
    t_start = time.perf_counter()
    for stream in args.streams:
        for label, controls in stream_controls(sims["reference"], stream, quick=args.quick, seconds=args.seconds,
                                               seed=args.seed).items():
            ref = play(sims["reference"], controls)
            entry = {"frames": len(controls[0]),
                     "reference": {k: v for k, v in figures(ref, ref).items()
                                   if k.startswith(("frames_per", "per_frame", "timings", "retries"))}}
            for m in args.modes:
                entry[m] = figures(play(sims[m], controls), ref)
                r = entry[m]
                print(f"{label:16s} {m:14s} fdp max {r['fdp_max_mm']:.3f} mm p99 {r['fdp_p99_mm']:.3f}  "
                      f"skin rms max {r['skin_rms_max_mm']:.3f} mm  keeps {r['keeps_contract']}  "
                      f"{r['frames_per_second_cpu']:.1f} frames/s (CPU)  it/frame {r['per_frame_mean']['iterations']:.1f}"
                      f"  fact/frame {r['per_frame_mean']['factorizations']:.2f}", flush=True)
            result["streams"][label] = entry
            save(name, result, device="cpu", benchmark="accuracy")  # a long run keeps what it measured
    result["seconds_total"] = round(time.perf_counter() - t_start, 1)
    summary = {}
    for m in args.modes:
        rows = [e[m] for e in result["streams"].values()]
        summary[m] = {"keeps_contract": all(r["keeps_contract"] for r in rows),
                      "fdp_max_mm": max(r["fdp_max_mm"] for r in rows),
                      "skin_rms_max_mm": max(r["skin_rms_max_mm"] for r in rows)}
    result["summary"] = summary
    print("summary", summary)
    print("wrote", save(name, result, device="cpu", benchmark="accuracy"))
    return result


if __name__ == "__main__":
    raise SystemExit(main())
