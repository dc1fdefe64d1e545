"""The speed a user feels, from one run (`make bench`): segloc through its command line.

Sections, one test each, every figure measured in the same run:

1. Default against ``--method icp``: held-out scans of each shared real log (the
   perturbation protocol of `real_logs.py`, its guesses for ``SCANS_PER_LOG`` scans spread
   over the run) localized with the defaults and with ICP, one job each; median ms per scan,
   the ratio default/icp and the right answers of each (within 10 cm and 1°).
2. Global search time against map area: ``--global`` on ``GLOBAL_SCANS_PER_LOG`` held-out
   scans of each shared log, and on scans simulated in generated maps of rooms tiled over
   the sizes of ``GENERATED_MAPS`` (a building, a campus); map area, segments, median
   seconds per scan, right places (within 30 cm and 3°).
3. Tracking rate: each shared raw log tracked with ``--track`` in its held-out map (the
   tracking protocol of `real_logs.py`); scans per second of wall time.
4. Map-build time per 1,000 scans: ``map build`` of each whole corrected log.
5. Peak resident memory: a column of sections 1 and 2, with the largest shared log's
   default run and the generated map's global run named below their tables.
6. First run: ``segloc localize`` of the shipped hall's 10 scans with the defaults on an
   empty numba cache (``NUMBA_CACHE_DIR`` a new folder: what a plain ``pip install`` gives),
   then again with the kernels that run cached.

ms/scan is the median of the estimates' ``runtime_ms`` (the time segloc spent on each scan);
wall is the whole command: start-up, reading the map and the log, writing the estimates.
Kernels are compiled into numba's cache first (``python -m segloc_cli.runs.warmup --all``, the
global search's too), so no run but section 6's first pays for compiling. A global search
shares its work among numba's threads (one per core); every other section's time is one
process on one core.
pytest-benchmark's table gives each section's total wall time, its preparation (importing
logs, building the held-out maps, simulating) left out. Nothing is asserted but that every
command succeeded. Every command run goes to ``WORK/commands.md``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from protocol import (
    DATASETS,
    DATASETS_DIR,
    HELD_OUT_ALONE,
    PLACE_DEG,
    PLACE_M,
    SUCCESS_DEG,
    SUCCESS_M,
    HeldOutSplit,
    commands_section,
    errors_against_truth,
    evenly_spread,
    is_right,
    is_right_place,
    perturbed_guesses,
    prepare_held_out,
    prepare_raw_log,
    run_segloc,
    run_segloc_measured,
    subset_poses,
)
from tabulate import tabulate

from segloc_cli.estimates import PoseTable
from segloc_cli.io.maps import read_map, write_world
from segloc_cli.io.tables import read_estimates, read_pose_table, write_pose_table
from segloc_cli.sim import random_free_poses, random_world
from segloc_cli.world import World

SCANS_PER_LOG = 40
"""Held-out scans per shared log localized by each method in section 1."""
GLOBAL_SCANS_PER_LOG = 6
"""Held-out scans per shared log localized with ``--global`` in section 2."""
ROOM_PITCH_M = (24.0, 18.0)
"""Rooms of ``random_world`` (20 m × 14 m, alcoves up to 2 m beyond) every this many metres in
x and y: neighbours never overlap; about 220 rooms and 10,000 segments over 300 m × 300 m."""


@dataclass(frozen=True)
class GeneratedMap:
    """A map of rooms tiled over about ``width_m`` × ``height_m`` metres, the rooms from
    consecutive seeds from ``first_seed``; ``scans`` of them (each in another room) are
    simulated and localized with --global, their rooms, poses and the sensor's noise drawn
    from ``seed``."""

    width_m: float
    height_m: float
    first_seed: int
    scans: int
    seed: int

    @property
    def name(self) -> str:
        """The map's name in the tables and the folder its files go to."""
        return f"rooms {self.width_m:g} × {self.height_m:g} m"


