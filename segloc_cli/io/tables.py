"""Pose table files (survey CSV, TUM trajectories) and the estimates CSV.

Survey CSV: ``pose_id,time_s,x_m,y_m,theta_deg`` (columns by name, any order).
TUM trajectory: whitespace-separated ``t x y z qx qy qz qw`` lines, ``#`` comments;
the heading is the yaw of the quaternion. Estimates CSV: ``estimates.ESTIMATE_COLUMNS``.
Poses are (N, 3) arrays ``x_m y_m theta_rad`` in the world frame; headings are
degrees only in the files.

Whole tables are written atomically (a temporary file renamed into place); the
estimates of a running ``localize`` are streamed row by row instead
(``EstimatesWriter``, ``TumWriter``), so a killed run keeps every finished row.
Numbers are written rounded to the precision of their column's unit (``numbers.py``).
"""

from __future__ import annotations

import csv
import io
import math
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Self

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.estimates import (
    ESTIMATE_COLUMNS,
    ESTIMATE_FORMER_NAMES,
    ESTIMATE_INT_COLUMNS,
    ESTIMATE_LATER_COLUMNS,
    ESTIMATE_LATER_COUNTS,
    ESTIMATE_POSITION_COLUMNS,
    ESTIMATE_REQUIRED_FLOAT_COLUMNS,
    ESTIMATE_TEXT_COLUMNS,
    HYPOTHESIS_COLUMNS,
    UNSAID_COUNT,
    HypothesisRow,
    PoseTable,
)
from segloc_cli.geometry import heading_to_quaternion, quaternion_to_heading
from segloc_cli.io.files import OutputError, atomic_write, reading, write_whole, writing_error
from segloc_cli.limits import MAX_ABS_ID, MAX_COORDINATE_M
from segloc_cli.numbers import number_text, unit_of

if TYPE_CHECKING:
    import pandas as pd

STREAM_FSYNC_INTERVAL_S = 1.0
"""Streamed tables are flushed after every row and synced to disk at most this often (s)."""

SURVEY_COLUMNS = ["pose_id", "time_s", "x_m", "y_m", "theta_deg"]
POSE_FILES = "a CSV with the header pose_id,time_s,x_m,y_m,theta_deg, or a TUM trajectory"
"""The pose tables ``read_pose_table`` reads, in words."""


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


def _shown(text: str, limit: int = 40) -> str:
    """A field as quoted in an error message: 'empty', or its repr cut to ``limit`` characters."""
    if text == "":
        return "empty"
    return repr(text) if len(text) <= limit else repr(text[:limit]) + "…"


def _parse_float(path, row: int, column: str, text: str, allow_empty: bool = False) -> float:
    if text == "" and allow_empty:
        return math.nan
    try:
        value = float(text)
    except ValueError:
        value = None
    if value is None or not math.isfinite(value):
        raise InputError(
            f"column {column} is {_shown(text)}; expected a finite number", path=path, row=row
        )
    return value


def _parse_int(path, row: int, column: str, text: str) -> int:
    try:
        # int() first: ids beyond 2**53 would lose digits on the way through a float.
        value = int(text)
    except ValueError:
        number = _parse_float(path, row, column, text)
        if not number.is_integer():
            raise InputError(
                f"column {column} is {_shown(text)}; expected an integer", path=path, row=row
            ) from None
        value = int(number)
    if abs(value) > MAX_ABS_ID:
        raise InputError(
            f"column {column} is {_shown(text)}; expected an integer within ±{MAX_ABS_ID}",
            path=path,
            row=row,
        )
    return value


def _check_coordinates(path, poses: np.ndarray) -> None:
    """Refuse positions beyond ``MAX_COORDINATE_M`` (rows numbered from 1)."""
    beyond = np.flatnonzero(np.any(np.abs(poses[:, :2]) > MAX_COORDINATE_M, axis=1))
    if beyond.size:
        row = int(beyond[0])
        x, y = poses[row, 0], poses[row, 1]
        raise InputError(
            f"position ({x:g}, {y:g}) m is beyond ±{MAX_COORDINATE_M:g} m; "
            "expected coordinates in metres",
            path=path,
            row=row + 1,
        )


