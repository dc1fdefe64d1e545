"""``segloc evaluate`` end to end through its command line, as CI runs it: one simulated run
(surveyed poses, estimates off by known errors, with covariances) written in every format
gives the same table; the JUnit file, the Markdown summary, the baseline comparison, the
covariance check, the relation gates, the HTML page and a one-line refusal for each bad
option, all held against values worked out here from the simulated errors."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from amcl_bags import write_amcl_bag
from PIL import Image
from test_cli import assert_one_line_error, run_cli
from trajectory_samples import (
    NS,
    ODOMETRY,
    PWCS,
    ROS1_STORE,
    ROS2_STORE,
    amcl_messages,
    estimates_frame,
    odometry,
    write_bag,
    write_foxglove_mcap,
    write_tum,
)

from segloc_cli.cli import main
from segloc_cli.estimates import PoseTable
from segloc_cli.io.tables import write_estimates, write_pose_table
from segloc_cli.numbers import step_of, unit_of

N = 30
T0_NS = 1_000 * NS + 123  # stamps with nanoseconds of their own
STAMPS = [T0_NS + i * 400_000_000 for i in range(N)]
TIMES_S = np.array([stamp / NS for stamp in STAMPS])
_rng = np.random.default_rng(3303)
_s = np.linspace(0.0, 3.0, N)
TRUTH = np.column_stack([1.0 + 4.0 * _s, 3.0 + 2.0 * np.sin(_s), np.arctan2(2.0 * np.cos(_s), 4.0)])
ERRORS = np.column_stack(
    [_rng.normal(0.0, 0.02, N), _rng.normal(0.0, 0.02, N), np.radians(_rng.normal(0.0, 0.4, N))]
)
FAR_OFF = {5: (0.25, -0.18), 13: (-0.40, 0.10), 22: (0.05, 0.30)}
for _i, (_dx, _dy) in FAR_OFF.items():
    ERRORS[_i, :2] += (_dx, _dy)
POSES = TRUTH + ERRORS
"""The localizer's estimates: the truth plus the known errors (x m, y m, θ rad)."""
ERR_XY_CM = 100.0 * np.hypot(ERRORS[:, 0], ERRORS[:, 1])
_rotations = _rng.uniform(0.0, np.pi, N)
COVARIANCES = np.zeros((N, 3, 3))
for _i, _angle in enumerate(_rotations):
    _c, _sn = np.cos(_angle), np.sin(_angle)
    _r = np.array([[_c, -_sn, 0.0], [_sn, _c, 0.0], [0.0, 0.0, 1.0]])
    COVARIANCES[_i] = _r @ np.diag([0.03**2, 0.015**2, 0.01**2]) @ _r.T
SURVEY = PoseTable(np.arange(1, N + 1, dtype=np.int64), TIMES_S.copy(), TRUTH.copy())
NAN_POSE = 9
"""The index of the pose the bag with a damaged message holds as NaN."""


def write_csv_estimates(path: Path, poses: np.ndarray, times_s: np.ndarray = TIMES_S) -> Path:
    write_estimates(path, estimates_frame(times_s, poses))
    return path


@pytest.fixture(scope="module")
def run_files(tmp_path_factory) -> dict[str, Path]:
    """The survey and the estimates in every format (``*_topic``: the ``--topic`` it needs)."""
    where = tmp_path_factory.mktemp("run")
    write_pose_table(where / "survey.csv", SURVEY)
    files = {
        "survey": where / "survey.csv",
        "segloc": write_csv_estimates(where / "est.csv", POSES),
        "tum": write_tum(where / "est.tum", STAMPS, POSES),
        "ros2": write_amcl_bag(where / "amcl_ros2", TIMES_S, POSES, COVARIANCES),
        "mcap": write_foxglove_mcap(where / "fox.mcap", STAMPS, POSES),
    }
    # A ROS 1 bag with two pose topics, so that --topic must choose.
    messages = amcl_messages(ROS1_STORE, STAMPS, POSES, COVARIANCES)
    messages += [
        ("/odom", stamp, odometry(ROS1_STORE, stamp, "odom", pose + 1.0))
        for stamp, pose in zip(STAMPS, POSES, strict=True)
    ]
    files["ros1"] = write_bag(
        "ros1", where / "amcl.bag", {"/amcl_pose": PWCS, "/odom": ODOMETRY}, messages
    )
    # A ROS 2 bag whose message of one pose is damaged (NaN).
    damaged = POSES.copy()
    damaged[NAN_POSE, 0] = np.nan
    messages = amcl_messages(ROS2_STORE, STAMPS, damaged, COVARIANCES)
    files["nan"] = write_bag("sqlite3", where / "nan_ros2", {"/amcl_pose": PWCS}, messages)
    return files


FORMAT_ARGS = {
    "segloc": (),
    "tum": (),
    "ros1": ("--topic", "/amcl_pose"),
    "ros2": (),
    "mcap": ("--topic", "/pose"),
}
WITH_COVARIANCE = {"ros1", "ros2"}


def evaluate(capsys, estimates: Path, survey: Path, *args):
    return run_cli(capsys, "evaluate", estimates, "--survey", survey, *args)


def pairing_line(err: str) -> str:
    (line,) = [ln for ln in err.splitlines() if " surveyed poses paired within " in ln]
    return line


# --------------------------------------------------------------------------- every format


