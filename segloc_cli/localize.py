"""The two stages together: one local map → one pose, and a whole log → estimates."""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np

from segloc_cli.align import RTable, align
from segloc_cli.extract import ExtractParams, extract_segments
from segloc_cli.geometry import Pose2, point_segment_distances, segment_lengths, wrap_angle
from segloc_cli.overlap import coarse_to_fine, overlap_at_poses
from segloc_cli.scan import Scan

STATUS_OK = "ok"
STATUS_TOO_FEW_SEGMENTS = "too_few_segments"
STATUS_NO_OVERLAP = "no_overlap"
STATUS_RECOVERED = "recovered"
"""Tracking: the first match failed its checks, a wider search passed them."""
STATUS_LOST = "lost"
"""Tracking: no search passed the checks; the pose given is the dead-reckoning guess."""
ESTIMATED = (STATUS_OK, STATUS_RECOVERED)
"""Statuses of rows that hold an accepted estimate; every other status marks a failure."""


@dataclass(frozen=True)
class LocalizeParams:
    """Settings of both stages (paper defaults: Table 1 used η0 = 1.5 m and Δα0 = 4°)."""

    window_deg: float | None = 20.0
    """Stage-1 half window around the prior heading; None scores the whole circle."""
    bin_deg: float = 1.0
    vote: str = "product"
    max_peaks: int = 8
    grid_m: float = 1.5
    dtheta_deg: float = 4.0
    iterations: int = 8
    """Halvings K; the paper leaves K to the accuracy wanted (last grid η0 / 2^(K−1))."""
    ratio: float = 0.9
    recentres: int = 8
    """Extra same-scale iterations while the estimate still moves (0 = the paper's schedule)."""
    min_segments: int = 3


@dataclass(frozen=True)
class Estimate:
    """Outcome for one scan. ``pose`` and ``align_theta_rad`` are NaN-filled when not ok."""

    pose: Pose2
    align_theta_rad: float
    overlap_m: float
    n_local_segments: int
    status: str


NAN_POSE = Pose2(float("nan"), float("nan"), float("nan"))


class Localizer:
    """Localizes local maps against one global map (M, 4), world frame."""

    def __init__(self, segments_world: np.ndarray, params: LocalizeParams | None = None):
        self.params = params or LocalizeParams()
        self.segments_world = np.asarray(segments_world, dtype=float)
        self.rtable = RTable.build(self.segments_world, self.params.bin_deg)

    def _rtable_near(self, initial: Pose2, segments_robot: np.ndarray) -> RTable:
        """The R-table of the map segments the scan could contain, seen from near ``initial``.

        In a large map nearly every orientation bin holds a segment of about
        any length, so every heading collects votes and the peak drowns. When
        the position is roughly known, only segments within the scan's reach
        of where stage 2 may go (the local map's radius plus the search's
        travel, 2·√2·η0) take part. With the whole map in reach this is the
        map's own R-table.
        """
        radius = float(np.hypot(segments_robot[:, 0::2], segments_robot[:, 1::2]).max())
        reach = radius + 2.0 * np.sqrt(2.0) * self.params.grid_m
        near = point_segment_distances([initial.x, initial.y], self.segments_world)[0] <= reach
        if near.all():
            return self.rtable
        return RTable.build(self.segments_world[near], self.params.bin_deg)

    def localize(self, segments_robot: np.ndarray, initial: Pose2) -> Estimate:
        """Estimate the pose at which the local map (N, 4), robot frame, was seen.

        ``initial`` supplies the starting position and, unless the window is
        None, the prior heading for stage 1.
        """
        p = self.params
        n_local = int(segments_robot.shape[0])
        if n_local < p.min_segments:
            return Estimate(NAN_POSE, float("nan"), 0.0, n_local, STATUS_TOO_FEW_SEGMENTS)
        prior = None if p.window_deg is None else initial.theta
        alignment = align(
            self.rtable if prior is None else self._rtable_near(initial, segments_robot),
            segments_robot,
            prior_rad=prior,
            window_deg=p.window_deg or 0.0,
            scheme=p.vote,
            max_peaks=p.max_peaks,
        )
        if alignment.peaks_rad.size == 0:
            return Estimate(NAN_POSE, float("nan"), 0.0, n_local, STATUS_NO_OVERLAP)
        best = None
        for heading in alignment.peaks_rad:
            result = coarse_to_fine(
                self.segments_world,
                segments_robot,
                Pose2(initial.x, initial.y, float(heading)),
                grid_m=p.grid_m,
                dtheta_deg=p.dtheta_deg,
                iterations=p.iterations,
                ratio=p.ratio,
                recentres=p.recentres,
            )
            if best is None or result.overlap_m > best[1].overlap_m:
                best = (float(heading), result)
        heading, result = best
        if result.overlap_m <= 0:
            return Estimate(NAN_POSE, heading, 0.0, n_local, STATUS_NO_OVERLAP)
        return Estimate(result.pose, heading, result.overlap_m, n_local, STATUS_OK)