GENERATED_MAPS = (
    GeneratedMap(130.0, 165.0, first_seed=9000, scans=6, seed=2),
    GeneratedMap(300.0, 300.0, first_seed=7000, scans=3, seed=1),
)
"""A large building's floor (130 × 165 m) and a campus (300 × 300 m), largest last."""

REPO = Path(__file__).resolve().parents[1]
WORK = REPO / "out" / "speed"
"""Where the imported logs, maps, guesses and estimates go."""
DATASETS_FOLDER = Path(os.environ.get("SEGLOC_DATASETS", DATASETS_DIR))
"""The shared real logs (``make bench DATASETS=...`` sets ``SEGLOC_DATASETS``)."""

_commands: dict[str, list[str]] = {}
"""Every command run, per dataset, written to ``WORK/commands.md`` at the end."""


def _commands_of(name: str) -> list[str]:
    """The list the commands run for dataset ``name`` are appended to."""
    return _commands.setdefault(name, [])


# --- preparation ------------------------------------------------------------------


@pytest.fixture(scope="module", autouse=True)
def _compiled_kernels():
    """Compile the kernels into numba's cache (a no-op when it is fresh); at the end, write
    every command run."""
    start = time.perf_counter()
    warmup = subprocess.run(
        [sys.executable, "-m", "segloc_cli.runs.warmup", "--all"],
        capture_output=True,
        text=True,
        check=False,
    )
    took_s = time.perf_counter() - start
    if warmup.returncode == 0:
        print(f"\nspeed: kernels compiled or found in numba's cache in {took_s:.1f} s")
    else:  # the first runs then compile what they use, and their times show it
        print(
            f"\nspeed: warm-up failed ({warmup.returncode}), times include compiling\n"
            f"{warmup.stderr}"
        )
    yield
    WORK.mkdir(parents=True, exist_ok=True)
    path = WORK / "commands.md"
    path.write_text(
        "\n".join(["# Commands of test_bench_speed.py", "", *commands_section(_commands)])
    )
    print(f"\nspeed: every command run is in {path}")


def _missing_file(name: str) -> Path | None:
    """The first of dataset ``name``'s files missing from ``DATASETS_FOLDER``, or None."""
    for file_name in DATASETS[name]:
        path = DATASETS_FOLDER / name / file_name
        if not path.is_file():
            return path
    return None


@pytest.fixture(scope="module")
def splits() -> dict[str, HeldOutSplit]:
    """Each shared log present, imported and its map built without the held-out scans."""
    prepared = {}
    for name in DATASETS:
        missing = _missing_file(name)
        if missing is not None:
            print(f"\nspeed: {name} skipped, {missing} not found")
            continue
        work = WORK / name
        work.mkdir(parents=True, exist_ok=True)
        prepared[name] = prepare_held_out(name, DATASETS_FOLDER, work, _commands_of(name))
    return prepared


def _need(splits: dict[str, HeldOutSplit]) -> None:
    """Skip the section when no shared log is present."""
    if not splits:
        pytest.skip(f"no shared real logs in {DATASETS_FOLDER}")


def _scored(est: pd.DataFrame, truth: PoseTable, within) -> tuple[int, int]:
    """How many estimate rows ``within`` (``is_right`` or ``is_right_place``) accepts, of all."""
    pos, head = errors_against_truth(est, truth)
    return int(np.sum(within(pos, head))), len(est)


def _share(hits: int, of: int) -> str:
    """Hits of a total, and as a percentage."""
    return f"{hits}/{of} ({100.0 * hits / of:.0f} %)" if of else "—"


def _median_ms(est: pd.DataFrame) -> float:
    """Median time segloc spent on a scan (ms), over the rows that have one."""
    return float(np.nanmedian(est["runtime_ms"].to_numpy(dtype=float)))


def _largest(splits: dict[str, HeldOutSplit]) -> str:
    """The shared log with the most scans."""
    return max(splits, key=lambda name: len(splits[name].reference))