@pytest.fixture(scope="module")
def scored_by_format(run_files) -> dict[str, tuple[dict, str, str]]:
    """Each format's (JSON document, md text, stderr of the md run), run once per module."""
    results = {}
    for name, extra in FORMAT_ARGS.items():
        code, out_json, _ = run_captured(
            "evaluate", run_files[name], "--survey", run_files["survey"], *extra, "--format", "json"
        )
        assert code == 0
        code, out_md, err_md = run_captured(
            "evaluate", run_files[name], "--survey", run_files["survey"], *extra
        )
        assert code == 0
        results[name] = (json.loads(out_json), out_md, err_md)
    return results


def run_captured(*args) -> tuple[int, str, str]:
    """``run_cli`` for module fixtures, where pytest's capsys is not at hand: exit status,
    standard output, standard error."""
    out, err = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main([str(a) for a in args])
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
    return code, out.getvalue(), err.getvalue()


def assert_same_poses(poses: list[dict], expected: list[dict]) -> None:
    """The same poses to two steps of each number's precision: one as the estimates' file
    keeps a position (1 µm), one as the JSON writes an error (1e-4 cm)."""
    assert len(poses) == len(expected)
    for got, want in zip(poses, expected, strict=True):
        assert got.keys() == want.keys()
        for key, value in want.items():
            if isinstance(value, float) and got[key] is not None:
                slack = 2.001 * step_of(unit_of(key))
                assert abs(got[key] - value) <= slack, (key, got[key], value)
            else:
                assert got[key] == value, (key, got[key], value)


def test_the_errors_are_the_simulated_ones(scored_by_format):
    document, _, _ = scored_by_format["segloc"]
    poses = document["poses"]
    assert [p["pose_id"] for p in poses] == list(range(1, N + 1))
    assert all(p["status"] == "ok" for p in poses)
    # Surveyed minus computed: the negated simulated errors, to the files' precision (1 µm
    # in the survey and the estimates, 1e-4 cm in the JSON; 1e-6° in each).
    cm, deg = 2e-4, 2e-6
    np.testing.assert_allclose([p["err_x_cm"] for p in poses], -100 * ERRORS[:, 0], atol=cm)
    np.testing.assert_allclose([p["err_y_cm"] for p in poses], -100 * ERRORS[:, 1], atol=cm)
    np.testing.assert_allclose([p["err_xy_cm"] for p in poses], ERR_XY_CM, atol=cm)
    theta = np.array([p["err_theta_deg"] for p in poses])
    np.testing.assert_allclose(theta, -np.degrees(ERRORS[:, 2]), atol=deg)


@pytest.mark.parametrize("name", [n for n in FORMAT_ARGS if n != "segloc"])
def test_every_format_gives_the_same_table(scored_by_format, name):
    reference_json, reference_md, _ = scored_by_format["segloc"]
    document, md, _ = scored_by_format[name]
    assert_same_poses(document["poses"], reference_json["poses"])
    # The same md tables and lines; only the estimates that carry a covariance say so.
    table, _, covariance = md.partition("\nCovariance: ")
    assert table.rstrip("\n") == reference_md.rstrip("\n")
    assert bool(covariance) == (name in WITH_COVARIANCE)


def test_the_bags_carrying_one_covariance_judge_it_alike(scored_by_format):
    _, ros1_md, _ = scored_by_format["ros1"]
    _, ros2_md, _ = scored_by_format["ros2"]
    assert ros1_md.partition("\nCovariance: ")[2] == ros2_md.partition("\nCovariance: ")[2]
    assert f"{N} of {N} poses carry a usable one" in ros1_md


@pytest.mark.parametrize("name", list(FORMAT_ARGS))
def test_the_pairing_line_names_the_counts(scored_by_format, name):
    _, _, err = scored_by_format[name]
    line = pairing_line(err)
    assert line.endswith(f": {N} of {N} surveyed poses paired within 50 ms, 0 unpaired")
    assert f"{N} rows" in line or f"{N} poses" in line


def test_a_bag_with_a_nan_pose_says_what_it_dropped(run_files, scored_by_format, capsys):
    code, out, err = evaluate(capsys, run_files["nan"], run_files["survey"], "--format", "json")
    assert code == 0
    line = pairing_line(err)
    assert f", {N - 1} poses in frame map: " in line
    assert line.endswith(
        f": {N - 1} of {N} surveyed poses paired within 50 ms, 1 unpaired; "
        "dropped 1 (1 not finite (or an all-zero quaternion))"
    )
    full = scored_by_format["ros2"][0]["poses"]
    poses = json.loads(out)["poses"]
    # The pose whose message was dropped stays in the table, with no estimate.
    (dropped,) = [p for p in poses if p["pose_id"] == NAN_POSE + 1]
    assert dropped["status"] == "no_estimate" and dropped["err_xy_cm"] is None
    assert_same_poses(
        [p for p in poses if p is not dropped], [p for p in full if p["pose_id"] != NAN_POSE + 1]
    )


# --------------------------------------------------------------------------- JUnit


def gap_limit(values: np.ndarray, above: float) -> float:
    """A limit between two neighbouring ``values`` (the first gap above ``above``), so that
    no value lies near it."""
    ordered = np.sort(values)
    i = int(np.searchsorted(ordered, above))
    return float((ordered[i - 1] + ordered[i]) / 2.0) if i else float(ordered[0] / 2.0)


