"""How much an adapted, textured head looks like its scan: renders from one camera, compared in CIELAB.

:func:`likeness_views` renders the head (its baked texture) and the scan (its own colour) with
the same orthographic camera (framing the head's face) and light, for each view, and compares
them over the face region (the pixels where the head shows its frontal faces and the scan shows
surface, eroded by two pixels so silhouettes and hole rims do not count). The figures compare
unlit renders (the surface colour alone, ``render_mesh(unlit=True)``), so shading the two share
does not count as likeness; the returned pictures are lit, for looking:

- **Delta E**: the mean CIE76 colour difference ``|Lab_head - Lab_scan|`` (sRGB D65 -> CIELAB,
  :func:`srgb_to_lab`); about 2.3 is a just noticeable difference;
- **lightness correlation**: Pearson's r of ``L*`` pixel by pixel (does the face's pattern of
  light and dark, brows, lips, shading, sit in the same places).

The same figures for the head in one flat colour (the scan's median colour) are the baseline a
texture has to beat (its lightness is constant: correlation 0). ``flat_face_mean`` is the stronger
flat baseline: the scan's own face pixels against their mean CIELAB colour (the one colour with the
least squared Delta E over the face; :func:`flat_color_difference`), no render needed.
"""

from __future__ import annotations

import numpy as np

from .render import render_mesh

__all__ = ["color_difference", "flat_color_difference", "likeness_views", "srgb_to_lab"]

_BACKGROUND = (1.0, 0.0, 1.0)  # magenta: no surface


def _openings_dark(img: np.ndarray) -> np.ndarray:
    """A lit picture rendered on the dark of a cavity (``COLORS["cavity"]``) with the background
    outside the surface made white: the openings the surface encloses (the eyes' and the mouth's,
    where only the skin is drawn) stay dark instead of showing as white holes."""
    from scipy.ndimage import binary_fill_holes

    from .looks import COLORS

    bg = np.abs(img.astype(np.int32) - np.round(np.array(COLORS["cavity"]) * 255)).max(2) <= 3
    outside = bg & ~binary_fill_holes(~bg)
    out = img.copy()
    out[outside] = 255
    return out


def srgb_to_lab(rgb) -> np.ndarray:
    """CIELAB (D65) of sRGB colours.

    Args:
        rgb: sRGB, shape (..., 3), uint8 (0-255) or float in [0, 1].

    Returns:
        ``(L*, a*, b*)``, shape (..., 3), float64 (L* in [0, 100]).
    """
    c = np.asarray(rgb)
    c = c.astype(np.float64) / 255.0 if np.issubdtype(c.dtype, np.integer) else c.astype(np.float64)
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    M = np.array([[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750],
                  [0.0193339, 0.1191920, 0.9503041]])
    xyz = lin @ M.T / np.array([0.95047, 1.0, 1.08883])
    e = 216.0 / 24389.0
    f = np.where(xyz > e, np.cbrt(xyz), (24389.0 / 27.0 * xyz + 16.0) / 116.0)
    return np.stack([116.0 * f[..., 1] - 16.0, 500.0 * (f[..., 0] - f[..., 1]), 200.0 * (f[..., 1] - f[..., 2])], -1)


def color_difference(a, b, mask) -> dict:
    """Mean CIE76 Delta E and the L* correlation of two sRGB images over ``mask``.

    Args:
        a, b: Images, shape (h, w, 3), uint8.
        mask: Pixels to compare, shape (h, w), bool.

    Returns:
        ``delta_e_mean``, ``delta_e_median``, ``delta_e_p95``, ``lightness_correlation``, ``pixels``.
    """
    la, lb = srgb_to_lab(a)[mask], srgb_to_lab(b)[mask]
    de = np.linalg.norm(la - lb, axis=1)
    r = float(np.corrcoef(la[:, 0], lb[:, 0])[0, 1]) if len(de) > 2 and la[:, 0].std() > 0 and lb[:, 0].std() > 0 else 0.0
    return _figures(de, r)


def _figures(de: np.ndarray, r: float) -> dict:
    """The figures of a comparison from its per-pixel Delta E (k,) and L* correlation ``r``."""
    return {"delta_e_mean": float(de.mean()), "delta_e_median": float(np.median(de)),
            "delta_e_p95": float(np.percentile(de, 95)), "lightness_correlation": r, "pixels": int(len(de))}


