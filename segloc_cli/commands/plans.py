"""``segloc map import`` and ``map export``: segment maps made from building plans (DXF,
SVG) and nav2 grids, and written as them."""

from __future__ import annotations

from pathlib import Path

import click

from segloc_cli.commands.configfile import check_command_outputs, config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.options import (
    FilePath,
    FiniteRange,
    force_option,
    path_option,
    with_options,
)
from segloc_cli.commands.optionvalues import parse_point
from segloc_cli.commands.printing import info, warn
from segloc_cli.errors import InputError
from segloc_cli.runs.runfile import RUN_FILE_OUTPUT, run_file_path
from segloc_cli.wording import counted

PLAN_FORMATS = {".dxf": "dxf", ".svg": "svg", ".yaml": "nav2", ".yml": "nav2"}
"""Plans ``map import`` reads and ``map export`` writes, by file extension."""

IMPORT_OPTIONS = (
    path_option("--out", "out_path", required=True, help="MAP.json to write."),
    click.option(
        "--layer",
        "layers",
        default=None,
        metavar="NAME[,NAME...]",
        help="DXF: read only these layers (comma-separated; default: every layer).",
    ),
    click.option(
        "--units",
        type=click.Choice(["m", "cm", "mm", "in", "ft"]),
        default=None,
        help="DXF: the drawing's unit, used when it does not say its own ($INSUNITS).",
    ),
    click.option(
        "--scale",
        "scale_m",
        type=float,
        default=None,
        metavar="METRES_PER_SVG_UNIT",
        help="SVG: metres per user unit (default: from the drawing's width, height and "
        "viewBox, when they give a size in mm, cm, in, pt, pc or px).",
    ),
    click.option(
        "--origin",
        "origin_m",
        default=None,
        metavar="X,Y",
        help="SVG: where the drawing's origin lands on the map, in metres (default 0,0).",
    ),
    config_option,
    force_option,
)


@click.command("import")
@click.argument("plan_path", metavar="PLAN.dxf|PLAN.svg|GRID.yaml", type=FilePath())
@with_options(*IMPORT_OPTIONS)
def map_import(plan_path, out_path, layers, units, scale_m, origin_m, force):
    """Make a segment map from a building plan (DXF or SVG) or a nav2 grid.

    \b
    DXF: every LINE, LWPOLYLINE, 2D POLYLINE, ARC, CIRCLE, ELLIPSE and SPLINE
      of the model space (or of --layer), block references included; $INSUNITS
      gives the unit, or --units.
    SVG: every line, polyline, polygon, rect and path, group and element
      transforms applied; a point (u, v) lands at (X + s*u, Y - s*v) m for
      --scale s and --origin X,Y (the drawing's y points down, the map's up).
    nav2 (ROS map_server YAML and its PGM or PNG): cells occupied as
      map_server decides (negate, occupied_thresh, mode), placed by origin and
      resolution; walls are traced along the occupied cells and fitted as scans
      are, a wall one cell thick as one segment, a thicker one as its faces.

    Curves are taken as straight chords (a warning counts them): in a DXF as
    few as keep each within 1 cm of its curve (polyline bulges too), in an SVG
    one per curved piece. Beside OUT goes its run file.

    \b
    Examples:
      segloc map import office.dxf --layer WALLS --out office.json
      segloc map import floor.svg --scale 0.01 --origin -5,12 --out floor.json
      segloc map import slam_map.yaml --out slam_map.json
      segloc localize scans.mcap --map office.json --out estimates.csv
    """
    from segloc_cli.io.maps import bounds_problem, write_map
    from segloc_cli.runs.pipeline import read_plan

    kind = _plan_format(plan_path, "PLAN")
    _only_for(kind, "dxf", {"--layer": layers, "--units": units})
    _only_for(kind, "svg", {"--scale": scale_m, "--origin": origin_m})
    origin = (0.0, 0.0) if origin_m is None else parse_point(origin_m, "--origin", "-5,12")
    outputs = {"--out": out_path, RUN_FILE_OUTPUT: run_file_path(out_path)}
    check_command_outputs(outputs, [plan_path], force)
    wanted = [name.strip() for name in (layers or "").split(",") if name.strip()]
    plan = read_plan(plan_path, kind, wanted, units, scale_m, origin)
    problem = bounds_problem(plan.segments)
    if problem is not None:
        raise InputError(f"the map read would be refused: {problem}", path=plan_path)
    write_map(out_path, plan.segments, source=plan.source)
    Invocation.current().write_run_file(out_path, [("image", p) for p in plan.also_read])
    for warning in plan.warnings:
        warn(f"{plan_path}: {warning}")
    info(f"{out_path}: {counted(len(plan.segments), 'segment')} {plan.summary}")