@pytest.mark.parametrize("above_cm", [3.0, 20.0, None])
def test_junit_fails_exactly_the_poses_beyond_the_limit(run_files, tmp_path, capsys, above_cm):
    from junitparser import Failure, JUnitXml

    limit = ERR_XY_CM.max() + 1.0 if above_cm is None else gap_limit(ERR_XY_CM, above_cm)
    report = tmp_path / "report.xml"
    code, _, err = evaluate(
        capsys,
        run_files["segloc"],
        run_files["survey"],
        "--fail-above-xy-cm",
        f"{limit:.6f}",
        "--junit",
        report,
    )
    expected = {i + 1 for i in np.flatnonzero(ERR_XY_CM > limit)}
    assert code == (1 if expected else 0), err
    (suite,) = JUnitXml.fromfile(str(report))
    cases = list(suite)
    poses = [case for case in cases if case.classname.endswith(".poses")]
    gates = [case for case in cases if case.classname.endswith(".gates")]
    assert len(cases) == len(poses) + len(gates)
    assert sorted(case.name for case in poses) == sorted(f"pose {i}" for i in range(1, N + 1))
    failed = {
        int(c.name.split()[1]) for c in poses if any(isinstance(r, Failure) for r in c.result)
    }
    assert failed == expected
    # One gate on the share of poses with an estimate (all have one), one on the largest
    # |XY| and one on the share of poses within it; named by what they ask, not what they
    # found.
    assert [c.name for c in gates] == [
        "gate: share of surveyed poses with an estimate ≥ 100 %",
        f"gate: max position error |XY| ≤ {float(f'{limit:.6f}'):g} cm",
        f"gate: share of poses accepted and within |XY| ≤ {float(f'{limit:.6f}'):g} cm ≥ 100 %",
    ]
    gates_failed = [c for c in gates if any(isinstance(r, Failure) for r in c.result)]
    assert len(gates_failed) == (2 if expected else 0)
    assert suite.tests == N + 3
    assert suite.failures == len(expected) + len(gates_failed)


# --------------------------------------------------------------------------- Markdown summary


@pytest.mark.parametrize(("limit_cm", "verdict"), [(50.0, "PASS"), (10.0, "FAIL")])
def test_the_summary_holds_the_table_and_is_appended_to_the_step_summary(
    run_files, tmp_path, capsys, monkeypatch, limit_cm, verdict
):
    earlier = "### an earlier step\n\nits own text\n"
    step_summary = tmp_path / "step_summary.md"
    step_summary.write_text(earlier, encoding="utf-8")
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(step_summary))
    summary = tmp_path / "summary.md"
    args = ("--fail-above-xy-cm", limit_cm, "--summary-md", summary)
    code, out, _ = evaluate(capsys, run_files["segloc"], run_files["survey"], *args)
    assert code == (0 if verdict == "PASS" else 1)
    assert not np.any(np.abs(ERR_XY_CM - limit_cm) < 0.1)  # no pose near the limit
    assert (verdict == "FAIL") == bool(np.any(ERR_XY_CM > limit_cm))
    text = summary.read_text(encoding="utf-8")
    lines = [ln for ln in text.splitlines() if ln]
    assert lines[0] == f"### segloc evaluate: {verdict}"
    beyond = [i + 1 for i in np.flatnonzero(ERR_XY_CM > limit_cm)]
    if verdict == "PASS":
        assert lines[1] == f"**PASS: 3 gates held over {N} poses.**"
    else:
        assert lines[1].startswith("**FAIL: 2 of 3 gates failed (max position error |XY| ≤ ")
        assert lines[1].endswith(
            f"{len(beyond)} of {N} poses failed: " + ", ".join(str(p) for p in beyond) + ".**"
        )
    # The answer comes first: the gates, then the failing poses, then every pose, folded.
    at = {title: text.index(title) for title in ("| result | gate |", "<details>")}
    assert at["| result | gate |"] < at["<details>"]
    folded = text[at["<details>"] :]
    failing = text[: at["<details>"]]
    listed = [int(p) for p in re.findall(r"^\| (\d+) ", failing, flags=re.MULTILINE)]
    assert listed == beyond
    # Table 1 printed (its header and rule, the poses, RMS and max) is in the summary row for
    # row, each pose marked when it failed.
    table_rows = [ln for ln in out.splitlines() if ln.startswith("|")][: N + 4]
    summary_rows = [ln for ln in folded.splitlines() if ln.startswith("|")]
    assert len(summary_rows) == len(table_rows)
    for printed, summarised in zip(table_rows, summary_rows, strict=True):
        assert summarised.startswith(printed[:-1])
    marked = [int(row.split()[1]) for row in summary_rows[2:] if row.rstrip(" |").endswith("✘")]
    assert marked == beyond
    appended = step_summary.read_text(encoding="utf-8")
    assert appended.startswith(earlier)
    assert appended[len(earlier) :].rstrip("\n") == text.rstrip("\n")


def test_without_the_variable_no_step_summary_is_written(run_files, tmp_path, capsys):
    assert "GITHUB_STEP_SUMMARY" not in os.environ
    summary = tmp_path / "summary.md"
    code, _, err = evaluate(
        capsys, run_files["segloc"], run_files["survey"], "--summary-md", summary
    )
    assert code == 0
    assert summary.read_text(encoding="utf-8").startswith("### segloc evaluate: no gates\n")
    assert [p.name for p in tmp_path.iterdir()] == ["summary.md"]
    assert f"segloc: wrote {summary}" in err.splitlines()


def copied_run(run_files, where: Path) -> tuple[Path, Path]:
    """The estimates and the survey copied into ``where``: a test may point an output at them."""
    for name in ("segloc", "survey"):
        (where / run_files[name].name).write_bytes(run_files[name].read_bytes())
    return where / run_files["segloc"].name, where / run_files["survey"].name


STEP_SUMMARY_WARNING = "segloc: warning: no step summary appended (GITHUB_STEP_SUMMARY): "


def step_summary_warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if "GITHUB_STEP_SUMMARY" in line]


