"""Preview colours and renders of a head: skin, vermilion, eyes (sclera, iris, pupil), teeth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..template.head import REGIONS, Template
from .render import render_mesh, save_png

__all__ = ["CAVITY", "LIPS", "MOUTH", "SKIN", "TEETH", "TONGUE", "colored_scene", "head_colors", "part_colors",
           "render_previews", "vermilion_weight"]


SKIN = np.array([0.87, 0.72, 0.62])
"""Skin colour of the previews, linear RGB in [0, 1], shape (3,)."""
LIPS = np.array([0.78, 0.47, 0.45])
"""Lip colour of the previews, linear RGB in [0, 1], shape (3,)."""
TEETH = np.array([0.97, 0.95, 0.85])
"""Teeth colour of the previews, linear RGB in [0, 1], shape (3,)."""
TONGUE = np.array([0.8, 0.42, 0.42])
"""Tongue colour of the previews, linear RGB in [0, 1], shape (3,)."""


def vermilion_weight(V, lm: dict, mask=None) -> np.ndarray:
    """Lip tint weight in [0, 1] per vertex of V (n, 3) [m]: an ellipse through the lip corners
    (8.3, 8.4) and the lip midpoints (8.1, 8.2) around the stomion (mean of 2.2, 2.3), with a
    soft edge; ``mask`` (n,) bool limits it to some vertices."""
    sto = 0.5 * (lm["2.2"] + lm["2.3"])
    half_w = 0.5 * abs(lm["8.3"][0] - lm["8.4"][0])
    up, dn = lm["8.1"][1] - sto[1], sto[1] - lm["8.2"][1]
    dy = V[:, 1] - sto[1]
    e = ((V[:, 0] - sto[0]) / half_w) ** 2 + (dy / np.where(dy > 0, up, dn)) ** 2
    w = np.clip((1.15 - e) / 0.3, 0.0, 1.0)
    return w if mask is None else w * mask


_EYE_PALETTE = np.array([[0.05, 0.05, 0.05], [0.33, 0.24, 0.16], [0.96, 0.95, 0.93]])  # pupil, iris, sclera
MOUTH = np.array([0.45, 0.2, 0.2])
"""Inside of the mouth (the lips' inner sheets), linear RGB."""
CAVITY = np.array([0.16, 0.05, 0.05])
"""The inside of the head seen through the open mouth (the skin's back side), linear RGB."""


def part_colors(name: str, V) -> np.ndarray:
    """Preview colours of a rigid part at rest, (k, 3) in [0, 1], for its vertices V (k, 3) [m].

    Eyeballs (names starting ``eye``): white sclera with a brown iris (6 mm radius) and a black
    pupil (2 mm) around the axis through the ball's centre along +z (the template's gaze);
    teeth :data:`TEETH`; anything else (the tongue) :data:`TONGUE`.
    """
    V = np.asarray(V, dtype=np.float64)
    if name.startswith("eye"):
        d = V - V.mean(0)
        r = np.linalg.norm(d, axis=1)
        ang = np.arccos(np.clip(d[:, 2] / np.maximum(r, 1e-12), -1, 1))
        rm = max(float(r.mean()), 6.5e-3)
        k = np.where(ang < np.arcsin(2.0e-3 / rm), 0, np.where(ang < np.arcsin(6.0e-3 / rm), 1, 2))
        return _EYE_PALETTE[k]
    return np.tile(TEETH if name.startswith("teeth") else TONGUE, (len(V), 1))


def head_colors(V, lm: dict) -> np.ndarray:
    """Preview colours of a head's skin at rest, (n, 3) in [0, 1], from its vertices V (n, 3) [m]
    and FDPs ``lm`` (id -> (3,) [m]; uses 2.2, 2.3, 8.1-8.4).

    Skin, the vermilion tinted on the front of the face (:func:`vermilion_weight`), and the inside
    of the mouth (the lips' inner sheets: within the lips' ellipse, more than 4 mm behind the
    stomion) darker, so an open mouth reads as one.
    """
    V = np.asarray(V, dtype=np.float64)
    lm = {k: np.asarray(v, dtype=np.float64) for k, v in lm.items()}
    sto = 0.5 * (lm["2.2"] + lm["2.3"])
    front = V[:, 2] > sto[2] - 0.02
    w = vermilion_weight(V, lm, front)[:, None]
    col = SKIN * (1 - w) + LIPS * w
    inner = (vermilion_weight(V, lm) > 0.5) & (V[:, 2] < sto[2] - 0.004) & front
    col[inner] = MOUTH
    return col


def colored_scene(t: Template) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Skin and rigid parts merged into one mesh with per-vertex colours for previews.

    Lips are tinted, eyeballs get a sclera, iris (6 mm) and pupil (2 mm) facing +z.
    Returns V (n, 3) [m], F (m, 3), colours (n, 3) in [0, 1].
    """
    Vs, Fs, Cs = [t.vertices], [t.faces], []
    col = np.tile(SKIN, (t.vertex_count, 1))
    lip_ids = [REGIONS.index(r) for r in ("upper_lip", "lower_lip", "lip_corner_L", "lip_corner_R")]
    on_lips = np.zeros(t.vertex_count, bool)
    on_lips[np.unique(t.faces[np.isin(t.face_region, lip_ids)])] = True
    wgt = vermilion_weight(t.vertices, t.landmarks(), on_lips)
    col = col * (1 - wgt[:, None]) + LIPS * wgt[:, None]
    Cs.append(col)
    off = t.vertex_count
    for name, (V, F) in t.parts.items():
        Cs.append(part_colors(name, V))
        Vs.append(V)
        Fs.append(F + off)
        off += len(V)
    return np.concatenate(Vs), np.concatenate(Fs), np.concatenate(Cs)


def render_previews(t: Template, out: Path, *, size: int = 800, device: str = "cpu") -> list[Path]:
    """Render ``preview_front.png`` and ``preview_side.png`` of the head into ``out``."""
    V, F, C = colored_scene(t)
    paths = []
    for view in ("front", "side"):
        img = render_mesh(V, F, view=view, width=size, height=size, vertex_colors=C, device=device)
        p = out / f"preview_{view}.png"
        what = f"facewarp default template, level {t.level}" if t.level >= 0 else "facewarp imported template"
        save_png(p, img, title=f"{what} ({t.vertex_count} vertices)")
        paths.append(p)
    return paths
