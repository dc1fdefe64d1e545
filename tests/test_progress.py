"""Progress of long work: nothing for short work, plain lines with rate and time left where
standard error is not a terminal, a bar where it is, both starting with ``segloc:``; the
outcomes a track counts as it goes; and the commands that report it."""

from __future__ import annotations

import csv
import fcntl
import io
import os
import pty
import re
import select
import signal
import struct
import sys
import termios
import time
from collections import Counter

import pytest
from conftest import HALL
from test_cli import run_cli

from segloc_cli import progress as progress_module
from segloc_cli.progress import SILENT, Progress, plain_line


class Clock:
    """A monotonic clock the test moves by hand (seconds)."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch):
    fake = Clock()
    monkeypatch.setattr(progress_module.time, "monotonic", fake)
    return fake


def test_a_plain_line_gives_count_share_rate_and_time_left():
    assert plain_line("localizing", 30, 120, "scan", 15.0) == (
        "segloc: localizing: 30/120 scans (25%), 2.0 scans/s, 00:45 left"
    )
    assert plain_line("global search", 2, 10, "scan", 8.0) == (
        "segloc: global search: 2/10 scans (20%), 4.0 s/scan, 00:32 left"
    )
    assert plain_line("reading", 500, None, "message", 100.0) == (
        "segloc: reading: 500 messages, 5.0 messages/s, 01:40 so far"
    )
    assert plain_line("fusing", 1, None, "round", 8.0) == (
        "segloc: fusing: 1 round, 8.0 s/round, 00:08 so far"
    )
    assert plain_line("reading", 0, 10, "scan", 0.0) == (
        "segloc: reading: 0/10 scans (0%), starting"
    )
    assert plain_line("reading", 0, None, "message", 3.0) == (
        "segloc: reading: 0 messages, starting, 00:03 so far"
    )
    assert plain_line("writing", 1, 1, "scan", 2.0) == (
        "segloc: writing: 1/1 scan (100%), 2.0 s/scan, 00:00 left"
    )


def test_a_plain_line_ends_with_the_outcomes_it_counts():
    assert plain_line("tracking", 30, 120, "scan", 15.0, None, {"lost": 2, "recovered": 0}) == (
        "segloc: tracking: 30/120 scans (25%), 2.0 scans/s, 00:45 left; 2 lost, 0 recovered"
    )


def test_plain_lines_come_every_few_seconds_and_once_at_the_end(clock):
    stream = io.StringIO()
    with Progress("localizing", 100, "scan", stream=stream, terminal=False) as shown:
        for _ in range(100):
            clock.now += 0.25  # 4 scans per second, 25 s in all
            shown.advance()
    lines = stream.getvalue().splitlines()
    every = progress_module.PLAIN_EVERY_S
    assert len(lines) == int(25 / every)  # the last, at 25 s, is not written again at the end
    assert lines[0] == "segloc: localizing: 20/100 scans (20%), 4.0 scans/s, 00:20 left"
    assert lines[-1] == "segloc: localizing: 100/100 scans (100%), 4.0 scans/s, 00:00 left"


def test_short_work_shows_nothing(clock):
    for terminal in (False, True):
        stream = io.StringIO()
        with Progress("building the map", 50, "scan", stream=stream, terminal=terminal) as p:
            for _ in range(50):
                clock.now += 0.01
                p.advance()
        assert stream.getvalue() == "", f"terminal={terminal}"


def test_a_terminal_gets_a_bar_with_rate_and_time_left(monkeypatch):
    monkeypatch.setattr(progress_module, "SHOW_AFTER_S", 0.0)
    stream = io.StringIO()
    with Progress("tracking", 10, "scan", stream=stream, terminal=True) as shown:
        shown.advance(3)
        time.sleep(0.15)  # tqdm redraws at most every 0.1 s
        shown.advance()  # the rate counts from the end of the first step
    drawn = stream.getvalue().split("\r")
    bar = drawn[-3]
    assert bar.startswith("segloc: tracking:") and "4/10 [00:00<" in bar and bar.endswith("scan/s]")
    assert drawn[-2].strip() == "", "the bar is cleared when the work ends"


def test_the_bar_says_starting_until_it_has_a_rate(monkeypatch):
    monkeypatch.setattr(progress_module, "SHOW_AFTER_S", 0.0)
    for total, count in ((10, "1/10"), (None, "1scan")):
        stream = io.StringIO()
        with Progress("localizing", total, "scan", stream=stream, terminal=True) as shown:
            time.sleep(0.15)  # tqdm redraws at most every 0.1 s
            shown.advance()  # the first step (compiling, reading a map) sets no rate
            time.sleep(0.15)
            shown.advance()
        *first, last = [part for part in stream.getvalue().split("\r") if part.strip()]
        assert all(part.startswith("segloc: localizing:") for part in first), first
        assert first[-1].endswith(f"{count} [00:00, starting]"), first
        assert all("?" not in part for part in first), first
        assert last.endswith("scan/s]") and "starting" not in last, last


def test_the_bar_counts_the_outcomes_it_is_told_to(monkeypatch):
    monkeypatch.setattr(progress_module, "SHOW_AFTER_S", 0.0)
    stream = io.StringIO()
    with Progress("tracking", 10, "scan", stream=stream, terminal=True) as shown:
        shown.tally(("lost", "recovered"))
        for outcome in ("ok", "lost", "lost", "recovered"):
            shown.advance(outcome=outcome)
        time.sleep(0.15)  # tqdm redraws at most every 0.1 s
        shown.advance(outcome="ok")
        assert shown.tallies == {"lost": 2, "recovered": 1}
    last = [part for part in stream.getvalue().split("\r") if part.strip()][-1]
    assert last.startswith("segloc: tracking:") and "5/10" in last, last
    assert last.endswith("2 lost, 1 recovered]"), last


WAITING = """
import pathlib, sys, time
from segloc_cli import progress
from segloc_cli.cli import cli, main

