"""Preview colours and renders of a head: skin, vermilion, eyes (sclera, iris, pupil), teeth and gums."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..template.head import REGIONS, Template
from .looks import COLORS, drawn_part, part_vertex_colors
from .render import render_mesh, save_png

__all__ = ["CAVITY", "GUMS", "LIPS", "MOUTH", "SKIN", "TEETH", "TONGUE", "colored_scene", "head_colors", "part_colors",
           "render_previews", "vermilion_weight"]


SKIN = np.array(COLORS["skin"])
"""Skin colour of the previews (the looks' palette, ``present.looks.COLORS``), linear RGB in [0, 1], shape (3,)."""
LIPS = np.array(COLORS["lips"])
"""Lip colour of the previews, linear RGB in [0, 1], shape (3,)."""
TEETH = np.array(COLORS["teeth"])
"""Teeth colour of the previews (ivory), linear RGB in [0, 1], shape (3,)."""
TONGUE = np.array(COLORS["tongue"])
"""Tongue colour of the previews, linear RGB in [0, 1], shape (3,)."""
GUMS = np.array(COLORS["gums"])
"""Gum colour of the previews (the root end of each tooth row), linear RGB in [0, 1], shape (3,)."""


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


MOUTH = np.array(COLORS["mouth"])
"""Inside of the mouth (the lips' inner sheets), linear RGB."""
CAVITY = np.array(COLORS["cavity"])
"""The inside of the head seen through the open mouth (the skin's back side), linear RGB."""


def part_colors(name: str, V, *, landmarks: dict | None = None, iris_color=None, ball=None,
                faces=None) -> np.ndarray:
    """Preview colours of a rigid part at rest, (k, 3) in [0, 1], for its vertices V (k, 3) [m].

    The looks of every output (``present.looks``): eyeballs (names with ``eye``) off-white sclera,
    a brown-hazel iris 11.7 mm across and a near-black pupil 4 mm across around the gaze axis (the
    ball's centre to its pupil FDP 3.5 / 3.6 in ``landmarks``, else +z); teeth (and other parts)
    :data:`TEETH`, a tooth row's root end pink gums (drawn split at the gum line,
    ``present.looks.tooth_mesh``); the tongue :data:`TONGUE`.

    Args:
        name: The part's name. V: Its vertices [m], shape (k, 3), float.
        landmarks: Optional FDP id -> rest position (3,) [m] (the pupils give the gaze).
        iris_color: Optional iris RGB (3,) in 0..1, linear.
        ball: Optional rest vertices (j, 3) [m] of the part that V draws (``present.looks.drawn_part``):
            an eyeball's centre and gaze, a tooth row's gum line.
        faces: Optional triangles (m, 3) int of V: the gums' colour stops sharp at the gum line.
    """
    return part_vertex_colors(name, V, landmarks, iris_color=iris_color, ball=ball, faces=faces)


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

    Lips are tinted, eyeballs (drawn refined) get a sclera, iris and pupil about the gaze, tooth
    rows (drawn split at the gum line) gums at their roots (:func:`part_colors`).
    Returns V (n, 3) float [m], F (m, 3) int, colours (n, 3) float in [0, 1].
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
    lm = t.landmarks()
    for name, (V0, F0) in t.parts.items():
        V, F = drawn_part(name, V0, F0)
        Cs.append(part_colors(name, V, landmarks=lm, ball=V0, faces=F))
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
