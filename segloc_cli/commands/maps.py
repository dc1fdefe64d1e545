"""``segloc map``: the group, and ``map build``, a segment map from the scans of a log at
surveyed poses, or at the poses segment SLAM finds from its odometry (``commands/plans.py``
holds ``map import`` and ``map export``)."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import click
import numpy as np

from segloc_cli.commands.configfile import check_command_outputs, config_option
from segloc_cli.commands.invocation import Invocation
from segloc_cli.commands.options import (
    SCAN_SELECTION,
    FilePath,
    force_option,
    path_option,
    scan_selection,
    setting_option,
    tuning_options,
    with_options,
)
from segloc_cli.commands.optionvalues import parse_planar_pose
from segloc_cli.commands.plans import map_export, map_import
from segloc_cli.commands.printing import info, load_log, write_pose_file
from segloc_cli.config import EXTRACT, FUSE
from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2
from segloc_cli.limits import MAX_COORDINATE_M
from segloc_cli.runs.runfile import RUN_FILE_OUTPUT, run_file_path
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
        help="Poses of the scans (survey CSV or TUM); scans without a row are ignored. "
        "Without it, the scans' poses are found from the log itself (segment SLAM on its "
        "scans and odometry).",
    ),
    path_option("--out", "out_path", required=True, help="MAP.json to write."),
    click.option(
        "--initial",
        "initial_text",
        metavar="X,Y,THETA_DEG",
        help="Without --survey: the first scan's pose in the map's frame (metres, degrees); "
        "default 0,0,0.",
    ),
    path_option(
        "--poses-out",
        "poses_out",
        help="Without --survey: also write every scan's pose found, at the scan's time: TUM "
        "for a name ending in .tum, else a CSV pose_id,time_s,x_m,y_m,theta_deg that --survey "
        "reads back.",
    ),
    path_option(
        "--loops-out",
        "loops_out",
        help="Without --survey: also write every loop candidate (CSV): the keyframe searched "
        "for and the submap keyframe nearest the find (pose ids), where the search put the "
        "one in the other's frame, its verdict and inlier ratio, the correction it implied, "
        "whether it was accepted, and how far the solved poses end up from it.",
    ),
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
@click.argument("log_path", metavar="LOG.mcap", type=FilePath())
@with_options(*BUILD_OPTIONS)
def map_build(
    log_path, survey_path, out_path, mcap_path, initial_text, poses_out, loops_out, force, **_
):  # fmt: skip
    """Build a global segment map from the scans of a log at surveyed poses, or, without
    --survey, at the poses the log's own scans and odometry give.

    With --survey, each scan with a survey row becomes a local map, is placed at
    its pose and fused with the others: nearly collinear segments that overlap
    or nearly touch become one. Without it, segment SLAM places the scans: each
    is fitted to the map of the last few metres from where the odometry puts
    it, the scans that moved far enough become keyframes, each keyframe is
    searched for in the older parts of the map near it (a loop, taken when the
    verdict is ok), and a pose graph over the keyframes is solved (gtsam)
    before every scan's local map is fused at its pose. With --min-observations, segments seen
    from too few poses are dropped; with --seen-through drop, those that more
    poses see through than see (people walking by). Beside OUT goes its run
    file (OUT.run.toml).
    """
    from segloc_cli.io.maps import bounds_problem, write_map
    from segloc_cli.io.tables import read_pose_table, refuse_map
    from segloc_cli.jit import SEEN_THROUGH_KERNELS, watching_compiles
    from segloc_cli.progress import Progress
    from segloc_cli.runs.pipeline import build_map

    run = Invocation.current()
    later = SEEN_THROUGH_KERNELS if run.config.fuse.seen_through == "drop" else None
    click.get_current_context().with_resource(watching_compiles(later=later))
    if survey_path is not None:
        for option, value in (
            ("--initial", initial_text), ("--poses-out", poses_out), ("--loops-out", loops_out)
        ):  # fmt: skip
            if value is not None:
                raise click.UsageError(
                    f"{option} is for a map built without --survey (the survey gives every "
                    "scan's pose)"
                )
    initial = None
    if initial_text is not None:
        initial = Pose2.from_deg(
            *parse_planar_pose(initial_text, "--initial", MAX_COORDINATE_M, "2.5,1.0,90")
        )
    outputs = {"--out": out_path, "--mcap": mcap_path, "--poses-out": poses_out}
    outputs |= {"--loops-out": loops_out, RUN_FILE_OUTPUT: run_file_path(out_path)}
    check_command_outputs(outputs, [log_path, survey_path], force)
    if survey_path is None:
        extra = {"poses": poses_out, "loops": loops_out, "view": mcap_path}
        _map_without_survey(run, log_path, out_path, extra, initial)
        return
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
    source |= _built_source(built, selection, selected, run.config)
    write_map(out_path, built.segments, source=source)
    run.write_run_file(out_path)
    if mcap_path is not None:
        metadata = {"command": "map build", "log": str(log_path), "survey": str(survey_path)}
        _write_build_view(mcap_path, log, built, metadata, "at the surveyed pose", "surveyed")
    unsurveyed = selected.size - built.scans_used
    which = "scan" if selection.whole else "selected scan"
    info(
        f"{out_path}: {counted(built.segments.shape[0], 'segment')} fused from "
        f"{counted(built.local_segments, 'local segment')} of "
        f"{counted(built.scans_used, 'scan')} ({counted(unsurveyed, which)} had no survey row)"
        f"{_dropped_note(built, run.config.fuse)}"
    )


def _map_without_survey(run, log_path, out_path, extra: dict, initial) -> None:
    """``map build`` without ``--survey``: segment SLAM (``runs.pipeline.slam_map``), the
    map, its run file, and the ``extra`` outputs asked for (None where not): every scan's
    pose (``poses``), every loop candidate (``loops``), the Foxglove view (``view``)."""
    from segloc_cli.estimates import PoseTable
    from segloc_cli.io.maps import bounds_problem, write_map
    from segloc_cli.progress import Progress
    from segloc_cli.runs.pipeline import slam_map

    log = load_log(log_path)
    selection = scan_selection(run.options)
    selected = selection.chosen(log.scan_times_s, log_path)
    if not log.has_odometry and selected.size > 1:
        info(
            "the log has no odometry: each scan is guessed to move as the one before did, "
            "and loops rest on the scans alone"
        )
    built, slam = slam_map(log, log_path, run.config, Progress, selected, initial)
    _say_jumps(log, selected, slam)
    problem = bounds_problem(built.segments)
    if problem is not None:
        raise InputError(f"the map built would be refused when read: {problem}", path=log_path)
    accepted = slam.loops_accepted
    placed = "segment SLAM on the log's scans and odometry"
    if not log.has_odometry:
        placed = "segment SLAM on the log's scans (no odometry)"
    source: dict[str, object] = {"log": str(log_path), "poses": placed}
    source |= _built_source(built, selection, selected, run.config)
    source |= {"keyframes": int(slam.keyframes.size), "loops_accepted": accepted}
    dropped = sum(loop.dropped for loop in slam.loops)
    source |= {"loops_rejected": len(slam.loops) - accepted - dropped, "loops_dropped": dropped}
    source |= {"slam": asdict(run.config.slam)}
    write_map(out_path, built.segments, source=source)
    run.write_run_file(out_path)
    poses_out, mcap_path = extra["poses"], extra["view"]
    if poses_out is not None:
        table = PoseTable(log.scan_numbers[selected], log.scan_times_s[selected], slam.poses)
        write_pose_file(poses_out, table, log.original_times_s[selected], "scan pose")
    if extra["loops"] is not None:
        _write_loops(extra["loops"], slam, log.scan_numbers[selected])
    if mcap_path is not None:
        metadata = {"command": "map build", "log": str(log_path), "poses": placed}
        odometry = [Pose2(*pose) for pose in slam.odometry]
        solved = slam.keyframe_poses
        loops = [(*solved[loop.anchor, :2], *solved[loop.keyframe, :2])
                 for loop in slam.accepted_loops]  # fmt: skip
        _write_build_view(
            mcap_path, log, built, metadata, "at the pose found", "mapped", odometry,
            np.array(loops).reshape(-1, 4),
        )  # fmt: skip
    corrections = [loop.correction_m for loop in slam.accepted_loops]
    largest = f", the largest correcting {max(corrections):.2f} m" if corrections else ""
    info(
        f"{out_path}: {counted(built.segments.shape[0], 'segment')} fused from "
        f"{counted(built.local_segments, 'local segment')} of "
        f"{counted(built.scans_used, 'scan')} ({counted(slam.keyframes.size, 'keyframe')}); "
        f"{counted(accepted, 'loop')} accepted of "
        f"{counted(len(slam.loops), 'candidate')}"
        f"{f' ({dropped} more dropped by the final solve)' if dropped else ''}{largest}"
        f"{_dropped_note(built, run.config.fuse)}"
    )


def _write_loops(path: Path, slam, numbers: np.ndarray) -> None:
    """Every loop candidate of ``slam`` (a ``SlamResult``) as a CSV at ``path``, keyframes
    named by their scans' pose ids (``numbers``, one per scan mapped)."""
    import pandas as pd

    from segloc_cli.io.files import atomic_path

    loops = slam.loops
    scan_of = numbers[slam.keyframes]
    motion = np.array([loop.motion for loop in loops]).reshape(-1, 3)
    offsets = slam.loop_offsets()
    frame = pd.DataFrame(
        {
            "pose_id": [scan_of[loop.keyframe] for loop in loops],
            "anchor_pose_id": [scan_of[loop.anchor] for loop in loops],
            "submap": [loop.submap for loop in loops],
            "x_m": motion[:, 0],
            "y_m": motion[:, 1],
            "theta_deg": np.rad2deg(motion[:, 2]),
            "status": [loop.status for loop in loops],
            "inlier_ratio": [loop.inlier_ratio for loop in loops],
            "correction_m": [loop.correction_m for loop in loops],
            "correction_deg": [loop.correction_deg for loop in loops],
            "accepted": [loop.accepted for loop in loops],
            "dropped": [loop.dropped for loop in loops],
            "solved_off_m": offsets[:, 0],
            "solved_off_deg": offsets[:, 1],
        }
    )
    with atomic_path(path) as partial:
        frame.to_csv(partial, index=False, float_format="%.6g")
    info(f"{path}: {counted(len(loops), 'loop candidate')} ({slam.loops_accepted} accepted)")


