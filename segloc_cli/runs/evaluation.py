"""``segloc evaluate``'s work as plain functions: estimates scored against a survey (the
paper's Table 1, its gates and its figures) or against reference relations.

``EvaluateOptions`` holds what was asked, typed; the functions read what they need, score,
and return text and tables for the command to print or write. None prints; bad input
raises ``InputError`` naming the file.

- ``read_scored_estimates``: the estimates to score, from any localizer's output, refused
  when they hold no row.
- ``survey_scores``: Table 1 of estimates against surveyed poses with its gates, the drift,
  the covariance's consistency and the comparison with a baseline (``read_baseline``), as
  ``Scores``.
- ``relation_scores``: the relation metric of Kümmerle et al. (2009) with its gates.
- ``check_plots``, ``figure_names``, ``figure_paths``, ``figures_of``,
  ``relation_figures_of``: the figures, checked before any work.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from segloc_cli.config import TIME_TOLERANCE_MS
from segloc_cli.errors import InputError
from segloc_cli.estimates import PoseTable, Relations
from segloc_cli.io.log import Log
from segloc_cli.numbers import json_text
from segloc_cli.scoring.gates import GateOutcome, Gates, outcomes_json
from segloc_cli.timing import time_range
from segloc_cli.wording import counted

if TYPE_CHECKING:
    from segloc_cli.scoring.baseline import Comparison
    from segloc_cli.scoring.relations import RelationErrors


GATE_FIELDS = {
    "fail_above_cm": "axis_cm",
    "fail_above_xy_cm": "xy_cm",
    "fail_above_deg": "deg",
    "min_within_pct": "min_within_pct",
    "min_paired_pct": "min_paired_pct",
    "fail_rms_above_cm": "rms_cm",
    "fail_rms_above_deg": "rms_deg",
    "fail_mean_above_cm": "mean_cm",
    "fail_mean_above_deg": "mean_deg",
    "fail_percentile_above_cm": "percentile_cm",
    "fail_percentile_above_deg": "percentile_deg",
    "percentile": "percentile",
}
"""The command's gate options (as click names them) → the ``Gates`` field each sets."""

PER_POSE_OPTIONS = "--fail-above-cm, --fail-above-xy-cm or --fail-above-deg"

FULL_COVERAGE_PCT = 100.0
"""``--min-paired-pct`` whenever another gate is given: every surveyed pose (relation) needs
an estimate."""

WARN_BELOW_PAIRED_PCT = 50.0
"""Under this share (%) of the truth paired with an estimate, a run warns even with no gate:
more likely the wrong survey or log than a localizer that answered so rarely."""


