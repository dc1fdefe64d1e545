"""``segloc evaluate``'s work as plain functions: estimates scored against a survey (the
paper's Table 1, its gates and its figures) or against reference relations.

``EvaluateOptions`` holds what was asked, typed; the functions read what they need, score,
and return text and tables for the command to print or write. None prints; bad input
raises ``InputError`` naming the file.

- ``read_scored_estimates``: the estimates to score, refused when they hold no row.
- ``survey_scores``: Table 1 of estimates against surveyed poses, as text, with the gates'
  violations.
- ``check_plots``, ``figures_of``: the figures of ``--plots``, checked before any work.
- ``relation_scores``: the relation metric of Kümmerle et al. (2009), as text.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from segloc_cli.config import TIME_TOLERANCE_MS
from segloc_cli.errors import InputError
from segloc_cli.estimates import PoseTable
from segloc_cli.io.log import Log
from segloc_cli.timing import time_range


@dataclass(frozen=True)
class EvaluateOptions:
    """What ``segloc evaluate`` was asked: the estimates (``estimates_path``) and the truth to
    score them against, a survey (``survey_path``) or reference relations (``relations_path``,
    with the ``published`` errors of a dataset beside); the table's format ``fmt`` and file
    ``out_path`` (None: standard output); whether only accepted poses count (``only_ok``);
    the gates on |X|, |Y| (cm) and |θ| (°); the figures' folder ``plots_dir`` and the map and
    log they draw from; and the largest time difference (ms) when pairing rows by time."""

    estimates_path: Path
    survey_path: Path | None = None
    relations_path: Path | None = None
    published: str | None = None
    fmt: str = "md"
    out_path: Path | None = None
    only_ok: bool = False
    fail_above_cm: float | None = None
    fail_above_deg: float | None = None
    plots_dir: Path | None = None
    map_path: Path | None = None
    log_path: Path | None = None
    tolerance_ms: float = TIME_TOLERANCE_MS

    @property
    def tolerance_s(self) -> float:
        return self.tolerance_ms / 1e3

    @property
    def limits(self) -> tuple[float | None, float | None]:
        """The gates: (|X| and |Y| in cm, |θ| in degrees), each None when not set."""
        return self.fail_above_cm, self.fail_above_deg

    @property
    def inputs(self) -> list[Path | None]:
        """Every file it reads (None where not given)."""
        paths = (self.survey_path, self.relations_path, self.map_path, self.log_path)
        return [self.estimates_path, *paths]

    @property
    def outputs(self) -> dict[str, Path | None]:
        """Every file it writes besides the figures, by the option that names it (as
        ``io/files.check_outputs`` takes them): the table's, and the run file beside it."""
        from segloc_cli.runs.runfile import run_file_path

        if self.out_path is None:
            return {"--out": None}
        return {"--out": self.out_path, "--out (run file)": run_file_path(self.out_path)}

    @property
    def with_map(self) -> bool:
        """Whether the figures include those that need the map and the log."""
        return self.map_path is not None and self.log_path is not None

    def usage_problem(self) -> str | None:
        """Why these options do not go together (in the command line's words), or None."""
        if (self.survey_path is None) == (self.relations_path is None):
            return "give exactly one of --survey and --relations"
        if self.plots_dir is None and (self.map_path is not None or self.log_path is not None):
            return "--map and --log go with --plots"
        if self.plots_dir is not None and self.survey_path is None:
            return "--plots goes with --survey"
        gates = self.fail_above_cm is not None or self.fail_above_deg is not None
        if self.relations_path is not None and gates:
            return "--fail-above-cm/--fail-above-deg go with --survey"
        if self.relations_path is None and self.published is not None:
            return "--published goes with --relations"
        return None


def read_scored_estimates(path: Path) -> pd.DataFrame:
    """The estimates CSV at ``path``, refused when it holds no row."""
    from segloc_cli.io.tables import read_estimates

    estimates = read_estimates(path)
    if estimates.empty:
        raise InputError(
            "has a header but no rows: no estimate to score (did `segloc localize` stop "
            "before its first scan?)",
            path=path,
        )
    return estimates


GATE_SHOWN = 5
"""Violations of a gate named on its one line; the table shows them all."""