def _say_jumps(log, selected, slam, shown: int = 3) -> None:
    """One line on the scans to which the odometry jumped (``SlamResult.odometry_jumps``),
    naming the first ``shown``."""
    from segloc_cli.geometry import relative_motion

    if not slam.odometry_jumps:
        return
    numbers, times = log.scan_numbers[selected], log.scan_times_s[selected]
    places = []
    for i in slam.odometry_jumps[:shown]:
        step = relative_motion(slam.odometry[i - 1], slam.odometry[i])[0]
        places.append(
            f"scan {numbers[i]} (t {times[i]:.3f} s: {np.hypot(step[0], step[1]):.2f} m, "
            f"{np.rad2deg(abs(step[2])):.0f}°)"
        )
    more = len(slam.odometry_jumps) - len(places)
    info(
        f"the odometry jumps at {counted(len(slam.odometry_jumps), 'scan')}: "
        f"{', '.join(places)}{f' and {more} more' if more else ''}; those scans were placed "
        "by the scans alone"
    )


def _built_source(built, selection, selected, config) -> dict:
    """The map's provenance common to both ways of building it: the scans and local
    segments used, the selection, the segments dropped, the extraction's and fusion's
    settings."""
    source = {"scans_used": built.scans_used, "local_segments": built.local_segments}
    if not selection.whole:
        source["scans_selected"] = f"{selected.size} ({selection.options_text()})"
    source |= {"dropped_segments": int(built.dropped.shape[0])}
    source |= {"dropped_seen_through": int(built.dropped_seen_through.sum())}
    return source | {"extract": asdict(config.extract), "fuse": asdict(config.fuse)}


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


