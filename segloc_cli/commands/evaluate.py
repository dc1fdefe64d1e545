"""``segloc evaluate``: estimates scored against a survey (Table 1) or reference relations."""

from __future__ import annotations

import sys
from pathlib import Path

import click
import numpy as np

from segloc_cli.commands.options import (
    FiniteRange,
    Invocation,
    ModuleChoice,
    config_option,
    force_option,
    format_option,
    info,
    load_log,
    path_option,
    setting_option,
    warn,
    with_options,
)
from segloc_cli.errors import EXIT_GATE_FAILED, InputError
from segloc_cli.runfile import run_file_path
from segloc_cli.timing import time_range

GATE_SHOWN = 5
"""Violations of an evaluate gate named on its one line; the table shows them all."""

EVALUATE_OPTIONS = (
    path_option(
        "--survey",
        "survey_path",
        help="Ground truth poses (survey CSV or TUM): prints the paper's Table 1.",
    ),
    path_option(
        "--relations",
        "relations_path",
        help=(
            "Reference relative motions (t1 t2 dx dy dz droll dpitch dyaw): prints the relation "
            "metric of Kümmerle et al. (2009) instead."
        ),
    ),
    click.option(
        "--published",
        type=ModuleChoice("segloc_cli.relations", "PUBLISHED"),
        default=None,
        help="With --relations: add the published graph-mapping errors for this dataset.",
    ),
    format_option("segloc_cli.evaluate", "FORMATS", "Table format."),
    path_option(
        "--out",
        "out_path",
        help="Write the table here instead of standard output (an existing file needs --force).",
    ),
    click.option(
        "--only-ok",
        is_flag=True,
        help="Summarise only poses whose status is ok (or recovered): RMS and max with --survey, "
        "the relations used with --relations. By default every pose with an estimate counts, "
        "whatever its status.",
    ),
    click.option(
        "--fail-above-cm",
        type=FiniteRange(min=0),
        default=None,
        help="Exit 1 if any pose's |X| or |Y| error exceeds this, or any pose is not ok.",
    ),
    click.option(
        "--fail-above-deg",
        type=FiniteRange(min=0),
        default=None,
        help="Exit 1 if any pose's |θ| error exceeds this, or any pose is not ok.",
    ),
    click.option(
        "--plots",
        "plots_dir",
        type=click.Path(path_type=Path, file_okay=False),
        default=None,
        help="With --survey: also draw figures (PNG and PDF) into this folder, created if needed "
        "(existing figures need --force).",
    ),
    path_option(
        "--map",
        "map_path",
        help="With --plots: the map the estimates were made with, for the figures of both stages.",
    ),
    path_option(
        "--log",
        "log_path",
        help="With --plots: the log the estimates were made from, for the figures of both stages.",
    ),
    setting_option("tolerance-ms", pairing="pairing estimates with survey rows"),
    config_option,
    force_option,
)


