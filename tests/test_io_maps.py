"""Map and world files: round trips and every error."""

from __future__ import annotations

import json

import numpy as np
import pytest

from segloc_cli.errors import InputError
from segloc_cli.io.files import OutputError
from segloc_cli.io.maps import (
    MAX_MAP_BYTES,
    MAX_SEGMENTS,
    bounds_problem,
    read_map,
    read_world,
    write_map,
    write_world,
)
from segloc_cli.world import World

SEGMENTS = np.array(
    [
        [0.0, 0.0, 10.0, 0.0],
        [10.0, 0.0, 10.0, 7.5],
        [0.1, 0.2, 1.0 / 3.0, -2.0 / 7.0],
        [-1e-9, 1234.56789, 5e-324, 1.0],
    ]
)


MICROMETRE = 1e-6


def test_map_round_trip_keeps_micrometres(tmp_path):
    path = tmp_path / "map.json"
    write_map(path, SEGMENTS, {"log": "log.mcap", "scans": 12})
    back = read_map(path)
    assert back.dtype == np.float64
    assert back.shape == (4, 4)
    np.testing.assert_allclose(back, SEGMENTS, rtol=0, atol=MICROMETRE / 2)
    # Coordinates that are whole micrometres come back exactly.
    np.testing.assert_array_equal(back[:2], SEGMENTS[:2])
    assert back[3].tolist() == [0.0, 1234.56789, 0.0, 1.0]
    document = json.loads(path.read_text())
    assert document["format"] == "segloc-map"
    assert document["version"] == 1
    assert document["frame"] == "world"
    assert document["units"] == "m"
    assert document["source"] == {"log": "log.mcap", "scans": 12}


def test_world_round_trip_keeps_micrometres(tmp_path):
    world = World(SEGMENTS, np.array(["wall", "glass", "wall", "glass"]), name="corridor")
    path = tmp_path / "world.json"
    write_world(path, world)
    back = read_world(path)
    np.testing.assert_allclose(back.segments, SEGMENTS, rtol=0, atol=MICROMETRE / 2)
    assert back.materials.tolist() == ["wall", "glass", "wall", "glass"]
    assert back.name == "corridor"
    document = json.loads(path.read_text())
    assert (document["format"], document["version"], document["units"], document["frame"]) == (
        "segloc-world",
        1,
        "m",
        "world",
    )


def test_world_sensor_round_trips_and_a_world_without_one_writes_none(tmp_path):
    sensor = {"readings": 361, "fov_deg": 180.0, "noise_cm": 0.5, "clutter": False}
    write_world(tmp_path / "lms.json", World(SEGMENTS, name="lms", sensor=sensor))
    assert read_world(tmp_path / "lms.json").sensor == sensor
    write_world(tmp_path / "plain.json", World(SEGMENTS, name="plain"))
    assert "sensor" not in json.loads((tmp_path / "plain.json").read_text())
    assert read_world(tmp_path / "plain.json").sensor == {}


def test_a_map_read_as_a_world_is_made_of_the_material_given(tmp_path):
    write_map(tmp_path / "plan.json", SEGMENTS)
    world = read_world(tmp_path / "plan.json", default_material="glass")
    np.testing.assert_array_equal(world.segments, read_map(tmp_path / "plan.json"))
    assert world.materials.tolist() == ["glass"] * 4
    assert world.name == "plan"


def test_world_materials_default_to_wall(tmp_path):
    path = tmp_path / "world.json"
    path.write_text(
        json.dumps(
            {"format": "segloc-world", "version": 1, "name": "box", "segments": [[0, 0, 1, 0]]}
        )
    )
    world = read_world(path)
    assert world.materials.tolist() == ["wall"]
    assert World(SEGMENTS).materials.tolist() == ["wall"] * 4


def test_world_is_accepted_as_map(tmp_path):
    path = tmp_path / "world.json"
    write_world(path, World(SEGMENTS, name="w"))
    np.testing.assert_array_equal(read_map(path), read_world(path).segments)


def test_map_is_written_one_segment_a_line_without_binary_noise(tmp_path):
    # Coordinates as arithmetic leaves them: 0.1 + 0.2 is 0.30000000000000004.
    segments = np.array([[0.1 + 0.2, 1.0 / 3.0, 2.0 / 3.0, 15.000035195825041]] * 3)
    segments[:, 1] += np.arange(3)
    path = tmp_path / "map.json"
    write_map(path, segments, {"extract": {"split_m": 0.1 + 0.2}})
    lines = path.read_text(encoding="utf-8").splitlines()
    rows = [line for line in lines if line.strip().startswith("[") and line.strip() != "["]
    assert rows == [
        "  [0.3, 0.333333, 0.666667, 15.000035],",
        "  [0.3, 1.333333, 0.666667, 15.000035],",
        "  [0.3, 2.333333, 0.666667, 15.000035]",
    ]
    assert '"split_m": 0.3' in path.read_text(encoding="utf-8")
    np.testing.assert_allclose(read_map(path), segments, rtol=0, atol=MICROMETRE / 2)


