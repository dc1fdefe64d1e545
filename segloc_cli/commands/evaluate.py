"""``segloc evaluate``: estimates scored against a survey (Table 1) or reference relations."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from segloc_cli.commands.configfile import config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.options import (
    FiniteRange,
    ModuleChoice,
    force_option,
    format_option,
    path_option,
    setting_option,
    with_options,
)
from segloc_cli.commands.printing import info, load_log, warn
from segloc_cli.errors import EXIT_GATE_FAILED

EVALUATE_OPTIONS = (
    path_option(
        "--survey",
        "survey_path",
        help="Ground truth poses (survey CSV or TUM): prints the paper's Table 1.",
    ),
    path_option(
        "--relations",
        "relations_path",
        help="Reference relative motions (t1 t2 dx dy dz droll dpitch dyaw): prints the "
        "relation metric of Kümmerle et al. (2009) instead.",
    ),
    click.option(
        "--published",
        type=ModuleChoice("segloc_cli.scoring.relations", "PUBLISHED"),
        help="With --relations: add the published graph-mapping errors for this dataset.",
    ),
    format_option("segloc_cli.scoring.evaluate", "FORMATS", "Table format."),
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
        help="Exit 1 if any pose's |X| or |Y| error exceeds this, or any pose is not ok.",
    ),
    click.option(
        "--fail-above-deg",
        type=FiniteRange(min=0),
        help="Exit 1 if any pose's |θ| error exceeds this, or any pose is not ok.",
    ),
    click.option(
        "--plots",
        "plots_dir",
        type=click.Path(path_type=Path, file_okay=False),
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
def evaluate(estimates_path, force, **given):
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
    from segloc_cli.runs import evaluation

    _unused_figure_inputs(given)
    options = evaluation.EvaluateOptions(estimates_path, **given)
    problem = options.usage_problem()
    if problem is not None:
        raise click.UsageError(problem)
    # Outputs are checked before any input is read, so a refusal costs no work.
    check_outputs(options.outputs, options.inputs, force)
    if options.plots_dir is not None:
        evaluation.check_plots(options.plots_dir, with_map=options.with_map, force=force)
    estimates = evaluation.read_scored_estimates(estimates_path)
    if options.relations_path is not None:
        relations = evaluation.relation_scores(estimates, options.relations_path, options)
        _emit(relations, options.out_path)
    else:
        _evaluate_survey(estimates, options)


def _unused_figure_inputs(given: dict) -> None:
    """Leave out ``--map`` and ``--log`` set by a ``--config`` file when ``--plots`` is not
    given, saying so: they serve the figures alone, and the run file of a run with figures
    holds them but not its output folder. Given on the command line they stay, and are
    refused as options that do not go together."""
    if given["plots_dir"] is not None:
        return
    ctx = click.get_current_context()
    from_file = [
        name
        for name in ("map_path", "log_path")
        if given[name] is not None
        and ctx.get_parameter_source(name) is click.core.ParameterSource.DEFAULT_MAP
    ]
    for name in from_file:
        warn(f"--config sets --{name.removesuffix('_path')}, which serves --plots alone: not read")
        given[name] = None


def _evaluate_survey(estimates, options) -> None:
    """Print (or write) Table 1, draw the figures asked for, and apply the gates."""
    from segloc_cli.io.maps import read_map
    from segloc_cli.io.tables import read_pose_table
    from segloc_cli.runs.evaluation import survey_scores

    survey = read_pose_table(options.survey_path)
    # Read before anything is printed, so a bad path stops the command with nothing half done.
    segments_world = None if options.map_path is None else read_map(options.map_path)
    log = None if options.log_path is None else load_log(options.log_path)
    scores = survey_scores(estimates, survey, options)
    _emit(scores.text, options.out_path)
    if options.plots_dir is not None:
        _draw(options, scores, estimates, survey, segments_world, log)
    if scores.violations:
        click.echo(f"segloc: gate: {scores.violations_line}", err=True)
        sys.exit(EXIT_GATE_FAILED)


def _draw(options, scores, estimates, survey, segments_world, log) -> None:
    """Draw the figures of ``--plots`` into its folder, made if needed, saying which."""
    from segloc_cli.io.figures import write_figures
    from segloc_cli.progress import Progress
    from segloc_cli.runs.evaluation import figures_of
    from segloc_cli.scoring.plots import MAP_FIGURES

    options.plots_dir.mkdir(parents=True, exist_ok=True)
    if segments_world is None or log is None:
        info(f"skipped {', '.join(MAP_FIGURES)}: they need --map MAP.json and --log LOG.mcap")
    figures = figures_of(options, scores, estimates, survey, segments_world, log)
    for path in write_figures(figures, options.plots_dir, progress=Progress):
        info(f"wrote {path}")


def _emit(text: str, out_path: Path | None) -> None:
    """Print a table, or write it to ``out_path``."""
    from segloc_cli.io.files import write_text_atomic

    if out_path is None:
        click.echo(text)
    else:
        write_text_atomic(out_path, text if text.endswith("\n") else text + "\n")
        Invocation.current().write_run_file(out_path)
        info(f"wrote {out_path}")
