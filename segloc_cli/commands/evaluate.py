"""``segloc evaluate``: any 2D localizer's estimates scored against a survey (Table 1) or
reference relations, with gates, a baseline comparison and CI reports."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from segloc_cli.commands.configfile import check_command_outputs
from segloc_cli.commands.evaluate_options import EVALUATE_OPTIONS
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.options import FilePath, with_options
from segloc_cli.commands.printing import info, load_log, warn
from segloc_cli.errors import EXIT_GATE_FAILED
from segloc_cli.wording import plural

EPILOG = """\b
Exit status: 0 every gate passed (or none was set); 1 a gate failed or the run got worse
than --baseline beyond its limits; 2 bad input or options that do not go together.
Whenever a gate is given, every surveyed pose needs an estimate (--min-paired-pct 100):
a pose without one fails every per-pose gate.

\b
Another localizer in CI, e.g. AMCL in a ROS 2 bag:
  segloc evaluate run/ --topic /amcl_pose --survey survey.csv --fail-above-xy-cm 10 \\
      --junit report.xml --html report.html --baseline main.json --fail-if-worse-cm 1
"""


@click.command(epilog=EPILOG)
@click.argument("estimates_path", metavar="EST", type=FilePath())
@with_options(*EVALUATE_OPTIONS)
def evaluate(estimates_path, force, **given):
    """Score estimates against ground truth.

    EST is segloc's estimates CSV, a TUM trajectory, or a ROS 1 bag, ROS 2 bag or MCAP
    file with --topic (any 2D localizer's output: AMCL, slam_toolbox, Cartographer...).
    Estimates are paired with the truth by time; two rows equally near a time are
    refused, never paired silently, and the counts paired, unpaired and dropped are
    printed.

    With --survey, the paper's Table 1: one row per surveyed pose with AE (the
    stage-1 heading error; blank for other localizers and --global runs), the initial
    and the final errors X, Y, |XY| (cm) and θ (°), "surveyed minus computed", then
    RMS and max (of absolute values) over one set of poses (every pose with an
    estimate; --only-ok: those accepted). Under it: the poses by status, the drift per
    travelled length (1, 2, 5, 10 m) and, where the estimates carry a covariance, the
    share of poses inside their 1σ/2σ/3σ ellipse and the NEES, which say whether the
    localizer's own uncertainty can be believed.

    With --relations, the metric of Kümmerle et al. (2009) for logs without surveyed
    poses: mean ± std of the translational (m) and rotational (°) error of the
    estimated relative motions.

    Gates (--fail-*) bound each pose or the RMS, mean or a percentile; --baseline
    compares with an earlier run; --junit, --summary-md and --html write what CI shows.
    --plots draws the figures: errors per pose, over time and over travelled distance,
    and with --map and --log those of both stages (--relations: the trajectory and the
    relation errors over time).
    """
    from segloc_cli.io.tables import refuse_map
    from segloc_cli.runs import evaluation

    _unused_figure_inputs(given)
    options = evaluation.EvaluateOptions.from_options(estimates_path, given)
    problem = options.usage_problem()
    if problem is not None:
        raise click.UsageError(problem)
    # Outputs are checked before any input is read, so a refusal costs no work.
    check_command_outputs(options.outputs, options.inputs, force, replaced=options.REPORTS)
    if options.survey_path is not None:
        refuse_map(options.survey_path, "--survey", "the surveyed poses")
    if options.plots_dir is not None:
        evaluation.check_plots(options, force)
    step_summary = _step_summary(options)
    estimates = evaluation.read_scored_estimates(options)
    scores, figures = _score(estimates, options)
    info(scores.pairing)
    for warning in scores.warnings:
        warn(warning)
    _emit(scores.text, options.out_path)
    _write_reports(options, scores, figures, step_summary)
    if options.plots_dir is not None:
        _draw(options, figures)
    if scores.all_outcomes:
        info(scores.verdict_line)
    if not scores.passed:
        info(f"gate: {scores.violations_line}")
        sys.exit(EXIT_GATE_FAILED)


def _score(estimates, options):
    """The scores, and the figures (name → drawing function) when figures are asked for."""
    from segloc_cli.io.maps import read_map
    from segloc_cli.io.tables import read_pose_table
    from segloc_cli.runs import evaluation

    drawn = options.plots_dir is not None or options.html_path is not None
    # Read before anything is printed, so a bad path stops the command with nothing half done.
    segments_world = None if options.map_path is None else read_map(options.map_path)
    if options.relations_path is not None:
        scores, run = evaluation.relation_scores(estimates, options)
        figures = evaluation.relation_figures_of(run, segments_world) if drawn else {}
        return scores, figures
    survey = read_pose_table(options.survey_path)
    log = None if options.log_path is None else load_log(options.log_path)
    scores = evaluation.survey_scores(estimates, survey, options)
    if not drawn:
        return scores, {}
    if options.plots_dir is not None and (segments_world is None or log is None):
        from segloc_cli.scoring.plots import MAP_FIGURES, OVERLAY

        # The stages' figures are segloc's own: another localizer's rows have no stages.
        stages = estimates[["align_theta_deg", "init_theta_deg"]].notna().to_numpy().any()
        skipped = MAP_FIGURES if stages else (OVERLAY,)
        need = plural(len(skipped), "it needs", "they need")
        info(f"skipped {', '.join(skipped)}: {need} --map MAP.json and --log LOG.mcap")
    return scores, evaluation.figures_of(options, scores, estimates, survey, segments_world, log)


def _unused_figure_inputs(given: dict) -> None:
    """Leave out ``--map`` and ``--log`` set by a ``--config`` file when neither ``--plots``
    nor ``--html`` is given, saying so: they serve the figures alone, and the run file of a
    run with figures holds them but not its output folder. Given on the command line they
    stay, and are refused as options that do not go together."""
    if given["plots_dir"] is not None or given["html_path"] is not None:
        return
    ctx = click.get_current_context()
    from_file = [
        name
        for name in ("map_path", "log_path")
        if given[name] is not None
        and ctx.get_parameter_source(name) is click.core.ParameterSource.DEFAULT_MAP
    ]
    for name in from_file:
        option = name.removesuffix("_path")
        warn(
            f"--config sets --{option}, which serves the figures alone (--plots, --html): not read"
        )
        given[name] = None


def _step_summary(options) -> Path | None:
    """The step summary to append to (``GITHUB_STEP_SUMMARY``'s file), checked before any
    work; one that cannot take it is left alone, saying so."""
    from segloc_cli.runs.reports import step_summary_path

    path, problem = step_summary_path(options)
    if problem is not None:
        warn(problem)
    return path


def _write_reports(options, scores, figures, step_summary: Path | None) -> None:
    """The CI outputs asked for: JUnit, the Markdown summary, the HTML page (and GitHub's
    step summary); each said, and a step summary that could not be appended to warned of."""
    from segloc_cli.runs.reports import write_reports

    settings = Invocation.current().options
    written, problems = write_reports(options, scores, figures, settings, step_summary)
    for path in written:
        info(f"wrote {path}")
    for problem in problems:
        warn(problem)


def _draw(options, figures) -> None:
    """Draw the figures of ``--plots`` into its folder, made if needed, saying which."""
    from segloc_cli.io.figures import write_figures
    from segloc_cli.progress import Progress

    options.plots_dir.mkdir(parents=True, exist_ok=True)
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
