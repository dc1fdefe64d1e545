"""Building plans (DXF) as maps: what is read from a hand-drawn office, in which units, from
which layers; round trips through map export; bad plans refused in one line; and scans of
the office localized on the imported map."""

from __future__ import annotations

import math
import re

import ezdxf
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_cli import run_cli

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.io.maps import read_map, write_map
from segloc_cli.io.plans import read_dxf, write_dxf
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.localize import Localizer
from segloc_cli.sim import SensorModel, random_free_poses, simulate_scan, uniform_initial_errors
from segloc_cli.world import World

# An L-shaped office, millimetres: the outline as one closed polyline, two walls as lines,
# a door drawn as an arc piece, a pillar as a block placed twice, desks on their own layer.
OUTLINE_MM = [(0, 0), (16000, 0), (16000, 7000), (9000, 7000), (9000, 12000), (0, 12000)]
WALLS_MM = [((6000, 0), (6000, 4000)), ((9000, 7000), (4000, 7000))]
DOOR_MM = [(0, 9000, 0.4), (0, 10000, 0.0)]  # vertex x, y, bulge: an arc from 9 m to 10 m
PILLAR_MM = [(0, 0), (500, 0), (500, 500), (0, 500)]
PILLARS_AT_MM = [(12000, 3000), (3000, 3000)]
DESKS_MM = [((1000, 10000), (2500, 10000)), ((13000, 5500), (14500, 5500))]


def _closed(points) -> list[list[float]]:
    return [[*a, *b] for a, b in zip(points, [*points[1:], points[0]], strict=True)]


def office_segments_m(with_desks: bool = False, door_pieces: int = 0) -> np.ndarray:
    """The office's walls as drawn, in metres, worked out from the drawing's numbers; the
    door as ``door_pieces`` equal chords of its arc (none: left out)."""
    rows = _closed(OUTLINE_MM) + [[*a, *b] for a, b in WALLS_MM]
    for dx, dy in PILLARS_AT_MM:
        rows += _closed([(x + dx, y + dy) for x, y in PILLAR_MM])
    if with_desks:
        rows += [[*a, *b] for a, b in DESKS_MM]
    walls = np.array(rows, dtype=float) / 1000.0
    return np.vstack([walls, door_arc_m(door_pieces)]) if door_pieces else walls


def door_circle_m() -> tuple[np.ndarray, float, float, float]:
    """The door's arc in metres: centre (2,), radius, and its start and end angles (rad),
    from its vertices and bulge (the tangent of a quarter of the angle it turns, counter-
    clockwise for a positive bulge)."""
    (x1, y1, bulge), (x2, y2, _) = DOOR_MM
    p1, p2 = np.array([x1, y1]) / 1000.0, np.array([x2, y2]) / 1000.0
    turn = 4.0 * np.arctan(bulge)
    chord = np.linalg.norm(p2 - p1)
    radius = chord / (2.0 * np.sin(turn / 2.0))
    left = np.array([-(p2 - p1)[1], (p2 - p1)[0]]) / chord
    centre = (p1 + p2) / 2.0 + left * radius * np.cos(turn / 2.0)
    start = np.arctan2(*(p1 - centre)[::-1])
    return centre, radius, start, start + turn


def door_arc_m(pieces: int) -> np.ndarray:
    """The door's arc as ``pieces`` equal chords (pieces, 4), metres, from its first vertex."""
    centre, radius, start, end = door_circle_m()
    angles = np.linspace(start, end, pieces + 1)
    points = centre + radius * np.column_stack([np.cos(angles), np.sin(angles)])
    return np.hstack([points[:-1], points[1:]])


def fewest_chords(radius: float, turn: float, sagitta: float = 0.01) -> int:
    """The fewest equal chords of an arc (radius, turn in rad) that stay within ``sagitta``."""
    return math.ceil(turn / (2.0 * math.acos(1.0 - sagitta / radius)))