@pytest.mark.parametrize(
    "target",
    ["estimates", "survey", "a link to the survey", "--out", "--out's run file", "--junit",
     "--summary-md"],
)  # fmt: skip
def test_a_step_summary_naming_an_input_or_another_output_is_left_alone(
    run_files, tmp_path, capsys, monkeypatch, target
):
    estimates, survey = copied_run(run_files, tmp_path)
    out, junit, summary = tmp_path / "t.json", tmp_path / "r.xml", tmp_path / "s.md"
    (tmp_path / "link.md").symlink_to(survey)
    named = {
        "estimates": estimates,
        "survey": survey,
        "a link to the survey": tmp_path / "link.md",
        "--out": out,
        "--out's run file": tmp_path / "t.run.toml",
        "--junit": junit,
        "--summary-md": summary,
    }[target]
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(named))
    inputs = {path: path.read_bytes() for path in (estimates, survey)}
    args = ("--fail-above-xy-cm", 10, "--format", "json", "--out", out)
    code, _, err = evaluate(
        capsys, estimates, survey, *args, "--junit", junit, "--summary-md", summary
    )
    # The gate's verdict stands, the step summary's trouble said once, before any work.
    assert code == 1, err
    (warning,) = step_summary_warnings(err)
    assert warning.startswith(STEP_SUMMARY_WARNING + str(named) + ": ")
    assert err.splitlines()[0] == warning
    assert ("is an input of this command" in warning) == (target in {
        "estimates", "survey", "a link to the survey"
    })  # fmt: skip
    # Nothing written into an input, nor twice into an output.
    assert {path: path.read_bytes() for path in inputs} == inputs
    assert json.loads(out.read_text(encoding="utf-8"))["summary"]["n_poses"] == N
    assert tomllib.loads((tmp_path / "t.run.toml").read_text(encoding="utf-8"))
    assert summary.read_text(encoding="utf-8").count("### segloc evaluate") == 1
    assert "### segloc evaluate" not in junit.read_text(encoding="utf-8")


@pytest.mark.parametrize("kind", ["folder", "pipe", "device", "missing folder", "read-only"])
def test_a_step_summary_that_cannot_be_appended_to_is_left_alone(
    run_files, tmp_path, capsys, monkeypatch, kind
):
    if kind == "device" and not Path("/dev/full").exists():
        pytest.skip("no /dev/full here")
    if kind == "read-only" and os.geteuid() == 0:
        pytest.skip("root writes read-only files")
    named = {
        "folder": tmp_path / "steps",
        "pipe": tmp_path / "steps.fifo",
        "device": Path("/dev/full"),  # every write fails: no space left on device
        "missing folder": tmp_path / "none" / "steps.md",
        "read-only": tmp_path / "steps.md",
    }[kind]
    if kind == "folder":
        named.mkdir()
    elif kind == "read-only":
        named.write_text("earlier\n", encoding="utf-8")
        named.chmod(0o444)
    reader = None
    if kind == "pipe":
        os.mkfifo(named)
        # A reader that waits for nothing: a writer then gets in at once, and nothing hangs.
        reader = os.open(named, os.O_RDONLY | os.O_NONBLOCK)
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(named))
    junit = tmp_path / "r.xml"
    try:
        args = ("--fail-above-xy-cm", 10, "--junit", junit)
        code, _, err = evaluate(capsys, run_files["segloc"], run_files["survey"], *args)
        if reader is not None:
            with contextlib.suppress(BlockingIOError):
                assert os.read(reader, 1 << 20) == b""
    finally:
        if reader is not None:
            os.close(reader)
    assert code == 1, err
    (warning,) = step_summary_warnings(err)
    assert warning.startswith(STEP_SUMMARY_WARNING + str(named) + ": ")
    assert err.splitlines()[0] == warning  # said before any work
    assert junit.stat().st_size > 0
    if kind == "read-only":
        assert named.read_text(encoding="utf-8") == "earlier\n"


def test_a_step_summary_whose_write_fails_is_taken_back_and_the_verdict_stands(
    run_files, tmp_path, capsys, monkeypatch
):
    import errno

    step_summary = tmp_path / "steps.md"
    step_summary.write_text("earlier\n", encoding="utf-8")
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(step_summary))
    written = []
    real_write = os.write

    def disk_fills(fd: int, data: bytes) -> int:
        if os.fstat(fd).st_ino != step_summary.stat().st_ino:
            return real_write(fd, data)
        if not written:  # the first part goes in, then the disk is full
            written.append(real_write(fd, data[:100]))
            return written[0]
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "write", disk_fills)
    summary = tmp_path / "s.md"
    args = ("--fail-above-xy-cm", 10, "--summary-md", summary)
    code, _, err = evaluate(capsys, run_files["segloc"], run_files["survey"], *args)
    assert code == 1, err
    assert written == [100]
    (warning,) = step_summary_warnings(err)
    assert warning == (
        f"{STEP_SUMMARY_WARNING}{step_summary}: cannot write file (No space left on device)"
    )
    assert step_summary.read_text(encoding="utf-8") == "earlier\n"
    assert summary.read_text(encoding="utf-8").startswith("### segloc evaluate: FAIL")


def test_a_step_summary_naming_a_figure_or_the_page_is_left_alone(run_files, tmp_path, monkeypatch):
    from segloc_cli.runs.evaluation import EvaluateOptions
    from segloc_cli.runs.reports import step_summary_path

    plots, page = tmp_path / "plots", tmp_path / "page.html"
    plots.mkdir()
    options = EvaluateOptions(
        run_files["segloc"], survey_path=run_files["survey"], plots_dir=plots, html_path=page
    )
    for named, other in ((plots / "errors.png", "--plots (errors.png)"), (page, "--html")):
        monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(named))
        path, problem = step_summary_path(options)
        assert path is None
        assert problem == (
            f"no step summary appended (GITHUB_STEP_SUMMARY): {named}: {other} and "
            "GITHUB_STEP_SUMMARY name the same file"
        )
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(tmp_path / "steps.md"))
    assert step_summary_path(options) == (tmp_path / "steps.md", None)
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", " ")
    assert step_summary_path(options) == (None, None)


