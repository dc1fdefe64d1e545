"""Several scans as one local map: a scan with the neighbours the odometry places around it.

A single scan of a corridor cannot tell two places a metre or two apart, but
the scans taken just before and after it, seen from elsewhere along the way,
often can. For each scan to localize, the window takes the scans of the log
within ``WindowParams.travel_m`` of odometry travel before and after it (and
within ``max_time_s``), one every ``spacing_m`` or ``spacing_deg`` of motion,
and places them in the scan's own frame by the odometry between them.

Odometry slips, so no neighbour is trusted as placed: each is fitted to the
segments of the scans already placed, nearest in the log first, with the
odometry as a prior whose spread grows with the distance from the scan
(``TrackParams.prior``), and a neighbour whose fit moves it farther than
``max_correction_m`` or turns it more than ``max_correction_deg`` is left out:
a window spans a metre and a few seconds, over which odometry slips less, so
a larger correction is the fit's slip (a few segments can hold a scan at a
wrong angle), not the odometry's. So is a neighbour that, fitted, puts less than
``min_agreement`` of its points on the scans placed before it, counting only the
points within ``max_correction_m`` of them: where the two overlap, a scan a
metre away sees the same walls, and what lies farther off is what the window has
not seen yet, which says nothing either way. Their points then join
the scan's own wherever they fall in a cell (``thin_m``) the scan and the
neighbours before them left empty: what the window adds is what the scan did
not see, so a window costs what it adds, not what it repeats.

The combined local map is in the scan's robot frame, so a pose found for it is
the scan's pose; its verdict weighs every scan of the window, and a rival that
explains the scan but not its neighbours falls behind.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from segloc_cli.config import ExtractParams, RefineParams, TrackParams, WindowParams
from segloc_cli.geometry import Pose2, transform_points, transform_segments, wrap_angle
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.refine import refine_pose, support
from segloc_cli.scan import Scan


@dataclass(frozen=True)
class Neighbour:
    """A scan of the window other than the one localized: its valid points and local
    segments (its robot frame), and where the odometry puts it in the localized scan's robot
    frame."""

    points: np.ndarray
    segments: np.ndarray
    odometry: Pose2


@dataclass(frozen=True)
class WindowMap:
    """The local map of a window, in the localized scan's robot frame: points (P, 2) and
    segments (N, 4), metres; ``scans``: how many scans it holds (1: the scan alone)."""

    points: np.ndarray
    segments: np.ndarray
    scans: int


@dataclass(frozen=True)
class Windows:
    """The windows of the scans a run localizes: for each, its neighbours as (scan, pose in
    the localized scan's robot frame by the odometry), nearest in the log first; ``params``
    choose and thin them, ``odometry`` says how far the odometry may have slipped."""

    neighbours: Sequence[Sequence[tuple[Scan, Pose2]]]
    params: WindowParams
    odometry: TrackParams

    def block(self, start: int, stop: int) -> Windows:
        """The windows of the scans ``start`` to ``stop`` (exclusive)."""
        return replace(self, neighbours=self.neighbours[start:stop])


def scan_window_map(
    points: np.ndarray,
    segments: np.ndarray,
    neighbours: Sequence[tuple[Scan, Pose2]],
    windows: Windows,
    extract_params: ExtractParams | None = None,
    refine: RefineParams | None = None,
) -> WindowMap:
    """``window_map`` of one scan's points (P, 2) and segments (N, 4), robot frame, with its
    ``neighbours``' points and segments extracted here."""
    placed = [
        Neighbour(scan.points(), extract_segments(scan, extract_params), pose)
        for scan, pose in neighbours
    ]
    return window_map(points, segments, placed, windows.params, refine, windows.odometry)


def neighbour_indices(
    odometry: np.ndarray, times_s: np.ndarray, target: int, params: WindowParams
) -> list[int]:
    """The scans of a window around scan ``target``, nearest in the log first.

    ``odometry`` (S, 3) holds each scan's odometry pose (``x_m, y_m, theta_rad``, any fixed
    frame; NaN where the scan has none) and ``times_s`` (S,) its time. Walking away from
    ``target`` on each side, a scan is taken once the odometry has moved ``spacing_m`` or
    turned ``spacing_deg`` since the last scan taken on that side; the walk stops past
    ``travel_m`` of travel along the way, past ``max_time_s``, at a scan without odometry,
    or once ``max_scans`` // 2 scans are taken on that side.
    """
    if params.travel_m <= 0 or not np.all(np.isfinite(odometry[target])):
        return []
    per_side = params.max_scans // 2
    spacing_rad = np.deg2rad(params.spacing_deg)
    sides: list[list[int]] = []
    for step in (-1, 1):
        taken: list[int] = []
        last = odometry[target]
        travelled = 0.0
        j = target + step
        while 0 <= j < len(odometry) and len(taken) < per_side:
            here = odometry[j]
            if (
                not np.all(np.isfinite(here))
                or abs(times_s[j] - times_s[target]) > params.max_time_s
            ):
                break
            travelled += float(np.hypot(*(here[:2] - odometry[j - step][:2])))
            if travelled > params.travel_m:
                break
            turned = abs(float(wrap_angle(here[2] - last[2])))
            if np.hypot(*(here[:2] - last[:2])) >= params.spacing_m or turned >= spacing_rad:
                taken.append(j)
                last = here
            j += step
        sides.append(taken)
    before, after = sides
    order = []
    for k in range(max(len(before), len(after))):
        order += [side[k] for side in (before, after) if k < len(side)]
    return order


def relative_pose(odometry: np.ndarray, target: int, other: int) -> Pose2:
    """Where the odometry puts scan ``other`` in the robot frame of scan ``target``."""
    return Pose2(*odometry[target]).inverse().compose(Pose2(*odometry[other]))


def window_map(
    points: np.ndarray,
    segments: np.ndarray,
    neighbours: list[Neighbour],
    params: WindowParams,
    refine: RefineParams | None = None,
    track: TrackParams | None = None,
) -> WindowMap:
    """The scan's points (P, 2) and segments (N, 4), robot frame, with its ``neighbours``
    fitted to each other and added (see the module's docstring)."""
    refine = refine or RefineParams()
    track = track or TrackParams()
    placed_segments = [np.asarray(segments, dtype=float).reshape(-1, 4)]
    placed_points = [np.asarray(points, dtype=float).reshape(-1, 2)]
    occupied = set(_cells(placed_points[0], params.thin_m))
    for neighbour in neighbours:
        fitted = _fitted(neighbour, np.vstack(placed_segments), params, refine, track)
        if fitted is None:
            continue
        moved = transform_points(neighbour.points, fitted)
        keys = _cells(moved, params.thin_m)
        new = np.array([key not in occupied for key in keys], dtype=bool)
        # A cell fills once: later neighbours' points in it add nothing the window lacks.
        occupied.update(keys)
        placed_points.append(moved[new])
        placed_segments.append(transform_segments(neighbour.segments, fitted))
    return WindowMap(np.vstack(placed_points), np.vstack(placed_segments), len(placed_points))


def _fitted(
    neighbour: Neighbour,
    reference: np.ndarray,
    params: WindowParams,
    refine: RefineParams,
    track: TrackParams,
) -> Pose2 | None:
    """The neighbour's pose fitted to the ``reference`` segments from its odometry pose (the
    odometry a prior of ``track``'s spread for that motion), or None when the fit corrects
    the odometry by more than it could have slipped (``max_correction_m``, ``_deg``) or
    leaves too few of its points on them (``min_agreement``)."""
    if neighbour.points.shape[0] == 0:
        return None  # it would add nothing
    if reference.shape[0] == 0:
        return neighbour.odometry
    sigma_m, sigma_deg = track.prior(neighbour.odometry)
    fit = refine_pose(
        neighbour.points,
        reference,
        neighbour.odometry,
        replace(refine, prior_sigma_m=sigma_m, prior_sigma_deg=sigma_deg),
    )
    shift = np.hypot(fit.pose.x - neighbour.odometry.x, fit.pose.y - neighbour.odometry.y)
    turn = abs(np.rad2deg(wrap_angle(fit.pose.theta - neighbour.odometry.theta)))
    if shift > params.max_correction_m or turn > params.max_correction_deg:
        return None
    # Agreement is judged where the neighbour overlaps the window: its points farther than
    # any allowed correction from the placed walls see what the window has not, and say
    # nothing either way.
    near, _ = support(neighbour.points, reference, fit.pose, params.max_correction_m)
    if near * neighbour.points.shape[0] < refine.min_points:
        return None
    if fit.inlier_ratio < params.min_agreement * near:
        return None
    return fit.pose


def _cells(points: np.ndarray, cell_m: float) -> list[tuple[int, int]]:
    """The grid cell (``cell_m`` on a side) of each point (K, 2), as hashable pairs."""
    keys = np.floor(np.asarray(points, dtype=float).reshape(-1, 2) / cell_m).astype(np.int64)
    return list(map(tuple, keys))
