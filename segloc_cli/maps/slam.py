"""Segment SLAM: every scan's pose and the map from a log's scans and odometry, no survey.

Front end: every scan is fitted (``refine_pose``) to the local map of the keyframes of the
last few metres of travel, from where the odometry moves the scan before it (without
odometry: as that scan moved); a fit that puts too few points on the map, or strays too far
from the odometry's guess, is not taken, and the guess stands. A scan that moved far enough
from the last keyframe (``SlamParams.keyframe_m``, ``keyframe_deg``) becomes one, joined to
it by an edge weighted by what the fit's points pin (``fit_information``) and what the
odometry adds; any other scan keeps its place relative to its keyframe.

Submaps: the keyframes of each stretch of travel (``submap_m``), their local maps fused in
the frame of the submap's first keyframe (its anchor); fused again before it is searched
once loops have bent it (moved a keyframe relative to the anchor: ``submap_bend_*``).

Loop closure: every few keyframes, a keyframe is searched for in the finished submaps whose
anchor lies within its pose uncertainty relative to them (a square and a heading window
growing with the travel between the two along the graph, where a loop closed earlier is a
short cut: ``_graph_travel``), with the localizer's own search and verdict; a find is taken
as a loop when the verdict says ``ok``, it lies in the square searched, and the find before
it in that submap put the anchor at the same place. The loop's edge joins the keyframe to
the submap's keyframe nearest the find, so that a submap bent by corrections made after it
was fused bends the loop least. Every candidate is recorded (``LoopCandidate``).

A keyframe's searches are handed to a ``LoopSearcher`` (``maps/loop_search.py``) and their
finds taken in when the next keyframe is searched for: on a long log, in a worker process
while the front end maps the keyframes between, with the same result.

Back end: a pose graph over the keyframes (gtsam's ``Pose2`` factors: the front end's edges,
and the loops' under a Cauchy loss), updated incrementally (iSAM2) as keyframes and loops
arrive and solved once more at the end (Levenberg–Marquardt).

Poses are (x_m, y_m, theta_rad) in the world frame of the first scan's pose (``initial``).
"""

from __future__ import annotations

import heapq
import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from segloc_cli.config import (
    ExtractParams,
    FuseParams,
    LocalizeParams,
    RefineParams,
    SearchParams,
    SlamParams,
)
from segloc_cli.geometry import (
    Pose2,
    chained_motions,
    relative_motion,
    transform_points,
    transform_segments,
    wrap_angle,
)
from segloc_cli.maps.fusion import fuse_segments
from segloc_cli.maps.loop_search import LoopFind, LoopQuery, LoopSearcher
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.refine import nearest_segments, refine_pose
from segloc_cli.method.search import distinct
from segloc_cli.method.spatial import NEAR_CELL_M, SegmentGrid
from segloc_cli.scan import Scan

WORLD_ORIGIN = Pose2(0.0, 0.0, 0.0)
"""Where the first scan is placed unless told otherwise."""

PARALLEL_SCANS = 2000
"""Logs of this many scans or more have their loop searches run in a worker process: a
worker takes a second or two to start."""


@dataclass(frozen=True)
class LoopCandidate:
    """A search of keyframe ``keyframe`` in submap ``submap``: what the verdict said,
    where it put the keyframe in the frame of ``anchor``, the submap's keyframe nearest
    the find (its first where nothing was found) (``motion``: x m, y m, θ rad; NaN where
    nothing was found), the correction that implied (m, °), whether it was accepted and
    whether the final solve then dropped it (``SlamParams.loop_drop_chi2``: no longer
    accepted)."""

    keyframe: int
    submap: int
    anchor: int
    motion: tuple[float, float, float]
    status: str
    inlier_ratio: float
    correction_m: float
    correction_deg: float
    accepted: bool
    dropped: bool = False


