"""What the benchmarks share: the real logs and how each is split, how segloc is run and its
commands recorded, and how an answer is scored against the truth.

`real_logs.py` and `peers.py` both hold out every 10th scan of a SLAM-corrected log, build the
map from the others through the command line and score answers within the same bounds;
`figures.py` runs the same segloc executable, and the pytest benchmarks measure pose errors
the same way; `test_bench_speed.py` times the same commands (``run_segloc_measured``) on the
same splits, from the perturbation protocol's guesses (``perturbed_guesses``).

Poses are in the world frame: metres, and radians in a ``PoseTable``; an estimates table
(``segloc localize --out``) gives headings in degrees.
"""

from __future__ import annotations

import argparse
import itertools
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from segloc_cli.estimates import PoseTable
from segloc_cli.geometry import wrap_angle
from segloc_cli.io.tables import read_pose_table, write_pose_table

SEGLOC = str(Path(sys.executable).parent / "segloc")
"""The segloc executable installed beside the running interpreter."""

HOLD_OUT_EVERY = 10
"""Every this many scans of a corrected log, one is left out of the map and localized."""
SUCCESS_M, SUCCESS_DEG = 0.10, 1.0
"""A right answer is within ``SUCCESS_M`` (metres) and ``SUCCESS_DEG`` (degrees) of the truth."""


PLACE_M, PLACE_DEG = 0.30, 3.0
"""Within ``PLACE_M`` (metres) and ``PLACE_DEG`` (degrees) of the truth an answer has found the
right place: beyond either it is a wrong place, not an imprecise fit."""

PERTURB_SEED = 2009
PERTURB_XY_M = 1.5
PERTURB_THETA_DEG = 20.0
"""The perturbation protocol: each held-out scan is localized from its reference pose plus
errors uniform in ±``PERTURB_XY_M`` per axis (metres) and ±``PERTURB_THETA_DEG`` (degrees),
drawn with seed ``PERTURB_SEED``."""

OWN_SCAN_ONLY = ("--tolerance-ms", "1")
"""How held-out scans are paired with poses here: each pose goes to the scan at its own time
only. The corrected logs hold scans 10 ms apart (intel 8 pairs, fr079 2), and the default
50 ms would hand a held-out scan's guess to its neighbour, a scan of the map, and score that
scan against the held-out scan's reference; and when building the map, place the held-out
scan at its neighbour's pose."""


HELD_OUT_ALONE = (*OWN_SCAN_ONLY, "--window-m", "0")
"""How the held-out scans of a corrected log are localized: each from its own pose, and
alone. The corrected logs' neighbours of a held-out scan are scans of the map, which a window
(``segloc localize``'s default where a log has odometry) would add to its local map."""


def is_right(pos_m, head_deg):
    """Whether each error (position in metres, heading in degrees, arrays) is a right answer:
    at most ``SUCCESS_M`` and ``SUCCESS_DEG``."""
    return (pos_m <= SUCCESS_M) & (head_deg <= SUCCESS_DEG)


def is_right_place(pos_m, head_deg):
    """Whether each error (position in metres, heading in degrees, arrays) lies within
    ``PLACE_M`` and ``PLACE_DEG``: the right place, whether or not precisely fitted."""
    return (pos_m <= PLACE_M) & (head_deg <= PLACE_DEG)


DATASETS_DIR = Path("../shared/datasets")
"""Where the real logs are unless ``--datasets`` says otherwise (they are not shipped)."""
DATASETS = {
    # name: (corrected log, raw log, relations), files in the folder <datasets>/<name>
    "intel": ("intel-corrected.log.gz", "intel.orig.bag", "intel.relations"),
    "aces": ("aces-corrected.log.gz", "aces.orig.bag", "aces.relations"),
    "fr079": ("fr079-corrected.log.gz", "fr079.orig.bag", "fr079.relations"),
    "mit-csail": ("mit-csail-corrected.log.gz", "mit-csail.clf", "mit-csail.relations"),
}


