"""What ``segloc evaluate`` gives CI besides its table and exit status: a JUnit file, a
Markdown summary (also appended to GitHub's step summary when ``GITHUB_STEP_SUMMARY`` names
one), and one self-contained HTML page.

``write_reports`` writes those asked for and returns their paths; nothing here prints.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import pandas as pd

from segloc_cli.io.files import OutputError

if TYPE_CHECKING:
    from segloc_cli.runs.evaluation import EvaluateOptions, Scores
    from segloc_cli.scoring.gates import GateOutcome

GITHUB_STEP_SUMMARY = "GITHUB_STEP_SUMMARY"
"""The variable GitHub Actions sets to the file a step appends its Markdown summary to."""


def verdict_word(scores: Scores) -> str:
    """``PASS``, ``FAIL`` or ``no gates``: the run's outcome in a word."""
    if not scores.passed:
        return "FAIL"
    return "PASS" if scores.outcomes or scores.comparison is not None else "no gates"


def _scored_against(options: EvaluateOptions) -> tuple[str, str]:
    """The names of the estimates and of the truth they were scored against."""
    truth = options.survey_path or options.relations_path
    return options.estimates_path.name, truth.name if truth is not None else ""


def _outcomes(scores: Scores) -> list[GateOutcome]:
    """Every gate's outcome, the baseline's last."""
    baseline = [] if scores.comparison is None else scores.comparison.outcomes
    return [*scores.outcomes, *baseline]


def summary_markdown(options: EvaluateOptions, scores: Scores) -> str:
    """The Markdown summary: a heading with the outcome and what was scored against what,
    how the estimates were paired, then every table and line the run printed in md."""
    estimates, truth = _scored_against(options)
    heading = f"### segloc evaluate: {verdict_word(scores)}"
    what = f"`{estimates}` against `{truth}`"
    parts = [heading, "", f"{what}: {scores.pairing}.", "", scores.markdown.rstrip("\n")]
    if not scores.passed:
        parts += ["", "Failed: " + "; ".join(scores.violations) + "."]
    return "\n".join(parts) + "\n"


def _given(settings: Mapping[str, object]) -> dict[str, object]:
    """The options the run was given, by key, those left unset out."""
    return {key: value for key, value in settings.items() if value not in (None, ())}


def _inputs(options: EvaluateOptions) -> dict[str, Path]:
    named = {
        "estimates": options.estimates_path,
        "survey": options.survey_path,
        "relations": options.relations_path,
        "map": options.map_path,
        "log": options.log_path,
        "baseline": options.baseline_path,
    }
    return {role: path for role, path in named.items() if path is not None}


def _junit_text(scores: Scores, settings: Mapping[str, object]) -> str:
    from segloc_cli.io.junit import junit_xml

    table = scores.table if scores.table is not None else pd.DataFrame({"pose_id": []})
    properties = {key: str(value) for key, value in _given(settings).items()}
    return junit_xml(table, scores.failures, _outcomes(scores), properties=properties)


def _html_text(
    options: EvaluateOptions,
    scores: Scores,
    figures: Mapping[str, Callable],
    settings: Mapping[str, object],
) -> str:
    from segloc_cli.io.html_report import ReportSection, html_report

    estimates, truth = _scored_against(options)
    sections = [ReportSection("Pairing", lines=(scores.pairing + ".",))]
    sections += [ReportSection(name, markdown_table=md) for name, md in scores.sections]
    return html_report(
        title=f"segloc evaluate: {estimates} against {truth}",
        sections=sections,
        gates=_outcomes(scores),
        figures=figures,
        settings=_given(settings),
        inputs=_inputs(options),
    )


def _append_step_summary(text: str) -> Path | None:
    """Append ``text`` to the file ``GITHUB_STEP_SUMMARY`` names, if set; its path."""
    named = os.environ.get(GITHUB_STEP_SUMMARY, "").strip()
    if not named:
        return None
    path = Path(named)
    try:
        with path.open("a", encoding="utf-8") as stream:
            stream.write(text + "\n")
    except OSError as exc:
        raise OutputError(
            f"cannot append the step summary ({exc.strerror or exc}); check {GITHUB_STEP_SUMMARY}",
            path=path,
        ) from None
    return path


def write_reports(
    options: EvaluateOptions,
    scores: Scores,
    figures: Mapping[str, Callable],
    settings: Mapping[str, object],
) -> list[Path]:
    """Write the CI outputs ``options`` asks for (JUnit, Markdown summary, GitHub's step
    summary, HTML page) and return the paths written, in that order; ``settings`` are the
    options the run was given by key, as the JUnit properties and the page show them."""
    from segloc_cli.io.files import write_text_atomic
    from segloc_cli.io.html_report import write_html_report
    from segloc_cli.io.junit import write_junit

    written = []
    if options.junit_path is not None:
        write_junit(options.junit_path, _junit_text(scores, settings))
        written.append(options.junit_path)
    markdown = summary_markdown(options, scores)
    if options.summary_md_path is not None:
        write_text_atomic(options.summary_md_path, markdown)
        written.append(options.summary_md_path)
    step_summary = _append_step_summary(markdown)
    if step_summary is not None:
        written.append(step_summary)
    if options.html_path is not None:
        write_html_report(options.html_path, _html_text(options, scores, figures, settings))
        written.append(options.html_path)
    return written
