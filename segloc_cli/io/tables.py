"""Pose tables (survey CSV, TUM trajectories), the estimates CSV, and time matching.

Survey CSV: ``pose_id,time_s,x_m,y_m,theta_deg`` (columns by name, any order).
TUM trajectory: whitespace-separated ``t x y z qx qy qz qw`` lines, ``#`` comments;
the heading is the yaw of the quaternion. Estimates CSV: ``ESTIMATE_COLUMNS``.
Poses are (N, 3) arrays ``x_m y_m theta_rad`` in the world frame; headings are
degrees only in the files.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from segloc_cli.errors import InputError
from segloc_cli.geometry import heading_to_quaternion, quaternion_to_heading
from segloc_cli.io.files import reading

SURVEY_COLUMNS = ["pose_id", "time_s", "x_m", "y_m", "theta_deg"]

ESTIMATE_COLUMNS = [
    "pose_id",
    "time_s",
    "init_x_m",
    "init_y_m",
    "init_theta_deg",
    "align_theta_deg",
    "stage2_x_m",
    "stage2_y_m",
    "stage2_theta_deg",
    "x_m",
    "y_m",
    "theta_deg",
    "overlap",
    "inlier_ratio",
    "runner_up_x_m",
    "runner_up_y_m",
    "runner_up_theta_deg",
    "runner_up_ratio",
    "n_local_segments",
    "runtime_ms",
    "status",
]
ESTIMATE_INT_COLUMNS = ["pose_id", "n_local_segments"]
ESTIMATE_TEXT_COLUMNS = ["status"]
# Float columns that must hold a number in every row; the others may be empty (NaN).
ESTIMATE_REQUIRED_FLOAT_COLUMNS = ["time_s"]


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


# --- time matching --------------------------------------------------------------


def nearest_by_time(query_times_s, ref_times_s, tolerance_s: float) -> np.ndarray:
    """Index into ``ref_times_s`` of the nearest reference time for each query.

    ``query_times_s`` (Q,) and ``ref_times_s`` (R,) seconds; ``ref`` need not be
    sorted. Returns (Q,) int64 indices, −1 where no reference time lies within
    ``tolerance_s`` (inclusive) or the query is NaN. On a tie the earlier
    reference time wins; among equal reference times, the first in ``ref``.
    """
    query = np.asarray(query_times_s, dtype=float).reshape(-1)
    ref = np.asarray(ref_times_s, dtype=float).reshape(-1)
    result = np.full(query.shape, -1, dtype=np.int64)
    finite_ref = np.flatnonzero(np.isfinite(ref))
    if finite_ref.size == 0 or query.size == 0:
        return result
    order = finite_ref[np.argsort(ref[finite_ref], kind="stable")]
    sorted_ref = ref[order]
    n = len(sorted_ref)

    right = np.searchsorted(sorted_ref, query, side="left")
    left = right - 1
    right_c = np.clip(right, 0, n - 1)
    left_c = np.clip(left, 0, n - 1)
    with np.errstate(invalid="ignore"):
        dist_right = np.where(right < n, sorted_ref[right_c] - query, np.inf)
        dist_left = np.where(left >= 0, query - sorted_ref[left_c], np.inf)
    # The left neighbour may be the last of a run of equal times: step back to its first.
    left_first = np.searchsorted(sorted_ref, sorted_ref[left_c], side="left")
    take_left = dist_left <= dist_right
    best_pos = np.where(take_left, left_first, right_c)
    best_dist = np.where(take_left, dist_left, dist_right)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(query) & (best_dist <= tolerance_s)
    result[ok] = order[best_pos[ok]]
    return result


# --- shared reading helpers -------------------------------------------------------


def _read_text(path: Path) -> str:
    with reading(path, "a CSV or TUM table"):
        # utf-8-sig drops the byte-order mark some spreadsheets write.
        return path.read_text(encoding="utf-8-sig")


def _read_csv_rows(path: Path, text: str) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """Header names and (1-based data row, fields) for every non-blank data row."""
    try:
        rows = [row for row in csv.reader(text.splitlines()) if any(f.strip() for f in row)]
    except csv.Error as exc:
        raise InputError(f"not a readable CSV file ({exc})", path=path) from None
    if not rows:
        raise InputError("file is empty; expected a CSV header and data rows", path=path)
    header = [name.strip() for name in rows[0]]
    data = []
    for number, fields in enumerate(rows[1:], start=1):
        if len(fields) != len(header):
            raise InputError(
                f"has {len(fields)} fields but the header has {len(header)}",
                path=path,
                row=number,
            )
        data.append((number, [f.strip() for f in fields]))
    return header, data


def _parse_float(path, row: int, column: str, text: str, allow_empty: bool = False) -> float:
    if text == "" and allow_empty:
        return math.nan
    try:
        value = float(text)
    except ValueError:
        value = None
    if value is None or not math.isfinite(value):
        shown = "empty" if text == "" else f"{text!r}"
        raise InputError(
            f"column {column} is {shown}; expected a finite number", path=path, row=row
        )
    return value


def _parse_int(path, row: int, column: str, text: str) -> int:
    value = _parse_float(path, row, column, text)
    if not value.is_integer():
        raise InputError(f"column {column} is {text!r}; expected an integer", path=path, row=row)
    return int(value)


def _check_unique_ids(path, pose_id: np.ndarray) -> None:
    first_row: dict[int, int] = {}
    for row, pid in enumerate(pose_id.tolist(), start=1):
        if pid in first_row:
            raise InputError(
                f"pose_id {pid} repeats row {first_row[pid]}; pose ids must be unique",
                path=path,
                row=row,
            )
        first_row[pid] = row


# --- pose tables ----------------------------------------------------------------------


def read_pose_table(path: str | Path, require_time: bool = True) -> PoseTable:
    """Read a survey CSV or a TUM trajectory → ``PoseTable``.

    Survey CSV columns are found by name: ``x_m, y_m, theta_deg`` required,
    ``time_s`` required when ``require_time``, ``pose_id`` optional (1..N); other
    columns are ignored. A file whose first non-comment line is not a CSV header
    naming ``x_m`` is read as TUM (pose ids 1..N). Raises ``InputError`` naming
    the file and the 1-based data row for missing columns, bad numbers,
    duplicate ids, or an empty table.
    """
    path = Path(path)
    text = _read_text(path)
    first = next(
        (ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")), ""
    )
    if "x_m" in [name.strip() for name in first.split(",")]:
        table = _read_survey_csv(path, text, require_time)
    else:
        table = _read_tum(path, text)
    if len(table) == 0:
        raise InputError("table has no data rows", path=path)
    _check_unique_ids(path, table.pose_id)
    return table


def _read_survey_csv(path: Path, text: str, require_time: bool) -> PoseTable:
    header, data = _read_csv_rows(path, text)
    required = ["x_m", "y_m", "theta_deg"] + (["time_s"] if require_time else [])
    for column in required:
        if column not in header:
            raise InputError(
                f"missing column {column!r}; a survey CSV needs the header "
                "pose_id,time_s,x_m,y_m,theta_deg (pose_id optional)",
                path=path,
            )
    col = {name: header.index(name) for name in SURVEY_COLUMNS if name in header}
    n = len(data)
    pose_id = np.arange(1, n + 1, dtype=np.int64)
    time_s = np.full(n, np.nan)
    poses = np.zeros((n, 3))
    for i, (row, fields) in enumerate(data):
        if "pose_id" in col:
            pose_id[i] = _parse_int(path, row, "pose_id", fields[col["pose_id"]])
        if "time_s" in col:
            time_s[i] = _parse_float(path, row, "time_s", fields[col["time_s"]])
        poses[i, 0] = _parse_float(path, row, "x_m", fields[col["x_m"]])
        poses[i, 1] = _parse_float(path, row, "y_m", fields[col["y_m"]])
        poses[i, 2] = math.radians(_parse_float(path, row, "theta_deg", fields[col["theta_deg"]]))
    return PoseTable(pose_id=pose_id, time_s=time_s, poses=poses)


TUM_FIELDS = ["t", "x", "y", "z", "qx", "qy", "qz", "qw"]


def _read_tum(path: Path, text: str) -> PoseTable:
    rows = []
    lines = (ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#"))
    for row, line in enumerate(lines, start=1):
        fields = line.split()
        if len(fields) != len(TUM_FIELDS):
            raise InputError(
                f"expected 8 whitespace-separated values 't x y z qx qy qz qw' (TUM), got "
                f"{len(fields)}; a survey CSV needs the header pose_id,time_s,x_m,y_m,theta_deg",
                path=path,
                row=row,
            )
        values = [
            _parse_float(path, row, name, text)
            for name, text in zip(TUM_FIELDS, fields, strict=True)
        ]
        if not any(values[4:]):
            raise InputError("quaternion is all zeros; expected a rotation", path=path, row=row)
        rows.append(values)
    if not rows:
        raise InputError("table has no data rows", path=path)
    matrix = np.array(rows, dtype=float)
    heading = quaternion_to_heading(matrix[:, 4], matrix[:, 5], matrix[:, 6], matrix[:, 7])
    return PoseTable(
        pose_id=np.arange(1, len(matrix) + 1, dtype=np.int64),
        time_s=matrix[:, 0].copy(),
        poses=np.column_stack([matrix[:, 1], matrix[:, 2], heading]),
    )


def _fmt(value: float) -> str:
    # repr() is the shortest text that parses back to the identical float64.
    return repr(float(value))


def write_pose_table(path: str | Path, table: PoseTable) -> None:
    """Write ``table`` as a survey CSV (theta in degrees, floats round-trip exactly).

    The ``time_s`` column is left out when every time is NaN; a table with only
    some NaN times raises ``ValueError``.
    """
    time_s = np.asarray(table.time_s, dtype=float)
    has_time = not np.all(np.isnan(time_s))
    if has_time and not np.all(np.isfinite(time_s)):
        raise ValueError("time_s must be finite in every row, or NaN in every row")
    poses = np.asarray(table.poses, dtype=float).reshape(-1, 3)
    columns = [c for c in SURVEY_COLUMNS if has_time or c != "time_s"]
    with open(path, "w", newline="", encoding="utf-8") as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow(columns)
        for pid, t, (x, y, theta) in zip(table.pose_id, time_s, poses, strict=True):
            row = [str(int(pid))] + ([_fmt(t)] if has_time else [])
            writer.writerow([*row, _fmt(x), _fmt(y), _fmt(math.degrees(theta))])


# --- estimates -------------------------------------------------------------------------


def _check_estimate_frame(frame: pd.DataFrame) -> None:
    missing = [c for c in ESTIMATE_COLUMNS if c not in frame.columns]
    if missing:
        raise ValueError(f"estimates frame lacks columns {missing}")


def write_estimates(path: str | Path, frame: pd.DataFrame) -> None:
    """Write the estimates CSV: columns ``ESTIMATE_COLUMNS`` in order (others are
    not written), floats that round-trip exactly, NaN as an empty field.

    Raises ``ValueError`` when a column is missing or an integer column
    (``pose_id``, ``n_local_segments``) or ``time_s`` holds NaN.
    """
    _check_estimate_frame(frame)
    for column in [*ESTIMATE_INT_COLUMNS, *ESTIMATE_REQUIRED_FLOAT_COLUMNS]:
        if frame[column].isna().any():
            raise ValueError(f"estimates column {column} must have a value in every row")
    columns = {c: frame[c].tolist() for c in ESTIMATE_COLUMNS}
    with open(path, "w", newline="", encoding="utf-8") as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow(ESTIMATE_COLUMNS)
        for i in range(len(frame)):
            row = []
            for c in ESTIMATE_COLUMNS:
                value = columns[c][i]
                if c in ESTIMATE_INT_COLUMNS:
                    row.append(str(int(value)))
                elif c in ESTIMATE_TEXT_COLUMNS:
                    row.append("" if pd.isna(value) else str(value))
                else:
                    row.append("" if pd.isna(value) else _fmt(value))
            writer.writerow(row)


def read_estimates(path: str | Path) -> pd.DataFrame:
    """Read an estimates CSV → DataFrame with ``ESTIMATE_COLUMNS`` in order.

    Types: ``pose_id`` and ``n_local_segments`` int64, ``status`` str, all
    others float64 (empty → NaN, except ``time_s`` which is required). Raises
    ``InputError`` naming the file and 1-based data row on a missing column or
    a bad value.
    """
    path = Path(path)
    header, data = _read_csv_rows(path, _read_text(path))
    missing = [c for c in ESTIMATE_COLUMNS if c not in header]
    if missing:
        raise InputError(
            f"missing column(s) {', '.join(missing)}; expected an estimates CSV written by "
            "`segloc localize`",
            path=path,
        )
    col = {name: header.index(name) for name in ESTIMATE_COLUMNS}
    values: dict[str, list] = {c: [] for c in ESTIMATE_COLUMNS}
    for row, fields in data:
        for c in ESTIMATE_COLUMNS:
            text = fields[col[c]]
            if c in ESTIMATE_INT_COLUMNS:
                values[c].append(_parse_int(path, row, c, text))
            elif c in ESTIMATE_TEXT_COLUMNS:
                values[c].append(text)
            else:
                optional = c not in ESTIMATE_REQUIRED_FLOAT_COLUMNS
                values[c].append(_parse_float(path, row, c, text, allow_empty=optional))
    frame = pd.DataFrame(
        {
            c: pd.Series(
                values[c],
                dtype=(
                    np.int64
                    if c in ESTIMATE_INT_COLUMNS
                    else object
                    if c in ESTIMATE_TEXT_COLUMNS
                    else np.float64
                ),
            )
            for c in ESTIMATE_COLUMNS
        }
    )
    return frame


def write_tum(path: str | Path, frame: pd.DataFrame) -> None:
    """Write the estimates as a TUM trajectory ``t x y 0 qx qy qz qw``.

    Only rows whose ``time_s, x_m, y_m, theta_deg`` are all finite are written.
    """
    _check_estimate_frame(frame)
    numbers = frame[["time_s", "x_m", "y_m", "theta_deg"]].to_numpy(dtype=float)
    numbers = numbers[np.all(np.isfinite(numbers), axis=1)]
    quats = heading_to_quaternion(np.deg2rad(numbers[:, 3]))
    lines = ["# segloc estimates: t x y z qx qy qz qw"]
    for (t, x, y, _), q in zip(numbers, quats, strict=True):
        lines.append(" ".join(_fmt(v) for v in (t, x, y, 0.0, *q)))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
