"""Commands that make and read logs: ``simulate``, and the log part of ``info``
(``log_info``; ``commands/info.py`` is the command, and describes run views);
``commands/imports.py`` holds ``import carmen|rosbag``."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import click

from segloc_cli.commands.configfile import check_command_outputs, config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.options import (
    FilePath,
    FiniteRange,
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
from segloc_cli.runs.runfile import RUN_FILE_OUTPUT, run_file_path
from segloc_cli.scan import AT_ROBOT_ORIGIN, MAX_READINGS
from segloc_cli.sim import OdometryDrift, SensorModel
from segloc_cli.wording import counted


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


def _from_world(key: str, default: str) -> str:
    """The end of a sensor option's help: where its value comes from when not given."""
    return f"[default: the world file's sensor.{key}, else {default}]"


NOISE_OPTION, SEED_OPTION = sensor_options(
    "Gaussian range noise σ. " + _from_world("noise_cm", f"{SensorModel.noise_cm:g}"),
    from_world=True,
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
        type=click.IntRange(2, MAX_READINGS),
        default=None,
        help="Beams per scan (the Explorer offers 128, 256, 1024 or 2048 per turn). "
        + _from_world("readings", str(SensorModel.readings)),
    ),
    click.option(
        "--fov-deg",
        type=FiniteRange(0, 360, min_open=True),
        default=None,
        help="Field of view: 360 is a full turn starting straight ahead; a narrower fan is "
        "centred straight ahead with a beam on each edge (180 with 361 readings: a SICK LMS "
        "at 0.5°). " + _from_world("fov_deg", f"{SensorModel.fov_deg:g}"),
    ),
    NOISE_OPTION,
    click.option(
        "--clutter/--no-clutter",
        default=None,
        help="Short spurious returns from passers-by, on average "
        f"{SensorModel.clutter_clusters:g} groups per scan (--no-clutter: none). "
        + _from_world("clutter", "on"),
    ),
    click.option(
        "--glass/--no-glass",
        default=None,
        help="Glass returns only "
        f"{SensorModel.glass_return_prob:.0%} of the beams reaching it, letting the rest "
        "through (--no-glass: glass is opaque, a wall to the beams). " + _from_world("glass", "on"),
    ),
    SEED_OPTION,
    click.option(
        "--material",
        type=ModuleChoice("segloc_cli.world", "MATERIALS"),
        default="wall",
        show_default=True,
        help="What the segments are made of when the file does not say: every segment of a "
        "map file (from map build or map import), those of a world file without materials.",
    ),
    click.option(
        "--init-errors",
        default=None,
        help="Initial-guess errors written to /odom: 'paper' (Table 1 of the paper, exactly; "
        "the default) or 'uniform:XY_M,THETA_DEG' (uniform in ±XY_M per axis and "
        "±THETA_DEG).",
    ),
    click.option(
        "--odometry",
        default=None,
        help="Write wheel odometry to /odom instead of initial guesses, starting at the "
        "origin of its own frame and drifting: 'drift' "
        f"({OdometryDrift().text}) or 'drift:DISTANCE_PCT,TURN_PCT,DEG_PER_M', each step "
        "off by up to DISTANCE_PCT % of its length and its turn by up to TURN_PCT % of "
        "the turn plus DEG_PER_M per metre. A log to map without a survey (segloc map build).",
    ),
    config_option,
    force_option,
)