@click.command()
@click.argument("estimates_path", metavar="EST.csv", type=click.Path(path_type=Path))
@with_options(*EVALUATE_OPTIONS)
def evaluate(estimates_path, **a):
    """Score estimates against ground truth.

    With --survey, the paper's Table 1: one row per surveyed pose that has an
    estimate row, with AE (the stage-1 heading error; blank without an
    initial guess, as in --global runs), the initial errors X, Y (cm) and θ (°)
    and the final errors X, Y (cm) and θ (°), all "surveyed minus computed",
    then RMS and max rows. RMS and max cover every pose with an estimate,
    whatever its status (--only-ok: status ok alone); under the table, the
    poses by status and how many surveyed poses have no estimate. Survey rows
    and estimates are paired by time; two rows that share the time nearest a
    pose are refused, never paired silently. With --fail-above-* the table
    says how many poses lie beyond the limits, and the exit status is 1 when
    any pose exceeds a limit or is not ok, so CI can gate on it.

    With --plots DIR, figures of the run go into DIR: the final errors per
    pose, and with --map and --log also the local maps over the map, the
    stage-1 heading error of each vote scheme, the vote accumulator and the
    stage-2 tracks from guesses around the first pose.

    With --relations, the metric of Kümmerle et al. (2009) for logs without
    surveyed poses: over the reference relations whose two times both have an
    estimate, the mean ± std of the translational (m) and rotational (°)
    error of the estimated relative motion, and how many relations were used
    and skipped.
    """
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.tables import read_estimates

    _unused_figure_inputs(a)
    _check_usage(a)
    # Outputs are checked before any input is read, so a refusal costs no work.
    inputs = [estimates_path, a["survey_path"], a["relations_path"], a["map_path"], a["log_path"]]
    outputs = {"--out": a["out_path"]}
    if a["out_path"] is not None:
        outputs["--out (run file)"] = run_file_path(a["out_path"])
    check_outputs(outputs, inputs, a["force"])
    if a["plots_dir"] is not None:
        with_map = a["map_path"] is not None and a["log_path"] is not None
        _check_plots(a["plots_dir"], with_map=with_map, force=a["force"])
    estimates = read_estimates(estimates_path)
    if estimates.empty:
        raise InputError(
            "has a header but no rows: no estimate to score (did `segloc localize` stop "
            "before its first scan?)",
            path=estimates_path,
        )
    if a["relations_path"] is not None:
        _evaluate_relations(estimates, estimates_path, a)
    else:
        _evaluate_survey(estimates, estimates_path, a)


def _unused_figure_inputs(a: dict) -> None:
    """Leave out ``--map`` and ``--log`` set by a ``--config`` file when ``--plots`` is not
    given, saying so: they serve the figures alone, and the run file of a run with figures
    holds them but not its output folder. Given on the command line they stay, and are
    refused by ``_check_usage``."""
    if a["plots_dir"] is not None:
        return
    ctx = click.get_current_context()
    from_file = [
        name
        for name in ("map_path", "log_path")
        if a[name] is not None
        and ctx.get_parameter_source(name) is click.core.ParameterSource.DEFAULT_MAP
    ]
    for name in from_file:
        warn(f"--config sets --{name.removesuffix('_path')}, which serves --plots alone: not read")
        a[name] = None


def _check_usage(a: dict) -> None:
    """Refuse options that do not go together."""
    if (a["survey_path"] is None) == (a["relations_path"] is None):
        raise click.UsageError("give exactly one of --survey and --relations")
    if a["plots_dir"] is None and (a["map_path"] is not None or a["log_path"] is not None):
        raise click.UsageError("--map and --log go with --plots")
    if a["plots_dir"] is not None and a["survey_path"] is None:
        raise click.UsageError("--plots goes with --survey")
    gates = a["fail_above_cm"] is not None or a["fail_above_deg"] is not None
    if a["relations_path"] is not None and gates:
        raise click.UsageError("--fail-above-cm/--fail-above-deg go with --survey")
    if a["relations_path"] is None and a["published"] is not None:
        raise click.UsageError("--published goes with --relations")


def _evaluate_survey(estimates, estimates_path: Path, a: dict) -> None:
    """Print (or write) Table 1, draw the figures asked for, and apply the gates."""
    from segloc_cli.evaluate import format_table, gate, summary, table1
    from segloc_cli.io.maps import read_map
    from segloc_cli.io.tables import read_pose_table

    survey_path, tolerance_s = a["survey_path"], a["tolerance_ms"] / 1e3
    survey = read_pose_table(survey_path)
    # Read before anything is printed, so a bad path stops the command with nothing half done.
    segments_world = None if a["map_path"] is None else read_map(a["map_path"])
    log = None if a["log_path"] is None else load_log(a["log_path"])
    try:
        paths = {"estimates_path": estimates_path, "survey_path": survey_path}
        table = table1(estimates, survey, tolerance_s, **paths)
    except InputError as exc:
        if exc.path is not None:
            raise
        raise InputError(str(exc), path=survey_path) from None
    limits = (a["fail_above_cm"], a["fail_above_deg"])
    _emit(format_table(table, summary(table, a["only_ok"], *limits), a["fmt"]), a["out_path"])
    if a["plots_dir"] is not None:
        figure_data = None
        if segments_world is not None and log is not None:
            figure_data = (segments_world, log, a["log_path"])
        paths = (survey_path, estimates_path)
        _write_plots(a["plots_dir"], table, estimates, survey, figure_data, tolerance_s, paths)
    violations = gate(table, *limits)
    if violations:
        shown = "; ".join(violations[:GATE_SHOWN])
        more = len(violations) - GATE_SHOWN
        click.echo(f"segloc: gate: {shown}" + (f"; and {more} more" if more > 0 else ""), err=True)
        sys.exit(EXIT_GATE_FAILED)


