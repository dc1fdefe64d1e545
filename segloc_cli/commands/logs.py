"""Commands that make and read logs: ``simulate``, and the log part of ``info``
(``log_info``; ``commands/info.py`` is the command, and describes run views);
``commands/imports.py`` holds ``import carmen|rosbag``."""

from __future__ import annotations

from pathlib import Path

import click

from segloc_cli.commands.configfile import config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.options import (
    ModuleChoice,
    force_option,
    path_option,
    sensor_options,
    with_options,
)
from segloc_cli.commands.optionvalues import parsed
from segloc_cli.commands.printing import info, load_log
from segloc_cli.errors import InputError
from segloc_cli.io.log import SIMULATED_GUESSES_KEY
from segloc_cli.runs.runfile import run_file_path
from segloc_cli.scan import AT_ROBOT_ORIGIN
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

    from segloc_cli.estimates import PoseTable
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import read_world
    from segloc_cli.io.tables import read_pose_table, write_pose_table
    from segloc_cli.runs import pipeline
    from segloc_cli.sim import parse_init_errors

    errors = parsed(parse_init_errors, init_errors, "--init-errors")
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
    from segloc_cli.runs.pipeline import no_odometry

    reason = no_odometry(log)
    if reason is None:
        return "windows:  yes; localize places each scan's neighbours by /odom (--window-m)"
    return f"windows:  no; {reason}"


def log_info(log_path: Path, selection) -> None:
    """Print what ``segloc info`` says of a log: channels and message counts, time span and
    how long it is (what ``--start`` and ``--end`` count from), the scans ``selection`` (a
    ``ScanSelection``) picks when it is not the whole log, sensor settings, whether the file
    was finished (a recording cut short still shows every complete scan)."""
    from segloc_cli.selection import span_line
    from segloc_cli.timing import time_range

    log = load_log(log_path)
    beams = sorted({len(s) for s in log.scans})
    times = log.scan_times_s
    chosen = selection.chosen(times, log_path)
    click.echo(f"file:      {log_path}")
    click.echo(f"finished:  {'yes' if log.finished else 'no (truncated or still being written)'}")
    click.echo(
        f"/scan:     {len(log.scans)} scans, {', '.join(map(str, beams)) or '-'} readings, "
        f"{time_range(times)}"
    )
    click.echo(f"length:    {span_line(times)}")
    if not selection.whole:
        numbers = log.scan_numbers[chosen]
        click.echo(
            f"selected:  {chosen.size} scans ({selection.options_text()}), numbers "
            f"{numbers[0]}–{numbers[-1]}, {time_range(times[chosen] - times.min())} after the "
            "first"
        )
    click.echo(f"/odom:     {log.odom_times_s.size} poses, {time_range(log.odom_times_s)}")
    click.echo(windows_line(log))
    click.echo(laser_offset_line(log))
    for topic, count in sorted(log.message_counts.items()):
        if topic not in ("/scan", "/odom"):
            click.echo(f"{topic}: {count} messages (not read by segloc)")
    for key, value in sorted(log.sensor.items()):
        click.echo(f"sensor.{key}: {value}")
