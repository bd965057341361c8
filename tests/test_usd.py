"""usd_export: meshes and time-sampled points read back through pxr."""

from __future__ import annotations

import numpy as np

from usd_export import write_meshes_usd


def test_time_sampled_mesh_roundtrip(tmp_path):
    from pxr import Usd, UsdGeom

    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2]])
    frames = np.stack([V + [0, 0, 0.1 * k] for k in range(3)])
    p = write_meshes_usd(tmp_path / "a.usda", {"skin": (V, F)}, frames={"skin": frames}, times=[0, 1 / 30, 2 / 30])
    stage = Usd.Stage.Open(str(p))
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Head/skin"))
    pts = np.array(mesh.GetPointsAttr().Get(2.0))
    np.testing.assert_allclose(pts[:, 2], 0.2, rtol=1e-6)
    assert list(mesh.GetFaceVertexIndicesAttr().Get()) == [0, 1, 2]
    assert not [q for q in tmp_path.iterdir() if q.name.startswith(".")]
