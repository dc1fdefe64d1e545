"""SVG drawings as maps: every shape of a hand-drawn floor read through its transforms, in
the units its size gives or --scale, placed by --origin with y flipped; maps written and
read back to the last few bits; bad drawings refused in one line; and scans of the floor
localized on the imported drawing."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_cli import assert_one_line_error, run_cli
from test_plans import localization_errors, random_map_file, same_segments

from segloc_cli.io.maps import read_map
from segloc_cli.io.svg import read_svg, write_svg
from segloc_cli.world import World

# A floor drawn in centimetres (1 user unit = 1 cm, from width/height in cm and the
# viewBox), the building turned 20° and moved by its group; y grows down the page.
FLOOR_SVG = """<?xml version="1.0"?>
<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink"
     width="1600cm" height="1300cm" viewBox="-100 -1200 1600 1300">
  <defs>
    <polygon id="column" points="0,0 40,0 40,-40 0,-40"/>
  </defs>
  <g transform="translate(50 -150) rotate(-20)" stroke="black" fill="none">
    <rect x="0" y="-800" width="1200" height="800"/>
    <polyline points="0,-480 310,-480"/>
    <path d="M 400 -480 H 830 M 920 -480 L 1200 -480"/>
    <line x1="560" y1="-480" x2="560" y2="-800"/>
    <path d="M 700 0 V -180 A 90 90 0 0 1 790 -270"/>
    <g transform="scale(2)"><line x1="150" y1="-60" x2="250" y2="-60"/></g>
    <use xlink:href="#column" x="250" y="-250"/>
    <circle cx="1000" cy="-200" r="30"/>
    <text x="100" y="-100">Lab 2</text>
  </g>
