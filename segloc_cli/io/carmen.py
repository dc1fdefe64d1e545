"""CARMEN text logs (``.clf``, ``.log``; plain or gzip-compressed) → scans and poses.

One record per line, fields separated by whitespace. Read here:

- ``FLASER n r1 … rn x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp``:
  the front laser. The record holds no beam geometry; CARMEN's own reader
  (``carmen_laser_guess_angle_increment``) takes it from ``n`` as a SICK LMS
  delivers it, and so does this one: beam i at ``−π/2 + i·step`` (robot frame,
  x forward, counter-clockwise), with a 1° step for 181 or 180 readings, 0.5°
  for 361 or 360, 0.25° for 401 or 400 (one fewer: the logger dropped the last
  beam), and 180° across ``n`` beams, ``π/(n−1)``, for any other count.
  Maps built from the public SLAM-corrected logs are sharpest with this rule.
- ``RLASER …``, same layout: the rear laser, facing backward. Its beams start at
  +90° and step as the front laser's. The angles are left continuous (not wrapped
  into [−π, π)) so that they stay evenly spaced, as ``foxglove.LaserScan`` and
  breakpoint detection need. The angles are relative to the robot's heading,
  which the odometry fields carry; the pose fields are returned as written, and
  CARMEN's robot module writes a rear laser's heading there as the robot's + π.
- ``ROBOTLASER1 laser_type start_angle field_of_view angular_resolution
  maximum_range accuracy remission_mode n r1 … rn k rem1 … remk laser_pose(3)
  robot_pose(3) tv rv forward_safety_dist side_safety_dist turn_axis ipc_timestamp
  host logger_timestamp``: the front laser in CARMEN's later layout. As in
  CARMEN's ``carmen_laser_laser_config_t``, ``start_angle`` is the first beam and
  the field of view runs from the first beam to the last, so
  ``angle_i = start_angle + i·fov/(n−1)``. Remissions, when there is one per
  beam, become the scan's intensities.
- ``ODOM x y theta tv rv accel ipc_timestamp host logger_timestamp``: parsed and
  validated (a bad one is skipped and counted in the warnings) but not returned.
  Localization uses the odometry fields of the laser records themselves, which
  are exactly at the scan times.
- ``PARAM name value …``: the laser's maximum range and mounting offset (below).

Comments (``#``), ``SYNC``, ``TRUEPOS`` and every other record type are ignored.

Units and frames: ranges in metres; beam angles in radians in the robot frame
(x forward); poses ``x_m, y_m, theta_rad`` in the log's world frame (odometry
frame for ``odom_poses``; for ``laser_poses`` whatever the pose fields hold, in
a SLAM-corrected log the corrected trajectory), headings wrapped into [−π, π).
Times are the records' ``ipc_timestamp`` in seconds, as written (relative or
absolute); the logger timestamp is only checked to be a number.

Maximum range: a reading at or above it means no return. It is, in order of
precedence: the ``range_max_m`` argument; a ROBOTLASER1 record's own
``maximum_range`` (for that record, when positive); the first ``PARAM`` whose
name contains "laser", "max" and the laser's side ("front" or "rear"), e.g.
``robot_front_laser_max``; else it is inferred from the readings of the chosen
laser records: the largest reading is the no-return value if it makes up at
least 0.5 % of all readings (a sentinel such as 81.83 m or 50 m appears
thousands of times), otherwise there is no maximum (inf).

Laser offset: a non-zero ``PARAM robot_frontlaser_offset`` (``robot_rearlaser_offset``
for the rear laser) says the scanner sits that many metres from the robot
centre along its own heading (ahead for the front laser, behind for the rear
one, as CARMEN's robot module places it). The scans are in the scanner's frame,
so every returned pose is the scanner's:

- the pose fields (``x y theta``, ROBOTLASER1's laser pose) are kept as written:
  CARMEN's robot module writes them at the scanner, and in the SLAM-corrected
  logs they are the poses the scans were registered at (fr079, whose offset is
  −0.04 m, aligns its scans best with them unshifted);
- the odometry fields (ROBOTLASER1's robot pose) are the robot centre and are
  moved by the offset along their heading, except in a record whose odometry
  equals its pose fields (a corrected log, where both hold the same pose).

Bad records (wrong field count, bad reading count, non-numeric or non-finite
values, negative or non-finite time) are skipped; each kind is summarised in
``CarmenLog.warnings`` with line numbers. A corrupt or truncated gzip stream
keeps every complete line before the damage and adds a warning.
"""

