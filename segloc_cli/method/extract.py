"""Local map from one scan: line segments in the robot frame.

Steps: drop invalid readings; cut the point sequence at range breakpoints
(an adaptive breakpoint detector, so the gap tolerated grows with range and
angular step); recursive split at the point farthest from the chord; merge
neighbours that still fit one line; total-least-squares refit with the end
points projected onto the fitted line. A segment is kept when it is long
enough and its direction is known well enough: the direction's standard error
follows from the points' spread along the line and their noise, so the same
rule serves 180 readings at 1° and 2048 at 0.18°, near walls and far ones.
That, not per-point filtering, is what makes the local map robust to noise.

The work runs in compiled kernels, one call per scan. Points are held as two
coordinate arrays (x, y) in metres, scanner frame, and a piece of them as an
index range [start, stop); ``extract_segments`` places the segments found in the
robot frame by the scanner's mounting (``Scan.mount``). Sums are added in numpy's
order (``_numpy_sum``), so the fits equal those of the plain numpy formulas to the
last bit but for ``arctan2``, which numpy may take from a vectorised library that
rounds a few results the other way.
"""

from __future__ import annotations

import numpy as np

from segloc_cli.config import ExtractParams
from segloc_cli.jit import njit
from segloc_cli.scan import Scan

_DEGENERATE_CHORD_M = 1e-12
"""A chord shorter than this (m) has no direction: the split measures distances to its start."""
_END_POINT_FLOOR_M = 1e-6
"""Least distance (m) at which an end point can be left out of a fit, so that round-off
does not reject the ends of exactly collinear points."""
_PAIRWISE_BLOCK = 128
"""Most values numpy sums as one block before it halves a run (its ``PW_BLOCKSIZE``)."""


# --- public functions -------------------------------------------------------------------------


def breakpoints(ranges_m: np.ndarray, angles_rad: np.ndarray, params: ExtractParams) -> np.ndarray:
    """Boolean (K−1,): True where consecutive valid readings belong to different surfaces.

    ``ranges_m`` (K,) in metres and ``angles_rad`` (K,) in radians, scanner frame.
    Adaptive breakpoint detector: the largest gap between neighbours on one
    surface, seen at incidence λ, is r·sin Δφ / sin(λ − Δφ), plus 3σ of noise.
    Neighbours λ or more apart (missing readings between) are always a breakpoint.
    """
    ranges = np.ascontiguousarray(ranges_m, dtype=float)
    angles = np.ascontiguousarray(angles_rad, dtype=float)
    xs, ys = _points_xy(ranges, angles)
    lam_rad, slack_m = _breakpoint_settings(params)
    return _breaks(ranges, angles, xs, ys, lam_rad, slack_m)


def fit_line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares line through points (K, 2) in metres: (centroid (2,), unit
    direction (2,)), in the points' frame."""
    xs, ys = _columns(points)
    cx, cy, ux, uy = _fit_line(xs, ys, 0, xs.size, np.empty(xs.size))
    return np.array([cx, cy]), np.array([ux, uy])


