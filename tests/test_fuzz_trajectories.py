"""Another localizer's trajectory of arbitrary and mangled input: poses or one line.

A TUM file of any bytes read by ``read_trajectory`` ends in estimates whose times rise and
whose poses are finite, level enough and within bounds, or in an ``InputError`` of one line
naming the file. A transform chain composed by ``compose_chain`` from any transforms (frames
from a few names, any numbers, stamps, static or not) ends in a chain or a ``ChainError`` of
one line; a chain is composed only at stamps where every moving link's latest transform is
usable (not at a stamp where it was given as NaN, with the value before).
"""

from __future__ import annotations

from itertools import combinations, pairwise

import numpy as np
from fuzzing import ODD_TOKENS, fuzz_settings, outcome
from hypothesis import example, given
from hypothesis import strategies as st

from segloc_cli.errors import InputError
from segloc_cli.io.pose_messages import Link
from segloc_cli.io.tf import transform_matrix
from segloc_cli.io.tf_chain import MAX_LINK_AGE_S, Chain, ChainError, compose_chain
from segloc_cli.io.times import NS_PER_S
from segloc_cli.io.trajectories import read_trajectory
from segloc_cli.limits import MAX_COORDINATE_M

GOOD_NUMBERS = st.one_of(
    st.floats(min_value=-1e3, max_value=1e3, allow_nan=False).map(repr),
    st.integers(min_value=-5, max_value=50).map(str),
)
TOKEN = st.one_of(GOOD_NUMBERS, GOOD_NUMBERS, GOOD_NUMBERS, st.sampled_from(ODD_TOKENS))


def check_estimates(tmp_path, data: bytes) -> None:
    path = tmp_path / "est.tum"
    path.write_bytes(data)
    result = outcome(lambda p: read_trajectory(p, fmt="tum"), path)
    if isinstance(result, InputError):
        return
    assert len(result) > 0
    times = result["time_s"].to_numpy(dtype=float)
    assert np.all(np.isfinite(times)) and np.all(np.diff(times) > 0)
    xy = result[["x_m", "y_m"]].to_numpy(dtype=float)
    assert np.all(np.isfinite(xy)) and np.all(np.abs(xy) <= MAX_COORDINATE_M)
    theta = result["theta_deg"].to_numpy(dtype=float)
    assert np.all((theta >= -180.0) & (theta < 180.0))
    assert all(isinstance(w, str) and "\n" not in w for w in result.attrs["warnings"])


@given(st.binary(max_size=1500))
@fuzz_settings
def test_arbitrary_bytes_as_a_tum_trajectory(tmp_path, data):
    check_estimates(tmp_path, data)


@given(
    st.lists(st.lists(TOKEN, min_size=7, max_size=9), max_size=12),
    st.sampled_from(["\n", "\r\n", "\t\n"]),
    st.booleans(),
)
@fuzz_settings
def test_tum_lines_of_odd_numbers(tmp_path, lines, newline, bom):
    text = newline.join(" ".join(fields) for fields in lines)
    check_estimates(tmp_path, ("\ufeff" if bom else "").encode() + text.encode("utf-8"))


FRAMES = ["map", "odom", "base_link", "laser"]
VALUE = st.one_of(
    st.floats(min_value=-10.0, max_value=10.0),
    st.floats(min_value=-10.0, max_value=10.0),
    st.sampled_from([np.nan, np.inf, -np.inf, 0.0, 1e300, -1e300, 1e-300]),
)
# Mostly the links of one tree (map → odom → base_link → laser), so that chains are composed
# often; sometimes any two frames (loops, a second parent).
EDGE = st.one_of(
    *[st.sampled_from(list(pairwise(FRAMES)))] * 6,
    st.tuples(st.sampled_from(FRAMES), st.sampled_from(FRAMES)),
)
QUERY = st.one_of(
    *[st.sampled_from(list(combinations(FRAMES, 2)))] * 4,
    st.tuples(st.sampled_from(FRAMES), st.sampled_from(FRAMES)),
)
LEVEL = (0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
TREE = [Link(0, parent, child, LEVEL, False) for parent, child in pairwise(FRAMES)]
"""Every link of the tree, level, at 0 s: what a drawn list of transforms may start with."""
LINKS = st.tuples(
    st.booleans(),
    st.lists(
        st.builds(
            lambda edge, stamp_ns, values, static: Link(stamp_ns, *edge, values, static),
            EDGE,
            st.integers(0, 30).map(lambda k: k * NS_PER_S // 2),
            st.one_of(st.tuples(*[VALUE] * 7), *[st.just(LEVEL)] * 2),
            st.sampled_from([False, False, False, True]),
        ),
        max_size=25,
    ),
).map(lambda drawn: (TREE if drawn[0] else []) + drawn[1])


def usable(link: Link) -> bool:
    try:
        transform_matrix(link.values[:3], link.values[3:])
    except ValueError:
        return False
    return True


@given(LINKS, QUERY)
@example(  # odom → base_link NaN at 1 s, where map → odom is given afresh
    [
        *TREE,
        Link(NS_PER_S, "odom", "base_link", (np.nan, *LEVEL[1:]), False),
        Link(NS_PER_S, "map", "odom", LEVEL, False),
    ],
    ("map", "base_link"),
)
@fuzz_settings
def test_any_transforms_give_a_chain_of_fresh_links_or_one_line(links, frames):
    parent, child = frames
    try:
        chain = compose_chain(links, parent, child)
    except ChainError as exc:
        assert "\n" not in str(exc)
        return
    assert isinstance(chain, Chain)
    stamps = chain.stamps_ns.tolist()
    assert stamps == sorted(set(stamps)) and len(stamps) == len(chain.matrices)
    on_chain = dict(pairwise(chain.frames))
    static = {link.child for link in links if link.static and usable(link)}
    for stamp in stamps:
        for below, above in on_chain.items():
            if below in static:
                continue
            given_before = [
                link
                for link in links
                if (link.child, link.parent) == (below, above)
                and not link.static
                and link.stamp_ns <= stamp
            ]
            assert given_before, f"{above} → {below} composed at {stamp} before it was given"
            latest = max(link.stamp_ns for link in given_before)
            assert stamp - latest <= MAX_LINK_AGE_S * NS_PER_S
            first_at_latest = next(link for link in given_before if link.stamp_ns == latest)
            assert usable(first_at_latest), f"{above} → {below} composed at {stamp} from a NaN"