from __future__ import annotations

import math
import zlib
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.geometry import wrap_angle
from segloc_cli.io.files import reading
from segloc_cli.scan import Scan, evenly_spaced_angles

LASER_RECORDS = {"front": ("FLASER", "ROBOTLASER1"), "rear": ("RLASER",)}
OFFSET_PARAMS = {"front": "robot_frontlaser_offset", "rear": "robot_rearlaser_offset"}
# First beam of FLASER/RLASER records.
FIXED_START_RAD = {"FLASER": -0.5 * math.pi, "RLASER": 0.5 * math.pi}
# Beam step of a SICK LMS by the number of readings a FLASER/RLASER record holds.
SICK_STEP_DEG = {181: 1.0, 180: 1.0, 361: 0.5, 360: 0.5, 401: 0.25, 400: 0.25}
# Fields of a FLASER/RLASER line besides its n readings: keyword, n, 6 pose values,
# ipc_timestamp, host, logger_timestamp.
FLASER_EXTRA_FIELDS = 11
# Fields of a ROBOTLASER1 line besides its n readings and k remissions: keyword,
# 7 config values, n, k, 12 pose and motion values, ipc_timestamp, host, logger_timestamp.
ROBOTLASER_EXTRA_FIELDS = 24
ROBOTLASER_N_FIELD = 8
ODOM_FIELDS = 10
SENTINEL_MIN_FRACTION = 0.005
LINES_SHOWN = 5
GZIP_MAGIC = b"\x1f\x8b"
GZIP_CHUNK_BYTES = 1 << 16
BINARY_SNIFF_BYTES = 8192
EXPECTED = "a CARMEN log (text, or gzip-compressed text)"

REASONS = {
    "count": "a wrong field count",
    "n": "a missing or invalid reading count",
    "value": "non-numeric or non-finite values",
    "time": "a negative or non-finite timestamp",
}


@dataclass(frozen=True)
class CarmenLog:
    """What ``read_carmen`` found.

    ``scans`` (S) in file order, each in the scanner frame with ``time_s`` the
    record's ipc timestamp; ``odom_times_s`` (S,) the scans' times;
    ``odom_poses`` (S, 3) the odometry pose of each laser record, moved to
    the scanner by the laser offset, and ``laser_poses`` (S, 3) its pose fields,
    both ``x_m, y_m, theta_rad``; ``sensor`` str → str settings for the MCAP
    metadata record (``range_max_m``, ``readings``, ``fov_deg``, ``source``,
    ``laser``, …); ``warnings`` one line per kind of skipped record or damage.
    """

    scans: list[Scan]
    odom_times_s: np.ndarray
    odom_poses: np.ndarray
    laser_poses: np.ndarray
    sensor: dict[str, str]
    warnings: list[str]


class _Skip(Exception):
    """A record that cannot be used; ``reason`` is a key of ``REASONS``."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class _LaserRecord:
    kind: str
    time_s: float
    ranges_m: np.ndarray
    start_rad: float
    fov_rad: float
    range_max_m: float | None  # the record's own maximum (ROBOTLASER1), if usable
    intensities: np.ndarray
    laser_pose: np.ndarray
    odom_pose: np.ndarray


# --- reading the bytes ------------------------------------------------------------


def _gunzip(data: bytes) -> tuple[bytes, str | None]:
    """Decompress gzip ``data`` (one or more members) → (bytes, damage or None).

    On damage, the returned bytes are everything decompressed before it.
    """
    out: list[bytes] = []
    damage: str | None = None
    rest = data
    while rest:
        # wbits 31: gzip header and trailer, checked (CRC and length) at the end.
        inflater = zlib.decompressobj(31)
        position = 0
        try:
            while position < len(rest) and not inflater.eof:
                chunk = rest[position : position + GZIP_CHUNK_BYTES]
                saved = inflater.copy()
                try:
                    out.append(inflater.decompress(chunk))
                except zlib.error:
                    # zlib drops the output of a failing call: replay the chunk a
                    # byte at a time to keep everything before the bad byte.
                    inflater = saved
                    for i in range(len(chunk)):
                        out.append(inflater.decompress(chunk[i : i + 1]))
                    raise
                position += len(chunk)
        except zlib.error as exc:
            damage = f"the compressed data is corrupt ({exc})"
            break
        if not inflater.eof:
            damage = "the file ends in the middle of the compressed data (truncated)"
            break
        out.append(inflater.flush())
        rest = inflater.unused_data + rest[position:]
        rest = rest if rest.strip(b"\x00") else b""  # zero padding after the last member
        if rest and not rest.startswith(GZIP_MAGIC):
            damage = "the compressed data is followed by bytes that are not gzip"
            break
    return b"".join(out), damage


def _read_lines(path: Path, warnings: list[str]) -> list[bytes]:
    """The file's lines (bytes, without line ends), decompressing gzip by its magic bytes."""
    with reading(path, EXPECTED):
        data = path.read_bytes()
    damage = None
    if data.startswith(GZIP_MAGIC):
        data, damage = _gunzip(data)
    if b"\x00" in data[:BINARY_SNIFF_BYTES]:
        raise InputError(f"not a text file; expected {EXPECTED}", path=path)
    lines = data.splitlines()
    if damage is not None:
        # The last piece has no line end when the damage cut it: it is incomplete.
        if data and not data.endswith((b"\n", b"\r")):
            lines.pop()
        warnings.append(
            f"{path}: {damage}; stopped at line {len(lines) + 1}, "
            f"keeping the {len(lines)} complete line{'' if len(lines) == 1 else 's'} before it"
        )
    return lines


