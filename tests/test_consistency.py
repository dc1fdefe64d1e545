"""Covariance consistency: simulated errors drawn from known covariances, hand-made poses
with exact NEES, unusable covariances, and χ² quantiles against tabulated values."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pandas as pd
import pytest

from segloc_cli.estimates import COVARIANCE_COLUMNS
from segloc_cli.scoring.consistency import (
    EXPECTED_SHARE,
    chi2_cdf,
    chi2_quantile,
    consistency,
    covariance_matrices,
)

# A positive definite covariance of (x m, y m, θ rad) with every entry non-zero.
HAND_COVARIANCE = np.array([[4.0, 1.0, 0.5], [1.0, 1.0, 0.2], [0.5, 0.2, 0.25]])


def random_covariances(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3, 3) covariances, correlated and each of its own size: B Bᵀ for a random B whose
    position rows are scaled by 2 to 30 cm and heading row by 0.01 to 0.1 rad."""
    scales = np.column_stack(
        [np.repeat(rng.uniform(0.02, 0.3, n)[:, None], 2, axis=1), rng.uniform(0.01, 0.1, n)]
    )
    b = scales[:, :, None] * rng.normal(size=(n, 3, 3))
    return b @ b.transpose(0, 2, 1) + 1e-6 * np.eye(3)


def simulated(seed: int = 7, n: int = 10_000) -> tuple[np.ndarray, np.ndarray]:
    """Errors (n, 3) drawn from the covariances (n, 3, 3) they are returned with."""
    rng = np.random.default_rng(seed)
    covariances = random_covariances(rng, n)
    errors = (np.linalg.cholesky(covariances) @ rng.normal(size=(n, 3, 1)))[:, :, 0]
    return errors, covariances


def test_errors_drawn_from_their_covariances_are_consistent():
    errors, covariances = simulated()
    # The simulation is the case worth testing only if poses differ and x, y correlate.
    correlation = covariances[:, 0, 1] / np.sqrt(covariances[:, 0, 0] * covariances[:, 1, 1])
    assert np.percentile(np.abs(correlation), 50) > 0.3
    assert np.ptp(covariances[:, 0, 0]) > 10 * np.median(covariances[:, 0, 0])

    result = consistency(errors, covariances)
    assert result is not None
    assert (result.n_poses, result.n_without) == (10_000, 0)
    np.testing.assert_allclose(result.share_within, [39.35, 86.47, 98.89], atol=2.0)
    assert result.nees_position == pytest.approx(2.0, rel=0.05)
    assert result.nees_heading == pytest.approx(1.0, rel=0.05)
    assert result.nees_interval[0] < 2.0 < result.nees_interval[1]
    assert result.verdict == "consistent"


@pytest.mark.parametrize(
    ("factor", "verdict", "nees"), [(0.25, "over-confident", 8.0), (4.0, "under-confident", 0.5)]
)
def test_scaled_covariances_are_judged_wrong(factor, verdict, nees):
    errors, covariances = simulated()
    result = consistency(errors, factor * covariances)
    assert result is not None
    assert result.verdict == verdict
    assert result.nees_position == pytest.approx(nees, rel=0.05)
    assert verdict in result.lines()[-1]


def test_expected_shares_are_those_of_a_two_dimensional_gaussian():
    np.testing.assert_allclose(EXPECTED_SHARE, [39.35, 86.47, 98.89], atol=0.005)


