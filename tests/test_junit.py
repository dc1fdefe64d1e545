"""The JUnit file of evaluate, read back as CI reads it (junitparser) and held against the
shape pytest's own ``--junitxml`` gives."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import xml.etree.ElementTree as ET

import pandas as pd
import pytest
from junitparser import Failure, JUnitXml, TestCase, TestSuite

from segloc_cli.io.files import OutputError
from segloc_cli.io.junit import junit_xml, write_junit
from segloc_cli.scoring.evaluate import TABLE_COLUMNS
from segloc_cli.scoring.gates import GateOutcome


def make_table(rows: list[tuple[int, float, float, float, str]]) -> pd.DataFrame:
    """Table 1 rows from (pose_id, err_x_cm, err_y_cm, err_theta_deg, status)."""
    ids, xs, ys, thetas, statuses = zip(*rows, strict=True)
    table = pd.DataFrame(
        {
            "pose_id": ids,
            "err_x_cm": xs,
            "err_y_cm": ys,
            "err_theta_deg": thetas,
            "status": statuses,
        }
    )
    table["err_xy_cm"] = [math.hypot(x, y) for x, y in zip(xs, ys, strict=True)]
    # The columns these scores do not read (initial errors, times) hold zeros.
    for column in set(TABLE_COLUMNS) - set(table.columns):
        table[column] = 0.0
    return table[list(TABLE_COLUMNS)]


TABLE = make_table(
    [
        (1, -1.23, 0.41, 0.456, "ok"),
        (2, 6.0, -8.0, -1.5, "ok"),
        (5, math.nan, math.nan, math.nan, "lost"),
        (9, 0.02, -0.04, 0.001, "recovered"),
    ]
)
FAILURES = {2: ["|err_x| 6.0 cm > 5.0 cm", "|err_y| 8.0 cm > 5.0 cm"], 5: ["status lost"], 9: []}
OUTCOMES = [
    GateOutcome("RMS position error", 5.1, 5.0, "cm", passed=False),
    GateOutcome("share of poses within limits", 75.0, 50.0, "%", passed=True, at_least=True),
]
PROPERTIES = {"map": "hall.json", "estimates sha256": "ab12", "--fail-above-cm": "5"}


def cases_of(text: str) -> tuple[TestSuite, dict[str, TestCase]]:
    (suite,) = JUnitXml.fromstring(text.encode("utf-8"))
    return suite, {case.name: case for case in suite}


def failure_of(case: TestCase) -> Failure | None:
    results = [result for result in case.result if isinstance(result, Failure)]
    assert len(results) == len(case.result) <= 1
    return results[0] if results else None


def test_one_case_per_pose_and_gate_failed_exactly_where_told():
    suite, cases = cases_of(junit_xml(TABLE, FAILURES, OUTCOMES, properties=PROPERTIES))
    assert suite.name == "segloc evaluate"
    assert list(cases) == [
        "pose 1",
        "pose 2",
        "pose 5",
        "pose 9",
        "RMS position error",
        "share of poses within limits",
    ]
    assert (suite.tests, suite.failures, suite.errors, suite.skipped) == (6, 3, 0, 0)
    failed = {name for name, case in cases.items() if failure_of(case) is not None}
    assert failed == {"pose 2", "pose 5", "RMS position error"}
    assert {cases[f"pose {i}"].classname for i in (1, 2, 5, 9)} == {"segloc evaluate.poses"}
    assert cases["RMS position error"].classname == "segloc evaluate.gates"

    pose_2 = failure_of(cases["pose 2"])
    assert pose_2 is not None
    assert pose_2.message == "|err_x| 6.0 cm > 5.0 cm; |err_y| 8.0 cm > 5.0 cm"
    assert pose_2.type == "gate"
    gate = failure_of(cases["RMS position error"])
    assert gate is not None and gate.message == OUTCOMES[0].text


def test_each_case_says_its_figures_in_one_line():
    _, cases = cases_of(junit_xml(TABLE, FAILURES, OUTCOMES))
    assert cases["pose 1"].system_out == "X -1.2 cm, Y 0.4 cm, |XY| 1.3 cm, θ 0.46°, status ok"
    assert cases["pose 2"].system_out == "X 6.0 cm, Y -8.0 cm, |XY| 10.0 cm, θ -1.50°, status ok"
    assert cases["pose 5"].system_out == "X none cm, Y none cm, |XY| none cm, θ none°, status lost"
    # A sign the shown precision cannot support is dropped.
    assert cases["pose 9"].system_out.startswith("X 0.0 cm, Y 0.0 cm, |XY| 0.0 cm, θ 0.00°")
    assert cases["share of poses within limits"].system_out == OUTCOMES[1].text
    assert cases["share of poses within limits"].system_out.endswith("pass")


def test_properties_and_suite_name_and_timestamp():
    text = junit_xml(
        TABLE, {}, [], suite="hall", properties=PROPERTIES, timestamp="2024-05-01T10:00:00"
    )
    suite, cases = cases_of(text)
    assert {p.name: p.value for p in suite.properties()} == PROPERTIES
    assert suite.name == "hall" and suite.timestamp == "2024-05-01T10:00:00"
    assert {case.classname for case in cases.values()} == {"hall.poses"}
    assert suite.failures == 0


def test_reasons_for_a_pose_not_in_the_table_are_refused():
    with pytest.raises(ValueError, match=r"\[7\]"):
        junit_xml(TABLE, {7: ["status lost"]}, [])


HOSTILE = "a \"quoted\" 'b' <tag> & &amp; ü θ 漢字 🙂\ttab"


def test_hostile_strings_round_trip_and_control_characters_stay_readable(tmp_path):
    table = make_table([(3, 1.0, 2.0, 0.5, HOSTILE), (4, 1.0, 2.0, 0.5, "bell\x07 nul\x00")])
    outcome = GateOutcome(HOSTILE, 1.0, 2.0, "cm", passed=False)
    path = tmp_path / "junit.xml"
    write_junit(
        path,
        junit_xml(
            table,
            {3: [HOSTILE, "line\nbreak"], 4: ["esc\x1b"]},
            [outcome],
            suite=HOSTILE,
            properties={HOSTILE: HOSTILE + "\x01"},
        ),
    )
    (suite,) = JUnitXml.fromfile(str(path))
    cases = {case.name: case for case in suite}
    assert suite.name == HOSTILE
    assert {p.name: p.value for p in suite.properties()} == {HOSTILE: HOSTILE + "\\x01"}
    assert cases["pose 3"].classname == HOSTILE + ".poses"
    assert cases["pose 3"].system_out.endswith("status " + HOSTILE)
    assert failure_of(cases["pose 3"]).message == HOSTILE + "; line\nbreak"
    assert cases["pose 4"].system_out.endswith("status bell\\x07 nul\\x00")
    assert failure_of(cases["pose 4"]).message == "esc\\x1b"
    assert failure_of(cases[HOSTILE]).message == outcome.text


def test_written_file_is_the_text_and_a_missing_folder_is_one_error(tmp_path):
    text = junit_xml(TABLE, FAILURES, OUTCOMES)
    write_junit(tmp_path / "j.xml", text)
    assert (tmp_path / "j.xml").read_text(encoding="utf-8") == text
    assert list(tmp_path.iterdir()) == [tmp_path / "j.xml"]
    with pytest.raises(OutputError, match="cannot write"):
        write_junit(tmp_path / "no such folder" / "j.xml", text)


PYTEST_SESSION = """
def test_passes(record_testsuite_property):
    record_testsuite_property("setting", "1")
    print("figures")

