"""Table 1: errors against a hand-made survey, matching, summary, gates and formats."""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pandas as pd
import pytest
from precision import BINARY_NOISE, assert_frame_within_precision
from test_cli import run_cli

from segloc_cli.errors import InputError
from segloc_cli.estimates import ESTIMATE_COLUMNS, PoseTable
from segloc_cli.scoring.evaluate import format_table, summary, table1
from segloc_cli.scoring.gates import Gates, pose_failures


def make_survey(rows: list[tuple[int, float, float, float, float]]) -> PoseTable:
    """Rows of (pose_id, time_s, x_m, y_m, theta_deg)."""
    ids, times, xs, ys, thetas_deg = (np.array(c) for c in zip(*rows, strict=True))
    return PoseTable(
        ids.astype(int), times.astype(float), np.column_stack([xs, ys, np.deg2rad(thetas_deg)])
    )


def make_estimates(rows: list[dict]) -> pd.DataFrame:
    """Estimate rows; unspecified columns default to the survey-free values below."""
    defaults = {
        "init_x_m": 0.0,
        "init_y_m": 0.0,
        "init_theta_deg": 0.0,
        "align_theta_deg": 0.0,
        "stage2_x_m": 0.0,
        "stage2_y_m": 0.0,
        "stage2_theta_deg": 0.0,
        "x_m": 0.0,
        "y_m": 0.0,
        "theta_deg": 0.0,
        "overlap_m": 1.0,
        "inlier_ratio": 1.0,
        "n_local_segments": 20,
        "runtime_ms": 5.0,
        "status": "ok",
        "window_scans": 1,
    }
    full = [{**defaults, "pose_id": i + 1, **row} for i, row in enumerate(rows)]
    return pd.DataFrame(full, columns=list(ESTIMATE_COLUMNS))


def md_rows(text: str) -> list[list[str]]:
    """The cells of each row of the first Markdown table in ``text`` (header included)."""
    lines = [line for line in text.splitlines() if line.startswith("|")]
    return [[cell.strip() for cell in line.strip("|").split("|")] for line in lines]


# --- errors -------------------------------------------------------------------------------


def test_errors_are_surveyed_minus_computed_in_world_frame():
    survey = make_survey([(7, 1.0, 2.0, 3.0, 30.0)])
    estimates = make_estimates(
        [
            {
                "time_s": 1.0,
                "init_x_m": 1.5,
                "init_y_m": 3.2,
                "init_theta_deg": 25.0,
                "align_theta_deg": 30.5,
                "x_m": 1.98,  # 2 cm west of the surveyed position
                "y_m": 3.0,
                "theta_deg": 29.9,
            }
        ]
    )
    row = table1(estimates, survey).iloc[0]
    assert row["pose_id"] == 7
    assert row["ae_deg"] == pytest.approx(-0.5)
    assert row["init_x_cm"] == pytest.approx(50.0)
    assert row["init_y_cm"] == pytest.approx(-20.0)
    assert row["init_theta_deg"] == pytest.approx(5.0)
    assert row["err_x_cm"] == pytest.approx(2.0)
    assert row["err_y_cm"] == pytest.approx(0.0, abs=1e-9)
    assert row["err_theta_deg"] == pytest.approx(0.1)
    assert row["err_xy_cm"] == pytest.approx(2.0)
    assert row["status"] == "ok"


def test_euclidean_error_combines_both_axes():
    survey = make_survey([(1, 0.0, 1.0, 1.0, 0.0)])
    estimates = make_estimates([{"time_s": 0.0, "x_m": 0.97, "y_m": 1.04}])
    row = table1(estimates, survey).iloc[0]
    assert (row["err_x_cm"], row["err_y_cm"]) == (pytest.approx(3.0), pytest.approx(-4.0))
    assert row["err_xy_cm"] == pytest.approx(5.0)


