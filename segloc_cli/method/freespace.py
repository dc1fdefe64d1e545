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

``seen_through`` asks the same of a map being built, per segment: which scans read free
space where it lies. A wall is not seen through; a person who walked by is, by the scans
taken after they left, whose beams reach the wall behind.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from segloc_cli.geometry import Pose2, segment_lengths
from segloc_cli.jit import njit
from segloc_cli.method.kernels import angular_interval, grown, point_segment_distance, wrap
from segloc_cli.method.spatial import SegmentGrid, near_mask

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
def _meeting(segments, j, ox, oy, dx, dy):
    """Where the beam from (ox, oy) to (ox + dx, oy + dy) meets the line of segment ``j``:
    t along the beam (0 at its start, 1 at its end), u along the segment (0 at its first
    end, 1 at its second) and the cross product of the two directions, 0 for a beam
    parallel to the segment (which does not meet it; t and u are then 0)."""
    ax, ay = segments[j, 0] - ox, segments[j, 1] - oy
    ex, ey = segments[j, 2] - segments[j, 0], segments[j, 3] - segments[j, 1]
    denominator = dx * ey - dy * ex
    if denominator == 0.0:
        return 0.0, 0.0, 0.0
    t = (ax * ey - ay * ex) / denominator
    u = (ax * dy - ay * dx) / denominator
    return t, u, denominator


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
            t, u, denominator = _meeting(segments, chosen[n], ox, oy, dx, dy)
            if denominator != 0.0 and 0.0 < t < 1.0 and 0.0 <= u <= 1.0:
                crossed += 1
                break
    return crossed, judged


