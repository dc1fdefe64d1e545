"""Commands that talk to scanners: ``emulate`` one on a pseudo-terminal, ``record`` from one."""

from __future__ import annotations

import sys
from pathlib import Path

import click
import numpy as np

from segloc_cli.commands.configfile import config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.logs import check_increasing_times
from segloc_cli.commands.options import (
    FiniteRange,
    force_option,
    path_option,
    sensor_options,
    with_options,
)
from segloc_cli.commands.optionvalues import parse_planar_pose
from segloc_cli.commands.printing import info
from segloc_cli.errors import EXIT_INTERRUPTED
from segloc_cli.geometry import Pose2
from segloc_cli.runfile import run_file_path


def _protocol_choice() -> click.Choice:
    from segloc_cli.devices import PROTOCOLS

    return click.Choice(sorted(PROTOCOLS))


def _parse_pose(value: str) -> Pose2:
    from segloc_cli.limits import MAX_COORDINATE_M

    x, y, theta_deg = parse_planar_pose(value, "--pose", MAX_COORDINATE_M, "2.5,1.0,90")
    return Pose2(x, y, float(np.deg2rad(theta_deg)))


EMULATE_OPTIONS = (
    click.option(
        "--device",
        "protocol",
        required=True,
        type=_protocol_choice(),
        help="Protocol to speak: explorer (the paper's 360° scanner, segloc's own framing; see "
        "docs/explorer-protocol.md) or scip2 (Hokuyo URG, emulating a URG-04LX).",
    ),
    path_option(
        "--world",
        "world_path",
        required=True,
        help="World to scan (segloc world JSON, as `segloc simulate` takes).",
    ),
    click.option("--pose", help="Scanner pose X_M,Y_M,THETA_DEG, held still (world frame)."),
    path_option(
        "--path",
        "path_csv",
        help=(
            "Or a CSV of poses pose_id,time_s,x_m,y_m,theta_deg followed in time (time from the "
            "first row; interpolated, held after the last)."
        ),
    ),
    click.option(
        "--faults",
        default="",
        help="Comma-separated faults to inject: garbage (random bytes between frames), "
        "checksum (spoiled frames), stall (silence after --fault-after scans), "
        "hangup (pty closed after --fault-after scans).",
    ),
    click.option(
        "--fault-rate",
        type=FiniteRange(0, 1),
        default=0.2,
        show_default=True,
        help="Chance per scan of a garbage burst or a spoiled checksum.",
    ),
    click.option(
        "--fault-after",
        type=click.IntRange(min=0),
        default=20,
        show_default=True,
        help="Scans served before a stall or hangup.",
    ),
    *sensor_options("Gaussian range noise σ of the simulated scanner."),
    config_option,
)


@click.command()
@with_options(*EMULATE_OPTIONS)
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
        check_increasing_times(table.time_s, path_csv, "the path's times")
        trajectory = Trajectory(table.time_s - table.time_s[0], table.poses)

    def announce(device_path: str) -> None:
        click.echo(device_path)
        sys.stdout.flush()
        info(f"emulating a {protocol} scanner on {device_path}; Ctrl-C to stop")

    ended = serve(
        protocol,
        world,
        trajectory,
        fault_plan,
        SensorModel(noise_cm=noise_cm),
        seed,
        announce,
    )
    info(f"emulator stopped ({ended})")


