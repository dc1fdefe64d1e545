"""Figures: the data behind each one on the hall, and ``segloc evaluate --plots`` end to end."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import HALL, made_once
from matplotlib.image import imread
from test_cli import run_cli, run_in_process
from test_trend_plots import legend_texts, overlapping_tick_labels

from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.io.figures import FIGURE_DPI
from segloc_cli.io.maps import read_map
from segloc_cli.io.mcap_log import read_log
from segloc_cli.io.tables import read_estimates, read_pose_table, write_pose_table_tum
from segloc_cli.method.align import VOTE_SCHEMES
from segloc_cli.scoring.evaluate import table1
from segloc_cli.scoring.plots import (
    ACCUMULATOR,
    COARSE_TO_FINE,
    EVALUATION_FIGURES,
    MAP_FIGURES,
    OVERLAY,
    RELATION_FIGURES,
    TABLE_FIGURES,
    OverlayPanel,
    SurveyedScan,
    accumulator_curves,
    coarse_to_fine_tracks,
    draw_heading_by_vote,
    draw_overlay,
    evaluation_figures,
    figure_size_in,
    heading_errors_by_vote,
    overlay_caption,
    overlay_pose_ids,
    ring_guesses,
    stage_pose,
    success_rates,
    surveyed_scans,
)

MAP = HALL / "map.json"
LOG = HALL / "log.mcap"
SURVEY = HALL / "survey.csv"


@dataclass(frozen=True)
class HallRun:
    estimates_csv: Path
    segments_world: np.ndarray
    table: pd.DataFrame
    items: list[SurveyedScan]


@pytest.fixture(scope="module")
def hall(tmp_path_factory) -> HallRun:
    """The hall localized against its shipped map by ``segloc localize`` with the defaults,
    once a session (``made_once``)."""

    def make(root: Path) -> None:
        result = run_in_process("localize", LOG, "--map", MAP, "--out", "estimates.csv", cwd=root)
        assert result.code == 0, result.err

    estimates_csv = made_once(tmp_path_factory, "plots-hall", make) / "estimates.csv"
    estimates = read_estimates(estimates_csv)
    survey = read_pose_table(SURVEY)
    items = surveyed_scans(estimates, survey, read_log(LOG).scans)
    return HallRun(estimates_csv, read_map(MAP), table1(estimates, survey), items)


# --------------------------------------------------------------------------- data


def test_surveyed_scans_pair_every_hall_pose(hall):
    assert [item.pose_id for item in hall.items] == list(range(1, 11))
    for item in hall.items:
        assert item.segments_robot.shape[0] >= 10 and item.segments_robot.shape[1] == 4
        assert item.points_robot.shape[1] == 2
        assert np.hypot(item.estimate.x - item.truth.x, item.estimate.y - item.truth.y) < 0.02


def test_heading_by_vote_product_is_stage_one_of_localize(hall):
    errors = heading_errors_by_vote(hall.segments_world, hall.items)
    assert list(errors.columns) == list(VOTE_SCHEMES)
    assert errors.index.tolist() == list(range(1, 11))
    assert np.isfinite(errors.to_numpy()).all()
    # The hall's map lies within every scan's reach, so localize votes with the same R-table:
    # its AE column (surveyed minus stage-1 heading) must be the product series exactly.
    np.testing.assert_allclose(errors["product"], hall.table["ae_deg"], atol=1e-9)
    # Candidates step 1° from the initial heading, so an exact vote still misses by up to
    # 0.5° (the hall measures 0.50° at most); over one bin means a neighbouring peak won.
    assert np.abs(errors["product"]).max() <= 1.0, errors


def test_accumulator_product_peaks_at_the_true_heading(hall):
    for item in hall.items:
        window = accumulator_curves(hall.segments_world, item, window_deg=20.0)
        assert len(window) == 41 and np.all(np.diff(window["heading_deg"]) > 0)
        assert window["product"].max() == 1.0 and window["count"].max() == 1.0
        peak = window["heading_deg"].iloc[int(np.argmax(window["product"]))]
        assert abs(peak - window.attrs["truth_deg"]) <= 1.0, (item.pose_id, peak)

    circle = accumulator_curves(hall.segments_world, hall.items[0], window_deg=None)
    assert len(circle) == 360
    assert circle["heading_deg"].min() >= -180.0 and circle["heading_deg"].max() < 180.0
    # Undirected orientations score α and α + 180° alike: the peak is the truth or its twin.
    peak = circle["heading_deg"].iloc[int(np.argmax(circle["product"]))]
    offset = (peak - circle.attrs["truth_deg"]) % 180.0
    assert min(offset, 180.0 - offset) <= 1.0, peak


def test_ring_guesses_circle_the_truth_with_alternating_heading_errors(hall):
    truth = hall.items[0].truth
    guesses = ring_guesses(truth, n=8, radius_m=1.5, heading_error_deg=2.0)
    assert guesses.shape == (8, 3)
    np.testing.assert_allclose(np.hypot(guesses[:, 0] - truth.x, guesses[:, 1] - truth.y), 1.5)
    np.testing.assert_allclose(
        np.rad2deg(wrap_angle(guesses[:, 2] - truth.theta)), [2.0, -2.0] * 4, atol=1e-9
    )


def test_coarse_to_fine_tracks_start_at_the_guesses_and_end_at_the_truth(hall):
    item = hall.items[0]
    guesses = ring_guesses(item.truth)
    tracks = coarse_to_fine_tracks(hall.segments_world, item.segments_robot, guesses)
    assert sorted(tracks["guess"].unique()) == list(range(8))
    starts = tracks[tracks["step"] == 0].sort_values("guess")
    np.testing.assert_array_equal(starts[["x_m", "y_m"]].to_numpy(), guesses[:, :2])
    np.testing.assert_allclose(np.deg2rad(starts["theta_deg"]), guesses[:, 2], atol=1e-12)
    ends = tracks.groupby("guess").last()
    miss_cm = 100.0 * np.hypot(ends["x_m"] - item.truth.x, ends["y_m"] - item.truth.y)
    miss_deg = np.abs(np.rad2deg(wrap_angle(np.deg2rad(ends["theta_deg"]) - item.truth.theta)))
    # Measured on the hall: every track ends within 0.6 cm and 0.03°.
    assert np.count_nonzero((miss_cm < 2.0) & (miss_deg < 0.1)) >= 7, (miss_cm, miss_deg)


def test_overlay_shows_poses_evenly_spaced_from_best_to_worst():
    ids = np.arange(1, 11)
    errors = np.array([5.0, 1.0, 9.0, 3.0, np.nan, 7.0, 2.0, 8.0, 4.0, 6.0])
    # Ranked by |XY|: 2, 7, 4, 9, 1, 10, 6, 8, 3; the median of nine is the fifth, pose 1.
    shown = overlay_pose_ids(ids, errors)
    np.testing.assert_array_equal(shown, [2, 4, 1, 10, 6, 3])
    assert overlay_caption(ids, errors, shown, n_poses=37) == (
        "poses 2 (best), 4, 1 (median), 10, 6, 3 (worst) of 37: evenly spaced from the best "
        "to the worst |XY| of the 9 with an estimate"
    )
    np.testing.assert_array_equal(overlay_pose_ids(ids[:3], errors[:3]), [2, 1, 3])
    assert overlay_caption(ids[:3], errors[:3], [2, 1, 3]) == (
        "poses 2 (best), 1 (median), 3 (worst) of 3: every one with an estimate, best to worst |XY|"
    )


def test_overlay_names_its_poses_and_why_in_the_title():
    segments = np.array([[0.0, 0.0, 2.0, 0.0], [2.0, 0.0, 2.0, 2.0]])
    panels = [
        OverlayPanel(
            pose_id=pose_id,
            estimate=Pose2(1.0, 1.0, 0.0),
            truth=Pose2(1.0, 1.0, 0.0),
            segments_world=segments,
            points_world=segments.reshape(-1, 2),
            extent_m=(-1.0, 3.0, -1.0, 3.0),
            err_xy_cm=error,
            err_theta_deg=0.1,
        )
        for pose_id, error in ((12, 0.5), (901, 9.0))
    ]
    caption = overlay_caption([12, 901], [0.5, 9.0], [12, 901], n_poses=37)
    fig = draw_overlay(segments, panels, caption)
    assert fig.get_suptitle().endswith("\npose" + caption.removeprefix("pose"))
    assert "12 (best), 901 (worst) of 37" in fig.get_suptitle()
    assert [ax.get_title() for ax in fig.axes if ax.get_visible()] == [
        "pose 12: 0.5 cm, +0.10°",
        "pose 901: 9.0 cm, +0.10°",
    ]
    assert set(legend_texts(fig.axes[0])) == {"global map", "readings", "local map", "estimate"}


def _stand_in(pose_id: int) -> SurveyedScan:
    nowhere = Pose2(0.0, 0.0, 0.0)
    return SurveyedScan(pose_id, nowhere, nowhere, nowhere, np.zeros((0, 4)), np.zeros((0, 2)))


def test_stage_pose_takes_the_first_ok_pose_and_says_its_status():
    items = [_stand_in(i) for i in (1, 4, 9)]
    table = pd.DataFrame({"pose_id": [1, 4, 9], "status": ["too_few_segments", "lost", "ok"]})
    item, status = stage_pose(items, table)
    assert (item.pose_id, status) == (9, "ok")
    item, status = stage_pose(items, table, pose_id=4)
    assert (item.pose_id, status) == (4, "lost")
    table["status"] = ["too_few_segments", "lost", "ambiguous"]
    item, status = stage_pose(items, table)
    assert (item.pose_id, status) == (1, "too_few_segments; no pose is ok")
    with pytest.raises(ValueError, match="pose 5 is not among"):
        stage_pose(items, table, pose_id=5)


def test_heading_by_vote_labels_forty_slots_readably():
    rng = np.random.default_rng(7)
    ids = np.r_[1, np.sort(rng.choice(np.arange(2, 901), 38, replace=False)), 901]
    errors = pd.DataFrame(
        {scheme: rng.normal(0.0, 0.5, 40) for scheme in VOTE_SCHEMES},
        index=pd.Index(ids, name="pose_id"),
    )
    fig = draw_heading_by_vote(errors)
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
    assert labels == [str(i) for i in ids[::2]]
    product = next(line for line in ax.get_lines() if line.get_label() == "product")
    assert np.ptp(np.diff(product.get_xdata())) == pytest.approx(0.0)  # evenly spaced slots
    assert set(legend_texts(ax)) == set(VOTE_SCHEMES)
    assert not overlapping_tick_labels(fig)


def test_stage_figures_take_the_first_ok_pose_of_the_hall(hall):
    table = hall.table.copy()
    table.loc[table["pose_id"] == 1, "status"] = "too_few_segments"
    figures = evaluation_figures(table, hall.segments_world, hall.items)
    accumulator = figures[ACCUMULATOR]()
    assert "pose 2 (ok)" in accumulator.get_suptitle()
    assert not overlapping_tick_labels(accumulator)
    stage_two = figures[COARSE_TO_FINE]()
    assert "around pose 2 (ok)" in stage_two.get_suptitle()


def test_success_rates_per_bin():
    trials = pd.DataFrame(
        {
            "dataset": ["a"] * 7 + ["b"] * 2,
            "method": ["m1", "m1", "m1", "m2", "m1", "m1", "m1", "m1", "m1"],
            "init_err_m": [0.0, 0.49, 0.5, 0.2, 2.0, 2.5, np.nan, 1.2, 1.4],
            "init_err_deg": np.zeros(9),
            "success": [True, False, True, False, True, True, True, True, True],
            "runtime_ms": np.ones(9),
        }
    )
    rates = success_rates(trials)
    expected = pd.DataFrame(
        {
            "dataset": ["a"] * 8 + ["b"] * 4,
            "method": ["m1"] * 4 + ["m2"] * 4 + ["m1"] * 4,
            "bin_lo_m": [0.0, 0.5, 1.0, 1.5] * 3,
            "bin_hi_m": [0.5, 1.0, 1.5, 2.0] * 3,
            "n_trials": [2, 1, 0, 1, 1, 0, 0, 0, 0, 0, 2, 0],
            "n_success": [1, 1, 0, 1, 0, 0, 0, 0, 0, 0, 2, 0],
            "success_rate": [0.5, 1.0, np.nan, 1.0, 0.0] + [np.nan] * 5 + [1.0, np.nan],
        }
    )
    pd.testing.assert_frame_equal(rates, expected)


def test_success_rates_read_success_written_as_text():
    trials = pd.DataFrame(
        {
            "dataset": ["a"] * 3,
            "method": ["m"] * 3,
            "init_err_m": [0.1, 0.2, 0.3],
            "success": ["True", "false", "TRUE"],
        }
    )
    assert success_rates(trials)["n_success"].iloc[0] == 2


# --------------------------------------------------------------------------- command line


def figure_files(names) -> set[str]:
    return {f"{name}.{ext}" for name in names for ext in ("png", "pdf")}


def test_evaluate_plots_writes_every_figure(hall, tmp_path):
    plots = tmp_path / "figures" / "hall"
    result = run_in_process(
        "evaluate", hall.estimates_csv, "--survey", SURVEY,
        "--plots", plots, "--map", MAP, "--log", LOG,
        cwd=tmp_path,
    )  # fmt: skip
    assert result.code == 0, result.err
    assert len(re.findall(r"^\|\s*\d+\s*\|", result.out, re.M)) == 10, result.out
    assert {p.name for p in plots.iterdir()} == figure_files(EVALUATION_FIGURES)
    wrote = [ln for ln in result.err.splitlines() if ln.startswith("segloc: wrote ")]
    assert sorted(Path(ln.removeprefix("segloc: wrote ")).name for ln in wrote) == sorted(
        figure_files(EVALUATION_FIGURES)
    )
    for name in EVALUATION_FIGURES:
        width_in, height_in = figure_size_in(name, 6 if name == OVERLAY else 1)
        image = imread(plots / f"{name}.png")
        assert image.shape[:2] == (round(height_in * FIGURE_DPI), round(width_in * FIGURE_DPI))
        assert (plots / f"{name}.pdf").read_bytes().startswith(b"%PDF")


def test_evaluate_plots_without_map_and_log_draws_the_errors_only(hall, tmp_path):
    plots = tmp_path / "plots"
    result = run_in_process(
        "evaluate", hall.estimates_csv, "--survey", SURVEY, "--plots", plots, cwd=tmp_path
    )
    assert result.code == 0, result.err
    assert {p.name for p in plots.iterdir()} == figure_files(TABLE_FIGURES)
    skipped = [ln for ln in result.err.splitlines() if ln.startswith("segloc: skipped")]
    assert skipped == [
        f"segloc: skipped {', '.join(MAP_FIGURES)}: they need --map MAP.json and --log LOG.mcap"
    ], result.err


def test_another_localizer_s_plots_skip_only_the_overlay_without_map_and_log(tmp_path, capsys):
    # Another localizer's trajectory (here the survey itself, as TUM) has no stages to draw.
    trajectory = tmp_path / "other.tum"
    write_pose_table_tum(trajectory, read_pose_table(SURVEY))
    result = run_cli(capsys, "evaluate", trajectory, "--survey", SURVEY, "--plots", tmp_path / "p")
    assert result.code == 0, result.err
    skipped = [ln for ln in result.err.splitlines() if ln.startswith("segloc: skipped")]
    assert skipped == [f"segloc: skipped {OVERLAY}: it needs --map MAP.json and --log LOG.mcap"], (
        result.err
    )


def test_evaluate_plots_with_relations_draws_the_relation_figures(hall, tmp_path):
    estimates = read_estimates(hall.estimates_csv)
    t = estimates["time_s"].to_numpy()
    relations = tmp_path / "rel.txt"
    lines = [f"{t[k]:.6f} {t[k + 1]:.6f} 0.1 0 0 0 0 0" for k in range(len(t) - 1)]
    relations.write_text("\n".join(lines) + "\n", encoding="utf-8")
    plots = tmp_path / "p"
    result = run_in_process(
        "evaluate", hall.estimates_csv, "--relations", relations, "--plots", plots,
        "--map", MAP, cwd=tmp_path,
    )  # fmt: skip
    assert result.code == 0, result.err
    assert {p.name for p in plots.iterdir()} == figure_files(RELATION_FIGURES)


def test_evaluate_plots_with_a_missing_log_fails_before_writing(hall, tmp_path):
    plots = tmp_path / "plots"
    missing = tmp_path / "nope.mcap"
    result = run_in_process(
        "evaluate", hall.estimates_csv, "--survey", SURVEY,
        "--plots", plots, "--map", MAP, "--log", missing,
        cwd=tmp_path,
    )  # fmt: skip
    assert result.code == 2
    lines = result.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("segloc: error:") and "nope.mcap" in lines[0]
    assert result.out == "" and not plots.exists()