@dataclass
class SlamResult:
    """What a SLAM run found: every scan's pose (S, 3), which scans are keyframes (K,), the
    keyframes' local maps (robot frame) and solved poses (K, 3), the odometry at the scans
    (S, 3, in the world frame of ``initial``), and every loop candidate."""

    poses: np.ndarray
    keyframes: np.ndarray
    local_maps: list[np.ndarray]
    keyframe_poses: np.ndarray
    odometry: np.ndarray
    loops: list[LoopCandidate] = field(default_factory=list)
    odometry_jumps: list[int] = field(default_factory=list)
    """The scans (indices) to which the odometry jumped (``SlamParams.odom_jump_*``): placed
    by the scans alone."""

    @property
    def accepted_loops(self) -> list[LoopCandidate]:
        """The candidates taken as loops, in the order they were found."""
        return [loop for loop in self.loops if loop.accepted]

    @property
    def loops_accepted(self) -> int:
        return len(self.accepted_loops)

    def loop_offsets(self) -> np.ndarray:
        """How far the solved poses place each candidate's keyframe from where its search
        found it in its anchor's frame (L, 2: m, °); NaN where nothing was found. Small
        for a loop the solution holds."""
        solved = self.keyframe_poses
        anchors = solved[[loop.anchor for loop in self.loops]]
        keyframes = solved[[loop.keyframe for loop in self.loops]]
        found = np.array([loop.motion for loop in self.loops]).reshape(-1, 3)
        off = relative_motion(relative_motion(anchors, keyframes), found)
        return np.column_stack([np.hypot(off[:, 0], off[:, 1]), np.rad2deg(np.abs(off[:, 2]))])


def odometry_at(
    times_s: np.ndarray, odom_times_s: np.ndarray, odom_poses: np.ndarray
) -> np.ndarray:
    """The odometry (K, 3) interpolated to ``times_s`` (S,): (S, 3), headings unwrapped
    between samples; times outside the odometry's span take its nearest end."""
    order = np.argsort(odom_times_s, kind="stable")
    t, poses = odom_times_s[order], odom_poses[order]
    theta = np.unwrap(poses[:, 2])
    out = np.column_stack(
        [np.interp(times_s, t, poses[:, 0]), np.interp(times_s, t, poses[:, 1]),
         np.interp(times_s, t, theta)]
    )  # fmt: skip
    out[:, 2] = wrap_angle(out[:, 2])
    return out