# --------------------------------------------------------------------------- baseline

COMPARISON_HEADER = "| figure | baseline | now | change | 95 % interval | verdict |"


def md_cells(text: str, first: str) -> list[str]:
    """The cells of the Markdown row whose first cell is ``first`` (``\\|`` read as ``|``)."""
    for line in text.splitlines():
        inner = line.strip()[1:-1]
        cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", inner)]
        if line.startswith("|") and cells[0] == first:
            return cells
    raise AssertionError(f"no row {first!r} in:\n{text}")


@pytest.fixture(scope="module")
def baseline_json(run_files, tmp_path_factory) -> Path:
    old = tmp_path_factory.mktemp("baseline") / "old.json"
    code, _, err = run_captured(
        "evaluate",
        run_files["segloc"],
        "--survey",
        run_files["survey"],
        "--format",
        "json",
        "--out",
        old,
    )
    assert code == 0, err
    return old


def test_a_run_worse_by_2_cm_on_every_pose_fails_against_its_baseline(
    run_files, baseline_json, tmp_path, capsys
):
    stretched = ERRORS.copy()
    stretched[:, :2] *= (1.0 + 2.0 / ERR_XY_CM)[:, None]  # each |XY| 2 cm longer
    worse = write_csv_estimates(tmp_path / "worse.csv", TRUTH + stretched)
    args = ("--baseline", baseline_json, "--fail-if-worse-cm", 1)
    code, out, err = evaluate(capsys, worse, run_files["survey"], *args)
    assert code == 1
    (gate,) = [ln for ln in err.splitlines() if ln.startswith("segloc: gate: ")]
    assert "mean |XY| worse by 2.0 cm" in gate
    assert COMPARISON_HEADER in out
    cells = md_cells(out, "mean |XY| (cm)")
    assert cells[1:4] == [f"{ERR_XY_CM.mean():.1f}", f"{ERR_XY_CM.mean() + 2.0:.1f}", "+2.0"]
    # Every pose got 2 cm worse: every resample's change is 2 cm.
    assert cells[4:] == ["[+2.0, +2.0]", "worse"]


def test_the_same_run_with_tiny_noise_passes_against_its_baseline(
    run_files, baseline_json, tmp_path, capsys
):
    noise = np.random.default_rng(7).normal(0.0, 0.0005, (N, 3)) * [1.0, 1.0, 0.0]
    again = write_csv_estimates(tmp_path / "again.csv", POSES + noise)
    args = ("--baseline", baseline_json, "--fail-if-worse-cm", 1)
    code, out, err = evaluate(capsys, again, run_files["survey"], *args)
    assert code == 0, err
    assert "segloc: gate" not in err
    assert COMPARISON_HEADER in out
    now_xy = 100.0 * np.hypot(ERRORS[:, 0] + noise[:, 0], ERRORS[:, 1] + noise[:, 1])
    cells = md_cells(out, "mean |XY| (cm)")
    assert cells[1:3] == [f"{ERR_XY_CM.mean():.1f}", f"{now_xy.mean():.1f}"]
    rms = np.sqrt(np.mean(ERR_XY_CM**2))
    assert md_cells(out, "RMS |XY| (cm)")[1] == f"{rms:.1f}"
    assert all(md_cells(out, f)[5] != "worse" for f in ("RMS |XY| (cm)", "mean |XY| (cm)"))


def test_a_run_against_its_own_baseline_changes_by_exactly_nothing(
    run_files, baseline_json, capsys
):
    args = ("--baseline", baseline_json, "--fail-if-worse-cm", 0, "--fail-if-worse-deg", 0)
    code, out, err = evaluate(
        capsys, run_files["segloc"], run_files["survey"], *args, "--format", "json"
    )
    assert code == 0, err
    comparison = json.loads(out)["summary"]["baseline"]
    assert comparison["n_shared"] == N and not comparison["failed"]
    for figure in comparison["figures"]:
        assert figure["change"] == figure["low"] == figure["high"] == 0.0, figure
        assert figure["verdict"] == "no change shown"


def test_the_same_poses_in_another_format_are_no_change(run_files, baseline_json, capsys):
    args = ("--baseline", baseline_json, "--fail-if-worse-cm", 0, "--fail-if-worse-deg", 0)
    code, out, err = evaluate(
        capsys, run_files["tum"], run_files["survey"], *args, "--format", "json"
    )
    figures = json.loads(out)["summary"]["baseline"]["figures"]
    assert [f["verdict"] for f in figures] == ["no change shown"] * len(figures)
    assert code == 0, err


# --------------------------------------------------------------------------- covariance

N_COV = 500
SHARES_LINE = re.compile(
    r"Within the 1σ / 2σ / 3σ ellipse of the position covariance: "
    r"([\d.]+) / ([\d.]+) / ([\d.]+) % of poses"
)
NEES_LINE = re.compile(
    r"Mean NEES of the position ([\d.]+) \(expected 2; 95 % of consistent "
    r"localizers within ([\d.]+) to ([\d.]+) over (\d+) poses\)"
)