def _write_build_view(
    mcap_path: Path, log, built, metadata: dict[str, str], placed: str, status: str,
    guesses: list[Pose2] | None = None, loops: np.ndarray | None = None,
) -> None:  # fmt: skip
    """The built map over its scans, each at its pose (``placed`` says which, in words) with
    ``status``, as a Foxglove view; with no survey, each scan's odometry pose as its guess
    (``guesses``, one per scan used) and the loops as lines (K, 4) in the map's frame."""
    from segloc_cli.io.runview import RunViewWriter
    from segloc_cli.progress import Progress

    odometry: list[Pose2 | None] = list(guesses) if guesses else [None] * built.scans_used
    parts = zip(built.scan_index, built.poses, built.local_maps, odometry, strict=True)
    with (
        RunViewWriter(mcap_path, built.segments, metadata) as view,
        Progress("writing the view", built.scans_used, "scan") as shown,
    ):
        for i, pose, local, guess in parts:
            text = f"scan {i + 1}: {counted(local.shape[0], 'local segment')} {placed}"
            view.add(log.scans[i], local, pose, guess=guess, status=status, text=text)
            shown.advance()
        if loops is not None and loops.shape[0]:
            view.add_loops(loops, log.scans[built.scan_index[-1]].time_s)
    info(f"{mcap_path}: the map over its {counted(built.scans_used, 'scan')}, to open in Foxglove")