def _map_area_m2(segments: np.ndarray) -> float:
    """Area (m²) of the bounding box of map segments (M, 4), metres."""
    xs, ys = segments[:, 0::2], segments[:, 1::2]
    return float((xs.max() - xs.min()) * (ys.max() - ys.min()))


# --- 1. the default method against ICP ---------------------------------------------


METHODS = {"default": (), "icp": ("--method", "icp")}
"""The localize options of each method compared in section 1."""


@dataclass(frozen=True)
class MethodRun:
    """One method on one log's scans: median ms per scan, right answers of rows, the
    command's wall time (s) and peak RSS (MiB)."""

    median_ms: float
    right: int
    rows: int
    wall_s: float
    peak_rss_mib: float


def _perturbed_scans(name: str, split: HeldOutSplit) -> tuple[Path, PoseTable]:
    """Guesses for ``SCANS_PER_LOG`` held-out scans spread over the log, drawn as in the full
    perturbation protocol, written to a CSV; its path and the scans' reference poses."""
    truth = split.held_out_reference()
    chosen = evenly_spread(len(truth), SCANS_PER_LOG)
    path = WORK / name / "speed-guesses.csv"
    _commands_of(name).append(
        f"# {path.name}: the perturbation protocol's guesses of "
        f"{int(chosen.sum())} held-out scans spread over the log"
    )
    write_pose_table(path, subset_poses(perturbed_guesses(truth), chosen))
    return path, subset_poses(truth, chosen)


def _localize_method(
    name: str, split: HeldOutSplit, guesses: Path, truth: PoseTable, method: str
) -> MethodRun:
    """Localize the guessed scans with ``method`` on one job and score the answers."""
    out = WORK / name / f"speed-{method}.csv"
    run = run_segloc_measured(
        _commands_of(name), "localize", split.log_path, "--map", split.map_path, *HELD_OUT_ALONE,
        "--initial", guesses, "--jobs", 1, *METHODS[method], "--out", out,
    )  # fmt: skip
    est = read_estimates(out)
    right, rows = _scored(est, truth, is_right)
    return MethodRun(_median_ms(est), right, rows, run.wall_s, run.peak_rss_mib)


def _compare_methods(splits: dict[str, HeldOutSplit]) -> dict[str, dict[str, MethodRun]]:
    """Every method on every shared log's perturbed scans."""
    runs = {}
    for name, split in splits.items():
        guesses, truth = _perturbed_scans(name, split)
        runs[name] = {m: _localize_method(name, split, guesses, truth, m) for m in METHODS}
    return runs


def _methods_table(runs: dict[str, dict[str, MethodRun]]) -> str:
    """Section 1's table: a row per log, the two methods side by side."""
    rows = []
    for name, by_method in runs.items():
        default, icp = by_method["default"], by_method["icp"]
        rows.append([
            name, default.rows, default.median_ms, icp.median_ms, default.median_ms / icp.median_ms,
            _share(default.right, default.rows), _share(icp.right, icp.rows),
            default.wall_s, icp.wall_s, default.peak_rss_mib, icp.peak_rss_mib,
        ])  # fmt: skip
    headers = [
        "log", "scans", "default ms/scan", "icp ms/scan", "default/icp", "default right",
        "icp right", "default wall s", "icp wall s", "default peak MiB", "icp peak MiB",
    ]  # fmt: skip
    formats = ("", "", ".1f", ".1f", ".2f", "", "", ".1f", ".1f", ".0f", ".0f")
    return tabulate(rows, headers, floatfmt=formats)


def test_speed_default_against_icp(benchmark, splits):
    _need(splits)
    runs = benchmark.pedantic(_compare_methods, args=(splits,), rounds=1, iterations=1)
    largest = _largest(splits)
    print(
        f"\nspeed 1: default against --method icp, one job; held-out scans of each log from "
        f"its reference pose plus the perturbation protocol's errors; right: within "
        f"{SUCCESS_M * 100:.0f} cm and {SUCCESS_DEG:g}°\n{_methods_table(runs)}\n"
        f"speed 5: peak RSS of the default run on the largest shared log ({largest}, "
        f"{len(splits[largest].reference)} scans): {runs[largest]['default'].peak_rss_mib:.0f} MiB"
    )


