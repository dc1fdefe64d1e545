"""Map and world files (JSON).

A map file holds the global segment map used for localization::

    {"format": "segloc-map", "version": 1, "frame": "world", "units": "m",
     "segments": [[x1, y1, x2, y2], ...], "source": {...}}

A world file is what the simulator renders; it adds a name, a material per
segment and, optionally, the scanner to simulate (``sim.SENSOR_CHOICES``)::

    {"format": "segloc-world", "version": 1, "units": "m", "frame": "world",
     "name": "...", "segments": [[...], ...], "materials": ["wall" | "glass", ...],
     "sensor": {"readings": 361, "fov_deg": 180, "noise_cm": 1.0,
                "clutter": false, "glass": true}}

Only ``format``, ``version`` and ``segments`` are required (``WORLD_KEYS`` lists them
all; any other key is refused). A world file is accepted wherever a map is
(``read_map`` returns its segments), and ``read_world`` takes a map as a world when
given the material its segments are made of. Segments are (M, 4) float64 arrays
``x1 y1 x2 y2`` in metres, world frame. Both files are written one segment a line,
coordinates to the micrometre (``numbers.py``).

Readers refuse, with one line naming the file, anything the localizer could not
hold in reasonable memory and time: files over ``MAX_MAP_BYTES``, more than
``MAX_SEGMENTS`` segments, coordinates beyond ±``MAX_COORDINATE_M``, maps whose
bounding box is wider or taller than ``MAX_MAP_EXTENT_M`` (the score raster spans
it), more than ``MAX_TOTAL_LENGTH_M`` of segments in all, and segments shorter than
``MIN_SEGMENT_LENGTH_M`` (zero length: they have no direction).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.io.files import reading, write_text_atomic
from segloc_cli.limits import MAX_COORDINATE_M
from segloc_cli.numbers import json_text, rounded_tree
from segloc_cli.wording import counted, did_you_mean
from segloc_cli.world import MATERIALS, World

MAP_FORMAT = "segloc-map"
WORLD_FORMAT = "segloc-world"
SUPPORTED_VERSION = 1

MAX_MAP_BYTES = 32 * 1024 * 1024
"""Largest map or world file read (bytes): ``MAX_SEGMENTS`` segments within ±1 km take
about 5 MB as segloc writes them (to the micrometre), 8 MB at float64's full precision."""

MAX_SEGMENTS = 100_000
"""Most segments in a map: a multi-storey campus plan holds tens of thousands."""

MAX_MAP_EXTENT_M = 2000.0
"""Largest width or height (m) of a map's bounding box. The score raster spans it: up to
about 500 m × 500 m at its 5 cm cells (400 MB), coarser cells beyond (20 cm at 2 km)."""

MAX_TOTAL_LENGTH_M = 1_000_000.0
"""Largest summed length (m) of a map's segments; building the score raster takes time in
proportion (about a second per 1,000 km)."""

MIN_SEGMENT_LENGTH_M = 1e-6
"""Shorter segments (1 µm) count as zero length: their direction is undefined."""

WORLD_KEYS = ("format", "version", "units", "frame", "name", "segments", "materials", "sensor")
"""Every key a world file may hold."""


def write_map(path: str | Path, segments_world: np.ndarray, source: dict | None = None) -> None:
    """Write a map file: ``segments_world`` (M, 4) metres, world frame; ``source``
    a JSON-serialisable description of where the map came from."""
    segments = _checked_array(segments_world, "map")
    document = {
        "format": MAP_FORMAT,
        "version": SUPPORTED_VERSION,
        "frame": "world",
        "units": "m",
        "segments": segments.tolist(),
        "source": dict(source or {}),
    }
    _write_json(path, document)


def read_map(path: str | Path) -> np.ndarray:
    """Read a map (or world) file → segments (M, 4) float64, metres, world frame.

    Raises ``InputError`` naming the file when it is missing, not JSON, not a
    segloc map/world, of an unsupported version, or has bad or no segments.
    """
    document = _read_json(path)
    kind = _check_header(path, document, (MAP_FORMAT, WORLD_FORMAT))
    segments = _parse_segments(path, document)
    if len(segments) == 0:
        raise InputError("map has no segments; build one with `segloc map build`", path=path)
    if kind == WORLD_FORMAT:
        _parse_world(path, document, segments, "wall")
    return segments