def draw_office(path, insunits: int | None = 4) -> None:
    doc = ezdxf.new("R2010")
    if insunits is not None:
        doc.header["$INSUNITS"] = insunits
    for layer in ("WALLS", "DOORS", "FURNITURE"):
        doc.layers.add(layer)
    space = doc.modelspace()
    space.add_lwpolyline(OUTLINE_MM, close=True, dxfattribs={"layer": "WALLS"})
    for start, end in WALLS_MM:
        space.add_line(start, end, dxfattribs={"layer": "WALLS"})
    space.add_lwpolyline(DOOR_MM, format="xyb", dxfattribs={"layer": "DOORS"})
    pillar = doc.blocks.new("PILLAR")
    pillar.add_polyline2d(PILLAR_MM, close=True, dxfattribs={"layer": "WALLS"})
    for at in PILLARS_AT_MM:
        space.add_blockref("PILLAR", at, dxfattribs={"layer": "WALLS"})
    for start, end in DESKS_MM:
        space.add_line(start, end, dxfattribs={"layer": "FURNITURE"})
    doc.saveas(path)


def same_segments(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two segment sets match one for one (either direction), to 1e-9 m."""
    if a.shape != b.shape:
        return False
    flipped = b[:, [2, 3, 0, 1]]
    left = np.vstack([a, a[:, [2, 3, 0, 1]]])
    for segment, twin in zip(b, flipped, strict=True):
        if not (
            np.any(np.all(np.abs(a - segment) < 1e-9, axis=1))
            or np.any(np.all(np.abs(left - twin) < 1e-9, axis=1))
        ):
            return False
    return True


def random_map_file(seed: int, path) -> np.ndarray:
    """A map of 1 to 199 random segments within ±500 m written to ``path``; its segments as
    the file holds them (to the micrometre)."""
    rng = np.random.default_rng(seed)
    write_map(path, rng.uniform(-500, 500, (int(rng.integers(1, 200)), 4)))
    return read_map(path)


def localization_errors(
    built: World, map_segments: np.ndarray, count: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and heading (degrees) errors (count,) of scans simulated in ``built`` at
    random free poses, localized on ``map_segments`` from guesses up to 1 m and 15° off."""
    localizer = Localizer.on_map(map_segments)
    rng = np.random.default_rng(seed)
    truths = random_free_poses(built, count, rng)
    errors = uniform_initial_errors(len(truths), 1.0, 15.0, rng)
    off_m, off_deg = [], []
    for truth, error in zip(truths, errors, strict=True):
        scan = simulate_scan(built, Pose2(*truth), SensorModel(), rng, 0.0)
        est = localizer.localize(extract_segments(scan), Pose2(*(truth - error)), scan.points())
        off_m.append(np.hypot(est.pose.x - truth[0], est.pose.y - truth[1]))
        off_deg.append(abs(np.rad2deg(wrap_angle(est.pose.theta - truth[2]))))
    return np.array(off_m), np.array(off_deg)


def test_every_wall_of_the_office_is_read_in_metres(tmp_path):
    path = tmp_path / "office.dxf"
    draw_office(path)
    plan = read_dxf(path, layers=["WALLS", "DOORS"])
    assert plan.source == {
        "format": "dxf",
        "plan": str(path),
        "layers": ["DOORS", "WALLS"],
        "metres_per_unit": 0.001,
    }
    _, radius, start, end = door_circle_m()
    door = fewest_chords(radius, end - start)
    assert door == 5  # a 1 m door bulging 20 cm, within 1 cm
    assert plan.chords == door
    assert plan.warnings == (
        "1 curve (LWPOLYLINE bulge 1) taken as 5 straight chords, each within 1 cm of its curve",
    )
    assert same_segments(plan.segments, office_segments_m(door_pieces=door))
    everything = read_dxf(path)
    assert same_segments(everything.segments, office_segments_m(True, door_pieces=door))


def test_a_drawing_without_units_needs_them_given(tmp_path):
    path = tmp_path / "office.dxf"
    draw_office(path, insunits=0)
    with pytest.raises(InputError, match=r"office\.dxf: the drawing gives no \$INSUNITS; give"):
        read_dxf(path)
    plan = read_dxf(path, units="mm", layers=["WALLS", "DOORS"])
    assert same_segments(plan.segments, office_segments_m(door_pieces=5))
    in_cm = read_dxf(path, units="cm", layers=["WALLS", "DOORS"])
    # Ten times as large, the door's arc needs more chords to stay within 1 cm.
    _, radius, start, end = door_circle_m()
    door = fewest_chords(radius * 10.0, end - start)
    assert door == 15 and in_cm.chords == door
    walls = np.vstack([office_segments_m(), door_arc_m(door)]) * 10.0
    assert same_segments(in_cm.segments, walls)


def test_bad_plans_are_one_line(tmp_path, capsys):
    path = tmp_path / "office.dxf"
    draw_office(path)
    with pytest.raises(InputError, match=r"no layer 'ROOF' in the drawing; its layers are 0, "):
        read_dxf(path, layers=["ROOF"])
    text = tmp_path / "notes.dxf"
    text.write_text("this is not a drawing\n")
    result = run_cli(capsys, "map", "import", text, "--out", tmp_path / "m.json")
    assert result.code == 2 and result.err.startswith("segloc: error: ")
    assert len(result.err.splitlines()) == 1 and "notes.dxf" in result.err
    empty = tmp_path / "empty.dxf"
    ezdxf.new().saveas(empty)
    result = run_cli(capsys, "map", "import", empty, "--out", tmp_path / "m.json", "--units", "m")
    assert result.code == 2 and result.err.endswith(
        "empty.dxf: no LINE, LWPOLYLINE, POLYLINE, ARC, CIRCLE, ELLIPSE or SPLINE in its model "
        "space; its layers are 0, Defpoints\n"
    )
    result = run_cli(capsys, "map", "import", tmp_path / "plan.svgz", "--out", tmp_path / "m.json")
    assert result.code == 2 and "plans are DXF (.dxf), SVG (.svg) or nav2 grid" in result.err
    assert not (tmp_path / "m.json").exists()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_a_map_exported_and_imported_is_the_same_map(seed, tmp_path_factory):
    folder = tmp_path_factory.mktemp("round")
    segments = random_map_file(seed, folder / "map.json")
    write_dxf(folder / "map.dxf", read_map(folder / "map.json"))
    back = read_dxf(folder / "map.dxf")
    np.testing.assert_array_equal(back.segments, segments)
    assert back.source["metres_per_unit"] == 1.0


def test_scans_of_the_office_localize_on_its_imported_plan(tmp_path, capsys):
    """Scans simulated in the office as built (the walls, the pillars, the door's arc, and
    desks the plan's wall layers leave out) localize on the map imported from the plan's
    walls within 1 cm and 0.2°, from guesses off by up to 1 m and 15°."""
    draw_office(tmp_path / "office.dxf")
    imported = tmp_path / "office.json"
    result = run_cli(
        capsys, "map", "import", tmp_path / "office.dxf", "--layer", "WALLS,DOORS",
        "--out", imported,
    )  # fmt: skip
    assert result.code == 0, result.err
    built = World(office_segments_m(with_desks=True, door_pieces=200), name="office")
    off_m, off_deg = localization_errors(built, read_map(imported), 12, seed=17)
    assert off_m.max() < 0.01 and off_deg.max() < 0.2, (off_m, off_deg)


def test_the_units_option_offers_the_units_the_reader_knows():
    from segloc_cli.commands.plans import map_import
    from segloc_cli.io.plans import UNITS_M

    (units,) = [p for p in map_import.params if p.name == "units"]
    assert list(units.type.choices) == list(UNITS_M)


# Curves, millimetres, one per layer: a door as a lone ARC, a round column (CIRCLE), an
# elliptical bay, a curved wall (a SPLINE of one cubic span, so a Bézier curve), an arc
# mirrored in CAD (its plane's normal -z: it lands at x -> -x) and a 2D POLYLINE whose first
# piece is a half circle (bulge 1); walls as lines, and a note the reader leaves out.
ARC_MM = ((3000.0, 2000.0), 900.0, 0.0, 90.0)  # centre, radius, start and end angle (deg)
COLUMN_MM = ((8000.0, 3000.0), 250.0)
BAY_MM = ((12000.0, 3000.0), 1500.0, 0.4)  # centre, major semi-axis along x, minor / major
WALL_CURVE_MM = [(1000.0, 6000.0), (3000.0, 9000.0), (5000.0, 4000.0), (7000.0, 7000.0)]
MIRRORED_MM = ((-10000.0, 8000.0), 1200.0, 30.0, 150.0)  # in its own (mirrored) plane
POLYLINE_MM = [(14000.0, 6000.0, 1.0), (16000.0, 6000.0, 0.0), (16000.0, 9000.0, 0.0)]
CURVE_LAYERS = ("DOORS", "COLUMN", "BAY", "WALL_CURVE", "MIRRORED", "POLYLINE")


def draw_curves(path, metres_per_unit: float = 0.001) -> None:
    """The curves above, in a drawing whose unit is ``metres_per_unit`` (mm or m)."""
    k = 0.001 / metres_per_unit  # drawing units per millimetre
    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = {0.001: 4, 1.0: 6}[metres_per_unit]
    for layer in (*CURVE_LAYERS, "WALLS", "NOTES"):
        doc.layers.add(layer)
    space = doc.modelspace()
    (cx, cy), radius, start, end = ARC_MM
    space.add_arc((cx * k, cy * k), radius * k, start, end, dxfattribs={"layer": "DOORS"})
    (cx, cy), radius = COLUMN_MM
    space.add_circle((cx * k, cy * k), radius * k, dxfattribs={"layer": "COLUMN"})
    (cx, cy), major, ratio = BAY_MM
    space.add_ellipse((cx * k, cy * k), (major * k, 0), ratio, dxfattribs={"layer": "BAY"})
    space.add_open_spline(
        [(x * k, y * k) for x, y in WALL_CURVE_MM], degree=3, dxfattribs={"layer": "WALL_CURVE"}
    )
    (cx, cy), radius, start, end = MIRRORED_MM
    mirrored = {"layer": "MIRRORED", "extrusion": (0, 0, -1)}
    space.add_arc((cx * k, cy * k), radius * k, start, end, dxfattribs=mirrored)
    polyline = space.add_polyline2d(
        [(x * k, y * k) for x, y, _ in POLYLINE_MM], dxfattribs={"layer": "POLYLINE"}
    )
    for vertex, (_, _, bulge) in zip(polyline.vertices, POLYLINE_MM, strict=True):
        vertex.dxf.bulge = bulge
    space.add_line((0, 0), (17000 * k, 0), dxfattribs={"layer": "WALLS"})
    space.add_text("mind the column", dxfattribs={"layer": "NOTES"})
    doc.saveas(path)


def _on_circle(centre_mm, radius_mm: float, start_deg: float, end_deg: float) -> np.ndarray:
    angles = np.deg2rad(np.linspace(start_deg, end_deg, 20001))
    return np.array(centre_mm) + radius_mm * np.column_stack([np.cos(angles), np.sin(angles)])


def curve_samples_m(layer: str) -> np.ndarray:
    """20001 points (K, 2), metres, along the curve on ``layer``, from its definition."""
    if layer == "DOORS":
        points = _on_circle(*ARC_MM)
    elif layer == "COLUMN":
        points = _on_circle(*COLUMN_MM, 0.0, 360.0)
    elif layer == "BAY":
        (cx, cy), major, ratio = BAY_MM
        t = np.linspace(0.0, 2.0 * np.pi, 20001)
        points = np.column_stack([cx + major * np.cos(t), cy + ratio * major * np.sin(t)])
    elif layer == "WALL_CURVE":
        t = np.linspace(0.0, 1.0, 20001)[:, None]
        p0, p1, p2, p3 = np.array(WALL_CURVE_MM)
        points = (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * p1 + 3 * (1 - t) * t**2 * p2 + t**3 * p3
    elif layer == "MIRRORED":
        (cx, cy), radius, start, end = MIRRORED_MM
        points = _on_circle((-cx, cy), radius, 180.0 - end, 180.0 - start)
    else:  # the polyline's half circle, counter-clockwise from its first vertex: below
        (x1, y1, _), (x2, _, _) = POLYLINE_MM[:2]
        points = _on_circle(((x1 + x2) / 2, y1), (x2 - x1) / 2, 180.0, 360.0)
    return points / 1000.0


def distances_to_segments(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Each point's (K, 2) distance to the nearest of the segments (N, 4), same units."""
    a, b = segments[:, :2], segments[:, 2:]
    along = b - a
    t = np.einsum("knd,nd->kn", points[:, None, :] - a, along) / np.sum(along**2, axis=1)
    nearest = a + np.clip(t, 0.0, 1.0)[..., None] * along
    return np.min(np.linalg.norm(points[:, None, :] - nearest, axis=2), axis=1)


@pytest.mark.parametrize("layer", CURVE_LAYERS)
def test_a_curve_becomes_chords_within_1_cm_of_it(layer, tmp_path):
    draw_curves(tmp_path / "curves.dxf")
    plan = read_dxf(tmp_path / "curves.dxf", layers=[layer])
    chords = plan.segments
    if layer == "POLYLINE":  # its second piece is straight, and taken as drawn
        chords, straight = plan.segments[:-1], plan.segments[-1]
        np.testing.assert_array_equal(straight, [16.0, 6.0, 16.0, 9.0])
    assert plan.chords == len(chords) > 1
    curve = curve_samples_m(layer)
    ends = chords.reshape(-1, 2)
    assert distances_to_segments(ends, np.hstack([curve[:-1], curve[1:]])).max() < 1e-6
    assert np.allclose(chords[1:, :2], chords[:-1, 2:], rtol=0, atol=1e-9)  # one chain
    off_m = distances_to_segments(curve, chords)
    assert off_m.max() <= 0.01 + 1e-9
    assert off_m.max() > 0.0025, "chords finer than the tolerance needs"
    if layer in ("DOORS", "COLUMN", "MIRRORED", "POLYLINE"):
        radius_m, turn_deg = {
            "DOORS": (0.9, 90.0), "COLUMN": (0.25, 360.0), "MIRRORED": (1.2, 120.0),
            "POLYLINE": (1.0, 180.0),
        }[layer]  # fmt: skip
        assert len(chords) == fewest_chords(radius_m, np.deg2rad(turn_deg))


def test_the_chords_tolerance_is_in_metres_whatever_the_drawing_unit(tmp_path):
    draw_curves(tmp_path / "mm.dxf", metres_per_unit=0.001)
    draw_curves(tmp_path / "m.dxf", metres_per_unit=1.0)
    in_mm, in_m = read_dxf(tmp_path / "mm.dxf"), read_dxf(tmp_path / "m.dxf")
    assert in_mm.chords == in_m.chords
    np.testing.assert_allclose(in_mm.segments, in_m.segments, rtol=0, atol=1e-9)


def test_importing_curves_warns_once_and_names_every_layer_read(tmp_path, capsys):
    """A door that is only an ARC on its own layer is read, the warning counts the curves by
    kind and their chords, and a layer asked for that holds nothing read is named."""
    path, out = tmp_path / "curves.dxf", tmp_path / "curves.json"
    draw_curves(path)
    result = run_cli(
        capsys, "map", "import", path, "--layer", "WALLS,DOORS,NOTES,COLUMN", "--out", out
    )
    assert result.code == 0, result.err
    door, column = fewest_chords(0.9, np.pi / 2), fewest_chords(0.25, 2 * np.pi)
    assert result.err.splitlines() == [
        f"segloc: warning: {path}: 2 curves (ARC 1, CIRCLE 1) taken as {door + column} "
        "straight chords, each within 1 cm of its curve",
        f"segloc: warning: {path}: nothing read from layer NOTES: no LINE, LWPOLYLINE, "
        "POLYLINE, ARC, CIRCLE, ELLIPSE or SPLINE there",
        f"segloc: {out}: {1 + door + column} segments from layers COLUMN, DOORS, WALLS "
        "(1 drawing unit = 0.001 m)",
    ]
    assert read_map(out).shape == (1 + door + column, 4)
    result = run_cli(capsys, "map", "import", path, "--layer", "WALLS", "--out", out, "--force")
    assert result.code == 0
    assert result.err == f"segloc: {out}: 1 segment from layer WALLS (1 drawing unit = 0.001 m)\n"


def test_a_curve_that_cannot_be_taken_as_chords_is_one_line(tmp_path, capsys):
    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = 6
    space = doc.modelspace()
    space.add_circle((0, 0), 2e7)
    doc.saveas(tmp_path / "huge.dxf")
    with pytest.raises(InputError, match=r"huge\.dxf: the CIRCLE \w+ on layer 0 lies beyond "):
        read_dxf(tmp_path / "huge.dxf")
    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = 6
    spline = doc.modelspace().add_spline(dxfattribs={"layer": "WALLS"})
    spline.control_points = [(0, 0), (1, 1), (2, 0), (3, 1)]
    spline.knots = [0, 1, 0, 1, 0, 1, 0, 1]  # not a knot vector: they must not decrease
    doc.saveas(tmp_path / "bad-spline.dxf")
    out = tmp_path / "m.json"
    result = run_cli(capsys, "map", "import", tmp_path / "bad-spline.dxf", "--out", out)
    assert result.code == 2 and len(result.err.splitlines()) == 1
    assert re.match(
        r"segloc: error: \S+bad-spline\.dxf: cannot follow the SPLINE \w+ on layer WALLS \(",
        result.err,
    )
    assert not out.exists()


def test_a_layer_missing_from_the_layer_table_is_a_layer(tmp_path, capsys):
    """Entities on layers the LAYER table does not list (minimal writers leave it out), drawn
    directly or inside a block, are read with --layer naming those layers as without it."""
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 6
    space = doc.modelspace()
    space.add_line((0, 0), (4, 0), dxfattribs={"layer": "WALLS"})
    space.add_line((0, 0), (0, 3), dxfattribs={"layer": "WALLS"})
    space.add_line((1, 1), (2, 1), dxfattribs={"layer": "DESKS"})
    pillar = doc.blocks.new("PILLAR")
    pillar.add_line((0, 0), (0.5, 0), dxfattribs={"layer": "PILLARS"})
    space.add_blockref("PILLAR", (3, 2))
    path = tmp_path / "minimal.dxf"
    doc.saveas(path)
    assert "WALLS" not in [layer.dxf.name for layer in ezdxf.readfile(path).layers]
    every = read_dxf(path)
    assert every.source["layers"] == ["DESKS", "PILLARS", "WALLS"]
    walls = read_dxf(path, layers=["WALLS", "PILLARS"])
    assert same_segments(walls.segments, np.array([[0, 0, 4, 0], [0, 0, 0, 3], [3, 2, 3.5, 2]]))
    assert same_segments(every.segments, np.vstack([walls.segments, [[1, 1, 2, 1]]]))
    result = run_cli(
        capsys, "map", "import", path, "--layer", "DESKS", "--out", tmp_path / "desks.json"
    )
    assert result.code == 0, result.err
    result = run_cli(
        capsys, "map", "import", path, "--layer", "ROOF", "--out", tmp_path / "roof.json"
    )
    assert result.code == 2 and result.err.endswith(
        "no layer 'ROOF' in the drawing; its layers are 0, DESKS, Defpoints, PILLARS, WALLS\n"
    )
