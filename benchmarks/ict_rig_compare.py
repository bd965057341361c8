"""Simulated expressions against the recorded human rig, on the ICT head imported as a template.

    python -m benchmarks.ict_rig_compare [--seconds 1.5] [--device cpu] [--ict ../shared/data/ict-facekit]

Issue 12: "on the ICT head imported as a template (``facewarp template import-ict``), where the
blendshapes of ``../shared/data/ict-facekit`` (mouthSmile_L/R, jawOpen, browInnerUp_L/R) live on
the same vertices, the simulated smile, jaw opening and brow raise have cosine similarity >= 0.7
with them over the FDP displacement field, and activation 1.0 matches their amplitude within 25 %."

The imported template's skin is the ICT skin, vertex for vertex, so each blendshape's displacement
is read at the template's own FDPs (face + barycentric) and over all its simulated face vertices.
Cases (each ramped in over 0.3 s and held, default simulator: implicit solver, physical material,
kinematic jaw):

* ``smile``: zygomatic major at activation 1.0 on both sides vs mouthSmile_L + mouthSmile_R;
* ``smile_L``: the left zygomatic major alone vs mouthSmile_L;
* ``brow_raise``: inner frontalis at 1.0 vs browInnerUp_L + browInnerUp_R;
* ``jaw_open``: the jaw opened to ICT jawOpen's own chin drop (FDP 2.1, measured on the rig) vs
  jawOpen: the direction of the whole field follows from the condyle hinge and Eq. 6.4.9, the
  amplitude of the chin is matched by construction (its ratio is reported, not judged).

Per case: cosine similarity of the stacked FDP displacements (the head FDPs that move > 0.5 mm in
either), the same over the face vertices, the amplitude ratio simulated / rig of the largest
FDP displacement, and per compared FDP both vectors [mm] with the FDP's share of the rig's squared
displacement (``per_fdp_mm``). Writes benchmarks/results/ict_rig_compare.json.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks._common import add_case_args, save
from benchmarks._ict import ict_dir

DEFAULT_ICT = ict_dir()

CASES = {
    "smile": ("zygomatic_major=1", ("mouthSmile_L", "mouthSmile_R")),
    "smile_L": ("zygomatic_major_L=1", ("mouthSmile_L",)),
    "brow_raise": ("frontalis_inner=1", ("browInnerUp_L", "browInnerUp_R")),
    "jaw_open": (None, ("jawOpen",)),
}


def _cos(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a.ravel(), b.ravel()
    den = float(np.linalg.norm(a) * np.linalg.norm(b))
    return float(a @ b / den) if den > 0 else float("nan")


def main(argv=None) -> None:
    import facewarp

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.5)
    add_case_args(ap, device="cpu")
    ap.add_argument("--ict", type=Path, default=DEFAULT_ICT)
    args = ap.parse_args(argv)
    if not (args.ict / "generic_neutral_mesh.obj").is_file():
        raise SystemExit(f"--ict: {args.ict} holds no ICT-FaceKit generic_neutral_mesh.obj")

    t0 = time.perf_counter()
    tpl = facewarp.heads.import_ict(args.ict, device=args.device)
    rig = facewarp.build_face(tpl)
    build_s = time.perf_counter() - t0
    n_skin = tpl.vertex_count
    neutral = facewarp.load_mesh(args.ict / "generic_neutral_mesh.obj", units="cm").vertices[:n_skin]

    # the head FDPs as (face, barycentric) on the skin: a blendshape's displacement at each
    head_fdps = [k for k in tpl.fdp if tpl.fdp[k][0] == "head"]
    F = np.asarray(tpl.faces)

    def at_fdps(D: np.ndarray) -> np.ndarray:
        out = []
        for k in head_fdps:
            sp = tpl.fdp[k][1]
            out.append(np.einsum("j,jk->k", np.asarray(sp.bary[0], float), D[F[int(sp.face[0])]]))
        return np.array(out)

    face_vertices = np.unique(F[np.asarray(tpl.frontal, bool)])  # the simulated (frontal) face

    def shape_delta(names) -> np.ndarray:
        D = np.zeros_like(neutral)
        for nm in names:
            D += facewarp.load_mesh(args.ict / f"{nm}.obj", units="cm").vertices[:n_skin] - neutral
        return D

    rows = {}
    for case, (spec, shapes) in CASES.items():
        D_rig = shape_delta(shapes)
        P_rig = at_fdps(D_rig)
        if spec is None:  # the jaw to the rig's own chin drop
            chin = P_rig[head_fdps.index("2.1")]
            spec = f"jaw_drop_mm={max(-chin[1], 0.0) * 1e3:.2f}"
        expr = facewarp.expressions.expression_from_activations(spec, name=case)
        sim = facewarp.FaceSimulator(rig, device=args.device, fps=30)
        tl = facewarp.Timeline([facewarp.expressions.Segment(expr, 0.0, 0.3, 60.0, 0.1)]).for_head(rig)
        t1 = time.perf_counter()
        frames = sim.run(tl, args.seconds)
        sim_s = time.perf_counter() - t1
        ids = [str(k) for k in frames.fdp_ids]
        P = frames.fdp_points.astype(np.float64)
        P_sim = np.array([P[-1, ids.index(k)] - P[0, ids.index(k)] for k in head_fdps])
        moving = (np.linalg.norm(P_sim, axis=1) > 5e-4) | (np.linalg.norm(P_rig, axis=1) > 5e-4)
        amp_sim = float(np.linalg.norm(P_sim, axis=1).max())
        amp_rig = float(np.linalg.norm(P_rig, axis=1).max())
        row = {
            "expression": spec, "rig_shapes": list(shapes),
            "fdps_compared": int(moving.sum()),
            "cosine_fdp": round(_cos(P_sim[moving], P_rig[moving]), 3),
            "amplitude_sim_mm": round(amp_sim * 1e3, 2), "amplitude_rig_mm": round(amp_rig * 1e3, 2),
            "amplitude_ratio": round(amp_sim / amp_rig, 3) if amp_rig > 0 else None,
            "largest_fdp_sim": head_fdps[int(np.argmax(np.linalg.norm(P_sim, axis=1)))],
            "largest_fdp_rig": head_fdps[int(np.argmax(np.linalg.norm(P_rig, axis=1)))],
            "seconds_simulated": args.seconds, "wall_s": round(sim_s, 1),
            "nan": bool(not np.isfinite(frames.points).all()),
        }
        # per FDP: the two vectors and the FDP's share of the rig's squared displacement (what a
        # region the simulation leaves still costs the cosine)
        e_rig = float((P_rig[moving] ** 2).sum())
        row["per_fdp_mm"] = {
            head_fdps[i]: {"sim": np.round(P_sim[i] * 1e3, 2).tolist(), "rig": np.round(P_rig[i] * 1e3, 2).tolist(),
                           "rig_share": round(float(P_rig[i] @ P_rig[i]) / e_rig, 3)}
            for i in np.flatnonzero(moving)}
        D_sim = frames.points[-1, :n_skin].astype(np.float64) - frames.points[0, :n_skin]
        row["cosine_face_vertices"] = round(_cos(D_sim[face_vertices], D_rig[face_vertices]), 3)
        row["cosine_ok"] = bool(row["cosine_fdp"] >= 0.7)
        row["amplitude_ok"] = None if case == "jaw_open" else bool(abs(row["amplitude_ratio"] - 1.0) <= 0.25)
        rows[case] = row
        print(f"{case:11s} cos {row['cosine_fdp']:.3f} amp {row['amplitude_sim_mm']:.1f}/{row['amplitude_rig_mm']:.1f} mm "
              f"({row['amplitude_ratio']}) {row.get('cosine_face_vertices', '')}", flush=True)
    save("ict_rig_compare", {
        "template": "ICT-FaceKit neutral imported (facewarp.heads.import_ict)",
        "nodes": int(len(rig.nodes)), "tets": int(len(rig.tets)), "build_s": round(build_s, 1),
        "solver": "implicit", "material": "physical", "jaw": "kinematic",
        "targets": "cosine >= 0.7 over the FDP displacement field; amplitude within 25 % at activation 1.0",
        "cases": rows}, device=args.device)


if __name__ == "__main__":
    raise SystemExit(main())
