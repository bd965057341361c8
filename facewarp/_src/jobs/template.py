"""Template jobs with their files and pictures: export the default template, import the ICT head."""

from __future__ import annotations

import os
import time
from pathlib import Path

from ..importers.ict import ict_import_report, import_ict
from ..present.template import render_previews
from ..template.files import save_template
from ..template.head import Template
from .checks import check_out_dir, make_out_dir

__all__ = ["export_template", "import_ict_files"]


def export_template(t: Template, out: str | os.PathLike, *, previews: bool = True, device: str = "cpu",
                    progress=None) -> list[Path]:
    """Write ``t`` into the folder ``out`` (created if needed) with its previews.

    Files: see :mod:`facewarp._src.template.files`; with ``previews``, ``preview_front.png`` and
    ``preview_side.png`` rendered on ``device``.

    Returns:
        The written paths.
    """
    make_out_dir(out)
    written = save_template(t, out, progress=progress)
    if previews:
        (progress or (lambda msg: None))("previews")
        written += render_previews(t, Path(out), device=device)
    return written


def import_ict_files(ict_dir, out, *, previews: bool = True, device: str = "cpu", progress=None) -> dict:
    """Import the ICT head and write it as a template folder (:func:`export_template`).

    Returns a JSON-ready summary (counts, written files, seconds).
    """
    t0 = time.perf_counter()
    check_out_dir(out)
    step = progress or (lambda msg: None)
    step("importing ICT-FaceKit")
    diag: dict = {}
    t = import_ict(ict_dir, device=device, report=diag)
    written = export_template(t, out, previews=previews, device=device, progress=progress)
    rep = ict_import_report(t)
    rep.update({
        "ict_dir": str(ict_dir),
        "out": str(out),
        "level": t.level,
        "boundary_loops": diag["skin_mesh"]["boundary_loop_count"],
        "files": [str(p) for p in written],
        "seconds": round(time.perf_counter() - t0, 3),
    })
    return rep
