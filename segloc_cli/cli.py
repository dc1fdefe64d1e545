"""The ``segloc`` command line: parse, call the library, print. No algorithm lives here."""

from __future__ import annotations

import io
import itertools
import math
import sys
import time
from dataclasses import asdict
from pathlib import Path

import click
import numpy as np

from segloc_cli import __version__
from segloc_cli.align import VOTE_SCHEMES
from segloc_cli.errors import InputError, SeglocError
from segloc_cli.geometry import Pose2
from segloc_cli.scan import MAX_RANGE_M

GATE_SHOWN = 5
"""Violations of an evaluate gate named on its one line; the table shows them all."""
PROGRESS_MIN_SCANS = 20
"""Show a progress bar when a command works through at least this many scans."""

TIME_TOLERANCE_MS = 50.0
"""Default largest time difference when pairing records of two files by time."""

EXIT_GATE_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERNAL_ERROR = 70
"""An unexpected error (a bug): one line, and the traceback in a file it names (sysexits'
EX_SOFTWARE)."""
EXIT_INTERRUPTED = 130


class FiniteRange(click.FloatRange):
    """``click.FloatRange`` that also refuses NaN and the infinities (which pass its bounds)."""

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return number


def _warn(message: str) -> None:
    click.echo(f"segloc: warning: {message}", err=True)


def _info(message: str) -> None:
    click.echo(message, err=True)


def _load_log(path: Path):
    from segloc_cli.io.mcap_log import read_log

    contents = read_log(path)
    for warning in contents.warnings:
        _warn(warning)
    return contents


def _tolerance_option(pairing: str):
    """The ``--tolerance-ms`` option, for pairing the records named by ``pairing``."""
    return click.option(
        "--tolerance-ms",
        type=FiniteRange(min=0, max=60_000),
        default=TIME_TOLERANCE_MS,
        show_default=True,
        help=f"Largest time difference when {pairing}.",
    )


force_option = click.option(
    "--force", is_flag=True, help="Overwrite the output file(s) if they exist."
)
"""``--force``: every command that writes a file refuses an existing one without it."""


def _time_range(times_s) -> str:
    times_s = np.asarray(times_s, dtype=float)
    if times_s.size == 0:
        return "none"
    return f"{times_s.min():.3f}–{times_s.max():.3f} s"


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="segloc")
def cli() -> None:
    """Localize a robot in a known map from 2D laser scans, and measure how well it works.

    segloc implements the two-stage method of Reina & Gonzalez (2000): the
    heading comes from a length-weighted Hough vote over segment orientations,
    then the position from a coarse-to-fine search that maximises how much the
    scan's segments overlap the map's.

    \b
    A typical run:
      segloc simulate world.json --poses poses.csv --out sim/
      segloc map build sim/log.mcap --survey sim/survey.csv --out map.json
      segloc localize sim/log.mcap --map map.json --out estimates.csv
      segloc evaluate estimates.csv --survey sim/survey.csv

    Units: metres and degrees in files and options, errors in cm and degrees
    in tables ("surveyed minus computed", as in the paper).
    """


# --------------------------------------------------------------------------- simulate


def _check_increasing_times(times_s: np.ndarray, path: Path, what: str) -> None:
    """Refuse, naming the row, times that are negative, past ``MAX_TIME_S`` or not increasing
    (a log of such times could not be paired with its survey)."""
    from segloc_cli.io.times import MAX_TIME_S

    outside = np.flatnonzero(~((times_s >= 0) & (times_s <= MAX_TIME_S)))
    if outside.size:
        row = int(outside[0])
        raise InputError(
            f"column time_s is {times_s[row]:g}; {what} must be from 0 to {MAX_TIME_S:.0f} s",
            path=path,
            row=row + 1,
        )
    stalled = np.flatnonzero(np.diff(times_s) <= 0)
    if stalled.size:
        row = int(stalled[0]) + 1
        raise InputError(
            f"column time_s is {times_s[row]:g}, not after the row before; {what} must increase",
            path=path,
            row=row + 1,
        )


def _parse_init_errors(value: str) -> tuple[str, float, float]:
    if value == "paper":
        return ("paper", 0.0, 0.0)
    if value.startswith("uniform:"):
        try:
            xy, theta = (float(v) for v in value[len("uniform:") :].split(","))
        except ValueError:
            pass
        else:
            if 0 <= xy <= MAX_RANGE_M and 0 <= theta <= 180:
                return ("uniform", xy, theta)
    raise click.BadParameter(
        f"{value!r}; use 'paper' or 'uniform:XY_M,THETA_DEG' with XY_M in 0..{MAX_RANGE_M:g} "
        "and THETA_DEG in 0..180 (e.g. uniform:1.5,20)",
        param_hint="--init-errors",
    )


