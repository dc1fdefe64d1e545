"""Another localizer's pose trajectory, read as estimates that ``segloc evaluate`` scores.

Formats (``EST_FORMATS``; ``guess_format`` tells them by extension and contents):

- ``segloc``: segloc's own estimates CSV (``io/tables.read_estimates``), rows as written;
- ``tum``: a TUM trajectory, ``t x y z qx qy qz qw`` per line (seconds, metres, a
  quaternion), ``#`` comments;
- ``ros1``, ``ros2``, ``mcap``: a ROS 1 ``.bag``, a ROS 2 bag folder (``metadata.yaml``,
  sqlite3 or MCAP storage) or an MCAP file, with the poses of one topic: a
  ``geometry_msgs/PoseWithCovarianceStamped`` (AMCL's ``/amcl_pose``),
  ``geometry_msgs/PoseStamped``, ``nav_msgs/Odometry`` or ``foxglove.PoseInFrame``
  (protobuf or JSON) per message, or the transform chain between two ``frames`` of a
  ``tf2_msgs/TFMessage`` (or ``foxglove.FrameTransforms``) topic, composed as
  ``io/tf_chain.py`` says with the links of ``/tf_static`` held fixed.

What comes back is a DataFrame with the columns ``estimates.ESTIMATE_COLUMNS`` and
``estimates.COVARIANCE_COLUMNS``. For the foreign formats: ``pose_id`` 1..N in time order;
``time_s`` the pose's time in seconds (a message's header stamp, not the time the bag
recorded it); ``x_m``, ``y_m`` the position and ``theta_deg`` the yaw (the heading of the
robot's x axis seen from above) in [-180, 180), in the frame the poses are in; ``status``
"ok"; the other estimate columns NaN and the counts 0; the covariance the (x, y, yaw)
block of the message's 6×6 pose covariance (m², m·rad, rad²), NaN where the input has none.

A 2D localizer's poses are level. A pose tilted more than ``MAX_PLANAR_TILT_DEG`` from
level is no floor pose and is left out; one tilted more than ``MAX_TILT_DEG`` is kept (its
heading is still its x axis seen from above) and counted in a warning (both limits are
``segloc_cli.limits``, the same for a bag's scanner).

Nothing is left out unsaid. ``frame.attrs`` holds ``source``, one line saying what was read
(format, topic, type, count, frame), ``dropped``, reason → count of the messages or
transforms left out (not finite, in another frame than most, a repeated stamp keeping the
first, undecodable, before a transform chain was complete …), and ``warnings``, notes on
poses kept (tilted, timed by their log time, a file read up to damage).
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from segloc_cli.errors import InputError
from segloc_cli.estimates import (
    COVARIANCE_COLUMNS,
    ESTIMATE_COLUMNS,
    ESTIMATE_INT_COLUMNS,
    ESTIMATE_TEXT_COLUMNS,
    STATUS_OK,
)
from segloc_cli.geometry import quaternion_to_heading
from segloc_cli.io.files import reading
from segloc_cli.io.other_logs import refuse_inside_ros2_bag
from segloc_cli.limits import MAX_COORDINATE_M, MAX_PLANAR_TILT_DEG, MAX_TILT_DEG
from segloc_cli.wording import counted, plural

EST_FORMATS = ("segloc", "tum", "ros1", "ros2", "mcap")
FORMAT_OPTION = "--est-format"
TOPIC_OPTION = "--topic"
FRAMES_OPTION = "--frames"
"""The options of ``segloc evaluate`` that set ``fmt``, ``topic`` and ``frames``, as the
messages name them."""
TUM_VALUES = 8
_EXTENSIONS = {".csv": "segloc", ".tum": "tum", ".bag": "ros1", ".mcap": "mcap"}
_KINDS = {"segloc": "segloc estimates CSV", "tum": "TUM trajectory"}


def guess_format(path: Path) -> str:
    """The format (one of ``EST_FORMATS``) of the trajectory at ``path``: a folder with
    ``metadata.yaml`` is a ROS 2 bag; a file by its extension (``.csv``, ``.tum``, ``.bag``,
    ``.mcap``), else by its first bytes (MCAP or ROS bag magic, a line of 8 numbers for
    TUM, an estimates header). ``InputError`` naming ``FORMAT_OPTION`` when it cannot tell.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("file or folder not found; check the path", path=path)
    choose = f"give {FORMAT_OPTION} (one of {', '.join(EST_FORMATS)})"
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "ros2"
        raise InputError(f"is a folder without metadata.yaml, not a ROS 2 bag; {choose}", path=path)
    if path.suffix.lower() in _EXTENSIONS:
        return _EXTENSIONS[path.suffix.lower()]
    with reading(path, "a trajectory"), path.open("rb") as stream:
        head = stream.read(4096)
    if head.startswith(b"\x89MCAP"):
        return "mcap"
    if head.startswith(b"#ROSBAG"):
        return "ros1"
    lines = head.decode("utf-8", errors="replace").lstrip("\ufeff").splitlines()
    first = next((ln.strip() for ln in lines if ln.strip() and not ln.lstrip().startswith("#")), "")
    if first.startswith("pose_id,"):
        return "segloc"
    if len(first.split()) == TUM_VALUES and _all_numbers(first.split()):
        return "tum"
    suffix = path.suffix or "no extension"
    raise InputError(f"cannot tell the trajectory's format ({suffix}); {choose}", path=path)


