"""SVG drawings as segment maps, in and out, through svgelements.

Reading takes every ``line``, ``polyline``, ``polygon``, ``rect`` and ``path`` of the drawing
(those in ``defs`` or a ``symbol`` only where a ``use`` places them; the content of a
``marker``, ``mask``, ``clipPath`` or ``pattern`` never, as segloc applies none of them),
with the transforms of their groups and their own applied, as straight pieces: a path's
curves (cubic and quadratic Béziers, elliptical arcs, a rect's rounded corners) are taken as
their chords, and counted. Other elements (``circle``, ``ellipse``, ``text``, ``image``) are
left out.

Coordinates are in the drawing's user units: those of the outermost ``svg`` element, its
``viewBox`` if it has one. A point (u, v) of the drawing lands on the map at
``(X + s·u, Y − s·v)`` metres: ``s`` metres per user unit, ``(X, Y)`` where the drawing's
origin lands, and the drawing's y, which grows downwards, flipped to the map's, which grows
upwards. ``s`` is given, or follows from the drawing's own size when its ``width`` and
``height`` carry an absolute unit (mm, cm, in, pt, pc, Q or px at 96 per inch) that its
``viewBox`` divides evenly; ``100%`` or unitless sizes say nothing physical.

The drawing is vetted before svgelements sees it, so that no file can make the reading
touch another file or swell without bound: the XML is parsed by defusedxml, which refuses
any entity declared in a DOCTYPE (nested entities, the "billion laughs", expand a few lines
into gigabytes; an external one names another file to read), and elements nested deeper than
``MAX_SVG_DEPTH``, a ``use`` that places an element inside itself, or more than
``MAX_SVG_ELEMENTS`` elements once every ``use`` is expanded refuse the drawing.

Writing draws each segment as a ``line`` in millimetre user units (``width`` and
``height`` in mm matching the ``viewBox``), the map's y flipped: reading the file back with
no options gives the map again, to within the rounding of the millimetre-to-metre
conversion (a few parts in 10¹⁶).
"""

from __future__ import annotations

import io
import math
import re
from pathlib import Path
from xml.etree.ElementTree import Element, ParseError, tostring

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.io.files import reading, write_text_atomic
from segloc_cli.io.plans import FloorPlan, checked_plan_segments

LENGTH_UNITS_M = {
    "mm": 0.001,
    "cm": 0.01,
    "q": 0.00025,
    "in": 0.0254,
    "pt": 0.0254 / 72.0,
    "pc": 0.0254 / 6.0,
    "px": 0.0254 / 96.0,
}
"""Metres per unit of the absolute CSS lengths an SVG's size may be given in."""

MARGIN_MM = 500.0
"""Blank drawing written around the map's bounding box, in millimetres (0.5 m)."""

STROKE_MM = 20.0
"""Width of the lines written (2 cm on the floor): visible at a plan's usual zoom."""

MAX_SVG_DEPTH = 256
"""Most levels of elements inside one another, those a ``use`` places counted where it places
them: svgelements follows them by recursion, which Python stops near 1,000."""

MAX_SVG_ELEMENTS = 250_000
"""Most elements in a drawing once every ``use`` is expanded: each costs svgelements about
60 µs, so this bounds the reading to about 15 s, where ``use`` elements placing groups of
``use`` elements could otherwise multiply a small file into billions."""

TEMPLATES = ("symbol", "marker", "mask")
"""Elements an SVG renderer never draws by themselves: their content is drawn only where
something refers to them (a ``use`` placing a ``symbol``; a marker or mask, which segloc does
not apply, draws no walls)."""

_HREFS = ("href", "{http://www.w3.org/1999/xlink}href")
"""Attributes through which a ``use`` names what it places (svgelements prefers ``href``)."""

_SVG_ERRORS = (ArithmeticError, AttributeError, LookupError, TypeError, ValueError)
"""What svgelements raises on attribute values it cannot make sense of."""

_SIZE = re.compile(r"^\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*([a-zA-Z%]*)\s*$")