def test_fails():
    print("figures")
    assert False, "reason"
"""


def shape(root: ET.Element) -> tuple[dict[str, set[str]], set[tuple[str, str]]]:
    """Attribute names of each element name, and the (parent, child) element names."""
    attributes: dict[str, set[str]] = {}
    nesting = set()
    for parent in root.iter():
        attributes.setdefault(parent.tag, set()).update(parent.attrib)
        nesting |= {(parent.tag, child.tag) for child in parent}
    return attributes, nesting


def test_shape_is_the_one_pytest_writes(tmp_path):
    (tmp_path / "test_tiny.py").write_text(PYTEST_SESSION, encoding="utf-8")
    (tmp_path / "pytest.ini").write_text("[pytest]\njunit_logging = system-out\n")
    report = tmp_path / "pytest.xml"
    command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-c", "pytest.ini"]
    subprocess.run(
        [*command, "test_tiny.py", f"--junitxml={report}"],
        cwd=tmp_path,
        env={**os.environ, "PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1"},
        capture_output=True,
        check=False,
    )
    theirs = shape(ET.parse(report).getroot())
    ours = shape(ET.fromstring(junit_xml(TABLE, FAILURES, OUTCOMES, properties=PROPERTIES)))
    assert ours[1] <= theirs[1], ours[1] - theirs[1]
    for element, names in ours[0].items():
        # pytest gives a failure no type; the JUnit schema does, and junitparser reads it.
        allowed = theirs[0][element] | ({"type"} if element == "failure" else set())
        assert names <= allowed, (element, names - allowed)
    assert set(ours[0]) == set(theirs[0])


def test_nothing_to_report_is_still_a_valid_file():
    suite, cases = cases_of(junit_xml(TABLE.iloc[:0], {}, []))
    assert (suite.tests, suite.failures, cases) == (0, 0, {})
