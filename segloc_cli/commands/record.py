"""``segloc record``: laser scans from a serial scanner into an MCAP log."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from segloc_cli.commands.configfile import check_command_outputs, config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.options import (
    FiniteRange,
    force_option,
    path_option,
    with_options,
)
from segloc_cli.commands.optionvalues import parsed
from segloc_cli.commands.printing import info
from segloc_cli.errors import EXIT_INTERRUPTED
from segloc_cli.runs.runfile import RUN_FILE_OUTPUT, run_file_path
from segloc_cli.wording import counted, said

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


@click.command("record")
@with_options(*RECORD_OPTIONS)
def record_command(
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
    from segloc_cli.devices.record import RecordSettings, record

    protocol, port = parsed(parse_device, device, "--device")
    check_command_outputs(
        {"--out": out_path, RUN_FILE_OUTPUT: run_file_path(out_path)}, [port], force
    )
    settings = RecordSettings(scans, duration_s, readings, rev_per_s, stall_s)
    driver = driver_class(protocol)(port, baud, timeout_s)
    display = _RecordDisplay(port, out_path, sys.stderr.isatty())
    progress = record(driver, out_path, settings, display.started, display.scanned)
    if display.interactive:
        click.echo("", err=True)
    Invocation.current().write_run_file(out_path)
    info(
        f"{out_path}: {counted(progress.scans, 'scan')} in {progress.elapsed_s:.1f} s, "
        f"{counted(progress.skipped, 'frame')} skipped (stopped by {progress.ended_by})"
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
            f"recorded {counted(progress.scans, 'scan')}, {progress.rate_hz:.1f} scans/s, "
            f"{counted(progress.skipped, 'frame')} skipped"
        )
        if self.interactive:
            click.echo(f"\r{said(line)}", nl=False, err=True)
        elif progress.elapsed_s - self.shown_s >= 1.0:
            self.shown_s = progress.elapsed_s
            info(line)
