"""The two stages together: one local map → one pose, and a whole log → estimates."""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from segloc_cli.align import RTable, align
from segloc_cli.extract import ExtractParams, extract_segments
from segloc_cli.geometry import Pose2
from segloc_cli.overlap import coarse_to_fine
from segloc_cli.scan import Scan

STATUS_OK = "ok"
STATUS_TOO_FEW_SEGMENTS = "too_few_segments"
STATUS_NO_OVERLAP = "no_overlap"


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
            self.rtable,
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
        local_map = extract_segments(scan, extract_params)
        est = localizer.localize(local_map, initial)
        runtime_ms = (time.perf_counter() - t0) * 1e3
        yield (
            {
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
                "status": est.status,
            }
        )
