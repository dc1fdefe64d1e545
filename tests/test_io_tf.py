"""Transform trees of ROS bags (``segloc_cli.io.tf``): which links count, and the chain."""

from __future__ import annotations

import math

import numpy as np
import pytest

from segloc_cli.io.tf import Transform, find_mounting, fixed_links, root_of, transform_matrix

LEVEL = (0.0, 0.0, 0.0, 1.0)


def link(topic: str, parent: str, child: str, x: float, yaw_deg: float = 0.0) -> Transform:
    half = math.radians(yaw_deg) / 2
    return Transform(
        topic, parent, child, (x, 0.0, 0.0), (0.0, 0.0, math.sin(half), math.cos(half))
    )


def test_the_latest_static_link_holds_and_beats_an_unchanging_tf_one():
    links = fixed_links(
        [
            link("/tf", "base_link", "laser", 0.5),
            link("/tf_static", "base_link", "laser", 0.1),
            link("/tf_static", "base_link", "laser", 0.2),
            link("/tf", "base_link", "laser", 0.5),
        ]
    )
    mounting = find_mounting(links, "base_link", "laser")
    assert mounting is not None
    assert mounting.x_m == pytest.approx(0.2, abs=1e-15)
    assert mounting.source == "tf_static:base_link->laser"


def test_frames_match_without_their_leading_slash_and_the_chain_composes():
    links = fixed_links(
        [
            link("/tf_static", "/base_link", "/mount", 1.0, 90.0),
            link("/tf", "mount", "laser", 0.5, 90.0),
            link("/tf", "mount", "laser", 0.5, 90.0),
        ]
    )
    mounting = find_mounting(links, "base_link", "/laser")
    assert mounting is not None
    assert (mounting.x_m, mounting.y_m) == pytest.approx((1.0, 0.5), abs=1e-12)
    assert math.degrees(mounting.theta_rad) == pytest.approx(-180.0, abs=1e-9)
    assert (mounting.tilt_deg, mounting.upside_down) == (0.0, False)
    assert mounting.source == "tf:base_link->laser"
    assert root_of(links, "laser") == "base_link"


def test_frames_of_separate_trees_or_a_loop_have_no_chain():
    apart = fixed_links([link("/tf_static", "a", "laser", 0.1), link("/tf_static", "b", "c", 1)])
    assert find_mounting(apart, "b", "laser") is None
    loop = fixed_links([link("/tf_static", "a", "b", 0.1), link("/tf_static", "b", "a", 0.1)])
    assert find_mounting(loop, "base_link", "a") is None
    assert root_of(loop, "a") == "b"


def test_a_quaternion_of_any_scale_is_the_turn_it_names():
    quarter = transform_matrix((1.0, 2.0, 0.0), (0.0, 0.0, 1.0, 1.0))  # 90° about z
    np.testing.assert_allclose(quarter[:2, :2], [[0.0, -1.0], [1.0, 0.0]], atol=1e-15)
    for scale in (1e-200, 1e-320, 1e200, 1e300):
        q = (0.0, 0.0, scale, scale)
        np.testing.assert_allclose(transform_matrix((1.0, 2.0, 0.0), q), quarter, atol=1e-15)
    with pytest.raises(ValueError, match="all zeros"):
        transform_matrix((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, -0.0))
