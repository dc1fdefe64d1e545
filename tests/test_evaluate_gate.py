"""``segloc evaluate`` as a CI gate a silent localizer cannot pass: a localizer that stopped
publishing (a ROS 2 bag of AMCL's ``/amcl_pose`` holding the first 10 % of the surveyed
poses) fails every per-pose gate and the share of poses with an estimate, one JUnit test
case per pose it left out; the whole run passes; the JUnit file's names are the same from
run to run and it fails exactly when the exit status does; the HTML page gives the verdict
and the gates on its first screen; the summary of 16,000 poses stays under GitHub's 1 MiB."""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pytest
from amcl_bags import write_amcl_bag
from junitparser import Failure, JUnitXml
from test_cli import run_cli
from trajectory_samples import estimates_frame

from segloc_cli.estimates import PoseTable
from segloc_cli.io.tables import write_estimates, write_pose_table
from segloc_cli.runs.reports import STEP_SUMMARY_LIMIT_BYTES

N = 340
"""Surveyed poses, as in the log the gate was first tried on."""
SHARE_PUBLISHED = 0.1
T0_S = 1_700_000_000.0
PERIOD_S = 0.5
LIMIT_CM = 10.0
rng = np.random.default_rng(43)
_s = np.linspace(0.0, 2.0 * np.pi, N)
TRUTH = np.column_stack([20.0 + 8.0 * np.cos(_s), 12.0 + 5.0 * np.sin(_s), _s + np.pi / 2.0])
NOISE = np.column_stack([rng.normal(0.0, 0.02, (N, 2)), np.radians(rng.normal(0.0, 0.3, N))])
"""AMCL's errors (x m, y m, θ rad): 2 cm and 0.3° a side, every pose within the 10 cm gate."""
TIMES_S = T0_S + PERIOD_S * np.arange(N)
COVARIANCES = np.tile(np.diag([0.02**2, 0.02**2, np.radians(0.3) ** 2]), (N, 1, 1))
GATE = ("--fail-above-xy-cm", LIMIT_CM)


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """The survey, AMCL's bag of every pose and the bag of a localizer that fell silent."""
    where = tmp_path_factory.mktemp("gate")
    survey = where / "survey.csv"
    write_pose_table(survey, PoseTable(np.arange(1, N + 1), TIMES_S, TRUTH))
    estimates = TRUTH + NOISE
    n_published = int(N * SHARE_PUBLISHED)
    part = slice(0, n_published)
    return {
        "survey": survey,
        "whole": write_amcl_bag(where / "whole", TIMES_S, estimates, COVARIANCES),
        "silent": write_amcl_bag(
            where / "silent", TIMES_S[part], estimates[part], COVARIANCES[part]
        ),
    }


def junit_run(capsys, runs, tmp_path, bag: str, *args) -> tuple[int, str, JUnitXml]:
    report = tmp_path / f"{bag}.xml"
    code, _, err = run_cli(
        capsys, "evaluate", runs[bag], "--survey", runs["survey"], "--junit", report, *args
    )
    (suite,) = JUnitXml.fromfile(str(report))
    return code, err, suite


def failed_names(suite) -> set[str]:
    return {case.name for case in suite if any(isinstance(r, Failure) for r in case.result)}


def test_a_localizer_that_stopped_publishing_fails_every_gate(runs, tmp_path, capsys):
    code, err, suite = junit_run(capsys, runs, tmp_path, "silent", *GATE)
    n_published = int(N * SHARE_PUBLISHED)
    assert code == 1, err
    poses = [case for case in suite if case.classname.endswith(".poses")]
    assert [case.name for case in poses] == [f"pose {i}" for i in range(1, N + 1)]
    silent = {f"pose {i}" for i in range(n_published + 1, N + 1)}
    gates = {
        "gate: share of surveyed poses with an estimate ≥ 100 %",
        "gate: max position error |XY| ≤ 10 cm",
        "gate: share of poses accepted and within |XY| ≤ 10 cm ≥ 100 %",
    }
    # Every pose it left out fails, each for want of an estimate; every gate fails.
    assert failed_names(suite) == silent | gates
    messages = {
        case.result[0].message for case in poses if case.name in silent and len(case.result)
    }
    assert messages == {"no estimate within 50 ms"}
    assert suite.failures == len(silent) + len(gates)
    (share,) = [case for case in suite if case.name.startswith("gate: share of surveyed")]
    assert share.system_out == (
        "share of surveyed poses with an estimate 10.0 % < 100 % (34 of 340 within 50 ms): FAIL"
    )
    # Under half of the survey paired: said even before any gate.
    (warning,) = [line for line in err.splitlines() if "warning" in line]
    assert "only 34 of 340 surveyed poses (10.0 %) have an estimate within 50 ms" in warning
    verdict = [line for line in err.splitlines() if line.startswith("segloc: FAIL: ")]
    assert verdict == [
        "segloc: FAIL: 3 of 3 gates failed (share of surveyed poses with an estimate ≥ 100 %; "
        "max position error |XY| ≤ 10 cm; share of poses accepted and within |XY| ≤ 10 cm ≥ "
        "100 %); 306 of 340 poses failed, 306 without an estimate: 35, 36, 37, 38, 39, 40, "
        "41, 42, 43, 44 and 296 more."
    ]


def test_the_same_localizer_publishing_every_pose_passes(runs, tmp_path, capsys):
    code, err, suite = junit_run(capsys, runs, tmp_path, "whole", *GATE)
    assert code == 0, err
    assert (suite.tests, suite.failures) == (N + 3, 0)
    assert "warning" not in err