def _check_position(path, row: int, column: str, value: float) -> None:
    """Refuse a position (m) beyond ``MAX_COORDINATE_M``; NaN (an empty field) passes."""
    if abs(value) > MAX_COORDINATE_M:
        raise InputError(
            f"column {column} is {value:g}, beyond ±{MAX_COORDINATE_M:g} m; expected metres",
            path=path,
            row=row,
        )


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
    columns are ignored. The first line that is neither blank nor a ``#``
    comment decides the format: one that looks like a CSV header (it holds a
    comma, or its first whitespace-separated token is not a number) makes the
    file a survey CSV, and anything else a TUM trajectory (pose ids 1..N).
    Raises ``InputError`` naming the file and the 1-based data row for missing
    columns, bad numbers, duplicate ids, positions beyond
    ``MAX_COORDINATE_M``, or an empty table. Every pose returned is finite.
    """
    path = Path(path)
    text = _read_text(path)
    lines = text.splitlines()
    start = next(
        (i for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")), None
    )
    if start is not None and _looks_like_csv_header(lines[start]):
        table = _read_survey_csv(path, "\n".join(lines[start:]), require_time)
    else:
        table = _read_tum(path, text)
    if len(table) == 0:
        raise InputError("table has no data rows", path=path)
    _check_coordinates(path, table.poses)
    _check_unique_ids(path, table.pose_id)
    return table


def refuse_map(path: str | Path, option: str, takes: str) -> None:
    """Refuse a segloc map or world file given as ``option``, a pose table, before any work:
    ``InputError`` naming the file, saying what it is and that ``option`` ``takes`` (in words,
    "the surveyed poses") one of ``POSE_FILES``. Anything else passes, for its reader to judge.
    """
    from segloc_cli.io.maps import segloc_kind

    kind = segloc_kind(path)
    if kind is not None:
        raise InputError(
            f"a segloc {kind}, not a table of poses; {option} takes {takes}: {POSE_FILES}",
            path=path,
        )


def _looks_like_csv_header(line: str) -> bool:
    if "," in line:
        return True
    try:
        float(line.split()[0])
    except ValueError:
        return True
    return False


def _read_survey_csv(path: Path, text: str, require_time: bool) -> PoseTable:
    header, data = _read_csv_rows(path, text)
    required = ["x_m", "y_m", "theta_deg"] + (["time_s"] if require_time else [])
    for column in required:
        if column not in header:
            tum = "; a TUM trajectory has 8 numbers a line instead" if len(header) == 1 else ""
            raise InputError(
                f"missing column {column!r}; a survey CSV needs the header "
                f"pose_id,time_s,x_m,y_m,theta_deg (pose_id optional){tum}",
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
    # Scaled to a largest component of 1 so that neither 1e-300 nor 1e300 over- or underflows.
    quats = matrix[:, 4:] / np.max(np.abs(matrix[:, 4:]), axis=1, keepdims=True)
    heading = quaternion_to_heading(quats[:, 0], quats[:, 1], quats[:, 2], quats[:, 3])
    return PoseTable(
        pose_id=np.arange(1, len(matrix) + 1, dtype=np.int64),
        time_s=matrix[:, 0].copy(),
        poses=np.column_stack([matrix[:, 1], matrix[:, 2], heading]),
    )


def write_pose_table(
    path: str | Path, table: PoseTable, extra_columns: dict[str, np.ndarray] | None = None
) -> None:
    """Write ``table`` as a survey CSV (theta in degrees), atomically, numbers rounded to
    their precision (``numbers.py``: 1 ns, 1 µm, 1e-6°).

    The ``time_s`` column is left out when every time is NaN; a table with only
    some NaN times raises ``ValueError``. ``extra_columns`` (name → (N,) values)
    are written after the standard columns, in the order given: floats
    rounded to the unit their name ends with (NaN as an empty field), other
    values as ``str``; the reader ignores them. A name that clashes with a
    standard column or a length other than N raises ``ValueError``. An OS error while writing raises
    ``OutputError`` naming ``path``, and leaves an existing file as it was.
    """
    time_s = np.asarray(table.time_s, dtype=float)
    has_time = not np.all(np.isnan(time_s))
    if has_time and not np.all(np.isfinite(time_s)):
        raise ValueError("time_s must be finite in every row, or NaN in every row")
    poses = np.asarray(table.poses, dtype=float).reshape(-1, 3)
    columns = [c for c in SURVEY_COLUMNS if has_time or c != "time_s"]
    extra = {name: np.asarray(values).reshape(-1) for name, values in (extra_columns or {}).items()}
    for name, values in extra.items():
        if name in SURVEY_COLUMNS:
            raise ValueError(f"extra column {name!r} clashes with a survey column")
        if len(values) != len(table.pose_id):
            raise ValueError(
                f"extra column {name!r} has {len(values)} values for {len(table.pose_id)} poses"
            )
    with atomic_write(path) as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow([*columns, *extra])
        for i, (pid, t, (x, y, theta)) in enumerate(zip(table.pose_id, time_s, poses, strict=True)):
            row = [str(int(pid))] + ([number_text(t, "s")] if has_time else [])
            row += [number_text(x, "m"), number_text(y, "m")]
            row += [number_text(math.degrees(theta), "deg")]
            cells = (_cell(values[i], unit_of(name)) for name, values in extra.items())
            writer.writerow([*row, *cells])


def _cell(value: object, unit: str | None) -> str:
    """A CSV field: floats rounded to ``unit`` (NaN empty), integers and text as they are."""
    if isinstance(value, float | np.floating):
        return "" if math.isnan(value) else number_text(value, unit)
    if isinstance(value, np.integer):
        return str(int(value))
    return "" if value is None else str(value)


# --- estimates -------------------------------------------------------------------------


def _missing_columns(present) -> list[str]:
    """The estimates columns not in ``present``, those of earlier versions' files excepted."""
    return [c for c in ESTIMATE_COLUMNS if c not in present and c not in ESTIMATE_LATER_COLUMNS]


