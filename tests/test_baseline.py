"""A run against its baseline: the paired bootstrap's false alarms and power on simulated
errors with known truth, exact results on hand-made runs, pairing, and bad baseline files."""

from __future__ import annotations

import json
import math
import re
import warnings

import numpy as np
import pandas as pd
import pytest

from segloc_cli.errors import InputError
from segloc_cli.runs.evaluation import read_baseline
from segloc_cli.scoring.baseline import (
    BETTER,
    NO_CHANGE,
    NOT_COMPARED,
    WORSE,
    WORSE_WITHIN_LIMIT,
    compare,
    parse_baseline,
)
from segloc_cli.scoring.evaluate import TABLE_COLUMNS, format_table, summary

FIGURES = ["RMS X", "RMS Y", "RMS |XY|", "RMS θ", "mean |XY|", "mean |θ|"]


def make_table(ids, err_x_cm, err_y_cm, err_theta_deg, status=None) -> pd.DataFrame:
    """Table 1 of a run from its final errors (cm, cm, degrees), statuses ``ok`` by default."""
    err_x_cm, err_y_cm = np.asarray(err_x_cm, float), np.asarray(err_y_cm, float)
    table = pd.DataFrame(
        {
            "pose_id": np.asarray(ids, dtype=np.int64),
            "err_x_cm": err_x_cm,
            "err_y_cm": err_y_cm,
            "err_theta_deg": np.asarray(err_theta_deg, float),
            "err_xy_cm": np.hypot(err_x_cm, err_y_cm),
            "status": ["ok"] * len(err_x_cm) if status is None else status,
        }
    )
    # The columns these scores do not read (initial errors, times) hold zeros.
    for column in set(TABLE_COLUMNS) - set(table.columns):
        table[column] = 0.0
    return table[list(TABLE_COLUMNS)]


def as_baseline(table: pd.DataFrame) -> dict:
    """The baseline ``segloc evaluate --format json`` would have written for ``table``."""
    return parse_baseline(format_table(table, summary(table), "json"))


def by_figure(comparison) -> dict:
    return {row.figure: row for row in comparison.rows}


# --- noise and power ----------------------------------------------------------------------

N_POSES = 40
N_TRIALS = 200


def simulated_runs(rng: np.random.Generator, worse_cm: float) -> tuple[dict, pd.DataFrame]:
    """Two runs over the same poses: one set of underlying errors (N(0, 3 cm) per axis,
    N(0, 1°)), each run adding its own noise (N(0, 0.5 cm), N(0, 0.05°)); the second run's
    position error vectors are then stretched so that each |XY| grows by ``worse_cm``."""
    truth_xy = rng.normal(0.0, 3.0, size=(N_POSES, 2))
    truth_theta = rng.normal(0.0, 1.0, size=N_POSES)
    runs = []
    for stretch in (0.0, worse_cm):
        xy = truth_xy + rng.normal(0.0, 0.5, size=(N_POSES, 2))
        xy *= 1.0 + stretch / np.hypot(xy[:, 0], xy[:, 1])[:, None]
        theta = truth_theta + rng.normal(0.0, 0.05, size=N_POSES)
        runs.append(make_table(np.arange(N_POSES), xy[:, 0], xy[:, 1], theta))
    # The JSON's shape without the JSON, so that 200 trials stay quick.
    return {"poses": runs[0].to_dict("records")}, runs[1]


def failures_over_trials(worse_cm: float) -> int:
    failed = 0
    for trial in range(N_TRIALS):
        baseline, now = simulated_runs(np.random.default_rng(trial), worse_cm)
        comparison = compare(baseline, now, fail_if_worse_cm=1.0, n_resamples=1000, seed=trial)
        failed += comparison.failed
    return failed


def test_the_same_errors_with_fresh_noise_never_fail():
    assert failures_over_trials(worse_cm=0.0) == 0


def test_a_run_worse_by_2_cm_on_every_pose_always_fails():
    assert failures_over_trials(worse_cm=2.0) == N_TRIALS


