"""The two stages together: one local map → one pose, and a log's scans → estimates rows.

Tracking along a log, where each scan starts from the one before, is ``tracking.py``.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Protocol, overload

import numpy as np

from segloc_cli.config import ExtractParams, LocalizeParams, RefineParams, SearchParams
from segloc_cli.estimates import (
    STATUS_NO_OVERLAP,
    STATUS_OK,
    STATUS_TOO_FEW_SEGMENTS,
    EstimateRow,
    HypothesisRow,
)
from segloc_cli.geometry import Pose2
from segloc_cli.jit import await_compiled
from segloc_cli.method.align import align
from segloc_cli.method.confidence import (
    LOCAL_MAPS,
    ConfidenceModel,
    Evidence,
    judge,
    points_status,
    shipped_models,
)
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.freespace import crossing_ratio
from segloc_cli.method.overlap import coarse_to_fine
from segloc_cli.method.prepared import PreparedMap, prepare_map
from segloc_cli.method.refine import Refinement, refine_pose, support
from segloc_cli.method.search import HypothesisSearch, distinct
from segloc_cli.method.window import Windows, scan_window_map
from segloc_cli.scan import Scan


@dataclass(frozen=True)
class Hypothesis:
    """A distinct pose (world frame) that explains the scan: the share of its points on the
    map there, its fit score (``Refinement.score``) and the probability that it is the right
    place, weighed against the best other hypothesis."""

    pose: Pose2
    inlier_ratio: float
    score: float
    confidence: float


@dataclass(frozen=True, kw_only=True)
class Estimate:
    """Outcome for one scan, world frame. ``pose`` is NaN-filled when nothing was found.

    ``align_theta_rad`` is stage 1's heading (NaN when it did not run);
    ``overlap_m`` the stage-2 overlap (0 without stage 2); ``stage2_pose`` is
    where the coarse-to-fine search ended; ``pose`` is the refined pose (the
    same when refinement is off). ``inlier_ratio`` is the share of the scan's
    points on the map at ``pose`` (NaN when not measured). ``runner_up`` is
    the best fit distinct from ``pose`` among the hypotheses refined, with its
    own inlier share (None and NaN when there was none). ``confidence`` is the
    probability that ``pose`` is the right place (``confidence.py``), from
    ``evidence``; NaN and None where no rival was sought (``--no-refine``).
    ``hypotheses`` lists the distinct fits found, best first (the first is
    ``pose``, the second ``runner_up``); empty where no rival was sought.
    """

    pose: Pose2
    status: str
    n_local_segments: int
    align_theta_rad: float = float("nan")
    overlap_m: float = 0.0
    stage2_pose: Pose2 | None = None
    inlier_ratio: float = float("nan")
    runner_up: Pose2 | None = None
    runner_up_ratio: float = float("nan")
    confidence: float = float("nan")
    evidence: Evidence | None = None
    hypotheses: tuple[Hypothesis, ...] = ()


@overload
def usable_points(points_robot: np.ndarray) -> np.ndarray: ...
@overload
def usable_points(points_robot: None) -> None: ...
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


INDEX_MIN_SEGMENTS = 400
"""Stage 2 looks segments up in the map's grid above this many; below, checking all is cheaper."""

NAN_POSE = Pose2(float("nan"), float("nan"), float("nan"))
NO_SEGMENTS = np.zeros((0, 4))


class ScanMatcher(Protocol):
    """What ``localize_scans`` needs of a localizer: ``Localizer`` and the peers have it.

    ``uses_segments`` says whether ``localize`` reads the scan's segments; when
    False none are extracted for it (an empty (0, 4) array is passed).
    ``supports_global`` says whether ``localize_global`` can find a pose with no
    initial guess; a matcher without it raises ``ValueError`` there.
    ``supports_window`` says whether it localizes a window of scans (``window.py``),
    points from several origins, passing ``own_points`` to both calls; one without
    it is given each scan alone.
    """

    segments_world: np.ndarray
    uses_segments: bool
    supports_global: bool
    supports_window: bool

    def localize(
        self, segments_robot: np.ndarray, initial: Pose2, points_robot: np.ndarray
    ) -> Estimate: ...

    def localize_global(self, segments_robot: np.ndarray, points_robot: np.ndarray) -> Estimate: ...


