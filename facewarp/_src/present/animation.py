"""Pictures of an animation: one head seen by a fixed camera, frame after frame (GIF), and labelled grids.

:class:`FaceView` renders the whole head (the template's full mesh: scalp, ears, neck down to the
template's own neck cut, lips tinted, the inside of the mouth darker, eyes with iris and pupil,
teeth with gums and tongue in place) for any vertex positions of the same topology, always from the same
camera, so frames of an animation line up: the camera frames a fixed rectangle of the image plane
(by default around the rest head; or around given point sets, e.g. every frame shown, or a box),
marked by four framing points drawn in the background colour. :func:`save_gif` writes frames as an
animated GIF with Pillow; :func:`label_grid` puts renders in rows and columns under text labels.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fileio import atomic_write
from .looks import drawn_part
from .render import colormap, render_mesh, view_axes
from .template import CAVITY, head_colors, part_colors

__all__ = ["FACE_HEIGHT", "FaceView", "label_grid", "save_gif", "skin_texture"]

_BACKGROUND = (1.0, 1.0, 1.0)
_MARGIN = 0.02  # empty border of a render, a fraction of the framed extent (render_mesh's margin)

FACE_HEIGHT = 400
"""Default height [px] of the face in a :class:`FaceView` render: hairline (FDP 11.1) to chin (2.1)."""


def _framed_points(bounds, rest: np.ndarray) -> np.ndarray:
    """The points a view frames: ``bounds`` None (the rest head), a box (2, 3) [m] (its 8 corners)
    or a sequence of point sets (k_i, 3) [m] (all of them)."""
    if bounds is None:
        return rest
    if np.shape(bounds) == (2, 3):
        lo, hi = np.asarray(bounds, dtype=np.float64)
        return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    try:
        sets = [np.asarray(P, dtype=np.float64).reshape(-1, 3) for P in bounds]
    except (TypeError, ValueError):
        raise InputError("bounds: expected a box (2, 3) [m] or a list of point arrays (k, 3) [m]") from None
    if not sets or not all(np.isfinite(P).all() for P in sets):
        raise InputError("bounds: expected finite points")
    return np.concatenate(sets)


def _rigid_map(A: np.ndarray, B: np.ndarray):
    """The rigid motion (Kabsch) taking the points A (k, 3) closest to B (k, 3) [m], as a function of (j, 3) points."""
    ca, cb = A.mean(0), B.mean(0)
    U, _, Vt = np.linalg.svd((A - ca).T @ (B - cb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return lambda X: (X - ca) @ R.T + cb


def skin_texture(fr):
    """``(image, corner_uv)`` of a face rig's skin texture, or None (no texture or no UVs)."""
    if getattr(fr, "skin_texture", None) is None or getattr(fr, "head_uv", None) is None:
        return None
    from PIL import Image

    with Image.open(fr.skin_texture) as img:
        return np.asarray(img.convert("RGB")), np.asarray(fr.head_uv)[np.asarray(fr.head_face_uv)]


