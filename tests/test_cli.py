"""The ``segloc`` command line as users run it.

The contract: bad input or usage gets exactly one line on stderr, starting
``segloc: error:`` and naming the file (and row) at fault, exit status 2 and
no traceback; ``evaluate --fail-above-*`` exits 1 when a pose exceeds a limit.
Error cases run ``segloc_cli.cli.main`` in-process (the console script's entry
point); the end-to-end pipeline and ``--help`` run the installed console script.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import subprocess
from contextlib import chdir, redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from conftest import HALL, HALL_WORLD, SEGLOC, made_once
from mcap.writer import Writer

from segloc_cli.cli import main
from segloc_cli.geometry import Pose2
from segloc_cli.io.mcap_log import LogWriter, read_log
from segloc_cli.io.tables import read_pose_table
from segloc_cli.scan import Scan

HALL_POSES = HALL / "poses.csv"
SEED = 2000

ESTIMATE_HEADER = (
    "pose_id,time_s,init_x_m,init_y_m,init_theta_deg,align_theta_deg,"
    "stage2_x_m,stage2_y_m,stage2_theta_deg,x_m,y_m,theta_deg,overlap_m,inlier_ratio,"
    "runner_up_x_m,runner_up_y_m,runner_up_theta_deg,runner_up_ratio,"
    "n_local_segments,runtime_ms,confidence,status,window_scans"
)

# Reina & Gonzalez (2000), Table 1: initial errors X (cm), Y (cm), θ (°) per pose,
# surveyed minus initial guess.
PAPER_INIT_ERRORS = {
    1: (182.2, 36.0, -9.75),
    2: (-63.7, 49.5, -15.6),
    3: (-91.2, 168.5, 7.82),
    4: (33.2, -131.8, -17.3),
    5: (-10.9, -14.7, -19.9),
    6: (47.2, -168.2, 14.1),
    7: (16.2, 38.7, -6.71),
    8: (74.4, -75.1, 16.4),
    9: (-56.3, 18.1, 3.7),
    10: (-46.5, -133.6, 0.5),
}

SURVEY_HEADER = "pose_id,time_s,x_m,y_m,theta_deg"


# --------------------------------------------------------------------------- helpers


class Result(NamedTuple):
    """What a run of ``segloc`` gave: exit status, standard output, standard error."""

    code: int
    out: str
    err: str


def _exit_code(exc: SystemExit) -> int:
    if exc.code is None:
        return 0
    return exc.code if isinstance(exc.code, int) else 1


def run_cli(capsys, *args) -> Result:
    """Run ``segloc ARGS`` in-process through the console entry point (``run_in_process``),
    whatever the test printed before left out."""
    capsys.readouterr()
    return run_in_process(*args)


def run_in_process(*args, cwd: Path | None = None, env: dict[str, str] | None = None) -> Result:
    """``segloc ARGS`` through the console script's entry point in this process, in ``cwd``
    with ``env`` as its environment (this process's where not given): what the installed
    script gives, less its start-up (a second or more: numba's registries, pandas). An
    exception out of it fails the test: the user would see a traceback."""
    argv = [str(a) for a in args]
    out, err, environ = io.StringIO(), io.StringIO(), dict(os.environ)
    if env is not None:
        os.environ.clear()
        os.environ.update(env)
    try:
        with chdir(cwd or Path.cwd()), redirect_stdout(out), redirect_stderr(err):
            try:
                main(argv)
                code = 0
            except SystemExit as exc:
                code = _exit_code(exc)
            except Exception as exc:
                pytest.fail(
                    f"`segloc {' '.join(argv)}` raised {type(exc).__name__}: {exc}; the user "
                    "would see a traceback instead of one 'segloc: error:' line and exit "
                    "status 2"
                )
    finally:
        if env is not None:
            os.environ.clear()
            os.environ.update(environ)
    return Result(code, out.getvalue(), err.getvalue())


IN_TURN = """
import contextlib, io, json, sys
from segloc_cli.cli import main
said = {}
for name, argv in json.loads(sys.argv[1]).items():
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(argv)
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
    said[name] = [code, out.getvalue(), err.getvalue()]
print(json.dumps({"said": said, "modules": sorted(sys.modules)}))
"""
"""Runs each command of the JSON object ``argv[1]`` (name: arguments) in turn in this
process, then prints what each gave (status, stdout, stderr) by name and the modules
imported by then, as JSON."""


def run_in_turn(
    commands: dict[str, list], cwd: Path | None = None, env: dict[str, str] | None = None
) -> tuple[dict[str, Result], set[str]]:
    """Each of ``commands`` (name: ``segloc`` arguments) in turn in one fresh process, in
    ``cwd`` with ``env``, through the console script's entry point: what each gave, by name,
    and the modules that process had imported at the end. An exception out of a command
    fails the test (the process ends with its traceback)."""
    argv = {name: [str(a) for a in args] for name, args in commands.items()}
    done = subprocess.run(
        [str(SEGLOC.parent / "python"), "-c", IN_TURN, json.dumps(argv)],
        capture_output=True, text=True, check=False, cwd=cwd, env=env,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-4000:]
    report = json.loads(done.stdout)
    said = {name: Result(*result) for name, result in report["said"].items()}
    return said, set(report["modules"])


def run_script(*args, cwd: Path) -> Result:
    """Run the installed ``segloc`` console script in a subprocess."""
    assert SEGLOC.exists(), f"console script not installed at {SEGLOC}"
    env = {**os.environ, "PYTHONIOENCODING": "utf-8"}
    proc = subprocess.run(
        [str(SEGLOC), *(str(a) for a in args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        encoding="utf-8",
        timeout=120,
        check=False,
    )
    return Result(proc.returncode, proc.stdout, proc.stderr)


def assert_one_line_error(result: Result, *fragments: str) -> str:
    """Exit status 2, no traceback, exactly one stderr line 'segloc: error: ...' with fragments."""
    assert "Traceback" not in result.err, f"traceback on stderr:\n{result.err}"
    lines = result.err.splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}:\n{result.err}"
    line = lines[0]
    assert line.startswith("segloc: error:"), f"stderr line lacks 'segloc: error:': {line!r}"
    assert result.code == 2, f"exit status {result.code}, expected 2 (bad input); stderr: {line}"
    for fragment in fragments:
        assert fragment in line, f"{fragment!r} is not named in the error: {line!r}"
    return line


def numbers_in(text: str) -> list[float]:
    return [float(m) for m in re.findall(r"-?\d+(?:\.\d+)?", text)]


def mentions_number(text: str, value: float) -> bool:
    return any(math.isclose(v, value, abs_tol=1e-6) for v in numbers_in(text))


def md_pose_rows(markdown: str) -> list[str]:
    """Rows of a Markdown Table 1 that belong to a pose (first cell a pose id)."""
    return [ln for ln in markdown.splitlines() if re.match(r"^\|\s*\d+\s*\|", ln)]


def read_csv_rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="", encoding="utf-8") as stream:
        reader = csv.DictReader(stream)
        rows = list(reader)
        return list(reader.fieldnames or []), rows


def write_text(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def write_log_without_scan_topic(path: Path) -> Path:
    """A valid MCAP file whose only channel is /chatter."""
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="test")
        schema = writer.register_schema("std_msgs/String", "jsonschema", b'{"type":"object"}')
        channel = writer.register_channel("/chatter", "json", schema)
        for i in range(3):
            t = (i + 1) * 1_000_000_000
            writer.add_message(channel, log_time=t, data=b'{"data":"hello"}', publish_time=t)
        writer.finish()
    return path


def setup_cli(*args) -> None:
    """Run a command that prepares test files; fail loudly if it does not succeed."""
    argv = [str(a) for a in args]
    try:
        main(argv)
    except SystemExit as exc:
        if _exit_code(exc) != 0:
            pytest.fail(f"setup command `segloc {' '.join(argv)}` exited {exc.code}")


@dataclass(frozen=True)
class Small:
    """A three-scan simulated run in the hall: the files the error cases start from."""

    dir: Path
    poses: Path
    log: Path
    survey: Path
    map: Path
    estimates: Path


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Small:
    root = tmp_path_factory.mktemp("small")
    lines = HALL_POSES.read_text(encoding="utf-8").splitlines()
    assert lines[0] == SURVEY_HEADER
    poses = write_text(root / "poses.csv", "\n".join(lines[:4]) + "\n")
    sim = root / "sim"
    log, survey = sim / "log.mcap", sim / "survey.csv"
    setup_cli("simulate", HALL_WORLD, "--poses", poses, "--out", sim, "--seed", SEED)
    setup_cli("map", "build", log, "--survey", survey, "--out", root / "map.json")
    setup_cli("localize", log, "--map", HALL_WORLD, "--out", root / "est.csv")
    return Small(
        dir=root,
        poses=poses,
        log=log,
        survey=survey,
        map=root / "map.json",
        estimates=root / "est.csv",
    )


# --------------------------------------------------------------------------- missing files

# Each case builds the arguments from the fixture and a path that does not exist; the path
# has a distinctive name so the test can check that the error names it.
MISSING_FILE_CASES = {
    "simulate-world": lambda s, m: ["simulate", m, "--poses", s.poses, "--out", s.dir / "o"],
    "simulate-poses": lambda s, m: ["simulate", HALL_WORLD, "--poses", m, "--out", s.dir / "o"],
    "map-build-log": lambda s, m: [
        "map", "build", m, "--survey", s.survey, "--out", s.dir / "o.json"
    ],
    "map-build-survey": lambda s, m: [
        "map", "build", s.log, "--survey", m, "--out", s.dir / "o.json"
    ],
    "localize-log": lambda s, m: ["localize", m, "--map", s.map, "--out", s.dir / "o.csv"],
    "localize-map": lambda s, m: ["localize", s.log, "--map", m, "--out", s.dir / "o.csv"],
    "evaluate-estimates": lambda s, m: ["evaluate", m, "--survey", s.survey],
    "evaluate-survey": lambda s, m: ["evaluate", s.estimates, "--survey", m],
    "info-log": lambda s, m: ["info", m],
}  # fmt: skip


@pytest.mark.parametrize("case", list(MISSING_FILE_CASES))
def test_missing_file_is_one_line_naming_it(case, small, tmp_path, capsys):
    missing = tmp_path / f"no-such-{case}.file"
    result = run_cli(capsys, *MISSING_FILE_CASES[case](small, missing))
    assert_one_line_error(result, missing.name)
    assert result.out == "", f"nothing belongs on stdout after an error, got {result.out!r}"


# --------------------------------------------------------------------------- garbage files

# Every command that reads a log, as a function of the fixture and the log's path.
LOG_COMMANDS = [
    lambda s, log: ["localize", log, "--map", s.map, "--out", s.dir / "o.csv"],
    lambda s, log: ["map", "build", log, "--survey", s.survey, "--out", s.dir / "o.json"],
    lambda s, log: ["info", log],
]
LOG_COMMAND_IDS = ["localize", "map-build", "info"]


@pytest.mark.parametrize("command", LOG_COMMANDS, ids=LOG_COMMAND_IDS)
def test_text_file_given_as_log(command, small, tmp_path, capsys):
    log = write_text(tmp_path / "notes-not-a-log.mcap", "pose 1 looked fine\n")
    result = run_cli(capsys, *command(small, log))
    line = assert_one_line_error(result, log.name)
    assert "MCAP" in line, f"the error should say the file is not an MCAP log: {line!r}"


# Every command that reads a log, on the hall's map and survey, as a function of the log's path
# and a folder for outputs: each refuses a log that is not one before any work.
HALL_LOG_COMMANDS = {
    "localize": lambda log, out: ["localize", log, "--map", HALL / "map.json",
                                  "--out", out / "est.csv"],
    "map-build": lambda log, out: ["map", "build", log, "--survey", HALL / "survey.csv",
                                   "--out", out / "map.json"],
    "info": lambda log, out: ["info", log],
}  # fmt: skip
CARMEN_LINES = "# CARMEN Logfile\nPARAM robot_frontlaser_offset 0.0 nohost 0\n"


@pytest.mark.parametrize(
    ("name", "converted"),
    [("run.log", "run.mcap"), ("run.log.gz", "run.mcap"), ("run.clf", "run.mcap"),
     ("run.clf.gz", "run.mcap"), ("run.txt", "run.mcap"), ("run.mcap", "run-segloc.mcap")],
)  # fmt: skip
@pytest.mark.parametrize("command", list(HALL_LOG_COMMANDS))
def test_a_carmen_log_given_as_log_names_the_import(name, converted, command, tmp_path, capsys):
    import gzip

    log = tmp_path / name
    lines = (CARMEN_LINES + _flaser([1.0] * 181, (0, 0, 0), (0, 0, 0), 1.0) + "\n").encode()
    log.write_bytes(gzip.compress(lines) if name.endswith(".gz") else lines)
    out = tmp_path / "out"
    out.mkdir()
    result = run_cli(capsys, *HALL_LOG_COMMANDS[command](log, out))
    assert assert_one_line_error(result) == (
        f"segloc: error: {log}: a CARMEN log, not a segloc log; convert it first with "
        f"`segloc import carmen {log} --out {tmp_path / converted}`"
    )
    assert not list(out.iterdir()), "nothing is written"


def test_a_text_file_named_as_a_carmen_log_is_not_taken_for_one(tmp_path, capsys):
    log = write_text(tmp_path / "run.log", "segloc: localizing: 3/10 scans (30%), starting\n")
    result = run_cli(capsys, "info", log)
    line = assert_one_line_error(result, "not an MCAP file")
    assert "CARMEN" not in line


@pytest.mark.parametrize(
    "text",
    [
        '{"hello": "world"}\n',
        "[[0, 0, 1, 1]]\n",
        '{"format": "segloc-map", "version": 1, "segments": "walls"}\n',
        '{"format": "segloc-map", "version": 1, "segments": [[0, 0, "x", 1]]}\n',
        "this is not JSON\n",
        '{"format": "segloc-map", "version": 1, "segments": [[0, 0, 1, 1]\n',
    ],
    ids=["no-format", "bare-list", "segments-not-list", "bad-coordinate", "text", "truncated"],
)
def test_json_that_is_not_a_map(text, small, tmp_path, capsys):
    bad_map = write_text(tmp_path / "not-really-a-map.json", text)
    out = tmp_path / "est.csv"
    result = run_cli(capsys, "localize", small.log, "--map", bad_map, "--out", out)
    assert_one_line_error(result, bad_map.name)
    assert not out.exists(), "no estimates may be written when the map cannot be read"


MAP_AS_POSES_CASES = {
    "localize-initial": (
        lambda out: ["localize", HALL / "log.mcap", "--map", HALL / "map.json",
                     "--initial", HALL / "map.json", "--out", out / "est.csv"],
        "--initial takes odom, the first scan's pose X,Y,THETA_DEG, or a file of guesses: ",
    ),
    "map-build-survey": (
        lambda out: ["map", "build", HALL / "log.mcap", "--survey", HALL / "map.json",
                     "--out", out / "map.json"],
        "--survey takes the surveyed poses of the scans: ",
    ),
    "evaluate-survey": (
        lambda out: ["evaluate", HALL / "survey.csv", "--survey", HALL / "world.json"],
        "--survey takes the surveyed poses: ",
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", list(MAP_AS_POSES_CASES))
def test_a_map_given_for_poses_says_what_the_option_takes(case, tmp_path, capsys):
    command, takes = MAP_AS_POSES_CASES[case]
    result = run_cli(capsys, *command(tmp_path))
    given = "world.json: a segloc world" if case == "evaluate-survey" else "map.json: a segloc map"
    pose_files = "a CSV with the header pose_id,time_s,x_m,y_m,theta_deg, or a TUM trajectory"
    line = assert_one_line_error(result, f"{given}, not a table of poses; {takes}{pose_files}")
    assert line.endswith(pose_files)
    assert not list(tmp_path.iterdir()), "nothing is written"


def _survey_with_bad_value(path: Path) -> Path:
    return write_text(
        path,
        f"{SURVEY_HEADER}\n1,1.0,11.0,1.6,90.0\n2,2.0,ten,3.6,125.0\n3,3.0,8.0,6.5,95.0\n",
    )


def _estimates_with_bad_value(source: Path, path: Path) -> Path:
    lines = source.read_text(encoding="utf-8").splitlines()
    fields = lines[2].split(",")
    fields[ESTIMATE_HEADER.split(",").index("x_m")] = "n/a"
    lines[2] = ",".join(fields)
    return write_text(path, "\n".join(lines) + "\n")


NON_NUMERIC_CASES = {
    "simulate-poses": lambda s, bad: ["simulate", HALL_WORLD, "--poses", bad, "--out", s.dir / "o"],
    "map-build-survey": lambda s, bad: [
        "map", "build", s.log, "--survey", bad, "--out", s.dir / "o.json"
    ],
    "localize-initial": lambda s, bad: [
        "localize", s.log, "--map", s.map, "--out", s.dir / "o.csv", "--initial", bad
    ],
    "evaluate-survey": lambda s, bad: ["evaluate", s.estimates, "--survey", bad],
}  # fmt: skip


@pytest.mark.parametrize("case", list(NON_NUMERIC_CASES))
def test_non_numeric_csv_value_names_file_and_row(case, small, tmp_path, capsys):
    bad = _survey_with_bad_value(tmp_path / f"typo-{case}.csv")
    result = run_cli(capsys, *NON_NUMERIC_CASES[case](small, bad))
    line = assert_one_line_error(result, bad.name, "row 2")
    assert "x_m" in line, f"the error should name the column: {line!r}"


def test_non_numeric_estimate_names_file_and_row(small, tmp_path, capsys):
    bad = _estimates_with_bad_value(small.estimates, tmp_path / "edited-estimates.csv")
    result = run_cli(capsys, "evaluate", bad, "--survey", small.survey)
    assert_one_line_error(result, bad.name, "row 2", "x_m")


def test_estimates_csv_missing_columns(small, tmp_path, capsys):
    bad = write_text(tmp_path / "survey-not-estimates.csv", small.survey.read_text())
    result = run_cli(capsys, "evaluate", bad, "--survey", small.survey)
    assert_one_line_error(result, bad.name)


# --------------------------------------------------------------------------- empty inputs


def test_map_with_no_segments(small, tmp_path, capsys):
    empty = write_text(
        tmp_path / "empty-map.json",
        '{"format":"segloc-map","version":1,"frame":"world","units":"m","segments":[]}\n',
    )
    out = tmp_path / "est.csv"
    result = run_cli(capsys, "localize", small.log, "--map", empty, "--out", out)
    line = assert_one_line_error(result, empty.name)
    assert "segment" in line, f"the error should say the map has no segments: {line!r}"
    assert not out.exists()


@pytest.mark.parametrize("command", LOG_COMMANDS, ids=LOG_COMMAND_IDS)
def test_log_without_scan_topic(command, small, tmp_path, capsys):
    log = write_log_without_scan_topic(tmp_path / "chatter-only.mcap")
    result = run_cli(capsys, *command(small, log))
    line = assert_one_line_error(result, log.name, "/scan")
    assert "/chatter" in line, f"the error should list the topics found: {line!r}"


def _empty_scan(like: Scan, time_s: float, kind: str) -> Scan:
    if kind == "all-zero":
        return Scan(time_s, like.angles_rad.copy(), np.zeros_like(like.ranges_m), like.range_max_m)
    return Scan(time_s, np.zeros(0), np.zeros(0), like.range_max_m)


@pytest.mark.parametrize("kind", ["all-zero", "no-readings"])
def test_scan_without_valid_readings_does_not_stop_the_batch(kind, small, tmp_path, capsys):
    good = read_log(small.log)
    log = tmp_path / "one-good-one-empty.mcap"
    with LogWriter(log, good.sensor) as writer:
        writer.add_scan(good.scans[0])
        writer.add_scan(_empty_scan(good.scans[0], 2.0, kind))
        for t, pose in zip(good.odom_times_s[:2], good.odom_poses[:2], strict=True):
            writer.add_odom(float(t), Pose2(*pose))
    assert len(read_log(log).scans) == 2

    out = tmp_path / "est.csv"
    result = run_cli(capsys, "localize", log, "--map", HALL_WORLD, "--out", out)
    assert result.code == 0, f"exit status {result.code}; stderr: {result.err}"
    assert "Traceback" not in result.err
    header, rows = read_csv_rows(out)
    assert ",".join(header) == ESTIMATE_HEADER
    assert [float(r["time_s"]) for r in rows] == [1.0, 2.0], "one row per scan, in log order"
    assert rows[0]["status"] == "ok", f"the good scan must still localize: {rows[0]}"
    assert rows[1]["status"] not in ("ok", ""), f"the empty scan must get a status: {rows[1]}"
    assert rows[1]["n_local_segments"] == "0"
    assert rows[1]["x_m"] == rows[1]["y_m"] == rows[1]["theta_deg"] == "", (
        f"a scan that could not be localized has no pose: {rows[1]}"
    )

    # The failed row is scored as a failure, and a gate counts it as a violation.
    result = run_cli(capsys, "evaluate", out, "--survey", small.survey, "--format", "json")
    assert result.code == 0, result.err
    table = json.loads(result.out)
    assert table["summary"]["n_poses"] == 2
    assert table["summary"]["n_failed"] == 1
    result = run_cli(capsys, "evaluate", out, "--survey", small.survey, "--fail-above-cm", 50)
    assert result.code == 1, f"a failed pose must fail the gate; stderr: {result.err}"
    assert "pose 2" in result.err and "pose 1" not in result.err, result.err


# --------------------------------------------------------------------------- time matching


def _shifted_survey(source: Path, path: Path, shift_s: float) -> Path:
    header, rows = read_csv_rows(source)
    lines = [",".join(header)]
    for row in rows:
        row["time_s"] = repr(float(row["time_s"]) + shift_s)
        lines.append(",".join(row[c] for c in header))
    return write_text(path, "\n".join(lines) + "\n")


def test_map_build_survey_matching_no_scan(small, tmp_path, capsys):
    shifted = _shifted_survey(small.survey, tmp_path / "shifted-survey.csv", 1000.0)
    out = tmp_path / "map.json"
    result = run_cli(capsys, "map", "build", small.log, "--survey", shifted, "--out", out)
    line = assert_one_line_error(result, shifted.name)
    for t in (1.0, 3.0, 1001.0, 1003.0):
        assert mentions_number(line, t), f"the error should give both time ranges ({t}): {line!r}"
    assert not out.exists()


def test_evaluate_survey_matching_no_estimate(small, tmp_path, capsys):
    shifted = _shifted_survey(small.survey, tmp_path / "shifted-survey.csv", 1000.0)
    result = run_cli(capsys, "evaluate", small.estimates, "--survey", shifted)
    assert "Traceback" not in result.err
    assert result.code == 2, f"exit status {result.code}; stderr: {result.err}"
    lines = result.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("segloc: error:"), result.err
    line = lines[0]
    for t in (1.0, 3.0, 1001.0, 1003.0):
        assert mentions_number(line, t), f"the error should give both time ranges ({t}): {line!r}"
    assert shifted.name in line or small.estimates.name in line, (
        f"the error must name the file at fault (the survey {shifted.name} or the estimates "
        f"{small.estimates.name}), as every other bad-input error does: {line!r}"
    )


# --------------------------------------------------------------------------- option values

BAD_OPTION_CASES = {
    "vote": (
        lambda s, out: ["localize", s.log, "--map", s.map, "--out", out, "--vote", "bogus"],
        "--vote",
    ),
    "readings": (
        lambda s, out: [
            "simulate", HALL_WORLD, "--poses", s.poses, "--out", out, "--readings", "1"
        ],
        "--readings",
    ),
    "init-errors": (
        lambda s, out: [
            "simulate", HALL_WORLD, "--poses", s.poses, "--out", out, "--init-errors", "weird"
        ],
        "--init-errors",
    ),
    "init-errors-negative": (
        lambda s, out: [
            "simulate", HALL_WORLD, "--poses", s.poses, "--out", out,
            "--init-errors", "uniform:-1,20",
        ],
        "--init-errors",
    ),
    "odometry": (
        lambda s, out: [
            "simulate", HALL_WORLD, "--poses", s.poses, "--out", out, "--odometry", "drift:1,2"
        ],
        "--odometry",
    ),
    "odometry-and-init-errors": (
        lambda s, out: [
            "simulate", HALL_WORLD, "--poses", s.poses, "--out", out, "--odometry", "drift",
            "--init-errors", "paper",
        ],
        "--odometry",
    ),
    "format": (
        lambda s, out: [
            "evaluate", s.estimates, "--survey", s.survey, "--out", out, "--format", "xml"
        ],
        "--format",
    ),
    "bin-deg": (
        lambda s, out: ["localize", s.log, "--map", s.map, "--out", out, "--bin-deg", "7"],
        "--bin-deg",
    ),
    "grid-m-negative": (
        lambda s, out: ["localize", s.log, "--map", s.map, "--out", out, "--grid-m", "-0.5"],
        "--grid-m",
    ),
    "grid-m-zero": (
        lambda s, out: ["localize", s.log, "--map", s.map, "--out", out, "--grid-m", "0"],
        "--grid-m",
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD_OPTION_CASES))
def test_bad_option_value(case, small, tmp_path, capsys):
    command, option = BAD_OPTION_CASES[case]
    out = tmp_path / "output-that-must-not-appear"
    result = run_cli(capsys, *command(small, out))
    assert_one_line_error(result, option)
    assert not out.exists(), "a rejected command must not write its output"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["localize", "log.mcap", "--map", "map.json", "--ouput", "x.csv"],
         "no such option --ouput; did you mean --out?"),
        (["localize", "log.mcap", "--ouput=x.csv"], "no such option --ouput; did you mean --out?"),
        (["evaluate", "est.csv", "--survy", "s.csv"],
         "no such option --survy; did you mean --survey?"),
        (["map", "build", "log.mcap", "--min-observaions", "2"],
         "no such option --min-observaions; did you mean --min-observations?"),
        (["import", "carmen", "run.log", "--survey-ot", "ref.csv"],
         "no such option --survey-ot; did you mean --survey-out?"),
        (["localize", "--zzzz"],
         "no such option --zzzz; run 'segloc localize --help' to list them"),
        (["info", "-q"], "no such option -q; run 'segloc info --help' to list them"),
    ],
    ids=["localize", "localize-equals", "evaluate", "map-build", "import-carmen", "far", "short"],
)  # fmt: skip
def test_a_mistyped_option_names_the_closest_one(args, message, capsys):
    result = run_cli(capsys, *args)
    assert assert_one_line_error(result) == f"segloc: error: {message}"


@pytest.mark.parametrize("args", [[], ["map"]], ids=["segloc", "segloc-map"])
def test_missing_command(args, capsys):
    result = run_cli(capsys, *args)
    command = " ".join(["segloc", *args])
    assert "Traceback" not in result.err
    shows_help = result.code == 0 and "Usage:" in result.out and result.err == ""
    one_line = (
        result.code == 2
        and len(result.err.splitlines()) == 1
        and result.err.startswith("segloc: error:")
    )
    assert shows_help or one_line, (
        f"`{command}` must either print its help on stdout and exit 0, or print "
        f"one 'segloc: error:' line and exit 2; got exit {result.code} and stderr:\n{result.err}"
    )


def test_negative_time_in_poses(small, tmp_path, capsys):
    poses = write_text(
        tmp_path / "poses-negative-time.csv", f"{SURVEY_HEADER}\n1,-1.0,11.0,1.6,90.0\n"
    )
    result = run_cli(capsys, "simulate", HALL_WORLD, "--poses", poses, "--out", tmp_path / "o")
    line = assert_one_line_error(result, poses.name, "row 1")
    assert "time_s" in line, line


# --------------------------------------------------------------------------- initial guesses


def test_initial_odom_without_odom(small, tmp_path, capsys):
    good = read_log(small.log)
    log = tmp_path / "scans-only.mcap"
    with LogWriter(log, good.sensor) as writer:
        for scan in good.scans:
            writer.add_scan(scan)
    out = tmp_path / "est.csv"
    result = run_cli(capsys, "localize", log, "--map", small.map, "--out", out)
    # A recorded log without odometry: a global search needs no guess, a file gives them.
    line = assert_one_line_error(result, log.name, "/odom", "--global", "--initial FILE.csv")
    assert "pose_id,time_s,x_m,y_m,theta_deg" in line, f"what a guess file holds: {line!r}"
    assert not out.exists()
    # Tracking needs odometry between scans even when a file seeds the first pose.
    first = write_text(tmp_path / "first.csv", f"{SURVEY_HEADER}\n1,1.0,11.0,1.6,90.0\n")
    for seed in (first, "11,1.6,90"):
        result = run_cli(
            capsys, "localize", log, "--map", small.map, "--out", out, "--track", "--initial", seed
        )
        assert_one_line_error(result, log.name, "/odom", "tracking", "--global")
        assert not out.exists()
    # One pose cannot guess the other scans without odometry to carry it.
    result = run_cli(capsys, "localize", log, "--map", small.map, "--out", out,
                     "--initial", "11,1.6,90")  # fmt: skip
    assert_one_line_error(result, log.name, "no /odom", "--initial X,Y,THETA_DEG", "--global")
    # ... but the first scan alone it can.
    result = run_cli(capsys, "localize", log, "--map", HALL_WORLD, "--out", out,
                     "--initial", "11,1.6,90", "--scans", "1")  # fmt: skip
    assert result.code == 0, result.err
    assert [r["status"] for r in read_csv_rows(out)[1]] == ["ok"]


def test_initial_file_covering_some_scans(small, tmp_path, capsys):
    # Guesses for the first and third scans only, 20 cm and 3° off, with their own ids.
    guesses = write_text(
        tmp_path / "guesses.csv",
        f"{SURVEY_HEADER}\n11,1.0,11.2,1.4,93.0\n13,3.0,8.2,6.3,98.0\n",
    )
    out = tmp_path / "est.csv"
    result = run_cli(
        capsys, "localize", small.log, "--map", HALL_WORLD, "--out", out, "--initial", guesses
    )
    assert result.code == 0, f"exit status {result.code}; stderr: {result.err}"
    assert "Traceback" not in result.err
    _, rows = read_csv_rows(out)
    assert [float(r["time_s"]) for r in rows] == [1.0, 3.0], "only scans with a guess"
    assert [r["pose_id"] for r in rows] == ["11", "13"], "pose_id comes from the guess file"
    assert [float(r["init_x_m"]) for r in rows] == [11.2, 8.2]
    assert all(r["status"] == "ok" for r in rows), rows
    skipped = [ln for ln in result.err.splitlines() if "skipped" in ln]
    assert skipped, f"stderr must report the skipped scans: {result.err!r}"
    assert mentions_number(skipped[0], 1), f"one scan was skipped: {skipped[0]!r}"


def test_initial_file_matching_no_scan(small, tmp_path, capsys):
    guesses = write_text(tmp_path / "late-guesses.csv", f"{SURVEY_HEADER}\n1,500.0,11.0,1.6,90\n")
    out = tmp_path / "est.csv"
    result = run_cli(
        capsys, "localize", small.log, "--map", small.map, "--out", out, "--initial", guesses
    )
    assert_one_line_error(result)
    assert not out.exists()


# --------------------------------------------------------------------------- end to end


@dataclass(frozen=True)
class Pipeline:
    dir: Path
    steps: dict[str, Result]
    log: Path
    survey: Path
    map: Path
    estimates: Path


@pytest.fixture(scope="module")
def hall(tmp_path_factory) -> Pipeline:
    """simulate → map build → localize on the hall, through the installed console script,
    once a session (``made_once``): the tests read its folder and write nothing there."""
    log, survey = Path("sim") / "log.mcap", Path("sim") / "survey.csv"

    def make(root: Path) -> None:
        steps = {
            "simulate": run_script(
                "simulate", HALL_WORLD, "--poses", HALL_POSES, "--out", "sim", "--seed", SEED,
                cwd=root,
            ),
            "map build": run_script(
                "map", "build", log, "--survey", survey, "--out", "map.json", cwd=root
            ),
            "localize": run_script(
                "localize", log, "--map", "map.json", "--out", "est.csv", cwd=root
            ),
        }  # fmt: skip
        (root / "steps.json").write_text(json.dumps(steps), encoding="utf-8")

    root = made_once(tmp_path_factory, "cli-hall", make)
    said = json.loads((root / "steps.json").read_text(encoding="utf-8"))
    steps = {name: Result(*result) for name, result in said.items()}
    return Pipeline(root, steps, root / log, root / survey, root / "map.json", root / "est.csv")


def test_pipeline_steps_succeed(hall):
    for name, result in hall.steps.items():
        assert result.code == 0, f"`segloc {name}` exited {result.code}; stderr:\n{result.err}"
        assert "Traceback" not in result.err, result.err
    for path in (hall.log, hall.survey, hall.map, hall.estimates):
        assert path.is_file(), f"{path} was not written"
    document = json.loads(hall.map.read_text(encoding="utf-8"))
    assert document["format"] == "segloc-map"
    assert len(document["segments"]) >= 4, "a map of the hall needs at least its outer walls"


def test_pipeline_estimates_csv(hall):
    header, rows = read_csv_rows(hall.estimates)
    assert hall.estimates.read_text(encoding="utf-8").splitlines()[0] == ESTIMATE_HEADER
    assert ",".join(header) == ESTIMATE_HEADER
    assert [int(r["pose_id"]) for r in rows] == list(range(1, 11))
    assert [float(r["time_s"]) for r in rows] == [float(i) for i in range(1, 11)]
    assert [r["status"] for r in rows] == ["ok"] * 10


def test_pipeline_evaluate_gate_passes(hall):
    result = run_in_process(
        "evaluate", hall.estimates, "--survey", hall.survey,
        "--fail-above-cm", 2, "--fail-above-deg", 0.3,
        cwd=hall.dir,
    )  # fmt: skip
    assert result.code == 0, f"the hall must pass a 2 cm / 0.3° gate; stderr:\n{result.err}"
    assert "segloc: gate:" not in result.err, result.err
    assert "segloc: PASS: 4 gates held over 10 poses." in result.err.splitlines()
    assert "Traceback" not in result.err
    assert len(md_pose_rows(result.out)) == 10, f"the table lists the 10 poses:\n{result.out}"


def test_pipeline_evaluate_json_has_paper_initial_errors(hall):
    result = run_in_process(
        "evaluate", hall.estimates, "--survey", hall.survey, "--format", "json", cwd=hall.dir
    )
    assert result.code == 0, result.err
    table = json.loads(result.out)
    poses = {p["pose_id"]: p for p in table["poses"]}
    assert sorted(poses) == list(range(1, 11))
    for pose_id, (x_cm, y_cm, theta_deg) in PAPER_INIT_ERRORS.items():
        row = poses[pose_id]
        got = (row["init_x_cm"], row["init_y_cm"], row["init_theta_deg"])
        assert got == pytest.approx((x_cm, y_cm, theta_deg), abs=0.01), (
            f"pose {pose_id}: initial errors {got} differ from the paper's Table 1 "
            f"{(x_cm, y_cm, theta_deg)}"
        )
        assert row["status"] == "ok"
    assert table["summary"]["n_poses"] == 10
    assert table["summary"]["n_failed"] == 0


def test_pipeline_evaluate_gate_fails(hall):
    result = run_in_process(
        "evaluate", hall.estimates, "--survey", hall.survey, "--fail-above-cm", 0.001, cwd=hall.dir
    )
    assert result.code == 1, f"a 0.001 cm gate must fail; exit {result.code}, stderr:\n{result.err}"
    assert "Traceback" not in result.err
    # The verdict in a line, then one naming the first violations and counting the rest (the
    # table shows them all).
    verdict, line = [ln for ln in result.err.splitlines() if "paired within" not in ln]
    assert verdict.startswith("segloc: FAIL: 2 of 3 gates failed (max |X|, |Y| ≤ 0.001 cm; ")
    assert line.startswith("segloc: gate: pose ") and re.search(r"; and \d+ more$", line), line
    assert re.search(r"\bpose (10|[1-9])\b", result.err), (
        f"stderr must name a pose that exceeds the limit: {result.err!r}"
    )
    assert len(md_pose_rows(result.out)) == 10, f"the table is still printed:\n{result.out}"


def test_gate_message_shows_the_limit_given(hall):
    result = run_in_process(
        "evaluate", hall.estimates, "--survey", hall.survey, "--fail-above-cm", 0.001, cwd=hall.dir
    )
    assert result.code == 1
    violations = [ln for ln in result.err.splitlines() if ln.startswith("segloc: gate")]
    assert violations, result.err
    for line in violations:
        assert mentions_number(line, 0.001), (
            f"a violation must show the limit the user gave (0.001 cm), not a rounded one: {line!r}"
        )


def test_info_counts_scans(hall):
    result = run_in_process("info", hall.log, cwd=hall.dir)
    assert result.code == 0, result.err
    scan_lines = [ln for ln in result.out.splitlines() if ln.startswith("/scan")]
    assert len(scan_lines) == 1, result.out
    assert re.search(r"\b10 scans\b", scan_lines[0]), scan_lines[0]
    assert re.search(r"\b1024 readings\b", scan_lines[0]), scan_lines[0]


def test_info_shows_how_long_a_log_lasts(hall, tmp_path, capsys):
    result = run_cli(capsys, "info", hall.log)
    assert result.code == 0, result.err
    # Nine seconds from 1 s on: the seconds say it all.
    assert (
        "length:    9.000 s from the first scan at 1.000 s (--start and --end count seconds "
        "from it)"
    ) in result.out.splitlines(), result.out
    # A log on Unix times (a recording, an imported bag): its length and its dates, in UTC.
    scans = read_log(hall.log).scans
    start = 1_134_962_360.5  # 2005-12-19 03:19:20.5 UTC
    recorded = tmp_path / "recorded.mcap"
    with LogWriter(recorded, {"range_max_m": "30"}) as writer:
        for k, seconds in enumerate((0.0, 15.0, 1783.0)):
            scan = scans[k]
            writer.add_scan(Scan(start + seconds, scan.angles_rad, scan.ranges_m, 30.0))
    result = run_cli(capsys, "info", recorded)
    assert result.code == 0, result.err
    lines = result.out.splitlines()
    assert (
        "length:    1783.000 s from the first scan at 1134962360.500 s (--start and --end count "
        "seconds from it); 29 min 43 s, 2005-12-19 03:19:20 to 03:49:03 UTC"
    ) in lines, result.out
    assert any(line.startswith("/scan:     3 scans, ") for line in lines), result.out


HELP_CASES = {
    "simulate": [
        "--poses",
        "--out",
        "--readings",
        "--fov-deg",
        "--noise-cm",
        "--no-clutter",
        "--no-glass",
        "--material",
        "--seed",
        "--init-errors",
        "WORLD_OR_MAP.json",
    ],
    "map build": ["--survey", "--out", "--tolerance-ms", "LOG.mcap"],
    "localize": ["--map", "--out", "--initial", "--vote", "--bin-deg", "--grid-m", "LOG.mcap"],
    "evaluate": [
        "--survey",
        "--format",
        "--fail-above-cm",
        "--fail-above-deg",
        "EST",
        "--topic",
        "--junit",
        "--baseline",
        "--html",
    ],
    "info": ["LOG.mcap"],
    "map": ["build"],
    "record": [
        "--device",
        "PROTOCOL:PORT",
        "--out",
        "--scans",
        "--duration",
        "--readings",
        "--rev-per-s",
        "--baud",
        "--stall-timeout",
    ],
    "emulate": ["--device", "--world", "--pose", "--path", "--faults", "--fault-after"],
}


@pytest.mark.parametrize("command", list(HELP_CASES))
def test_help(command, tmp_path):
    result = run_in_process(*command.split(), "--help", cwd=tmp_path)
    assert result.code == 0, f"`segloc {command} --help` exited {result.code}: {result.err}"
    assert result.err == "", result.err
    assert result.out.startswith(f"Usage: segloc {command}"), result.out[:200]
    for option in HELP_CASES[command]:
        assert option in result.out, f"`segloc {command} --help` does not mention {option}"


# --------------------------------------------------------------------------- interruption


def test_interrupted_localize_keeps_the_scans_already_done(small, tmp_path, capsys, monkeypatch):
    """Ctrl-C during the third scan: the first two estimates are written, exit status 130."""
    from segloc_cli.method.localize import Localizer

    real_localize = Localizer.localize
    calls = {"n": 0}

    def localize_then_interrupt(self, segments_robot, initial, points_robot=None):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real_localize(self, segments_robot, initial, points_robot)

    monkeypatch.setattr(Localizer, "localize", localize_then_interrupt)
    out = tmp_path / "partial.csv"
    result = run_cli(capsys, "localize", small.log, "--map", HALL_WORLD, "--out", out)
    assert result.code == 130
    assert result.err.strip().splitlines() == [
        f"segloc: {small.log}: each scan alone (the log's /odom holds simulated initial "
        "guesses, not odometry)",
        f"segloc: interrupted (Ctrl-C) after 2 of 3 scans; their estimates are in {out}",
    ]
    header, rows = read_csv_rows(out)
    assert ",".join(header) == ESTIMATE_HEADER
    assert [r["pose_id"] for r in rows] == ["1", "2"]
    assert all(r["status"] == "ok" for r in rows)


# --------------------------------------------------------------------------- relations


def _estimates_csv(path: Path, poses: list[tuple[float, float, float, float]], status="ok"):
    """An estimates file holding (time_s, x_m, y_m, theta_deg) rows."""
    lines = [ESTIMATE_HEADER]
    for k, (t, x, y, th) in enumerate(poses, 1):
        lines.append(
            f"{k},{t},{x},{y},{th},{th},{x},{y},{th},{x},{y},{th},1.0,0.9,,,,0.0,10,1.0,0.99,{status},1"
        )
    return write_text(path, "\n".join(lines) + "\n")


def test_evaluate_relations_scores_relative_motion(tmp_path, capsys):
    # Estimates at t = 0, 1, 2 along x, heading 90° (so the robot moves sideways, to its right).
    est = _estimates_csv(tmp_path / "est.csv", [(0, 0, 0, 90), (1, 1, 0, 90), (2, 2, 0, 90)])
    # Reference motions in the frame of the pose at t1: 1 m to the right is (0, −1).
    # The second relation claims (0, −1.1): 0.1 m off; the third (t = 5) has no estimate.
    rel = write_text(
        tmp_path / "ref.relations",
        "# t1 t2 dx dy dz droll dpitch dyaw\n"
        "0 1 0 -1 0 0 0 0\n"
        "1 2 0 -1.1 0 0 0 0\n"
        "2 5 0 -1 0 0 0 0\n",
    )
    result = run_cli(capsys, "evaluate", est, "--relations", rel, "--format", "json")
    assert result.code == 0, result.err
    summary = json.loads(result.out)["summary"]
    assert (summary["used"], summary["skipped"]) == (2, 1)
    assert summary["trans_m"]["mean"] == pytest.approx(0.05, abs=1e-12)
    assert summary["rot_deg"]["mean"] == pytest.approx(0.0, abs=1e-12)


def test_the_relations_table_names_the_estimates_file(tmp_path, capsys):
    est = _estimates_csv(tmp_path / "run-7.csv", [(0, 0, 0, 90), (1, 1, 0, 90), (2, 2, 0, 90)])
    rel = write_text(tmp_path / "ref.relations", "0 1 0 -1 0 0 0 0\n1 2 0 -1.1 0 0 0 0\n")
    rows = {}
    for fmt in ("md", "csv", "json"):
        result = run_cli(capsys, "evaluate", est, "--relations", rel, "--format", fmt)
        assert result.code == 0, result.err
        rows[fmt] = result.out
    assert rows["md"].splitlines()[2].startswith("| run-7.csv | 2 | 0 |"), rows["md"]
    assert rows["csv"].splitlines()[1].startswith("run-7.csv,2,0,"), rows["csv"]
    assert json.loads(rows["json"])["trajectory"] == "run-7.csv"


def test_published_rows_say_where_they_are_not_like_for_like(tmp_path, capsys):
    """Beside a dataset whose maps segloc builds from its SLAM-corrected log, estimates
    localized in a map built at given poses (their run file names it) get a line under the
    table saying they are not like for like with the published ones; estimates localized in
    a map segment SLAM built from the log, or with no segloc map known, and a dataset with
    no such log, get none."""
    from segloc_cli.io.maps import write_map

    est = _estimates_csv(tmp_path / "est.csv", [(0, 0, 0, 90), (1, 1, 0, 90), (2, 2, 0, 90)])
    rel = write_text(tmp_path / "ref.relations", "0 1 0 -1 0 0 0 0\n1 2 0 -1.1 0 0 0 0\n")
    wall = np.array([[0.0, 0.0, 1.0, 0.0]])
    write_map(tmp_path / "surveyed.json", wall, {"log": "x.mcap", "survey": "ref.csv"})
    write_map(tmp_path / "slam.json", wall, {"log": "x.mcap", "poses": "segment SLAM"})

    def caveats(dataset, map_name):
        run_file = tmp_path / "est.run.toml"
        run_file.unlink(missing_ok=True)
        if map_name:
            write_text(run_file, f'[localize]\nmap = "{map_name}"\n')
        shown = run_cli(capsys, "evaluate", est, "--relations", rel, "--published", dataset)
        assert shown.code == 0, shown.err
        rows, note = shown.out.split("\n\n", 1)
        assert "GraphMapping (published)" in rows.splitlines()[-1]
        as_json = run_cli(capsys, "evaluate", est, "--relations", rel, "--published", dataset,
                          "--format", "json")  # fmt: skip
        lines = [line for line in note.splitlines() if line.startswith("Not like for like")]
        assert json.loads(as_json.out).get("published_note") == (lines[0] if lines else None)
        return lines

    for dataset in ("intel", "fr079"):
        (line,) = caveats(dataset, "surveyed.json")
        assert f"built from {dataset}'s SLAM-corrected log ({dataset}-corrected.log.gz)" in line
        assert caveats(dataset, "slam.json") == caveats(dataset, None) == []
    assert caveats("mit-killian-court", "surveyed.json") == []
    plain = run_cli(capsys, "evaluate", est, "--relations", rel)
    assert "like for like" not in plain.out


def test_evaluate_needs_exactly_one_reference(small, capsys):
    for extra in ([], ["--survey", small.survey, "--relations", small.survey]):
        result = run_cli(capsys, "evaluate", small.estimates, *extra)
        assert_one_line_error(result, "--survey", "--relations")


def test_evaluate_relations_that_match_no_estimate(tmp_path, capsys):
    est = _estimates_csv(tmp_path / "est.csv", [(0, 0, 0, 0), (1, 1, 0, 0)])
    rel = write_text(tmp_path / "late.relations", "100 101 1 0 0 0 0 0\n")
    result = run_cli(capsys, "evaluate", est, "--relations", rel)
    assert_one_line_error(result, "late.relations", "no relation")


# --------------------------------------------------------------------------- import


def _flaser(ranges, pose, odom, t):
    values = " ".join(f"{r:g}" for r in ranges)
    return (
        f"FLASER {len(ranges)} {values} {pose[0]} {pose[1]} {pose[2]} "
        f"{odom[0]} {odom[1]} {odom[2]} {t} host {t}"
    )


def test_import_carmen_writes_scans_odometry_and_reference(tmp_path, capsys):
    lines = [
        "# a tiny log",
        "PARAM robot_frontlaser_offset 0.0 nohost 0",
        _flaser([1.0, 2.0, 81.83, 3.0, 81.83], (1.0, 2.0, 0.5), (0.1, 0.2, 0.3), 10.0),
        "FLASER 5 1 2 3",  # truncated: skipped, counted
        _flaser([4.0, 81.83, 5.0, 6.0, 7.0], (1.5, 2.5, -0.5), (0.6, 0.7, -0.3), 10.5),
    ]
    log_in = write_text(tmp_path / "tiny.log", "\n".join(lines) + "\n")
    out, ref = tmp_path / "tiny.mcap", tmp_path / "ref.csv"
    result = run_cli(
        capsys,
        "import",
        "carmen",
        log_in,
        "--out",
        out,
        "--survey-out",
        ref,
        "--range-max-m",
        81.83,
    )
    assert result.code == 0, result.err
    assert "skipped 1" in result.err and "line 4" in result.err
    log = read_log(out)
    assert [s.time_s for s in log.scans] == [10.0, 10.5]
    np.testing.assert_allclose(
        log.scans[0].angles_rad, np.deg2rad([-90, -45, 0, 45, 90]), atol=1e-12
    )
    assert log.scans[0].valid.tolist() == [True, True, False, True, False]
    np.testing.assert_allclose(log.odom_poses, [[0.1, 0.2, 0.3], [0.6, 0.7, -0.3]], atol=1e-12)
    header, rows = read_csv_rows(ref)
    assert header == ["pose_id", "time_s", "x_m", "y_m", "theta_deg", "original_time_s"]
    assert [float(rows[1][k]) for k in ("time_s", "x_m", "y_m")] == [10.5, 1.5, 2.5]
    assert [float(r["original_time_s"]) for r in rows] == [10.0, 10.5]  # no time collided
    assert float(rows[1]["theta_deg"]) == pytest.approx(np.rad2deg(-0.5), abs=0.5e-6)  # 1e-6°


def test_import_carmen_writes_the_reference_as_tum_for_a_tum_name(tmp_path, capsys):
    """--survey-out REF.tum gives the TUM trajectory evo reads, the same poses as the CSV."""
    lines = [
        _flaser([1.0, 2.0, 3.0], (1.0, 2.0, 0.5), (0.1, 0.2, 0.3), 10.0),
        _flaser([4.0, 5.0, 6.0], (1.5, 2.5, -0.5), (0.6, 0.7, -0.3), 10.5),
    ]
    log_in = write_text(tmp_path / "tiny.log", "\n".join(lines) + "\n")
    for name in ("ref.csv", "ref.tum"):
        args = ["import", "carmen", log_in, "--out", tmp_path / f"{name}.mcap", "--survey-out"]
        assert run_cli(capsys, *args, tmp_path / name).code == 0
    tum, csv_table = read_pose_table(tmp_path / "ref.tum"), read_pose_table(tmp_path / "ref.csv")
    first = (tmp_path / "ref.tum").read_text().splitlines()[1].split()
    assert first[:4] == ["10.0", "1.0", "2.0", "0.0"]  # t x y z
    np.testing.assert_array_equal(tum.time_s, csv_table.time_s)
    np.testing.assert_array_equal(tum.poses[:, :2], csv_table.poses[:, :2])
    # Headings to 1e-6° in the CSV, through a quaternion to 1e-9 in the TUM file.
    np.testing.assert_allclose(tum.poses[:, 2], csv_table.poses[:, 2], rtol=0, atol=2e-8)


def test_import_bad_inputs_are_one_line(tmp_path, capsys):
    empty = write_text(tmp_path / "nolaser.log", "ODOM 0 0 0 0 0 0 1.0 host 1.0\n")
    result = run_cli(capsys, "import", "carmen", empty, "--out", tmp_path / "a.mcap")
    assert_one_line_error(result, "nolaser.log", "FLASER")
    result = run_cli(
        capsys, "import", "rosbag", tmp_path / "gone.bag", "--out", tmp_path / "b.mcap"
    )
    assert_one_line_error(result, "gone.bag")
    assert not (tmp_path / "b.mcap").exists()


def test_refinement_polishes_the_stage2_pose_and_no_refine_stops_there(small, tmp_path, capsys):
    plain = tmp_path / "stage2.csv"
    assert (
        run_cli(
            capsys, "localize", small.log, "--map", HALL_WORLD, "--no-refine", "--out", plain
        ).code
        == 0
    )
    _, stage2_rows = read_csv_rows(plain)
    _, refined_rows = read_csv_rows(small.estimates)
    _, survey = read_csv_rows(small.survey)
    assert len(stage2_rows) == len(refined_rows) == len(survey) == 3
    for stage2, refined, truth in zip(stage2_rows, refined_rows, survey, strict=True):
        # Without refinement the final pose is the stage-2 pose, its verdict from the share of
        # the scan's points on the map there.
        assert (stage2["x_m"], stage2["y_m"]) == (stage2["stage2_x_m"], stage2["stage2_y_m"])
        assert float(stage2["inlier_ratio"]) > 0.5 and stage2["status"] == "ok"
        # With it, stage 2 ends at the same pose and the fit moves on from there.
        assert float(refined["stage2_x_m"]) == pytest.approx(float(stage2["x_m"]), abs=1e-9)
        assert float(refined["inlier_ratio"]) > 0.8
        assert stage2["pose_id"] == refined["pose_id"] == truth["pose_id"]
        miss = np.hypot(
            float(refined["x_m"]) - float(truth["x_m"]), float(refined["y_m"]) - float(truth["y_m"])
        )
        assert miss < 0.005


def test_global_localizes_every_scan_without_a_guess(small, tmp_path, capsys):
    out = tmp_path / "global.csv"
    result = run_cli(capsys, "localize", small.log, "--map", HALL_WORLD, "--global", "--out", out)
    assert result.code == 0, result.err
    _, rows = read_csv_rows(out)
    _, survey = read_csv_rows(small.survey)
    assert [r["pose_id"] for r in rows] == [t["pose_id"] for t in survey]
    for row, truth in zip(rows, survey, strict=True):
        assert row["init_x_m"] == row["init_theta_deg"] == ""
        assert row["status"] == "ok"
        miss = np.hypot(
            float(row["x_m"]) - float(truth["x_m"]), float(row["y_m"]) - float(truth["y_m"])
        )
        assert miss < 0.005
        assert float(row["runner_up_ratio"]) < float(row["inlier_ratio"]) - 0.1


def test_global_in_a_region_finds_the_scans_inside_it_and_says_how_long(small, tmp_path, capsys):
    """--region limits the search to a rectangle: the scans of the survey inside it are
    found as well as by a search of the whole map, and the run tells the time per scan."""
    _, survey = read_csv_rows(small.survey)
    xs, ys = [float(t["x_m"]) for t in survey], [float(t["y_m"]) for t in survey]
    region = f"{min(xs) - 1:g},{min(ys) - 1:g},{max(xs) + 1:g},{max(ys) + 1:g}"
    out = tmp_path / "region.csv"
    args = ["localize", small.log, "--map", HALL_WORLD, "--global", "--region", region]
    result = run_cli(capsys, *args, "--out", out)
    assert result.code == 0, result.err
    assert re.search(r"global search: about [0-9.]+ s per scan, 3 scans", result.err)
    _, rows = read_csv_rows(out)
    for row, truth in zip(rows, survey, strict=True):
        assert row["status"] == "ok"
        miss = np.hypot(
            float(row["x_m"]) - float(truth["x_m"]), float(row["y_m"]) - float(truth["y_m"])
        )
        assert miss < 0.005


@pytest.mark.parametrize(
    ("region", "fragments"),
    [
        ("0,0,1", ["--region", "X0,Y0,X1,Y1"]),
        ("5,0,1,4", ["--region", "X0 < X1"]),
        ("0,0,nan,4", ["--region"]),
        ("500,500,510,510", ["does not meet the map"]),
        ("0,0,600,600", ["--region", "600 m × 600 m", "250,000"]),
    ],
)
def test_bad_region_is_one_line(region, fragments, small, tmp_path, capsys):
    out = tmp_path / "region.csv"
    args = ["localize", small.log, "--map", HALL_WORLD, "--global", "--region", region]
    assert_one_line_error(run_cli(capsys, *args, "--out", out), *fragments)
    assert not out.exists()


def test_region_needs_global(small, tmp_path, capsys):
    args = ["localize", small.log, "--map", HALL_WORLD, "--region", "0,0,5,5"]
    assert_one_line_error(run_cli(capsys, *args, "--out", tmp_path / "e.csv"), "--global")


@pytest.mark.parametrize("other", ["--track", "--no-refine"])
def test_global_refuses_track_and_no_refine(small, tmp_path, capsys, other):
    out = tmp_path / "global.csv"
    result = run_cli(
        capsys, "localize", small.log, "--map", HALL_WORLD, "--global", other, "--out", out
    )
    assert result.code == 2
    assert "--global cannot be combined with " + other in result.err
    assert "Traceback" not in result.err
    assert not out.exists()


def _required_options():
    """(command path, option, the other required options' arguments) for every required
    option of every command: a value for each other required option (a choice's first
    choice, else a file name) and one for each required argument."""
    import click

    from segloc_cli.cli import cli

    def commands(command, path=()):
        if isinstance(command, click.Group):
            for name, sub in sorted(command.commands.items()):
                yield from commands(sub, (*path, name))
        else:
            yield path, command

    for path, command in commands(cli):
        required = [p for p in command.params if isinstance(p, click.Option) and p.required]
        arguments = [p for p in command.params if isinstance(p, click.Argument) and p.required]
        for option in required:
            given = ["x.mcap"] * len(arguments)
            for other in required:
                if other is not option:
                    choices = getattr(other.type, "choices", None)
                    given += [other.opts[0], choices[0] if choices else "x.csv"]
            yield pytest.param(path, option.opts[0], given, id=f"{' '.join(path)} {option.opts[0]}")


@pytest.mark.parametrize(("path", "option", "given"), list(_required_options()))
def test_a_required_option_left_out_is_named(capsys, tmp_path, monkeypatch, path, option, given):
    """Left out, a required option is one line naming it and exit status 2, not an internal
    error once the command runs without it."""
    monkeypatch.chdir(tmp_path)
    result = run_cli(capsys, *path, *given)
    assert result.code == 2, result
    (line,) = result.err.splitlines()  # a choice's line goes on to list the choices
    assert line.startswith(f"segloc: error: Missing option '{option}'.")


def _commands(group, names=()):
    """(names, command) of every command under ``group``."""
    import click

    for name, command in group.commands.items():
        if isinstance(command, click.Group):
            yield from _commands(command, (*names, name))
        else:
            yield (*names, name), command


def test_every_file_option_and_argument_refuses_an_empty_path():
    """An empty value is no file: Path('') is the current folder, which commands would read
    as a folder of inputs or fail to name an output after (an internal error)."""
    import click

    from segloc_cli.cli import cli
    from segloc_cli.commands.options import holds_path

    checked = []
    for names, command in _commands(cli):
        ctx = click.Context(command, info_name=names[-1])
        for param in command.params:
            if holds_path(param):
                with pytest.raises(click.BadParameter, match="an empty"):
                    param.type.convert("", param, ctx)
                checked.append((names, param.name))
    assert {("localize", "initial"), ("sweep", "convergence"), ("evaluate", "estimates_path")} <= {
        (names[-1], name) for names, name in checked
    }


@pytest.mark.parametrize(
    ("args", "fragments"),
    [
        (["localize", HALL / "log.mcap", "--map", HALL / "map.json", "--out", ""],
         ["'--out'", "an empty path"]),
        (["localize", HALL / "log.mcap", "--map", HALL / "map.json", "--out", "{tmp}/e.csv",
          "--initial", ""],
         ["'--initial'", "an empty value", "odom"]),
        (["sweep", HALL.parents[1] / "sweep.toml", "--out", "{tmp}/s.parquet",
          "--convergence", ""],
         ["'--convergence'", "an empty path"]),
        (["map", "export", HALL / "map.json", "--out", "{tmp}/m.yaml", "--resolution", "nan"],
         ["'--resolution'", "not a finite number"]),
        (["map", "export", HALL / "map.json", "--out", "{tmp}/m.yaml", "--resolution", "inf"],
         ["'--resolution'", "not a finite number"]),
    ],
    ids=["out", "initial", "convergence", "resolution-nan", "resolution-inf"],
)  # fmt: skip
def test_an_empty_path_or_a_number_that_is_none_is_one_line_naming_the_option(
    capsys, tmp_path, args, fragments
):
    args = [str(a).replace("{tmp}", str(tmp_path)) for a in args]
    result = run_cli(capsys, *args)
    assert_one_line_error(result, *fragments)
    assert not list(tmp_path.iterdir())
