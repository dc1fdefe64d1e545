"""The two stages together: one local map → one pose, and a whole log → estimates."""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np

from segloc_cli.align import RTable, align
from segloc_cli.confidence import (
    STATUS_AMBIGUOUS,
    STATUS_LOST,
    STATUS_OK,
    ConfidenceParams,
    judge,
)
from segloc_cli.extract import ExtractParams, extract_segments
from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.overlap import coarse_to_fine
from segloc_cli.refine import Refinement, RefineParams, inlier_ratio, refine_pose, support
from segloc_cli.scan import Scan
from segloc_cli.search import HypothesisSearch, SearchParams, distinct
from segloc_cli.spatial import SegmentGrid

STATUS_TOO_FEW_SEGMENTS = "too_few_segments"
"""The scan cannot pin a pose: too few local segments, too few points, or points spread along
one line (``scan_is_degenerate``). A pose found anyway is kept in the row, but not trusted."""
STATUS_NO_OVERLAP = "no_overlap"
STATUS_RECOVERED = "recovered"
"""Tracking: the first match failed its checks, a wider search passed them."""
ESTIMATED = (STATUS_OK, STATUS_RECOVERED)
"""Statuses of rows that hold an accepted estimate; every other status marks a failure.
(``ambiguous`` and ``lost`` rows hold a pose too, the best found, but it is not trusted.)"""


MIN_POINT_SPREAD_M = 0.1
"""Smallest spread (m) of a scan's points across their main direction for a trusted pose.
Every scan of the Intel Research Lab log spreads at least 0.2 m; one wall seen alone, or a
fan whose beams all lie on one ray, spreads about the range noise (a centimetre)."""


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
    """Fewer local segments and the status is ``too_few_segments`` (stage 2 does not run)."""
    min_points: int = 20
    """Fewer valid readings and the status is ``too_few_segments``. The verdict compares
    inlier shares with a margin of 0.1: below 20 points two stray readings would decide it, and
    three segments of extraction's 4 readings each leave little to check a fit against."""
    min_spread_m: float = MIN_POINT_SPREAD_M
    """Points spread less than this across their main direction: ``too_few_segments``."""
    refine: RefineParams | None = field(default_factory=RefineParams)
    """Least-squares fit of the scan's points after stage 2; None stops at stage 2 (the paper)."""
    search: SearchParams | None = field(default_factory=SearchParams)
    """With refinement: also refine the best poses of a search of the prior window by the
    scan's points, and keep the fit that puts them closest to the map."""
    confidence: ConfidenceParams = field(default_factory=ConfidenceParams)


@dataclass(frozen=True)
class Estimate:
    """Outcome for one scan. ``pose`` and ``align_theta_rad`` are NaN-filled when not ok.

    ``stage2_pose`` is where the coarse-to-fine search ended; ``pose`` is the
    refined pose (the same when refinement is off). ``inlier_ratio`` is the
    share of the scan's points on the map at ``pose`` (NaN when not measured).
    ``runner_up`` is the best fit distinct from ``pose`` among the hypotheses
    refined, with its own inlier share (None and NaN when there was none).
    """

    pose: Pose2
    align_theta_rad: float
    overlap_m: float
    n_local_segments: int
    status: str
    stage2_pose: Pose2 | None = None
    inlier_ratio: float = float("nan")
    runner_up: Pose2 | None = None
    runner_up_ratio: float = float("nan")


def usable_points(points_robot: np.ndarray | None) -> np.ndarray | None:
    """The rows (K, 2) of ``points_robot`` with finite coordinates (None stays None)."""
    if points_robot is None:
        return None
    points = np.asarray(points_robot, dtype=float).reshape(-1, 2)
    return points[np.all(np.isfinite(points), axis=1)]


