"""nav2 occupancy grids (the ROS map_server format) as segment maps, in and out.

A grid is a YAML file naming an image beside it (PGM or PNG, path relative to the YAML)::

    image: office.pgm
    resolution: 0.05            # metres per cell
    origin: [-1.05, -1.05, 0.0] # x, y (m) and yaw (rad) of the outer corner of the bottom-left cell
    negate: 0
    occupied_thresh: 0.65
    free_thresh: 0.196
    mode: trinary               # optional: trinary (default), scale or raw

Reading classifies every pixel as map_server does. A pixel's shade s ∈ [0, 1] is its grey
value over the largest value of its depth (the mean of R, G and B for a colour image); its
occupancy is p = 1 − s, or s with ``negate``. In trinary and scale modes a pixel is occupied
when p > occupied_thresh and free when p < free_thresh (the map_server documentation's
rule; its releases from Jazzy on also count a pixel exactly at a threshold, which no 8-bit
value meets for the usual 0.65, 0.196 or 0.25), and a pixel that is not fully opaque is
unknown. In raw mode the grey value (0–255) is the occupancy in percent itself: 100 is
occupied, 0–99 free or partly occupied, above 100 unknown; negate and the thresholds do not
apply. Image row 0 is the top of the map (largest y); cell (column i, row j from the
bottom) has its centre at ``origin ⊕ ((i + ½)·resolution, (j + ½)·resolution)``, the
offset turned by the origin's yaw.

The occupied cells become segments as ``maps.wall_tracing.trace_walls`` traces them:
through the centres of each surface's outermost occupied cells, split and fitted as scans
are, a wall one cell thick as one segment, a thicker one as one segment per face.

Writing draws each segment as the thin line of cells it crosses
(``maps.wall_tracing.line_cells``) in black (occupied, 0) on a grid covering the map's
bounding box,
``MARGIN_CELLS`` beyond it on every side. Cells inside the bounding box are free (254):
a segment map says where walls are, not where floor is, so nothing inside can be marked
unknown with reason, and free is what a plan drawn on white paper says. Cells of the margin
are unknown (205): the map holds nothing about what lies beyond its walls' extent, and
nav2 then neither plans paths nor places particles there. The YAML uses map_saver's
trinary values and thresholds (occupied_thresh 0.65, free_thresh 0.196), so map_server
reads the image back as written.
"""

from __future__ import annotations

import contextlib
import math
import reprlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segloc_cli.config import ExtractParams
from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2, transform_segments
from segloc_cli.io.files import atomic_paths, reading, writing
from segloc_cli.io.plans import FloorPlan, checked_plan_segments
from segloc_cli.limits import MAX_COORDINATE_M
from segloc_cli.maps.wall_tracing import SPLIT_CELLS, line_cells, trace_walls
from segloc_cli.wording import with_article

OCCUPANCY_MODES = ("trinary", "scale", "raw")
"""Values of the YAML's ``mode`` key; ``trinary`` when it is absent."""

OCCUPIED = 100
"""The value map_server gives an occupied cell (nav_msgs/OccupancyGrid)."""

MAX_GRID_CELLS = 100_000_000
"""Most cells read or written (10,000 × 10,000: 500 m square at 5 cm): such a grid takes
about 25 s and 1.5 GB to trace, and a larger one is refused by its image's header, before
any pixel is read."""

MAX_YAML_BYTES = 1 << 20
"""Largest nav2 map YAML read (1 MiB): a handful of keys, not data."""

MAX_YAW_RAD = 4.0 * math.pi
"""Largest |yaw| of a grid's origin: radians, as map_server takes them (90 is degrees)."""

IMAGE_FORMATS = ("PNG", "PPM")
"""Pillow's formats a grid's image may be in: PNG, and PGM (Pillow's PPM reads PGM, PBM and
PPM). No other decoder is tried, so a file that only names itself an image runs no
decoder beyond these two (Pillow's EPS reader, for one, would start Ghostscript)."""

MARGIN_CELLS = 10
"""Unknown cells written around the map's bounding box."""

OCCUPIED_PIXEL, FREE_PIXEL, UNKNOWN_PIXEL = 0, 254, 205
"""Grey values written for occupied, free and unknown cells (map_saver's trinary values)."""

WRITTEN_OCCUPIED_THRESH, WRITTEN_FREE_THRESH = 0.65, 0.196
"""Thresholds written with those values: 0 → p = 1, occupied; 254 → p = 0.004, free;
205 → p = 0.196078…, neither."""

