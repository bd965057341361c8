"""The person's likeness (issue 25): the scan's colour baked onto the adapted head, and the scan's scale.

Run: ``python -m benchmarks.likeness [--seeds 3] [--texture-size 2048] [--render-size 400] [--device cpu]``

Per seed, the package's synthetic scan (:func:`facewarp.synthetic_scan`: another face, noise,
holes, a random pose, millimetres, with its procedural colour as vertex colours) is written as an
OBJ with ``v x y z r g b`` and:

1. **colour**: ``facewarp adapt`` (levels 2, ``--units mm``, the given landmarks) bakes ``texture.png``; the adapted head (its baked texture) and the scan (its
   vertex colours) are rendered from the same cameras, front and three-quarter
   (:func:`facewarp.render.likeness_views`, unlit for the figures), and compared over the face
   region: mean CIELAB Delta E (CIE76) and the L* correlation, beside the same figures for the
   head in the scan's median colour (the flat baseline). Targets: Delta E < 4, r >= 0.6.
   The first seed's lit renders go to ``results/likeness/seed<k>.png`` (head | scan | flat).
2. **scale**: the same scan written in an arbitrary unit (1 unit = a random 2-50 mm) with no
   landmarks and no ``--units`` adapts with the default units (the extent is no head in metres:
   ``auto``; the FDPs found by the detector give the scale); the recovered metres per unit
   against the truth (target within 5 %), and the same from the given FDPs in mm, cm, m; and
   the scale from the given FDPs over ``--scale-seeds`` faces (20), no adaptation.

Results: ``benchmarks/results/likeness.json`` (machine, versions, date, per seed and the means).

**A real scan** (``--scan PATH``; results ``likeness_real.json``, pictures ``likeness_real.png``)::

    python -m benchmarks likeness --scan /work/scans/leeperrysmith_intact/LeePerrySmith.glb \\
        --scan-texture /work/scans/leeperrysmith_intact/Map-COL.jpg --scan-texture-flip-v \\
        --scan-source "..." --scan-licence "CC BY 3.0" --scan-attribution "..." --observed "..."

The scan (any mesh ``facewarp adapt`` reads; with ``--scan-texture`` its UVs and that image are
first written together as a textured GLB, for scans that ship the colour map beside the mesh)
adapts with no landmarks (detected FDPs) and ``--units auto``; the scan is brought into the
template's frame by the similarity between ``adapted_scan_frame.obj`` and ``adapted.obj``, and
the same renders and figures as above are taken (front and three-quarter, ``--render-size``
default 512). The picture is scan | adapted head | flat colour, a row per view. The scan files
stay outside the repository; the result records their source, licence and attribution.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks._common import RESULTS, machine, save


def _write_scan(scan, folder: Path, metres_per_unit: float, *, landmarks: bool = True) -> dict:
    import facewarp as fw

    folder.mkdir(parents=True, exist_ok=True)
    fw.geometry.save_obj(folder / "scan.obj", scan.vertices / metres_per_unit, scan.faces, colors=scan.colors)
    out = {"scan": folder / "scan.obj", "landmarks": None}
    if landmarks:
        lm = {k: (np.asarray(v) / metres_per_unit).tolist() for k, v in scan.landmarks.items()}
        (folder / "lm.json").write_text(json.dumps(lm))
        out["landmarks"] = folder / "lm.json"
    return out


def _adapt(argv: list[str], device: str) -> dict:
    """``facewarp adapt ARGV`` in this process; its report.json."""
    from facewarp.cli import main as cli

    out = Path(argv[argv.index("--out") + 1])
    code = cli(["--device", device, "--json", "adapt", *argv])
    if code != 0:
        raise RuntimeError(f"facewarp adapt {' '.join(argv)} failed with exit code {code}")
    return json.loads((out / "report.json").read_text())


def run_seed(seed: int, work: Path, *, texture_size: int, render_size: int, device: str, picture: bool) -> dict:
    import facewarp as fw
    from PIL import Image

    scan = fw.synthetic_scan(seed)
    t = fw.default_template(0)
    files = _write_scan(scan, work / f"scan{seed}", 1e-3)
    out = work / f"adapt{seed}"
    t0 = time.perf_counter()
    rep = _adapt([str(files["scan"]), "--landmarks", str(files["landmarks"]), "--out", str(out), "--units", "mm",
                  "--levels", "2", "--texture-size", str(texture_size)], device)
    wall = time.perf_counter() - t0
    tex = np.asarray(Image.open(out / "texture.png").convert("RGB"))
    a = fw.load_mesh(out / "adapted_scan_frame.obj", units="mm")

    def to_template(X):
        return (np.asarray(X) - scan.translation) @ scan.rotation

    res = fw.render.likeness_views(to_template(a.vertices), t.faces, tex, t.uv[t.face_uv], t.frontal,
                                   to_template(scan.vertices), scan.faces, scan_colors=scan.colors, size=render_size,
                                   device=device)
    if picture:
        (RESULTS / "likeness").mkdir(parents=True, exist_ok=True)
        rows = [np.concatenate(v, axis=1) for v in res["images"].values()]
        img = Image.fromarray(np.concatenate(rows, axis=0))
        img.thumbnail((900, 900))
        img.save(RESULTS / "likeness" / f"seed{seed}.png", optimize=True)
    # scale: an arbitrary unit, no landmarks, no --units
    f = float(np.random.default_rng([seed, 5]).uniform(0.002, 0.05))
    any_files = _write_scan(scan, work / f"any{seed}", f, landmarks=False)
    t1 = time.perf_counter()
    rep_any = _adapt([str(any_files["scan"]), "--out", str(work / f"adapt_any{seed}"), "--levels", "1",
                      "--texture-size", "256"], device)
    wall_any = time.perf_counter() - t1
    given = {}
    for unit, m in (("mm", 1e-3), ("cm", 1e-2), ("m", 1.0)):
        est = fw.adaptation.estimate_scale({k: np.asarray(v) / m for k, v in scan.landmarks.items()})
        given[unit] = est.metres_per_unit / m - 1.0
    return {
        "seed": seed,
        "adapt_wall_s": round(wall, 2),
        "texture": rep["texture"],
        "likeness": res["views"],
        "mean": res["mean"],
        "flat_color": res["flat_color"],
        "scale": {"true_metres_per_unit": f, "auto_metres_per_unit": rep_any["scale"]["metres_per_unit"],
                  "auto_relative_error": rep_any["scale"]["metres_per_unit"] / f - 1.0,
                  "auto_units": rep_any["scale"]["units"], "auto_wall_s": round(wall_any, 2),
                  "from_given_fdps_relative_error": given},
    }


def _textured_glb(scan: Path, image: Path, out: Path, *, flip_v: bool) -> Path:
    """The scan's mesh with its UVs and ``image`` as one textured GLB (colour maps shipped beside the mesh).

    ``flip_v``: the map is addressed with v measured the other way (three.js's ``TextureLoader``
    flips images by default, and maps made for it, like the LeePerrySmith head's, expect that),
    so the image is flipped top to bottom before it goes into the GLB.
    """
    import trimesh
    from PIL import Image

    m = trimesh.load(str(scan), process=False, force="mesh")
    uv = getattr(m.visual, "uv", None)
    if uv is None or len(uv) != len(m.vertices):
        raise SystemExit(f"--scan {scan}: no per-vertex UVs to put --scan-texture on")
    img = Image.open(image).convert("RGB")
    if flip_v:
        img = img.transpose(Image.Transpose.FLIP_TOP_BOTTOM)
    tex = trimesh.Trimesh(m.vertices, m.faces, process=False,
                          visual=trimesh.visual.TextureVisuals(uv=uv, image=img))
    out.parent.mkdir(parents=True, exist_ok=True)
    tex.export(str(out))
    return out


def run_scan(args, work: Path) -> dict:
    """A real textured scan: detected FDPs, ``--units auto``, the texture baked, head vs scan rendered."""
    import facewarp as fw
    from PIL import Image

    scan_path = Path(args.scan)
    if args.scan_texture:
        scan_path = _textured_glb(scan_path, Path(args.scan_texture), work / "scan" / "scan_textured.glb",
                                  flip_v=args.scan_texture_flip_v)
    scan = fw.load_mesh(scan_path)  # file units (auto below); the similarity fit takes them to the template frame
    if scan.texture is None and scan.colors is None:
        raise SystemExit(f"--scan {args.scan}: no colour (give --scan-texture)")
    out = work / "adapt"
    t0 = time.perf_counter()
    rep = _adapt([str(scan_path), "--out", str(out), "--units", "auto", "--levels", str(args.levels),
                  "--texture-size", str(args.texture_size)], args.device)
    wall = time.perf_counter() - t0
    tex = np.asarray(Image.open(out / "texture.png").convert("RGB"))
    head = fw.load_mesh(out / "adapted.obj")  # template frame [m]
    head_scan = fw.load_mesh(out / "adapted_scan_frame.obj")  # the same vertices in the scan's frame and unit
    to_template = fw.geometry.fit_similarity(head_scan.vertices, head.vertices)
    fit_rms = float(np.sqrt(np.mean(np.sum((to_template.apply(head_scan.vertices) - head.vertices) ** 2, axis=1))))
    t = fw.default_template(0)
    look = ({"scan_colors": scan.colors} if scan.texture is None
            else {"scan_texture": scan.texture, "scan_corner_uv": scan.corner_uv})
    res = fw.render.likeness_views(head.vertices, t.faces, tex, t.uv[t.face_uv], t.frontal,
                                   to_template.apply(scan.vertices), scan.faces, **look, size=args.render_size,
                                   device=args.device)
    rows = [np.concatenate([v[1], v[0], v[2]], axis=1) for v in res["images"].values()]  # scan | head | flat
    img = Image.fromarray(np.concatenate(rows, axis=0))
    picture = RESULTS / f"{args.name}.png"
    img.save(picture, optimize=True)
    for colours in (256, 128, 64):  # keep the repository small: a palette looks the same at this size
        if picture.stat().st_size <= 300_000:  # tests/test_benchmarks_suite.py: pictures < 300 KB
            break
        img.quantize(colours, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(picture, optimize=True)
    m = res["mean"]
    return {
        "scan": {"file": Path(args.scan).name,
                 "texture_file": Path(args.scan_texture).name if args.scan_texture else None,
                 "texture_flipped_v": bool(args.scan_texture and args.scan_texture_flip_v),
                 "source": args.scan_source, "licence": args.scan_licence, "attribution": args.scan_attribution,
                 "vertex_count": int(len(scan.vertices)), "face_count": int(len(scan.faces)),
                 "texture_px": list(scan.texture.shape[:2]) if scan.texture is not None else None},
        "adapt_wall_s": round(wall, 2),
        "scale": rep["scale"],
        "calibration_rms_residual_m": rep["calibration"]["rms_residual"],
        "distance_to_scan_m": rep["distance_to_scan_m"],
        "scan_to_template_fit_rms_m": fit_rms,
        "texture": rep["texture"],
        "likeness": res["views"],
        "mean": res["mean"],
        "flat_color": res["flat_color"],
        "summary": {"delta_e_mean": m["delta_e_mean"]["textured"], "delta_e_flat": m["delta_e_mean"]["flat"],
                    "delta_e_flat_face_mean": m["delta_e_mean"]["flat_face_mean"],
                    "lightness_correlation": m["lightness_correlation"]["textured"],
                    "lightness_correlation_flat": m["lightness_correlation"]["flat"],
                    "targets": {"delta_e_below": 4.0, "lightness_correlation_at_least": 0.6}},
        "picture": {"file": picture.name, "layout": "columns scan | adapted head (baked texture) | flat colour; "
                    "rows " + ", ".join(res["images"]), "px_per_image": args.render_size},
    }


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.likeness", description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="synthetic scans 0..N-1 (default 3)")
    ap.add_argument("--texture-size", type=int, default=2048)
    ap.add_argument("--render-size", type=int, default=None, help="image side [px] (default 400, with --scan 512)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--scale-seeds", type=int, default=20, help="faces for the scale from given FDPs (default 20)")
    ap.add_argument("--name", default=None, help="result file name (default likeness, with --scan likeness_real)")
    ap.add_argument("--scan", default=None, metavar="PATH", help="a real scan instead of the synthetic ones")
    ap.add_argument("--scan-texture", default=None, metavar="IMG", help="the scan's colour map, when not in its file")
    ap.add_argument("--scan-texture-flip-v", action="store_true",
                    help="the colour map expects v flipped (maps for three.js's TextureLoader, e.g. LeePerrySmith)")
    ap.add_argument("--scan-source", default="", help="where the scan comes from (recorded)")
    ap.add_argument("--scan-licence", default="", help="its licence (recorded)")
    ap.add_argument("--scan-attribution", default="", help="its attribution (recorded)")
    ap.add_argument("--levels", type=int, default=2, help="adaptation levels with --scan (default 2)")
    ap.add_argument("--observed", default="", help="what the side-by-side picture shows to a person (recorded)")
    args = ap.parse_args(argv)
    if args.scan is not None:
        args.name = args.name or "likeness_real"
        args.render_size = args.render_size or 512
        with tempfile.TemporaryDirectory() as tmp:
            r = run_scan(args, Path(tmp))
        r["observed"] = args.observed
        s = r["summary"]
        print(f"{Path(args.scan).name}: Delta E {s['delta_e_mean']:.2f} (flat {s['delta_e_flat']:.2f}, the face's mean "
              f"colour {s['delta_e_flat_face_mean']:.2f}), L* r "
              f"{s['lightness_correlation']:.3f}; texels from the scan {r['texture']['covered_fraction'] * 100:.1f} %")
        result = {"benchmark": "likeness", "machine": machine(args.device), "settings": vars(args), **r}
        path = save(args.name, result)
        print(f"wrote {path}")
        return result
    args.name, args.render_size = args.name or "likeness", args.render_size or 400
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            r = run_seed(seed, Path(tmp), texture_size=args.texture_size, render_size=args.render_size,
                         device=args.device, picture=seed == 0)
            cases.append(r)
            m = r["mean"]
            print(f"seed {seed}: Delta E {m['delta_e_mean']['textured']:.2f} (flat {m['delta_e_mean']['flat']:.2f}), "
                  f"L* r {m['lightness_correlation']['textured']:.3f}; texels from the scan "
                  f"{r['texture']['covered_fraction'] * 100:.1f} %; scale auto error "
                  f"{r['scale']['auto_relative_error'] * 100:+.1f} %", flush=True)
    # the scale from the given FDPs over many faces (cheap: no adaptation)
    import facewarp as fw

    given = []
    for seed in range(args.scale_seeds):
        sc = fw.synthetic_scan(seed)
        given.append(fw.adaptation.estimate_scale(sc.landmarks).metres_per_unit - 1.0)
    given = np.array(given)
    summary = {
        "delta_e_mean": float(np.mean([c["mean"]["delta_e_mean"]["textured"] for c in cases])),
        "delta_e_flat": float(np.mean([c["mean"]["delta_e_mean"]["flat"] for c in cases])),
        "lightness_correlation": float(np.mean([c["mean"]["lightness_correlation"]["textured"] for c in cases])),
        "worst_delta_e": float(max(c["mean"]["delta_e_mean"]["textured"] for c in cases)),
        "worst_lightness_correlation": float(min(c["mean"]["lightness_correlation"]["textured"] for c in cases)),
        "scale_auto_worst_relative_error": float(max(abs(c["scale"]["auto_relative_error"]) for c in cases)),
        "scale_given_fdps": {"seeds": args.scale_seeds, "mean_abs_relative_error": float(np.abs(given).mean()),
                             "worst_abs_relative_error": float(np.abs(given).max()),
                             "within_5_percent": int((np.abs(given) <= 0.05).sum()),
                             "relative_errors": given.round(4).tolist()},
        "targets": {"delta_e_below": 4.0, "lightness_correlation_at_least": 0.6, "scale_within": 0.05},
    }
    result = {"benchmark": "likeness", "machine": machine(args.device), "settings": vars(args),
              "summary": summary, "cases": cases}
    path = save(args.name, result)
    print(json.dumps(summary, indent=1))
    print(f"wrote {path}")
    return result


if __name__ == "__main__":
    main()