# --- parsing records ----------------------------------------------------------------


def _numbers(tokens: list[bytes]) -> np.ndarray:
    try:
        values = np.array(tokens, dtype=float)
    except ValueError:
        raise _Skip("value") from None
    if not np.all(np.isfinite(values)):
        raise _Skip("value")
    return values


def _count(token: bytes, minimum: int) -> int:
    try:
        value = int(token)
    except ValueError:
        raise _Skip("n") from None
    if value < minimum:
        raise _Skip("n")
    return value


def _time(fields: list[bytes]) -> float:
    """The ipc timestamp (third field from the end); checks the logger timestamp too."""
    _numbers(fields[-1:])
    try:
        time_s = float(fields[-3])
    except ValueError:
        raise _Skip("value") from None
    if not (math.isfinite(time_s) and time_s >= 0.0):
        raise _Skip("time")
    return time_s


def sick_fov_rad(n: int) -> float:
    """First-to-last-beam field of view (radians) of a FLASER/RLASER record of ``n`` readings."""
    step_deg = SICK_STEP_DEG.get(n)
    return math.pi if step_deg is None else math.radians(step_deg) * (n - 1)


def _parse_flaser(kind: str, fields: list[bytes]) -> _LaserRecord:
    if len(fields) < 2:
        raise _Skip("n")
    n = _count(fields[1], 1)
    if len(fields) != n + FLASER_EXTRA_FIELDS:
        raise _Skip("count")
    values = _numbers(fields[2 : 2 + n + 6])
    time_s = _time(fields)
    return _LaserRecord(
        kind=kind,
        time_s=time_s,
        ranges_m=values[:n],
        start_rad=FIXED_START_RAD[kind],
        fov_rad=sick_fov_rad(n),
        range_max_m=None,
        intensities=np.zeros(0),
        laser_pose=values[n : n + 3],
        odom_pose=values[n + 3 : n + 6],
    )


def _parse_robotlaser(kind: str, fields: list[bytes]) -> _LaserRecord:
    if len(fields) <= ROBOTLASER_N_FIELD:
        raise _Skip("count")
    n = _count(fields[ROBOTLASER_N_FIELD], 1)
    k_field = ROBOTLASER_N_FIELD + 1 + n
    if len(fields) <= k_field:
        raise _Skip("count")
    k = _count(fields[k_field], 0)
    if len(fields) != n + k + ROBOTLASER_EXTRA_FIELDS:
        raise _Skip("count")
    config = _numbers(fields[1:ROBOTLASER_N_FIELD])
    ranges = _numbers(fields[ROBOTLASER_N_FIELD + 1 : k_field])
    remissions = _numbers(fields[k_field + 1 : k_field + 1 + k])
    poses = _numbers(fields[k_field + 1 + k : k_field + 1 + k + 11])
    time_s = _time(fields)
    _, start, fov, _, maximum_range = config[:5]
    return _LaserRecord(
        kind=kind,
        time_s=time_s,
        ranges_m=ranges,
        start_rad=float(start),
        fov_rad=float(fov),
        range_max_m=float(maximum_range) if maximum_range > 0 else None,
        intensities=remissions if k == n else np.zeros(0),
        laser_pose=poses[0:3],
        odom_pose=poses[3:6],
    )


def _check_odom(fields: list[bytes]) -> None:
    if len(fields) != ODOM_FIELDS:
        raise _Skip("count")
    _numbers(fields[1:7])
    _time(fields)


