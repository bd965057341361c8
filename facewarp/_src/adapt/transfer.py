"""The template carried onto an adapted head (Sec. 6.5, 6.6): rigid parts, UVs, :func:`load_head`.

- :func:`eye_transform`: the uniform scale, rotation and translation of Eq. 6.6.1-6.6.4 that
  carries an eyeball (or any rigid part) from the template to the adapted head, from the FDPs
  around it: left eye 3.7 (outer corner), 3.11 (inner corner), 3.13 (upper lid), 3.9 (lower
  lid); right eye 3.12, 3.8, 3.14, 3.10.
- :func:`fit_part_transform`: the least-squares similarity from any template FDPs to their
  adapted positions (for the teeth, e.g. 9.8-9.11, or when an eye FDP is missing).
- :func:`transfer_uv`: each adapted vertex takes the UV of its closest point on the textured
  scan (closest triangle, barycentric weights on the scan's per-vertex UVs; Sec. 6.5).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from .calibrate import Similarity, fit_similarity

__all__ = ["EYE_FDPS", "apply_part", "eye_transform", "fit_part_transform", "load_head", "transfer_uv"]

EYE_FDPS: dict[str, tuple[str, str, str, str]] = {
    "left": ("3.7", "3.11", "3.13", "3.9"),
    "right": ("3.12", "3.8", "3.14", "3.10"),
}
"""Per eye: (outer corner, inner corner, upper lid, lower lid) FDPs (Sec. 6.6)."""


def _get(lm: dict, ids, what: str) -> np.ndarray:
    missing = [k for k in ids if k not in lm]
    if missing:
        raise InputError(f"{what} landmarks lack FDP {', '.join(missing)}")
    return np.array([np.asarray(lm[k], dtype=np.float64).reshape(3) for k in ids])


def _frame(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Orthonormal frame (columns) from an x axis and an approximate y axis."""
    ex = x / np.linalg.norm(x)
    ey = y - ex * float(ex @ y)
    ey = ey / np.linalg.norm(ey)
    return np.stack([ex, ey, np.cross(ex, ey)], axis=1)


def eye_transform(template_landmarks: dict, adapted_landmarks: dict, center, *, side: str = "left") -> Similarity:
    """Eq. 6.6.1-6.6.4 for one eye.

    ``delta = |P37^s - P311^s| |P313^s - P39^s| / (|P37^t - P311^t| |P313^t - P39^t|)``
    (Eq. 6.6.1, used here as its square root so that it scales lengths: the thesis's ratio
    is a ratio of areas); the rotation takes the template frame (x along 3.7 - 3.11, y along
    3.13 - 3.9) onto the adapted one; with the reference point psi (mean of the four FDPs),
    ``gamma^t = psi^t - phi^t`` (Eq. 6.6.2), ``phi^t' = psi^s - delta R gamma^t`` (Eq. 6.6.3) and
    ``p' = delta R (p - phi^t) + phi^t'`` (Eq. 6.6.4).

    Args:
        template_landmarks: FDP id -> template position [m].
        adapted_landmarks: FDP id -> adapted (scan) position [m].
        center: Template eyeball centre phi^t [m], shape (3,).
        side: "left" (FDPs 3.7, 3.11, 3.13, 3.9) or "right" (3.12, 3.8, 3.14, 3.10).

    Returns:
        The :class:`Similarity` p -> p'.
    """
    if side not in EYE_FDPS:
        raise InputError(f"side must be 'left' or 'right', got {side!r}")
    ids = EYE_FDPS[side]
    Pt = _get(template_landmarks, ids, "template")
    Ps = _get(adapted_landmarks, ids, "adapted")
    num = np.linalg.norm(Ps[0] - Ps[1]) * np.linalg.norm(Ps[2] - Ps[3])
    den = np.linalg.norm(Pt[0] - Pt[1]) * np.linalg.norm(Pt[2] - Pt[3])
    if den <= 0 or num <= 0:
        raise InputError(f"{side} eye FDPs coincide")
    delta = float(np.sqrt(num / den))  # Eq. 6.6.1 (area ratio -> length scale)
    Ft = _frame(Pt[0] - Pt[1], Pt[2] - Pt[3])
    Fs = _frame(Ps[0] - Ps[1], Ps[2] - Ps[3])
    R = Fs @ Ft.T
    phi_t = np.asarray(center, dtype=np.float64).reshape(3)
    gamma = Pt.mean(0) - phi_t  # Eq. 6.6.2
    phi_s = Ps.mean(0) - delta * R @ gamma  # Eq. 6.6.3
    return Similarity(delta, R, phi_s - delta * R @ phi_t)  # Eq. 6.6.4


def fit_part_transform(template_landmarks: dict, adapted_landmarks: dict, ids, *, with_scale: bool = True) -> Similarity:
    """Least-squares similarity (or rigid map) from template FDPs ``ids`` to their adapted positions."""
    ids = list(ids)
    if len(ids) < 3:
        raise InputError(f"a rigid part needs at least 3 FDPs, got {len(ids)}")
    return fit_similarity(_get(template_landmarks, ids, "template"), _get(adapted_landmarks, ids, "adapted"), with_scale=with_scale)


