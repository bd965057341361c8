"""The adaptation job with its files: load scan + landmarks + template, adapt, write results.

Writes into the output folder:
``adapted.obj`` (template topology, template frame, metres), ``adapted_scan_frame.obj`` (scan
frame and units), ``adapted_landmarks.json`` (metres, template frame), ``report.json``,
``error_heatmap.png`` (distance to the scan on the adapted head) and ``error_curve.png``.
"""

from __future__ import annotations

import numpy as np

from ..adapt.metrics import vertex_groups
from ..adapt.pipeline import adapt
from ..core.errors import InputError
from ..core.fileio import write_json
from ..geometry.surface import MeshQuery
from ..geometry.landmarks import load_landmarks, save_landmarks_json
from ..geometry.mesh import load_mesh, save_obj, unit_scale
from .checks import check_out_dir, make_out_dir

__all__ = ["adapt_files"]

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


def adapt_files(scan, landmarks, out, *, template_dir=None, template_mesh=None, template_landmarks=None,
                method="multilevel", levels=5, markers=None, units="m", template_units="m", device="cpu",
                progress=None) -> dict:
    """Run the adaptation on files and write the outputs; returns the report dict.

    ``levels`` is :func:`~facewarp.adapt`'s: refinement levels after the FDP level. Inputs are
    checked first (units of scan and landmarks, FDPs shared with the template, landmarks on
    the scan, the output folder), so a bad input fails in seconds.
    """
    step = progress or (lambda msg: None)
    out = check_out_dir(out)
    scale = unit_scale(units)
    step("loading")
    scan_mesh = load_mesh(scan, units=units)
    scan_lm = load_landmarks(landmarks, units=units)
    _check_units(scan_mesh.vertices, scan_lm, landmarks, f"the scan {scan}")
    TV, TF, tlm, groups, tmpl = _load_template(template_dir, template_mesh, template_landmarks, template_units)
    if template_mesh is not None:
        _check_units(TV, tlm, template_landmarks, f"the template mesh {template_mesh}")
    mk = None
    if markers is not None:
        scan_markers = load_landmarks(markers, units=units)
        unknown = sorted(set(scan_markers) - set(tlm))
        if unknown:
            raise InputError(f"{markers}: markers {', '.join(unknown)} are not FDPs of the template")
        mk = ({k: tlm[k] for k in scan_markers}, scan_markers)
        scan_lm = {k: v for k, v in scan_lm.items() if k not in scan_markers}
    _check_inputs(scan_mesh, scan_lm, tlm, TV, landmarks=landmarks, scan=scan, device=device)
    make_out_dir(out)
    step("adapting")
    res = adapt(TV, TF, tlm, scan_mesh.vertices, scan_mesh.faces, scan_lm, method=method, levels=levels,
                markers=mk, region=groups, device=device)
    step("writing")
    save_obj(out / "adapted.obj", res.vertices, TF)
    save_obj(out / "adapted_scan_frame.obj", res.vertices_scan_frame, TF, units=units)
    # landmarks follow the adapted surface (face + barycentric on the template)
    from ..geometry.mesh import closest_surface_points

    ids = list(tlm)
    sp = closest_surface_points(TV, TF, np.array([tlm[k] for k in ids]), device=device)
    P = sp.positions(res.vertices, TF)
    save_landmarks_json(out / "adapted_landmarks.json", dict(zip(ids, P)))
    # distance of every adapted vertex to the (calibrated) scan for the heat map
    cal = res.calibration.transform
    SV = cal.apply(scan_mesh.vertices)
    q = MeshQuery(SV, scan_mesh.faces, device=device)
    d = q.closest_point(res.vertices).dist
    hw = float(np.ptp(TV[:, 0]))
    d_show = np.where(d < 0.1 * hw, d, np.nan)  # holes: no scan surface nearby
    report = res.to_dict()
    report.update({
        "scan": str(scan), "landmarks": str(landmarks), "units": units, "scale_to_metres": scale,
        "template": str(template_mesh or template_dir or "default template (level 0)"),
        "vertex_count": int(len(TV)), "scan_vertex_count": int(len(scan_mesh.vertices)),
        "distance_to_scan_m": {"median": float(np.nanmedian(d_show)), "rms": float(np.sqrt(np.nanmean(d_show**2))),
                               "p95": float(np.nanpercentile(d_show, 95))},
    })
    write_json(out / "report.json", report)
    step("pictures")
    from ..present.plot import line_chart
    from ..present.render import colormap, render_mesh, save_png

    vmax = max(float(np.nanpercentile(d_show, 98)) * 1e3, 0.5)
    colors = colormap(d_show * 1e3, 0.0, vmax)
    img = render_mesh(res.vertices, TF, view="front", width=700, height=700, vertex_colors=colors, device=device)
    save_png(out / "error_heatmap.png", img, title="distance of the adapted head to the scan",
             colorbar=(0.0, vmax, "mm"))
    lv = [r for r in res.levels]
    line_chart(out / "error_curve.png", [r.level for r in lv],
               {"E_d [mm^2]": [r.E_d * 1e6 for r in lv], "E_m [mm^2]": [r.E_m * 1e6 for r in lv],
                "E [mm^2]": [r.E * 1e6 for r in lv]},
               title="adaptation error per level (Eq. 5.2.1-5.2.3)", xlabel="level", ylabel="error", log_y=True)
    return report
