"""Compile segloc's numba kernels ahead of the first run: ``python -m segloc_cli.runs.warmup``.

The kernels (``@njit(cache=True)``) are compiled on first use and kept in numba's
on-disk cache beside their modules (``segloc_cli/__pycache__/*.nbi``, ``*.nbc``).
Compiling them all takes 10–20 s, which a newcomer's first
``segloc localize`` would otherwise spend. ``make setup`` runs this module as its
last step: it simulates a small room, builds its map and localizes a few of its
scans in every mode of the command line, through the functions the commands
call, so each kernel on those paths is compiled with the argument types a real
run gives it, whatever its name or module.

Run here: extraction, ``map build`` (fusion, and the free-space carving of
``--seen-through drop``), and ``localize`` guided (stage 1,
stage 2, the hypothesis search, refinement, the verdict), ``--no-refine``,
``--global``, ``--track`` (its failed matches retried by the wider search), and
``--method icp|correlative`` where their packages are installed (their own
libraries come compiled; their verdict is segloc's). Not run, as they compile
nothing of their own: ``evaluate`` and ``--jobs`` (its workers are forked from
a parent that has compiled already).

``--times [N]`` compiles in one process and lists the N kernels (10 by default) that took
longest; ``--late-stages`` is what a first run's second process does (``jit.py``).

Numba drops a kernel's cache when its module's source file changes (for a kernel
that calls others, only its own file counts: see ``kernels.py``). ``make setup``
runs this warm-up again only when pyproject.toml changes; otherwise an edited
module's kernels are compiled on their first use and cached from then on.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numba.core.dispatcher import Dispatcher

from segloc_cli.config import Config
from segloc_cli.errors import SeglocError
from segloc_cli.estimates import PoseTable
from segloc_cli.geometry import Pose2
from segloc_cli.io.log import Log
from segloc_cli.jit import loaded_kernels
from segloc_cli.method.refine import nearest_segments
from segloc_cli.method.search import HypothesisSearch
from segloc_cli.runs import pipeline
from segloc_cli.sim import (
    SensorModel,
    initial_guesses,
    paper_initial_errors,
    random_free_poses,
    random_world,
    simulate_scan,
)

ROOM_M = (8.0, 6.0)
"""Size (m) of the simulated room: small, so that the global search is quick."""
SCANS = 3
"""Scans of the simulated log: the third follows two on the track."""
SENSOR = SensorModel(readings=256)
"""Fewer beams than the default scanner, as the kernels' types do not depend on how many."""
SEED = 1
SCAN_PERIOD_S = 1.0
PLACEHOLDER_PATH = Path("warmup.mcap")
"""The name the in-memory log and survey go by (only messages about bad input would show it)."""

LOCALIZE_RUNS: dict[str, tuple[str, dict[str, Any]]] = {
    "guided": ("guided", {}),
    "--no-refine": ("guided", {"no-refine": True}),
    "--global": ("global", {}),
    "--track": ("track", {}),
    "--method icp": ("guided", {"method": "icp"}),
    "--method correlative": ("guided", {"method": "correlative"}),
}
"""The ``localize`` runs, by their options: (``pipeline.RUN_MODES`` entry, settings as
``Config.from_values`` takes them)."""


def simulated_run(seed: int = SEED) -> tuple[Log, PoseTable]:
    """A log of ``SCANS`` scans of a random room, with /odom guesses off by the paper's
    initial errors (world frame, metres and radians), and the true poses as its survey."""
    rng = np.random.default_rng(seed)
    world = random_world(rng, ROOM_M)
    truth = random_free_poses(world, SCANS, rng)
    times_s = SCAN_PERIOD_S * np.arange(SCANS, dtype=float)
    scans = [
        simulate_scan(world, Pose2(*pose), SENSOR, rng, float(t))
        for t, pose in zip(times_s, truth, strict=True)
    ]
    guesses = initial_guesses(truth, paper_initial_errors(SCANS))
    log = Log(
        scans=scans,
        original_times_s=times_s,
        odom_times_s=times_s,
        odom_poses=guesses,
        sensor={},
    )
    survey = PoseTable(pose_id=np.arange(1, SCANS + 1), time_s=times_s, poses=truth)
    return log, survey


