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
faces can carry, however their coefficients are chosen.

Writes benchmarks/results/material_levels.json.
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks._common import machine, save


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


def main():
    import facewarp
    from facewarp.physics import ModelBuilder, isotropic_moduli, linear_stiffness, material_profile

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--levels", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--materials", nargs="+", default=["physical", "thesis"])
    args = ap.parse_args()

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
                mod = np.asarray(mat.distance_modulus, float)
                for label, d in (("outer", mod[0]), ("inner", mod[1])):
                    lam = d / 15 + 2 * mat.area_modulus / 5 + mat.volume_modulus
                    g = (d + mat.area_modulus) / 15
                    E, nu = isotropic_moduli(d, mat.area_modulus, mat.volume_modulus)
                    row[f"isotropic_{label}"] = {"C11_Pa": round(lam + 2 * g), "G_Pa": round(g),
                                                 "E_Pa": round(E), "nu": round(float(nu), 3)}
            print(row, flush=True)
            rows.append(row)
    path = save("material_levels", {"machine": machine("cpu"), "rows": rows})
    print("wrote", path)


if __name__ == "__main__":
    main()
