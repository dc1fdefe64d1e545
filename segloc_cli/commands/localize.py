"""``segloc localize``: every scan of some logs against a map, rows written as they come."""

from __future__ import annotations

import sys
import time
from collections import Counter
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path

import click

from segloc_cli.commands.options import (
    GuessSource,
    Invocation,
    config_option,
    force_option,
    info,
    load_log,
    path_option,
    setting_option,
    tuning_options,
    warn,
    with_options,
    within_cores,
)
from segloc_cli.config import (
    GUESSES_KEYWORD,
    LOCALIZE_TUNING,
    MATCHER,
    REGION,
    STAGES,
    WINDOW,
    run_config,
)
from segloc_cli.errors import EXIT_INTERRUPTED
from segloc_cli.runfile import beside, run_file_path

PROGRESS_LABELS = {"guided": "localizing", "global": "global search", "track": "tracking"}
"""What the progress display says a run of each mode is doing."""

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
    click.option(
        "--initial",
        type=GuessSource(),
        default=GUESSES_KEYWORD,
        show_default=True,
        help="Initial guesses: 'odom' (the log's /odom nearest in time) or a CSV/TUM file; "
        "scans without a guess are skipped.",
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
        help="Track along the log: --initial seeds only the first scan; each next guess is the "
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
@click.argument(
    "log_paths", metavar="LOG.mcap...", nargs=-1, required=True, type=click.Path(path_type=Path)
)
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
):
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
    from segloc_cli import pipeline
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import read_map

    run = Invocation.current()
    config = run_config(run.options, global_search, track)
    config = replace(config, jobs=within_cores(config.jobs, "localizing on {cores} processes"))
    mode = "global" if global_search else "track" if track else "guided"
    guess_file = None if initial == GUESSES_KEYWORD else Path(initial)
    listed = None if hypotheses is None else (beside(out_path, ".hypotheses.csv"), hypotheses)
    outputs = {"--out": out_path, "--tum": tum_path, "--mcap": mcap_path}
    outputs["--hypotheses"] = None if listed is None else listed[0]
    outputs["--out (run file)"] = run_file_path(out_path)
    check_outputs(outputs, [*log_paths, map_path, guess_file], run.force)
    segments_world = read_map(map_path)
    if mode == "global":
        pipeline.check_global_extent(segments_world, map_path, config.localize.search.region)
    localizer = pipeline.localizer_for(segments_world, config)
    stops: list[str] = []  # signals asking the run to stop, noted while it runs

    def stop() -> bool:
        return bool(stops)

    logs = [load_log(p) for p in log_paths]
    runs = [
        pipeline.localize_log(log, p, localizer, mode, guess_file, config, stop)
        for log, p in zip(logs, log_paths, strict=True)
    ]
    for message in pipeline.overlapping_logs(runs):
        warn(message)
    for log_run in runs:
        if log_run.local_maps:
            info(f"{log_run.path}: {log_run.local_maps}")
    with ExitStack() as stack:
        rows = (row for run in runs for row in run.rows)
        if mcap_path is not None:
            view = stack.enter_context(
                _run_view(mcap_path, segments_world, log_paths, map_path, mode)
            )
            rows = _shown(view, runs, logs, config)
        summary = _write_rows(rows, runs, out_path, tum_path, listed, stops, mode)
    run.write_run_file(out_path)
    _report(summary, out_path, stops, skipped=sum(r.skipped for r in runs))
    if listed is not None:
        info(f"{listed[0]}: up to {listed[1]} distinct poses per scan, best first")


def _run_view(mcap_path: Path, segments_world, log_paths, map_path: Path, mode: str):
    """The run view's writer, for a run of the logs on the map."""
    from segloc_cli.io.runview import RunViewWriter

    metadata = {"command": "localize", "mode": mode, "map": str(map_path)}
    metadata["logs"] = ", ".join(str(log_path) for log_path in log_paths)
    return RunViewWriter(mcap_path, segments_world, metadata)


def _shown(view, runs, logs, config):
    """The rows of ``runs``, each also added to the run view with its scan."""
    from segloc_cli.extract import extract_segments

    for run, log in zip(runs, logs, strict=True):
        scans = {scan.time_s: scan for scan in log.scans}
        for row in run.rows:
            scan = scans[row["time_s"]]
            view.add(
                scan,
                extract_segments(scan, config.extract),
                _row_pose(row, ""),
                guess=_row_pose(row, "init_"),
                runner_up=_row_pose(row, "runner_up_"),
                hypotheses=tuple(_row_pose(h, "") for h in row.get("hypotheses", [])[1:]),
                status=row["status"],
                level=_level(row["status"]),
                text=_row_text(run.path, row),
            )
            yield row