@dataclass(frozen=True)
class EvaluateOptions:
    """What ``segloc evaluate`` was asked: the estimates (``estimates_path``, in format
    ``est_format``, None to tell by the name; a bag's or MCAP's ``topic`` and, for TF, the
    ``frames`` parent, child) and the truth to score them against, a survey
    (``survey_path``) or reference relations (``relations_path``, with the ``published``
    errors of a dataset beside); the table's format ``fmt`` and file ``out_path`` (None:
    standard output); whether only accepted poses count (``only_ok``); the ``gates``; the
    figures' folder ``plots_dir`` and the map and log they draw from; the largest time
    difference (ms) when pairing rows by time; the CI outputs (JUnit, Markdown summary,
    HTML page) and the earlier run to compare with (``baseline_path``) with its limits."""

    estimates_path: Path
    survey_path: Path | None = None
    relations_path: Path | None = None
    published: str | None = None
    fmt: str = "md"
    out_path: Path | None = None
    only_ok: bool = False
    gates: Gates = field(default_factory=Gates)
    plots_dir: Path | None = None
    map_path: Path | None = None
    log_path: Path | None = None
    tolerance_ms: float = TIME_TOLERANCE_MS
    est_format: str | None = None
    topic: str | None = None
    frames: tuple[str, str] | None = None
    junit_path: Path | None = None
    summary_md_path: Path | None = None
    html_path: Path | None = None
    baseline_path: Path | None = None
    fail_if_worse_cm: float | None = None
    fail_if_worse_deg: float | None = None
    fail_if_fewer_pct: float | None = None

    @classmethod
    def from_options(cls, estimates_path: Path, given: dict) -> EvaluateOptions:
        """From the command's options by their click names (the gate options among them).

        Whenever a gate is given, the share of the truth with an estimate is one too: 100 %
        unless ``--min-paired-pct`` says otherwise, so that a localizer that fell silent
        cannot pass on the poses it still answered. With ``--fail-if-worse-*``, the poses
        compared with the baseline may not fall short of the baseline's (0 % unless
        ``--fail-if-fewer-pct`` says otherwise)."""
        given = dict(given)
        limits = {GATE_FIELDS[k]: given.pop(k) for k in GATE_FIELDS if k in given}
        limits = {k: v for k, v in limits.items() if v is not None}
        gates = Gates(**limits)
        worse = any(given.get(k) is not None for k in ("fail_if_worse_cm", "fail_if_worse_deg"))
        if worse and given.get("fail_if_fewer_pct") is None:
            given["fail_if_fewer_pct"] = 0.0
        fewer = given.get("fail_if_fewer_pct") is not None
        if gates.min_paired_pct is None and (gates.any or worse or fewer):
            gates = replace(gates, min_paired_pct=FULL_COVERAGE_PCT)
        return cls(estimates_path, gates=gates, **given)

    @property
    def tolerance_s(self) -> float:
        return self.tolerance_ms / 1e3

    @property
    def inputs(self) -> list[Path | None]:
        """Every file it reads (None where not given)."""
        paths = (self.survey_path, self.relations_path, self.map_path, self.log_path)
        return [self.estimates_path, *paths, self.baseline_path]

    @property
    def outputs(self) -> dict[str, Path | None]:
        """Every file it writes besides the figures, by the option that names it (as
        ``io/files.check_outputs`` takes them): the table's and the run file beside it, the
        JUnit file, the Markdown summary, the HTML page."""
        from segloc_cli.runs.runfile import RUN_FILE_OUTPUT, run_file_path

        named: dict[str, Path | None] = {"--out": self.out_path}
        if self.out_path is not None:
            named[RUN_FILE_OUTPUT] = run_file_path(self.out_path)
        named |= {"--junit": self.junit_path, "--summary-md": self.summary_md_path}
        return named | {"--html": self.html_path}

    REPORTS = ("--junit", "--summary-md", "--html")
    """The outputs that are reports of the run: a rerun replaces them without --force, as CI
    reruns a job in the same workspace (the table of --out, a result, keeps --force)."""

    @property
    def with_map(self) -> bool:
        """Whether the figures include those that need the map and the log."""
        return self.map_path is not None and self.log_path is not None

    def usage_problem(self) -> str | None:
        """Why these options do not go together (in the command line's words), or None."""
        gates = self.gates
        if (self.survey_path is None) == (self.relations_path is None):
            return "give exactly one of --survey and --relations"
        drawn = self.plots_dir is not None or self.html_path is not None
        if not drawn and (self.map_path is not None or self.log_path is not None):
            return "--map and --log go with --plots or --html"
        if self.relations_path is not None:
            if gates.per_pose or gates.min_within_pct is not None:
                return (
                    "relations bound no single pose: with --relations gate the mean, RMS or "
                    "a percentile of the relation errors (--fail-mean-above-cm/-deg, "
                    "--fail-rms-above-cm/-deg, --fail-percentile-above-cm/-deg)"
                )
            if self.log_path is not None:
                return "--log goes with --survey (the stages' figures); --relations takes --map"
            if self.baseline_path is not None:
                return "--baseline goes with --survey: it compares pose by pose"
        elif self.published is not None:
            return "--published goes with --relations"
        if gates.min_within_pct is not None and not gates.per_pose:
            return f"--min-within-pct goes with {PER_POSE_OPTIONS}"
        bounded = gates.percentile_cm is not None or gates.percentile_deg is not None
        if gates.percentile != 95.0 and not bounded:
            return "--percentile goes with --fail-percentile-above-cm or -deg"
        worse = self.fail_if_worse_cm is not None or self.fail_if_worse_deg is not None
        if worse and self.baseline_path is None:
            return "--fail-if-worse-cm/--fail-if-worse-deg go with --baseline OLD.json"
        if self.fail_if_fewer_pct is not None and self.baseline_path is None:
            return "--fail-if-fewer-pct goes with --baseline OLD.json"
        return None