def _current_names(header: list[str]) -> list[str]:
    """An estimates header with the columns that earlier versions named otherwise
    (``ESTIMATE_FORMER_NAMES``) under their names of now."""
    former = {old: new for new, old in ESTIMATE_FORMER_NAMES.items() if new not in header}
    return [former.get(name, name) for name in header]


def _check_estimate_frame(frame: pd.DataFrame) -> None:
    missing = _missing_columns(frame.columns)
    if missing:
        raise ValueError(f"estimates frame lacks columns {missing}")


def estimate_cells(row: Mapping[str, Any]) -> list[str]:
    """One estimates row (column name → value) as the CSV fields of ``ESTIMATE_COLUMNS``.

    Integer columns as integers, ``status`` as text, other columns rounded to
    the unit of their name (``numbers.py``); a missing value (NaN, None) is
    an empty field. Keys beyond ``ESTIMATE_COLUMNS`` are ignored.
    Raises ``ValueError`` when a column is absent, or an integer column or
    ``time_s`` has no value.
    """
    missing = _missing_columns(row)
    if missing:
        raise ValueError(f"estimates row lacks columns {missing}")
    cells = []
    for c in ESTIMATE_COLUMNS:
        value = row.get(c, UNSAID_COUNT if c in ESTIMATE_LATER_COUNTS else None)
        absent = _absent(value)
        if absent and (c in ESTIMATE_INT_COLUMNS or c in ESTIMATE_REQUIRED_FLOAT_COLUMNS):
            raise ValueError(f"estimates column {c} must have a value in every row")
        if absent:
            cells.append("")
        elif c in ESTIMATE_INT_COLUMNS:
            cells.append(str(int(value)))
        elif c in ESTIMATE_TEXT_COLUMNS:
            cells.append(str(value))
        else:
            cells.append(number_text(value, unit_of(c)))
    return cells