def _row_pose(row, prefix: str):
    """The pose of a row's ``{prefix}x_m``, ``y_m``, ``theta_deg`` columns: NaN where the row
    has none, which the run view leaves out."""
    from segloc_cli.geometry import Pose2

    return Pose2.from_deg(row[f"{prefix}x_m"], row[f"{prefix}y_m"], row[f"{prefix}theta_deg"])


def _level(status: str) -> str:
    """The run view's log level of a status: info when the estimate is accepted, warning when
    a distinct pose fits nearly as well, error otherwise."""
    from segloc_cli.estimates import ESTIMATED, STATUS_AMBIGUOUS

    return "info" if status in ESTIMATED else "warning" if status == STATUS_AMBIGUOUS else "error"


def _row_text(log_path: Path, row) -> str:
    """One line on a row for the run view's log."""
    import math

    runner_up = (
        f"a distinct pose fits {row['runner_up_ratio']:.0%}"
        if math.isfinite(row["runner_up_x_m"])
        else "no distinct pose fits as well"
    )
    return (
        f"{log_path.name} pose {row['pose_id']} at {row['time_s']:.3f} s: "
        f"{row['inlier_ratio']:.0%} of the points on the map, overlap {row['overlap']:.2f} m, "
        f"{row['n_local_segments']} local segments; {runner_up}; "
        f"confidence {row['confidence']:.2f}"
    )


def _write_rows(rows, runs, out_path: Path, tum_path, listed, stops: list[str], mode: str):
    """Write ``rows`` (those of ``runs``) to ``out_path`` (and ``tum_path``, and the first K
    hypotheses of each to the path of ``listed`` = (path, K)) as they come,
    with progress on long runs (and, for a global search, the first scan's time as the time
    to expect per scan). Ctrl-C, SIGTERM and SIGHUP, noted in ``stops``, stop it between
    scans with every finished row kept. Returns (n scans planned, statuses, runtimes (ms), s)."""
    from segloc_cli.io.tables import EstimatesWriter, HypothesesWriter, TumWriter
    from segloc_cli.progress import Progress
    from segloc_cli.stopping import stop_requests

    n_scans = sum(run.times_s.size for run in runs)
    t0 = time.perf_counter()
    statuses: list[str] = []
    runtimes_ms: list[float] = []
    with ExitStack() as stack:
        stack.enter_context(stop_requests(stops))
        writers = [stack.enter_context(EstimatesWriter(out_path))]
        if tum_path is not None:
            writers.append(stack.enter_context(TumWriter(tum_path)))
        if listed is not None:
            writers.append(stack.enter_context(HypothesesWriter(*listed)))
        progress = stack.enter_context(Progress(PROGRESS_LABELS[mode], n_scans, "scan"))
        try:
            for row in rows:
                progress.advance()
                for writer in writers:
                    writer.write_row(row)
                statuses.append(row["status"])
                runtimes_ms.append(row["runtime_ms"])
                if mode == "global" and len(runtimes_ms) == 1:
                    _expect(row["runtime_ms"], n_scans)
                if stops:
                    break
        except KeyboardInterrupt:  # Ctrl-C that arrived outside the stop handler
            stops.append("Ctrl-C")
    return n_scans, statuses, runtimes_ms, time.perf_counter() - t0


def _expect(first_ms: float, n_scans: int) -> None:
    """Say how long a global run will take, from its first scan."""
    each = first_ms / 1e3
    total_min = each * n_scans / 60.0
    info(f"global search: about {each:.1f} s per scan, {n_scans} scans (about {total_min:.1f} min)")


def _report(summary, out_path: Path, stops: list[str], skipped: int) -> None:
    """Print how the run went; exit 130 if it was interrupted."""
    import numpy as np

    n_scans, statuses, runtimes_ms, elapsed = summary
    done = len(statuses)
    if stops:
        kept = f"their estimates are in {out_path}" if done else f"{out_path} holds the header only"
        click.echo(
            f"segloc: interrupted ({stops[0]}) after {done} of {n_scans} scans; {kept}", err=True
        )
        sys.exit(EXIT_INTERRUPTED)
    counts = ", ".join(f"{n} {status}" for status, n in Counter(statuses).most_common())
    info(
        f"{out_path}: {done} scans localized ({counts}) in {elapsed:.2f} s, "
        f"median {np.median(runtimes_ms):.1f} ms per scan"
        + (f"; {skipped} scans skipped (no initial guess or odometry)" if skipped else "")
    )