DEFAULT_RESOLUTION_M = 0.05
"""Cell size ``map export`` writes unless told otherwise (nav2's usual 5 cm)."""

_REQUIRED_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")


@dataclass(frozen=True)
class GridHeader:
    """The YAML of a nav2 map: ``image`` the image's path (joined to the YAML's folder
    unless absolute, as map_server joins it); ``resolution_m`` the side of a cell;
    ``origin`` (x m, y m, yaw rad) of the bottom-left cell's outer corner in the world
    frame; ``negate``; the thresholds (0–1); ``mode`` one of ``OCCUPANCY_MODES``."""

    image: Path
    resolution_m: float
    origin: tuple[float, float, float]
    negate: bool
    occupied_thresh: float
    free_thresh: float
    mode: str


@dataclass(frozen=True)
class WrittenGrid:
    """What ``write_nav2`` wrote: the image beside the YAML, its size (columns, rows), the
    number of occupied cells, and the origin (x m, y m, yaw rad) written."""

    image: Path
    shape: tuple[int, int]
    occupied_cells: int
    origin: tuple[float, float, float]


# --- reading ------------------------------------------------------------------------------


def read_nav2(path: str | Path) -> FloorPlan:
    """Read a nav2 map (YAML and image) as segments (M, 4) in metres, world frame.

    See the module docstring for the rules. Raises ``InputError`` naming the file at fault
    when the YAML is over ``MAX_YAML_BYTES``, not valid YAML, lacks a key or holds a bad
    value (a threshold outside [0, 1], free_thresh not below occupied_thresh, a resolution
    ≤ 0, an origin that is not three finite numbers or whose yaw exceeds ``MAX_YAW_RAD``,
    an unknown mode), when the image is missing, not a regular file, not a PNG or PGM, larger
    than ``MAX_GRID_CELLS`` or reaching beyond ``MAX_COORDINATE_M``, or when no occupied
    cells make a segment. The image may lie anywhere (an absolute path, or ``..``), as
    map_server allows; the map's ``source`` and the run file name it.
    """
    path = Path(path)
    header = read_header(path)
    occupied = occupied_cells(header, path)
    res = header.resolution_m
    # Image row 0 is the map's top row; the grid's row 0 is at its origin.
    walls_grid = trace_walls(occupied[::-1], res)
    segments = transform_segments(walls_grid, Pose2(*header.origin))
    hint = f" (origin {list(header.origin)}, resolution {res:g} m); check the YAML"
    segments = checked_plan_segments(path, segments, hint)
    rows, columns = occupied.shape
    n_occupied = int(np.count_nonzero(occupied))
    kept = ExtractParams()
    if len(segments) == 0:
        found = f"{n_occupied} occupied cells" if n_occupied else "no occupied cells"
        raise InputError(
            f"{found} in {header.image.name} ({columns} × {rows} cells of {res:g} m) make no "
            f"wall of {kept.min_length_m:g} m or more; check resolution, negate and "
            "occupied_thresh",
            path=path,
        )
    source = {
        "format": "nav2",
        "plan": str(path),
        "image": str(header.image),
        "mode": header.mode,
        "resolution_m": res,
        "origin": list(header.origin),
        "negate": header.negate,
        "occupied_thresh": header.occupied_thresh,
        "free_thresh": header.free_thresh,
        "cells": [columns, rows],
        "occupied_cells": n_occupied,
        "split_m": SPLIT_CELLS * res,
        "min_length_m": kept.min_length_m,
    }
    summary = (
        f"traced from {n_occupied} occupied cells of {header.image.name} "
        f"({columns} × {rows} cells of {res:g} m)"
    )
    return FloorPlan(segments, source, 0, summary, also_read=(header.image,))


def read_header(path: Path) -> GridHeader:
    """The checked YAML of a nav2 map (see ``read_nav2`` for what is refused)."""
    document = _yaml_document(path)
    image = document["image"]
    if not isinstance(image, str) or not image.strip():
        raise InputError(f"`image` must name the map's image, got {_shown(image)}", path=path)
    resolution = _number(path, document, "resolution")
    if resolution <= 0:
        raise InputError(f"`resolution` must be more than 0 m, got {resolution:g}", path=path)
    origin = _checked_origin(path, document["origin"])
    occupied, free = _checked_thresholds(path, document)
    negate = document["negate"]
    if negate not in (0, 1):  # True and False are 1 and 0
        raise InputError(f"`negate` must be 0 or 1, got {_shown(negate)}", path=path)
    mode = document.get("mode", "trinary")
    if not isinstance(mode, str) or mode.lower() not in OCCUPANCY_MODES:
        modes = ", ".join(OCCUPANCY_MODES)
        raise InputError(f"`mode` must be one of {modes}, got {_shown(mode)}", path=path)
    return GridHeader(
        image=path.parent / image,
        resolution_m=resolution,
        origin=origin,
        negate=bool(negate),
        occupied_thresh=occupied,
        free_thresh=free,
        mode=mode.lower(),
    )