@pytest.mark.parametrize(
    ("survey_deg", "estimate_deg", "expected_deg"),
    [(179.9, -179.9, -0.2), (-179.9, 179.9, 0.2), (-90.0, 90.0, -180.0)],
)
def test_heading_errors_wrap_to_half_open_interval(survey_deg, estimate_deg, expected_deg):
    survey = make_survey([(1, 0.0, 0.0, 0.0, survey_deg)])
    estimates = make_estimates(
        [
            {
                "time_s": 0.0,
                "init_theta_deg": estimate_deg,
                "align_theta_deg": estimate_deg,
                "theta_deg": estimate_deg,
            }
        ]
    )
    row = table1(estimates, survey).iloc[0]
    for column in ("ae_deg", "init_theta_deg", "err_theta_deg"):
        assert row[column] == pytest.approx(expected_deg, abs=1e-9)


def test_failed_pose_keeps_its_status_and_initial_errors():
    survey = make_survey([(1, 0.0, 1.0, 2.0, 10.0)])
    estimates = make_estimates(
        [
            {
                "time_s": 0.0,
                "init_x_m": 0.9,
                "align_theta_deg": np.nan,
                "x_m": np.nan,
                "y_m": np.nan,
                "theta_deg": np.nan,
                "status": "too_few_segments",
            }
        ]
    )
    row = table1(estimates, survey).iloc[0]
    assert row["status"] == "too_few_segments"
    assert row["init_x_cm"] == pytest.approx(10.0)
    for column in ("ae_deg", "err_x_cm", "err_y_cm", "err_theta_deg", "err_xy_cm"):
        assert math.isnan(row[column])


def test_empty_status_reads_as_missing_and_counts_as_failed():
    survey = make_survey([(1, 0.0, 0.0, 0.0, 0.0)])
    estimates = make_estimates([{"time_s": 0.0, "status": np.nan}])
    table = table1(estimates, survey)
    assert table["status"].tolist() == ["missing"]
    assert summary(table).attrs["n_failed"] == 1


def test_ae_is_blank_without_an_initial_guess():
    # A --global row: no initial pose, so stage 1 had no window and its heading is no answer.
    survey = make_survey([(1, 0.0, 1.0, 2.0, 10.0), (2, 1.0, 1.0, 2.0, 10.0)])
    estimates = make_estimates(
        [
            {
                "time_s": 0.0,
                "init_x_m": np.nan,
                "init_y_m": np.nan,
                "init_theta_deg": np.nan,
                "align_theta_deg": -134.0,
                "x_m": 1.0,
                "y_m": 2.0,
                "theta_deg": 10.0,
            },
            {"time_s": 1.0, "init_theta_deg": 12.0, "align_theta_deg": 9.0, "theta_deg": 10.0},
        ]
    )
    table = table1(estimates, survey)
    assert math.isnan(table.loc[0, "ae_deg"])
    assert math.isnan(table.loc[0, "init_x_cm"]) and math.isnan(table.loc[0, "init_theta_deg"])
    assert table.loc[0, "err_theta_deg"] == pytest.approx(0.0, abs=1e-12)
    assert table.loc[1, "ae_deg"] == pytest.approx(1.0)
    rows = md_rows(format_table(table, summary(table), "md"))
    assert rows[2][:2] == ["1", "—"]
    assert summary(table).loc["RMS", "ae_deg"] == pytest.approx(1.0)


# --- time matching ------------------------------------------------------------------------


def test_matching_tolerance_and_survey_ids():
    survey = make_survey([(101, 10.0, 0.0, 0.0, 0.0), (102, 20.0, 0.0, 0.0, 0.0)])
    estimates = make_estimates([{"time_s": 10.03}, {"time_s": 20.08}])
    table = table1(estimates, survey)
    # 20.08 s lies beyond the 50 ms tolerance: pose 102 stays, with no estimate.
    assert table["pose_id"].tolist() == [101, 102]
    assert table["status"].tolist() == ["ok", "no_estimate"]
    assert np.isfinite(table.loc[0, "err_xy_cm"]) and np.isnan(table.loc[1, "err_xy_cm"])


