"""Commands that make and read logs: ``simulate``, ``import carmen|rosbag``, and the log part
of ``info`` (``info_command``; ``commands/info.py`` is the command, and describes run views)."""

from __future__ import annotations

from pathlib import Path

import click

from segloc_cli.commands.configfile import config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.options import (
    FiniteRange,
    ModuleChoice,
    force_option,
    path_option,
    sensor_options,
    with_options,
)
from segloc_cli.commands.optionvalues import parse_planar_pose
from segloc_cli.commands.printing import info, load_log, warn
from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2
from segloc_cli.io.log import SIMULATED_GUESSES_KEY
from segloc_cli.runfile import run_file_path
from segloc_cli.scan import AT_ROBOT_ORIGIN, MAX_RANGE_M
from segloc_cli.sim import SensorModel


def check_increasing_times(times_s, path: Path, what: str) -> None:
    """Refuse, naming the row, times that are negative, past ``MAX_TIME_S`` or not increasing
    (a log of such times could not be paired with its survey)."""
    import numpy as np

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
    from segloc_cli.sim import parse_init_errors

    try:
        return parse_init_errors(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--init-errors") from None


SIMULATE_OPTIONS = (
    path_option(
        "--poses",
        "poses_path",
        required=True,
        help="CSV of true poses: pose_id,[time_s,]x_m,y_m,theta_deg.",
    ),
    path_option("--out", "out_dir", required=True, help="Output folder."),
    click.option(
        "--readings",
        type=ModuleChoice("segloc_cli.sim", "EXPLORER_READINGS"),
        default=str(SensorModel.readings),
        show_default=True,
        help="Readings per 360° revolution (the Explorer's settings).",
    ),
    *sensor_options("Gaussian range noise σ."),
    click.option(
        "--init-errors",
        default="paper",
        show_default=True,
        help="Initial-guess errors written to /odom: 'paper' (Table 1 of the paper, exactly) "
        "or 'uniform:XY_M,THETA_DEG' (uniform in ±XY_M per axis and ±THETA_DEG).",
    ),
    config_option,
    force_option,
)


@click.command()
@click.argument("world_path", metavar="WORLD.json", type=click.Path(path_type=Path))
@with_options(*SIMULATE_OPTIONS)
def simulate(world_path, poses_path, out_dir, readings, noise_cm, seed, init_errors, force):
    """Simulate a 360° laser log of a world at given poses.

    Writes OUT/log.mcap (/scan as foxglove.LaserScan, /odom as
    foxglove.PoseInFrame carrying the initial guesses), OUT/survey.csv (the
    true poses, as ground truth) and OUT/log.run.toml (the run file). The
    sensor is modelled on the paper's Explorer: Gaussian range noise, 1 mm
    resolution, dropouts, short spurious returns from people, and glass that
    rarely returns.
    """
    import numpy as np

    from segloc_cli import pipeline
    from segloc_cli.estimates import PoseTable
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import read_world
    from segloc_cli.io.tables import read_pose_table, write_pose_table

    errors = _parse_init_errors(init_errors)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("is a file; --out takes a folder", path=out_dir)
    log_path, survey_path = out_dir / "log.mcap", out_dir / "survey.csv"
    if out_dir.is_dir():
        outputs = {"--out (log.mcap)": log_path, "--out (survey.csv)": survey_path}
        outputs["--out (run file)"] = run_file_path(log_path)
        check_outputs(outputs, [world_path, poses_path], force)
    world = read_world(world_path)
    truth = read_pose_table(poses_path, require_time=False)
    times = truth.time_s
    if np.isnan(times).any():
        times = np.arange(1, len(truth) + 1, dtype=float)
    check_increasing_times(times, poses_path, "log times")
    truth = PoseTable(truth.pose_id, times, truth.poses)
    sensor = SensorModel(readings=int(readings), noise_cm=noise_cm)
    settings = {"device": "simulated Explorer", "readings": readings, "noise_cm": repr(noise_cm)}
    settings |= {"range_max_m": repr(sensor.range_max_m), "seed": str(seed)}
    settings |= {"world": world.name, SIMULATED_GUESSES_KEY: init_errors}
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the folder ({exc.strerror})", path=out_dir) from None
    pipeline.simulate_log(log_path, world, truth, errors, sensor, seed, settings)
    write_pose_table(survey_path, truth)
    Invocation.current().write_run_file(log_path)
    info(f"wrote {len(truth)} scans to {log_path} and the true poses to {survey_path}")


def laser_offset_line(log) -> str:
    """One line on the log's laser offset: the scanner's pose in the robot frame and where
    it came from."""
    offset, source = log.laser_offset, log.laser_offset_source
    if source == "none" and offset == AT_ROBOT_ORIGIN:
        return "laser offset: none (the scanner is taken to be at the robot's origin)"
    return (
        f"laser offset: x {offset.x:.6g} m, y {offset.y:.6g} m, theta {offset.theta_deg:.6g}° "
        f"(robot frame; from {source})"
    )


def windows_line(log) -> str:
    """One line on whether ``localize`` gives the log's scans windows (``window.py``)."""
    from segloc_cli.pipeline import no_odometry

    reason = no_odometry(log)
    if reason is None:
        return "windows:  yes; localize places each scan's neighbours by /odom (--window-m)"
    return f"windows:  no; {reason}"


@click.group("import")
def import_group() -> None:
    """Convert public laser logs into segloc's MCAP log."""


def _write_imported(log, out_path: Path) -> None:
    """Write scans, odometry at the scans and sensor settings of an imported log, and the
    run file beside it."""
    from segloc_cli.io.files import atomic_path
    from segloc_cli.io.mcap_log import write_log
    from segloc_cli.progress import Progress

    for warning in log.warnings:
        warn(warning)
    odometry = [
        (float(t), Pose2(*p)) for t, p in zip(log.odom_times_s, log.odom_poses, strict=True)
    ]
    with (
        atomic_path(out_path) as partial,
        Progress("writing the log", len(log.scans), "scan") as shown,
    ):
        write_log(
            partial, log.scans, odometry, log.sensor, log.original_times_s, shown,
            log.scan_numbers,
        )  # fmt: skip
    Invocation.current().write_run_file(out_path)
    info(f"{out_path}: {len(log.scans)} scans, {len(log.odom_times_s)} odometry poses")


CARMEN_OPTIONS = (
    path_option("--out", "out_path", required=True, help="MCAP log to write."),
    path_option(
        "--survey-out",
        help=(
            "Also write the laser records' poses as a reference trajectory: a survey CSV, or "
            "a TUM trajectory (which evo reads) for a name ending in .tum; in a "
            "SLAM-corrected log these are the corrected poses."
        ),
    ),
    click.option(
        "--laser",
        type=click.Choice(["front", "rear"]),
        default="front",
        show_default=True,
        help="Which laser's records to read (FLASER/ROBOTLASER1 or RLASER).",
    ),
    click.option(
        "--range-max-m",
        type=FiniteRange(min=0, max=MAX_RANGE_M, min_open=True),
        default=None,
        help="Readings at or beyond this mean no return (default: from PARAM lines, or "
        "the sentinel value the log repeats).",
    ),
    config_option,
    force_option,
)


@import_group.command("carmen")
@click.argument("log_path", metavar="FILE[.gz]", type=click.Path(path_type=Path))
@with_options(*CARMEN_OPTIONS)
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

    from segloc_cli.estimates import PoseTable
    from segloc_cli.io.carmen import read_carmen
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.tables import write_pose_table, write_pose_table_tum
    from segloc_cli.progress import Progress

    outputs = {"--out": out_path, "--survey-out": survey_out}
    check_outputs({**outputs, "--out (run file)": run_file_path(out_path)}, [log_path], force)
    log = read_carmen(log_path, laser=laser, range_max_m=range_max_m, progress=Progress)
    _write_imported(log, out_path)
    if survey_out is not None:
        n = len(log.scans)
        reference = PoseTable(log.scan_numbers, log.odom_times_s, log.laser_poses)
        if survey_out.suffix.lower() == ".tum":
            write_pose_table_tum(survey_out, reference)  # TUM has no column for original times
        else:
            write_pose_table(survey_out, reference, {"original_time_s": log.original_times_s})
        info(f"{survey_out}: {n} reference poses")


ROSBAG_OPTIONS = (
    path_option("--out", "out_path", required=True, help="MCAP log to write."),
    click.option(
        "--scan-topic", default="/scan", show_default=True, help="sensor_msgs/LaserScan topic."
    ),
    click.option(
        "--odom-topic",
        default="/odom",
        show_default=True,
        help="nav_msgs/Odometry topic, interpolated to each scan's time ('' for none).",
    ),
    click.option(
        "--laser-offset",
        metavar="X,Y,THETA_DEG",
        default=None,
        help="The scanner's pose in the robot frame (the odometry's child frame, e.g. "
        "base_link): x and y in metres, heading in degrees, e.g. 0.22,0,0 for a scanner "
        "22 cm ahead. Overrides the bag's /tf_static (and unchanging /tf) transforms, which "
        "give it by default; with neither, the scanner is taken to be at the robot's origin.",
    ),
    config_option,
    force_option,
)


@import_group.command("rosbag")
@click.argument("bag_path", metavar="PATH", type=click.Path(path_type=Path))
@with_options(*ROSBAG_OPTIONS)
def import_rosbag(bag_path, out_path, scan_topic, odom_topic, laser_offset, force):
    """Import a ROS 1 .bag, a ROS 2 bag folder or a ROS 2 .mcap file.

    Scans stay in the scanner's frame; the scanner's pose on the robot (--laser-offset,
    else the bag's transforms) is kept in the log's sensor settings, and segloc places the
    scans on the robot by it, so that the odometry, the survey and every estimate are the
    robot's poses. An upside-down scanner's beams are mirrored into an upright scan.
    """
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.log import MAX_LASER_OFFSET_M
    from segloc_cli.io.rosbag import read_rosbag
    from segloc_cli.progress import Progress

    given = None
    if laser_offset is not None:
        given = parse_planar_pose(laser_offset, "--laser-offset", MAX_LASER_OFFSET_M, "0.22,0,0")
    check_outputs(
        {"--out": out_path, "--out (run file)": run_file_path(out_path)}, [bag_path], force
    )
    log = read_rosbag(
        bag_path,
        scan_topic=scan_topic,
        odom_topic=odom_topic or None,
        laser_offset=given,
        progress=Progress,
    )
    _write_imported(log, out_path)
    if log.laser_offset_source != "none":  # else a warning has said so
        info(laser_offset_line(log))


@click.command("info")
@click.argument("log_path", metavar="LOG.mcap", type=click.Path(path_type=Path))
def info_command(log_path):
    """Summarise a log: channels and message counts, time span, sensor settings, whether
    the file was finished (a recording cut short still shows every complete scan)."""
    from segloc_cli.timing import time_range

    log = load_log(log_path)
    beams = sorted({len(s) for s in log.scans})
    click.echo(f"file:      {log_path}")
    click.echo(f"finished:  {'yes' if log.finished else 'no (truncated or still being written)'}")
    click.echo(
        f"/scan:     {len(log.scans)} scans, {', '.join(map(str, beams)) or '-'} readings, "
        f"{time_range(log.scan_times_s)}"
    )
    click.echo(f"/odom:     {log.odom_times_s.size} poses, {time_range(log.odom_times_s)}")
    click.echo(windows_line(log))
    click.echo(laser_offset_line(log))
    for topic, count in sorted(log.message_counts.items()):
        if topic not in ("/scan", "/odom"):
            click.echo(f"{topic}: {count} messages (not read by segloc)")
    for key, value in sorted(log.sensor.items()):
        click.echo(f"sensor.{key}: {value}")
