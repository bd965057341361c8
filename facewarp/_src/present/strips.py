"""Frame strips and expression sheets: renders of the whole head at chosen frames, over rows of
displacement heat maps.

:func:`expression_sheet` is the picture of ``facewarp simulate`` (``frames.png``) and of the demo
(``expressions.png``): per expression a pair rest | peak, in a front row and a three-quarter row,
over a heat-map row of the peak's displacement from rest (front | three-quarter); the face
(hairline to chin) at least :data:`~facewarp.render.FACE_HEIGHT` pixels high; the pairs wrap into
rows of ``columns`` expressions. :func:`render_strip` is the older strip of a few frames side by side.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from .animation import FACE_HEIGHT, FaceView

__all__ = ["displacement_max", "expression_sheet", "frames_sheet", "render_strip", "sheet_font_size"]

SHEET_VIEWS = ("front", "three_quarter")
"""The two views of an expression sheet (rows), each a view of :func:`~facewarp.render_mesh`."""

_ROW_LABELS = ("front", "3/4", "moved")
_WHITE = (255, 255, 255)


def _landmarks(frames, k: int = 0) -> dict:
    return {str(fid): frames.fdp_points[k, i] for i, fid in enumerate(frames.fdp_ids)}


def _ceil_mm(d: float) -> float:
    return max(1e-3, float(np.ceil(d * 1e3 - 1e-9)) * 1e-3)


def render_strip(frames, idx, *, size: int | None = None, device: str = "cpu", view="front",
                 heat_max: float | None = None) -> np.ndarray:
    """Renders of the whole head at frames ``idx`` of ``frames`` (a :class:`~facewarp.Frames`),
    side by side, with eyes (iris and pupil), teeth and tongue, lips tinted; one fixed camera that
    frames the head in all of them, ``size`` pixels high (default: the face, hairline to chin,
    :data:`~facewarp.render.FACE_HEIGHT` pixels).

    With ``heat_max`` [m], a second row shows each frame's displacement from frame 0 as a
    heat map from 0 to ``heat_max`` (turbo), which makes a few millimetres of motion visible.

    Returns:
        RGB image, uint8.
    """
    idx = [int(k) for k in idx]
    if not idx:
        raise InputError("idx: expected at least one frame index")
    P0 = frames.points[0]
    parts0 = {name: (V[0], Fp) for name, (V, Fp) in frames.parts.items()}
    fv = FaceView(P0, frames.faces, _landmarks(frames), parts0, view=view, size=None if size is None else int(size),
                  bounds=[frames.points[k] for k in idx], device=device)

    def parts_at(k):
        return {name: V[k] for name, (V, _) in frames.parts.items()}

    img = np.concatenate([fv.render(frames.points[k], part_points=parts_at(k)) for k in idx], axis=1)
    if heat_max is None:
        return img
    top = max(float(heat_max), 1e-9)
    heat = [fv.render(frames.points[k], part_points=parts_at(k), heat=np.linalg.norm(frames.points[k] - P0, axis=1),
                      heat_max=top) for k in idx]
    return np.concatenate([img, np.concatenate(heat, axis=1)], axis=0)


def displacement_max(frames, idx) -> float:
    """Largest displacement [m] of a head vertex from frame 0 over frames ``idx`` (the heat
    map's top, rounded up to a whole millimetre)."""
    d = max(float(np.linalg.norm(frames.points[k] - frames.points[0], axis=1).max()) for k in idx)
    return _ceil_mm(d)


def sheet_font_size(sheet) -> int:
    """Text height [px] for the title and colour bar of a sheet (:func:`~facewarp.save_png`'s
    ``font_size``): readable when the sheet is shown a screen wide."""
    return int(min(56, max(16, np.asarray(sheet).shape[1] // 40)))


def _views(rest, faces, landmarks, parts, sets, face_height: int, device, texture=None) -> list[FaceView]:
    """One FaceView per sheet view, all of one image size, each face >= ``face_height`` px."""
    probe = [FaceView(rest, faces, landmarks, parts, view=v, bounds=sets, face_height=face_height, device=device)
             for v in SHEET_VIEWS]
    aspect = max(p.width / p.size for p in probe)
    sized = [FaceView(rest, faces, landmarks, parts, view=v, bounds=sets, face_height=face_height, aspect=aspect,
                      device=device) for v in SHEET_VIEWS]
    size = max(p.size for p in sized)
    return [FaceView(rest, faces, landmarks, parts, view=v, bounds=sets, size=size, aspect=aspect, device=device,
                     texture=texture) for v in SHEET_VIEWS]


def expression_sheet(rest, faces, landmarks: dict, parts: dict, shots, *, face_height: int = FACE_HEIGHT,
                     columns: int = 3, heat_max: float | None = None, device: str = "cpu",
                     texture=None) -> tuple[np.ndarray, float]:
    """Per expression a pair rest | peak of the whole head, front and three-quarter rows over a
    heat-map row (see the module docstring).

    Args:
        rest: Head vertices at rest [m], shape (n, 3), float.
        faces: Head triangles, shape (m, 3), int.
        landmarks: FDP id -> rest position [m] (those :class:`~facewarp.render.FaceView` uses).
        parts: Rigid parts at rest, name -> (V (k, 3) [m], F (l, 3) int).
        shots: One entry per expression, ``(label, points, part_points)`` or ``(label, points,
            part_points, caption)``: its name, the head vertices at its peak [m] (n, 3), its parts'
            vertices (name -> (k, 3) [m]) or None (parts at rest), and the caption of the peak
            column (default ``"peak"``, e.g. ``"peak, 1.20 s"``).
        face_height: Least height [px] of the face (hairline 11.1 to chin 2.1) in every render.
        columns: Expressions per row of the sheet (>= 1); more wrap into further rows.
        heat_max: Top of the heat colour map [m]; default the largest displacement of any shot,
            rounded up to a whole millimetre.
        device: Warp device to render on.
        texture: Optional skin texture ``(image, corner_uv)`` for the rest and peak renders
            (:class:`~facewarp.render.FaceView`).

    Returns:
        The sheet, RGB (H, W, 3) uint8, and the heat map's top [m].
    """
    shots = list(shots)
    if not shots:
        raise InputError("shots: expected at least one (label, points, part_points)")
    if not (isinstance(columns, (int, np.integer)) and columns >= 1):
        raise InputError(f"columns: expected a whole number >= 1, got {columns!r}")
    rest = np.asarray(rest, dtype=np.float64)
    peaks = []
    for i, shot in enumerate(shots):
        try:
            label, P, part_points, *caption = shot
        except (TypeError, ValueError):
            raise InputError(f"shots[{i}]: expected (label, points, part_points[, caption])") from None
        if len(caption) > 1:
            raise InputError(f"shots[{i}]: expected (label, points, part_points[, caption])")
        P = np.asarray(P, dtype=np.float64)
        if P.shape != rest.shape:
            raise InputError(f"shots[{i}] points: expected shape {rest.shape}, got {P.shape}")
        peaks.append((str(label), P, part_points, str(caption[0]) if caption else "peak"))
    disp = [np.linalg.norm(P - rest, axis=1) for _, P, _, _ in peaks]
    top = _ceil_mm(max(float(d.max()) for d in disp)) if heat_max is None else float(heat_max)
    if not (np.isfinite(top) and top > 0):
        raise InputError(f"heat_max: expected a positive distance [m], got {heat_max!r}")
    views = _views(rest, faces, landmarks, parts, [rest] + [P for _, P, _, _ in peaks], face_height, device, texture)
    rest_tiles = [v.render(rest) for v in views]
    blocks = []
    for (label, P, pp, caption), d in zip(peaks, disp):
        tiles = [[rest_tiles[r], v.render(P, part_points=pp)] for r, v in enumerate(views)]
        tiles.append([v.render(P, part_points=pp, heat=d, heat_max=top) for v in views])
        blocks.append((label, caption, tiles))
    return _compose(blocks, columns), top


def _compose(blocks: list, columns: int) -> np.ndarray:
    """Lay out the blocks ``(label, caption, [[rest, peak] per row])`` of one tile size in rows of
    ``columns``: the label over each pair, "rest" and the caption over its columns, the row
    labels at the left."""
    from PIL import Image, ImageDraw

    from .render import _font

    h, w = blocks[0][2][0][0].shape[:2]
    gap, block_gap = 6, 36
    t_title, t_sub = max(16, w // 7), max(13, w // 10)
    f_title, f_sub = _font(t_title), _font(t_sub)
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    left = max(int(probe.textlength(t, font=f_sub)) for t in _ROW_LABELS) + 3 * gap
    head = gap + t_title + gap + t_sub + gap
    block_w = 2 * w + gap
    n_cols = min(columns, len(blocks))
    n_rows = -(-len(blocks) // n_cols)
    band_h = head + 3 * h + 2 * gap
    canvas = Image.new("RGB", (left + n_cols * block_w + (n_cols - 1) * block_gap,
                               n_rows * band_h + (n_rows - 1) * block_gap), _WHITE)
    draw = ImageDraw.Draw(canvas)

    def centred(x, y, text, font):
        draw.text((round(x - draw.textlength(text, font=font) / 2), y), text, fill=(0, 0, 0), font=font)

    for b, (label, caption, tiles) in enumerate(blocks):
        row, col = divmod(b, n_cols)
        x0, y0 = left + col * (block_w + block_gap), row * (band_h + block_gap)
        centred(x0 + block_w / 2, y0 + gap, label, f_title)
        for j, sub in enumerate(("rest", caption)):
            centred(x0 + j * (w + gap) + w / 2, y0 + 2 * gap + t_title, sub, f_sub)
        for r, pair in enumerate(tiles):
            y = y0 + head + r * (h + gap)
            for j, im in enumerate(pair):
                canvas.paste(Image.fromarray(np.asarray(im, dtype=np.uint8), mode="RGB"), (x0 + j * (w + gap), y))
            if col == 0:
                draw.text((gap, y + h / 2 - t_sub / 2), _ROW_LABELS[r], fill=(0, 0, 0), font=f_sub)
    return np.asarray(canvas)


def frames_sheet(frames, picks, *, face_height: int = FACE_HEIGHT, columns: int = 3, device: str = "cpu"):
    """:func:`expression_sheet` of a :class:`~facewarp.Frames`: frame 0 is the rest, ``picks`` a
    list of (label, frame index) of the peaks (captioned with their time). Returns the sheet
    (uint8) and the heat top [m]."""
    picks = [(str(label), int(k)) for label, k in picks]
    n = len(frames.points)
    bad = [k for _, k in picks if not 0 <= k < n]
    if bad:
        raise InputError(f"picks: frame {bad[0]} outside 0..{n - 1}")
    parts0 = {name: (V[0], Fp) for name, (V, Fp) in frames.parts.items()}
    shots = [(label, frames.points[k], {name: V[k] for name, (V, _) in frames.parts.items()},
              f"peak, {float(frames.times[k]):.2f} s") for label, k in picks]
    return expression_sheet(frames.points[0], frames.faces, _landmarks(frames), parts0, shots, face_height=face_height,
                            columns=columns, device=device)
