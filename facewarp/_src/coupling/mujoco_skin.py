"""The simulated skin inside a MuJoCo model: head.xml's ``skin`` mesh moved by the face.

:func:`~facewarp._src.coupling.mjcf.head_mjcf` with ``skin=(V, F)`` puts the skin on the cranium
as a visual mesh geom ``skin`` (its rest shape, in the head frame). MuJoCo's renderer and viewer
draw the model's meshes from ``MjModel.mesh_vert`` / ``mesh_normal`` uploaded once to the GL
context; :class:`MujocoSkin` writes the face's current vertices (jaw, muscles, contact: the
simulator's :meth:`~facewarp.FaceSimulator.surface` in the head frame) into the model each frame
and re-uploads that one mesh to the renderers it is given, so ``mujoco.Renderer`` and
``mujoco.viewer`` show the moving face on whatever body carries the head.

MuJoCo's compiler moves each mesh into its own inertial frame (``mesh_pos``, ``mesh_quat``, kept
in the model) and puts the inverse on the geom; the update applies the same map,
``v_mesh = R^T (v_head - p)``, so the geom's pose needs no change. Normals are the area-weighted
vertex normals of the moved surface (MuJoCo computes per-vertex normals for an inline mesh, one
per vertex in the same order). A textured skin (``head_mjcf(skin=(V, F, uv, face_uv))``) has its
vertices split at the UV seams (:func:`~facewarp._src.coupling.mjcf.skin_vertex_split`: the face's
own vertices first, then the copies); the update writes each copy with its vertex's position and
normal, so the seams stay closed and smooth. The skin is visual only: no contact, no mass, and MuJoCo's
bounding volumes of the mesh stay those of the rest shape (used for collision and ray queries,
which a visual geom does not take part in).
"""

from __future__ import annotations

import time

import numpy as np

from ..core.errors import InputError
from ..geometry.surface import vertex_normals
from .mujoco import _mujoco

__all__ = ["MujocoSkin"]


