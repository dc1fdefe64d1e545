"""Free space: how many of a scan's beams would have passed through a wall of the map.

A pose can put most of a scan's points on walls and still be the wrong place, and a right
pose can leave many points off the map, on furniture and people the map does not hold. The
two differ in where the stray points lie: clutter stands in front of the walls, so its
beams stop short of them, while at a wrong pose some beams run on through a wall to reach
their reading. ``crossing_ratio`` counts those, the evidence a beam model uses and a count
of points on the map leaves out.

Each beam is taken from the robot's origin to its point (robot frame, placed at the pose in
the world frame) and shortened by ``SHORTEN_M``, so that a point on a wall, or one a little
behind a wall drawn a few centimetres off, does not count; a scanner mounted off the origin
by a few centimetres stays well inside that.
"""

from __future__ import annotations

import numpy as np

from segloc_cli.geometry import Pose2
from segloc_cli.jit import njit
from segloc_cli.method.kernels import angular_interval, point_segment_distance, wrap
from segloc_cli.method.spatial import SegmentGrid

SHORTEN_M = 0.3
"""Metres cut from the end of each beam before it is tested against the walls."""


def crossing_ratio(points_robot: np.ndarray, pose: Pose2, index: SegmentGrid) -> float:
    """Share (0–1) of the beams to ``points_robot`` (P, 2), robot frame, that cross a segment
    of the map filed in ``index`` on their way, with the robot at ``pose`` (world frame); the
    beams shorter than ``SHORTEN_M`` are not counted either way. 0 with no beam to judge."""
    points = np.ascontiguousarray(points_robot, dtype=float).reshape(-1, 2)
    if points.shape[0] == 0 or not np.isfinite(pose.x):
        return 0.0
    reach = float(np.hypot(points[:, 0], points[:, 1]).max())
    allowed = index.mask_near([pose.x, pose.y], reach)
    crossed, judged = _crossed(
        points, pose.as_array().astype(float), index.segments_world, allowed, SHORTEN_M
    )
    return crossed / judged if judged else 0.0


SLACK = 1e-9
"""Metres and radians by which ``_crossed``'s quick rejections err towards testing."""


@njit(cache=True)
def _in_sight(segments, allowed, ox, oy):
    """The ``allowed`` segments (indices (K,)) as seen from (ox, oy): each one's nearest
    distance (K,) and the arc of directions it spans (``angular_interval``: centre (K,) and
    half-width (K,); π, every direction, for a segment through or next to the point)."""
    chosen = np.flatnonzero(allowed)
    near, mid, half = np.empty(chosen.size), np.empty(chosen.size), np.empty(chosen.size)
    for n in range(chosen.size):
        x1, y1 = segments[chosen[n], 0] - ox, segments[chosen[n], 1] - oy
        x2, y2 = segments[chosen[n], 2] - ox, segments[chosen[n], 3] - oy
        near[n] = point_segment_distance(0.0, 0.0, x1, y1, x2, y2)
        mid[n], half[n] = angular_interval(x1, y1, x2, y2)
        if near[n] <= SLACK or half[n] >= 0.5 * np.pi - SLACK:
            half[n] = np.pi
    return chosen, near, mid, half


@njit(cache=True)
def _crossed(points, pose, segments, allowed, shorten_m):
    """(beams crossing an ``allowed`` segment, beams long enough to judge) of ``points``
    (P, 2), robot frame, at ``pose`` (3,).

    A segment farther from the robot than the beam is long, or outside the directions the
    beam could point along to meet it, is passed over before the exact test of crossing."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    ox, oy = pose[0], pose[1]
    chosen, near, mid, half = _in_sight(segments, allowed, ox, oy)
    crossed, judged = 0, 0
    for i in range(points.shape[0]):
        r = np.hypot(points[i, 0], points[i, 1])
        if not r > shorten_m:
            continue
        judged += 1
        keep = (r - shorten_m) / r
        dx = (points[i, 0] * c - points[i, 1] * s) * keep
        dy = (points[i, 0] * s + points[i, 1] * c) * keep
        length, direction = r - shorten_m, np.arctan2(dy, dx)
        for n in range(chosen.size):
            if near[n] > length + SLACK:
                continue
            if abs(wrap(direction - mid[n])) > half[n] + SLACK:
                continue
            j = chosen[n]
            ax, ay = segments[j, 0] - ox, segments[j, 1] - oy
            ex, ey = segments[j, 2] - segments[j, 0], segments[j, 3] - segments[j, 1]
            denominator = dx * ey - dy * ex
            if denominator == 0.0:
                continue  # parallel: a beam along a wall does not pass through it
            t = (ax * ey - ay * ex) / denominator  # along the beam, 0 at the robot
            u = (ax * dy - ay * dx) / denominator  # along the segment
            if 0.0 < t < 1.0 and 0.0 <= u <= 1.0:
                crossed += 1
                break
    return crossed, judged