def read_scored_estimates(options: EvaluateOptions) -> pd.DataFrame:
    """The estimates to score, from any format ``io/trajectories`` reads, refused when they
    hold no row."""
    from segloc_cli.io.trajectories import read_trajectory

    path = options.estimates_path
    estimates = read_trajectory(path, options.est_format, options.topic, options.frames)
    if estimates.empty:
        raise InputError(
            "has a header but no rows: no estimate to score (did `segloc localize` stop "
            "before its first scan?)",
            path=path,
        )
    return estimates


GATE_SHOWN = 5
"""Violations of a gate named on its one line; the tables show them all."""
IDS_SHOWN = 10
"""Failing poses (relations) named by id in the verdict line."""


@dataclass(frozen=True)
class Item:
    """One surveyed pose (or reference relation) as CI reports it: ``name`` (``pose 140``,
    the same in every run), its figures in one ``line``, why it fails its gates (``reasons``,
    empty when it does not) and whether the localizer gave no estimate for it at all
    (``missing``)."""

    name: str
    line: str
    reasons: tuple[str, ...] = ()
    missing: bool = False


@dataclass(frozen=True)
class Scores:
    """A scored run: ``text`` in the format asked, ``markdown`` the same in Markdown (Table 1
    or the relations' table with its lines), each gate's ``outcomes`` (the baseline's not
    among them), the per-pose ``failures`` (pose id → reasons; with --survey alone),
    Table 1 (``table``, every surveyed pose; None with --relations), the ``comparison``
    with a baseline, ``pairing``: how the estimates met the truth, in one line, the extra
    figures in titled Markdown ``sections`` (drift, covariance), the ``items`` CI reports
    one by one (every surveyed pose; with --relations, the relations missing an end), of
    ``item_kind`` ("pose" or "relation"), ``n_truth`` the surveyed poses or reference
    relations scored against, ``warnings`` to print and Table 1's ``stats``
    (``scoring.evaluate.summary``; None with --relations)."""

    text: str
    markdown: str
    outcomes: list[GateOutcome]
    failures: dict[int, list[str]]
    table: pd.DataFrame | None = None
    comparison: Comparison | None = None
    pairing: str = ""
    sections: tuple[tuple[str, str], ...] = ()
    items: tuple[Item, ...] = ()
    item_kind: str = "pose"
    n_truth: int = 0
    warnings: tuple[str, ...] = ()
    stats: pd.DataFrame | None = None

    @functools.cached_property
    def all_outcomes(self) -> list[GateOutcome]:
        """Every gate's outcome, the baseline's last."""
        baseline = [] if self.comparison is None else self.comparison.outcomes
        return [*self.outcomes, *baseline]

    @functools.cached_property
    def _judged(self) -> tuple[bool, bool]:
        """Whether an item with reasons fails (``gates.judged``): one with an estimate, and
        one without."""
        from segloc_cli.scoring.gates import judged

        return judged(False, self.all_outcomes), judged(True, self.all_outcomes)

    def fails(self, item: Item) -> bool:
        """Whether ``item`` fails in the run's verdict: it has reasons and a gate that judges
        them failed (``gates.judged``). One a gate tolerates (``--min-within-pct``,
        ``--min-paired-pct`` under 100) does not."""
        return bool(item.reasons) and self._judged[item.missing]

    @functools.cached_property
    def failing_items(self) -> list[Item]:
        """The items that fail, in order."""
        return [item for item in self.items if self.fails(item)]

    @property
    def violations(self) -> list[str]:
        """Every failed gate in a phrase: the poses beyond their limits or without an
        estimate when a gate over them failed, then the other gates, then the figures worse
        than the baseline's."""
        poses = [f"{item.name}: {r}" for item in self.failing_items for r in item.reasons]
        others = [o.text for o in self.outcomes if not o.passed and not o.per_pose]
        worse = [] if self.comparison is None else self.comparison.failures
        return poses + others + worse

    @property
    def passed(self) -> bool:
        """Whether every gate held, the baseline's among them."""
        return all(o.passed for o in self.all_outcomes)

    @property
    def verdict(self) -> str:
        """``PASS``, ``FAIL`` or ``no gates``: the run's outcome in a word."""
        if not self.passed:
            return "FAIL"
        return "PASS" if self.all_outcomes else "no gates"

    @property
    def verdict_line(self) -> str:
        """The answer in one line: the verdict, which gates failed, how many poses (relations)
        failed and the first of them."""
        outcomes = self.all_outcomes
        n_items = counted(self.n_truth, self.item_kind)
        if not outcomes:
            return f"No gates set: {n_items} scored, nothing to fail."
        failed = [o for o in outcomes if not o.passed]
        if not failed:
            return f"PASS: {counted(len(outcomes), 'gate')} held over {n_items}."
        titles = "; ".join(o.title for o in failed)
        line = f"FAIL: {len(failed)} of {counted(len(outcomes), 'gate')} failed ({titles})"
        failing = self.failing_items
        if failing:
            missing = sum(item.missing for item in failing)
            without = f", {missing} without an estimate" if missing else ""
            names = ", ".join(item.name.split(" ", 1)[-1] for item in failing[:IDS_SHOWN])
            more = len(failing) - IDS_SHOWN
            names += f" and {more} more" if more > 0 else ""
            line += f"; {len(failing)} of {n_items} failed{without}: {names}"
        return line + "."

    @property
    def violations_line(self) -> str:
        """The violations in one line: the first ``GATE_SHOWN``, and how many more."""
        more = len(self.violations) - GATE_SHOWN
        shown = "; ".join(self.violations[:GATE_SHOWN])
        return shown + (f"; and {more} more" if more > 0 else "")