@cli.command()
@click.argument("world_path", metavar="WORLD.json", type=click.Path(path_type=Path))
@click.option(
    "--poses",
    "poses_path",
    required=True,
    type=click.Path(path_type=Path),
    help="CSV of true poses: pose_id,[time_s,]x_m,y_m,theta_deg.",
)
@click.option(
    "--out", "out_dir", required=True, type=click.Path(path_type=Path), help="Output folder."
)
@click.option(
    "--readings",
    type=click.Choice(["128", "256", "1024", "2048"]),
    default="1024",
    show_default=True,
    help="Readings per 360° revolution (the Explorer's settings).",
)
@click.option(
    "--noise-cm",
    type=FiniteRange(min=0, max=100),
    default=1.2,
    show_default=True,
    help="Gaussian range noise σ.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option(
    "--init-errors",
    default="paper",
    show_default=True,
    help="Initial-guess errors written to /odom: 'paper' (Table 1 of the paper, exactly) "
    "or 'uniform:XY_M,THETA_DEG' (uniform in ±XY_M per axis and ±THETA_DEG).",
)
@force_option
def simulate(world_path, poses_path, out_dir, readings, noise_cm, seed, init_errors, force):
    """Simulate a 360° laser log of a world at given poses.

    Writes OUT/log.mcap (/scan as foxglove.LaserScan, /odom as
    foxglove.PoseInFrame carrying the initial guesses) and OUT/survey.csv (the
    true poses, as ground truth). The sensor is modelled on the paper's
    Explorer: Gaussian range noise, 1 mm resolution, dropouts, short spurious
    returns from people, and glass that rarely returns.
    """
    from segloc_cli.io.files import atomic_path, check_outputs
    from segloc_cli.io.maps import read_world
    from segloc_cli.io.mcap_log import LogWriter
    from segloc_cli.io.tables import PoseTable, read_pose_table, write_pose_table
    from segloc_cli.sim import (
        SensorModel,
        initial_guesses,
        paper_initial_errors,
        simulate_scan,
        uniform_initial_errors,
    )

    mode, xy_m, theta_deg = _parse_init_errors(init_errors)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("is a file; --out takes a folder", path=out_dir)
    log_path, survey_path = out_dir / "log.mcap", out_dir / "survey.csv"
    if out_dir.is_dir():
        outputs = {"--out (log.mcap)": log_path, "--out (survey.csv)": survey_path}
        check_outputs(outputs, [world_path, poses_path], force)
    world = read_world(world_path)
    truth = read_pose_table(poses_path, require_time=False)
    times = truth.time_s
    if np.isnan(times).any():
        times = np.arange(1, len(truth) + 1, dtype=float)
    _check_increasing_times(times, poses_path, "log times")
    rng = np.random.default_rng(seed)
    if mode == "paper":
        errors = paper_initial_errors(len(truth))
    else:
        errors = uniform_initial_errors(len(truth), xy_m, theta_deg, rng)
    guesses = initial_guesses(truth.poses, errors)
    sensor = SensorModel(readings=int(readings), noise_cm=noise_cm)

    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the folder ({exc.strerror})", path=out_dir) from None
    settings = {
        "device": "simulated Explorer",
        "readings": readings,
        "noise_cm": repr(noise_cm),
        "range_max_m": repr(sensor.range_max_m),
        "seed": str(seed),
        "world": world.name,
        "init_errors": init_errors,
    }
    with atomic_path(log_path) as partial, LogWriter(partial, settings) as log:
        for t, pose, guess in zip(times, truth.poses, guesses, strict=True):
            log.add_odom(float(t), Pose2(*guess))
            log.add_scan(simulate_scan(world, Pose2(*pose), sensor, rng, float(t)))
    write_pose_table(survey_path, PoseTable(truth.pose_id, times, truth.poses))
    _info(f"wrote {len(truth)} scans to {log_path} and the true poses to {survey_path}")


# --------------------------------------------------------------------------- import


@cli.group("import")
def import_group() -> None:
    """Convert public laser logs into segloc's MCAP log."""


def _write_imported(log, out_path: Path) -> None:
    """Write scans, odometry at the scans and sensor settings of an imported log."""
    from segloc_cli.io.files import atomic_path
    from segloc_cli.io.mcap_log import write_log

    for warning in log.warnings:
        _warn(warning)
    odometry = [
        (float(t), Pose2(*p)) for t, p in zip(log.odom_times_s, log.odom_poses, strict=True)
    ]
    with atomic_path(out_path) as partial:
        write_log(partial, log.scans, odometry, log.sensor, log.original_times_s)
    _info(f"{out_path}: {len(log.scans)} scans, {len(log.odom_times_s)} odometry poses")


@import_group.command("carmen")
@click.argument("log_path", metavar="FILE[.gz]", type=click.Path(path_type=Path))
@click.option(
    "--out", "out_path", required=True, type=click.Path(path_type=Path), help="MCAP log to write."
)
@click.option(
    "--survey-out",
    type=click.Path(path_type=Path),
    default=None,
    help="Also write the laser records' poses as a reference trajectory (survey CSV); "
    "in a SLAM-corrected log these are the corrected poses.",
)
@click.option(
    "--laser",
    type=click.Choice(["front", "rear"]),
    default="front",
    show_default=True,
    help="Which laser's records to read (FLASER/ROBOTLASER1 or RLASER).",
)
@click.option(
    "--range-max-m",
    type=FiniteRange(min=0, max=MAX_RANGE_M, min_open=True),
    default=None,
    help="Readings at or beyond this mean no return (default: from PARAM lines, or "
    "the sentinel value the log repeats).",
)
@force_option
def import_carmen(log_path, out_path, survey_out, laser, range_max_m, force):
    """Import a CARMEN text log (plain or gzip-compressed).

    Laser records become /scan (180°: the front laser from −90°, the rear
    from +90°; any number of beams) and their odometry fields /odom at the
    scan times. Malformed records are skipped and counted; every good record
    is kept. Records that share a time or go back in time get distinct times
    in file order (the README's "colliding times" rule), in the log and in
    --survey-out alike; their original times are kept as each message's MCAP
    publish time and in the survey's original_time_s column.
    """
    from segloc_cli.io.carmen import read_carmen
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.tables import PoseTable, write_pose_table

    check_outputs({"--out": out_path, "--survey-out": survey_out}, [log_path], force)
    log = read_carmen(log_path, laser=laser, range_max_m=range_max_m)
    _write_imported(log, out_path)
    if survey_out is not None:
        n = len(log.scans)
        write_pose_table(
            survey_out,
            PoseTable(np.arange(1, n + 1), log.odom_times_s, log.laser_poses),
            {"original_time_s": log.original_times_s},
        )
        _info(f"{survey_out}: {n} reference poses")


@import_group.command("rosbag")
@click.argument("bag_path", metavar="PATH", type=click.Path(path_type=Path))
@click.option(
    "--out", "out_path", required=True, type=click.Path(path_type=Path), help="MCAP log to write."
)
@click.option(
    "--scan-topic", default="/scan", show_default=True, help="sensor_msgs/LaserScan topic."
)
@click.option(
    "--odom-topic",
    default="/odom",
    show_default=True,
    help="nav_msgs/Odometry topic, interpolated to each scan's time ('' for none).",
)
@force_option
def import_rosbag(bag_path, out_path, scan_topic, odom_topic, force):
    """Import a ROS 1 .bag, a ROS 2 bag folder or a ROS 2 .mcap file."""
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.rosbag import read_rosbag

    check_outputs({"--out": out_path}, [bag_path], force)
    log = read_rosbag(bag_path, scan_topic=scan_topic, odom_topic=odom_topic or None)
    _write_imported(log, out_path)


# --------------------------------------------------------------------------- map


@cli.group("map")
def map_group() -> None:
    """Build segment maps."""