def log_arguments(doc: str, work: str, out: str) -> argparse.ArgumentParser:
    """A benchmark's command line over the real logs: ``--datasets`` (their folder),
    ``--only`` (names, comma-separated), ``--work`` (default ``work``) and ``--out``
    (default ``out``), described by ``doc``'s first line; ``chosen_logs`` checks ``--only``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--datasets", type=Path, default=DATASETS_DIR)
    parser.add_argument("--only", default=",".join(DATASETS))
    parser.add_argument("--work", type=Path, default=Path(work))
    parser.add_argument("--out", type=Path, default=Path(out))
    return parser


def chosen_logs(only: str) -> list[str]:
    """The datasets ``--only`` names; the script ends naming one it does not know."""
    names = [name for name in only.split(",") if name]
    unknown = [n for n in names if n not in DATASETS]
    if unknown:
        raise SystemExit(f"unknown dataset {unknown[0]!r}; expected some of {', '.join(DATASETS)}")
    return names


# --- running segloc -------------------------------------------------------------


def segloc_argv(*args: object) -> list[str]:
    """The argument vector that runs ``segloc ARGS`` (each argument as text)."""
    return [SEGLOC, *map(str, args)]


def as_typed(argv: list[str]) -> str:
    """``argv`` as a user would type it in the repository: ``segloc ...``, with absolute
    paths (a ``--datasets`` given as one) written relative to the current folder, so that
    a report names no one machine's folders."""
    words = [os.path.relpath(a) if os.path.isabs(a) else a for a in argv[1:]]
    return " ".join(["segloc", *words])


def run_segloc(commands: list[str], *args: object) -> subprocess.CompletedProcess:
    """Run ``segloc ARGS --force`` (replacing the outputs of an earlier run) and return it.

    The command is appended to ``commands`` as a user would type it; a failure
    ends the script with the command and its error output.
    """
    argv = segloc_argv(*args, "--force")
    commands.append(as_typed(argv))
    proc = subprocess.run(argv, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"command failed ({proc.returncode}): {' '.join(argv)}\n{proc.stderr}")
    return proc


@dataclass(frozen=True)
class MeasuredRun:
    """A segloc command that succeeded: its output, its wall time (seconds, process start to
    exit) and the peak resident memory (MiB) of its largest process."""

    stdout: str
    stderr: str
    wall_s: float
    peak_rss_mib: float


_MEASURING_LAUNCHER = """
import os, subprocess, sys, time
start = time.perf_counter()
child = subprocess.Popen(sys.argv[2:])
_, status, usage = os.wait4(child.pid, 0)
with open(sys.argv[1], "w") as report:
    report.write(f"{time.perf_counter() - start!r} {usage.ru_maxrss}")
sys.exit(os.waitstatus_to_exitcode(status) % 256)
"""
"""Runs a command and writes its wall time (s) and peak RSS (``wait4``'s ``ru_maxrss``) to
the file named first. A process forked from a large one is charged that one's resident set
from the start (Linux keeps the high-water mark across exec), so the command is started from
this small interpreter, not from the benchmark's own process."""


def run_segloc_measured(
    commands: list[str], *args: object, env: dict[str, str] | None = None
) -> MeasuredRun:
    """Run ``segloc ARGS --force`` as ``run_segloc`` does, timing it and reading its peak RSS;
    in the environment ``env`` if given (else this process's).

    The peak comes from the kernel's account of the finished process (``wait4``): the
    largest resident set of the process or of any worker it waited for, counted from a
    small launcher (``_MEASURING_LAUNCHER``), so the benchmark's own memory is not in it.
    """
    argv = segloc_argv(*args, "--force")
    commands.append(as_typed(argv))
    with (
        tempfile.TemporaryFile("w+") as out,
        tempfile.TemporaryFile("w+") as err,
        tempfile.TemporaryDirectory() as folder,
    ):
        report = Path(folder) / "measured"
        launcher = [sys.executable, "-c", _MEASURING_LAUNCHER, str(report), *argv]
        returncode = subprocess.run(launcher, stdout=out, stderr=err, text=True, env=env).returncode
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
        if returncode != 0:
            raise SystemExit(f"command failed ({returncode}): {' '.join(argv)}\n{stderr}")
        wall_s, max_rss = report.read_text().split()
    return MeasuredRun(stdout, stderr, float(wall_s), _max_rss_mib(int(max_rss)))


