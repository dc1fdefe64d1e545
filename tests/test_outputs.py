"""Outputs survive: whole files appear at once or not at all, existing files are kept unless
``--force``, the output's folder is checked before any work, and ``localize`` keeps every
finished row when it is stopped or killed."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from conftest import HALL, SEGLOC
from test_cli import ESTIMATE_HEADER, assert_one_line_error, run_cli
from test_foxglove import messages_before_the_cut, validated_messages

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2
from segloc_cli.io.files import OutputError, atomic_path, atomic_write, check_output
from segloc_cli.io.mcap_log import read_log, write_log
from segloc_cli.scan import Scan

LOG = HALL / "log.mcap"
SURVEY = HALL / "survey.csv"
MAP = HALL / "map.json"


# --------------------------------------------------------------------------- io.files


def test_atomic_write_replaces_the_file_only_when_complete(tmp_path):
    target = tmp_path / "table.csv"
    target.write_text("old\n", encoding="utf-8")
    with pytest.raises(RuntimeError), atomic_write(target) as stream:
        stream.write("half a ")
        raise RuntimeError("killed mid-write")
    assert target.read_text(encoding="utf-8") == "old\n"
    with atomic_write(target) as stream:
        stream.write("new\n")
    assert target.read_text(encoding="utf-8") == "new\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.csv"], "temporary file left"


def test_a_failed_write_names_the_file_and_leaves_no_fragment(tmp_path):
    target = tmp_path / "map.json"
    target.write_text("{}\n", encoding="utf-8")
    with pytest.raises(OutputError) as caught, atomic_path(target) as partial:
        partial.write_text('{"segm', encoding="utf-8")
        raise OSError(27, "File too large")
    assert str(caught.value) == f"{target}: cannot write file (File too large)"
    assert target.read_text(encoding="utf-8") == "{}\n"
    assert [p.name for p in tmp_path.iterdir()] == ["map.json"]


def test_check_output_refuses_before_any_work(tmp_path):
    existing = tmp_path / "est.csv"
    existing.write_text("x\n", encoding="utf-8")
    with pytest.raises(InputError, match="file exists; choose another --out or pass --force"):
        check_output(existing, force=False)
    assert check_output(existing, force=True) == existing
    with pytest.raises(InputError, match=r"folder .*missing-dir does not exist"):
        check_output(tmp_path / "missing-dir" / "est.csv", force=False)
    with pytest.raises(InputError, match="is a directory"):
        check_output(tmp_path, force=True)


# --------------------------------------------------------------------------- --force


@pytest.mark.parametrize(
    "command",
    [
        ["map", "build", LOG, "--survey", SURVEY],
        ["localize", LOG, "--map", MAP, "--no-refine"],
        ["simulate", HALL / "world.json", "--poses", HALL / "poses.csv"],
    ],
    ids=["map-build", "localize", "simulate"],
)
def test_an_existing_output_is_kept_without_force(capsys, tmp_path, command):
    if command[0] == "simulate":
        out = tmp_path / "sim"
        out.mkdir()
        kept = out / "survey.csv"
    else:
        out = kept = tmp_path / "existing.out"
    kept.write_text("precious\n", encoding="utf-8")
    result = run_cli(capsys, *command, "--out", out)
    assert_one_line_error(result, str(kept), "file exists", "--force")
    assert kept.read_text(encoding="utf-8") == "precious\n"
    forced = run_cli(capsys, *command, "--out", out, "--force")
    assert forced.code == 0, forced.err
    assert kept.read_text(encoding="utf-8") != "precious\n"


def test_import_refuses_an_existing_survey_out_before_reading(capsys, tmp_path):
    survey_out = tmp_path / "ref.csv"
    survey_out.write_text("precious\n", encoding="utf-8")
    result = run_cli(
        capsys,
        "import",
        "carmen",
        tmp_path / "no-such-log.gz",
        "--out",
        tmp_path / "log.mcap",
        "--survey-out",
        survey_out,
    )
    # The output is checked first: the missing input is not even opened.
    assert_one_line_error(result, str(survey_out), "--survey-out", "--force")
    assert not (tmp_path / "log.mcap").exists()


def test_a_missing_output_folder_is_named_before_localizing(capsys, tmp_path):
    out = tmp_path / "no-such-folder" / "est.csv"
    result = run_cli(capsys, "localize", LOG, "--map", tmp_path / "not-read.json", "--out", out)
    assert_one_line_error(result, str(out), "folder", "does not exist")


# --------------------------------------------------------------------------- last resort


def test_an_unexpected_error_is_one_line_with_its_traceback_kept(capsys, monkeypatch, tmp_path):
    import segloc_cli.io.maps

    def broken(*_args, **_kwargs):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(segloc_cli.io.maps, "read_map", broken)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)
    result = run_cli(capsys, "localize", LOG, "--map", MAP, "--out", tmp_path / "est.csv")
    assert result.code == 70
    lines = result.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("segloc: internal error: ZeroDivisionError")
    kept = [p for p in tmp_path.iterdir() if p.name.startswith("segloc-error-")]
    assert len(kept) == 1 and str(kept[0]) in lines[0]
    assert "Traceback" in kept[0].read_text(encoding="utf-8")
    assert "Traceback" not in result.err


def test_too_deep_input_is_one_line_exit_2(capsys, monkeypatch, tmp_path):
    import segloc_cli.io.maps

    def deep(*_args, **_kwargs):
        raise RecursionError("maximum recursion depth exceeded")

    monkeypatch.setattr(segloc_cli.io.maps, "read_map", deep)
    result = run_cli(capsys, "localize", LOG, "--map", MAP, "--out", tmp_path / "est.csv")
    assert_one_line_error(result, "too large or too deeply nested")


# --------------------------------------------------------------------------- streamed rows


def write_long_log(path: Path, copies: int) -> Path:
    """The hall's scans repeated ``copies`` times at distinct times, with their guesses."""
    hall = read_log(LOG)
    period_s = hall.scan_times_s.max() + 1.0
    scans, odometry = [], []
    for k in range(copies):
        for scan, t, pose in zip(hall.scans, hall.odom_times_s, hall.odom_poses, strict=True):
            shift = k * period_s
            scans.append(
                Scan(scan.time_s + shift, scan.angles_rad, scan.ranges_m, scan.range_max_m)
            )
            odometry.append((t + shift, Pose2(*pose)))
    write_log(path, scans, odometry, hall.sensor)
    return path


