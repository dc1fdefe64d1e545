"""``segloc import carmen|rosbag``: public laser logs converted into segloc's MCAP log."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import click
import numpy as np

from segloc_cli.commands.configfile import check_command_outputs, config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.logs import laser_offset_line
from segloc_cli.commands.options import (
    FilePath,
    FiniteRange,
    force_option,
    path_option,
    with_options,
)
from segloc_cli.commands.optionvalues import parse_planar_pose
from segloc_cli.commands.printing import info, warn, write_pose_file
from segloc_cli.errors import InputError
from segloc_cli.estimates import PoseTable
from segloc_cli.geometry import Pose2
from segloc_cli.runs.runfile import RUN_FILE_OUTPUT, run_file_path
from segloc_cli.scan import MAX_RANGE_M
from segloc_cli.wording import counted


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
    info(
        f"{out_path}: {counted(len(log.scans), 'scan')}, "
        f"{counted(len(log.odom_times_s), 'odometry pose')}"
    )


SURVEY_FORMATS = "a survey CSV, or a TUM trajectory (which evo reads) for a name ending in .tum"
"""What ``--survey-out`` writes, by the name's suffix (``_write_survey``)."""


def _range_max_option(default: str) -> Callable:
    """``--range-max-m``: the scanner's range limit (m), overriding the one the importer finds
    (``default`` says which)."""
    return click.option(
        "--range-max-m",
        type=FiniteRange(min=0, max=MAX_RANGE_M, min_open=True),
        default=None,
        help=f"Readings at or beyond this mean no return (default: {default}).",
    )


CARMEN_OPTIONS = (
    path_option("--out", "out_path", required=True, help="MCAP log to write."),
    path_option(
        "--survey-out",
        help=(
            f"Also write the laser records' poses as a reference trajectory: {SURVEY_FORMATS}; "
            "in a SLAM-corrected log these are the corrected poses."
        ),
    ),
    click.option(
        "--laser",
        type=click.Choice(["front", "rear"]),
        default="front",
        show_default=True,
        help="Which laser's records to read (FLASER/ROBOTLASER1 or RLASER).",
    ),
    _range_max_option(
        "the no-return value the log's readings repeat; a PARAM line's limit only where they "
        "repeat none and no return lies beyond it"
    ),
    config_option,
    force_option,
)


@import_group.command("carmen")
@click.argument("log_path", metavar="FILE[.gz]", type=FilePath())
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

    from segloc_cli.io.carmen import read_carmen
    from segloc_cli.progress import Progress

    outputs = {"--out": out_path, "--survey-out": survey_out}
    check_command_outputs({**outputs, RUN_FILE_OUTPUT: run_file_path(out_path)}, [log_path], force)
    log = read_carmen(log_path, laser=laser, range_max_m=range_max_m, progress=Progress)
    _write_imported(log, out_path)
    if survey_out is not None:
        reference = PoseTable(log.scan_numbers, log.odom_times_s, log.laser_poses)
        write_pose_file(survey_out, reference, log.original_times_s, "reference pose")


ROSBAG_OPTIONS = (
    path_option("--out", "out_path", required=True, help="MCAP log to write."),
    path_option(
        "--survey-out",
        help=(
            "Also write the odometry at the scans (the robot's poses in the odometry frame, "
            f"as the log holds them) as a trajectory: {SURVEY_FORMATS}."
        ),
    ),
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
    _range_max_option(
        "each message's range_max, unless the scanner's returns lie beyond it: then the "
        "no-return value its readings repeat"
    ),
    config_option,
    force_option,
)


@import_group.command("rosbag")
@click.argument("bag_path", metavar="PATH", type=FilePath())
@with_options(*ROSBAG_OPTIONS)
def import_rosbag(
    bag_path, out_path, survey_out, scan_topic, odom_topic, laser_offset, range_max_m, force
):
    """Import a ROS 1 .bag, a ROS 2 bag folder or a ROS 2 .mcap file.

    Scans stay in the scanner's frame; the scanner's pose on the robot (--laser-offset,
    else the bag's transforms) is kept in the log's sensor settings, and segloc places the
    scans on the robot by it, so that the odometry, the survey and every estimate are the
    robot's poses. An upside-down scanner's beams are mirrored into an upright scan.
    """
    from segloc_cli.io.log import MAX_LASER_OFFSET_M
    from segloc_cli.io.rosbag import read_rosbag
    from segloc_cli.progress import Progress

    given = None
    if laser_offset is not None:
        given = parse_planar_pose(laser_offset, "--laser-offset", MAX_LASER_OFFSET_M, "0.22,0,0")
    if survey_out is not None and not odom_topic:
        raise click.UsageError(
            "--survey-out writes the bag's odometry, but --odom-topic '' reads none; name the "
            "odometry topic (nav_msgs/Odometry)"
        )
    outputs = {"--out": out_path, "--survey-out": survey_out}
    check_command_outputs({**outputs, RUN_FILE_OUTPUT: run_file_path(out_path)}, [bag_path], force)
    log = read_rosbag(
        bag_path,
        scan_topic=scan_topic,
        odom_topic=odom_topic or None,
        laser_offset=given,
        progress=Progress,
        range_max_m=range_max_m,
    )
    if survey_out is not None and log.odom_times_s.size == 0:
        raise InputError(
            f"no scan has an odometry pose from {odom_topic} (the topic holds none, or none "
            "around the scans' times), so --survey-out has nothing to write",
            path=bag_path,
        )
    _write_imported(log, out_path)
    if log.laser_offset_source != "none":  # else a warning has said so
        info(laser_offset_line(log))
    if survey_out is not None:
        table, original_times_s = _odometry_rows(log)
        write_pose_file(survey_out, table, original_times_s, "odometry pose")


def _odometry_rows(log) -> tuple[PoseTable, np.ndarray]:
    """The log's odometry as survey rows, each with the pose id (number) of the scan it was
    looked up at, and those scans' original times (s)."""
    at = np.searchsorted(log.scan_times_s, log.odom_times_s)
    table = PoseTable(log.scan_numbers[at], log.odom_times_s, log.odom_poses)
    return table, log.original_times_s[at]