class FaceView:
    """A fixed camera on the whole head of one topology (see the module docstring).

    Args:
        rest_points: Head vertices at rest [m], shape (n, 3), float.
        faces: Head triangles, shape (m, 3), int: all of them are drawn.
        landmarks: FDP id -> rest position [m] (uses 2.1, 2.2, 2.3, 8.1-8.4 and 11.1).
        parts: Rigid parts at rest, name -> (V (k, 3) [m], F (l, 3) int); coloured by
            :func:`~facewarp.render.part_colors` (eyes with iris and pupil about the gaze to the
            pupil FDPs 3.5 / 3.6, teeth with gums at their roots, tongue).
        view: A view of :func:`~facewarp.render_mesh` (``"front"``, ``"three_quarter"``, ...).
        size: Image height [px]; default: tall enough that the face (hairline 11.1 to chin 2.1)
            spans ``face_height`` pixels.
        face_height: Height [px] of the face when ``size`` is not given (default :data:`FACE_HEIGHT`).
        aspect: Image width over height (> 0); default the framed rectangle's own.
        reach: Room [m] left around the framed points on every side of the image (how far
            anything not framed may move).
        bounds: What the camera frames: None (the rest head), a box (2, 3) [m] (min and max
            corner), or a list of point sets (k_i, 3) [m], e.g. the head in every frame shown.
        supersample: Rays per pixel along each axis (:func:`~facewarp.render_mesh`; 1 for the
            frames of a GIF, four times faster).
        device: Warp device to render on.
        texture: Optional skin texture ``(image (h, w, 3) uint8, corner_uv (m, 3, 2))`` drawn instead
            of the skin colours (:func:`~facewarp.render_mesh`'s ``texture``).
        iris_color: Optional iris RGB (3,) in 0..1, linear (default brown-hazel).

    Attributes:
        size, width: Image height and width [px].
        pixels_per_metre: Scale of the render [px/m].
        face_pixels: Hairline-to-chin height of the rest face in the image [px].
    """

    def __init__(self, rest_points, faces, landmarks: dict, parts: dict | None = None, *, view="front",
                 size: int | None = None, face_height: int | None = None, aspect: float | None = None,
                 reach: float = 0.004, bounds=None, supersample: int = 2, device: str = "cpu", texture=None,
                 iris_color=None):
        P0 = np.asarray(rest_points, dtype=np.float64)
        if P0.ndim != 2 or P0.shape[1] != 3:
            raise InputError(f"rest_points: expected shape (n, 3), got {P0.shape}")
        F = np.asarray(faces, dtype=np.int64)
        missing = [k for k in ("2.1", "2.2", "2.3", "8.1", "8.2", "8.3", "8.4", "11.1") if k not in landmarks]
        if missing:
            raise InputError(f"landmarks: FaceView needs FDP {', '.join(missing)}")
        lm = {k: np.asarray(v, dtype=np.float64) for k, v in landmarks.items()}
        if not (isinstance(reach, (int, float)) and 0 <= reach < 1):
            raise InputError(f"reach: expected a distance in [0, 1) m, got {reach!r}")
        # drawn outward-facing (the inside, seen through the mouth, is a dark cavity): a head whose
        # triangles wind inward (negative enclosed volume about its centroid) is drawn flipped
        self.used = np.unique(F)
        c = P0[self.used].mean(0)
        volume = np.einsum("ij,ij->i", P0[F[:, 0]] - c, np.cross(P0[F[:, 1]] - c, P0[F[:, 2]] - c)).sum()
        self.faces = F if volume >= 0 else F[:, ::-1].copy()
        self.texture = None
        if texture is not None:
            img, cuv = texture
            cuv = np.asarray(cuv, dtype=np.float64)
            if cuv.shape != (len(F), 3, 2):
                raise InputError(f"texture: corner_uv must have shape ({len(F)}, 3, 2), got {cuv.shape}")
            self.texture = (np.asarray(img), cuv if volume >= 0 else cuv[:, ::-1].copy())
        self.rest = P0
        self.colors = head_colors(P0, lm)
        self.parts = {k: (np.asarray(V, np.float64), np.asarray(Fp, np.int64)) for k, (V, Fp) in (parts or {}).items()}
        # eyeballs are drawn refined (round iris and pupil), tooth rows split at their gum lines; parts
        # move rigidly, so a drawn mesh follows its part by the part's rigid motion
        self._drawn = {k: drawn_part(k, V, Fp) for k, (V, Fp) in self.parts.items()}
        self.part_colors = {k: part_colors(k, Vd, landmarks=lm, iris_color=iris_color, ball=self.parts[k][0],
                                           faces=Fd)
                            for k, (Vd, Fd) in self._drawn.items()}
        self.view, self.device, self.supersample = view, device, supersample
        # the framed rectangle in the image plane, and its four corners as framing points
        right, up, forward = view_axes(view)
        Q = _framed_points(bounds, P0)
        x, y, z = Q @ right, Q @ up, Q @ forward
        x0, x1, y0, y1 = x.min() - reach, x.max() + reach, y.min() - reach, y.max() + reach
        zm = 0.5 * (z.min() + z.max())
        self.frame_points = np.array([a * right + b * up + zm * forward for a in (x0, x1) for b in (y0, y1)])
        ext_x, ext_y = x1 - x0, y1 - y0
        if aspect is None:
            aspect = ext_x / ext_y
        if not (isinstance(aspect, (int, float, np.floating)) and 0 < aspect < 10):
            raise InputError(f"aspect: expected a number in (0, 10), got {aspect!r}")
        face = abs(float((lm["11.1"] - lm["2.1"]) @ up))
        if size is None:
            fh = FACE_HEIGHT if face_height is None else face_height
            if not (isinstance(fh, (int, np.integer)) and 16 <= fh <= 8192):
                raise InputError(f"face_height: expected a whole number of pixels in [16, 8192], got {fh!r}")
            # render_mesh fits the framed extent (grown by the margin) into the tighter axis
            size = int(np.ceil(fh * max(ext_y, ext_x / aspect) * (1 + 2 * _MARGIN) / max(face, 1e-6)))
        if not (isinstance(size, (int, np.integer)) and 8 <= size <= 16384):
            raise InputError(f"size: expected a whole number of pixels in [8, 16384], got {size!r}")
        self.size = int(size)
        self.width = max(1, int(round(self.size * float(aspect))))
        self.pixels_per_metre = 1.0 / (max(ext_x / self.width, ext_y / self.size) * (1 + 2 * _MARGIN))
        self.face_pixels = face * self.pixels_per_metre

    def render(self, points, part_transforms: dict | None = None, *, part_points: dict | None = None, heat=None,
               heat_max: float | None = None) -> np.ndarray:
        """The head at ``points`` (n, 3) [m] as an RGB image (size, width, 3), uint8.

        Args:
            points: Head vertex positions [m], shape (n, 3).
            part_transforms: Optional part name -> 4x4 rest-to-current transform in the row-vector
                convention (``p' = p @ M``, translation in ``M[3, :3]``).
            part_points: Optional part name -> current vertices (k, 3) [m] (instead of a transform).
                Parts in neither stay at rest.
            heat: Optional per-vertex scalar (n,) drawn on the skin with the turbo colour map from 0
                to ``heat_max`` instead of the skin colours (NaN grey); the parts keep their colours.
            heat_max: Top of the heat colour map (> 0); default the largest ``heat``.
        """
        extra = []
        for name, (V, _) in self.parts.items():
            Vd, Fd = self._drawn[name]
            M = None if part_transforms is None else part_transforms.get(name)
            P = None if part_points is None else part_points.get(name)
            if P is not None:
                P = np.asarray(P, dtype=np.float64)
                if P.shape != V.shape:
                    raise InputError(f"part_points[{name!r}]: expected shape {V.shape}, got {P.shape}")
                Vd = P if Vd is V else _rigid_map(V, P)(Vd)
            elif M is not None:
                Vd = Vd @ np.asarray(M)[:3, :3] + np.asarray(M)[3, :3]
            extra.append((Vd, Fd, self.part_colors[name]))
        colors = self.colors
        texture = self.texture
        if heat is not None:
            h = np.asarray(heat, dtype=np.float64)
            top = float(np.nanmax(h)) if heat_max is None else float(heat_max)
            colors = colormap(h, 0.0, max(top, 1e-12))
            texture = None
        return render_mesh(points, self.faces, view=self.view, width=self.width, height=self.size,
                           vertex_colors=colors, texture=texture, extra_meshes=extra, points=self.frame_points,
                           point_color=_BACKGROUND, point_radius=1e-3, background=_BACKGROUND, margin=_MARGIN,
                           inside_color=CAVITY, supersample=self.supersample, device=self.device)


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
