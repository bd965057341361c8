"""Accuracy of the implicit solver (issue 10): per frame, at rest, across steps per frame and levels.

    python -m benchmarks.solver_accuracy [--materials physical thesis] [--parts frames static levels]
                                         [--presets smile laugh surprise angry sad] [--device cpu]
                                         (parts: frames static levels pcg loads)

* ``frames``: each Table 6.4 preset (attack 0.3 s, hold 0.7 s, release 0.3 s) on the default head
  (level 0) with the default solver (tolerance 3e-5 m), the interactive mode (1, 2, 3 iterations
  per frame) and the fully converged solution of the same steps (tolerance 1e-7 m, springs to
  1e-4); per phase, the largest distance of any of the 84 FDPs from the converged one, and whether
  every FDP is within 0.5 mm or 10 % of its displacement from rest; frames per second of each.
* ``static``: each preset ramped in over 0.3 s and held 0.5 s, at 1, 2, 4 and 8 steps per frame,
  against the Verlet reference of the same model (same profile, energies, muscles) run the same
  way: the largest FDP distance at rest [mm] and relative to the FDP's displacement.
* ``pcg``: the device method (``newton-pcg``: a fixed count of Newton iterations, each a fixed
  count of CG iterations) on ``--device`` at several (Newton, CG) counts, against the fully
  converged CPU solution of the same steps (L-BFGS, tolerance 1e-7 m), per phase as ``frames``,
  with frames per second: which counts keep every FDP within 0.5 mm or 10 %.
* ``levels``: the same static shapes on level 1 (27k tets) against level 0 (``--compare-levels``:
  further pairs, e.g. 0 1 2 also compares level 2 with level 1): the relative difference of the
  FDP displacements (FDPs moving more than 1 mm on the coarser level), per FDP and over the field.

* ``loads``: per preset and level (``--compare-levels``), the muscle springs' load at the static
  shape: the active attachments' stiffness sum, the stiffness-weighted mean travel of their
  targets and of the attached nodes, beside the largest FDP displacement: whether levels differ in
  the load or in the tissue's response to it.

``--shear-modulus MU`` adds a run of every part with the physical profile's shear term (modulus MU
[Pa]) in place of its distance and area energies (``physical+shear<MU>`` in the results): the
volume energy plus a shear energy that is the same material for any tet shape.

Writes benchmarks/results/solver_accuracy_<device>.json.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks._common import (add_case_args, case_face, material_label, run_timeline, save, shear_material,
                                static_shape)

PRESETS = ("smile", "laugh", "surprise", "angry", "sad")
ATTACK, HOLD, RELEASE, START = 0.3, 0.7, 0.3, 0.1


def _within(err, disp, mm=5e-4, rel=0.1):
    """Every FDP within ``mm`` metres or ``rel`` of its displacement."""
    return bool(np.all((err <= mm) | (err <= rel * disp)))


def part_frames(fr, material, presets, device) -> list:
    import facewarp

    rows = []
    seconds = START + ATTACK + HOLD + RELEASE + 0.2
    for name in presets:
        tl = facewarp.timeline_for(name, attack=ATTACK, hold=HOLD, release=RELEASE, start=START)
        # spring_tolerance is an option of the host solver (the CPU default), not of the device one
        opts = dict(max_iterations=500, **(dict(spring_tolerance=1e-4) if str(device) == "cpu" else {}))
        conv, _ = run_timeline(fr, tl, seconds, device=device, material=material, tolerance=1e-7, solver_options=opts)
        t = conv.times
        phase = np.where(t < START + ATTACK, "attack", np.where(t < START + ATTACK + HOLD, "hold", "release"))
        disp = np.linalg.norm(conv.fdp_points - conv.fdp_points[:1], axis=2)
        row = {"preset": name, "material": material_label(material), "frames": int(len(t)),
               "max_fdp_displacement_mm": round(float(disp.max()) * 1e3, 3),
               "converged_fps": round(conv.frames_per_second, 2)}
        for label, kw in (("default", {}), ("iterations_1", dict(iterations=1)), ("iterations_2", dict(iterations=2)),
                          ("iterations_3", dict(iterations=3))):
            frames, sim = run_timeline(fr, tl, seconds, device=device, material=material, **kw)
            err = np.linalg.norm(frames.fdp_points - conv.fdp_points, axis=2)  # (f, 84)
            r = {"fps": round(frames.frames_per_second, 2), "realtime_factor": round(frames.realtime_factor, 3),
                 "max_error_mm": round(float(err.max()) * 1e3, 4), "within_0.5mm_or_10pct": _within(err, disp)}
            for ph in ("attack", "hold", "release"):
                m = phase == ph
                r[f"{ph}_max_error_mm"] = round(float(err[m].max()) * 1e3, 4)
                r[f"{ph}_within"] = _within(err[m], disp[m])
            if label == "default":
                r["factorizations"] = sim.solver.factorizations
                r["seconds_per_frame"] = {k: round(v / (len(t) - 1) * 1e3, 2) for k, v in sim.solver.timings.items()}
            row[label] = r
        print(row, flush=True)
        rows.append(row)
    return rows


def part_static(fr, material, presets, device) -> list:
    rows = []
    from facewarp import SimulationError

    for name in presets:
        t0 = time.perf_counter()
        try:
            ref, rest, sim = static_shape(fr, name, material, device, solver="verlet")
        except SimulationError as e:  # the explicit reference itself failed
            row = {"preset": name, "material": material_label(material), "verlet_error": str(e)}
            print(row, flush=True)
            rows.append(row)
            continue
        tv = time.perf_counter() - t0
        disp = np.linalg.norm(ref - rest, axis=1)
        row = {"preset": name, "material": material_label(material), "verlet_substeps_per_frame": sim.substeps,
               "verlet_seconds": round(tv, 1), "max_fdp_displacement_mm": round(float(disp.max()) * 1e3, 3)}
        for steps in (1, 2, 4, 8):
            x, _, _ = static_shape(fr, name, material, device, substeps=steps, tolerance=1e-6)
            err = np.linalg.norm(x - ref, axis=1)
            moving = disp > 1e-3
            row[f"steps_{steps}"] = {
                "max_error_mm": round(float(err.max()) * 1e3, 4),
                "max_relative_error": round(float((err[moving] / disp[moving]).max()) if moving.any() else 0.0, 4),
                "within_0.2mm_or_3pct": _within(err, disp, 2e-4, 0.03)}
        print(row, flush=True)
        rows.append(row)
    return rows


PCG_COUNTS = ["3x50", "2x50", "3x30", "4x20", "5x15", "4x15", "3x20", "2x20"]  # Newton x CG [+e<extrapolate>]


def part_pcg(fr, material, presets, device, counts=PCG_COUNTS) -> list:
    import facewarp

    rows = []
    seconds = START + ATTACK + HOLD + RELEASE + 0.2
    for name in presets:
        tl = facewarp.timeline_for(name, attack=ATTACK, hold=HOLD, release=RELEASE, start=START)
        conv, _ = run_timeline(fr, tl, seconds, device="cpu", method="lbfgs", material=material, tolerance=1e-7,
                       solver_options=dict(spring_tolerance=1e-4, max_iterations=500))
        t = conv.times
        phase = np.where(t < START + ATTACK, "attack", np.where(t < START + ATTACK + HOLD, "hold", "release"))
        disp = np.linalg.norm(conv.fdp_points - conv.fdp_points[:1], axis=2)
        row = {"preset": name, "material": material_label(material), "device": device, "frames": int(len(t)),
               "max_fdp_displacement_mm": round(float(disp.max()) * 1e3, 3)}
        for label in counts:
            label_, _, rounds = label.partition("+r")
            nc, _, ex = label_.partition("+e")
            newton, cg = nc.split("x")
            newton, cg = (None if newton == "a" else int(newton)), int(cg)  # "a": adaptive (the default)
            kw = dict(device=device, material=material, method="newton-pcg", iterations=newton,
                      solver_options=dict(linear_iterations=cg, extrapolate=float(ex or 0.5)))
            if rounds:
                kw["solver_options"]["rounds"] = int(rounds)
            run_timeline(fr, tl, 0.1, **kw)  # warm: kernels, graph
            frames, sim = run_timeline(fr, tl, seconds, **kw)
            err = np.linalg.norm(frames.fdp_points - conv.fdp_points, axis=2)
            r = {"fps": round(frames.frames_per_second, 1), "max_error_mm": round(float(err.max()) * 1e3, 4),
                 # a fixed count replayed from a CUDA graph is not counted on the host
                 "newton_iterations_per_frame": newton or round(sim.solver.total_iterations / max(1, len(t) - 1), 2),
                 "within_0.5mm_or_10pct": _within(err, disp)}
            for ph in ("attack", "hold", "release"):
                m = phase == ph
                r[f"{ph}_max_error_mm"] = round(float(err[m].max()) * 1e3, 4)
            row[label] = r
        print(row, flush=True)
        rows.append(row)
    return rows


def part_levels(fr0, material, presets, device, levels=(0, 1)) -> list:
    """Each consecutive pair of ``levels`` (default 0 vs 1): per FDP moving more than 1 mm on the
    coarser level, |d_fine - d_coarse| / |d_coarse|; also the field's ||d_fine - d_coarse|| / ||d_coarse||."""
    rigs = {lv: fr0 if lv == 0 else case_face("default", lv) for lv in levels}
    rows = []
    for name in presets:
        disp = {}
        for lv in levels:
            x, r, _ = static_shape(rigs[lv], name, material, device, tolerance=1e-6)
            disp[lv] = x - r
        for lc, lf in zip(levels[:-1], levels[1:]):
            d0, d1 = disp[lc], disp[lf]
            n0 = np.linalg.norm(d0, axis=1)
            moving = n0 > 1e-3
            rel = np.linalg.norm(d1 - d0, axis=1)[moving] / n0[moving]
            row = {"preset": name, "material": material_label(material), "levels": [lc, lf],
                   "fdps_moving_over_1mm": int(moving.sum()),
                   "median_relative_difference": round(float(np.median(rel)), 4) if moving.any() else None,
                   "max_relative_difference": round(float(rel.max()), 4) if moving.any() else None,
                   "field_relative_difference": round(float(np.linalg.norm(d1[moving] - d0[moving])
                                                            / np.linalg.norm(d0[moving])), 4) if moving.any() else None,
                   "displacement_norm_ratio_fine_over_coarse": round(float(np.linalg.norm(d1[moving])
                                                                           / np.linalg.norm(d0[moving])), 4)
                   if moving.any() else None}
            print(row, flush=True)
            rows.append(row)
    return rows


