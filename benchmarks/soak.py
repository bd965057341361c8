"""Soak: random legal control streams on several heads, every frame checked.

    python -m benchmarks soak [--heads 10] [--seconds 60] [--device cpu] [--seed S] [--name soak_cpu]
                              [--budget-s B] [--skip K]

Each head plays ``--seconds`` of a stream that a tracker or a controller could send, switching
every frame: about 40 % of the muscles on with activations drawn in [0, 1], the jaw opening drawn
anywhere in 0-40 deg and its side angle in +-5 deg (full speed: a new angle every frame, within
the hinge's limits), and the head spinning about a random axis at up to 5 rev/s (its speed and
axis drawn anew every 10 frames). Heads: the default head (level 0) and, where the ICT-FaceKit
data is there (``$FACEWARP_SHARED/data/ict-facekit``), its identities adapted and built with the
public CLI (``facewarp adapt`` of the identity mesh with its FDPs, ``facewarp build``); without
it, synthetic scans (``facewarp.synthetic_scan``) of new seeds adapted likewise.

Every frame is checked: a :class:`facewarp.SimulationError` (a NaN or an inverted tet that
sub-stepping could not avoid) is a failure, and the frame's node positions are checked for NaN
and for inverted tets on the host; the smallest tet volume ratio V / V0, the frames the simulator
sub-stepped (``FaceSimulator.stats``) and frames/s (wall and process CPU time: the machine may be
shared) are recorded. A new seed every run unless ``--seed`` (recorded). ``--budget-s`` stops
starting new heads after that many seconds and says so in the result (``complete: false``).
Writes benchmarks/results/<name>.json (default ``soak_<device>``; the one result schema of
``benchmarks/_common.py``, the figures below), rewritten every 150 frames (the head in progress
marked ``in_progress``).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import secrets
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks._common import save, shared_dir

ACTIVE_FRACTION = 0.4
"""Share of the muscles switched on in a frame."""
JAW_OPEN_MAX_DEG = 40.0
JAW_SIDE_MAX_DEG = 5.0
SPIN_MAX_REV_S = 5.0
SPIN_HOLD_FRAMES = 10
"""Frames between new head-spin speeds and axes."""


def _cli(*argv) -> None:
    from facewarp.cli import main as facewarp_cli

    with contextlib.redirect_stdout(io.StringIO()):
        code = facewarp_cli([str(a) for a in argv])
    if code != 0:
        raise RuntimeError(f"facewarp {' '.join(map(str, argv))} failed with exit code {code}")


def _ict_head(ict: Path, identity: int, root: Path):
    """The default template adapted to ICT-FaceKit identity ``identity`` and built (public CLI)."""
    import facewarp as fw

    mesh = fw.load_mesh(ict / f"identity{identity:03d}.obj", units="cm")
    V = mesh.vertices
    case = root / f"identity{identity:03d}"
    case.mkdir(parents=True, exist_ok=True)
    lm = {fid: (100.0 * V[i]).tolist() for fid, i in fw.ICT_FDP_VERTICES.items()}  # cm, as the mesh file
    (case / "landmarks.json").write_text(json.dumps(lm))
    _cli("adapt", ict / f"identity{identity:03d}.obj", "--landmarks", case / "landmarks.json", "--units", "cm",
         "--out", case / "adapt")
    _cli("build", case / "adapt", "--out", case / "build")
    return fw.load_face_rig(case / "build")


def _synthetic_head(seed: int, root: Path):
    """A synthetic scan of seed ``seed`` adapted and built (public API and CLI)."""
    import facewarp as fw

    scan = fw.synthetic_scan(seed, level=0)
    case = root / f"synthetic{seed}"
    case.mkdir(parents=True, exist_ok=True)
    fw.save_obj(case / "scan.obj", scan.vertices, scan.faces)
    (case / "landmarks.json").write_text(json.dumps({k: np.asarray(v).tolist() for k, v in scan.landmarks.items()}))
    _cli("adapt", case / "scan.obj", "--landmarks", case / "landmarks.json", "--units", scan.units,
         "--out", case / "adapt")
    _cli("build", case / "adapt", "--out", case / "build")
    return fw.load_face_rig(case / "build")


def heads(count: int, seed: int, root: Path):
    """Yield ``(name, face rig builder)`` for ``count`` heads: the default head first, then ICT
    identities (or synthetic scans without the ICT data)."""
    import facewarp as fw

    yield "default_level0", lambda: fw.build_face(fw.default_template(0))
    ict = shared_dir() / "data" / "ict-facekit"
    ids = sorted(int(p.stem[8:]) for p in ict.glob("identity[0-9][0-9][0-9].obj")) if ict.is_dir() else []
    for k in range(count - 1):
        if ids:
            i = ids[k % len(ids)]
            yield f"ict_identity{i:03d}", lambda i=i: _ict_head(ict, i, root)
        else:
            yield f"synthetic{seed + k}", lambda s=seed + k: _synthetic_head(s, root)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _volume_ratios(rig, X: np.ndarray, v0: np.ndarray) -> np.ndarray:
    T = rig.tets
    a = X[T[:, 0]]
    return np.einsum("ij,ij->i", np.cross(X[T[:, 1]] - a, X[T[:, 2]] - a), X[T[:, 3]] - a) / 6.0 / v0


def soak_head(rig, seconds: float, rng: np.random.Generator, *, device: str = "cpu", progress=None) -> dict:
    """Play one random control stream on ``rig`` (kinematic jaw); the head's row of the result.
    ``progress(row)`` is called every 150 frames with the row so far."""
    import facewarp as fw

    sim = fw.FaceSimulator(rig, device=device)
    M = len(sim.muscle_names)
    T = rig.tets
    a0 = rig.nodes[T[:, 0]]
    v0 = np.einsum("ij,ij->i", np.cross(rig.nodes[T[:, 1]] - a0, rig.nodes[T[:, 2]] - a0),
                   rig.nodes[T[:, 3]] - a0) / 6.0
    frames = int(round(seconds * sim.fps))
    axis, omega = np.array([0.0, 1.0, 0.0]), 0.0
    row = {"frames": 0, "failures": 0, "failure": None, "nan_frames": 0, "inverted_frames": 0,
           "min_volume_ratio": 1.0}
    wall0, cpu0 = time.perf_counter(), time.process_time()
    step_wall = step_cpu = 0.0
    for k in range(frames):
        a = np.where(rng.random(M) < ACTIVE_FRACTION, rng.random(M), 0.0)
        sim.set_activations(a)
        u = math.radians(rng.uniform(0.0, JAW_OPEN_MAX_DEG))
        v = math.radians(rng.uniform(-JAW_SIDE_MAX_DEG, JAW_SIDE_MAX_DEG))
        if k % SPIN_HOLD_FRAMES == 0:
            axis = rng.normal(size=3)
            omega = 2 * math.pi * rng.uniform(0.0, SPIN_MAX_REV_S)
        sim.set_head_pose(_rotation(axis, omega / sim.fps) @ sim.head_pose[0], np.zeros(3))
        w0, c0 = time.perf_counter(), time.process_time()
        try:
            sim.set_jaw(u, v)
            sim.step()
        except fw.SimulationError as e:
            row["failures"] += 1
            row["failure"] = f"frame {k}: {e}"
            break
        step_wall += time.perf_counter() - w0
        step_cpu += time.process_time() - c0
        X = sim.positions()
        row["frames"] += 1
        if not np.isfinite(X).all():
            row["nan_frames"] += 1
            row["failures"] += 1
            row["failure"] = f"frame {k}: NaN positions"
            break
        r = _volume_ratios(rig, X, v0)
        row["min_volume_ratio"] = min(row["min_volume_ratio"], float(r.min()))
        if (r <= 0).any():
            row["inverted_frames"] += 1
        if progress is not None and row["frames"] % 150 == 0:
            progress(_finish_row(row, sim, step_wall, step_cpu, wall0, cpu0))
    return _finish_row(row, sim, step_wall, step_cpu, wall0, cpu0)


def _finish_row(row: dict, sim, step_wall: float, step_cpu: float, wall0: float, cpu0: float) -> dict:
    row = dict(row)
    st = sim.stats.as_dict()
    rig = sim.fr
    row.update({
        "seconds_simulated": row["frames"] / sim.fps, "nodes": int(len(rig.nodes)), "tets": int(len(rig.tets)),
        "substepped_frames": st["substepped_frames"], "retries": st["retries"],
        "max_substep_factor": st["max_substep_factor"], "frames_below_floor": st["frames_below_floor"],
        "unconverged_frames": st["unconverged_frames"], "volume_floor": st["volume_floor"],
        "frames_per_second_wall": row["frames"] / max(step_wall, 1e-9),
        "frames_per_second_cpu": row["frames"] / max(step_cpu, 1e-9),
        "wall_s": time.perf_counter() - wall0, "cpu_s": time.process_time() - cpu0,
        "events": st["events"][:5],
    })
    return row


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--heads", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seed", type=int, help="default: a new seed every run (recorded)")
    ap.add_argument("--name", help="result name (default soak_<device>)")
    ap.add_argument("--budget-s", type=float, help="start no new head after this many seconds")
    ap.add_argument("--skip", type=int, default=0,
                    help="leave out the first SKIP heads of the list (e.g. 1: ICT heads only)")
    args = ap.parse_args(argv)
    if args.heads < 1 or not (args.seconds > 0):
        ap.error("--heads must be >= 1 and --seconds > 0")
    seed = args.seed if args.seed is not None else secrets.randbelow(2**31)
    name = args.name or f"soak_{args.device.split(':')[0]}"
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    rows = []
    result = {}
    root = Path(tempfile.mkdtemp(prefix="facewarp_soak_"))
    for i, (head_name, make) in enumerate(heads(args.heads + args.skip, seed, root)):
        if i < args.skip:
            continue
        if args.budget_s is not None and time.perf_counter() - t0 > args.budget_s:
            break
        tb = time.perf_counter()
        try:
            rig = make()
        except Exception as e:  # a head that cannot be built is recorded, not a soak failure
            rows.append({"head": head_name, "build_error": f"{type(e).__name__}: {e}"})
            continue
        build_s = time.perf_counter() - tb

        def partial(r, head_name=head_name, build_s=build_s):
            save(name, _summary(args, seed, rows + [{"head": head_name, "build_s": build_s, "in_progress": True, **r}],
                                time.perf_counter() - t0), device=args.device, benchmark="soak", machine_extra=_extra())

        row = {"head": head_name, "build_s": build_s,
               **soak_head(rig, args.seconds, rng, device=args.device, progress=partial)}
        rows.append(row)
        print(json.dumps({k: row[k] for k in ("head", "frames", "failures", "min_volume_ratio", "substepped_frames",
                                              "frames_per_second_cpu")}), flush=True)
        result = _summary(args, seed, rows, time.perf_counter() - t0)
        save(name, result, device=args.device, benchmark="soak", machine_extra=_extra())
    result = _summary(args, seed, rows, time.perf_counter() - t0)
    print("wrote", save(name, result, device=args.device, benchmark="soak", machine_extra=_extra()))
    return result


def _extra() -> dict:
    return {"omp_num_threads": os.environ.get("OMP_NUM_THREADS")}


def _summary(args, seed: int, rows: list, wall: float) -> dict:
    run = [r for r in rows if "frames" in r]
    frames = sum(r["frames"] for r in run)
    done = (len(run) == args.heads and not any(r.get("in_progress") for r in run)
            and all(r["seconds_simulated"] >= args.seconds - 1e-9 or r["failures"] for r in run))
    return {
        "seed": seed,
        "requested": {"heads": args.heads, "seconds": args.seconds, "jaw": "kinematic",
                      "active_fraction": ACTIVE_FRACTION, "jaw_open_max_deg": JAW_OPEN_MAX_DEG,
                      "jaw_side_max_deg": JAW_SIDE_MAX_DEG, "spin_max_rev_s": SPIN_MAX_REV_S},
        "complete": bool(done),
        "heads_run": len(run),
        "frames": frames,
        "failures": sum(r["failures"] for r in run),
        "nan_frames": sum(r["nan_frames"] for r in run),
        "inverted_frames": sum(r["inverted_frames"] for r in run),
        "min_volume_ratio": min((r["min_volume_ratio"] for r in run), default=None),
        "substepped_frames": sum(r["substepped_frames"] for r in run),
        "frames_below_floor": sum(r["frames_below_floor"] for r in run),
        "frames_per_second_cpu": frames / max(sum(r["frames"] / r["frames_per_second_cpu"] for r in run if r["frames"]),
                                              1e-9),
        "frames_per_second_wall": frames / max(sum(r["frames"] / r["frames_per_second_wall"] for r in run
                                                   if r["frames"]), 1e-9),
        "wall_s": wall,
        "heads": rows,
    }


if __name__ == "__main__":
    main()
