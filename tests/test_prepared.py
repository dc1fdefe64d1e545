"""The prepared map: what it builds for which settings, and what it shares between them."""

from __future__ import annotations

import numpy as np
import pytest

from segloc_cli.config import LocalizeParams, SearchParams
from segloc_cli.geometry import Pose2
from segloc_cli.method.extract import extract_segments
from segloc_cli.method.localize import Localizer
from segloc_cli.method.prepared import prepare_map
from segloc_cli.method.spatial import NEAR_CELL_M
from segloc_cli.sim import NOISE_FREE, random_free_poses, random_world, simulate_scan

ROOM = random_world(np.random.default_rng(11))


def test_a_map_prepared_for_other_settings_shares_what_they_leave_unchanged():
    first = prepare_map(ROOM.segments)
    same_bins = first.for_params(LocalizeParams(grid_m=1.0))
    assert same_bins.rtable is first.rtable and same_bins.index is first.index
    assert same_bins.search is first.search and same_bins.near_index is first.near_index
    finer = first.for_params(LocalizeParams(bin_deg=0.5))
    assert finer.rtable is not first.rtable and finer.index is first.index
    assert finer.search is first.search
    wider = first.for_params(LocalizeParams(search=SearchParams(half_width_m=3.0)))
    assert wider.search is not first.search and wider.search.params.half_width_m == 3.0
    assert wider.search.pyramid is first.search.pyramid  # the square searched is no raster
    assert wider.rtable is first.rtable
    coarser = first.for_params(LocalizeParams(search=SearchParams(cell_m=0.1)))
    assert coarser.search.pyramid is not first.search.pyramid


def test_a_wider_square_finds_what_a_search_built_for_it_finds():
    rng = np.random.default_rng(12)
    true = Pose2(*random_free_poses(ROOM, 1, rng)[0])
    points = simulate_scan(ROOM, true, NOISE_FREE, rng, 0.0).points()
    guess = Pose2(true.x + 2.3, true.y - 0.4, true.theta + 0.05)  # beyond the default 2 m
    wide = LocalizeParams(search=SearchParams(half_width_m=2.5))
    shared = prepare_map(ROOM.segments).for_params(wide).search
    built = prepare_map(ROOM.segments, wide).search
    found = shared.around(points, guess, 10.0)
    assert found == built.around(points, guess, 10.0)
    assert np.hypot(found[0].pose.x - true.x, found[0].pose.y - true.y) < 0.1


def test_the_search_is_built_only_where_the_settings_run_it():
    assert prepare_map(ROOM.segments).search is not None
    paper = LocalizeParams(refine=None)
    assert prepare_map(ROOM.segments, paper).search is None
    assert prepare_map(ROOM.segments, LocalizeParams(search=None)).search is None
    assert prepare_map(ROOM.segments, paper, global_search=True).search is not None
    fine = prepare_map(ROOM.segments, paper).near_index
    assert fine.cell_m == NEAR_CELL_M


def test_a_localizer_refuses_a_map_prepared_for_other_settings():
    prepared = prepare_map(ROOM.segments)
    with pytest.raises(ValueError, match=r"bins are not 0\.5° wide"):
        Localizer(prepared, LocalizeParams(bin_deg=0.5))
    with pytest.raises(ValueError, match="other settings"):
        Localizer(prepared, LocalizeParams(search=SearchParams(hypotheses=2)))
    with pytest.raises(ValueError, match="no hypothesis search"):
        Localizer(prepare_map(ROOM.segments, LocalizeParams(search=None)), LocalizeParams())
    Localizer(prepared.for_params(LocalizeParams(bin_deg=0.5)), LocalizeParams(bin_deg=0.5))


def test_a_global_search_needs_a_map_prepared_for_it():
    rng = np.random.default_rng(3)
    truth = random_free_poses(ROOM, 1, rng)[0]
    scan = simulate_scan(ROOM, Pose2(*truth), NOISE_FREE, rng, 0.0)
    paper = Localizer.on_map(ROOM.segments, LocalizeParams(refine=None))
    with pytest.raises(ValueError, match="global_search=True"):
        paper.localize_global(extract_segments(scan), scan.points())
    est = Localizer.on_map(ROOM.segments, global_search=True).localize_global(
        extract_segments(scan), scan.points()
    )
    assert np.hypot(est.pose.x - truth[0], est.pose.y - truth[1]) < 0.01