def _with_extras(text: str, fmt: str, sections: dict[str, tuple[str, object]]) -> str:
    """``text`` with the extra figures (name → (Markdown, JSON value)) added where the
    format has room: after the table in md, under ``summary`` in json."""
    if fmt == "md":
        return text + "".join(f"\n{md}" for md, _ in sections.values() if md)
    if fmt == "json":
        document = json.loads(text)
        document["summary"] |= {name: value for name, (_, value) in sections.items()}
        return json_text(document)
    return text


def survey_scores(estimates: pd.DataFrame, survey: PoseTable, options: EvaluateOptions) -> Scores:
    """Score ``estimates`` against the surveyed poses ``survey`` (paired by time): Table 1,
    its gates, the drift per travelled length, the covariance's consistency where the
    estimates carry one, and the comparison with a baseline where asked. A pairing that fails
    names the survey when it names no file."""
    from segloc_cli.scoring.evaluate import format_table, summary, table1
    from segloc_cli.scoring.gates import pose_failures

    paths = {"estimates_path": options.estimates_path, "survey_path": options.survey_path}
    try:
        table = table1(estimates, survey, options.tolerance_s, **paths)
    except InputError as exc:
        if exc.path is not None:
            raise
        raise InputError(str(exc), path=options.survey_path) from None
    stats = summary(table, options.only_ok, options.gates)
    extras = _survey_extras(table, survey, estimates, options)
    comparison = _comparison(table, options)
    printed = dict(extras)
    if comparison is not None:
        printed["baseline"] = (comparison.format_md(), comparison.as_json())
    table_md = format_table(table, stats, "md")
    asked = table_md if options.fmt == "md" else format_table(table, stats, options.fmt)
    text = _with_extras(asked, options.fmt, printed)
    failures = pose_failures(table, options.gates)
    n_paired = stats.attrs["n_poses"]
    return Scores(
        text,
        table_md,
        stats.attrs["outcomes"],
        failures,
        table,
        comparison,
        _pairing_line(estimates, len(table), n_paired, options),
        tuple((SECTION_TITLES[k], md) for k, (md, _) in extras.items()),
        _pose_items(table, failures),
        "pose",
        len(table),
        _read_warnings(estimates, options)
        + _coverage_warnings(n_paired, len(table), "surveyed pose", "have an estimate", options),
        stats,
    )