def test_matching_takes_the_nearest_and_refuses_two_equally_near():
    survey = make_survey([(1, 10.0, 0.0, 0.0, 0.0), (2, 20.0, 0.0, 0.0, 0.0)])
    # Rows out of time order; x_m tells which row was paired.
    rows = [
        {"time_s": 10.03, "x_m": -0.01},
        {"time_s": 9.96, "x_m": -0.02},
        {"time_s": 20.04, "x_m": -0.03},
        {"time_s": 20.01, "x_m": -0.04},
    ]
    table = table1(make_estimates(rows), survey)
    assert table["err_x_cm"].to_numpy() == pytest.approx([1.0, 4.0])
    # 1/32 s on either side keeps the two exactly as near: neither is taken.
    rows[0]["time_s"], rows[1]["time_s"] = 10.03125, 9.96875
    with pytest.raises(InputError) as caught:
        table1(make_estimates(rows), survey, estimates_path="est.csv", survey_path="survey.csv")
    assert str(caught.value) == (
        "est.csv, rows 1 and 2: their times 9.969 and 10.031 s are equally near a row at "
        "10.000 s, so it matches either; give times that are not halfway between two rows "
        "(or lower --tolerance-ms)"
    )


def test_rows_follow_survey_order_and_unmatched_are_counted():
    survey = make_survey(
        [(30, 3.0, 0.0, 0.0, 0.0), (10, 1.0, 0.0, 0.0, 0.0), (20, 2.0, 0.0, 0.0, 0.0)]
    )
    estimates = make_estimates([{"time_s": 1.0}, {"time_s": 3.0}])
    table = table1(estimates, survey)
    assert table["pose_id"].tolist() == [30, 10, 20]
    assert table["status"].tolist() == ["ok", "ok", "no_estimate"]
    stats = summary(table)
    assert stats.attrs["n_poses"] == 2
    assert stats.attrs["n_surveyed"] == 3
    assert stats.attrs["n_no_estimate"] == 1
    assert stats.attrs["status_counts"] == {"ok": 2, "no_estimate": 1}


def test_two_estimates_at_the_time_of_a_survey_row_are_refused():
    survey = make_survey([(1, 10.0, 0.0, 0.0, 0.0), (2, 20.0, 0.0, 0.0, 0.0)])
    estimates = make_estimates([{"time_s": 10.0}, {"time_s": 20.0}, {"time_s": 20.0}])
    with pytest.raises(InputError) as caught:
        table1(estimates, survey, estimates_path="est.csv", survey_path="survey.csv")
    assert str(caught.value) == (
        "est.csv, rows 2 and 3: both have time 20.000 s, so a row at 20.000 s matches more "
        "than one row; give every row a distinct time"
    )


def test_two_survey_rows_with_one_time_are_refused():
    # Scoring the one estimate twice (once against a pose 2 m off) is what this prevents.
    survey = make_survey(
        [(1, 10.0, 0.0, 0.0, 0.0), (2, 12.5, 0.0, 0.0, 0.0), (3, 12.5, 2.0, 0.0, 0.0)]
    )
    estimates = make_estimates([{"time_s": 10.0}, {"time_s": 12.5}])
    with pytest.raises(InputError) as caught:
        table1(estimates, survey, estimates_path="est.csv", survey_path="survey.csv")
    assert str(caught.value) == (
        "survey.csv, rows 2 and 3: both have time 12.500 s, so both would be paired with row 2 "
        "of est.csv; give every row a distinct time"
    )


def test_no_match_error_gives_both_time_ranges():
    survey = make_survey([(1, 0.0, 0.0, 0.0, 0.0), (2, 1.0, 0.0, 0.0, 0.0)])
    estimates = make_estimates([{"time_s": 100.0}, {"time_s": 101.0}, {"time_s": 100.5}])
    with pytest.raises(
        InputError,
        match=r"no estimate lies within 0.05 s of any survey time: "
        r"estimates span 100.000 to 101.000 s \(3 rows\), "
        r"survey spans 0.000 to 1.000 s \(2 rows\)",
    ):
        table1(estimates, survey)


