"""Material profiles of the skin model: Table 6.3 as it stands, and the same energies in physical units.

Both profiles keep the thesis's energies (Sec. 6.4.2): per tet edge the distance energy of
Eq. 6.4.4 with the nonlinear stiffness of Eq. 6.4.6, per tet face the area energy of Eq. 6.4.7,
per tet the volume energy of Eq. 6.4.8, each ``E = 1/2 k C^2`` of a dimensionless relative
strain C. They differ in where the coefficients come from.

``thesis`` (:class:`MaterialThesis`): Table 6.3's numbers in SI as they stand. Every node weighs
0.5 kg and every element has the same k [J] whatever its size, so an edge of rest length D0 is a
spring ``k0 / D0^2`` [N/m]: the material stiffens as the mesh is refined (about 2e8-2e9 Pa of
effective modulus on the default head) and its 2,448 nodes weigh 1.2 t. Damping is Table 6.3's
``k_damping`` 0.002 per substep of the Verlet reference (a rate of ``0.002 / dt``), plus the edge
dashpot that kept the stiff layer from ringing. ``solver="verlet", material="thesis"`` is the
behaviour before the physical profile existed.

``physical`` (:class:`MaterialPhysical`, the default): the same energies with coefficients from
material constants, converted per element so that refining the mesh does not change the
material:

* mass: lumped from the tissue density, ``m_i = rho * sum(V_t / 4)`` over the node's tets;
* stiffness: each term is given as a modulus mu [Pa] (an energy density per unit squared
  strain) and each element gets ``k = mu * (its share of the tet volume)`` [J]: an edge the sixth
  of each tet it belongs to, a face the quarter, a tet its own volume. Then ``E = 1/2 k C^2``
  summed over a region under a uniform strain is ``1/2 mu <C^2> volume``, whatever the element
  size (for the distance energy an edge of rest length L is a spring ``mu V_e / L^2`` [N/m]);
* damping: a mass-proportional rate ``alpha`` [1/s] on the velocity relative to the cranium and a
  stiffness-proportional (Rayleigh) time ``beta`` [s], applied per element as a dashpot on the
  strain rate, ``F = -beta k dC/dt grad C`` (it damps deformation only, never a rigid motion);
  both are independent of the step;
* springs to bone (held and supported inner-sheet nodes) and muscle springs: a stiffness per unit
  area of the inner sheet [N/m^3] times the node's share of that area.

Linear response of the three energies. Under a small uniform strain eps and edge, face-normal
directions spread evenly, the mean squared constraints are
``<C_dist^2> = (2 eps:eps + tr(eps)^2) / 15``, ``<C_area^2> = (6 tr(eps)^2 + 2 eps:eps) / 15`` and
``C_vol^2 = tr(eps)^2``, so the energy density ``1/2 sum(mu <C^2>)`` is that of an isotropic
linear material with Lame constants

    lambda = mu_dist / 15 + 2 mu_area / 5 + mu_vol,   G = (mu_dist + mu_area) / 15.

The defaults keep Table 6.3's proportions (distance 15 : 10 : 5 outer / inner / cross, area 7.5,
volume 7.5) with one scale of 20 kPa per Table-6.3 joule: mu_dist = 300 / 200 / 100 kPa,
mu_area = mu_vol = 150 kPa, which gives the outer layer Young's modulus ``E = 87 kPa`` and Poisson
ratio 0.44 (inner 68 kPa, 0.45): in the range measured for skin in vivo, 1e4-1e6 Pa (Agache et
al. 1980, torsion, 0.42-0.85 MPa; Diridollou et al. 2000, suction, ~0.1 MPa; Pailler-Mattei et al.
2008, indentation, dermis 35 kPa, hypodermis 2 kPa; Luboz et al. 2014, aspiration of facial soft
tissue, tens of kPa), nearly incompressible as soft tissue is (nu 0.45-0.49). See
:func:`isotropic_moduli`.

The even spread is an assumption the skin layer does not meet: it is one tet thick (2 mm) under
7.2 / 3.7 / 2.0 mm edges at template levels 0 / 1 / 2, and a flat tet's edges and faces carry
little transverse shear (in the layer's frame 5.3 / 9.1 / 9.9 kPa against the nominal 23-30 kPa;
:func:`linear_stiffness`, ``benchmarks/material_levels.py``), so the material still changes with the
mesh; the optional shear term (``MaterialPhysical.shear_modulus``) is the same for any tet shape.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from ..geometry.tets import TET_EDGES as _TET_EDGES, TET_FACES as _TET_FACES

__all__ = [
    "CONTACT_MODULUS",
    "CONTACT_MUSCLE_RATIO",
    "EDGE_DAMPING",
    "MATERIALS",
    "linear_stiffness",
    "MaterialPhysical",
    "MaterialThesis",
    "isotropic_moduli",
    "material_profile",
]

EDGE_DAMPING = 500.0
"""Dashpot along every tet edge [N s/m] of the face's thesis profile (Eq. 6.4.5 on the relative
velocity; :meth:`~facewarp._src.physics.builder.ModelBuilder.add_face`). Table 6.3's per-substep damping alone leaves the stiff skin ringing for many periods when the jaw moves the
held nodes; about a quarter of the edges' critical damping 2 sqrt(k0 / D0^2 m) calms it without
slowing rigid motion (and stays far below the explicit limit 2 m / dt)."""

CONTACT_MODULUS = 2.0e9
"""Contact stiffness per unit sheet area [N/m^3] (:mod:`facewarp._src.physics.contact`)."""
CONTACT_MUSCLE_RATIO = 50.0
"""A node's contact spring is at least this many times the muscle springs on it (:mod:`facewarp._src.physics.contact`)."""