@pytest.fixture(scope="module")
def covariance_run(tmp_path_factory) -> tuple[Path, Path, Path, np.ndarray]:
    """A survey of ``N_COV`` poses, a ROS 2 bag of estimates whose errors are drawn from the
    covariances it carries, one of the same poses with covariances 10 times too small, and
    the position NEES of each pose worked out here."""
    where = tmp_path_factory.mktemp("covariance")
    rng = np.random.default_rng(5005)
    s = np.linspace(0.0, 20.0, N_COV)
    truth = np.column_stack([10.0 + 8.0 * np.cos(s / 4), 10.0 + 6.0 * np.sin(s / 3), s % np.pi])
    times_s = 100.0 + 0.2 * np.arange(N_COV)
    angles = rng.uniform(0.0, np.pi, N_COV)
    stds = np.column_stack(
        [rng.uniform(0.02, 0.06, N_COV), rng.uniform(0.01, 0.03, N_COV), np.full(N_COV, 0.01)]
    )
    covariances = np.zeros((N_COV, 3, 3))
    for i, (angle, std) in enumerate(zip(angles, stds, strict=True)):
        c, sn = np.cos(angle), np.sin(angle)
        r = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
        covariances[i] = r @ np.diag(std**2) @ r.T
    errors = np.einsum("nij,nj->ni", np.linalg.cholesky(covariances), rng.normal(size=(N_COV, 3)))
    estimates = truth + errors
    survey = where / "survey.csv"
    write_pose_table(survey, PoseTable(np.arange(1, N_COV + 1), times_s, truth))
    honest = write_amcl_bag(where / "honest", times_s, estimates, covariances)
    overconfident = write_amcl_bag(where / "overconfident", times_s, estimates, covariances / 10)
    xy = errors[:, :2]
    nees = np.einsum("ni,nij,nj->n", xy, np.linalg.inv(covariances[:, :2, :2]), xy)
    return survey, honest, overconfident, nees


def covariance_text(out: str) -> str:
    (line,) = [ln for ln in out.splitlines() if "ellipse of the position covariance" in ln]
    return line


def test_errors_drawn_from_their_covariance_are_judged_consistent(covariance_run, capsys):
    survey, honest, _, nees = covariance_run
    code, out, err = evaluate(capsys, honest, survey)
    assert code == 0, err
    text = covariance_text(out)
    shares = [float(v) for v in SHARES_LINE.search(text).groups()]
    expected = [f"{100.0 * np.mean(nees <= k * k):.1f}" for k in (1, 2, 3)]
    assert [f"{v:.1f}" for v in shares] == expected
    # A consistent localizer: 39.3, 86.5 and 98.9 %, give or take the draw of 500 poses.
    for share, ideal, reach in zip(shares, (39.3, 86.5, 98.9), (7.0, 5.0, 2.0), strict=True):
        assert abs(share - ideal) < reach
    mean_nees, low, high, n_used = NEES_LINE.search(text).groups()
    assert float(mean_nees) == pytest.approx(nees.mean(), abs=0.006)
    assert int(n_used) == N_COV and float(low) < nees.mean() < float(high)
    assert "Covariance verdict: consistent" in text


def test_covariances_ten_times_too_small_are_judged_over_confident(covariance_run, capsys):
    survey, _, overconfident, nees = covariance_run
    code, out, err = evaluate(capsys, overconfident, survey)
    assert code == 0, err
    text = covariance_text(out)
    mean_nees = float(NEES_LINE.search(text).group(1))
    assert mean_nees == pytest.approx(10.0 * nees.mean(), abs=0.006)
    assert "Covariance verdict: over-confident" in text


def test_the_covariance_section_says_covariance_once(covariance_run, capsys):
    survey, honest, _, _ = covariance_run
    code, out, _ = evaluate(capsys, honest, survey)
    assert code == 0
    assert "Covariance: Covariance:" not in out


# --------------------------------------------------------------------------- relations


def relative_motion(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """(K, 3): the motion from each pose of ``first`` to ``second``, in the first's frame."""
    dx, dy = second[:, 0] - first[:, 0], second[:, 1] - first[:, 1]
    c, s = np.cos(first[:, 2]), np.sin(first[:, 2])
    turn = np.angle(np.exp(1j * (second[:, 2] - first[:, 2])))
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, turn])


RELATION_PAIRS = [(i, i + step) for step in (1, 3) for i in range(N - step)]
_first, _second = (np.array(side) for side in zip(*RELATION_PAIRS, strict=True))
REFERENCE = relative_motion(TRUTH[_first], TRUTH[_second])
_estimated = relative_motion(POSES[_first], POSES[_second])
RELATION_ERR_CM = 100.0 * np.hypot(*(_estimated[:, :2] - REFERENCE[:, :2]).T)
"""The translational error of each relation, as the simulated errors make it."""

try:
    from segloc_cli.scoring.plots import relation_figures  # noqa: F401

    HAS_RELATION_FIGURES = True
except ImportError:
    HAS_RELATION_FIGURES = False


@pytest.fixture(scope="module")
def relations_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("relations") / "track.relations"
    lines = ["# t1 t2 dx dy dz droll dpitch dyaw"]
    for (i, j), (dx, dy, dyaw) in zip(RELATION_PAIRS, REFERENCE, strict=True):
        values = (TIMES_S[i], TIMES_S[j], dx, dy, 0.0, 0.0, 0.0, dyaw)
        lines.append(" ".join(repr(float(v)) for v in values))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def relations_run(capsys, run_files, relations_file, *args):
    return run_cli(capsys, "evaluate", run_files["segloc"], "--relations", relations_file, *args)