def test_missing_estimate_column_is_named():
    survey = make_survey([(1, 0.0, 0.0, 0.0, 0.0)])
    estimates = make_estimates([{"time_s": 0.0}]).drop(columns=["align_theta_deg", "status"])
    with pytest.raises(InputError, match=r"estimates lack the column\(s\) align_theta_deg, status"):
        table1(estimates, survey)


# --- summary ------------------------------------------------------------------------------


def small_table() -> pd.DataFrame:
    """Three poses: errors 3/-4 cm on the ok ones, a large error on the failed one."""
    survey = make_survey(
        [(1, 1.0, 0.0, 0.0, 0.0), (2, 2.0, 0.0, 0.0, 0.0), (3, 3.0, 0.0, 0.0, 0.0)]
    )
    estimates = make_estimates(
        [
            {"time_s": 1.0, "init_x_m": -0.1, "x_m": -0.03, "theta_deg": -0.1},
            {"time_s": 2.0, "init_x_m": 0.2, "x_m": 0.04, "theta_deg": 0.3},
            {"time_s": 3.0, "init_x_m": 0.2, "x_m": 1.0, "theta_deg": 5.0, "status": "diverged"},
        ]
    )
    return table1(estimates, survey)


def test_summary_only_ok_covers_the_ok_poses_in_every_column():
    stats = summary(small_table(), only_ok=True)
    assert stats.index.tolist() == ["RMS", "max"]
    assert stats.loc["RMS", "err_x_cm"] == pytest.approx(math.sqrt((3.0**2 + 4.0**2) / 2))
    assert stats.loc["max", "err_x_cm"] == pytest.approx(4.0)
    assert stats.loc["RMS", "err_theta_deg"] == pytest.approx(math.sqrt((0.1**2 + 0.3**2) / 2))
    assert stats.loc["max", "err_theta_deg"] == pytest.approx(0.3)
    # One set of poses in every column: the initial errors of the ok poses alone.
    assert stats.loc["RMS", "init_x_cm"] == pytest.approx(math.sqrt((10**2 + 20**2) / 2))
    assert stats.loc["max", "init_x_cm"] == pytest.approx(20.0)
    every = summary(small_table())
    assert every.loc["RMS", "init_x_cm"] == pytest.approx(math.sqrt((10**2 + 20**2 + 20**2) / 3))
    assert (stats.attrs["n_poses"], stats.attrs["n_failed"], stats.attrs["n_scored"]) == (3, 1, 2)


def mixed_table() -> pd.DataFrame:
    """Five surveyed poses: ok (3 cm), ok (-4 cm), ambiguous (12 cm), lost (-100 cm), and a
    scan without segments (no pose); a sixth survey row has no estimate in time."""
    survey = make_survey([(k, float(k), 0.0, 0.0, 0.0) for k in range(1, 7)])
    estimates = make_estimates(
        [
            {"time_s": 1.0, "x_m": -0.03, "theta_deg": -0.1},
            {"time_s": 2.0, "x_m": 0.04, "theta_deg": 0.2},
            {"time_s": 3.0, "x_m": -0.12, "theta_deg": 0.5, "status": "ambiguous"},
            {"time_s": 4.0, "x_m": 1.0, "theta_deg": -3.0, "status": "lost"},
            {"time_s": 5.0, "x_m": np.nan, "y_m": np.nan, "theta_deg": np.nan,
             "status": "too_few_segments"},
            {"time_s": 60.0},
        ]
    )  # fmt: skip
    return table1(estimates, survey)


