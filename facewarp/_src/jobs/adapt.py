"""The adaptation job with its files: load scan + landmarks + template, adapt, write results.

Writes into the output folder:
``adapted.obj`` (template topology, template frame, metres, the template's UVs), ``adapted_scan_frame.obj`` (scan
frame and units), ``adapted.glb`` (the same head as binary glTF with its UVs and, from a coloured scan, its texture),
with a coloured scan ``texture.png`` (the scan's colour baked over the UVs) and
``adapted.mtl`` (its material, referenced by ``adapted.obj``) and ``likeness.png`` (the textured
head beside the scan from the same cameras; the CIELAB figures in the report's ``likeness``), ``adapted_landmarks.json`` (metres, template frame), ``report.json`` (the
levels, the calibration, the distance to the scan, and ``quality``: folds, dihedral angles,
curvature difference to the scan and the template's edge stretch and angle change per region,
figures that need no truth), ``error_heatmap.png`` (distance to the scan on the adapted head),
``quality_heatmap.png`` (curvature difference, folds marked), ``distortion_heatmap.png``
(edge stretch) and ``error_curve.png``.
"""

from __future__ import annotations

import contextlib

from pathlib import Path

import numpy as np

from ..adapt.metrics import vertex_groups
from ..adapt.pipeline import adapt
from ..core.errors import InputError
from ..core.fileio import write_json
from ..geometry.surface import MeshQuery
from ..geometry.landmarks import FDP_CATALOGUE, load_landmarks, save_landmarks_json
from ..geometry.mesh import load_mesh, save_obj, unit_scale
from .checks import check_out_dir, make_out_dir

__all__ = ["adapt_files", "detect_landmarks_files"]

def _load_template(template_dir, template_mesh, template_landmarks, template_units):
    """(V, F, landmarks, region labels or None, Template or None) in metres."""
    if template_mesh is not None:
        if template_landmarks is None:
            raise InputError("template_mesh needs template_landmarks (the FDPs of the template mesh)")
        m = load_mesh(template_mesh, units=template_units)
        lm = load_landmarks(template_landmarks, units=template_units)
        return m.vertices, m.faces, lm, None, None
    if template_dir is not None:
        from ..template.files import load_template_dir

        t = load_template_dir(template_dir)
    else:
        from ..template import default_template

        t = default_template(0)
    lm = {k: v for k, v in t.landmarks().items() if t.fdp[k][0] == "head"}
    return t.vertices, t.faces, lm, vertex_groups(t), t


SPAN_RATIO_LIMITS = (1.0 / 50.0, 3.0)
"""Landmark span / mesh span outside this range: the two files are in different units."""

OFF_SURFACE_LIMIT = 0.2
"""A landmark farther than this fraction of the head size from its mesh is rejected up front."""


def _check_units(V, lm: dict, lm_name, mesh_name) -> None:
    """Landmarks lie on their mesh, so their span is at most the mesh's: a ratio of about 10,
    100 or 1000 (or its inverse) means the files are in different units."""
    if len(lm) < 2 or len(V) < 2:
        return
    ls = float(np.ptp(np.array(list(lm.values())), axis=0).max())
    ms = float(np.ptp(V, axis=0).max())
    if ls <= 0 or ms <= 0:
        return
    r = ls / ms
    if not SPAN_RATIO_LIMITS[0] <= r <= SPAN_RATIO_LIMITS[1]:
        raise InputError(f"{lm_name}: the landmarks span {ls:.3g} m but {mesh_name} spans {ms:.3g} m (ratio {r:.3g}): "
                         "the two files seem to be in different units (mm, cm, m)")