@pytest.mark.parametrize(("factor", "code"), [(1.05, 0), (0.95, 1)])
def test_the_mean_relation_gate_holds_the_simulated_mean(
    run_files, relations_file, capsys, factor, code
):
    mean_cm = RELATION_ERR_CM.mean()
    limit = f"{factor * mean_cm:.4f}"
    result = relations_run(capsys, run_files, relations_file, "--fail-mean-above-cm", limit)
    assert result.code == code, result.err
    verdict = "pass" if code == 0 else "FAIL"
    sign = "≤" if code == 0 else ">"
    gate = f"Gate: mean translational error {mean_cm:.1f} cm {sign} {float(limit):g} cm: {verdict}."
    assert gate in result.out.splitlines()
    assert (f"segloc: gate: mean translational error {mean_cm:.1f} cm" in result.err) == bool(code)
    n = len(RELATION_PAIRS)
    assert f": {n} of {n} relations have estimates at both times" in result.err


@pytest.mark.parametrize(("factor", "code"), [(1.02, 0), (0.98, 1)])
def test_the_percentile_relation_gate_holds_the_simulated_percentile(
    run_files, relations_file, capsys, factor, code
):
    p90_cm = np.percentile(RELATION_ERR_CM, 90)
    limit = f"{factor * p90_cm:.4f}"
    args = ("--fail-percentile-above-cm", limit, "--percentile", 90)
    result = relations_run(capsys, run_files, relations_file, *args)
    assert result.code == code, result.err
    sign = "≤" if code == 0 else ">"
    gate = f"90th percentile translational error {p90_cm:.1f} cm {sign} {float(limit):g} cm"
    assert gate in result.out


def test_a_per_pose_limit_with_relations_points_at_the_figure_gates(
    run_files, relations_file, capsys
):
    result = relations_run(capsys, run_files, relations_file, "--fail-above-cm", 5)
    assert_one_line_error(result, "--fail-mean-above-cm", "--fail-percentile-above-cm")


def test_relations_missing_an_end_fail_as_cases_of_their_own(
    run_files, relations_file, tmp_path, capsys
):
    from junitparser import Failure, JUnitXml

    # Estimates of every pose but the third: the relations that end there have no error.
    kept = np.arange(N) != 2
    estimates = write_csv_estimates(tmp_path / "est.csv", POSES[kept], TIMES_S[kept])
    report = tmp_path / "relations.xml"
    args = ("--relations", relations_file, "--fail-mean-above-cm", 100, "--junit", report)
    code, _, err = run_cli(capsys, "evaluate", estimates, *args)
    assert code == 1, err
    missing = [k for k, (i, j) in enumerate(RELATION_PAIRS) if 2 in (i, j)]
    (suite,) = JUnitXml.fromfile(str(report))
    cases = {case.name: case for case in suite}
    assert list(cases) == [
        *(f"relation {k + 1}" for k in missing),
        "gate: share of relations estimated at both ends ≥ 100 %",
        "gate: mean translational error ≤ 100 cm",
    ]
    failed = {
        name for name, case in cases.items() if any(isinstance(r, Failure) for r in case.result)
    }
    assert failed == {
        *(f"relation {k + 1}" for k in missing),
        "gate: share of relations estimated at both ends ≥ 100 %",
    }
    first = cases[f"relation {missing[0] + 1}"].result[0].message
    assert first == "no estimate within 50 ms of " + (
        "t1" if RELATION_PAIRS[missing[0]][0] == 2 else "t2"
    )


def test_relations_without_a_gate_give_a_junit_file_of_the_relations_missing_an_end(
    run_files, relations_file, tmp_path, capsys
):
    from junitparser import JUnitXml

    report = tmp_path / "relations.xml"
    code, _, err = relations_run(capsys, run_files, relations_file, "--junit", report)
    assert code == 0, err
    (suite,) = JUnitXml.fromfile(str(report))
    assert (suite.tests, suite.failures, suite.errors) == (0, 0, 0)
    # Estimates of every pose but the third: its relations are cases, which no gate fails.
    kept = np.arange(N) != 2
    estimates = write_csv_estimates(tmp_path / "est.csv", POSES[kept], TIMES_S[kept])
    missing = [k for k, (i, j) in enumerate(RELATION_PAIRS) if 2 in (i, j)]
    # Without a gate, and with gates that tolerate them (saying so once).
    for gates, tail in (((), ""), (("--min-paired-pct", 50), "; tolerated by the gates")):
        args = ("--relations", relations_file, "--junit", report, *gates)
        code, _, err = run_cli(capsys, "evaluate", estimates, *args)
        assert code == 0, err
        (suite,) = JUnitXml.fromfile(str(report))
        cases = [case for case in suite if case.name.startswith("relation ")]
        assert [case.name for case in cases] == [f"relation {k + 1}" for k in missing]
        assert suite.failures == 0 and all(case.is_passed for case in suite)
        for case, k in zip(cases, missing, strict=True):
            i, j = RELATION_PAIRS[k]
            end = "t1" if i == 2 else "t2"
            assert case.system_out == (
                f"t1 {TIMES_S[i]:.3f} s, t2 {TIMES_S[j]:.3f} s: no estimate within 50 ms of "
                f"{end}{tail}"
            )


def test_relation_figures_are_drawn_as_pngs(run_files, relations_file, tmp_path, capsys):

    plots = tmp_path / "plots"
    result = relations_run(capsys, run_files, relations_file, "--plots", plots)
    assert result.code == 0, result.err
    pngs = sorted(plots.glob("*.png"))
    assert len(pngs) >= 2  # the trajectory and the relation errors over time
    for png in pngs:
        with Image.open(png) as image:
            assert image.format == "PNG"
            assert image.width > 100 and image.height > 100
            pixels = np.asarray(image.convert("L"))
        assert len(np.unique(pixels)) > 8  # more than a blank canvas
        assert f"wrote {png}" in result.err