def test_summary_scores_every_pose_with_an_estimate_whatever_its_status():
    table = mixed_table()
    stats = summary(table)
    assert stats.loc["RMS", "err_x_cm"] == pytest.approx(
        math.sqrt((3.0**2 + 4.0**2 + 12.0**2 + 100.0**2) / 4)
    )
    assert stats.loc["max", "err_x_cm"] == pytest.approx(100.0)
    assert stats.loc["max", "err_theta_deg"] == pytest.approx(3.0)
    assert stats.attrs["n_scored"] == 4
    assert stats.attrs["n_no_estimate"] == 2  # no pose in row 5; no estimate for pose 6
    assert stats.attrs["status_counts"] == {
        "ok": 2,
        "ambiguous": 1,
        "lost": 1,
        "no_estimate": 1,
        "too_few_segments": 1,
    }
    old = summary(table, only_ok=True)
    assert old.loc["RMS", "err_x_cm"] == pytest.approx(math.sqrt((3.0**2 + 4.0**2) / 2))
    assert old.attrs["n_scored"] == 2
    # Right (within 30 cm and 3°): the two ok poses and the ambiguous one at 12 cm; wrong: the
    # lost pose 1 m off and the one without a pose.
    assert stats.attrs["verdict"] == {
        "accepted": 2,
        "accepted_right": 2,
        "right": 3,
        "right_flagged": 1,
        "wrong": 2,
        "wrong_flagged": 2,
    }
    text = format_table(table, stats, "md")
    assert text.splitlines()[-3:] == [
        "6 surveyed poses: ok 2, ambiguous 1, lost 1, too_few_segments 1, no_estimate 1.",
        "RMS and max (of absolute values) cover the 4 poses with an estimate, whatever their "
        "status; 2 surveyed poses have no estimate. Errors are surveyed minus computed; XY is "
        "the position error's magnitude √(X² + Y²).",
        "Verdict (right = within 30 cm and 3° of the survey): 2 of 2 accepted answers right; "
        "1 of 3 right answers flagged; 2 of 2 wrong answers flagged.",
    ]
    assert (
        format_table(table, old, "md")
        .splitlines()[-2]
        .startswith("RMS and max (of absolute values) cover the 2 poses with status ok; 2 surveyed")
    )


def test_gate_counts_in_every_format():
    table = mixed_table()
    gates = Gates(axis_cm=3.5, deg=0.3)
    stats = summary(table, gates=gates)
    assert (stats.attrs["n_beyond"], stats.attrs["n_gate_failed"]) == (3, 5)
    # Beyond: -4 cm (ok), 12 cm (ambiguous), -100 cm (lost); failing also too_few_segments
    # and pose 6, which has no estimate.
    assert pose_failures(table, gates)[6] == ["no estimate within 50 ms"]
    assert len(pose_failures(table, gates)) == 5
    md = format_table(table, stats, "md").splitlines()
    assert md[-4] == (
        "3 of 4 poses exceed the per-pose limits (|X|, |Y| ≤ 3.5 cm; |θ| ≤ 0.3°); the gate "
        "fails 5, counting 2 without an accepted estimate (status other than ok)."
    )
    # The max gates fail for the two poses without an estimate even where the others keep
    # to them.
    assert md[-2] == "Gate: max |θ| 3.00° > 0.3° (2 of 6 poses without an estimate): FAIL."
    assert md[-1] == (
        "Gate: share of poses accepted and within |X|, |Y| ≤ 3.5 cm; |θ| ≤ 0.3° 16.7 % < 100 % "
        "(1 of 6 poses): FAIL."
    )
    document = json.loads(format_table(table, stats, "json"))
    gate_json = document["summary"]["gate"]
    assert gate_json["limits"] == {"axis_cm": 3.5, "deg": 0.3, "percentile": 95.0}
    assert (gate_json["n_beyond"], gate_json["n_gate_failed"]) == (3, 5)
    assert [o["passed"] for o in gate_json["outcomes"]] == [False, False, False]
    assert [p["beyond_gate"] for p in document["poses"]] == [False, True, True, True, False, False]
    assert [p["scored"] for p in document["poses"]] == [True, True, True, True, False, False]
    assert document["summary"]["status_counts"]["no_estimate"] == 1
    assert (document["summary"]["n_surveyed"], document["summary"]["n_no_estimate"]) == (6, 2)
    back = pd.read_csv(io.StringIO(format_table(table, stats, "csv")))
    assert back["beyond_gate"].tolist() == [0, 1, 1, 1, 0, 0]
    assert back["scored"].tolist() == [1, 1, 1, 1, 0, 0]
    latex = format_table(table, stats, "latex")
    assert (
        r"exceed the per-pose limits (|X|, |Y| $\leq$ 3.5 cm; |$\theta$| $\leq$ 0.3$^\circ$)"
        in latex
    )
    # Without a gate the csv column is empty and the json gate null.
    plain = summary(table)
    assert pd.read_csv(io.StringIO(format_table(table, plain, "csv")))["beyond_gate"].isna().all()
    assert json.loads(format_table(table, plain, "json"))["summary"]["gate"] is None