class MujocoSkin:
    """Moves head.xml's skin mesh with a face simulator (see the module docstring).

    Args:
        sim: The :class:`~facewarp.FaceSimulator` of the head.
        model: The ``mujoco.MjModel`` holding the skin mesh (``head_mjcf(..., skin=...)``).
        prefix: The name prefix; None (default): the one prefix under which the model has a mesh
            named ``mesh``.
        mesh: The skin mesh's name after the prefix.

    Attributes:
        mesh_id: The mesh's index in the model.
        update_seconds: Wall-clock seconds spent in :meth:`update` so far, split as
            ``{"surface": ..., "model": ..., "upload": ...}`` (the face's vertices from the
            simulator; the transform and normals written into the model; the GL uploads).
        updates: How many times :meth:`update` ran.

    Raises:
        InputError: no such mesh (or several heads and no prefix), or a mesh whose vertex count
            is not the face's.
    """

    def __init__(self, sim, model, *, prefix: str | None = None, mesh: str = "skin"):
        if not (callable(getattr(sim, "surface", None)) and hasattr(getattr(sim, "fr", None), "head_vertices")):
            raise InputError(f"sim: expected a FaceSimulator, got {type(sim).__name__}")
        mj = _mujoco()
        if not isinstance(model, mj.MjModel):
            raise InputError(f"model: expected a mujoco.MjModel (mujoco.MjModel.from_xml_path of a head.xml written "
                             f"with skin=), got {type(model).__name__}")
        if prefix is not None and not isinstance(prefix, str):
            raise InputError(f"prefix: expected a string or None, got {type(prefix).__name__}")
        if not isinstance(mesh, str) or not mesh:
            raise InputError(f"mesh: expected a mesh name, got {mesh!r:.40}")
        self.mj, self.sim, self.model = mj, sim, model
        names = [model.mesh(i).name for i in range(model.nmesh)]
        if prefix is None:
            found = [n[: len(n) - len(mesh)] for n in names if n.endswith(mesh)]
            if len(found) != 1:
                raise InputError(f"mesh: {'no' if not found else len(found)} meshes named {mesh!r} (after any prefix) "
                                 "in the MuJoCo model" + ("; pass prefix= to pick one" if found else
                                                          " (write head.xml with skin=)"))
            prefix = found[0]
        i = mj.mj_name2id(model, mj.mjtObj.mjOBJ_MESH, prefix + mesh)
        if i < 0:
            raise InputError(f"mesh: no mesh named {prefix + mesh!r} in the MuJoCo model")
        self.prefix, self.mesh_id = prefix, int(i)
        self.faces = np.asarray(sim.fr.head_faces, np.int64)
        n = int(model.mesh_vertnum[i])
        n_head = len(sim.fr.head_vertices)
        self._src = None  # a textured skin: its vertices split at the UV seams, the copies after the first n_head
        if n != n_head and getattr(sim.fr, "head_face_uv", None) is not None:
            from .mjcf import skin_vertex_split

            src = skin_vertex_split(self.faces, sim.fr.head_face_uv)[1]
            if len(src) == n:
                self._src = src
        if (n != n_head and self._src is None) or int(model.mesh_normalnum[i]) != n:
            raise InputError(f"mesh {prefix + mesh!r}: {n} vertices ({int(model.mesh_normalnum[i])} normals), the "
                             f"face has {n_head}: not this head's skin")
        self._v = slice(int(model.mesh_vertadr[i]), int(model.mesh_vertadr[i]) + n)
        self._n = slice(int(model.mesh_normaladr[i]), int(model.mesh_normaladr[i]) + n)
        q = np.asarray(model.mesh_quat[i], np.float64)
        R = np.empty(9)
        mj.mju_quat2Mat(R, q)
        self._R = R.reshape(3, 3)  # v_head = R v_mesh + p
        self._p = np.asarray(model.mesh_pos[i], np.float64).copy()
        self.update_seconds = {"surface": 0.0, "model": 0.0, "upload": 0.0}
        self.updates = 0

    def update(self, *targets) -> None:
        """Write the face's current skin into the model and upload it to each target: a
        ``mujoco.Renderer``, a ``mujoco.MjrContext`` (its GL context current) or a passive
        viewer handle (``mujoco.viewer.launch_passive``)."""
        t0 = time.perf_counter()
        V = self.sim.surface(frame="head")
        t1 = time.perf_counter()
        Vm = (V - self._p) @ self._R
        N = vertex_normals(Vm, self.faces)  # smooth across the UV seams: the copies take their vertex's normal
        if self._src is not None:
            Vm, N = Vm[self._src], N[self._src]
        self.model.mesh_vert[self._v] = Vm
        self.model.mesh_normal[self._n] = N
        t2 = time.perf_counter()
        for target in targets:
            self._upload(target)
        t3 = time.perf_counter()
        for key, dt in (("surface", t1 - t0), ("model", t2 - t1), ("upload", t3 - t2)):
            self.update_seconds[key] += dt
        self.updates += 1

    def _upload(self, target) -> None:
        mj = self.mj
        if hasattr(target, "update_mesh"):  # the passive viewer's handle: it uploads under its own lock
            target.update_mesh(self.mesh_id)
        elif isinstance(target, mj.MjrContext):
            mj.mjr_uploadMesh(self.model, target, self.mesh_id)
        elif isinstance(target, mj.Renderer):
            # the Renderer keeps its GL and MjrContext private: make its context current first
            target._gl_context.make_current()
            mj.mjr_uploadMesh(self.model, target._mjr_context, self.mesh_id)
        else:
            raise InputError(f"targets: expected a mujoco.Renderer, MjrContext or viewer handle, got "
                             f"{type(target).__name__}")

    def vertices(self) -> np.ndarray:
        """The skin as the model holds it now, in the head frame [m], shape (n, 3), float64 (the
        face's n vertices; a textured skin's seam copies left out)."""
        V = np.asarray(self.model.mesh_vert[self._v], np.float64) @ self._R.T + self._p
        return V[: len(self.sim.fr.head_vertices)]