def _rows_when(path: Path, n: int, proc: subprocess.Popen, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, "localize ended before it could be stopped"
        if path.exists() and len(path.read_text(encoding="utf-8").splitlines()) > n:
            return
        time.sleep(0.05)
    pytest.fail(f"fewer than {n} rows after {timeout_s} s")


def _complete_rows(path: Path) -> list[dict]:
    text = path.read_text(encoding="utf-8")
    assert text.endswith("\n"), "the last row is cut"
    lines = text.splitlines()
    assert lines[0] == ESTIMATE_HEADER
    rows = list(csv.DictReader(lines))
    for row in rows:
        assert None not in row.values() and row["status"], f"incomplete row {row}"
    return rows


@pytest.mark.parametrize("how", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_a_stopped_localize_keeps_every_finished_row(tmp_path, how):
    log = tmp_path / "long.mcap"
    write_long_log(log, copies=60)
    out, view = tmp_path / "est.csv", tmp_path / "run.mcap"
    argv = ["localize", log, "--map", MAP, "--out", out, "--mcap", view]
    proc = subprocess.Popen(
        [str(SEGLOC), *map(str, argv)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONIOENCODING": "utf-8"},
    )
    try:
        _rows_when(out, 5, proc)
        proc.send_signal(how)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    rows = _complete_rows(out)
    assert 5 <= len(rows) < 600
    if how == signal.SIGTERM:
        assert proc.returncode == 130
        assert f"interrupted (SIGTERM) after {len(rows)} of 600 scans" in err
        assert "Traceback" not in err
        shown = validated_messages(view)  # the run view is finished, with every row's scan
        assert len(shown["/scan"]) == len(shown["/status"]) == len(rows)
    else:
        assert proc.returncode == -signal.SIGKILL
        # The view is streamed too: readable up to its last chunk, of whole scans.
        shown = messages_before_the_cut(view)
        assert 1 <= len(shown["/scan"]) == len(shown["/status"]) <= len(rows) + 1
        assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


# --------------------------------------------------------------------------- inputs kept


@pytest.mark.parametrize(
    ("command", "fragment"),
    [
        (["localize", LOG, "--map", MAP, "--out", LOG], "is an input of this command"),
        (["localize", LOG, "--map", MAP, "--out", MAP], "is an input of this command"),
        (["map", "build", LOG, "--survey", SURVEY, "--out", SURVEY], "is an input"),
        (["evaluate", SURVEY, "--survey", SURVEY, "--out", SURVEY], "is an input"),
    ],
    ids=["localize-log", "localize-map", "map-build-survey", "evaluate-survey"],
)
def test_force_never_overwrites_an_input(capsys, tmp_path, command, fragment):
    before = {p: p.read_bytes() for p in (LOG, MAP, SURVEY)}
    result = run_cli(capsys, *command, "--force")
    assert_one_line_error(result, fragment)
    assert {p: p.read_bytes() for p in before} == before


@pytest.mark.parametrize(
    ("command", "table"),
    [
        (["localize", LOG], f'[localize]\nmap = "{MAP}"\n'),
        (["map", "build", LOG], f'[map.build]\nsurvey = "{SURVEY}"\n'),
        (["evaluate", SURVEY], f'[evaluate]\nsurvey = "{SURVEY}"\n'),
    ],
    ids=["localize", "map-build", "evaluate"],
)
def test_force_never_overwrites_the_config_file_read(capsys, tmp_path, command, table):
    config = tmp_path / "options.toml"
    config.write_text(table, encoding="utf-8")
    before = config.read_bytes()
    result = run_cli(capsys, *command, "--config", config, "--out", config, "--force")
    assert_one_line_error(result, "options.toml", "is an input of this command", "--out")
    assert config.read_bytes() == before


def test_an_input_reached_through_a_link_is_kept(capsys, tmp_path):
    log = tmp_path / "log.mcap"
    log.write_bytes(LOG.read_bytes())
    link = tmp_path / "est.csv"
    link.symlink_to(log)
    result = run_cli(capsys, "localize", log, "--map", MAP, "--out", link, "--force")
    assert_one_line_error(result, str(log), "is an input")
    assert log.read_bytes() == LOG.read_bytes()


def test_two_outputs_naming_one_file_are_refused(capsys, tmp_path):
    out = tmp_path / "est.csv"
    result = run_cli(capsys, "localize", LOG, "--map", MAP, "--out", out, "--tum", out)
    assert_one_line_error(result, "--out and --tum name the same file")
    assert not out.exists()


def test_a_device_is_not_an_output(capsys):
    result = run_cli(
        capsys, "map", "build", LOG, "--survey", SURVEY, "--out", "/dev/null", "--force"
    )
    assert_one_line_error(result, "/dev/null", "not a regular file")


@pytest.mark.parametrize(
    ("option", "value"),
    [("--grid-m", "nan"), ("--grid-m", "inf"), ("--dtheta-deg", "nan"), ("--ratio", "nan"),
     ("--window-deg", "nan"), ("--tolerance-ms", "inf"), ("--grid-m", "1e308")],
)  # fmt: skip
def test_option_values_must_be_finite_and_in_range(capsys, tmp_path, option, value):
    out = tmp_path / "est.csv"
    result = run_cli(capsys, "localize", LOG, "--map", MAP, "--out", out, option, value)
    assert_one_line_error(result, option)
    assert not out.exists()


def test_the_papers_answer_is_lost_where_the_points_are_not_on_the_map(capsys, tmp_path):
    # Two segments of the hall: stage 2 finds some overlap anywhere, the points say no.
    from segloc_cli.io.maps import read_map, write_map

    two = tmp_path / "two.json"
    write_map(two, read_map(MAP)[:2])
    out = tmp_path / "est.csv"
    result = run_cli(capsys, "localize", LOG, "--map", two, "--no-refine", "--out", out)
    assert result.code == 0, result.err
    rows = _complete_rows(out)
    assert len(rows) == 10 and all(r["status"] != "ok" for r in rows)


# --------------------------------------------------------------------------- signals


def _started(command: list, **kwargs) -> subprocess.Popen:
    return subprocess.Popen(
        [str(SEGLOC), *map(str, command)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONIOENCODING": "utf-8"},
        **kwargs,
    )


def test_sigterm_mid_command_is_one_line_and_leaves_no_fragment(capsys, tmp_path):
    estimates = tmp_path / "est.csv"
    assert run_cli(capsys, "localize", LOG, "--map", MAP, "--out", estimates).code == 0
    figures = tmp_path / "figures"
    command = ["evaluate", estimates, "--survey", SURVEY, "--plots", figures]
    proc = _started([*command, "--map", MAP, "--log", LOG])
    time.sleep(1.5)  # past start-up, drawing the figures (which takes several seconds)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    if proc.returncode == 0:
        pytest.skip("evaluate finished before the signal arrived")
    assert proc.returncode == 130, err
    assert err.splitlines()[-1] == "segloc: interrupted"
    assert "" not in err.splitlines(), f"a blank line on stderr:\n{err}"
    assert "Traceback" not in err
    left = [p.name for p in figures.iterdir()] if figures.exists() else []
    assert not [name for name in left if name.endswith(".tmp")], left


def test_stopping_parallel_workers_ends_every_process(tmp_path):
    log = tmp_path / "long.mcap"
    write_long_log(log, copies=60)
    out = tmp_path / "est.csv"
    command = ["localize", log, "--map", MAP, "--out", out, "--jobs", "2"]
    proc = _started(command, start_new_session=True)
    try:
        _rows_when(out, 8, proc)
        os.killpg(proc.pid, signal.SIGTERM)  # the whole group, as a terminal or a job runner does
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    rows = _complete_rows(out)
    assert proc.returncode == 130
    assert f"interrupted (SIGTERM) after {len(rows)} of 600 scans" in err
    time.sleep(0.5)
    alive = subprocess.run(
        ["ps", "-o", "pid=", "-s", str(proc.pid)], capture_output=True, text=True
    )
    assert alive.stdout.split() == [], "worker processes outlived the run"


# --------------------------------------------------------------------------- inputs


def test_a_pipe_is_refused_rather_than_waited_on(capsys, tmp_path):
    fifo = tmp_path / "log.mcap"
    os.mkfifo(fifo)  # nobody will ever write to it
    result = run_cli(capsys, "info", fifo)
    assert_one_line_error(result, str(fifo), "not a regular file")


def test_global_search_of_a_map_too_large_to_search_is_refused(capsys, tmp_path):
    from segloc_cli.io.maps import write_map

    wide = tmp_path / "wide.json"
    write_map(wide, [[0.0, 0.0, 1999.0, 0.0], [0.0, 0.0, 0.0, 1999.0]])
    out = tmp_path / "est.csv"
    result = run_cli(capsys, "localize", LOG, "--map", wide, "--global", "--out", out)
    assert_one_line_error(result, str(wide), "1999 m × 1999 m", "--initial")
    assert not out.exists()


def test_logs_that_overlap_in_time_are_named(capsys, tmp_path):
    copy = tmp_path / "again.mcap"
    copy.write_bytes(LOG.read_bytes())
    out = tmp_path / "est.csv"
    result = run_cli(capsys, "localize", LOG, copy, "--map", MAP, "--out", out, "--no-refine")
    assert result.code == 0, result.err
    assert f"segloc: warning: {LOG} and {copy} overlap in time (1.000–10.000 s)" in result.err
    assert len(_complete_rows(out)) == 20
