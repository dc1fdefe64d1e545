"""Map and world files on hostile text: a bounded map or one line naming the file, never more."""

from __future__ import annotations

import json

import numpy as np
from fuzzing import fuzz_settings, outcome
from hypothesis import given
from hypothesis import strategies as st

from segloc_cli.errors import InputError
from segloc_cli.io.maps import (
    MAX_COORDINATE_M,
    MAX_MAP_EXTENT_M,
    MAX_SEGMENTS,
    MAX_TOTAL_LENGTH_M,
    MIN_SEGMENT_LENGTH_M,
    read_map,
    read_world,
)
from segloc_cli.world import World


def _check_segments(segments: np.ndarray) -> None:
    assert isinstance(segments, np.ndarray) and segments.dtype == np.float64
    assert segments.ndim == 2 and segments.shape[1] == 4
    assert 1 <= segments.shape[0] <= MAX_SEGMENTS
    assert np.all(np.isfinite(segments))
    assert np.all(np.abs(segments) <= MAX_COORDINATE_M)
    ends = segments.reshape(-1, 2)
    assert np.all(ends.max(axis=0) - ends.min(axis=0) <= MAX_MAP_EXTENT_M)
    lengths = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    assert np.all(lengths >= MIN_SEGMENT_LENGTH_M)
    assert lengths.sum() <= MAX_TOTAL_LENGTH_M


def _read_both(path) -> None:
    """Both readers end in a bounded result or one line naming the file."""
    result = outcome(read_map, path)
    if not isinstance(result, InputError):
        _check_segments(result)
    world = outcome(read_world, path)
    if not isinstance(world, InputError):
        assert isinstance(world, World)
        _check_segments(world.segments)
        assert len(world.materials) == len(world.segments)


numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-3000.0, max_value=3000.0),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.sampled_from([0, 1, -1, 1e7, 1e7 + 1, -1e12, 5e-324, 2000.0, 2000.0001]),
)
values = st.one_of(numbers, st.booleans(), st.none(), st.text(max_size=5), st.lists(numbers))
segment = st.one_of(st.lists(numbers, min_size=4, max_size=4), st.lists(values, max_size=5))


@given(
    segments=st.lists(segment, max_size=12),
    kind=st.sampled_from(["segloc-map", "segloc-world"]),
    materials=st.one_of(st.none(), st.lists(st.sampled_from(["wall", "glass", "rock", 3]))),
    version=st.sampled_from([1, 1.0, True, 2, "1", None]),
)
@fuzz_settings
def test_valid_structure_with_hostile_values(tmp_path, segments, kind, materials, version):
    document = {"format": kind, "version": version, "segments": segments}
    if materials is not None:
        document["materials"] = materials
    path = tmp_path / "map.json"
    path.write_text(json.dumps(document, allow_nan=True))
    _read_both(path)


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=8)),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=30,
)


@given(body=json_values, header=st.booleans())
@fuzz_settings
def test_random_json(tmp_path, body, header):
    document = {"format": "segloc-map", "version": 1, "segments": body} if header else body
    path = tmp_path / "map.json"
    path.write_text(json.dumps(document, allow_nan=True))
    _read_both(path)


@given(depth=st.integers(min_value=1, max_value=200_000), where=st.sampled_from(["top", "in"]))
@fuzz_settings
def test_deep_nesting(tmp_path, depth, where):
    nested = "[" * depth + "]" * depth
    text = nested if where == "top" else '{"format": "segloc-map", "version": 1, "segments": '
    if where == "in":
        text += nested + "}"
    path = tmp_path / "map.json"
    path.write_text(text)
    _read_both(path)


@given(
    number=st.one_of(
        st.integers(min_value=1, max_value=6000).map(lambda k: "1" + "0" * k),
        st.integers(min_value=1, max_value=6000).map(lambda k: "-" + "9" * k),
        st.sampled_from(["1e400", "-1e309", "1e-400", "NaN", "Infinity", "-Infinity", "1E+99"]),
    ),
    slot=st.integers(min_value=0, max_value=3),
)
@fuzz_settings
def test_huge_numbers(tmp_path, number, slot):
    values = ["0", "0", "1", "1"]
    values[slot] = number
    path = tmp_path / "map.json"
    path.write_text(
        '{"format": "segloc-map", "version": 1, "segments": [[' + ", ".join(values) + "]]}"
    )
    _read_both(path)


VALID = json.dumps(
    {
        "format": "segloc-world",
        "version": 1,
        "segments": [[0, 0, 4, 0], [4, 0, 4, 3], [4, 3, 0, 3]],
        "materials": ["wall", "glass", "wall"],
    }
).encode()


@given(
    edits=st.lists(
        st.tuples(st.integers(min_value=0, max_value=len(VALID) - 1), st.binary(max_size=3)),
        min_size=1,
        max_size=6,
    ),
    cut=st.integers(min_value=1, max_value=len(VALID)),
)
@fuzz_settings
def test_mangled_bytes(tmp_path, edits, cut):
    data = bytearray(VALID[:cut])
    for index, replacement in edits:
        index = min(index, max(len(data) - 1, 0))
        data[index : index + len(replacement)] = replacement
    path = tmp_path / "map.json"
    path.write_bytes(bytes(data))
    _read_both(path)


def test_the_valid_document_reads(tmp_path):
    """The text the mangling starts from is a world, so the mangled cases are near misses."""
    path = tmp_path / "world.json"
    path.write_bytes(VALID)
    assert read_world(path).materials.tolist() == ["wall", "glass", "wall"]
