"""Write datasets/hall/world.json: a simulated entrance hall in the spirit of the
university lobby of Reina & Gonzalez (2000).

The hall is 24 m × 16 m (world frame, metres, origin at the south-west corner,
x east, y north): an entrance of glass doors set back in the south wall, a
glass window further east, a glass side door in the west wall, a cut north-west
corner, an elevator alcove in the north wall, two doorways opening onto short
dead-end corridors, a grid of columns with one missing where the stair is, the
stair with its railings, a reception desk, benches, plant boxes and a notice
board. None of it is symmetric, so a scan tells where it was taken.

Edit the lists below and run ``.venv/bin/python datasets/hall/make_world.py``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

OUT = Path(__file__).with_name("world.json")
DECIMALS = 4

Point = tuple[float, float]

# The outer wall, counter-clockwise, as (vertex, material of the edge leaving it).
# Doorways are openings into short corridors that end in a closed door, so the
# outline stays one closed chain.
OUTER: list[tuple[Point, str]] = [
    # south wall, entrance set back 0.6 m with three glass door panels
    ((0.0, 0.0), "wall"),
    ((9.0, 0.0), "wall"),
    ((9.0, -0.6), "glass"),
    ((10.2, -0.6), "glass"),
    ((11.4, -0.6), "glass"),
    ((12.6, -0.6), "wall"),
    ((12.6, 0.0), "wall"),
    ((17.0, 0.0), "glass"),  # a window next to the reception
    ((20.0, 0.0), "wall"),
    # east wall, doorway onto a corridor closed 3 m further on
    ((24.0, 0.0), "wall"),
    ((24.0, 5.0), "wall"),
    ((27.0, 5.0), "wall"),
    ((27.0, 6.6), "wall"),
    ((24.0, 6.6), "wall"),
    # north wall, elevator alcove and a doorway onto a short corridor
    ((24.0, 16.0), "wall"),
    ((20.0, 16.0), "wall"),
    ((20.0, 17.5), "wall"),
    ((15.0, 17.5), "wall"),
    ((15.0, 16.0), "wall"),
    ((7.4, 16.0), "wall"),
    ((7.4, 18.5), "wall"),
    ((6.0, 18.5), "wall"),
    ((6.0, 16.0), "wall"),
    ((3.0, 16.0), "wall"),  # the cut north-west corner
    # west wall with a glass side door
    ((0.0, 12.5), "wall"),
    ((0.0, 8.0), "glass"),
    ((0.0, 6.5), "wall"),
]

# Columns: centre x, y (m), radius (m), number of sides.
COLUMNS = [
    (6.0, 5.0, 0.20, 10),
    (12.0, 5.0, 0.20, 10),
    (18.0, 5.0, 0.20, 10),
    (6.0, 11.0, 0.20, 10),
    (12.0, 11.0, 0.20, 10),
    (21.0, 2.0, 0.15, 8),  # a thinner pillar behind the reception
]

# Closed obstacles as rectangles: centre x, y (m), size along, across (m), heading (deg).
BOXES = [
    (3.0, 9.5, 1.8, 0.5, 90.0),  # bench along the west wall
    (9.0, 8.0, 1.8, 0.5, 25.0),  # bench in the middle of the hall
    (8.2, 1.0, 0.6, 0.6, 0.0),  # plant box by the entrance
    (2.0, 2.0, 0.6, 0.6, 45.0),  # plant box in the south-west corner
    (21.5, 14.5, 0.7, 0.7, 0.0),  # plant box by the elevators
]

# Reception desk, an L seen from the hall (closed outline).
DESK = [(15.0, 2.0), (18.0, 2.0), (18.0, 2.8), (15.8, 2.8), (15.8, 3.8), (15.0, 3.8)]

# The stair rises eastwards between two railings; its lowest risers face the hall.
STAIR_X0, STAIR_TREAD, STAIR_RISERS = 18.8, 0.28, 4
STAIR_Y = (10.75, 12.75)
RAILINGS = [(18.5, 10.6, 22.5, 10.6), (18.5, 12.9, 22.5, 12.9)]

# Free-standing notice board: centre x, y (m), length (m), heading (deg).
BOARDS = [(20.5, 8.0, 1.6, 60.0)]


def closed(points: list[Point]) -> list[list[float]]:
    """Edges of the closed outline through ``points``."""
    return [[*points[k], *points[(k + 1) % len(points)]] for k in range(len(points))]


def column(x: float, y: float, radius: float, sides: int) -> list[list[float]]:
    step = 2.0 * math.pi / sides
    return closed(
        [(x + radius * math.cos(k * step), y + radius * math.sin(k * step)) for k in range(sides)]
    )


def box(x: float, y: float, along: float, across: float, heading_deg: float) -> list[list[float]]:
    c, s = math.cos(math.radians(heading_deg)), math.sin(math.radians(heading_deg))
    half = [(-along / 2, -across / 2), (along / 2, -across / 2)]
    half += [(along / 2, across / 2), (-along / 2, across / 2)]
    return closed([(x + c * u - s * v, y + s * u + c * v) for u, v in half])


def board(x: float, y: float, length: float, heading_deg: float) -> list[float]:
    dx = 0.5 * length * math.cos(math.radians(heading_deg))
    dy = 0.5 * length * math.sin(math.radians(heading_deg))
    return [x - dx, y - dy, x + dx, y + dy]


def build() -> tuple[list[list[float]], list[str]]:
    """All segments (x1, y1, x2, y2 in metres) and their materials."""
    segments = closed([vertex for vertex, _ in OUTER])
    materials = [material for _, material in OUTER]

    def add(pieces: list[list[float]], material: str = "wall") -> None:
        segments.extend(pieces)
        materials.extend([material] * len(pieces))

    for spec in COLUMNS:
        add(column(*spec))
    for spec in BOXES:
        add(box(*spec))
    add(closed(DESK))
    risers = [STAIR_X0 + k * STAIR_TREAD for k in range(STAIR_RISERS)]
    add([[x, STAIR_Y[0], x, STAIR_Y[1]] for x in risers])
    add([list(r) for r in RAILINGS])
    add([board(*spec) for spec in BOARDS])
    return segments, materials


def main() -> None:
    segments, materials = build()
    # Rounding each vertex the same way keeps shared endpoints exactly shared.
    rounded = [[round(v, DECIMALS) + 0.0 for v in segment] for segment in segments]
    header = {"format": "segloc-world", "version": 1, "units": "m", "frame": "world"}
    # One segment per line, so a diff of the file reads like a diff of the hall.
    lines = [f'  "{key}": {json.dumps(value)},' for key, value in header.items()]
    lines.append('  "name": "hall",')
    lines.append('  "segments": [')
    lines += [f"    {json.dumps(segment)}," for segment in rounded]
    lines[-1] = lines[-1].rstrip(",")
    lines.append("  ],")
    lines.append(f'  "materials": {json.dumps(materials)}')
    text = "{\n" + "\n".join(lines) + "\n}\n"
    json.loads(text)  # the file must stay valid JSON
    OUT.write_text(text, encoding="utf-8")
    print(f"wrote {OUT} ({len(segments)} segments)")


if __name__ == "__main__":
    main()