def compose(pose: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """``pose ⊕ motion`` (3,) ⊕ (3,) → (3,), as ``Pose2.compose`` on arrays."""
    return Pose2(*pose).compose(Pose2(*motion)).as_array()


def fit_information(
    points_robot: np.ndarray, segments_world: np.ndarray, pose: np.ndarray, gate_m: float,
    sigma_m: float,
) -> np.ndarray:  # fmt: skip
    """Information (3, 3) of a pose fitted by putting the points (P, 2, robot frame) on the
    segments (M, 4, world frame): Σ JᵀJ / σ² over the points within ``gate_m`` of a segment,
    J = ∂(point-to-line distance)/∂(x, y, θ) taken in the robot's frame (the tangent space
    gtsam's ``Pose2`` uses), σ = ``sigma_m``."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    px, py = points_robot[:, 0], points_robot[:, 1]
    world = transform_points(points_robot, Pose2(*pose))
    index, _ = nearest_segments(world, segments_world, within_m=gate_m)
    near = index >= 0
    seg = segments_world[index[near]]
    d = seg[:, 2:] - seg[:, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    length[length == 0] = 1.0
    normal_world = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    # A body-frame step (dx, dy, dθ) moves a point by R·(dx, dy) + R·(−py, px)·dθ.
    nb = np.column_stack(
        [c * normal_world[:, 0] + s * normal_world[:, 1],
         -s * normal_world[:, 0] + c * normal_world[:, 1]]
    )  # fmt: skip
    jac = np.column_stack([nb[:, 0], nb[:, 1], -nb[:, 0] * py[near] + nb[:, 1] * px[near]])
    return jac.T @ jac / sigma_m**2


def _odometry_information(motion: np.ndarray | None, params: SlamParams) -> np.ndarray:
    """Information (3, 3) of the odometry's ``motion`` (x m, y m, θ rad) between two
    keyframes; None, a log with no odometry: a guess of a metre and 30° either way."""
    if motion is None:
        return np.diag([1.0, 1.0, np.deg2rad(30.0) ** -2])
    travel = float(np.hypot(motion[0], motion[1]))
    sigma_m = params.odom_sigma_m * max(travel, 0.1)
    sigma_rad = np.deg2rad(params.odom_sigma_deg * max(travel, 0.1)) + 0.1 * abs(motion[2])
    return np.diag([sigma_m**-2, sigma_m**-2, sigma_rad**-2])


class _Graph:
    """The keyframes' pose graph in gtsam (imported here: only the SLAM needs it)."""

    def __init__(self, first: np.ndarray, floor_m: float, floor_deg: float):
        import gtsam

        self.loop_edges: list[tuple[int, int, int, int, np.ndarray, np.ndarray]] = []
        """Each loop's edge: (the loop's number, its factor's index, keyframes a and b, the
        motion (3,) and the inverse of its covariance (3, 3))."""

        self.floor = np.diag([floor_m**2, floor_m**2, np.deg2rad(floor_deg) ** 2])
        """Added to every edge's covariance (``SlamParams.edge_floor_*``)."""

        self.gtsam = gtsam
        self.isam = gtsam.ISAM2()
        self.graph = gtsam.NonlinearFactorGraph()
        prior = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
        self._add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*first), prior), 0, first)

    def _add(self, factor, key: int | None, guess: np.ndarray | None) -> None:
        """``factor``, and with ``key`` a new keyframe's pose, first ``guess``."""
        graph, values = self.gtsam.NonlinearFactorGraph(), self.gtsam.Values()
        graph.add(factor)
        self.graph.add(factor)
        if key is not None and guess is not None:
            values.insert(key, self.gtsam.Pose2(*guess))
        self.isam.update(graph, values)

    def _covariance(self, information: np.ndarray) -> np.ndarray:
        return np.linalg.inv(information + np.diag([1e-6, 1e-6, 1e-6])) + self.floor

    def _noise(self, covariance: np.ndarray, cauchy: float | None):
        gtsam = self.gtsam
        model = gtsam.noiseModel.Gaussian.Covariance(covariance)
        if cauchy is None:
            return model
        loss = gtsam.noiseModel.mEstimator.Cauchy.Create(cauchy)
        return gtsam.noiseModel.Robust.Create(loss, model)

    def add_edge(
        self, a: int, b: int, motion: np.ndarray, information: np.ndarray,
        guess: np.ndarray | None = None, cauchy: float | None = None, loop: int | None = None,
    ) -> None:  # fmt: skip
        """An edge from keyframe ``a`` to ``b`` (``motion`` in ``a``'s frame), under a Cauchy
        loss of scale ``cauchy`` if given; ``guess`` introduces ``b``; ``loop`` numbers a
        loop's edge, which the final solve may drop (``loop_edges``)."""
        covariance = self._covariance(information)
        factor = self.gtsam.BetweenFactorPose2(
            a, b, self.gtsam.Pose2(*motion), self._noise(covariance, cauchy)
        )
        if loop is not None:
            weight = np.linalg.inv(covariance)
            index = int(self.graph.size())
            self.loop_edges.append((loop, index, a, b, np.asarray(motion), weight))
        self._add(factor, b if guess is not None else None, guess)

    def poses(self) -> np.ndarray:
        """Every keyframe's pose (K, 3) as iSAM2 has it now."""
        return self.gtsam.utilities.extractPose2(self.isam.calculateEstimate())

    def solved(self, drop_chi2: float, rounds: int = 3) -> tuple[np.ndarray, set[int]]:
        """Every keyframe's pose (K, 3) after a batch Levenberg–Marquardt solve from iSAM2's,
        and the numbers of the loops dropped: a loop whose residual at the solution, weighed
        by its covariance, exceeds ``drop_chi2`` (squared Mahalanobis distance) is taken out
        and the graph solved again, up to ``rounds`` times."""
        gtsam = self.gtsam
        result = self.isam.calculateEstimate()
        dropped: set[int] = set()
        for round_ in range(rounds + 1):
            result = gtsam.LevenbergMarquardtOptimizer(
                self.graph, result, gtsam.LevenbergMarquardtParams()
            ).optimize()
            if round_ == rounds:  # the solution of the last loops kept
                break
            live = [edge for edge in self.loop_edges if edge[0] not in dropped]
            failing = _failing_loops(gtsam.utilities.extractPose2(result), live, drop_chi2)
            if not failing:
                break
            for loop, index, *_ in live:
                if loop in failing:
                    self.graph.remove(index)
            dropped |= failing
        return gtsam.utilities.extractPose2(result), dropped