def _absent(value: object) -> bool:
    """Whether a cell has no value: None, NaN, or a frame's missing value (pandas' NA, NaT;
    pandas is imported only for a value of its own, so that a run streaming its rows
    starts without it)."""
    if value is None:
        return True
    if isinstance(value, float | np.floating):
        return math.isnan(value)
    if type(value).__module__.partition(".")[0] == "pandas":
        import pandas as pd

        return bool(pd.isna(value))
    return False


def write_estimates(path: str | Path, frame: pd.DataFrame) -> None:
    """Write the estimates CSV atomically: columns ``ESTIMATE_COLUMNS`` in order
    (others are not written), each row as ``estimate_cells`` formats it.

    Raises ``ValueError`` when a column is missing or an integer column
    (``pose_id``, ``n_local_segments``) or ``time_s`` holds NaN, before
    anything is written; ``OutputError`` naming ``path`` on an OS error.
    """
    _check_estimate_frame(frame)
    for column in [*ESTIMATE_INT_COLUMNS, *ESTIMATE_REQUIRED_FLOAT_COLUMNS]:
        if column in frame and frame[column].isna().any():
            raise ValueError(f"estimates column {column} must have a value in every row")
    absent = [UNSAID_COUNT if c in ESTIMATE_INT_COLUMNS else None for c in ESTIMATE_COLUMNS]
    columns = {
        c: frame[c].tolist() if c in frame else [empty] * len(frame)
        for c, empty in zip(ESTIMATE_COLUMNS, absent, strict=True)
    }
    with atomic_write(path) as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow(ESTIMATE_COLUMNS)
        for i in range(len(frame)):
            writer.writerow(estimate_cells({c: columns[c][i] for c in ESTIMATE_COLUMNS}))


class _RowStream:
    """A text file written in place, one line at a time, each handed to the OS as written.

    Every line reaches the operating system before ``write_line`` returns, so a
    killed process leaves every line it finished; ``os.fsync`` runs at most
    every ``STREAM_FSYNC_INTERVAL_S`` and on ``close``, bounding what a power
    cut can take. A line the OS takes only part of (a full disk) is cut off again,
    so the file ends at the last whole line. OS errors come out as ``OutputError``
    naming the file.
    """

    def __init__(self, path: str | Path, header: str):
        self.path = Path(path)
        self.rows = 0
        self._size = 0  # bytes of the whole lines written
        try:
            # Unbuffered: nothing is left in a buffer for close() to fail on after an error.
            self._stream: IO[bytes] | None = open(self.path, "wb", buffering=0)
        except OSError as exc:
            raise writing_error(self.path, exc) from None
        self._synced_at = time.monotonic()
        try:
            self._write(header)
            self._sync()
        except OutputError:
            self._stream.close()
            self._stream = None
            raise

    def _write(self, line: str) -> None:
        if self._stream is None:
            raise ValueError(f"{self.path} is closed")
        encoded = (line + "\n").encode("utf-8")
        try:
            write_whole(self._stream.fileno(), encoded, self._size)
        except OSError as exc:
            raise writing_error(self.path, exc) from None
        self._size += len(encoded)

    def _sync(self) -> None:
        assert self._stream is not None
        try:
            os.fsync(self._stream.fileno())
        except OSError as exc:
            raise writing_error(self.path, exc) from None
        self._synced_at = time.monotonic()

    def write_line(self, line: str) -> None:
        self._write(line)
        self.rows += 1
        if time.monotonic() - self._synced_at >= STREAM_FSYNC_INTERVAL_S:
            self._sync()

    def close(self) -> None:
        """Sync and close the file; closing again does nothing."""
        if self._stream is None:
            return
        stream, self._stream = self._stream, None
        try:
            os.fsync(stream.fileno())
        except OSError as exc:
            raise writing_error(self.path, exc) from None
        finally:
            stream.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