def _max_rss_mib(ru_maxrss: int) -> float:
    """``ru_maxrss`` in MiB: the kernel counts it in KiB on Linux, in bytes on macOS."""
    return ru_maxrss / (2**20 if sys.platform == "darwin" else 2**10)


def commands_section(commands: dict[str, list[str]]) -> list[str]:
    """Markdown lines: every command run, per dataset."""
    lines = ["## Commands", ""]
    for name, cmds in commands.items():
        lines += [f"### {name}", "", "```sh", *cmds, "```", ""]
    return lines


# --- the held-out split of a corrected log --------------------------------------


@dataclass(frozen=True)
class HeldOutSplit:
    """A corrected log imported as ``log_path`` and its map built without the held-out scans.

    ``reference`` holds every scan's reference pose; ``held_out`` (N,) bool
    marks the scans left out of the map at ``map_path``, whose reference poses
    ``held_out_path`` holds as a survey CSV.
    """

    log_path: Path
    map_path: Path
    held_out_path: Path
    reference: PoseTable
    held_out: np.ndarray

    def held_out_reference(self) -> PoseTable:
        """The reference poses of the held-out scans."""
        return subset_poses(self.reference, self.held_out)


def prepare_held_out(
    name: str, datasets: Path, work: Path, commands: list[str], first: int = 0
) -> HeldOutSplit:
    """Import dataset ``name``'s corrected log into ``work`` and build its map without the
    held-out scans (every ``HOLD_OUT_EVERY``-th from the ``first``, 0-based); the commands run
    are appended to ``commands``.

    ``datasets`` is the folder holding a folder per dataset (see ``DATASETS``). The benchmarks
    hold out the scans from the first; ``calibrate.py`` fits the verdict on another split.
    """
    carmen_log = datasets / name / DATASETS[name][0]
    log_path, reference_path = work / "corrected.mcap", work / "reference.csv"
    run_segloc(
        commands, "import", "carmen", carmen_log, "--out", log_path, "--survey-out", reference_path
    )
    # The importer gives colliding records (mit-csail's six-digit times) distinct times,
    # in the log and the reference alike.
    reference = read_pose_table(reference_path)
    held_out = np.zeros(len(reference), dtype=bool)
    held_out[first::HOLD_OUT_EVERY] = True
    start = f", from scan {first + 1}" if first else ""
    commands.append(
        f"# map_poses.csv, held_out.csv: written by {Path(sys.argv[0]).name} "
        f"(every {HOLD_OUT_EVERY}th scan held out{start})"
    )
    map_path, held_out_path = map_without(log_path, reference, held_out, work, commands)
    return HeldOutSplit(log_path, map_path, held_out_path, reference, held_out)


def map_without(
    log_path: Path,
    reference: PoseTable,
    held_out: np.ndarray,
    work: Path,
    commands: list[str],
    held_out_name: str = "held_out.csv",
) -> tuple[Path, Path]:
    """Build ``work/map.json`` from the scans of ``log_path`` at their ``reference`` poses,
    leaving out those ``held_out`` ((N,) bool) marks, whose poses go to ``held_out_name``;
    returns (map path, held-out poses path). ``map_poses.csv`` holds the others."""
    map_poses_path, held_out_path = work / "map_poses.csv", work / held_out_name
    write_pose_table(map_poses_path, subset_poses(reference, ~held_out))
    write_pose_table(held_out_path, subset_poses(reference, held_out))
    map_path = work / "map.json"
    # Paired within 1 ms, a held-out scan 10 ms from a map scan does not take its survey row.
    run_segloc(
        commands, "map", "build", log_path, "--survey", map_poses_path, *OWN_SCAN_ONLY,
        "--out", map_path,
    )  # fmt: skip
    return map_path, held_out_path