def _yaml_document(path: Path) -> dict:
    """The YAML at ``path`` as a mapping holding every one of ``_REQUIRED_KEYS`` (their
    values unchecked), or an ``InputError`` saying why it is not one."""
    import yaml

    with reading(path, "a nav2 map YAML"):
        if path.stat().st_size > MAX_YAML_BYTES:
            raise InputError(f"is over {MAX_YAML_BYTES:,} bytes; not a nav2 map YAML", path=path)
        text = path.read_text(encoding="utf-8")
    try:
        document = yaml.safe_load(text)
    except RecursionError:
        raise InputError("not a nav2 map YAML: nested too deep to read", path=path) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise InputError(f"not valid YAML{where}: {exc.problem}", path=path) from None
    except yaml.YAMLError as exc:
        raise InputError(f"not valid YAML: {' '.join(str(exc).split())}", path=path) from None
    if not isinstance(document, dict):
        raise InputError(
            f"not a nav2 map YAML: expected the keys {', '.join(_REQUIRED_KEYS)}", path=path
        )
    missing = [key for key in _REQUIRED_KEYS if key not in document]
    if missing:
        raise InputError(f"no `{'`, `'.join(missing)}` in this nav2 map YAML", path=path)
    return document


def _checked_origin(path: Path, origin: object) -> tuple[float, float, float]:
    """The YAML's ``origin`` as (x m, y m, yaw rad), each finite, the yaw within
    ±``MAX_YAW_RAD``."""
    if not (isinstance(origin, list) and len(origin) == 3):
        raise InputError(f"`origin` must be [x, y, yaw], got {_shown(origin)}", path=path)
    x, y, yaw = (_number(path, {"origin": v}, "origin") for v in origin)
    if abs(yaw) > MAX_YAW_RAD:
        raise InputError(
            f"`origin` yaw must lie within ±{MAX_YAW_RAD:.2f} rad, got {yaw:g}; "
            "map_server takes radians, not degrees",
            path=path,
        )
    return x, y, yaw


def _checked_thresholds(path: Path, document: dict) -> tuple[float, float]:
    """The YAML's ``occupied_thresh`` and ``free_thresh``, each in [0, 1], free below
    occupied."""
    occupied = _number(path, document, "occupied_thresh")
    free = _number(path, document, "free_thresh")
    for key, value in (("occupied_thresh", occupied), ("free_thresh", free)):
        if not 0.0 <= value <= 1.0:
            raise InputError(f"`{key}` must lie in [0, 1], got {value:g}", path=path)
    if free >= occupied:
        raise InputError(
            f"`free_thresh` ({free:g}) must be below `occupied_thresh` ({occupied:g})", path=path
        )
    return occupied, free


def occupied_cells(header: GridHeader, yaml_path: Path) -> np.ndarray:
    """Boolean (rows, columns), True where map_server would publish 100 (occupied); row 0 is
    the image's top row (largest y)."""
    shade, top, opaque = _load_image(header, yaml_path)
    level = np.arange(top + 1)
    if header.mode == "raw":
        # The percent as map_server takes it: the grey value on an 8-bit scale.
        return (np.rint(level * (255.0 / top)) == OCCUPIED)[shade]
    # One lookup per grey level: the comparison made as map_server makes it, in doubles.
    occupancy = level / top if header.negate else 1.0 - level / top
    occupied = (occupancy > header.occupied_thresh)[shade]
    return occupied if opaque is None else occupied & opaque