def read_svg(
    path: str | Path, scale_m: float | None = None, origin_m: tuple[float, float] = (0.0, 0.0)
) -> FloorPlan:
    """Read the walls of an SVG drawing as segments (M, 4) in metres, world frame.

    ``scale_m`` is metres per user unit (None: from the drawing's size, see the module
    docstring); ``origin_m`` (X, Y) where the drawing's origin lands. Raises ``InputError``
    naming the file when the scale is not a positive number or cannot be found, the
    origin is not finite, the file is not well-formed XML or not an SVG, it holds no line,
    polyline, polygon, rect or path, or a point lands beyond ``MAX_COORDINATE_M``.
    """
    import svgelements as se

    path = Path(path)
    if scale_m is not None and not (math.isfinite(scale_m) and scale_m > 0):
        raise InputError(
            f"--scale must be a positive number of metres per SVG unit, got {scale_m:g}",
            path=path,
        )
    if not all(math.isfinite(v) for v in origin_m):
        raise InputError(f"--origin must be two finite numbers, got {origin_m}", path=path)
    with reading(path, "an SVG drawing"):
        data = path.read_bytes()
    root = _vetted_xml(path, data)
    _check_structure(path, root)
    if _hide_templates(root):
        data = tostring(root)
    try:
        drawing = se.SVG.parse(io.BytesIO(data), reify=True)
    except _SVG_ERRORS as exc:
        raise _unreadable(path, exc) from None
    if not isinstance(drawing, se.SVG):
        raise InputError("not an SVG drawing: its outermost element is not <svg>", path=path)
    to_user = _to_user_units(path, drawing, se)
    scale_from = "--scale"
    if scale_m is None:
        scale_m = _drawing_scale(path, drawing)
        scale_from = "width, height and viewBox"
    try:
        pieces, chords, shapes = _pieces_in_user_units(drawing, to_user, se)
    except _SVG_ERRORS as exc:
        raise _unreadable(path, exc) from None
    x0, y0 = (float(v) for v in origin_m)
    placed = np.array([x0, y0, x0, y0]) + scale_m * pieces * np.array([1.0, -1.0, 1.0, -1.0])
    segments = checked_plan_segments(path, placed, f" (×{scale_m:g}); check --scale and --origin")
    if len(segments) == 0:
        raise InputError(
            "no line, polyline, polygon, rect or path in the drawing (circles, ellipses and "
            "text are not read)",
            path=path,
        )
    source = {
        "format": "svg",
        "plan": str(path),
        "metres_per_unit": scale_m,
        "scale_from": scale_from,
        "origin_m": [x0, y0],
        "elements": shapes,
    }
    summary = f"from {shapes} elements (1 SVG unit = {scale_m:g} m, origin at {x0:g}, {y0:g})"
    warnings = (f"{chords} arc or curve pieces taken as straight chords",) if chords else ()
    return FloorPlan(segments, source, chords, summary, warnings=warnings)


def write_svg(path: str | Path, segments_world: np.ndarray) -> None:
    """Write segments (M, 4), metres, world frame, as ``line`` elements of an SVG drawing in
    millimetres (see the module docstring), atomically."""
    segments = np.asarray(segments_world, dtype=float).reshape(-1, 4)
    drawn = segments * np.array([1000.0, -1000.0, 1000.0, -1000.0])
    ends = drawn.reshape(-1, 2)
    low_x, low_y = (float(v) for v in ends.min(axis=0) - MARGIN_MM)
    width, height = (float(v) for v in ends.max(axis=0) + MARGIN_MM - (low_x, low_y))
    lines = "".join(
        f'<line x1="{x1!r}" y1="{y1!r}" x2="{x2!r}" y2="{y2!r}"/>\n'
        for x1, y1, x2, y2 in drawn.tolist()
    )
    text = (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<svg xmlns="http://www.w3.org/2000/svg" '
        f'width="{width!r}mm" height="{height!r}mm" '
        f'viewBox="{low_x!r} {low_y!r} {width!r} {height!r}">\n'
        "<desc>segloc map: 1 unit = 1 mm; y points south (the map's y flipped)</desc>\n"
        f'<g fill="none" stroke="black" stroke-width="{STROKE_MM!r}" stroke-linecap="round">\n'
        f"{lines}</g>\n</svg>\n"
    )
    write_text_atomic(path, text)


