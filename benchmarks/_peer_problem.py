"""The peers' problem (benchmarks/peers.py's module doc): a face rig's tets, pinned nodes, supports and the
muscles' pull at a preset's converged shape as a dead load, in NumPy and SI; shared by ``peers`` and ``batch``."""

from __future__ import annotations

import numpy as np

SUPPORT_LENGTH = 1.0  # m: rest length of Newton's long support springs


def _lame(E, nu):
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))


def export_problem(fr, preset: str) -> dict:
    """The peer problem of ``preset`` on the face rig ``fr`` (module doc), numpy, SI."""
    import facewarp
    from facewarp.physics import MaterialPhysical, ModelBuilder, isotropic_moduli

    mat = MaterialPhysical()
    sim = facewarp.FaceSimulator(fr, device="cpu", material=mat, tolerance=1e-7,
                                 solver_options=dict(spring_tolerance=1e-4, max_iterations=500))
    sim.set_activations(facewarp.preset(preset))
    for _ in range(10):
        sim.step()
    X = sim.positions()
    sp = sim.muscles.springs  # Eq. 6.4.1 springs at the solution: 1/2 k_m w (|p - x| - l0)^2
    node = sp.node.numpy()
    d = sp.point.numpy().astype(np.float64) - X[node]
    L = np.linalg.norm(d, axis=1)
    k = sp.stiffness.numpy().astype(np.float64)
    f = (k * (L - sp.rest_length.numpy()) / np.maximum(L, 1e-12))[:, None] * d
    force = np.zeros_like(X)
    np.add.at(force, node, f)

    pinned = fr.fixed | fr.held
    b = ModelBuilder(fr.nodes, fr.tets, layer=fr.layer, fixed=pinned, material=mat)
    sn = np.asarray(fr.support_nodes)
    normal = fr.support_normal / np.linalg.norm(fr.support_normal, axis=1, keepdims=True)
    k_support = mat.support_modulus * b.vertex_area[sn]
    # per-tet linear moduli: the mean distance modulus of the tet's six edges
    T = np.asarray(fr.tets)
    lay = np.asarray(fr.layer)[T]
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    cls = np.stack([np.where(lay[:, i] != lay[:, j], 2, np.where(lay[:, i] == 0, 0, 1)) for i, j in pairs], 1)
    dmod = np.asarray(mat.distance_modulus)[cls].mean(1)
    E, nu = np.array([isotropic_moduli(float(dm), mat.area_modulus, mat.volume_modulus) for dm in dmod]).T
    mu, lam = _lame(E, nu)
    vol = b.tet_rest_volumes
    mu_m, lam_m = np.average(mu, weights=vol), np.average(lam, weights=vol)
    E_m = mu_m * (3 * lam_m + 2 * mu_m) / (lam_m + mu_m)
    nu_m = lam_m / (2 * (lam_m + mu_m))
    return {
        "nodes": np.asarray(fr.nodes, np.float64), "tets": T.astype(np.int64), "layer": np.asarray(fr.layer),
        "pinned": pinned, "mass_all": b.mass, "mass": np.where(pinned, 0.0, b.mass),
        "young": E, "poisson": nu, "k_mu": mu, "k_lambda": lam, "k_damp": mat.stiffness_damping * mu,
        "young_mean": E_m, "poisson_mean": nu_m, "damping_rate": mat.damping_rate,
        "stiffness_damping": mat.stiffness_damping, "force": force,
        "support_node": sn, "support_normal": normal, "support_k": k_support,
        "spring_node": sn, "spring_anchor": fr.nodes[sn] - SUPPORT_LENGTH * normal, "spring_k": k_support,
        "spring_rest": np.full(len(sn), SUPPORT_LENGTH), "preset_shape": X,
    }