class Localizer:
    """Localizes local maps against one global map, prepared for its settings
    (``prepared.PreparedMap``: the map (M, 4), world frame, with its indexes, R-table and,
    where the settings search, the hypothesis search; ``on_map`` prepares one).

    ``model`` gives the verdict's confidence for every local map (by default the shipped
    models, one for a scan and one for a window).
    """

    uses_segments = True
    supports_global = True
    supports_window = True

    def __init__(
        self,
        prepared: PreparedMap,
        params: LocalizeParams | None = None,
        *,
        model: ConfidenceModel | None = None,
    ):
        self.params = params or LocalizeParams()
        unsuited = prepared.unsuited_to(self.params)
        if unsuited is not None:
            raise ValueError(
                f"the prepared map does not suit these settings: {unsuited} "
                "(prepare it for them with PreparedMap.for_params)"
            )
        self.prepared = prepared
        self.segments_world = prepared.segments_world
        self.model = model
        self.models = shipped_models() if model is None else dict.fromkeys(LOCAL_MAPS, model)

    @classmethod
    def on_map(
        cls,
        segments_world: np.ndarray,
        params: LocalizeParams | None = None,
        *,
        global_search: bool = False,
        model: ConfidenceModel | None = None,
    ) -> Localizer:
        """A localizer on the map (M, 4), world frame, prepared now for ``params`` and, with
        ``global_search``, for ``localize_global`` (``prepared.prepare_map``)."""
        prepared = prepare_map(segments_world, params, global_search=global_search)
        return cls(prepared, params, model=model)

    def with_params(self, params: LocalizeParams) -> Localizer:
        """A localizer on the same map with other settings, sharing what they leave unchanged
        (``PreparedMap.for_params``)."""
        return Localizer(self.prepared.for_params(params), params, model=self.model)

    def _search(self) -> HypothesisSearch:
        """The prepared map's hypothesis search; ``ValueError`` when it was prepared without
        one (for settings that never search, and no global search)."""
        if self.prepared.search is None:
            raise ValueError(
                "the map was prepared without the hypothesis search; prepare it with "
                "global_search=True to search it globally"
            )
        return self.prepared.search

    def _near_mask(self, initial: Pose2, segments_robot: np.ndarray) -> np.ndarray | None:
        """The map segments (mask (M,)) the scan could contain, seen from near ``initial``;
        None when that is all of them.

        In a large map nearly every orientation bin holds a segment of about
        any length, so every heading collects votes and the peak drowns. When
        the position is roughly known, only segments within the scan's reach
        of where stage 2 may go (the local map's radius plus the search's
        travel, 2·√2·η0) take part.
        """
        radius = float(np.hypot(segments_robot[:, 0::2], segments_robot[:, 1::2]).max(initial=0.0))
        reach = radius + 2.0 * np.sqrt(2.0) * self.params.grid_m
        near = self.prepared.index.mask_near([initial.x, initial.y], reach)
        return None if near.all() else near

    def headings(self, segments_robot: np.ndarray, initial: Pose2 | None) -> np.ndarray:
        """Stage 1: up to ``max_peaks`` headings (radians, world frame).

        Best first. Without an initial pose (or with no heading window) the
        whole circle is voted over by the whole map.
        """
        p = self.params
        if initial is None or p.window_deg is None:
            allowed, prior = None, None
        else:
            allowed, prior = self._near_mask(initial, segments_robot), initial.theta
        return align(
            self.prepared.rtable,
            segments_robot,
            prior_rad=prior,
            window_deg=p.window_deg or 0.0,
            scheme=p.vote,
            max_peaks=p.max_peaks,
            allowed=allowed,
        ).peaks_rad

    def localize(
        self,
        segments_robot: np.ndarray,
        initial: Pose2,
        points_robot: np.ndarray | None = None,
        own_points: int | None = None,
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
        the estimate is the stage-2 pose, the paper's answer. ``own_points``: of a
        window's local map (``window.py``), how many of the first points are the
        scan's own, whose beams left from the robot's origin (None: all of them).
        """
        p = self.params
        n_local = int(segments_robot.shape[0])
        degenerate = scan_is_degenerate(points_robot, segments_robot, p)
        points_robot = usable_points(points_robot)
        robust = p.refine is not None and points_robot is not None
        searching = robust and p.search is not None
        enough = n_local >= p.min_segments
        if not enough and not searching:
            return Estimate(pose=NAN_POSE, status=STATUS_TOO_FEW_SEGMENTS, n_local_segments=n_local)
        est = self._localize(
            segments_robot, initial, points_robot, enough, robust, searching, own_points
        )
        if degenerate or not enough:
            est = untrusted(est)
        return est

    def _localize(
        self,
        segments_robot: np.ndarray,
        initial: Pose2,
        points_robot: np.ndarray | None,
        enough: bool,
        robust: bool,
        searching: bool,
        own_points: int | None,
    ) -> Estimate:
        """``localize`` once the scan's size is known: the stages, the search, the verdict."""
        p = self.params
        n_local = int(segments_robot.shape[0])
        peaks = self.headings(segments_robot, initial) if enough else np.zeros(0)
        heading, stage2 = float("nan"), None
        if peaks.size:
            heading, stage2 = self._stage2(segments_robot, initial, peaks)
        if not robust or points_robot is None:  # robust: refined, so the points are there
            if stage2 is None or stage2.overlap_m <= 0:
                return Estimate(
                    pose=NAN_POSE,
                    status=STATUS_NO_OVERLAP,
                    n_local_segments=n_local,
                    align_theta_rad=heading,
                )
            est = Estimate(
                pose=stage2.pose,
                status=STATUS_OK,
                n_local_segments=n_local,
                align_theta_rad=heading,
                overlap_m=stage2.overlap_m,
                stage2_pose=stage2.pose,
            )
            return est if points_robot is None else self._checked_by_points(est, points_robot)
        seeds = [] if stage2 is None else [stage2.pose]
        if searching:
            await_compiled()  # a first run: the search's kernels may be compiling elsewhere
            window = 180.0 if p.window_deg is None else p.window_deg
            known = None if stage2 is None else stage2.pose
            hyps = self._search().around(points_robot, initial, window, peaks, known)
            seeds += [h.pose for h in hyps]
        overlap = 0.0 if stage2 is None else stage2.overlap_m
        stage2_pose = None if stage2 is None else stage2.pose
        return self._judged(seeds, points_robot, heading, overlap, n_local, stage2_pose, own_points)

    def localize_global(
        self, segments_robot: np.ndarray, points_robot: np.ndarray, own_points: int | None = None
    ) -> Estimate:
        """Estimate the pose with no initial guess: the whole map is searched.

        The hypothesis search scores the scan's points at every heading and
        every position of the map's extent; the best distinct grid poses are
        refined and the fit that puts the points closest to the map wins, the
        runner-up reported beside. The points alone decide, so a scan with
        too few segments for the two stages is still searched and its best
        pose reported, but its status is ``too_few_segments`` (as for too few
        or collinear points); stage 1's whole-circle vote is reported as the
        aligned heading when it can run. ``own_points`` as for ``localize``.
        """
        n_local = int(segments_robot.shape[0])
        degenerate = scan_is_degenerate(points_robot, segments_robot, self.params)
        points_robot = usable_points(points_robot)
        seeds = [h.pose for h in self._search().everywhere(points_robot)]
        heading = float("nan")
        enough = n_local >= self.params.min_segments
        if enough:
            peaks = self.headings(segments_robot, None)
            heading = float(peaks[0]) if peaks.size else heading
        est = self._judged(seeds, points_robot, heading, 0.0, n_local, None, own_points)
        if degenerate or not enough:
            est = untrusted(est)
        return est

    def _checked_by_points(self, est: Estimate, points_robot: np.ndarray) -> Estimate:
        """The paper's answer with a verdict from the scan's points: overlap alone rates a
        pose that shares a few segments with the map as highly as the right one, so the
        answer is ``lost`` unless enough of the points lie on the map there. No rival was
        sought, so the points alone decide (``points_status``), with no confidence."""
        near = self.prepared.near_index
        ratio, hold = support(points_robot, self.segments_world, est.pose, self._band_m, index=near)
        status = points_status(ratio, hold, self.params.confidence)
        return replace(est, inlier_ratio=ratio, status=status)

    def _evidence(
        self,
        points_robot: np.ndarray,
        best: Refinement,
        runner_up: Refinement | None,
        own_points: int | None = None,
    ) -> Evidence:
        """What the verdict weighs at ``best``, against its best distinct rival. Only the
        first ``own_points`` points (all when None) are beams from the robot at ``best``,
        whose crossings of walls count."""
        own = points_robot[:own_points]
        return Evidence(
            inlier_ratio=best.inlier_ratio,
            runner_up_ratio=0.0 if runner_up is None else runner_up.inlier_ratio,
            score=best.score,
            runner_up_score=0.0 if runner_up is None else runner_up.score,
            hold_points=self.hold_points(points_robot, best.pose),
            crossing_ratio=crossing_ratio(own, best.pose, self.prepared.near_index),
            points=int(points_robot.shape[0]),
        )

    @property
    def _band_m(self) -> float:
        """How near the map a point must lie to count as on it (refinement's final gate)."""
        return (self.params.refine or RefineParams()).final_gate_m

    def hold_points(self, points_robot: np.ndarray, pose: Pose2) -> float:
        """How firmly the points on the map fix the position at ``pose`` (``refine.support``)."""
        band, near = self._band_m, self.prepared.near_index
        return support(points_robot, self.segments_world, pose, band, index=near)[1]

    def _stage2(self, segments_robot: np.ndarray, initial: Pose2, peaks: np.ndarray):
        """Stage 2 from each stage-1 peak: (heading, result) of the largest overlap."""
        p = self.params
        index = self.prepared.index if len(self.segments_world) > INDEX_MIN_SEGMENTS else None
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
                index=index,
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
        own_points: int | None = None,
    ) -> Estimate:
        """Refine every seed; the best fit score wins, judged against its best distinct rival,
        and every distinct fit is listed with its own confidence."""
        p = self.params
        if not seeds:
            return Estimate(
                pose=NAN_POSE,
                status=STATUS_NO_OVERLAP,
                n_local_segments=n_local,
                align_theta_rad=heading,
                stage2_pose=stage2_pose,
            )
        near = self.prepared.near_index
        fits = [
            refine_pose(points_robot, self.segments_world, s, p.refine, index=near) for s in seeds
        ]
        kept = self._distinct(fits)
        best = kept[0]
        runner_up = kept[1] if len(kept) > 1 else None
        evidence = self._evidence(points_robot, best, runner_up, own_points)
        windowed = own_points is not None and own_points < points_robot.shape[0]
        if windowed:  # whether the answer is lost is for the scan's own points to say
            own = support(points_robot[:own_points], self.segments_world, best.pose,
                          self._band_m, index=near)[0]  # fmt: skip
            evidence = replace(evidence, scan_inlier_ratio=own)
        model = self.models["window" if windowed else "single"]
        status, confidence = judge(evidence, p.confidence, model)
        others = [
            Hypothesis(f.pose, f.inlier_ratio, f.score,
                       model.probability(self._evidence(points_robot, f, best, own_points)))
            for f in kept[1:]
        ]  # fmt: skip
        return Estimate(
            pose=best.pose,
            status=status,
            n_local_segments=n_local,
            align_theta_rad=heading,
            overlap_m=overlap_m,
            stage2_pose=stage2_pose,
            inlier_ratio=best.inlier_ratio,
            runner_up=None if runner_up is None else runner_up.pose,
            runner_up_ratio=evidence.runner_up_ratio,
            confidence=confidence,
            evidence=evidence,
            hypotheses=(Hypothesis(best.pose, best.inlier_ratio, best.score, confidence), *others),
        )

    def _distinct(self, fits: list[Refinement]) -> list[Refinement]:
        """The fits, best score first, each kept only if distinct from every one kept before."""
        apart = self.params.search or SearchParams()
        kept: list[Refinement] = []
        for fit in sorted(fits, key=lambda f: -f.score):
            if distinct([k.pose for k in kept], fit.pose, apart.distinct_m, apart.distinct_deg):
                kept.append(fit)
        return kept