def _vetted_xml(path: Path, data: bytes) -> Element:
    """The root element of the drawing's XML, parsed by defusedxml; ``InputError`` naming the
    file when it is not well-formed or declares an entity (which is neither expanded nor,
    for an external one, read)."""
    from defusedxml import DefusedXmlException, EntitiesForbidden
    from defusedxml.ElementTree import fromstring

    try:
        return fromstring(data)
    except ParseError as exc:
        raise InputError(f"not an SVG drawing: not well-formed XML ({exc})", path=path) from None
    except EntitiesForbidden as exc:
        if exc.sysid is not None or exc.pubid is not None:
            raise InputError(
                f"declares the external entity {exc.name} ({exc.sysid or exc.pubid}), a "
                "reference to another file, which segloc does not read; remove the entity",
                path=path,
            ) from None
        raise InputError(
            f"declares the entity {exc.name} in its DOCTYPE; segloc expands no XML entities "
            "(nested ones can swell a small file to gigabytes): save the drawing without them",
            path=path,
        ) from None
    except DefusedXmlException as exc:
        raise InputError(
            f"not an SVG drawing segloc reads: {exc}; save it as plain SVG", path=path
        ) from None


def _hide_templates(element: Element) -> bool:
    """Put each ``TEMPLATES`` element below ``element`` that is not in a ``defs`` yet into a
    ``defs`` of its own, in its place, so that svgelements draws its content only where a
    ``use`` places it (as it does for ``defs``, ``clipPath`` and ``pattern`` content, but not
    for these); whether any was moved."""
    moved = False
    for place, child in enumerate(list(element)):
        if not isinstance(child.tag, str):
            continue  # a comment or processing instruction
        namespace, _, tag = child.tag.rpartition("}")
        if tag in TEMPLATES:
            defs = Element(f"{namespace}}}defs" if namespace else "defs")
            element.remove(child)
            defs.append(child)
            element.insert(place, defs)
            moved = True
        elif tag != "defs":
            moved = _hide_templates(child) or moved
    return moved


def _check_structure(path: Path, root: Element) -> None:
    """Refuse a drawing nested deeper than ``MAX_SVG_DEPTH``, holding a ``use`` that places an
    element inside itself, or expanding to more than ``MAX_SVG_ELEMENTS`` elements."""
    _Expansion(path, root).placed(root, 1)


class _Expansion:
    """The elements of a drawing as svgelements expands them, every ``use`` replaced by what it
    places (the element whose id is its href less the first character), counted depth first
    with each element's count kept, so that a clone of a clone costs one look-up."""

    def __init__(self, path: Path, root: Element):
        self.path = path
        self.by_id = {element.get("id"): element for element in root.iter() if element.get("id")}
        self.counted: dict[int, tuple[int, int]] = {}  # by id(element): elements, levels
        self.open_ids: list[str] = []  # ids of the elements being counted, outermost first

    def placed(self, element: Element, depth: int) -> tuple[int, int]:
        """Elements ``element`` places, itself included, and the levels they span, for the
        element ``depth`` levels down from the root (1); ``InputError`` past the bounds."""
        key = id(element)
        if key not in self.counted:
            if depth > MAX_SVG_DEPTH:
                raise self._too_deep()
            self.open_ids.append(element.get("id") or "")
            count, levels = 1, 0
            for inner in [*element, *self._used(element)]:
                inner_count, inner_levels = self.placed(inner, depth + 1)
                count, levels = count + inner_count, max(levels, inner_levels)
                if count > MAX_SVG_ELEMENTS:
                    raise InputError(
                        f"the drawing places more than {MAX_SVG_ELEMENTS:,} elements once "
                        "every <use> is expanded; unlink the repeated clones",
                        path=self.path,
                    )
            self.open_ids.pop()
            self.counted[key] = (count, levels + 1)
        count, levels = self.counted[key]
        if depth + levels - 1 > MAX_SVG_DEPTH:
            raise self._too_deep()
        return count, levels

    def _used(self, element: Element) -> list[Element]:
        """What a ``use`` element places ([] for any other element, or a ``use`` of nothing);
        ``InputError`` when that is an element being counted, placed inside itself."""
        if element.tag.rsplit("}", 1)[-1] != "use":
            return []
        href = next((value for name in _HREFS if (value := element.get(name))), "")
        target = self.by_id.get(href[1:])
        if target is None:
            return []
        if href[1:] in self.open_ids:
            cycle = self.open_ids[self.open_ids.index(href[1:]) :]
            chain = " → ".join(f"#{i}" for i in cycle if i)
            raise InputError(
                f"a <use> of {href} places #{href[1:]} inside itself ({chain} → {href}), "
                "without end; point the <use> elsewhere",
                path=self.path,
            )
        return [target]

    def _too_deep(self) -> InputError:
        return InputError(
            f"elements nest more than {MAX_SVG_DEPTH} levels deep (what a <use> places "
            "counted where it is placed); flatten the drawing's groups",
            path=self.path,
        )


