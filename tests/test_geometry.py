"""Exact tests of the planar geometry helpers: angles, poses, frame changes."""

from __future__ import annotations

import numpy as np
import pytest

from segloc_cli.geometry import (
    Pose2,
    as_segments,
    chained_motions,
    circular_mean,
    relative_motion,
    rotation,
    segment_lengths,
    segment_orientations,
    transform_points,
    transform_segments,
    wrap_angle,
)

PI = np.pi


# --- wrap_angle -------------------------------------------------------------------------------


def test_wrap_angle_maps_both_pi_edges_to_minus_pi():
    # [-π, π): +π is the same direction as −π and must come out as −π.
    assert wrap_angle(PI) == -PI
    assert wrap_angle(-PI) == -PI
    assert wrap_angle(3 * PI) == pytest.approx(-PI, abs=1e-12)
    assert wrap_angle(-3 * PI) == pytest.approx(-PI, abs=1e-12)


def test_wrap_angle_just_inside_the_edges_is_unchanged():
    assert wrap_angle(PI - 1e-6) == pytest.approx(PI - 1e-6, abs=1e-12)
    assert wrap_angle(-PI + 1e-6) == pytest.approx(-PI + 1e-6, abs=1e-12)
    # Just past +π wraps to just past −π, and the other way round.
    assert wrap_angle(PI + 0.1) == pytest.approx(-PI + 0.1, abs=1e-12)
    assert wrap_angle(-PI - 0.1) == pytest.approx(PI - 0.1, abs=1e-12)


def test_wrap_angle_arrays_and_whole_turns():
    base = np.array([-3.0, -1.0, 0.0, 0.5, 2.5, 3.1])
    for turns in (-3, -1, 1, 2, 5):
        np.testing.assert_allclose(wrap_angle(base + turns * 2 * PI), base, atol=1e-12)
    # 270° → −90°, −270° → 90°, 540° → −180°.
    np.testing.assert_allclose(
        wrap_angle(np.deg2rad([270.0, -270.0, 540.0])),
        np.deg2rad([-90.0, 90.0, -180.0]),
        atol=1e-12,
    )


def test_wrap_angle_never_leaves_the_half_open_interval():
    angles = np.linspace(-20 * PI, 20 * PI, 100_001)
    wrapped = wrap_angle(angles)
    assert np.all(wrapped >= -PI)
    assert np.all(wrapped < PI)


# --- circular_mean ----------------------------------------------------------------------------


def test_circular_mean_across_the_pi_seam():
    # 170° and −170° are 20° apart across ±180°: their mean is 180°, not 0°.
    mean = circular_mean(np.deg2rad([170.0, -170.0]))
    assert abs(wrap_angle(mean - PI)) < 1e-12
    # Weights 1 and 3 on 180° ∓ 10°: the vector sum is
    #   (cos170 + 3·cos190, sin170 + 3·sin190) = (−4·cos10, −2·sin10),
    # so the mean is atan2(−2·sin10, −4·cos10) = −180° + atan(tan(10°)/2) ≈ −175.04°.
    mean = circular_mean(np.deg2rad([170.0, -170.0]), np.array([1.0, 3.0]))
    expected = -PI + np.arctan(np.tan(np.deg2rad(10.0)) / 2.0)
    assert mean == pytest.approx(expected, abs=1e-12)


def test_circular_mean_of_symmetric_pair_is_the_bisector():
    # −30° and +50° with equal weights: bisector 10°.
    assert circular_mean(np.deg2rad([-30.0, 50.0])) == pytest.approx(np.deg2rad(10.0), abs=1e-12)
    # Weights only matter relatively.
    a = np.deg2rad([10.0, 40.0, 100.0])
    assert circular_mean(a, [1.0, 2.0, 3.0]) == pytest.approx(
        circular_mean(a, [2.0, 4.0, 6.0]), abs=1e-15
    )


