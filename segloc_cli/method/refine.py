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

The whole fit is one compiled call. Which map segments lie near a point comes
from a ``SegmentGrid`` of the map: a caller that refines many scans against one
map (``Localizer``) builds it once and passes it as ``index``; without one, a
call tests every segment of the map (as through a grid of one cell).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from segloc_cli.config import RefineParams
from segloc_cli.geometry import Pose2
from segloc_cli.jit import njit
from segloc_cli.method.kernels import (
    copy_into,
    list_if_within,
    point_segment_distance,
    wrap_remainder,
)
from segloc_cli.method.spatial import SegmentGrid, filed_within, near_mask, nearest_filed


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


def nearest_segments(
    points_world: np.ndarray,
    segments_world: np.ndarray,
    *,
    index: SegmentGrid | None = None,
    within_m: float | None = None,
):
    """Index (P,) of the nearest segment to each point and the distance (P,) in metres.

    With ``within_m``, points with no segment that near get index -1 and distance
    inf; ``index``, a ``SegmentGrid`` of ``segments_world``, then spares testing
    the segments that are farther. Among equally near segments the lowest index wins.
    """
    points = np.ascontiguousarray(points_world, dtype=float).reshape(-1, 2)
    segments = np.ascontiguousarray(segments_world, dtype=float).reshape(-1, 4)
    if within_m is not None and index is not None:
        _check_index(index, segments)
        return index.nearest(points, within_m)
    if segments.shape[0] == 0:
        return np.full(points.shape[0], -1, dtype=np.int64), np.full(points.shape[0], np.inf)
    found, dist = _nearest_segments(points, segments)
    if within_m is not None:
        beyond = ~(dist <= within_m)
        found[beyond], dist[beyond] = -1, np.inf
    return found, dist


def _check_index(index: SegmentGrid, segments: np.ndarray) -> None:
    if index.segments_world.shape != segments.shape:
        raise ValueError(
            f"index holds {index.segments_world.shape[0]} segments, the map {segments.shape[0]}"
        )


def _gates(params: RefineParams) -> list[float]:
    gates = [params.gate_m]
    while gates[-1] / 2.0 > params.final_gate_m:
        gates.append(gates[-1] / 2.0)
    if gates[-1] > params.final_gate_m:
        gates.append(params.final_gate_m)
    return gates


def support(
    points_robot: np.ndarray,
    segments_world: np.ndarray,
    pose: Pose2,
    band_m: float,
    *,
    index: SegmentGrid | None = None,
) -> tuple[float, float]:
    """How well the map explains the scan at ``pose``: the share of the points (robot frame)
    within ``band_m`` of a map segment, and how firmly those points fix the position along
    the direction they fix it least, in points' worth.

    Each point on a segment pins the position across that segment's line only:
    the smaller eigenvalue of the sum of n·nᵀ over the points on the map (n the
    unit normal of the segment each lies on) counts how many points' worth pin
    the weakest direction. Along a corridor or a lone wall it is about 0,
    however many of the points lie on the map. ``index`` is an optional
    ``SegmentGrid`` of ``segments_world``.
    """
    if points_robot.shape[0] == 0 or not np.isfinite(pose.x):
        return 0.0, 0.0
    index = _index_of(np.asarray(segments_world, dtype=float).reshape(-1, 4), index)
    points = np.ascontiguousarray(points_robot, dtype=float).reshape(-1, 2)
    placed = _placed(
        points, pose.as_array().astype(float), index.cells, index.segments_world,
        index.mask_all(), float(band_m),
    )  # fmt: skip
    sxx, sxy, syy = placed[3:6]
    weakest = np.linalg.eigvalsh(np.array([[sxx, sxy], [sxy, syy]]))[0]
    return float(placed[0] / points.shape[0]), float(weakest)


def _index_of(segments: np.ndarray, index: SegmentGrid | None) -> SegmentGrid:
    """``index`` checked against the map's segments (M, 4), or without one a grid of one
    cell, through which every segment is tested."""
    if index is None:
        return SegmentGrid(segments, cell_m=np.inf)
    _check_index(index, segments)
    return index