class EstimatesWriter(_RowStream):
    """The estimates CSV written row by row as a run makes them.

    Opens ``path`` in place (truncating it; checking that it may be
    overwritten is the caller's job) and writes the ``ESTIMATE_COLUMNS`` header
    at once. ``write_row(row)`` writes one row exactly as ``write_estimates``
    would (``estimate_cells``) and flushes it, so a killed run leaves a file
    of whole rows that ``read_estimates`` reads; the file is synced to disk at
    most every ``STREAM_FSYNC_INTERVAL_S`` and on ``close``. A context manager:
    leaving the block closes the file, whatever happened. ``rows`` counts the
    rows written.
    """

    def __init__(self, path: str | Path):
        super().__init__(path, ",".join(ESTIMATE_COLUMNS))

    def write_row(self, row: Mapping[str, Any]) -> None:
        """Write one estimates row (column → value); ``ValueError`` as ``estimate_cells``."""
        cells = estimate_cells(row)
        buffer = io.StringIO()
        csv.writer(buffer, lineterminator="").writerow(cells)
        self.write_line(buffer.getvalue())


def read_estimates(path: str | Path) -> pd.DataFrame:
    """Read an estimates CSV → DataFrame with ``ESTIMATE_COLUMNS`` in order.

    Types: ``pose_id`` and ``n_local_segments`` int64, ``status`` str, all
    others float64 (empty → NaN, except ``time_s`` which is required). Raises
    ``InputError`` naming the file and 1-based data row on a missing column or
    a bad value (a position beyond ±``MAX_COORDINATE_M`` among them).
    """
    import pandas as pd

    path = Path(path)
    header, data = _read_csv_rows(path, _read_text(path))
    header = _current_names(header)
    missing = _missing_columns(header)
    if missing:
        raise InputError(
            f"missing column(s) {', '.join(missing)}; expected an estimates CSV written by "
            "`segloc localize`",
            path=path,
        )
    col = {name: header.index(name) if name in header else None for name in ESTIMATE_COLUMNS}
    values: dict[str, list] = {c: [] for c in ESTIMATE_COLUMNS}
    for row, fields in data:
        for c in ESTIMATE_COLUMNS:
            index = col[c]
            text = "" if index is None else fields[index]
            if c in ESTIMATE_INT_COLUMNS:
                unsaid = index is None
                values[c].append(UNSAID_COUNT if unsaid else _parse_int(path, row, c, text))
            elif c in ESTIMATE_TEXT_COLUMNS:
                values[c].append(text)
            else:
                optional = c not in ESTIMATE_REQUIRED_FLOAT_COLUMNS
                values[c].append(_parse_float(path, row, c, text, allow_empty=optional))
                if c in ESTIMATE_POSITION_COLUMNS:
                    _check_position(path, row, c, values[c][-1])
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


TUM_HEADER = "# segloc estimates: t x y z qx qy qz qw"


def _tum_lines(numbers: np.ndarray) -> list[str]:
    """Rows (K, 4) ``time_s, x_m, y_m, theta_deg`` → TUM lines ``t x y 0 qx qy qz qw``
    (seconds, metres, the quaternion's plain numbers, each rounded as ``numbers.py`` says)."""
    quats = heading_to_quaternion(np.deg2rad(numbers[:, 3]))
    units = ("s", "m", "m", "m", None, None, None, None)
    return [
        " ".join(number_text(v, unit) for v, unit in zip((t, x, y, 0.0, *q), units, strict=True))
        for (t, x, y, _), q in zip(numbers, quats, strict=True)
    ]