def _failing_loops(poses: np.ndarray, edges: list[tuple], chi2: float) -> set[int]:
    """The numbers of the loop ``edges`` (``_Graph.loop_edges``) that ``poses`` (K, 3) leave
    off by more than ``chi2`` (squared Mahalanobis distance of the residual)."""
    if not edges:
        return set()
    loop, _, a, b, motion, weight = zip(*edges, strict=True)
    off = relative_motion(relative_motion(poses[list(a)], poses[list(b)]), np.array(motion))
    distance = np.einsum("ni,nij,nj->n", off, np.array(weight), off)
    return {number for number, d in zip(loop, distance, strict=True) if d > chi2}


@dataclass
class _Submap:
    """Keyframes ``first`` to ``last`` (inclusive), their segments fused in the frame of
    ``first`` (the anchor)."""

    first: int
    last: int
    segments: np.ndarray
    members: np.ndarray
    """The poses (n, 3) of keyframes ``first`` to ``last`` in the anchor's frame, as fused."""
    pending: tuple[int, np.ndarray] | None = None
    """The last keyframe found in it with an ok verdict, and where that put the anchor."""
    checked: int = 0
    """How many loops had been closed when its keyframes' poses were last compared with
    ``members``."""


def run_slam(
    scans: list[Scan],
    odometry: np.ndarray | None,
    params: SlamParams | None = None,
    *,
    initial: Pose2 = WORLD_ORIGIN,
    extract_params: ExtractParams | None = None,
    refine_params: RefineParams | None = None,
    fuse_params: FuseParams | None = None,
    advance: Callable[[int, dict[str, int]], None] | None = None,
    parallel: bool | None = None,
) -> SlamResult:
    """Every scan's pose and the keyframes' local maps, from the ``scans`` (S) and the
    ``odometry`` (S, 3) at their times (any world frame: only its motions count; None: no
    odometry, each scan guessed to move as the one before did); the first scan is placed
    at ``initial``. ``advance(scans_done, counts)`` is called after every scan. With
    ``parallel`` (by default for ``PARALLEL_SCANS`` scans or more on a machine of more
    than one core), the loop searches run in a worker process beside the mapping, with
    the same result."""
    if parallel is None:
        parallel = len(scans) >= PARALLEL_SCANS and (os.cpu_count() or 1) > 1
    mapping = _Mapping(scans, odometry, params or SlamParams(), initial, extract_params,
                       refine_params or RefineParams(), fuse_params, parallel)  # fmt: skip
    try:
        for i in range(1, len(scans)):
            mapping.add_scan(i)
            if advance:
                advance(i + 1, mapping.counts())
        return mapping.result()
    finally:
        mapping.searcher.close()


