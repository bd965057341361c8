"""USD export for facewarp: the only package that imports ``pxr`` (usd-core).

Plain numpy arrays in, no dependency on ``facewarp``. Coordinates are in the stage's unit
(``metersPerUnit``, default 1: SI metres, as facewarp works), Y up by default; times in seconds.

Animation (:class:`AnimationWriter`, read back with :func:`read_animation`)
    Streams an animated head, frame by frame and with no frame cap, into one ``.usda``, ``.usdc``
    or ``.usdz`` file (no value clips, nothing beside it) with bounded memory: pending samples are
    appended to a working ``.usdc`` whenever ``flush_bytes`` (32 MiB) accumulate, and the text or
    package is made from it at ``close()`` (measurements in ``usd_export/_writer.py``). The format
    is chosen by the extension; anything else raises :class:`UsdExportError`. The file is written
    in a hidden temporary folder beside ``path`` and renamed at ``close()``: an exception in the
    ``with`` block (KeyboardInterrupt included) leaves neither a partial file nor temporaries.

    Stage layout (default prim ``/Head``, kind ``component``)::

        /Head                      Xform
          Skin                     Mesh: constant triangle topology; time-sampled points,
                                   normals (area-weighted, interpolation "vertex") and extent;
                                   primvars:st (vertex or indexed faceVarying) when uv is given;
                                   material Looks/Skin; subdivisionScheme "none"
          Parts/<Name>             the part's Mesh at rest with a time-sampled xformOp:transform
                                   (matrix4d); material Looks/White (Looks/Skin for names
                                   containing "tongue"), or Looks/<Name> of its ``part_colors``
            <Subset>               with ``subsets``: GeomSubsets (family materialBind, a partition
                                   of the mesh's faces) bound to Looks/<Subset>; facewarp's looks:
                                   Sclera, Iris, Pupil on each eyeball, Lips on the skin
          Muscles                  BasisCurves, type "linear", one curve per muscle; time-sampled
                                   points and extent; uniform primvars:activation (float, one per
                                   curve) and primvars:displayColor, time-sampled; uniform
                                   string[] muscleNames
          Tissue                   TetMesh (purpose "guide"), time-sampled points and extent
          Looks/Skin, Looks/White  Material with a UsdPreviewSurface (and one per part colour and
                                   subset name)
          Looks/SkinTexture        with ``skin_texture``: UsdPreviewSurface whose diffuseColor is a
                                   UsdUVTexture (sRGB, ``./<stem>_skin.png``) read at primvars:st;
                                   bound to the skin instead of Looks/Skin

    Stage metadata: ``upAxis``, ``metersPerUnit``, ``timeCodesPerSecond`` = ``framesPerSecond`` =
    ``fps``, ``startTimeCode``/``endTimeCode`` = first/last frame's time code, ``defaultPrim``.
    Time code = ``time_s * fps``, i.e. the frame index for frames at ``k / fps``.

    Shapes and dtypes: ``points``/``rest_points`` V (n, 3), ``faces`` F (m, 3) int (counter-clockwise
    seen from outside), ``uv`` (n, 2) or (k, 2) with ``uv_indices`` (m, 3), parts name -> (V (k, 3),
    F (l, 3)), ``muscle_points`` (M, s, 3), ``activations`` (M,), ``tets`` (T (k, 4) int, nodes (p, 3)).
    Floats may come as any real dtype and are stored as float32 (read back bit-exactly); indices
    as int32; all values must be finite.

    Transform convention: ``part_transforms[name]`` is a 4x4 matrix in USD's **row-vector**
    convention, ``p' = p @ M`` (``p`` a row ``[x, y, z, 1]``), rotation in ``M[:3, :3]``,
    translation in ``M[3, :3]``, last column ``(0, 0, 0, 1)``; this is the transpose of the
    column-vector matrix ``p' = M @ p`` (pass ``M.T``). It maps the part's rest mesh to its pose in
    the head's frame. A matrix with a translation in its last column is refused.

Many heads in one stage (:func:`write_crowd_stage`)
    ``/Crowd/<name>`` per head: an Xform with its placement referencing the head's own animation file.

Static meshes (:func:`write_meshes_usd`)
    Triangle meshes as ``/Head/<name>`` with optional time-sampled points, used by the CLI.

Blendshape rigs (:func:`write_skel_rig`)
    A rig baked from the physics as UsdSkel: Skeleton (root, jaw), SkelRoot, BlendShapes with
    in-betweens, a SkelAnimation (see ``usd_export/_skel.py``).

Checks (:func:`validate_usd`)
    USD's compliance checks (usdchecker's rules) on a file, returning the problems as lines.
"""

from __future__ import annotations

from ._arrays import UsdExportError
from ._reader import read_animation, validate_usd
from ._skel import write_skel_rig
from ._writer import AnimationWriter, part_prim_name
from .stage import write_crowd_stage, write_meshes_usd

__all__ = ["AnimationWriter", "UsdExportError", "part_prim_name", "read_animation", "validate_usd",
           "write_crowd_stage", "write_meshes_usd", "write_skel_rig"]
