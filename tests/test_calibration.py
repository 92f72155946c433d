"""Calibration statistics against hand-made cases: NEES, NIS, coverage and the χ² band."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from corrections_sim import calibration


def test_nees_by_hand():
    # e = (1, -2), P = diag(4, 1): eᵀP⁻¹e = 1/4 + 4 = 4.25.
    assert calibration.nees([1.0, -2.0], np.diag([4.0, 1.0]), [0.0, 0.0]) == pytest.approx(4.25)
    # A correlated P: P = [[2, 1], [1, 2]], P⁻¹ = [[2, -1], [-1, 2]] / 3; e = (1, 1) -> 2/3.
    cov = np.array([[2.0, 1.0], [1.0, 2.0]])
    assert calibration.nees([2.0, 0.0], cov, [1.0, -1.0]) == pytest.approx(2.0 / 3.0)


def test_nis_by_hand():
    assert calibration.nis([3.0], [[9.0]]) == pytest.approx(1.0)
    assert calibration.nis([1.0, 1.0], np.eye(2) * 0.5) == pytest.approx(4.0)


def test_shape_mismatch_is_refused():
    with pytest.raises(ValueError, match="cov"):
        calibration.nees([0.0, 0.0], np.eye(3), [1.0, 1.0])


def test_credible_radius_and_sigma_probabilities():
    assert calibration.ONE_SIGMA == pytest.approx(0.6827, abs=1e-4)
    assert calibration.TWO_SIGMA == pytest.approx(0.9545, abs=1e-4)
    # k = 1: the "1σ" ellipse is |e| ≤ σ, i.e. NEES ≤ 1; k = 2: χ²₂ quantile = −2 ln(1 − p).
    assert calibration.credible_radius(1, calibration.ONE_SIGMA) == pytest.approx(1.0)
    p = calibration.TWO_SIGMA
    assert calibration.credible_radius(2, p) == pytest.approx(-2 * np.log(1 - p))


def test_band_of_a_mean():
    # One run: the χ²_k interval itself; 60 runs of k = 2: χ²_120 quantiles / 60.
    assert calibration.mean_band(2, 1) == pytest.approx(
        (stats.chi2.ppf(0.025, 2), stats.chi2.ppf(0.975, 2))
    )
    low, high = calibration.mean_band(2, 60)
    assert (low, high) == pytest.approx((1.526, 2.537), abs=1e-3)  # the issue's [1.53, 2.54]
    with pytest.raises(ValueError):
        calibration.mean_band(2, 0)


def test_summarize_a_hand_made_table():
    # 4 runs, prior + 2 iterations, k = 2. 1σ radius (k=2) ≈ 2.296, 2σ ≈ 6.18.
    values = np.array(
        [
            [2.0, 1.0, 7.0],
            [2.0, 2.0, 1.0],
            [2.0, 3.0, 2.0],
            [2.0, np.nan, 100.0],  # a missing entry is ignored
        ]
    )
    out = calibration.summarize(values, 2)
    assert out["runs"] == 4
    assert out["mean_nees"] == pytest.approx([2.0, 2.0, 27.5])
    low, high = calibration.mean_band(2, 4)
    assert out["band"] == pytest.approx([low, high])
    assert out["inside_band"] == pytest.approx(0.5)  # iteration 1 inside, 2 not
    assert out["coverage_1sigma"] == pytest.approx([1.0, 2 / 3, 0.5])
    assert out["coverage_2sigma"] == pytest.approx([1.0, 1.0, 0.5])
    assert out["coverage_2sigma_mean"] == pytest.approx(0.75)


def test_a_calibrated_gaussian_is_inside_its_band(rng):
    # Errors drawn from the belief itself: NEES ~ χ²₂, coverage ≈ 68% / 95%.
    cov = np.array([[1.0, 0.3], [0.3, 0.5]])
    errors = rng.multivariate_normal(np.zeros(2), cov, size=(4000, 3))
    values = np.array([[calibration.nees(e, cov, np.zeros(2)) for e in run] for run in errors])
    out = calibration.summarize(values, 2)
    assert out["inside_band"] == 1.0
    assert out["coverage_1sigma_mean"] == pytest.approx(calibration.ONE_SIGMA, abs=0.02)
    assert out["coverage_2sigma_mean"] == pytest.approx(calibration.TWO_SIGMA, abs=0.01)
