"""Calibration (Sec. 4.3.2, Eq. 4.3.2-4.3.4): least-squares similarity from shared FDPs."""

import numpy as np
import pytest

from facewarp import InputError
from facewarp.adaptation import CALIBRATION_FDPS, calibrate
from facewarp.geometry import Similarity, fit_similarity


def _rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _landmarks(ids, rng):
    return {k: rng.normal(scale=0.05, size=3) for k in ids}


def test_recovers_known_similarity_exactly():
    rng = np.random.default_rng(0)
    tmpl = _landmarks(CALIBRATION_FDPS + ("9.3", "3.8"), rng)
    truth = Similarity(1234.5, _rotation(rng), rng.normal(size=3) * 100)  # template [m] -> scan [mm]
    scan = {k: truth.apply(v) for k, v in tmpl.items()}
    cal = calibrate(scan, tmpl)
    assert cal.thesis_set
    assert set(cal.fdps_used) == set(CALIBRATION_FDPS)
    inv = truth.inverse()
    np.testing.assert_allclose(cal.transform.scale, inv.scale, rtol=1e-12, err_msg="scale")
    np.testing.assert_allclose(cal.transform.rotation, inv.rotation, atol=1e-12, err_msg="rotation")
    np.testing.assert_allclose(cal.transform.translation, inv.translation, atol=1e-12, err_msg="translation")
    assert cal.rms_residual < 1e-12


def test_subset_and_fallback_to_all_shared():
    rng = np.random.default_rng(1)
    tmpl = _landmarks(("2.1", "3.7", "3.12", "9.3", "3.8", "8.1"), rng)
    T = Similarity(0.9, _rotation(rng), [0.1, 0.2, 0.3])
    scan = {k: T.apply(v) for k, v in tmpl.items() if k != "8.1"}  # 3 thesis points + 2 others shared
    cal = calibrate(scan, tmpl)
    assert not cal.thesis_set
    assert cal.fdps_used == ("2.1", "3.7", "3.8", "3.12", "9.3")
    np.testing.assert_allclose(cal.transform.apply(scan["9.3"]), tmpl["9.3"], atol=1e-12)


def test_four_thesis_points_are_enough():
    rng = np.random.default_rng(2)
    tmpl = _landmarks(("2.1", "3.7", "3.12", "8.3"), rng)
    cal = calibrate({k: v + 1.0 for k, v in tmpl.items()}, tmpl)
    assert cal.thesis_set and len(cal.fdps_used) == 4
    np.testing.assert_allclose(cal.transform.translation, -np.ones(3), atol=1e-12)


def test_too_few_or_coplanar_is_an_error():
    rng = np.random.default_rng(3)
    tmpl = _landmarks(("2.1", "3.7", "3.12"), rng)
    with pytest.raises(InputError, match="at least 4"):
        calibrate(tmpl, tmpl)
    flat = {k: np.array([x, y, 0.0]) for k, (x, y) in zip(("2.1", "3.7", "3.12", "8.3", "8.4"), rng.normal(size=(5, 2)))}
    with pytest.raises(InputError, match="coplanar"):
        calibrate(flat, flat)


def test_similarity_inverse_and_compose():
    rng = np.random.default_rng(4)
    S = Similarity(2.5, _rotation(rng), rng.normal(size=3))
    X = rng.normal(size=(10, 3))
    np.testing.assert_allclose(S.inverse().apply(S.apply(X)), X, atol=1e-12)
    np.testing.assert_allclose(S.compose(S.inverse()).matrix(), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(fit_similarity(X, S.apply(X)).matrix(), S.matrix(), atol=1e-10)