def read_map_source(path: str | Path) -> dict:
    """The ``source`` record of a map file (how it was built; {} where it says nothing)."""
    document = _read_json(path)
    _check_header(path, document, (MAP_FORMAT, WORLD_FORMAT))
    source = document.get("source", {})
    return source if isinstance(source, dict) else {}


def segloc_kind(path: str | Path) -> str | None:
    """ "map" or "world" when ``path`` is a segloc map or world file (a JSON object whose
    ``format`` says so), else None, also for a file that cannot be read (its own reader says
    why). Of a file that does not start as a JSON object, only the first bytes are read."""
    path = Path(path)
    try:
        if not path.is_file():
            return None
        with path.open("rb") as stream:
            head = stream.read(64)
        if not head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"{"):
            return None
        kind = _read_json(path).get("format")
    except (OSError, InputError):
        return None
    return {MAP_FORMAT: "map", WORLD_FORMAT: "world"}.get(kind) if isinstance(kind, str) else None


def write_world(path: str | Path, world: World) -> None:
    """Write a world file (its ``sensor`` only when it chooses one)."""
    segments = _checked_array(world.segments, "world")
    document = {
        "format": WORLD_FORMAT,
        "version": SUPPORTED_VERSION,
        "units": "m",
        "frame": "world",
        "name": str(world.name),
        "segments": segments.tolist(),
        "materials": [str(m) for m in world.materials],
    }
    if world.sensor:
        document["sensor"] = dict(world.sensor)
    _write_json(path, document)


def read_world(path: str | Path, default_material: str | None = None) -> World:
    """Read a world file → ``World``; its segments without a ``materials`` list are made
    of ``default_material`` (wall when None). A map file is taken as a world of
    ``default_material`` named after the file, and is refused when that is None (it has
    no materials). Every key, material and sensor choice is checked (``InputError``)."""
    document = _read_json(path)
    accepted = (WORLD_FORMAT,) if default_material is None else (WORLD_FORMAT, MAP_FORMAT)
    kind = _check_header(path, document, accepted)
    segments = _parse_segments(path, document)
    if len(segments) == 0:
        what = "world" if kind == WORLD_FORMAT else "map"
        raise InputError(f"{what} has no segments; add walls to its `segments` list", path=path)
    material = default_material or "wall"
    if kind == MAP_FORMAT:
        materials = np.full(len(segments), material)
        return World(segments=segments, materials=materials, name=Path(path).stem)
    return _parse_world(path, document, segments, material)


def _parse_world(path, document: dict, segments: np.ndarray, default_material: str) -> World:
    """The world a world file's ``document`` describes around its ``segments``, every
    key but the header's checked."""
    unknown = [key for key in document if key not in WORLD_KEYS]
    if unknown:
        raise InputError(_unknown_key(unknown[0], WORLD_KEYS, "a world file"), path=path)
    for key, wanted, meaning in (("units", "m", "metres"), ("frame", "world", "the world frame")):
        if key in document and document[key] != wanted:
            raise InputError(
                f"`{key}` is {shown_value(document[key])}; a world file is in {meaning} "
                f'("{wanted}")',
                path=path,
            )
    materials = _parse_materials(path, document, len(segments), default_material)
    name = document.get("name", Path(path).stem)
    if not isinstance(name, str):
        raise InputError(f"`name` must be a string, got {shown_value(name)}", path=path)
    sensor = _parse_sensor(path, document.get("sensor", {}))
    return World(segments=segments, materials=materials, name=name, sensor=sensor)


