"""The default head's shape, authored in code as a radial function over horizontal slices.

The surface is described in a head frame (millimetres inside this module only; the mesh
builder converts to metres): x toward the subject's left, y up, z out of the face, the origin on
the line through the two tragions (y = 0 is the tragion level, x = z = 0 its midpoint).

Every horizontal slice at height ``y`` is a closed curve ``r(phi, y)`` around the vertical axis
``(0, y, zc(y))``, with ``phi`` the azimuth measured from +z toward +x::

    x = r sin(phi),   z = zc(y) + r cos(phi)

``r`` is a base superellipse (front and back halves with their own depth and exponent, Sec. 1
below) plus localized features (nose, eyes, lips, chin, cheeks, ears, Sec. 2), each a smooth
bump evaluated at the base surface point.

Proportions are adult-male means of Farkas, L. G. (1994), *Anthropometry of the Head and Face*,
2nd ed., Raven Press (North-American Caucasian norms, the values below rounded to the mm):

===============================  ===========  ===============================
measurement (Farkas landmarks)   value [mm]   used as
===============================  ===========  ===============================
head width eu-eu                 151          2 * max slice half-width
head length g-op                 197          glabella z + opisthocranion depth
face height n-gn                 121          nasion y - gnathion y
upper face height n-sto          76           nasion y - stomion y
nose height n-sn                 54           nasion y - subnasale y
nasal tip protrusion sn-prn      20           pronasale z - subnasale z
nose width al-al                 35           2 * alar half-width
intercanthal width en-en         33           2 * endocanthion x
biocular width ex-ex             91           2 * exocanthion x
mouth width ch-ch                54           2 * cheilion x
upper lip height sn-sto          22           subnasale y - stomion y
mandible width go-go             97           2 * gonion half-width
face width zy-zy                 139          2 * zygion half-width
ear length sa-sba                63           vertical ear extent
ear width pra-pa                 35           horizontal ear extent
===============================  ===========  ===============================

The eyeball is 24 mm across (axial length of the adult eye, Bekerman et al. 2014, Anatomy
Research International). The tragion-to-vertex height (128 mm) and the vertical eye level
(12 mm above the tragion, from the Frankfort horizontal through porion and orbitale with the
orbitale about 12 mm below the pupil) place the face on the cranium.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["HeadShape", "LANDMARKS_MM"]


# --- Sagittal and frontal landmarks of the face [mm] (Farkas 1994 norms, see module doc) ---
Y_EYE = 12.0  # canthal line (endocanthion and exocanthion)
Y_NASION = Y_EYE + 10.0  # n
Y_SUBNASALE = Y_NASION - 54.0  # sn (n-sn = 54)
Y_STOMION = Y_SUBNASALE - 22.0  # sto (sn-sto = 22)
Y_GNATHION = Y_NASION - 121.0  # gn (n-gn = 121)
Y_VERTEX = 134.0  # v (vertex)
Y_NECK_CUT = -190.0  # the mesh ends here (boundary loop)

X_EN = 33.0 / 2  # endocanthion
X_EX = 91.0 / 2  # exocanthion
X_CH = 54.0 / 2  # cheilion
X_AL = 35.0 / 2  # alare
EYE_RADIUS = 12.0  # eyeball
X_PUPIL = 0.5 * (X_EN + X_EX) + 0.5

LANDMARKS_MM = {
    "y_eye": Y_EYE,
    "y_nasion": Y_NASION,
    "y_subnasale": Y_SUBNASALE,
    "y_stomion": Y_STOMION,
    "y_gnathion": Y_GNATHION,
    "x_en": X_EN,
    "x_ex": X_EX,
    "x_ch": X_CH,
}


def _pchip(knots):
    from scipy.interpolate import PchipInterpolator  # only when a head is built (not when loaded from its cache)

    k = np.asarray(sorted(knots), dtype=np.float64)
    return PchipInterpolator(k[:, 0], k[:, 1], extrapolate=True)


def _smooth_profile(knots, sigma=7.0):
    """A C2 profile over y: the monotone cubic through ``knots`` smoothed by a Gaussian of
    ``sigma`` [mm], so curvature has no kinks at the knots (no shading bands across rows)."""
    from scipy.interpolate import CubicSpline
    from scipy.ndimage import gaussian_filter1d

    base = _pchip(knots)
    ys = np.arange(-240.0, Y_VERTEX + 0.25, 0.25)
    vals = gaussian_filter1d(base(ys), sigma / 0.25, mode="nearest")
    top = ys > Y_VERTEX - 4 * sigma  # keep the closure at the vertex exact
    vals[top] = base(ys[top])
    return CubicSpline(ys, vals, extrapolate=True)


@functools.lru_cache(maxsize=1)
def _feature_profiles():
    """Profiles over y [mm] of the nose ridge height, nose half width, upper and lower lip
    protrusion (built once: :meth:`HeadShape.features` runs thousands of times per head)."""
    y_tip = Y_NASION - 39.0
    prof = _pchip([
        (Y_NASION + 6, 0.0), (Y_NASION, 2.0), (Y_NASION - 15, 9.0), (y_tip + 6, 22.0),
        (y_tip, 26.0), (y_tip - 5, 22.0), (Y_SUBNASALE + 4, 10.0), (Y_SUBNASALE, 3.0),
        (Y_SUBNASALE - 3, 0.0),
    ])
    half = _pchip([
        (Y_NASION + 6, 7.0), (Y_NASION, 8.0), (Y_NASION - 20, 9.5), (y_tip, 12.0),
        (Y_SUBNASALE + 4, 11.0), (Y_SUBNASALE - 3, 9.0),
    ])
    upper = _pchip([
        (Y_SUBNASALE, 0.0), (Y_SUBNASALE - 6, 3.5), (Y_STOMION + 9, 6.5), (Y_STOMION + 7, 9.5),
        (Y_STOMION + 3, 10.0), (Y_STOMION, 6.0),
    ])
    lower = _pchip([
        (Y_STOMION, 6.0), (Y_STOMION - 4, 11.0), (Y_STOMION - 9, 10.0), (Y_STOMION - 14, 4.0),
        (Y_STOMION - 21, 0.0),
    ])
    return prof, half, upper, lower


def _bump(d2):
    """Smooth compact bump of a squared normalized distance: (1 - d2)^3 inside, 0 outside."""
    return np.clip(1.0 - d2, 0.0, None) ** 3


def _gauss(x, y, cx, cy, sx, sy):
    return np.exp(-0.5 * (((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))


def _smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


@dataclass(frozen=True)
class _Eye:
    """One eyeball: centre [mm] and radius [mm]."""

    center: np.ndarray
    radius: float


class HeadShape:
    """Radial surface function of the default head (millimetres).

    All methods are vectorised over numpy arrays of equal shape.
    """

    def __init__(self):
        # Section 1: slice profiles over y. Columns: y [mm], value [mm].
        # Half width of the slice at the axis (side of head); cranium eu-eu 151 -> 75.5,
        # narrowing to the jaw (go-go 97 -> 48.5) and the neck.
        self._w = _smooth_profile([
            (-215, 68), (-165, 68), (-145, 64), (-125, 58), (-100, 56.5), (-80, 57), (-65, 58.5),
            (-50, 63), (-30, 69), (0, 74), (30, 77), (50, 77.5), (65, 77), (75, 75.5), (85, 72),
            (95, 67.5), (105, 61.7), (115, 51.4), (125, 37), (130, 25), (Y_VERTEX, 0.5),
        ])
        # Depth of the face in front of the axis at the midline, without nose, lips and chin
        # (those are features). Glabella at z = 103 (g-op 193 with op at -90).
        self._df = _smooth_profile([
            (-215, 76), (-190, 72), (-165, 61.5), (-145, 63), (-125, 63), (-115, 60), (-108, 72),
            (-104, 86), (-95, 95), (-85, 93.6), (-75, 96.5), (-65, 101), (-55, 104), (-45, 102),
            (-35, 104), (-25, 100), (-15, 98), (-5, 96), (5, 94), (15, 96), (25, 102), (35, 103),
            (45, 103.5), (55, 101.4), (65, 99), (75, 95.2), (85, 91.5), (95, 83.3), (105, 71.7),
            (115, 62), (125, 39.4), (130, 25), (Y_VERTEX, 0.5),
        ])
        # Depth behind the axis (occiput; opisthocranion 90 behind the axis near y = 35).
        self._db = _smooth_profile([
            (-215, 62), (-145, 64), (-125, 64), (-105, 69), (-85, 67), (-65, 65.5), (-45, 67),
            (-25, 73), (-5, 82), (15, 87.5), (35, 90), (55, 89), (75, 83), (95, 75), (105, 64),
            (115, 57), (125, 43), (130, 30), (Y_VERTEX, 0.5),
        ])
        # Axis offset: the neck sits behind the face.
        self._zc = _smooth_profile([
            (-215, -42), (-165, -40), (-145, -35), (-125, -23), (-110, -12), (-95, -3), (-80, 0),
            (Y_VERTEX, 0),
        ])
        # Superellipse exponent of the front half (2 = ellipse, larger = flatter face).
        self._nf = _smooth_profile([
            (-215, 2.0), (-125, 2.0), (-105, 1.6), (-90, 1.9), (-75, 2.3), (-40, 2.6), (0, 2.7),
            (30, 2.3), (60, 2.1), (90, 2.0), (Y_VERTEX, 2.0),
        ])
        self.eyes = (
            _Eye(np.array([X_PUPIL, Y_EYE + 0.5, 83.5]), EYE_RADIUS),
            _Eye(np.array([-X_PUPIL, Y_EYE + 0.5, 83.5]), EYE_RADIUS),
        )

    # ------------------------------------------------------------------ Section 1: base
    def axis_z(self, y):
        return self._zc(y)

    def base_radius(self, phi, y):
        """Superellipse slice radius [mm] at azimuth ``phi`` [rad] and height ``y`` [mm]."""
        w = np.maximum(self._w(y), 0.5)
        front = np.cos(phi) >= 0.0
        d = np.where(front, self._df(y), self._db(y))
        d = np.maximum(d, 0.5)
        n = np.where(front, self._nf(y), 2.3)
        s = np.abs(np.sin(phi)) / w
        c = np.abs(np.cos(phi)) / d
        return (s**n + c**n) ** (-1.0 / n)

    # ------------------------------------------------------------------ Section 2: features
    def features(self, phi, y, x, z):
        """Radial offset [mm] of the facial features at base point (x, y, z)."""
        front = np.clip(np.cos(phi) * 4.0, 0.0, 1.0)  # features live on the front only
        ax = np.abs(x)
        out = np.zeros_like(x)

        # Brow ridge (supraorbital torus) and eye sockets.
        out += 3.0 * _gauss(ax, y, 28.0, Y_EYE + 17.0, 20.0, 6.0)
        out -= 7.0 * _gauss(ax, y, X_PUPIL, Y_EYE + 1.0, 14.0, 9.0)
        # Cheekbones (zygomatic prominence, lateral to and below the eyes).
        out += 4.0 * _gauss(ax, y, 50.0, Y_EYE - 22.0, 14.0, 14.0)

        # Nose: a ridge from nasion to the tip (pronasale), cross-section (1 - s^2)^1.5.
        prof, half, upper, lower = _feature_profiles()
        inside_y = (y < Y_NASION + 6) & (y > Y_SUBNASALE - 3)
        s2 = (x / half(y)) ** 2
        out += np.where(inside_y, prof(y) * np.clip(1.0 - s2, 0.0, None) ** 1.5, 0.0)
        # Alae (nose wings) and nostrils.
        out += 7.0 * _bump(((ax - (X_AL - 5.0)) / 7.0) ** 2 + ((y - (Y_SUBNASALE + 5.0)) / 7.0) ** 2)
        out -= 4.0 * _bump(((ax - 6.0) / 3.5) ** 2 + ((y - (Y_SUBNASALE + 2.5)) / 2.5) ** 2)

        # Lips: upper lip (sn to sto) and lower lip (sto to the labiomental fold).
        mouth_w = X_CH + 6.0
        lat = np.clip(1.0 - (x / mouth_w) ** 2, 0.0, None) ** 1.6
        lip = np.where(
            (y <= Y_SUBNASALE) & (y >= Y_STOMION), upper(np.clip(y, Y_STOMION, Y_SUBNASALE)), 0.0
        ) + np.where(
            (y < Y_STOMION) & (y >= Y_STOMION - 21), lower(np.clip(y, Y_STOMION - 21, Y_STOMION)), 0.0
        )
        out += lip * lat
        # Philtrum groove.
        out -= 1.0 * _gauss(x, y, 0.0, Y_SUBNASALE - 9.0, 3.0, 5.0)

        # Chin (mental protuberance) and the labiomental sulcus above it.
        out += 7.0 * _gauss(x, y, 0.0, Y_GNATHION + 13.0, 17.0, 10.0)

        out *= front

        # Ears (both sides): elliptical rim with a concha, on the side of the head.
        for side in (1.0, -1.0):
            out += self._ear(side * phi, y)
        return out

    def _ear(self, phi, y):
        """Ear relief [mm] on the +x side at azimuth ``phi`` (mirror by negating phi)."""
        # Ear centre 15 mm behind the tragion on the side (phi ~ 97 deg), sa-sba 63, pra-pa 35.
        u = (phi - np.deg2rad(99.0)) * 75.0 / 17.5
        v = (y - (-5.0)) / 31.5
        s = np.sqrt(u * u + v * v)
        rim = 12.0 * _smoothstep(1.05, 0.75, s)
        concha = 9.0 * np.exp(-(((u + 0.25) / 0.35) ** 2 + ((v + 0.1) / 0.45) ** 2))
        return rim - concha

    # ------------------------------------------------------------------ eyes (lids hug them)
    def _eyeball_radius(self, phi, y, eye):
        """Radial distance [mm] from the slice axis to the front of ``eye`` along phi (NaN where
        the ray misses it) and how squarely the ray meets it: the ray-sphere discriminant over
        the squared radius, 0 at the silhouette, 1 through the centre."""
        zc = self.axis_z(y)
        d = np.stack([np.sin(phi), np.zeros_like(phi), np.cos(phi)], -1)
        o = np.stack([np.zeros_like(phi), y, zc], -1)
        oc = o - eye.center
        b = np.sum(oc * d, -1)
        c = np.sum(oc * oc, -1) - eye.radius**2
        disc = b * b - c
        dist = np.where(disc > 0, -b + np.sqrt(np.maximum(disc, 0.0)), np.nan)
        return dist, np.clip(disc / eye.radius**2, 0.0, 1.0)

    def eye_weight(self, x, y):
        """1 where the lids lie on the eyeball, fading to 0 on the surrounding face."""
        w = np.zeros_like(x)
        for sign in (1.0, -1.0):
            u = (x - sign * X_PUPIL) / (0.5 * (X_EX - X_EN) + 2.0)
            v = (y - Y_EYE) / 9.0
            w = np.maximum(w, _smoothstep(1.25, 0.85, np.sqrt(u * u + v * v)))
        return w

    # ------------------------------------------------------------------ full surface
    def radius(self, phi, y):
        """Final slice radius [mm] (base + features, lids on the eyeballs)."""
        phi = np.asarray(phi, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64) + 0.0 * phi
        r0 = self.base_radius(phi, y)
        x0 = r0 * np.sin(phi)
        z0 = self.axis_z(y) + r0 * np.cos(phi)
        r = r0 + self.features(phi, y, x0, z0)
        (l0, q0), (l1, q1) = (self._eyeball_radius(phi, y, e) for e in self.eyes)
        lid = np.fmax(l0, l1)
        # the lids lie on the eyeball only where the ray meets it squarely; toward its silhouette
        # the weight fades to 0, so the surface stays continuous (no cliff, no fold)
        square = _smoothstep(0.0, 0.35, np.maximum(q0, q1))
        we = self.eye_weight(x0, y) * (np.cos(phi) > 0.3) * square  # the eyes are on the front only
        lid_r = np.where(np.isfinite(lid) & (lid > 0), lid + 1.2, r)
        return np.where(we > 0, (1 - we) * r + we * lid_r, r)

    def point(self, phi, y):
        """Surface point(s) [mm], shape (..., 3)."""
        phi = np.asarray(phi, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64) + 0.0 * phi
        r = self.radius(phi, y)
        return np.stack([r * np.sin(phi), y, self.axis_z(y) + r * np.cos(phi)], -1)

    def phi_at_x(self, x, y, *, back=False):
        """Azimuth [rad] of the surface point with lateral coordinate ``x`` on slice ``y``.

        Solved by bisection on the front half (or the back half with ``back=True``).
        """
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64) + 0.0 * x
        sgn = np.where(x >= 0, 1.0, -1.0)
        lo = np.zeros_like(x)
        hi = np.full_like(x, np.pi / 2)
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            ph = sgn * (np.pi - mid if back else mid)
            xm = np.abs(self.radius(ph, y) * np.sin(ph))
            left = xm < np.abs(x)
            lo = np.where(left, mid, lo)
            hi = np.where(left, hi, mid)
        mid = 0.5 * (lo + hi)
        return sgn * (np.pi - mid if back else mid)

    def skull_depth(self, phi, y):
        """Soft-tissue depth [mm] from the skin to the skull along the inward radial direction.

        Mean adult tissue depths of forensic facial reconstruction (De Greef et al. 2006,
        Forensic Sci. Int. 157S: supraglabella 5.5, nasion 6.5, mid-philtrum 11-12,
        mental eminence 11, mid-masseter 17, supraorbital 6, zygomatic 7, vertex 5-6 mm);
        over the nose and lips the protruding cartilage and lip tissue are added, and the
        orbit is bridged at the depth of the eyeball's back (the skull has an opening there).
        """
        phi = np.asarray(phi, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64) + 0.0 * phi
        r0 = self.base_radius(phi, y)
        x = r0 * np.sin(phi)
        front = np.clip(np.cos(phi) * 3.0, 0.0, 1.0)
        ax = np.abs(x)
        d = np.full_like(x, 5.5)  # cranial vault
        d += front * (
            1.0 * _gauss(x, y, 0, Y_NASION, 12, 8)
            + 6.0 * _gauss(x, y, 0, Y_STOMION, 28, 12)
            + 5.5 * _gauss(x, y, 0, Y_GNATHION + 13, 18, 10)
            + 11.5 * _gauss(ax, y, 55, Y_STOMION + 5, 18, 22)  # masseter / buccal fat
            + 2.0 * _gauss(ax, y, 45, Y_EYE - 20, 12, 10)
        )
        # Neck: soft tissue over the cervical spine is deep; keep the skull out of it.
        d += 20.0 * _smoothstep(-100.0, -130.0, y)
        r = self.radius(phi, y)
        feat = r - r0  # nose, lips, ears are soft tissue over the bone
        return d + np.clip(feat, 0.0, None) * front + np.clip(feat, 0.0, None) * (1 - front)