def untrusted(est: Estimate) -> Estimate:
    """``est`` of a scan that cannot pin a pose (``STATUS_TOO_FEW_SEGMENTS``): whatever was
    found stays for the user to see, untrusted, so with no confidence, its own or its
    hypotheses' (a probability of being the right place beside it would say otherwise)."""
    nan = float("nan")
    return replace(
        est,
        status=STATUS_TOO_FEW_SEGMENTS,
        confidence=nan,
        hypotheses=tuple(replace(h, confidence=nan) for h in est.hypotheses),
    )


def estimate_row(
    pose_id: int,
    scan: Scan,
    initial: Pose2,
    est: Estimate,
    runtime_ms: float,
    status: str,
    window_scans: int = 1,
) -> EstimateRow:
    """The estimates row of one scan: ``est`` in metres and degrees, under ``status``, from a
    local map of ``window_scans`` scans."""
    stage2 = est.stage2_pose or NAN_POSE
    runner_up = est.runner_up or NAN_POSE
    return EstimateRow(
        pose_id=int(pose_id),
        time_s=scan.time_s,
        init_x_m=initial.x,
        init_y_m=initial.y,
        init_theta_deg=initial.theta_deg,
        align_theta_deg=float(np.rad2deg(est.align_theta_rad)),
        stage2_x_m=stage2.x,
        stage2_y_m=stage2.y,
        stage2_theta_deg=stage2.theta_deg,
        x_m=est.pose.x,
        y_m=est.pose.y,
        theta_deg=est.pose.theta_deg,
        overlap_m=est.overlap_m,
        inlier_ratio=est.inlier_ratio,
        runner_up_x_m=runner_up.x,
        runner_up_y_m=runner_up.y,
        runner_up_theta_deg=runner_up.theta_deg,
        runner_up_ratio=est.runner_up_ratio,
        n_local_segments=est.n_local_segments,
        runtime_ms=runtime_ms,
        confidence=est.confidence,
        status=status,
        window_scans=int(window_scans),
        hypotheses=[
            HypothesisRow(
                x_m=h.pose.x,
                y_m=h.pose.y,
                theta_deg=h.pose.theta_deg,
                inlier_ratio=h.inlier_ratio,
                score=h.score,
                confidence=h.confidence,
            )
            for h in est.hypotheses
        ],
    )