@map_group.command("build")
@click.argument("log_path", metavar="LOG.mcap", type=click.Path(path_type=Path))
@click.option(
    "--survey",
    "survey_path",
    required=True,
    type=click.Path(path_type=Path),
    help="Poses of the scans (survey CSV or TUM); scans without a row are ignored.",
)
@click.option(
    "--out", "out_path", required=True, type=click.Path(path_type=Path), help="MAP.json to write."
)
@_tolerance_option("pairing scans with survey rows")
@force_option
def map_build(log_path, survey_path, out_path, tolerance_ms, force):
    """Build a global segment map from the scans of a log at surveyed poses.

    Each scan with a survey row becomes a local map, is placed at its pose and
    fused with the others: nearly collinear segments that overlap or nearly
    touch become one.
    """
    from segloc_cli.extract import ExtractParams, extract_segments
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import bounds_problem, write_map
    from segloc_cli.io.tables import pair_by_time, read_pose_table
    from segloc_cli.mapping import FuseParams, build_global_map

    check_outputs({"--out": out_path}, [log_path, survey_path], force)
    log = _load_log(log_path)
    survey = read_pose_table(survey_path)
    times = log.scan_times_s
    rows = pair_by_time(
        times,
        survey.time_s,
        tolerance_ms / 1e3,
        query_path=log_path,
        ref_path=survey_path,
        query_label="scan",
    )
    used = np.flatnonzero(rows >= 0)
    if used.size == 0:
        raise InputError(
            f"no scan is within {tolerance_ms:g} ms of a survey row (scans {_time_range(times)}, "
            f"survey {_time_range(survey.time_s)}); check the time base or --tolerance-ms",
            path=survey_path,
        )
    extract_params = ExtractParams()
    local_maps = [extract_segments(log.scans[i], extract_params) for i in used]
    poses = [Pose2(*survey.poses[rows[i]]) for i in used]
    n_local = sum(lm.shape[0] for lm in local_maps)
    fuse_params = FuseParams()
    segments = build_global_map(local_maps, poses, fuse_params)
    if segments.shape[0] == 0:
        raise InputError("no segments could be extracted from the surveyed scans", path=log_path)
    problem = bounds_problem(segments)
    if problem is not None:
        raise InputError(f"the map built would be refused when read: {problem}", path=out_path)
    write_map(
        out_path,
        segments,
        source={
            "log": str(log_path),
            "survey": str(survey_path),
            "scans_used": int(used.size),
            "local_segments": int(n_local),
            "extract": asdict(extract_params),
            "fuse": asdict(fuse_params),
        },
    )
    _info(
        f"{out_path}: {segments.shape[0]} segments fused from {n_local} local segments "
        f"of {used.size} scans ({len(log.scans) - used.size} scans had no survey row)"
    )


# --------------------------------------------------------------------------- localize


def _odometry_rows(log, log_path: Path, tolerance_s: float, missing: str) -> np.ndarray:
    """Index of the /odom message nearest each scan in time (−1 where none is close enough).

    Two /odom messages at the time nearest a scan, or two scans at one time, are refused;
    a log without /odom is refused with "the log has no /odom messages" + ``missing``.
    """
    from segloc_cli.io.tables import pair_by_time

    if log.odom_times_s.size == 0:
        raise InputError(f"the log has no /odom messages{missing}", path=log_path)
    return pair_by_time(
        log.scan_times_s,
        log.odom_times_s,
        tolerance_s,
        query_path=log_path,
        ref_path=log_path,
        query_label="scan",
        ref_label="/odom message",
    )


def _initial_guesses(initial: str, log, log_path: Path, tolerance_s: float):
    """(scan indices, initial poses, pose ids) for the scans that have an initial guess.

    Pose ids come from the guess file's rows, or are the scans' indices in the log
    (from 1) when the guesses come from /odom. A guess shared by two rows of equal
    time, or two scans at one time, is refused rather than paired silently.
    """
    from segloc_cli.io.tables import pair_by_time, read_pose_table

    if initial == "odom":
        missing = " to take initial guesses from; pass --initial FILE.csv"
        rows = _odometry_rows(log, log_path, tolerance_s, missing)
        ref_poses, ref_ids = log.odom_poses, None
    else:
        table = read_pose_table(Path(initial))
        ref_poses, ref_ids = table.poses, table.pose_id
        rows = pair_by_time(
            log.scan_times_s,
            table.time_s,
            tolerance_s,
            query_path=log_path,
            ref_path=Path(initial),
            query_label="scan",
        )
    idx = np.flatnonzero(rows >= 0)
    poses = [Pose2(*ref_poses[r]) for r in rows[idx]]
    return idx, poses, idx + 1 if ref_ids is None else ref_ids[rows[idx]]


