"""Tracking along a log: each scan starts from the previous estimate moved by the odometry.

Where ``localize.py`` treats every scan on its own, a track carries each
answer on to the next scan, checks every match against the odometry (how
far it may correct the dead-reckoning guess) and widens the search when a
match fails, so one bad scan does not end the track.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import replace

import numpy as np

from segloc_cli.config import ExtractParams, RefineParams, TrackParams
from segloc_cli.estimates import (
    ESTIMATED,
    STATUS_AMBIGUOUS,
    STATUS_LOST,
    STATUS_NO_OVERLAP,
    STATUS_OK,
    STATUS_RECOVERED,
    STATUS_TOO_FEW_SEGMENTS,
    EstimateRow,
)
from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.localize import (
    Estimate,
    Localizer,
    estimate_row,
    scan_is_degenerate,
    untrusted,
    usable_points,
)
from segloc_cli.method.refine import inlier_ratio, refine_pose
from segloc_cli.scan import Scan

__all__ = ["TrackParams", "track_scans"]


def track_scans(
    scans: Sequence[Scan],
    odometry: Sequence[Pose2],
    first_guess: Pose2,
    pose_ids: Sequence[int] | np.ndarray,
    localizer: Localizer,
    extract_params: ExtractParams | None = None,
    track: TrackParams | None = None,
) -> Iterator[EstimateRow]:
    """Track along a log: each scan's guess is the previous estimate moved by the odometry since.

    ``odometry`` holds the dead-reckoning pose at each scan (any world frame:
    only increments are used); ``first_guess`` seeds the first scan.

    With refinement on, the scan's points are fitted from the guess with the
    odometry as a prior (it holds the pose where the points say nothing, as
    along a corridor); with it off, the two stages run from the guess. A match
    is accepted when enough of the scan lies on the map and the correction of
    the guess is plausible. Otherwise a wider search is tried (status
    ``recovered`` if it passes): the two stages with the grid, heading window
    and jump limits widened and, as odometry errs most in heading, fits from
    the guessed position at stage 1's headings and at a fan of headings around
    the guess. Failing that the scan is ``lost``, the dead-reckoning guess
    carries the track on, and the next scan's recovery search is wider still.
    A scan with fewer than ``min_points`` points or points along one line
    (``scan_is_degenerate``) is ``too_few_segments`` and the guess carries on
    through it likewise; with refinement on, the local segments are not
    counted, since the odometry prior holds what a corridor's two walls
    cannot.
    """
    track = track or TrackParams()
    p = localizer.params
    wider: dict[float, Localizer] = {}  # recovery localizers by widening factor

    def widened(factor: float) -> Localizer:
        if factor not in wider:
            window = None if p.window_deg is None else min(180.0, p.window_deg * factor)
            wider[factor] = localizer.with_params(
                replace(p, grid_m=p.grid_m * factor, window_deg=window)
            )
        return wider[factor]

    lost_in_a_row = 0
    previous: tuple[Pose2, Pose2] | None = None  # (estimate, odometry) at the previous scan
    for scan, odom, pose_id in zip(scans, odometry, pose_ids, strict=True):
        t0 = time.perf_counter()
        guess, increment = first_guess, None
        if previous is not None:
            increment = previous[1].inverse().compose(odom)
            guess = previous[0].compose(increment)
        local = extract_segments(scan, extract_params)
        points = usable_points(scan.points())
        est = _track_match(localizer, local, points, guess, increment, track)
        status = est.status
        # The first guess may be rough: only its overlap is checked, not the jump.
        scale = 1.0 if previous is not None else np.inf
        if scan_is_degenerate(points, local, p):
            est = untrusted(est)
            status = est.status  # the guess carries on, as for a lost scan
        elif status in (STATUS_OK, STATUS_NO_OVERLAP) and not _accepted(est, guess, track, scale):
            factor = track.widen ** min(lost_in_a_row + 1, track.max_widenings)
            wide = widened(factor)
            candidates = [_measured(localizer, wide.localize(local, guess, points), points)]
            candidates += _heading_fits(wide, local, points, guess, track, factor)
            passing = [c for c in candidates if _accepted(c, guess, track, scale * factor)]
            if passing:
                est = max(passing, key=lambda c: c.inlier_ratio)
                status = STATUS_RECOVERED
            else:
                status = STATUS_LOST
        if status != STATUS_TOO_FEW_SEGMENTS:  # a scan that says nothing leaves the count
            lost_in_a_row = lost_in_a_row + 1 if status == STATUS_LOST else 0
        if status in ESTIMATED:
            carried = est.pose
            # Along a corridor the odometry, not the scan, fixes the position: say so.
            hold = localizer.hold_points(points, est.pose)
            if hold < p.confidence.min_hold_points:
                status = STATUS_AMBIGUOUS
        else:
            carried = guess
            est = replace(est, pose=guess)
        previous = (carried, odom)
        yield estimate_row(pose_id, scan, guess, est, (time.perf_counter() - t0) * 1e3, status)


def _track_match(
    localizer: Localizer,
    local: np.ndarray,
    points: np.ndarray,
    guess: Pose2,
    increment: Pose2 | None,
    track: TrackParams,
) -> Estimate:
    """The first match of a tracked scan, with its inlier share measured; ``points`` are the
    scan's usable points (``usable_points``), robot frame."""
    p = localizer.params
    if p.refine is None:
        return _measured(localizer, localizer.localize(local, guess), points)
    sigma_m, sigma_deg = (None, None) if increment is None else track.prior(increment)
    fit = refine_pose(
        points,
        localizer.segments_world,
        guess,
        replace(p.refine, prior_sigma_m=sigma_m, prior_sigma_deg=sigma_deg),
        index=localizer.prepared.near_index,
    )
    return Estimate(
        pose=fit.pose,
        status=STATUS_OK,
        n_local_segments=int(local.shape[0]),
        stage2_pose=guess,
        inlier_ratio=fit.inlier_ratio,
    )


