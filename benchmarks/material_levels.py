"""The material the skin's tet layer stands for, per template level (issue 10: "refining the mesh
does not change the material").

    python -m benchmarks.material_levels [--levels 0 1 2] [--materials physical thesis]

For each level of the default head and each material profile, the tissue energies' stiffness at
rest (:func:`facewarp.physics.linear_stiffness`) in each tet's layer frame (two tangents and the
thickness direction, the tet's edge from an outer node to its own inner copy), averaged over the
tets by volume [Pa]: in-plane stretch ``C11`` (mean of xx and yy), through-thickness stretch
``C33``, in-plane shear ``G12`` (C66 / 2) and transverse shear ``G13`` (mean of C44 and C55, / 2),
beside the isotropic values the profile's moduli stand for with evenly spread element directions
(:func:`facewarp.physics.isotropic_moduli`). Also the tets' median edge length and the layer's
mean thickness: the flatter the tets (edge / thickness), the less transverse shear the edges and
faces can carry, however their coefficients are chosen: ``best_isotropic_fit_residual_median`` is
how far the best nonnegative choice of a tet's 11 coefficients stays from the inner layer's
isotropic tensor (relative, every strain mode weighted alike; median over the tets).

Writes benchmarks/results/material_levels.json.
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks._common import add_case_args, save


def layer_frames(nodes, tets, layer) -> np.ndarray:
    """Per tet: rows (tangent, tangent, thickness direction), shape (k, 3, 3).

    Node ``l * p + i`` is sheet ``l`` under frontal vertex ``i`` (p outer nodes); every tet of
    the extruded layer has one edge from an outer node to its own inner copy."""
    p = int((np.asarray(layer) == 0).sum())
    T = np.asarray(tets)
    src = T % p
    nz = np.zeros((len(T), 3))
    for a in range(4):
        for b in range(4):
            m = (src[:, a] == src[:, b]) & (T[:, a] < T[:, b])
            nz[m] = nodes[T[m, a]] - nodes[T[m, b]]
    nz /= np.linalg.norm(nz, axis=1, keepdims=True)
    helper = np.where(np.abs(nz[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    ex = np.cross(nz, helper)
    ex /= np.linalg.norm(ex, axis=1, keepdims=True)
    return np.stack([ex, np.cross(nz, ex), nz], axis=1)


_TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def best_fit_residual(X, lam: float, g: float) -> np.ndarray:
    """Per tet: how far the best choice of its 11 coefficients (6 edges, 4 faces, 1 volume; each
    >= 0) comes from the isotropic tensor (lam, g) [Pa], relative, in the norm scaled by the
    target (``|C^-1/2 (sum k a a^T) C^-1/2 - I| / |I|``: every mode of strain counts alike).

    X: tet corners, shape (k, 4, 3) [m]. Returns shape (k,), float64."""
    from scipy.optimize import nnls

    r2 = np.sqrt(2.0)

    def mandel(S):
        return np.stack([S[..., 0, 0], S[..., 1, 1], S[..., 2, 2], r2 * S[..., 1, 2], r2 * S[..., 0, 2],
                         r2 * S[..., 0, 1]], -1)

    e = X[:, _TET_EDGES[:, 1]] - X[:, _TET_EDGES[:, 0]]
    n = e / np.linalg.norm(e, axis=2, keepdims=True)
    f = X[:, _TET_FACES]
    m = np.cross(f[:, :, 1] - f[:, :, 0], f[:, :, 2] - f[:, :, 0])
    m /= np.linalg.norm(m, axis=2, keepdims=True)
    A = np.concatenate([mandel(n[..., :, None] * n[..., None, :]), mandel(np.eye(3) - m[..., :, None] * m[..., None, :]),
                        np.broadcast_to(mandel(np.eye(3)), (len(X), 1, 6))], axis=1)  # (k, 11, 6)
    i = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0]) / np.sqrt(3.0)
    pv = np.outer(i, i)
    scale = pv / np.sqrt(3.0 * (lam + 2.0 * g / 3.0)) + (np.eye(6) - pv) / np.sqrt(2.0 * g)
    A = A @ scale.T
    iu = np.triu_indices(6)
    w = np.where(iu[0] == iu[1], 1.0, r2)
    M = (A[:, :, :, None] * A[:, :, None, :])[:, :, iu[0], iu[1]] * w  # (k, 11, 21)
    b = np.eye(6)[iu] * w
    res = np.empty(len(X))
    for t in range(len(X)):
        res[t] = nnls(M[t].T, b)[1] / np.linalg.norm(b)
    return res


def main(argv=None):
    import facewarp
    from facewarp.physics import ModelBuilder, isotropic_moduli, linear_stiffness, material_profile

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_case_args(ap, levels=[0, 1, 2])
    ap.add_argument("--materials", nargs="+", default=["physical", "thesis"])
    args = ap.parse_args(argv)

    rows = []
    for level in args.levels:
        fr = facewarp.build_face(facewarp.default_template(level))
        p = int((fr.layer == 0).sum())
        thickness = np.linalg.norm(fr.nodes[p:2 * p] - fr.nodes[:p], axis=1)
        frames = layer_frames(fr.nodes, fr.tets, fr.layer)
        for name in args.materials:
            b = ModelBuilder(fr.nodes, fr.tets, layer=fr.layer, material=name)
            C = linear_stiffness(b, frames=frames)
            w = b.tet_rest_volumes / b.tet_rest_volumes.sum()
            avg = np.einsum("k,kab->ab", w, C)
            row = {"level": level, "material": name, "tets": int(len(fr.tets)),
                   "median_edge_mm": round(float(np.median(b.edge_rest_lengths)) * 1e3, 3),
                   "mean_thickness_mm": round(float(thickness.mean()) * 1e3, 3),
                   "C11_Pa": round(float(0.5 * (avg[0, 0] + avg[1, 1]))),
                   "C33_Pa": round(float(avg[2, 2])),
                   "G12_Pa": round(float(avg[5, 5] / 2)),
                   "G13_Pa": round(float(0.25 * (avg[3, 3] + avg[4, 4])))}
            mat = material_profile(name)
            if name == "physical":
                # the inner layer's isotropic target (lambda, G); the best per-tet coefficients miss it by
                lam_i = mat.distance_modulus[1] / 15 + 2 * mat.area_modulus / 5 + mat.volume_modulus
                g_i = (mat.distance_modulus[1] + mat.area_modulus) / 15
                res = best_fit_residual(np.einsum("kab,kib->kia", frames, fr.nodes[fr.tets]), lam_i, g_i)
                row["best_isotropic_fit_residual_median"] = round(float(np.median(res)), 3)
                mod = np.asarray(mat.distance_modulus, float)
                for label, d in (("outer", mod[0]), ("inner", mod[1])):
                    lam = d / 15 + 2 * mat.area_modulus / 5 + mat.volume_modulus
                    g = (d + mat.area_modulus) / 15
                    E, nu = isotropic_moduli(d, mat.area_modulus, mat.volume_modulus)
                    row[f"isotropic_{label}"] = {"C11_Pa": round(lam + 2 * g), "G_Pa": round(g),
                                                 "E_Pa": round(E), "nu": round(float(nu), 3)}
            print(row, flush=True)
            rows.append(row)
    path = save("material_levels", {"rows": rows})
    print("wrote", path)


if __name__ == "__main__":
    raise SystemExit(main())
