"""``runs.evaluation``: evaluate's options, typed, and what they say of themselves."""

from __future__ import annotations

from pathlib import Path

import pytest

from segloc_cli.runs.evaluation import GATE_SHOWN, EvaluateOptions, Item, Scores
from segloc_cli.scoring.gates import GateOutcome, Gates

EST = Path("est.csv")


@pytest.mark.parametrize(
    ("given", "problem"),
    [
        ({}, "give exactly one of --survey and --relations"),
        ({"survey_path": Path("s"), "relations_path": Path("r")}, "give exactly one of"),
        ({"survey_path": Path("s"), "map_path": Path("m")}, "--map and --log go with --plots"),
        ({"relations_path": Path("r"), "plots_dir": Path("p")}, None),
        ({"relations_path": Path("r"), "gates": Gates(axis_cm=1.0)}, "relations bound no single"),
        ({"relations_path": Path("r"), "gates": Gates(mean_cm=1.0)}, None),
        ({"relations_path": Path("r"), "plots_dir": Path("p"), "log_path": Path("l")}, "--log"),
        ({"relations_path": Path("r"), "baseline_path": Path("b")}, "--baseline goes with"),
        ({"survey_path": Path("s"), "gates": Gates(min_within_pct=90)}, "--min-within-pct"),
        ({"survey_path": Path("s"), "gates": Gates(percentile=50)}, "--percentile goes with"),
        ({"survey_path": Path("s"), "fail_if_worse_cm": 1.0}, "--fail-if-worse-cm/"),
        ({"survey_path": Path("s"), "html_path": Path("h"), "map_path": Path("m")}, None),
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
    assert options.inputs == [EST, Path("s.csv"), None, None, None, None]
    assert options.outputs == {
        "--out": Path("t.md"),
        "--out (run file)": Path("t.run.toml"),
        "--junit": None,
        "--summary-md": None,
        "--html": None,
    }
    assert EvaluateOptions(EST).outputs["--out"] is None
    assert not options.with_map
    assert options.tolerance_s == 0.05 and not options.gates.any


def test_gate_options_become_gates():
    given = {"survey_path": Path("s"), "fail_above_xy_cm": 5.0, "fail_rms_above_deg": 1.0}
    options = EvaluateOptions.from_options(EST, given | {"fail_above_cm": None})
    # Any gate brings the share of poses with an estimate along, at 100 % unless told.
    assert options.gates == Gates(xy_cm=5.0, rms_deg=1.0, min_paired_pct=100.0)
    told = EvaluateOptions.from_options(EST, given | {"min_paired_pct": 90.0})
    assert told.gates.min_paired_pct == 90.0
    assert EvaluateOptions.from_options(EST, {"survey_path": Path("s")}).gates == Gates()
    # So does a limit against a baseline, with the poses compared bounded too.
    worse = EvaluateOptions.from_options(EST, {"baseline_path": Path("b"), "fail_if_worse_cm": 1})
    assert (worse.gates.min_paired_pct, worse.fail_if_fewer_pct) == (100.0, 0.0)


def lost_poses(n: int) -> tuple[Item, ...]:
    return tuple(Item(f"pose {i}", "", ("status lost",)) for i in range(n))


def test_the_violations_line_names_the_first_few():
    violations = [f"pose {i}: status lost" for i in range(GATE_SHOWN + 2)]
    share = GateOutcome("share of poses accepted", 0.0, 100.0, "%", False, True, True)
    line = Scores("", "", [share], {}, items=lost_poses(GATE_SHOWN + 2)).violations_line
    assert line.startswith("pose 0: status lost; pose 1") and line.endswith("; and 2 more")
    assert Scores("", "", [share], {}, items=lost_poses(1)).violations_line == violations[0]
    # With --min-within-pct the share held: the poses beyond are no violation.
    held = GateOutcome("share of poses accepted", 90.0, 80.0, "%", True, True, True)
    assert Scores("", "", [held], {}, items=lost_poses(3)).passed
    assert Scores("", "", [held], {}, items=lost_poses(3)).violations == []


def test_a_pose_without_an_estimate_fails_with_the_gate_that_counts_it():
    missing = Item("pose 7", "no estimate within 50 ms", ("no estimate within 50 ms",), True)
    beyond = Item("pose 8", "X 12.0 cm ...", ("|XY| 12.0 cm > 10.0 cm",))
    paired = GateOutcome("share with an estimate", 50.0, 100.0, "%", False, True, coverage=True)
    tolerated = GateOutcome("share accepted", 90.0, 80.0, "%", True, True, per_pose=True)
    scores = Scores("", "", [paired, tolerated], {}, items=(missing, beyond), n_truth=2)
    # The pose without an estimate fails with the coverage gate; the one beyond the limit is
    # tolerated by --min-within-pct.
    assert [scores.fails(item) for item in scores.items] == [True, False]
    assert scores.verdict_line == (
        "FAIL: 1 of 2 gates failed (share with an estimate ≥ 100 %); 1 of 2 poses failed, "
        "1 without an estimate: 7."
    )