@njit(cache=True)
def _placed(points, pose, cells, segments, allowed, band_m):
    """The scan's points (P, 2), robot frame, placed at ``pose`` (3,) on the ``allowed``
    segments of a map filed in ``cells``: (points within ``band_m`` of one, the sum of
    their squared distances (m²), the sum over all points of 1 − (d / band)² clipped at 0,
    and Σ nx², Σ nx·ny, Σ ny² of the unit normals of the segments the near points lie on)."""
    n = points.shape[0]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    world = np.empty((n, 2))
    for i in range(n):
        world[i, 0] = points[i, 0] * c - points[i, 1] * s + pose[0]
        world[i, 1] = points[i, 0] * s + points[i, 1] * c + pose[1]
    nearest, dist = nearest_filed(cells, segments, allowed, world, band_m)
    out = np.zeros(6)
    for i in range(n):
        if not dist[i] <= band_m:
            continue
        out[0] += 1.0
        out[1] += dist[i] * dist[i]
        out[2] += min(max(1.0 - (dist[i] / band_m) ** 2, 0.0), 1.0)
        j = nearest[i]
        dx, dy = segments[j, 2] - segments[j, 0], segments[j, 3] - segments[j, 1]
        length = np.hypot(dx, dy)
        length = length if length > 0 else 1.0
        nx, ny = -dy / length, dx / length
        out[3] += nx * nx
        out[4] += nx * ny
        out[5] += ny * ny
    return out


def inlier_ratio(
    points_robot: np.ndarray,
    segments_world: np.ndarray,
    pose: Pose2,
    band_m: float,
    *,
    index: SegmentGrid | None = None,
) -> float:
    """Share of the points (robot frame) within ``band_m`` of a map segment at ``pose``."""
    return support(points_robot, segments_world, pose, band_m, index=index)[0]


def refine_pose(
    points_robot: np.ndarray,
    segments_world: np.ndarray,
    initial: Pose2,
    params: RefineParams | None = None,
    *,
    index: SegmentGrid | None = None,
) -> Refinement:
    """Fit scan points (P, 2), robot frame, to map segments (M, 4), world frame.

    Returns the fitted pose (world frame) and the inlier share at it. A round
    in which fewer than ``min_points`` points are within its gate stops there,
    so when that is so from the start ``initial`` is returned unchanged, with
    its own inlier share. ``index``, a ``SegmentGrid`` of ``segments_world``
    built once per map, makes the fit cost what the scan's neighbourhood holds
    rather than what the map holds; the result is the same without it.
    """
    p = params or RefineParams()
    points = np.asarray(points_robot, dtype=float).reshape(-1, 2)
    segments = np.asarray(segments_world, dtype=float).reshape(-1, 4)
    n = points.shape[0]
    if n == 0 or segments.shape[0] == 0:
        return Refinement(initial, 0.0, float("nan"), n, 0.0)
    index = _index_of(segments, index)
    rounds = _Rounds(
        np.array(_gates(p)), p.steps_per_round, p.min_points, _prior_weights(p), p.final_gate_m
    )
    pose, placed = _fit(
        np.ascontiguousarray(points),
        index.segments_world,
        index.cells,
        initial.as_array().astype(float),
        rounds,
        2.0 * p.gate_m,
    )
    fitted = Pose2(float(pose[0]), float(pose[1]), float(pose[2]))
    n_in = placed[0]
    rms = float(np.sqrt(placed[1] / n_in)) if n_in > 0 else float("nan")
    return Refinement(fitted, float(n_in / n), rms, n, float(placed[2] / n))


class _Rounds(NamedTuple):
    """The fit's rounds (``RefineParams``): one per gate (m) of ``gates``, of at most
    ``steps_per_round`` Gauss-Newton steps, each needing ``min_points`` points within the
    gate; the ``prior``'s weights (3,) on x, y, θ (``_prior_weights``); and the gate of the
    fitted pose's inliers, ``final_gate_m``."""

    gates: np.ndarray
    steps_per_round: int
    min_points: int
    prior: np.ndarray
    final_gate_m: float


@njit(cache=True)
def _fit(points, segments, cells, initial, rounds, margin_m):
    """``refine_pose`` compiled: the fitted pose (3,) and ``_placed`` there, from the points'
    farthest reach plus ``margin_m`` of the map around ``initial``."""
    # Only segments within reach of the scan from near the guess can pair. Points that are
    # not finite never pair (their distances are NaN) and must not widen the reach.
    reach = 0.0
    for i in range(points.shape[0]):
        r = np.hypot(points[i, 0], points[i, 1])
        if np.isfinite(r):
            reach = max(reach, r)
    reach += margin_m
    allowed = near_mask(cells, segments, initial[0], initial[1], reach)
    pose = _gauss_newton(points, segments, allowed, cells, initial, rounds, reach)
    return pose, _placed(points, pose, cells, segments, allowed, rounds.final_gate_m)


def _prior_weights(p: RefineParams) -> np.ndarray:
    """Weights (3,) of the prior on x, y, θ in units of one well-placed point (0: none).

    The prior holds the pose where the points say nothing, e.g. along a
    featureless corridor.
    """
    prior = np.zeros(3)
    if p.prior_sigma_m is not None:
        prior[:2] = (p.point_sigma_m / p.prior_sigma_m) ** 2
    if p.prior_sigma_deg is not None:
        prior[2] = (p.point_sigma_m / np.deg2rad(p.prior_sigma_deg)) ** 2
    return prior


