"""Time per pose, measured with pytest-benchmark (`make bench`).

Scenarios:
- paper scale: the paper timed a global map of 52 segments and local maps of
  19–31 segments with K = 6. A generated room is used whose segment count is
  within 48–56 (chosen by size only), and scans whose local maps have 19–31
  segments; the paper's schedule (K = 6, no re-centring) and the defaults.
- large maps: about 1,000 and 5,000 segments, a grid of generated rooms side
  by side, localizing in one of them with the default settings.
- throughput: a batch of scans of the hall localized with the defaults
  (refinement included) on one process and on two (`--jobs 2`); the ratio
  of the two is printed.
- refinement: the defaults followed by the least-squares fit of the scan's
  points (the two stages alone are what the other scenarios time).

Each benchmark call localizes one pose (cycling through the prepared ones), so
the reported median is the time per pose. Extraction is timed on its own.
The accuracy of the poses timed is printed too, misses included.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from protocol import pose_errors

from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.io.maps import read_map, read_world
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.localize import LocalizeParams, Localizer
from segloc_cli.runs.parallel import localize_scans_parallel
from segloc_cli.sim import (
    SensorModel,
    random_free_poses,
    random_world,
    simulate_scan,
    uniform_initial_errors,
)
from segloc_cli.world import World

HALL = Path(__file__).resolve().parents[1] / "datasets" / "hall"
PAPER_MAP_SEGMENTS = (48, 56)
PAPER_LOCAL_SEGMENTS = (19, 31)
POSES = 40


def _paper_scale_world() -> World:
    for seed in itertools.count(100):
        world = random_world(np.random.default_rng(seed))
        if PAPER_MAP_SEGMENTS[0] <= world.segments.shape[0] <= PAPER_MAP_SEGMENTS[1]:
            return world
    raise AssertionError("unreachable")


def _large_world(target_segments: int = 1000) -> World:
    """Generated rooms on a grid, 25 m apart, until the map holds ~target segments."""
    parts, materials = [], []
    for k in itertools.count():
        room = random_world(np.random.default_rng(500 + k))
        shift = np.array([25.0 * (k % 5), 20.0 * (k // 5)] * 2)
        parts.append(room.segments + shift)
        materials.extend(room.materials)
        if sum(p.shape[0] for p in parts) >= target_segments:
            break
    return World(np.concatenate(parts), np.array(materials), "rooms")


def _cases(world: World, n: int, seed: int, local_range=None, region=None):
    """(local map, points, initial guess, truth); initial errors ±1.5 m, ±20°."""
    rng = np.random.default_rng(seed)
    room = world if region is None else region
    cases = []
    while len(cases) < n:
        truth = Pose2(*random_free_poses(room, 1, rng)[0])
        scan = simulate_scan(world, truth, SensorModel(), rng, 0.0)
        local = extract_segments(scan)
        if local_range and not local_range[0] <= local.shape[0] <= local_range[1]:
            continue
        err = uniform_initial_errors(1, 1.5, 20.0, rng)[0]
        guess = Pose2(truth.x - err[0], truth.y - err[1], float(wrap_angle(truth.theta - err[2])))
        cases.append((local, scan.points(), guess, truth))
    return cases


def _run(benchmark, localizer: Localizer, cases, label: str, refine: bool = False) -> None:
    """Time one pose per call: the two stages, and the fit of the points when ``refine``."""
    cycle = itertools.cycle(cases)
    benchmark.extra_info.update(
        map_segments=int(localizer.segments_world.shape[0]),
        local_segments=f"{min(c[0].shape[0] for c in cases)}-{max(c[0].shape[0] for c in cases)}",
    )

    def one_pose():
        local, points, guess, _ = next(cycle)
        return localizer.localize(local, guess, points if refine else None)

    benchmark(one_pose)
    errors = []
    for local, points, guess, truth in cases:
        est = localizer.localize(local, guess, points if refine else None)
        errors.append(
            pose_errors(est.pose.x - truth.x, est.pose.y - truth.y, est.pose.theta - truth.theta)
        )
    e = np.nan_to_num(np.array(errors), nan=np.inf)
    hits = (e[:, 0] < 0.02) & (e[:, 1] < 0.3)
    print(
        f"\n{label}: map {localizer.segments_world.shape[0]} segments, local "
        f"{benchmark.extra_info['local_segments']}; {hits.sum()}/{len(cases)} poses within "
        f"2 cm and 0.3° from ±1.5 m/±20° starts; median error {np.median(e[:, 0]) * 100:.2f} cm "
        f"{np.median(e[:, 1]):.3f}°; worst {e[:, 0].max() * 100:.1f} cm {e[:, 1].max():.2f}°"
    )


@pytest.fixture(scope="module")
def paper_world() -> World:
    return _paper_scale_world()


@pytest.fixture(scope="module")
def paper_cases(paper_world):
    return _cases(paper_world, POSES, seed=1, local_range=PAPER_LOCAL_SEGMENTS)


def test_localize_paper_scale_paper_schedule_k6(benchmark, paper_world, paper_cases):
    params = LocalizeParams(iterations=6, recentres=0)
    _run(benchmark, Localizer.on_map(paper_world.segments, params), paper_cases, "paper scale, K=6")


def test_localize_paper_scale_defaults(benchmark, paper_world, paper_cases):
    _run(benchmark, Localizer.on_map(paper_world.segments), paper_cases, "paper scale, defaults")


def test_localize_paper_scale_defaults_refined(benchmark, paper_world, paper_cases):
    localizer = Localizer.on_map(paper_world.segments)
    _run(benchmark, localizer, paper_cases, "paper scale, defaults + refinement", refine=True)


@pytest.mark.parametrize("segments", [1000, 5000])
def test_localize_large_map(benchmark, segments):
    world = _large_world(segments)
    first_room = random_world(np.random.default_rng(500))
    cases = _cases(world, POSES, seed=2, region=first_room)
    _run(benchmark, Localizer.on_map(world.segments), cases, f"{segments}-segment map, defaults")


BATCH_SCANS = 48
_batch_seconds: dict[int, float] = {}


@pytest.fixture(scope="module")
def hall_batch():
    """Scans of the hall at random free poses, each with a ±1.5 m / ±20° guess."""
    world = read_world(HALL / "world.json")
    rng = np.random.default_rng(4)
    scans, guesses = [], []
    for k, pose in enumerate(random_free_poses(world, BATCH_SCANS, rng)):
        truth = Pose2(*pose)
        scans.append(simulate_scan(world, truth, SensorModel(), rng, float(k)))
        err = uniform_initial_errors(1, 1.5, 20.0, rng)[0]
        guesses.append(Pose2(truth.x - err[0], truth.y - err[1], truth.theta - err[2]))
    return scans, guesses, read_map(HALL / "map.json")


@pytest.mark.parametrize("jobs", [1, 2])
def test_throughput_jobs(benchmark, hall_batch, jobs):
    """Wall time of a batch; the second run prints the speed-up of two processes over one."""
    scans, guesses, segments = hall_batch
    ids = list(range(len(scans)))
    localizer = Localizer.on_map(segments)

    def batch():
        return list(localize_scans_parallel(scans, guesses, ids, localizer, jobs))

    benchmark.pedantic(batch, rounds=3, warmup_rounds=1)
    _batch_seconds[jobs] = benchmark.stats.stats.median
    print(
        f"\nbatch of {len(scans)} hall scans, defaults, --jobs {jobs}: "
        f"{len(scans) / _batch_seconds[jobs]:.1f} scans/s"
    )
    if jobs == 2 and 1 in _batch_seconds:
        print(f"--jobs 2 throughput: {_batch_seconds[1] / _batch_seconds[2]:.2f}x --jobs 1")


def test_extract_segments_1024_readings(benchmark, paper_world):
    rng = np.random.default_rng(3)
    poses = random_free_poses(paper_world, 10, rng)
    scans = itertools.cycle(
        [simulate_scan(paper_world, Pose2(*p), SensorModel(), rng, 0.0) for p in poses]
    )
    benchmark(lambda: extract_segments(next(scans)))