def _check_on_surface(V, F, lm: dict, head_size: float, lm_name, mesh_name, device) -> None:
    """Every landmark within :data:`OFF_SURFACE_LIMIT` x ``head_size`` of the mesh surface."""
    from scipy.spatial import cKDTree

    ids = list(lm)
    if not ids or not head_size > 0:
        return
    P = np.array([lm[k] for k in ids])
    limit = OFF_SURFACE_LIMIT * head_size
    d_vertex = cKDTree(V).query(P)[0]  # >= the distance to the surface
    suspect = np.flatnonzero(d_vertex > limit)
    if not len(suspect):
        return
    d = MeshQuery(V, F, device=device).closest_point(P[suspect]).dist
    far = np.flatnonzero(d > limit)
    if len(far):
        k, dk = int(suspect[far[0]]), float(d[far[0]])
        raise InputError(f"{lm_name}: FDP {ids[k]} is {dk * 1e3:.0f} mm off {mesh_name}, {dk / head_size:.0%} of the head "
                         "size: a wrong landmark file, or landmarks in other units than the mesh")


def _check_inputs(scan_mesh, scan_lm, tlm, TV, *, landmarks, scan, device) -> None:
    """Input checks that take seconds, before the adaptation (which takes minutes): FDPs shared
    with the template (>= 4, not coplanar: :func:`calibrate`) and landmarks on the scan surface."""
    from ..adapt.calibrate import calibrate
    from ..adapt.metrics import head_width

    cal = calibrate(scan_lm, tlm)
    s = cal.transform.scale  # template length = s x scan length
    if s > 0:
        _check_on_surface(scan_mesh.vertices, scan_mesh.faces, scan_lm, head_width(TV) / s, landmarks,
                          f"the scan {scan}", device)


def _confidence_path(out_json: Path) -> Path:
    return out_json.with_name(out_json.stem + "_confidence.json")


def detect_landmarks_files(scan, out_json, *, units="m", template_dir=None, template_mesh=None,
                           template_landmarks=None, template_units="m", device="cpu", progress=None) -> dict:
    """Find the template's FDPs on a scan (:func:`~facewarp.adaptation.detect_landmarks`) and write
    them as a landmarks JSON in ``units``, with the confidences beside it
    (``<name>_confidence.json``: FDP id -> 0..1, and the detector's diagnostics).

    Returns:
        The report dict: ``landmarks`` (FDP id -> [x, y, z] in ``units``), ``confidence``,
        ``info``, ``path``, ``confidence_path``.
    """
    from ..adapt.detect import detect_landmarks

    step = progress or (lambda msg: None)
    out_json = Path(out_json)
    if out_json.suffix.lower() != ".json":
        raise InputError(f"out {out_json}: the landmarks file must end in .json")
    if out_json.exists() and out_json.is_dir():
        raise InputError(f"out {out_json}: is a folder, expected a .json file")
    if not out_json.parent.exists():
        raise InputError(f"out {out_json}: the folder {out_json.parent} does not exist")
    step("loading")
    scan_mesh = load_mesh(scan, units=units)
    template = None
    if template_dir is not None or template_mesh is not None:
        TV, TF, tlm, _, _ = _load_template(template_dir, template_mesh, template_landmarks, template_units)
        template = (TV, TF, tlm)
    step("detecting")
    lm, conf = detect_landmarks(scan_mesh.vertices, scan_mesh.faces, template=template, device=device)
    step("writing")
    save_landmarks_json(out_json, dict(lm), units=units)
    scale = unit_scale(units)
    rep = {"path": str(out_json), "confidence_path": str(_confidence_path(out_json)), "units": units,
           "landmarks": {k: (np.asarray(v) / scale).tolist() for k, v in lm.items()},
           "confidence": conf, "info": getattr(lm, "info", {})}
    write_json(_confidence_path(out_json), {"confidence": conf, "info": rep["info"], "scan": str(scan)})
    return rep


@contextlib.contextmanager
def _naming_calibration(landmarks: str, template: str):
    """Calibration errors (too few or coplanar FDPs, a scale that says the units differ) name the
    two landmark files."""
    try:
        yield
    except InputError as e:
        if str(e).startswith("calibration"):
            raise InputError(f"{landmarks} and {template}: {e}") from None
        raise


