"""JUnit XML for CI: each scored pose and each summary gate of ``evaluate`` as one test case.

The file follows the JUnit schema that pytest writes (``--junitxml``) and that CI services
read (GitLab, Jenkins, GitHub test reporters): one ``<testsuites>`` holding one
``<testsuite>``, its ``<properties>`` (the run's settings and input hashes), then one
``<testcase>`` per pose of Table 1 (``classname="<suite>.poses"``, ``name="pose <id>"``) and
one per gate (``classname="<suite>.gates"``, ``name`` the gate's). A failed case holds a
``<failure type="gate">`` whose ``message`` says why; every case's ``<system-out>`` holds its
figures in one line.

XML 1.0 cannot carry most control characters, not even escaped; any found in a status, a
name or a message is written as its ``\\xNN`` escape so that a strange status cannot make
the whole report unreadable.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from segloc_cli.io.files import write_text_atomic

if TYPE_CHECKING:
    # Only the outcome's fields are read here: io/ does not import the layers above it.
    from segloc_cli.scoring.gates import GateOutcome

_NOT_XML = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")
"""Characters XML 1.0 does not allow: C0 controls but tab and line ends, surrogates, FFFE/F."""

_POSE_COLUMNS = ("pose_id", "err_x_cm", "err_y_cm", "err_xy_cm", "err_theta_deg", "status")


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


def _case(parent: ET.Element, classname: str, name: str) -> ET.Element:
    return ET.SubElement(
        parent,
        "testcase",
        {"classname": _xml_text(classname), "name": _xml_text(name), "time": "0"},
    )


def _fail(case: ET.Element, message: str) -> None:
    ET.SubElement(case, "failure", {"message": _xml_text(message), "type": "gate"})


def _out(case: ET.Element, text: str) -> None:
    ET.SubElement(case, "system-out").text = _xml_text(text)


def junit_xml(
    table: pd.DataFrame,
    pose_failures: Mapping[int, Sequence[str]],
    outcomes: Sequence[GateOutcome],
    *,
    suite: str = "segloc evaluate",
    properties: Mapping[str, str] | None = None,
    timestamp: str | None = None,
) -> str:
    """The JUnit XML text (UTF-8, with its declaration) of a scored run.

    ``table`` is a ``scoring.evaluate.table1`` result (``pose_id``, ``err_x_cm``,
    ``err_y_cm``, ``err_xy_cm`` in cm, ``err_theta_deg`` in degrees, ``status``); each row
    becomes a case that fails exactly when ``pose_failures`` holds a non-empty list of
    reasons for its ``pose_id`` (the failure's message: the reasons joined by ``"; "``).
    Each ``GateOutcome`` of ``outcomes`` becomes a case after the poses, failed when it did
    not pass, its ``text`` as output. ``properties`` (name → value: settings, input hashes)
    go into the suite's ``<properties>`` in their order; ``timestamp`` (ISO 8601), when
    given, into its ``timestamp`` attribute. Times are "0": a score takes no time worth
    reporting.

    Raises ``ValueError`` when ``table`` lacks a column or ``pose_failures`` gives reasons
    for a pose that is not in ``table`` (they would go unreported).
    """
    missing = [c for c in _POSE_COLUMNS if c not in table.columns]
    if missing:
        raise ValueError(f"table lacks the column(s) {', '.join(missing)}")
    ids = table["pose_id"].to_numpy()
    failing = {int(k) for k, reasons in pose_failures.items() if len(reasons)}
    unknown = sorted(failing - {int(i) for i in ids})
    if unknown:
        raise ValueError(f"pose_failures names poses not in the table: {unknown}")

    root = ET.Element("testsuites", {"name": _xml_text(suite)})
    n_failed = len(failing) + sum(not outcome.passed for outcome in outcomes)
    attributes = {
        "name": _xml_text(suite),
        "tests": str(len(table) + len(outcomes)),
        "failures": str(n_failed),
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

    x_cm, y_cm, xy_cm, theta_deg = (table[c].to_numpy(dtype=float) for c in _POSE_COLUMNS[1:5])
    for row, (pose_id, status) in enumerate(zip(ids, table["status"], strict=True)):
        case = _case(testsuite, f"{suite}.poses", f"pose {pose_id}")
        reasons = pose_failures.get(int(pose_id), ())
        if len(reasons):
            _fail(case, "; ".join(str(reason) for reason in reasons))
        _out(case, pose_line(x_cm[row], y_cm[row], xy_cm[row], theta_deg[row], str(status)))
    for outcome in outcomes:
        case = _case(testsuite, f"{suite}.gates", outcome.name)
        if not outcome.passed:
            _fail(case, outcome.text)
        _out(case, outcome.text)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_junit(path: Path, text: str) -> None:
    """Write ``junit_xml``'s ``text`` to ``path`` atomically (``files.write_text_atomic``): a
    CI job never reads half a report. An ``OSError`` comes out as an ``OutputError``."""
    write_text_atomic(path, text)