@click.command()
@click.argument("world_path", metavar="WORLD_OR_MAP.json", type=FilePath())
@with_options(*SIMULATE_OPTIONS)
def simulate(
    world_path,
    poses_path,
    out_dir,
    readings,
    fov_deg,
    noise_cm,
    clutter,
    glass,
    seed,
    material,
    init_errors,
    odometry,
    force,
):
    """Simulate a laser log of a world (or a map) at given poses.

    Writes OUT/log.mcap (/scan as foxglove.LaserScan, /odom as
    foxglove.PoseInFrame carrying the initial guesses, or the wheel odometry
    of --odometry), OUT/survey.csv (the
    true poses, as ground truth) and OUT/log.run.toml (the run file, with the
    sensor as simulated). The sensor is modelled on the paper's Explorer (360°,
    1024 readings): Gaussian range noise, 1 mm resolution, dropouts, short
    spurious returns from people, and glass that rarely returns; the options,
    or the world file's "sensor", choose another. The README describes the
    world file.
    """
    import numpy as np

    from segloc_cli.estimates import PoseTable
    from segloc_cli.io.maps import read_world
    from segloc_cli.io.tables import read_pose_table, write_pose_table
    from segloc_cli.runs import pipeline
    from segloc_cli.sim import parse_init_errors, parse_odometry, sensor_model

    if odometry is not None and init_errors is not None:
        raise click.UsageError(
            "--init-errors and --odometry both say what /odom holds; give one of them"
        )
    errors = parsed(parse_init_errors, init_errors or "paper", "--init-errors")
    drift = None if odometry is None else parsed(parse_odometry, odometry, "--odometry")
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("is a file; --out takes a folder", path=out_dir)
    log_path, survey_path = out_dir / "log.mcap", out_dir / "survey.csv"
    if out_dir.is_dir():
        outputs = {"--out (log.mcap)": log_path, "--out (survey.csv)": survey_path}
        outputs[RUN_FILE_OUTPUT] = run_file_path(log_path)
        check_command_outputs(outputs, [world_path, poses_path], force)
    world = read_world(world_path, default_material=material)
    truth = read_pose_table(poses_path, require_time=False)
    times = truth.time_s
    if np.isnan(times).any():
        times = np.arange(1, len(truth) + 1, dtype=float)
    check_increasing_times(times, poses_path, "log times")
    truth = PoseTable(truth.pose_id, times, truth.poses)
    # The options given win over the world file's sensor (their name is the choice's).
    given = {"readings": readings, "fov_deg": fov_deg, "noise_cm": noise_cm}
    given |= {"clutter": clutter, "glass": glass}
    sensor = sensor_model(world.sensor | {k: v for k, v in given.items() if v is not None})
    settings = sensor_settings(sensor) | {"seed": str(seed), "world": world.name}
    if drift is None:
        settings[SIMULATED_GUESSES_KEY] = init_errors or "paper"
    else:
        settings["odometry"] = drift.text
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the folder ({exc.strerror})", path=out_dir) from None
    pipeline.simulate_log(log_path, world, truth, errors, sensor, seed, settings, drift)
    write_pose_table(survey_path, truth)
    invocation = Invocation.current()
    as_simulated = {k.replace("_", "-"): v for k, v in sensor.choices.items()}
    replace(invocation, options=invocation.options | as_simulated).write_run_file(log_path)
    info(f"wrote {counted(len(truth), 'scan')} to {log_path} and the true poses to {survey_path}")


def sensor_settings(sensor: SensorModel) -> dict[str, str]:
    """The log's sensor settings of a simulated ``sensor``: the device, readings, noise and
    range, and the field of view when it is no Explorer's, clutter and glass when off."""
    choices = sensor.choices
    device = "simulated Explorer" if sensor.is_explorer else "simulated scanner"
    settings = {"device": device, "readings": str(sensor.readings)}
    if not sensor.is_explorer:
        settings["fov_deg"] = repr(choices["fov_deg"])
    settings |= {"noise_cm": repr(choices["noise_cm"]), "range_max_m": repr(sensor.range_max_m)}
    if not choices["clutter"]:
        settings["clutter"] = "off"
    if not choices["glass"]:
        settings["glass"] = "opaque"
    return settings


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
    how long it is (what ``--start`` and ``--end`` count from; in minutes or hours, and the
    dates of Unix times, where the seconds alone do not say it readily), the scans ``selection`` (a
    ``ScanSelection``) picks when it is not the whole log, sensor settings, whether the file
    was finished (a recording cut short still shows every complete scan)."""
    from segloc_cli.selection import span_line
    from segloc_cli.timing import time_range

    log = load_log(log_path)
    beams = ", ".join(map(str, sorted({len(s) for s in log.scans}))) or "-"
    times = log.scan_times_s
    chosen = selection.chosen(times, log_path)
    click.echo(f"file:      {log_path}")
    click.echo(f"finished:  {'yes' if log.finished else 'no (truncated or still being written)'}")
    click.echo(
        f"/scan:     {counted(len(log.scans), 'scan')}, {beams} readings, {time_range(times)}"
    )
    click.echo(f"length:    {span_line(times)}")
    if not selection.whole:
        numbers = log.scan_numbers[chosen]
        click.echo(
            f"selected:  {counted(chosen.size, 'scan')} ({selection.options_text()}), numbers "
            f"{numbers[0]}–{numbers[-1]}, {time_range(times[chosen] - times.min())} after the "
            "first"
        )
    click.echo(
        f"/odom:     {counted(log.odom_times_s.size, 'pose')}, {time_range(log.odom_times_s)}"
    )
    click.echo(windows_line(log))
    click.echo(laser_offset_line(log))
    for topic, count in sorted(log.message_counts.items()):
        if topic not in ("/scan", "/odom"):
            click.echo(f"{topic}: {counted(count, 'message')} (not read by segloc)")
    for key, value in sorted(log.sensor.items()):
        click.echo(f"sensor.{key}: {value}")
