"""Building plans as segment maps: DXF drawings in and out, through ezdxf; the plan type
every plan reader returns (``FloorPlan``; SVG drawings are in ``svg``, nav2 grids in ``grids``).

A plan's walls are its lines and curves. Reading a DXF takes, from the model space (or the
layers asked for), every ``LINE``, every piece of a ``LWPOLYLINE`` or 2D ``POLYLINE``
(closed ones back to their first vertex), every ``ARC``, ``CIRCLE``, ``ELLIPSE`` and
``SPLINE``, and the same inside block references (``INSERT``, placed as drawn, every copy of
a ``MINSERT`` array). References are counted before any is placed: a block that holds a
reference to itself, references nested more than ``MAX_INSERT_DEPTH`` deep or placing more
than ``MAX_PLACED_ENTITIES`` entities refuse the drawing. A curve (an arc piece of a
polyline, drawn with a bulge, included) becomes straight chords, as few as keep each within
``CHORD_SAGITTA_M`` of it once in metres, through ezdxf's flattening.
Coordinates are scaled to metres by the drawing's ``$INSUNITS``, or by the units the caller
gives when the drawing does not say (``$INSUNITS`` missing or 0). The plan's x and y are
the map's (world coordinates, the entities' own planes applied); z is dropped. Pieces
shorter than ``MIN_SEGMENT_LENGTH_M`` are left out.

Writing puts each map segment as a ``LINE`` on layer ``SEGLOC_LAYER``, in metres
(``$INSUNITS`` 6), so that a CAD program shows the map at its true size and reading the
file back gives the same segments.
"""

from __future__ import annotations

import itertools
import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.geometry import segment_lengths
from segloc_cli.io.files import atomic_path, reading
from segloc_cli.io.maps import MIN_SEGMENT_LENGTH_M
from segloc_cli.limits import MAX_COORDINATE_M
from segloc_cli.wording import counted, plural

UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
"""Units a caller can give for a drawing that does not say its own, in metres."""

_INSUNITS_M = {1: 0.0254, 2: 0.3048, 4: 0.001, 5: 0.01, 6: 1.0, 14: 0.1, 3: 1609.344, 7: 1000.0}
"""Metres per drawing unit for the DXF ``$INSUNITS`` codes a building plan uses (inches,
feet, millimetres, centimetres, metres, decimetres; miles and kilometres for completeness)."""

SEGLOC_LAYER = "segloc-map"
"""The layer ``write_dxf`` draws the map on."""

MAX_INSERT_DEPTH = 16
"""Most levels of block references inside one another; a drawing nesting them deeper is
refused, as is a block that holds a reference to itself (directly or through others)."""

MAX_PLACED_ENTITIES = 250_000
"""Most entities the block references of a drawing may place, every copy of a ``MINSERT``
array counted: each costs ezdxf about 0.1 ms to place, so this bounds the reading to about
half a minute, where nested references could otherwise multiply a small file into billions."""

CHORD_SAGITTA_M = 0.01
"""Largest distance (m) between a DXF curve and the chords that stand for it (their sagitta):
below a scanner's range noise (1.2 cm in ``segloc simulate``), so a wall drawn as an arc is
no farther from its chords than a scan's points are from the wall."""

CURVES = ("ARC", "CIRCLE", "ELLIPSE", "SPLINE")
"""DXF curves read as chords (a polyline's bulged pieces come as ARCs)."""

DXF_ENTITIES = "LINE, LWPOLYLINE, POLYLINE, ARC, CIRCLE, ELLIPSE or SPLINE"
"""What a DXF plan's walls are read from, as the messages name it."""


@dataclass(frozen=True)
class FloorPlan:
    """What a plan reader made of a file.

    ``segments`` (M, 4) metres, world frame; ``source`` the record of what was read, for
    the map file's ``source`` (JSON-serialisable, its ``format`` first); ``chords`` how
    many of the segments are straight chords standing for curves; ``summary`` a phrase
    saying where the segments came from ("from layer WALLS (1 drawing unit = 0.001 m)");
    ``also_read`` the other files it was read from (a grid's image), for the run file;
    ``warnings`` lines for the user on what was approximated or not found.
    """

    segments: np.ndarray
    source: dict
    chords: int = 0
    summary: str = ""
    also_read: tuple[Path, ...] = ()
    warnings: tuple[str, ...] = ()


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