def _pose_items(table: pd.DataFrame, failures: Mapping[int, list[str]]) -> tuple[Item, ...]:
    """Every pose of Table 1 as CI reports it: its final errors in a line (or why it has none),
    and its reasons to fail."""
    from segloc_cli.io.junit import pose_line
    from segloc_cli.scoring.gates import missing_reason, unpaired_mask

    missing = unpaired_mask(table)
    none = missing_reason(table)
    columns = ("err_x_cm", "err_y_cm", "err_xy_cm", "err_theta_deg")
    x_cm, y_cm, xy_cm, theta_deg = (table[c].to_numpy(dtype=float) for c in columns)
    items = []
    for row, (pose_id, status) in enumerate(zip(table["pose_id"], table["status"], strict=True)):
        errors = (x_cm[row], y_cm[row], xy_cm[row], theta_deg[row])
        line = none if missing[row] else pose_line(*errors, str(status))
        reasons = tuple(failures.get(int(pose_id), ()))
        items.append(Item(f"pose {pose_id}", line, reasons, bool(missing[row])))
    return tuple(items)


def _read_warnings(estimates: pd.DataFrame, options: EvaluateOptions) -> tuple[str, ...]:
    """What the estimates' reader noted about the poses it kept (tilted, timed by their log
    time, read up to damage: ``io/trajectories``), one line each with its count, naming the
    file."""
    return tuple(f"{options.estimates_path}: {w}" for w in estimates.attrs.get("warnings") or ())


def _coverage_warnings(
    n_paired: int, n_truth: int, noun: str, having: str, options: EvaluateOptions
) -> tuple[str, ...]:
    """A warning when under ``WARN_BELOW_PAIRED_PCT`` of the truth was paired: more likely a
    survey (relations) of another log, or times in another clock, than a localizer that
    answered so rarely."""
    if n_truth == 0 or 100.0 * n_paired / n_truth >= WARN_BELOW_PAIRED_PCT:
        return ()
    truth = options.survey_path or options.relations_path
    return (
        f"only {n_paired} of {counted(n_truth, noun)} ({100.0 * n_paired / n_truth:.1f} %) "
        f"{having} within {options.tolerance_ms:g} ms: is {truth} the truth of "
        f"{options.estimates_path}? (--tolerance-ms widens the pairing)",
    )


SECTION_TITLES = {
    "drift": "Drift per travelled length",
    "covariance": "Covariance consistency",
}