def test_summary_of_paper_rows():
    # Poses 1-3 of the paper's Table 1: AE (°), final X (cm), Y (cm), θ (°).
    paper = [(-1.5, 2.2, -1.0, -0.07), (0.5, 3.7, -2.1, -0.25), (2.1, 1.2, -1.4, 0.18)]
    truth = [(1, 1.0, 4.0, 2.0, 90.0), (2, 2.0, 6.5, 2.5, 0.0), (3, 3.0, 9.0, 1.0, -45.0)]
    survey = make_survey(truth)
    estimates = make_estimates(
        [
            {
                "time_s": t,
                "align_theta_deg": theta - ae,
                "x_m": x - ex / 100.0,
                "y_m": y - ey / 100.0,
                "theta_deg": theta - eth,
            }
            for (_, t, x, y, theta), (ae, ex, ey, eth) in zip(truth, paper, strict=True)
        ]
    )
    stats = summary(table1(estimates, survey))
    rms = stats.loc["RMS"]
    assert rms["ae_deg"] == pytest.approx(math.sqrt((1.5**2 + 0.5**2 + 2.1**2) / 3))
    assert rms["err_x_cm"] == pytest.approx(math.sqrt((2.2**2 + 3.7**2 + 1.2**2) / 3))
    assert rms["err_y_cm"] == pytest.approx(math.sqrt((1.0**2 + 2.1**2 + 1.4**2) / 3))
    assert rms["err_theta_deg"] == pytest.approx(math.sqrt((0.07**2 + 0.25**2 + 0.18**2) / 3))
    assert stats.loc["max", "err_y_cm"] == pytest.approx(2.1)


# --- gate ---------------------------------------------------------------------------------


def test_gate_messages():
    failures = pose_failures(small_table(), Gates(axis_cm=3.5, deg=0.2))
    assert failures == {2: ["|X| 4.0 cm > 3.5 cm", "|θ| 0.30° > 0.20°"], 3: ["status diverged"]}


def test_gate_shows_enough_decimals_to_tell_value_from_limit():
    survey = make_survey([(4, 0.0, 0.0, 0.0, 0.0)])
    estimates = make_estimates([{"time_s": 0.0, "y_m": 0.0104}])
    table = table1(estimates, survey)
    assert pose_failures(table, Gates(axis_cm=1.0)) == {4: ["|Y| 1.04 cm > 1.00 cm"]}
    assert pose_failures(table, Gates(xy_cm=1.0)) == {4: ["|XY| 1.04 cm > 1.00 cm"]}
    assert pose_failures(table, Gates(xy_cm=1.05)) == {}


def test_gate_passes_and_ignores_status_without_limits():
    table = small_table()
    assert pose_failures(table, Gates()) == {}
    assert pose_failures(table[table["status"] == "ok"], Gates(axis_cm=4.0, deg=0.3)) == {}


def test_gate_rejects_negative_limit():
    with pytest.raises(ValueError, match="axis_cm must be a non-negative number, got -1"):
        Gates(axis_cm=-1.0)


# --- formats ------------------------------------------------------------------------------


