"""Segment SLAM benchmark (`make bench-slam`): `segloc map build` with no survey on the raw logs.

Each dataset's raw log (the ROS bag, or MIT CSAIL's CARMEN log) is imported in the scanner's
frame (the relations are the scanner's poses; ``protocol.prepare_raw_log``), then mapped with
no survey, every scan's pose written with ``--poses-out``. The poses are scored on every one
of the dataset's relations (the relative-pose error of Kümmerle et al. 2009: mean ± standard
deviation, translation and rotation), beside Cartographer's published means (Hess et al.
2016, Table II), Graph Mapping's (``scoring.relations.PUBLISHED``) and the odometry alone,
scored the same way. The wall time and the peak memory are the map build's, keyframes and
loops as it reports them; loop precision is Cartographer's (Hess et al. 2016, Table IV): the
share of the loops accepted that the final poses violate by at most 20 cm and 1°
(``--loops-out``). Figures: the trajectory over the map, coloured by relation error, and
the errors over time (``segloc evaluate --plots``), into ``benchmarks/figures/slam/LOG/``.
Then the tracking protocol of ``make bench-real`` in segloc's own map: the raw log tracked
(``localize --track``) from the first scan's pose, scored on the same relations. Nothing is
tuned per log: one set of settings for all.

Usage: python benchmarks/slam_real.py [--datasets DIR] [--only aces,fr079] [--work DIR]
       [--out FILE]
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
from protocol import (
    DATASETS,
    chosen_logs,
    commands_section,
    log_arguments,
    mean_sd,
    percent,
    prepare_raw_log,
    run_segloc,
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

FIGURES = Path("benchmarks/figures/slam")
"""Where each log's figures go (a folder per log)."""

LOOP_HELD_M, LOOP_HELD_DEG = 0.2, 1.0
"""A loop accepted is a true positive when the final poses violate it by at most this much
(Hess et al. 2016, Table IV)."""

SUMMARY = re.compile(r"\((\d+) keyframes?\); (\d+) loops? accepted of (\d+) candidates?")
"""What map build's summary line says of its keyframes and loops."""


def scored(times_s: np.ndarray, poses: np.ndarray, relations) -> tuple[str, str]:
    """Mean ± standard deviation of the translation (m) and rotation (°) errors."""
    errors = relation_errors(times_s, poses, relations)
    return tuple(
        mean_sd((float(np.mean(e)), float(np.std(e, ddof=1))), digits)
        for e, digits in ((errors.trans_m, 3), (errors.rot_deg, 2))
    )


def loop_precision(loops_path: Path) -> tuple[str, str]:
    """The loops dropped by the final solve, in words; the share of the accepted loops that
    the final poses hold (``LOOP_HELD_*``), of how many, and that share counting the
    dropped loops as accepted too."""
    loops = pd.read_csv(loops_path)
    held = (loops.solved_off_m <= LOOP_HELD_M) & (loops.solved_off_deg <= LOOP_HELD_DEG)
    taken, dropped = loops.accepted, loops.dropped
    if not taken.any():
        return "", "no loop"
    with_dropped = percent(held[taken | dropped].mean())
    return (
        f" ({dropped.sum()} dropped)",
        f"{percent(held[taken].mean())} of {taken.sum()} ({with_dropped} with the dropped)",
    )


def run_log(name: str, datasets: Path, work: Path, commands: list[str]) -> tuple[list, list]:
    """Map dataset ``name`` with no survey, then track its raw log in that map; the two
    tables' rows."""
    folder = work / name
    folder.mkdir(parents=True, exist_ok=True)
    raw = prepare_raw_log(name, datasets, folder, commands)
    poses_path, map_path, loops_path = (
        folder / "poses.tum",
        folder / "map.json",
        folder / "loops.csv",
    )
    built = run_segloc_measured(
        commands, "map", "build", raw.log_path, "--out", map_path,
        "--poses-out", poses_path, "--loops-out", loops_path,
    )  # fmt: skip
    said = SUMMARY.search(built.stderr)
    keyframes, accepted, candidates = said.groups() if said else ("?", "?", "?")
    relations_path = datasets / name / DATASETS[name][2]
    relations = read_relations(relations_path)
    found = read_pose_table(poses_path)
    slam = scored(found.time_s, found.poses, relations)
    run_segloc(
        commands, "evaluate", poses_path, "--relations", relations_path, "--map", map_path,
        "--plots", FIGURES / name,
    )  # fmt: skip
    for pdf in (FIGURES / name).glob("*.pdf"):  # the PNGs say the same in a fifth of the bytes
        pdf.unlink()
    log = read_log(raw.log_path)
    times = log.scan_times_s
    odometry = scored(times, odometry_at(times, log.odom_times_s, log.odom_poses), relations)
    graph = PUBLISHED[name]["GraphMapping"]
    carto_m, carto_deg = CARTOGRAPHER[name]
    dropped, precision = loop_precision(loops_path)
    mapped = [
        name,
        f"{slam[0]} m, {slam[1]}°",
        f"{carto_m:.4f} m, {carto_deg:.3f}°",
        f"{graph['trans_m'][0]:.3f} m, {graph['rot_deg'][0]:.2f}°",
        f"{odometry[0]} m, {odometry[1]}°",
        f"{keyframes} of {raw.scans}",
        f"{accepted} of {candidates}{dropped}",
        precision,
        f"{built.wall_s:.0f} s",
        f"{built.peak_rss_mib / 1024:.2f} GiB",
    ]
    return mapped, tracked(name, raw, map_path, relations_path, folder, commands)