HEADING_STEP_DEG = 10.0
"""Spacing of the headings tried around the guess when a tracked match fails."""


def _heading_fits(
    localizer: Localizer,
    local: np.ndarray,
    points: np.ndarray,
    guess: Pose2,
    track: TrackParams,
    factor: float,
) -> list[Estimate]:
    """Fits from the guessed position at other headings, the position held by a prior.

    The headings are stage 1's peaks and a fan every ``HEADING_STEP_DEG``
    within the widened jump limit: on sparse scans stage 1 can miss by more
    than the fit's reach, and odometry errs most in heading (a slipping turn).
    """
    if localizer.params.refine is None:
        return []
    reach = min(180.0, track.max_jump_deg * factor)
    fan = np.deg2rad(np.arange(-reach, reach + 1e-9, HEADING_STEP_DEG))
    headings = guess.theta + fan
    if local.shape[0] >= localizer.params.min_segments:
        headings = np.concatenate([localizer.headings(local, guess), headings])
    params = replace(localizer.params.refine, prior_sigma_m=track.max_jump_m * factor / 4.0)
    out, n_local, near = [], int(local.shape[0]), localizer.prepared.near_index
    for heading in headings:
        start = Pose2(guess.x, guess.y, float(wrap_angle(heading)))
        fit = refine_pose(points, localizer.segments_world, start, params, index=near)
        out.append(
            Estimate(
                pose=fit.pose,
                status=STATUS_OK,
                n_local_segments=n_local,
                align_theta_rad=start.theta,
                stage2_pose=start,
                inlier_ratio=fit.inlier_ratio,
            )
        )
    return out


def _measured(localizer: Localizer, est: Estimate, points: np.ndarray) -> Estimate:
    """``est`` with its inlier share filled in where refinement did not measure it."""
    if est.status != STATUS_OK or np.isfinite(est.inlier_ratio):
        return est
    band = (localizer.params.refine or RefineParams()).final_gate_m
    near = localizer.prepared.near_index
    ratio = inlier_ratio(points, localizer.segments_world, est.pose, band, index=near)
    return replace(est, inlier_ratio=ratio)


def _accepted(est: Estimate, guess: Pose2, track: TrackParams, scale: float) -> bool:
    """Whether a tracked match passes the inlier and plausible-jump checks.

    The search's own verdict (``ambiguous``, ``lost``) is not asked: along a
    track the odometry, through the jump limits, decides among look-alikes.
    """
    if not np.isfinite(est.pose.x) or not est.inlier_ratio >= track.min_inlier_ratio:
        return False
    jump_m = np.hypot(est.pose.x - guess.x, est.pose.y - guess.y)
    jump_deg = abs(np.rad2deg(wrap_angle(est.pose.theta - guess.theta)))
    return bool(jump_m <= track.max_jump_m * scale and jump_deg <= track.max_jump_deg * scale)