#: Density of soft tissue [kg/m^3] (skin and subcutis ~1,050-1,150; ICRP 89 "soft tissue" 1,030).
TISSUE_DENSITY = 1100.0


def isotropic_moduli(distance: float, area: float, volume: float) -> tuple[float, float]:
    """Young's modulus [Pa] and Poisson ratio of the distance / area / volume energies' moduli.

    The linear response of ``1/2 (mu_d <C_dist^2> + mu_a <C_area^2> + mu_v C_vol^2)`` under a
    small uniform strain with evenly spread element directions (module doc):
    ``lambda = mu_d / 15 + 2 mu_a / 5 + mu_v``, ``G = (mu_d + mu_a) / 15``.

    Args:
        distance, area, volume: the three moduli [Pa].

    Returns:
        ``(E, nu)``: Young's modulus [Pa] and Poisson ratio.
    """
    lam = distance / 15.0 + 2.0 * area / 5.0 + volume
    g = (distance + area) / 15.0
    if g <= 0.0:
        return 0.0, 0.5
    return g * (3.0 * lam + 2.0 * g) / (lam + g), lam / (2.0 * (lam + g))


def _check_nonneg(name: str, value, *, positive: bool = False) -> None:
    vals = np.atleast_1d(np.asarray(value, dtype=np.float64))
    ok = np.isfinite(vals).all() and ((vals > 0).all() if positive else (vals >= 0).all())
    if not ok:
        want = "> 0" if positive else ">= 0"
        raise InputError(f"{name} must be finite and {want}, got {value!r}")


