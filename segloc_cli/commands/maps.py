"""``segloc map``: the group, and ``map build``, a segment map from the scans of a log at
surveyed poses (``commands/plans.py`` holds ``map import`` and ``map export``)."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import click

from segloc_cli.commands.configfile import config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.options import (
    SCAN_SELECTION,
    force_option,
    path_option,
    scan_selection,
    setting_option,
    tuning_options,
    with_options,
)
from segloc_cli.commands.plans import map_export, map_import
from segloc_cli.commands.printing import info, load_log
from segloc_cli.config import EXTRACT, FUSE
from segloc_cli.errors import InputError
from segloc_cli.runs.runfile import run_file_path
from segloc_cli.wording import counted


@click.group("map")
def map_group() -> None:
    """Build segment maps, or exchange them with CAD plans and nav2 grids."""


map_group.add_command(map_import)
map_group.add_command(map_export)


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
    *SCAN_SELECTION,
    setting_option("polish"),
    setting_option("min-observations"),
    setting_option("seen-through"),
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
    touch become one. With --min-observations, segments seen from too few
    poses are dropped; with --seen-through drop, those that more poses see
    through than see (people walking by). Beside OUT goes its run file
    (OUT.run.toml).
    """
    from segloc_cli.io.files import check_outputs
    from segloc_cli.io.maps import bounds_problem, write_map
    from segloc_cli.io.tables import read_pose_table, refuse_map
    from segloc_cli.jit import SEEN_THROUGH_KERNELS, watching_compiles
    from segloc_cli.progress import Progress
    from segloc_cli.runs.pipeline import build_map

    run = Invocation.current()
    later = SEEN_THROUGH_KERNELS if run.config.fuse.seen_through == "drop" else None
    click.get_current_context().with_resource(watching_compiles(later=later))
    outputs = {"--out": out_path, "--mcap": mcap_path}
    outputs["--out (run file)"] = run_file_path(out_path)
    check_outputs(outputs, [log_path, survey_path], force)
    refuse_map(survey_path, "--survey", "the surveyed poses of the scans")
    log = load_log(log_path)
    selection = scan_selection(run.options)
    selected = selection.chosen(log.scan_times_s, log_path)
    survey = read_pose_table(survey_path)
    built = build_map(log, log_path, survey, survey_path, run.config, Progress, selected)
    problem = bounds_problem(built.segments)
    if problem is not None:
        raise InputError(f"the map built would be refused when read: {problem}", path=out_path)
    source = {"log": str(log_path), "survey": str(survey_path)}
    source |= {"scans_used": built.scans_used, "local_segments": built.local_segments}
    if not selection.whole:
        source["scans_selected"] = f"{selected.size} ({selection.options_text()})"
    source |= {"dropped_segments": int(built.dropped.shape[0])}
    source |= {"dropped_seen_through": int(built.dropped_seen_through.sum())}
    source |= {"extract": asdict(run.config.extract), "fuse": asdict(run.config.fuse)}
    write_map(out_path, built.segments, source=source)
    run.write_run_file(out_path)
    if mcap_path is not None:
        metadata = {"command": "map build", "log": str(log_path), "survey": str(survey_path)}
        _write_build_view(mcap_path, log, built, metadata)
    unsurveyed = selected.size - built.scans_used
    which = "scan" if selection.whole else "selected scan"
    info(
        f"{out_path}: {counted(built.segments.shape[0], 'segment')} fused from "
        f"{counted(built.local_segments, 'local segment')} of "
        f"{counted(built.scans_used, 'scan')} ({counted(unsurveyed, which)} had no survey row)"
        f"{_dropped_note(built, run.config.fuse)}"
    )


def _dropped_note(built, fuse) -> str:
    """What ``map build`` left out of ``built`` (a ``BuiltMap``), as the end of its summary
    line: how many fused segments, how long, and why, under the settings ``fuse``."""
    from segloc_cli.geometry import segment_lengths

    def note(segments, why: str) -> str:
        count = counted(segments.shape[0], "segment")
        return f"; {count} ({segment_lengths(segments).sum():.1f} m) {why} dropped"

    through = built.dropped_seen_through
    notes = ""
    if fuse.min_observations > 1:
        notes += note(
            built.dropped[~through], f"seen from fewer than {fuse.min_observations} surveyed poses"
        )
    if fuse.seen_through == "drop":
        notes += note(built.dropped[through], "seen through from more surveyed poses than saw them")
    return notes


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
            text = f"scan {i + 1}: {counted(local.shape[0], 'local segment')} at the surveyed pose"
            view.add(log.scans[i], local, pose, status="surveyed", text=text)
            shown.advance()
    info(f"{mcap_path}: the map over its {counted(built.scans_used, 'scan')}, to open in Foxglove")
