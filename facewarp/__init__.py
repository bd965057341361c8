"""facewarp: personalized, physically simulated faces.

Public API (everything else lives in :mod:`facewarp._src` and may change):

- meshes and files: :func:`load_mesh`, :func:`save_obj`, :func:`mesh_report`, :class:`Mesh`,
  :class:`SurfacePoints`, :func:`closest_surface_points`;
- MPEG-4 feature points: :data:`FDP_CATALOGUE`, :data:`FDP_IDS`, :func:`fapu`,
  :func:`load_landmarks`, :func:`save_landmarks_json`;
- geometry: :func:`vertex_normals`, :func:`mean_curvature`, :class:`MeshQuery`;
- the default template: :func:`default_template`, :class:`Template`, :data:`REGIONS`,
  :func:`export_template`, :func:`load_template_dir`;
- pictures: :func:`render_mesh`, :func:`save_png`, :func:`colormap`.

Units are SI inside (metres); convert at file edges with ``units=``.
"""

from ._src.errors import FacewarpError, InputError, SimulationError
from ._src.geometry import MeshQuery, mean_curvature, vertex_normals
from ._src.landmarks import FDP_CATALOGUE, FDP_IDS, fapu, load_landmarks, save_landmarks_json
from ._src.mesh import Mesh, SurfacePoints, closest_surface_points, load_mesh, mesh_report, save_obj
from ._src.render import colormap, render_mesh, save_png
from ._src.template import FRONTAL_REGIONS, REGIONS, THICKNESS_FACTOR, Template, default_template
from ._src.template.export import export_template, load_template_dir

__version__ = "0.1.0"

__all__ = [
    "FDP_CATALOGUE",
    "FDP_IDS",
    "FRONTAL_REGIONS",
    "REGIONS",
    "THICKNESS_FACTOR",
    "FacewarpError",
    "InputError",
    "Mesh",
    "MeshQuery",
    "SimulationError",
    "SurfacePoints",
    "Template",
    "__version__",
    "closest_surface_points",
    "colormap",
    "default_template",
    "export_template",
    "fapu",
    "load_landmarks",
    "load_mesh",
    "load_template_dir",
    "mean_curvature",
    "mesh_report",
    "render_mesh",
    "save_landmarks_json",
    "save_obj",
    "save_png",
    "vertex_normals",
]
