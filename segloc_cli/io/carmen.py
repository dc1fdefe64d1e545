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
Times are the records' ``ipc_timestamp`` in seconds (relative or absolute);
the logger timestamp is only checked to be a number. Laser records that share
their time with another record or go back in time are given distinct times in
file order by the rule of ``segloc_cli.io.times`` (one warning says how many);
``Log.original_times_s`` keeps the times as written.

Maximum range: a reading at or above it means no return. It is the scanner's own, found
as ``segloc_cli.io.range_limits`` says: the ``range_max_m`` argument when given; else, for a
ROBOTLASER1 record with a positive ``maximum_range`` (the laser's configuration, carried in
each record), that value; for the other records, the no-return value their readings repeat
(81.83 m, 50 m; a lone corrupt 99999 m reading is not one). A ``PARAM`` whose name
contains "laser", "max" and the laser's side ("front" or "rear"), e.g.
``robot_front_laser_max``, is a setting of CARMEN's robot module (how far the navigation
looks), not the scanner's limit: it is used only when the readings repeat no no-return
value. A stated limit (that PARAM, a ``maximum_range``) that returns lie beyond is not used,
and a warning says how many readings it would have dropped and which limit is used
instead. When no limit is found, there is none (inf) and a warning says so.

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

Both front-laser layouts of one scan: a log that writes each scan as a FLASER and a
ROBOTLASER1 record (same time, as many readings) is read from its ROBOTLASER1 records,
which carry the scanner's geometry and maximum range; one warning says how many FLASER
duplicates were left out. FLASER records without a ROBOTLASER1 twin are kept.

Bad records (wrong field count, a reading count below 1 or above
``segloc_cli.scan.MAX_READINGS``, non-numeric or non-finite values, a time that
is negative, non-finite or above ``segloc_cli.io.times.MAX_TIME_S``, a
ROBOTLASER1 fan that ``segloc_cli.scan.fan_defect`` refuses) are skipped; each kind
is summarised in ``Log.warnings`` with line numbers. So are lines holding
NUL bytes; a file where more than half of the lines hold one, or where no laser
record can be read and any line holds one, is refused as not text.