PARSERS = {"FLASER": _parse_flaser, "RLASER": _parse_flaser, "ROBOTLASER1": _parse_robotlaser}


# --- putting it together ------------------------------------------------------------


def _line_list(lines: list[int]) -> str:
    shown = ", ".join(str(n) for n in lines[:LINES_SHOWN])
    more = f" and {len(lines) - LINES_SHOWN} more" if len(lines) > LINES_SHOWN else ""
    return f"line{'s' if len(lines) > 1 else ''} {shown}{more}"


def _skip_warnings(path: Path, skipped: dict[tuple[str, str], list[int]]) -> list[str]:
    return [
        f"{path}: skipped {len(lines)} {kind} record{'s' if len(lines) > 1 else ''} "
        f"with {REASONS[reason]} ({_line_list(lines)})"
        for (kind, reason), lines in skipped.items()
    ]


def _param_value(
    path: Path, params: dict[str, tuple[bytes, int]], name: str, warnings: list[str]
) -> float | None:
    """The first value of PARAM ``name`` as a float, None if absent or unusable."""
    if name not in params:
        return None
    text, line = params[name]
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        shown = text.decode("latin-1")
        warnings.append(f"{path}: PARAM {name} is {shown!r}, not a number (line {line}); ignored")
        return None
    return value


def _range_max_param(
    path: Path, params: dict[str, tuple[bytes, int]], laser: str, warnings: list[str]
) -> tuple[float, str] | None:
    for name in params:
        lowered = name.lower()
        if "laser" in lowered and "max" in lowered and laser in lowered:
            value = _param_value(path, params, name, warnings)
            if value is not None and value > 0:
                return value, f"PARAM {name}"
            if value is not None:
                warnings.append(f"{path}: PARAM {name} is {value:g}, not positive; ignored")
    return None


def _infer_range_max(ranges: list[np.ndarray]) -> tuple[float, str]:
    readings = np.concatenate(ranges) if ranges else np.zeros(0)
    if readings.size == 0:
        return math.inf, "none: no readings to infer it from"
    largest = float(np.max(readings))
    fraction = float(np.count_nonzero(readings == largest)) / readings.size
    share = f"{_fmt(largest)} m is {100.0 * fraction:.3g} % of the readings"
    if fraction >= SENTINEL_MIN_FRACTION:
        return largest, f"inferred: the largest reading, {share}"
    return math.inf, f"none: the largest reading, {share}, is too rare to be a no-return value"


def _fmt(value: float) -> str:
    return "inf" if math.isinf(value) else f"{value:.10g}"


def _record_kinds(counts: Counter) -> str:
    if not counts:
        return "the file has no records"
    listed = ", ".join(f"{kind} ×{n}" for kind, n in sorted(counts.items())[:12])
    more = ", …" if len(counts) > 12 else ""
    return f"record types found: {listed}{more}"


def _no_records_message(path: Path, laser: str, counts: Counter, warnings: list[str]) -> str:
    wanted = LASER_RECORDS[laser]
    nor = f" (nor {', '.join(wanted[1:])})" if len(wanted) > 1 else ""
    present = sum(counts[kind] for kind in wanted)
    unusable = f" that can be read (all {present} were skipped)" if present else ""
    hints = [
        f"the file has {' and '.join(kinds)} records (the {other} laser)"
        for other in LASER_RECORDS
        if other != laser and (kinds := [kind for kind in LASER_RECORDS[other] if counts[kind]])
    ]
    notes = [w.removeprefix(f"{path}: ") for w in warnings]
    return "; ".join(
        [f"no {wanted[0]} records{nor}{unusable}", _record_kinds(counts), *hints, *notes]
    )


def _wrapped(theta_rad: np.ndarray) -> np.ndarray:
    """Headings wrapped into [-pi, pi); those already inside keep their exact value."""
    inside = (theta_rad >= -np.pi) & (theta_rad < np.pi)
    return np.where(inside, theta_rad, wrap_angle(theta_rad))


def _shift(poses: np.ndarray, offset_m: float) -> np.ndarray:
    """Move poses (S, 3) ``offset_m`` along their headings."""
    moved = poses.copy()
    moved[:, 0] += offset_m * np.cos(poses[:, 2])
    moved[:, 1] += offset_m * np.sin(poses[:, 2])
    return moved


