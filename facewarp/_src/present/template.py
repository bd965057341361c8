"""Preview colours and renders of a head: skin, vermilion, eyes (sclera, iris, pupil), teeth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..template.head import REGIONS, Template
from .render import render_mesh, save_png

__all__ = ["LIPS", "SKIN", "TEETH", "TONGUE", "colored_scene", "render_previews", "vermilion_weight"]


SKIN = np.array([0.87, 0.72, 0.62])
LIPS = np.array([0.78, 0.47, 0.45])
TEETH = np.array([0.97, 0.95, 0.85])
TONGUE = np.array([0.8, 0.42, 0.42])


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
        if name.startswith("eye"):
            c = V.mean(0)
            d = V - c
            ang = np.arccos(np.clip(d[:, 2] / np.linalg.norm(d, axis=1), -1, 1))
            r = np.linalg.norm(d, axis=1).mean()
            pc = np.where(ang < np.arcsin(2.0e-3 / r), 0.0, np.where(ang < np.arcsin(6.0e-3 / r), 1.0, 2.0))
            pal = np.array([[0.05, 0.05, 0.05], [0.33, 0.24, 0.16], [0.96, 0.95, 0.93]])
            Cs.append(pal[pc.astype(int)])
        else:
            Cs.append(np.tile(TEETH if name.startswith("teeth") else TONGUE, (len(V), 1)))
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