def test_a_relations_page_holds_the_relation_table(run_files, relations_file, tmp_path, capsys):
    page = tmp_path / "relations.html"
    result = relations_run(capsys, run_files, relations_file, "--html", page)
    assert result.code == 0, result.err
    text = page.read_text(encoding="utf-8")
    assert "Relations" in text and "<img " in text


# --------------------------------------------------------------------------- HTML page


# --------------------------------------------------------------------------- bad input


def _wrong_shape_json(tmp_path: Path) -> Path:
    path = tmp_path / "wrong.json"
    path.write_text(json.dumps({"rows": [{"pose_id": 1}]}), encoding="utf-8")
    return path


def _not_json(tmp_path: Path) -> Path:
    path = tmp_path / "notes.json"
    path.write_text("pose_id,err_x_cm\n1,2.0\n", encoding="utf-8")
    return path


# Each: the arguments after ``evaluate`` (files by name, tmp_path-made files by function),
# and the phrases the one error line must hold.
BAD_INPUT = {
    "frames-one": (
        ("ros1", "--topic", "/amcl_pose", "--frames", "map"),
        ["--frames", "PARENT,CHILD"],
    ),
    "frames-same": (("ros1", "--topic", "/amcl_pose", "--frames", "a,a"), ["two different frames"]),
    "topic-missing": (("ros1",), ["--topic", "2 pose topics", "/amcl_pose", "/odom"]),
    "topic-unknown": (("ros1", "--topic", "/nope"), ["no topic /nope", "/amcl_pose"]),
    "tum-on-ros1-bag": (("ros1", "--est-format", "tum"), ["amcl.bag", "TUM"]),
    "tum-on-ros2-bag": (("ros2", "--est-format", "tum"), ["amcl_ros2", "TUM"]),
    "baseline-not-json": (("segloc", "--baseline", _not_json), ["notes.json", "not JSON"]),
    "baseline-wrong-shape": (
        ("segloc", "--baseline", _wrong_shape_json),
        ["wrong.json", '"poses"', "--format json"],
    ),
    "percentile-101": (
        ("segloc", "--fail-percentile-above-cm", 5, "--percentile", 101),
        ["--percentile", "101"],
    ),
    "min-within-alone": (("segloc", "--min-within-pct", 90), ["--min-within-pct", "--fail-above"]),
    "worse-without-baseline": (("segloc", "--fail-if-worse-cm", 1), ["--baseline"]),
}


@pytest.mark.parametrize("case", list(BAD_INPUT))
def test_each_bad_option_is_one_line_and_exit_2(run_files, tmp_path, capsys, case):
    given, phrases = BAD_INPUT[case]
    estimates, *rest = given
    args = [a(tmp_path) if callable(a) else a for a in rest]
    result = evaluate(capsys, run_files[estimates], run_files["survey"], *args)
    assert result.out == ""
    assert_one_line_error(result, *phrases)


def test_an_existing_table_needs_force_and_nothing_is_written(run_files, tmp_path, capsys):
    table = tmp_path / "table.md"
    table.write_text("old table\n", encoding="utf-8")
    args = [
        "--junit", tmp_path / "report.xml",
        "--summary-md", tmp_path / "summary.md",
        "--html", tmp_path / "page.html",
        "--out", table,
        "--plots", tmp_path / "plots",
    ]  # fmt: skip
    result = evaluate(capsys, run_files["segloc"], run_files["survey"], *args)
    assert_one_line_error(result, "table.md", "--out", "--force")
    assert result.out == ""
    assert table.read_text(encoding="utf-8") == "old table\n"
    assert [p.name for p in tmp_path.iterdir()] == ["table.md"]


def test_reports_are_replaced_on_a_rerun_without_force(run_files, tmp_path, capsys):
    reports = {
        "--junit": tmp_path / "report.xml",
        "--summary-md": tmp_path / "summary.md",
        "--html": tmp_path / "page.html",
    }
    for path in reports.values():
        path.write_text("from an earlier run\n", encoding="utf-8")
    args = [item for option, path in reports.items() for item in (option, path)]
    code, _, err = evaluate(capsys, run_files["segloc"], run_files["survey"], *args)
    assert code == 0, err
    for path in reports.values():
        assert "from an earlier run" not in path.read_text(encoding="utf-8")


def test_junit_and_html_naming_one_file_are_refused(run_files, tmp_path, capsys):
    same = tmp_path / "report.out"
    args = ("--junit", same, "--html", same)
    result = evaluate(capsys, run_files["segloc"], run_files["survey"], *args)
    assert_one_line_error(result, "--junit and --html name the same file")
    assert list(tmp_path.iterdir()) == []


def test_a_baseline_with_relations_is_refused(run_files, relations_file, baseline_json, capsys):
    args = ("--baseline", baseline_json)
    result = relations_run(capsys, run_files, relations_file, *args)
    assert_one_line_error(result, "--baseline goes with --survey")


def test_bad_input_appends_nothing_to_the_step_summary(run_files, tmp_path, capsys, monkeypatch):
    step_summary = tmp_path / "step_summary.md"
    step_summary.write_text("earlier\n", encoding="utf-8")
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(step_summary))
    result = evaluate(capsys, run_files["ros1"], run_files["survey"], "--topic", "/nope")
    assert_one_line_error(result, "no topic /nope")
    assert step_summary.read_text(encoding="utf-8") == "earlier\n"