def line_residuals(points: np.ndarray, centroid: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Distances (K,) in metres of points (K, 2) from the line through ``centroid`` along
    unit ``direction`` (all in one frame)."""
    xs, ys = _columns(points)
    residuals = np.empty(xs.size)
    _residuals_into(xs, ys, 0, xs.size, *_line_of(centroid, direction), residuals)
    return residuals


def direction_sigma_rad(
    points: np.ndarray, centroid: np.ndarray, direction: np.ndarray, range_sigma_m: float
) -> float:
    """Standard error (radians) of the direction of the line fitted to ``points`` (K, 2).

    For a total-least-squares line, σ_dir ≈ σ / √Σ tᵢ², with tᵢ the points'
    positions along the line from the centroid and σ the points' noise across
    it: the scanner's ``range_sigma_m``, or the fit's own residual RMS (K − 2
    degrees of freedom) where that is larger, as on a rough or curved surface.
    Few readings far apart fix a direction as well as many close together.
    """
    xs, ys = _columns(points)
    line = _line_of(centroid, direction)
    return _direction_sigma(xs, ys, 0, xs.size, *line, float(range_sigma_m), np.empty(xs.size))


def extract_segments(scan: Scan, params: ExtractParams | None = None) -> np.ndarray:
    """Local map (N, 4) in metres, robot frame, from ``scan``. Empty (0, 4) if nothing qualifies.

    The segments are found in the scanner's frame, where the readings' polar geometry
    holds, and placed in the robot frame by the scan's mounting (``Scan.to_robot``).
    """
    params = params or ExtractParams()
    all_angles = np.asarray(scan.angles_rad, dtype=float)
    valid = scan.valid & np.isfinite(all_angles)
    ranges = np.asarray(scan.ranges_m, dtype=float)[valid]
    angles = all_angles[valid]
    if ranges.size < params.min_points:
        return np.zeros((0, 4))
    lam_rad, slack_m = _breakpoint_settings(params)
    segments_scanner = _extract(
        ranges,
        angles,
        lam_rad,
        slack_m,
        float(max(params.split_m, 3.0 * params.range_sigma_m)),
        int(params.min_points),
        float(params.min_length_m),
        float(np.deg2rad(params.max_direction_sigma_deg)),
        float(params.range_sigma_m),
    )
    return scan.to_robot(segments_scanner)


def _breakpoint_settings(params: ExtractParams) -> tuple[float, float]:
    """(incidence λ in radians, slack 3σ in metres) of the breakpoint detector."""
    return float(np.deg2rad(params.breakpoint_lambda_deg)), float(3 * params.range_sigma_m)


def _columns(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The x and y columns (K,) of points (K, 2), contiguous float arrays for the kernels."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    return np.ascontiguousarray(points[:, 0]), np.ascontiguousarray(points[:, 1])


def _line_of(centroid: np.ndarray, direction: np.ndarray) -> tuple[float, float, float, float]:
    """A line as the kernels take it: (centroid x, y, unit direction x, y)."""
    return float(centroid[0]), float(centroid[1]), float(direction[0]), float(direction[1])


# --- the scan kernel --------------------------------------------------------------------------


@njit(cache=True, error_model="numpy")
def _extract(
    ranges: np.ndarray,
    angles: np.ndarray,
    lam_rad: float,
    slack_m: float,
    tol_m: float,
    min_points: int,
    min_length_m: float,
    max_sigma_rad: float,
    range_sigma_m: float,
) -> np.ndarray:
    """Segments (N, 4) in metres, scanner frame, from the valid readings of a scan (K,).

    ``tol_m`` is the split and merge tolerance; the other settings are those of
    ``ExtractParams`` in the units their names give.
    """
    count = ranges.size
    xs, ys = _points_xy(ranges, angles)
    breaks = _breaks(ranges, angles, xs, ys, lam_rad, slack_m)
    wraps = _closes_ring(ranges, angles, lam_rad, slack_m)
    if wraps:
        # Indices of the runs that cross reading 0 go on into a second copy of the points.
        xs = np.concatenate((xs, xs))
        ys = np.concatenate((ys, ys))
    scratch = np.empty(xs.size)
    # Pieces of a run overlap by one point and hold at least two: at most K of them in all.
    segments = np.empty((count, 4))
    kept = 0
    for run in _runs(breaks, count, wraps):
        start, stop = run[0], run[1]
        if stop - start < min_points:
            continue
        pieces = pieces_of_run(xs, ys, start, stop, tol_m, scratch)
        if wraps and stop - start == count:
            pieces = _rejoin_across_seam(xs, ys, pieces, count, tol_m, scratch)
        for piece in pieces:
            if piece[1] - piece[0] < min_points:
                continue
            if segment_of_piece(
                xs,
                ys,
                piece[0],
                piece[1],
                min_points,
                min_length_m,
                max_sigma_rad,
                range_sigma_m,
                scratch,
                segments[kept],
            ):
                kept += 1
    return segments[:kept].copy()


@njit(cache=True, error_model="numpy")
def _points_xy(ranges: np.ndarray, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Readings (K,) (metres, radians) as point coordinates x (K,) and y (K,) in metres."""
    return ranges * np.cos(angles), ranges * np.sin(angles)


@njit(cache=True, error_model="numpy")
def _breaks(
    ranges: np.ndarray,
    angles: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    lam_rad: float,
    slack_m: float,
) -> np.ndarray:
    """The kernel of ``breakpoints``: readings (K,) and their points → boolean (K−1,)."""
    breaks = np.empty(max(ranges.size - 1, 0), dtype=np.bool_)
    for i in range(breaks.size):
        dphi = abs(angles[i + 1] - angles[i])
        clearance = lam_rad - dphi
        if clearance < 1e-9:  # a NaN stays NaN, as with numpy's maximum
            clearance = 1e-9
        d_max = ranges[i] * np.sin(dphi) / np.sin(clearance) + slack_m
        gap = np.hypot(xs[i + 1] - xs[i], ys[i + 1] - ys[i])
        breaks[i] = gap > d_max or dphi >= lam_rad
    return breaks


@njit(cache=True, error_model="numpy")
def _closes_ring(ranges: np.ndarray, angles: np.ndarray, lam_rad: float, slack_m: float) -> bool:
    """Whether the readings (K ≥ 1,) make a full revolution whose last and first readings are
    neighbours on one surface (no breakpoint between them)."""
    step = _median_step(angles)
    span = (angles[-1] - angles[0]) % (2 * np.pi)
    closing_gap = 2 * np.pi - span
    if not (step > 0 and closing_gap <= 1.5 * step):
        return False
    pair_ranges = np.array([ranges[-1], ranges[0]])
    pair_angles = np.array([angles[-1], angles[-1] + closing_gap])
    pair_xs, pair_ys = _points_xy(pair_ranges, pair_angles)
    return not _breaks(pair_ranges, pair_angles, pair_xs, pair_ys, lam_rad, slack_m)[0]


@njit(cache=True, error_model="numpy")
def _median_step(angles: np.ndarray) -> float:
    """Median (radians) of the steps between consecutive angles (K,), 0 for one angle:
    the value ``np.median`` gives (the mean of the middle two for an even count)."""
    steps = np.empty(max(angles.size - 1, 0))
    if steps.size == 0:
        return 0.0
    for i in range(steps.size):
        steps[i] = abs(angles[i + 1] - angles[i])
    steps.sort()
    middle = steps.size // 2
    if steps.size % 2:
        return steps[middle]
    return (steps[middle - 1] + steps[middle]) / 2


@njit(cache=True, error_model="numpy")
def _runs(breaks: np.ndarray, count: int, wraps: bool) -> np.ndarray:
    """Index ranges [start, stop) (R, 2) of the unbroken runs of ``count`` points.

    ``wraps``: the last run joins the first, as the range (last start, first stop + count).
    """
    cuts = 0
    for i in range(breaks.size):
        cuts += breaks[i]
    runs = np.empty((cuts + 1, 2), dtype=np.int64)
    found = 0
    begin = 0
    for i in range(breaks.size):
        if breaks[i]:
            runs[found, 0], runs[found, 1] = begin, i + 1
            found += 1
            begin = i + 1
    runs[found, 0], runs[found, 1] = begin, count
    found += 1
    if wraps and found > 1:
        runs[0, 0], runs[0, 1] = runs[found - 1, 0], runs[0, 1] + count
        found -= 1
    return runs[:found]


# --- split and merge --------------------------------------------------------------------------


@njit(cache=True, error_model="numpy")
def pieces_of_run(
    xs: np.ndarray, ys: np.ndarray, start: int, stop: int, tol_m: float, scratch: np.ndarray
) -> np.ndarray:
    """Index ranges (P, 2) of the pieces of points [start, stop), split and merged, in order."""
    pieces = np.empty((stop - start, 2), dtype=np.int64)
    found = split_points(xs, ys, start, stop, tol_m, pieces)
    return pieces[: _merge(xs, ys, pieces, found, tol_m, scratch)]


@njit(cache=True, error_model="numpy")
def split_points(
    xs: np.ndarray, ys: np.ndarray, start: int, stop: int, tol_m: float, pieces: np.ndarray
) -> int:
    """Recursive end-point fit on points [start, stop): writes the pieces' index ranges into
    ``pieces`` in scan order and returns how many. A split point starts the second half
    and ends the first."""
    # Pending ranges hold two points or more and overlap by one: at most stop − start of them.
    pending = np.empty((stop - start + 1, 2), dtype=np.int64)
    pending[0, 0], pending[0, 1] = start, stop
    depth = 1
    found = 0
    while depth > 0:
        depth -= 1
        i0, i1 = pending[depth, 0], pending[depth, 1]
        k = _farthest_from_chord(xs, ys, i0, i1, tol_m)
        if 0 < k < i1 - i0 - 1:
            # Pushed in reverse to keep scan order.
            pending[depth, 0], pending[depth, 1] = i0 + k, i1
            pending[depth + 1, 0], pending[depth + 1, 1] = i0, i0 + k + 1
            depth += 2
        else:
            pieces[found, 0], pieces[found, 1] = i0, i1
            found += 1
    return found


@njit(cache=True, error_model="numpy")
def _farthest_from_chord(xs: np.ndarray, ys: np.ndarray, i0: int, i1: int, tol_m: float) -> int:
    """Offset from ``i0`` of the first point of [i0, i1) farthest from the chord between its
    ends, or −1 when there are two points or fewer or none lies more than ``tol_m`` off."""
    if i1 - i0 <= 2:
        return -1
    ax, ay = xs[i0], ys[i0]
    chord_x, chord_y = xs[i1 - 1] - ax, ys[i1 - 1] - ay
    norm = np.hypot(chord_x, chord_y)
    farthest = 0
    largest = -np.inf
    for k in range(i1 - i0):
        sx, sy = xs[i0 + k] - ax, ys[i0 + k] - ay
        if norm < _DEGENERATE_CHORD_M:
            dist = np.hypot(sx, sy)
        else:
            dist = abs(sx * chord_y - sy * chord_x) / norm
        if dist > largest:
            farthest, largest = k, dist
    return farthest if largest > tol_m else -1


@njit(cache=True, error_model="numpy")
def _merge(
    xs: np.ndarray,
    ys: np.ndarray,
    pieces: np.ndarray,
    count: int,
    tol_m: float,
    scratch: np.ndarray,
) -> int:
    """Join neighbouring pieces (in place) whose union still fits one line within ``tol_m``;
    returns how many pieces are left."""
    merged = 0
    for p in range(count):
        i0, i1 = pieces[p, 0], pieces[p, 1]
        if (
            merged > 0
            and pieces[merged - 1, 1] >= i0
            and _fits_one_line(xs, ys, pieces[merged - 1, 0], i1, tol_m, scratch)
        ):
            pieces[merged - 1, 1] = i1
            continue
        pieces[merged, 0], pieces[merged, 1] = i0, i1
        merged += 1
    return merged


@njit(cache=True, error_model="numpy")
def _rejoin_across_seam(
    xs: np.ndarray,
    ys: np.ndarray,
    pieces: np.ndarray,
    count: int,
    tol_m: float,
    scratch: np.ndarray,
) -> np.ndarray:
    """Pieces (P, 2) of a run once round the ring of ``count`` points, with the last and
    first joined into one (the last's start, the first's stop + count) when they fit one
    line: a ring without breakpoints was cut at reading 0, across a wall.

    A ring with one breakpoint is one such run too, from the breakpoint round to it,
    so there the join is across the breakpoint, and its range can run past the end of
    the points' second copy (it is cut there, see ``_clipped``).
    """
    last = pieces.shape[0] - 1
    if last < 1 or not _fits_one_line(
        xs, ys, pieces[last, 0], pieces[0, 1] + count, tol_m, scratch
    ):
        return pieces
    pieces[0, 0], pieces[0, 1] = pieces[last, 0], pieces[0, 1] + count
    return pieces[:last]


@njit(cache=True, error_model="numpy")
def _fits_one_line(
    xs: np.ndarray, ys: np.ndarray, start: int, stop: int, tol_m: float, scratch: np.ndarray
) -> bool:
    """Whether points [start, stop), less its two end points, fit one line within ``tol_m``.

    The end points are left out because a split point is shared by both of its
    pieces, and a corner reading belongs to the next wall as much as to this one.
    """
    if stop - start > 4:
        start, stop = start + 1, stop - 1
    start, stop = _clipped(start, stop, xs.size)
    if stop == start:  # no points, no line
        return False
    cx, cy, ux, uy = _fit_line(xs, ys, start, stop, scratch)
    largest = 0.0
    for i in range(start, stop):
        largest = max(largest, _residual(xs[i], ys[i], cx, cy, ux, uy))
    return largest <= tol_m


@njit(cache=True, error_model="numpy")
def _clipped(start: int, stop: int, size: int) -> tuple[int, int]:
    """The index range [start, stop) cut to an array of ``size`` as a Python slice cuts it
    (the range that rejoins a ring cut at a breakpoint can run past the second copy)."""
    start = min(start, size)
    return start, max(min(stop, size), start)


# --- fits -------------------------------------------------------------------------------------


@njit(cache=True, error_model="numpy")
def segment_of_piece(
    xs: np.ndarray,
    ys: np.ndarray,
    start: int,
    stop: int,
    min_points: int,
    min_length_m: float,
    max_sigma_rad: float,
    range_sigma_m: float,
    scratch: np.ndarray,
    segment: np.ndarray,
) -> bool:
    """Fit the piece of points [start, stop) and write its segment ``x1 y1 x2 y2`` (the fitted
    line between its end points' projections) into ``segment`` (4,); returns whether the
    piece passes the keep rules (enough points, long enough, direction known well enough)."""
    start, stop = _clipped(start, stop, xs.size)
    cx, cy, ux, uy, start, stop = _fit_piece(xs, ys, start, stop, scratch)
    if stop - start < min_points:
        return False
    t0 = (xs[start] - cx) * ux + (ys[start] - cy) * uy
    t1 = (xs[stop - 1] - cx) * ux + (ys[stop - 1] - cy) * uy
    if abs(t1 - t0) < min_length_m:
        return False
    sigma = _direction_sigma(xs, ys, start, stop, cx, cy, ux, uy, range_sigma_m, scratch)
    if sigma > max_sigma_rad:
        return False
    segment[0], segment[1] = cx + t0 * ux, cy + t0 * uy
    segment[2], segment[3] = cx + t1 * ux, cy + t1 * uy
    return True


@njit(cache=True, error_model="numpy")
def _fit_piece(
    xs: np.ndarray, ys: np.ndarray, start: int, stop: int, scratch: np.ndarray
) -> tuple[float, float, float, float, int, int]:
    """Line through the points [start, stop), leaving out an end point that does not belong.

    Returns (centroid x, y, unit direction x, y, start, stop of the points kept).
    An end point is left out when it lies more than 3 × the interior RMS from the
    interior's line: a corner reading shared with the neighbouring wall would
    otherwise tilt the fit.
    """
    if stop - start > 4:
        cx, cy, ux, uy = _fit_line(xs, ys, start + 1, stop - 1, scratch)
        count = _residuals_into(xs, ys, start + 1, stop - 1, cx, cy, ux, uy, scratch)
        rms = np.sqrt(_numpy_sum_of_squares(scratch, count) / count)
        bound = max(3.0 * rms, _END_POINT_FLOOR_M)
        first_off = _residual(xs[start], ys[start], cx, cy, ux, uy) > bound
        last_off = _residual(xs[stop - 1], ys[stop - 1], cx, cy, ux, uy) > bound
        if first_off:
            start += 1
        if last_off:
            stop -= 1
    cx, cy, ux, uy = _fit_line(xs, ys, start, stop, scratch)
    return cx, cy, ux, uy, start, stop


@njit(cache=True, error_model="numpy")
def _fit_line(
    xs: np.ndarray, ys: np.ndarray, start: int, stop: int, scratch: np.ndarray
) -> tuple[float, float, float, float]:
    """Total-least-squares line through points [start, stop): (centroid x, y, unit
    direction x, y). ``scratch`` holds at least stop − start values."""
    count = stop - start
    # numpy's mean over axis 0 of a (K, 2) array adds row after row, from zero.
    sum_x = 0.0
    sum_y = 0.0
    for i in range(start, stop):
        sum_x += xs[i]
        sum_y += ys[i]
    cx, cy = sum_x / count, sum_y / count
    for i in range(start, stop):
        scratch[i - start] = xs[i] - cx
    sxx = _numpy_sum_of_squares(scratch, count)
    for i in range(start, stop):
        scratch[i - start] = (xs[i] - cx) * (ys[i] - cy)
    sxy = _numpy_sum(scratch, count)
    for i in range(start, stop):
        scratch[i - start] = ys[i] - cy
    syy = _numpy_sum_of_squares(scratch, count)
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    return cx, cy, np.cos(phi), np.sin(phi)


@njit(cache=True, error_model="numpy")
def _residual(x: float, y: float, cx: float, cy: float, ux: float, uy: float) -> float:
    """Distance (m) of the point (x, y) from the line through (cx, cy) along unit (ux, uy)."""
    return abs((x - cx) * uy - (y - cy) * ux)


@njit(cache=True, error_model="numpy")
def _residuals_into(
    xs: np.ndarray,
    ys: np.ndarray,
    start: int,
    stop: int,
    cx: float,
    cy: float,
    ux: float,
    uy: float,
    out: np.ndarray,
) -> int:
    """Distances (m) of points [start, stop) from a line, written to ``out[: stop − start]``;
    returns how many."""
    for i in range(start, stop):
        out[i - start] = _residual(xs[i], ys[i], cx, cy, ux, uy)
    return stop - start


@njit(cache=True, error_model="numpy")
def _direction_sigma(
    xs: np.ndarray,
    ys: np.ndarray,
    start: int,
    stop: int,
    cx: float,
    cy: float,
    ux: float,
    uy: float,
    range_sigma_m: float,
    scratch: np.ndarray,
) -> float:
    """The kernel of ``direction_sigma_rad`` for points [start, stop) and their line."""
    count = stop - start
    for i in range(start, stop):
        scratch[i - start] = (xs[i] - cx) * ux + (ys[i] - cy) * uy
    spread = np.sqrt(_numpy_sum_of_squares(scratch, count))
    if spread == 0.0:
        return np.inf
    _residuals_into(xs, ys, start, stop, cx, cy, ux, uy, scratch)
    rms = np.sqrt(_numpy_sum_of_squares(scratch, count) / max(count - 2, 1))
    return max(range_sigma_m, rms) / spread


# --- sums in numpy's order --------------------------------------------------------------------


@njit(cache=True, error_model="numpy")
def _numpy_sum_of_squares(values: np.ndarray, count: int) -> float:
    """Σ values[:count]² in numpy's order (squares ``values`` in place)."""
    for i in range(count):
        values[i] = values[i] * values[i]
    return _numpy_sum(values, count)


@njit(cache=True, error_model="numpy")
def _numpy_sum(values: np.ndarray, count: int) -> float:
    """Σ values[:count] added as ``np.sum`` adds a contiguous 1-D array: pairwise, from +0."""
    return 0.0 + _pairwise_sum(values, count)


@njit(cache=True, error_model="numpy")
def _pairwise_sum(values: np.ndarray, count: int) -> float:
    """numpy's pairwise summation of values[:count], to the bit.

    Up to 128 values are one block (``_pairwise_block``). numpy halves a longer
    run, the first half a multiple of 8 long, and adds the halves' sums; the
    halving is done here on explicit stacks, as numba cannot cache a recursive kernel.
    """
    if count <= _PAIRWISE_BLOCK:
        return _pairwise_block(values, np.int64(0), count)  # one specialization, no literal 0
    # Runs to sum, as (start, length, whether its halves are summed); each level of halving
    # leaves at most two on the stack, and a length below 2**63 has fewer than 64 levels.
    runs = np.empty((128, 3), dtype=np.int64)
    sums = np.empty(64)
    runs[0, 0], runs[0, 1], runs[0, 2] = 0, count, 0
    pending = 1
    summed = 0
    while pending > 0:
        pending -= 1
        start, length, halved = runs[pending, 0], runs[pending, 1], runs[pending, 2]
        if length <= _PAIRWISE_BLOCK:
            sums[summed] = _pairwise_block(values, start, length)
            summed += 1
        elif halved:
            summed -= 1
            sums[summed - 1] = sums[summed - 1] + sums[summed]
        else:
            half = length // 2
            half -= half % 8
            # Popped in reverse: the first half, then the second, then their sum.
            runs[pending, 0], runs[pending, 1], runs[pending, 2] = start, length, 1
            runs[pending + 1, 0], runs[pending + 1, 1], runs[pending + 1, 2] = (
                start + half,
                length - half,
                0,
            )
            runs[pending + 2, 0], runs[pending + 2, 1], runs[pending + 2, 2] = start, half, 0
            pending += 3
    return sums[0]


@njit(cache=True, error_model="numpy")
def _pairwise_block(values: np.ndarray, start: int, count: int) -> float:
    """numpy's sum of values[start : start + count] for up to 128 values: fewer than 8 one
    after another; more in eight interleaved partial sums, combined as a tree, and then
    the remainder one after another."""
    if count < 8:
        total = -0.0
        for i in range(start, start + count):
            total += values[i]
        return total
    s0, s1, s2, s3 = values[start], values[start + 1], values[start + 2], values[start + 3]
    s4, s5, s6, s7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
    i = start + 8
    blocks_end = start + count - count % 8
    while i < blocks_end:
        s0 += values[i]
        s1 += values[i + 1]
        s2 += values[i + 2]
        s3 += values[i + 3]
        s4 += values[i + 4]
        s5 += values[i + 5]
        s6 += values[i + 6]
        s7 += values[i + 7]
        i += 8
    total = ((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))
    while i < start + count:
        total += values[i]
        i += 1
    return total
