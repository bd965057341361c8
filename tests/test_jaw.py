"""Kinematic jaw (Sec. 6.4.3, Eq. 6.4.9): axes, direction, rotation amounts."""

from __future__ import annotations

import numpy as np
import pytest

from facewarp import default_template
from facewarp.anatomy import JawKinematic, rotate_about


@pytest.fixture(scope="module")
def jaw_and_lm():
    t = default_template(0)
    lm = t.landmarks()
    return JawKinematic.from_landmarks(t.condyles, lm), lm


def test_rotation_is_rigid():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(10, 3))
    Q = rotate_about(P, np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.6, 0.8]), 0.7)
    d0 = np.linalg.norm(P[:, None] - P[None], axis=-1)
    d1 = np.linalg.norm(Q[:, None] - Q[None], axis=-1)
    np.testing.assert_allclose(d0, d1, atol=1e-12)


def test_opening_moves_chin_down_and_back(jaw_and_lm):
    jaw, lm = jaw_and_lm
    P = np.array([lm["2.1"]])
    Q = jaw.apply(P, np.ones(1), np.deg2rad(20.0))
    assert Q[0, 1] < P[0, 1] - 0.01 and Q[0, 2] < P[0, 2]
    # the v-axis turns the chin sideways
    R = jaw.apply(P, np.ones(1), 0.0, np.deg2rad(5.0))
    assert abs(R[0, 0] - P[0, 0]) > 0.003


def test_amounts_follow_eq_6_4_9_text(jaw_and_lm):
    jaw, lm = jaw_and_lm
    P = np.array([lm["8.2"], lm["8.3"], lm["8.4"], lm["2.1"], lm["8.1"]])
    a = jaw.amounts(P, ["lower_lip", "lip_corner_L", "lip_corner_R", "chin", "upper_lip"])
    assert a[0] == pytest.approx(1.0, abs=0.02)  # middle of the lower lip: full rotation
    assert a[1] == pytest.approx(1 / 3) and a[2] == pytest.approx(1 / 3)  # corners: a third
    assert a[3] == pytest.approx(1.0)  # chin rigid with the mandible
    assert a[4] == pytest.approx(0.0, abs=0.02)  # upper lip middle stays
    # sqrt decrease from the middle to the corner
    mid = 0.5 * (lm["8.2"] + lm["8.3"])
    am = jaw.amounts(mid[None], ["lower_lip"])[0]
    assert 1 / 3 < am < 1.0