def _all_numbers(fields: list[str]) -> bool:
    try:
        [float(f) for f in fields]
    except ValueError:
        return False
    return True


def read_trajectory(
    path: Path,
    fmt: str | None = None,
    topic: str | None = None,
    frames: tuple[str, str] | None = None,
) -> pd.DataFrame:
    """Read a pose trajectory as estimates (see the module docstring).

    ``fmt`` one of ``EST_FORMATS`` (None: ``guess_format``); ``topic`` the topic of a bag
    or MCAP file (None: its one topic of a supported type, if it has exactly one);
    ``frames`` (parent, child), e.g. ("map", "base_link"), for a transform topic.
    ``InputError``, one line saying what to do, on a file that cannot be read, a topic
    missing, empty or of an unsupported type, frames missing or not on one chain, a TUM
    line that is not 8 numbers, or no usable pose; naming the bag folder for a file inside
    a ROS 2 bag (its ``metadata.yaml``, a ``.db3``).
    """
    path = Path(path)
    refuse_inside_ros2_bag(path)
    fmt = guess_format(path) if fmt is None else fmt
    if fmt not in EST_FORMATS:
        raise InputError(
            f"unknown trajectory format {fmt!r}; {FORMAT_OPTION} takes one of "
            f"{', '.join(EST_FORMATS)}",
            path=path,
        )
    if fmt in _KINDS:
        for given, option in ((topic, TOPIC_OPTION), (frames, FRAMES_OPTION)):
            if given is not None:
                raise InputError(
                    f"{option} applies to ROS bags and MCAP files, not a {_KINDS[fmt]}; "
                    "leave it out",
                    path=path,
                )
        return _read_segloc(path) if fmt == "segloc" else _read_tum(path)
    from segloc_cli.io.bag_trajectory import read_bag_trajectory

    return read_bag_trajectory(path, fmt, topic, frames)


def _read_segloc(path: Path) -> pd.DataFrame:
    from segloc_cli.io.tables import read_estimates

    frame = read_estimates(path)
    for column in COVARIANCE_COLUMNS:
        frame[column] = np.nan
    frame.attrs.update(source=f"segloc estimates CSV, {len(frame)} rows", dropped={}, warnings=[])
    return frame


def _read_tum(path: Path) -> pd.DataFrame:
    """A TUM trajectory's poses; ``InputError`` naming the line that is not 8 numbers."""
    with reading(path, "a TUM trajectory"):
        text = path.read_text(encoding="utf-8-sig")
    rows = []
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        if len(fields) != TUM_VALUES:
            raise InputError(
                f"line {number} holds {len(fields)} values; a TUM line holds 8 numbers "
                "'t x y z qx qy qz qw'",
                path=path,
            )
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            bad = next(f for f in fields if not _all_numbers([f]))
            raise InputError(
                f"line {number}: {bad[:40]!r} is not a number; a TUM line holds 8 numbers "
                "'t x y z qx qy qz qw'",
                path=path,
            ) from None
    values = np.array(rows, dtype=float).reshape(-1, TUM_VALUES)
    planar = planar_of_quaternions(values[:, 1:])
    n = len(values)
    return trajectory_frame(
        path,
        PosesRead(values[:, 0], [""] * n, planar, np.full((n, 6), np.nan)),
        "TUM trajectory",
    )


class Planar(NamedTuple):
    """Poses seen from above: ``usable`` (N,) whether each is finite with a rotation,
    ``x_m``, ``y_m``, ``yaw_rad``, ``tilt_deg`` (N,) (from level, 0 to 180)."""

    usable: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    yaw_rad: np.ndarray
    tilt_deg: np.ndarray