# --- 2. global search against map area ------------------------------------------------


@dataclass(frozen=True)
class GlobalRun:
    """``--global`` on one map: its area (m²) and segments, the median seconds per scan,
    right places of rows, the command's wall time (s) and peak RSS (MiB)."""

    area_m2: float
    segments: int
    median_s: float
    right: int
    rows: int
    wall_s: float
    peak_rss_mib: float


def _localize_globally(name: str, log_path: Path, map_path: Path, scans_path: Path) -> GlobalRun:
    """Localize the scans listed in ``scans_path`` (a survey CSV of their true poses, which
    the search does not use) with ``--global`` and score the answers against those poses."""
    out = scans_path.with_name("speed-global.csv")
    run = run_segloc_measured(
        _commands_of(name), "localize", log_path, "--map", map_path, "--global", *HELD_OUT_ALONE,
        "--initial", scans_path, "--jobs", 1, "--out", out,
    )  # fmt: skip
    est = read_estimates(out)
    # The poses as the command read them (the file holds headings in degrees).
    right, rows = _scored(est, read_pose_table(scans_path), is_right_place)
    segments = read_map(map_path)
    return GlobalRun(
        _map_area_m2(segments), len(segments), _median_ms(est) / 1000.0, right, rows,
        run.wall_s, run.peak_rss_mib,
    )  # fmt: skip


def _held_out_for_global(name: str, split: HeldOutSplit) -> Path:
    """A survey CSV of ``GLOBAL_SCANS_PER_LOG`` held-out scans spread over the log."""
    truth = split.held_out_reference()
    path = WORK / name / "speed-global-scans.csv"
    _commands_of(name).append(
        f"# {path.name}: reference poses of held-out scans spread over the log"
    )
    write_pose_table(path, subset_poses(truth, evenly_spread(len(truth), GLOBAL_SCANS_PER_LOG)))
    return path