def _load_image(header: GridHeader, yaml_path: Path) -> tuple[np.ndarray, int, np.ndarray | None]:
    """The image's grey levels (rows, columns) as unsigned integers 0..top, that top, and
    where it is fully opaque (None when it has no alpha). Colour images give R + G + B (top
    765): map_server averages the channels. The image's size is checked from its header
    (``_check_size``) before any pixel is read."""
    from PIL import Image, UnidentifiedImageError

    image = header.image
    if not image.exists():
        raise InputError(f"its image {image} is not there; check `image`", path=yaml_path)
    named = f"named by {yaml_path.name}"
    with reading(image, "a PGM or PNG image"), image.open("rb") as stream:
        try:
            with _no_pillow_size_limit():
                picture = Image.open(stream, formats=IMAGE_FORMATS)  # reads the header alone
            with picture:
                _check_size(header, picture.size, yaml_path)
                picture.load()
                return _grey_levels(picture)
        except UnidentifiedImageError:
            raise InputError(
                f"not a readable PGM or PNG image (its bytes are neither; {named})", path=image
            ) from None
        except (OSError, SyntaxError, ValueError) as exc:
            # Truncated or corrupt data: OSErrors and ValueErrors of the decoder.
            text = " ".join(str(exc).split()) or type(exc).__name__
            raise InputError(
                f"not a readable PGM or PNG image ({text}; {named})", path=image
            ) from None


@contextlib.contextmanager
def _no_pillow_size_limit() -> Iterator[None]:
    """Pillow's own limit on pixels lifted while an image is opened (which reads its header
    alone), ``_check_size`` taking its place before the pixels are loaded: Pillow's (89
    million pixels, refusing outright at twice that) neither matches ``MAX_GRID_CELLS`` nor
    says the size."""
    from PIL import Image

    limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
    try:
        yield
    finally:
        Image.MAX_IMAGE_PIXELS = limit


def _check_size(header: GridHeader, size: tuple[int, int], yaml_path: Path) -> None:
    """Refuse an image (columns, rows) of more than ``MAX_GRID_CELLS`` cells, or whose cells,
    placed by the YAML's origin and resolution, reach beyond ``MAX_COORDINATE_M``."""
    columns, rows = size
    if columns * rows > MAX_GRID_CELLS:
        raise InputError(
            f"image is {columns} × {rows} pixels, more than {MAX_GRID_CELLS:,} cells (named "
            f"by {yaml_path.name}); crop or coarsen the grid",
            path=header.image,
        )
    x, y, _ = header.origin
    reach_m = max(abs(x), abs(y)) + math.hypot(columns, rows) * header.resolution_m
    if not reach_m <= MAX_COORDINATE_M:
        raise InputError(
            f"its {columns} × {rows} cells of {header.resolution_m:g} m from origin ({x:g}, "
            f"{y:g}) reach beyond ±{MAX_COORDINATE_M:g} m; check `resolution` and `origin`",
            path=yaml_path,
        )


def _grey_levels(picture) -> tuple[np.ndarray, int, np.ndarray | None]:
    """``_load_image``'s result for an open Pillow image."""
    mode = picture.mode
    if mode == "P":
        picture = picture.convert("RGBA" if "transparency" in picture.info else "RGB")
        mode = picture.mode
    if mode in ("1", "L"):
        return np.asarray(picture.convert("L"), dtype=np.uint8), 255, None
    if mode in ("I;16", "I;16B", "I;16L", "I"):
        levels = np.asarray(picture)
        if levels.size and (levels.min() < 0 or levels.max() > 65535):
            raise ValueError(f"grey values outside 0..65535 in {with_article(mode)} image")
        return levels.astype(np.uint16), 65535, None
    if mode == "LA":
        grey, alpha = (np.asarray(band, dtype=np.uint8) for band in picture.split())
        return grey, 255, alpha == 255
    if mode not in ("RGB", "RGBA"):
        picture = picture.convert("RGB")
    channels = np.asarray(picture, dtype=np.uint8)
    opaque = channels[..., 3] == 255 if picture.mode == "RGBA" else None
    return channels[..., :3].sum(axis=2, dtype=np.uint16), 765, opaque


def _number(path: Path, document: dict, key: str) -> float:
    """``document[key]`` as a finite float (a YAML number, or a string holding one)."""
    value = document[key]
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(f"`{key}` must be a finite number, got {_shown(value)}", path=path)
    return float(value)


def _shown(value) -> str:
    """A value of the YAML as an error message quotes it, on one line, at most 60 characters:
    a few items, two levels deep, so that a document whose aliases nest a billion items (the
    YAML "billion laughs") is never spelt out."""
    quoting = reprlib.Repr()
    quoting.maxlevel, quoting.maxlist, quoting.maxdict = 2, 4, 4
    quoting.maxstring = quoting.maxother = 40
    text = " ".join(quoting.repr(value).split())
    return text if len(text) <= 60 else text[:57] + "..."


# --- writing ------------------------------------------------------------------------------