def point_spread_m(points: np.ndarray) -> float:
    """Standard deviation (m) of points (K, 2) across their main direction: the square root of
    the smaller eigenvalue of their covariance; 0 for fewer than two points.

    Near 0 when every point lies on one line (one wall, or every beam along one ray): such a
    scan fixes at most a heading and one offset, never a pose.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    if points.shape[0] < 2:
        return 0.0
    centred = points - points.mean(axis=0)
    sxx, syy = float(np.mean(centred[:, 0] ** 2)), float(np.mean(centred[:, 1] ** 2))
    sxy = float(np.mean(centred[:, 0] * centred[:, 1]))
    smaller = 0.5 * (sxx + syy) - np.hypot(0.5 * (sxx - syy), sxy)
    return float(np.sqrt(max(smaller, 0.0))) if np.isfinite(smaller) else 0.0


def scan_is_degenerate(
    points_robot: np.ndarray | None, segments_robot: np.ndarray, params: LocalizeParams
) -> bool:
    """Whether a scan is too poor to pin a pose: fewer than ``min_points`` usable points, or
    a spread across their main direction under ``min_spread_m``.

    Without points the local segments' endpoints stand in for them, and only the spread is
    checked (segment count is the caller's separate rule).
    """
    if points_robot is None:
        ends = np.asarray(segments_robot, dtype=float).reshape(-1, 2)
        return point_spread_m(ends) < params.min_spread_m
    points = usable_points(points_robot)
    if points.shape[0] < params.min_points:
        return True
    return point_spread_m(points) < params.min_spread_m


MAX_GLOBAL_AREA_M2 = 40_000.0
"""Largest map (bounding box, m²) the command line searches whole with ``--global``: at
about a minute per scan on 2 cores, more than that is no answer a user waits for."""

INDEX_MIN_SEGMENTS = 400
"""Stage 2 looks segments up in the map's grid above this many; below, checking all is cheaper."""

NAN_POSE = Pose2(float("nan"), float("nan"), float("nan"))
NO_SEGMENTS = np.zeros((0, 4))


class ScanMatcher(Protocol):
    """What ``localize_scans`` needs of a localizer: ``Localizer`` and the peers have it."""

    uses_segments: bool
    segments_world: np.ndarray

    def localize(
        self, segments_robot: np.ndarray, initial: Pose2, points_robot: np.ndarray
    ) -> Estimate: ...


class Localizer:
    """Localizes local maps against one global map (M, 4), world frame."""

    uses_segments = True
    """The scan's segments are what it matches (peers that match points alone say False)."""

    def __init__(self, segments_world: np.ndarray, params: LocalizeParams | None = None):
        self.params = params or LocalizeParams()
        self.segments_world = np.asarray(segments_world, dtype=float)
        self.rtable = RTable.build(self.segments_world, self.params.bin_deg)
        self.index = SegmentGrid(self.segments_world)
        self._search: HypothesisSearch | None = None

    def with_params(self, params: LocalizeParams) -> Localizer:
        """A localizer on the same map with other settings, sharing what they leave unchanged.

        The R-table is shared when the bin width is the same, the score
        raster when the search settings are.
        """
        other = object.__new__(Localizer)
        other.params = params
        other.segments_world = self.segments_world
        other.index = self.index
        same_bins = params.bin_deg == self.params.bin_deg
        other.rtable = (
            self.rtable if same_bins else RTable.build(self.segments_world, params.bin_deg)
        )
        same_search = params.search is not None and params.search == self.params.search
        other._search = self.hypothesis_search if same_search else None
        return other

    @property
    def hypothesis_search(self) -> HypothesisSearch:
        """The map's score raster and search, built on first use."""
        if self._search is None:
            self._search = HypothesisSearch(self.segments_world, self.params.search)
        return self._search

    def _rtable_near(self, initial: Pose2, segments_robot: np.ndarray) -> RTable:
        """The R-table of the map segments the scan could contain, seen from near ``initial``.

        In a large map nearly every orientation bin holds a segment of about
        any length, so every heading collects votes and the peak drowns. When
        the position is roughly known, only segments within the scan's reach
        of where stage 2 may go (the local map's radius plus the search's
        travel, 2·√2·η0) take part. With the whole map in reach this is the
        map's own R-table.
        """
        radius = float(np.hypot(segments_robot[:, 0::2], segments_robot[:, 1::2]).max(initial=0.0))
        reach = radius + 2.0 * np.sqrt(2.0) * self.params.grid_m
        near = self.index.near([initial.x, initial.y], reach)
        if near.size == self.segments_world.shape[0]:
            return self.rtable
        return RTable.build(self.segments_world[near], self.params.bin_deg)

    def headings(self, segments_robot: np.ndarray, initial: Pose2 | None) -> np.ndarray:
        """Stage 1: up to ``max_peaks`` headings (radians, world frame).

        Best first. Without an initial pose (or with no heading window) the
        whole circle is voted over with the whole map's R-table.
        """
        p = self.params
        if initial is None or p.window_deg is None:
            table, prior = self.rtable, None
        else:
            table, prior = self._rtable_near(initial, segments_robot), initial.theta
        return align(
            table,
            segments_robot,
            prior_rad=prior,
            window_deg=p.window_deg or 0.0,
            scheme=p.vote,
            max_peaks=p.max_peaks,
        ).peaks_rad

    def localize(
        self, segments_robot: np.ndarray, initial: Pose2, points_robot: np.ndarray | None = None
    ) -> Estimate:
        """Estimate the pose at which the local map (N, 4), robot frame, was seen.

        ``initial`` supplies the starting position and, unless the window is
        None, the prior heading for stage 1. A scan with fewer than
        ``min_segments`` local segments, fewer than ``min_points`` points, or
        points along one line (``scan_is_degenerate``) gets the status
        ``too_few_segments``; when the search still found a pose, the estimate
        holds it. ``points_robot`` (P, 2), the
        scan's valid readings in the robot frame, are what refinement fits and
        the hypothesis search scores; without them (or with refinement off)
        the estimate is the stage-2 pose, the paper's answer.
        """
        p = self.params
        n_local = int(segments_robot.shape[0])
        degenerate = scan_is_degenerate(points_robot, segments_robot, p)
        points_robot = usable_points(points_robot)
        robust = p.refine is not None and points_robot is not None
        searching = robust and p.search is not None
        enough = n_local >= p.min_segments
        if not enough and not searching:
            return Estimate(NAN_POSE, float("nan"), 0.0, n_local, STATUS_TOO_FEW_SEGMENTS)
        est = self._localize(segments_robot, initial, points_robot, enough, robust, searching)
        if degenerate or not enough:
            # Whatever was found stays in the row for the user to see, but is not trusted.
            est = replace(est, status=STATUS_TOO_FEW_SEGMENTS)
        return est

    def _localize(
        self,
        segments_robot: np.ndarray,
        initial: Pose2,
        points_robot: np.ndarray | None,
        enough: bool,
        robust: bool,
        searching: bool,
    ) -> Estimate:
        """``localize`` once the scan's size is known: the stages, the search, the verdict."""
        p = self.params
        n_local = int(segments_robot.shape[0])
        peaks = self.headings(segments_robot, initial) if enough else np.zeros(0)
        heading, stage2 = float("nan"), None
        if peaks.size:
            heading, stage2 = self._stage2(segments_robot, initial, peaks)
        if not robust:
            if stage2 is None or stage2.overlap_m <= 0:
                return Estimate(NAN_POSE, heading, 0.0, n_local, STATUS_NO_OVERLAP)
            est = Estimate(stage2.pose, heading, stage2.overlap_m, n_local, STATUS_OK, stage2.pose)
            return est if points_robot is None else self._checked_by_points(est, points_robot)
        seeds = [] if stage2 is None else [stage2.pose]
        if searching:
            window = 180.0 if p.window_deg is None else p.window_deg
            hyps = self.hypothesis_search.around(points_robot, initial, window, peaks)
            seeds += [h.pose for h in hyps]
        overlap = 0.0 if stage2 is None else stage2.overlap_m
        stage2_pose = None if stage2 is None else stage2.pose
        return self._judged(seeds, points_robot, heading, overlap, n_local, stage2_pose)

    def localize_global(self, segments_robot: np.ndarray, points_robot: np.ndarray) -> Estimate:
        """Estimate the pose with no initial guess: the whole map is searched.

        The hypothesis search scores the scan's points at every heading and
        every position of the map's extent; the best distinct grid poses are
        refined and the fit that puts the points closest to the map wins, the
        runner-up reported beside. The points alone decide, so a scan with
        too few segments for the two stages is still searched and its best
        pose reported, but its status is ``too_few_segments`` (as for too few
        or collinear points); stage 1's whole-circle vote is reported as the
        aligned heading when it can run.
        """
        n_local = int(segments_robot.shape[0])
        degenerate = scan_is_degenerate(points_robot, segments_robot, self.params)
        points_robot = usable_points(points_robot)
        seeds = [h.pose for h in self.hypothesis_search.everywhere(points_robot)]
        heading = float("nan")
        enough = n_local >= self.params.min_segments
        if enough:
            peaks = self.headings(segments_robot, None)
            heading = float(peaks[0]) if peaks.size else heading
        est = self._judged(seeds, points_robot, heading, 0.0, n_local, None)
        if degenerate or not enough:
            est = replace(est, status=STATUS_TOO_FEW_SEGMENTS)
        return est

    def _checked_by_points(self, est: Estimate, points_robot: np.ndarray) -> Estimate:
        """The paper's answer with a verdict from the scan's points: overlap alone rates a
        pose that shares a few segments with the map as highly as the right one, so the
        answer is ``lost`` unless enough of the points lie on the map there."""
        ratio, hold = support(points_robot, self.segments_world, est.pose, self._band_m)
        status = judge(ratio, 0.0, self.params.confidence, hold)
        return replace(est, inlier_ratio=ratio, status=status)

    @property
    def _band_m(self) -> float:
        """How near the map a point must lie to count as on it (refinement's final gate)."""
        return (self.params.refine or RefineParams()).final_gate_m

    def hold_points(self, points_robot: np.ndarray, pose: Pose2) -> float:
        """How firmly the points on the map fix the position at ``pose`` (``refine.support``)."""
        return support(points_robot, self.segments_world, pose, self._band_m)[1]

    def _stage2(self, segments_robot: np.ndarray, initial: Pose2, peaks: np.ndarray):
        """Stage 2 from each stage-1 peak: (heading, result) of the largest overlap."""
        p = self.params
        best = None
        for heading in peaks:
            result = coarse_to_fine(
                self.segments_world,
                segments_robot,
                Pose2(initial.x, initial.y, float(heading)),
                grid_m=p.grid_m,
                dtheta_deg=p.dtheta_deg,
                iterations=p.iterations,
                ratio=p.ratio,
                recentres=p.recentres,
                index=self.index if len(self.segments_world) > INDEX_MIN_SEGMENTS else None,
            )
            if best is None or result.overlap_m > best[1].overlap_m:
                best = (float(heading), result)
        return best

    def _judged(
        self,
        seeds: list[Pose2],
        points_robot: np.ndarray,
        heading: float,
        overlap_m: float,
        n_local: int,
        stage2_pose: Pose2 | None,
    ) -> Estimate:
        """Refine every seed; the best fit score wins, judged against its best distinct rival."""
        p = self.params
        if not seeds:
            return Estimate(NAN_POSE, heading, 0.0, n_local, STATUS_NO_OVERLAP, stage2_pose)
        fits: list[Refinement] = sorted(
            (refine_pose(points_robot, self.segments_world, s, p.refine) for s in seeds),
            key=lambda fit: -fit.score,
        )
        best = fits[0]
        apart = p.search or SearchParams()
        rivals = [
            f
            for f in fits[1:]
            if distinct([best.pose], f.pose, apart.distinct_m, apart.distinct_deg)
        ]
        runner_up = rivals[0] if rivals else None
        runner_up_ratio = 0.0 if runner_up is None else runner_up.inlier_ratio
        return Estimate(
            best.pose,
            heading,
            overlap_m,
            n_local,
            judge(
                best.inlier_ratio,
                runner_up_ratio,
                p.confidence,
                self.hold_points(points_robot, best.pose),
            ),
            stage2_pose,
            best.inlier_ratio,
            None if runner_up is None else runner_up.pose,
            runner_up_ratio,
        )


def _row(pose_id: int, scan: Scan, initial: Pose2, est: Estimate, runtime_ms: float, status: str):
    """One row of the estimates table (``ESTIMATE_COLUMNS``): metres and degrees."""
    stage2 = est.stage2_pose or NAN_POSE
    runner_up = est.runner_up or NAN_POSE
    return {
        "pose_id": int(pose_id),
        "time_s": scan.time_s,
        "init_x_m": initial.x,
        "init_y_m": initial.y,
        "init_theta_deg": initial.theta_deg,
        "align_theta_deg": float(np.rad2deg(est.align_theta_rad)),
        "stage2_x_m": stage2.x,
        "stage2_y_m": stage2.y,
        "stage2_theta_deg": stage2.theta_deg,
        "x_m": est.pose.x,
        "y_m": est.pose.y,
        "theta_deg": est.pose.theta_deg,
        "overlap": est.overlap_m,
        "inlier_ratio": est.inlier_ratio,
        "runner_up_x_m": runner_up.x,
        "runner_up_y_m": runner_up.y,
        "runner_up_theta_deg": runner_up.theta_deg,
        "runner_up_ratio": est.runner_up_ratio,
        "n_local_segments": est.n_local_segments,
        "runtime_ms": runtime_ms,
        "status": status,
    }


def localize_scans(
    scans: Sequence[Scan],
    initial_poses: Sequence[Pose2] | None,
    pose_ids: Sequence[int],
    localizer: ScanMatcher,
    extract_params: ExtractParams | None = None,
) -> Iterator[dict]:
    """Localize each scan from its initial guess, yielding one estimates row per scan.

    With ``initial_poses`` None every scan is localized globally (the whole
    map searched, the initial-pose columns left empty). Rows hold the
    estimates columns (``ESTIMATE_COLUMNS``): angles in degrees, positions in
    metres, ``runtime_ms`` covering extraction and the search. Yielding row
    by row lets a caller keep what is done if the run is cut short.
    """
    guesses = [None] * len(scans) if initial_poses is None else initial_poses
    for scan, initial, pose_id in zip(scans, guesses, pose_ids, strict=True):
        t0 = time.perf_counter()
        local = extract_segments(scan, extract_params)
        if initial is None:
            est = localizer.localize_global(local, scan.points())
        else:
            est = localizer.localize(local, initial, scan.points())
        runtime_ms = (time.perf_counter() - t0) * 1e3
        yield _row(pose_id, scan, initial or NAN_POSE, est, runtime_ms, est.status)


@dataclass(frozen=True)
class TrackParams:
    """How each tracked scan is fitted and when the fit is accepted (metres, degrees)."""

    min_inlier_ratio: float = 0.5
    """Share of the scan's points that must lie on the map (within refinement's final gate)."""
    max_jump_m: float = 0.5
    """Largest correction of the dead-reckoning guess accepted (position)."""
    max_jump_deg: float = 15.0
    widen: float = 2.0
    """The recovery search multiplies the grid, the heading window and the jump limits by this..."""
    max_widenings: int = 3
    """...once more for every scan lost in a row, up to this many times in all."""
    odom_sigma_m: float = 0.02
    """Spread of the guess per scan when standing still (position, per axis)..."""
    odom_sigma_per_m: float = 0.1
    """...plus this much per metre the odometry moved since the previous scan."""
    odom_sigma_deg: float = 1.0
    """Spread of the guess's heading per scan when not turning..."""
    odom_sigma_per_deg: float = 0.2
    """...plus this much per degree the odometry turned since the previous scan."""

    def prior(self, increment: Pose2) -> tuple[float, float]:
        """Spread (m, °) of a guess made by moving the previous estimate by ``increment``."""
        return (
            self.odom_sigma_m + self.odom_sigma_per_m * float(np.hypot(increment.x, increment.y)),
            self.odom_sigma_deg + self.odom_sigma_per_deg * abs(increment.theta_deg),
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
            status = STATUS_TOO_FEW_SEGMENTS  # the guess carries on, as for a lost scan
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
        yield _row(pose_id, scan, guess, est, (time.perf_counter() - t0) * 1e3, status)


def _track_match(
    localizer: Localizer,
    local: np.ndarray,
    points: np.ndarray,
    guess: Pose2,
    increment: Pose2 | None,
    track: TrackParams,
) -> Estimate:
    """The first match of a tracked scan, with its inlier share measured."""
    p = localizer.params
    points = usable_points(points)
    if p.refine is None:
        return _measured(localizer, localizer.localize(local, guess), points)
    sigma_m, sigma_deg = (None, None) if increment is None else track.prior(increment)
    fit = refine_pose(
        points,
        localizer.segments_world,
        guess,
        replace(p.refine, prior_sigma_m=sigma_m, prior_sigma_deg=sigma_deg),
    )
    n_local = int(local.shape[0])
    return Estimate(fit.pose, float("nan"), 0.0, n_local, STATUS_OK, guess, fit.inlier_ratio)


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
    out, n_local = [], int(local.shape[0])
    for heading in headings:
        start = Pose2(guess.x, guess.y, float(wrap_angle(heading)))
        fit = refine_pose(points, localizer.segments_world, start, params)
        out.append(
            Estimate(fit.pose, start.theta, 0.0, n_local, STATUS_OK, start, fit.inlier_ratio)
        )
    return out


def _measured(localizer: Localizer, est: Estimate, points: np.ndarray) -> Estimate:
    """``est`` with its inlier share filled in where refinement did not measure it."""
    if est.status != STATUS_OK or np.isfinite(est.inlier_ratio):
        return est
    band = (localizer.params.refine or RefineParams()).final_gate_m
    return replace(est, inlier_ratio=inlier_ratio(points, localizer.segments_world, est.pose, band))


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