def test_circular_mean_result_is_in_half_open_interval():
    # The docstring promises [-π, π). Two headings symmetric about 180° average to 180°
    # exactly (the sines cancel to +0.0, so atan2 returns +π); that must come out as −π,
    # as every other heading in the package is wrapped.
    mean = circular_mean(np.deg2rad([179.0, -179.0]))
    assert -PI <= mean < PI, (
        f"circular_mean returned {mean!r}, outside [-π, π): atan2 can return +π; "
        "the result should be passed through wrap_angle"
    )


# --- Pose2 ------------------------------------------------------------------------------------


def test_pose_from_deg_and_back():
    p = Pose2.from_deg(1.0, -2.0, 90.0)
    assert p.theta == pytest.approx(PI / 2, abs=1e-15)
    assert p.theta_deg == pytest.approx(90.0, abs=1e-12)
    np.testing.assert_array_equal(p.as_array(), [1.0, -2.0, p.theta])


def test_pose_compose_exact():
    # a = (1, 2, 90°); b = (1, 0, 0) in a's frame: one metre along a's x axis, which points
    # along world +y → (1, 3), heading 90°.
    a = Pose2.from_deg(1.0, 2.0, 90.0)
    b = Pose2(1.0, 0.0, 0.0)
    c = a.compose(b)
    assert (c.x, c.y) == pytest.approx((1.0, 3.0), abs=1e-12)
    assert c.theta_deg == pytest.approx(90.0, abs=1e-12)
    # (0, 0, 150°) ⊕ (2, 1, 60°): position R(150°)·(2, 1) = (2cos150 − sin150, 2sin150 + cos150)
    # = (−√3 − 0.5, 1 − √3/2); heading 210° wraps to −150°.
    d = Pose2.from_deg(0.0, 0.0, 150.0).compose(Pose2.from_deg(2.0, 1.0, 60.0))
    assert (d.x, d.y) == pytest.approx((-np.sqrt(3) - 0.5, 1 - np.sqrt(3) / 2), abs=1e-12)
    assert d.theta_deg == pytest.approx(-150.0, abs=1e-12)


def test_pose_inverse_exact_and_round_trip():
    # (1, 2, 90°)⁻¹: heading −90°, position −R(−90°)·(1, 2) = −(2, −1) = (−2, 1).
    p = Pose2.from_deg(1.0, 2.0, 90.0)
    q = p.inverse()
    assert (q.x, q.y) == pytest.approx((-2.0, 1.0), abs=1e-12)
    assert q.theta_deg == pytest.approx(-90.0, abs=1e-12)
    rng = np.random.default_rng(7)
    for x, y, t in rng.uniform([-10, -10, -4], [10, 10, 4], size=(50, 3)):
        p = Pose2(float(x), float(y), float(t))
        for ident in (p.compose(p.inverse()), p.inverse().compose(p)):
            assert ident.x == pytest.approx(0.0, abs=1e-12)
            assert ident.y == pytest.approx(0.0, abs=1e-12)
            assert abs(wrap_angle(ident.theta)) < 1e-12
        back = p.inverse().inverse()
        assert (back.x, back.y) == pytest.approx((p.x, p.y), abs=1e-12)
        assert abs(wrap_angle(back.theta - p.theta)) < 1e-12


def test_pose_compose_wraps_heading():
    c = Pose2.from_deg(0, 0, 170.0).compose(Pose2.from_deg(0, 0, 20.0))
    assert c.theta_deg == pytest.approx(-170.0, abs=1e-12)


# --- frame changes ----------------------------------------------------------------------------


def test_rotation_matrix():
    np.testing.assert_allclose(rotation(PI / 2), [[0.0, -1.0], [1.0, 0.0]], atol=1e-15)


def test_transform_points_and_segments_exact():
    pose = Pose2.from_deg(1.0, 2.0, 90.0)
    # R(90°)(x, y) = (−y, x), then + (1, 2).
    np.testing.assert_allclose(
        transform_points([[1.0, 0.0], [0.0, 1.0], [2.0, -3.0]], pose),
        [[1.0, 3.0], [0.0, 2.0], [4.0, 4.0]],
        atol=1e-12,
    )
    segs = np.array([[1.0, 0.0, 2.0, 0.0], [0.0, 1.0, 2.0, -3.0]])
    np.testing.assert_allclose(
        transform_segments(segs, pose), [[1.0, 3.0, 1.0, 4.0], [0.0, 2.0, 4.0, 4.0]], atol=1e-12
    )
    # 180° about (−1, 0): (x, y) → (−1 − x, −y).
    np.testing.assert_allclose(
        transform_segments([[0.0, 1.0, 1.0, 1.0]], Pose2.from_deg(-1.0, 0.0, 180.0)),
        [[-1.0, -1.0, -2.0, -1.0]],
        atol=1e-12,
    )


