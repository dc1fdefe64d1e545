"""Compile segloc's numba kernels ahead of the first run: ``python -m segloc_cli.runs.warmup``.

The kernels (``@njit(cache=True)``) are compiled on first use and kept in numba's
on-disk cache beside their modules (``segloc_cli/__pycache__/*.nbi``, ``*.nbc``).
``make setup`` (and ``make demo``) runs this module once segloc is installed: it simulates
a small room, builds its map and localizes its scans at the default settings, through the
functions the commands call, so that each kernel of ``make demo`` and of a first default
``segloc localize`` (extraction, stage 1, stage 2, the hypothesis search, refinement, the
verdict) is compiled with the argument types a real run gives it, whatever its name or
module: ``FIRST_RUN_KERNELS`` kernels in about ``FIRST_RUN_S`` s on two cores, a second
process compiling the search's and refinement's (``jit.watching_compiles``). It says so
when it starts compiling, shows how many kernels are compiled every few seconds, and ends
with a line on what it did (``warmup_lines``). ``--no-refine``, ``--track`` and the peers
(``--method icp|correlative``: their own libraries come compiled; their verdict is
segloc's) use no other kernel.

``--all`` runs every other path too: ``map build --seen-through drop`` (the free-space
carving), ``localize --global`` (its parallel bounds, and the later batches a small room
does not reach), a search without a bound pyramid (``localize.search.max_depth`` 0),
``--track``, the peers where their packages are installed, and a library
call without a grid of the map. ``make kernels`` runs it before the tests and benchmarks,
so that their processes load every kernel instead of each compiling its own. Without it,
a first ``--global`` or ``--seen-through drop`` compiles its kernels and says so
(``jit.LaterKernels``). Not run, as they compile nothing of their own: ``evaluate`` and
``--jobs`` (its workers are forked from a parent that has compiled already).

``--times [N]`` compiles in one process and lists the N kernels (10 by default) that took
longest; ``--late-stages`` is what a first run's second process does (``jit.py``);
``--record FOLDER`` keeps the run's record there (``warmup_record``: ``make setup`` keeps
one for the suite's warm-up tests).

Numba drops a kernel's cache when its module's source file changes (for a kernel
that calls others, only its own file counts: see ``kernels.py``). ``make setup``
runs this warm-up again only when pyproject.toml changes; otherwise an edited
module's kernels are compiled on their first use and cached from then on.
"""

from __future__ import annotations

import argparse
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
from segloc_cli.jit import kernel_name, loaded_kernels
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

FIRST_RUN = "map build and a default localize"
"""What the warm-up runs unless asked for every path, in words."""
FIRST_RUN_KERNELS = 108
"""The kernels map build and a default localize use: what the warm-up compiles
(tests/test_warmup.py checks the count)."""
FIRST_RUN_S = 33
"""About how long (s) the warm-up takes on an empty cache, on two cores (31–35 s)."""
ALL_S = 50
"""About how long (s) ``--all`` takes on an empty cache, on two cores (48 s; 18 s after the
warm-up, 4 s when every kernel is cached)."""

LATER_RUNS: dict[str, tuple[str, dict[str, Any]]] = {
    "--global": ("global", {}),
    "--track": ("track", {}),
    "--method icp": ("guided", {"method": "icp"}),
    "--method correlative": ("guided", {"method": "correlative"}),
}
"""The ``localize`` runs of ``--all`` beyond the default one, by their options:
(``pipeline.RUN_MODES`` entry, settings as ``Config.from_values`` takes them)."""


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


def warm_up(every_path: bool = False) -> list[str]:
    """Build the simulated room's map and localize its log with ``--no-refine``, then at the
    default settings; with ``every_path``, also build it with ``--seen-through drop`` and
    localize it in each of ``LATER_RUNS``. Returns the options of ``LATER_RUNS`` run, those
    left out (a peer not installed) marked so.

    The map and estimates are thrown away: only the compiling counts.
    """
    log, survey = simulated_run()
    built = pipeline.build_map(log, PLACEHOLDER_PATH, survey, PLACEHOLDER_PATH, Config())
    # The two stages and the check of their answer by the points first, as ``--no-refine``
    # runs them: on an empty cache, while a second process compiles the search's and
    # refinement's kernels (``compile_late_stages``), which the default run then loads.
    _localize(log, built.segments, "guided", Config.from_values({"no-refine": True}))
    _localize(log, built.segments, "guided", Config())
    if not every_path:
        return []
    ran = []
    for option, (mode, settings) in LATER_RUNS.items():
        try:
            _localize(log, built.segments, mode, Config.from_values(settings))
        except SeglocError:  # a peer's package is missing: the command would refuse it too
            option += " (not installed)"
        ran.append(option)
    _library_paths(log, built.segments)
    # Last: the second process of ``--all`` compiles it once done with its own kernels, while
    # this one compiles those above.
    _carve(log, survey)
    return ran


def _carve(log: Log, survey: PoseTable) -> None:
    """What ``map build --seen-through drop`` adds: the scans' beams against the map."""
    carving = Config.from_values({"seen-through": "drop"})
    pipeline.build_map(log, PLACEHOLDER_PATH, survey, PLACEHOLDER_PATH, carving)


def _localize(log: Log, segments: np.ndarray, mode: str, config: Config) -> None:
    """Localize every scan of ``log`` on the map ``segments`` (M, 4), as ``localize`` in
    ``mode`` does with ``config``."""
    localizer = pipeline.localizer_for(segments, config, mode)
    run = pipeline.localize_log(log, PLACEHOLDER_PATH, localizer, mode, None, config)
    _drain(run.rows)


