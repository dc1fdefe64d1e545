"""Drift per length travelled: exact errors on hand-made paths, pairing, NaN rows, the table."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pandas as pd
import pytest

from segloc_cli.scoring.drift import (
    DRIFT_COLUMNS,
    DRIFT_LENGTHS_M,
    drift_per_length,
    format_drift_md,
    travelled_m,
)

ERROR_COLUMNS = [c for c in DRIFT_COLUMNS if c not in ("length_m", "n_pairs")]


def straight_line(step_m: float = 0.5, length_m: float = 10.0) -> np.ndarray:
    """Poses along +x every ``step_m``, heading 0 (x m, y m, θ rad)."""
    x = np.arange(0.0, length_m + step_m / 2, step_m)
    return np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])


def shifted(poses: np.ndarray, dx_m: float, dy_m: float, dtheta_rad: float) -> np.ndarray:
    """Every pose moved by the same amounts in x, y and heading (not a rigid motion)."""
    return poses + np.array([dx_m, dy_m, dtheta_rad])


def loop_path() -> np.ndarray:
    """A 4 m × 3 m rectangle walked once every 0.25 m, heading along the walk, with a
    little sway so the headings are not all multiples of 90°."""
    corners = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0], [0.0, 0.0]])
    points = []
    for start, end in itertools.pairwise(corners):
        n = round(float(np.hypot(*(end - start))) / 0.25)
        t = np.arange(n)[:, None] / n
        points.append(start + t * (end - start))
    xy = np.vstack(points)
    theta = np.arctan2(*np.diff(xy, axis=0, append=xy[:1]).T[::-1])
    return np.column_stack([xy, theta + 0.05 * np.sin(np.arange(len(xy)))])


def test_travelled_counts_steps_not_turns():
    truth = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [3.0, 4.0, 2.0], [3.0, 0.0, -1.0]])
    np.testing.assert_allclose(travelled_m(truth), [0.0, 5.0, 5.0, 9.0])
    assert travelled_m(np.zeros((0, 3))).shape == (0,)


def test_constant_heading_bias_gives_chord_error_growing_with_length():
    truth = straight_line()
    bias_rad = np.deg2rad(2.0)
    estimates = shifted(truth, 0.0, 0.0, bias_rad)
    frame = drift_per_length(truth, estimates)
    # Over a true step of L straight ahead, the biased estimate steps L along a heading
    # turned by the bias: the two ends are a chord 2 L sin(bias / 2) apart.
    chord = 2.0 * math.sin(bias_rad / 2.0)
    lengths = np.array(DRIFT_LENGTHS_M)
    np.testing.assert_array_equal(frame["length_m"], lengths)
    np.testing.assert_array_equal(frame["n_pairs"], 21 - 2 * lengths.astype(int))
    for column in ("trans_mean_cm", "trans_rms_cm", "trans_max_cm"):
        np.testing.assert_allclose(frame[column], 100.0 * lengths * chord, rtol=1e-9)
    np.testing.assert_allclose(frame["trans_pct"], 100.0 * chord, rtol=1e-9)
    np.testing.assert_allclose(frame[["rot_mean_deg", "rot_max_deg"]], 0.0, atol=1e-12)


def test_scale_error_is_a_percentage_of_the_length_and_ends_are_the_first_beyond_it():
    x = np.array([0.0, 0.4, 0.9, 1.0, 1.6, 2.5])
    truth = np.column_stack([x, np.zeros(6), np.zeros(6)])
    estimates = truth * [1.1, 1.0, 1.0]
    row = drift_per_length(truth, estimates, lengths_m=(1.0,)).iloc[0]
    # Pairs 0→3 (1.0 m), 1→4 (1.2 m), 2→5 (1.6 m), 3→5 (1.5 m); 4 has no end 1 m on.
    assert row["n_pairs"] == 4
    assert row["trans_mean_cm"] == pytest.approx(10.0 * (1.0 + 1.2 + 1.6 + 1.5) / 4)
    assert row["trans_max_cm"] == pytest.approx(16.0)
    assert row["trans_pct"] == pytest.approx(10.0)


def test_heading_drift_per_metre():
    truth = straight_line()
    rate_rad_per_m = np.deg2rad(0.5)
    estimates = truth + np.column_stack([np.zeros((len(truth), 2)), rate_rad_per_m * truth[:, 0]])
    frame = drift_per_length(truth, estimates)
    lengths = np.array(DRIFT_LENGTHS_M)
    np.testing.assert_allclose(frame["rot_mean_deg"], 0.5 * lengths, rtol=1e-9)
    np.testing.assert_allclose(frame["rot_max_deg"], 0.5 * lengths, rtol=1e-9)
    np.testing.assert_allclose(frame["rot_deg_per_m"], 0.5, rtol=1e-9)


@pytest.mark.parametrize(
    "move",
    [
        lambda p: shifted(p, 2.0, -1.5, 0.0),
        lambda p: np.column_stack(
            [
                math.cos(0.7) * p[:, 0] - math.sin(0.7) * p[:, 1],
                math.sin(0.7) * p[:, 0] + math.cos(0.7) * p[:, 1],
                p[:, 2] + 0.7,
            ]
        ),
    ],
    ids=["offset", "rotation-about-origin"],
)
def test_moving_the_whole_trajectory_gives_no_drift(move):
    truth = loop_path()
    frame = drift_per_length(truth, move(truth))
    assert (frame["n_pairs"] > 0).all()
    np.testing.assert_allclose(frame[ERROR_COLUMNS], 0.0, atol=1e-9)


def test_pairs_touching_a_failed_pose_are_left_out():
    truth = straight_line()
    estimates = shifted(truth, 0.0, 0.0, np.deg2rad(2.0))
    estimates[3] = np.nan
    frame = drift_per_length(truth, estimates, lengths_m=(1.0, 10.0))
    # 1 m is two poses on: the pairs 1→3 and 3→5 go; the one 10 m pair 0→20 stays.
    assert frame["n_pairs"].tolist() == [17, 1]
    chord_cm = np.array([100.0, 1000.0]) * 2.0 * math.sin(np.deg2rad(1.0))
    np.testing.assert_allclose(frame["trans_mean_cm"], chord_cm, rtol=1e-9)


def test_lengths_beyond_the_path_give_no_pairs():
    truth = straight_line(length_m=3.0)
    frame = drift_per_length(truth, shifted(truth, 0.0, 0.0, 0.01))
    assert frame["n_pairs"].tolist() == [5, 3, 0, 0]
    assert frame.loc[2:, ERROR_COLUMNS].isna().all().all()
    assert frame.loc[:1, ERROR_COLUMNS].notna().all().all()


def test_a_length_reached_only_up_to_rounding_still_pairs():
    # Ten steps of 0.1 m add up to a hair under 1 m in floating point.
    x = np.cumsum(np.r_[0.0, np.full(10, 0.1)])
    truth = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    assert drift_per_length(truth, truth, lengths_m=(1.0,))["n_pairs"].item() == 1


def test_bad_shapes_and_lengths_are_refused():
    truth = straight_line()
    with pytest.raises(ValueError, match="pair up"):
        drift_per_length(truth, truth[:-1])
    with pytest.raises(ValueError, match="positive"):
        drift_per_length(truth, truth, lengths_m=(1.0, 0.0))
    with pytest.raises(ValueError, match="finite"):
        travelled_m(np.array([[0.0, 0.0, 0.0], [np.nan, 1.0, 0.0]]))


def test_markdown_table_rounds_and_marks_missing_lengths():
    frame = pd.DataFrame(
        [
            [1.0, 12, 1.234, 1.5, 2.06, 1.234, 0.123, 0.4567, 0.123],
            [5.0, 0, *([np.nan] * 7)],
        ],
        columns=list(DRIFT_COLUMNS),
    )
    lines = format_drift_md(frame).splitlines()
    assert [c.strip() for c in lines[0].strip("|").split("|")] == [
        "length (m)",
        "pairs",
        "mean (cm)",
        "RMS (cm)",
        "max (cm)",
        "drift (%)",
        "rot mean (°)",
        "rot max (°)",
        "rot (°/m)",
    ]
    assert [c.strip() for c in lines[2].strip("|").split("|")] == [
        "1.0",
        "12",
        "1.2",
        "1.5",
        "2.1",
        "1.23",
        "0.12",
        "0.46",
        "0.12",
    ]
    assert [c.strip() for c in lines[3].strip("|").split("|")] == ["5.0", "0", *["—"] * 7]