class _Mapping:
    """The state of a SLAM run as its scans are added one by one (``run_slam``)."""

    def __init__(
        self, scans: list[Scan], odometry: np.ndarray | None, p: SlamParams, initial: Pose2,
        extract_params: ExtractParams | None, refine: RefineParams,
        fuse_params: FuseParams | None, parallel: bool,
    ) -> None:  # fmt: skip
        self.searcher = LoopSearcher(parallel)
        self.scans, self.p, self.refine = scans, p, refine
        self.extract_params, self.fuse_params = extract_params, fuse_params
        n = len(scans)
        self.blind = odometry is None
        self.odometry = np.zeros((n, 3)) if self.blind else np.asarray(odometry, dtype=float)
        start = initial.as_array()
        self.steps = np.vstack(
            [np.zeros((1, 3)), relative_motion(self.odometry[:-1], self.odometry[1:])]
        )
        gaps_s = np.diff([scan.time_s for scan in scans], prepend=scans[0].time_s)
        step_m = np.hypot(self.steps[:, 0], self.steps[:, 1])
        turn_deg = np.rad2deg(np.abs(self.steps[:, 2]))
        self.jumped = (step_m > np.maximum(p.odom_jump_m, p.odom_jump_m_per_s * gaps_s)) | (
            turn_deg > np.maximum(p.odom_jump_deg, p.odom_jump_deg_per_s * gaps_s)
        )
        self.odom_world = chained_motions(start, self.steps[1:])
        self.graph = _Graph(start, p.edge_floor_m, p.edge_floor_deg)
        self.keyframes, self.kf_pose, self.kf_travel = [0], [start], [0.0]
        self.local_maps = [extract_segments(scans[0], extract_params)]
        self.owner, self.offset = np.zeros(n, dtype=np.int64), np.zeros((n, 3))
        self.submaps: list[_Submap] = []
        self.submap_first = 0
        self.loops: list[LoopCandidate] = []
        self.loops_closed = 0
        self.links: list[tuple[int, int]] = []
        """The submaps each closed loop joins: (the submap found, the keyframe's own)."""
        self.previous = start
        self.local_world = transform_segments(self.local_maps[0], initial)
        self._index: tuple[np.ndarray, SegmentGrid] | None = None
        self.request: _LoopRequest | None = None
        """The searches handed to ``searcher`` whose finds are not yet taken in."""
        self._counted, self._found = 0, 0
        """Loop candidates counted so far (``counts``), and how many the verdict said ok."""

    def add_scan(self, i: int) -> None:
        """Place scan ``i``; make it a keyframe if it moved far enough from the last one."""
        p = self.p
        before = self.previous
        points = self.scans[i].points()
        self.previous, fitted = self._placed(i, points)
        if self.blind:  # no odometry: the next scan is guessed to move as this one did
            self.steps[i + 1 : i + 2] = relative_motion(before, self.previous)
        motion = relative_motion(self.kf_pose[-1], self.previous)[0]
        if np.hypot(motion[0], motion[1]) < p.keyframe_m and (
            abs(np.rad2deg(motion[2])) < p.keyframe_deg
        ):
            self.owner[i], self.offset[i] = len(self.keyframes) - 1, motion
            return
        self._add_keyframe(i, motion, fitted, points)

    def _placed(self, i: int, points: np.ndarray) -> tuple[np.ndarray, bool]:
        """Where scan ``i`` (its points (P, 2), robot frame) goes, and whether the scans (a
        fit or a search) placed it rather than the guess."""
        p = self.p
        jumped = bool(self.jumped[i])
        # Where the odometry jumps (a robot carried off, a reset), the scan is placed by the
        # scans, from the pose of the one before.
        guess = self.previous if jumped else compose(self.previous, self.steps[i])
        fit = refine_pose(
            points, self.local_world, Pose2(*guess), self.refine, index=self._local_index()
        )
        correction = relative_motion(guess, fit.pose.as_array())[0]
        plausible = self.blind or (
            np.hypot(correction[0], correction[1]) <= p.max_correction_m
            and np.rad2deg(abs(correction[2])) <= p.max_correction_deg
        )
        # After a jump the heading may be anything: the search decides, not the fit.
        if fit.inlier_ratio >= p.min_inlier_ratio and plausible and not jumped:
            return fit.pose.as_array(), True
        if not (self.blind or jumped):
            return guess, False
        local_map = extract_segments(self.scans[i], self.extract_params)
        found = _searched(self.local_world, local_map, guess, points, any_heading=jumped)
        return (guess, False) if found is None else (found, True)

    def _local_index(self) -> SegmentGrid:
        """The spatial index of the local map the scans are fitted to, built once for the
        scans between two keyframes (the fit is the same without it, only slower)."""
        if self._index is None or self._index[0] is not self.local_world:
            self._index = (self.local_world, SegmentGrid(self.local_world, cell_m=NEAR_CELL_M))
        return self._index[1]

    def _add_keyframe(self, i: int, motion: np.ndarray, fitted: bool, points: np.ndarray):
        """Scan ``i`` as the next keyframe, ``motion`` from the last; its edge, its submap,
        the loops it closes, and the local map the next scans are fitted to."""
        p, k = self.p, len(self.keyframes)
        # The odometry bounds what the fit leaves free (along a corridor, all of it).
        travelled = None
        if not (self.blind or self.jumped[self.keyframes[-1] + 1 : i + 1].any()):
            travelled = relative_motion(self.odometry[self.keyframes[-1]], self.odometry[i])[0]
        information = _odometry_information(travelled, p)
        if fitted:
            information = information + fit_information(
                points, self.local_world, self.previous, self.refine.final_gate_m,
                p.point_sigma_m,
            )  # fmt: skip
        self.graph.add_edge(k - 1, k, motion, information, guess=self.previous)
        moved = float(np.hypot(motion[0], motion[1]))
        self.owner[i] = k
        self.keyframes.append(i)
        self.local_maps.append(extract_segments(self.scans[i], self.extract_params))
        self.kf_pose.append(self.previous)
        self.kf_travel.append(self.kf_travel[-1] + moved)
        if self.kf_travel[-1] - self.kf_travel[self.submap_first] >= p.submap_m:
            self.submaps.append(
                _submap(self.submap_first, k, self.local_maps, self.kf_pose, self.fuse_params)
            )  # fmt: skip
            self.searcher.add_submap(len(self.submaps) - 1, self.submaps[-1].segments)
            self.submap_first = k
        if k % p.loop_every == 0:
            # The finds of the keyframe searched for before, then this one's searches: in a
            # worker, they run while the next keyframes are mapped.
            self._take_loops()
            self._fuse_bent_submaps(self.kf_pose[k])
            self.request = _loop_request(
                k, points, self.kf_pose, self.kf_travel, self.submaps, p, self.links
            )
            self.searcher.submit(self.local_maps[k], points, self.request.queries)
        first = int(np.searchsorted(self.kf_travel, self.kf_travel[-1] - p.local_map_m))
        self.local_world = np.concatenate(
            [transform_segments(self.local_maps[j], Pose2(*self.kf_pose[j]))
             for j in range(first, k + 1)]
        )  # fmt: skip

    def _take_loops(self) -> None:
        """Add the loops the last keyframe searched for closes, if any."""
        if self.request is None:
            return
        finds = self.searcher.collect()
        before = len(self.loops)
        closed = _close_loops(
            self.graph, self.request, finds, self.submaps, self.p, self.loops,
            self.refine.final_gate_m,
        )  # fmt: skip
        # The keyframe's own submap: the last begun at or before it (one not closed yet).
        own = sum(sub.first <= self.request.k for sub in self.submaps)
        own -= own > 0 and self.submaps[own - 1].last >= self.request.k
        self.links += [(loop.submap, own) for loop in self.loops[before:] if loop.accepted]
        self.request = None
        if closed:
            self.loops_closed += closed
            self.kf_pose = list(self.graph.poses())
            self.previous = self.kf_pose[-1]

    def _fuse_bent_submaps(self, here: np.ndarray) -> None:
        """Fuse again each submap within the loop search's reach of ``here`` (3,) whose
        keyframes the graph has moved, relative to its anchor, by more than
        ``SlamParams.submap_bend_m`` or ``submap_bend_deg`` since it was fused: loops found
        in it then rest on where its walls are now."""
        p = self.p
        reach = p.loop_max_radius_m + p.submap_m
        for index, sub in enumerate(self.submaps):
            if sub.checked == self.loops_closed:  # no loop has moved a keyframe since
                continue
            anchor = self.kf_pose[sub.first]
            if np.hypot(here[0] - anchor[0], here[1] - anchor[1]) > reach:
                continue
            sub.checked = self.loops_closed
            now = relative_motion(anchor[None], np.array(self.kf_pose[sub.first : sub.last + 1]))
            bend = relative_motion(sub.members, now)
            if (
                np.hypot(bend[:, 0], bend[:, 1]).max() <= p.submap_bend_m
                and np.rad2deg(np.abs(bend[:, 2])).max() <= p.submap_bend_deg
            ):
                continue
            fused = _submap(sub.first, sub.last, self.local_maps, self.kf_pose, self.fuse_params)
            fused.pending, fused.checked = sub.pending, sub.checked
            self.submaps[index] = fused
            self.searcher.add_submap(index, fused.segments)

    def counts(self) -> dict[str, int]:
        """What the run has made so far, as its progress shows it."""
        searched = sum(loop.status == "ok" for loop in self.loops[self._counted :])
        self._counted, self._found = len(self.loops), self._found + searched
        return {
            "keyframes": len(self.keyframes),
            "submaps": len(self.submaps),
            "loops found": self._found,
            "closed": self.loops_closed,
        }

    def result(self) -> SlamResult:
        """Every scan's pose once the graph is solved, and what the run found."""
        self._take_loops()
        solved, dropped = self.graph.solved(self.p.loop_drop_chi2)
        for number in dropped:
            self.loops[number] = replace(self.loops[number], accepted=False, dropped=True)
        poses = np.array(
            [compose(solved[o], d) for o, d in zip(self.owner, self.offset, strict=True)]
        )
        jumps = [int(i) for i in np.flatnonzero(self.jumped)]
        return SlamResult(
            poses, np.array(self.keyframes), self.local_maps, solved, self.odom_world,
            self.loops, jumps,
        )  # fmt: skip