def read_carmen(
    path: str | Path, laser: str = "front", range_max_m: float | None = None
) -> CarmenLog:
    """Read the scans of one laser and their poses from a CARMEN log.

    ``path``: a CARMEN text log, plain or gzip-compressed (found by its magic
    bytes, whatever its name). ``laser``: "front" (FLASER and ROBOTLASER1
    records) or "rear" (RLASER), else ``ValueError``. ``range_max_m``: the
    sensor's maximum range in metres, overriding the log (see the module
    docstring for how it is found otherwise).

    Raises ``InputError`` naming the file when it is missing, a directory, not
    text, or holds no usable record of the chosen laser.
    """
    if laser not in LASER_RECORDS:
        raise ValueError(f"laser must be one of {sorted(LASER_RECORDS)}, got {laser!r}")
    if range_max_m is not None and not range_max_m > 0:
        raise ValueError(f"range_max_m must be positive, got {range_max_m}")
    path = Path(path)
    warnings: list[str] = []
    lines = _read_lines(path, warnings)
    wanted = LASER_RECORDS[laser]

    records: list[_LaserRecord] = []
    counts: Counter = Counter()
    params: dict[str, tuple[bytes, int]] = {}
    skipped: dict[tuple[str, str], list[int]] = {}
    for number, line in enumerate(lines, start=1):
        fields = line.split()
        if not fields or fields[0].startswith(b"#"):
            continue
        kind = fields[0].decode("latin-1")
        counts[kind[:24]] += 1
        try:
            if kind in wanted:
                records.append(PARSERS[kind](kind, fields))
            elif kind == "ODOM":
                _check_odom(fields)
            elif kind == "PARAM" and len(fields) >= 3:
                params.setdefault(fields[1].decode("latin-1"), (fields[2], number))
        except _Skip as skip:
            skipped.setdefault((kind, skip.reason), []).append(number)
    # The damage note, if any, reads best after the per-record summaries.
    warnings[:0] = _skip_warnings(path, skipped)

    if not records:
        raise InputError(_no_records_message(path, laser, counts, warnings), path=path)

    if range_max_m is not None:
        fallback, rule = float(range_max_m), "given"
    else:
        from_param = _range_max_param(path, params, laser, warnings)
        if from_param is None:
            needing = [r.ranges_m for r in records if r.range_max_m is None]
            fallback, rule = _infer_range_max(needing)
        else:
            fallback, rule = from_param
    per_record = [
        r.range_max_m if range_max_m is None and r.range_max_m is not None else fallback
        for r in records
    ]
    if range_max_m is None and any(r.range_max_m is not None for r in records):
        rule = "ROBOTLASER1 maximum_range" + ("" if len(set(per_record)) == 1 else f"; {rule}")

    scans = [
        Scan(
            time_s=r.time_s,
            angles_rad=evenly_spaced_angles(len(r.ranges_m), r.start_rad, r.start_rad + r.fov_rad),
            ranges_m=r.ranges_m,
            range_max_m=limit,
            intensities=r.intensities,
        )
        for r, limit in zip(records, per_record, strict=True)
    ]

    offset_m = _param_value(path, params, OFFSET_PARAMS[laser], warnings) or 0.0
    # The rear scanner faces backward: its offset runs along the robot's heading + π.
    along_m = offset_m if laser == "front" else -offset_m
    laser_poses = np.array([r.laser_pose for r in records], dtype=float)
    odom_poses = np.array([r.odom_pose for r in records], dtype=float)
    at_centre = np.any(odom_poses != laser_poses, axis=1)
    if along_m != 0.0:
        odom_poses[at_centre] = _shift(odom_poses[at_centre], along_m)
    laser_poses[:, 2] = _wrapped(laser_poses[:, 2])
    odom_poses[:, 2] = _wrapped(odom_poses[:, 2])

    beams = sorted({len(s) for s in scans})
    fovs = sorted({_fmt(math.degrees(r.fov_rad)) for r in records}, key=float)
    sensor = {
        "range_max_m": _fmt(max(per_record)),
        "range_max_from": rule,
        "readings": ",".join(str(n) for n in beams),
        "fov_deg": ",".join(fovs),
        "laser": laser,
        "laser_offset_m": _fmt(offset_m),
        "records": ",".join(k for k in wanted if any(r.kind == k for r in records)),
        "source": path.name,
        "format": "CARMEN log",
    }
    return CarmenLog(
        scans=scans,
        odom_times_s=np.array([s.time_s for s in scans], dtype=float),
        odom_poses=odom_poses,
        laser_poses=laser_poses,
        sensor=sensor,
        warnings=warnings,
    )