def subset_poses(table: PoseTable, mask: np.ndarray) -> PoseTable:
    """The rows of ``table`` where ``mask`` ((N,) bool) holds."""
    return PoseTable(table.pose_id[mask], table.time_s[mask], table.poses[mask])


def evenly_spread(count: int, wanted: int) -> np.ndarray:
    """Mask (count,) bool choosing ``wanted`` rows spread evenly from first to last (all of
    them when there are no more than ``wanted``)."""
    if count <= wanted:
        return np.ones(count, dtype=bool)
    return np.isin(np.arange(count), np.linspace(0, count - 1, wanted).round())


def perturbed_guesses(truth: PoseTable) -> PoseTable:
    """The perturbation protocol's initial guesses: each pose of ``truth`` plus uniform errors
    (``PERTURB_XY_M``, ``PERTURB_THETA_DEG``), drawn with ``PERTURB_SEED`` row for row.

    The same ``truth`` always gets the same guesses, so a subset of its rows keeps the
    guesses those rows have in the full protocol.
    """
    rng = np.random.default_rng(PERTURB_SEED)
    n = len(truth)
    offsets = np.column_stack(
        [
            rng.uniform(-PERTURB_XY_M, PERTURB_XY_M, (n, 2)),
            np.deg2rad(rng.uniform(-PERTURB_THETA_DEG, PERTURB_THETA_DEG, n)),
        ]
    )
    return PoseTable(truth.pose_id, truth.time_s, truth.poses + offsets)


# --- tracking a raw log -----------------------------------------------------------


@dataclass(frozen=True)
class RawLog:
    """A dataset's raw log imported as ``log_path``, with ``first_pose_path``: a survey CSV
    seeding its first scan at (0, 0, 0), where the corrected log's map frame starts."""

    log_path: Path
    first_pose_path: Path
    scans: int


SCANNER_FRAME = ("--laser-offset", "0,0,0")
"""How a raw ROS bag is imported here: in the scanner's frame, not the robot's. The maps and
the reference poses come from the corrected CARMEN logs, whose poses are the scanner's (and
so are the relations'), so the scanner's poses are the ones to track and score; a bag's
base_link → laser offset (0.04 m in fr079's) would otherwise stand between them."""


def prepare_raw_log(name: str, datasets: Path, work: Path, commands: list[str]) -> RawLog:
    """Import dataset ``name``'s raw log (ROS bag or CARMEN) into ``work`` and write the pose
    that seeds ``--track`` at its first scan; the commands run are appended to ``commands``."""
    from segloc_cli.io.mcap_log import read_log

    raw = datasets / name / DATASETS[name][1]
    raw_format, options = ("rosbag", SCANNER_FRAME) if raw.suffix == ".bag" else ("carmen", ())
    log_path, first_pose_path = work / "raw.mcap", work / "first_pose.csv"
    run_segloc(commands, "import", raw_format, raw, *options, "--out", log_path)
    scans = read_log(log_path).scans
    commands.append(f"# first_pose.csv: (0, 0, 0) at the first scan of {log_path.name}")
    write_pose_table(
        first_pose_path,
        PoseTable(np.array([1]), np.array([scans[0].time_s]), np.zeros((1, 3))),
    )
    return RawLog(log_path, first_pose_path, len(scans))


@dataclass(frozen=True)
class RawHeldOut:
    """The held-out scans of a split, found in the dataset's raw log (with its odometry), and a
    map that none of their windows meets.

    ``map_path``: the corrected log's map without the held-out scans and without every scan
    in the window of one (``left_out_near`` of them); ``log_path``: the raw log less every scan
    that map was built from (found by its readings), so that a window holds no scan of the
    map yet every neighbour it would hold in a log of its own; ``truth_path`` and ``truth``:
    the held-out scans' reference poses at their times in that log, under the split's pose
    ids; ``missing``: held-out scans not found in the raw log.
    """

    log_path: Path
    truth_path: Path
    truth: PoseTable
    missing: int
    map_path: Path
    left_out_near: int


