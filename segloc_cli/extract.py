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
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np

from segloc_cli.config import ExtractParams
from segloc_cli.scan import Scan


def breakpoints(ranges_m: np.ndarray, angles_rad: np.ndarray, params: ExtractParams) -> np.ndarray:
    """Boolean (K−1,): True where consecutive valid readings belong to different surfaces.

    Adaptive breakpoint detector: the largest gap between neighbours on one
    surface, seen at incidence λ, is r·sin Δφ / sin(λ − Δφ), plus 3σ of noise.
    """
    r = np.asarray(ranges_m, dtype=float)
    dphi = np.abs(np.diff(np.asarray(angles_rad, dtype=float)))
    lam = np.deg2rad(params.breakpoint_lambda_deg)
    with np.errstate(invalid="ignore", divide="ignore"):
        d_max = (
            r[:-1] * np.sin(dphi) / np.sin(np.maximum(lam - dphi, 1e-9)) + 3 * params.range_sigma_m
        )
    x = r * np.cos(angles_rad)
    y = r * np.sin(angles_rad)
    gap = np.hypot(np.diff(x), np.diff(y))
    # Neighbours λ or more apart (missing readings between) cannot be shown to be one surface.
    return (gap > d_max) | (dphi >= lam)


def fit_line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares line through points (K, 2): (centroid (2,), unit direction (2,))."""
    centroid = points.mean(axis=0)
    d = points - centroid
    sxx, syy, sxy = (d[:, 0] ** 2).sum(), (d[:, 1] ** 2).sum(), (d[:, 0] * d[:, 1]).sum()
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    return centroid, np.array([np.cos(phi), np.sin(phi)])


def line_residuals(points: np.ndarray, centroid: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Distances (K,) of points from the line through ``centroid`` along unit ``direction``."""
    d = points - centroid
    return np.abs(d[:, 0] * direction[1] - d[:, 1] * direction[0])


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
    t = (points - centroid) @ direction
    spread = float(np.sqrt(np.sum(t**2)))
    if spread == 0.0:
        return np.inf
    residuals = line_residuals(points, centroid, direction)
    rms = float(np.sqrt(np.sum(residuals**2) / max(points.shape[0] - 2, 1)))
    return max(range_sigma_m, rms) / spread


def _split(points: np.ndarray, start: int, stop: int, tol_m: float, out: list[tuple[int, int]]):
    """Recursive end-point fit on points[start:stop]; appends (start, stop) ranges to ``out``."""
    stack = [(start, stop)]
    while stack:
        i0, i1 = stack.pop()
        if i1 - i0 <= 2:
            out.append((i0, i1))
            continue
        a, b = points[i0], points[i1 - 1]
        chord = b - a
        norm = np.hypot(*chord)
        seg = points[i0:i1] - a
        if norm < 1e-12:
            dist = np.hypot(seg[:, 0], seg[:, 1])
        else:
            dist = np.abs(seg[:, 0] * chord[1] - seg[:, 1] * chord[0]) / norm
        k = int(np.argmax(dist))
        if dist[k] > tol_m and 0 < k < i1 - i0 - 1:
            # The split point starts the second half; pushed in reverse to keep scan order.
            stack.append((i0 + k, i1))
            stack.append((i0, i0 + k + 1))
        else:
            out.append((i0, i1))


def _merge(
    points: np.ndarray, ranges: list[tuple[int, int]], tol_m: float
) -> list[tuple[int, int]]:
    """Join neighbouring ranges whose union still fits one line within ``tol_m``."""
    merged: list[tuple[int, int]] = []
    for r in ranges:
        if merged and merged[-1][1] >= r[0] and _fits_one_line(points, merged[-1][0], r[1], tol_m):
            merged[-1] = (merged[-1][0], r[1])
            continue
        merged.append(r)
    return merged


def _fits_one_line(points: np.ndarray, start: int, stop: int, tol_m: float) -> bool:
    """Whether points[start:stop], less its two end points, fit one line within ``tol_m``.

    The end points are left out because a split point is shared by both of its
    pieces, and a corner reading belongs to the next wall as much as to this one.
    """
    pts = points[start + 1 : stop - 1] if stop - start > 4 else points[start:stop]
    return bool(line_residuals(pts, *fit_line(pts)).max() <= tol_m)