Damaged gzip: a corrupt or truncated stream keeps every complete line before
the damage, and the warning says from which line on records are lost. A member
whose data decompresses completely but does not match the checksum (or length)
at its end is kept whole, and the warning names its lines as possibly damaged.
"""

from __future__ import annotations

import math
import re
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.geometry import wrap_angle
from segloc_cli.io.files import reading
from segloc_cli.io.log import MAX_LASER_OFFSET_M, Log
from segloc_cli.io.range_limits import (
    NoReturn,
    dropped_returns,
    fmt_m,
    no_return_value,
    overruled,
    overruled_text,
    stated_limit,
)
from segloc_cli.io.times import MAX_TIME_S, importer_times
from segloc_cli.progress import Progress, ProgressFactory, silent
from segloc_cli.scan import MAX_READINGS, Scan, evenly_spaced_angles, fan_defect
from segloc_cli.wording import counted, plural

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
BINARY_LINE_FRACTION = 0.5
"""A file is refused as not text when more than this share of its non-empty lines hold NULs."""
LINES_SHOWN = 5
SHOWN_CHARS = 40  # of a record type or PARAM name or value quoted in a message
GZIP_MAGIC = b"\x1f\x8b"
GZIP_CHUNK_BYTES = 1 << 16
EXPECTED = "a CARMEN log (text, or gzip-compressed text)"
# zlib's messages for a gzip trailer that does not match the data, what they mean,
# and how many trailer bytes follow the byte at which zlib notices.
CHECK_FAILURES = {
    "incorrect data check": ("the checksum", 4),
    "incorrect length check": ("the length", 0),
}

REASONS = {
    "count": "a wrong field count",
    "n": f"a missing, invalid or too large reading count (at most {MAX_READINGS:,})",
    "value": "non-numeric or non-finite values",
    "time": f"a negative, non-finite or too large timestamp (at most {MAX_TIME_S:.0f} s)",
    "geometry": (
        "a beam fan that decreases, is degenerate, is wider than a full turn, lies beyond ±4π "
        "rad, or whose angular resolution disagrees with its field of view"
    ),
}


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


@dataclass(frozen=True)
class _Damage:
    """Damage met while decompressing.

    ``text`` says what; the decompressed bytes from ``start`` up to ``end`` may
    be wrong (a trailer that does not match), or, with ``end`` None, nothing
    from ``start`` on could be recovered.
    """

    text: str
    start: int
    end: int | None


def _inflate(member: bytes) -> tuple[list[bytes], int, bool, str | None]:
    """Decompress the gzip member at the start of ``member``.

    Returns the pieces of output, how many input bytes were used, whether the
    member ended, and zlib's message if it failed. On failure the output is
    everything before the byte that failed and the count includes that byte.
    """
    # wbits 31: gzip header and trailer, checked (CRC and length) at the end.
    inflater = zlib.decompressobj(31)
    out: list[bytes] = []
    position = 0
    while position < len(member) and not inflater.eof:
        chunk = member[position : position + GZIP_CHUNK_BYTES]
        saved = inflater.copy()
        try:
            out.append(inflater.decompress(chunk))
        except zlib.error:
            # zlib drops the output of a failing call: replay the chunk a byte
            # at a time to keep everything before the bad byte.
            inflater = saved
            for i in range(len(chunk)):
                try:
                    out.append(inflater.decompress(chunk[i : i + 1]))
                except zlib.error as exc:
                    return out, position + i + 1, False, str(exc)
            # Not reached in practice (the bytes fail as the chunk did); if it were, bytes
            # fed after the member's end are in unused_data, as below.
        position += len(chunk)
    if not inflater.eof:
        return out, position, False, None
    out.append(inflater.flush())
    return out, position - len(inflater.unused_data), True, None


def _gunzip(data: bytes) -> tuple[bytes, list[_Damage]]:
    """Decompress gzip ``data`` (one or more members) → (bytes, damage found).

    A member whose trailer does not match its data is kept and decompression
    goes on with the next member; any other damage ends it, keeping everything
    decompressed before.
    """
    out: list[bytes] = []
    size = 0
    damages: list[_Damage] = []
    rest = data
    while rest:
        start = size
        pieces, used, ended, failure = _inflate(rest)
        out += pieces
        size += sum(len(piece) for piece in pieces)
        check = next((CHECK_FAILURES[k] for k in CHECK_FAILURES if k in (failure or "")), None)
        if check is not None:
            what, trailer_left = check
            text = f"{what} at the end of the compressed data does not match"
            damages.append(_Damage(text, start, size))
            used += trailer_left
        elif failure is not None:
            damages.append(_Damage(f"the compressed data is corrupt ({failure})", size, None))
            break
        elif not ended:
            text = "the file ends in the middle of the compressed data (truncated)"
            damages.append(_Damage(text, size, None))
            break
        rest = rest[used:]
        rest = rest if rest.strip(b"\x00") else b""  # zero padding after the last member
        if rest and not rest.startswith(GZIP_MAGIC):
            text = "the compressed data is followed by bytes that are not gzip"
            damages.append(_Damage(text, size, None))
            break
    return b"".join(out), damages


def _line_of(data: bytes, offset: int) -> int:
    """The 1-based number of the line that holds byte ``offset`` of ``data``."""
    ends = len(re.findall(rb"\r\n|\r|\n", data[:offset]))
    # A "\r\n" that the offset splits is one line end, of the line before.
    split_pair = 0 < offset < len(data) and data[offset - 1 : offset + 1] == b"\r\n"
    return ends + 1 - split_pair


def _read_lines(path: Path, warnings: list[str]) -> list[bytes]:
    """The file's lines (bytes, without line ends), decompressing gzip by its magic bytes."""
    with reading(path, EXPECTED):
        data = path.read_bytes()
    damages: list[_Damage] = []
    if data.startswith(GZIP_MAGIC):
        data, damages = _gunzip(data)
    lines = data.splitlines()
    for damage in damages:
        if damage.end is None:
            # The last piece has no line end when the damage cut it: it is incomplete.
            if data and not data.endswith((b"\n", b"\r")):
                lines.pop()
            n = len(lines)
            kept = {0: "", 1: "; the 1 complete line before it is kept"}.get(
                n, f"; the {n} complete lines before it are kept"
            )
            warnings.append(f"{path}: {damage.text}; records from line {n + 1} on are lost{kept}")
        elif damage.end > damage.start:
            first, last = _line_of(data, damage.start), _line_of(data, damage.end - 1)
            where = f"line {first}" if first == last else f"lines {first}–{last}"
            warnings.append(f"{path}: {where} may hold damaged values; {damage.text}")
        else:
            warnings.append(f"{path}: {damage.text}, in a part that holds no lines")
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
    if not minimum <= value <= MAX_READINGS:
        raise _Skip("n")
    return value


