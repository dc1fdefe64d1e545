"""One voice on standard error: every line segloc writes there starts with ``segloc:``
(summaries, warnings, errors, progress lines where no bar is drawn, an emulator's and a
recorder's lines, a Python warning raised inside a command), counts take the number they
ask for and words the article they sound like they take."""

from __future__ import annotations

import subprocess
import warnings
from pathlib import Path

import pytest
from conftest import HALL, HALL_WORLD, SEGLOC, start_emulator, stop_emulator
from test_cli import _estimates_csv, _flaser, run_cli, write_text

from segloc_cli import jit
from segloc_cli import progress as progress_module
from segloc_cli.wording import article, counted, plural, said


def unsaid(err: str) -> list[str]:
    """The non-empty lines of ``err`` that do not start with ``segloc: ``."""
    return [line for line in err.splitlines() if line.strip() and not line.startswith("segloc: ")]


@pytest.fixture
def every_step_shown(monkeypatch):
    """Progress lines from the first step, one at every step (as a long run writes them)."""
    monkeypatch.setattr(progress_module, "SHOW_AFTER_S", 0.0)
    monkeypatch.setattr(progress_module, "PLAIN_EVERY_S", 0.0)


def _carmen_log(path: Path) -> Path:
    lines = [
        "PARAM robot_frontlaser_offset 0.0 nohost 0",
        _flaser([1.0, 2.0, 3.0] * 60, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 10.0),
        "FLASER 5 1 2 3",  # cut short: skipped with a warning
        _flaser([1.5, 2.5, 3.5] * 60, (0.1, 0.0, 0.0), (0.1, 0.0, 0.0), 10.5),
    ]
    return write_text(path, "\n".join(lines) + "\n")


def _ros1_bag(folder: Path) -> Path:
    from test_io_rosbag import TOPICS, standard_messages, write_bag

    return write_bag("ros1", folder, TOPICS, standard_messages("ros1"))


def _commands(tmp: Path) -> list[tuple[list[object], int]]:
    """Every command that writes to standard error, on small inputs, in an order where each
    finds the files of those before it, with the exit status each should end with."""
    sim, poses = tmp / "sim", tmp / "poses.csv"
    write_text(poses, "\n".join((HALL / "poses.csv").read_text().splitlines()[:4]) + "\n")
    log, survey, built = sim / "log.mcap", sim / "survey.csv", tmp / "map.json"
    relations = write_text(tmp / "ref.relations", "0 1 0 -1 0 0 0 0\n1 2 0 -1.1 0 0 0 0\n")
    moved = _estimates_csv(tmp / "moved.csv", [(0, 0, 0, 90), (1, 1, 0, 90), (2, 2, 0, 90)])
    unset = write_text(tmp / "other.toml", "[simulate]\nseed = 3\n")
    return [
        (["simulate", HALL_WORLD, "--poses", poses, "--out", sim, "--seed", 7], 0),
        (["map", "build", log, "--survey", survey, "--out", built, "--mcap", tmp / "built.mcap"],
         0),
        (["localize", log, "--map", built, "--out", tmp / "est.csv", "--hypotheses", 2,
          "--mcap", tmp / "run.mcap", "--config", unset], 0),
        (["localize", log, "--map", built, "--out", tmp / "track.csv", "--track"], 0),
        (["localize", log, "--map", HALL_WORLD, "--out", tmp / "global.csv", "--global"], 0),
        (["localize", log, "--map", built, "--out", tmp / "jobs.csv", "--jobs", 400], 0),
        (["evaluate", tmp / "est.csv", "--survey", survey, "--fail-above-cm", 0.001], 1),
        (["evaluate", moved, "--relations", relations, "--published", "intel"], 0),
        (["info", log], 0),
        (["info", tmp / "run.mcap"], 0),
        (["map", "export", built, "--out", tmp / "grid.yaml"], 0),
        (["map", "import", tmp / "grid.yaml", "--out", tmp / "traced.json"], 0),
        (["import", "carmen", _carmen_log(tmp / "run.log"), "--out", tmp / "carmen.mcap"], 0),
        (["import", "rosbag", _ros1_bag(tmp), "--out", tmp / "bag.mcap"], 0),
        (["info", tmp / "test.bag"], 2),  # a bag where a log is expected
        (["localize", tmp / "missing.mcap", "--map", built, "--out", tmp / "no.csv"], 2),
    ]  # fmt: skip