def seen_through(
    segments_world: np.ndarray,
    points_robot: Sequence[np.ndarray],
    poses: Sequence[Pose2],
    margin_m: float,
    behind_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where scans see through segments: triples (scan (K,), segment (K,), piece (K,)), each
    once, the pieces being those of ``interior_pieces``.

    Scan k's points (P_k, 2), robot frame, are the ends of its beams from the robot at
    ``poses[k]`` (world frame). It sees through a segment of ``segments_world`` (M, 4) where
    one of its beams crosses it more than ``margin_m`` from either end and reads a range
    that ends more than ``behind_m`` behind the segment's line: free space where the map has
    a segment. A beam that ends on the segment, in front of it, just behind a segment drawn a
    little off, or past an end drawn a little long sees nothing through it.
    """
    segments = np.ascontiguousarray(segments_world, dtype=float).reshape(-1, 4)
    if len(points_robot) != len(poses):
        raise ValueError(f"{len(points_robot)} scans but {len(poses)} poses")
    if not margin_m > 0.0:
        raise ValueError(f"margin_m must be > 0, got {margin_m}")
    first, _ = interior_pieces(segments, margin_m)
    if first[-1] == 0 or not poses:
        return tuple(np.zeros(0, dtype=np.int64) for _ in range(3))  # type: ignore[return-value]
    counts = [p.shape[0] for p in points_robot]
    points = np.ascontiguousarray(np.concatenate(points_robot), dtype=float).reshape(-1, 2)
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    pose_array = np.array([pose.as_array() for pose in poses], dtype=float)
    cells = SegmentGrid(segments).cells
    scans, crossed = _seen_through(
        cells, segments, points, starts, pose_array, float(margin_m), float(behind_m), first
    )
    segment = np.searchsorted(first, crossed, side="right") - 1
    return scans, segment, crossed - first[segment]


def interior_pieces(segments_world: np.ndarray, margin_m: float) -> tuple[np.ndarray, np.ndarray]:
    """How ``seen_through`` cuts segments (M, 4): each one's interior, the stretch more than
    ``margin_m`` from either end, into pieces of ``margin_m`` from its first end, the last
    piece shorter; none for a segment shorter than 2·``margin_m``. Returns the number of
    each segment's first piece (M + 1,: its pieces run to the next one's) and every piece's
    length (N,), metres."""
    interior = np.maximum(segment_lengths(segments_world) - 2.0 * margin_m, 0.0)
    counts = np.ceil(interior / margin_m).astype(np.int64)
    first = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    lengths = np.full(int(first[-1]), float(margin_m))
    cut = counts > 0
    lengths[first[1:][cut] - 1] = interior[cut] - (counts[cut] - 1) * margin_m
    return first, lengths


@njit(cache=True)
def _seen_through(cells, segments, points, starts, poses, margin_m, behind_m, first):
    """``seen_through``'s pairs (scan, piece) for the scans' points (P, 2), robot frame,
    scan k's being ``points[starts[k]:starts[k + 1]]``, at ``poses`` (S, 3); segment j's
    pieces are numbered from ``first[j]`` to ``first[j + 1]`` − 1."""
    lengths = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    marked_by = np.full(first[-1], -1, dtype=np.int64)
    scans, crossed = np.empty(64, dtype=np.int64), np.empty(64, dtype=np.int64)
    count = 0
    for k in range(poses.shape[0]):
        ox, oy, c, s = poses[k, 0], poses[k, 1], np.cos(poses[k, 2]), np.sin(poses[k, 2])
        reach = 0.0
        for i in range(starts[k], starts[k + 1]):
            reach = max(reach, np.hypot(points[i, 0], points[i, 1]))
        allowed = near_mask(cells, segments, ox, oy, reach)
        for j in range(segments.shape[0]):
            allowed[j] = allowed[j] and first[j + 1] > first[j]
        chosen, near, mid, half = _in_sight(segments, allowed, ox, oy)
        offsets, members = _by_sector(mid, half)
        # Room for every piece in sight, made before the beams: a scan marks each once.
        room = 0
        for n in range(chosen.size):
            room += first[chosen[n] + 1] - first[chosen[n]]
        if count + room > scans.size:
            size = max(2 * scans.size, count + room)
            scans, crossed = grown(scans, count, size), grown(crossed, count, size)
        for i in range(starts[k], starts[k + 1]):
            r = np.hypot(points[i, 0], points[i, 1])
            if not r > behind_m:
                continue
            dx = points[i, 0] * c - points[i, 1] * s
            dy = points[i, 0] * s + points[i, 1] * c
            sector = _sector(np.arctan2(dy, dx))
            for m in range(offsets[sector], offsets[sector + 1]):
                n = members[m]
                if near[n] > r + SLACK:
                    continue
                j = chosen[n]
                t, u, denominator = _meeting(segments, j, ox, oy, dx, dy)
                if denominator == 0.0 or not 0.0 < t < 1.0:
                    continue
                along = u * lengths[j] - margin_m  # from the start of the interior
                # (1 − t)·|d × e| / |e|: how far behind the segment's line the beam ends.
                behind = (1.0 - t) * abs(denominator) / lengths[j]
                if not (0.0 <= along <= lengths[j] - 2.0 * margin_m and behind > behind_m):
                    continue
                piece = first[j] + min(int(along / margin_m), first[j + 1] - first[j] - 1)
                if marked_by[piece] != k:
                    marked_by[piece] = k
                    scans[count], crossed[count] = k, piece
                    count += 1
    return scans[:count].copy(), crossed[:count].copy()


SECTORS = 256
"""Sectors of direction round the robot under which ``seen_through`` files the segments in
sight, so that each beam is tested against those of its own sector only."""


@njit(cache=True)
def _sector_count(direction):
    """The sector of a direction (radians) counted from −π without wrapping round: below 0
    or from ``SECTORS`` on for a direction outside [−π, π)."""
    return np.int64(np.floor((direction + np.pi) * SECTORS / (2.0 * np.pi)))


@njit(cache=True)
def _sector(direction):
    """The sector (0 … ``SECTORS`` − 1) of a direction (radians, any turn)."""
    return _sector_count(direction) % SECTORS


@njit(cache=True)
def _by_sector(mid, half):
    """The segments in sight (``_in_sight``'s arcs: centre ``mid`` (K,), half-width ``half``
    (K,), radians) filed under every sector their arc touches: CSR, offsets (SECTORS + 1,)
    into positions (0 … K − 1)."""
    lo = np.empty(mid.size, dtype=np.int64)
    span = np.empty(mid.size, dtype=np.int64)
    for n in range(mid.size):
        if half[n] >= np.pi:
            lo[n], span[n] = 0, SECTORS
        else:
            lo[n] = _sector_count(mid[n] - half[n] - SLACK)
            span[n] = min(_sector_count(mid[n] + half[n] + SLACK) - lo[n] + 1, SECTORS)
    offsets = np.zeros(SECTORS + 1, dtype=np.int64)
    for n in range(mid.size):
        for q in range(span[n]):
            offsets[(lo[n] + q) % SECTORS + 1] += 1
    offsets = np.cumsum(offsets)
    members = np.empty(offsets[-1], dtype=np.int64)
    filled = offsets[:-1].copy()
    for n in range(mid.size):
        for q in range(span[n]):
            sector = (lo[n] + q) % SECTORS
            members[filled[sector]] = n
            filled[sector] += 1
    return offsets, members
