"""``segloc localize``: every scan of some logs against a map, rows written as they come."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import click

from segloc_cli.commands.configfile import check_command_outputs, config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.localize_lines import expect, report, say_how
from segloc_cli.commands.options import (
    SCAN_SELECTION,
    FilePath,
    GuessSource,
    force_option,
    path_option,
    scan_selection,
    setting_option,
    tuning_options,
    with_options,
)
from segloc_cli.commands.printing import load_log, within_cores
from segloc_cli.config import GUESSES_KEYWORD, LOCALIZE_TUNING, MATCHER, REGION, STAGES, WINDOW

LOCALIZE_OPTIONS = (
    path_option(
        "--map", "map_path", required=True, help="Global map (MAP.json; a world file also works)."
    ),
    path_option("--out", "out_path", required=True, help="Estimates CSV to write."),
    path_option(
        "--tum", "tum_path", help="Also write the estimates as a TUM trajectory (for evo)."
    ),
    path_option(
        "--mcap",
        "mcap_path",
        help="Also write the run view to open in Foxglove: the map, each scan placed at its "
        "estimate, the guesses, runner-ups and other hypotheses, local segments and statuses "
        "(the layout to open it with: segloc info --foxglove-layout prints its path).",
    ),
    click.option(
        "--hypotheses",
        type=click.IntRange(1, 64),
        default=None,
        metavar="K",
        help="Also write OUT's .hypotheses.csv (est.csv → est.hypotheses.csv): for each scan "
        "up to K distinct poses that explain it, best first, each with the probability that "
        "it is the right place. The search hands on --search-hypotheses poses (4), so at "
        "most one more than that is found.",
    ),
    *SCAN_SELECTION,
    click.option(
        "--initial",
        type=GuessSource(),
        default=GUESSES_KEYWORD,
        show_default=True,
        metavar="odom|X,Y,THETA_DEG|FILE",
        help="Initial guesses: 'odom' (the log's /odom nearest in time); X,Y,THETA_DEG, the "
        "pose of the first (selected) scan in the map (metres, degrees), the others' guesses "
        "carried from it by the log's odometry (with --track: where the track starts); or a "
        "CSV file with the columns pose_id,time_s,x_m,y_m,theta_deg (or a TUM file), each row "
        "the guess of the scan nearest its time within --tolerance-ms. Scans without a guess "
        "are skipped.",
    ),
    *(setting_option(s.key) for s in STAGES),
    click.option(
        "--global",
        "global_search",
        is_flag=True,
        help="No initial pose: search the whole map at every heading and report the best fit "
        "and its runner-up. Every scan is localized, or only those listed by --initial FILE "
        "(whose poses are then not used).",
    ),
    setting_option(REGION.key),
    click.option(
        "--track",
        is_flag=True,
        help="Track along the log: --initial seeds only the first scan (--initial "
        "X,Y,THETA_DEG gives its pose); each next guess is the "
        "previous estimate moved by the /odom increment, and the scan's points are fitted from "
        "it with the odometry as a prior (with --no-refine: the two stages from it). Failed "
        "matches are retried wider and flagged (status recovered or lost).",
    ),
    *(setting_option(s.key) for s in MATCHER),
    setting_option(WINDOW.key),
    setting_option("tolerance-ms", pairing="pairing scans with initial guesses or odometry"),
    config_option,
    force_option,
    tuning_options(LOCALIZE_TUNING),
)


@click.command()
@click.argument("log_paths", metavar="LOG.mcap...", nargs=-1, required=True, type=FilePath())
@with_options(*LOCALIZE_OPTIONS)
def localize(
    log_paths,
    map_path,
    out_path,
    tum_path,
    mcap_path,
    hypotheses,
    initial,
    global_search,
    track,
    **_,
) -> None:
    """Localize every scan of one or more logs against a map.

    For each scan: extract its segments, find the heading by the stage-1 vote
    around the initial heading, then the position (and a refined heading) by
    the stage-2 coarse-to-fine overlap search from the initial position, and
    last a robust least-squares fit of the scan's points to the map segments
    (the stage-2 pose is kept in its own columns). Stage 2 descends from one
    guess, so the best poses of a search of ±2 m around the guess, scored by
    how many of the scan's points fall on the map, are refined too, and the
    fit that explains the scan best wins.

    Where the log has odometry (an imported ROS bag or CARMEN log), each scan
    is localized with its window: the scans within --window-m (1 m) of
    odometry travel before and after it, placed by the odometry and fitted to
    each other, as one local map, so that a place that explains the scan but
    not its neighbours falls behind. A line per log says which way it ran;
    the window_scans column says how many scans each local map held.

    Each row's confidence is the probability that its answer is the right
    place (within 30 cm and 3°), fitted on simulated and real trials from
    how many of the points on the map at the answer the best distinct pose
    (the runner_up columns) leaves off it, and how firmly the points fix the
    position. The status follows: ok at a confidence of 0.9 or more
    (--confidence-min-confidence); ambiguous below it, or where nothing fixes
    the position along one direction (a featureless corridor); lost (under
    half the scan lies on the map). A scan that yields too few segments gets
    a status instead of a pose, and the batch goes on. --no-refine runs the
    paper's two stages alone.

    --method icp and --method correlative run two widely used matchers on
    the same scans and guesses, for comparison (see make bench-peers).

    Rows are written to OUT as they are made: Ctrl-C, SIGTERM or even a
    killed process leaves every finished row in the file. Beside OUT goes
    its run file (OUT.run.toml): --config OUT.run.toml repeats the run.
    """
    from segloc_cli.io.maps import read_map
    from segloc_cli.jit import GLOBAL_KERNELS, watching_compiles
    from segloc_cli.progress import Progress
    from segloc_cli.runs import pipeline
    from segloc_cli.runs.rowstream import RowOutputs, write_rows

    run = Invocation.current()
    config, mode = _config(run, global_search, track)
    later = GLOBAL_KERNELS if mode == "global" and config.method == "two-stage" else None
    click.get_current_context().with_resource(watching_compiles(ahead=True, later=later))
    guesses = _guess_source(initial, mode, len(log_paths))
    selection = scan_selection(run.options)
    written = RowOutputs.beside(out_path, tum_path, hypotheses, mcap_path)
    guess_file = guesses if isinstance(guesses, Path) else None
    check_command_outputs(written.by_option(), [*log_paths, map_path, guess_file], run.force)
    segments_world = read_map(map_path)
    if mode == "global":
        pipeline.check_global_extent(segments_world, map_path, config.localize.search.region)
    # Before the map is prepared (compiling the kernels, the first time): a log that is not
    # one is told at once.
    logs = [load_log(p) for p in log_paths]
    localizer = pipeline.localizer_for(segments_world, config, mode)
    stops: list[str] = []  # signals asking the run to stop, noted while it runs
    runs = [
        pipeline.localize_log(
            log,
            p,
            localizer,
            mode,
            guesses,
            config,
            lambda: bool(stops),
            selection.chosen(log.scan_times_s, p),
        )
        for log, p in zip(logs, log_paths, strict=True)
    ]
    say_how(runs)
    view = _view(segments_world, logs, mode, config) if mcap_path else None
    summary = write_rows(runs, written, stops, mode, Progress, expect, view)
    run.write_run_file(out_path, stopped=summary.stopped)
    report(summary, written)


def _config(run: Invocation, global_search: bool, track: bool):
    """(the run's ``Config``, its mode): its settings checked together (``run_config``), and
    ``--jobs`` no more than the cores there are."""
    from segloc_cli.config import run_config

    config = run_config(run.options, global_search, track)
    config = replace(
        config, jobs=within_cores(config.jobs, "localizing on", "process", "processes")
    )
    return config, "global" if global_search else "track" if track else "guided"


def _guess_source(initial: str, mode: str, n_logs: int):
    """Where ``--initial`` takes the guesses from: None (the log's /odom), the first scan's
    pose (a ``Pose2``, world frame) or a file's path. A pose is refused with ``--global``,
    which takes no initial pose, and for more than one log (``n_logs``), which would all
    start there; a file that is a segloc map or world, which would take guesses from nothing."""
    from segloc_cli.commands.optionvalues import seed_pose
    from segloc_cli.geometry import Pose2
    from segloc_cli.io.tables import refuse_map

    if initial == GUESSES_KEYWORD:
        return None
    pose = seed_pose(initial)
    if pose is None:
        refuse_map(
            initial,
            "--initial",
            f"{GUESSES_KEYWORD}, the first scan's pose X,Y,THETA_DEG, or a file of guesses",
        )
        return Path(initial)
    if mode == "global":
        raise click.UsageError(
            "--initial X,Y,THETA_DEG cannot be combined with --global: a global search takes "
            "no initial pose (--initial FILE lists the scans to search)"
        )
    if n_logs > 1:
        raise click.UsageError(
            f"--initial X,Y,THETA_DEG is the pose of one log's first scan, not of {n_logs} "
            "logs': localize them one at a time, or give a guess file"
        )
    return Pose2.from_deg(*pose)


def _view(segments_world, logs, mode: str, config):
    """What the run view shows: the map (M, 4; world frame) and ``logs`` (the command's logs,
    localized in ``mode``)."""
    from segloc_cli.runs.rowstream import RunView

    run = Invocation.current()
    metadata = {"command": "localize", "mode": mode, "map": str(run.options["map"])}
    metadata["logs"] = ", ".join(str(log_path) for _, log_path in run.arguments)
    return RunView(segments_world, metadata, logs, config.extract)