def test_world_rejects_map_file(tmp_path):
    path = tmp_path / "map.json"
    write_map(path, SEGMENTS, {})
    with pytest.raises(InputError, match=r"map\.json: this is a map file .*not a world file"):
        read_world(path)


def test_world_dataclass_checks_materials():
    with pytest.raises(ValueError, match="1 materials for 4 segments"):
        World(SEGMENTS, np.array(["wall"]))
    with pytest.raises(ValueError, match="unknown material"):
        World(SEGMENTS[:1], np.array(["brick"]))


DROP = object()


def write_doc(path, **fields):
    """A valid map document with ``fields`` replaced (or removed when set to DROP)."""
    document = {"format": "segloc-map", "version": 1, "segments": [[0, 0, 1, 1]]}
    document.update(fields)
    path.write_text(json.dumps({k: v for k, v in document.items() if v is not DROP}))


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"format": "geojson"}, r"`format` is 'geojson'; expected \"segloc-map\" or"),
        ({"format": DROP}, r"`format` is missing"),
        ({"version": DROP}, r"unsupported segloc-map version None"),
        ({"version": 2}, r"unsupported segloc-map version 2"),
        ({"segments": "none"}, r"`segments` must be a list"),
        ({"segments": [[0, 0, 1, 1], [0, 0, 1]]}, r"segment 1 must be 4 finite numbers"),
        ({"segments": [[0, 0, 1, "a"]]}, r"segment 0 must be 4 finite numbers"),
        ({"segments": [[0, 0, 1, 1], [0, 0, 1, True]]}, r"segment 1 must be 4 finite numbers"),
        ({"segments": [[0, 0, 1, 1], [2, 2, 1, 1], [3, 3, 3, 3]]}, r"segment 2 has zero length"),
        ({"segments": []}, r"map has no segments; build one with `segloc map build`"),
    ],
)
def test_map_errors(tmp_path, fields, message):
    path = tmp_path / "map.json"
    write_doc(path, **fields)
    with pytest.raises(InputError, match=r"map\.json: " + message):
        read_map(path)


def test_map_non_finite_coordinate(tmp_path):
    path = tmp_path / "map.json"
    path.write_text(
        '{"format": "segloc-map", "version": 1, "segments": [[0, 0, 1, 1], [0, NaN, 1, 1]]}'
    )
    with pytest.raises(InputError, match=r"map\.json: segment 1 must be 4 finite numbers"):
        read_map(path)


def test_map_not_json_names_the_line(tmp_path):
    path = tmp_path / "map.json"
    path.write_text(
        '{\n  "format": "segloc-map",\n  "version": 1,\n  "segments": [[0, 0, 1, 1],]\n}'
    )
    with pytest.raises(InputError, match=r"map\.json: not valid JSON at line 4"):
        read_map(path)


def test_map_top_level_not_object(tmp_path):
    path = tmp_path / "map.json"
    path.write_text("[[0, 0, 1, 1]]")
    with pytest.raises(InputError, match=r"expected a JSON object"):
        read_map(path)


def test_missing_and_binary_files(tmp_path):
    with pytest.raises(InputError, match=r"gone\.json: file not found"):
        read_map(tmp_path / "gone.json")
    with pytest.raises(InputError, match=r"gone\.json: file not found"):
        read_world(tmp_path / "gone.json")
    binary = tmp_path / "map.json"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    with pytest.raises(InputError, match=r"map\.json: not a text file"):
        read_map(binary)
    with pytest.raises(InputError, match=r"is a directory"):
        read_map(tmp_path)


@pytest.mark.parametrize(
    ("materials", "message"),
    [
        (["wall"], r"`materials` must list one material per segment: 2 segments, materials 1"),
        ("wall", r"`materials` must list one material per segment: 2 segments, materials not a"),
        (["wall", "mirror"], r"segment 1 has unknown material 'mirror'"),
    ],
)
def test_world_material_errors(tmp_path, materials, message):
    path = tmp_path / "world.json"
    document = {
        "format": "segloc-world",
        "version": 1,
        "name": "w",
        "segments": [[0, 0, 1, 0], [1, 0, 1, 1]],
        "materials": materials,
    }
    path.write_text(json.dumps(document))
    with pytest.raises(InputError, match=r"world\.json: " + message):
        read_world(path)
    # read_map checks a world's materials too.
    with pytest.raises(InputError, match="material"):
        read_map(path)


