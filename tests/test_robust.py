"""Issue 23, the solver side: any legal control stream simulates (rollback with sub-steps, the
volume floor), and the frame stats that say so. Level-0 default head, a few frames each."""

from __future__ import annotations

import numpy as np
import pytest

import facewarp as fw


# ----------------------------------------------------------------------------------------
# devices: every array a stage, Springs or solver receives is on the model's device


def test_an_array_on_another_device_is_an_input_error():
    import warp as wp

    from facewarp.physics import check_device

    check_device(wp.zeros(3, dtype=float, device="cpu"), "cpu", "x")  # the same device: fine
    check_device(np.zeros(3), "cuda:0", "x")  # not a Warp array: not checked
    with pytest.raises(fw.InputError, match=r"stages: Foo.springs\[0\].node: a Warp array on cpu, but the model is on cuda:0"):
        check_device(wp.zeros(3, dtype=wp.int32, device="cpu"), "cuda:0", "stages: Foo.springs[0].node")


@pytest.mark.skipif("not __import__('warp').is_cuda_available()", reason="needs a CUDA device")
def test_springs_on_cuda_for_a_cpu_model_are_refused():
    """On a GPU machine Warp's default device is cuda:0: Springs made without device= for a CPU
    model crashed the process (CPU kernels reading CUDA pointers)."""
    import warp as wp

    from conftest import grid_tets
    from facewarp.physics import ModelBuilder, SolverImplicit, Springs

    V, T = grid_tets(2, 1, 1)
    model = ModelBuilder(V, T, material="physical").finalize("cpu")
    sp = Springs(node=wp.array([0, 1], dtype=wp.int32, device="cuda:0"),
                 point=wp.zeros(2, dtype=wp.vec3, device="cuda:0"), stiffness=wp.ones(2, dtype=float, device="cuda:0"),
                 rest_length=wp.zeros(2, dtype=float, device="cuda:0"))

    class Stage:
        springs = sp

        def prepare(self, *args):
            pass

    with pytest.raises(fw.InputError, match="springs\\[0\\].node: a Warp array on cuda:0, but the model is on cpu"):
        SolverImplicit(model, stages=[Stage()])
    cuda_state = ModelBuilder(V, T, material="physical").finalize("cuda:0").state()
    solver = SolverImplicit(model)
    with pytest.raises(fw.InputError, match="state_in.positions: a Warp array on cuda:0"):
        solver.step(cuda_state, model.state(), model.control(), 0.01)