def read_dxf(path: str | Path, layers: Sequence[str] = (), units: str | None = None) -> FloorPlan:
    """Read the walls of a DXF plan as segments (M, 4) in metres (see the module docstring).

    ``layers`` limits the reading to those layers (all by default); ``units`` (a key of
    ``UNITS_M``) is the drawing's unit when ``$INSUNITS`` does not give one. The plan's
    ``warnings`` count the curves taken as chords and name the layers asked for that gave
    nothing. Raises ``InputError`` naming the file when it is not a readable DXF, gives no
    units and none were given, asks for a layer it lacks, holds nothing ``DXF_ENTITIES``
    names on the layers read, holds a curve that cannot be followed, or places a point
    beyond ``MAX_COORDINATE_M``.
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
    _BlockCensus(path, doc).check(doc.modelspace())
    entities = list(_flattened(doc.modelspace()))
    # A layer that entities name but the LAYER table lacks (minimal writers leave the table
    # out) exists all the same, as it does for a CAD program.
    known = sorted({layer.dxf.name for layer in doc.layers} | {e.dxf.layer for e in entities})
    unknown = [name for name in layers if name not in known]
    if unknown:
        raise InputError(
            f"no layer {', '.join(map(repr, unknown))} in the drawing; its layers are "
            f"{', '.join(known)}",
            path=path,
        )
    wanted = set(layers)
    read = _DxfReading(path, scale)
    for entity in entities:
        if not wanted or entity.dxf.layer in wanted:
            read.add(entity)
    pieces_m = np.array(read.pieces, dtype=float).reshape(-1, 4) * scale
    segments = checked_plan_segments(path, pieces_m, f" (×{scale:g}); check --units")
    if len(segments) == 0:
        where = (
            f"on {plural(len(layers), 'layer')} {', '.join(layers)}"
            if layers
            else "in its model space"
        )
        raise InputError(f"no {DXF_ENTITIES} {where}; its layers are {', '.join(known)}", path=path)
    read_layers = sorted(read.layers)
    source = {"format": "dxf", "plan": str(path), "layers": read_layers, "metres_per_unit": scale}
    summary = (
        f"from {plural(len(read_layers), 'layer')} {', '.join(read_layers)} "
        f"(1 drawing unit = {scale:g} m)"
    )
    empty = [name for name in layers if name not in read.layers]
    warnings = [read.chords_warning()] if read.chords else []
    if empty:
        layers_read = f"{plural(len(empty), 'layer')} {', '.join(empty)}"
        warnings.append(f"nothing read from {layers_read}: no {DXF_ENTITIES} there")
    return FloorPlan(segments, source, read.chords, summary, warnings=tuple(warnings))


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


def _flattened(entities: Iterable) -> Iterable:
    """The entities, with each block reference replaced by what it draws, where it draws it
    (every copy of a ``MINSERT`` array). ``_BlockCensus.count`` must have passed them."""
    for entity in entities:
        if entity.dxftype() != "INSERT":
            yield entity
            continue
        for placed in entity.multi_insert() if entity.mcount > 1 else (entity,):
            yield from _flattened(placed.virtual_entities())


class _BlockCensus:
    """How many entities the block references of a drawing place, found before any is placed;
    ``InputError`` for references that cannot be followed (see ``count``). A reference to a
    block the drawing lacks places nothing (ezdxf's recovery drops such references)."""

    def __init__(self, path: Path, doc):
        self.path = path
        self.doc = doc
        self._blocks: dict[str, tuple[int, int]] = {}  # by upper-case name: placed, levels

    def check(self, layout: Iterable) -> None:
        """Raise ``InputError`` naming the file when the references of ``layout`` (the model
        space) reach a block that holds a reference to itself, nest deeper than
        ``MAX_INSERT_DEPTH`` or place more than ``MAX_PLACED_ENTITIES`` entities in all."""
        self._contents(layout, ())

    def _contents(self, entities: Iterable, chain: tuple[str, ...]) -> tuple[int, int]:
        """Entities placed by ``entities`` inside the blocks ``chain`` (outermost first), and
        the levels of references they nest (0: none)."""
        placed = levels = 0
        for entity in entities:
            if entity.dxftype() != "INSERT":
                placed += bool(chain)  # the model space's own entities are not placed
                continue
            inner, depth = self._block(str(entity.dxf.get("name", "")), chain)
            placed += max(entity.mcount, 1) * inner
            levels = max(levels, depth)
            if placed > MAX_PLACED_ENTITIES:
                raise self._refusal(
                    f"its block references place more than {MAX_PLACED_ENTITIES:,} entities "
                    f"(block {self._path_text((*chain, entity.dxf.get('name', '')))}); "
                    "explode or purge the repeated blocks in the CAD program"
                )
        return placed, levels

    def _block(self, name: str, chain: tuple[str, ...]) -> tuple[int, int]:
        """Entities one reference to block ``name`` places from inside ``chain``, and the
        levels of references it nests, itself included."""
        key = name.upper()
        above = [c.upper() for c in chain]
        if key in above:
            cycle = self._path_text((*chain[above.index(key) :], name))
            raise self._refusal(
                f"block {name} holds a reference to itself ({cycle}), so it has no end; fix "
                "the block in the CAD program"
            )
        if key not in self._blocks:
            if len(chain) >= MAX_INSERT_DEPTH:
                raise self._refusal(
                    f"block references nest more than {MAX_INSERT_DEPTH} levels deep "
                    f"({self._path_text((*chain, name))}); explode the outer blocks in the "
                    "CAD program"
                )
            block = self.doc.blocks.get(name)
            inner, levels = (0, 0) if block is None else self._contents(block, (*chain, name))
            self._blocks[key] = (inner, levels + 1)
        placed, levels = self._blocks[key]
        if len(chain) + levels > MAX_INSERT_DEPTH:
            raise self._refusal(
                f"block references nest more than {MAX_INSERT_DEPTH} levels deep "
                f"({self._path_text((*chain, name))} and {levels - 1} more inside it); "
                "explode the outer blocks in the CAD program"
            )
        return placed, levels

    @staticmethod
    def _path_text(chain: Sequence[str]) -> str:
        """Block names joined by arrows, the middle of a long chain left out."""
        names = list(chain)
        if len(names) > 6:
            names = [*names[:3], "…", *names[-2:]]
        return " → ".join(names)

    def _refusal(self, message: str) -> InputError:
        return InputError(message, path=self.path)


class _DxfReading:
    """The straight pieces (x1, y1, x2, y2), drawing units, of the entities read so far; how
    many of them are chords of curves, the curves by kind, and the layers that gave any."""

    def __init__(self, path: Path, metres_per_unit: float):
        self.path = path
        self.metres_per_unit = metres_per_unit
        self.pieces: list[tuple[float, float, float, float]] = []
        self.chords = 0
        self.curves: Counter[str] = Counter()
        self.layers: set[str] = set()

    def add(self, entity) -> None:
        """Add a LINE, a 2D polyline (as its LINE and ARC pieces) or a curve; skip others."""
        kind = entity.dxftype()
        polyline = kind == "LWPOLYLINE" or (kind == "POLYLINE" and entity.is_2d_polyline)
        before = len(self.pieces)
        for part in entity.virtual_entities() if polyline else (entity,):
            if part.dxftype() == "LINE":
                start, end = part.dxf.start, part.dxf.end
                self.pieces.append((start.x, start.y, end.x, end.y))
            elif part.dxftype() in CURVES:
                chords = self._chords(part)
                self.pieces.extend(chords)
                self.chords += len(chords)
                self.curves[f"{kind} bulge" if polyline else kind] += bool(chords)
        if len(self.pieces) > before:
            self.layers.add(entity.dxf.layer)

    def chords_warning(self) -> str:
        """One line on the curves taken as chords: how many of each kind, how many chords."""
        total = sum(self.curves.values())
        kinds = ", ".join(f"{kind} {n}" for kind, n in sorted(self.curves.items()))
        return (
            f"{counted(total, 'curve')} ({kinds}) taken as "
            f"{counted(self.chords, 'straight chord')}, each within {CHORD_SAGITTA_M * 100:g} cm "
            "of its curve"
        )

    def _chords(self, curve) -> list[tuple[float, float, float, float]]:
        """The chords (drawing units) of an ARC, CIRCLE, ELLIPSE or SPLINE, each within
        ``CHORD_SAGITTA_M`` of it in metres; ``InputError`` for one that cannot be followed
        or reaches beyond ``MAX_COORDINATE_M``."""
        import ezdxf
        from ezdxf import bbox

        name = f"{curve.dxftype()} {curve.dxf.handle} on layer {curve.dxf.layer}"
        try:
            extent = bbox.extents([curve], fast=True)
            reach = max(map(abs, (*extent.extmin, *extent.extmax))) if extent.has_data else 0.0
            # Checked before flattening: a curve larger than any map would be cut into more
            # chords than memory holds. (InputError is none of the errors caught below.)
            if not (math.isfinite(reach) and reach * self.metres_per_unit <= MAX_COORDINATE_M):
                raise InputError(
                    f"the {name} lies beyond ±{MAX_COORDINATE_M:g} m once in metres "
                    f"(×{self.metres_per_unit:g}); check --units",
                    path=self.path,
                )
            points = list(curve.flattening(CHORD_SAGITTA_M / self.metres_per_unit))
        except (ValueError, ArithmeticError, ezdxf.DXFError) as exc:
            raise InputError(f"cannot follow the {name} ({exc})", path=self.path) from None
        return [(a.x, a.y, b.x, b.y) for a, b in itertools.pairwise(points)]
