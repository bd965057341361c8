"""Human-likeness of a template: distance of the ICT-FaceKit neutral face to its surface.

After a least-squares similarity on the FDPs both heads share (2.1, 3.7, 3.12, 3.8, 3.11, 8.3,
8.4, 9.3), the RMS distance from the ICT face vertices (0-9408, centimetres -> metres) to the
template surface measures how human the template's shape is.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..geometry.similarity import fit_similarity
from ..core.errors import InputError
from ..geometry.surface import closest_point
from ..geometry.mesh import load_mesh

__all__ = ["ICT_FDP_VERTICES", "ICT_FACE_VERTICES", "human_likeness"]

# FDP -> ICT-FaceKit vertex (0-based, from ICT's Multi-PIE 68 landmarks; ../shared/docs/MPEG4_FDP.md)
ICT_FDP_VERTICES = {
    "2.1": 966, "3.7": 3721, "3.12": 1507, "3.8": 1528, "3.11": 3742, "8.3": 6213, "8.4": 5708,
    "9.3": 4857, "8.1": 0, "8.2": 5518, "2.2": 5533, "2.3": 5517,
}
"""FDP id -> vertex index on the ICT-FaceKit neutral head (its published topology)."""
ICT_FACE_VERTICES = slice(0, 9409)
LIKENESS_FDPS = ("2.1", "3.7", "3.12", "3.8", "3.11", "8.3", "8.4", "9.3")


def human_likeness(template, ict_dir: str | os.PathLike, *, device: str = "cpu") -> dict:
    """Distances [m] from the aligned ICT neutral face vertices to ``template``'s skin.

    Returns a dict with ``rms_m``, ``median_m``, ``p95_m``, ``max_m``, the alignment ``scale``,
    the FDP ids used, and the per-vertex ``distances_m`` (9409,).
    """
    path = Path(ict_dir) / "generic_neutral_mesh.obj"
    if not path.is_file():
        raise InputError(f"{path}: ICT-FaceKit neutral mesh not found")
    ict = load_mesh(path, units="cm").vertices
    lm = template.landmarks()
    src = np.array([ict[ICT_FDP_VERTICES[k]] for k in LIKENESS_FDPS])
    dst = np.array([lm[k] for k in LIKENESS_FDPS])
    sim = fit_similarity(src, dst)
    P = sim.apply(ict[ICT_FACE_VERTICES])
    d = closest_point(template.vertices, template.faces, P, device=device).dist
    return {
        "rms_m": float(np.sqrt(np.mean(d**2))),
        "median_m": float(np.median(d)),
        "p95_m": float(np.percentile(d, 95)),
        "max_m": float(d.max()),
        "scale": sim.scale,
        "fdps": list(LIKENESS_FDPS),
        "fdp_residual_m": np.linalg.norm(sim.apply(src) - dst, axis=1).tolist(),
        "distances_m": d,
    }