def _survey_extras(
    table: pd.DataFrame, survey: PoseTable, estimates: pd.DataFrame, options: EvaluateOptions
) -> dict[str, tuple[str, object]]:
    """The drift per travelled length and, where the estimates carry a covariance, its
    consistency: name → (Markdown, JSON value)."""
    from segloc_cli.scoring.consistency import consistency, covariance_matrices
    from segloc_cli.scoring.drift import drift_per_length, format_drift_md
    from segloc_cli.scoring.evaluate import scored

    extras: dict[str, tuple[str, object]] = {}
    if len(table) >= 2:
        drift = drift_per_length(*_truth_and_estimates(table, survey))
        records = drift.astype(object).where(drift.notna(), None).to_dict(orient="records")
        md = "Drift per travelled length (relative pose error, pairs along the survey):\n\n"
        extras["drift"] = (md + format_drift_md(drift), records)
    summarised = scored(table, options.only_ok)
    errors, covariances = _errors_m_rad(table)[summarised], covariance_matrices(table)
    checked = consistency(errors, covariances[summarised])
    if checked is not None:
        md = " ".join(checked.lines()) + "\n"
        extras["covariance"] = (md, checked.as_json())
    return extras


def _errors_m_rad(table: pd.DataFrame) -> np.ndarray:
    """(N, 3) Table 1's final errors in metres and radians: x, y, θ (surveyed − estimate)."""
    return np.column_stack(
        [
            table["err_x_cm"].to_numpy(float) / 100.0,
            table["err_y_cm"].to_numpy(float) / 100.0,
            np.deg2rad(table["err_theta_deg"].to_numpy(float)),
        ]
    )


def _truth_and_estimates(table: pd.DataFrame, survey: PoseTable) -> tuple[np.ndarray, np.ndarray]:
    """The surveyed poses of Table 1's rows and the estimates made there (each (N, 3): x m,
    y m, θ rad, world frame; NaN where no estimate), in time order."""
    order = np.argsort(table["time_s"].to_numpy(float), kind="stable")
    rows = table.iloc[order]
    index = {int(pose_id): i for i, pose_id in enumerate(np.asarray(survey.pose_id))}
    truth = np.asarray(survey.poses, float)[[index[int(p)] for p in rows["pose_id"]]]
    return truth, truth - _errors_m_rad(rows)


def read_baseline(path: Path) -> dict:
    """The poses of an earlier run from the JSON ``segloc evaluate --format json`` wrote
    (``scoring/baseline.parse_baseline``), refused in one line when not such a file."""
    from segloc_cli.io.files import reading
    from segloc_cli.scoring.baseline import HOW_TO_MAKE, parse_baseline

    with reading(path, f"a baseline JSON ({HOW_TO_MAKE})"):
        text = Path(path).read_text(encoding="utf-8")
    return parse_baseline(text, path)


def _comparison(table: pd.DataFrame, options: EvaluateOptions) -> Comparison | None:
    if options.baseline_path is None:
        return None
    from segloc_cli.scoring.baseline import compare

    return compare(
        read_baseline(options.baseline_path),
        table,
        only_ok=options.only_ok,
        fail_if_worse_cm=options.fail_if_worse_cm,
        fail_if_worse_deg=options.fail_if_worse_deg,
        fail_if_fewer_pct=options.fail_if_fewer_pct,
    )


def _source(estimates: pd.DataFrame) -> str:
    """What the estimates were read from, in words (their reader's), or how many there are."""
    return estimates.attrs.get("source") or f"{len(estimates)} estimates"


def _pairing_line(
    estimates: pd.DataFrame, n_truth: int, n_paired: int, options: EvaluateOptions
) -> str:
    """How the estimates met the truth in one line: paired, unpaired and dropped counts."""
    dropped = estimates.attrs.get("dropped") or {}
    line = (
        f"{_source(estimates)}: {n_paired} of {counted(n_truth, 'surveyed pose')} paired within "
        f"{options.tolerance_ms:g} ms, {n_truth - n_paired} unpaired"
    )
    if dropped:
        reasons = ", ".join(f"{n} {why}" for why, n in dropped.items())
        line += f"; dropped {sum(dropped.values())} ({reasons})"
    return line