@njit(cache=True)
def _travel(pose, start, reach_m):
    """Largest distance (m) any point within ``reach_m`` of the scanner moved between poses."""
    turn = abs(wrap_remainder(pose[2] - start[2]))
    return np.hypot(pose[0] - start[0], pose[1] - start[1]) + reach_m * turn


@njit(cache=True)
def _nearest_listed(px, py, moved_m, segments, listed, listed_d, first, stop, hint, gate):
    """Index and distance of the point's nearest segment among ``listed[first:stop]`` when
    it lies within ``gate``; of equally near ones the lowest index. (-1, inf) or some
    segment farther than ``gate`` otherwise.

    ``listed_d`` holds each listed segment's distance from where the point was when the
    list was made, ``moved_m`` (m) how far it has moved since: a segment that was farther
    than the nearest found so far, or the gate, by more than that cannot be nearer now,
    and is passed over without working out its distance. ``hint`` (-1: none), the
    point's nearest segment at the step before, is tried first so that most are.
    """
    best, best_j = np.inf, -1
    if hint >= 0:
        d = point_segment_distance(
            px, py, segments[hint, 0], segments[hint, 1], segments[hint, 2], segments[hint, 3]
        )
        if d <= gate:
            # Within the gate it is listed: a segment that is not lies farther than the
            # list's radius less the travel the list allows, which is at least the gate.
            best, best_j = d, hint
    bound = min(best, gate) + moved_m + 1e-9 * (1.0 + abs(px) + abs(py))  # with rounding slack
    for k in range(first, stop):
        if listed_d[k] > bound:
            continue  # farther now than the nearest so far (or the gate): cannot win or tie
        j = listed[k]
        d = point_segment_distance(
            px, py, segments[j, 0], segments[j, 1], segments[j, 2], segments[j, 3]
        )
        if d < best or (d == best and j < best_j):
            best, best_j = d, j
            bound = min(best, gate) + moved_m + 1e-9 * (1.0 + abs(px) + abs(py))
    return best_j, best


@njit(cache=True)
def _narrowed(points_world, segments, listed_from, listed, radius_m):
    """CSR lists (offsets, indices, distances (m)) of each point (P, 2) narrowed to the
    listed segments within ``radius_m`` of it."""
    n = points_world.shape[0]
    kept_from = np.zeros(n + 1, dtype=np.int64)
    kept = np.empty(listed.size, dtype=np.int64)
    kept_d = np.empty(listed.size)
    count = np.int64(0)  # typed, so list_if_within compiles once, not for a literal 0
    for i in range(n):
        px, py = points_world[i, 0], points_world[i, 1]
        for k in range(listed_from[i], listed_from[i + 1]):
            count = list_if_within(px, py, segments, listed[k], radius_m, kept, kept_d, count)
        kept_from[i + 1] = count
    return kept_from, kept[:count], kept_d[:count]


@njit(cache=True)
def _solve3(a, b):
    """x with a·x = b for a (3, 3), by elimination with partial pivoting, and whether a
    was regular (False on an exactly zero pivot, as LAPACK reports a singular matrix)."""
    m, x = a.copy(), b.copy()
    for col in range(3):
        pivot = col
        for r in range(col + 1, 3):
            if abs(m[r, col]) > abs(m[pivot, col]):
                pivot = r
        if m[pivot, col] == 0.0:
            return x, False
        for c in range(3):
            m[col, c], m[pivot, c] = m[pivot, c], m[col, c]
        x[col], x[pivot] = x[pivot], x[col]
        for r in range(col + 1, 3):
            f = m[r, col] / m[col, col]
            for c in range(col, 3):
                m[r, c] -= f * m[col, c]
            x[r] -= f * x[col]
    for r in range(2, -1, -1):
        for c in range(r + 1, 3):
            x[r] -= m[r, c] * x[c]
        x[r] /= m[r, r]
    return x, True