def _parse_sensor(path, raw) -> dict:
    """A world file's ``sensor`` object, checked key by key and value by value."""
    from segloc_cli.sim import SENSOR_CHOICES, sensor_model

    if not isinstance(raw, dict):
        listed = ", ".join(SENSOR_CHOICES)
        raise InputError(f"`sensor` must be an object of {listed}", path=path)
    for key, value in raw.items():
        kind = SENSOR_CHOICES.get(key)
        if kind is None:
            raise InputError(_unknown_key(key, tuple(SENSOR_CHOICES), "`sensor`"), path=path)
        if kind is bool and not isinstance(value, bool):
            raise InputError(f"`sensor.{key}` must be true or false, got {value!r}", path=path)
        if kind is int and (isinstance(value, bool) or not isinstance(value, int)):
            raise InputError(
                f"`sensor.{key}` must be a whole number, got {shown_value(value)}", path=path
            )
        if kind is float and not _is_number(value):
            raise InputError(
                f"`sensor.{key}` must be a finite number, got {shown_value(value)}", path=path
            )
    try:
        sensor_model(raw)
    except ValueError as exc:
        raise InputError(f"sensor.{exc}", path=path) from None
    return dict(raw)


def _unknown_key(key, known: tuple[str, ...], where: str) -> str:
    hint = did_you_mean(str(key), known)
    hint = f"; {hint}" if hint else ""
    return f"unknown key {shown_value(key)} in {where}, which holds {', '.join(known)}{hint}"


# --- helpers ---------------------------------------------------------------


def _checked_array(segments, what: str) -> np.ndarray:
    segments = np.asarray(segments, dtype=float)
    if segments.size == 0:
        return np.zeros((0, 4))
    if segments.ndim != 2 or segments.shape[1] != 4:
        raise ValueError(f"{what} segments must be an (M, 4) array, got shape {segments.shape}")
    if not np.all(np.isfinite(segments)):
        raise ValueError(f"{what} segments contain non-finite coordinates")
    return segments


_SEGMENTS_HERE = "\0segments\0"
"""Stands for the segments in the JSON text of a document, to be replaced by one line each."""


def _write_json(path: str | Path, document: dict) -> None:
    """Write a map or world ``document``: its fields one a line, its ``segments`` (metres)
    one ``[x1, y1, x2, y2]`` a line, every number rounded (``numbers.py``)."""
    segments = rounded_tree(document["segments"], "m")
    text = json_text({**document, "segments": _SEGMENTS_HERE}, indent=1)
    rows = ",\n".join(f"  {json.dumps(segment)}" for segment in segments)
    block = f"[\n{rows}\n ]" if rows else "[]"
    write_text_atomic(path, text.replace(json.dumps(_SEGMENTS_HERE), block, 1))


def _parse_int(digits: str) -> int | float:
    # Python refuses to convert ints of more than 4300 digits, and float() of a huge int
    # overflows: a number that long becomes a float (inf), which the checks then refuse.
    return int(digits) if len(digits) <= 20 else float(digits)


def _read_json(path: str | Path) -> dict:
    path = Path(path)
    with reading(path, "a JSON map or world file"):
        size = path.stat().st_size
        if size > MAX_MAP_BYTES:
            raise InputError(
                f"file is {size} bytes, more than a map may hold ({MAX_MAP_BYTES} bytes)",
                path=path,
            )
        text = path.read_text(encoding="utf-8")
    try:
        document = json.loads(text, parse_int=_parse_int)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"not valid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}", path=path
        ) from None
    except RecursionError:
        raise InputError("not a map: its JSON is nested too deeply", path=path) from None
    except ValueError as exc:
        raise InputError(f"not valid JSON: {_one_line(exc)}", path=path) from None
    if not isinstance(document, dict):
        raise InputError("expected a JSON object with a `format` field", path=path)
    return document


