"""The compiled geometry helpers on hand-made geometry, and against their numpy twins."""

from __future__ import annotations

import numpy as np
import pytest

from segloc_cli.geometry import (
    TWO_PI,
    Pose2,
    point_segment_distances,
    transform_segments,
    wrap_angle,
)
from segloc_cli.method.kernels import (
    angular_interval,
    out_of_frame,
    point_into_frame,
    point_segment_distance,
    segment_distance_ends,
    wrap,
)

# --- point to segment ----------------------------------------------------------------------

# A 3-4-5 segment from the origin: its unit direction is (0.6, 0.8), its normal (-0.8, 0.6).
OBLIQUE = (0.0, 0.0, 3.0, 4.0)


def test_distance_to_the_interior_is_along_the_normal():
    # (1, 3) stands 3 above the middle of (0, 0)–(4, 0).
    assert point_segment_distance(1.0, 3.0, 0.0, 0.0, 4.0, 0.0) == 3.0
    assert point_segment_distance(1.0, -3.0, 0.0, 0.0, 4.0, 0.0) == 3.0
    # The middle of OBLIQUE, (1.5, 2), plus 5 along its normal: (-2.5, 5).
    assert point_segment_distance(-2.5, 5.0, *OBLIQUE) == 5.0
    # A point on the segment.
    assert point_segment_distance(1.5, 2.0, *OBLIQUE) == 0.0


def test_distance_beyond_either_end_is_to_that_end():
    # Past the first end (0, 0) of (0, 0)–(4, 0): to (-3, 4) it is 5.
    assert point_segment_distance(-3.0, 4.0, 0.0, 0.0, 4.0, 0.0) == 5.0
    # Past the second end (4, 0): to (7, -4) it is 5.
    assert point_segment_distance(7.0, -4.0, 0.0, 0.0, 4.0, 0.0) == 5.0
    # On the line of OBLIQUE but beyond its ends.
    assert point_segment_distance(-3.0, -4.0, *OBLIQUE) == 5.0
    assert point_segment_distance(6.0, 8.0, *OBLIQUE) == 5.0
    # Reversing the segment changes nothing.
    assert point_segment_distance(-3.0, 4.0, 4.0, 0.0, 0.0, 0.0) == 5.0


def test_distance_to_a_zero_length_segment_is_to_its_point():
    assert point_segment_distance(4.0, 5.0, 1.0, 1.0, 1.0, 1.0) == 5.0
    assert point_segment_distance(1.0, 1.0, 1.0, 1.0, 1.0, 1.0) == 0.0


def test_point_segment_distance_agrees_with_the_numpy_version():
    rng = np.random.default_rng(3)
    points = rng.uniform(-10.0, 10.0, (200, 2))
    segments = rng.uniform(-10.0, 10.0, (50, 4))
    segments[:5, 2:4] = segments[:5, 0:2]  # some of zero length
    expected = point_segment_distances(points, segments)
    got = np.array([[point_segment_distance(*p, *s) for s in segments] for p in points])
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)


# --- segment to segment ----------------------------------------------------------------------


def test_segment_distance():
    horizontal = np.array([0.0, 0.0, 4.0, 0.0])
    # Crossing, and touching at an end: 0.
    assert segment_distance_ends(*horizontal, *[2.0, -1.0, 2.0, 1.0]) == 0.0
    assert segment_distance_ends(*horizontal, *[4.0, 0.0, 5.0, 3.0]) == 0.0
    # Parallel, 3 apart and overlapping in x.
    assert segment_distance_ends(*horizontal, *[1.0, 3.0, 6.0, 3.0]) == 3.0
    # A T short of the bar: 2 from the stem's end to the bar's interior, either order.
    stem = np.array([2.0, 2.0, 2.0, 7.0])
    assert segment_distance_ends(*horizontal, *stem) == 2.0
    assert segment_distance_ends(*stem, *horizontal) == 2.0
    # End to end: (4, 0) to (7, 4).
    assert segment_distance_ends(*horizontal, *[7.0, 4.0, 9.0, 4.0]) == 5.0


