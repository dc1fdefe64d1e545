"""Map and world files (JSON).

A map file holds the global segment map used for localization::

    {"format": "segloc-map", "version": 1, "frame": "world", "units": "m",
     "segments": [[x1, y1, x2, y2], ...], "source": {...}}

A world file is what the simulator renders; it adds a name and a material per
segment::

    {"format": "segloc-world", "version": 1, "units": "m", "frame": "world",
     "name": "...", "segments": [[...], ...], "materials": ["wall" | "glass", ...]}

A world file is accepted wherever a map is (``read_map`` returns its segments).
Segments are (M, 4) float64 arrays ``x1 y1 x2 y2`` in metres, world frame.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.io.files import reading

MAP_FORMAT = "segloc-map"
WORLD_FORMAT = "segloc-world"
SUPPORTED_VERSION = 1
MATERIALS = ("wall", "glass")


@dataclass(frozen=True)
class World:
    """A simulated environment.

    ``segments`` (M, 4) float64, metres, world frame; ``materials`` (M,) str, one
    of ``MATERIALS`` per segment; ``name`` a label for reports.
    """

    segments: np.ndarray
    materials: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=str))
    name: str = "world"

    def __post_init__(self) -> None:
        segments = np.asarray(self.segments, dtype=float).reshape(-1, 4)
        materials = np.asarray(self.materials, dtype=str).reshape(-1)
        if materials.size == 0 and len(segments) > 0:
            materials = np.full(len(segments), "wall")
        if len(materials) != len(segments):
            raise ValueError(
                f"world {self.name!r}: {len(materials)} materials for {len(segments)} segments"
            )
        unknown = sorted(set(materials.tolist()) - set(MATERIALS))
        if unknown:
            raise ValueError(
                f"world {self.name!r}: unknown material(s) {unknown}; use one of {list(MATERIALS)}"
            )
        object.__setattr__(self, "segments", segments)
        object.__setattr__(self, "materials", materials)

    def __len__(self) -> int:
        return len(self.segments)


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
        _parse_materials(path, document, len(segments))
    return segments


def write_world(path: str | Path, world: World) -> None:
    """Write a world file."""
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
    _write_json(path, document)


def read_world(path: str | Path) -> World:
    """Read a world file → ``World``. A map file is rejected (it has no materials)."""
    document = _read_json(path)
    _check_header(path, document, (WORLD_FORMAT,))
    segments = _parse_segments(path, document)
    if len(segments) == 0:
        raise InputError("world has no segments; add walls to its `segments` list", path=path)
    materials = _parse_materials(path, document, len(segments))
    name = document.get("name", Path(path).stem)
    if not isinstance(name, str):
        raise InputError(f"`name` must be a string, got {name!r}", path=path)
    return World(segments=segments, materials=materials, name=name)


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


def _write_json(path: str | Path, document: dict) -> None:
    # json writes floats with repr(), which round-trips float64 exactly.
    text = json.dumps(document, indent=1, allow_nan=False)
    Path(path).write_text(text + "\n", encoding="utf-8")


def _read_json(path: str | Path) -> dict:
    path = Path(path)
    with reading(path, "a JSON map or world file"):
        text = path.read_text(encoding="utf-8")
    try:
        document = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"not valid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}", path=path
        ) from None
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
        found = "missing" if kind is None else f"{kind!r}"
        raise InputError(f"`format` is {found}; expected {wanted}", path=path)
    version = document.get("version")
    if version != SUPPORTED_VERSION:
        raise InputError(
            f"unsupported {kind} version {version!r}; this segloc reads version "
            f"{SUPPORTED_VERSION}",
            path=path,
        )
    return kind


def _is_number(value) -> bool:
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(float(value))
    )


def _parse_segments(path, document: dict) -> np.ndarray:
    raw = document.get("segments")
    if not isinstance(raw, list):
        raise InputError("`segments` must be a list of [x1, y1, x2, y2]", path=path)
    for index, item in enumerate(raw):
        if not (isinstance(item, list) and len(item) == 4 and all(_is_number(v) for v in item)):
            raise InputError(
                f"segment {index} must be 4 finite numbers [x1, y1, x2, y2], got {item!r}",
                path=path,
            )
    segments = np.array(raw, dtype=float).reshape(-1, 4)
    lengths = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    zero = np.flatnonzero(lengths == 0.0)
    if zero.size:
        raise InputError(
            f"segment {int(zero[0])} has zero length (both endpoints equal); remove it",
            path=path,
        )
    return segments


def _parse_materials(path, document: dict, n_segments: int) -> np.ndarray:
    raw = document.get("materials")
    if raw is None:
        return np.full(n_segments, "wall")
    if not isinstance(raw, list) or len(raw) != n_segments:
        count = len(raw) if isinstance(raw, list) else "not a list"
        raise InputError(
            f"`materials` must list one material per segment: {n_segments} segments, "
            f"materials {count}",
            path=path,
        )
    for index, material in enumerate(raw):
        if material not in MATERIALS:
            raise InputError(
                f"segment {index} has unknown material {material!r}; use one of {list(MATERIALS)}",
                path=path,
            )
    return np.array(raw, dtype=str)
