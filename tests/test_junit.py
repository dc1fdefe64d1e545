"""The JUnit writer of evaluate, read back as CI reads it (junitparser) and held against the
shape pytest's own ``--junitxml`` gives. Which cases a run writes, and which fail, is
tested through the command in test_evaluate_ci.py."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest
from junitparser import Failure, JUnitXml, TestCase, TestSuite

from segloc_cli.io.files import OutputError
from segloc_cli.io.junit import JUnitCase, junit_xml, pose_line, write_junit

CASES = [
    JUnitCase("poses", "pose 1", pose_line(-1.23, 0.41, math.hypot(-1.23, 0.41), 0.456, "ok")),
    JUnitCase(
        "poses",
        "pose 2",
        pose_line(6.0, -8.0, 10.0, -1.5, "ok"),
        "|err_x| 6.0 cm > 5.0 cm; |err_y| 8.0 cm > 5.0 cm",
    ),
    JUnitCase("poses", "pose 5", pose_line(*[math.nan] * 4, "lost"), "status lost"),
    JUnitCase("poses", "pose 9", pose_line(0.02, -0.04, 0.045, 0.001, "recovered")),
    JUnitCase("gates", "gate: RMS position error ≤ 5 cm", "RMS 5.1 cm > 5 cm: FAIL", "RMS FAIL"),
    JUnitCase("gates", "gate: share ≥ 50 %", "share 75.0 % ≥ 50 %: pass"),
]
PROPERTIES = {"map": "hall.json", "estimates sha256": "ab12", "--fail-above-cm": "5"}


def cases_of(text: str) -> tuple[TestSuite, dict[str, TestCase]]:
    (suite,) = JUnitXml.fromstring(text.encode("utf-8"))
    return suite, {case.name: case for case in suite}


def failure_of(case: TestCase) -> Failure | None:
    results = [result for result in case.result if isinstance(result, Failure)]
    assert len(results) == len(case.result) <= 1
    return results[0] if results else None


def test_one_case_each_failed_exactly_where_told():
    suite, cases = cases_of(junit_xml(CASES, properties=PROPERTIES))
    assert suite.name == "segloc evaluate"
    assert list(cases) == [case.name for case in CASES]
    assert (suite.tests, suite.failures, suite.errors, suite.skipped) == (6, 3, 0, 0)
    failed = {name for name, case in cases.items() if failure_of(case) is not None}
    assert failed == {"pose 2", "pose 5", "gate: RMS position error ≤ 5 cm"}
    assert {cases[f"pose {i}"].classname for i in (1, 2, 5, 9)} == {"segloc evaluate.poses"}
    assert cases["gate: share ≥ 50 %"].classname == "segloc evaluate.gates"

    pose_2 = failure_of(cases["pose 2"])
    assert pose_2 is not None
    assert pose_2.message == "|err_x| 6.0 cm > 5.0 cm; |err_y| 8.0 cm > 5.0 cm"
    assert pose_2.type == "gate"
    assert failure_of(cases["gate: RMS position error ≤ 5 cm"]).message == "RMS FAIL"


def test_each_case_says_its_figures_in_one_line():
    _, cases = cases_of(junit_xml(CASES))
    assert cases["pose 1"].system_out == "X -1.2 cm, Y 0.4 cm, |XY| 1.3 cm, θ 0.46°, status ok"
    assert cases["pose 2"].system_out == "X 6.0 cm, Y -8.0 cm, |XY| 10.0 cm, θ -1.50°, status ok"
    assert cases["pose 5"].system_out == "X none cm, Y none cm, |XY| none cm, θ none°, status lost"
    # A sign the shown precision cannot support is dropped.
    assert cases["pose 9"].system_out.startswith("X 0.0 cm, Y 0.0 cm, |XY| 0.0 cm, θ 0.00°")
    assert cases["gate: share ≥ 50 %"].system_out == "share 75.0 % ≥ 50 %: pass"


def test_properties_and_suite_name_and_timestamp():
    text = junit_xml(
        CASES[:1], suite="hall", properties=PROPERTIES, timestamp="2024-05-01T10:00:00"
    )
    suite, cases = cases_of(text)
    assert {p.name: p.value for p in suite.properties()} == PROPERTIES
    assert suite.name == "hall" and suite.timestamp == "2024-05-01T10:00:00"
    assert {case.classname for case in cases.values()} == {"hall.poses"}
    assert suite.failures == 0


def test_two_cases_of_one_name_are_refused():
    with pytest.raises(ValueError, match="pose 1"):
        junit_xml([CASES[0], CASES[0]])


HOSTILE = "a \"quoted\" 'b' <tag> & &amp; ü θ 漢字 🙂\ttab"


def test_hostile_strings_round_trip_and_control_characters_stay_readable(tmp_path):
    cases = [
        JUnitCase(
            "poses", "pose 3", pose_line(1.0, 2.0, 2.2, 0.5, HOSTILE), HOSTILE + "; line\nbreak"
        ),
        JUnitCase("poses", "pose 4", pose_line(1.0, 2.0, 2.2, 0.5, "bell\x07 nul\x00"), "esc\x1b"),
        JUnitCase("gates", HOSTILE, HOSTILE, HOSTILE + "\x02"),
    ]
    path = tmp_path / "junit.xml"
    write_junit(path, junit_xml(cases, suite=HOSTILE, properties={HOSTILE: HOSTILE + "\x01"}))
    (suite,) = JUnitXml.fromfile(str(path))
    cases = {case.name: case for case in suite}
    assert suite.name == HOSTILE
    assert {p.name: p.value for p in suite.properties()} == {HOSTILE: HOSTILE + "\\x01"}
    assert cases["pose 3"].classname == HOSTILE + ".poses"
    assert cases["pose 3"].system_out.endswith("status " + HOSTILE)
    assert failure_of(cases["pose 3"]).message == HOSTILE + "; line\nbreak"
    assert cases["pose 4"].system_out.endswith("status bell\\x07 nul\\x00")
    assert failure_of(cases["pose 4"]).message == "esc\\x1b"
    assert failure_of(cases[HOSTILE]).message == HOSTILE + "\\x02"


def test_written_file_is_the_text_and_a_missing_folder_is_one_error(tmp_path):
    text = junit_xml(CASES)
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
    ours = shape(ET.fromstring(junit_xml(CASES, properties=PROPERTIES)))
    assert ours[1] <= theirs[1], ours[1] - theirs[1]
    for element, names in ours[0].items():
        # pytest gives a failure no type; the JUnit schema does, and junitparser reads it.
        allowed = theirs[0][element] | ({"type"} if element == "failure" else set())
        assert names <= allowed, (element, names - allowed)
    assert set(ours[0]) == set(theirs[0])


def test_nothing_to_report_is_still_a_valid_file():
    suite, cases = cases_of(junit_xml([]))
    assert (suite.tests, suite.failures, cases) == (0, 0, {})