def apply_part(V, transform: Similarity) -> np.ndarray:
    """The part's vertices V [m], shape (k, 3), moved by ``transform`` (Eq. 6.6.4)."""
    return transform.apply(V)


def transfer_uv(V, scan_V, scan_F, scan_uv, *, device: str = "cpu") -> np.ndarray:
    """UV of each vertex of V from the closest point on a textured scan (Sec. 6.5).

    Args:
        V: Adapted vertices [m], shape (n, 3), float64 (in the scan's frame).
        scan_V, scan_F: The scan [m], shapes (k, 3) and (l, 3).
        scan_uv: Per-vertex UVs of the scan, shape (k, 2), float64.
        device: Warp device of the closest-point query.

    Returns:
        UVs, shape (n, 2), float64.
    """
    from ..geometry.surface import closest_point

    scan_uv = np.asarray(scan_uv, dtype=np.float64)
    if scan_uv.shape != (len(scan_V), 2):
        raise InputError(f"scan UVs must have shape ({len(scan_V)}, 2), got {scan_uv.shape}")
    cp = closest_point(scan_V, scan_F, V, device=device)
    F = np.asarray(scan_F, dtype=np.int64)
    return np.einsum("kc,kcd->kd", cp.bary, scan_uv[F[cp.face]])


def _head_from_adapt_dir(path: Path):
    """The template an ``adapt`` output was made from, carried onto the adapted shape (Sec. 6.6):
    same faces, FDP surface points, regions, per-vertex thickness and skull depth; rigid parts
    and condyles follow the FDPs (Eq. 6.6.1-6.6.4 for the eyes, a least-squares similarity for
    the rest)."""
    from ..geometry.mesh import load_mesh
    from ..template import default_template
    from ..template.files import load_template_dir

    rep_path = path / "report.json"
    try:
        rep = json.loads(rep_path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(f"{path}: not an adapt output (report.json unreadable: {e})") from None
    tmpl = str(rep.get("template", ""))
    if tmpl.startswith("default template"):
        t = default_template(0)
    elif tmpl and Path(tmpl).is_dir():
        t = load_template_dir(tmpl)
    else:
        raise InputError(f"{path}: adapted from {tmpl or 'an unknown template'}, which carries no regions, "
                         "skull or muscles; adapt with the default template or a template folder to build anatomy")
    m = load_mesh(path / "adapted.obj")
    if m.vertices.shape != t.vertices.shape or not np.array_equal(m.faces, t.faces):
        raise InputError(f"{path / 'adapted.obj'}: topology does not match its template "
                         f"({len(m.vertices)} vs {t.vertex_count} vertices)")
    tl = t.landmarks()
    adapted = replace(t, vertices=m.vertices, parts=dict(t.parts))
    al = {k: v for k, v in adapted.landmarks().items() if t.fdp[k][0] == "head"}
    parts = {}
    for name, (V, F) in t.parts.items():
        if name in ("eye_L", "eye_R"):
            sim = eye_transform(tl, al, V.mean(0), side="left" if name == "eye_L" else "right")
        else:
            ids = ["8.1", "8.2", "8.3", "8.4", "2.2", "2.3", "9.15", "2.1"]
            sim = fit_part_transform(tl, al, ids)
        parts[name] = (sim.apply(V), F)
    ids = [k for k in ("2.1", "3.7", "3.12", "8.3", "8.4", "10.9", "10.10", "9.3", "11.1") if k in al]
    condyles = fit_part_transform(tl, al, ids).apply(t.condyles)
    texture = path / "texture.png"
    return replace(adapted, parts=parts, condyles=condyles, level=t.level,
                   texture=str(texture) if texture.is_file() and t.uv is not None else None)


def load_head(path) -> "Template":
    """A head to build anatomy on.

    Args:
        path: A template folder (``facewarp template export``), an ``adapt`` output folder, or
            ``"default"`` / ``"default:LEVEL"`` for the built-in template at that level (0..4).

    Returns:
        A :class:`~facewarp.Template` (an adapted head carries its template's regions, FDPs,
        thickness, skull depth, rigid parts and condyles, moved onto the adapted shape).

    Raises:
        InputError: naming the path and what is wrong with it.
    """
    from ..core.checks import check_path

    check_path("path", path)
    from ..template import MAX_LEVEL, default_template
    from ..template.files import load_template_dir

    text = str(path)
    if text == "default" or text.startswith("default:"):
        lv = text.partition(":")[2] or "0"
        if not (lv.isdigit() and 0 <= int(lv) <= MAX_LEVEL):
            raise InputError(f"head {text!r}: the default template has levels 0..{MAX_LEVEL}, got {lv!r}")
        return default_template(int(lv))
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such head folder")
    if not path.is_dir():
        raise InputError(f"{path}: HEAD must be a folder (a `template export` or `adapt` output)")
    if (path / "template.npz").is_file():
        return load_template_dir(path)
    if (path / "adapted.obj").is_file():
        return _head_from_adapt_dir(path)
    raise InputError(f"{path}: neither a template folder (template.npz) nor an adapt output (adapted.obj)")
