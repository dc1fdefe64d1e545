"""Least-squares refinement: scan points pulled onto the map segments they lie on.

The coarse-to-fine search stops at the resolution of its last grid and, with
a handful of local segments, often on a flat stretch of the overlap score.
Refinement takes its pose (or any close guess) and fits the scan's points to
the global map directly: each point pairs with its nearest map segment, the
residual is the point's signed distance to that segment's supporting line
(point-to-line ICP), and a few damped Gauss-Newton steps with Cauchy weights
minimise the sum. Points farther than a gate from every segment (clutter,
people, walls the map lacks) are left out; the gate shrinks from round to
round so a guess tens of centimetres off can still be pulled in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from segloc_cli.config import RefineParams
from segloc_cli.geometry import (
    Pose2,
    point_segment_distances,
    rotation,
    transform_points,
    wrap_angle,
)
from segloc_cli.kernels import point_segment_distance


@dataclass(frozen=True)
class Refinement:
    """Outcome of a fit: the pose and how well the scan sits on the map there."""

    pose: Pose2
    inlier_ratio: float
    """Share of the scan's points within ``final_gate_m`` of a map segment at ``pose``."""
    rms_m: float
    """Root mean square distance of those inliers from their nearest segment (NaN if none)."""
    n_points: int
    score: float = 0.0
    """Mean over all points of 1 − (d / final_gate_m)², 0 beyond the gate: in [0, 1], 1 when
    every point lies exactly on a segment. Ranks fits that put equally many points on the map
    by how closely they do."""


@njit(cache=True)
def _nearest_segments(points, segments):
    """Index and distance of the nearest segment to each point (P, 2) among (M, 4)."""
    n = points.shape[0]
    index = np.empty(n, dtype=np.int64)
    dist = np.empty(n)
    for i in range(n):
        px, py = points[i, 0], points[i, 1]
        best, best_j = np.inf, -1
        for j in range(segments.shape[0]):
            d = point_segment_distance(
                px, py, segments[j, 0], segments[j, 1], segments[j, 2], segments[j, 3]
            )
            if d < best:
                best, best_j = d, j
        index[i] = best_j
        dist[i] = best
    return index, dist


@njit(cache=True)
def _candidate_lists(points, segments, radius):
    """Per point, the segments within ``radius`` of it, as CSR (offsets (P+1,), indices)."""
    n = points.shape[0]
    counts = np.zeros(n + 1, dtype=np.int64)
    found = []
    for i in range(n):
        px, py = points[i, 0], points[i, 1]
        for j in range(segments.shape[0]):
            if (
                point_segment_distance(
                    px, py, segments[j, 0], segments[j, 1], segments[j, 2], segments[j, 3]
                )
                <= radius
            ):
                found.append(j)
                counts[i + 1] += 1
    return np.cumsum(counts), np.array(found, dtype=np.int64)


@njit(cache=True)
def _nearest_among(points, segments, offsets, indices):
    """Index (−1: none) and distance (inf: none) of each point's nearest listed segment."""
    n = points.shape[0]
    index = np.full(n, -1, dtype=np.int64)
    dist = np.full(n, np.inf)
    for i in range(n):
        px, py = points[i, 0], points[i, 1]
        for k in range(offsets[i], offsets[i + 1]):
            j = indices[k]
            d = point_segment_distance(
                px, py, segments[j, 0], segments[j, 1], segments[j, 2], segments[j, 3]
            )
            if d < dist[i]:
                dist[i], index[i] = d, j
    return index, dist


def nearest_segments(points_world: np.ndarray, segments_world: np.ndarray):
    """Index (P,) of the nearest segment to each point and the distance (P,) in metres."""
    points = np.ascontiguousarray(points_world, dtype=float).reshape(-1, 2)
    segments = np.ascontiguousarray(segments_world, dtype=float).reshape(-1, 4)
    if segments.shape[0] == 0:
        return np.full(points.shape[0], -1, dtype=np.int64), np.full(points.shape[0], np.inf)
    return _nearest_segments(points, segments)


def _line_normals(segments: np.ndarray) -> np.ndarray:
    """Unit normals (M, 2) of segments (M, 4)."""
    d = segments[:, 2:4] - segments[:, 0:2]
    length = np.hypot(d[:, 0], d[:, 1])
    return np.column_stack([-d[:, 1], d[:, 0]]) / np.where(length > 0, length, 1.0)[:, None]


def _travel(pose: np.ndarray, start: np.ndarray, reach_m: float) -> float:
    """Largest distance any point within ``reach_m`` of the scanner moved between two poses."""
    turn = abs(wrap_angle(pose[2] - start[2]))
    return float(np.hypot(*(pose[:2] - start[:2])) + reach_m * turn)


def _gates(params: RefineParams) -> list[float]:
    gates = [params.gate_m]
    while gates[-1] / 2.0 > params.final_gate_m:
        gates.append(gates[-1] / 2.0)
    if gates[-1] > params.final_gate_m:
        gates.append(params.final_gate_m)
    return gates