def test_every_line_on_stderr_starts_with_segloc(capsys, tmp_path, every_step_shown):
    said_lines = 0
    for args, code in _commands(tmp_path):
        result = run_cli(capsys, *args)
        command = " ".join(map(str, args[:2]))
        assert result.code == code, f"`segloc {command}` exited {result.code}:\n{result.err}"
        assert not unsaid(result.err), f"`segloc {command}` wrote:\n" + "\n".join(
            unsaid(result.err)
        )
        said_lines += len(result.err.splitlines())
    assert said_lines > 60, "the commands should have said plenty (progress at every step)"


def test_a_python_warning_inside_a_command_is_one_line_of_segloc_s(capsys, monkeypatch):
    from segloc_cli.commands import logs

    shown = logs.windows_line

    def warning_then_shown(log):
        warnings.warn("a library's remark\nover two lines", UserWarning, stacklevel=1)
        return shown(log)

    monkeypatch.setattr(logs, "windows_line", warning_then_shown)
    result = run_cli(capsys, "info", HALL / "log.mcap")
    assert result.code == 0, result.err
    assert result.err.splitlines() == [
        "segloc: warning: UserWarning: a library's remark over two lines"
    ]


def test_the_compile_notices_start_with_segloc(capsys, monkeypatch):
    monkeypatch.setattr(jit, "_said_uncached", False)
    jit._say_uncached()
    err = capsys.readouterr().err
    assert err.startswith("segloc: numba can write no cache") and not unsaid(err)


def test_a_recording_and_its_emulated_scanner_speak_in_segloc_lines(tmp_path):
    port, emulator = start_emulator("explorer")
    try:
        log = tmp_path / "rec.mcap"
        recorded = subprocess.run(
            [str(SEGLOC), "record", "--device", f"explorer:{port}", "--scans", "3",
             "--out", log],
            capture_output=True, text=True, timeout=120, check=False,
        )  # fmt: skip
        assert recorded.returncode == 0, recorded.stderr
        assert not unsaid(recorded.stderr), recorded.stderr
        summary = recorded.stderr.splitlines()[-1]
        assert summary.startswith(f"segloc: {log}: 3 scans in ") and " skipped (" in summary
        emulator.terminate()
        _, err = emulator.communicate(timeout=10)
    finally:
        stop_emulator(emulator)
    assert not unsaid(err), err
    assert f"segloc: emulating an explorer scanner on {port}; Ctrl-C to stop" in err, err


# --------------------------------------------------------------------------- words


def test_a_count_takes_the_number_it_asks_for():
    assert counted(1, "scan") == "1 scan"
    assert counted(2, "scan") == "2 scans"
    assert counted(0, "frame") == "0 frames"
    assert counted(1, "hypothesis", "hypotheses") == "1 hypothesis"
    assert counted(3, "hypothesis", "hypotheses") == "3 hypotheses"
    assert plural(1, "holds", "hold") == "holds" and plural(4, "holds", "hold") == "hold"


@pytest.mark.parametrize(
    ("word", "expected"),
    [("explorer", "an"), ("scip2", "a"), ("unit", "a"), ("estimate", "an"), ("RGBA", "an"),
     ("L", "an"), ("P", "a"), ("URL", "a"), ("8-byte", "an"), ("11", "an"), ("18", "an"),
     ("110", "a"), ("11,000", "an"), ("1-byte", "a"), ("562", "a"), ("80", "an")],
)  # fmt: skip
def test_a_word_takes_the_article_it_sounds_like_it_takes(word, expected):
    assert article(word) == expected


def test_said_puts_the_prefix_before_a_message():
    assert said("wrote x") == "segloc: wrote x"


@pytest.mark.parametrize(("skipped", "words"), [(1, "1 scan skipped"), (2, "2 scans skipped")])
def test_the_localize_summary_counts_skipped_scans_in_the_right_number(capsys, skipped, words):
    from segloc_cli.commands.localize_lines import report
    from segloc_cli.runs.rowstream import RowOutputs, RunSummary

    summary = RunSummary(3, ("ok",), (12.0,), 0.5, None, skipped)
    report(summary, RowOutputs(Path("est.csv")))
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("segloc: est.csv: 1 scan localized (1 ok) in 0.50 s"), line
    assert line.endswith(f"; {words} (no initial guess or odometry)"), line