def planar_of_quaternions(values: np.ndarray) -> Planar:
    """``Planar`` of poses (N, 7) ``x y z qx qy qz qw`` (metres; any non-zero quaternion)."""
    values = np.asarray(values, dtype=float).reshape(-1, 7)
    q = values[:, 3:]
    usable = np.all(np.isfinite(values), axis=1) & np.any(q != 0.0, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        # Scaled to a largest component of 1 so that neither 1e-300 nor 1e300 overflows.
        q = q / np.max(np.abs(q), axis=1, keepdims=True)
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
    yaw = quaternion_to_heading(q[:, 0], q[:, 1], q[:, 2], q[:, 3])
    up = 1.0 - 2.0 * (q[:, 0] ** 2 + q[:, 1] ** 2)  # the z axis's z: cos(tilt)
    tilt = np.degrees(np.arccos(np.clip(np.nan_to_num(up), -1.0, 1.0)))
    return Planar(usable, values[:, 0], values[:, 1], yaw, tilt)


def planar_of_matrices(matrices: np.ndarray) -> Planar:
    """``Planar`` of poses as homogeneous matrices (N, 4, 4) (metres)."""
    m = np.asarray(matrices, dtype=float).reshape(-1, 4, 4)
    usable = np.all(np.isfinite(m.reshape(len(m), -1)), axis=1)
    yaw = np.arctan2(m[:, 1, 0], m[:, 0, 0])
    tilt = np.degrees(np.arccos(np.clip(np.nan_to_num(m[:, 2, 2]), -1.0, 1.0)))
    return Planar(usable, m[:, 0, 3], m[:, 1, 3], yaw, tilt)


class PosesRead(NamedTuple):
    """Poses as read, before any is left out: ``time_s`` (N,) seconds, ``frame_ids`` (N,)
    the frame each is in ("" when the format names none), ``planar`` their ``Planar``,
    ``covariance`` (N, 6) the values of ``COVARIANCE_COLUMNS`` (NaN where none)."""

    time_s: np.ndarray
    frame_ids: list[str]
    planar: Planar
    covariance: np.ndarray


def trajectory_frame(
    path: Path,
    read: PosesRead,
    described: str,
    dropped: Counter[str] | None = None,
    warnings: list[str] | None = None,
    what: str = "the file",
) -> pd.DataFrame:
    """The estimates frame of the poses ``read`` (module docstring): the unusable ones left
    out and counted in ``dropped``, the rest in time order. ``described`` begins the
    ``source`` line (the count and frame follow). ``InputError`` when no pose is left."""
    dropped = Counter() if dropped is None else dropped
    warnings = [] if warnings is None else warnings
    p = read.planar
    keep = p.usable & np.isfinite(read.time_s)
    dropped["not finite (or an all-zero quaternion)"] += int(np.count_nonzero(~keep))
    far = keep & ((np.abs(p.x_m) > MAX_COORDINATE_M) | (np.abs(p.y_m) > MAX_COORDINATE_M))
    dropped[f"positions beyond ±{MAX_COORDINATE_M:g} m"] += int(np.count_nonzero(far))
    upright = keep & ~far & (p.tilt_deg > MAX_PLANAR_TILT_DEG)
    dropped[f"tilted more than {MAX_PLANAR_TILT_DEG:g}° from level"] += int(
        np.count_nonzero(upright)
    )
    keep &= ~far & ~upright
    frame_ids = np.array(read.frame_ids, dtype=object)
    counts = Counter(frame_ids[keep].tolist())
    main = counts.most_common(1)[0][0] if counts else ""
    for other, count in counts.items():
        if other != main:
            dropped[f"in frame {other or '(none)'}, not {main} (the frame most poses are in)"] += (
                count
            )
    keep &= frame_ids == main
    order = np.flatnonzero(keep)[np.argsort(read.time_s[keep], kind="stable")]
    repeated = np.zeros(len(order), dtype=bool)
    repeated[1:] = read.time_s[order[1:]] == read.time_s[order[:-1]]
    dropped["repeating a time (the first kept)"] += int(np.count_nonzero(repeated))
    order = order[~repeated]
    shown = {reason: count for reason, count in dropped.items() if count}
    if len(order) == 0:
        left_out = "; ".join(f"{count} {reason}" for reason, count in shown.items())
        raise InputError(f"{what} holds no usable pose ({left_out or 'none at all'})", path=path)
    tilted = p.tilt_deg[order] > MAX_TILT_DEG
    if tilted.any():
        n_tilted = int(np.count_nonzero(tilted))
        warnings.append(
            f"{counted(n_tilted, 'pose')} tilted more than {MAX_TILT_DEG:g}° from level (at most "
            f"{p.tilt_deg[order].max():.1f}°); {plural(n_tilted, 'its', 'their')} heading is "
            f"{plural(n_tilted, 'its', 'their')} x axis seen from above"
        )
    frame = _estimates(read.time_s[order], p, order, read.covariance[order])
    in_frame = f" in frame {main}" if main else ""
    frame.attrs.update(
        source=f"{described}, {counted(len(order), 'pose')}{in_frame}",
        dropped=shown,
        warnings=warnings,
    )
    return frame


def _estimates(time_s: np.ndarray, p: Planar, order: np.ndarray, covariance: np.ndarray):
    n = len(order)
    theta_deg = (np.degrees(p.yaw_rad[order]) + 180.0) % 360.0 - 180.0
    theta_deg = np.where(theta_deg >= 180.0, theta_deg - 360.0, theta_deg)
    given = {
        "pose_id": np.arange(1, n + 1, dtype=np.int64),
        "time_s": time_s,
        "x_m": p.x_m[order],
        "y_m": p.y_m[order],
        "theta_deg": theta_deg,
    }
    columns: dict[str, object] = {}
    for column in ESTIMATE_COLUMNS:
        if column in given:
            columns[column] = given[column]
        elif column in ESTIMATE_INT_COLUMNS:
            columns[column] = np.zeros(n, dtype=np.int64)
        elif column in ESTIMATE_TEXT_COLUMNS:
            columns[column] = np.full(n, STATUS_OK, dtype=object)
        else:
            columns[column] = np.full(n, math.nan)
    for i, column in enumerate(COVARIANCE_COLUMNS):
        columns[column] = covariance[:, i]
    return pd.DataFrame(columns)
