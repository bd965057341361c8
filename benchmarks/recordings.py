"""Recordings as they really are (issue 36): an actor's mocap take retargeted to another head, real-looking Live Link Face and MediaPipe takes driven, and the drive's speed at level 0 with where a frame's time goes.

    python -m benchmarks recordings [--actor identity001] [--seconds 3] [--seed S] [--arkit-seconds 4]
                                    [--ict-dir DIR] [--table-dir DIR] [--skip-arkit] [--name recordings_cpu]

* ``retarget``: a random performance (smooth activations of about 40 % of the muscles, jaw opening
  and side) simulated on the actor (an adapted ICT-FaceKit identity, built; ``--actor``), its 41
  markers (``benchmarks/_takes.py`` ``MARKERS_41``) moved by rigid head motion, placed in a room in
  centimetres with y up, 0.2 mm noise and dropouts, written as a mocap CSV and read back; then
  ``fw.drive(sim, take, retarget=True)`` on the default head at level 0 (``method`` affine and
  fapu), and this head's own points under the same controls driven back (the bound). Per frame: the RMS distance of the driven points from their retargeted targets (target
  <= 1.5 mm), and the activations against the actor's on the muscles the take used (target within
  0.1), with the actor's head motion recovered against the truth.
* ``arkit``: a Live Link Face CSV (30 fps on a 60 fps timecode, frames dropped, EyeLookIn to 1.05,
  ``BlendshapeCount``) and MediaPipe JSONs (51+1 categories, microsecond and whole-ms timestamps)
  generated and driven through the default head's ARKit table (built from the ICT-FaceKit
  expressions found, ``--ict-dir``), the frames per second of the ARKit drive, and whether the
  table moves the mouth and jaw to the face's own left for mouthLeft / jawLeft.
* ``speed``: frames per second of the marker drive (offline) and the ARKit drive at level 0 on
  this machine, and a profile of each (the functions that take most of a frame).

The box is shared: speeds are lower bounds (the load averages are recorded).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import secrets
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import _takes
from benchmarks._common import case_face, save


def _profile_top(prof: cProfile.Profile, count: int = 12) -> list:
    """The functions with the most cumulative time below the frame loop, as rows."""
    s = io.StringIO()
    st = pstats.Stats(prof, stream=s)
    rows = []
    total = max(st.total_tt, 1e-9)
    for (file, line, fn), (cc, nc, tt, ct, callers) in sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:count]:
        rows.append({"function": f"{Path(file).name}:{line}:{fn}", "self_s": round(tt, 3),
                     "self_share": round(tt / total, 3), "cumulative_s": round(ct, 3), "calls": nc})
    return rows


def retarget_cases(fw, actor_rig, head_rig, seconds: float, fps: float, rng, tmp: Path) -> dict:
    names = [n for n in _takes.MARKERS_41 if n in {str(i) for i in head_rig.fdp_ids}]
    sim_a = fw.FaceSimulator(actor_rig, fps=fps)
    M = len(sim_a.muscle_names)
    names_a = list(sim_a.muscle_names)
    T = int(round(seconds * fps)) + 1
    A, J = _takes.random_controls(rng, T, fps, M)
    local = _takes.simulate_points(actor_rig, A, J, fps, names)
    take, (R, t) = _takes.marker_take(local, fps, rng, names=names)
    path = tmp / "take.csv"
    _takes.save_take_csv(take, path, units="cm")
    track = fw.load_markers(path, units="cm")
    used = [i for i in range(M) if A[:, i].max() > 0.05]
    # the bound: this head's own points under the same controls (no noise, no motion) driven back
    own = _takes.simulate_points(head_rig, A, J, fps, names)
    sim_o = fw.FaceSimulator(head_rig, fps=fps)
    res_o = fw.drive(sim_o, fw.MarkerTrack(fps, names, own, "own"))
    same = [list(sim_o.muscle_names).index(names_a[i]) for i in used]
    dA_own = np.abs(res_o.activations[:, same] - A[:, used])
    out = {"frames": T, "markers": len(names), "muscles_used": [names_a[i] for i in used],
           "take": {"frames_filled": track.info.get("frames_filled"),
                    "missing_marker_frames": int(np.isnan(take.positions).any(axis=2).sum()),
                    "noise_mm_per_axis": 0.2, "units": "cm"},
           "own_motion_driven_back": {
               "activation_error_max": float(dA_own.max()), "activation_error_p95": float(np.percentile(dA_own, 95)),
               "activation_error_max_per_muscle": {names_a[i]: round(float(dA_own[:, k].max()), 4)
                                                   for k, i in enumerate(used)},
               "fdp_rms_mm_per_frame_max": float(np.nanmax(res_o.rms) * 1e3)}}
    for method in ("fapu", "affine"):
        sim = fw.FaceSimulator(head_rig, fps=track.fps)
        t0 = time.perf_counter()
        res = fw.drive(sim, track, retarget=True, method=method)
        wall = time.perf_counter() - t0
        dA = np.abs(res.activations[:, same] - A[:, used])
        R_fit = np.asarray(res.head_poses)[:, :3, :3]
        rot_err = np.degrees(np.arccos(np.clip((np.einsum("tij,tij->t", R_fit, R) - 1) / 2, -1, 1)))
        rms = np.asarray(res.rms)
        map_err = np.sqrt(np.nanmean(np.sum((np.asarray(res.targets) - own) ** 2, axis=2), axis=1))
        out[method] = {
            "fdp_rms_mm_per_frame_max": float(np.nanmax(rms) * 1e3), "fdp_rms_mm_mean": float(np.nanmean(rms) * 1e3),
            "frames_within_1_5mm": float(np.mean(rms <= 1.5e-3)),
            "activation_error_max": float(dA.max()), "activation_error_p95": float(np.percentile(dA, 95)),
            "activation_error_mean": float(dA.mean()),
            "activation_error_max_per_muscle": {names_a[i]: round(float(dA[:, k].max()), 4) for k, i in enumerate(used)},
            "jaw_error_deg_max": float(np.degrees(np.abs(res.jaw - J).max())),
            "targets_vs_own_motion_rms_mm_max": float(np.nanmax(map_err) * 1e3),
            "targets_vs_own_motion_rms_mm_mean": float(np.nanmean(map_err) * 1e3),
            "head_rotation_error_deg_max": float(rot_err.max()),
            "head_frames_held": res.retarget["head_motion"]["frames_held"],
            "neutral_residual_mm": res.retarget["neutral_residual_mm"], "scale": res.retarget["scale"],
            "frames_per_second": float(res.frames_per_second), "wall_s": wall, "notes": res.unreachable[:8],
        }
        print(method, {k: v for k, v in out[method].items() if not isinstance(v, (dict, list))}, flush=True)
    return out


def arkit_cases(fw, head_rig, seconds: float, rng, ict_dir, tmp: Path, build: Path) -> dict:
    sim = fw.FaceSimulator(head_rig)
    t0 = time.perf_counter()
    kw = {"ict_dir": ict_dir} if ict_dir else {}
    table = fw.arkit_table(sim, cache=build, **kw)
    table_s = time.perf_counter() - t0
    W = _takes.arkit_curves(seconds, 30.0, rng, active=12)
    out = {"table_s": round(table_s, 2), "table_from_cache": bool(table.info.get("from_cache")),
           "out_of_reach": table.out_of_reach(), "takes": {}}
    files = {
        "livelink_dropped_60tc": lambda p: _takes.write_livelink(p, W, 30.0, rng, count_header="BlendshapeCount"),
        "mediapipe_us": lambda p: _takes.write_mediapipe(p, np.clip(W, 0, 1), 30.0, rng, stamps="us"),
        "mediapipe_people_strings": lambda p: _takes.write_mediapipe(p, np.clip(W, 0, 1), 30.0, rng,
                                                                     layout="people", strings=True, drop=True),
    }
    for name, write in files.items():
        p = tmp / (name + (".csv" if name.startswith("livelink") else ".json"))
        write(p)
        track = fw.load_arkit(p)
        s = fw.FaceSimulator(head_rig, fps=track.fps)
        prof = cProfile.Profile()
        c0 = time.process_time()
        prof.enable()
        res = fw.drive(s, track, table=table)
        prof.disable()
        cpu = time.process_time() - c0
        out["takes"][name] = {"frames": res.frames, "fps": track.fps, "notes": track.notes,
                              "frames_per_second": float(res.frames_per_second),
                              "frames_per_cpu_second": res.frames / cpu,
                              "target_rms_mm_max": float(np.max(res.rms) * 1e3),
                              "active_shapes": int((track.weights.max(0) > 0.05).sum())}
        if name == "livelink_dropped_60tc":
            out["profile_livelink"] = _profile_top(prof)
    # conventions: mouthLeft / jawLeft move the mouth and chin towards the face's own left
    ids = [str(i) for i in head_rig.fdp_ids]
    rest = sim.fdp_points()
    left = np.sign(rest[ids.index("8.3"), 0] - rest[ids.index("8.4"), 0])  # the face's own left along x
    conv = {}
    for shape, point in (("mouthLeft", "8.3"), ("jawLeft", "2.1"), ("mouthRight", "8.4"), ("jawRight", "2.1")):
        if shape in table.reasons:
            conv[shape] = {"reached": False, "reason": table.reasons[shape]}
            continue
        w = np.zeros((1, 52))
        w[0, list(fw.ARKIT_NAMES).index(shape)] = 1.0
        dx = float(table.targets_for(w)[0, list(table.fdp_ids).index(point), 0] - rest[ids.index(point), 0])
        want = 1.0 if shape.endswith("Left") else -1.0
        conv[shape] = {"point": point, "dx_mm_towards_face_left": round(dx * left * 1e3, 3),
                       "as_arkit_says": bool(dx * left * want > 0)}
    out["left_right_conventions"] = conv
    return out


def speed_markers(fw, head_rig, seconds: float, rng) -> dict:
    """The marker drive's frames per second (offline, 84 FDPs of a random performance) and its profile."""
    fps = 30.0
    sim0 = fw.FaceSimulator(head_rig, fps=fps)
    T = int(round(seconds * fps)) + 1
    A, J = _takes.random_controls(rng, T, fps, len(sim0.muscle_names))
    ids = [str(i) for i in head_rig.fdp_ids]
    P = _takes.simulate_points(head_rig, A, J, fps, ids)
    sim = fw.FaceSimulator(head_rig, fps=fps)
    prof = cProfile.Profile()
    c0 = time.process_time()
    prof.enable()
    res = fw.drive(sim, fw.MarkerTrack(fps, ids, P, "speed"))
    prof.disable()
    cpu = time.process_time() - c0
    st = res.stats
    return {"frames": res.frames, "frames_per_second": float(res.frames_per_second),
            "frames_per_cpu_second": res.frames / cpu,
            "steps_per_frame": st["steps"] / max(st["frames"], 1),
            "seconds": {"solve": st["solve_seconds"], "step": st["step_seconds"], "jacobian": st["jacobian_seconds"]},
            "jacobians": st["jacobians"], "profile": _profile_top(prof)}