def test_csv_and_json_round_trip_to_the_precision_of_each_unit():
    table = small_table()
    # Errors as arithmetic leaves them: 182.2 cm from metres is 182.19999999999993.
    table["init_x_cm"] = (np.array([1.822, 0.1, 0.2]) - np.array([0.0, 0.2, -0.1])) * 100.0
    table["err_theta_deg"] = np.rad2deg(np.deg2rad([125.0, 30.0, 1.0 / 3.0]))
    text = format_table(table, summary(table), "csv")
    back = pd.read_csv(io.StringIO(text))
    assert back.columns.tolist() == [*table.columns, "scored", "beyond_gate"]
    assert back["pose_id"].tolist() == [1, 2, 3]
    assert back["status"].tolist() == ["ok", "ok", "diverged"]
    numeric = [c for c in table.columns if c not in ("pose_id", "status")]
    assert_frame_within_precision(back[numeric], table[numeric])
    assert back["init_x_cm"].tolist()[0] == 182.2
    assert back["err_theta_deg"].tolist()[:2] == [125.0, 30.0]
    document = format_table(table, summary(table), "json")
    assert not BINARY_NOISE.search(text) and not BINARY_NOISE.search(document)
    poses = pd.DataFrame(json.loads(document)["poses"])[numeric].astype(float)
    assert_frame_within_precision(poses, table[numeric])


def test_json_has_poses_and_summary_with_nulls():
    survey = make_survey([(1, 0.0, 0.0, 0.0, 0.0), (2, 1.0, 0.0, 0.0, 0.0)])
    estimates = make_estimates(
        [{"time_s": 0.0, "x_m": -0.03}, {"time_s": 1.0, "x_m": np.nan, "status": "no_scan"}]
    )
    table = table1(estimates, survey)
    stats = summary(table)
    doc = json.loads(format_table(table, stats, "json"))
    assert [p["pose_id"] for p in doc["poses"]] == [1, 2]
    assert doc["poses"][0]["err_x_cm"] == pytest.approx(table.loc[0, "err_x_cm"], abs=1e-4)
    assert doc["poses"][1]["err_x_cm"] is None
    assert doc["poses"][1]["status"] == "no_scan"
    assert doc["summary"]["n_poses"] == 2
    assert doc["summary"]["n_failed"] == 1
    assert doc["summary"]["RMS"]["err_x_cm"] == pytest.approx(
        stats.loc["RMS", "err_x_cm"], abs=1e-4
    )
    assert doc["summary"]["max"]["init_x_cm"] == pytest.approx(
        stats.loc["max", "init_x_cm"], abs=1e-4
    )


def test_markdown_table_has_paper_header_precision_and_summary_rows():
    table = small_table()
    rows = md_rows(format_table(table, summary(table), "md"))
    header = ["pose", "AE (°)", "init X (cm)", "init Y (cm)", "init θ (°)"]
    header += ["X (cm)", "Y (cm)", "XY (cm)", "θ (°)", "status"]
    assert rows[0] == header
    body = rows[2:]  # rows[1] is the alignment line
    assert [r[0] for r in body] == ["1", "2", "3", "RMS", "max abs"]
    assert body[0] == ["1", "0.00", "10.0", "0.0", "0.00", "3.0", "0.0", "3.0", "0.10", "ok"]
    assert body[4][5] == "100.0"  # the diverged pose has an estimate, so it is scored
    assert md_rows(format_table(table, summary(table, only_ok=True), "md"))[6][5] == "4.0"


def test_markdown_marks_missing_values():
    survey = make_survey([(1, 0.0, 0.0, 0.0, 0.0)])
    estimates = make_estimates([{"time_s": 0.0, "x_m": np.nan, "status": "no_scan"}])
    table = table1(estimates, survey)
    text = format_table(table, summary(table), "md")
    assert md_rows(text)[2][5] == "—"
    assert "1 surveyed pose: no_scan 1." in text
    assert (
        "cover the 0 poses with an estimate, whatever their status; 1 surveyed pose has no" in text
    )


