"""``segloc sweep``: logs × settings × seeds localized and scored, on a Dask cluster."""

from __future__ import annotations

import os
from pathlib import Path

import click
from click.core import ParameterSource

from segloc_cli.commands.configfile import check_command_outputs, config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.options import FilePath, force_option, format_option, path_option
from segloc_cli.commands.printing import info, warn, within_cores
from segloc_cli.method.confidence import RIGHT_PLACE_DEG, RIGHT_PLACE_M
from segloc_cli.wording import counted


@click.command()
@click.argument("spec_path", metavar="SPEC.toml", type=FilePath())
@path_option("--out", "out_path", required=True, help="Results table to write (Parquet).")
@click.option(
    "--scheduler",
    metavar="ADDRESS",
    default=None,
    help="Run the tasks on the Dask cluster of this scheduler (e.g. tcp://10.0.0.5:8786) "
    "instead of a local one.",
)
@click.option(
    "--jobs",
    type=click.IntRange(1, 1024),
    default=os.cpu_count() or 1,
    show_default="this machine's cores",
    help="Worker processes of the local cluster (not with --scheduler).",
)
@format_option("segloc_cli.runs.sweep", "SUMMARY_FORMATS", "Format of the summary printed.")
@click.option(
    "--convergence",
    metavar="PREFIX",
    type=FilePath(),
    help="Also write convergence curves, per combination the share of poses found within "
    f"{100 * RIGHT_PLACE_M:g} cm and {RIGHT_PLACE_DEG:g}° of the truth against the guess's "
    "position and heading errors, with 95 % Wilson intervals: PREFIX.md, PREFIX.png, "
    "PREFIX.pdf (existing ones need --force, which runs the sweep afresh).",
)
@config_option
@force_option
def sweep(spec_path, out_path, scheduler, jobs, fmt, convergence, force):
    """Localize and score every log × combination of settings × seed of a spec.

    \b
    The spec (TOML; paths relative to its folder):
      map = "datasets/hall/map.json"
      logs = ["datasets/hall/log.mcap"]
      survey = "datasets/hall/survey.csv"
      init-errors = "uniform:1.5,20"   # guesses = survey − errors; or initial = "FILE"
      seeds = [1, 2]
      [grid]                           # every combination is run
      iterations = [6, 8]
      grid-m = [1.0, 1.5]

    Any setting of segloc localize (its long option name, e.g. method,
    global, no-refine, search-half-width-m) can be fixed at the top level or
    listed in [grid]. A log may be a table {path = ..., map = ..., survey =
    ...} with a map and survey of its own. The guesses are drawn per seed and
    log (the same for every combination), or taken from initial = "FILE", or
    from the log's /odom (initial = "odom", the default). fail-above-cm and
    fail-above-deg (10 cm, 1°) set the summary's gates, as in evaluate.

    Each task (one log, combination and seed) runs on a Dask worker: a local
    cluster of --jobs processes, or the cluster of --scheduler, whose workers
    must have segloc installed and read each log from the path given (a
    shared folder); the map, survey and guesses go with the task.

    OUT holds one row per log × scan × seed × combination: the task's key,
    log, combination and seed, the grid's values, the guess and estimate
    (metres, degrees), status, confidence, errors (cm, degrees, surveyed
    minus estimate) and runtime_ms. The rows are the same wherever and in
    whatever order the tasks ran, but for runtime_ms. Each finished task is
    kept at once (in OUT.parts/ until the sweep ends), so a sweep stopped by
    Ctrl-C or even killed keeps all it finished, and running it again with
    the same OUT runs only the tasks it lacks (--force starts afresh). A task
    that fails is tried once more, then kept as a row with status "task
    failed" and its error; the sweep goes on, exits 1, and a rerun tries it
    again.

    Every survey pose within a log's time span has a row: one that no scan
    lies near in time to has status "no scan", one without a guess "no
    guess", and both count as misses. The summary printed has a row per
    combination: poses, the share within the gates, median and 95th
    percentile errors (a pose without an estimate counting as infinitely
    wrong), and the median time per scan.
    """
    from segloc_cli.runs.sweepspec import read_spec

    _check_extra()
    _check_scheduler(scheduler)
    from segloc_cli.runs.runfile import RUN_FILE_OUTPUT, run_file_path
    from segloc_cli.runs.sweep import convergence_outputs

    run = Invocation.current()
    curves = convergence_outputs(convergence)
    check_command_outputs(curves, [], force)
    # An existing OUT is the sweep's to resume (force), but never one of its inputs.
    outputs = {"--out": out_path, RUN_FILE_OUTPUT: run_file_path(out_path), **curves}
    check_command_outputs(outputs, [spec_path], force=True)
    plan = read_spec(spec_path)
    check_command_outputs(outputs, [path for _, path in plan.inputs], force=True)
    table, stops = _run(plan, out_path, scheduler, jobs, force)
    run.write_run_file(out_path, also_read=plan.inputs)
    from segloc_cli.commands.sweep_lines import report

    report(plan, table, out_path, fmt, stops, convergence)