def check_plots(options: EvaluateOptions, force: bool) -> None:
    """Refuse, before any work, figures of ``--plots`` that exist (without ``force``) and a
    folder that cannot be made or written."""
    from segloc_cli.io.files import OutputError, check_output

    plots_dir = options.plots_dir
    assert plots_dir is not None
    if plots_dir.exists() and not plots_dir.is_dir():
        raise OutputError("is not a folder; --plots takes a folder", path=plots_dir)
    if not plots_dir.exists():
        # The folder is made later; what must exist now is a writable ancestor to make it in.
        ancestor = plots_dir.absolute().parent
        while not ancestor.exists():
            ancestor = ancestor.parent
        check_output(ancestor / ".segloc-plots", force=True, option="--plots")
        return
    for path in figure_paths(options):
        check_output(path, force, option="--plots")


def figure_paths(options: EvaluateOptions) -> list[Path]:
    """The files of the figures a run draws into ``--plots`` (none without it)."""
    if options.plots_dir is None:
        return []
    names = figure_names(options)
    return [options.plots_dir / f"{name}{suffix}" for name in names for suffix in (".png", ".pdf")]


def figure_names(options: EvaluateOptions) -> tuple[str, ...]:
    """The figures a run draws: of the relations, or of Table 1 (with the map's and the
    stages' when given the map and the log)."""
    from segloc_cli.scoring.plots import EVALUATION_FIGURES, TABLE_FIGURES
    from segloc_cli.scoring.relation_plots import RELATION_FIGURES

    if options.relations_path is not None:
        return RELATION_FIGURES
    return EVALUATION_FIGURES if options.with_map else TABLE_FIGURES


def figures_of(
    options: EvaluateOptions,
    scores: Scores,
    estimates: pd.DataFrame,
    survey: PoseTable,
    segments_world: np.ndarray | None = None,
    log: Log | None = None,
) -> Mapping[str, Callable]:
    """The figures of ``--plots`` (name → drawing function): the final errors of each pose,
    and with the map (M, 4; world frame) and the log also the local maps over the map, the
    stage-1 heading error of each vote scheme, the vote accumulator and the stage-2 tracks;
    refused when no scan of the log lies near a surveyed estimate."""
    from segloc_cli.scoring.gates import failing_mask
    from segloc_cli.scoring.plots import evaluation_figures, surveyed_scans

    flagged = failing_mask(scores.table, options.gates) if options.gates.per_pose else None
    if segments_world is None or log is None:
        return evaluation_figures(scores.table, flagged=flagged)
    paths = (options.survey_path, options.estimates_path, options.log_path)
    items = surveyed_scans(estimates, survey, log.scans, options.tolerance_s, paths=paths)
    if not items:
        raise InputError(
            f"no scan lies within {options.tolerance_s * 1e3:g} ms of a surveyed estimate "
            f"(scans {time_range(log.scan_times_s)}); is this the log of the estimates?",
            path=options.log_path,
        )
    return evaluation_figures(scores.table, segments_world, items, flagged=flagged)


def relation_figures_of(
    run: RelationRun, segments_world: np.ndarray | None = None
) -> Mapping[str, Callable]:
    """The figures of a relations run (name → drawing function): the estimated trajectory,
    over the map (M, 4; world frame) when given, and the relation errors over time."""
    from segloc_cli.scoring.plots import relation_figures

    return relation_figures(run.times_s, run.poses, run.errors, run.relations, segments_world)


@dataclass(frozen=True)
class RelationRun:
    """What the relation figures draw: the estimated trajectory (``times_s`` (N,) s,
    ``poses`` (N, 3) x m, y m, θ rad, world frame), the relation ``errors`` and the
    reference ``relations``."""

    times_s: np.ndarray
    poses: np.ndarray
    errors: RelationErrors
    relations: Relations