def _check_header(path, document: dict, accepted: tuple[str, ...]) -> str:
    kind = document.get("format")
    if kind not in accepted:
        wanted = " or ".join(f'"{k}"' for k in accepted)
        if kind == MAP_FORMAT and WORLD_FORMAT in accepted:
            raise InputError(
                'this is a map file ("segloc-map"), not a world file; the simulator needs a '
                '"segloc-world" file with materials',
                path=path,
            )
        found = "missing" if kind is None else shown_value(kind)
        raise InputError(f"`format` is {found}; expected {wanted}", path=path)
    version = document.get("version")
    if isinstance(version, bool) or version != SUPPORTED_VERSION:
        raise InputError(
            f"unsupported {kind} version {shown_value(version)}; this segloc reads version "
            f"{SUPPORTED_VERSION}",
            path=path,
        )
    return kind


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _parse_segments(path, document: dict) -> np.ndarray:
    raw = document.get("segments")
    if not isinstance(raw, list):
        raise InputError("`segments` must be a list of [x1, y1, x2, y2]", path=path)
    if len(raw) > MAX_SEGMENTS:
        raise InputError(
            f"{len(raw)} segments, more than a map may hold ({MAX_SEGMENTS})", path=path
        )
    for index, item in enumerate(raw):
        if not (isinstance(item, list) and len(item) == 4 and all(_is_number(v) for v in item)):
            raise InputError(
                f"segment {index} must be 4 finite numbers [x1, y1, x2, y2], "
                f"got {shown_value(item)}",
                path=path,
            )
    segments = np.array(raw, dtype=float).reshape(-1, 4)
    problem = bounds_problem(segments)
    if problem is not None:
        raise InputError(problem, path=path)
    return segments


def bounds_problem(segments: np.ndarray) -> str | None:
    """Why segments (M, 4), metres, world frame, cannot be a map, or None when they can.

    Checks every bound of the module (``MAX_SEGMENTS``, ``MAX_COORDINATE_M``,
    ``MIN_SEGMENT_LENGTH_M``, ``MAX_MAP_EXTENT_M``, ``MAX_TOTAL_LENGTH_M``) and
    finiteness; the answer is one line, fit for an error message.
    """
    segments = np.asarray(segments, dtype=float).reshape(-1, 4)
    if segments.shape[0] > MAX_SEGMENTS:
        return f"{segments.shape[0]} segments, more than a map may hold ({MAX_SEGMENTS})"
    if segments.shape[0] == 0:
        return None
    bad = np.flatnonzero(~np.all(np.isfinite(segments), axis=1))
    if bad.size:
        return f"segment {int(bad[0])} has non-finite coordinates"
    far = np.flatnonzero(np.any(np.abs(segments) > MAX_COORDINATE_M, axis=1))
    if far.size:
        return (
            f"segment {int(far[0])} has a coordinate beyond ±{MAX_COORDINATE_M:g} m "
            f"({shown_value(segments[far[0]].tolist())})"
        )
    lengths = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    short = np.flatnonzero(lengths < MIN_SEGMENT_LENGTH_M)
    if short.size:
        return (
            f"segment {int(short[0])} has zero length (its ends lie within "
            f"{MIN_SEGMENT_LENGTH_M:g} m); remove it"
        )
    ends = segments.reshape(-1, 2)
    width, height = ends.max(axis=0) - ends.min(axis=0)
    if max(width, height) > MAX_MAP_EXTENT_M:
        return (
            f"map spans {width:.6g} m × {height:.6g} m, more than {MAX_MAP_EXTENT_M:g} m "
            "across; split it, or check for a stray segment far from the rest"
        )
    total = float(lengths.sum())
    if total > MAX_TOTAL_LENGTH_M:
        return f"segments total {total:.6g} m, more than {MAX_TOTAL_LENGTH_M:g} m"
    return None


def shown_value(value, limit: int = 80) -> str:
    """``repr`` of a value from a user's file on one line, cut to ``limit`` characters, as
    error messages quote it."""
    text = _one_line(repr(value))
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _one_line(value) -> str:
    return " ".join(str(value).split())


def _parse_materials(path, document: dict, n_segments: int, default: str) -> np.ndarray:
    raw = document.get("materials")
    if raw is None:
        return np.full(n_segments, default)
    if not isinstance(raw, list) or len(raw) != n_segments:
        count = len(raw) if isinstance(raw, list) else "not a list"
        raise InputError(
            f"`materials` must list one material per segment: "
            f"{counted(n_segments, 'segment')}, materials {count}",
            path=path,
        )
    for index, material in enumerate(raw):
        if material not in MATERIALS:
            raise InputError(
                f"segment {index} has unknown material {shown_value(material)}; "
                f"use one of {list(MATERIALS)}",
                path=path,
            )
    return np.array(raw, dtype=str)