@njit(cache=True)
def _normal_equations(world, rotated, segments, lists, listed_where, hints, gate):
    """The Gauss-Newton system of one step: the Hessian (3, 3) and gradient (3,) of the
    point-to-line residuals, with Cauchy weights, of the points at ``world`` (``rotated``
    about the pose's position) within ``gate`` of their nearest segment in their lists
    (``_nearest_listed``: CSR ``lists``, made with the points at ``listed_where``), and how
    many such points there are. ``hints`` (P,) holds each point's nearest segment at the
    step before, and gets this step's."""
    starts, listed, listed_d = lists
    hessian = np.zeros((3, 3))
    gradient = np.zeros(3)
    jacobian = np.empty(3)
    used = 0
    for i in range(world.shape[0]):
        px, py = world[i, 0], world[i, 1]
        ex, ey = px - listed_where[i, 0], py - listed_where[i, 1]
        moved = np.sqrt(ex * ex + ey * ey)
        j, d = _nearest_listed(
            px, py, moved, segments, listed, listed_d, starts[i], starts[i + 1], hints[i], gate
        )
        hints[i] = j
        if not d <= gate:
            continue
        used += 1
        dx, dy = segments[j, 2] - segments[j, 0], segments[j, 3] - segments[j, 1]
        length = np.hypot(dx, dy)
        length = length if length > 0 else 1.0
        nx, ny = -dy / length, dx / length
        residual = nx * (world[i, 0] - segments[j, 0]) + ny * (world[i, 1] - segments[j, 1])
        jacobian[0], jacobian[1] = nx, ny
        jacobian[2] = nx * -rotated[i, 1] + ny * rotated[i, 0]
        # Cauchy weights with the scale at half the gate: points near the
        # gate count for less, so a wrong pairing cannot drag the pose far.
        weight = 1.0 / (1.0 + (residual / (0.5 * gate)) ** 2)
        for a in range(3):
            weighted = jacobian[a] * weight
            gradient[a] += weighted * residual
            for b in range(3):
                hessian[a, b] += weighted * jacobian[b]
    return hessian, gradient, used


@njit(cache=True)
def _gauss_newton(points, segments, allowed, cells, initial, rounds, reach_m):
    """The fitted pose (3,): damped Gauss-Newton ``rounds``, one per gate, of point-to-line
    residuals with Cauchy weights and a prior on ``initial``.

    Points (P, 2) are in the robot frame; segments (M, 4), of which only the
    ``allowed`` (M,) take part, in the world frame, filed in ``cells``
    (``SegmentGrid.cells``). ``reach_m`` bounds the points' distance from the
    scanner.
    """
    n = points.shape[0]
    pose = initial.copy()
    world = np.empty((n, 2))
    rotated = np.empty((n, 2))
    # Each point is compared only with the segments listed near where it was when the
    # lists were made, out to ``radius``: enough while the pose travels less than the
    # radius less the gate. Lists are made for twice the gate, narrowed when the gate
    # shrinks, and made anew from the grid when the pose has travelled too far for them.
    # Each point's nearest segment at the last step is tried first at the next, and a listed
    # segment is passed over when it was too far, given how far the point has moved since.
    # The lists are CSR: (starts (P + 1,), segment indices, distances (m)).
    lists_at = initial.copy()
    lists = filed_within(cells, segments, allowed, world[:0], 0.0)
    listed_where = np.empty((n, 2))
    hints = np.full(n, -1, dtype=np.int64)
    radius = -np.inf
    gates, prior = rounds.gates, rounds.prior
    for gate in gates:
        for _ in range(rounds.steps_per_round):
            c, s = np.cos(pose[2]), np.sin(pose[2])
            for i in range(n):  # the points turned by the pose's heading, and placed at it
                rotated[i, 0] = points[i, 0] * c - points[i, 1] * s
                rotated[i, 1] = points[i, 0] * s + points[i, 1] * c
                world[i, 0] = rotated[i, 0] + pose[0]
                world[i, 1] = rotated[i, 1] + pose[1]
            travel = _travel(pose, lists_at, reach_m)
            renew = not travel <= radius - gate  # and on the first step, or at a NaN pose
            narrow = not renew and radius > 2.0 * gate and radius - travel >= 2.0 * gate
            if renew:
                lists = filed_within(cells, segments, allowed, world, 2.0 * gate)
            elif narrow:
                lists = _narrowed(world, segments, lists[0], lists[1], 2.0 * gate)
            if renew or narrow:
                copy_into(lists_at, pose)
                copy_into(listed_where.reshape(-1), world.reshape(-1))
                radius = 2.0 * gate
            hessian, gradient, used = _normal_equations(
                world, rotated, segments, lists, listed_where, hints, gate
            )
            if used < rounds.min_points:
                break
            # The damped step, with the prior pulling towards ``initial``.
            offset = pose - initial
            offset[2] = wrap_remainder(offset[2])
            for a in range(3):
                hessian[a, a] += prior[a] + 1e-6
            step, regular = _solve3(hessian, -gradient - prior * offset)
            if not regular or not np.all(np.isfinite(step)):
                break
            pose += step
            pose[2] = wrap_remainder(pose[2])
            if np.hypot(step[0], step[1]) < 1e-5 and abs(step[2]) < 1e-6:
                break
    return pose