def flat_color_difference(b, mask) -> dict:
    """The figures of :func:`color_difference` for the best single colour against image ``b`` over ``mask``.

    The colour is the mean CIELAB of ``b``'s masked pixels (it minimises the mean squared Delta E;
    the mean Delta E of any other flat colour is at most a few per cent lower).

    Args:
        b: Image, shape (h, w, 3), uint8.
        mask: Pixels to compare, shape (h, w), bool.

    Returns:
        ``delta_e_mean``, ``delta_e_median``, ``delta_e_p95``, ``lightness_correlation`` (0: one
        colour has no pattern), ``pixels`` and ``lab``: the colour, ``(L*, a*, b*)``.
    """
    lb = srgb_to_lab(b)[np.asarray(mask, bool)]
    c = lb.mean(axis=0)
    return {**_figures(np.linalg.norm(lb - c, axis=1), 0.0), "lab": c.tolist()}


def likeness_views(head_V, head_F, texture, corner_uv, face_mask, scan_V, scan_F, *, scan_colors=None,
                   scan_texture=None, scan_corner_uv=None, views=("front", "three_quarter"), size: int = 400,
                   device: str = "cpu") -> dict:
    """Render head and scan from the same cameras and compare them (see the module docstring).

    Args:
        head_V: The adapted head's vertices [m], shape (n, 3), in the same frame as the scan
            (the views are taken in this frame: +z the face's front, +y up).
        head_F: Its triangles, shape (m, 3), int.
        texture: Its texture, shape (h, w, 3), uint8; corner_uv: its corner UVs, shape (m, 3, 2).
        face_mask: The head's triangles of the face region, shape (m,), bool.
        scan_V, scan_F: The scan [m], (s, 3) and (l, 3).
        scan_colors: The scan's vertex colours (s, 3) in [0, 1]; or ``scan_texture`` (h, w, 3)
            with ``scan_corner_uv`` (l, 3, 2).
        views: Views of :func:`~facewarp.render_mesh`.
        size: Image side [px].
        device: Warp device of the renders.

    Returns:
        ``{"views": {view: {"textured": figures, "flat": figures, "flat_face_mean": figures}}, "mean": {...},
        "flat_color": sRGB, "images": {view: (head, scan, flat) uint8 images}}``.
    """
    from scipy.ndimage import binary_erosion

    head_V = np.asarray(head_V, np.float64)
    head_F = np.asarray(head_F, np.int64)
    face_mask = np.asarray(face_mask, bool)
    frame = head_V[np.unique(head_F[face_mask])]
    common = dict(width=size, height=size, frame_points=frame, background=_BACKGROUND, device=device, margin=0.04)
    if scan_colors is not None:
        scan_look = {"vertex_colors": np.asarray(scan_colors, float)}
        flat = np.median(np.asarray(scan_colors, float), axis=0)
    else:
        tex = np.asarray(scan_texture)
        scan_look = {"texture": (tex, scan_corner_uv)}
        t = tex.reshape(-1, 3).astype(float) / (255.0 if np.issubdtype(tex.dtype, np.integer) else 1.0)
        flat = np.median(t, axis=0)
    out: dict = {"views": {}, "images": {}, "flat_color": flat.tolist()}
    for view in views:
        head = render_mesh(head_V, head_F, view=view, texture=(texture, corner_uv), unlit=True, **common)
        scan = render_mesh(scan_V, scan_F, view=view, **scan_look, unlit=True, **common)
        flat_img = render_mesh(head_V, head_F, view=view, base_color=tuple(flat), unlit=True, **common)
        region = render_mesh(head_V, head_F, view=view, face_colors=np.where(face_mask[:, None], 1.0, 0.0) * np.ones(3),
                             **{**common, "background": (0.0, 0.0, 0.0)})
        bg = np.array(_BACKGROUND) * 255
        mask = (region.min(axis=2) > 40) & (np.abs(scan - bg).sum(2) > 30) & (np.abs(head - bg).sum(2) > 30)
        mask = binary_erosion(mask, iterations=2)
        name = view if isinstance(view, str) else f"{view[0]:g}_{view[1]:g}"
        out["views"][name] = {"textured": color_difference(head, scan, mask),
                              "flat": color_difference(flat_img, scan, mask),
                              "flat_face_mean": flat_color_difference(scan, mask)}
        from .looks import COLORS

        lit = {**common, "background": COLORS["cavity"]}  # openings dark, the outside white (_openings_dark)
        out["images"][name] = tuple(_openings_dark(img) for img in (
            render_mesh(head_V, head_F, view=view, texture=(texture, corner_uv), **lit),
            render_mesh(scan_V, scan_F, view=view, **scan_look, **lit),
            render_mesh(head_V, head_F, view=view, base_color=tuple(flat), **lit)))
    keys = ("delta_e_mean", "lightness_correlation")
    kinds = ("textured", "flat", "flat_face_mean")
    out["mean"] = {k: {kind: float(np.mean([v[kind][k] for v in out["views"].values()])) for kind in kinds}
                   for k in keys}
    return out
