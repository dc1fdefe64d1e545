"""Fuzzing the ROS bag reader: a mangled ROS 1 bag (index, chunks, records) yields scans or
one line naming the bag, never another exception."""

from __future__ import annotations

import numpy as np
from fuzzing import byte_mutations, fuzz_settings, mutate, outcome
from hypothesis import given
from hypothesis import strategies as st
from test_io_rosbag import write_ros1_in_chunks

from segloc_cli.errors import InputError
from segloc_cli.io.rosbag import read_rosbag


@given(mutations=st.lists(byte_mutations(length_fields=True), min_size=1, max_size=4))
@fuzz_settings
def test_a_mangled_ros1_bag_gives_scans_or_one_line(tmp_path_factory, mutations):
    folder = tmp_path_factory.mktemp("mangled")
    whole = write_ros1_in_chunks(folder / "whole.bag", "BZ2")
    path = folder / "mangled.bag"
    path.write_bytes(mutate(whole.read_bytes(), mutations))
    result = outcome(read_rosbag, path)
    if not isinstance(result, InputError):
        assert all(np.all(np.isfinite(s.angles_rad)) for s in result.scans)
        assert np.all(np.diff([s.time_s for s in result.scans]) > 0)
