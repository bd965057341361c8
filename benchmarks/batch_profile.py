"""Where a batched frame's time goes: FaceBatch (one Model of N faces) profiled kernel by kernel with Warp's timers.

    python -m benchmarks batch_profile [--device cuda] [--sizes 1,100,300] [--heads default,scaled]
                                       [--preset laugh] [--frames 10] [--profile-frames 3]
                                       [--newton 300,1000] [--name batch_profile_cuda]

For each N: a :class:`facewarp.FaceBatch` (``backend="model"``) of N level-0 heads cycling through
``--heads``, playing ``--preset`` (laugh: the jaw opens) from rest. First the frame as it runs in
production (one CUDA graph per frame, the adaptive Newton loop a conditional node): ms per frame,
head-frames per second and Newton iterations per frame (the solver's device counter). Then the
same frames from rest again launch by launch (graphs off) inside ``wp.timing_begin`` /
``wp.timing_end`` (CUDA events around every kernel launch and copy): per kernel its GPU
milliseconds per frame, launches per frame and share of the frame's kernel time, grouped by the
solver's jobs (CG, Hessian assembly, line search, energy and gradient, muscles, contact, checks).
The kernel time summed against the graph's wall time says how much of the frame is arithmetic and
memory traffic and how much is launch latency and the host. ``--newton``: Newton VBD (its
``replicate``, tissue only, benchmarks/batch.py's peer problem) at these N, for the peer table's
missing sizes.

The JSON (benchmarks/results/<name>.json) is rewritten after every N, so a run cut short keeps
what it measured.
"""

from __future__ import annotations

import argparse
import re
import time
import traceback

from benchmarks._batch_heads import drive, make_rigs, newton_replicated, plan
from benchmarks._common import save

THREADS = 1

# kernel name patterns -> the solver's job (first match wins; names are Warp's kernel keys)
GROUPS = (
    ("conjugate gradients", r"cg|bsr_mv|_dot|_sums|precond|jacobi"),
    ("Hessian assembly", r"hessian|_block|bsr"),
    ("line search", r"trial|line_search|backtrack"),
    ("energy and gradient", r"energ|grad|potential|_tet_|tissue|strain|barrier|inertia"),
    ("muscles", r"muscle|fibre|fiber|bezier|cosine|spring_pool|_pool"),
    ("contact", r"contact|mesh|lid|lip|teeth|query"),
    ("jaw and supports", r"jaw|support|carry|pivot"),
    ("Newton loop and checks", r"newton|converg|volume|ratio|largest|check|finite|_cond"),
    ("copies", r"memcpy|memset|copy|assign|fill"),
)


def job(name: str) -> str:
    low = name.lower()
    for label, pat in GROUPS:
        if re.search(pat, low):
            return label
    return "other"


def kernel_name(r) -> str:
    """A timing record's kernel key without Warp's prefixes and module hash."""
    name = str(r.name)
    for p in ("forward kernel ", "backward kernel ", "kernel "):
        if name.startswith(p):
            name = name[len(p):]
    return re.sub(r"_[0-9a-f]{7,}$", "", name)



def newton_iterations(batch) -> int | None:
    try:
        return int(batch.solver.total_iterations)
    except Exception:
        return None