def raw_held_out(split: HeldOutSplit, raw: RawLog, work: Path, commands: list[str]) -> RawHeldOut:
    """Find the held-out scans of ``split`` in the raw log ``raw``, build their map without
    their windows' scans in ``work/odometry`` and write the raw log less the map's scans
    there (``RawHeldOut``); windows as ``segloc localize`` makes them by default."""
    from segloc_cli.config import WindowParams
    from segloc_cli.geometry import Pose2
    from segloc_cli.io.mcap_log import LogWriter, read_log
    from segloc_cli.method.window import neighbour_indices
    from segloc_cli.runs.pipeline import scan_odometry

    corrected, raw_log = read_log(split.log_path), read_log(raw.log_path)
    in_raw = same_scans(corrected.scans, raw_log.scans)
    odometry = scan_odometry(raw_log, raw.log_path, 1e-6)
    times = raw_log.scan_times_s
    windows: set[int] = set()
    for i in in_raw[split.held_out & (in_raw >= 0)]:
        windows.update(neighbour_indices(odometry, times, int(i), WindowParams()))
    near = np.isin(in_raw, sorted(windows)) & ~split.held_out
    folder = work / "odometry"
    folder.mkdir(parents=True, exist_ok=True)
    commands.append(
        f"# odometry/: {split.log_path.name}'s map without the held-out scans and the "
        f"{int(near.sum())} scans in their windows in {raw.log_path.name} (1 m of odometry "
        f"travel, 3 s), written by {Path(sys.argv[0]).name}"
    )
    map_path, _ = map_without(split.log_path, split.reference, split.held_out | near, folder,
                              commands)  # fmt: skip
    in_map = np.zeros(len(raw_log.scans), dtype=bool)
    in_map[in_raw[~(split.held_out | near) & (in_raw >= 0)]] = True
    log_path, truth_path = folder / "raw-held-out.mcap", folder / "raw-held-out.csv"
    kept = [scan for scan, mapped in zip(raw_log.scans, in_map, strict=True) if not mapped]
    odometry_messages = zip(raw_log.odom_times_s, raw_log.odom_poses, strict=True)
    events = [(float(t), 0, Pose2(*pose)) for t, pose in odometry_messages]
    events += [(scan.time_s, 1, scan) for scan in kept]
    with LogWriter(log_path, raw_log.sensor) as out:
        for t, kind, item in sorted(events, key=lambda event: event[:2]):
            out.add_odom(t, item) if kind == 0 else out.add_scan(item)
    held = split.held_out_reference()
    found = in_raw[split.held_out]
    times_found = np.array([raw_log.scans[i].time_s for i in found[found >= 0]])
    truth = PoseTable(held.pose_id[found >= 0], times_found, held.poses[found >= 0])
    write_pose_table(truth_path, truth)
    commands.append(
        f"# {log_path.name}: {raw.log_path.name} less the {int(in_map.sum())} scans of "
        f"{map_path.name} (found by their readings); {truth_path.name}: the held-out "
        "scans' reference poses at their times there; written by "
        f"{Path(sys.argv[0]).name}"
    )
    return RawHeldOut(
        log_path, truth_path, truth, int(np.sum(found < 0)), map_path, int(near.sum())
    )


# --- scoring --------------------------------------------------------------------