def _tiled_rooms(spec: GeneratedMap) -> tuple[World, list[World]]:
    """Rooms of ``random_world`` (each from its own seed) every ``ROOM_PITCH_M`` over about
    ``spec``'s size, world frame in metres; the whole map and each room in it."""
    columns = int(np.ceil(spec.width_m / ROOM_PITCH_M[0]))
    rows = int(np.ceil(spec.height_m / ROOM_PITCH_M[1]))
    rooms = []
    for k in range(columns * rows):
        room = random_world(np.random.default_rng(spec.first_seed + k))
        shift = np.array([ROOM_PITCH_M[0] * (k % columns), ROOM_PITCH_M[1] * (k // columns)])
        rooms.append(World(room.segments + np.tile(shift, 2), room.materials, f"room {k}"))
    segments = np.concatenate([room.segments for room in rooms])
    materials = np.concatenate([room.materials for room in rooms])
    return World(segments, materials, "tiled rooms"), rooms


def _poses_in_rooms(rooms: list[World], count: int, rng: np.random.Generator) -> np.ndarray:
    """One free pose (x m, y m, θ rad) in each of ``count`` rooms drawn without repeats."""
    chosen = rng.choice(len(rooms), size=count, replace=False)
    return np.vstack([random_free_poses(rooms[k], 1, rng) for k in chosen])


def _generated_map(spec: GeneratedMap) -> tuple[Path, Path, Path]:
    """``spec``'s world file, and a log of scans simulated in it with their true poses:
    (world, log, survey)."""
    work = WORK / spec.name.replace(" × ", "x").replace(" ", "-")
    work.mkdir(parents=True, exist_ok=True)
    world, rooms = _tiled_rooms(spec)
    world_path, poses_path = work / "world.json", work / "poses.csv"
    write_world(world_path, world)
    poses = _poses_in_rooms(rooms, spec.scans, np.random.default_rng(spec.seed))
    count = len(poses)
    write_pose_table(
        poses_path, PoseTable(np.arange(1, count + 1), np.arange(count, dtype=float), poses)
    )
    commands = _commands_of(spec.name)
    commands.append(
        f"# world.json: {len(rooms)} rooms of random_world (seeds {spec.first_seed}–"
        f"{spec.first_seed + len(rooms) - 1}) every {ROOM_PITCH_M[0]:g} × "
        f"{ROOM_PITCH_M[1]:g} m; poses.csv: a free pose in each of {count} of them "
        f"(seed {spec.seed})"
    )
    run_segloc(
        commands, "simulate", world_path, "--poses", poses_path, "--seed", spec.seed,
        "--out", work / "sim",
    )  # fmt: skip
    return world_path, work / "sim" / "log.mcap", work / "sim" / "survey.csv"


@pytest.fixture(scope="module")
def generated_maps() -> dict[str, tuple[Path, Path, Path]]:
    """Each of ``GENERATED_MAPS`` by name: (world, log, survey)."""
    return {spec.name: _generated_map(spec) for spec in GENERATED_MAPS}


def _global_runs(
    splits: dict[str, HeldOutSplit], generated_maps: dict[str, tuple[Path, Path, Path]]
) -> dict[str, GlobalRun]:
    """``--global`` on each shared log's held-out scans, then on each generated map."""
    runs = {}
    for name, split in splits.items():
        scans = _held_out_for_global(name, split)
        runs[name] = _localize_globally(name, split.log_path, split.map_path, scans)
    for name, (world_path, log_path, survey_path) in generated_maps.items():
        runs[name] = _localize_globally(name, log_path, world_path, survey_path)
    return runs


def _global_table(runs: dict[str, GlobalRun]) -> str:
    """Section 2's table: a row per map."""
    rows = [
        [name, r.area_m2, r.segments, r.rows, 1000.0 * r.median_s, _share(r.right, r.rows),
         r.wall_s, r.peak_rss_mib]
        for name, r in runs.items()
    ]  # fmt: skip
    headers = ["map", "area m²", "segments", "scans", "ms/scan", "right place", "wall s",
               "peak MiB"]  # fmt: skip
    return tabulate(rows, headers, floatfmt=("", ".0f", "", "", ".0f", "", ".1f", ".0f"))


def test_speed_global_against_map_area(benchmark, splits, generated_maps):
    runs = benchmark.pedantic(_global_runs, args=(splits, generated_maps), rounds=1, iterations=1)
    largest = GENERATED_MAPS[-1].name
    print(
        f"\nspeed 2: --global (no initial pose), one job, against map area (bounding box); "
        f"right place: within {PLACE_M * 100:.0f} cm and {PLACE_DEG:g}°\n{_global_table(runs)}\n"
        f"speed 5: peak RSS of --global on the largest map ({largest}, "
        f"{runs[largest].segments} segments): {runs[largest].peak_rss_mib:.0f} MiB"
    )


# --- 3. tracking ------------------------------------------------------------------


@dataclass(frozen=True)
class TrackRun:
    """``--track`` along one raw log: estimate rows, their statuses, the median ms per scan,
    the command's wall time (s) and peak RSS (MiB)."""

    rows: int
    statuses: dict[str, int]
    median_ms: float
    wall_s: float
    peak_rss_mib: float


def _track(name: str, split: HeldOutSplit, log_path: Path, first_pose: Path) -> TrackRun:
    """Track the raw log at ``log_path`` in the held-out map from ``first_pose``."""
    out = WORK / name / "speed-track.csv"
    run = run_segloc_measured(
        _commands_of(name), "localize", log_path, "--map", split.map_path, "--track",
        "--initial", first_pose, "--out", out,
    )  # fmt: skip
    est = read_estimates(out)
    statuses = est["status"].value_counts().to_dict()
    return TrackRun(len(est), statuses, _median_ms(est), run.wall_s, run.peak_rss_mib)


def test_speed_tracking(benchmark, splits):
    _need(splits)
    raw_logs = {
        name: prepare_raw_log(name, DATASETS_FOLDER, WORK / name, _commands_of(name))
        for name in splits
    }

    def track_all() -> dict[str, TrackRun]:
        return {
            name: _track(name, split, raw_logs[name].log_path, raw_logs[name].first_pose_path)
            for name, split in splits.items()
        }

    runs = benchmark.pedantic(track_all, rounds=1, iterations=1)
    rows = [
        [name, r.rows, r.wall_s, r.rows / r.wall_s, r.median_ms,
         ", ".join(f"{n} {s}" for s, n in sorted(r.statuses.items())), r.peak_rss_mib]
        for name, r in runs.items()
    ]  # fmt: skip
    headers = ["raw log", "scans", "wall s", "scans/s", "ms/scan", "statuses", "peak MiB"]
    print(
        "\nspeed 3: --track along each raw log in its held-out map from (0, 0, 0); scans/s: "
        f"scans over the command's wall time\n{tabulate(rows, headers, floatfmt='.1f')}"
    )


# --- 4. map building ----------------------------------------------------------------


def _build_map(name: str, split: HeldOutSplit) -> tuple[int, float]:
    """Build the map of every scan of the corrected log at its reference pose: the scans
    used and the command's wall time (s)."""
    work = WORK / name
    reference_path = work / "speed-reference.csv"
    write_pose_table(reference_path, split.reference)
    run = run_segloc_measured(
        _commands_of(name), "map", "build", split.log_path, "--survey", reference_path,
        "--out", work / "speed-map.json",
    )  # fmt: skip
    return len(split.reference), run.wall_s


def test_speed_map_build(benchmark, splits):
    _need(splits)

    def build_all() -> dict[str, tuple[int, float]]:
        return {name: _build_map(name, split) for name, split in splits.items()}

    runs = benchmark.pedantic(build_all, rounds=1, iterations=1)
    rows = [
        [name, scans, wall_s, 1000.0 * wall_s / scans] for name, (scans, wall_s) in runs.items()
    ]
    headers = ["corrected log", "scans", "wall s", "s per 1,000 scans"]
    print(
        "\nspeed 4: map build from every scan of each corrected log at its reference pose\n"
        + tabulate(rows, headers, floatfmt=".1f")
    )


# --- 6. the first run ---------------------------------------------------------------

HALL = REPO / "datasets" / "hall"
"""The shipped hall, which ``make demo`` localizes."""


def _first_runs() -> tuple[float, float]:
    """The wall time (s) of ``segloc localize`` of the hall on an empty numba cache, then of
    the same command again, the hall's map built beforehand with the kernels cached."""
    commands, work = _commands_of("hall"), WORK / "hall"
    map_path, out = work / "map.json", work / "first-run.csv"
    work.mkdir(parents=True, exist_ok=True)
    run_segloc(
        commands, "map", "build", HALL / "mapping" / "log.mcap",
        "--survey", HALL / "mapping" / "survey.csv", "--out", map_path,
    )  # fmt: skip
    with tempfile.TemporaryDirectory() as cache:
        commands.append("# the next two with NUMBA_CACHE_DIR set to a new, empty folder")
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        args = ("localize", HALL / "log.mcap", "--map", map_path, "--out", out)
        first = run_segloc_measured(commands, *args, env=env)
        second = run_segloc_measured(commands, *args, env=env)
    return first.wall_s, second.wall_s


def test_speed_first_run(benchmark):
    first_s, second_s = benchmark.pedantic(_first_runs, rounds=1, iterations=1)
    rows = [["empty cache (compiles)", first_s], ["kernels cached", second_s]]
    print(
        "\nspeed 6: segloc localize of the hall's 10 scans with the defaults, wall s\n"
        + tabulate(rows, ["run", "wall s"], floatfmt=".1f")
    )