def _searched(
    segments_world: np.ndarray, local_map: np.ndarray, guess: np.ndarray, points: np.ndarray,
    any_heading: bool,
) -> np.ndarray | None:  # fmt: skip
    """The pose (3,) at which the localizer places a scan (its local map (N, 4) and points
    (P, 2), robot frame) on ``segments_world`` around ``guess`` (its default search window;
    with ``any_heading``, at every heading), when its verdict is ``ok``; else None."""
    from segloc_cli.estimates import STATUS_OK
    from segloc_cli.method.localize import Localizer

    params = LocalizeParams(window_deg=None) if any_heading else None
    localizer = Localizer.on_map(segments_world, params)
    est = localizer.localize(local_map, Pose2(*guess), points)
    return est.pose.as_array() if est.status == STATUS_OK else None


def _same_place(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two poses (3,) are one answer by the search's own measure (``SearchParams``:
    ``distinct_m``, ``distinct_deg``)."""
    near = SearchParams()
    return not distinct([Pose2(*a)], Pose2(*b), near.distinct_m, near.distinct_deg)


def _submap(first, last, local_maps, kf_pose, fuse_params) -> _Submap:
    members = relative_motion(np.array([kf_pose[first]]), np.array(kf_pose[first : last + 1]))
    placed = [
        transform_segments(local_maps[j], Pose2(*members[j - first]))
        for j in range(first, last + 1)
    ]
    return _Submap(first, last, fuse_segments(np.concatenate(placed), fuse_params), members)


@dataclass
class _LoopRequest:
    """The searches of keyframe ``k`` handed to the ``LoopSearcher``: its pose when they
    were asked for (``here``), its points (robot frame) and the queries."""

    k: int
    here: np.ndarray
    points: np.ndarray
    queries: list[LoopQuery]
    radii: list[float]
    """Each query's square's half side (m)."""


def _loop_request(
    k: int, points: np.ndarray, kf_pose: list, kf_travel: list, submaps: list[_Submap],
    p: SlamParams, links: list[tuple[int, int]],
) -> _LoopRequest:  # fmt: skip
    """The searches of keyframe ``k`` in the submaps near its pose: for each, a square and a
    heading window that grow with the travel between the two along the graph, loops closed
    so far (``links``: the submaps each joins) counting as no travel."""
    here = kf_pose[k]
    apart = _graph_travel(kf_travel, submaps, links, k)
    queries, radii = [], []
    for index, sub in enumerate(submaps):
        if kf_travel[k] - kf_travel[sub.last] < p.loop_min_travel_m:
            continue
        radius = min(p.loop_radius_m + p.loop_radius_per_m * apart[index], p.loop_max_radius_m)
        anchor = kf_pose[sub.first]
        if np.hypot(*(here[:2] - anchor[:2])) > radius + p.submap_m:
            continue
        window_deg = min(p.loop_window_deg + p.loop_window_per_m * apart[index], 180.0)
        search = SearchParams(half_width_m=radius, min_score=p.loop_min_score)
        params = LocalizeParams(window_deg=window_deg, search=search)
        queries.append(LoopQuery(index, relative_motion(anchor, here)[0], params))
        radii.append(radius)
    return _LoopRequest(k, here, points, queries, radii)


def _graph_travel(
    kf_travel: list, submaps: list[_Submap], links: list[tuple[int, int]], k: int
) -> np.ndarray:
    """The least travel (m) from keyframe ``k`` to the anchor of each submap (S,), along the
    chain of submaps, a loop between two (``links``) costing none: how far the odometry may
    have drifted between the two poses a search relates. ``k`` ends the submap after the
    last (not closed yet); a path crosses each submap it passes through, a loop's too
    (where in it the loop lands is left out: the longer way is taken)."""
    n = len(submaps)
    ends = [(kf_travel[sub.first], kf_travel[sub.last]) for sub in submaps]
    ends.append((kf_travel[submaps[-1].last] if submaps else 0.0, kf_travel[k]))
    span = [end - start for start, end in ends]
    neighbours: list[list[tuple[int, float]]] = [[] for _ in range(n + 1)]
    for a in range(n):
        gap = ends[a + 1][0] - ends[a][1]
        neighbours[a].append((a + 1, span[a] + gap))
        neighbours[a + 1].append((a, span[a + 1] + gap))
    for a, b in links:
        neighbours[a].append((b, span[a]))
        neighbours[b].append((a, span[b]))
    best = np.full(n + 1, np.inf)
    best[n] = 0.0
    heap = [(0.0, n)]
    while heap:  # Dijkstra from k's submap
        cost, a = heapq.heappop(heap)
        if cost > best[a]:
            continue
        for b, step in neighbours[a]:
            if cost + step < best[b]:
                best[b] = cost + step
                heapq.heappush(heap, (best[b], b))
    return best[:n] + np.array(span[:n])  # from the near end on to the anchor


def _close_loops(
    graph: _Graph, request: _LoopRequest, finds: list[LoopFind], submaps: list[_Submap],
    p: SlamParams, loops: list[LoopCandidate], gate_m: float,
) -> int:  # fmt: skip
    """Record the ``finds`` of a ``request``'s searches as loop candidates; add the loops
    accepted (their information from the points within ``gate_m`` of the submap) and say
    how many."""
    from segloc_cli.estimates import STATUS_OK

    k, here, points = request.k, request.here, request.points
    closed = 0
    for query, find, radius in zip(request.queries, finds, request.radii, strict=True):
        sub, found = submaps[query.submap], find.pose
        correction = relative_motion(query.guess, found)[0]  # NaN where nothing was found
        # The verdict's ``ok``, at a place inside the square searched, that the last such
        # find in this submap agrees with: both put the anchor at one place.
        plausible = find.status == STATUS_OK and bool(
            np.hypot(correction[0], correction[1]) <= radius * np.sqrt(2.0)
        )
        accepted = False
        if plausible:
            anchor_found = compose(here, Pose2(*found).inverse().as_array())
            earlier, sub.pending = sub.pending, (k, anchor_found)
            accepted = earlier is not None and _same_place(earlier[1], anchor_found)
        # The loop joins the submap's keyframe nearest the find: what bends a submap after
        # it was fused bends the loop least there.
        nearest = int(np.argmin(np.hypot(*(sub.members[:, :2] - found[:2]).T))) if plausible else 0
        motion = relative_motion(sub.members[nearest], found)[0]
        loops.append(
            LoopCandidate(
                k,
                query.submap,
                sub.first + nearest,
                (float(motion[0]), float(motion[1]), float(motion[2])),
                find.status,
                find.inlier_ratio,
                float(np.hypot(correction[0], correction[1])),
                float(np.rad2deg(abs(correction[2]))),
                accepted,
            )
        )
        if not accepted:
            continue
        information = fit_information(points, sub.segments, found, gate_m, p.point_sigma_m)
        graph.add_edge(
            sub.first + nearest, k, motion, information, cauchy=p.loop_cauchy, loop=len(loops) - 1
        )
        closed += 1
    return closed
