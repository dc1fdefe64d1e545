"""``segloc map build``: a segment map from the scans of a log at surveyed poses."""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path

import click

from segloc_cli.commands.configfile import config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.options import (
    force_option,
    path_option,
    setting_option,
    tuning_options,
    with_options,
)
from segloc_cli.commands.printing import info, load_log, warn
from segloc_cli.config import EXTRACT, FUSE
from segloc_cli.errors import InputError
from segloc_cli.runfile import run_file_path


@click.group("map")
def map_group() -> None:
    """Build segment maps, or exchange them with CAD plans and nav2 grids."""


BUILD_OPTIONS = (
    path_option(
        "--survey",
        "survey_path",
        required=True,
        help="Poses of the scans (survey CSV or TUM); scans without a row are ignored.",
    ),
    path_option("--out", "out_path", required=True, help="MAP.json to write."),
    path_option(
        "--mcap",
        "mcap_path",
        help="Also write a view to open in Foxglove: the built map over the scans that made "
        "it, each at its surveyed (or polished) pose with its local segments.",
    ),
    setting_option("polish"),
    setting_option("tolerance-ms", pairing="pairing scans with survey rows"),
    config_option,
    force_option,
    tuning_options((*EXTRACT, *FUSE)),
)


@map_group.command("build")
@click.argument("log_path", metavar="LOG.mcap", type=click.Path(path_type=Path))
@with_options(*BUILD_OPTIONS)
def map_build(log_path, survey_path, out_path, mcap_path, force, **_):
    """Build a global segment map from the scans of a log at surveyed poses.

    Each scan with a survey row becomes a local map, is placed at its pose and
    fused with the others: nearly collinear segments that overlap or nearly
    touch become one. Beside OUT goes its run file (OUT.run.toml).
    """
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import bounds_problem, write_map
    from segloc_cli.io.tables import read_pose_table
    from segloc_cli.pipeline import build_map
    from segloc_cli.progress import Progress

    run = Invocation.current()
    outputs = {"--out": out_path, "--mcap": mcap_path}
    outputs["--out (run file)"] = run_file_path(out_path)
    check_outputs(outputs, [log_path, survey_path], force)
    log = load_log(log_path)
    survey = read_pose_table(survey_path)
    built = build_map(log, log_path, survey, survey_path, run.config, Progress)
    problem = bounds_problem(built.segments)
    if problem is not None:
        raise InputError(f"the map built would be refused when read: {problem}", path=out_path)
    source = {"log": str(log_path), "survey": str(survey_path)}
    source |= {"scans_used": built.scans_used, "local_segments": built.local_segments}
    source |= {"extract": asdict(run.config.extract), "fuse": asdict(run.config.fuse)}
    write_map(out_path, built.segments, source=source)
    run.write_run_file(out_path)
    if mcap_path is not None:
        metadata = {"command": "map build", "log": str(log_path), "survey": str(survey_path)}
        _write_build_view(mcap_path, log, built, metadata)
    info(
        f"{out_path}: {built.segments.shape[0]} segments fused from {built.local_segments} "
        f"local segments of {built.scans_used} scans ({len(log.scans) - built.scans_used} "
        "scans had no survey row)"
    )


def _write_build_view(mcap_path: Path, log, built, metadata: dict[str, str]) -> None:
    """The built map over its scans, each at its surveyed pose, as a Foxglove view."""
    from segloc_cli.io.runview import RunViewWriter
    from segloc_cli.progress import Progress

    parts = zip(built.scan_index, built.poses, built.local_maps, strict=True)
    with (
        RunViewWriter(mcap_path, built.segments, metadata) as view,
        Progress("writing the view", built.scans_used, "scan") as shown,
    ):
        for i, pose, local in parts:
            text = f"scan {i + 1}: {local.shape[0]} local segments at the surveyed pose"
            view.add(log.scans[i], local, pose, status="surveyed", text=text)
            shown.advance()
    info(f"{mcap_path}: the map over its {built.scans_used} scans, to open in Foxglove")


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


@map_group.command("import")
@click.argument("plan_path", metavar="PLAN.dxf|PLAN.svg|GRID.yaml", type=click.Path(path_type=Path))
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
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import bounds_problem, write_map

    kind = _plan_format(plan_path, "PLAN")
    _only_for(kind, "dxf", {"--layer": layers, "--units": units})
    _only_for(kind, "svg", {"--scale": scale_m, "--origin": origin_m})
    origin = _parsed_origin(origin_m)
    outputs = {"--out": out_path, "--out (run file)": run_file_path(out_path)}
    check_outputs(outputs, [plan_path], force)
    if kind == "dxf":
        from segloc_cli.io.plans import read_dxf

        wanted = [name.strip() for name in (layers or "").split(",") if name.strip()]
        plan = read_dxf(plan_path, wanted, units)
    elif kind == "svg":
        from segloc_cli.io.svg import read_svg

        plan = read_svg(plan_path, scale_m, origin)
    else:
        from segloc_cli.io.grids import read_nav2

        plan = read_nav2(plan_path)
    problem = bounds_problem(plan.segments)
    if problem is not None:
        raise InputError(f"the map read would be refused: {problem}", path=plan_path)
    write_map(out_path, plan.segments, source=plan.source)
    Invocation.current().write_run_file(out_path, [("image", p) for p in plan.also_read])
    for warning in plan.warnings:
        warn(f"{plan_path}: {warning}")
    info(f"{out_path}: {len(plan.segments)} segments {plan.summary}")


@map_group.command("export")
@click.argument("map_path", metavar="MAP.json", type=click.Path(path_type=Path))
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
        type=click.FloatRange(min=0.0, min_open=True),
        default=None,
        metavar="M",
        help="nav2: the side of a cell in metres (default 0.05).",
    ),
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

    \b
    Examples:
      segloc map export map.json --out map.dxf
      segloc map export map.json --out map.svg
      segloc map export map.json --out map.yaml --resolution 0.025
    """
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import read_map

    kind = plan_format or _plan_format(out_path, "--out")
    _only_for(kind, "nav2", {"--resolution": resolution_m})
    outputs = {"--out": out_path}
    if kind == "nav2":
        outputs["--out (image)"] = out_path.with_suffix(".pgm")
    check_outputs(outputs, [map_path], force)
    segments = read_map(map_path)
    if kind == "nav2":
        from segloc_cli.io.grids import DEFAULT_RESOLUTION_M, write_nav2

        res = DEFAULT_RESOLUTION_M if resolution_m is None else resolution_m
        grid = write_nav2(out_path, segments, res)
        columns, rows = grid.shape
        info(
            f"{out_path}: {len(segments)} segments drawn in {grid.occupied_cells} occupied "
            f"cells of a {columns} × {rows} grid of {res:g} m ({grid.image})"
        )
    elif kind == "svg":
        from segloc_cli.io.svg import write_svg

        write_svg(out_path, segments)
        info(f"{out_path}: {len(segments)} segments as lines, 1 unit = 1 mm")
    else:
        from segloc_cli.io.plans import write_dxf

        write_dxf(out_path, segments)
        info(f"{out_path}: {len(segments)} segments as lines, in metres")


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


def _parsed_origin(text: str | None) -> tuple[float, float]:
    """``X,Y`` metres → (x, y); ``click.BadParameter`` unless two finite numbers."""
    if text is None:
        return (0.0, 0.0)
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        x = y = math.nan
    if not (math.isfinite(x) and math.isfinite(y)):
        raise click.BadParameter(f"{text!r}; use X,Y in metres (e.g. -5,12)", param_hint="--origin")
    return x, y
