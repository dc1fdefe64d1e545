"""Figures: the data behind each one on the hall, and ``segloc evaluate --plots`` end to end."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import HALL
from matplotlib.image import imread
from test_cli import run_script

from segloc_cli.geometry import wrap_angle
from segloc_cli.io.figures import FIGURE_DPI
from segloc_cli.io.maps import read_map
from segloc_cli.io.mcap_log import read_log
from segloc_cli.io.tables import read_estimates, read_pose_table
from segloc_cli.method.align import VOTE_SCHEMES
from segloc_cli.scoring.evaluate import table1
from segloc_cli.scoring.plots import (
    ERRORS,
    EVALUATION_FIGURES,
    MAP_FIGURES,
    OVERLAY,
    SurveyedScan,
    accumulator_curves,
    coarse_to_fine_tracks,
    figure_size_in,
    heading_errors_by_vote,
    overlay_pose_ids,
    ring_guesses,
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
    """The hall localized against its shipped map by ``segloc localize`` with the defaults."""
    root = tmp_path_factory.mktemp("plots")
    estimates_csv = root / "estimates.csv"
    result = run_script("localize", LOG, "--map", MAP, "--out", estimates_csv, cwd=root)
    assert result.code == 0, result.err
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


def test_overlay_shows_the_first_poses_and_the_worst():
    ids = np.arange(1, 11)
    errors = np.array([1.0, 2.0, 1.0, 1.0, 1.0, 1.0, 1.0, 9.0, np.nan, 1.0])
    np.testing.assert_array_equal(overlay_pose_ids(ids, errors), [1, 2, 3, 4, 5, 8])
    errors[1] = 20.0
    np.testing.assert_array_equal(overlay_pose_ids(ids, errors), [1, 2, 3, 4, 5, 6])
    np.testing.assert_array_equal(overlay_pose_ids(ids[:3], errors[:3]), [1, 2, 3])


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
    result = run_script(
        "evaluate", hall.estimates_csv, "--survey", SURVEY,
        "--plots", plots, "--map", MAP, "--log", LOG,
        cwd=tmp_path,
    )  # fmt: skip
    assert result.code == 0, result.err
    assert len(re.findall(r"^\|\s*\d+\s*\|", result.out, re.M)) == 10, result.out
    assert {p.name for p in plots.iterdir()} == figure_files(EVALUATION_FIGURES)
    wrote = [ln for ln in result.err.splitlines() if ln.startswith("wrote ")]
    assert sorted(Path(ln.removeprefix("wrote ")).name for ln in wrote) == sorted(
        figure_files(EVALUATION_FIGURES)
    )
    for name in EVALUATION_FIGURES:
        width_in, height_in = figure_size_in(name, 6 if name == OVERLAY else 1)
        image = imread(plots / f"{name}.png")
        assert image.shape[:2] == (round(height_in * FIGURE_DPI), round(width_in * FIGURE_DPI))
        assert (plots / f"{name}.pdf").read_bytes().startswith(b"%PDF")


def test_evaluate_plots_without_map_and_log_draws_the_errors_only(hall, tmp_path):
    plots = tmp_path / "plots"
    result = run_script(
        "evaluate", hall.estimates_csv, "--survey", SURVEY, "--plots", plots, cwd=tmp_path
    )
    assert result.code == 0, result.err
    assert {p.name for p in plots.iterdir()} == figure_files([ERRORS])
    skipped = [ln for ln in result.err.splitlines() if ln.startswith("skipped")]
    assert len(skipped) == 1, result.err
    for fragment in (*MAP_FIGURES, "--map", "--log"):
        assert fragment in skipped[0]


def test_evaluate_plots_goes_with_survey(hall, tmp_path):
    relations = tmp_path / "rel.txt"
    relations.write_text("1 2 0 0 0 0 0 0\n", encoding="utf-8")
    result = run_script(
        "evaluate", hall.estimates_csv, "--relations", relations, "--plots", tmp_path / "p",
        cwd=tmp_path,
    )  # fmt: skip
    assert result.code == 2
    lines = result.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("segloc: error:") and "--plots" in lines[0]
    assert not (tmp_path / "p").exists()


def test_evaluate_plots_with_a_missing_log_fails_before_writing(hall, tmp_path):
    plots = tmp_path / "plots"
    missing = tmp_path / "nope.mcap"
    result = run_script(
        "evaluate", hall.estimates_csv, "--survey", SURVEY,
        "--plots", plots, "--map", MAP, "--log", missing,
        cwd=tmp_path,
    )  # fmt: skip
    assert result.code == 2
    lines = result.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("segloc: error:") and "nope.mcap" in lines[0]
    assert result.out == "" and not plots.exists()