def localize_scan(
    localizer: ScanMatcher,
    scan: Scan,
    initial: Pose2 | None,
    extract_params: ExtractParams | None = None,
    neighbours: Sequence[tuple[Scan, Pose2]] = (),
    windows: Windows | None = None,
) -> tuple[Estimate, int]:
    """One scan localized from ``initial`` (None: globally), alone or with its
    ``neighbours`` as one local map (``window.py``; ``windows`` says how); returns the
    estimate and how many scans its local map held."""
    local = extract_segments(scan, extract_params) if localizer.uses_segments else NO_SEGMENTS
    points = scan.points()
    if not neighbours or windows is None:
        if initial is None:
            return localizer.localize_global(local, points), 1
        return localizer.localize(local, initial, points), 1
    if not isinstance(localizer, Localizer):
        raise TypeError(f"{type(localizer).__name__} cannot localize a window of scans")
    refine = localizer.params.refine
    window = scan_window_map(points, local, neighbours, windows, extract_params, refine)
    own = int(points.shape[0])
    if initial is None:
        return localizer.localize_global(
            window.segments, window.points, own_points=own
        ), window.scans
    est = localizer.localize(window.segments, initial, window.points, own_points=own)
    return est, window.scans


def localize_scans(
    scans: Sequence[Scan],
    initial_poses: Sequence[Pose2] | None,
    pose_ids: Sequence[int] | np.ndarray,
    localizer: ScanMatcher,
    extract_params: ExtractParams | None = None,
    windows: Windows | None = None,
) -> Iterator[EstimateRow]:
    """Localize each scan from its initial guess, yielding one estimates row per scan.

    With ``initial_poses`` None every scan is localized globally (the whole
    map searched, the initial-pose columns left empty); the localizer must
    support that. With ``windows`` (one per scan) each scan is localized with its
    neighbours (``localize_scan``). Angles in degrees, positions in metres,
    ``runtime_ms`` covering extraction (for a matcher that uses segments), the
    window and the search. Yielding row by row lets a caller keep what is done if
    the run is cut short.
    """
    if initial_poses is None and not localizer.supports_global:
        raise ValueError(f"{type(localizer).__name__} needs an initial guess for every scan")
    guesses = [None] * len(scans) if initial_poses is None else initial_poses
    around = [()] * len(scans) if windows is None else windows.neighbours
    for scan, initial, pose_id, neighbours in zip(scans, guesses, pose_ids, around, strict=True):
        t0 = time.perf_counter()
        est, held = localize_scan(localizer, scan, initial, extract_params, neighbours, windows)
        runtime_ms = (time.perf_counter() - t0) * 1e3
        yield estimate_row(pose_id, scan, initial or NAN_POSE, est, runtime_ms, est.status, held)
