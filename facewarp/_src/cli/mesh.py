"""``facewarp mesh check``: load and validate an input mesh."""

from __future__ import annotations

from pathlib import Path

from .common import Parser, emit


# ----------------------------------------------------------------------------- options
def add_parser(sub) -> None:
    m = sub.add_parser("mesh", help="inspect input meshes")
    msub = m.add_subparsers(dest="mesh_command", metavar="ACTION", parser_class=Parser)
    msub.required = True
    c = msub.add_parser("check", example="facewarp mesh check scan.ply --units mm",
                        help="load and validate a mesh; report degenerate faces, non-manifold edges, holes")
    c.add_argument("mesh", type=Path, metavar="MESH", help="OBJ, PLY, STL, OFF, GLB or GLTF file")
    c.add_argument("--units", choices=["mm", "cm", "m"], default="m", help="units of the file (default m)")
    c.set_defaults(func=run_check)


# ----------------------------------------------------------------------------- run and report
def run_check(args):
    from ..geometry.mesh import load_mesh, mesh_report

    m = load_mesh(args.mesh, units=args.units)
    rep = mesh_report(m.vertices, m.faces)
    rep["path"] = str(args.mesh)
    rep["has_uv"] = m.uv is not None
    lines = [f"{args.mesh}: " + ", ".join(f"{k} {v}" for k, v in rep.items() if k not in ("path", "bounding_box"))]
    emit(args, rep, lines)

