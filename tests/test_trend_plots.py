"""Figures of Table 1 alone: bars per pose on readable slots, and errors along time and travel."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.container import BarContainer
from matplotlib.figure import Figure

from segloc_cli.scoring.plots import EVALUATION_FIGURES, MAP_FIGURES, evaluation_figures
from segloc_cli.scoring.trend_plots import (
    BAR_FILL,
    ERRORS,
    ERRORS_OVER_DISTANCE,
    ERRORS_OVER_TIME,
    FLAGGED_COLOUR,
    MAX_TICK_LABELS,
    PASSED_COLOUR,
    TABLE_FIGURES,
    draw_error_trend,
    draw_errors,
    errors_by_pose,
    thinned_slots,
)


def run_table(n: int = 40, top_id: int = 901, seed: int = 3) -> pd.DataFrame:
    """A Table 1 of ``n`` poses with ids from 1 to ``top_id``, uneven in time and travel.

    Rows 0, 5, 9 and 12 (those below ``n``) are not accepted; 0 and 5 have no estimate.
    """
    rng = np.random.default_rng(seed)
    ids = np.r_[1, np.sort(rng.choice(np.arange(2, top_id), n - 2, replace=False)), top_id]
    err_x = rng.normal(0.0, 3.0, n)
    err_y = rng.normal(0.0, 3.0, n)
    err_theta = rng.normal(0.0, 0.5, n)
    missing = [row for row in (0, 5) if row < n]
    for column in (err_x, err_y, err_theta):
        column[missing] = np.nan
    status = np.full(n, "ok", dtype=object)
    status[[row for row in (0, 5, 9) if row < n]] = "too_few_segments"
    status[[row for row in (12,) if row < n]] = "lost"
    return pd.DataFrame(
        {
            "pose_id": ids,
            "time_s": 1000.0 + np.r_[0.0, np.cumsum(rng.uniform(1.0, 30.0, n - 1))],
            "travelled_m": np.r_[0.0, np.cumsum(rng.uniform(0.5, 5.0, n - 1))],
            "err_x_cm": err_x,
            "err_y_cm": err_y,
            "err_theta_deg": err_theta,
            "err_xy_cm": np.hypot(err_x, err_y),
            "status": status,
        }
    )


def overlapping_tick_labels(fig: Figure) -> list[tuple[str, str]]:
    """Pairs of visible tick labels, on any axis of ``fig``, whose drawn boxes overlap."""
    canvas = fig.canvas
    assert isinstance(canvas, FigureCanvasAgg)
    canvas.draw()
    renderer = canvas.get_renderer()
    clashes = []
    for ax in fig.axes:
        for labels in (ax.get_xticklabels(), ax.get_yticklabels()):
            shown = [t for t in labels if t.get_visible() and t.get_text()]
            boxes = [t.get_window_extent(renderer) for t in shown]
            for (a, box_a), (b, box_b) in itertools.combinations(zip(shown, boxes, strict=True), 2):
                if box_a.overlaps(box_b):
                    clashes.append((a.get_text(), b.get_text()))
    return clashes


def legend_texts(ax) -> list[str]:
    legend = ax.get_legend()
    return [] if legend is None else [t.get_text() for t in legend.get_texts()]


def bars_of(ax) -> list:
    return [patch for c in ax.containers if isinstance(c, BarContainer) for patch in c]


def shown_tick_texts(ax) -> list[str]:
    return [t.get_text() for t in ax.get_xticklabels() if t.get_text()]


# --------------------------------------------------------------------------- slots


def test_thinned_slots_keep_at_most_the_readable_count():
    np.testing.assert_array_equal(thinned_slots(7), np.arange(7))
    np.testing.assert_array_equal(thinned_slots(40), np.arange(0, 40, 2))
    assert thinned_slots(41).size == 14 and thinned_slots(41)[1] == 3
    assert thinned_slots(1000).size <= MAX_TICK_LABELS
    assert thinned_slots(0).size == 0


# --------------------------------------------------------------------------- per pose


def test_errors_figure_has_one_evenly_spaced_slot_per_pose():
    table = run_table()
    fig = draw_errors(errors_by_pose(table))
    axes = fig.axes
    assert [ax.get_ylabel() for ax in axes] == [
        "X error (cm)",
        "Y error (cm)",
        "|XY| error (cm)",
        "θ error (°)",
    ]
    finite = np.isfinite(table["err_x_cm"].to_numpy())
    columns = ("err_x_cm", "err_y_cm", "err_xy_cm", "err_theta_deg")
    for ax, column in zip(axes, columns, strict=True):
        bars = bars_of(ax)
        assert len(bars) == finite.sum()
        centres = sorted(bar.get_x() + bar.get_width() / 2 for bar in bars)
        np.testing.assert_allclose(centres, np.flatnonzero(finite))
        # Slots are one unit apart: a bar fills BAR_FILL of its slot, not a hairline.
        np.testing.assert_allclose([bar.get_width() for bar in bars], BAR_FILL)
        heights = {round(bar.get_x() + bar.get_width() / 2): bar.get_height() for bar in bars}
        np.testing.assert_allclose(
            [heights[i] for i in np.flatnonzero(finite)], table[column].to_numpy()[finite]
        )
    bottom = axes[-1]
    ids = table["pose_id"].astype(str).tolist()
    assert shown_tick_texts(bottom) == ids[::2]
    assert len(shown_tick_texts(bottom)) <= MAX_TICK_LABELS
    assert "pose id" in bottom.get_xlabel()
    assert bottom.get_xlim() == (-0.5, len(table) - 0.5)
    assert not overlapping_tick_labels(fig)


def test_errors_figure_names_every_colour_and_paints_failed_poses_apart():
    table = run_table()
    fig = draw_errors(errors_by_pose(table))
    ax = fig.axes[0]
    assert sorted(legend_texts(ax)) == [
        "accepted (ok, recovered)",
        "no estimate",
        "not accepted (status)",
    ]
    red = {
        round(bar.get_x() + bar.get_width() / 2)
        for bar in bars_of(ax)
        if bar.get_facecolor() == pytest.approx(_rgba(FLAGGED_COLOUR))
    }
    assert red == {9, 12}  # not accepted, with an estimate; 0 and 5 have none
    crosses = [line for line in ax.get_lines() if line.get_label() == "no estimate"]
    np.testing.assert_array_equal(crosses[0].get_xdata(), [0, 5])


def test_errors_figure_flags_the_poses_it_is_told_failed_the_gates():
    table = run_table()
    flagged = np.zeros(len(table), dtype=bool)
    flagged[[3, 30]] = True
    fig = draw_errors(errors_by_pose(table), flagged=flagged)
    ax = fig.axes[2]
    colours = {round(bar.get_x() + bar.get_width() / 2): bar.get_facecolor() for bar in bars_of(ax)}
    assert {i for i, c in colours.items() if c == pytest.approx(_rgba(FLAGGED_COLOUR))} == {3, 30}
    assert colours[12] == pytest.approx(_rgba(PASSED_COLOUR))
    assert {"within the gates", "failed the gates"} <= set(legend_texts(fig.axes[0]))
    with pytest.raises(ValueError, match="flagged has 3 entries for 40 poses"):
        draw_errors(errors_by_pose(table), flagged=np.ones(3, dtype=bool))


def test_errors_figure_on_a_time_axis_places_bars_at_the_survey_time():
    table = run_table(n=8)
    fig = draw_errors(errors_by_pose(table), axis="time")
    bottom = fig.axes[-1]
    times = table["time_s"].to_numpy() - table["time_s"].min()
    bars = bars_of(fig.axes[2])
    finite = np.isfinite(table["err_xy_cm"].to_numpy())
    centres = sorted(bar.get_x() + bar.get_width() / 2 for bar in bars)
    np.testing.assert_allclose(centres, times[finite])
    np.testing.assert_allclose(
        [bar.get_width() for bar in bars], BAR_FILL * np.diff(np.sort(times)).min()
    )
    assert bottom.get_xlabel().endswith("(s)")
    assert not overlapping_tick_labels(fig)
    with pytest.raises(ValueError, match="axis must be one of"):
        draw_errors(errors_by_pose(table), axis="distance")


def test_long_pose_ids_turn_upright_and_never_overlap():
    table = run_table(n=40)
    table["pose_id"] = 987_654_321 + 1000 * np.arange(40)
    fig = draw_errors(errors_by_pose(table))
    bottom = fig.axes[-1]
    assert {label.get_rotation() for label in bottom.get_xticklabels()} == {90.0}
    assert not overlapping_tick_labels(fig)
    short = draw_errors(errors_by_pose(run_table(n=6)))
    assert {label.get_rotation() for label in short.axes[-1].get_xticklabels()} == {0.0}


# --------------------------------------------------------------------------- trends


@pytest.mark.parametrize(
    ("along", "column", "unit"), [("time", "time_s", "(s)"), ("distance", "travelled_m", "(m)")]
)
def test_error_trend_draws_each_error_against_time_or_travel(along, column, unit):
    table = run_table()
    fig = draw_error_trend(table, along)
    ax_xy, ax_theta = fig.axes
    x = table[column].to_numpy()
    if along == "time":
        x = x - x.min()
    series = {line.get_label(): line for line in ax_xy.get_lines() + ax_theta.get_lines()}
    for label, source in (("X", "err_x_cm"), ("Y", "err_y_cm"), ("|XY|", "err_xy_cm")):
        np.testing.assert_allclose(series[label].get_xdata(), x)
        np.testing.assert_allclose(series[label].get_ydata(), table[source], equal_nan=True)
        assert series[label].get_marker() == "o"
    np.testing.assert_allclose(series["θ"].get_ydata(), table["err_theta_deg"], equal_nan=True)
    assert ax_theta.get_xlabel().endswith(unit)
    assert ax_xy.get_ylabel() == "position error (cm)" and ax_theta.get_ylabel() == "θ error (°)"
    assert legend_texts(ax_xy) == [
        "X",
        "Y",
        "|XY|",
        "not accepted (status)",
        "not accepted (status), no estimate",
    ]
    # Rings around every value of the failed poses that have one (rows 9 and 12), on X, Y, |XY|.
    rings = next(line for line in ax_xy.get_lines() if line.get_label() == "not accepted (status)")
    assert sorted(np.asarray(rings.get_xdata()).tolist()) == sorted(
        np.repeat(x[[9, 12]], 3).tolist()
    )
    # Failed poses without an estimate are lines across the panel at their place.
    (blanks,) = [c for c in ax_xy.collections if c.get_label().endswith("no estimate")]
    assert sorted(segment[0][0] for segment in blanks.get_segments()) == sorted(x[[0, 5]])
    assert not overlapping_tick_labels(fig)


def test_error_trend_sorts_poses_surveyed_out_of_time_order():
    table = run_table(n=6).iloc[[3, 0, 5, 1, 4, 2]].reset_index(drop=True)
    fig = draw_error_trend(table, "time")
    line = next(line for line in fig.axes[0].get_lines() if line.get_label() == "|XY|")
    assert np.all(np.diff(line.get_xdata()) > 0)
    order = np.argsort(table["time_s"].to_numpy())
    np.testing.assert_allclose(line.get_ydata(), table["err_xy_cm"].to_numpy()[order])


# --------------------------------------------------------------------------- all at once


def test_evaluation_figures_without_a_map_are_the_table_figures():
    table = run_table(n=10)
    figures = evaluation_figures(table)
    assert tuple(figures) == TABLE_FIGURES == (ERRORS, ERRORS_OVER_TIME, ERRORS_OVER_DISTANCE)
    assert EVALUATION_FIGURES == (*MAP_FIGURES, *TABLE_FIGURES)
    flagged = np.zeros(10, dtype=bool)
    flagged[4] = True
    fig = evaluation_figures(table, flagged=flagged)[ERRORS_OVER_DISTANCE]()
    assert "failed the gates" in legend_texts(fig.axes[0])


@pytest.mark.parametrize("name", TABLE_FIGURES)
def test_no_tick_labels_overlap_for_forty_poses_with_ids_up_to_901(name):
    fig = evaluation_figures(run_table(n=40, top_id=901))[name]()
    assert fig.get_suptitle()
    for ax in fig.axes:
        assert ax.get_ylabel().endswith(("(cm)", "(°)"))
    assert not overlapping_tick_labels(fig)


def _rgba(colour: str) -> tuple[float, ...]:
    from matplotlib.colors import to_rgba

    return to_rgba(colour)