def localized_in(options: EvaluateOptions) -> dict | None:
    """The ``source`` record of the map the estimates were localized in: ``--map``'s, else
    that of the map their run file names (``localize``'s, beside the estimates); None where
    neither says, or the map cannot be read."""
    from segloc_cli.io.maps import read_map_source
    from segloc_cli.runs.runfile import load_toml, run_file_path

    map_path = options.map_path
    run_file = run_file_path(options.estimates_path)
    if map_path is None and run_file.is_file():
        try:
            named = load_toml(run_file).get("localize", {}).get("map")
        except (InputError, AttributeError):
            named = None
        map_path = run_file.parent / named if isinstance(named, str) else None
    if map_path is None:
        return None
    try:
        return read_map_source(map_path)
    except InputError:
        return None


def relation_scores(
    estimates: pd.DataFrame, options: EvaluateOptions
) -> tuple[Scores, RelationRun]:
    """The relation errors of the estimates' trajectory against the reference relations of
    ``options.relations_path``, as text in the format asked (with the published errors
    beside, where asked) and the gates' outcomes over them; refused when no relation has
    estimates at both of its times."""
    from segloc_cli.io.relations import read_relations
    from segloc_cli.scoring.gates import relation_outcomes
    from segloc_cli.scoring.relations import (
        PUBLISHED,
        format_relations,
        published_note,
        relation_errors,
        trajectory_from_estimates,
    )

    assert options.relations_path is not None
    relations = read_relations(options.relations_path)
    times_s, poses = trajectory_from_estimates(estimates, only_ok=options.only_ok)
    errors = relation_errors(
        times_s,
        poses,
        relations,
        tolerance_s=options.tolerance_s,
        estimates_path=options.estimates_path,
    )
    if errors.used == 0:
        raise InputError(
            f"no relation has estimates at both of its times (within {options.tolerance_ms:g} "
            f"ms; estimates {time_range(times_s)}, relations "
            f"{time_range(np.concatenate([relations.t1_s, relations.t2_s]))})",
            path=options.relations_path,
        )
    reference = None if options.published is None else PUBLISHED.get(options.published)
    caveat = None
    if options.published is not None:
        caveat = published_note(options.published, localized_in(options))
    within = f"within {options.tolerance_ms:g} ms"
    outcomes = relation_outcomes(
        100.0 * errors.trans_m, errors.rot_deg, options.gates, len(relations), within
    )
    gate_lines = "".join(f"Gate: {o.text}.\n" for o in outcomes)
    summary = errors.summary()
    shown = functools.partial(
        format_relations,
        summary,
        published=reference,
        label=options.estimates_path.name,
        published_caveat=caveat,
    )
    markdown = shown("md") + gate_lines
    text = markdown if options.fmt == "md" else shown(options.fmt)
    if options.fmt == "json":
        document = json.loads(text)
        document["gate"] = outcomes_json(outcomes) if outcomes else None
        text = json_text(document)
    pairing = (
        f"{_source(estimates)}: {errors.used} of {counted(len(relations), 'relation')} "
        "have estimates "
        f"at both times (within {options.tolerance_ms:g} ms), {errors.skipped} skipped"
    )
    scores = Scores(
        text,
        markdown,
        outcomes,
        {},
        pairing=pairing,
        items=_relation_items(errors, relations),
        item_kind="relation",
        n_truth=len(relations),
        warnings=_read_warnings(estimates, options)
        + _coverage_warnings(
            errors.used, len(relations), "relation", "have estimates at both ends", options
        ),
    )
    return scores, RelationRun(times_s, poses, errors, relations)


def _relation_items(errors: RelationErrors, relations: Relations) -> tuple[Item, ...]:
    """The relations left out for want of an estimate at an end, as CI reports them: named
    by their row in the relations file (from 1), failing for want of it."""
    return tuple(
        Item(
            f"relation {i + 1}",
            f"t1 {relations.t1_s[i]:.3f} s, t2 {relations.t2_s[i]:.3f} s: {why}",
            (why,),
            missing=True,
        )
        for i, why in zip(errors.skipped_index, errors.skipped_why, strict=True)
    )