@cli.command()
@click.argument(
    "log_paths", metavar="LOG.mcap...", nargs=-1, required=True, type=click.Path(path_type=Path)
)
@click.option(
    "--map",
    "map_path",
    required=True,
    type=click.Path(path_type=Path),
    help="Global map (MAP.json; a world file also works).",
)
@click.option(
    "--out",
    "out_path",
    required=True,
    type=click.Path(path_type=Path),
    help="Estimates CSV to write.",
)
@click.option(
    "--tum",
    "tum_path",
    type=click.Path(path_type=Path),
    default=None,
    help="Also write the estimates as a TUM trajectory (for evo).",
)
@click.option(
    "--initial",
    default="odom",
    show_default=True,
    help="Initial guesses: 'odom' (the log's /odom nearest in time) or a CSV/TUM file; "
    "scans without a guess are skipped.",
)
@click.option(
    "--window-deg",
    type=FiniteRange(min=0, max=180),
    default=20.0,
    show_default=True,
    help="Stage 1 searches headings within ± this of the initial heading.",
)
@click.option(
    "--no-prior-heading",
    is_flag=True,
    help="Ignore the initial heading: stage 1 votes over the whole circle and stage 2 "
    "chooses among its peaks.",
)
@click.option(
    "--vote",
    type=click.Choice(VOTE_SCHEMES),
    default="product",
    show_default=True,
    help="Stage-1 vote: product λL·λG (paper eq. 1), count (eq. 2), local λL (eq. 3), "
    "sum λL+λG (eq. 4).",
)
@click.option(
    "--bin-deg",
    type=FiniteRange(min=0.05, max=45),
    default=1.0,
    show_default=True,
    help="Stage-1 orientation bin width (must divide 180).",
)
@click.option(
    "--grid-m",
    type=FiniteRange(min=0, max=50, min_open=True),
    default=1.5,
    show_default=True,
    help="Stage-2 initial grid spacing η0 (halved every iteration).",
)
@click.option(
    "--dtheta-deg",
    type=FiniteRange(min=0, max=90),
    default=4.0,
    show_default=True,
    help="Stage-2 initial heading step Δα0 (halved every iteration).",
)
@click.option(
    "--iterations",
    type=click.IntRange(min=1, max=30),
    default=8,
    show_default=True,
    help="Stage-2 iterations K; the last grid is η0/2^(K-1).",
)
@click.option(
    "--ratio",
    type=FiniteRange(min=0, max=1, min_open=True),
    default=0.9,
    show_default=True,
    help="Candidates within this ratio of the best overlap are averaged.",
)
@click.option(
    "--recentre",
    type=click.IntRange(min=0, max=100),
    default=8,
    show_default=True,
    help="Up to this many extra stage-2 iterations, spent re-searching at the same scale while "
    "the estimate still moves by over half a step; 0 keeps the paper's fixed schedule.",
)
@click.option(
    "--no-refine",
    is_flag=True,
    help="Stop at the stage-2 pose (the paper's method) instead of fitting the scan's points "
    "to the map segments by robust least squares afterwards.",
)
@click.option(
    "--global",
    "global_search",
    is_flag=True,
    help="No initial pose: search the whole map at every heading and report the best fit "
    "and its runner-up. Every scan is localized, or only those listed by --initial FILE (whose "
    "poses are then not used).",
)
@click.option(
    "--track",
    is_flag=True,
    help="Track along the log: --initial seeds only the first scan; each next guess is the "
    "previous estimate moved by the /odom increment, and the scan's points are fitted from it "
    "with the odometry as a prior (with --no-refine: the two stages from it). Failed matches "
    "are retried wider and flagged (status recovered or lost).",
)
@click.option(
    "--method",
    type=click.Choice(["two-stage", "icp", "correlative"]),
    default="two-stage",
    show_default=True,
    help="two-stage: this tool's method. For comparison: icp registers the scan's points to "
    "points sampled along the map (small-gicp), correlative searches ±2.1 m and ±20° around "
    "the guess against virtual scans of the map (Karto's matcher); both need "
    "pip install 'segloc[peers]' and an initial guess per scan.",
)
@click.option(
    "--icp-variant",
    type=click.Choice(["gicp", "plane"]),
    default="gicp",
    show_default=True,
    help="With --method icp: generalized ICP or point-to-plane ICP.",
)
@click.option(
    "--jobs",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Localize scans on this many processes (not with --track, whose scans depend on "
    "each other); the estimates are the same as with 1.",
)
@_tolerance_option("pairing scans with initial guesses or odometry")
@force_option
def localize(
    log_paths,
    map_path,
    out_path,
    tum_path,
    initial,
    window_deg,
    no_prior_heading,
    vote,
    bin_deg,
    grid_m,
    dtheta_deg,
    iterations,
    ratio,
    recentre,
    no_refine,
    global_search,
    track,
    method,
    icp_variant,
    jobs,
    tolerance_ms,
    force,
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

    Each row's status says how far to trust it: ok; ambiguous (a distinct
    pose, given in the runner_up columns, fits nearly as well, e.g. along a
    featureless corridor); lost (under half the scan lies on the map). A
    scan that yields too few segments gets a status instead of a pose, and
    the batch goes on. --no-refine runs the paper's two stages alone.

    --method icp and --method correlative run two widely used matchers on
    the same scans and guesses, for comparison (see make bench-peers).

    Rows are written to OUT as they are made: Ctrl-C, SIGTERM or even a
    killed process leaves every finished row in the file.
    """
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import read_map
    from segloc_cli.localize import LocalizeParams, Localizer, track_scans
    from segloc_cli.parallel import localize_scans_parallel
    from segloc_cli.refine import RefineParams

    if not np.isclose(180.0 / bin_deg, round(180.0 / bin_deg)):
        raise click.BadParameter(f"{bin_deg:g} does not divide 180", param_hint="--bin-deg")
    if method != "two-stage" and (global_search or track):
        other = "--global" if global_search else "--track"
        raise click.UsageError(
            f"--method {method} cannot be combined with {other}: it matches each scan from "
            "its own initial guess"
        )
    if track and jobs > 1:
        raise click.UsageError(
            "--jobs cannot be combined with --track: each tracked scan starts from the "
            "previous one's estimate"
        )
    if global_search and (track or no_refine):
        other = "--track" if track else "--no-refine"
        raise click.UsageError(
            f"--global cannot be combined with {other}: it searches every scan afresh and "
            "ranks its candidates by refining them"
        )
    every_scan = global_search and (
        click.get_current_context().get_parameter_source("initial")
        == click.core.ParameterSource.DEFAULT
    )
    guess_file = None if initial == "odom" else Path(initial)
    check_outputs({"--out": out_path, "--tum": tum_path}, [*log_paths, map_path, guess_file], force)
    segments_world = read_map(map_path)
    if global_search:
        _check_global_extent(segments_world, map_path)
    params = LocalizeParams(
        window_deg=None if no_prior_heading else window_deg,
        bin_deg=bin_deg,
        vote=vote,
        grid_m=grid_m,
        dtheta_deg=dtheta_deg,
        iterations=iterations,
        ratio=ratio,
        recentres=recentre,
        refine=None if no_refine else RefineParams(),
    )
    if method == "two-stage":
        localizer = Localizer(segments_world, params)
    else:
        from segloc_cli.peers import peer_localizer

        options = {"variant": icp_variant} if method == "icp" else {}
        localizer = peer_localizer(method, segments_world, **options)

    tolerance_s = tolerance_ms / 1e3
    stops: list[str] = []  # signals asking the run to stop, noted while it runs
    streams = []  # one iterator of estimates rows per log
    n_scans = skipped = 0
    spans = []  # (log, first and last time localized), to catch logs that overlap in time
    for log_path in log_paths:
        log = _load_log(log_path)
        if every_scan:
            idx = np.arange(len(log.scans))
            poses, ids = None, idx + 1
        else:
            idx, poses, ids = _initial_guesses(initial, log, log_path, tolerance_s)
        if idx.size == 0:
            raise InputError(
                f"no scan has an initial guess within {tolerance_ms:g} ms (--initial {initial})",
                path=log_path,
            )
        if track:
            # The first scan with a guess seeds the track; odometry carries it on.
            missing = "; tracking needs odometry between scans"
            odom_rows = _odometry_rows(log, log_path, tolerance_s, missing)
            keep = np.flatnonzero((odom_rows >= 0) & (np.arange(len(log.scans)) >= idx[0]))
            if keep.size == 0:
                raise InputError(
                    f"no scan from the first guess on has odometry within {tolerance_ms:g} ms; "
                    "tracking needs /odom at the scans",
                    path=log_path,
                )
            odometry = [Pose2(*log.odom_poses[r]) for r in odom_rows[keep]]
            scans = [log.scans[i] for i in keep]
            streams.append(track_scans(scans, odometry, poses[0], keep + 1, localizer))
        else:
            keep = idx
            guesses = None if global_search else poses
            scans = [log.scans[i] for i in idx]
            streams.append(
                localize_scans_parallel(
                    scans, guesses, ids, localizer, jobs, stop=lambda: bool(stops)
                )
            )
        n_scans += keep.size
        skipped += len(log.scans) - keep.size
        if keep.size:
            times = log.scan_times_s[keep]
            spans.append((log_path, times.min(), times.max()))
    _warn_overlapping(spans)

    rows = itertools.chain.from_iterable(streams)
    _localize_rows(rows, n_scans, out_path, tum_path, skipped, stops)


def _warn_overlapping(spans: list[tuple[Path, float, float]]) -> None:
    """Warn when two logs' localized scans overlap in time: their rows share a time span, and
    scoring them against one survey would pair rows it cannot tell apart."""
    ordered = sorted(spans, key=lambda span: span[1])
    for (first, _, end), (second, start, _) in itertools.pairwise(ordered):
        if start <= end:
            _warn(
                f"{first} and {second} overlap in time ({start:.3f}–{end:.3f} s); their rows "
                "in the estimates cannot be told apart by time (evaluate will refuse them)"
            )


def _check_global_extent(segments_world: np.ndarray, map_path: Path) -> None:
    """Refuse ``--global`` on a map too large to search whole in reasonable time."""
    from segloc_cli.localize import MAX_GLOBAL_AREA_M2

    width, height = np.ptp(segments_world[:, 0::2]), np.ptp(segments_world[:, 1::2])
    if width * height > MAX_GLOBAL_AREA_M2:
        raise InputError(
            f"--global searches the whole map, and this one spans {width:.0f} m × "
            f"{height:.0f} m, more than the {MAX_GLOBAL_AREA_M2:,.0f} m² it searches in about "
            "a minute per scan; give initial guesses (--initial) or a map of the area the "
            "robot is in",
            path=map_path,
        )


def _localize_rows(
    rows, n_scans: int, out_path: Path, tum_path: Path | None, skipped: int, stops: list[str]
):
    """Run the localization, writing each row to ``out_path`` (and ``tum_path``) as it comes;
    print the summary. Ctrl-C, SIGTERM and SIGHUP, noted in ``stops``, stop it between scans
    with every finished row kept (exit 130)."""
    from collections import Counter
    from contextlib import ExitStack

    from segloc_cli.io.tables import EstimatesWriter, TumWriter
    from segloc_cli.stopping import stop_requests

    t0 = time.perf_counter()
    statuses: list[str] = []
    runtimes_ms: list[float] = []
    stream = sys.stderr if n_scans >= PROGRESS_MIN_SCANS else io.StringIO()
    with ExitStack() as stack:
        stack.enter_context(stop_requests(stops))
        writers = [stack.enter_context(EstimatesWriter(out_path))]
        if tum_path is not None:
            writers.append(stack.enter_context(TumWriter(tum_path)))
        bar = stack.enter_context(
            click.progressbar(rows, length=n_scans, label="localizing", file=stream)
        )
        try:
            for row in bar:
                for writer in writers:
                    writer.write_row(row)
                statuses.append(row["status"])
                runtimes_ms.append(row["runtime_ms"])
                if stops:
                    break
        except KeyboardInterrupt:  # Ctrl-C that arrived outside the stop handler
            stops.append("Ctrl-C")
    elapsed = time.perf_counter() - t0
    done = len(statuses)
    if stops:
        kept = f"their estimates are in {out_path}" if done else f"{out_path} holds the header only"
        click.echo(
            f"segloc: interrupted ({stops[0]}) after {done} of {n_scans} scans; {kept}", err=True
        )
        sys.exit(EXIT_INTERRUPTED)
    counts = ", ".join(f"{n} {status}" for status, n in Counter(statuses).most_common())
    _info(
        f"{out_path}: {done} scans localized ({counts}) in {elapsed:.2f} s, "
        f"median {np.median(runtimes_ms):.1f} ms per scan"
        + (f"; {skipped} scans skipped (no initial guess or odometry)" if skipped else "")
    )


# --------------------------------------------------------------------------- evaluate


@cli.command()
@click.argument("estimates_path", metavar="EST.csv", type=click.Path(path_type=Path))
@click.option(
    "--survey",
    "survey_path",
    type=click.Path(path_type=Path),
    help="Ground truth poses (survey CSV or TUM): prints the paper's Table 1.",
)
@click.option(
    "--relations",
    "relations_path",
    type=click.Path(path_type=Path),
    help="Reference relative motions (t1 t2 dx dy dz droll dpitch dyaw): prints the relation "
    "metric of Kümmerle et al. (2009) instead.",
)
@click.option(
    "--published",
    type=click.Choice(["aces", "fr079", "intel", "mit-csail", "mit-killian-court"]),
    default=None,
    help="With --relations: add the published graph-mapping errors for this dataset.",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["md", "csv", "latex", "json"]),
    default="md",
    show_default=True,
    help="Table format.",
)
@click.option(
    "--out",
    "out_path",
    type=click.Path(path_type=Path),
    default=None,
    help="Write the table here instead of standard output (an existing file needs --force).",
)
@click.option(
    "--only-ok",
    is_flag=True,
    help="Summarise only poses whose status is ok (or recovered): RMS and max with --survey, "
    "the relations used with --relations. By default every pose with an estimate counts, "
    "whatever its status.",
)
@click.option(
    "--fail-above-cm",
    type=FiniteRange(min=0),
    default=None,
    help="Exit 1 if any pose's |X| or |Y| error exceeds this, or any pose is not ok.",
)
@click.option(
    "--fail-above-deg",
    type=FiniteRange(min=0),
    default=None,
    help="Exit 1 if any pose's |θ| error exceeds this, or any pose is not ok.",
)
@click.option(
    "--plots",
    "plots_dir",
    type=click.Path(path_type=Path, file_okay=False),
    default=None,
    help="With --survey: also draw figures (PNG and PDF) into this folder, created if needed "
    "(existing figures need --force).",
)
@click.option(
    "--map",
    "map_path",
    type=click.Path(path_type=Path),
    default=None,
    help="With --plots: the map the estimates were made with, for the figures of both stages.",
)
@click.option(
    "--log",
    "log_path",
    type=click.Path(path_type=Path),
    default=None,
    help="With --plots: the log the estimates were made from, for the figures of both stages.",
)
@_tolerance_option("pairing estimates with survey rows")
@force_option
def evaluate(
    estimates_path,
    survey_path,
    relations_path,
    published,
    fmt,
    out_path,
    only_ok,
    fail_above_cm,
    fail_above_deg,
    plots_dir,
    map_path,
    log_path,
    tolerance_ms,
    force,
):
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

    if (survey_path is None) == (relations_path is None):
        raise click.UsageError("give exactly one of --survey and --relations")
    if plots_dir is None and (map_path is not None or log_path is not None):
        raise click.UsageError("--map and --log go with --plots")
    if plots_dir is not None and survey_path is None:
        raise click.UsageError("--plots goes with --survey")
    if relations_path is not None and (fail_above_cm is not None or fail_above_deg is not None):
        raise click.UsageError("--fail-above-cm/--fail-above-deg go with --survey")
    if relations_path is None and published is not None:
        raise click.UsageError("--published goes with --relations")
    # Outputs are checked before any input is read, so a refusal costs no work.
    inputs = [estimates_path, survey_path, relations_path, map_path, log_path]
    check_outputs({"--out": out_path}, inputs, force)
    if plots_dir is not None:
        _check_plots(plots_dir, with_map=map_path is not None and log_path is not None, force=force)
    estimates = read_estimates(estimates_path)
    if relations_path is not None:
        _evaluate_relations(
            estimates,
            relations_path,
            published,
            fmt,
            out_path,
            tolerance_ms,
            only_ok=only_ok,
            estimates_path=estimates_path,
        )
        return

    from segloc_cli.evaluate import format_table, gate, summary, table1
    from segloc_cli.io.maps import read_map
    from segloc_cli.io.tables import read_pose_table

    survey = read_pose_table(survey_path)
    # Read before anything is printed, so a bad path stops the command with nothing half done.
    segments_world = None if map_path is None else read_map(map_path)
    log = None if log_path is None else _load_log(log_path)
    try:
        table = table1(
            estimates,
            survey,
            tolerance_s=tolerance_ms / 1e3,
            estimates_path=estimates_path,
            survey_path=survey_path,
        )
    except InputError as exc:
        if exc.path is not None:
            raise
        raise InputError(str(exc), path=survey_path) from None
    stats = summary(table, only_ok, fail_above_cm, fail_above_deg)
    _emit(format_table(table, stats, fmt), out_path)
    if plots_dir is not None:
        figure_data = None
        if segments_world is not None and log is not None:
            figure_data = (segments_world, log, log_path)
        _write_plots(
            plots_dir,
            table,
            estimates,
            survey,
            figure_data,
            tolerance_ms / 1e3,
            (survey_path, estimates_path),
        )
    violations = gate(table, fail_above_cm, fail_above_deg)
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
    from segloc_cli.plots import MAP_FIGURES, surveyed_scans, write_evaluation_figures

    plots_dir.mkdir(parents=True, exist_ok=True)
    if figure_data is None:
        _info(f"skipped {', '.join(MAP_FIGURES)}: they need --map MAP.json and --log LOG.mcap")
        written = write_evaluation_figures(plots_dir, table)
    else:
        segments_world, log, log_path = figure_data
        survey_path, estimates_path = paths
        items = surveyed_scans(
            estimates, survey, log.scans, tolerance_s, paths=(survey_path, estimates_path, log_path)
        )
        if not items:
            raise InputError(
                f"no scan lies within {tolerance_s * 1e3:g} ms of a surveyed estimate "
                f"(scans {_time_range(log.scan_times_s)}); is this the log of the estimates?",
                path=log_path,
            )
        written = write_evaluation_figures(plots_dir, table, segments_world, items)
    for path in written:
        _info(f"wrote {path}")


def _evaluate_relations(
    estimates, relations_path, published, fmt, out_path, tolerance_ms, *, only_ok, estimates_path
):
    from segloc_cli.relations import (
        PUBLISHED,
        format_relations,
        read_relations,
        relation_errors,
        trajectory_from_estimates,
    )

    relations = read_relations(relations_path)
    times_s, poses = trajectory_from_estimates(estimates, only_ok=only_ok)
    errors = relation_errors(
        times_s, poses, relations, tolerance_s=tolerance_ms / 1e3, estimates_path=estimates_path
    )
    if errors.used == 0:
        raise InputError(
            f"no relation has estimates at both of its times (within {tolerance_ms:g} ms; "
            f"estimates {_time_range(times_s)}, relations "
            f"{_time_range(np.concatenate([relations.t1_s, relations.t2_s]))})",
            path=relations_path,
        )
    reference = None if published is None else PUBLISHED.get(published)
    _emit(format_relations(errors.summary(), fmt, reference), out_path)


def _emit(text: str, out_path: Path | None) -> None:
    """Print a table, or write it to ``out_path``."""
    from segloc_cli.io.files import write_text_atomic

    if out_path is None:
        click.echo(text)
    else:
        write_text_atomic(out_path, text if text.endswith("\n") else text + "\n")
        _info(f"wrote {out_path}")


# --------------------------------------------------------------------------- info


def _protocol_choice() -> click.Choice:
    from segloc_cli.devices import PROTOCOLS

    return click.Choice(sorted(PROTOCOLS))


def _parse_pose(value: str) -> Pose2:
    from segloc_cli.io.maps import MAX_COORDINATE_M

    try:
        x, y, theta_deg = (float(v) for v in value.split(","))
    except ValueError:
        x = y = theta_deg = math.nan
    if not (max(abs(x), abs(y)) <= MAX_COORDINATE_M and math.isfinite(theta_deg)):
        raise click.BadParameter(
            f"{value!r}; use X_M,Y_M,THETA_DEG, finite and within ±{MAX_COORDINATE_M:g} m "
            "(e.g. 2.5,1.0,90)",
            param_hint="--pose",
        )
    return Pose2(x, y, float(np.deg2rad(theta_deg)))


@cli.command()
@click.option(
    "--device",
    "protocol",
    required=True,
    type=_protocol_choice(),
    help="Protocol to speak: explorer (the paper's 360° scanner, segloc's own framing; see "
    "docs/explorer-protocol.md) or scip2 (Hokuyo URG, emulating a URG-04LX).",
)
@click.option(
    "--world",
    "world_path",
    required=True,
    type=click.Path(path_type=Path),
    help="World to scan (segloc world JSON, as `segloc simulate` takes).",
)
@click.option("--pose", help="Scanner pose X_M,Y_M,THETA_DEG, held still (world frame).")
@click.option(
    "--path",
    "path_csv",
    type=click.Path(path_type=Path),
    help="Or a CSV of poses pose_id,time_s,x_m,y_m,theta_deg followed in time "
    "(time from the first row; interpolated, held after the last).",
)
@click.option(
    "--faults",
    default="",
    help="Comma-separated faults to inject: garbage (random bytes between frames), "
    "checksum (spoiled frames), stall (silence after --fault-after scans), "
    "hangup (pty closed after --fault-after scans).",
)
@click.option(
    "--fault-rate",
    type=FiniteRange(0, 1),
    default=0.2,
    show_default=True,
    help="Chance per scan of a garbage burst or a spoiled checksum.",
)
@click.option(
    "--fault-after",
    type=click.IntRange(min=0),
    default=20,
    show_default=True,
    help="Scans served before a stall or hangup.",
)
@click.option(
    "--noise-cm",
    type=FiniteRange(min=0, max=100),
    default=1.2,
    show_default=True,
    help="Gaussian range noise σ of the simulated scanner.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
def emulate(protocol, world_path, pose, path_csv, faults, fault_rate, fault_after, noise_cm, seed):
    """Emulate a laser scanner on a pseudo-terminal, scanning a simulated world.

    Prints the device path (e.g. /dev/pts/3) on the first line of standard
    output, then answers the protocol byte for byte until Ctrl-C or SIGTERM:
    point `segloc record` (or any driver) at that path. With hangup among the
    faults it exits by itself after closing the pty.

    \b
    Example:
      segloc emulate --device scip2 --world datasets/hall/world.json --pose 5,3,0 &
      segloc record --device scip2:/dev/pts/3 --scans 50 --out bench.mcap
    """
    from segloc_cli.devices.emulator import Faults, Trajectory, serve
    from segloc_cli.io.maps import read_world
    from segloc_cli.io.tables import read_pose_table
    from segloc_cli.sim import SensorModel

    if (pose is None) == (path_csv is None):
        raise click.UsageError("give the scanner's pose with exactly one of --pose or --path")
    try:
        fault_plan = Faults.parse(faults, fault_rate, fault_after)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--faults") from None
    world = read_world(world_path)
    if pose is not None:
        trajectory = Trajectory(np.zeros(1), _parse_pose(pose).as_array()[None, :])
    else:
        table = read_pose_table(path_csv)
        _check_increasing_times(table.time_s, path_csv, "the path's times")
        trajectory = Trajectory(table.time_s - table.time_s[0], table.poses)

    def announce(device_path: str) -> None:
        click.echo(device_path)
        sys.stdout.flush()
        _info(f"emulating a {protocol} scanner on {device_path}; Ctrl-C to stop")

    ended = serve(
        protocol,
        world,
        trajectory,
        fault_plan,
        SensorModel(noise_cm=noise_cm),
        seed,
        announce,
    )
    _info(f"emulator stopped ({ended})")


@cli.command()
@click.option(
    "--device",
    "device",
    required=True,
    metavar="PROTOCOL:PORT",
    help="Scanner to record from: explorer:/dev/ttyUSB0 or scip2:/dev/ttyACM0 "
    "(or the path `segloc emulate` prints).",
)
@click.option(
    "--out",
    "out_path",
    required=True,
    type=click.Path(path_type=Path),
    help="MCAP log to write (/scan as foxglove.LaserScan; settings and device identity "
    "in the segloc.sensor metadata record).",
)
@click.option("--scans", type=click.IntRange(min=1), help="Stop after this many scans.")
@click.option(
    "--duration",
    "duration_s",
    type=FiniteRange(min=0, max=1e7, min_open=True),
    help="Stop after S s.",
)
@click.option(
    "--readings",
    type=click.IntRange(min=1),
    help="Readings per scan (Explorer: 128, 256, 1024 or 2048 per revolution; "
    "SCIP 2.0: a count the angular range divides into). Default: the device's.",
)
@click.option(
    "--rev-per-s",
    type=FiniteRange(min=0, max=100, min_open=True),
    help="Revolutions per second (Explorer: 0.5 to 4). Default: the device's.",
)
@click.option(
    "--baud", type=click.IntRange(min=1, max=10_000_000), help="Baud rate. Default: the protocol's."
)
@click.option(
    "--timeout",
    "timeout_s",
    type=FiniteRange(min=0, max=3600, min_open=True),
    default=1.0,
    show_default=True,
    help="Seconds to wait for the device to answer a command.",
)
@click.option(
    "--stall-timeout",
    "stall_s",
    type=FiniteRange(min=0, max=3600, min_open=True),
    default=3.0,
    show_default=True,
    help="Seconds without a scan after which the device counts as stalled.",
)
@force_option
def record(
    device, out_path, scans, duration_s, readings, rev_per_s, baud, timeout_s, stall_s, force
):
    """Record laser scans from a serial scanner into an MCAP log.

    Runs until --scans or --duration is reached, or until Ctrl-C / SIGTERM,
    and then finishes the file. Every scan is flushed to disk as it arrives,
    so even a killed recorder keeps all scans but the one in flight, and a
    scanner that stalls or is unplugged ends the run with the scans received
    kept. Frames with a bad checksum or stray bytes are skipped and counted.

    \b
    Example:
      segloc record --device scip2:/dev/ttyACM0 --duration 60 --out hall.mcap
      segloc info hall.mcap
    """
    from segloc_cli.devices import driver_class, parse_device
    from segloc_cli.io.files import check_outputs
    from segloc_cli.record import RecordSettings
    from segloc_cli.record import record as run_record

    try:
        protocol, port = parse_device(device)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--device") from None
    check_outputs({"--out": out_path}, [port], force)
    settings = RecordSettings(scans, duration_s, readings, rev_per_s, stall_s)
    driver = driver_class(protocol)(port, baud, timeout_s)
    interactive = sys.stderr.isatty()
    shown = [0.0]

    def on_start(info, sensor) -> None:
        _info(
            f"{port}: {info.model} (serial {info.serial_number}, firmware {info.firmware}), "
            f"{sensor.get('readings', '?')} readings at {sensor.get('rev_per_s', '?')} rev/s; "
            f"recording to {out_path}"
        )

    def on_scan(progress) -> None:
        line = (
            f"recorded {progress.scans} scans, {progress.rate_hz:.1f} scans/s, "
            f"{progress.skipped} frames skipped"
        )
        if interactive:
            click.echo(f"\r{line}", nl=False, err=True)
        elif progress.elapsed_s - shown[0] >= 1.0:
            shown[0] = progress.elapsed_s
            _info(line)

    progress = run_record(driver, out_path, settings, on_start, on_scan)
    if interactive:
        click.echo("", err=True)
    _info(
        f"{out_path}: {progress.scans} scans in {progress.elapsed_s:.1f} s, "
        f"{progress.skipped} frames skipped (stopped by {progress.ended_by})"
    )
    if progress.ended_by.startswith("SIG"):  # interrupted: the file is whole, the run cut short
        sys.exit(EXIT_INTERRUPTED)


@cli.command()
@click.argument("log_path", metavar="LOG.mcap", type=click.Path(path_type=Path))
def info(log_path):
    """Summarise a log: channels and message counts, time span, sensor settings, whether
    the file was finished (a recording cut short still shows every complete scan)."""
    log = _load_log(log_path)
    times = log.scan_times_s
    beams = sorted({len(s) for s in log.scans})
    click.echo(f"file:      {log_path}")
    click.echo(f"finished:  {'yes' if log.finished else 'no (truncated or still being written)'}")
    click.echo(
        f"/scan:     {len(log.scans)} scans, {', '.join(map(str, beams)) or '-'} readings, "
        f"{_time_range(times)}"
    )
    click.echo(f"/odom:     {log.odom_times_s.size} poses, {_time_range(log.odom_times_s)}")
    for topic, count in sorted(log.message_counts.items()):
        if topic not in ("/scan", "/odom"):
            click.echo(f"{topic}: {count} messages (not read by segloc)")
    for key, value in sorted(log.sensor.items()):
        click.echo(f"sensor.{key}: {value}")


# --------------------------------------------------------------------------- entry point


def _one_line(text: object) -> str:
    """``text`` on one line: the contract of every message segloc prints for an error."""
    return " ".join(str(text).split())


def _interrupted(exc: BaseException) -> bool:
    """Whether ``exc`` came of an interrupt: compiled code that Ctrl-C (or SIGTERM) reaches
    returns with the KeyboardInterrupt set, and Python reports that as a SystemError."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _report_internal_error(exc: BaseException) -> str:
    """Keep the traceback of an unexpected error in a file; return that file's path."""
    import tempfile
    import traceback

    stamp = time.strftime("%Y%m%d-%H%M%S")
    with tempfile.NamedTemporaryFile(
        "w", prefix=f"segloc-error-{stamp}-", suffix=".txt", delete=False, encoding="utf-8"
    ) as stream:
        stream.write(f"segloc {__version__}\ncommand: {' '.join(sys.argv)}\n\n")
        traceback.print_exception(exc, file=stream)
    return stream.name


def main(argv: list[str] | None = None) -> None:
    """Console entry point: every error is one line on stderr and a non-zero exit, no traceback.

    Exit status: 0 success, 1 a gate failed, 2 bad input or usage, 70 an internal
    error (its traceback kept in a file the line names), 130 interrupted.
    """
    try:
        cli.main(args=argv, prog_name="segloc", standalone_mode=False)
    except (click.exceptions.Abort, KeyboardInterrupt):
        # Click turns Ctrl-C (and SIGTERM or SIGHUP, which the entry point makes alike) into Abort.
        click.echo("segloc: interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except click.ClickException as exc:
        no_args = getattr(click.exceptions, "NoArgsIsHelpError", None)  # click >= 8.2
        if no_args is not None and isinstance(exc, no_args):
            message = f"missing command; run '{exc.ctx.command_path} --help' to list them"
        else:
            message = exc.format_message()
        click.echo(f"segloc: error: {_one_line(message)}", err=True)
        sys.exit(EXIT_BAD_INPUT if exc.exit_code != 0 else 0)
    except SeglocError as exc:
        click.echo(f"segloc: error: {_one_line(exc)}", err=True)
        sys.exit(EXIT_BAD_INPUT)
    except BrokenPipeError:
        # The reader of our output went away (e.g. `| head`): nothing left to say.
        sys.stderr.close()
        sys.exit(EXIT_BAD_INPUT)
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        click.echo(f"segloc: error: {where}{_one_line(exc.strerror or exc)}", err=True)
        sys.exit(EXIT_BAD_INPUT)
    except (RecursionError, OverflowError, MemoryError) as exc:
        kind = type(exc).__name__
        click.echo(
            f"segloc: error: the input is too large or too deeply nested to read ({kind}); "
            "check the files given",
            err=True,
        )
        sys.exit(EXIT_BAD_INPUT)
    except Exception as exc:
        if _interrupted(exc):
            click.echo("segloc: interrupted", err=True)
            sys.exit(EXIT_INTERRUPTED)
        where = _report_internal_error(exc)
        click.echo(
            f"segloc: internal error: {type(exc).__name__}: {_one_line(exc)} "
            f"(a bug in segloc; the traceback is in {where}, please report it)",
            err=True,
        )
        sys.exit(EXIT_INTERNAL_ERROR)