def pose_errors(
    dx_m: float | np.ndarray, dy_m: float | np.ndarray, dtheta_rad: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Position error (m) and absolute heading error (°, wrapped) of pose differences.

    The differences are estimate minus truth, in metres and radians: scalars,
    or arrays of one shape, and the two errors are the same.
    """
    return np.hypot(dx_m, dy_m), np.abs(np.rad2deg(wrap_angle(dtheta_rad)))


def distances(est: pd.DataFrame, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and heading (°) distance of estimate rows from poses (N, 3), row for row."""
    return pose_errors(
        est["x_m"].to_numpy() - poses[:, 0],
        est["y_m"].to_numpy() - poses[:, 1],
        np.deg2rad(est["theta_deg"].to_numpy()) - poses[:, 2],
    )


def rows_by_pose_id(pose_ids: np.ndarray | pd.Series) -> dict[int, int]:
    """Each pose id of ``pose_ids`` mapped to its row."""
    return {int(pid): k for k, pid in enumerate(pose_ids)}


def truth_rows(est: pd.DataFrame, truth: PoseTable) -> list[int]:
    """The row of ``truth`` with each estimate row's pose_id."""
    row_of = rows_by_pose_id(truth.pose_id)
    return [row_of[int(pid)] for pid in est["pose_id"]]


def errors_against_truth(est: pd.DataFrame, truth: PoseTable) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and heading (°) error of each estimate row against its pose_id's truth.

    Rows without a pose count as failures (inf).
    """
    pos, head = distances(est, truth.poses[truth_rows(est, truth)])
    failed = ~np.isfinite(pos) | ~np.isfinite(head)
    pos[failed] = np.inf
    head[failed] = np.inf
    return pos, head


def stage2_answers(est: pd.DataFrame) -> pd.DataFrame:
    """Estimates with the stage-2 pose as the answer: the paper's, before search and refinement."""
    return est.assign(
        x_m=est["stage2_x_m"], y_m=est["stage2_y_m"], theta_deg=est["stage2_theta_deg"]
    )


CONFIDENCE_BINS = (0.0, 0.5, 0.7, 0.8, 0.9, 0.95, 0.99, 1.0)
"""Edges of the confidence bins of a reliability table."""


def reliability_rows(confidence: np.ndarray, right: np.ndarray) -> list[list[str]]:
    """Per bin of ``CONFIDENCE_BINS``: the bin, its trials, their mean confidence and the
    share of them that is right (``right`` (N,) bool beside ``confidence`` (N,))."""
    rows = []
    for lo, hi in itertools.pairwise(CONFIDENCE_BINS):
        inside = (confidence >= lo) & ((confidence < hi) if hi < 1.0 else (confidence <= hi))
        n = int(inside.sum())
        shown = [f"{confidence[inside].mean():.3f}", f"{right[inside].mean():.3f}"] if n else []
        rows.append([f"{lo:g}–{hi:g}", str(n), *(shown or ["—", "—"])])
    return rows


def same_scans(wanted: list, scans: list, look_back: int = 50, look_ahead: int = 3000):
    """Index into ``scans`` of the scan with the same readings as each of ``wanted`` (−1: none).

    Both lists are nearly in recording order (the corrected logs swap a
    neighbouring pair now and then), so the search walks on from the previous
    match; readings agree within a millimetre (text logs print fewer digits).
    """
    ranges = [np.asarray(s.ranges_m, dtype=float) for s in scans]
    out = np.full(len(wanted), -1, dtype=np.int64)
    last = 0
    for k, scan in enumerate(wanted):
        target = np.asarray(scan.ranges_m, dtype=float)
        for i in range(max(0, last - look_back), min(len(scans), last + look_ahead)):
            if ranges[i].shape == target.shape and np.max(np.abs(ranges[i] - target)) < 1e-3:
                out[k], last = i, i
                break
    return out


def percent(share: float) -> str:
    """A share (0–1) as a percentage, or a dash where there is none."""
    return "—" if not np.isfinite(share) else f"{share * 100:.1f} %"


def mean_sd(value: object, digits: int) -> str:
    """Mean ± std with ``digits`` decimals from a {"mean", "std"} dict, a (mean, std) pair or
    a bare mean; a dash where there is none (NaN or None)."""
    if isinstance(value, dict):
        mean, std = value.get("mean"), value.get("std")
    elif isinstance(value, list | tuple):
        mean, std = value
    else:
        mean, std = value, None
    if mean is None or not np.isfinite(mean):
        return "—"
    if std is None or not np.isfinite(std):
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} ± {std:.{digits}f}"