RECORD_OPTIONS = (
    click.option(
        "--device",
        "device",
        required=True,
        metavar="PROTOCOL:PORT",
        help="Scanner to record from: explorer:/dev/ttyUSB0 or scip2:/dev/ttyACM0 "
        "(or the path `segloc emulate` prints).",
    ),
    path_option(
        "--out",
        "out_path",
        required=True,
        help=(
            "MCAP log to write (/scan as foxglove.LaserScan; settings and device identity in the "
            "segloc.sensor metadata record)."
        ),
    ),
    click.option("--scans", type=click.IntRange(min=1), help="Stop after this many scans."),
    click.option(
        "--duration",
        "duration_s",
        type=FiniteRange(min=0, max=1e7, min_open=True),
        help="Stop after S s.",
    ),
    click.option(
        "--readings",
        type=click.IntRange(min=1),
        help="Readings per scan (Explorer: 128, 256, 1024 or 2048 per revolution; "
        "SCIP 2.0: a count the angular range divides into). Default: the device's.",
    ),
    click.option(
        "--rev-per-s",
        type=FiniteRange(min=0, max=100, min_open=True),
        help="Revolutions per second (Explorer: 0.5 to 4). Default: the device's.",
    ),
    click.option(
        "--baud",
        type=click.IntRange(min=1, max=10_000_000),
        help="Baud rate. Default: the protocol's.",
    ),
    click.option(
        "--timeout",
        "timeout_s",
        type=FiniteRange(min=0, max=3600, min_open=True),
        default=1.0,
        show_default=True,
        help="Seconds to wait for the device to answer a command.",
    ),
    click.option(
        "--stall-timeout",
        "stall_s",
        type=FiniteRange(min=0, max=3600, min_open=True),
        default=3.0,
        show_default=True,
        help="Seconds without a scan after which the device counts as stalled.",
    ),
    config_option,
    force_option,
)


@click.command()
@with_options(*RECORD_OPTIONS)
def record(
    device, out_path, scans, duration_s, readings, rev_per_s, baud, timeout_s, stall_s, force
):
    """Record laser scans from a serial scanner into an MCAP log.

    Runs until --scans or --duration is reached, or until Ctrl-C / SIGTERM,
    and then finishes the file. Scans reach the disk in compressed chunks of
    at most half a second of recording, so even a killed recorder keeps all
    scans but those of its last half second, and a scanner that stalls or is
    unplugged ends the run with the scans received kept. Frames with a bad
    checksum or stray bytes are skipped and counted.

    \b
    Example:
      segloc record --device scip2:/dev/ttyACM0 --duration 60 --out hall.mcap
      segloc info hall.mcap
    """
    from segloc_cli.devices import driver_class, parse_device
    from segloc_cli.devices.record import RecordSettings
    from segloc_cli.devices.record import record as run_record
    from segloc_cli.io.files import check_outputs

    try:
        protocol, port = parse_device(device)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--device") from None
    check_outputs({"--out": out_path, "--out (run file)": run_file_path(out_path)}, [port], force)
    settings = RecordSettings(scans, duration_s, readings, rev_per_s, stall_s)
    driver = driver_class(protocol)(port, baud, timeout_s)
    display = _RecordDisplay(port, out_path, sys.stderr.isatty())
    progress = run_record(driver, out_path, settings, display.started, display.scanned)
    if display.interactive:
        click.echo("", err=True)
    Invocation.current().write_run_file(out_path)
    info(
        f"{out_path}: {progress.scans} scans in {progress.elapsed_s:.1f} s, "
        f"{progress.skipped} frames skipped (stopped by {progress.ended_by})"
    )
    if progress.ended_by.startswith("SIG"):  # interrupted: the file is whole, the run cut short
        sys.exit(EXIT_INTERRUPTED)


class _RecordDisplay:
    """What a recording shows: the device when it starts, then the count of scans, on one
    line rewritten in place on a terminal, or a line a second into a log file."""

    def __init__(self, port: str, out_path: Path, interactive: bool):
        self.port, self.out_path, self.interactive = port, out_path, interactive
        self.shown_s = 0.0

    def started(self, device, sensor) -> None:
        info(
            f"{self.port}: {device.model} (serial {device.serial_number}, firmware "
            f"{device.firmware}), {sensor.get('readings', '?')} readings at "
            f"{sensor.get('rev_per_s', '?')} rev/s; recording to {self.out_path}"
        )

    def scanned(self, progress) -> None:
        line = (
            f"recorded {progress.scans} scans, {progress.rate_hz:.1f} scans/s, "
            f"{progress.skipped} frames skipped"
        )
        if self.interactive:
            click.echo(f"\r{line}", nl=False, err=True)
        elif progress.elapsed_s - self.shown_s >= 1.0:
            self.shown_s = progress.elapsed_s
            info(line)
