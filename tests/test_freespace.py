"""Free space: beams that would have passed through a wall, on hand-made geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from segloc_cli.geometry import Pose2
from segloc_cli.method.freespace import SHORTEN_M, crossing_ratio, seen_through
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


# --------------------------------------------------------------------------- seen_through

FENCE = np.array([[2.0, -1.0, 2.0, 1.0]])
"""A 2 m segment across the x axis, 2 m ahead of a robot at the origin facing +x."""


def _triples(points_by_scan, poses, segments, margin_m=0.1, behind_m=0.3) -> set[tuple]:
    scan, segment, piece = seen_through(segments, points_by_scan, poses, margin_m, behind_m)
    found = set(zip(scan.tolist(), segment.tolist(), piece.tolist(), strict=True))
    assert len(found) == scan.size  # each once
    return found


def test_a_scan_sees_through_a_segment_where_its_beam_ends_well_behind_it():
    """The fence's interior (0.1 m from either end: y from −0.9 to 0.9) is cut into pieces
    of 0.1 m from its first end (y = −1); a beam is counted in the piece it crosses."""
    points = np.array(
        [
            [4.0, 0.1],  # ends 2 m behind, crossing at y = 0.05: piece 9 of 18
            [3.0, 0.825],  # ends 1 m behind, crossing at y = 0.55: piece 14
            [4.0, 0.12],  # crosses piece 9 again: the scan counts there once
            [2.2, 0.0],  # ends 0.2 m behind: the fence drawn a little off, not seen through
            [1.5, 0.0],  # ends in front of it
            [4.0, 1.9],  # crosses at y = 0.95, within 0.1 m of its end
            [4.0, 3.0],  # passes beside it
        ]
    )
    seen = _triples([points], [Pose2(0.0, 0.0, 0.0)], FENCE)
    assert seen == {(0, 0, 9), (0, 0, 14)}
    # The same beams from a pose turned round see nothing of it; a second scan that crosses
    # it is numbered as the second.
    behind = np.array([[-4.0, -0.1]])
    assert _triples([points, behind], [Pose2(0.0, 0.0, math.pi), Pose2(0, 0, math.pi)], FENCE) == {
        (1, 0, 9)
    }


def test_seen_through_needs_a_segment_long_enough_to_judge():
    """A segment no longer than two end margins has no interior to see through; no scan or
    no segment gives nothing."""
    short = np.array([[2.0, -0.09, 2.0, 0.09]])
    beam = [np.array([[4.0, 0.0]])]
    assert _triples(beam, [Pose2(0.0, 0.0, 0.0)], short) == set()
    assert _triples([], [], FENCE) == set()
    assert _triples(beam, [Pose2(0.0, 0.0, 0.0)], np.zeros((0, 4))) == set()
    with pytest.raises(ValueError, match="2 scans but 1 poses"):
        seen_through(FENCE, beam * 2, [Pose2(0.0, 0.0, 0.0)], 0.1, 0.3)


def _seen_through_by_brute_force(points_by_scan, poses, segments, margin_m, behind_m) -> set:
    """Every beam tested against every segment, from the definitions."""
    found = set()
    for k, (points, pose) in enumerate(zip(points_by_scan, poses, strict=True)):
        c, s = math.cos(pose.theta), math.sin(pose.theta)
        for px, py in points:
            dx, dy = px * c - py * s, px * s + py * c
            for j, (x1, y1, x2, y2) in enumerate(segments):
                ex, ey = x2 - x1, y2 - y1
                length = math.hypot(ex, ey)
                denominator = dx * ey - dy * ex
                if denominator == 0.0 or length <= 2 * margin_m:
                    continue
                ax, ay = x1 - pose.x, y1 - pose.y
                t, u = (ax * ey - ay * ex) / denominator, (ax * dy - ay * dx) / denominator
                along = u * length - margin_m
                behind = (1.0 - t) * abs(denominator) / length
                if 0.0 < t < 1.0 and 0.0 <= along <= length - 2 * margin_m and behind > behind_m:
                    pieces = math.ceil((length - 2 * margin_m) / margin_m)
                    found.add((k, j, min(int(along / margin_m), pieces - 1)))
    return found


@pytest.mark.parametrize("seed", range(3))
def test_seen_through_finds_what_every_beam_against_every_segment_finds(seed):
    """Random segments, some through or next to a robot, and scans all around: the grid,
    the sectors of direction and the distance check pass over none that a beam crosses."""
    rng = np.random.default_rng(9200 + seed)
    ends = rng.uniform(-6.0, 6.0, (60, 2))
    segments = np.hstack([ends, ends + rng.normal(0.0, 1.5, (60, 2))])
    segments[:3] = [[-1.0, 0.0, 1.0, 0.0], [0.0, -2.0, 0.0, 2.0], [-3.0, -3.0, 3.0, 3.0]]
    poses = [Pose2(*rng.uniform(-1.0, 1.0, 2), float(rng.uniform(-math.pi, math.pi)))
             for _ in range(3)]  # fmt: skip
    poses[0] = Pose2(0.0, 0.0, 0.0)
    points = [rng.uniform(-8.0, 8.0, (300, 2)) for _ in poses]
    found = _triples(points, poses, segments, margin_m=0.06, behind_m=0.3)
    assert len(found) > 50
    assert found == _seen_through_by_brute_force(points, poses, segments, 0.06, 0.3)