def main(argv=None) -> dict:
    import facewarp as fw

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--actor", default="identity001", help="the actor's head (identityNNN or a build folder)")
    ap.add_argument("--seconds", type=float, default=3.0, help="length of the retargeted take [s]")
    ap.add_argument("--arkit-seconds", type=float, default=4.0)
    ap.add_argument("--ict-dir", default=None, help="a folder of ICT-FaceKit expression OBJs for the ARKit table")
    ap.add_argument("--skip-arkit", action="store_true")
    ap.add_argument("--table-dir", default=None, help="a folder to keep the head's ARKit table in between runs")
    ap.add_argument("--seed", type=int)
    ap.add_argument("--name", default="recordings_cpu")
    args = ap.parse_args(argv)
    seed = args.seed if args.seed is not None else secrets.randbits(32)
    rng = np.random.default_rng(seed)
    load0 = list(os.getloadavg())
    t0 = time.perf_counter()
    actor = case_face(args.actor)
    head = case_face("default")
    figures = {"seed": seed, "actor": args.actor, "head": "default level 0", "load_average_at_start": load0,
               "targets": {"retarget_fdp_rms_mm_per_frame": 1.5, "retarget_activation_error": 0.1,
                           "arkit_frames_per_second": 60, "marker_frames_per_second": 30}}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        figures["retarget"] = retarget_cases(fw, actor, head, args.seconds, 30.0, rng, tmp)
        figures["speed_markers"] = speed_markers(fw, head, 2.0, rng)
        print("markers", figures["speed_markers"]["frames_per_second"], flush=True)
        if not args.skip_arkit:
            build = Path(args.table_dir) if args.table_dir else tmp / "build"
            build.mkdir(parents=True, exist_ok=True)
            figures["arkit"] = arkit_cases(fw, head, args.arkit_seconds, rng, args.ict_dir, tmp, build)
            print("arkit", {k: v["frames_per_second"] for k, v in figures["arkit"]["takes"].items()}, flush=True)
    figures["load_average_at_end"] = list(os.getloadavg())
    figures["wall_s"] = time.perf_counter() - t0
    figures["note"] = ("2-core box shared with other jobs: frames per second are lower bounds (load averages above); "
                       "frames_per_cpu_second (frames over the process's CPU time) estimates the unloaded rate; "
                       "level 0; CPU")
    print("wrote", save(args.name, figures, benchmark="recordings"))
    return figures


if __name__ == "__main__":
    main()
