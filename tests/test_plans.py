"""Building plans (DXF) as maps: what is read from a hand-drawn office, in which units, from
which layers; round trips through map export; bad plans refused in one line; and scans of
the office localized on the imported map."""

from __future__ import annotations

import ezdxf
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_cli import run_cli

from segloc_cli.errors import InputError
from segloc_cli.extract import extract_segments
from segloc_cli.geometry import Pose2, wrap_angle
from segloc_cli.io.maps import World, read_map, write_map
from segloc_cli.io.plans import read_dxf, write_dxf
from segloc_cli.localize import Localizer
from segloc_cli.sim import SensorModel, random_free_poses, simulate_scan, uniform_initial_errors

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


def office_segments_m(with_desks: bool = False) -> np.ndarray:
    """The office's walls as drawn, in metres, worked out from the drawing's numbers."""
    rows = _closed(OUTLINE_MM) + [[*a, *b] for a, b in WALLS_MM]
    rows.append([*DOOR_MM[0][:2], *DOOR_MM[1][:2]])
    for dx, dy in PILLARS_AT_MM:
        rows += _closed([(x + dx, y + dy) for x, y in PILLAR_MM])
    if with_desks:
        rows += [[*a, *b] for a, b in DESKS_MM]
    return np.array(rows, dtype=float) / 1000.0


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
    """A map of 1 to 199 random segments within ±500 m written to ``path``; its segments."""
    rng = np.random.default_rng(seed)
    segments = rng.uniform(-500, 500, (int(rng.integers(1, 200)), 4))
    write_map(path, segments)
    return segments


def localization_errors(
    built: World, map_segments: np.ndarray, count: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and heading (degrees) errors (count,) of scans simulated in ``built`` at
    random free poses, localized on ``map_segments`` from guesses up to 1 m and 15° off."""
    localizer = Localizer(map_segments)
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
    assert plan.chords == 1
    assert same_segments(plan.segments, office_segments_m())
    everything = read_dxf(path)
    assert same_segments(everything.segments, office_segments_m(with_desks=True))


def test_a_drawing_without_units_needs_them_given(tmp_path):
    path = tmp_path / "office.dxf"
    draw_office(path, insunits=0)
    with pytest.raises(InputError, match=r"office\.dxf: the drawing gives no \$INSUNITS; give"):
        read_dxf(path)
    plan = read_dxf(path, units="mm", layers=["WALLS", "DOORS"])
    assert same_segments(plan.segments, office_segments_m())
    in_cm = read_dxf(path, units="cm", layers=["WALLS", "DOORS"])
    assert same_segments(in_cm.segments, office_segments_m() * 10.0)


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
    assert result.code == 2 and "no LINE, LWPOLYLINE or POLYLINE in its model space" in result.err
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
    """Scans simulated in the office as built (the walls, the pillars, and desks the plan's
    wall layers leave out) localize on the map imported from the plan's walls within 1 cm
    and 0.2°, from guesses off by up to 1 m and 15°."""
    draw_office(tmp_path / "office.dxf")
    imported = tmp_path / "office.json"
    result = run_cli(
        capsys, "map", "import", tmp_path / "office.dxf", "--layer", "WALLS,DOORS",
        "--out", imported,
    )  # fmt: skip
    assert result.code == 0, result.err
    built = World(office_segments_m(with_desks=True), name="office")
    off_m, off_deg = localization_errors(built, read_map(imported), 12, seed=17)
    assert off_m.max() < 0.01 and off_deg.max() < 0.2, (off_m, off_deg)


def test_the_units_option_offers_the_units_the_reader_knows():
    from segloc_cli.commands.maps import map_import
    from segloc_cli.io.plans import UNITS_M

    (units,) = [p for p in map_import.params if p.name == "units"]
    assert list(units.type.choices) == list(UNITS_M)