@pytest.mark.parametrize(
    ("error", "nees_position", "nees_heading", "share"),
    [
        # Position block [[4, 1], [1, 1]], determinant 3: (1, 1) gives (1 − 2 + 4) / 3.
        ((1.0, 1.0, 0.5), 1.0, 1.0, (100.0, 100.0, 100.0)),
        ((2.0, 0.0, 0.0), 4.0 / 3.0, 0.0, (0.0, 100.0, 100.0)),
        ((0.0, -1.5, -1.0), 3.0, 4.0, (0.0, 100.0, 100.0)),
        ((0.0, 2.25, 0.0), 6.75, 0.0, (0.0, 0.0, 100.0)),
        # A heading error a turn away from 0.5 rad is 0.5 rad.
        ((0.0, 0.0, 0.5 + 2.0 * math.pi), 0.0, 1.0, (100.0, 100.0, 100.0)),
    ],
)
def test_single_pose_has_the_nees_worked_by_hand(error, nees_position, nees_heading, share):
    result = consistency(np.array([error]), HAND_COVARIANCE[None])
    assert result is not None
    assert result.nees_position == pytest.approx(nees_position, abs=1e-12)
    assert result.nees_heading == pytest.approx(nees_heading, abs=1e-12)
    assert result.share_within == share
    # One pose: its NEES is χ²(2), whose 2.5 % and 97.5 % points are tabulated.
    np.testing.assert_allclose(result.nees_interval, [0.0506, 7.378], atol=6e-4)
    np.testing.assert_allclose(result.nees_heading_interval, [0.000982, 5.024], atol=6e-4)


def covariance_frame(matrices: list[np.ndarray]) -> pd.DataFrame:
    # The cells written out, not taken from the package: a wrong placement there must fail.
    cells = [(0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2)]
    columns = zip(COVARIANCE_COLUMNS, cells, strict=True)
    return pd.DataFrame({name: [m[cell] for m in matrices] for name, cell in columns})


def test_covariance_matrices_are_built_symmetric_from_the_columns():
    other = np.diag([0.01, 0.04, 0.0025])
    matrices = covariance_matrices(covariance_frame([HAND_COVARIANCE, other]))
    np.testing.assert_array_equal(matrices, [HAND_COVARIANCE, other])

    partial = covariance_frame([HAND_COVARIANCE]).drop(columns=["cov_y_theta_m_rad"])
    expected = HAND_COVARIANCE.copy()
    expected[1, 2] = expected[2, 1] = np.nan
    np.testing.assert_array_equal(covariance_matrices(partial), [expected])

    assert np.isnan(covariance_matrices(pd.DataFrame({"x_m": [1.0, 2.0]}))).all()


def test_poses_without_a_usable_covariance_are_counted_not_judged():
    nan = np.full((3, 3), np.nan)
    half_missing = HAND_COVARIANCE.copy()
    half_missing[2, 2] = np.nan
    singular = 0.01 * np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    negative = np.diag([-0.01, 0.01, 0.01])
    covariances = np.stack([HAND_COVARIANCE, nan, half_missing, singular, negative, nan])
    errors = np.array([[1.0, 1.0, 0.5], *[[0.3, -0.2, 0.1]] * 4, [np.nan] * 3])
    result = consistency(errors, covariances)
    assert result is not None
    # The last pose has no estimate: it is no pose to judge at all.
    assert (result.n_poses, result.n_without, result.n_used) == (5, 4, 1)
    assert (result.nees_position, result.nees_heading) == (1.0, 1.0)
    assert "4 without" in result.lines()[0]