def profile_size(n: int, rigs: list, args) -> dict:
    import facewarp as fw
    import warp as wp

    row: dict = {"n": n}
    t0 = time.perf_counter()
    batch = fw.FaceBatch([rigs[i % len(rigs)] for i in range(n)], device=args.device, backend="model")
    row["build_seconds"] = time.perf_counter() - t0
    row["method"] = getattr(batch.solver, "method", type(batch.solver).__name__)
    row["linear_iterations"] = getattr(batch.solver, "linear_iterations", None)
    row["nodes"], row["tets"] = int(batch.model.vertex_count), int(batch.model.tet_count)
    frames, pf = args.frames, args.profile_frames
    tl = fw.timeline_for(args.preset, attack=0.3, hold=10.0, release=0.3, start=0.0)
    controls = plan(batch, [tl.for_head(fr) for fr in batch.rigs], 2 + max(frames, pf))
    # production: graphs on
    drive(batch, controls, 2, 1)  # compile and capture
    i0 = newton_iterations(batch)
    sec = drive(batch, controls, frames, 3)
    i1 = newton_iterations(batch)
    row["ms_per_frame"] = sec / frames * 1e3
    row["head_frames_per_second"] = n * frames / sec
    row["graphs"] = bool(batch.stepper.use_graph)
    if i0 is not None and i1 is not None:
        row["newton_iterations_per_frame"] = (i1 - i0) / frames
    row["failed_heads"] = [s["head"] for s in batch.status if not s["ok"]]
    print(f"N={n}: {row['ms_per_frame']:.2f} ms/frame, {row['head_frames_per_second']:.0f} head-frames/s, "
          f"{row.get('newton_iterations_per_frame')} Newton iterations/frame", flush=True)
    # the same frames launch by launch, every kernel timed
    if batch.device.is_cuda:
        batch.reset()
        graphs = batch.stepper.use_graph
        batch.stepper.use_graph = False
        try:
            drive(batch, controls, 2, 1)
            wp.timing_begin(cuda_filter=wp.TIMING_ALL, synchronize=True)
            t0 = time.perf_counter()
            drive(batch, controls, pf, 3)
            wall = time.perf_counter() - t0
            records = wp.timing_end(synchronize=True)
        finally:
            batch.stepper.use_graph = graphs
        per: dict[str, list] = {}
        for r in records:
            k = kernel_name(r)
            e = per.setdefault(k, [0.0, 0])
            e[0] += float(r.elapsed)
            e[1] += 1
        total = sum(v[0] for v in per.values())
        kernels = sorted(({"kernel": k, "job": job(k), "ms_per_frame": v[0] / pf, "launches_per_frame": v[1] / pf,
                           "us_per_launch": v[0] / v[1] * 1e3, "share": v[0] / total if total else 0.0}
                          for k, v in per.items()), key=lambda d: -d["ms_per_frame"])
        jobs: dict[str, dict] = {}
        for d in kernels:
            g = jobs.setdefault(d["job"], {"ms_per_frame": 0.0, "launches_per_frame": 0.0})
            g["ms_per_frame"] += d["ms_per_frame"]
            g["launches_per_frame"] += d["launches_per_frame"]
        for g in jobs.values():
            g["share"] = g["ms_per_frame"] * pf / total if total else 0.0
        row["profile"] = {
            "frames": pf,
            "kernel_ms_per_frame": total / pf,
            "launches_per_frame": sum(v[1] for v in per.values()) / pf,
            "wall_ms_per_frame_without_graphs": wall / pf * 1e3,
            "kernel_share_of_graph_frame": (total / pf) / row["ms_per_frame"],
            "jobs": dict(sorted(jobs.items(), key=lambda kv: -kv[1]["ms_per_frame"])),
            "kernels": kernels[:40],
        }
        print(f"  kernels {total / pf:.2f} ms/frame in {row['profile']['launches_per_frame']:.0f} launches "
              f"({row['profile']['kernel_share_of_graph_frame']:.0%} of the graph's frame)", flush=True)
        for label, g in row["profile"]["jobs"].items():
            print(f"  {label:24s} {g['ms_per_frame']:8.2f} ms/frame {g['share']:6.1%} "
                  f"{g['launches_per_frame']:8.0f} launches", flush=True)
    del batch
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--sizes", default=None, help="comma list of N (default cuda 1,100,300; cpu 1,2)")
    ap.add_argument("--heads", default="default,scaled", help="head specs cycled over the batch (benchmarks/_batch_heads.py)")
    ap.add_argument("--preset", default="laugh")
    ap.add_argument("--frames", type=int, default=10, help="timed frames with graphs (after 2 warm-up frames)")
    ap.add_argument("--profile-frames", type=int, default=3, help="frames timed kernel by kernel")
    ap.add_argument("--newton", default="", help="comma list of N for Newton VBD's replicate (tissue only)")
    ap.add_argument("--level", type=int, default=0)
    ap.add_argument("--name", default=None, help="result name (default batch_profile_<device>)")
    args = ap.parse_args(argv)

    cuda = args.device.startswith("cuda")
    sizes = [int(s) for s in (args.sizes or ("1,100,300" if cuda else "1,2")).split(",") if s.strip()]
    name = args.name or f"batch_profile_{'cuda' if cuda else 'cpu'}"
    rigs, specs, notes = make_rigs([s.strip() for s in args.heads.split(",") if s.strip()], args.level)
    figures = {"device": args.device, "level": args.level, "heads": specs, "preset": args.preset,
               "frames": args.frames, "profile_frames": args.profile_frames, "notes": notes, "rows": [],
               "newton_vbd": []}
    for n in sizes:
        try:
            figures["rows"].append(profile_size(n, rigs, args))
        except Exception as e:
            traceback.print_exc()
            figures["rows"].append({"n": n, "error": f"{type(e).__name__}: {e}"})
            if "memory" in str(e).lower():
                break
        save(name, figures, device=args.device)
    newton_sizes = [int(s) for s in args.newton.split(",") if s.strip()]
    if newton_sizes:
        from benchmarks._peer_problem import export_problem

        problem = export_problem(rigs[0], args.preset)
        for n in newton_sizes:
            r = newton_replicated(problem, n, args.device, frames=3)
            r["n"] = n
            figures["newton_vbd"].append(r)
            print(f"Newton VBD N={n}: {r}", flush=True)
            save(name, figures, device=args.device)
    print(save(name, figures, device=args.device))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