def adapt_files(scan, landmarks, out, *, template_dir=None, template_mesh=None, template_landmarks=None,
                method="multilevel", levels=None, markers=None, units=None, template_units="m", device="cpu",
                progress=None, texture_size: int = 2048, landmark_scheme: str = "auto") -> dict:
    """Run the adaptation on files and write the outputs; returns the report dict.

    ``landmark_scheme``: the scheme of the ``landmarks`` file (:func:`~facewarp.geometry.load_landmarks`'s
    ``scheme``: "auto", "fdp", "ibug68" or "ibug51"; the 68- and 51-point schemes give the FDPs of
    :data:`~facewarp.geometry.IBUG68_TO_FDP`).

    ``levels`` is :func:`~facewarp.adapt`'s: refinement levels after the FDP level (None: its
    default). ``landmarks`` None: the FDPs are found on the scan
    (:func:`~facewarp.adaptation.detect_landmarks`), written to ``detected_landmarks.json`` (scan
    units) with their confidences in the report. Inputs are checked first (units of scan and
    landmarks, FDPs shared with the template, landmarks on the scan, the output folder), so a bad
    input fails in seconds.

    ``units``: the unit of the scan and its landmarks, ``"mm"``, ``"cm"``, ``"m"`` or ``"auto"``:
    the scale from the FDPs against human proportions (:mod:`~facewarp._src.adapt.scale`),
    written to the report's ``scale``. None (default): ``"m"`` when the scan's extent is a
    plausible head in metres, else ``"auto"``. In given units, FDPs far outside human
    proportions stop the run (:func:`~facewarp._src.adapt.scale.check_human_scale`).

    A scan with colour (vertex colours, or a texture over UVs) is baked into ``texture.png``
    (``texture_size`` px square) over the template's UVs (:mod:`~facewarp._src.adapt.bake`).
    """
    from ..adapt.scale import check_human_scale, estimate_scale, plausible_extent, prescale

    step = progress or (lambda msg: None)
    out = check_out_dir(out)
    if units is not None and units != "auto":
        unit_scale(units)  # names a bad unit
    if not (isinstance(texture_size, (int, np.integer)) and not isinstance(texture_size, bool)
            and 64 <= texture_size <= 16384):
        raise InputError(f"texture_size: expected a whole number of pixels in 64..16384, got {texture_size!r}")
    step("loading")
    raw = load_mesh(scan, units="m")  # the file's numbers
    units_given = units
    if units is None:
        units = "m" if plausible_extent(raw.vertices) else "auto"
    auto = units == "auto"
    detected = None
    if landmarks is not None:
        raw_lm = load_landmarks(landmarks, units="m", scheme=landmark_scheme)
        _check_units(raw.vertices, raw_lm, landmarks, f"the scan {scan}")
    TV, TF, tlm, groups, tmpl = _load_template(template_dir, template_mesh, template_landmarks, template_units)
    if landmarks is None:
        from ..adapt.detect import detect_landmarks

        step("detecting landmarks")
        s0 = prescale(raw.vertices) if auto else unit_scale(units)
        found, conf = detect_landmarks(raw.vertices * s0, raw.faces, template=(TV, TF, tlm), device=device)
        detected = {"confidence": conf, "info": getattr(found, "info", {})}
        raw_lm = {k: np.asarray(v) / s0 for k, v in dict(found).items()}
        landmarks = "detected_landmarks.json"
    if auto:
        est = estimate_scale(raw_lm, what=str(landmarks))
        scale = est.metres_per_unit
        scale_report = {"units": "auto", "given": units_given, **est.to_dict()}
    else:
        scale = unit_scale(units)
        est = check_human_scale({k: v * scale for k, v in raw_lm.items()}, units, f"{scan}")
        scale_report = {"units": units, "given": units_given, "metres_per_unit": scale,
                        **({} if est is None else {"factor_from_fdps": est.metres_per_unit,
                                                   "measures_m": est.measures})}
    scan_mesh = raw
    scan_mesh.vertices = raw.vertices * scale
    scan_lm = {k: np.asarray(v) * scale for k, v in raw_lm.items()}
    scheme_report = None
    if detected is None:
        scan_lm, tlm, scheme_report = _scheme_pairs(landmarks, landmark_scheme, scan_lm, tlm, scale,
                                                    default_template=template_dir is None and template_mesh is None)
    if template_mesh is not None:
        _check_units(TV, tlm, template_landmarks, f"the template mesh {template_mesh}")
    mk = None
    if markers is not None:
        scan_markers = {k: v * scale for k, v in load_landmarks(markers, units="m").items()}
        unknown = sorted(set(scan_markers) - set(tlm))
        if unknown:
            raise InputError(f"{markers}: markers {', '.join(unknown)} are not FDPs of the template")
        mk = ({k: tlm[k] for k in scan_markers}, scan_markers)
        scan_lm = {k: v for k, v in scan_lm.items() if k not in scan_markers}
    lm_name = f"the FDPs found on {scan}" if detected is not None else str(landmarks)
    t_name = str(template_landmarks or (Path(template_dir) / "landmarks.json" if template_dir else "the default template"))
    with _naming_calibration(lm_name, t_name):
        _check_inputs(scan_mesh, scan_lm, tlm, TV, landmarks=landmarks, scan=scan, device=device)
    make_out_dir(out)
    step("adapting")
    settings = {} if levels is None else {"levels": levels}
    with _naming_calibration(lm_name, t_name):
        res = adapt(TV, TF, tlm, scan_mesh.vertices, scan_mesh.faces, scan_lm, method=method, markers=mk,
                    region=groups, device=device, **settings)
    step("writing")
    if detected is not None:
        save_landmarks_json(out / "detected_landmarks.json", {k: v / scale for k, v in scan_lm.items()}, units="m")
    uv = {} if tmpl is None or tmpl.uv is None else {"uv": tmpl.uv, "face_uv": tmpl.face_uv}
    baked = png = None
    if uv and scan_mesh.has_color:
        step("texture")
        baked, png = _bake(out, res.vertices_scan_frame, TF, tmpl, scan_mesh, texture_size, device)
        uv["mtl"] = "adapted.mtl"
    save_obj(out / "adapted.obj", res.vertices, TF, **uv)
    if uv:
        from ..geometry.mesh import _save_glb

        # the texture embedded as texture.png's own bytes (what encoding it again would give)
        _save_glb(out / "adapted.glb", res.vertices, TF, uv["uv"], uv["face_uv"], png)
    save_obj(out / "adapted_scan_frame.obj", res.vertices_scan_frame / scale, TF, **uv)  # the scan's units
    # landmarks follow the adapted surface (face + barycentric on the template)
    from ..geometry.mesh import closest_surface_points

    ids = [k for k in tlm if k in FDP_CATALOGUE]  # FDPs (a 68-point file's other points are not written)
    sp = closest_surface_points(TV, TF, np.array([tlm[k] for k in ids]), device=device)
    P = sp.positions(res.vertices, TF)
    save_landmarks_json(out / "adapted_landmarks.json", dict(zip(ids, P)))
    # distance of every adapted vertex to the (calibrated) scan for the heat map
    d = res.vertex_distance
    hw = float(np.ptp(TV[:, 0]))
    d_show = np.where(d < 0.1 * hw, d, np.nan)  # holes: no scan surface nearby
    report = res.to_dict()
    report.update({
        "scan": str(scan), "landmarks": str(landmarks), "units": units, "scale_to_metres": scale,
        "scale": scale_report,
        "template": str(template_mesh or template_dir or "default template (level 0)"),
        "vertex_count": int(len(TV)), "scan_vertex_count": int(len(scan_mesh.vertices)),
        "levels_requested": int(res.options.levels),
        "distance_to_scan_m": {"median": float(np.nanmedian(d_show)), "rms": float(np.sqrt(np.nanmean(d_show**2))),
                               "p95": float(np.nanpercentile(d_show, 95))},
    })
    if detected is not None:
        report["detected_landmarks"] = detected
    if scheme_report is not None:
        report["landmark_scheme"] = scheme_report
    if uv:
        from ..template.uv import uv_distortion

        # the template's UVs on this head's shape: the face chart's stretch here
        report["uv"] = {"face_chart_distortion": uv_distortion(res.vertices, TF, uv["uv"], uv["face_uv"],
                                                               tmpl.frontal)}
    if baked is not None:
        report["texture"] = {"path": "texture.png", **baked.to_dict()}
        step("likeness")
        report["likeness"] = _likeness(out, res, TF, tmpl, scan_mesh, baked.image, device)
    write_json(out / "report.json", report)
    step("pictures")
    _pictures(out, res, TF, d_show, device)
    return report