def write_nav2(
    path: str | Path, segments_world: np.ndarray, resolution_m: float = DEFAULT_RESOLUTION_M
) -> WrittenGrid:
    """Write segments (M, 4), metres, world frame, as a nav2 map: the YAML at ``path`` and a
    PGM of the same name beside it, replaced together or not at all (``atomic_paths``).

    Cells of ``resolution_m`` metres; see the module docstring for what is occupied, free
    and unknown. Raises ``InputError`` naming ``path`` when the grid would hold more than
    ``MAX_GRID_CELLS`` cells.
    """
    import yaml
    from PIL import Image

    path = Path(path)
    segments = np.asarray(segments_world, dtype=float).reshape(-1, 4)
    ends = segments.reshape(-1, 2)
    # Lattice offsets (cells) with the cell centres on the integers: the origin is a whole
    # number of cells plus the phase, written to the micrometre.
    phase = lattice_phase(segments, resolution_m)
    low = np.floor(ends.min(axis=0) / resolution_m - phase) - MARGIN_CELLS
    high = np.floor(ends.max(axis=0) / resolution_m - phase) + MARGIN_CELLS
    columns, rows = (int(n) for n in high - low + 1)
    if columns * rows > MAX_GRID_CELLS:
        raise InputError(
            f"a grid of {resolution_m:g} m cells over this map would be {columns} × {rows} "
            f"cells, more than {MAX_GRID_CELLS:,}; choose a coarser --resolution",
            path=path,
        )
    corner = (low + phase - 0.5) * resolution_m
    origin = (round(float(corner[0]), 6), round(float(corner[1]), 6), 0.0)
    image = np.full((rows, columns), UNKNOWN_PIXEL, dtype=np.uint8)
    image[MARGIN_CELLS : rows - MARGIN_CELLS, MARGIN_CELLS : columns - MARGIN_CELLS] = FREE_PIXEL
    column, row = line_cells(segments - np.tile(origin[:2], 2), resolution_m)
    image[rows - 1 - row, column] = OCCUPIED_PIXEL
    image_path = path.with_suffix(".pgm")
    header = {
        "image": image_path.name,
        "mode": "trinary",
        "resolution": float(resolution_m),
        "origin": list(origin),
        "negate": 0,
        "occupied_thresh": WRITTEN_OCCUPIED_THRESH,
        "free_thresh": WRITTEN_FREE_THRESH,
    }
    text = yaml.safe_dump(header, sort_keys=False, default_flow_style=None)
    comment = (
        "# segloc map: walls occupied (0), free inside the map's bounding box (254), "
        f"unknown in the {MARGIN_CELLS}-cell margin beyond it (205)\n"
    )
    # Replaced as a pair: an old YAML over a new image would read it at the old resolution.
    with atomic_paths(image_path, path) as (image_partial, yaml_partial):
        with writing(image_path):
            Image.fromarray(image, mode="L").save(image_partial, format="PPM")
        with writing(path):
            yaml_partial.write_text(comment + text, encoding="utf-8")
    occupied = int(np.count_nonzero(image == OCCUPIED_PIXEL))
    return WrittenGrid(image_path, (columns, rows), occupied, origin)


def lattice_phase(segments_world: np.ndarray, resolution_m: float) -> np.ndarray:
    """Where (x, y) the cell centres of a grid of ``resolution_m`` cells best sit for the
    segments (M, 4), metres, world frame: as fractions of a cell in [0, 1), cell centres
    lying at (k + phase)·resolution.

    A wall along a grid axis comes back from the grid at its cells' centres, up to half a
    cell from where it was drawn. Taking, for each axis, the circular mean (weighted by
    length) of the offsets of the walls within one cell of that axis puts the centres on
    them: a plan drawn to round measures comes back without the shift a fixed lattice
    would give it. Without such walls the phase is 0.
    """
    segments = np.asarray(segments_world, dtype=float).reshape(-1, 4)
    spans = np.abs(segments[:, 2:] - segments[:, :2])
    phase = np.zeros(2)
    for axis in (0, 1):
        # Walls along the other axis: within one column (axis 0) or one row (axis 1).
        along = spans[:, axis] < 0.5 * resolution_m
        middle = 0.5 * (segments[along, axis] + segments[along, axis + 2]) / resolution_m
        turn = 2.0 * np.pi * (middle % 1.0)
        weight = spans[along, 1 - axis]
        if weight.sum() > 0:
            angle = np.arctan2(np.sum(weight * np.sin(turn)), np.sum(weight * np.cos(turn)))
            phase[axis] = (angle / (2.0 * np.pi)) % 1.0
    return phase
