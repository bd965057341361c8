"""Meshing of the default head: rows of horizontal slices zipped into triangles.

The head surface of :mod:`.shape` is sampled on rows of constant parameter ``t`` (arc length
of the midline profile from the neck cut to the vertex) and azimuth samples per row (denser
toward the face). Neighbouring rows are zipped into triangles; the top row is closed by a fan to
the vertex. The eye fissures and the mouth slit are *cuts* along one row: between the corners
the row's vertices are duplicated, the copies are pulled apart by the lid (or lip) opening, and
the rows around are pushed away smoothly so nothing folds. So every level has boundary loops
exactly at the neck, the two eyes and the mouth, and the same definitions (FDPs, regions) at
every level, because they are all given in the continuous (phi, y) parametrisation.

Level ``L`` uses a sample spacing ``H0 / 2**L``: each level has about 4x the vertices of the
previous one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import shape as S

__all__ = ["RawHead", "build_raw_head", "H0_MM"]

H0_MM = 6.9  # level-0 sample spacing along the face [mm]; gives about 3,400 vertices
_FRONT_DENSITY = 0.45  # phi(u) = u - a sin(u): samples are 1/(1-a) denser at the front


@dataclass
class _Cut:
    y: float  # row height [mm]
    x0: float  # inner corner |x| [mm] (0 for the mouth: one cut across the midline)
    x1: float  # outer corner |x| [mm]
    up: callable  # opening above the row [mm] as a function of |x|
    down: callable  # opening below the row [mm] as a function of |x|
    decay: float  # rows within this distance [mm] are pushed away smoothly
    mirrored: bool  # two cuts (left and right) instead of one across the midline


def _lid(amplitude, x0, x1, skew=0.0):
    def f(ax):
        s = np.clip((ax - x0) / (x1 - x0), 0.0, 1.0)
        s = s + skew * s * (1 - s)
        return amplitude * np.clip(4.0 * s * (1.0 - s), 0.0, None) ** 0.75

    return f


def _mouth(amplitude):
    def f(ax):
        s = np.clip(ax / S.X_CH, 0.0, 1.0)
        return amplitude * np.sqrt(np.clip(1.0 - s * s, 0.0, None))

    return f


EYE_UP_MM = 4.5  # upper lid margin above the canthal line at its highest (palpebral fissure
EYE_DOWN_MM = 5.0  # about 10 mm high in adults)
MOUTH_GAP_MM = 0.6  # half gap of the closed mouth slit

CUTS = (
    _Cut(S.Y_EYE, S.X_EN, S.X_EX, _lid(EYE_UP_MM, S.X_EN, S.X_EX, 0.3), _lid(EYE_DOWN_MM, S.X_EN, S.X_EX, -0.2),
         14.0, True),
    _Cut(S.Y_STOMION, 0.0, S.X_CH, _mouth(MOUTH_GAP_MM), _mouth(MOUTH_GAP_MM), 3.0, False),
)


def _phi_of_u(u):
    return u - _FRONT_DENSITY * np.sin(u)


def _u_of_phi(phi):
    u = np.array(phi, dtype=np.float64)
    for _ in range(60):  # Newton on phi(u) - phi = 0, phi' = 1 - a cos u > 0
        u = u - (_phi_of_u(u) - phi) / (1.0 - _FRONT_DENSITY * np.cos(u))
    return u


@dataclass
class RawHead:
    """The skin mesh of one level in millimetres plus its parametrisation.

    Attributes:
        vertices: positions [mm], shape (n, 3), float64.
        faces: triangles, shape (m, 3), int64, outward oriented.
        phi: azimuth of every vertex [rad], shape (n,).
        y: slice height of every vertex [mm], shape (n,).
    """

    vertices: np.ndarray
    faces: np.ndarray
    phi: np.ndarray
    y: np.ndarray


def _row_heights(head: S.HeadShape, h: float):
    ys = np.linspace(S.Y_NECK_CUT, S.Y_VERTEX, 6000)
    zf = head.point(np.zeros_like(ys), ys)[:, 2]
    seg = np.hypot(np.diff(ys), np.diff(zf))
    t = np.concatenate([[0.0], np.cumsum(seg)])
    fixed = sorted([0.0, float(np.interp(S.Y_STOMION, ys, t)), float(np.interp(S.Y_EYE, ys, t)), t[-1]])
    rows = []
    for a, b in zip(fixed[:-1], fixed[1:]):
        n = max(1, int(round((b - a) / h)))
        rows.extend(np.linspace(a, b, n + 1)[:-1])
    rows = np.asarray(rows)  # the last fixed value (the vertex) is the pole, not a row
    return np.interp(rows, t, ys)


def _circumference(head, y):
    ph = np.linspace(-np.pi, np.pi, 256, endpoint=False)
    p = head.point(ph, np.full_like(ph, y))
    return float(np.sum(np.linalg.norm(np.roll(p, -1, 0) - p, axis=1)))


def _zip(a, ua, b, ub):
    """Triangles between ring ``a`` (lower) and ring ``b`` (upper), both periodic in u."""
    na, nb = len(a), len(b)
    ia = int(np.argmin(ua))
    ib = int(np.argmin(ub))
    tris = []
    i = j = 0
    while i < na or j < nb:
        a0, a1 = a[(ia + i) % na], a[(ia + i + 1) % na]
        b0, b1 = b[(ib + j) % nb], b[(ib + j + 1) % nb]
        ua1 = ua[(ia + i + 1) % na] + (2 * np.pi if ia + i + 1 >= na else 0.0)
        ub1 = ub[(ib + j + 1) % nb] + (2 * np.pi if ib + j + 1 >= nb else 0.0)
        if j >= nb or (i < na and ua1 <= ub1):
            tris.append((a0, a1, b0))
            i += 1
        else:
            tris.append((a0, b1, b0))
            j += 1
    return tris


def build_raw_head(level: int, head: S.HeadShape | None = None) -> RawHead:
    """Sample and triangulate the head at ``level`` (0 = about 3,400 vertices)."""
    head = head or S.HeadShape()
    h = H0_MM / (2**level)
    ys = _row_heights(head, h)

    verts_phi: list[np.ndarray] = []
    verts_y: list[np.ndarray] = []
    rings = []  # per row: (u, lower-facing indices, upper-facing indices)
    count = 0
    for y in ys:
        circ = _circumference(head, y)
        n = max(8, int(round(circ / (h * 1.25))))
        u = np.linspace(-np.pi, np.pi, n, endpoint=False) + np.pi / n
        cut = next((c for c in CUTS if abs(c.y - y) < 1e-9), None)
        corners = []
        if cut is not None:
            xs = [cut.x1] if not cut.mirrored else [cut.x0, cut.x1]
            for x in xs:
                for sgn in (1.0, -1.0):
                    ph = head.phi_at_x(np.array([sgn * x]), np.array([y]))[0]
                    corners.append(_u_of_phi(ph))
            for uc in corners:
                u[np.argmin(np.abs(u - uc))] = uc
            u = np.sort(u)
        phi = _phi_of_u(u)
        x_row = head.radius(phi, np.full_like(phi, y)) * np.sin(phi)
        dy = _push(x_row, phi, y)
        base_idx = np.arange(count, count + n)
        verts_phi.append(phi)
        verts_y.append(y + dy)
        count += n
        down_idx = base_idx.copy()
        up_idx = base_idx.copy()
        if cut is not None:
            ax = np.abs(x_row)
            inside = (ax > cut.x0 + 1e-6) & (ax < cut.x1 - 1e-6) & (np.cos(phi) > 0)
            if not cut.mirrored:
                inside = (ax < cut.x1 - 1e-6) & (np.cos(phi) > 0)
            k = int(inside.sum())
            up_y = y + cut.up(ax[inside])
            dn_y = y - cut.down(ax[inside])
            # the base copy becomes the lower margin, a new copy the upper margin
            verts_y[-1] = verts_y[-1].copy()
            verts_y[-1][inside] = dn_y
            verts_phi.append(phi[inside])
            verts_y.append(up_y)
            up_idx[inside] = np.arange(count, count + k)
            count += k
        rings.append((u, down_idx, up_idx))

    phi_all = np.concatenate(verts_phi)
    y_all = np.concatenate(verts_y)
    faces = []
    for r in range(len(rings) - 1):
        ua, _, a_up = rings[r]
        ub, b_down, _ = rings[r + 1]
        faces.extend(_zip(a_up, ua, b_down, ub))
    # the vertex (pole) closes the top row
    pole = count
    ut, _, top = rings[-1]
    order = np.argsort(ut)
    for k in range(len(order)):
        faces.append((top[order[k]], top[order[(k + 1) % len(order)]], pole))
    phi_all = np.concatenate([phi_all, [0.0]])
    y_all = np.concatenate([y_all, [S.Y_VERTEX]])
    F = np.asarray(faces, dtype=np.int64)
    V = head.point(phi_all, y_all)
    V[pole] = [0.0, S.Y_VERTEX, float(head.axis_z(S.Y_VERTEX))]
    # outward orientation: the nose-tip normal must point +z
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    c = V[F].mean(1)
    front = np.argmax(c[:, 2])
    if n[front, 2] < 0:
        F = F[:, ::-1].copy()
    return RawHead(V, F, phi_all, y_all)


def _push(x_row, phi, y):
    """Vertical displacement [mm] of a row at ``y`` that opens room for the cuts."""
    dy = np.zeros_like(x_row)
    ax = np.abs(x_row)
    for c in CUTS:
        d = y - c.y
        if abs(d) < 1e-9 or abs(d) >= c.decay:
            continue
        g = (1.0 - abs(d) / c.decay) ** 2
        amp = c.up(ax) if d > 0 else -c.down(ax)
        dy += amp * g * (np.cos(phi) > 0)  # same |x| profile as the margin, front only
    return dy
