"""The adaptation job with its files: load scan + landmarks + template, adapt, write results.

Writes into the output folder:
``adapted.obj`` (template topology, template frame, metres), ``adapted_scan_frame.obj`` (scan
frame and units), ``adapted_landmarks.json`` (metres, template frame), ``report.json``,
``error_heatmap.png`` (distance to the scan on the adapted head) and ``error_curve.png``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..adapt.metrics import vertex_groups
from ..adapt.pipeline import adapt
from ..core.errors import InputError
from ..core.fileio import write_json
from ..geometry.surface import MeshQuery
from ..geometry.landmarks import load_landmarks, save_landmarks_json
from ..geometry.mesh import load_mesh, save_obj, unit_scale

__all__ = ["adapt_files"]

def _load_template(template_dir, template_mesh, template_landmarks, template_units):
    """(V, F, landmarks, region labels or None, Template or None) in metres."""
    if template_mesh is not None:
        if template_landmarks is None:
            raise InputError("--template-mesh needs --template-landmarks")
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


def adapt_files(scan, landmarks, out, *, template_dir=None, template_mesh=None, template_landmarks=None,
                method="multilevel", levels=5, markers=None, units="m", template_units="m", device="cpu",
                progress=None) -> dict:
    """Run the adaptation on files and write the outputs; returns the report dict."""
    step = progress or (lambda msg: None)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    scale = unit_scale(units)
    step("loading")
    scan_mesh = load_mesh(scan, units=units)
    scan_lm = load_landmarks(landmarks, units=units)
    TV, TF, tlm, groups, tmpl = _load_template(template_dir, template_mesh, template_landmarks, template_units)
    mk = None
    if markers is not None:
        scan_markers = load_landmarks(markers, units=units)
        unknown = sorted(set(scan_markers) - set(tlm))
        if unknown:
            raise InputError(f"{markers}: markers {', '.join(unknown)} are not FDPs of the template")
        mk = ({k: tlm[k] for k in scan_markers}, scan_markers)
        scan_lm = {k: v for k, v in scan_lm.items() if k not in scan_markers}
    step("adapting")
    res = adapt(TV, TF, tlm, scan_mesh.vertices, scan_mesh.faces, scan_lm, method=method, levels=levels,
                markers=mk, region=groups, device=device)
    step("writing")
    out.mkdir(parents=True, exist_ok=True)
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
