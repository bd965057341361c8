"""Peak FDP amplitudes of every preset against the issue-12 targets, on the default head.

    python -m benchmarks.expression_targets [--level 0] [--seconds 1.5] [--device cpu]

Builds the default head, plays each preset (and zygomatic major / inner frontalis alone at
activation 1.0, the recorded human rig's full-weight smile and brow raise) ramped in over 0.3 s
and held, with the default simulator (implicit solver, physical material, contact, kinematic jaw), and
records the displacement [mm] of the lip corners (8.3/8.4), chin (2.1), brows (4.1-4.6) and
cheeks (5.1/5.2), the lid fissures (3.1-3.3, 3.2-3.4), the lip gap (2.2-2.3), the mouth width
(8.3-8.4), and the inverted tets at the end. Writes benchmarks/results/expression_targets_L<level>.json.
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks._common import add_case_args, save

POINTS = ("8.3", "8.4", "2.1", "4.1", "4.2", "4.3", "4.4", "4.5", "4.6", "5.1", "5.2", "3.1", "3.2", "3.3", "3.4")
DISTANCES = {"fissure_L": ("3.1", "3.3"), "fissure_R": ("3.2", "3.4"), "lip_gap": ("2.2", "2.3"),
             "mouth_width": ("8.3", "8.4")}
TARGETS = {
    "smile": "lip corners 8.3/8.4 move 8-16 mm, up (+y), back (-z) and outward; cheeks 5.1/5.2 up",
    "laugh": "chin 2.1 down 10-25 mm; lip corners >= 8 mm as in smile; lips apart",
    "surprise": "brows 4.1-4.6 up 4-12 mm; jaw opens 5-15 mm",
    "sad": "inner brows 4.1/4.2 up >= 2 mm; lip corners down >= 2 mm",
    "angry": "inner brows toward the midline and down, >= 1 mm each way (>= 1.5 mm in all)",
    "blink": "lid fissures 3.1-3.3 and 3.2-3.4 within 1 mm",
    "squint": "lid fissures narrowed (orbicularis oculi 0.3) but open",
    "pucker": "orbicularis oris: the mouth 8.3-8.4 narrows, the corners come forward",
    "press": "orbicularis oris: the lips touch (2.2-2.3 gap near 0, kept by the lip contact)",
    "zygomatic_major=1": "ICT mouthSmile at full weight: lip corners 15.6 mm (up 10.5, back 9.1, out 7.1), within 25 %",
    "frontalis_inner=1": "ICT browInnerUp at full weight: inner brows 4.5 mm up, within 25 %",
}


def main(argv=None) -> None:
    import facewarp
    from facewarp.geometry import signed_tet_volumes

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_case_args(ap, level=0, device="cpu")
    ap.add_argument("--seconds", type=float, default=1.5)
    args = ap.parse_args(argv)

    rig = facewarp.build_face(facewarp.default_template(args.level))
    T = rig.tets

    rest_sign = np.sign(signed_tet_volumes(rig.nodes, T))
    rows = {}
    for name in list(facewarp.PRESETS) + ["zygomatic_major=1", "frontalis_inner=1"]:
        e = facewarp.expressions.expression_from_activations(name) if "=" in name else facewarp.preset(name)
        sim = facewarp.FaceSimulator(rig, device=args.device, fps=30)
        tl = facewarp.Timeline([facewarp.expressions.Segment(e, 0.0, 0.3, 60.0, 0.1)]).for_head(rig)
        frames = sim.run(tl, args.seconds)
        ids = [str(k) for k in frames.fdp_ids]
        P = frames.fdp_points.astype(np.float64)
        d = (P[-1] - P[0]) * 1e3
        row = {"jaw_u_rad": float(tl.sample(args.seconds).jaw_u), "jaw_drop_mm": None if e.jaw_drop_m is None
               else e.jaw_drop_m * 1e3, "displacement_mm": {k: d[ids.index(k)].round(2) for k in POINTS},
               "distance_mm": {n: [round(float(np.linalg.norm(P[f, ids.index(a)] - P[f, ids.index(b)]) * 1e3), 2)
                                   for f in (0, -1)] for n, (a, b) in DISTANCES.items()},
               "still_moving_mm": float(np.abs(P[-1] - P[-8]).max() * 1e3),
               "inverted_tets": int((np.sign(signed_tet_volumes(sim.positions(), T)) != rest_sign).sum()),
               "nan": bool(not np.isfinite(frames.points).all()), "target": TARGETS.get(name, "")}
        rows[name] = row
        c = row["displacement_mm"]
        print(f"{name:18s} 8.3 {c['8.3']} 8.4 {c['8.4']} 2.1 {c['2.1']} 4.1 {c['4.1']} 4.3 {c['4.3']}", flush=True)
    save(f"expression_targets_L{args.level}", {
        "level": args.level, "seconds": args.seconds,
        "jaw_lever_m": facewarp.expressions.jaw_lever(rig), "solver": "implicit", "material": "physical", "jaw": "kinematic",
        "contact": True,
        "muscles": "two-way anchors, Fig. 6.4 region filter, saturating activation curve (muscle_defs.json)",
        "note": "displacements [mm] at the end (x left, y up, z out); distances [mm] at rest and at the end",
        "presets": rows}, device=args.device)


if __name__ == "__main__":
    raise SystemExit(main())