@dataclass(frozen=True)
class MaterialThesis:
    """Table 6.3 as it stands, in SI (see the module doc).

    Attributes:
        mass: Node mass [kg] (Table 6.3: 0.5).
        k0_outer, k0_inner, k0_cross: Basic distance stiffness k0 [J] of Eq. 6.4.6 (15, 10, 5).
        k_area, k_volume: Area and volume stiffness [J] (7.5, 7.5).
        damping: Table 6.3 ``k_damping``: velocity loss per substep of the Verlet reference
            (0.002); the model's rate is ``damping / dt`` with the reference substep dt.
        edge_damping: Dashpot along every edge on the relative velocity [N s/m] (Eq. 6.4.5 per
            spring). Table 6.3 has none (0); the face simulator's thesis profile adds
            :data:`EDGE_DAMPING` (500), which keeps the stiff layer
            from ringing when the jaw moves held nodes.
        muscle_stiffness: Muscle spring stiffness k_m of Eq. 6.4.1 [N/m] shared by the springs
            on a node (None: the rig's own, :data:`~facewarp._src.anatomy.rig.MUSCLE_STIFFNESS`).
    """

    name: str = "thesis"
    mass: float = 0.5
    k0_outer: float = 15.0
    k0_inner: float = 10.0
    k0_cross: float = 5.0
    k_area: float = 7.5
    k_volume: float = 7.5
    damping: float = 0.002
    edge_damping: float = 0.0
    muscle_stiffness: float | None = None

    def __post_init__(self):
        _check_nonneg("mass", self.mass, positive=True)
        for n in ("k0_outer", "k0_inner", "k0_cross", "k_area", "k_volume", "edge_damping"):
            _check_nonneg(n, getattr(self, n))
        if not (np.isfinite(self.damping) and 0.0 <= self.damping < 1.0):
            raise InputError(f"damping must lie in [0, 1) (velocity loss per substep), got {self.damping!r}")
        if self.muscle_stiffness is not None:
            _check_nonneg("muscle_stiffness", self.muscle_stiffness, positive=True)


@dataclass(frozen=True)
class MaterialPhysical:
    """The thesis's energies in physical units (see the module doc for the conversion).

    Attributes:
        density: Tissue density [kg/m^3] (1,100).
        distance_modulus: Modulus mu [Pa] of the distance energy for outer-outer, inner-inner and
            cross-layer edges (300, 200, 100 kPa: Table 6.3's 15 : 10 : 5).
        area_modulus: Modulus [Pa] of the area energy (150 kPa).
        volume_modulus: Modulus [Pa] of the volume energy (150 kPa); the bulk modulus of the
            volume term alone.
        damping_rate: Mass-proportional damping alpha [1/s] on the velocity relative to the
            cranium (50: a 20 ms decay, about a frame).
        stiffness_damping: Rayleigh stiffness-proportional damping beta [s] (2e-5: critical
            damping of the layer's fastest modes, ~1e5 rad/s, while the response at frame rates
            stays quasi-static as Sec. 6.4.4 intends).
        hold_modulus: Stiffness per unit area [N/m^3] of the springs that tie held inner-sheet
            nodes to the bone (their target): a node gets ``hold_modulus * area`` (2.5e7: a
            1 mm offset costs 25 kPa; the thesis profile's holds on the default head in the same
            proportion to its tissue).
        support_modulus: Stiffness per unit area [N/m^3] of the sliding support of the other
            inner-sheet nodes (acts along their rest normal only; 2.5e7).
        muscle_modulus: Muscle spring stiffness per unit inner-sheet area [N/m^3] (Eq. 6.4.1's
            k_m of a node is ``muscle_modulus * area``, shared by the muscles on the node; 4e7:
            a 5 mm stretched spring pulls with 200 kPa, the order of the largest active stress
            of skeletal muscle, and the thesis profile's 1e7 N/m per node in the same proportion
            to its tissue on levels 0 and 1).
        shear_modulus: Shear modulus mu [Pa] of an optional fourth term that is not in the
            thesis: per tet ``mu V0 |G|^2`` of its Green strain G (:mod:`.model`, "Shear term";
            Saint Venant-Kirchhoff with lambda = 0), damped like the others (Rayleigh beta).
            Default 0 (off). The distance and area energies give a thin layer of flat tets
            little transverse shear, and less the flatter the tets
            (:func:`linear_stiffness`; ``benchmarks/material_levels.py``: 5.3 / 9.1 / 9.9 kPa at
            levels 0 / 1 / 2 of the default head), so the material still changes with the mesh;
            this term is the same material for any tet shape. With
            ``distance_modulus=(0, 0, 0), area_modulus=0`` and ``shear_modulus=3e4`` (volume
            energy and shear term only) levels 1 and 2 of the default head agree per FDP within
            1.8-4.9 % on the five Table 6.4 presets (3.9-23.1 % with the default energies;
            ``benchmarks/solver_accuracy.py --shear-modulus``). Not the default: the muscles and
            the presets' amplitudes are calibrated with the thesis's energies.
    """

    name: str = "physical"
    density: float = TISSUE_DENSITY
    distance_modulus: tuple = (3.0e5, 2.0e5, 1.0e5)
    area_modulus: float = 1.5e5
    volume_modulus: float = 1.5e5
    damping_rate: float = 50.0
    stiffness_damping: float = 2.0e-5
    hold_modulus: float = 2.5e7
    support_modulus: float = 2.5e7
    muscle_modulus: float = 4.0e7
    shear_modulus: float = 0.0

    def __post_init__(self):
        _check_nonneg("density", self.density, positive=True)
        d = np.asarray(self.distance_modulus, dtype=np.float64)
        if d.shape != (3,):
            raise InputError(f"distance_modulus must be 3 values (outer, inner, cross) [Pa], got {self.distance_modulus!r}")
        _check_nonneg("distance_modulus", d)
        for n in ("area_modulus", "volume_modulus", "damping_rate", "stiffness_damping", "hold_modulus",
                  "support_modulus", "shear_modulus"):
            _check_nonneg(n, getattr(self, n))
        _check_nonneg("muscle_modulus", self.muscle_modulus, positive=True)
        if d.max() + self.area_modulus + self.volume_modulus + self.shear_modulus <= 0.0:
            raise InputError("distance_modulus, area_modulus, volume_modulus and shear_modulus are all 0: "
                             "the tissue has no stiffness")

    def young_poisson(self, edge_class: int = 0) -> tuple[float, float]:
        """Young's modulus [Pa] and Poisson ratio of one edge class's layer (:func:`isotropic_moduli`)."""
        return isotropic_moduli(float(self.distance_modulus[edge_class]), self.area_modulus, self.volume_modulus)