def test_world_with_no_segments(tmp_path):
    path = tmp_path / "world.json"
    path.write_text(json.dumps({"format": "segloc-world", "version": 1, "segments": []}))
    with pytest.raises(InputError, match=r"world\.json: world has no segments"):
        read_world(path)


# --- bounds ----------------------------------------------------------------------------------


def _map_text(segments_text: str) -> str:
    return '{"format": "segloc-map", "version": 1, "segments": ' + segments_text + "}"


@pytest.mark.parametrize(
    ("segments", "message"),
    [
        ("[[0, 0, 1, 1], [1e12, 0, 1, 1]]", r"segment 1 has a coordinate beyond ±1e\+07 m"),
        ("[[0, 0, 1, 0], [0, 0, 2500, 0]]", r"map spans 2500 m × 0 m, more than 2000 m across"),
        ("[[0, 0, 1, 0], [2000, 1500, 2001, 1500]]", r"map spans 2001 m × 1500 m"),
        ("[[0, 0, 1, 1], [5, 5, 5.0000001, 5]]", r"segment 1 has zero length \(its ends lie"),
        ("[[0, 0, 1, " + "1" + "0" * 400 + "]]", r"segment 0 must be 4 finite numbers"),
        ("[[0, 0, 1, " + "9" * 5000 + "]]", r"segment 0 must be 4 finite numbers"),
        ("[[0, 0, 1, 1e400]]", r"segment 0 must be 4 finite numbers"),
        ("[[0, 0, 1, -Infinity]]", r"segment 0 must be 4 finite numbers"),
        ("[" * 100_000 + "]" * 100_000, r"not a map: its JSON is nested too deeply"),
    ],
)
def test_map_bounds(tmp_path, segments, message):
    path = tmp_path / "map.json"
    path.write_text(_map_text(segments))
    with pytest.raises(InputError, match=r"map\.json: " + message) as caught:
        read_map(path)
    assert "\n" not in str(caught.value) and len(str(caught.value)) < 300


def test_map_extent_at_the_bound_is_read(tmp_path):
    path = tmp_path / "map.json"
    segments = np.array([[0.0, 0.0, 1.0, 0.0], [1999.0, 2000.0, 2000.0, 2000.0]])
    write_map(path, segments)
    np.testing.assert_array_equal(read_map(path), segments)
    assert bounds_problem(segments) is None


def test_too_many_segments(tmp_path):
    path = tmp_path / "map.json"
    path.write_text(_map_text(json.dumps([[0, 0, 1, 0]] * (MAX_SEGMENTS + 1))))
    with pytest.raises(InputError, match=r"map\.json: 100001 segments, more than a map may hold"):
        read_map(path)


def test_too_much_wall(tmp_path):
    # 600 walls of 1,999 m each: each inside the extent, 1,199 km in all.
    walls = [[0.0, float(k), 1999.0, float(k)] for k in range(600)]
    path = tmp_path / "map.json"
    path.write_text(_map_text(json.dumps(walls)))
    with pytest.raises(InputError, match=r"map\.json: segments total 1\.1994e\+06 m, more than"):
        read_map(path)


def test_file_too_large_is_not_read(tmp_path):
    path = tmp_path / "map.json"
    with open(path, "wb") as stream:
        stream.truncate(MAX_MAP_BYTES + 1)  # sparse: nothing is written
    with pytest.raises(InputError, match=r"map\.json: file is 33554433 bytes, more than a map"):
        read_map(path)


def test_long_values_are_cut_in_messages(tmp_path):
    path = tmp_path / "map.json"
    path.write_text(_map_text(json.dumps([[0, 0, 1, "x" * 10_000]])))
    with pytest.raises(InputError, match=r"segment 0 must be 4 finite numbers") as caught:
        read_map(path)
    assert len(str(caught.value)) < 300 and str(caught.value).endswith("...")


def test_writers_are_atomic(tmp_path):
    path = tmp_path / "map.json"
    write_map(path, SEGMENTS)
    before = path.read_bytes()
    with pytest.raises(ValueError, match="non-finite"):
        write_map(path, np.array([[0.0, 0.0, np.nan, 1.0]]))
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.json"]
    with pytest.raises(OutputError, match=r"missing/world\.json: cannot write file"):
        write_world(tmp_path / "missing" / "world.json", World(SEGMENTS))