def _time(fields: list[bytes]) -> float:
    """The ipc timestamp (third field from the end); checks the logger timestamp too."""
    _numbers(fields[-1:])
    try:
        time_s = float(fields[-3])
    except ValueError:
        raise _Skip("value") from None
    if not (math.isfinite(time_s) and 0.0 <= time_s <= MAX_TIME_S):
        raise _Skip("time")
    return time_s + 0.0  # -0.0 becomes 0.0


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
    _, start, fov, resolution, maximum_range = config[:5]
    if fan_defect(n, float(start), float(start + fov)) is not None:
        raise _Skip("geometry")
    if n > 1 and abs(fov / (n - 1) - resolution) * (n - 1) > abs(resolution):
        raise _Skip("geometry")  # the step and the field of view disagree by over a beam
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
    return f"{plural(len(lines), 'line')} {shown}{more}"


def _skip_warnings(path: Path, skipped: dict[tuple[str, str], list[int]]) -> list[str]:
    return [
        f"{path}: skipped {len(lines)} {kind} {plural(len(lines), 'record')} "
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
        shown = _shown(text[:SHOWN_CHARS]) + ("…" if len(text) > SHOWN_CHARS else "")
        warnings.append(f"{path}: PARAM {name} is '{shown}', not a number (line {line}); ignored")
        return None
    return value


def _shown(token: bytes) -> str:
    """``token`` as printable ASCII, other bytes as ``\\xNN`` escapes."""
    if token.isascii() and token.decode("ascii").isprintable():
        return token.decode("ascii")
    return "".join(chr(b) if 0x20 <= b < 0x7F else f"\\x{b:02x}" for b in token)


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


@dataclass
class _Parsed:
    """What the lines of a log hold: the chosen laser's records, how many records of each
    type there are, the first value and line of each PARAM, the line numbers of skipped
    records per (type, reason), the lines holding NUL bytes and the count of non-empty lines.
    ``numbers``: each kept record's place among the chosen laser's records, from 1, those
    skipped included."""

    records: list[_LaserRecord] = field(default_factory=list)
    numbers: list[int] = field(default_factory=list)
    counts: Counter = field(default_factory=Counter)
    params: dict[str, tuple[bytes, int]] = field(default_factory=dict)
    skipped: dict[tuple[str, str], list[int]] = field(default_factory=dict)
    with_nul: list[int] = field(default_factory=list)
    n_lines: int = 0


def read_carmen(
    path: str | Path,
    laser: str = "front",
    range_max_m: float | None = None,
    progress: ProgressFactory = silent,
) -> Log:
    """Read the scans of one laser and their poses from a CARMEN log.

    ``path``: a CARMEN text log, plain or gzip-compressed (found by its magic
    bytes, whatever its name). ``laser``: "front" (FLASER and ROBOTLASER1
    records) or "rear" (RLASER), else ``ValueError``. ``range_max_m``: the
    sensor's maximum range in metres, overriding the log (see the module
    docstring for how it is found otherwise).

    Raises ``InputError`` naming the file when it is missing, a directory, not
    text, or holds no usable record of the chosen laser. Everything else odd
    (bad records, NUL bytes, damaged gzip, colliding times, no maximum range
    found) is a line of ``Log.warnings``. The log's ``odom_times_s`` are the
    scans' times and its ``laser_poses`` the records' pose fields. The parsing reports
    its lines to ``progress``.
    """
    if laser not in LASER_RECORDS:
        raise ValueError(f"laser must be one of {sorted(LASER_RECORDS)}, got {laser!r}")
    if range_max_m is not None and not range_max_m > 0:
        raise ValueError(f"range_max_m must be positive, got {range_max_m}")
    path = Path(path)
    warnings: list[str] = []
    lines = _read_lines(path, warnings)
    with progress("reading the log", len(lines), "line") as shown:
        parsed = _parse_lines(lines, LASER_RECORDS[laser], shown)
    _check_records(path, parsed, laser, warnings)
    _drop_repeated_scans(path, parsed, warnings)
    records = parsed.records
    per_record, rule = _range_maxes(path, parsed, laser, range_max_m, warnings)
    original_times_s = np.array([r.time_s for r in records], dtype=float)
    times_s, collided = importer_times(
        original_times_s, path, "laser records", "file order", str(path)
    )
    warnings += [collided] if collided else []
    scans = _scans(records, per_record, times_s)
    offset_m = _laser_offset(path, parsed.params, laser, warnings)
    laser_poses, odom_poses = _poses(records, laser, offset_m)
    return Log(
        scans=scans,
        original_times_s=original_times_s,
        odom_times_s=times_s,
        odom_poses=odom_poses,
        sensor=_sensor(path, records, scans, laser, per_record, rule, offset_m),
        laser_poses=laser_poses,
        warnings=warnings,
        numbers=np.array(parsed.numbers, dtype=np.int64),
    )


def _parse_lines(lines: list[bytes], wanted: tuple[str, ...], progress: Progress) -> _Parsed:
    """The records of the laser record types ``wanted``, the PARAMs and what was skipped;
    each line is a step of ``progress``."""
    parsed = _Parsed()
    for number, line in enumerate(lines, start=1):
        progress.advance()
        if b"\x00" in line:
            parsed.with_nul.append(number)
            parsed.n_lines += 1
            continue
        fields = line.split()
        if not fields:
            continue
        parsed.n_lines += 1
        if fields[0].startswith(b"#"):
            continue
        kind = _shown(fields[0][:SHOWN_CHARS])
        parsed.counts[kind] += 1
        try:
            if kind in wanted:
                parsed.records.append(PARSERS[kind](kind, fields))
                parsed.numbers.append(sum(parsed.counts[k] for k in wanted))
            elif kind == "ODOM":
                _check_odom(fields)
            elif kind == "PARAM" and len(fields) >= 3:
                parsed.params.setdefault(_shown(fields[1][:SHOWN_CHARS]), (fields[2], number))
        except _Skip as skip:
            parsed.skipped.setdefault((kind, skip.reason), []).append(number)
    return parsed


def _check_records(path: Path, parsed: _Parsed, laser: str, warnings: list[str]) -> None:
    """Refuse a file that is not text or holds no usable laser record; put the warnings on
    skipped records and NUL lines ahead of ``warnings``."""
    with_nul = parsed.with_nul
    if with_nul and (len(with_nul) > BINARY_LINE_FRACTION * parsed.n_lines or not parsed.records):
        raise InputError(f"not a text file; expected {EXPECTED}", path=path)
    # The damage note, if any, reads best after the per-record summaries.
    warnings[:0] = _skip_warnings(path, parsed.skipped)
    if with_nul:
        n = len(with_nul)
        note = f"{path}: skipped {counted(n, 'line')} holding NUL bytes"
        warnings.insert(len(parsed.skipped), f"{note} ({_line_list(with_nul)})")
    if not parsed.records:
        raise InputError(_no_records_message(path, laser, parsed.counts, warnings), path=path)


def _drop_repeated_scans(path: Path, parsed: _Parsed, warnings: list[str]) -> None:
    """Leave out each FLASER record that repeats a ROBOTLASER1 record: same time, as many
    readings (a logger writing both layouts of every scan), with one warning. ROBOTLASER1
    is kept as it carries the scanner's own geometry and maximum range."""
    robot = {(r.time_s, len(r.ranges_m)) for r in parsed.records if r.kind == "ROBOTLASER1"}
    repeats = [r.kind == "FLASER" and (r.time_s, len(r.ranges_m)) in robot for r in parsed.records]
    n = sum(repeats)
    if not n:
        return
    kept = [i for i, repeat in enumerate(repeats) if not repeat]
    parsed.records = [parsed.records[i] for i in kept]
    parsed.numbers = [parsed.numbers[i] for i in kept]
    warnings.append(
        f"{path}: imported the ROBOTLASER1 records; left out {counted(n, 'FLASER record')} "
        "repeating one of them (same time, as many readings)"
    )


def _range_maxes(
    path: Path, parsed: _Parsed, laser: str, range_max_m: float | None, warnings: list[str]
) -> tuple[list[float], str]:
    """The maximum range (m) of each record and the rules that gave them (module docstring)."""
    records = parsed.records
    if range_max_m is not None:
        return [float(range_max_m)] * len(records), "given"
    per_record = [math.inf] * len(records)
    stating: dict[float, list[int]] = {}
    for i, record in enumerate(records):
        if record.range_max_m is not None:
            stating.setdefault(record.range_max_m, []).append(i)
    own_rules = []
    for stated_m, indices in stating.items():
        limit_m, rule = _own_range_max(path, records, indices, stated_m, warnings)
        for i in indices:
            per_record[i] = limit_m
        own_rules.append(rule)
    # An empty rule: those records keep their own maximum_range.
    rules = ["ROBOTLASER1 maximum_range"] if "" in own_rules else []
    rules += [rule for rule in own_rules if rule]
    needing = [i for i, record in enumerate(records) if record.range_max_m is None]
    if needing:
        readings = np.concatenate([records[i].ranges_m for i in needing])
        fallback, rule = _fallback_range_max(path, parsed, laser, readings, warnings)
        for i in needing:
            per_record[i] = fallback
        rules.append(rule)
    return per_record, "; ".join(rules)


def _own_range_max(
    path: Path,
    records: list[_LaserRecord],
    indices: list[int],
    stated_m: float,
    warnings: list[str],
) -> tuple[float, str]:
    """The maximum range (m) of the ROBOTLASER1 records ``indices``, whose own
    ``maximum_range`` is ``stated_m``: that value, unless returns lie beyond it (a warning,
    and the rule that gave the limit used instead; else the rule is "")."""
    readings = np.concatenate([records[i].ranges_m for i in indices])
    group = counted(len(indices), "ROBOTLASER1 record")
    limit = stated_limit(readings, stated_m, "maximum_range", group)
    if limit is None:
        return stated_m, ""
    warnings.append(f"{path}: {limit.warning}")
    return limit.value_m, limit.rule


def _fallback_range_max(
    path: Path, parsed: _Parsed, laser: str, readings: np.ndarray, warnings: list[str]
) -> tuple[float, str]:
    """The maximum range (m) of records without their own, holding ``readings``, and how it
    was found: the no-return value the readings repeat, else the laser's maximum-range PARAM
    unless returns lie beyond it (a warning when they do, and when no limit is found)."""
    no_return = no_return_value(readings)
    param = _range_max_param(path, parsed.params, laser, warnings)
    if param is None:
        if no_return.unsure:
            warnings.append(_no_maximum_warning(path, no_return))
        return no_return.value_m, no_return.rule
    stated_m, source = param
    check = overruled(readings, stated_m)
    if check is None:
        if no_return.found:
            return no_return.value_m, f"{no_return.rule}; {source} ({fmt_m(stated_m)} m) not used"
        return stated_m, (
            f"{source} (the readings repeat no no-return value, and no return lies beyond it)"
        )
    limit = no_return if no_return.found else check.no_return
    dropped = dropped_returns(readings, stated_m, limit.value_m)
    if dropped[0]:
        used = limit.limit_text()
        warnings.append(f"{path}: {overruled_text(source, stated_m, dropped, readings.size, used)}")
    return limit.value_m, (
        f"{limit.rule}; {source} ({fmt_m(stated_m)} m) not used: returns lie beyond it"
    )


def _no_maximum_warning(path: Path, no_return: NoReturn) -> str:
    return (
        f"{path}: no maximum range found, {no_return.rule.removeprefix('none: ')}; every "
        "positive reading counts as a return (pass --range-max-m if the scanner "
        "has a maximum range)"
    )


def _scans(records: list[_LaserRecord], per_record: list[float], times_s: np.ndarray) -> list[Scan]:
    """The records' scans at ``times_s`` (S,) seconds with their maximum ranges (m)."""
    return [
        Scan(
            time_s=float(time_s),
            angles_rad=evenly_spaced_angles(len(r.ranges_m), r.start_rad, r.start_rad + r.fov_rad),
            ranges_m=r.ranges_m,
            range_max_m=limit,
            intensities=r.intensities,
        )
        for r, limit, time_s in zip(records, per_record, times_s, strict=True)
    ]


def _laser_offset(
    path: Path, params: dict[str, tuple[bytes, int]], laser: str, warnings: list[str]
) -> float:
    """The laser's offset PARAM (m, along the robot's heading for the front laser), 0 when
    absent, unusable or too large (with a warning)."""
    offset_m = _param_value(path, params, OFFSET_PARAMS[laser], warnings) or 0.0
    if abs(offset_m) > MAX_LASER_OFFSET_M:
        warnings.append(
            f"{path}: PARAM {OFFSET_PARAMS[laser]} is {offset_m:g} m, more than "
            f"{MAX_LASER_OFFSET_M:g} m; ignored"
        )
        offset_m = 0.0
    return offset_m


def _poses(
    records: list[_LaserRecord], laser: str, offset_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """The records' pose fields and odometry (S, 3) ``x_m, y_m, theta_rad``, headings
    wrapped; the odometry moved from the robot centre to the scanner by ``offset_m``."""
    # The rear scanner faces backward: its offset runs along the robot's heading + π.
    along_m = offset_m if laser == "front" else -offset_m
    laser_poses = np.array([r.laser_pose for r in records], dtype=float)
    odom_poses = np.array([r.odom_pose for r in records], dtype=float)
    at_centre = np.any(odom_poses != laser_poses, axis=1)
    if along_m != 0.0:
        odom_poses[at_centre] = _shift(odom_poses[at_centre], along_m)
    laser_poses[:, 2] = _wrapped(laser_poses[:, 2])
    odom_poses[:, 2] = _wrapped(odom_poses[:, 2])
    return laser_poses, odom_poses


def _sensor(
    path: Path,
    records: list[_LaserRecord],
    scans: list[Scan],
    laser: str,
    per_record: list[float],
    rule: str,
    offset_m: float,
) -> dict[str, str]:
    """Settings for the MCAP log's metadata record (str → str)."""
    beams = sorted({len(s) for s in scans})
    fovs = sorted({f"{math.degrees(r.fov_rad):.10g}" for r in records}, key=float)
    wanted = LASER_RECORDS[laser]
    return {
        "range_max_m": fmt_m(max(per_record)),
        "range_max_from": rule,
        "readings": ",".join(str(n) for n in beams),
        "fov_deg": ",".join(fovs),
        "laser": laser,
        "laser_offset_m": fmt_m(offset_m),
        "records": ",".join(k for k in wanted if any(r.kind == k for r in records)),
        "source": path.name,
        "format": "CARMEN log",
    }
