"""What ``segloc evaluate`` gives CI besides its table and exit status: a JUnit file, a
Markdown summary (also appended to GitHub's step summary when ``GITHUB_STEP_SUMMARY`` names
one), and one self-contained HTML page.

Each report opens with the answer: the verdict in one line (which gates failed, how many
poses and which), then the gates, the change against a baseline, the poses that failed
and the figures; the table of every pose comes last, folded, its failing rows marked. The
Markdown summary stays under ``SUMMARY_MAX_BYTES`` (GitHub refuses a step summary over
1 MiB): what does not fit is left out, and a line says what and where to find it.

``step_summary_path`` checks the step summary before any work; ``write_reports`` writes
those asked for and returns their paths; nothing here prints.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from segloc_cli.io.files import OutputError, write_whole, writing_error
from segloc_cli.markdown import cell
from segloc_cli.wording import counted

if TYPE_CHECKING:
    from segloc_cli.io.html_report import ReportSection
    from segloc_cli.io.junit import JUnitCase
    from segloc_cli.runs.evaluation import EvaluateOptions, Item, Scores

GITHUB_STEP_SUMMARY = "GITHUB_STEP_SUMMARY"
"""The variable GitHub Actions sets to the file a step appends its Markdown summary to."""
STEP_SUMMARY_SKIPPED = f"no step summary appended ({GITHUB_STEP_SUMMARY})"
"""How the warning of a step summary left alone starts."""

STEP_SUMMARY_LIMIT_BYTES = 1024 * 1024
"""The most GitHub Actions takes in one step's summary (1 MiB); more and it shows none."""

SUMMARY_MAX_BYTES = 1_000_000
"""The most a Markdown summary of ``evaluate`` holds, under the step summary's limit with
room for what else the step writes."""

FAILING_SHOWN = 50
"""Failing poses (relations) listed one by one in the summary and the page; the JUnit file
and the full table hold them all."""

FAIL_MARK = "✘"
"""How the full table marks a pose that failed; one a gate tolerated is marked ``TOLERATED``."""
TOLERATED_MARK = "(✘)"


def _scored_against(options: EvaluateOptions) -> tuple[str, str]:
    """The names of the estimates and of the truth they were scored against."""
    truth = options.survey_path or options.relations_path
    return options.estimates_path.name, truth.name if truth is not None else ""


def _gates_md(scores: Scores) -> str:
    """The gates as a Markdown table: result, gate (what it asks), measured against limit."""
    rows = ["| result | gate | measured |", "| --- | --- | --- |"]
    for outcome in scores.all_outcomes:
        result = "✔ pass" if outcome.passed else "✘ **FAIL**"
        cells = (result, cell(outcome.title), cell(outcome.result))
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows) + "\n"


def _failing_md(scores: Scores, shown: int) -> str:
    """The first ``shown`` failing poses (relations) with why each failed, and how many more."""
    failing = scores.failing_items
    if scores.table is None or scores.item_kind != "pose":
        rows = ["| relation | why |", "| --- | --- |"]
        rows += [f"| {item.name} | {cell(item.line)} |" for item in failing[:shown]]
        text = "\n".join(rows) + "\n"
    else:
        from segloc_cli.scoring.evaluate import pose_table_md

        positions = np.flatnonzero([scores.fails(item) for item in scores.items])[:shown]
        why = ["; ".join(scores.items[i].reasons) for i in positions]
        text = pose_table_md(scores.table, rows=positions, extra={"why": why})
    more = len(failing) - shown
    if more > 0:
        where = f", each marked {FAIL_MARK} in Table 1" if scores.table is not None else ""
        text += f"\n… and {counted(more, scores.item_kind)} more{where}.\n"
    return text


def _marks(scores: Scores) -> list[str]:
    """Each pose's mark in the full table: failed, failing but tolerated by a gate, or none."""
    marks = []
    for item in scores.items:
        if scores.fails(item):
            marks.append(FAIL_MARK)
        else:
            marks.append(TOLERATED_MARK if item.reasons else "")
    return marks