def part_loads(fr0, material, presets, device, levels=(0, 1)) -> list:
    """Per preset and level, the muscle springs' load at the static shape: the sum of the active
    attachments' stiffness [N/m] (:meth:`facewarp.physics.MuscleRig.weighted_stiffness`, the
    profile's ``muscle_modulus`` times each node's sheet area), the stiffness-weighted mean travel of
    their targets on the contracted muscles [mm] and of the attached nodes [mm]: whether the levels
    differ in the load or in the tissue's response to it."""
    from facewarp.physics import rig_reference

    rigs = {lv: fr0 if lv == 0 else case_face("default", lv) for lv in levels}
    rows = []
    for name in presets:
        row = {"preset": name, "material": material_label(material)}
        for lv in levels:
            fr = rigs[lv]
            x, rest, sim = static_shape(fr, name, material, device, tolerance=1e-6)
            X = sim.positions()
            rig = sim.muscles.rig  # with the stiffness the simulator gave each attachment
            k = rig.weighted_stiffness()
            acts = sim.activations
            att_muscle = np.asarray(rig.ctrl_muscle)[np.asarray(rig.curve_ctrl)[np.asarray(rig.seg_curve)[rig.att_seg], 0]]
            on = np.clip(acts[np.asarray(rig.activation_index)[att_muscle]], 0, 1) > 0
            _, p1 = rig_reference(rig, acts, jaw=sim.jaw, jaw_angles=tuple(sim.jaw_angles))
            _, p0 = rig_reference(rig, np.zeros_like(acts))
            kk = k[on]
            travel = np.linalg.norm(((p1 - p0)[on] * kk[:, None]).sum(0) / kk.sum())
            node = np.linalg.norm(((X - fr.nodes)[rig.att_node[on]] * kk[:, None]).sum(0) / kk.sum())
            row[f"level{lv}"] = {"attachments": int(on.sum()), "stiffness_sum_N_per_m": round(float(kk.sum()), 1),
                                 "target_mean_travel_mm": round(float(travel) * 1e3, 3),
                                 "attached_node_mean_travel_mm": round(float(node) * 1e3, 3),
                                 "fdp_max_displacement_mm": round(float(np.linalg.norm(x - rest, axis=1).max()) * 1e3, 3)}
        print(row, flush=True)
        rows.append(row)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_case_args(ap, device="cpu", presets=list(PRESETS))
    ap.add_argument("--materials", nargs="*", default=["physical", "thesis"])
    ap.add_argument("--parts", nargs="+", default=["frames", "static", "levels"])
    ap.add_argument("--name", default=None, help="result file suffix")
    ap.add_argument("--shear-modulus", type=float, default=None,
                    help="physical profile with the shear term of this modulus [Pa] in place of the distance "
                         "and area energies (MaterialPhysical.shear_modulus); reported as material "
                         "'physical+shear<mu>'")
    ap.add_argument("--volume-modulus", type=float, default=None,
                    help="with --shear-modulus: the volume modulus [Pa] of that run (default the profile's 150 kPa)")
    ap.add_argument("--compare-levels", type=int, nargs="+", default=[0, 1],
                    help="levels part: the levels compared pairwise in order (e.g. 0 1 2: 0 vs 1 and 1 vs 2)")
    ap.add_argument("--pcg-counts", nargs="+", default=PCG_COUNTS,
                    help="pcg part: Newton x CG iteration counts, e.g. 3x50, ax20 (adaptive), 3x20+e0 (extrapolate 0; "
                         "default 0.5), ax20+r3 (3 rounds)")
    args = ap.parse_args(argv)
    from facewarp.physics import factorization_backend

    fr = case_face("default", 0)
    result = {"factorization_backend": factorization_backend(),
              "level0_tets": int(len(fr.tets))}
    name = "solver_accuracy_" + args.device.split(":")[0] + (f"_{args.name}" if args.name else "")
    materials = list(args.materials)
    if args.shear_modulus is not None:
        materials.append(shear_material(args.shear_modulus, args.volume_modulus))
    for mat in materials:
        for part in args.parts:
            fn = {"frames": part_frames, "static": part_static, "levels": part_levels, "pcg": part_pcg,
                  "loads": part_loads}[part]
            extra = (dict(counts=args.pcg_counts) if part == "pcg"
                     else dict(levels=tuple(args.compare_levels)) if part in ("levels", "loads") else {})
            result[f"{part}_{material_label(mat)}"] = fn(fr, mat, args.presets, args.device, **extra)
            save(name, result, device=args.device)  # after every part: a long run keeps what it measured
    print("wrote", save(name, result, device=args.device))


if __name__ == "__main__":
    raise SystemExit(main())
