"""Free space: beams that would have passed through a wall, on hand-made geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from segloc_cli.geometry import Pose2
from segloc_cli.method.freespace import SHORTEN_M, crossing_ratio
from segloc_cli.method.spatial import SegmentGrid

WALL = SegmentGrid(np.array([[2.0, -5.0, 2.0, 5.0], [-4.0, 3.0, -4.0, 4.0]]))


def test_a_beam_counts_only_when_it_runs_on_through_a_wall():
    points = np.array(
        [
            [3.0, 0.0],  # behind the wall at x = 2: the beam crosses it
            [1.0, 0.5],  # in front of it: clutter, free space up to there
            [2.0, 1.0],  # on the wall: shortened by SHORTEN_M, it stops before it
            [2.0 + SHORTEN_M / 2, 0.0],  # just behind a wall drawn a little off: not counted
            [0.1, 0.0],  # too short to judge
        ]
    )
    assert crossing_ratio(points, Pose2(0.0, 0.0, 0.0), WALL) == pytest.approx(1 / 4)


def test_the_beams_are_placed_at_the_pose():
    """Turned by a half turn, the same points lie away from the wall: nothing crosses; moved
    past the wall, the beam to the point in front of the robot no longer meets it either."""
    points = np.array([[3.0, 0.0], [1.0, 0.5]])
    assert crossing_ratio(points, Pose2(0.0, 0.0, math.pi), WALL) == 0.0
    assert crossing_ratio(points, Pose2(2.5, 0.0, 0.0), WALL) == 0.0
    assert crossing_ratio(points, Pose2(0.0, 0.0, 0.0), WALL) == 0.5


def test_no_beam_to_judge_gives_zero():
    assert crossing_ratio(np.zeros((0, 2)), Pose2(0.0, 0.0, 0.0), WALL) == 0.0
    assert crossing_ratio(np.array([[0.1, 0.0]]), Pose2(0.0, 0.0, 0.0), WALL) == 0.0
    assert crossing_ratio(np.array([[3.0, 0.0]]), Pose2(float("nan"), 0.0, 0.0), WALL) == 0.0


def _crossings_by_brute_force(points, pose: Pose2, segments) -> int:
    """Beams (shortened by SHORTEN_M) crossing any segment, every pair tested."""
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    count = 0
    for px, py in points:
        r = math.hypot(px, py)
        if not r > SHORTEN_M:
            continue
        keep = (r - SHORTEN_M) / r
        dx, dy = (px * c - py * s) * keep, (px * s + py * c) * keep
        for x1, y1, x2, y2 in segments:
            ax, ay, ex, ey = x1 - pose.x, y1 - pose.y, x2 - x1, y2 - y1
            denominator = dx * ey - dy * ex
            if denominator == 0.0:
                continue
            t, u = (ax * ey - ay * ex) / denominator, (ax * dy - ay * dx) / denominator
            if 0.0 < t < 1.0 and 0.0 <= u <= 1.0:
                count += 1
                break
    return count


@pytest.mark.parametrize("seed", range(4))
def test_segments_passed_over_by_distance_and_direction_are_none_a_beam_crosses(seed):
    """Random walls, some through or right next to the robot, and beams all around: the
    quick rejections by distance and direction leave the count every pair gives."""
    rng = np.random.default_rng(9100 + seed)
    ends = rng.uniform(-6.0, 6.0, (40, 2))
    segments = np.hstack([ends, ends + rng.normal(0.0, 1.0, (40, 2))])
    segments[:5] = [[-1.0, 0.0, 1.0, 0.0], [0.0, -2.0, 0.0, 2.0], [0.0, 0.0, 3.0, 3.0],
                    [1e-12, -1.0, 1e-12, 1.0], [-3.0, -3.0, 3.0, 3.0]]  # fmt: skip
    points = rng.uniform(-7.0, 7.0, (400, 2))
    pose = Pose2(0.0, 0.0, float(rng.uniform(-math.pi, math.pi)))
    ratio = crossing_ratio(points, pose, SegmentGrid(segments, cell_m=np.inf))
    judged = int(np.count_nonzero(np.hypot(points[:, 0], points[:, 1]) > SHORTEN_M))
    assert 0 < ratio < 1
    assert ratio == _crossings_by_brute_force(points, pose, segments) / judged