def test_latex_is_a_tabular_with_escaped_status():
    survey = make_survey([(1, 0.0, 0.0, 0.0, 0.0)])
    estimates = make_estimates([{"time_s": 0.0, "status": "too_few_segments"}])
    table = table1(estimates, survey)
    text = format_table(table, summary(table), "latex")
    assert text.startswith("% needs \\usepackage{booktabs}\n\\begin{tabular}{lrrrrrrrrl}")
    assert text.rstrip().endswith("\\end{tabular}")
    assert "too\\_few\\_segments" in text
    assert text.count("\\midrule") == 3
    assert "\\multicolumn{10}{l}{\\footnotesize 1 surveyed pose: too\\_few\\_segments 1.}" in text


def test_unknown_format_names_the_choices():
    table = small_table()
    with pytest.raises(ValueError, match="unknown table format 'xlsx'; choose one of md, csv"):
        format_table(table, summary(table), "xlsx")


# --- the command line -----------------------------------------------------------------------


@pytest.fixture
def run_files(tmp_path):
    """An estimates CSV (ok, ambiguous 12 cm off) and its survey, written as the tools do."""
    from segloc_cli.io.tables import write_estimates, write_pose_table

    survey = make_survey([(1, 1.0, 0.0, 0.0, 0.0), (2, 2.0, 0.0, 0.0, 0.0)])
    estimates = make_estimates(
        [{"time_s": 1.0, "x_m": -0.03}, {"time_s": 2.0, "x_m": -0.12, "status": "ambiguous"}]
    )
    write_pose_table(tmp_path / "survey.csv", survey)
    write_estimates(tmp_path / "est.csv", estimates)
    return tmp_path / "est.csv", tmp_path / "survey.csv"


def test_cli_scores_all_poses_and_only_ok_on_request(run_files, capsys):
    est, survey = run_files
    code, out, _ = run_cli(capsys, "evaluate", est, "--survey", survey, "--format", "json")
    assert code == 0
    assert json.loads(out)["summary"]["max"]["err_x_cm"] == pytest.approx(12.0)
    code, out, _ = run_cli(
        capsys, "evaluate", est, "--survey", survey, "--format", "json", "--only-ok"
    )
    assert code == 0
    assert json.loads(out)["summary"]["max"]["err_x_cm"] == pytest.approx(3.0)
    code, out, err = run_cli(capsys, "evaluate", est, "--survey", survey, "--fail-above-cm", 5)
    assert code == 1
    assert "1 of 2 poses exceed the per-pose limits (|X|, |Y| ≤ 5 cm)." in out.splitlines()
    assert err.splitlines()[-1] == "segloc: gate: pose 2: status ambiguous"
    code, out, err = run_cli(capsys, "evaluate", est, "--survey", survey, "--fail-above-cm", 20)
    assert code == 1
    assert (
        "0 of 2 poses exceed the per-pose limits (|X|, |Y| ≤ 20 cm); the gate fails 1, counting "
        "1 without an accepted estimate (status other than ok)."
    ) in out.splitlines()


def test_cli_out_needs_force_and_is_checked_before_the_inputs(run_files, tmp_path, capsys):
    est, survey = run_files
    out = tmp_path / "table.md"
    out.write_text("keep me\n")
    # The inputs do not exist: the refusal of the output comes first.
    code, _, err = run_cli(
        capsys, "evaluate", tmp_path / "none.csv", "--survey", survey, "--out", out
    )
    assert (code, err) == (2, f"segloc: error: {out}: file exists; choose another --out or pass "
                               "--force\n")  # fmt: skip
    assert out.read_text() == "keep me\n"
    code, _, err = run_cli(capsys, "evaluate", est, "--survey", survey, "--out", out, "--force")
    assert code == 0, err
    assert out.read_text().startswith("| pose")


def test_cli_plots_refuse_existing_figures_before_work(run_files, tmp_path, capsys):
    est, survey = run_files
    plots = tmp_path / "figures"
    plots.mkdir()
    (plots / "errors.pdf").write_text("old figure")
    code, out, err = run_cli(capsys, "evaluate", est, "--survey", survey, "--plots", plots)
    assert code == 2 and out == ""
    assert err == (
        f"segloc: error: {plots / 'errors.pdf'}: file exists; choose another --plots or pass "
        "--force\n"
    )
    assert (plots / "errors.pdf").read_text() == "old figure"
