"""Segment SLAM benchmark (`make bench-slam`): `segloc map build` with no survey on the raw logs.

Each dataset's raw log (the ROS bag, or MIT CSAIL's CARMEN log) is imported in the scanner's
frame (the relations are the scanner's poses; ``protocol.prepare_raw_log``), then mapped with
no survey, every scan's pose written with ``--poses-out``. The poses are scored on every one
of the dataset's relations (the relative-pose error of Kümmerle et al. 2009: mean ± standard
deviation, translation and rotation), beside Cartographer's published means (Hess et al.
2016, Table II), Graph Mapping's (``scoring.relations.PUBLISHED``) and the odometry alone,
scored the same way. The wall time and the peak memory are the map build's, keyframes and
loops as it reports them. Nothing is tuned per log: one set of settings for all.

Usage: python benchmarks/slam_real.py [--datasets DIR] [--only aces,fr079] [--work DIR]
       [--out FILE]
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from protocol import (
    DATASETS,
    chosen_logs,
    commands_section,
    log_arguments,
    mean_sd,
    prepare_raw_log,
    run_segloc_measured,
)

from segloc_cli.io.mcap_log import read_log
from segloc_cli.io.relations import read_relations
from segloc_cli.io.tables import read_pose_table
from segloc_cli.maps.slam import odometry_at
from segloc_cli.scoring.relations import PUBLISHED, relation_errors

CARTOGRAPHER = {
    "intel": (0.0229, 0.453),
    "aces": (0.0375, 0.373),
    "fr079": (0.0452, 0.538),
    "mit-csail": (0.0319, 0.369),
}
"""Cartographer's mean relation errors (m, °): Hess et al., "Real-Time Loop Closure in 2D
LIDAR SLAM", ICRA 2016, Table II."""

SUMMARY = re.compile(r"\((\d+) keyframes?\); (\d+) loops? accepted of (\d+) candidates?")
"""What map build's summary line says of its keyframes and loops."""


def scored(times_s: np.ndarray, poses: np.ndarray, relations) -> tuple[str, str]:
    """Mean ± standard deviation of the translation (m) and rotation (°) errors."""
    errors = relation_errors(times_s, poses, relations)
    return tuple(
        mean_sd((float(np.mean(e)), float(np.std(e, ddof=1))), digits)
        for e, digits in ((errors.trans_m, 3), (errors.rot_deg, 2))
    )


def run_log(name: str, datasets: Path, work: Path, commands: list[str]) -> list[str]:
    """Map dataset ``name`` with no survey; its table row."""
    folder = work / name
    folder.mkdir(parents=True, exist_ok=True)
    raw = prepare_raw_log(name, datasets, folder, commands)
    poses_path = folder / "poses.tum"
    built = run_segloc_measured(
        commands, "map", "build", raw.log_path, "--out", folder / "map.json",
        "--poses-out", poses_path,
    )  # fmt: skip
    said = SUMMARY.search(built.stderr)
    keyframes, accepted, candidates = said.groups() if said else ("?", "?", "?")
    relations = read_relations(datasets / name / DATASETS[name][2])
    found = read_pose_table(poses_path)
    slam = scored(found.time_s, found.poses, relations)
    log = read_log(raw.log_path)
    times = log.scan_times_s
    odometry = scored(times, odometry_at(times, log.odom_times_s, log.odom_poses), relations)
    graph = PUBLISHED[name]["GraphMapping"]
    carto_m, carto_deg = CARTOGRAPHER[name]
    return [
        name,
        f"{slam[0]} m, {slam[1]}°",
        f"{carto_m:.4f} m, {carto_deg:.3f}°",
        f"{graph['trans_m'][0]:.3f} m, {graph['rot_deg'][0]:.2f}°",
        f"{odometry[0]} m, {odometry[1]}°",
        f"{keyframes} of {raw.scans}",
        f"{accepted} of {candidates}",
        f"{built.wall_s:.0f} s",
        f"{built.peak_rss_mib / 1024:.2f} GiB",
    ]


def report(rows: list[list[str]], commands: dict[str, list[str]]) -> str:
    head = ["log", "segloc, no survey", "Cartographer", "Graph Mapping", "odometry",
            "keyframes", "loops accepted", "wall", "peak memory"]  # fmt: skip
    lines = [
        "# Segment SLAM on the public logs (`make bench-slam`)",
        "",
        "Relation error of every relation (mean ± standard deviation; the published rows are "
        "means), `segloc map build` with no survey on the raw log, one set of settings.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "|".join([":---"] + ["---:"] * (len(head) - 1)) + "|",
        *("| " + " | ".join(row) + " |" for row in rows),
        "",
        *commands_section(commands),
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    args = log_arguments(__doc__, "out/slam", "benchmarks/results-slam.md").parse_args()
    names = chosen_logs(args.only)
    missing = [n for n in names if not (args.datasets / n / DATASETS[n][1]).is_file()]
    if missing:
        raise SystemExit(f"no raw log of {', '.join(missing)} under {args.datasets}")
    commands: dict[str, list[str]] = {}
    rows = []
    for name in names:
        rows.append(run_log(name, args.datasets, args.work, commands.setdefault(name, [])))
        print(" | ".join(rows[-1]), flush=True)
    args.out.write_text(report(rows, commands), encoding="utf-8")
    print(f"{args.out}: {len(rows)} logs")


if __name__ == "__main__":
    main()