def warm_up() -> list[str]:
    """Build the simulated room's map (also with ``--seen-through drop``) and localize its
    log in each of ``LOCALIZE_RUNS``, at default settings otherwise; returns the runs left
    out (a peer not installed).

    The map and estimates are thrown away: only the compiling counts.
    """
    log, survey = simulated_run()
    built = pipeline.build_map(log, PLACEHOLDER_PATH, survey, PLACEHOLDER_PATH, Config())
    # What ``map build --seen-through drop`` adds: the scans' beams against the map.
    carving = Config.from_values({"seen-through": "drop"})
    pipeline.build_map(log, PLACEHOLDER_PATH, survey, PLACEHOLDER_PATH, carving)
    left_out = []
    for option, (mode, settings) in LOCALIZE_RUNS.items():
        config = Config.from_values(settings)
        try:
            localizer = pipeline.localizer_for(built.segments, config, mode)
        except SeglocError:  # a peer's package is missing: the command would refuse it too
            left_out.append(option)
            continue
        run = pipeline.localize_log(log, PLACEHOLDER_PATH, localizer, mode, None, config)
        _drain(run.rows)
    # What a library call without a grid of the map runs (the commands always pass one).
    nearest_segments(log.scans[0].points(), built.segments)
    # A global search's later batches, which a room this small does not reach: one top
    # square a batch.
    search = HypothesisSearch(built.segments)
    centre, half = search.extent()
    headings = np.deg2rad(np.arange(0.0, 360.0, 10.0))
    search.search(log.scans[0].points(), headings, centre, half, reach_m=30.0, first_batch=1)
    return left_out


def compile_late_stages(seed: int = SEED) -> None:
    """Compile the kernels of the hypothesis search and of refinement first, then the rest
    of a guided localize, on a simulated room whose walls are its own map: what a first run
    on an empty cache has a second process do (``jit.watch_compiles``) while it extracts
    segments and runs the two stages. No extraction is needed: the walls, placed in the
    robot's frame, are the local map."""
    from segloc_cli.geometry import transform_segments
    from segloc_cli.jit import say_ahead_ready
    from segloc_cli.method.refine import refine_pose

    rng = np.random.default_rng(seed)
    world = random_world(rng, ROOM_M)
    truth = Pose2(*random_free_poses(world, 1, rng)[0])
    points = simulate_scan(world, truth, SENSOR, rng, 0.0).points()
    config = Config()
    localizer = pipeline.localizer_for(world.segments, config, "guided")
    guess = Pose2(truth.x + 0.3, truth.y - 0.2, truth.theta + 0.1)
    if localizer.prepared.search is not None:
        peaks = np.array([guess.theta])
        localizer.prepared.search.around(points, guess, 20.0, peaks, guess)
    near = localizer.prepared.near_index
    refine_pose(points, localizer.segments_world, guess, config.localize.refine, index=near)
    say_ahead_ready()
    # The rest, whatever this run has not compiled yet (stage 1, stage 2, the verdict).
    local_map = transform_segments(world.segments, truth.inverse())
    localizer.localize(local_map, guess, points)


def _drain(rows: Iterator) -> None:
    """Make every row of a lazily localized log."""
    for _ in rows:
        pass


def compile_times(kernels: list[Dispatcher]) -> list[tuple[float, str]]:
    """(seconds, kernel) of each specialization this process compiled, longest first: the
    time in numba's compiler, the kernels it calls that were not compiled yet included."""
    times = []
    for kernel in kernels:
        for signature in kernel.signatures:
            metadata = kernel.get_metadata(signature) or {}  # none when loaded from the cache
            timers = metadata.get("timers", {})
            if "compiler_lock" in timers:
                name = f"{kernel.py_func.__module__}.{kernel.py_func.__qualname__}"
                times.append((float(timers["compiler_lock"]), name))
    return sorted(times, reverse=True)


def main(show_times: int = 0) -> None:
    """Warm the cache up and say in one line what was done; with ``show_times``, list that
    many kernels this process compiled, longest first."""
    from segloc_cli.jit import started_ahead, watching_compiles

    t0 = time.perf_counter()
    # On two cores, as a first run; alone when the compile times are asked for, so that
    # each kernel's time is its own and not shared with a second process.
    with watching_compiles(ahead=not show_times, notice=lambda partly: ""):
        left_out = warm_up()
    ran = [option for option in LOCALIZE_RUNS if option not in left_out]
    kernels = loaded_kernels()
    compiled = sum(bool(kernel.stats.cache_misses) for kernel in kernels)
    done = f"{len(kernels)} numba kernels in the cache, {compiled} compiled by this process"
    if not compiled:
        done = "all were cached"
    elif started_ahead():
        done += " and the search's and refinement's by a second one"
    missing = f" (not installed: {', '.join(left_out)})" if left_out else ""
    print(
        f"segloc warm-up: map build and localize ({', '.join(ran)}) run on a simulated room "
        f"in {time.perf_counter() - t0:.1f} s{missing}; {done}"
    )
    if show_times:
        for seconds, name in compile_times(kernels)[:show_times]:
            print(f"  {seconds:5.1f} s  {name}")


if __name__ == "__main__":
    if sys.argv[1:] == ["--late-stages"]:
        compile_late_stages()
    elif sys.argv[1:2] == ["--times"]:
        main(show_times=int(sys.argv[2]) if len(sys.argv) > 2 else 10)
    else:
        main()
