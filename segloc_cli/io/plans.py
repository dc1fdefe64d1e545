"""Building plans as segment maps: DXF drawings in and out, through ezdxf; the plan type
every plan reader returns (``Plan``; SVG drawings are in ``svg``, nav2 grids in ``grids``).

A plan's walls are its straight lines. Reading a DXF takes, from the model space (or the
layers asked for), every ``LINE``, every piece of a ``LWPOLYLINE`` or 2D ``POLYLINE``
(closed ones back to their first vertex; an arc piece, drawn with a bulge, as its straight
chord) and the same inside block references (``INSERT``, placed as drawn). Coordinates are
scaled to metres by the drawing's ``$INSUNITS``, or by the units the caller gives when the
drawing does not say (``$INSUNITS`` missing or 0). The plan's x and y are the map's; z is
dropped. Pieces shorter than ``MIN_SEGMENT_LENGTH_M`` are left out.

Writing puts each map segment as a ``LINE`` on layer ``SEGLOC_LAYER``, in metres
(``$INSUNITS`` 6), so that a CAD program shows the map at its true size and reading the
file back gives the same segments.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.geometry import segment_lengths
from segloc_cli.io.files import atomic_path, reading
from segloc_cli.io.maps import MAX_COORDINATE_M, MIN_SEGMENT_LENGTH_M

UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
"""Units a caller can give for a drawing that does not say its own, in metres."""

_INSUNITS_M = {1: 0.0254, 2: 0.3048, 4: 0.001, 5: 0.01, 6: 1.0, 14: 0.1, 3: 1609.344, 7: 1000.0}
"""Metres per drawing unit for the DXF ``$INSUNITS`` codes a building plan uses (inches,
feet, millimetres, centimetres, metres, decimetres; miles and kilometres for completeness)."""

SEGLOC_LAYER = "segloc-map"
"""The layer ``write_dxf`` draws the map on."""

MAX_INSERT_DEPTH = 16
"""Block references nested deeper than this are not followed (a block that holds itself)."""


@dataclass(frozen=True)
class Plan:
    """What a plan reader made of a file.

    ``segments`` (M, 4) metres, world frame; ``source`` the record of what was read, for
    the map file's ``source`` (JSON-serialisable, its ``format`` first); ``chords`` how
    many curved pieces were taken as straight chords; ``summary`` a phrase saying where
    the segments came from ("from layer(s) WALLS (1 drawing unit = 0.001 m)");
    ``also_read`` the other files it was read from (a grid's image), for the run file.
    """

    segments: np.ndarray
    source: dict
    chords: int = 0
    summary: str = ""
    also_read: tuple[Path, ...] = ()


def checked_plan_segments(path: Path, pieces_m: np.ndarray, hint: str) -> np.ndarray:
    """Pieces (M, 4) in metres, less those shorter than ``MIN_SEGMENT_LENGTH_M``.

    Raises ``InputError`` naming ``path`` when a coordinate is not finite or lies beyond
    ``MAX_COORDINATE_M``; ``hint`` ends that message (the scale applied, the option to check).
    """
    segments = np.asarray(pieces_m, dtype=float).reshape(-1, 4)
    if not np.all(np.isfinite(segments)) or np.any(np.abs(segments) > MAX_COORDINATE_M):
        raise InputError(
            f"a line lies beyond ±{MAX_COORDINATE_M:g} m once in metres{hint}", path=path
        )
    return segments[segment_lengths(segments) >= MIN_SEGMENT_LENGTH_M]


def read_dxf(path: str | Path, layers: Sequence[str] = (), units: str | None = None) -> Plan:
    """Read the walls of a DXF plan as segments (M, 4) in metres (see the module docstring).

    ``layers`` limits the reading to those layers (all by default); ``units`` (a key of
    ``UNITS_M``) is the drawing's unit when ``$INSUNITS`` does not give one. Raises
    ``InputError`` naming the file when it is not a readable DXF, gives no units and none
    were given, asks for a layer it lacks, holds no straight line on the layers read, or
    places a point beyond ``MAX_COORDINATE_M``.
    """
    import ezdxf
    from ezdxf import recover

    path = Path(path)
    with reading(path, "a DXF drawing"):
        try:
            doc, _ = recover.readfile(str(path))
        except ezdxf.DXFStructureError as exc:
            raise InputError(f"not a readable DXF drawing ({exc})", path=path) from None
    scale = _metres_per_unit(path, doc.header.get("$INSUNITS", 0), units)
    known = sorted(layer.dxf.name for layer in doc.layers)
    unknown = [name for name in layers if name not in known]
    if unknown:
        raise InputError(
            f"no layer {', '.join(map(repr, unknown))} in the drawing; its layers are "
            f"{', '.join(known)}",
            path=path,
        )
    wanted = set(layers)
    pieces: list[tuple[float, float, float, float]] = []
    chords = 0
    found_layers: set[str] = set()
    for entity in _flattened(doc.modelspace(), 0):
        layer = entity.dxf.layer
        if wanted and layer not in wanted:
            continue
        drawn, arcs = _entity_pieces(entity)
        pieces.extend(drawn)
        chords += arcs
        if drawn:
            found_layers.add(layer)
    pieces_m = np.array(pieces, dtype=float).reshape(-1, 4) * scale
    segments = checked_plan_segments(path, pieces_m, f" (×{scale:g}); check --units")
    if len(segments) == 0:
        where = f"on layer(s) {', '.join(layers)}" if layers else "in its model space"
        raise InputError(
            f"no LINE, LWPOLYLINE or POLYLINE {where}; its layers are {', '.join(known)}",
            path=path,
        )
    read_layers = sorted(found_layers)
    source = {"format": "dxf", "plan": str(path), "layers": read_layers, "metres_per_unit": scale}
    summary = f"from layer(s) {', '.join(read_layers)} (1 drawing unit = {scale:g} m)"
    return Plan(segments, source, chords, summary)


def write_dxf(path: str | Path, segments_world: np.ndarray) -> None:
    """Write segments (M, 4), metres, as LINEs of a DXF drawing in metres, atomically."""
    import ezdxf

    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = 6
    doc.layers.add(SEGLOC_LAYER)
    space = doc.modelspace()
    for x1, y1, x2, y2 in np.asarray(segments_world, dtype=float).reshape(-1, 4).tolist():
        space.add_line((x1, y1), (x2, y2), dxfattribs={"layer": SEGLOC_LAYER})
    with atomic_path(Path(path)) as partial:
        doc.saveas(partial)


def _metres_per_unit(path: Path, insunits: object, units: str | None) -> float:
    code = int(insunits) if isinstance(insunits, int | float) and math.isfinite(insunits) else 0
    if code in _INSUNITS_M:
        return _INSUNITS_M[code]
    if units is not None:
        return UNITS_M[units]
    said = "gives no $INSUNITS" if code == 0 else f"has $INSUNITS {code}, not a length unit"
    raise InputError(
        f"the drawing {said}; give its unit with --units ({', '.join(UNITS_M)})", path=path
    )


def _flattened(entities: Iterable, depth: int) -> Iterable:
    """The entities, with each block reference replaced by what it draws, where it draws it."""
    for entity in entities:
        if entity.dxftype() == "INSERT":
            if depth < MAX_INSERT_DEPTH:
                yield from _flattened(entity.virtual_entities(), depth + 1)
        else:
            yield entity


def _entity_pieces(entity) -> tuple[list[tuple[float, float, float, float]], int]:
    """The straight pieces (x1, y1, x2, y2), drawing units, of a LINE or a 2D polyline, and
    how many of them stand for arcs (bulged pieces, taken as chords)."""
    kind = entity.dxftype()
    if kind == "LINE":
        start, end = entity.dxf.start, entity.dxf.end
        return [(start.x, start.y, end.x, end.y)], 0
    if kind == "LWPOLYLINE":
        points = [(x, y, bulge) for x, y, _, _, bulge in entity.get_points("xyseb")]
        closed = entity.closed
    elif kind == "POLYLINE" and entity.is_2d_polyline:
        points = [
            (v.dxf.location.x, v.dxf.location.y, v.dxf.get("bulge", 0.0)) for v in entity.vertices
        ]
        closed = entity.is_closed
    else:
        return [], 0
    if closed and len(points) > 2:
        points = [*points, points[0]]
    pairs = list(itertools.pairwise(points))
    pieces = [(x1, y1, x2, y2) for (x1, y1, _), (x2, y2, _) in pairs]
    return pieces, sum(1 for (_, _, bulge), _ in pairs if bulge)