def _full_table_md(scores: Scores) -> str:
    """Table 1 with a ``gate`` column marking the poses that failed."""
    from segloc_cli.scoring.evaluate import pose_table_md

    assert scores.table is not None
    return pose_table_md(scores.table, scores.stats, extra={"gate": _marks(scores)})


def _first_rows(table_md: str, n_poses: int, n_rows: int) -> str:
    """``_full_table_md``'s text with its first ``n_rows`` poses only: the header, those
    rows, the RMS and max rows and the lines under the table (every row has one width, so
    the table stays whole)."""
    lines = table_md.splitlines()
    return "\n".join(lines[: 2 + n_rows] + lines[2 + n_poses :]) + "\n"


def _full_elsewhere(options: EvaluateOptions) -> str:
    """Where the full table is, in words: the outputs of this run that hold every pose."""
    held = [
        f"{option} {path}"
        for option, path in (
            ("--out", options.out_path),
            ("--html", options.html_path),
            ("--junit", options.junit_path),
        )
        if path is not None
    ]
    if held:
        return "every pose is in " + " and ".join(held)
    return "--out FILE or --html FILE writes every pose"


def summary_markdown(
    options: EvaluateOptions, scores: Scores, max_bytes: int = SUMMARY_MAX_BYTES
) -> str:
    """The Markdown summary, answer first: a heading with the verdict, the verdict line, how
    the estimates were paired, the gates, the change against the baseline, the failing poses
    (relations), the other figures, then Table 1 folded (``<details>``; with --relations,
    the relation table). At most ``max_bytes`` of UTF-8: Table 1's rows, then the failing
    poses, are cut to fit, with a line saying what was left out and where it is."""
    estimates, truth = _scored_against(options)
    head = [
        f"### segloc evaluate: {scores.verdict}",
        f"**{scores.verdict_line}**",
        f"`{estimates}` against `{truth}`: {scores.pairing}.",
    ]
    if scores.all_outcomes:
        head.append(_gates_md(scores))
    if scores.comparison is not None:
        head.append("#### Change against the baseline\n\n" + scores.comparison.format_md())
    if scores.table is None:
        head.append(scores.markdown.rstrip("\n"))

    full = None if scores.table is None else _full_table_md(scores)

    def compose(failing_shown: int, table_rows: int | None) -> str:
        parts = list(head)
        failing = scores.failing_items
        if failing and failing_shown > 0:
            title = f"#### Failing {scores.item_kind}s ({len(failing)})"
            parts.append(f"{title}\n\n{_failing_md(scores, failing_shown)}")
        parts += [f"#### {title}\n\n{md.rstrip()}" for title, md in scores.sections]
        if full is not None:
            parts.append(_folded_table_md(scores, full, options, table_rows))
        return "\n\n".join(part.rstrip("\n") for part in parts) + "\n"

    text = compose(FAILING_SHOWN, None)
    if _size(text) <= max_bytes or scores.table is None:
        return _within(text, max_bytes)
    # Cut Table 1 to the rows that fit: they all have one width.
    bare = _size(compose(FAILING_SHOWN, 0))
    per_row = (_size(text) - bare) / len(scores.table)
    rows = int(max(0.0, max_bytes - bare) // per_row)
    text = compose(FAILING_SHOWN, rows)
    while rows > 0 and _size(text) > max_bytes:
        rows -= max(1, rows // 100)
        text = compose(FAILING_SHOWN, rows)
    if _size(text) > max_bytes:
        text = compose(0, 0)
    return _within(text, max_bytes)


def _folded_table_md(
    scores: Scores, full: str, options: EvaluateOptions, n_rows: int | None
) -> str:
    """Table 1 (``full``, from ``_full_table_md``) in a ``<details>`` block: its first
    ``n_rows`` poses when given, saying how many were left out and where they all are."""
    assert scores.table is not None
    n_poses = len(scores.table)
    table, note = full, ""
    if n_rows is not None and n_rows < n_poses:
        table = _first_rows(full, n_poses, n_rows)
        note = (
            f"\n\nThis summary shows the first {n_rows} of {counted(n_poses, 'pose')} (a step "
            f"summary holds at most 1 MiB); {_full_elsewhere(options)}."
        )
    title = f"Table 1: every surveyed pose ({n_poses}), failing ones marked {FAIL_MARK}"
    return f"<details><summary>{title}</summary>\n\n{table.rstrip()}{note}\n\n</details>"


def _size(text: str) -> int:
    return len(text.encode("utf-8"))


def _within(text: str, max_bytes: int) -> str:
    """``text`` if it fits in ``max_bytes``; else its head cut at a line, saying so."""
    if _size(text) <= max_bytes:
        return text
    note = "\n\n(cut here: a step summary holds at most 1 MiB)\n"
    kept = text.encode("utf-8")[: max(0, max_bytes - _size(note))].decode("utf-8", "ignore")
    return kept[: kept.rfind("\n") + 1] + note


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


def junit_cases(scores: Scores) -> list[JUnitCase]:
    """One case per pose of Table 1 (with --relations, per relation missing an end), then
    one per gate. A pose fails when it fails the run's verdict (``Scores.fails``); one a gate
    tolerates passes, its reasons in its output, so that the file fails exactly when the
    exit status does."""
    from segloc_cli.io.junit import JUnitCase

    cases = [_item_case(scores, item) for item in scores.items]
    for outcome in scores.all_outcomes:
        failure = None if outcome.passed else outcome.text
        cases.append(JUnitCase("gates", f"gate: {outcome.title}", outcome.text, failure))
    return cases


def _item_case(scores: Scores, item: Item) -> JUnitCase:
    from segloc_cli.io.junit import JUnitCase

    group = f"{scores.item_kind}s"
    reasons = "; ".join(item.reasons)
    if scores.fails(item):
        return JUnitCase(group, item.name, item.line, reasons)
    if item.reasons and item.line != reasons and scores.all_outcomes:
        # A relation's line already ends with why it has no error: not said twice.
        told = "" if item.line.endswith(reasons) else f": {reasons}"
        return JUnitCase(group, item.name, f"{item.line}; tolerated by the gates{told}")
    return JUnitCase(group, item.name, item.line)


def _junit_text(scores: Scores, settings: Mapping[str, object]) -> str:
    from segloc_cli.io.junit import junit_xml

    properties = {key: str(value) for key, value in _given(settings).items()}
    return junit_xml(junit_cases(scores), properties=properties)


def _html_text(
    options: EvaluateOptions,
    scores: Scores,
    figures: Mapping[str, Callable],
    settings: Mapping[str, object],
) -> str:
    from segloc_cli.io.html_report import ReportSection, html_report

    estimates, truth = _scored_against(options)
    sections = []
    if scores.comparison is not None:
        change = scores.comparison.format_md()
        sections.append(ReportSection("Change against the baseline", markdown_table=change))
    failing = scores.failing_items
    if failing:
        title = f"Failing {scores.item_kind}s ({len(failing)})"
        sections.append(ReportSection(title, markdown_table=_failing_md(scores, FAILING_SHOWN)))
    sections.append(ReportSection("Pairing", lines=(scores.pairing + ".",)))
    if scores.table is None:
        sections.append(ReportSection("Relations", markdown_table=scores.markdown))
    appendix = [ReportSection(name, markdown_table=md) for name, md in scores.sections]
    appendix += _table_sections(scores)
    return html_report(
        title=f"segloc evaluate: {estimates} against {truth}",
        verdict_line=scores.verdict_line,
        sections=sections,
        gates=scores.all_outcomes,
        figures=figures,
        appendix=appendix,
        settings=_given(settings),
        inputs=_inputs(options),
    )


def _table_sections(scores: Scores) -> list[ReportSection]:
    """Table 1, folded, with its failing rows marked."""
    from segloc_cli.io.html_report import ReportSection

    if scores.table is None:
        return []
    marked = frozenset(i for i, mark in enumerate(_marks(scores)) if mark == FAIL_MARK)
    title = f"Table 1: every surveyed pose ({len(scores.table)})"
    return [ReportSection(title, _full_table_md(scores), folded=True, marked_rows=marked)]


def step_summary_path(options: EvaluateOptions) -> tuple[Path | None, str | None]:
    """The file ``GITHUB_STEP_SUMMARY`` names, checked before any work (``files.check_appended``),
    or None and why it is left alone (a warning's text, None when the variable is unset).
    One that is an input or another output of the run (the figures among them), is not a
    regular file, or cannot be written is skipped, not refused: the variable is the CI
    runner's, not the command line's, and the run's results and exit status must not hang
    on it."""
    from segloc_cli.io.files import check_appended
    from segloc_cli.runs.evaluation import figure_paths

    named = os.environ.get(GITHUB_STEP_SUMMARY, "").strip()
    if not named:
        return None, None
    outputs: dict[str, Path | None] = dict(options.outputs)
    outputs |= {f"--plots ({path.name})": path for path in figure_paths(options)}
    try:
        return check_appended(named, GITHUB_STEP_SUMMARY, outputs, options.inputs), None
    except OutputError as exc:
        return None, f"{STEP_SUMMARY_SKIPPED}: {exc}"


def _append_step_summary(path: Path, options: EvaluateOptions, scores: Scores) -> str | None:
    """Append the summary to the step summary ``path`` within what it has room for; None,
    or why it could not be (a warning's text: the run's verdict does not hang on it). A
    write that fails part way is taken back: the file keeps what it held before."""
    try:
        # Not blocking: should a pipe have taken the file's place, opening it fails at once.
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NONBLOCK, 0o666)
    except OSError as exc:
        return f"{STEP_SUMMARY_SKIPPED}: {writing_error(path, exc)}"
    try:
        used = os.fstat(fd).st_size
        room = min(SUMMARY_MAX_BYTES, STEP_SUMMARY_LIMIT_BYTES - used - 1)
        data = (summary_markdown(options, scores, max(room, 0)) + "\n").encode("utf-8")
        try:
            write_whole(fd, data, used)
        except OSError as exc:
            return f"{STEP_SUMMARY_SKIPPED}: {writing_error(path, exc)}"
    finally:
        os.close(fd)
    return None


def write_reports(
    options: EvaluateOptions,
    scores: Scores,
    figures: Mapping[str, Callable],
    settings: Mapping[str, object],
    step_summary: Path | None = None,
) -> tuple[list[Path], list[str]]:
    """Write the CI outputs ``options`` asks for (JUnit, Markdown summary, HTML page), each
    replacing an earlier one, then append the summary to ``step_summary`` (``step_summary_path``'s,
    None: none); return the paths written, in that order, and warnings: a step summary
    that could not be appended to is one, not an error. ``settings`` are the options the
    run was given by key, as the JUnit properties and the page show them."""
    from segloc_cli.io.files import write_text_atomic
    from segloc_cli.io.html_report import write_html_report
    from segloc_cli.io.junit import write_junit

    written = []
    if options.junit_path is not None:
        write_junit(options.junit_path, _junit_text(scores, settings))
        written.append(options.junit_path)
    if options.summary_md_path is not None:
        write_text_atomic(options.summary_md_path, summary_markdown(options, scores))
        written.append(options.summary_md_path)
    if options.html_path is not None:
        write_html_report(options.html_path, _html_text(options, scores, figures, settings))
        written.append(options.html_path)
    warnings = []
    if step_summary is not None:
        problem = _append_step_summary(step_summary, options, scores)
        if problem is None:
            written.append(step_summary)
        else:
            warnings.append(problem)
    return written, warnings