def support(
    points_robot: np.ndarray, segments_world: np.ndarray, pose: Pose2, band_m: float
) -> tuple[float, float]:
    """How well the map explains the scan at ``pose``: the share of the points (robot frame)
    within ``band_m`` of a map segment, and how firmly those points fix the position along
    the direction they fix it least, in points' worth.

    Each point on a segment pins the position across that segment's line only:
    the smaller eigenvalue of the sum of n·nᵀ over the points on the map (n the
    unit normal of the segment each lies on) counts how many points' worth pin
    the weakest direction. Along a corridor or a lone wall it is about 0,
    however many of the points lie on the map.
    """
    if points_robot.shape[0] == 0 or not np.isfinite(pose.x):
        return 0.0, 0.0
    segments = np.asarray(segments_world, dtype=float).reshape(-1, 4)
    index, dist = nearest_segments(transform_points(points_robot, pose), segments)
    on_map = dist <= band_m
    normals = _line_normals(segments[index[on_map]])
    return float(np.mean(on_map)), float(np.linalg.eigvalsh(normals.T @ normals)[0])


def inlier_ratio(
    points_robot: np.ndarray, segments_world: np.ndarray, pose: Pose2, band_m: float
) -> float:
    """Share of the points (robot frame) within ``band_m`` of a map segment at ``pose``."""
    return support(points_robot, segments_world, pose, band_m)[0]


def refine_pose(
    points_robot: np.ndarray,
    segments_world: np.ndarray,
    initial: Pose2,
    params: RefineParams | None = None,
) -> Refinement:
    """Fit scan points (P, 2), robot frame, to map segments (M, 4), world frame.

    Returns the fitted pose (world frame) and the inlier share at it. When
    fewer than ``min_points`` points are ever within the gate, ``initial`` is
    returned unchanged with its own inlier share.
    """
    p = params or RefineParams()
    points = np.asarray(points_robot, dtype=float).reshape(-1, 2)
    segments = np.asarray(segments_world, dtype=float).reshape(-1, 4)
    n = points.shape[0]
    if n == 0 or segments.shape[0] == 0:
        return Refinement(initial, 0.0, float("nan"), n, 0.0)
    # Only segments within reach of the scan from near the guess can pair. Points that are
    # not finite never pair (their distances are NaN) and must not widen the reach.
    radii = np.hypot(points[:, 0], points[:, 1])
    reach = float(radii[np.isfinite(radii)].max(initial=0.0)) + 2.0 * p.gate_m
    near = point_segment_distances([initial.x, initial.y], segments)[0] <= reach
    segments = segments[near]
    normals = _line_normals(segments)
    pose = initial.as_array()
    # Each point is compared only with the segments near where it starts;
    # the lists are rebuilt should the pose travel more than a gate.
    lists_at, lists = None, None
    # A prior on the guess holds the pose where the points say nothing, e.g.
    # along a featureless corridor, in units of one well-placed point.
    prior = np.zeros(3)
    if p.prior_sigma_m is not None:
        prior[:2] = (p.point_sigma_m / p.prior_sigma_m) ** 2
    if p.prior_sigma_deg is not None:
        prior[2] = (p.point_sigma_m / np.deg2rad(p.prior_sigma_deg)) ** 2
    for gate in _gates(p):
        for _ in range(p.steps_per_round):
            rotated = points @ rotation(pose[2]).T
            world = rotated + pose[:2]
            if lists_at is None or _travel(pose, lists_at, reach) > p.gate_m:
                lists_at = pose.copy()
                lists = _candidate_lists(world, segments, 2.0 * p.gate_m)
            index, dist = _nearest_among(world, segments, *lists)
            use = dist <= gate
            if np.count_nonzero(use) < p.min_points:
                break
            normal = normals[index[use]]
            anchor = segments[index[use], 0:2]
            residual = np.sum(normal * (world[use] - anchor), axis=1)
            jacobian = np.column_stack(
                [normal, normal[:, 0] * -rotated[use, 1] + normal[:, 1] * rotated[use, 0]]
            )
            # Cauchy weights with the scale at half the gate: points near the
            # gate count for less, so a wrong pairing cannot drag the pose far.
            weight = 1.0 / (1.0 + (residual / (0.5 * gate)) ** 2)
            jw = jacobian * weight[:, None]
            offset = pose - initial.as_array()
            offset[2] = wrap_angle(offset[2])
            hessian = jw.T @ jacobian + np.diag(prior + 1e-6)
            try:
                step = np.linalg.solve(hessian, -jw.T @ residual - prior * offset)
            except np.linalg.LinAlgError:
                break
            if not np.all(np.isfinite(step)):
                break
            pose = pose + step
            pose[2] = wrap_angle(pose[2])
            if np.hypot(step[0], step[1]) < 1e-5 and abs(step[2]) < 1e-6:
                break
    fitted = Pose2(float(pose[0]), float(pose[1]), float(pose[2]))
    _, dist = nearest_segments(transform_points(points, fitted), segments)
    inliers = dist <= p.final_gate_m
    rms = float(np.sqrt(np.mean(dist[inliers] ** 2))) if inliers.any() else float("nan")
    score = float(np.mean(np.clip(1.0 - (dist / p.final_gate_m) ** 2, 0.0, 1.0)))
    return Refinement(fitted, float(np.mean(inliers)), rms, n, score)