</svg>
"""
BUILDING_TURN_DEG, BUILDING_AT = -20.0, (50.0, -150.0)
# The floor's straight pieces in the building's own units (cm, y down), worked out by hand.
PIECES_CM = [
    (0, -800, 1200, -800), (1200, -800, 1200, 0), (1200, 0, 0, 0), (0, 0, 0, -800),
    (0, -480, 310, -480), (400, -480, 830, -480), (920, -480, 1200, -480),
    (560, -480, 560, -800), (700, 0, 700, -180), (700, -180, 790, -270),
    (300, -120, 500, -120),
    (250, -250, 290, -250), (290, -250, 290, -290), (290, -290, 250, -290), (250, -290, 250, -250),
]  # fmt: skip


def floor_m(scale_m: float = 0.01, origin_m=(0.0, 0.0)) -> np.ndarray:
    """The floor's segments in metres: the building's pieces through its group's transform,
    then onto the map (x = X + s·u, y = Y − s·v)."""
    turn = np.deg2rad(BUILDING_TURN_DEG)
    rotate = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    ends = np.array(PIECES_CM, dtype=float).reshape(-1, 2) @ rotate.T + BUILDING_AT
    placed = np.column_stack(
        [origin_m[0] + scale_m * ends[:, 0], origin_m[1] - scale_m * ends[:, 1]]
    )
    return placed.reshape(-1, 4)


def test_every_shape_of_the_floor_is_read_through_its_transforms(tmp_path):
    path = tmp_path / "floor.svg"
    path.write_text(FLOOR_SVG)
    plan = read_svg(path)
    assert same_segments(plan.segments, floor_m())
    assert plan.chords == 1  # the door's arc
    assert plan.source == {
        "format": "svg",
        "plan": str(path),
        "metres_per_unit": 0.01,
        "scale_from": "width, height and viewBox",
        "origin_m": [0.0, 0.0],
        "elements": 7,
    }


def test_scale_and_origin_place_the_drawing(tmp_path):
    path = tmp_path / "floor.svg"
    path.write_text(FLOOR_SVG)
    plan = read_svg(path, scale_m=0.025, origin_m=(-5.0, 12.0))
    assert same_segments(plan.segments, floor_m(0.025, (-5.0, 12.0)))
    assert plan.source["scale_from"] == "--scale"
    line = '<line x1="10" y1="20" x2="30" y2="20"/>'
    pixel_m = 0.0254 / 96  # a user unit without a viewBox: a CSS pixel, whatever the size
    for size in ('width="2in" height="1in"', 'width="5mm" height="5mm"'):
        (tmp_path / "sized.svg").write_text(
            f'<svg xmlns="http://www.w3.org/2000/svg" {size}>{line}</svg>'
        )
        got = read_svg(tmp_path / "sized.svg").segments
        assert np.allclose(got, np.array([[10, -20, 30, -20]]) * pixel_m, rtol=1e-12)
    boxed = f'{SVG_HEAD} width="2in" height="1in" viewBox="0 0 8 4">{line}</svg>'
    (tmp_path / "boxed.svg").write_text(boxed)
    got = read_svg(tmp_path / "boxed.svg").segments
    assert np.allclose(got, np.array([[10, -20, 30, -20]]) * 0.0254 / 4, rtol=1e-12)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_a_map_written_as_svg_reads_back_to_the_last_bits(seed, tmp_path_factory):
    folder = tmp_path_factory.mktemp("round")
    segments = random_map_file(seed, folder / "map.json")
    write_svg(folder / "map.svg", read_map(folder / "map.json"))
    back = read_svg(folder / "map.svg")
    assert back.segments.shape == segments.shape
    # Millimetres to metres and back: a few units in the last place of 500 m.
    assert np.abs(back.segments - segments).max() < 1e-12
    assert back.chords == 0 and back.source["scale_from"] == "width, height and viewBox"


def test_scans_of_the_floor_localize_on_its_imported_drawing(tmp_path, capsys):
    """Scans simulated in the floor as built (its arc a wall along the chord) localize on
    the map imported from the drawing within 1 cm and 0.2°, from guesses up to 1 m and 15°
    off."""
    (tmp_path / "floor.svg").write_text(FLOOR_SVG)
    result = run_cli(capsys, "map", "import", tmp_path / "floor.svg", "--out", tmp_path / "f.json")
    assert result.code == 0, result.err
    assert "1 arc or curve pieces taken as straight chords" in result.err
    built = World(floor_m(), name="floor")
    off_m, off_deg = localization_errors(built, read_map(tmp_path / "f.json"), 15, seed=31)
    assert off_m.max() < 0.01 and off_deg.max() < 0.2, (off_m, off_deg)


SVG_HEAD = '<svg xmlns="http://www.w3.org/2000/svg"'
BAD_DRAWINGS = {
    "not-xml": ("walls: 4\n", [], "not an SVG drawing: not well-formed XML"),
    "truncated": (f'{SVG_HEAD}><line x1="0"', [], "not an SVG drawing: not well-formed XML"),
    "html": ("<html><body><p>plan</p></body></html>", [], "its outermost element is not <svg>"),
    "nothing-usable": (
        f'{SVG_HEAD} width="1m"><circle r="3"/><text>hall</text></svg>',
        ["--scale", "1"],
        "no line, polyline, polygon, rect or path in the drawing",
    ),
    "no-size": (
        f'{SVG_HEAD} width="800" height="600"><line x1="0" y1="0" x2="5" y2="0"/></svg>',
        [],
        "give no absolute size (mm, cm, in, pt, pc, Q, px); give --scale",
    ),
    "percent": (
        f'{SVG_HEAD} width="100%" height="100%" viewBox="0 0 9 9"><line x2="5"/></svg>',
        [],
        "give no absolute size",
    ),
    "flat-viewbox": (
        f'{SVG_HEAD} width="1cm" height="1cm" viewBox="0 0 0 10"><line x2="5"/></svg>',
        [],
        "viewBox needs a positive width and height",
    ),
    "stretched": (
        f'{SVG_HEAD} width="2cm" height="1cm" viewBox="0 0 10 10" preserveAspectRatio="none">'
        '<line x2="5"/></svg>',
        [],
        "scale x and y differently",
    ),
    "negative-scale": (f'{SVG_HEAD}><line x2="5"/></svg>', ["--scale", "-1"], "--scale must be"),
    "zero-scale": (f'{SVG_HEAD}><line x2="5"/></svg>', ["--scale", "0"], "got 0"),
    "nan-scale": (f'{SVG_HEAD}><line x2="5"/></svg>', ["--scale", "nan"], "got nan"),
    "far": (
        f'{SVG_HEAD}><line x1="0" y1="0" x2="3e9" y2="0"/></svg>',
        ["--scale", "0.01"],
        "a line lies beyond ±1e+07 m once in metres (×0.01); check --scale and --origin",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_DRAWINGS))
def test_bad_drawings_are_one_line_naming_them(case, tmp_path, capsys):
    text, options, fragment = BAD_DRAWINGS[case]
    path = tmp_path / "plan.svg"
    path.write_text(text)
    result = run_cli(capsys, "map", "import", path, "--out", tmp_path / "m.json", *options)
    assert_one_line_error(result, f"{path}: ", fragment)
    assert not (tmp_path / "m.json").exists()


def test_options_of_other_formats_are_refused(tmp_path, capsys):
    path = tmp_path / "plan.svg"
    path.write_text(FLOOR_SVG)
    out = tmp_path / "m.json"
    result = run_cli(capsys, "map", "import", path, "--out", out, "--units", "mm")
    assert_one_line_error(result, "--units", "applies to DXF plans only, not to SVG plans")
    result = run_cli(capsys, "map", "import", path, "--out", out, "--origin", "3")
    assert_one_line_error(result, "--origin", "use X,Y in metres")
    result = run_cli(capsys, "map", "import", tmp_path / "grid.yaml", "--out", out, "--scale", "2")
    assert_one_line_error(result, "--scale", "applies to SVG plans only, not to nav2 grids")
    assert not out.exists()


@pytest.mark.parametrize("container", ["symbol", "marker", "mask", "clipPath", "pattern", "defs"])
@pytest.mark.parametrize("xmlns", [' xmlns="http://www.w3.org/2000/svg"', ""])
def test_what_only_a_reference_draws_is_read_only_where_a_use_places_it(container, xmlns, tmp_path):
    """The content of a symbol, marker, mask, clipPath, pattern or defs is never drawn by
    itself, at the top or inside a group: only the wall is read; a use of the symbol's or the
    defs' content places it where the use says."""
    inner = f'<{container} id="t"><line id="l" x1="0" y1="20" x2="10" y2="20"/></{container}>'
    drawing = (
        f'<svg{xmlns} viewBox="0 0 100 100"><line x1="0" y1="50" x2="40" y2="50"/>'
        f'{inner}<g transform="translate(1 1)">{inner.replace("id=", "data-id=")}</g>{{use}}</svg>'
    )
    path = tmp_path / "plan.svg"
    path.write_text(drawing.format(use=""))
    wall = np.array([[0.0, -0.5, 0.4, -0.5]])
    assert same_segments(read_svg(path, scale_m=0.01).segments, wall)
    if container in ("symbol", "defs"):
        target = "t" if container == "symbol" else "l"
        path.write_text(drawing.format(use=f'<use href="#{target}" x="30" y="5"/>'))
        placed = np.array([[0.3, -0.25, 0.4, -0.25]])
        assert same_segments(read_svg(path, scale_m=0.01).segments, np.vstack([wall, placed]))