progress.SHOW_AFTER_S = float(sys.argv[1])

@cli.command("wait")
def wait():
    with progress.Progress("waiting", 10, "step") as shown:
        shown.advance()
        pathlib.Path(sys.argv[2]).touch()
        time.sleep(60)

main(["wait"])
"""
"""A command that shows its bar after the seconds its first argument says, makes the file its
second names once it is under way, and waits to be stopped."""


def _screen(text: str) -> list[str]:
    """The rows a terminal shows for ``text``: a carriage return goes back to the start of the
    row, written over by what follows."""
    rows, row, column = [], [], 0
    for char in text:
        if char == "\r":
            column = 0
        elif char == "\n":
            rows.append("".join(row).rstrip())
            row, column = [], 0
        else:
            row[column : column + 1] = [char]
            column += 1
    return rows + (["".join(row).rstrip()] if row else [])


@pytest.mark.parametrize("bar", [True, False], ids=["bar", "no-bar-yet"])
def test_ctrl_c_leaves_no_blank_line_before_interrupted(bar, tmp_path):
    started = tmp_path / "started"
    pid, terminal = pty.fork()
    if pid == 0:  # the child: the command, on the terminal's other side
        try:
            # As a shell starts it: the test's process may ignore Ctrl-C (an earlier test in
            # the same pytest worker, a worker started so), and an ignored signal stays
            # ignored across exec.
            signal.signal(signal.SIGINT, signal.SIG_DFL)
            argv = [sys.executable, "-c", WAITING, "0" if bar else "60", str(started)]
            os.execv(sys.executable, argv)
        finally:
            os._exit(127)
    fcntl.ioctl(terminal, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    shown, typed, ended, deadline = b"", False, False, time.monotonic() + 60
    while not ended and time.monotonic() < deadline:
        if not typed and started.exists():
            os.write(terminal, b"\x03")  # Ctrl-C typed: the terminal sends SIGINT, echoes ^C
            typed = True
        if select.select([terminal], [], [], 0.1)[0]:
            try:
                data = os.read(terminal, 65536)
            except OSError:  # the command has ended
                data = b""
            ended = not data
            shown += data
    if not ended:
        os.kill(pid, signal.SIGKILL)
    _, status = os.waitpid(pid, 0)
    os.close(terminal)
    assert typed, f"the command did not start: {shown!r}"
    rows = _screen(shown.decode("utf-8", errors="replace"))
    assert os.waitstatus_to_exitcode(status) == 130, rows
    # Written over the "^C" the terminal echoed, on the row after the bar where it stopped.
    assert rows[-1] == "segloc: interrupted", rows
    if bar:
        assert rows[-2].startswith("segloc: waiting:"), rows
    assert "" not in rows, rows


def test_the_silent_progress_prints_nothing(capsys):
    SILENT.advance(5)
    SILENT.close()
    assert capsys.readouterr() == ("", "")


# --------------------------------------------------------------------------- the commands


@pytest.fixture
def every_step_shown(monkeypatch):
    """Progress shown from the first step and a plain line at every step."""
    monkeypatch.setattr(progress_module, "SHOW_AFTER_S", 0.0)
    monkeypatch.setattr(progress_module, "PLAIN_EVERY_S", 0.0)


def _progress_lines(err: str, what: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith(f"segloc: {what}: ")]


def test_long_commands_report_progress_in_plain_lines(capsys, tmp_path, every_step_shown,
                                                       monkeypatch):  # fmt: skip
    from segloc_cli.maps import fusion

    monkeypatch.setattr(fusion, "PAIRING_ENTRIES", 512)  # fusion in stretches on a small log
    mapping = HALL / "mapping"
    built = run_cli(
        capsys, "map", "build", mapping / "log.mcap", "--survey", mapping / "survey.csv",
        "--out", tmp_path / "map.json",
    )  # fmt: skip
    assert built.code == 0, built.err
    extracting = _progress_lines(built.err, "extracting segments")
    assert extracting[-1].startswith("segloc: extracting segments: 125/125 scans (100%), ")
    assert len(extracting) == 125  # a line per scan here, the last one not repeated
    # Fusion tells its total, the local segments fused, and the time left, as it goes.
    local = int(re.search(r"fused from (\d+) local segments", built.err).group(1))
    fused = _progress_lines(built.err, "fusing segments")
    shown = [re.match(r"segloc: fusing segments: (\d+)/(\d+) segments \(", line) for line in fused]
    assert all(shown), fused
    assert {int(m.group(2)) for m in shown} == {local}
    done = [int(m.group(1)) for m in shown]
    assert len(done) > 3 and done == sorted(done) and done[-1] == local, done
    assert all(line.endswith((" left", ", starting")) for line in fused), fused
    assert fused[-1].endswith(" left"), fused

    estimates = tmp_path / "est.csv"
    ran = run_cli(capsys, "localize", HALL / "log.mcap", "--map", tmp_path / "map.json",
                  "--out", estimates)  # fmt: skip
    assert ran.code == 0, ran.err
    assert _progress_lines(ran.err, "localizing")[-1].startswith(
        "segloc: localizing: 10/10 scans (100%), "
    )
    assert _progress_lines(ran.err, "localizing")[-1].endswith(" 00:00 left")

    drawn = run_cli(capsys, "evaluate", estimates, "--survey", HALL / "survey.csv",
                    "--plots", tmp_path / "plots")  # fmt: skip
    assert drawn.code == 0, drawn.err
    from segloc_cli.scoring.plots import TABLE_FIGURES

    n = len(TABLE_FIGURES)
    assert _progress_lines(drawn.err, "drawing figures")[-1].startswith(
        f"segloc: drawing figures: {n}/{n} figures"
    )


def test_an_import_reports_reading_and_writing(capsys, tmp_path, every_step_shown):
    from test_io_carmen import laser_line, write

    lines = [laser_line([1.0, 2.0, 3.0] * 60, (0.1 * i, 0, 0), (0.1 * i, 0, 0), 1.0 + i)
             for i in range(4)]  # fmt: skip
    source = tmp_path / "run.log"
    write(source, lines)
    done = run_cli(capsys, "import", "carmen", source, "--out", tmp_path / "log.mcap")
    assert done.code == 0, done.err
    assert _progress_lines(done.err, "reading the log")[-1].startswith(
        "segloc: reading the log: 4/4 lines (100%), "
    )
    assert _progress_lines(done.err, "writing the log")[-1].startswith(
        "segloc: writing the log: 4/4 scans (100%), "
    )


def test_the_rate_and_time_left_leave_the_first_step_out(monkeypatch):
    # A first scan of 20 s (compiling), then 0.5 s per scan: the time left after the third
    # scan is 7 scans × 0.5 s, not 7 × the average with the first one in it.
    clock = iter([0.0, 20.0, 20.5, 21.0, 21.0])
    monkeypatch.setattr(progress_module.time, "monotonic", lambda: next(clock))
    monkeypatch.setattr(progress_module, "SHOW_AFTER_S", 0.0)
    monkeypatch.setattr(progress_module, "PLAIN_EVERY_S", 0.0)
    stream = io.StringIO()
    shown = Progress("localizing", 10, "scan", stream=stream, terminal=False)
    for _ in range(3):
        shown.advance()
    assert stream.getvalue().splitlines() == [
        "segloc: localizing: 1/10 scans (10%), starting",
        "segloc: localizing: 2/10 scans (20%), 2.0 scans/s, 00:04 left",
        "segloc: localizing: 3/10 scans (30%), 2.0 scans/s, 00:03 left",
    ]


def test_the_tracking_progress_counts_lost_and_recovered_scans(capsys, tmp_path,
                                                               every_step_shown):  # fmt: skip
    estimates = tmp_path / "track.csv"
    ran = run_cli(capsys, "localize", HALL / "log.mcap", "--map", HALL / "map.json", "--track",
                  "--out", estimates)  # fmt: skip
    assert ran.code == 0, ran.err
    with open(estimates, newline="", encoding="utf-8") as stream:
        statuses = [row["status"] for row in csv.DictReader(stream)]
    lines = _progress_lines(ran.err, "tracking")
    assert len(lines) == len(statuses), lines
    for k, line in enumerate(lines, 1):
        so_far = Counter(statuses[:k])
        assert line.startswith(f"segloc: tracking: {k}/{len(statuses)} scans ("), line
        assert line.endswith(f"; {so_far['lost']} lost, {so_far['recovered']} recovered"), line
    assert {"lost", "recovered"} <= set(statuses), "the hall's track should show both"


def test_counts_that_are_no_outcomes_are_shown_as_they_are_given(monkeypatch):
    monkeypatch.setattr(progress_module, "SHOW_AFTER_S", 0.0)
    monkeypatch.setattr(progress_module, "PLAIN_EVERY_S", 0.0)
    stream = io.StringIO()
    with Progress("mapping", 4, "scan", stream=stream, terminal=False) as shown:
        for done in range(1, 5):
            shown.count({"keyframes": done // 2, "loops closed": done // 4})
            shown.advance()
    assert stream.getvalue().splitlines()[-1].endswith("; 2 keyframes, 1 loops closed")