def test_the_share_of_poses_with_an_estimate_is_a_gate_of_its_own(runs, tmp_path, capsys):
    # 10 % answered: a 5 % floor passes, and so does every pose it left out, told so.
    code, err, suite = junit_run(capsys, runs, tmp_path, "silent", "--min-paired-pct", 5)
    assert code == 0, err
    assert suite.failures == 0
    (pose,) = [case for case in suite if case.name == f"pose {N}"]
    assert pose.system_out.endswith("no estimate within 50 ms")
    # Without any gate nothing fails, but a survey that pairs under half is warned of.
    code, err, suite = junit_run(capsys, runs, tmp_path, "silent")
    assert (code, suite.failures, suite.tests) == (0, 0, N)
    assert "segloc: warning: only 34 of 340 surveyed poses" in err


def test_junit_names_stay_and_failures_agree_with_the_exit_status(runs, tmp_path, capsys):
    # Three runs with three outcomes: every pose within, one pose tolerated by
    # --min-within-pct, one pose failing.
    limit = 100.0 * float(np.sort(np.hypot(NOISE[:, 0], NOISE[:, 1]))[-2] + 1e-4)
    runs_seen = []
    for gate in (GATE, ("--fail-above-xy-cm", limit, "--min-within-pct", 99)):
        runs_seen.append(junit_run(capsys, runs, tmp_path, "whole", *gate))
    runs_seen.append(junit_run(capsys, runs, tmp_path, "whole", "--fail-above-xy-cm", limit))
    codes = [code for code, _, _ in runs_seen]
    assert codes == [0, 0, 1]
    # The last fails its pose and both per-pose gates.
    assert [suite.failures for _, _, suite in runs_seen] == [0, 0, 3]
    pose_names = [
        [case.name for case in suite if case.classname.endswith(".poses")]
        for _, _, suite in runs_seen
    ]
    assert pose_names[0] == pose_names[1] == pose_names[2]
    # The gates' names carry the limits asked, never the counts found.
    for _, _, suite in runs_seen:
        for case in suite:
            assert not re.search(r"\(\d+ of \d+", case.name), case.name


def test_the_page_gives_the_verdict_and_gates_on_its_first_screen(runs, tmp_path, capsys):
    from PIL import Image
    from test_html_report import assert_images_drawn, browse

    from segloc_cli.scoring.plots import TABLE_FIGURES

    page = tmp_path / "report.html"
    args = ("--survey", runs["survey"], *GATE, "--html", page, "--min-within-pct", 95)
    code, _, err = run_cli(capsys, "evaluate", runs["silent"], *args)
    assert code == 1, err
    seen = browse(page, viewport=(1400, 900), locate=("p.verdict", "table.gates"))
    assert seen.complaints == []
    verdict, gates = seen.located["p.verdict"], seen.located["table.gates"]
    assert verdict is not None and gates is not None
    assert verdict["y"] + verdict["height"] <= 900
    assert gates["y"] + gates["height"] <= 900
    # The first screen shows the failure in red: the verdict line and the badge.
    with Image.open(io.BytesIO(seen.first_screen)) as screen:
        pixels = np.asarray(screen.convert("RGB"), dtype=int)
    red = (pixels[..., 0] > 150) & (pixels[..., 1] < 60) & (pixels[..., 2] < 80)
    assert red.sum() > 500
    # Without --map and --log the run draws the figures of the table alone, each shown.
    assert len(seen.images) == len(TABLE_FIGURES)
    assert_images_drawn(seen)
    for header in ("pose", "X (cm)", "Y (cm)", "XY (cm)", "θ (°)", "status", "gate"):
        assert header in seen.text
    # The table of every pose is there, folded: a row each, and the RMS and max rows.
    html = page.read_text(encoding="utf-8")
    folded = html[html.index("<details>") : html.index("</details>")]
    assert folded.count("<tr") == 1 + N + 2
    assert folded.count('<tr class="failing">') == N - int(N * SHARE_PUBLISHED)


def test_the_summary_of_16000_poses_stays_under_a_step_summarys_limit(
    tmp_path, capsys, monkeypatch
):
    n = 16_000
    times_s = T0_S + 0.1 * np.arange(n)
    angle = np.linspace(0.0, 20.0 * np.pi, n)
    truth = np.column_stack([50.0 * np.cos(angle / 10), 30.0 * np.sin(angle / 10), angle])
    survey = tmp_path / "survey.csv"
    write_pose_table(survey, PoseTable(np.arange(1, n + 1), times_s, truth))
    estimates = truth + np.column_stack([np.full((n, 2), 0.2), np.zeros(n)])  # 28 cm off
    est = tmp_path / "est.csv"
    write_estimates(est, estimates_frame(times_s, estimates))
    step_summary = tmp_path / "step.md"
    step_summary.write_text("x" * 100_000 + "\n", encoding="utf-8")
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(step_summary))
    summary = tmp_path / "summary.md"
    out = tmp_path / "table.md"
    args = ("--survey", survey, *GATE, "--summary-md", summary, "--out", out)
    code, _, err = run_cli(capsys, "evaluate", est, *args)
    assert code == 1, err
    text = summary.read_text(encoding="utf-8")
    assert len(text.encode("utf-8")) < 1_000_000
    assert step_summary.stat().st_size < STEP_SUMMARY_LIMIT_BYTES
    shown = re.search(r"This summary shows the first (\d+) of 16000 poses", text)
    assert shown is not None and 1000 < int(shown.group(1)) < n
    assert f"every pose is in --out {out}" in text
    # The answer is whole: every pose failed, the first ones listed with why.
    assert "16000 of 16000 poses failed: 1, 2, 3" in text
    assert "|XY\\| 28.3 cm > 10.0 cm" in text
