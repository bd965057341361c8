"""Small line charts drawn with Pillow (no matplotlib): error curves over adaptation levels."""

from __future__ import annotations

import numpy as np

from .render import save_png

__all__ = ["line_chart"]

_COLORS = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14)]


def line_chart(path, x, series: dict, *, title: str = "", xlabel: str = "", ylabel: str = "",
               log_y: bool = False, width: int = 720, height: int = 440, xticks=None) -> str:
    """Plot ``series`` (name -> (k,) values) over ``x`` (k,) and save a PNG atomically; ``xticks``:
    the x values to mark (default: every x)."""
    from PIL import Image, ImageDraw, ImageFont

    x = np.asarray(x, dtype=np.float64)
    img = Image.new("RGB", (width, height), (255, 255, 255))
    d = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    L, R, T, B = 80, 20, 30, 50
    vals = [np.asarray(v, dtype=np.float64) for v in series.values()]
    allv = np.concatenate([v[np.isfinite(v)] for v in vals]) if vals else np.array([0.0, 1.0])
    if log_y:
        allv = allv[allv > 0]
    lo, hi = (allv.min(), allv.max()) if len(allv) else (0.0, 1.0)
    if log_y and len(allv):
        lo, hi = np.log10(lo), np.log10(hi)
    if hi - lo < 1e-12:
        lo, hi = lo - 0.5, hi + 0.5
    xlo, xhi = (x.min(), x.max()) if len(x) > 1 else (x.min() - 0.5 if len(x) else 0.0, x.max() + 0.5 if len(x) else 1.0)

    def px(xv, yv):
        yv = np.log10(yv) if log_y else yv
        return (L + (xv - xlo) / (xhi - xlo) * (width - L - R), height - B - (yv - lo) / (hi - lo) * (height - T - B))

    d.rectangle([L, T, width - R, height - B], outline=(0, 0, 0))
    for k in range(5):
        yv = lo + (hi - lo) * k / 4
        yy = height - B - (yv - lo) / (hi - lo) * (height - T - B)
        d.line([L - 4, yy, L, yy], fill=(0, 0, 0))
        d.text((4, yy - 6), f"{(10 ** yv if log_y else yv):.3g}", fill=(0, 0, 0), font=font)
    for xv in (x if xticks is None else np.asarray(xticks, dtype=np.float64)):
        xx = px(xv, 10**lo if log_y else lo)[0]
        d.line([xx, height - B, xx, height - B + 4], fill=(0, 0, 0))
        d.text((xx - 4, height - B + 6), f"{xv:g}", fill=(0, 0, 0), font=font)
    d.text((width / 2 - 40, height - 18), xlabel, fill=(0, 0, 0), font=font)
    d.text((4, 8), ylabel, fill=(0, 0, 0), font=font)
    for i, (name, v) in enumerate(series.items()):
        c = _COLORS[i % len(_COLORS)]
        v = np.asarray(v, dtype=np.float64)
        ok = np.isfinite(v) & ((v > 0) if log_y else True)
        pts = [px(a, b) for a, b in zip(x[ok], v[ok])]
        if len(pts) > 1:
            d.line(pts, fill=c, width=2)
        for p in pts:
            d.ellipse([p[0] - 3, p[1] - 3, p[0] + 3, p[1] + 3], fill=c)
        d.text((width - R - 150, T + 8 + 14 * i), f"- {name}", fill=c, font=font)
    return save_png(path, np.asarray(img), title=title or None)