MATERIALS = {"physical": MaterialPhysical(), "thesis": MaterialThesis()}
"""The named profiles: ``physical`` (default of :class:`~facewarp.FaceSimulator`) and ``thesis``."""


def material_profile(material) -> MaterialPhysical | MaterialThesis:
    """A profile by name (``"physical"``, ``"thesis"``) or a profile object, checked.

    Raises:
        InputError: an unknown name or another type.
    """
    if isinstance(material, (MaterialPhysical, MaterialThesis)):
        return material
    if isinstance(material, str) and material in MATERIALS:
        return MATERIALS[material]
    raise InputError(f"material: expected one of {sorted(MATERIALS)} or a MaterialPhysical / MaterialThesis, "
                     f"got {material!r}")


_SQRT2 = float(np.sqrt(2.0))


def _mandel(S: np.ndarray) -> np.ndarray:
    """Mandel vectors (..., 6) of symmetric matrices (..., 3, 3): (xx, yy, zz, sqrt2 yz, sqrt2 xz, sqrt2 xy)."""
    return np.stack([S[..., 0, 0], S[..., 1, 1], S[..., 2, 2], _SQRT2 * S[..., 1, 2], _SQRT2 * S[..., 0, 2],
                     _SQRT2 * S[..., 0, 1]], axis=-1)


