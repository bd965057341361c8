"""Soak: random legal control streams on several heads, every frame checked.

    python -m benchmarks soak [--heads 10] [--seconds 60] [--device cpu|cuda] [--jobs 1] [--seed S]
                              [--name soak_cpu] [--budget-s B] [--skip K] [--method newton-pcg]
                              [--synthetic] [--only 6,9]

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
shared) are recorded. A new seed every run unless ``--seed`` (recorded); head ``i``'s stream is
drawn from ``numpy.random.default_rng([seed, i])``, the same whatever ``--jobs``.

``--jobs N`` plays N heads at once, each in its own (spawned) process with one BLAS thread, on
``--device`` (``cuda``: every worker on that GPU). ``--budget-s`` starts no head after that many
seconds and stops the heads still playing then (rows ``stopped_by_budget``, ``complete: false``),
so a run fits a limited call: e.g. ``--heads 10 --seconds 60 --jobs 10 --budget-s 540``.
Writes benchmarks/results/<name>.json (default ``soak_<device>``; the one result schema of
``benchmarks/_common.py``, the figures below) as each head finishes and every 20 s of a head in
progress (its row marked ``in_progress``), so a killed run leaves its partial result.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import secrets
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks._common import save, shared_dir
from benchmarks._streams import ACTIVE_FRACTION, JAW_OPEN_MAX_DEG, JAW_SIDE_MAX_DEG, SPIN_MAX_REV_S, control_stream

PROGRESS_EVERY_S = 20.0
"""Wall seconds between partial results of a head in progress."""


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
    lm = {fid: (100.0 * V[i]).tolist() for fid, i in fw.heads.ICT_FDP_VERTICES.items()}  # cm, as the mesh file
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
    fw.geometry.save_obj(case / "scan.obj", scan.vertices, scan.faces, units=scan.units)  # the scan's files in its units
    fw.geometry.save_landmarks_json(case / "landmarks.json", scan.landmarks, units=scan.units)
    _cli("adapt", case / "scan.obj", "--landmarks", case / "landmarks.json", "--units", scan.units,
         "--out", case / "adapt")
    _cli("build", case / "adapt", "--out", case / "build")
    return fw.load_face_rig(case / "build")


def head_specs(count: int, seed: int, *, synthetic: bool = False) -> list[tuple[str, str, int]]:
    """``count`` heads as picklable ``(name, kind, parameter)``: the default head first, then ICT
    identities (or synthetic scans of seeds ``seed + k`` without the ICT data, or with ``synthetic``)."""
    specs = [("default_level0", "default", 0)]
    ict = shared_dir() / "data" / "ict-facekit"
    ids = (sorted(int(p.stem[8:]) for p in ict.glob("identity[0-9][0-9][0-9].obj"))
           if ict.is_dir() and not synthetic else [])
    for k in range(count - 1):
        if ids:
            i = ids[k % len(ids)]
            specs.append((f"ict_identity{i:03d}", "ict", i))
        else:
            specs.append((f"synthetic{seed + k}", "synthetic", seed + k))
    return specs


def make_head(spec: tuple[str, str, int], root: Path):
    """The face rig of one ``head_specs`` entry (built with the public API and CLI under ``root``)."""
    import facewarp as fw

    _, kind, param = spec
    if kind == "default":
        return fw.build_face(fw.default_template(0))
    if kind == "ict":
        return _ict_head(shared_dir() / "data" / "ict-facekit", param, root)
    return _synthetic_head(param, root)


def _volume_ratios(rig, X: np.ndarray, v0: np.ndarray) -> np.ndarray:
    T = rig.tets
    a = X[T[:, 0]]
    return np.einsum("ij,ij->i", np.cross(X[T[:, 1]] - a, X[T[:, 2]] - a), X[T[:, 3]] - a) / 6.0 / v0


def soak_head(rig, seconds: float, rng: np.random.Generator, *, device: str = "cpu", progress=None,
              deadline: float | None = None, progress_every_s: float = PROGRESS_EVERY_S,
              method: str | None = None) -> dict:
    """Play one random control stream on ``rig`` (kinematic jaw); the head's row of the result.
    ``method``: the implicit solver's method (None: the simulator's default for the device).
    ``progress(row)`` is called every ``progress_every_s`` seconds (wall) with the row so far;
    at ``deadline`` (a ``time.perf_counter()`` value) the stream stops early and the row says so
    (``stopped_by_budget``)."""
    import facewarp as fw

    sim = fw.FaceSimulator(rig, device=device, method=method)
    M = len(sim.muscle_names)
    T = rig.tets
    a0 = rig.nodes[T[:, 0]]
    v0 = np.einsum("ij,ij->i", np.cross(rig.nodes[T[:, 1]] - a0, rig.nodes[T[:, 2]] - a0),
                   rig.nodes[T[:, 3]] - a0) / 6.0
    frames = int(round(seconds * sim.fps))
    row = {"frames": 0, "failures": 0, "failure": None, "nan_frames": 0, "inverted_frames": 0,
           "min_volume_ratio": 1.0, "stopped_by_budget": False}
    wall0, cpu0 = time.perf_counter(), time.process_time()
    step_wall = step_cpu = 0.0
    last = wall0
    stream = control_stream(rng, M, sim.fps)
    for k in range(frames):
        if deadline is not None and time.perf_counter() > deadline:
            row["stopped_by_budget"] = True
            break
        a, u, v, dR = next(stream)
        sim.set_activations(a)
        sim.set_head_pose(dR @ sim.head_pose[0], np.zeros(3))
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
        if progress is not None and time.perf_counter() - last > progress_every_s:
            last = time.perf_counter()
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


def _run_head(index: int, spec, seconds: float, seed: int, device: str, root: str, deadline_s: float | None,
              queue=None, method: str | None = None) -> dict:
    """Build head ``spec`` and play its stream (in this process or a worker); its row of the result.
    The stream's generator is seeded by ``(seed, index)``, so a head's stream does not depend on
    ``--jobs`` or on the heads before it. Partial rows go to ``queue.put((index, row))`` when one
    is given. ``deadline_s``: seconds from now after which the stream stops (None: no limit)."""
    import facewarp as fw

    t0 = time.perf_counter()
    deadline = None if deadline_s is None else t0 + deadline_s
    name = spec[0]
    try:
        rig = make_head(spec, Path(root))
    except Exception as e:  # a head that cannot be built is recorded, not a soak failure
        return {"head": name, "build_error": f"{type(e).__name__}: {e}"}
    build_s = time.perf_counter() - t0

    def partial(r):
        if queue is not None:
            queue.put((index, {"head": name, "build_s": build_s, "in_progress": True, **r}))

    rng = np.random.default_rng([seed, index])
    try:
        row = soak_head(rig, seconds, rng, device=device, progress=partial, deadline=deadline, method=method)
    except fw.InputError as e:  # e.g. a device this machine does not have: not a soak failure either
        return {"head": name, "build_s": build_s, "run_error": f"{type(e).__name__}: {e}"}
    return {"head": name, "build_s": build_s, **row}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--heads", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N (every worker uses this device)")
    ap.add_argument("--jobs", type=int, default=1,
                    help="heads played at once in separate processes (default 1: in this process)")
    ap.add_argument("--seed", type=int, help="default: a new seed every run (recorded)")
    ap.add_argument("--name", help="result name (default soak_<device>)")
    ap.add_argument("--budget-s", type=float,
                    help="start no new head after this many seconds, and stop the heads still playing then "
                         "(their rows say stopped_by_budget; the result complete: false)")
    ap.add_argument("--skip", type=int, default=0,
                    help="leave out the first SKIP heads of the list (e.g. 1: ICT heads only)")
    ap.add_argument("--method", default=None,
                    help="the implicit solver's method (default: the device's; newton-pcg runs the device solver on "
                         "the CPU too, to replay a CUDA run's streams)")
    ap.add_argument("--synthetic", action="store_true",
                    help="synthetic heads even where the ICT-FaceKit data is (as on a machine without it)")
    ap.add_argument("--only", default=None,
                    help="comma list of head indices to play (their streams as in the whole list, seeded by index)")
    args = ap.parse_args(argv)
    if args.heads < 1 or not (args.seconds > 0) or args.jobs < 1 or args.skip < 0:
        ap.error("--heads and --jobs must be >= 1, --skip >= 0 and --seconds > 0")
    if args.budget_s is not None and not args.budget_s > 0:
        ap.error("--budget-s must be > 0")
    seed = args.seed if args.seed is not None else secrets.randbelow(2**31)
    name = args.name or f"soak_{args.device.split(':')[0]}"
    t0 = time.perf_counter()
    root = tempfile.mkdtemp(prefix="facewarp_soak_")
    specs = list(enumerate(head_specs(args.heads + args.skip, seed, synthetic=args.synthetic)[args.skip:]))
    if args.only:
        keep = {int(k) for k in args.only.split(",") if k.strip()}
        specs = [(i, sp) for i, sp in specs if i in keep]
    rows: dict[int, dict] = {}

    def write() -> Path:
        ordered = [rows[i] for i in sorted(rows)]
        return save(name, _summary(args, seed, ordered, time.perf_counter() - t0), device=args.device,
                    benchmark="soak", machine_extra=_extra(args))

    def finished(i: int, row: dict) -> None:
        rows[i] = row
        keys = ("head", "frames", "failures", "min_volume_ratio", "substepped_frames", "frames_per_second_cpu",
                "build_error", "run_error", "stopped_by_budget")
        print(json.dumps({k: row[k] for k in keys if k in row}), flush=True)
        write()

    def budget_left() -> float | None:
        return None if args.budget_s is None else args.budget_s - (time.perf_counter() - t0)

    if args.jobs == 1:
        class _Direct:  # partial rows straight into the result file
            def put(self, item):
                rows[item[0]] = item[1]
                write()

        for i, spec in specs:
            left = budget_left()
            if left is not None and left <= 0:
                break
            finished(i, _run_head(i, spec, args.seconds, seed, args.device, root, left, _Direct(), args.method))
    else:
        _parallel(args, specs, seed, root, rows, finished, write, budget_left)
    path = write()
    print("wrote", path)
    return json.loads(path.read_text())["figures"]


def _parallel(args, specs, seed: int, root: str, rows: dict, finished, write, budget_left) -> None:
    """Play ``specs`` in ``args.jobs`` spawned worker processes; partial rows arrive on a queue and
    are written as they come, each finished row as its head ends."""
    import multiprocessing as mp
    import queue as queue_mod
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    # workers inherit the environment: one BLAS thread each unless the caller chose otherwise
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    ctx = mp.get_context("spawn")  # Warp's and CUDA's state does not survive fork
    with ctx.Manager() as manager, ProcessPoolExecutor(max_workers=min(args.jobs, len(specs)),
                                                       mp_context=ctx) as pool:
        q = manager.Queue()
        t_submit = time.perf_counter()
        pending = {pool.submit(_run_head_budgeted, i, spec, args.seconds, seed, args.device, root,
                               budget_left(), t_submit, q, args.method): i for i, spec in specs}
        while pending:
            done, _ = wait(pending, timeout=2.0, return_when=FIRST_COMPLETED)
            dirty = False
            while True:
                try:
                    i, row = q.get_nowait()
                except queue_mod.Empty:
                    break
                if i not in rows or rows[i].get("in_progress"):
                    rows[i] = row
                    dirty = True
            for f in done:
                i = pending.pop(f)
                try:
                    row = f.result()
                except Exception as e:  # a worker that died (BrokenProcessPool) or raised
                    row = {"head": dict(specs)[i][0], "run_error": f"{type(e).__name__}: {e}"}
                finished(i, row)
                dirty = False
            if dirty:
                write()


def _run_head_budgeted(index, spec, seconds, seed, device, root, budget_s, t_submit, queue, method=None):
    """:func:`_run_head` in a worker, its budget shortened by the time it waited for a free worker
    (``time.perf_counter`` is CLOCK_MONOTONIC, one clock for every process on Linux)."""
    left = None if budget_s is None else budget_s - (time.perf_counter() - t_submit)
    if left is not None and left <= 0:
        return {"head": spec[0], "run_error": "not started: --budget-s was spent before a worker was free"}
    return _run_head(index, spec, seconds, seed, device, root, left, queue, method)


def _extra(args) -> dict:
    return {"omp_num_threads": os.environ.get("OMP_NUM_THREADS"), "jobs": args.jobs, "cpu_count": os.cpu_count()}


def _summary(args, seed: int, rows: list, wall: float) -> dict:
    run = [r for r in rows if "frames" in r]
    frames = sum(r["frames"] for r in run)
    wanted = len({int(k) for k in args.only.split(",") if k.strip()}) if args.only else args.heads
    done = (len(run) == wanted and not any(r.get("in_progress") or r.get("stopped_by_budget") for r in run)
            and all(r["seconds_simulated"] >= args.seconds - 1e-9 or r["failures"] for r in run))
    return {
        "seed": seed,
        "requested": {"heads": args.heads, "only": args.only, "synthetic": args.synthetic, "method": args.method,
                      "seconds": args.seconds, "jaw": "kinematic",
                      "active_fraction": ACTIVE_FRACTION, "jaw_open_max_deg": JAW_OPEN_MAX_DEG,
                      "jaw_side_max_deg": JAW_SIDE_MAX_DEG, "spin_max_rev_s": SPIN_MAX_REV_S},
        "complete": bool(done),
        "heads_run": len(run),
        "heads_in_progress": sum(bool(r.get("in_progress")) for r in run),
        "heads_not_run": [f"{r['head']}: {r.get('build_error') or r.get('run_error')}" for r in rows if "frames" not in r],
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