def test_the_stretch_adds_exactly_the_asked_centimetres():
    baseline, now = simulated_runs(np.random.default_rng(1), 2.0)
    before = np.array([pose["err_xy_cm"] for pose in baseline["poses"]])
    # Not the same noise, so only the mean shift is known: 2 cm, within the noise's reach.
    assert np.mean(now["err_xy_cm"].to_numpy() - before) == pytest.approx(2.0, abs=0.3)
    row = by_figure(compare(baseline, now, fail_if_worse_cm=1.0, seed=1))["mean |XY|"]
    assert row.verdict == WORSE and row.low > 1.0 and row.low < row.change < row.high


# --- exact results --------------------------------------------------------------------------


def test_identical_runs_change_by_exactly_nothing():
    rng = np.random.default_rng(7)
    table = make_table(np.arange(12), *rng.normal(0.0, 3.0, size=(3, 12)))
    comparison = compare(as_baseline(table), table, fail_if_worse_cm=0.0, fail_if_worse_deg=0.0)
    assert [row.figure for row in comparison.rows] == FIGURES
    for row in comparison.rows:
        assert (row.change, row.low, row.high) == (0.0, 0.0, 0.0), row
        assert row.baseline == row.now and row.verdict == NO_CHANGE
    assert not comparison.failed


