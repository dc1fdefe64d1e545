"""``segloc emulate``: a laser scanner on a pseudo-terminal, scanning a simulated world."""

from __future__ import annotations

import sys

import click
import numpy as np

from segloc_cli.commands.configfile import config_option
from segloc_cli.commands.logs import check_increasing_times
from segloc_cli.commands.options import (
    FiniteRange,
    path_option,
    sensor_options,
    with_options,
)
from segloc_cli.commands.optionvalues import parse_planar_pose, parsed
from segloc_cli.commands.printing import info
from segloc_cli.geometry import Pose2
from segloc_cli.wording import with_article


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
    fault_plan = parsed(
        lambda text: Faults.parse(text, fault_rate, fault_after), faults, "--faults"
    )
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
        info(f"emulating {with_article(protocol)} scanner on {device_path}; Ctrl-C to stop")

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
