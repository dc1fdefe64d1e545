"""JUnit XML for CI: each scored pose (or reference relation) and each gate of ``evaluate`` as
one test case.

The file follows the JUnit schema that pytest writes (``--junitxml``) and that CI services
read (GitLab, Jenkins, GitHub test reporters): one ``<testsuites>`` holding one
``<testsuite>``, its ``<properties>`` (the run's settings and input hashes), then one
``<testcase>`` per ``JUnitCase`` (``classname="<suite>.<group>"``). A failed case holds a
``<failure type="gate">`` whose ``message`` says why; every case's ``<system-out>`` holds its
figures in one line. Names stay the same from run to run (``pose 140``, ``gate: RMS position
error ≤ 5 cm``) so that a CI service follows each case's history; what changes goes in the
message and the output.

XML 1.0 cannot carry most control characters, not even escaped; any found in a status, a
name or a message is written as its ``\\xNN`` escape so that a strange status cannot make
the whole report unreadable.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segloc_cli.io.files import write_text_atomic

_NOT_XML = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")
"""Characters XML 1.0 does not allow: C0 controls but tab and line ends, surrogates, FFFE/F."""


def _xml_text(value: object) -> str:
    """``value`` as text XML can hold: forbidden characters become ``\\xNN`` (``\\uNNNN``)."""
    return _NOT_XML.sub(_escape_char, str(value))


def _escape_char(match: re.Match[str]) -> str:
    code = ord(match.group())
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def _figure(value: float, decimals: int) -> str:
    if not np.isfinite(value):
        return "none"
    text = f"{value:.{decimals}f}"
    # "-0.0" would claim a sign the precision shown cannot support.
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def pose_line(
    err_x_cm: float, err_y_cm: float, err_xy_cm: float, theta_deg: float, status: str
) -> str:
    """A pose's final errors in one line: ``X -1.2 cm, Y 0.4 cm, |XY| 1.3 cm, θ 0.46°, status
    ok`` (surveyed minus computed, world frame; cm to 0.1, degrees to 0.01; ``none`` where an
    error is missing)."""
    return (
        f"X {_figure(err_x_cm, 1)} cm, Y {_figure(err_y_cm, 1)} cm, "
        f"|XY| {_figure(err_xy_cm, 1)} cm, θ {_figure(theta_deg, 2)}°, status {status}"
    )


@dataclass(frozen=True)
class JUnitCase:
    """One test case: its ``group`` (``poses``, ``relations``, ``gates``: the class name's
    last part), its ``name``, its one-line ``output`` and, when it failed, the ``failure``
    message (None: passed)."""

    group: str
    name: str
    output: str
    failure: str | None = None


def junit_xml(
    cases: Sequence[JUnitCase],
    *,
    suite: str = "segloc evaluate",
    properties: Mapping[str, str] | None = None,
    timestamp: str | None = None,
) -> str:
    """The JUnit XML text (UTF-8, with its declaration) of ``cases``, in their order.

    ``properties`` (name → value: settings, input hashes) go into the suite's
    ``<properties>`` in their order; ``timestamp`` (ISO 8601), when given, into its
    ``timestamp`` attribute. Times are "0": a score takes no time worth reporting. The
    suite's ``failures`` counts the cases that hold a failure.

    Raises ``ValueError`` when two cases of one group share a name (a CI service would
    merge their histories).
    """
    seen: set[tuple[str, str]] = set()
    for case in cases:
        key = (case.group, case.name)
        if key in seen:
            raise ValueError(f"two {case.group} cases are named {case.name!r}")
        seen.add(key)
    root = ET.Element("testsuites", {"name": _xml_text(suite)})
    attributes = {
        "name": _xml_text(suite),
        "tests": str(len(cases)),
        "failures": str(sum(case.failure is not None for case in cases)),
        "errors": "0",
        "skipped": "0",
        "time": "0",
    }
    if timestamp is not None:
        attributes["timestamp"] = _xml_text(timestamp)
    testsuite = ET.SubElement(root, "testsuite", attributes)
    if properties:
        holder = ET.SubElement(testsuite, "properties")
        for name, value in properties.items():
            ET.SubElement(holder, "property", {"name": _xml_text(name), "value": _xml_text(value)})
    for case in cases:
        element = ET.SubElement(
            testsuite,
            "testcase",
            {
                "classname": _xml_text(f"{suite}.{case.group}"),
                "name": _xml_text(case.name),
                "time": "0",
            },
        )
        if case.failure is not None:
            attributes = {"message": _xml_text(case.failure), "type": "gate"}
            ET.SubElement(element, "failure", attributes)
        ET.SubElement(element, "system-out").text = _xml_text(case.output)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_junit(path: Path, text: str) -> None:
    """Write ``junit_xml``'s ``text`` to ``path`` atomically (``files.write_text_atomic``): a
    CI job never reads half a report. An ``OSError`` comes out as an ``OutputError``."""
    write_text_atomic(path, text)