def _scheme_pairs(landmarks, scheme: str, scan_lm: dict, tlm: dict, scale: float, *, default_template: bool
                  ) -> tuple[dict, dict, dict | None]:
    """A 68- or 51-point landmark file: besides its FDPs, every other point of the scheme becomes a
    landmark pair (id ``ibug68.N``) with its place on the default template
    (:data:`~facewarp._src.template.ibug68.IBUG68_TEMPLATE`); other templates have no such places
    and use the FDPs only. Returns (scan landmarks [m], template landmarks [m], report or None)."""
    from ..geometry.landmarks import IBUG68_TO_FDP, load_scheme_points

    got = load_scheme_points(landmarks, units="m", scheme=scheme)
    if got is None:
        return scan_lm, tlm, None
    name, P = got
    first = 0 if name == "ibug68" else 17
    rep = {"scheme": name, "fdps": sorted(k for k in scan_lm if k in FDP_CATALOGUE), "other_points": 0,
           "other_points_used": default_template}
    if not default_template:
        return scan_lm, tlm, rep
    from ..template.ibug68 import IBUG68_KEY, IBUG68_TEMPLATE

    scan_lm, tlm = dict(scan_lm), dict(tlm)
    for j in range(first, 68):
        if j in IBUG68_TO_FDP:
            continue
        key = IBUG68_KEY.format(j)
        scan_lm[key] = P[j - first] * scale
        tlm[key] = IBUG68_TEMPLATE[j]
        rep["other_points"] += 1
    return scan_lm, tlm, rep


