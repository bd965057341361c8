"""Pictures of an animation: one head seen by a fixed camera, frame after frame (GIF), and labelled grids.

:class:`FaceView` renders the face of a head (cropped below the chin, behind the ears and above
the hairline, lips tinted, eyes, teeth and tongue in place) for any vertex positions of the same
topology, always from the same camera, so frames of an animation line up: the camera frames a
fixed box (by default the rest face grown by ``reach``, how far anything may move; or given
``bounds``), marked by framing points drawn in the background colour. :func:`save_gif` writes frames as an animated GIF with
Pillow; :func:`label_grid` puts renders in rows and columns under text labels.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fileio import atomic_write
from .render import colormap, render_mesh
from .template import LIPS, SKIN, TEETH, TONGUE, vermilion_weight

__all__ = ["FaceView", "label_grid", "save_gif"]

_BACKGROUND = (1.0, 1.0, 1.0)


class FaceView:
    """A fixed camera on the face of one head (see the module docstring).

    Args:
        rest_points: Head vertices at rest [m], shape (n, 3), float.
        faces: Head triangles, shape (m, 3), int.
        landmarks: FDP id -> rest position [m] (uses 2.1, 2.2, 2.3, 3.7, 8.1-8.4, 11.1).
        parts: Rigid parts at rest, name -> (V (k, 3) [m], F (l, 3) int); drawn white (eyes,
            teeth) or red (tongue).
        view: A view of :func:`~facewarp.render_mesh` (``"front"``, ``"three_quarter"``, ...).
        size: Image height [px].
        aspect: Image width over height (> 0; a face is taller than wide).
        reach: How far [m] vertices may move from rest; the framed box grows by it.
        bounds: Optional box to frame instead, (2, 3) [m] (min and max corner), e.g. the
            union of the face's boxes over an animation.
        device: Warp device to render on.
    """

    def __init__(self, rest_points, faces, landmarks: dict, parts: dict | None = None, *, view="front",
                 size: int = 320, aspect: float = 0.8, reach: float = 0.02, bounds=None, device: str = "cpu"):
        P0 = np.asarray(rest_points, dtype=np.float64)
        F = np.asarray(faces, dtype=np.int64)
        missing = [k for k in ("2.1", "2.2", "2.3", "3.7", "8.1", "8.2", "8.3", "8.4", "11.1") if k not in landmarks]
        if missing:
            raise InputError(f"landmarks: FaceView needs FDP {', '.join(missing)}")
        lm = {k: np.asarray(v, dtype=np.float64) for k, v in landmarks.items()}
        c = P0[F].mean(1)
        keep = (c[:, 1] > lm["2.1"][1] - 0.03) & (c[:, 2] > lm["3.7"][2] - 0.06) & (c[:, 1] < lm["11.1"][1] + 0.02)
        self.faces = F[keep]
        front = P0[:, 2] > 0.5 * (lm["2.2"][2] + lm["2.3"][2]) - 0.02
        w = vermilion_weight(P0, lm, front)[:, None]
        self.colors = SKIN * (1 - w) + LIPS * w
        self.parts = {k: (np.asarray(V, np.float64), np.asarray(Fp, np.int64)) for k, (V, Fp) in (parts or {}).items()}
        if bounds is None:
            used = P0[np.unique(self.faces)]
            lo, hi = used.min(0) - reach, used.max(0) + reach
        else:
            lo, hi = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
        self.frame_points = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        self.rest = P0
        self.used = np.unique(self.faces)
        if not (isinstance(aspect, (int, float)) and 0 < aspect < 10):
            raise InputError(f"aspect: expected a number in (0, 10), got {aspect!r}")
        self.view, self.size, self.device = view, int(size), device
        self.width = max(1, int(round(self.size * aspect)))

    def _part_color(self, name: str):
        return TONGUE if "tongue" in name else TEETH

    def render(self, points, part_transforms: dict | None = None, *, heat=None, heat_max: float | None = None) -> np.ndarray:
        """The face at ``points`` (n, 3) [m] as an RGB image (size, width, 3), uint8.

        Args:
            points: Head vertex positions [m], shape (n, 3).
            part_transforms: Optional part name -> 4x4 rest-to-current transform in the row-vector
                convention (``p' = p @ M``, translation in ``M[3, :3]``); parts left out stay at rest.
            heat: Optional per-vertex scalar (n,) drawn with the turbo colour map from 0 to
                ``heat_max`` instead of the skin colours (NaN grey).
            heat_max: Top of the heat colour map (> 0); default the largest ``heat``.
        """
        extra = []
        for name, (V, Fp) in self.parts.items():
            M = None if part_transforms is None else part_transforms.get(name)
            Vp = V if M is None else V @ np.asarray(M)[:3, :3] + np.asarray(M)[3, :3]
            extra.append((Vp, Fp, self._part_color(name)))
        colors = self.colors
        if heat is not None:
            h = np.asarray(heat, dtype=np.float64)
            top = float(np.nanmax(h)) if heat_max is None else float(heat_max)
            colors = colormap(h, 0.0, max(top, 1e-12))
        return render_mesh(points, self.faces, view=self.view, width=self.width, height=self.size,
                           vertex_colors=colors, extra_meshes=extra, points=self.frame_points,
                           point_color=_BACKGROUND, point_radius=1e-3, background=_BACKGROUND, margin=0.02,
                           device=self.device)


def save_gif(path, images, *, fps: float = 15.0, loop: int = 0) -> Path:
    """Write RGB frames (each (h, w, 3) uint8, all of one size) as an animated GIF, atomically.

    Args:
        path: Destination ``.gif``.
        images: Sequence of at least one frame.
        fps: Frames per second of playback (> 0; GIF stores whole hundredths of a second).
        loop: Number of loops (0: forever).
    """
    from PIL import Image

    images = list(images)
    if not images:
        raise InputError("images: expected at least one frame")
    if not (isinstance(fps, (int, float)) and np.isfinite(fps) and fps > 0):
        raise InputError(f"fps: expected a positive number, got {fps!r}")
    shape = np.asarray(images[0]).shape
    frames = []
    for i, im in enumerate(images):
        a = np.asarray(im)
        if a.shape != shape or a.ndim != 3 or a.shape[2] != 3:
            raise InputError(f"images[{i}]: expected shape {shape} (h, w, 3), got {a.shape}")
        frames.append(Image.fromarray(a.astype(np.uint8), mode="RGB").quantize(colors=255, dither=Image.Dither.NONE))
    buf = io.BytesIO()
    frames[0].save(buf, format="GIF", save_all=True, append_images=frames[1:], loop=int(loop),
                   duration=max(20, int(round(1000.0 / fps))), disposal=1)
    with atomic_write(path, "wb", encoding=None) as f:
        f.write(buf.getvalue())
    return Path(path)


def label_grid(rows, *, column_labels=None, row_labels=None, gap: int = 6) -> np.ndarray:
    """Images in a grid with optional labels above the columns and at the left of the rows.

    Args:
        rows: List of rows, each a list of RGB images (h, w, 3) uint8 of one size.
        column_labels: Optional text per column.
        row_labels: Optional text per row.
        gap: White pixels between images.

    Returns:
        The grid as an RGB image, uint8.
    """
    from PIL import Image, ImageDraw

    from .render import _font

    if not rows or not rows[0]:
        raise InputError("rows: expected at least one row with one image")
    h, w = np.asarray(rows[0][0]).shape[:2]
    n_cols = max(len(r) for r in rows)
    fsize = max(12, w // 14)
    font = _font(fsize)
    top = fsize + gap * 2 if column_labels else 0
    left = 0
    if row_labels:
        probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
        left = max(int(probe.textlength(str(t), font=font)) for t in row_labels) + 2 * gap
    W = left + n_cols * w + (n_cols - 1) * gap
    H = top + len(rows) * h + (len(rows) - 1) * gap
    canvas = Image.new("RGB", (W, H), (255, 255, 255))
    draw = ImageDraw.Draw(canvas)
    for j, text in enumerate(column_labels or []):
        x = left + j * (w + gap) + w / 2
        tw = draw.textlength(str(text), font=font)
        draw.text((x - tw / 2, gap), str(text), fill=(0, 0, 0), font=font)
    for i, row in enumerate(rows):
        y = top + i * (h + gap)
        if row_labels:
            draw.text((gap, y + h / 2 - fsize / 2), str(row_labels[i]), fill=(0, 0, 0), font=font)
        for j, im in enumerate(row):
            canvas.paste(Image.fromarray(np.asarray(im, dtype=np.uint8), mode="RGB"), (left + j * (w + gap), y))
    return np.asarray(canvas)
