"""README's "Evaluating another localizer in CI", run as written: two ROS 2 bags of simulated
AMCL estimates over the hall's survey (a main branch's run and a pull request's, worse by
4 cm on every pose), scored with a gate, a JUnit file, a step summary and a baseline; the
output README quotes must be the output the commands print."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from junitparser import JUnitXml
from test_cli import run_cli
from trajectory_samples import write_amcl_bag

from segloc_cli.io.tables import read_pose_table

ROOT = Path(__file__).resolve().parents[1]
SURVEY = ROOT / "datasets" / "hall" / "survey.csv"
SIGMA_M, SIGMA_RAD = 0.03, np.deg2rad(0.5)
"""AMCL's claimed 1σ: 3 cm per axis, 0.5° in heading; the simulated errors are drawn from it."""
WORSE_CM = 4.0


def amcl_run(path: Path, seed: int, worse_cm: float = 0.0) -> Path:
    """A ROS 2 bag of ``/amcl_pose`` at the survey's times: the surveyed poses plus errors
    drawn from the covariance each message carries, pushed ``worse_cm`` further out."""
    survey = read_pose_table(SURVEY)
    rng = np.random.default_rng(seed)
    n = len(survey)
    covariance = np.diag([SIGMA_M**2, SIGMA_M**2, SIGMA_RAD**2])
    errors = rng.multivariate_normal(np.zeros(3), covariance, size=n)
    norms = np.hypot(errors[:, 0], errors[:, 1])
    errors[:, :2] *= ((norms + worse_cm / 100.0) / norms)[:, None]
    poses = survey.poses + errors
    return write_amcl_bag(path, survey.time_s, poses, np.repeat(covariance[None], n, axis=0))


def quoted_output(name: str) -> list[str]:
    """The lines of README's fenced block after the ``<!-- name -->`` marker."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    match = re.search(rf"<!-- {name} -->\n```[a-z]*\n(.*?)```", text, re.S)
    assert match, f"README lacks the block marked {name}"
    return [line for line in match.group(1).splitlines() if line.strip()]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("amcl")
    amcl_run(folder / "main", seed=7)
    amcl_run(folder / "pr", seed=8, worse_cm=WORSE_CM)
    return folder


def test_the_readme_example_prints_what_readme_says(runs, capsys, monkeypatch):
    monkeypatch.chdir(runs)
    step_summary = runs / "step_summary.md"
    step_summary.write_text("earlier steps\n")
    monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(step_summary))
    survey = str(SURVEY)
    code, _, err = run_cli(
        capsys, "evaluate", "main", "--topic", "/amcl_pose", "--survey", survey,
        "--format", "json", "--out", "main.json", "--force",
    )  # fmt: skip
    assert code == 0, err
    code, out, err = run_cli(
        capsys, "evaluate", "pr", "--topic", "/amcl_pose", "--survey", survey,
        "--fail-above-xy-cm", "10", "--junit", "amcl.xml", "--baseline", "main.json",
        "--fail-if-worse-cm", "1", "--force",
    )  # fmt: skip
    assert code == 1, err
    printed = out.splitlines() + err.splitlines()
    missing = [line for line in quoted_output("ci-example-output") if line not in printed]
    assert not missing, f"README quotes lines the command does not print: {missing}"
    # The JUnit file: a case per surveyed pose and per gate, the baseline's among them.
    suite = next(iter(JUnitXml.fromfile(str(runs / "amcl.xml"))))
    names = [case.name for case in suite]
    assert names[:10] == [f"pose {i}" for i in range(1, 11)]
    failed = [case.name for case in suite if not case.is_passed]
    assert any(name.startswith("worsening of RMS |XY|") for name in failed)
    # The step summary is appended to, the earlier steps' text kept.
    summary = step_summary.read_text()
    assert summary.startswith("earlier steps\n") and "### segloc evaluate: FAIL" in summary
