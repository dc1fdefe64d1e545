"""Convergence curves: success against initial error, counted on hand-made sweep rows."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from segloc_cli.estimates import STATUS_TASK_FAILED
from segloc_cli.scoring.convergence import (
    ALL,
    HEADING_BINS_DEG,
    POSITION_BINS_M,
    combination_labels,
    convergence_table,
    draw_convergence,
    format_convergence_md,
    initial_errors,
    succeeded,
    wilson_interval,
)

NAN = math.nan
Z = 1.959963984540054
"""The two-sided 95 % quantile of the normal distribution."""


def _row(iterations, init, estimate, error, status="ok", pose_id=1):
    """A sweep row: the guess and estimate (x m, y m, θ °), errors (x cm, y cm, θ °)."""
    err_x, err_y, err_theta = error
    return {
        "log": "hall", "pose_id": pose_id, "iterations": iterations,
        "init_x_m": init[0], "init_y_m": init[1], "init_theta_deg": init[2],
        "x_m": estimate[0], "y_m": estimate[1], "theta_deg": estimate[2],
        "status": status, "err_x_cm": err_x, "err_y_cm": err_y,
        "err_xy_cm": math.hypot(err_x, err_y), "err_theta_deg": err_theta,
    }  # fmt: skip


ROWS = pd.DataFrame(
    [
        # iterations=6
        # truth (2, 1, 90): 0.25 m off, exactly on an edge, so in the second position bin
        _row(6, (2.0, 0.75, 90.0), (2.0, 1.0, 90.0), (0.0, 0.0, 0.0)),
        # truth (3.05, 1, 11): 0.1 m off; 5° off, on an edge; 5 cm and 1° wrong: a success
        _row(6, (3.05, 1.1, 6.0), (3.0, 1.0, 10.0), (5.0, 0.0, 1.0)),
        # truth (0, 0, 0): 0.75 m and 170° off; right, but lost: a failure
        _row(6, (0.0, 0.75, -170.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), status="lost"),
        # truth (5.4, 5, 0): on the spot, 180° off (the last edge); 40 cm wrong: a failure
        _row(6, (5.4, 5.0, 180.0), (5.0, 5.0, 0.0), (40.0, 0.0, 0.0)),
        # a global search: no guess
        _row(6, (NAN, NAN, NAN), (1.0, 1.0, 0.0), (0.0, 0.0, 0.0)),
        # truth (1, 1, 175): 1.5 m off, and 10° across ±180° (an edge); recovered: a success
        _row(6, (1.0, 2.5, -175.0), (1.0, 1.0, 175.0), (0.0, 0.0, 0.0), status="recovered"),
        # iterations=8
        _row(8, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
        # 10 m off: beyond the last position bin, in the first heading bin
        _row(8, (10.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
        _row(8, (NAN, NAN, NAN), (NAN, NAN, NAN), (NAN, NAN, NAN), STATUS_TASK_FAILED, -1),
        # a guess but no estimate: its truth is known from the survey alone
        _row(8, (1.0, 1.5, 30.0), (NAN, NAN, NAN), (NAN, NAN, NAN), "too_few_segments", 7),
    ]
)
TRUTH = pd.DataFrame(
    {"log": ["hall"], "pose_id": [7], "x_m": [1.0], "y_m": [1.0], "theta_deg": [0.0]}
)  # fmt: skip


def _counts(table, combination, axis):
    part = table[(table["combination"] == combination) & (table["axis"] == axis)]
    return list(zip(part["n_trials"], part["n_success"], strict=True))


def test_initial_errors_are_the_guess_against_the_truth():
    position_m, heading_deg = initial_errors(ROWS)
    assert position_m[0] == 0.25 and heading_deg[1] == 5.0
    assert position_m[2] == 0.75 and heading_deg[2] == 170.0
    assert heading_deg[3] == 180.0 and heading_deg[5] == 10.0
    assert np.isnan(position_m[4]) and np.isnan(position_m[9])
    position_m, heading_deg = initial_errors(ROWS, TRUTH)
    assert position_m[9] == 0.5 and heading_deg[9] == 30.0


def test_success_needs_an_accepted_status_and_both_errors_within_the_bounds():
    rows = pd.DataFrame(
        [
            _row(6, (0, 0, 0), (0, 0, 0), (30.0, 0.0, 3.0)),  # on both bounds
            _row(6, (0, 0, 0), (0, 0, 0), (30.0, 0.5, 0.0)),
            _row(6, (0, 0, 0), (0, 0, 0), (0.0, 0.0, -3.5)),
            _row(6, (0, 0, 0), (0, 0, 0), (0.0, 0.0, 0.0), status="ambiguous"),
            _row(6, (0, 0, 0), (NAN, NAN, NAN), (NAN, NAN, NAN)),
        ]
    )
    assert succeeded(rows, 30.0, 3.0).tolist() == [True, False, False, False, False]


def test_counts_per_combination_axis_and_bin():
    table = convergence_table(ROWS, grid_keys=["iterations"])
    assert list(dict.fromkeys(table["combination"])) == ["iterations=6", "iterations=8"]
    assert len(table) == 2 * (len(POSITION_BINS_M) - 1 + len(HEADING_BINS_DEG) - 1)
    assert _counts(table, "iterations=6", "position") == [(2, 1), (1, 1), (1, 0), (1, 1), (0, 0)]
    assert _counts(table, "iterations=6", "heading") == [
        (1, 1), (1, 1), (1, 1), (0, 0), (0, 0), (2, 0)
    ]  # fmt: skip
    assert _counts(table, "iterations=8", "position") == [(1, 1), (0, 0), (0, 0), (0, 0), (0, 0)]
    assert _counts(table, "iterations=8", "heading")[0] == (2, 2)
    six = table[(table["combination"] == "iterations=6") & (table["axis"] == "position")]
    assert six["success_rate"].tolist()[:4] == [0.5, 1.0, 0.0, 1.0]
    assert np.isnan(six["success_rate"].iloc[4]) and np.isnan(six["wilson_lo"].iloc[4])
    assert six["bin_lo"].tolist() == list(POSITION_BINS_M[:-1])
    assert table.attrs["notes"] == [
        "no guess (a global search, a pose without a scan or guess, a failed task): 2 of 10 "
        "rows, in no bin",
        "a guess, but neither an estimate nor a survey pose to measure it against: 1 row, in "
        "no bin",
        "a guess beyond 4 m of the truth: 1 row, in no position bin",
    ]


def test_the_survey_counts_the_misses_of_rows_without_an_estimate():
    table = convergence_table(ROWS, TRUTH, grid_keys=["iterations"])
    assert _counts(table, "iterations=8", "position") == [(1, 1), (0, 0), (1, 0), (0, 0), (0, 0)]
    assert _counts(table, "iterations=8", "heading")[3] == (1, 0)
    assert len(table.attrs["notes"]) == 2


def test_a_stricter_criterion_counts_fewer_successes():
    table = convergence_table(ROWS, grid_keys=["iterations"], success_cm=4.0, success_deg=3.0)
    # The 5 cm answer no longer succeeds.
    assert _counts(table, "iterations=6", "position")[0] == (2, 0)
    assert table.attrs["success_cm"] == 4.0


def test_one_combination_is_all():
    assert set(combination_labels(ROWS, [])) == {ALL}
    assert set(combination_labels(ROWS[ROWS["iterations"] == 6], ["iterations"])) == {ALL}
    assert set(convergence_table(ROWS)["combination"]) == {ALL}


def test_wilson_interval_against_hand_computed_bounds():
    low, high = wilson_interval(np.array([8, 0, 4, 0]), np.array([10, 5, 4, 0]))
    # 8 of 10: the textbook example, (0.4902, 0.9433).
    assert low[0] == pytest.approx(0.4902, abs=1e-4)
    assert high[0] == pytest.approx(0.9433, abs=1e-4)
    # None of n: [0, z²/(n + z²)]; all of n: [n/(n + z²), 1].
    assert (low[1], high[1]) == (0.0, pytest.approx(Z**2 / (5 + Z**2)))
    assert (low[2], high[2]) == (pytest.approx(4 / (4 + Z**2)), 1.0)
    assert np.isnan(low[3]) and np.isnan(high[3])


def test_markdown_rows_and_notes():
    text = format_convergence_md(convergence_table(ROWS, grid_keys=["iterations"]))
    assert text.startswith("Success: an accepted estimate (ok, recovered) within 30 cm and 3°")
    lines = [" ".join(line.split()) for line in text.splitlines()]
    one_of_one = f"{100 / (1 + Z**2):.1f}–100.0"
    assert f"| iterations=6 | 0.25–0.5 m | 1 | 1 | 100.0 | {one_of_one} |" in lines
    assert "| iterations=6 | 2–4 m | 0 | 0 | – | – |" in lines
    assert "| iterations=6 | 90–180° | 2 | 0 | 0.0 | 0.0–65.8 |" in lines
    assert lines[-1] == "- a guess beyond 4 m of the truth: 1 row, in no position bin"


def test_the_figure_has_a_line_per_combination_and_labelled_axes():
    table = convergence_table(ROWS, grid_keys=["iterations"])
    fig = draw_convergence(table)
    position, heading = fig.axes
    assert position.get_xlabel() == "initial position error (m)"
    assert heading.get_xlabel() == "initial heading error (°)"
    assert position.get_ylabel() == "success (%)"
    for ax, edges in ((position, POSITION_BINS_M), (heading, HEADING_BINS_DEG)):
        assert len(ax.get_lines()) == 2
        assert [t.get_text() for t in ax.get_xticklabels()] == [f"{e:g}" for e in edges]
    legend = [t.get_text() for t in position.get_legend().get_texts()]
    assert legend == ["iterations=6", "iterations=8"]
    six = position.get_lines()[0].get_ydata()
    np.testing.assert_array_equal(six, [50.0, 100.0, 0.0, 100.0, NAN])