# --- angles ----------------------------------------------------------------------------------


def test_wrap_maps_plus_and_minus_pi_to_minus_pi_like_wrap_angle():
    for angle in (np.pi, -np.pi):
        assert wrap(angle) == -np.pi
        assert wrap(angle) == wrap_angle(angle)


@pytest.mark.parametrize("k", range(-4, 5))
def test_wrap_agrees_with_wrap_angle_at_multiples_of_pi(k):
    # 2kπ → 0 and 2kπ ± π → −π, bit for bit, for |k| ≤ 4.
    for angle, expected in ((k * TWO_PI, 0.0), (k * TWO_PI + np.pi, -np.pi)):
        assert wrap(angle) == expected
        assert wrap(angle) == wrap_angle(angle)
    assert wrap(k * TWO_PI - np.pi) == wrap_angle(k * TWO_PI - np.pi) == -np.pi


def test_wrap_and_wrap_angle_part_only_in_the_last_bit():
    # One subtracts 2π·floor(·), the other takes a remainder: over the angles the kernels
    # see (within a few turns) they agree to one ulp of 2π, and exactly at most angles.
    angles = np.concatenate(
        [
            np.linspace(-4.0 * np.pi, 4.0 * np.pi, 20001),
            np.random.default_rng(1).uniform(-4.0, -3.0, 5000),  # full-precision low bits
            np.nextafter(np.array([np.pi, -np.pi, np.pi, -np.pi]), [0.0, 0.0, 4.0, -4.0]),
        ]
    )
    compiled = np.array([wrap(a) for a in angles])
    vectorised = wrap_angle(angles)
    assert np.max(np.abs(compiled - vectorised)) <= np.spacing(TWO_PI)
    assert np.mean(compiled == vectorised) > 0.9
    assert np.all(compiled >= -np.pi - np.spacing(np.pi))
    assert np.all(compiled < np.pi)


def test_angular_interval():
    # A wall in front, x = 1 from y = −1 to 1: centred ahead, ±45°.
    centre, half = angular_interval(1.0, -1.0, 1.0, 1.0)
    assert centre == 0.0
    assert half == pytest.approx(np.pi / 4.0, abs=1e-15)
    # Its ends either way round: the same interval.
    assert angular_interval(1.0, 1.0, 1.0, -1.0) == (centre, half)
    # Behind, across ±π: centred on −π (not +π), still ±45°.
    centre, half = angular_interval(-1.0, 1.0, -1.0, -1.0)
    assert centre == -np.pi
    assert half == pytest.approx(np.pi / 4.0, abs=1e-15)


# --- frames ----------------------------------------------------------------------------------


def test_point_into_frame_by_hand():
    # A robot at (1, 2) facing +y: the world point (1, 5) is 3 straight ahead.
    x, y = point_into_frame(1.0, 5.0, 1.0, 2.0, 0.0, 1.0)
    assert (x, y) == (3.0, 0.0)
    # The world point (0, 2) is 1 to its left.
    assert point_into_frame(0.0, 2.0, 1.0, 2.0, 0.0, 1.0) == (0.0, 1.0)


def test_points_into_and_segments_out_of_frame_match_transform_segments():
    rng = np.random.default_rng(4)
    segments = rng.uniform(-5.0, 5.0, (30, 4))
    pose = Pose2(1.5, -0.5, 2.5)
    c, s = np.cos(pose.theta), np.sin(pose.theta)
    robot = np.array(
        [
            [
                *point_into_frame(a, b, pose.x, pose.y, c, s),
                *point_into_frame(d, e, pose.x, pose.y, c, s),
            ]
            for a, b, d, e in segments
        ]
    )
    np.testing.assert_allclose(
        robot, transform_segments(segments, pose.inverse()), rtol=0, atol=1e-12
    )
    world = out_of_frame(robot, pose.x, pose.y, pose.theta)
    np.testing.assert_allclose(world, transform_segments(robot, pose), rtol=0, atol=1e-12)
    np.testing.assert_allclose(world, segments, rtol=0, atol=1e-12)