@click.command("export")
@click.argument("map_path", metavar="MAP.json", type=FilePath())
@with_options(
    path_option(
        "--out",
        "out_path",
        required=True,
        help="File to write: PLAN.dxf, PLAN.svg or GRID.yaml (its GRID.pgm beside it).",
    ),
    click.option(
        "--format",
        "plan_format",
        type=click.Choice(["nav2", "dxf", "svg"]),
        default=None,
        help="What to write (default: from the extension of --out: .yaml or .yml is nav2).",
    ),
    click.option(
        "--resolution",
        "resolution_m",
        type=FiniteRange(min=0.0, min_open=True),
        default=None,
        metavar="M",
        help="nav2: the side of a cell in metres (default 0.05).",
    ),
    config_option,
    force_option,
)
def map_export(map_path, out_path, plan_format, resolution_m, force):
    """Write a segment map as a CAD plan (DXF or SVG) or a nav2 grid.

    \b
    DXF: LINEs in metres on layer segloc-map.
    SVG: lines in millimetres (width and height in mm), the y axis flipped,
      so that `map import` reads it back without --scale or --origin.
    nav2: GRID.yaml and GRID.pgm for map_server: walls occupied (black);
      free (white) inside the map's bounding box, where a segment map cannot
      tell floor from outside; unknown (grey) in a 10-cell margin round it,
      where the map says nothing.

    Beside OUT goes its run file, named after the whole of OUT
    (map.dxf.run.toml), so that the map's own map.run.toml stays.

    \b
    Examples:
      segloc map export map.json --out map.dxf
      segloc map export map.json --out map.svg
      segloc map export map.json --out map.yaml --resolution 0.025
    """
    from segloc_cli.io.maps import read_map
    from segloc_cli.runs.pipeline import write_plan

    kind = plan_format or _plan_format(out_path, "--out")
    _only_for(kind, "nav2", {"--resolution": resolution_m})
    outputs = {"--out": out_path}
    if kind == "nav2":
        outputs["--out (image)"] = out_path.with_suffix(".pgm")
    outputs[RUN_FILE_OUTPUT] = run_file_path(out_path, whole_name=True)
    check_command_outputs(outputs, [map_path], force)
    segments = read_map(map_path)
    written = write_plan(out_path, segments, kind, resolution_m)
    Invocation.current().write_run_file(out_path, whole_name=True)
    info(f"{out_path}: {counted(len(segments), 'segment')} {written}")


def _plan_format(path: Path, what: str) -> str:
    kind = PLAN_FORMATS.get(path.suffix.lower())
    if kind is None:
        raise click.BadParameter(
            f"{path.name}: plans are DXF (.dxf), SVG (.svg) or nav2 grid (.yaml, .yml) "
            "files, named so",
            param_hint=what,
        )
    return kind


def _only_for(kind: str, wanted: str, given: dict[str, object]) -> None:
    """Refuse options of one plan format given for a file of another."""
    for option, value in given.items():
        if value is not None and kind != wanted:
            raise click.BadParameter(
                f"applies to {_FORMAT_NAMES[wanted]} only, not to {_FORMAT_NAMES[kind]}",
                param_hint=option,
            )


_FORMAT_NAMES = {"dxf": "DXF plans", "svg": "SVG plans", "nav2": "nav2 grids"}
