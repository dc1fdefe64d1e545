"""Distinct record times: the colliding-times rule on hand-made times, and its properties."""

from __future__ import annotations

import numpy as np
import pytest
from fuzzing import fuzz_settings
from hypothesis import given
from hypothesis import strategies as st

from segloc_cli.io.times import colliding, distinct_times, time_groups


def test_all_zeros_are_one_second_apart():
    np.testing.assert_array_equal(distinct_times(np.zeros(5)), [0.0, 1.0, 2.0, 3.0, 4.0])
    np.testing.assert_array_equal(colliding(np.zeros(5)), [True] * 5)
    np.testing.assert_array_equal(distinct_times(np.full(1, 7.5)), [7.5])
    assert distinct_times(np.zeros(0)).shape == (0,)


def test_six_significant_digit_groups_spread_over_their_gaps():
    t0, t1, t2 = 1.13486e9, 1.13487e9, 1.13488e9
    times = np.array([t0] * 4 + [t1] * 2 + [t2] * 3)
    # Gaps per record: 10000/4 = 2500 s and 10000/2 = 5000 s; the last group would be
    # spaced by their median, 3750 s, but is held to 1 s apart.
    expected = [t0, t0 + 2500, t0 + 5000, t0 + 7500, t1, t1 + 5000, t2, t2 + 1, t2 + 2]
    np.testing.assert_array_equal(distinct_times(times), expected)
    np.testing.assert_array_equal(time_groups(times), [0, 0, 0, 0, 1, 1, 2, 2, 2])
    assert colliding(times).all()


def test_one_duplicate_pair():
    times = np.array([0.0, 0.1, 0.2, 0.2, 0.4, 0.5])
    out = distinct_times(times)
    # The pair spreads over [0.2, 0.4): 0.2 and 0.2 + 0.2/2.
    np.testing.assert_array_equal(out, [0.0, 0.1, 0.2, 0.2 + (0.4 - 0.2) / 2, 0.4, 0.5])
    np.testing.assert_array_equal(colliding(times), [False, False, True, True, False, False])


def test_a_step_back_joins_the_group_before_it():
    times = np.array([10.0, 11.0, 12.0, 11.5, 11.9, 15.0])
    np.testing.assert_array_equal(distinct_times(times), [10.0, 11.0, 12.0, 13.0, 14.0, 15.0])
    np.testing.assert_array_equal(time_groups(times), [0, 1, 2, 2, 2, 3])
    # Going back below an earlier group's time still joins the current group.
    np.testing.assert_array_equal(distinct_times(np.array([5.0, 6.0, 1.0, 8.0])), [5, 6, 7, 8])


def test_a_colliding_last_group_takes_the_median_interval():
    times = np.array([0.0, 1.0, 3.0, 4.0, 4.0, 4.0])
    # Intervals per record before it: 1, 2, 1 → median 1.
    np.testing.assert_array_equal(distinct_times(times), [0, 1, 3, 4, 5, 6])


def test_increasing_times_come_back_identical():
    times = np.array([0.1, 0.30000000000000004, 1e-300, 2.5, 1134864629.895182, 1e9 + 1e-6])
    times = np.sort(times)
    out = distinct_times(times)
    assert out.tobytes() == times.tobytes()
    assert out is not times
    assert not colliding(times).any()


def test_gaps_too_narrow_for_floats_are_nudged():
    # 1e-7 s at 1e9 s is less than one float step: the times rise by single steps.
    times = np.array([1e9, 1e9, 1e9, 1e9 + 1e-7])
    out = distinct_times(times)
    assert np.all(np.diff(out) > 0)
    assert out[0] == 1e9
    assert out[1] == np.nextafter(1e9, np.inf)


@pytest.mark.parametrize(
    "bad", [np.array([0.0, np.nan]), np.array([np.inf]), np.array([[0.0, 1.0]])]
)
def test_non_finite_or_misshapen_times_are_refused(bad):
    with pytest.raises(ValueError, match="times must be"):
        distinct_times(bad)


# Times as logs print them: milliseconds over a day, often repeated, sometimes going back.
times_ms = st.lists(st.integers(min_value=0, max_value=86_400_000), min_size=1, max_size=60)


@given(times_ms, st.sampled_from([0.0, 1.13486e9]))
@fuzz_settings
def test_properties(ms, base):
    times = base + np.array(ms, dtype=float) / 1000.0
    out = distinct_times(times)
    groups = time_groups(times)
    assert out.shape == times.shape
    assert np.all(np.diff(out) > 0)
    # Records alone in their group keep their exact value ...
    alone = ~colliding(times)
    np.testing.assert_array_equal(out[alone], times[alone])
    # ... and every record lies at or after its group's time, before the next group's.
    first = np.flatnonzero(np.r_[True, np.diff(groups) > 0])
    group_time = times[first][groups]
    assert np.all(out >= group_time)
    next_time = np.append(times[first][1:], np.inf)[groups]
    assert np.all(out < next_time)