@pytest.mark.parametrize(
    ("tiny", "error_m"),
    [
        (np.eye(3) * 1e-310, 0.01),  # subnormal: the 2×2 determinant rounds to 0
        (np.diag([1e-310, 1.0, 1.0]), 0.01),  # one subnormal variance
        (np.eye(3) * 1e-150, 1e80),  # invertible, but the NEES is past float64's range
        (np.diag([1.0, 1.0, 1e-320]), 0.01),  # the heading's variance
    ],
)
def test_a_covariance_too_small_to_invert_is_counted_not_judged(tiny, error_m):
    errors = np.array([[1.0, 1.0, 0.5], [error_m, -error_m, error_m]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = consistency(errors, np.stack([HAND_COVARIANCE, tiny]))
    assert result is not None
    assert (result.n_poses, result.n_without, result.n_used) == (2, 1, 1)
    assert (result.nees_position, result.nees_heading) == (1.0, 1.0)
    assert (
        "1 without (missing, not positive definite, or too small to invert)" in (result.lines()[0])
    )
    # Alone, it leaves nothing to judge.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        alone = consistency(errors[1:], tiny[None])
    assert alone is not None and (alone.n_used, alone.verdict) == (0, "unknown")
    assert json.loads(json.dumps(alone.as_json(), allow_nan=False))["nees_position"] is None


def test_a_mean_nees_whose_sum_overflows_stays_finite():
    # Two poses, each NEES finite but near float64's largest: their plain sum overflows.
    covariance = np.eye(3) * 1e-100
    errors = np.array([[1.3e104, 0.0, 0.0], [1.3e104, 0.0, 0.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = consistency(errors, np.stack([covariance, covariance]))
    assert result is not None and result.n_used == 2
    assert math.isfinite(result.nees_position) and result.nees_position > 1e307
    assert result.verdict == "over-confident"


def test_no_covariance_at_all_gives_none_and_none_usable_gives_unknown():
    errors = np.zeros((2, 3))
    assert consistency(errors, np.full((2, 3, 3), np.nan)) is None

    singular = np.stack([np.zeros((3, 3)), np.ones((3, 3))])
    result = consistency(errors, singular)
    assert result is not None
    assert (result.n_poses, result.n_without, result.verdict) == (2, 2, "unknown")
    assert len(result.lines()) == 1 and "none of the 2 poses" in result.lines()[0]
    plain = json.loads(json.dumps(result.as_json(), allow_nan=False))
    assert plain["nees_position"] is None and plain["share_within_pct"] == [None] * 3
    assert plain["verdict"] == "unknown"


def test_json_holds_the_numbers_of_the_result():
    errors, covariances = simulated(n=500)
    result = consistency(errors, covariances)
    assert result is not None
    plain = json.loads(json.dumps(result.as_json(), allow_nan=False))
    assert plain["n_poses"] == 500 and plain["n_used"] == 500
    assert plain["share_within_pct"] == list(result.share_within)
    assert plain["nees_position"] == result.nees_position
    assert plain["nees_interval"] == list(result.nees_interval)
    assert plain["verdict"] == result.verdict


def test_wrong_shapes_are_refused():
    with pytest.raises(ValueError, match="errors"):
        consistency(np.zeros((2, 2)), np.zeros((2, 3, 3)))
    with pytest.raises(ValueError, match="covariances"):
        consistency(np.zeros((2, 3)), np.zeros((3, 3, 3)))


# Tabulated χ² quantiles (dof, lower-tail probability, value to the table's 3 decimals).
CHI2_TABLE = [
    (1, 0.025, 0.000982),
    (1, 0.95, 3.841),
    (1, 0.975, 5.024),
    (2, 0.025, 0.0506),
    (2, 0.975, 7.378),
    (3, 0.025, 0.216),
    (3, 0.975, 9.348),
    (5, 0.025, 0.831),
    (5, 0.975, 12.833),
    (10, 0.025, 3.247),
    (10, 0.95, 18.307),
    (10, 0.975, 20.483),
    (20, 0.025, 9.591),
    (20, 0.975, 34.170),
    (30, 0.975, 46.979),
    (50, 0.025, 32.357),
    (50, 0.975, 71.420),
    (100, 0.025, 74.222),
    (100, 0.975, 129.561),
]


@pytest.mark.parametrize(("dof", "probability", "value"), CHI2_TABLE)
def test_chi2_quantiles_match_the_table(dof, probability, value):
    assert chi2_quantile(probability, dof) == pytest.approx(value, abs=6e-4, rel=1e-3)
    assert chi2_cdf(chi2_quantile(probability, dof), dof) == pytest.approx(probability, abs=1e-9)


@pytest.mark.parametrize("probability", [0.01, 0.025, 0.5, 0.975, 0.999])
def test_chi2_with_two_degrees_of_freedom_is_exponential(probability):
    assert chi2_quantile(probability, 2) == pytest.approx(-2.0 * math.log1p(-probability))


@pytest.mark.parametrize(("probability", "z"), [(0.025, -1.959964), (0.975, 1.959964)])
def test_chi2_quantile_of_many_poses_agrees_with_wilson_hilferty(probability, z):
    # For 20,000 degrees of freedom the cube-root normal approximation is far within 1e-5.
    dof = 20_000
    approx = dof * (1.0 - 2.0 / (9.0 * dof) + z * math.sqrt(2.0 / (9.0 * dof))) ** 3
    assert chi2_quantile(probability, dof) == pytest.approx(approx, rel=1e-5)
