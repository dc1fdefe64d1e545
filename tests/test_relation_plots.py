"""Figures of a run scored by relations: the trajectory coloured by error, errors in time."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.collections import LineCollection, PathCollection
from test_trend_plots import legend_texts, overlapping_tick_labels

from segloc_cli.estimates import Relations
from segloc_cli.geometry import relative_motion
from segloc_cli.scoring.relation_plots import (
    PERCENTILE,
    RELATION_ERRORS_OVER_TIME,
    RELATION_FIGURES,
    TRAJECTORY,
    relation_figures,
    relation_start_errors,
)
from segloc_cli.scoring.relations import RelationErrors, relation_errors

WALLS = np.array([[-6, -4, 6, -4], [6, -4, 6, 4], [6, 4, -6, 4], [-6, 4, -6, -4]], dtype=float)


def ellipse_run(n: int = 40, seed: int = 5):
    """Times (s), estimated poses (one NaN) and relations three poses apart on an ellipse."""
    rng = np.random.default_rng(seed)
    times_s = 100.0 + 0.5 * np.arange(n)
    angle = np.linspace(0.0, 2.0 * np.pi, n)
    truth = np.column_stack([5 * np.cos(angle), 3 * np.sin(angle), angle + np.pi / 2])
    poses = truth + rng.normal(0.0, 0.02, truth.shape)
    poses[7] = np.nan
    first = np.arange(n - 3)
    relations = Relations(
        times_s[first], times_s[first + 3], relative_motion(truth[first], truth[first + 3])
    )
    return times_s, poses, relations, relation_errors(times_s, poses, relations)


def test_relation_start_errors_keep_the_largest_error_of_each_start_pose():
    times_s = np.array([0.0, 1.0, 2.0, 3.0])
    relations = Relations(
        np.array([0.0, 0.0, 2.0, 3.0]), np.array([1.0, 2.0, 3.0, 0.0]), np.zeros((4, 3))
    )
    errors = RelationErrors(
        trans_m=np.array([0.01, 0.05, 0.02]),
        rot_deg=np.zeros(3),
        used=3,
        skipped=1,
        index=np.array([0, 1, 2]),
    )
    rows, trans_cm = relation_start_errors(times_s, errors, relations)
    np.testing.assert_array_equal(rows, [0, 2])
    np.testing.assert_allclose(trans_cm, [5.0, 2.0])


def test_trajectory_colours_the_start_of_each_relation_by_its_error_over_the_map():
    times_s, poses, relations, errors = ellipse_run()
    fig = relation_figures(times_s, poses, errors, relations, WALLS)[TRAJECTORY]()
    ax = fig.axes[0]
    walls = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert len(walls) == 1 and len(walls[0].get_segments()) == len(WALLS)
    (points,) = [c for c in ax.collections if isinstance(c, PathCollection)]
    rows, trans_cm = relation_start_errors(times_s, errors, relations)
    order = np.argsort(trans_cm, kind="stable")
    np.testing.assert_allclose(points.get_offsets(), poses[rows[order], :2])
    np.testing.assert_allclose(points.get_array(), trans_cm[order])
    # Relations starting at the NaN pose, or ending on it, are not drawn.
    assert 7 not in rows and len(rows) == errors.used
    colourbar = fig.axes[1]
    assert colourbar.get_ylabel().endswith("(cm)")
    assert set(legend_texts(ax)) == {"map", "estimated trajectory", "start of a relation"}
    assert ax.get_xlabel() == "x (m)" and ax.get_ylabel() == "y (m)"
    assert f"{errors.used} used relations" in ax.get_title()
    assert not overlapping_tick_labels(fig)


def test_trajectory_without_a_map_draws_no_walls():
    times_s, poses, relations, errors = ellipse_run(n=12)
    fig = relation_figures(times_s, poses, errors, relations)[TRAJECTORY]()
    ax = fig.axes[0]
    assert not [c for c in ax.collections if isinstance(c, LineCollection)]
    assert "map" not in legend_texts(ax)


def test_relation_errors_over_time_draw_each_relation_with_mean_and_percentile():
    times_s, poses, relations, errors = ellipse_run()
    fig = relation_figures(times_s, poses, errors, relations)[RELATION_ERRORS_OVER_TIME]()
    ax_trans, ax_rot = fig.axes
    t1_s = relations.t1_s[errors.index] - times_s[0]
    for ax, values, unit in (
        (ax_trans, 100.0 * errors.trans_m, "cm"),
        (ax_rot, errors.rot_deg, "°"),
    ):
        series = ax.get_lines()[0]
        np.testing.assert_allclose(series.get_xdata(), t1_s)
        np.testing.assert_allclose(series.get_ydata(), values)
        mean = next(line for line in ax.get_lines() if line.get_label().startswith("mean"))
        high = next(line for line in ax.get_lines() if "percentile" in line.get_label())
        assert mean.get_ydata()[0] == pytest.approx(np.mean(values))
        assert high.get_ydata()[0] == pytest.approx(np.percentile(values, PERCENTILE))
        assert mean.get_label() == f"mean {np.mean(values):.2f} {unit}"
        assert high.get_label().startswith("95th percentile")
        assert ax.get_ylabel().endswith(f"({unit})")
        assert len(legend_texts(ax)) == 3
    assert ax_rot.get_xlabel().endswith("(s)")
    assert f"{errors.used} used relations ({errors.skipped} skipped)" in fig.get_suptitle()
    assert not overlapping_tick_labels(fig)


def test_relation_figures_are_named_in_order():
    times_s, poses, relations, errors = ellipse_run(n=8)
    assert tuple(relation_figures(times_s, poses, errors, relations)) == RELATION_FIGURES
