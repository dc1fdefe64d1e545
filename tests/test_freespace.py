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