def _check_plots(plots_dir: Path, with_map: bool, force: bool) -> None:
    """Refuse, before any work, figures of ``evaluate --plots`` that exist (without --force)
    and a folder that cannot be made or written."""
    from segloc_cli.io.files import OutputError, check_output
    from segloc_cli.plots import ERRORS, EVALUATION_FIGURES

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


def _write_plots(
    plots_dir: Path,
    table,
    estimates,
    survey,
    figure_data,
    tolerance_s: float,
    paths: tuple[Path, Path],
):
    """Draw the figures of ``evaluate --plots``; ``figure_data`` is (map, log, log path) or None,
    ``paths`` (survey, estimates) name the inputs in errors."""
    from segloc_cli.io.figures import write_figures
    from segloc_cli.plots import MAP_FIGURES, evaluation_figures, surveyed_scans
    from segloc_cli.progress import Progress

    plots_dir.mkdir(parents=True, exist_ok=True)
    if figure_data is None:
        info(f"skipped {', '.join(MAP_FIGURES)}: they need --map MAP.json and --log LOG.mcap")
        figures = evaluation_figures(table)
    else:
        segments_world, log, log_path = figure_data
        survey_path, estimates_path = paths
        items = surveyed_scans(
            estimates, survey, log.scans, tolerance_s, paths=(survey_path, estimates_path, log_path)
        )
        if not items:
            raise InputError(
                f"no scan lies within {tolerance_s * 1e3:g} ms of a surveyed estimate "
                f"(scans {time_range(log.scan_times_s)}); is this the log of the estimates?",
                path=log_path,
            )
        figures = evaluation_figures(table, segments_world, items)
    written = write_figures(figures, plots_dir, progress=Progress)
    for path in written:
        info(f"wrote {path}")


def _evaluate_relations(estimates, estimates_path: Path, a: dict) -> None:
    """Print (or write) the relation errors of the estimates (``a``: the command's arguments)."""
    from segloc_cli.io.relations import read_relations
    from segloc_cli.relations import (
        PUBLISHED,
        format_relations,
        relation_errors,
        trajectory_from_estimates,
    )

    relations = read_relations(a["relations_path"])
    times_s, poses = trajectory_from_estimates(estimates, only_ok=a["only_ok"])
    tolerance_ms = a["tolerance_ms"]
    errors = relation_errors(
        times_s, poses, relations, tolerance_s=tolerance_ms / 1e3, estimates_path=estimates_path
    )
    if errors.used == 0:
        raise InputError(
            f"no relation has estimates at both of its times (within {tolerance_ms:g} ms; "
            f"estimates {time_range(times_s)}, relations "
            f"{time_range(np.concatenate([relations.t1_s, relations.t2_s]))})",
            path=a["relations_path"],
        )
    reference = None if a["published"] is None else PUBLISHED.get(a["published"])
    _emit(format_relations(errors.summary(), a["fmt"], reference), a["out_path"])


def _emit(text: str, out_path: Path | None) -> None:
    """Print a table, or write it to ``out_path``."""
    from segloc_cli.io.files import write_text_atomic

    if out_path is None:
        click.echo(text)
    else:
        write_text_atomic(out_path, text if text.endswith("\n") else text + "\n")
        Invocation.current().write_run_file(out_path)
        info(f"wrote {out_path}")