def _bake(out: Path, V_scan_frame, TF, tmpl, scan_mesh, size: int, device):
    """``texture.png`` (the scan's colour over the template's UVs, :mod:`~facewarp._src.adapt.bake`)
    and ``adapted.mtl`` (material ``skin`` with it as ``map_Kd``); returns the bake and the
    PNG file's bytes."""
    import io

    from PIL import Image

    from ..adapt.bake import bake_texture
    from ..core.fileio import atomic_write

    b = bake_texture(V_scan_frame, TF, tmpl.uv, tmpl.face_uv, scan_mesh.vertices, scan_mesh.faces,
                     colors=scan_mesh.colors, texture=scan_mesh.texture, corner_uv=scan_mesh.corner_uv, size=size,
                     device=device)
    with io.BytesIO() as buf:
        Image.fromarray(b.image).save(buf, format="PNG")
        png = buf.getvalue()
    with atomic_write(out / "texture.png", "wb", encoding=None) as f:
        f.write(png)
    with atomic_write(out / "adapted.mtl", "w") as f:
        f.write("# facewarp: the skin, its colour baked from the scan\nnewmtl skin\nKa 1 1 1\nKd 1 1 1\n"
                "Ks 0 0 0\nmap_Kd texture.png\n")
    return b, png


def _likeness(out: Path, res, TF, tmpl, scan_mesh, texture, device) -> dict:
    """``likeness.png``: the adapted head in its baked texture beside the scan in its own colour,
    both in the template's frame (the scan moved by the calibration), from the same cameras
    (front, three-quarter); returns the CIELAB figures of
    :func:`~facewarp._src.present.compare.likeness_views` (face region, unlit)."""
    from ..present.animation import label_grid
    from ..present.compare import likeness_views
    from ..present.render import save_png

    SV = res.calibration.transform.apply(scan_mesh.vertices)
    look = ({"scan_colors": scan_mesh.colors} if scan_mesh.colors is not None
            else {"scan_texture": scan_mesh.texture, "scan_corner_uv": scan_mesh.corner_uv})
    r = likeness_views(res.vertices, TF, texture, tmpl.uv[tmpl.face_uv], tmpl.frontal, SV, scan_mesh.faces,
                       size=300, device=device, **look)
    mean = r["mean"]
    grid = label_grid([[head, sc] for head, sc, _ in r["images"].values()],
                      column_labels=["adapted head, baked texture", "scan"])
    save_png(out / "likeness.png", grid, title=f"Delta E {mean['delta_e_mean']['textured']:.2f} (one flat colour "
                                               f"{mean['delta_e_mean']['flat']:.2f}), L* r "
                                               f"{mean['lightness_correlation']['textured']:.2f}")
    return {"views": r["views"], "mean": mean, "flat_color": r["flat_color"], "picture": "likeness.png"}