def _check_extra() -> None:
    """Refuse to start without Dask and pyarrow, saying how to get them."""
    import importlib.util

    missing = [m for m in ("distributed", "pyarrow") if importlib.util.find_spec(m) is None]
    if missing:
        raise click.UsageError(
            f"segloc sweep needs {' and '.join(missing)}: pip install 'segloc[sweep]'"
        )


def _check_scheduler(scheduler: str | None) -> None:
    """Refuse ``--jobs`` with ``--scheduler``, and a ``--scheduler`` that names no scheduler
    (before the spec is read)."""
    from segloc_cli.runs.sweep import address_problem

    if scheduler is None:
        return
    if click.get_current_context().get_parameter_source("jobs") == ParameterSource.COMMANDLINE:
        raise click.UsageError("--jobs sets the local cluster; with --scheduler, the cluster's "
                               "workers are those started with `dask worker`")  # fmt: skip
    problem = address_problem(scheduler)
    if problem is not None:
        raise click.BadParameter(
            f"{scheduler!r}: {problem}; e.g. tcp://10.0.0.5:8786", param_hint="--scheduler"
        )


def _local_workers(jobs: int, n_tasks: int) -> int:
    """The local cluster's size: ``jobs``, but no more than the tasks to run, nor than the
    cores segloc may use (``within_cores``, which warns only when ``--jobs`` was given)."""
    from segloc_cli.runs.parallel import usable_cores

    source = click.get_current_context().get_parameter_source("jobs")
    if source == ParameterSource.DEFAULT:
        jobs = min(jobs, usable_cores())
    else:
        jobs = within_cores(jobs, "a local cluster of at most", "worker")
    return max(1, min(jobs, n_tasks))


def _run(plan, out_path: Path, scheduler: str | None, jobs: int, force: bool):
    """Run the plan's tasks not yet in ``out_path``; (the table written, stop signals)."""
    from segloc_cli.progress import Progress
    from segloc_cli.runs.sweep import ResultStore, connect, run_tasks, where
    from segloc_cli.stopping import stop_requests

    store = ResultStore(out_path, fresh=force)
    todo = store.todo(plan.tasks)
    planned = f"sweep: {counted(len(plan.tasks), 'task')}"
    if len(todo) < len(plan.tasks):
        planned += f", {len(plan.tasks) - len(todo)} done before"
    stops: list[str] = []
    if not todo:
        info(f"{planned}; nothing to run")
    else:
        workers = jobs if scheduler else _local_workers(jobs, len(todo))
        with connect(scheduler, workers, warn) as client, stop_requests(stops):
            info(f"{planned}; running {len(todo)} on {where(client, scheduler)}")
            with Progress("sweeping", len(todo), "task") as progress:
                run_tasks(client, todo, store, progress.advance, lambda: bool(stops))
    table = store.finish([t.key for t in plan.tasks])
    return table, stops
