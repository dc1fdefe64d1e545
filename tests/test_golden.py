"""Golden files: what users script against, pinned before the command layer is reshaped.

Every ``--help`` text, a set of one-line error messages and the hall's estimates
(every column but the measured ``runtime_ms``; numbers to their last written digit, see
``LAST_BITS``) must stay as recorded in ``tests/golden/``. A change that means to alter
one regenerates the files with ``SEGLOC_UPDATE_GOLDEN=1 make test`` and shows the
difference in its commit.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import click
import pytest
from click.testing import CliRunner
from conftest import HALL
from test_cli import run_cli

from segloc_cli.cli import cli
from segloc_cli.numbers import decimals_of, unit_of

GOLDEN = Path(__file__).parent / "golden"
UPDATE = os.environ.get("SEGLOC_UPDATE_GOLDEN") == "1"
HELP_COLUMNS = "100"


def _matches_golden(name: str, text: str) -> None:
    path = GOLDEN / name
    if UPDATE:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    assert path.is_file(), f"{path} is missing; run with SEGLOC_UPDATE_GOLDEN=1 to record it"
    assert text == path.read_text(encoding="utf-8"), f"{name} differs from its golden file"


def _command_paths(command: click.Command, path: tuple[str, ...] = ()):
    yield path
    if isinstance(command, click.Group):
        for name, sub in sorted(command.commands.items()):
            yield from _command_paths(sub, (*path, name))


@pytest.mark.parametrize("path", list(_command_paths(cli)), ids=lambda p: " ".join(p) or "segloc")
def test_help_text_is_unchanged(path):
    result = CliRunner().invoke(cli, [*path, "--help"], env={"COLUMNS": HELP_COLUMNS})
    assert result.exit_code == 0, result.output
    _matches_golden(f"help/{'-'.join(path) or 'segloc'}.txt", result.output)


# Each case: the arguments (relative to a folder holding the files below) and the input
# files it needs. The folder makes the messages, which name files, the same on any machine.
ERROR_CASES = {
    "missing-log": ["info", "none.mcap"],
    "not-mcap": ["info", "text.mcap"],
    "map-not-json": ["localize", "hall.mcap", "--map", "text.mcap", "--out", "est.csv"],
    "existing-out": ["map", "build", "hall.mcap", "--survey", "survey.csv", "--out", "taken.csv"],
    "out-is-input": ["map", "build", "hall.mcap", "--survey", "survey.csv", "--out", "survey.csv",
                     "--force"],
    "missing-folder": ["localize", "hall.mcap", "--map", "map.json", "--out", "no/est.csv"],
    "nan-option": ["localize", "hall.mcap", "--map", "map.json", "--out", "e.csv",
                   "--grid-m", "nan"],
    "bin-deg": ["localize", "hall.mcap", "--map", "map.json", "--out", "e.csv", "--bin-deg", "7"],
    "global-track": ["localize", "hall.mcap", "--map", "map.json", "--out", "e.csv", "--global",
                     "--track"],
    "survey-no-x": ["map", "build", "hall.mcap", "--survey", "no-x.csv", "--out", "m.json"],
    "duplicate-times": ["map", "build", "hall.mcap", "--survey", "twice.csv", "--out", "m.json"],
    "survey-and-relations": ["evaluate", "survey.csv"],
    "not-carmen": ["import", "carmen", "hall.mcap", "--out", "x.mcap"],
    "emulate-map": ["emulate", "--device", "scip2", "--world", "map.json", "--pose", "1,1,0"],
    "emulate-pose": ["emulate", "--device", "scip2", "--world", "world.json", "--pose", "nan,0,0"],
    "record-device": ["record", "--device", "usb:/dev/null", "--out", "r.mcap"],
    "unknown-command": ["frobnicate"],
}  # fmt: skip


@pytest.fixture
def error_folder(tmp_path, monkeypatch):
    (tmp_path / "hall.mcap").write_bytes((HALL / "log.mcap").read_bytes())
    (tmp_path / "map.json").write_bytes((HALL / "map.json").read_bytes())
    (tmp_path / "survey.csv").write_bytes((HALL / "survey.csv").read_bytes())
    (tmp_path / "world.json").write_bytes((HALL / "world.json").read_bytes())
    (tmp_path / "text.mcap").write_text("not a log\n", encoding="utf-8")
    (tmp_path / "taken.csv").write_text("keep me\n", encoding="utf-8")
    (tmp_path / "no-x.csv").write_text("pose_id,time_s,y_m,theta_deg\n1,1,0,0\n", encoding="utf-8")
    rows = "pose_id,time_s,x_m,y_m,theta_deg\n1,1.0,11,1.6,90\n2,1.0,11,1.6,90\n"
    (tmp_path / "twice.csv").write_text(rows, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_error_messages_are_unchanged(capsys, error_folder):
    lines = []
    for name, args in ERROR_CASES.items():
        result = run_cli(capsys, *args)
        assert result.code == 2, (name, result)
        (line,) = result.err.splitlines()
        lines.append(f"{name}: {line}\n")
    _matches_golden("errors.txt", "".join(lines))


LAST_BITS = 1e-9
"""Numbers of the hall's estimates may differ from the golden file by this much (relative,
and absolute near 0), or by one step of their column's precision (``numbers.py``): a
CPU's vector maths library (numpy uses SVML's arctan2, sin and cos where AVX-512 is present)
rounds some results one bit differently from the C library, those bits reach the last digits
of a fit, and where a value lies that close to a rounding boundary its written text takes
the next step. Everything else must be exactly as recorded."""


def _cells_match(column: str, recorded: str, made: str) -> bool:
    if recorded == made:
        return True
    try:
        a, b = float(recorded), float(made)
    except ValueError:
        return False
    step = 10.0 ** -decimals_of(unit_of(column))
    return abs(a - b) <= LAST_BITS * max(1.0, abs(a), abs(b)) + step


def test_hall_estimates_are_unchanged(capsys, tmp_path):
    out = tmp_path / "est.csv"
    result = run_cli(
        capsys, "localize", HALL / "log.mcap", "--map", HALL / "map.json", "--out", out
    )
    assert result.code == 0, result.err
    rows = list(csv.reader(out.read_text(encoding="utf-8").splitlines()))
    drop = rows[0].index("runtime_ms")
    made = [[cell for i, cell in enumerate(row) if i != drop] for row in rows]
    if UPDATE:
        text = io.StringIO()
        csv.writer(text, lineterminator="\n").writerows(made)
        _matches_golden("hall_estimates.csv", text.getvalue())
    recorded = list(csv.reader((GOLDEN / "hall_estimates.csv").read_text().splitlines()))
    assert made[0] == recorded[0], "the estimates' columns changed"
    assert len(made) == len(recorded), "the estimates have another number of rows"
    for row, (golden_row, made_row) in enumerate(zip(recorded[1:], made[1:], strict=True), 2):
        for column, a, b in zip(recorded[0], golden_row, made_row, strict=True):
            assert _cells_match(column, a, b), f"row {row}, {column}: recorded {a}, made {b}"