def _pictures(out, res, TF, d_show, device) -> None:
    """error_heatmap.png (distance to the scan), quality_heatmap.png (|H_adapted - H_scan| with
    folded faces as red dots), distortion_heatmap.png (stretch of the template's edges) and
    error_curve.png (E_d, E_m, E per level)."""
    from ..present.plot import line_chart
    from ..present.render import shared_hits

    with shared_hits():  # the quality and distortion maps: one head, one camera, one ray cast
        _heat_maps(out, res, TF, d_show, device)
    lv = list(res.levels)
    line_chart(out / "error_curve.png", [r.level for r in lv],
               {"E_d [mm^2]": [r.E_d * 1e6 for r in lv], "E_m [mm^2]": [r.E_m * 1e6 for r in lv],
                "E [mm^2]": [r.E * 1e6 for r in lv]},
               title="adaptation error per level (Eq. 5.2.1-5.2.3)", xlabel="level", ylabel="error", log_y=True)


def _heat_maps(out, res, TF, d_show, device) -> None:
    """The three heat maps of :func:`_pictures`."""
    from ..geometry.surface import face_normals
    from ..present.adapt_maps import heat_map

    V = res.vertices
    vmax = max(float(np.nanpercentile(d_show, 98)) * 1e3, 0.5)
    heat_map(out / "error_heatmap.png", V, TF, d_show * 1e3, vmax=vmax, unit="mm", size=500,
             title="distance of the adapted head to the scan", device=device)
    q = res.quality.get("surface", {})
    dH = res.vertex_curvature_diff
    if dH is not None and np.isfinite(dH).any():
        n0 = face_normals(res.template_vertices, TF) if res.template_vertices is not None else None
        folds = None
        if n0 is not None:
            turned = np.einsum("kd,kd->k", face_normals(V, TF), n0) < np.cos(np.radians(q.get("fold_threshold_deg", 75.0)))
            folds = V[TF[turned]].mean(axis=1)
        hmax = max(float(np.nanpercentile(dH, 98)), 1.0)
        heat_map(out / "quality_heatmap.png", V, TF, dH, vmax=hmax, unit="1/m", size=400, points=folds,
                 title=f"|mean curvature - scan's| ({q.get('folds', 0)} folds as red dots)", device=device)
    if res.vertex_stretch is not None:
        heat_map(out / "distortion_heatmap.png", V, TF, res.vertex_stretch * 100.0, vmax=30.0, unit="% stretch",
                 size=400, title="stretch of the template's edges (|log(l / l0)|)", device=device)