def _row(pose_id: int, scan: Scan, initial: Pose2, est: Estimate, runtime_ms: float, status: str):
    """One row of the estimates table (``ESTIMATE_COLUMNS``): metres and degrees."""
    return {
        "pose_id": int(pose_id),
        "time_s": scan.time_s,
        "init_x_m": initial.x,
        "init_y_m": initial.y,
        "init_theta_deg": initial.theta_deg,
        "align_theta_deg": float(np.rad2deg(est.align_theta_rad)),
        "x_m": est.pose.x,
        "y_m": est.pose.y,
        "theta_deg": est.pose.theta_deg,
        "overlap": est.overlap_m,
        "n_local_segments": est.n_local_segments,
        "runtime_ms": runtime_ms,
        "status": status,
    }


def localize_scans(
    scans: Sequence[Scan],
    initial_poses: Sequence[Pose2],
    pose_ids: Sequence[int],
    localizer: Localizer,
    extract_params: ExtractParams | None = None,
) -> Iterator[dict]:
    """Localize each scan from its initial guess, yielding one estimates row per scan.

    Rows hold the estimates columns (``ESTIMATE_COLUMNS``): angles in degrees,
    positions in metres, ``runtime_ms`` covering extraction and both stages.
    Yielding row by row lets a caller keep what is done if the run is cut short.
    """
    for scan, initial, pose_id in zip(scans, initial_poses, pose_ids, strict=True):
        t0 = time.perf_counter()
        est = localizer.localize(extract_segments(scan, extract_params), initial)
        yield _row(pose_id, scan, initial, est, (time.perf_counter() - t0) * 1e3, est.status)


@dataclass(frozen=True)
class TrackParams:
    """When a tracked match is accepted (metres, degrees)."""

    min_match_ratio: float = 0.3
    """Share of the local map's length that must overlap the map within ``match_band_m``."""
    match_band_m: float = 0.05
    max_jump_m: float = 0.5
    """Largest correction of the dead-reckoning guess accepted (position)."""
    max_jump_deg: float = 15.0
    widen: float = 2.0
    """The recovery search multiplies the grid, the heading window and the jump limits by this."""


def match_ratio(
    segments_world: np.ndarray, segments_robot: np.ndarray, pose: Pose2, band_m: float
) -> float:
    """Overlap at ``pose`` within ``band_m`` over its largest possible value, 2 × local length."""
    total = 2.0 * float(segment_lengths(segments_robot).sum())
    if total <= 0 or not np.isfinite(pose.x):
        return 0.0
    return (
        float(overlap_at_poses(segments_world, segments_robot, pose.as_array(), band_m)[0]) / total
    )


def track_scans(
    scans: Sequence[Scan],
    odometry: Sequence[Pose2],
    first_guess: Pose2,
    pose_ids: Sequence[int],
    localizer: Localizer,
    extract_params: ExtractParams | None = None,
    track: TrackParams | None = None,
) -> Iterator[dict]:
    """Track along a log: each scan's guess is the previous estimate moved by the odometry since.

    ``odometry`` holds the dead-reckoning pose at each scan (any world frame:
    only increments are used); ``first_guess`` seeds the first scan. A match is
    accepted when enough of the local map overlaps the map and the correction
    of the guess is plausible; otherwise a wider search is tried (status
    ``recovered`` if it passes) and failing that the scan is marked ``lost``
    and the dead-reckoning guess carries the track on. Yields estimates rows.
    """
    track = track or TrackParams()
    p = localizer.params
    wide = Localizer(
        localizer.segments_world,
        replace(
            p,
            grid_m=p.grid_m * track.widen,
            window_deg=None if p.window_deg is None else min(180.0, p.window_deg * track.widen),
        ),
    )
    previous: tuple[Pose2, Pose2] | None = None  # (estimate, odometry) at the previous scan
    for scan, odom, pose_id in zip(scans, odometry, pose_ids, strict=True):
        t0 = time.perf_counter()
        guess = first_guess
        if previous is not None:
            guess = previous[0].compose(previous[1].inverse().compose(odom))
        local = extract_segments(scan, extract_params)
        est = localizer.localize(local, guess)
        status = est.status
        first = previous is None
        if status != STATUS_TOO_FEW_SEGMENTS and not _accepted(
            est, local, guess, localizer, track, 1, first
        ):
            retry = wide.localize(local, guess)
            if _accepted(retry, local, guess, localizer, track, track.widen, first):
                est, status = retry, STATUS_RECOVERED
            else:
                status = STATUS_LOST
        if status in ESTIMATED:
            carried = est.pose
        else:
            carried = guess
            est = replace(est, pose=guess)
        previous = (carried, odom)
        yield _row(pose_id, scan, guess, est, (time.perf_counter() - t0) * 1e3, status)


def _accepted(
    est: Estimate,
    local: np.ndarray,
    guess: Pose2,
    localizer: Localizer,
    track: TrackParams,
    scale: float,
    first: bool,
) -> bool:
    """Whether a tracked match passes the overlap and plausible-jump checks."""
    if est.status != STATUS_OK:
        return False
    ratio = match_ratio(localizer.segments_world, local, est.pose, track.match_band_m)
    if ratio < track.min_match_ratio:
        return False
    if first:
        return True
    jump_m = np.hypot(est.pose.x - guess.x, est.pose.y - guess.y)
    jump_deg = abs(np.rad2deg(wrap_angle(est.pose.theta - guess.theta)))
    return bool(jump_m <= track.max_jump_m * scale and jump_deg <= track.max_jump_deg * scale)
