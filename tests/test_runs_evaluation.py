"""``runs.evaluation``: evaluate's options, typed, and what they say of themselves."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from segloc_cli.runs.evaluation import GATE_SHOWN, EvaluateOptions, SurveyScores

EST = Path("est.csv")


@pytest.mark.parametrize(
    ("given", "problem"),
    [
        ({}, "give exactly one of --survey and --relations"),
        ({"survey_path": Path("s"), "relations_path": Path("r")}, "give exactly one of"),
        ({"survey_path": Path("s"), "map_path": Path("m")}, "--map and --log go with --plots"),
        ({"relations_path": Path("r"), "plots_dir": Path("p")}, "--plots goes with --survey"),
        ({"relations_path": Path("r"), "fail_above_cm": 1.0}, "--fail-above-cm/--fail-above"),
        ({"survey_path": Path("s"), "published": "intel"}, "--published goes with --relations"),
        ({"survey_path": Path("s"), "plots_dir": Path("p"), "log_path": Path("l")}, None),
        ({"relations_path": Path("r"), "published": "intel"}, None),
    ],
)
def test_options_that_do_not_go_together_are_named(given, problem):
    said = EvaluateOptions(EST, **given).usage_problem()
    assert said == problem or (problem is not None and said.startswith(problem))


def test_the_files_read_and_written_are_listed():
    options = EvaluateOptions(EST, survey_path=Path("s.csv"), out_path=Path("t.md"))
    assert options.inputs == [EST, Path("s.csv"), None, None, None]
    assert options.outputs == {"--out": Path("t.md"), "--out (run file)": Path("t.run.toml")}
    assert EvaluateOptions(EST).outputs == {"--out": None}
    assert not options.with_map
    assert options.tolerance_s == 0.05 and options.limits == (None, None)


def test_the_violations_line_names_the_first_few():
    violations = [f"pose {i}: status lost" for i in range(GATE_SHOWN + 2)]
    line = SurveyScores(pd.DataFrame(), "", violations).violations_line
    assert line.startswith("pose 0: status lost; pose 1") and line.endswith("; and 2 more")
    assert SurveyScores(pd.DataFrame(), "", violations[:1]).violations_line == violations[0]