def test_hand_made_runs_give_their_figures_and_verdicts():
    # Every pose 1 cm worse in X and 1° better in θ: each resample sees the same change.
    before = make_table([1, 2, 3, 4], [3.0, 4.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [2, -2, 2, -2])
    after = make_table([1, 2, 3, 4], [4.0, 5.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.0], [1, -1, 1, -1])
    rows = by_figure(compare(as_baseline(before), after, fail_if_worse_cm=0.5, n_resamples=50))
    assert rows["mean |XY|"].baseline == pytest.approx(1.75)
    assert rows["mean |XY|"].now == pytest.approx(2.75)
    assert (rows["mean |XY|"].low, rows["mean |XY|"].high) == pytest.approx((1.0, 1.0))
    assert rows["mean |XY|"].verdict == WORSE
    assert rows["RMS X"].baseline == pytest.approx(2.5)
    assert rows["RMS X"].now == pytest.approx(math.sqrt(43.0 / 4.0))
    assert rows["RMS Y"].verdict == NO_CHANGE
    assert (rows["mean |θ|"].change, rows["mean |θ|"].high) == pytest.approx((-1.0, -1.0))
    assert rows["mean |θ|"].verdict == BETTER
    assert rows["RMS θ"].limit is None and rows["RMS X"].limit == 0.5


def md_cells(text: str) -> list[list[str]]:
    """The cells of the Markdown table in ``text``, split on the pipes that are not escaped."""
    rows = [line for line in text.splitlines() if line.startswith("|")]
    return [[c.strip() for c in re.split(r"(?<!\\)\|", row)[1:-1]] for row in rows]


def test_markdown_table_keeps_its_columns_and_says_what_failed():
    before = make_table([1, 2, 3], [1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [0.5, -0.5, 0.5])
    after = make_table([1, 2, 3], [3.0, 4.0, 5.0], [0.0, 0.0, 0.0], [0.5, -0.5, 0.5])
    comparison = compare(as_baseline(before), after, fail_if_worse_cm=1.0, n_resamples=50)
    text = comparison.format_md()
    cells = md_cells(text)
    assert cells[0] == ["figure", "baseline", "now", "change", "95 % interval", "verdict"]
    assert cells[2 + FIGURES.index("mean |XY|")] == [
        "mean \\|XY\\| (cm)",
        "2.0",
        "4.0",
        "+2.0",
        "[+2.0, +2.0]",
        WORSE,
    ]
    assert cells[2 + FIGURES.index("RMS θ")] == [
        "RMS θ (°)",
        "0.50",
        "0.50",
        "0.00",
        "[0.00, 0.00]",
        NO_CHANGE,
    ]
    assert text.splitlines()[-1].endswith("RMS X, RMS |XY|, mean |XY| worse beyond it: FAIL.")
    assert comparison.failed and comparison.lines()[-1] == text.splitlines()[-1]


def test_worse_but_not_beyond_the_limit_does_not_fail():
    before = make_table([1, 2, 3], [3.0, 4.0, 5.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    after = make_table([1, 2, 3], [3.5, 4.5, 5.5], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    comparison = compare(as_baseline(before), after, fail_if_worse_cm=1.0, n_resamples=50)
    assert by_figure(comparison)["mean |XY|"].verdict == WORSE_WITHIN_LIMIT
    assert not comparison.failed
    assert comparison.as_json()["failed"] is False
    assert comparison.format_md().endswith("above 1 cm (cm figures); none is: pass.\n")


# --- pairing -------------------------------------------------------------------------------


def test_poses_pair_by_id_and_the_rest_are_counted():
    before = make_table([1, 2, 3, 4, 5, 6], [9.0, 9.0, 1.0, 2.0, 3.0, 4.0], [0.0] * 6, [0.0] * 6)
    # Poses 3..9 in another order; pose 5 lost its estimate now, pose 6 is not ok now.
    after = make_table(
        [9, 6, 5, 4, 3, 8, 7],
        [7.0, 4.0, math.nan, 2.0, 1.0, 7.0, 7.0],
        [0.0] * 7,
        [0.0] * 7,
        status=["ok", "lost", "lost", "ok", "ok", "ok", "ok"],
    )
    comparison = compare(as_baseline(before), after)
    counts = (comparison.n_shared, comparison.n_only_baseline, comparison.n_only_now)
    assert counts == (3, 2, 3) and comparison.n_left_out == 1
    # Paired by id, the shared poses (3, 4, 6) have the same errors in both runs.
    assert by_figure(comparison)["RMS X"].baseline == pytest.approx(math.sqrt(21.0 / 3.0))
    assert by_figure(comparison)["RMS X"].change == 0.0
    only_ok = compare(as_baseline(before), after, only_ok=True)
    assert (only_ok.n_shared, only_ok.n_left_out) == (2, 2)
    assert "2 only in the baseline, 3 only in this run; 1 of both left out" in (
        comparison.format_md()
    )


def test_fewer_than_two_poses_to_compare_is_one_error():
    before = make_table([1, 2], [1.0, 2.0], [0.0, 0.0], [0.0, 0.0])
    after = make_table([2, 3], [1.0, 2.0], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(InputError, match="share 1 pose with errors") as caught:
        compare(as_baseline(before), after)
    assert "\n" not in str(caught.value)


def test_json_of_a_comparison_is_plain_json():
    table = make_table([1, 2, 3], [1.0, 2.0, 3.0], [0.0, 0.0, 1.0], [0.5, 0.0, 0.1])
    out = json.loads(json.dumps(compare(as_baseline(table), table).as_json(), allow_nan=False))
    assert [f["figure"] for f in out["figures"]] == FIGURES
    assert out["n_shared"] == 3 and out["failed"] is False


def test_figures_that_cannot_be_compared_never_pass():
    # This run's errors so large that their squares overflow: the X figures are not finite.
    before = make_table([1, 2, 3], [1.0, 2.0, 3.0], [0.0, 0.5, 1.0], [0.5, 0.0, 0.1])
    now = make_table([1, 2, 3], [1e300, 2.0, 3.0], [0.0, 0.5, 1.0], [0.5, 0.0, 0.1])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        comparison = compare(as_baseline(before), now, fail_if_worse_cm=1.0)
        unlimited = compare(as_baseline(before), now, fail_if_worse_deg=1.0)
    rows = by_figure(comparison)
    not_compared = [f for f, row in rows.items() if row.verdict == NOT_COMPARED]
    assert not_compared == ["RMS X", "RMS |XY|"]
    assert comparison.failed and rows["RMS X"].failed and not rows["mean |XY|"].failed
    assert "RMS X cannot be compared" in comparison.failures[0]
    assert [o.passed for o in comparison.outcomes if "RMS X" in o.title] == [False]
    # Without a limit on its unit the figure is shown as not compared, and fails nothing.
    assert by_figure(unlimited)["RMS X"].verdict == NOT_COMPARED and not unlimited.failed
    assert json.loads(json.dumps(comparison.as_json(), allow_nan=False))["failed"] is True


# --- baseline files ------------------------------------------------------------------------


def test_a_baseline_file_round_trips_through_evaluate_json(tmp_path):
    table = make_table([4, 8, 15], [1.0, math.nan, -2.0], [0.5, math.nan, 1.0], [0.1, 0.0, 0.2])
    path = tmp_path / "old.json"
    path.write_text(format_table(table, summary(table), "json"), encoding="utf-8")
    comparison = compare(read_baseline(path), table)
    assert (comparison.n_shared, comparison.n_left_out) == (2, 1)
    assert all(row.change == 0.0 for row in comparison.rows)


GOOD_POSE = {
    "pose_id": 1,
    "err_x_cm": 1.0,
    "err_y_cm": 0.0,
    "err_xy_cm": 1.0,
    "err_theta_deg": 0.1,
    "status": "ok",
}


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        ("pose_id,err_x_cm\n1,2\n", "not JSON"),
        ("[1, 2]", 'no "poses" list'),
        ('{"summary": {}}', 'no "poses" list'),
        (json.dumps({"poses": [{"pose_id": 1, "err_x_cm": 1.0}]}), "lacks err_y_cm"),
        (json.dumps({"poses": [GOOD_POSE, 3]}), r"poses\[1\] lacks pose_id"),
        (json.dumps({"poses": [{**GOOD_POSE, "pose_id": "a"}]}), "pose_id 'a' is not an int"),
        (json.dumps({"poses": [{**GOOD_POSE, "pose_id": 1.5}]}), "is not an integer"),
        (json.dumps({"poses": [{**GOOD_POSE, "err_y_cm": "2"}]}), "err_y_cm '2' is not a num"),
        (json.dumps({"poses": [{**GOOD_POSE, "err_y_cm": True}]}), "err_y_cm True is not a"),
        (json.dumps({"poses": [GOOD_POSE, GOOD_POSE]}), "pose 1 more than once"),
        # Ids beyond int64, numbers too long to read, and nesting too deep name the file too.
        (json.dumps({"poses": [{**GOOD_POSE, "pose_id": 2**63}]}), "not an integer within"),
        (json.dumps({"poses": [{**GOOD_POSE, "pose_id": -(2**64)}]}), "not an integer within"),
        (json.dumps({"poses": [{**GOOD_POSE, "pose_id": 10**4000}]}), r"1\d+… \(4001 digits\)"),
        ('{"poses": [{"pose_id": 1' + "0" * 5000 + "}]}", "a number too long to read"),
        ('{"poses": ' + "[" * 100_000 + "]" * 100_000 + "}", "nested too deeply"),
        # Errors that are not finite, or so large that their squares overflow, are refused.
        *(
            (json.dumps({"poses": [{**GOOD_POSE, key: value}]}), f"{key} .* is no error")
            for key, value in (
                ("err_x_cm", 1e308),
                ("err_y_cm", -1e300),
                ("err_xy_cm", math.inf),
                ("err_theta_deg", math.nan),
                ("err_theta_deg", 400.0),
                ("err_x_cm", 10**20),
            )
        ),
        (
            '{"poses": [{"pose_id": 1, "err_x_cm": 1e400, "err_y_cm": 0, "err_xy_cm": 0, '
            '"err_theta_deg": 0, "status": "ok"}]}',
            "err_x_cm inf is no error",
        ),
    ],
)
def test_bad_baseline_files_are_one_line_errors(tmp_path, content, expected):
    path = tmp_path / "old.json"
    path.write_text(content, encoding="utf-8")
    with pytest.raises(InputError, match=expected) as caught:
        read_baseline(path)
    message = str(caught.value)
    assert "\n" not in message and message.startswith(str(path))


def test_a_wrong_file_says_how_to_make_a_baseline(tmp_path):
    for content in ("{", '{"poses": 3}', json.dumps({"poses": [{"pose_id": 1}]})):
        (tmp_path / "old.json").write_text(content, encoding="utf-8")
        with pytest.raises(InputError, match=r"--format json --out OLD\.json"):
            read_baseline(tmp_path / "old.json")
    with pytest.raises(InputError, match="file not found; check the path"):
        read_baseline(tmp_path / "missing.json")
    with pytest.raises(InputError, match="is a directory"):
        read_baseline(tmp_path)
    (tmp_path / "binary.json").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(InputError, match="not a text file"):
        read_baseline(tmp_path / "binary.json")
