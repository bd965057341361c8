"""ICT-FaceKit cases shared by the benchmarks: the data folder, the FDP map, scan-like targets of an
identity (:func:`make_scan`), random unseen faces (:func:`make_case`, :func:`error_stats`) and
the default template adapted to an identity and built (:func:`adapted_identity`).

Scans are the ICT identity shapes (vertices 0-11247, the face and head) re-tessellated, with noise
along the normals, holes away from the landmarks, a random rigid pose and millimetre units; FDP
indices per ``docs/MPEG4_FDP.md``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks._common import shared_dir

FACE_VERTS = 9409  # ICT face area: vertices 0-9408
HEAD_VERTS = 11248  # face + head and neck: vertices 0-11247

# FDP -> ICT vertex index (docs/MPEG4_FDP.md)
ICT_FDP = {
    "2.1": 966, "3.7": 3721, "3.12": 1507, "3.8": 1528, "3.11": 3742, "8.3": 6213,
    "8.4": 5708, "9.3": 4857, "8.1": 0, "8.2": 5518, "2.2": 5533, "2.3": 5517,
}  # fmt: skip


def ict_dir() -> Path:
    return shared_dir() / "data" / "ict-facekit"


def load_ict(d: Path):
    from facewarp import load_mesh

    neutral = load_mesh(d / "generic_neutral_mesh.obj", units="cm")
    F = neutral.faces[(neutral.faces < HEAD_VERTS).all(axis=1)]
    markers = json.loads((d / "vertex_indices.json").read_text())["idx_to_landmark_verts"]
    return neutral.vertices[:HEAD_VERTS].copy(), F, [int(i) for i in markers]


def _random_rotation(rng, max_angle: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = rng.uniform(-max_angle, max_angle)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def make_scan(V_true: np.ndarray, F: np.ndarray, seed: int, *, faces: int = 60000, noise_mm: float = 0.15, holes: int = 4):
    """A scan-like mesh of the head V_true [m]: new tessellation, noise, holes, pose, mm.

    Returns (scan_V_mm, scan_F, pose) with pose = (R, t_mm): scan_mm = 1000 * R @ x + t_mm.
    """
    import igl

    from facewarp.geometry import vertex_normals

    rng = np.random.default_rng(seed)
    V2, F2 = igl.upsample(V_true, F, 2)
    res = igl.decimate(V2, F2, faces)
    SV, SF = np.asarray(res[0], dtype=np.float64), np.asarray(res[1], dtype=np.int64)
    N = vertex_normals(SV, SF)
    SV = SV + N * rng.normal(scale=noise_mm * 1e-3, size=(len(SV), 1))
    # holes: discs on the face (not at the landmarks)
    lm = V_true[list(ICT_FDP.values())]
    cent = []
    while len(cent) < holes:
        c = V_true[rng.integers(0, FACE_VERTS)]
        if np.linalg.norm(lm - c, axis=1).min() > 0.02:
            cent.append(c)
    C = SV[SF].mean(axis=1)
    keep = np.ones(len(SF), dtype=bool)
    for c in cent:
        keep &= np.linalg.norm(C - c, axis=1) > 0.006
    SF = SF[keep]
    used = np.unique(SF)
    remap = np.full(len(SV), -1)
    remap[used] = np.arange(len(used))
    SV, SF = SV[used], remap[SF]
    R = _random_rotation(rng, np.radians(30))
    t = rng.uniform(-200, 200, size=3)
    return 1000.0 * SV @ R.T + t, SF, (R, t)


def to_scan_frame(X: np.ndarray, pose) -> np.ndarray:
    R, t = pose
    return 1000.0 * X @ R.T + t


@dataclass
class ICTModel:
    """The ICT neutral head and its identity offsets (metres, ICT frame: y up, z front).

    Attributes:
        neutral: Neutral head vertices [m], shape (11248, 3), float64.
        faces: Head triangles, shape (m, 3), int64.
        offsets: identity_k - neutral [m], shape (k, 11248, 3), float64 (k = 10 in the shared folder, 100 in
            the public rig).
        markers: ICT's 68 landmark vertex indices.
    """

    neutral: np.ndarray
    faces: np.ndarray
    offsets: np.ndarray
    markers: list


def identity_files(identities: Path | str | None = None) -> list[Path]:
    """The ICT-FaceKit identity OBJs (``identityNNN.obj``) of ``identities`` (a folder: the
    public rig's ``FaceXModel`` has all 100) or, when None, of ``$FACEWARP_ICT_IDENTITIES`` or the
    shared folder (its first 10)."""
    import os

    d = Path(identities or os.environ.get("FACEWARP_ICT_IDENTITIES") or ict_dir())
    files = sorted(d.glob("identity[0-9][0-9][0-9].obj"))
    if not files:
        raise SystemExit(f"no identityNNN.obj in {d}")
    return files


def _obj_vertices(path: Path, count: int) -> np.ndarray:
    """The first ``count`` vertex positions of an OBJ (its own units), shape (count, 3)."""
    rows = []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                rows.append(line.split()[1:4])
                if len(rows) == count:
                    break
    return np.array(rows, dtype=np.float64)


def load_model(identities: Path | str | None = None) -> ICTModel:
    """The ICT neutral head and the identity offsets of :func:`identity_files` (all of them)."""
    from facewarp import load_mesh

    d = ict_dir()
    neutral = load_mesh(d / "generic_neutral_mesh.obj", units="cm")
    F = neutral.faces[(neutral.faces < HEAD_VERTS).all(axis=1)]
    V0 = neutral.vertices[:HEAD_VERTS].copy()
    files = identity_files(identities) if identities is not None else [d / f"identity{k:03d}.obj" for k in range(10)]
    offs = np.stack([_obj_vertices(f, HEAD_VERTS) * 0.01 - V0 for f in files])
    markers = [int(i) for i in json.loads((d / "vertex_indices.json").read_text())["idx_to_landmark_verts"]]
    return ICTModel(V0, np.asarray(F, dtype=np.int64), offs, markers)


@dataclass
class Case:
    """One unseen case. The scan frame is ``x_scan_mm = 1000 * scale * R @ x + t_mm``.

    Attributes:
        seed: The case's seed.
        weights: Identity weights, shape (10,).
        truth: The true shape in the ICT frame [m], shape (11248, 3), float64.
        truth_scan_mm: The true shape in the scan's frame [mm], shape (11248, 3), float64.
        scan_V_mm: Scan vertices [mm], shape (k, 3), float64.
        scan_F: Scan triangles, shape (l, 3), int64.
        landmarks_mm: FDP id -> scan position [mm], shape (3,).
        rotation, scale, translation_mm: The pose.
        noise_mm: Normal noise sigma [mm].
        holes: Hole centres (ICT frame) [m], shape (h, 3), and radii [m], shape (h,).
    """

    seed: int
    weights: np.ndarray
    truth: np.ndarray
    truth_scan_mm: np.ndarray
    scan_V_mm: np.ndarray
    scan_F: np.ndarray
    landmarks_mm: dict
    rotation: np.ndarray
    scale: float
    translation_mm: np.ndarray
    noise_mm: float
    holes: tuple

    def to_scan_mm(self, X: np.ndarray) -> np.ndarray:
        """ICT-frame points [m] -> scan frame [mm]."""
        return 1000.0 * self.scale * X @ self.rotation.T + self.translation_mm

    def info(self) -> dict:
        return {"seed": self.seed, "weights": [float(w) for w in self.weights], "scale": self.scale,
                "noise_mm": self.noise_mm, "holes": len(self.holes[1]), "hole_radii_mm": [float(r * 1e3) for r in self.holes[1]],
                "scan_vertices": int(len(self.scan_V_mm)), "scan_faces": int(len(self.scan_F)),
                "rotation": self.rotation.tolist(), "translation_mm": self.translation_mm.tolist()}


def retessellate(V: np.ndarray, F: np.ndarray, rng, *, faces: int = 60000, jitter: float = 0.4):
    """A new tessellation of the surface (V, F) [m] with about ``faces`` triangles: linear
    subdivision x2, shortest-edge decimation, then each vertex moved by a random tangent step
    (up to ``jitter`` of its mean edge length) and put back on the surface (closest point)."""
    import igl

    from facewarp.geometry import MeshQuery, vertex_normals

    V2, F2 = igl.upsample(V, F, 2)
    res = igl.decimate(V2, F2, faces)
    SV, SF = np.asarray(res[0], dtype=np.float64), np.asarray(res[1], dtype=np.int64)
    used = np.unique(SF)
    remap = np.full(len(SV), -1)
    remap[used] = np.arange(len(used))
    SV, SF = SV[used], remap[SF]
    N = vertex_normals(SV, SF)
    E = np.concatenate([SF[:, [0, 1]], SF[:, [1, 2]], SF[:, [2, 0]]])
    el = np.linalg.norm(SV[E[:, 0]] - SV[E[:, 1]], axis=1)
    mean_len = np.bincount(E.ravel(), weights=np.repeat(el, 2), minlength=len(SV)) / np.maximum(np.bincount(E.ravel(), minlength=len(SV)), 1)
    step = rng.normal(size=SV.shape)
    step -= np.einsum("kd,kd->k", step, N)[:, None] * N
    step /= np.maximum(np.linalg.norm(step, axis=1, keepdims=True), 1e-12)
    step *= (rng.uniform(0.0, jitter, size=len(SV)) * mean_len)[:, None]
    boundary = np.zeros(len(SV), bool)
    Es = np.sort(E, axis=1)
    u, c = np.unique(Es, axis=0, return_counts=True)
    boundary[u[c == 1].ravel()] = True
    step[boundary] = 0.0
    cp = MeshQuery(V, F).closest_point(SV + step)
    SV = np.where(np.isfinite(cp.points), cp.points, SV)
    return SV, SF


def make_case(model: ICTModel, seed: int, *, faces: int = 60000) -> Case:
    """A random unseen case (see the module docstring) from ``seed``."""
    from scipy.spatial.transform import Rotation

    from facewarp.geometry import vertex_normals

    rng = np.random.default_rng(seed)
    w = rng.normal(size=len(model.offsets))
    truth = model.neutral + np.einsum("k,kvd->vd", w, model.offsets)
    SV, SF = retessellate(truth, model.faces, rng, faces=faces)
    noise = float(rng.uniform(0.05, 0.3)) * 1e-3
    SV = SV + vertex_normals(SV, SF) * rng.normal(scale=noise, size=(len(SV), 1))
    # holes: discs on the face, away from the landmarks
    lm = truth[list(ICT_FDP.values())]
    n_holes = int(rng.integers(2, 7))
    cent, rad = [], []
    while len(cent) < n_holes:
        c = truth[rng.integers(0, FACE_VERTS)]
        r = float(rng.uniform(0.004, 0.010))
        if np.linalg.norm(lm - c, axis=1).min() > r + 0.01:
            cent.append(c)
            rad.append(r)
    C = SV[SF].mean(axis=1)
    keep = np.ones(len(SF), dtype=bool)
    for c, r in zip(cent, rad):
        keep &= np.linalg.norm(C - c, axis=1) > r
    SF = SF[keep]
    used = np.unique(SF)
    remap = np.full(len(SV), -1)
    remap[used] = np.arange(len(used))
    SV, SF = SV[used], remap[SF]
    R = Rotation.random(random_state=rng).as_matrix()
    s = float(rng.uniform(0.8, 1.2))
    t = rng.uniform(-300, 300, size=3)
    case = Case(seed, w, truth, np.zeros(0), np.zeros(0), SF, {}, R, s, t, noise * 1e3, (np.array(cent), np.array(rad)))
    case.scan_V_mm = case.to_scan_mm(SV)
    case.truth_scan_mm = case.to_scan_mm(truth)
    case.landmarks_mm = {f: case.truth_scan_mm[i] for f, i in ICT_FDP.items()}
    return case


def error_stats(V_mm: np.ndarray, case: Case, faces: np.ndarray) -> tuple[dict, np.ndarray, np.ndarray]:
    """E_v over the face vertices (scan frame, mm): stats, per-vertex total and tangential error."""
    from facewarp.geometry import vertex_normals

    T = case.truth_scan_mm
    d = V_mm - T
    e = np.linalg.norm(d, axis=1)
    N = vertex_normals(T, faces)
    tang = np.linalg.norm(d - np.einsum("kd,kd->k", d, N)[:, None] * N, axis=1)
    f = e[:FACE_VERTS]
    ft = tang[:FACE_VERTS]
    stats = {
        "E_v_median_mm": float(np.median(f)), "E_v_rms_mm": float(np.sqrt(np.mean(f**2))),
        "E_v_p95_mm": float(np.percentile(f, 95)), "E_v_max_mm": float(f.max()),
        "E_v_over_5mm": int((f > 5).sum()), "E_v_over_20mm": int((f > 20).sum()),
        "tangential_median_mm": float(np.median(ft)), "tangential_rms_mm": float(np.sqrt(np.mean(ft**2))),
        "head_E_v_rms_mm": float(np.sqrt(np.mean(e**2))),
    }
    return stats, e, tang


def adapted_identity(k: int, root: Path, *, fresh: bool = False) -> dict:
    """The default template adapted to ICT identity ``k`` (scan: :func:`make_scan`, seed 100 + k) and built.

    Runs ``facewarp adapt`` and ``facewarp build`` into ``root/identityNNN/{adapt,build}`` unless that
    build folder already holds a ``face_rig.npz`` (``fresh=True``: always). Returns ``{"dir", "report" (adapt's report.json or
    None when reused), "adapt_seconds", "build_seconds"}``.
    """
    import contextlib
    import io
    import time

    from facewarp import load_mesh
    from facewarp.geometry import save_obj
    from facewarp.cli import main as facewarp_cli

    case = Path(root) / f"identity{k:03d}"
    if not fresh and (case / "build" / "face_rig.npz").is_file():
        return {"dir": case, "report": None, "adapt_seconds": None, "build_seconds": None}

    def cli(*argv):  # `facewarp ...`; the results are the files it writes
        with contextlib.redirect_stdout(io.StringIO()):
            code = facewarp_cli([str(a) for a in argv])
        if code != 0:
            raise SystemExit(f"facewarp {' '.join(map(str, argv))} failed with exit code {code}")

    d = ict_dir()
    _, F, _ = load_ict(d)
    V = load_mesh(d / f"identity{k:03d}.obj", units="cm").vertices[:HEAD_VERTS]
    SV, SF, pose = make_scan(V, F, seed=100 + k)
    case.mkdir(parents=True, exist_ok=True)
    save_obj(case / "scan.obj", SV, SF)
    lm = {fid: (1000.0 * V[i] @ pose[0].T + pose[1]).tolist() for fid, i in ICT_FDP.items()}
    (case / "scan_landmarks.json").write_text(json.dumps(lm))
    t0 = time.perf_counter()
    cli("adapt", case / "scan.obj", "--landmarks", case / "scan_landmarks.json", "--out", case / "adapt",
        "--units", "mm")
    report = json.loads((case / "adapt" / "report.json").read_text())
    t1 = time.perf_counter()
    cli("build", case / "adapt", "--out", case / "build")
    return {"dir": case, "report": report, "adapt_seconds": t1 - t0, "build_seconds": time.perf_counter() - t1}


ICT_REGION_GROUPS = {"jaw line": range(0, 17), "brows": range(17, 27), "nose": range(27, 36), "eyes": range(36, 48),
                     "lips": range(48, 68)}
"""Regions of the ICT face by its 68 landmark vertices (iBUG order): a face vertex belongs to the
group of its nearest landmark within 12 mm (lips 10 mm); "ears" are the vertices farther from
the midline than the jaw line's ends + 5 mm; the rest is "other" (cheeks, forehead, temples)."""


def ict_regions(model: ICTModel) -> np.ndarray:
    """Region name per ICT head vertex (see :data:`ICT_REGION_GROUPS`), shape (11248,), str."""
    from scipy.spatial import cKDTree

    V0, mk = model.neutral, np.asarray(model.markers)
    reg = np.full(len(V0), "other", dtype=object)
    best = np.full(len(V0), np.inf)
    for g, r in ICT_REGION_GROUPS.items():
        d, _ = cKDTree(V0[mk[list(r)]]).query(V0)
        sel = (d < (0.010 if g == "lips" else 0.012)) & (d < best)
        reg[sel] = g
        best[sel] = d[sel]
    x_jaw = float(np.abs(V0[mk[[0, 16]], 0]).mean())
    reg[(np.abs(V0[:, 0]) > x_jaw + 0.005) & (reg == "other")] = "ears"
    return reg.astype(str)


@dataclass
class TemplateTruth:
    """Where each vertex of the default template lies on the ICT head: the point where
    facewarp puts it on the ICT neutral head (true FDPs), as a triangle and barycentric
    coordinates. On a case, a template vertex's true place is the same surface point of the
    case's shape; the figure is the consistency of the correspondence with the ICT model's own
    (a convention: the map itself is facewarp's, fixed once per run).

    Attributes:
        vertices, faces: The template (level 0) [m], shapes (n, 3) float64 and (m, 3) int64.
        landmarks: Its head FDPs [m] (the ICT_FDP ids).
        face: ICT triangle per template vertex, shape (n,), int64.
        bary: Barycentric coordinates, shape (n, 3), float64.
        mask: Measured vertices: frontal and mapped inside the ICT face area, shape (n,), bool.
        region: Template region name per vertex, shape (n,), str.
    """

    vertices: np.ndarray
    faces: np.ndarray
    landmarks: dict
    face: np.ndarray
    bary: np.ndarray
    mask: np.ndarray
    region: np.ndarray

    def truth_scan_mm(self, model: ICTModel, case: Case) -> np.ndarray:
        """True places of the template's vertices on the case, scan frame [mm], shape (n, 3)."""
        X = np.einsum("kj,kjd->kd", self.bary, case.truth[model.faces[self.face]])
        return case.to_scan_mm(X)


def default_template_truth(model: ICTModel) -> TemplateTruth:
    """The default template's vertices located on the ICT head (see :class:`TemplateTruth`)."""
    from facewarp.heads import REGIONS
    from facewarp.geometry import MeshQuery
    from facewarp import default_template
    from facewarp import adapt

    t = default_template(0)
    TV, TF = np.asarray(t.vertices), np.asarray(t.faces)
    tl = {k: v for k, v in t.landmarks().items() if t.fdp[k][0] == "head" and k in ICT_FDP}
    res = adapt(TV, TF, tl, model.neutral, model.faces, {f: model.neutral[i] for f, i in ICT_FDP.items()})
    cp = MeshQuery(model.neutral, model.faces).closest_point(res.vertices_scan_frame)
    inside = (cp.face >= 0) & (model.faces[np.maximum(cp.face, 0)] < FACE_VERTS).all(axis=1) & (cp.dist < 1e-3)
    frontal = np.zeros(len(TV), bool)
    frontal[np.unique(TF[np.asarray(t.frontal)])] = True
    region = np.empty(len(TV), dtype=object)
    for fi, r in enumerate(np.asarray(t.face_region)):
        region[TF[fi]] = REGIONS[r]
    return TemplateTruth(TV, TF, tl, np.maximum(cp.face, 0), cp.bary, inside & frontal, region.astype(str))


TEMPLATE_REGION_GROUPS = {"lips": ("upper_lip", "lower_lip", "lip_corner_L", "lip_corner_R"),
                          "eyes": ("eyelid_upper_L", "eyelid_upper_R", "eyelid_lower_L", "eyelid_lower_R"),
                          "nose": ("nose",), "cheeks": ("cheek_L", "cheek_R"), "forehead": ("forehead",),
                          "jaw line": ("chin", "bottom_face")}
"""Groups of the default template's frontal regions in the per-region figures."""


def region_rms(e: np.ndarray, labels: np.ndarray, groups: dict | None = None, mask: np.ndarray | None = None) -> dict:
    """RMS of the per-vertex error ``e`` [mm] per region group (labels: a name per vertex;
    groups: group -> label names, default one group per label), over ``mask``."""
    m = np.ones(len(e), bool) if mask is None else mask
    groups = groups or {str(k): (k,) for k in np.unique(labels[m])}
    out = {}
    for g, names in groups.items():
        sel = m & np.isin(labels, names)
        if sel.any():
            out[g] = float(np.sqrt(np.mean(e[sel] ** 2)))
    return out
