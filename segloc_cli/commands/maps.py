"""``segloc map build``: a segment map from the scans of a log at surveyed poses."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import click

from segloc_cli.commands.options import (
    Invocation,
    config_option,
    force_option,
    info,
    load_log,
    path_option,
    setting_option,
    tuning_options,
    warn,
    with_options,
)
from segloc_cli.config import EXTRACT, FUSE
from segloc_cli.errors import InputError
from segloc_cli.runfile import run_file_path


@click.group("map")
def map_group() -> None:
    """Build segment maps, or exchange them with CAD plans."""


BUILD_OPTIONS = (
    path_option(
        "--survey",
        "survey_path",
        required=True,
        help="Poses of the scans (survey CSV or TUM); scans without a row are ignored.",
    ),
    path_option("--out", "out_path", required=True, help="MAP.json to write."),
    setting_option("tolerance-ms", pairing="pairing scans with survey rows"),
    config_option,
    force_option,
    tuning_options((*EXTRACT, *FUSE)),
)


@map_group.command("build")
@click.argument("log_path", metavar="LOG.mcap", type=click.Path(path_type=Path))
@with_options(*BUILD_OPTIONS)
def map_build(log_path, survey_path, out_path, force, **_):
    """Build a global segment map from the scans of a log at surveyed poses.

    Each scan with a survey row becomes a local map, is placed at its pose and
    fused with the others: nearly collinear segments that overlap or nearly
    touch become one. Beside OUT goes its run file (OUT.run.toml).
    """
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import bounds_problem, write_map
    from segloc_cli.io.tables import read_pose_table
    from segloc_cli.pipeline import build_map

    run = Invocation.current()
    outputs = {"--out": out_path, "--out (run file)": run_file_path(out_path)}
    check_outputs(outputs, [log_path, survey_path], force)
    log = load_log(log_path)
    survey = read_pose_table(survey_path)
    built = build_map(log, log_path, survey, survey_path, run.config)
    problem = bounds_problem(built.segments)
    if problem is not None:
        raise InputError(f"the map built would be refused when read: {problem}", path=out_path)
    source = {"log": str(log_path), "survey": str(survey_path)}
    source |= {"scans_used": built.scans_used, "local_segments": built.local_segments}
    source |= {"extract": asdict(run.config.extract), "fuse": asdict(run.config.fuse)}
    write_map(out_path, built.segments, source=source)
    run.write_run_file(out_path)
    info(
        f"{out_path}: {built.segments.shape[0]} segments fused from {built.local_segments} "
        f"local segments of {built.scans_used} scans ({len(log.scans) - built.scans_used} "
        "scans had no survey row)"
    )


PLAN_FORMATS = ("dxf",)
"""Plans ``map import`` reads and ``map export`` writes, by file extension."""

IMPORT_OPTIONS = (
    path_option("--out", "out_path", required=True, help="MAP.json to write."),
    click.option(
        "--layer",
        "layers",
        default=None,
        metavar="NAME[,NAME...]",
        help="Read only these layers (comma-separated; default: every layer).",
    ),
    click.option(
        "--units",
        type=click.Choice(["m", "cm", "mm", "in", "ft"]),
        default=None,
        help="The drawing's unit, used when it does not say its own ($INSUNITS).",
    ),
    config_option,
    force_option,
)


@map_group.command("import")
@click.argument("plan_path", metavar="PLAN.dxf", type=click.Path(path_type=Path))
@with_options(*IMPORT_OPTIONS)
def map_import(plan_path, out_path, layers, units, force):
    """Make a segment map from a building plan (DXF).

    Every LINE, LWPOLYLINE and 2D POLYLINE of the model space (or of --layer),
    block references included, becomes map segments in metres: the drawing's
    $INSUNITS says its unit, or --units when it does not. Arcs drawn into
    polylines are taken as their straight chords. Beside OUT goes its run file.

    \b
    Example:
      segloc map import office.dxf --layer WALLS --out office.json
      segloc localize scans.mcap --map office.json --out estimates.csv
    """
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import write_map
    from segloc_cli.io.plans import read_dxf

    _check_plan_format(plan_path, "PLAN")
    outputs = {"--out": out_path, "--out (run file)": run_file_path(out_path)}
    check_outputs(outputs, [plan_path], force)
    wanted = [name.strip() for name in (layers or "").split(",") if name.strip()]
    plan = read_dxf(plan_path, wanted, units)
    source = {
        "plan": str(plan_path),
        "layers": list(plan.layers),
        "metres_per_unit": plan.metres_per_unit,
    }
    write_map(out_path, plan.segments, source=source)
    Invocation.current().write_run_file(out_path)
    if plan.chords:
        warn(f"{plan_path}: {plan.chords} arc pieces taken as straight chords")
    info(
        f"{out_path}: {len(plan.segments)} segments from layer(s) {', '.join(plan.layers)} "
        f"(1 drawing unit = {plan.metres_per_unit:g} m)"
    )


@map_group.command("export")
@click.argument("map_path", metavar="MAP.json", type=click.Path(path_type=Path))
@with_options(
    path_option("--out", "out_path", required=True, help="Plan to write (PLAN.dxf)."),
    force_option,
)
def map_export(map_path, out_path, force):
    """Write a segment map as a plan a CAD program opens (DXF, in metres).

    \b
    Example:
      segloc map export map.json --out map.dxf
    """
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import read_map
    from segloc_cli.io.plans import write_dxf

    _check_plan_format(out_path, "--out")
    check_outputs({"--out": out_path}, [map_path], force)
    segments = read_map(map_path)
    write_dxf(out_path, segments)
    info(f"{out_path}: {len(segments)} segments as lines, in metres")


def _check_plan_format(path: Path, what: str) -> None:
    if path.suffix.lower().lstrip(".") not in PLAN_FORMATS:
        raise click.BadParameter(
            f"{path.name}: plans are {', '.join(PLAN_FORMATS)} files, named so",
            param_hint=what,
        )