def tracked(name, raw, map_path: Path, relations_path: Path, folder: Path, commands) -> list:
    """The raw log tracked in segloc's own map of it from the first scan's pose; its row."""
    track = folder / "track.csv"
    run_segloc(
        commands, "localize", raw.log_path, "--map", map_path, "--track", "--initial",
        raw.first_pose_path, "--out", track,
    )  # fmt: skip
    shown = run_segloc(
        commands, "evaluate", track, "--relations", relations_path, "--published", name,
        "--format", "json",
    )  # fmt: skip
    metric = json.loads(shown.stdout)
    summary = metric["summary"]
    statuses = pd.read_csv(track)["status"].value_counts()
    return [
        name,
        f"{mean_sd((summary['trans_m']['mean'], summary['trans_m']['std']), 3)} m, "
        f"{mean_sd((summary['rot_deg']['mean'], summary['rot_deg']['std']), 2)}°",
        f"{statuses.get('ok', 0)} of {statuses.sum()}",
        "yes" if metric.get("published_note") else "no",
    ]


def report(rows: list[list[str]], tracks: list[list[str]], commands: dict[str, list[str]]) -> str:
    head = ["log", "segloc, no survey", "Cartographer", "Graph Mapping", "odometry",
            "keyframes", "loops accepted", "loop precision", "wall", "peak memory"]  # fmt: skip
    track_head = ["log", "tracked in its own map", "scans ok", "'not like for like' note"]
    lines = [
        "# Segment SLAM on the public logs (`make bench-slam`)",
        "",
        "Relation error of every relation (mean ± standard deviation; the published rows are "
        "means), `segloc map build` with no survey on the raw log, one set of settings. Loop "
        f"precision: the share of the loops accepted that the final poses hold within "
        f"{LOOP_HELD_M * 100:.0f} cm and {LOOP_HELD_DEG:g}° (Cartographer's measure); the "
        "loops the final solve drops (their residual beyond the 99th percentile of χ² with "
        "three degrees of freedom) are not accepted, and the share counting them too is "
        "given beside.",
        "",
        *_table(head, rows),
        "",
        "The raw log tracked (`localize --track`) in that map from the first scan's pose, "
        "scored on the same relations, and whether `evaluate --published` says it is not "
        "like for like with the published rows (it does only for a map built from given poses).",
        "",
        *_table(track_head, tracks),
        "",
        f"Figures: `{FIGURES}/LOG/trajectory.png` (the poses over the map, coloured by "
        "relation error) and `relation_errors_over_time.png`.",
        "",
        *commands_section(commands),
    ]
    return "\n".join(lines) + "\n"


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
    return [
        "| " + " | ".join(head) + " |",
        "|" + "|".join([":---"] + ["---:"] * (len(head) - 1)) + "|",
        *("| " + " | ".join(row) + " |" for row in rows),
    ]


def main() -> None:
    args = log_arguments(__doc__, "out/slam", "benchmarks/results-slam.md").parse_args()
    names = chosen_logs(args.only)
    missing = [n for n in names if not (args.datasets / n / DATASETS[n][1]).is_file()]
    if missing:
        raise SystemExit(f"no raw log of {', '.join(missing)} under {args.datasets}")
    commands: dict[str, list[str]] = {}
    rows, tracks = [], []
    for name in names:
        mapped, track = run_log(name, args.datasets, args.work, commands.setdefault(name, []))
        rows.append(mapped)
        tracks.append(track)
        print(" | ".join(mapped), "|", " | ".join(track[1:]), flush=True)
    args.out.write_text(report(rows, tracks, commands), encoding="utf-8")
    print(f"{args.out}: {len(rows)} logs")


if __name__ == "__main__":
    main()