def linear_stiffness(builder, frames=None) -> np.ndarray:
    """The material each tet of a model stands for: the stiffness tensor of its energies at rest.

    Under a small uniform strain eps every constraint of the thesis's energies is linear in eps:
    an edge along the unit vector n has ``C = n . eps n``, a face with unit normal m
    ``C = tr(eps) - m . eps m``, a tet ``C = tr(eps)``; so ``E = 1/2 k C^2`` is the quadratic form
    ``1/2 k (a . e)^2`` of the strain's Mandel vector e, with a = Mandel(n n^T), Mandel(I - m m^T),
    Mandel(I). Each unique element's coefficient k is split among the tets that share it in
    proportion to their volumes (for the physical profile this is exactly the per-tet share the
    profile gives), and a tet's tensor is ``sum k a a^T / V`` [Pa]: ``1/2 e^T C e`` is the
    energy density of that strain. An isotropic material has ``C = lambda 1 1^T + 2 G I`` in
    these coordinates; the module doc's Lame constants are the average over evenly spread
    element directions, which a thin layer of flat tets is not.

    Args:
        builder: A :class:`~facewarp._src.physics.builder.ModelBuilder` (its rest geometry and
            per-element coefficients).
        frames: Optional local axes per tet, shape (k, 3, 3), float, rows orthonormal
            (e.g. two tangents and the layer's thickness direction): the tensors are then given
            in those axes. None: world axes.

    Returns:
        Stiffness tensors in Mandel notation, shape (k, 6, 6), float64 [Pa].

    Raises:
        InputError: ``frames`` of the wrong shape or not orthonormal.
    """
    V = np.asarray(builder.vertices, dtype=np.float64).astype(np.float32).astype(np.float64)
    T = np.asarray(builder.tets, dtype=np.int64)
    vol = np.asarray(builder.tet_rest_volumes, dtype=np.float64)
    X = V[T]  # (k, 4, 3)
    if frames is not None:
        R = np.asarray(frames, dtype=np.float64)
        if R.shape != (len(T), 3, 3):
            raise InputError(f"frames must have shape ({len(T)}, 3, 3), got {R.shape}")
        if not np.allclose(np.einsum("kab,kcb->kac", R, R), np.eye(3), atol=1e-6):
            raise InputError("frames must hold orthonormal rows (local axes per tet)")
        X = np.einsum("kab,kib->kia", R, X)

    # each unique element's k over its tets, by volume
    def per_tet(inv, k):
        vsum = np.bincount(inv.ravel(), weights=np.repeat(vol, inv.shape[1]), minlength=len(k))
        return np.asarray(k, np.float64)[inv] * vol[:, None] / vsum[inv]

    ke = per_tet(builder.tet_edge_index, builder.edge_k0)  # (k, 6)
    kf = per_tet(builder.tet_face_index, builder.face_k)  # (k, 4)
    e = X[:, _TET_EDGES[:, 1]] - X[:, _TET_EDGES[:, 0]]
    n = e / np.linalg.norm(e, axis=2, keepdims=True)
    f = X[:, _TET_FACES]
    m = np.cross(f[:, :, 1] - f[:, :, 0], f[:, :, 2] - f[:, :, 0])
    m /= np.linalg.norm(m, axis=2, keepdims=True)
    a_e = _mandel(n[..., :, None] * n[..., None, :])
    a_f = _mandel(np.eye(3) - m[..., :, None] * m[..., None, :])
    a_v = _mandel(np.eye(3))
    C = np.einsum("kj,kja,kjb->kab", ke, a_e, a_e) + np.einsum("kj,kja,kjb->kab", kf, a_f, a_f)
    C += np.asarray(builder.tet_k, np.float64)[:, None, None] * np.outer(a_v, a_v)
    # the shear term 1/2 k_s |G|^2 is 1/2 k_s e.e at small strain: k_s I in any axes
    C += np.asarray(builder.tet_shear_k, np.float64)[:, None, None] * np.eye(6)
    return C / vol[:, None, None]


__all__ += ["TABLE_6_3", "TISSUE_DENSITY"]


TABLE_6_3 = {
    "mass": 0.5,  # kg per node
    "damping": 0.002,  # per-substep velocity loss of the Verlet reference (dimensionless)
    "k0_outer": 15.0,  # J
    "k0_inner": 10.0,  # J
    "k0_cross": 5.0,  # J
    "k_area": 7.5,  # J
    "k_volume": 7.5,  # J
}
"""Table 6.3 of the thesis in SI as it stands (the ``thesis`` material profile)."""