def _library_paths(log: Log, segments: np.ndarray) -> None:
    """What no command of a small room reaches: a library call without a grid of the map
    (the commands always pass one), and a global search's later batches, one top square a
    batch."""
    from segloc_cli.method.refine import nearest_segments
    from segloc_cli.method.search import HypothesisSearch

    nearest_segments(log.scans[0].points(), segments)
    search = HypothesisSearch(segments)
    centre, half = search.extent()
    headings = np.deg2rad(np.arange(0.0, 360.0, 10.0))
    search.search(log.scans[0].points(), headings, centre, half, reach_m=30.0, first_batch=1)


def compile_late_stages(seed: int = SEED, every_path: bool = False) -> None:
    """Compile the kernels of the hypothesis search and of refinement first, then the rest
    of a guided localize, on a simulated room whose walls are its own map: what a first run
    on an empty cache has a second process do (``jit.watching_compiles``) while it extracts
    segments and runs the two stages. No extraction is needed: the walls, placed in the
    robot's frame, are the local map. With ``every_path`` (the second process of ``--all``),
    then the free-space carving of ``map build --seen-through drop`` and a search without a
    bound pyramid, while the first compiles the global search. Each kernel compiled is named
    on standard output (``jit.reporting_compiles``)."""
    from segloc_cli.geometry import transform_segments
    from segloc_cli.jit import reporting_compiles, say_ahead_ready
    from segloc_cli.method.refine import refine_pose

    with reporting_compiles():
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
        if every_path:
            _carve(*simulated_run(seed))
            _no_pyramid_search(world.segments, points, guess)


def _no_pyramid_search(segments: np.ndarray, points: np.ndarray, guess: Pose2) -> None:
    """What a search without a bound pyramid (``localize.search.max_depth`` 0, its bounds
    exact sums) compiles, on one thread and on several: a few headings over a small square
    around ``guess`` (world frame), of the map ``segments`` (M, 4) and ``points`` (N, 2)."""
    from segloc_cli.config import SearchParams
    from segloc_cli.method.search import HypothesisSearch

    search = HypothesisSearch(segments, SearchParams(max_depth=0))
    headings = guess.theta + np.deg2rad(np.arange(-2.0, 3.0, 1.0))
    for threads in (False, True):
        search.search(points, headings, np.array([guess.x, guess.y]), 0.2, 30.0, threads=threads)


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
                times.append((float(timers["compiler_lock"]), kernel_name(kernel)))
    return sorted(times, reverse=True)


def main(every_path: bool = False, show_times: int = 0, record: Path | None = None) -> None:
    """Warm the cache up, with ``every_path`` on every path of the command line: say when it
    starts compiling (how many kernels, about how long), count the kernels compiled as it
    goes, and end with one line on what was done (``warmup_lines``); with ``show_times``,
    compile in this process alone, quietly, and list that many kernels it compiled, longest
    first; with ``record``, keep the run's record in that folder (``warmup_record``)."""
    from segloc_cli.jit import finish_ahead, start_ahead, watching_compiles
    from segloc_cli.runs.warmup_lines import CompileCount, closing_line

    t0 = time.perf_counter()
    if every_path:
        count = CompileCount("every command and option", _every_kernel(), ALL_S, bool(show_times))
    else:
        count = CompileCount(FIRST_RUN, FIRST_RUN_KERNELS, FIRST_RUN_S, bool(show_times))
    # On two cores, as a first run; alone when the compile times are asked for, so that
    # each kernel's time is its own and not shared with a second process. Every path has
    # kernels of its own for the second process even where a first run's are cached.
    if every_path and not show_times:
        start_ahead("--all")
    with watching_compiles(ahead=not show_times, notice=count.notice), count:
        ran = warm_up(every_path)
        finish_ahead()
    runs = FIRST_RUN
    if every_path:
        options = ", ".join(["guided", "--no-refine", *ran])
        runs = f"map build (and --seen-through drop) and localize ({options})"
    closing = closing_line(runs, time.perf_counter() - t0, count.partly)
    print(closing)
    if record is not None:
        from segloc_cli.runs.warmup_record import write_record

        write_record(record, count.said, closing, count.partly)
    if show_times:
        kernels = [kernel for kernel in loaded_kernels() if kernel.overloads]
        for seconds, name in compile_times(kernels)[:show_times]:
            print(f"  {seconds:5.1f} s  {name}")


def _every_kernel() -> int:
    """How many kernels segloc defines: those of every module of ``segloc_cli.method``."""
    import importlib
    import pkgutil

    import segloc_cli.method

    for module in pkgutil.iter_modules(segloc_cli.method.__path__):
        importlib.import_module(f"segloc_cli.method.{module.name}")
    return len(loaded_kernels())


def _arguments(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog=f"python -m {__name__}", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--all", action="store_true", help="every path, not the first run's")
    parser.add_argument("--times", nargs="?", type=int, const=10, default=0, metavar="N")
    parser.add_argument("--late-stages", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument(
        "--record", type=Path, metavar="FOLDER", help="keep what this run compiled and said there"
    )
    return parser.parse_args(argv)


if __name__ == "__main__":
    arguments = _arguments(sys.argv[1:])
    if arguments.late_stages:
        compile_late_stages(every_path=arguments.all)
    else:
        main(every_path=arguments.all, show_times=arguments.times, record=arguments.record)
