"""Positions unchanged by the physics split (issue 35: a change of shape, not of numbers).

Every expression preset, the Fig. 6.16 sequence, the Verlet and Newton-PCG solvers and both batch
backends, a few frames each on the default head (level 0, CPU), against node positions recorded on
the tree before the split (``tests/data/positions_baseline.npz``, float32 [m], as the State holds them); each must stay within
1e-6 m. Re-record (only on purpose, when the numbers are meant to change) with
``python tests/test_positions_unchanged.py --record``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import facewarp as fw

BASELINE = Path(__file__).resolve().parent / "data" / "positions_baseline.npz"
TOLERANCE_M = 1e-6
FRAMES = 3  # frames after rest, at 30 fps
PRESET_NAMES = tuple(fw.PRESETS)


def _rig():
    return fw.build_face(fw.default_template(0))


def _sequence():
    # the Fig. 6.16 sequence squeezed so that a few frames pass through every expression
    return fw.thesis_sequence(each=0.06, overlap=0.02)


def _run(sim, timeline, frames: int) -> np.ndarray:
    """Node positions [m] after each of ``frames`` frames, shape (frames, p, 3), float64."""
    head = timeline.for_head(sim.fr)
    out = []
    for k in range(1, frames + 1):
        e = head.sample(k / sim.fps)
        sim.set_activations(e)
        sim.set_jaw(e.jaw_u, e.jaw_v)
        sim.step()
        out.append(sim.positions())
    return np.stack(out)


def _batch(rig, backend: str) -> np.ndarray:
    b = fw.FaceBatch(rig, 2, device="cpu", backend=backend)
    tl = [fw.timeline_for("smile", attack=0.05, start=0.0).for_head(rig),
          fw.timeline_for("laugh", attack=0.05, start=0.0).for_head(rig)]
    out = []
    for k in range(1, FRAMES):
        es = [t.sample(k / 30.0) for t in tl]
        b.set_activations([e.activations for e in es])
        b.set_jaw([(e.jaw_u, e.jaw_v) for e in es])
        b.step()
        out.append(np.stack([b.positions(i) for i in range(2)]))
    return np.stack(out)


# (the squeezed sequence starts at 0.2 s: the implicit run reaches it, the Verlet run's two frames would not)
CASES = ([f"implicit/{p}" for p in PRESET_NAMES] + ["implicit/sequence", "verlet/smile", "newton-pcg/laugh",
         "batch-heads", "batch-model"])


def compute(case: str, rig) -> np.ndarray:
    if case.startswith("batch-"):
        return _batch(rig, case.split("-", 1)[1])
    solver, name = case.split("/")
    tl = _sequence() if name == "sequence" else fw.timeline_for(name, attack=0.05, start=0.0)
    if solver == "verlet":
        sim = fw.FaceSimulator(rig, device="cpu", solver="verlet")
        return _run(sim, tl, 2)
    if solver == "newton-pcg":
        sim = fw.FaceSimulator(rig, device="cpu", method="newton-pcg")
        return _run(sim, tl, FRAMES)
    frames = 9 if name == "sequence" else FRAMES
    return _run(fw.FaceSimulator(rig, device="cpu"), tl, frames)


@pytest.fixture(scope="module")
def rig():
    return _rig()


@pytest.fixture(scope="module")
def baseline():
    if not BASELINE.is_file():
        pytest.fail(f"{BASELINE} missing: record it on the tree before the change")
    return dict(np.load(BASELINE))


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES)
def test_positions_unchanged(case, rig, baseline):
    X = compute(case, rig)
    ref = baseline[case].astype(np.float64)
    assert X.shape == ref.shape, f"{case}: shape {X.shape} vs baseline {ref.shape}"
    assert np.isfinite(X).all()
    moved = float(np.abs(ref - _rest(rig)).max())
    assert moved > 1e-5 or case == "implicit/neutral", f"{case}: the face did not move ({moved} m): a test that cannot fail"
    err = float(np.abs(X - ref).max())
    assert err <= TOLERANCE_M, f"{case}: positions differ from the baseline by {err:.3g} m (> {TOLERANCE_M} m)"


def _rest(rig):
    return np.asarray(rig.nodes, np.float64)


if __name__ == "__main__":
    if "--record" not in sys.argv[1:]:
        sys.exit("usage: python tests/test_positions_unchanged.py --record")
    import time

    r = _rig()
    got = {}
    for c in CASES:
        t0 = time.perf_counter()
        got[c] = compute(c, r)
        print(f"{c}: {got[c].shape} moved {np.abs(got[c] - (_rest(r) if got[c].ndim == 3 else 0)).max():.3g} m "
              f"{time.perf_counter() - t0:.1f} s", flush=True)
    BASELINE.parent.mkdir(exist_ok=True)
    np.savez_compressed(BASELINE, **{c: X.astype(np.float32) for c, X in got.items()})  # float32 State: lossless
    print(f"wrote {BASELINE}")