def _fit_piece(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Line through a piece's points, leaving out an end point that does not belong.

    Returns (centroid, unit direction, the points kept). An end point is left
    out when it lies more than 3 × the interior RMS from the interior's line:
    a corner reading shared with the neighbouring wall would otherwise tilt the fit.
    """
    if pts.shape[0] > 4:
        interior = pts[1:-1]
        centroid, direction = fit_line(interior)
        rms = np.sqrt(np.mean(line_residuals(interior, centroid, direction) ** 2))
        ends = line_residuals(pts[[0, -1]], centroid, direction)
        keep = np.ones(pts.shape[0], dtype=bool)
        # The 1 µm floor keeps round-off from rejecting ends of exactly collinear points.
        keep[[0, -1]] = ends <= max(3.0 * rms, 1e-6)
        pts = pts[keep]
    centroid, direction = fit_line(pts)
    return centroid, direction, pts


def _chains(points_count: int, breaks: np.ndarray, wraps: bool) -> list[tuple[int, int]]:
    """Index ranges [start, stop) of unbroken runs; ``wraps``: the last run joins the first."""
    cut = np.flatnonzero(breaks) + 1
    bounds = np.concatenate([[0], cut, [points_count]])
    runs = [(int(a), int(b)) for a, b in pairwise(bounds) if b > a]
    if wraps and len(runs) > 1:
        first, last = runs[0], runs[-1]
        runs = [(last[0], first[1] + points_count), *runs[1:-1]]
    return runs


def extract_segments(scan: Scan, params: ExtractParams | None = None) -> np.ndarray:
    """Local map (N, 4) in metres, robot frame, from ``scan``. Empty (0, 4) if nothing qualifies."""
    params = params or ExtractParams()
    all_angles = np.asarray(scan.angles_rad, dtype=float)
    valid = scan.valid & np.isfinite(all_angles)
    ranges = np.asarray(scan.ranges_m, dtype=float)[valid]
    angles = all_angles[valid]
    if ranges.size < params.min_points:
        return np.zeros((0, 4))
    points = np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles)])
    breaks = breakpoints(ranges, angles, params)

    # A full revolution closes on itself: the last and first readings are neighbours.
    step = np.median(np.abs(np.diff(angles))) if angles.size > 1 else 0.0
    span = (angles[-1] - angles[0]) % (2 * np.pi)
    closing_gap = 2 * np.pi - span
    wraps = bool(step > 0 and closing_gap <= 1.5 * step)
    if wraps:
        wrap_ranges = np.array([ranges[-1], ranges[0]])
        wrap_angles = np.array([angles[-1], angles[-1] + closing_gap])
        wraps = not bool(breakpoints(wrap_ranges, wrap_angles, params)[0])
    n = points.shape[0]
    ring = np.concatenate([points, points]) if wraps else points

    tol = max(params.split_m, 3.0 * params.range_sigma_m)
    max_sigma_rad = np.deg2rad(params.max_direction_sigma_deg)
    segments = []
    for start, stop in _chains(n, breaks, wraps):
        if stop - start < params.min_points:
            continue
        pieces: list[tuple[int, int]] = []
        _split(ring, start, stop, tol, pieces)
        pieces = _merge(ring, pieces, tol)
        closed = wraps and stop - start == n
        if (
            closed
            and len(pieces) > 1
            and _fits_one_line(ring, pieces[-1][0], pieces[0][1] + n, tol)
        ):
            # A ring without breakpoints was cut at reading 0: rejoin the wall across it.
            pieces = [(pieces[-1][0], pieces[0][1] + n), *pieces[1:-1]]
        for i0, i1 in pieces:
            if i1 - i0 < params.min_points:
                continue
            centroid, direction, pts = _fit_piece(ring[i0:i1])
            t0 = (pts[0] - centroid) @ direction
            t1 = (pts[-1] - centroid) @ direction
            if (
                pts.shape[0] < params.min_points
                or abs(t1 - t0) < params.min_length_m
                or direction_sigma_rad(pts, centroid, direction, params.range_sigma_m)
                > max_sigma_rad
            ):
                continue
            segments.append(np.concatenate([centroid + t0 * direction, centroid + t1 * direction]))
    return np.array(segments).reshape(-1, 4)