def _unreadable(path: Path, exc: Exception) -> InputError:
    """The one-line error for a drawing svgelements fails on, with its reason on one line."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return InputError(f"not a readable SVG drawing ({text})", path=path)


def _pieces_in_user_units(drawing, to_user, se) -> tuple[np.ndarray, int, int]:
    """Straight pieces (K, 4) of the drawing in its outermost user units (y down), how many
    of them are chords of curves, and how many elements gave pieces; ``to_user`` the
    matrix from svgelements' pixels to those units (None: the same)."""
    pieces: list[tuple[float, float, float, float]] = []
    chords = shapes = 0
    straight = (se.Line, se.Close)
    for element in drawing.elements():
        if not isinstance(element, se.SimpleLine | se.Polyline | se.Polygon | se.Rect | se.Path):
            continue
        if isinstance(element, se.Rect) and not (element.width > 0 and element.height > 0):
            continue  # a rect without area is not drawn
        outline = se.Path(element)
        if to_user is not None:
            outline = outline * to_user
        outline.reify()
        before = len(pieces)
        for part in outline:
            if isinstance(part, se.Move) or part.start is None or part.end is None:
                continue
            pieces.append((part.start.x, part.start.y, part.end.x, part.end.y))
            chords += not isinstance(part, straight)
        shapes += len(pieces) > before
    return np.array(pieces, dtype=float).reshape(-1, 4), chords, shapes


def _to_user_units(path: Path, drawing, se):
    """The matrix from svgelements' pixels to the drawing's user units, None when they are
    the same (no viewBox): svgelements maps the outermost viewBox onto the drawing's size."""
    box = drawing.viewbox
    if box is None:
        return None
    size = (box.width, box.height)
    if not all(isinstance(v, float | int) and math.isfinite(v) and v > 0 for v in size):
        raise InputError(
            f"the drawing's viewBox needs a positive width and height, got {box}", path=path
        )
    try:
        return ~se.Matrix(drawing.viewbox_transform)
    except _SVG_ERRORS:
        raise InputError(
            "the drawing's width or height is zero, so its viewBox has no place", path=path
        ) from None


def _drawing_scale(path: Path, drawing) -> float:
    """Metres per user unit from the outermost element's width, height and viewBox."""
    sizes = [_absolute_length_m(drawing.values.get(key)) for key in ("width", "height")]
    if None in sizes:
        raise InputError(
            "the drawing's width and height give no absolute size (mm, cm, in, pt, pc, Q, "
            "px); give --scale METRES_PER_SVG_UNIT",
            path=path,
        )
    width_m, height_m = sizes
    box = drawing.viewbox
    if box is None:
        return LENGTH_UNITS_M["px"]  # without a viewBox a user unit is a CSS pixel
    per_x, per_y = width_m / box.width, height_m / box.height
    if not math.isclose(per_x, per_y, rel_tol=1e-9):
        raise InputError(
            f"the drawing's size and viewBox scale x and y differently ({per_x:g} and "
            f"{per_y:g} m per unit); give --scale METRES_PER_SVG_UNIT",
            path=path,
        )
    return per_x


def _absolute_length_m(text: object) -> float | None:
    """Metres in an SVG length such as "210mm", or None when it has no absolute unit."""
    match = _SIZE.match(text) if isinstance(text, str) else None
    if match is None:
        return None
    unit = LENGTH_UNITS_M.get(match.group(2).lower())
    value = float(match.group(1))
    return value * unit if unit is not None and math.isfinite(value) and value > 0 else None
