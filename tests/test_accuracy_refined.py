"""Millimetre accuracy of the default pipeline from ±2 m / ±20° starts, noise-free scans.

Setting: 6 generated rooms (world seeds 40000–40005, about 20 m × 14 m), 10
free poses each, 60 trials. Each room's own segments are the map. The initial
guess is the true pose minus an error uniform in ±2 m per axis and ±20° of
heading. The scan is a 360° sweep of 1024 exact ranges (no noise, no
quantisation, no dropouts, no people; glass never returns). The defaults run:
stage 1, stage 2 and the hypothesis search of the ±2 m square, the
least-squares fit of the scan's points, the confidence verdict.

Every trial must end within 5 mm of position and 0.05° of heading with status
``ok``. benchmarks/test_bench_accuracy.py measures the same on 500 trials in
other rooms, and with realistic noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.localize import Localizer
from segloc_cli.sim import (
    NOISE_FREE,
    initial_guesses,
    random_free_poses,
    random_world,
    simulate_scan,
    uniform_initial_errors,
)

WORLD_SEEDS = range(40000, 40006)
POSES_PER_WORLD = 10
INITIAL_XY_M = 2.0
INITIAL_THETA_DEG = 20.0
POSITION_TOL_M = 0.005
HEADING_TOL_DEG = 0.05


@pytest.fixture(scope="module")
def outcomes() -> list[tuple[int, int, float, float, str, int]]:
    """Per trial: world seed, pose index, position error m, |heading error| °, status, segments."""
    out = []
    for seed in WORLD_SEEDS:
        rng = np.random.default_rng(seed)
        world = random_world(rng)
        localizer = Localizer.on_map(world.segments)
        truth = random_free_poses(world, POSES_PER_WORLD, rng)
        errors = uniform_initial_errors(POSES_PER_WORLD, INITIAL_XY_M, INITIAL_THETA_DEG, rng)
        for k, (pose, guess) in enumerate(zip(truth, initial_guesses(truth, errors), strict=True)):
            true = Pose2(*pose)
            scan = simulate_scan(world, true, NOISE_FREE, rng, float(k))
            local = extract_segments(scan)
            est = localizer.localize(local, Pose2(*guess), scan.points())
            position_m = float(np.hypot(est.pose.x - true.x, est.pose.y - true.y))
            heading_deg = abs(float(np.rad2deg(wrap_angle(est.pose.theta - true.theta))))
            out.append(
                (
                    seed,
                    k,
                    position_m if np.isfinite(position_m) else np.inf,
                    heading_deg if np.isfinite(heading_deg) else np.inf,
                    est.status,
                    int(local.shape[0]),
                )
            )
    return out


def test_every_noise_free_trial_ends_within_5mm_and_0_05deg_and_ok(outcomes):
    assert len(outcomes) == len(WORLD_SEEDS) * POSES_PER_WORLD
    misses = [
        f"world {seed} pose {k}: {pos_m * 1e3:.2f} mm {head_deg:.4f}° {status} ({n} segments)"
        for seed, k, pos_m, head_deg, status, n in outcomes
        if not (pos_m < POSITION_TOL_M and head_deg < HEADING_TOL_DEG and status == "ok")
    ]
    assert not misses, f"{len(misses)}/{len(outcomes)} misses:\n" + "\n".join(misses)
