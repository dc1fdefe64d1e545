"""What a run makes: the estimates row of each scan, its columns, its statuses, and the
pose tables (survey, reference, guesses) that rows are scored against or seeded from.

The types are plain data shared by the method, the scoring and the file formats
(``io/tables.py`` reads and writes them); importing them loads neither pandas nor a kernel.
Positions are metres and headings degrees in rows, world frame; ``PoseTable`` holds radians.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypedDict, get_type_hints

import numpy as np

STATUS_OK = "ok"
STATUS_AMBIGUOUS = "ambiguous"
"""The answer may well be the wrong place: a distinct pose explains the scan nearly as well,
or the scan cannot tell such places apart."""
STATUS_LOST = "lost"
"""Too little of the scan lies on the map at the answer."""
STATUS_TOO_FEW_SEGMENTS = "too_few_segments"
"""The scan cannot pin a pose: too few local segments, too few points, or points spread along
one line (``localize.scan_is_degenerate``). A pose found anyway is kept in the row, but not
trusted."""
STATUS_NO_OVERLAP = "no_overlap"
STATUS_RECOVERED = "recovered"
"""Tracking: the first match failed its checks, a wider search passed them."""
ESTIMATED = (STATUS_OK, STATUS_RECOVERED)
"""Statuses of rows that hold an accepted estimate; every other status marks a failure.
(``ambiguous`` and ``lost`` rows hold a pose too, the best found, but it is not trusted.)"""
STATUS_TASK_FAILED = "task failed"
"""The status of the one row a failed task leaves: its ``error`` says why."""
STATUS_NO_SCAN = "no scan"
"""A survey pose within the log's time span that no scan lies near enough in time to."""
STATUS_NO_GUESS = "no guess"
"""A survey pose whose scan has no initial guess (from the guesses file or /odom)."""
STATUS_NO_ESTIMATE = "no_estimate"
"""Scoring: a surveyed pose that no estimate lies near enough in time to (the localizer said
nothing there). It fails every per-pose gate and counts against ``--min-paired-pct``."""


class EstimateColumns(TypedDict):
    """One row of the estimates CSV: the outcome for one scan, world frame.

    Positions in metres, headings in degrees, NaN where a value was not made:
    the initial guess (``init_*``, NaN for a global search), stage 1's heading
    (``align_theta_deg``), where stage 2 ended (``stage2_*``), the answer
    (``x_m``, ``y_m``, ``theta_deg``), the stage-2 overlap (``overlap_m``, m of segment), the
    share of the scan's points on the map at the answer, the best distinct
    alternative found and its share (``runner_up_*``), the count of local
    segments, the time spent on the scan (ms), the probability that the answer is
    the right place (``confidence``, NaN where no verdict was made from the scan's
    points), the verdict (``status``) and how many scans the local map held
    (``window_scans``: 1 for the scan alone, more with its neighbours placed by
    odometry; 0 where a file of an earlier version does not say).
    The fields, in order, are the file's columns.
    """

    pose_id: int
    time_s: float
    init_x_m: float
    init_y_m: float
    init_theta_deg: float
    align_theta_deg: float
    stage2_x_m: float
    stage2_y_m: float
    stage2_theta_deg: float
    x_m: float
    y_m: float
    theta_deg: float
    overlap_m: float
    inlier_ratio: float
    runner_up_x_m: float
    runner_up_y_m: float
    runner_up_theta_deg: float
    runner_up_ratio: float
    n_local_segments: int
    runtime_ms: float
    confidence: float
    status: str
    window_scans: int


class HypothesisRow(TypedDict):
    """One distinct pose found for a scan (world frame; metres, degrees): its share of points
    on the map, fit score (0–1) and probability of being the right place."""

    x_m: float
    y_m: float
    theta_deg: float
    inlier_ratio: float
    score: float
    confidence: float


class EstimateRow(EstimateColumns, total=False):
    """An estimates row as a run makes it: the columns, and beside them (not a column) the
    distinct poses found for the scan, best first (``HypothesesWriter``)."""

    hypotheses: list[HypothesisRow]


ESTIMATE_COLUMNS = list(EstimateColumns.__annotations__)
"""Columns of the estimates CSV, in order: the fields of ``EstimateColumns``."""
ESTIMATE_INT_COLUMNS = [c for c, kind in get_type_hints(EstimateColumns).items() if kind is int]
ESTIMATE_TEXT_COLUMNS = [c for c, kind in get_type_hints(EstimateColumns).items() if kind is str]
HYPOTHESIS_COLUMNS = ["pose_id", "time_s", "rank", *HypothesisRow.__annotations__]
"""Columns of the hypotheses CSV (``HypothesesWriter``): a row per distinct pose of a scan,
``rank`` 1 the answer."""
# Float columns that must hold a number in every row; the others may be empty (NaN).
ESTIMATE_REQUIRED_FLOAT_COLUMNS = ["time_s"]
ESTIMATE_POSITION_COLUMNS = [c for c in ESTIMATE_COLUMNS if c.endswith(("x_m", "y_m"))]
"""Columns holding a position (m), within ±``MAX_COORDINATE_M`` where not empty."""
ESTIMATE_LATER_COLUMNS = ["confidence", "window_scans"]
"""Columns that files written by earlier versions lack; read as empty (NaN) there, or as
``UNSAID_COUNT`` for a count."""
UNSAID_COUNT = 0
"""``window_scans`` of a row made before the column was: the count was not kept."""
COVARIANCE_COLUMNS = (
    "var_x_m2",
    "cov_xy_m2",
    "var_y_m2",
    "cov_x_theta_m_rad",
    "cov_y_theta_m_rad",
    "var_theta_rad2",
)
"""The pose covariance an estimate may carry (another localizer's, read by
``io/trajectories.py``): the upper triangle of the symmetric 3×3 covariance of (x m, y m,
θ rad), world frame, column by column. Not columns of segloc's own estimates CSV; NaN where the
input has none."""
COVARIANCE_CELLS = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))
"""Where each of ``COVARIANCE_COLUMNS`` sits in the 3×3 covariance of (x, y, θ): (row,
column), the matrix being symmetric."""
ESTIMATE_FORMER_NAMES = {"overlap_m": "overlap"}
"""Columns that files of segloc 0.1 name otherwise: the column → its name there."""
ESTIMATE_LATER_COUNTS = [c for c in ESTIMATE_LATER_COLUMNS if c in ESTIMATE_INT_COLUMNS]
"""The later columns that are counts, ``UNSAID_COUNT`` where a row lacks them."""


@dataclass(frozen=True)
class PoseTable:
    """Poses with ids and times.

    ``pose_id`` (N,) int64; ``time_s`` (N,) float64 seconds, NaN when the file
    has no times; ``poses`` (N, 3) float64 ``x_m, y_m, theta_rad``, world frame.
    """

    pose_id: np.ndarray
    time_s: np.ndarray
    poses: np.ndarray

    def __len__(self) -> int:
        return len(self.pose_id)


@dataclass(frozen=True)
class Relations:
    """Reference relative motions between pairs of robot poses.

    ``t1_s``, ``t2_s`` (R,) float64 seconds, the times of the two poses;
    ``delta`` (R, 3) float64 ``dx_m, dy_m, dyaw_rad``: the motion from the pose
    at t1 to the pose at t2, expressed in the frame of the pose at t1.
    """

    t1_s: np.ndarray
    t2_s: np.ndarray
    delta: np.ndarray

    def __len__(self) -> int:
        return len(self.t1_s)