def _tum_numbers(rows: Mapping[str, Any] | pd.DataFrame) -> np.ndarray:
    """``time_s, x_m, y_m, theta_deg`` of the rows whose four values are all finite, (K, 4)."""
    columns = ["time_s", "x_m", "y_m", "theta_deg"]
    if not isinstance(rows, Mapping):  # a frame
        numbers = rows[columns].to_numpy(dtype=float)
    else:
        numbers = np.array(
            [[np.nan if rows[c] is None else float(rows[c]) for c in columns]], dtype=float
        )
    return numbers[np.all(np.isfinite(numbers), axis=1)]


def write_tum(path: str | Path, frame: pd.DataFrame) -> None:
    """Write the estimates as a TUM trajectory ``t x y 0 qx qy qz qw``, atomically.

    Only rows whose ``time_s, x_m, y_m, theta_deg`` are all finite are written.
    """
    _check_estimate_frame(frame)
    lines = [TUM_HEADER, *_tum_lines(_tum_numbers(frame))]
    with atomic_write(path) as stream:
        stream.write("\n".join(lines) + "\n")


def write_pose_table_tum(path: str | Path, table: PoseTable) -> None:
    """Write ``table`` as a TUM trajectory ``t x y 0 qx qy qz qw`` (what evo reads), atomically;
    ``read_pose_table`` reads it back (pose ids 1..N). Every time must be finite
    (``ValueError``)."""
    time_s = np.asarray(table.time_s, dtype=float).reshape(-1)
    if not np.all(np.isfinite(time_s)):
        raise ValueError("a TUM trajectory needs a finite time in every row")
    poses = np.asarray(table.poses, dtype=float).reshape(-1, 3)
    numbers = np.column_stack([time_s, poses[:, :2], np.rad2deg(poses[:, 2])])
    with atomic_write(path) as stream:
        stream.write("\n".join(["# segloc reference: t x y z qx qy qz qw", *_tum_lines(numbers)]))
        stream.write("\n")


class HypothesesWriter(_RowStream):
    """The hypotheses CSV (``HYPOTHESIS_COLUMNS``), written as ``EstimatesWriter`` writes the
    estimates: for each estimates row, a line for each of the first ``limit`` poses its
    ``hypotheses`` list (none for a row without), ranked from 1, the answer."""

    def __init__(self, path: str | Path, limit: int):
        super().__init__(path, ",".join(HYPOTHESIS_COLUMNS))
        self.limit = int(limit)

    def write_row(self, row: Mapping[str, Any]) -> None:
        """Write the hypotheses of one estimates row (needs ``pose_id`` and ``time_s``)."""
        listed = list(row.get("hypotheses") or [])[: self.limit]
        for rank, hypothesis in enumerate(listed, 1):
            cells = [str(int(row["pose_id"])), number_text(row["time_s"], "s"), str(rank)]
            for column in HypothesisRow.__annotations__:
                value = float(hypothesis[column])
                cells.append(number_text(value, unit_of(column)) if math.isfinite(value) else "")
            self.write_line(",".join(cells))


class TumWriter(_RowStream):
    """A TUM trajectory written row by row, as ``EstimatesWriter`` writes the CSV.

    ``write_row(row)`` takes an estimates row and writes the line
    ``write_tum`` would write for it (none when its time or pose is not
    finite); every line is flushed as written and synced as in
    ``EstimatesWriter``. A context manager; ``rows`` counts the lines written.
    """

    def __init__(self, path: str | Path):
        super().__init__(path, TUM_HEADER)

    def write_row(self, row: Mapping[str, Any]) -> None:
        """Write the pose of one estimates row (needs ``time_s, x_m, y_m, theta_deg``)."""
        for line in _tum_lines(_tum_numbers(row)):
            self.write_line(line)