@dataclass(frozen=True)
class SurveyScores:
    """Table 1 of a run (a row per surveyed pose with an estimate: ``evaluate.table1``), as
    ``text`` in the format asked with its summary, and the gates' ``violations`` (one phrase
    each; empty when every pose is within them or no gate was set)."""

    table: pd.DataFrame
    text: str
    violations: list[str]

    @property
    def violations_line(self) -> str:
        """The violations in one line: the first ``GATE_SHOWN``, and how many more."""
        more = len(self.violations) - GATE_SHOWN
        shown = "; ".join(self.violations[:GATE_SHOWN])
        return shown + (f"; and {more} more" if more > 0 else "")


def survey_scores(estimates: pd.DataFrame, survey: PoseTable, options: EvaluateOptions):
    """Score ``estimates`` against the surveyed poses ``survey`` (paired by time); a pairing
    that fails names the survey when it names no file."""
    from segloc_cli.scoring.evaluate import format_table, gate, summary, table1

    paths = {"estimates_path": options.estimates_path, "survey_path": options.survey_path}
    try:
        table = table1(estimates, survey, options.tolerance_s, **paths)
    except InputError as exc:
        if exc.path is not None:
            raise
        raise InputError(str(exc), path=options.survey_path) from None
    text = format_table(table, summary(table, options.only_ok, *options.limits), options.fmt)
    return SurveyScores(table, text, gate(table, *options.limits))


def check_plots(plots_dir: Path, with_map: bool, force: bool) -> None:
    """Refuse, before any work, figures of ``--plots`` that exist (without ``force``) and a
    folder that cannot be made or written; ``with_map``: the map's figures are drawn too."""
    from segloc_cli.io.files import OutputError, check_output
    from segloc_cli.scoring.plots import ERRORS, EVALUATION_FIGURES

    if plots_dir.exists() and not plots_dir.is_dir():
        raise OutputError("is not a folder; --plots takes a folder", path=plots_dir)
    if not plots_dir.exists():
        # The folder is made later; what must exist now is a writable ancestor to make it in.
        ancestor = plots_dir.absolute().parent
        while not ancestor.exists():
            ancestor = ancestor.parent
        check_output(ancestor / ".segloc-plots", force=True, option="--plots")
        return
    for name in EVALUATION_FIGURES if with_map else (ERRORS,):
        for suffix in (".png", ".pdf"):
            check_output(plots_dir / f"{name}{suffix}", force, option="--plots")


def figures_of(
    options: EvaluateOptions,
    scores: SurveyScores,
    estimates: pd.DataFrame,
    survey: PoseTable,
    segments_world: np.ndarray | None = None,
    log: Log | None = None,
) -> Mapping[str, Callable]:
    """The figures of ``--plots`` (name → drawing function): the final errors of each pose,
    and with the map (M, 4; world frame) and the log also the local maps over the map, the
    stage-1 heading error of each vote scheme, the vote accumulator and the stage-2 tracks;
    refused when no scan of the log lies near a surveyed estimate."""
    from segloc_cli.scoring.plots import evaluation_figures, surveyed_scans

    if segments_world is None or log is None:
        return evaluation_figures(scores.table)
    paths = (options.survey_path, options.estimates_path, options.log_path)
    items = surveyed_scans(estimates, survey, log.scans, options.tolerance_s, paths=paths)
    if not items:
        raise InputError(
            f"no scan lies within {options.tolerance_s * 1e3:g} ms of a surveyed estimate "
            f"(scans {time_range(log.scan_times_s)}); is this the log of the estimates?",
            path=options.log_path,
        )
    return evaluation_figures(scores.table, segments_world, items)


def relation_scores(estimates: pd.DataFrame, relations_path: Path, options: EvaluateOptions) -> str:
    """The relation errors of the estimates' trajectory against the reference relations of
    ``relations_path``, as text in the format asked (with the published errors beside, where
    asked); refused when no relation has estimates at both of its times."""
    from segloc_cli.io.relations import read_relations
    from segloc_cli.scoring.relations import (
        PUBLISHED,
        format_relations,
        relation_errors,
        trajectory_from_estimates,
    )

    relations = read_relations(relations_path)
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
    return format_relations(errors.summary(), options.fmt, reference)
