"""The presets on the default head: a picture of each at its peak, and the table of measured
amplitudes beside the real (human) ranges for the README.

    python -m benchmarks.preset_strip [--level 0] [--seconds 1.0] [--device cpu] [--table-only] [--readme]

Picture: builds the default head, plays every preset (ramped in over 0.3 s and held, the default
simulator: implicit solver, physical material, kinematic jaw) and renders the whole head at the end
of the run, front view, beside the head at rest -> ``benchmarks/results/preset_strip.png``.

Table: reads ``benchmarks/results/expression_targets_L<level>.json`` (written by
``python -m benchmarks.expression_targets``; re-run that first after changing muscles or presets)
and writes the markdown table ``benchmarks/results/preset_strip.md`` (and prints it). With
``--readme`` it also replaces the table in README.md between the markers
``<!-- preset-table:begin -->`` and ``<!-- preset-table:end -->``. ``--table-only`` skips the
simulation and the picture.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from benchmarks._common import RESULTS

README = Path(__file__).resolve().parents[1] / "README.md"
BEGIN, END = "<!-- preset-table:begin -->", "<!-- preset-table:end -->"
COLUMNS = 4
"""Heads per row of the picture."""


# ------------------------------------------------------------------------------------- picture
def render_strip(level: int, seconds: float, device: str, face_height: int) -> Path:
    import facewarp as fw
    from facewarp.render import FaceView, label_grid, save_png

    rig = fw.build_face(fw.default_template(level))
    names = [n for n in fw.PRESETS if n != "neutral"]
    shots = []
    for name in names:
        sim = fw.FaceSimulator(rig, device=device, fps=30)
        frames = sim.run(fw.Timeline([fw.Segment(fw.preset(name), 0.0, 0.3, 60.0, 0.1)]).for_head(rig), seconds)
        if not np.isfinite(frames.points).all():
            raise SystemExit(f"{name}: NaN in the frames")
        shots.append((name, frames.points[-1], {k: V[-1] for k, (V, _) in frames.parts.items()}))
        moved = np.linalg.norm(frames.points[-1] - frames.points[0], axis=1).max()
        print(f"{name:9s} largest vertex displacement {moved * 1e3:5.1f} mm", flush=True)
    rest = frames.points[0]
    lm = {str(k): frames.fdp_points[0, i] for i, k in enumerate(frames.fdp_ids)}
    parts = {k: (V[0], F) for k, (V, F) in frames.parts.items()}
    view = FaceView(rest, frames.faces, lm, parts, view="front", face_height=face_height,
                    bounds=[rest] + [P for _, P, _ in shots], device=device)
    images = [view.render(rest)] + [view.render(P, part_points=pp) for _, P, pp in shots]
    labels = ["rest"] + names
    rows = [images[i:i + COLUMNS] for i in range(0, len(images), COLUMNS)]
    grid = label_grid(rows, column_labels=None, row_labels=None, gap=8)
    grid = _captions(grid, labels, images[0].shape[:2], gap=8)
    path = RESULTS / "preset_strip.png"
    save_png(path, grid, title=f"default head (level {level}): each preset after {seconds:g} s")
    return path


def _captions(grid: np.ndarray, labels: list, tile: tuple, gap: int) -> np.ndarray:
    """Each tile's label written into its top-left corner."""
    from PIL import Image, ImageDraw, ImageFont

    h, w = tile
    img = Image.fromarray(grid)
    draw = ImageDraw.Draw(img)
    try:
        font = ImageFont.load_default(size=max(14, w // 11))
    except TypeError:  # Pillow < 10.1
        font = ImageFont.load_default()
    for i, text in enumerate(labels):
        r, c = divmod(i, COLUMNS)
        draw.text((c * (w + gap) + 6, r * (h + gap) + 4), text, fill=(0, 0, 0), font=font)
    return np.asarray(img)


# --------------------------------------------------------------------------------------- table
def _norm(v) -> float:
    return float(np.linalg.norm(v))


def _pair(a: float, b: float, fmt: str = "{:.1f}") -> str:
    return f"{fmt.format(a)} / {fmt.format(b)}"


def _rows(p: dict) -> list[tuple[str, str, str, bool | None]]:
    """(preset, measured, real range / target, met) per preset of the expression_targets results."""
    out = []

    def d(name, k):
        return np.asarray(p[name]["displacement_mm"][k], dtype=np.float64)

    def dist(name, k):
        return p[name]["distance_mm"][k]

    def corners(name):
        a, b = d(name, "8.3"), d(name, "8.4")
        return a, b, (f"lip corners 8.3 / 8.4 {_pair(_norm(a), _norm(b))} mm (up {_pair(a[1], b[1])}, "
                      f"back {_pair(-a[2], -b[2])}, out {_pair(a[0], -b[0])})")

    def smiling(v, outward):
        return _norm(v) >= 8 and v[1] > 4 and v[2] < -2 and outward * v[0] > 2

    if "smile" in p:
        a, b, text = corners("smile")
        c1, c2 = d("smile", "5.1"), d("smile", "5.2")
        out.append(("smile", f"{text}; cheeks 5.1 / 5.2 up {_pair(c1[1], c2[1])} mm",
                    "lip corners 8-16 mm, up, back and outward; cheeks up (human rig, ICT mouthSmile at full "
                    "weight: 15.6 mm)", smiling(a, 1) and smiling(b, -1) and c1[1] > 2 and c2[1] > 2))
    if "laugh" in p:
        a, b, _ = corners("laugh")
        chin = d("laugh", "2.1")
        gap = dist("laugh", "lip_gap")
        out.append(("laugh", f"chin 2.1 down {-chin[1]:.1f} mm ({_norm(chin):.1f} mm along its arc); lip corners "
                             f"{_pair(_norm(a), _norm(b))} mm; lips apart {gap[1]:.1f} mm (rest {gap[0]:.1f})",
                    "chin down 10-25 mm (a laugh; the widest human opening is about 50 mm); lip corners >= 8 mm "
                    "as in smile; lips apart", 10 <= -chin[1] <= 25 and smiling(a, 1) and smiling(b, -1)
                    and gap[1] > gap[0] + 3))
    if "surprise" in p:
        ups = [d("surprise", k)[1] for k in ("4.1", "4.2", "4.3", "4.4", "4.5", "4.6")]
        chin = d("surprise", "2.1")
        out.append(("surprise", f"brows 4.1-4.6 up {min(ups):.1f}-{max(ups):.1f} mm; chin down {-chin[1]:.1f} mm",
                    "brows up 4-12 mm; jaw opens 5-15 mm", all(4 <= u <= 12 for u in ups) and 5 <= -chin[1] <= 15))
    if "sad" in p:
        b1, b2 = d("sad", "4.1"), d("sad", "4.2")
        a, b = d("sad", "8.3"), d("sad", "8.4")
        out.append(("sad", f"inner brows 4.1 / 4.2 up {_pair(b1[1], b2[1])} mm; lip corners down "
                           f"{_pair(-a[1], -b[1])} mm", "inner brows up >= 2 mm; lip corners down >= 2 mm",
                    b1[1] >= 2 and b2[1] >= 2 and -a[1] >= 2 and -b[1] >= 2))
    if "angry" in p:
        b1, b2 = d("angry", "4.1"), d("angry", "4.2")
        out.append(("angry", f"inner brows 4.1 / 4.2 toward the midline {_pair(-b1[0], b2[0])} mm, down "
                             f"{_pair(-b1[1], -b2[1])} mm ({_pair(_norm(b1), _norm(b2))} mm in all)",
                    "inner brows toward the midline and down, >= 1 mm each way (>= 1.5 mm in all)",
                    -b1[0] >= 1 and b2[0] >= 1 and -b1[1] >= 1 and -b2[1] >= 1 and min(_norm(b1), _norm(b2)) >= 1.5))
    for name, target in (("blink", "lid fissures 3.1-3.3 and 3.2-3.4 closed (within 1 mm)"),
                         ("squint", "lid fissures narrower than at rest (no number in the issue)")):
        if name in p:
            fl, fr = dist(name, "fissure_L"), dist(name, "fissure_R")
            met = max(fl[1], fr[1]) <= 1 if name == "blink" else (fl[1] < fl[0] and fr[1] < fr[0])
            out.append((name, f"lid fissures L / R {_pair(fl[1], fr[1])} mm (rest {fl[0]:.1f})", target, met))
    if "pucker" in p:
        w = dist("pucker", "mouth_width")
        out.append(("pucker", f"mouth width 8.3-8.4 {w[1]:.1f} mm (rest {w[0]:.1f})",
                    "mouth narrower than at rest (no number in the issue)", w[1] < w[0]))
    if "jaw_open" in p:
        chin = d("jaw_open", "2.1")
        gap = dist("jaw_open", "lip_gap")
        drop = p["jaw_open"].get("jaw_drop_mm")
        out.append(("jaw_open", f"chin 2.1 down {-chin[1]:.1f} mm ({_norm(chin):.1f} mm along its arc); lips apart "
                                f"{gap[1]:.1f} mm", f"the preset's chin drop {drop:g} mm" if drop else "-", None))
    for name, this, other, outward in (("smile_L", "8.3", "8.4", 1), ("smile_R", "8.4", "8.3", -1)):
        if name in p:
            a, b = d(name, this), d(name, other)
            out.append((name, f"lip corner {this} {_norm(a):.1f} mm (up {a[1]:.1f}); the other ({other}) "
                              f"{_norm(b):.1f} mm",
                        "one corner as in smile (>= 8 mm, up, back, out), the other still (< 1 mm)",
                        smiling(a, outward) and _norm(b) < 1))
    if "zygomatic_major=1" in p:
        a, b = d("zygomatic_major=1", "8.3"), d("zygomatic_major=1", "8.4")
        out.append(("zygomatic major at 1.0", f"lip corners 8.3 / 8.4 {_pair(_norm(a), _norm(b))} mm",
                    "human rig: ICT mouthSmile at full weight 15.6 mm, within 25 % (11.7-19.5 mm)",
                    all(11.7 <= _norm(v) <= 19.5 for v in (a, b))))
    if "frontalis_inner=1" in p:
        a, b = d("frontalis_inner=1", "4.1"), d("frontalis_inner=1", "4.2")
        out.append(("inner frontalis at 1.0", f"inner brows 4.1 / 4.2 up {_pair(a[1], b[1])} mm",
                    "human rig: ICT browInnerUp at full weight 4.5 mm up, within 25 % (3.4-5.6 mm)",
                    all(3.375 <= v[1] <= 5.625 for v in (a, b))))
    return out


def table(level: int) -> str:
    src = RESULTS / f"expression_targets_L{level}.json"
    data = json.loads(src.read_text())
    p = data["presets"]
    lines = [f"Measured on the default head (level {level}), {data['solver']} solver, {data['material']} material, "
             f"{data['jaw']} jaw, each preset ramped in over 0.3 s and held, at {data['seconds']:g} s "
             f"(`benchmarks/results/{src.name}`, {data['machine']['date'][:16].replace('T', ' ')} UTC).",
             "", "| preset | measured (FDP displacement) | real range / target | met |", "|---|---|---|---|"]
    for name, measured, target, met in _rows(p):
        mark = "-" if met is None else ("yes" if met else "**no**")
        lines.append(f"| {name} | {measured} | {target} | {mark} |")
    bad = [n for n, r in p.items() if r.get("inverted_tets") or r.get("nan")]
    lines += ["", f"Inverted tets or NaN at the end: {', '.join(bad) if bad else 'none'} "
                  f"({len(p)} runs)."]
    return "\n".join(lines) + "\n"


def write_readme(md: str) -> None:
    text = README.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"README.md: no {BEGIN} ... {END} markers")
    a, b = text.index(BEGIN) + len(BEGIN), text.index(END)
    README.write_text(text[:a] + "\n" + md + text[b:])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--level", type=int, default=0)
    ap.add_argument("--seconds", type=float, default=1.0, help="length of each run [s] (the picture)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--face-height", type=int, default=240, help="face height in the picture [px]")
    ap.add_argument("--table-only", action="store_true", help="only the table (no simulation, no picture)")
    ap.add_argument("--readme", action="store_true", help="also replace the table in README.md")
    args = ap.parse_args(argv)
    if not args.table_only:
        print(f"wrote {render_strip(args.level, args.seconds, args.device, args.face_height)}")
    md = table(args.level)
    (RESULTS / "preset_strip.md").write_text(md)
    print(md)
    if args.readme:
        write_readme(md)
        print(f"updated {README}")


if __name__ == "__main__":
    raise SystemExit(main())
