"""Numbers in the files segloc writes: each rounded to the precision of its unit, read from
the name it is written under (``numbers.py``), with no float64 noise in any file."""

from __future__ import annotations

import csv
import json
import math

import pytest
from conftest import HALL
from precision import BINARY_NOISE, assert_at_precision, decimals
from test_cli import run_cli

from segloc_cli.io.maps import read_map, write_map
from segloc_cli.io.times import logged_times
from segloc_cli.numbers import json_text, number_text, rounded, unit_of


@pytest.mark.parametrize(
    ("name", "unit"),
    [
        ("x_m", "m"),
        ("err_xy_cm", "cm"),
        ("theta_deg", "deg"),
        ("time_s", "s"),
        ("runtime_ms", "ms"),
        ("trans_pct", "pct"),
        ("rot_deg_per_m", "deg_per_m"),
        ("trans_sq_mean_m2", "m2"),
        ("grid-m", "m"),
        ("median °", "deg"),
        ("within gates %", "pct"),
        ("median ms", "ms"),
        ("confidence", None),
        ("inlier_ratio", None),
        ("n_scans", None),
        ("status", None),
    ],
)
def test_the_unit_is_the_end_of_the_name(name, unit):
    assert unit_of(name) == unit


def test_numbers_are_rounded_to_their_unit_and_written_shortest():
    assert number_text(125.00000000000001, "deg") == "125.0"
    assert number_text(182.19999999999993, "cm") == "182.2"
    assert number_text(0.1 + 0.2, "m") == "0.3"
    assert number_text(1.0 / 3.0, "m") == "0.333333"
    assert number_text(1.0 / 3.0, None) == "0.333333333"
    assert number_text(-1e-9, "m") == "0.0"  # never -0.0
    assert number_text(1.5e-5, "m") == "1.5e-05"
    assert number_text(math.inf, "m") == "inf"
    assert math.isnan(rounded(math.nan, "m"))


def test_a_logs_times_come_back_from_their_text_exactly():
    """A log keeps whole nanoseconds (``logged_times``); written to the nanosecond, such a
    time reads back as the same float64, relative or absolute (Unix time in 2026)."""
    import numpy as np

    rng = np.random.default_rng(11)
    for base in (0.0, 1234.5, 1.77e9):
        times = logged_times(np.sort(base + rng.uniform(0, 100, 500)))
        back = [float(number_text(t, "s")) for t in times]
        assert back == times.tolist()


def test_json_numbers_take_the_unit_of_the_key_above_them():
    document = {"trans_m": {"mean": 0.1 + 0.2, "std": 1 / 3}, "drift": [{"rot_deg": 2 / 3}]}
    document |= {"confidence": 1 / 7, "n": 3, "ok": True, "none": None}
    assert json.loads(json_text(document)) == {
        "trans_m": {"mean": 0.3, "std": 0.333333},
        "drift": [{"rot_deg": 0.666667}],
        "confidence": 0.142857143,
        "n": 3,
        "ok": True,
        "none": None,
    }
    with pytest.raises(ValueError):
        json_text({"x_m": math.nan})


def _numbers(rows: list[list[str]]) -> list[tuple[str, str]]:
    """(column, text) of every number in a CSV's rows (the first row its header)."""
    header, *body = rows
    found = []
    for row in body:
        for column, text in zip(header, row, strict=True):
            try:
                float(text)
            except ValueError:
                continue
            found.append((column, text))
    return found


def test_every_table_of_a_hall_run_is_written_at_its_precision(tmp_path, capsys):
    """The estimates, the hypotheses, the TUM trajectory and evaluate's csv and json of a run
    on the hall: no float64 noise, each number within its unit's decimals."""
    est = tmp_path / "est.csv"
    args = ["localize", HALL / "log.mcap", "--map", HALL / "map.json", "--out", est]
    result = run_cli(capsys, *args, "--hypotheses", "3", "--tum", tmp_path / "est.tum")
    assert result.code == 0, result.err
    for fmt in ("csv", "json"):
        out = tmp_path / f"table_{fmt}.{fmt}"
        args = ["evaluate", est, "--survey", HALL / "survey.csv", "--format", fmt, "--out", out]
        assert run_cli(capsys, *args).code == 0
    files = [est, tmp_path / "est.hypotheses.csv", tmp_path / "est.tum", tmp_path / "table_csv.csv"]
    for path in [*files, tmp_path / "table_json.json", HALL / "survey.csv", HALL / "map.json"]:
        assert not BINARY_NOISE.search(path.read_text(encoding="utf-8")), path
    for path in (est, tmp_path / "est.hypotheses.csv", tmp_path / "table_csv.csv"):
        rows = list(csv.reader(path.read_text(encoding="utf-8").splitlines()))
        numbers = _numbers(rows)
        assert len(numbers) > 10 * len(rows[0]) // 2, path
        for column, text in numbers:
            assert_at_precision(text, unit_of(column))
    tum = [line.split() for line in (tmp_path / "est.tum").read_text().splitlines()[1:]]
    assert max(decimals(text) for line in tum for text in line[1:4]) <= 6
    assert max(decimals(text) for line in tum for text in line[4:]) <= 9


def test_the_shipped_map_is_as_the_writer_writes_it(tmp_path):
    """datasets/hall/map.json is `map build`'s output: one segment a line, to the micrometre,
    and written again unchanged."""
    text = (HALL / "map.json").read_text(encoding="utf-8")
    rows = [line for line in text.splitlines() if line.startswith("  [")]
    assert len(rows) == len(read_map(HALL / "map.json")) == 220
    assert all(decimals(v) <= 6 for row in rows for v in row.strip(" [],").split(", "))
    again = tmp_path / "map.json"
    write_map(again, read_map(HALL / "map.json"), json.loads(text)["source"])
    assert again.read_text(encoding="utf-8") == text