def test_transform_segments_composes_and_inverts():
    rng = np.random.default_rng(3)
    segs = rng.uniform(-5, 5, size=(6, 4))
    a = Pose2(0.7, -1.2, 2.5)
    b = Pose2(-3.0, 0.4, -1.1)
    # Expressed in b's frame, then b into a's frame == in (a ⊕ b)'s frame directly.
    np.testing.assert_allclose(
        transform_segments(transform_segments(segs, b), a),
        transform_segments(segs, a.compose(b)),
        atol=1e-12,
    )
    np.testing.assert_allclose(
        transform_segments(transform_segments(segs, a), a.inverse()), segs, atol=1e-12
    )
    # Rigid motion: lengths unchanged, orientations shifted by the heading (mod 180°).
    moved = transform_segments(segs, a)
    np.testing.assert_allclose(segment_lengths(moved), segment_lengths(segs), atol=1e-12)
    shift = (segment_orientations(moved) - segment_orientations(segs) - a.theta) % PI
    assert np.all(np.minimum(shift, PI - shift) < 1e-12)


def test_transform_segments_accepts_flat_and_empty():
    assert transform_segments(np.zeros((0, 4)), Pose2(1, 2, 3)).shape == (0, 4)
    np.testing.assert_allclose(
        transform_segments([1.0, 0.0, 2.0, 0.0], Pose2(0.0, 0.0, 0.0)), [[1.0, 0.0, 2.0, 0.0]]
    )


def test_segment_lengths_and_undirected_orientations():
    segs = np.array(
        [
            [0.0, 0.0, 3.0, 4.0],  # length 5, atan2(4, 3)
            [0.0, 0.0, -1.0, 0.0],  # pointing along −x: orientation 0, not 180°
            [1.0, 1.0, 0.0, 0.0],  # pointing at −135°: orientation 45°
            [0.0, 0.0, 0.0, -2.0],  # pointing down: orientation 90°
        ]
    )
    np.testing.assert_allclose(segment_lengths(segs), [5.0, 1.0, np.sqrt(2.0), 2.0])
    np.testing.assert_allclose(
        segment_orientations(segs), [np.arctan2(4.0, 3.0), 0.0, PI / 4, PI / 2], atol=1e-15
    )


def test_as_segments_validates():
    assert as_segments([]).shape == (0, 4)
    np.testing.assert_array_equal(as_segments([[1, 2, 3, 4]]), [[1.0, 2.0, 3.0, 4.0]])
    with pytest.raises(ValueError, match="shape"):
        as_segments([1.0, 2.0, 3.0, 4.0])
    with pytest.raises(ValueError, match="shape"):
        as_segments([[1.0, 2.0, 3.0]])
    with pytest.raises(ValueError, match="non-finite"):
        as_segments([[0.0, 0.0, np.nan, 1.0]])


def test_chained_motions_undo_relative_motion_across_the_wrap():
    """Poses turning through ±180°: their motions chained from the first give them back."""
    poses = np.array([[1.0, 2.0, 3.0], [1.5, 2.2, -3.0], [0.5, 3.0, 2.9], [0.0, 0.0, -1.0]])
    again = chained_motions(poses[0], relative_motion(poses[:-1], poses[1:]))
    np.testing.assert_allclose(again[:, :2], poses[:, :2], atol=1e-12)
    np.testing.assert_allclose(wrap_angle(again[:, 2] - poses[:, 2]), 0.0, atol=1e-12)
    np.testing.assert_array_equal(chained_motions(poses[0], np.zeros((0, 3))), poses[:1])
