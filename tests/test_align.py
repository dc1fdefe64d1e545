"""Stage 1 (map alignment) on hand-made maps: R-table, accumulator, peaks, prior window."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from segloc_cli.geometry import (
    Pose2,
    segment_lengths,
    segment_orientations,
    transform_segments,
    wrap_angle,
)
from segloc_cli.method.align import (
    VOTE_SCHEMES,
    RTable,
    accumulate,
    align,
    candidate_headings,
    circular_peaks,
    orientation_bins,
    vote_weight,
)

DEG = np.pi / 180.0


def seg(theta_deg: float, length: float, x0: float = 0.0, y0: float = 0.0) -> list[float]:
    """A segment from (x0, y0) along direction ``theta_deg`` with the given length."""
    t = np.deg2rad(theta_deg)
    return [x0, y0, x0 + length * np.cos(t), y0 + length * np.sin(t)]


def as_local(segments_world: np.ndarray, pose: Pose2) -> np.ndarray:
    """The world map expressed in the robot frame of ``pose`` (what the robot would see)."""
    return transform_segments(segments_world, pose.inverse())


# --- R-table ----------------------------------------------------------------------------------

# Orientation (direction of travel) and length of each global segment.
RT_MAP = np.array(
    [
        seg(0.0, 2.0004, 1.0, 1.0),  # bin 0; 2.0004 m rounds to 2.000
        seg(0.4, 1.0, -3.0, 2.0),  # 0.4° rounds into bin 0 (1° bins)
        seg(179.6, 0.5),  # 179.6° rounds to 180° = bin 0 (wraps)
        seg(-90.0, 3.0),  # pointing down: orientation 90°
        seg(45.0, 1.41449),  # bin 45; rounds to 1.414
        seg(2.4, 0.75),  # 1° bins: bin 2;   5° bins: 2.4/5 = 0.48 → bin 0
        seg(2.6, 0.25),  # 1° bins: bin 3;   5° bins: 2.6/5 = 0.52 → bin 1
        seg(227.4, 0.6),  # orientation 47.4°: bin 47; 5° bins: 9.48 → bin 9 (with 45°)
        seg(-0.3, 1.2345),  # orientation 179.7°: bin 0 (both widths); 1.2345 m → 1.234 or 1.235
    ]
)


def test_rtable_one_degree_bins_exact():
    table = RTable.build(RT_MAP, bin_width_deg=1.0)
    assert table.n_bins == 180
    assert table.bin_width_rad == pytest.approx(DEG)
    last = round(1.2345, 3)  # whatever 1-mm rounding gives for 1.2345 (1.234 in binary)
    expected = {
        0: sorted([2.0, 1.0, 0.5, last]),
        2: [0.75],
        3: [0.25],
        45: [1.414],
        47: [0.6],
        90: [3.0],
    }
    for b in range(180):
        np.testing.assert_allclose(table.lengths_m[b], expected.get(b, []), atol=1e-12)
    # Sorted, rounded to the millimetre.
    assert list(table.lengths_m[0]) == sorted(table.lengths_m[0])
    assert table.lengths_m[0][-1] == pytest.approx(2.0, abs=1e-12)


def test_rtable_five_degree_bins_exact():
    table = RTable.build(RT_MAP, bin_width_deg=5.0)
    assert table.n_bins == 36  # 180 / 5
    assert table.bin_width_rad == pytest.approx(5 * DEG)
    last = round(1.2345, 3)
    expected = {
        0: sorted([2.0, 1.0, 0.5, 0.75, last]),  # 0°, 0.4°, 179.6°, 2.4°, 179.7°
        1: [0.25],  # 2.6°
        9: [0.6, 1.414],  # 45° and 47.4°
        18: [3.0],  # 90°
    }
    for b in range(36):
        np.testing.assert_allclose(table.lengths_m[b], expected.get(b, []), atol=1e-12)


@pytest.mark.parametrize("bad_deg", [7.0, 0.7, 200.0, 50.0])
def test_rtable_bin_width_must_divide_180(bad_deg):
    with pytest.raises(ValueError, match="divide 180"):
        RTable.build(RT_MAP, bin_width_deg=bad_deg)


def test_rtable_half_degree_bins_accepted():
    table = RTable.build(RT_MAP, bin_width_deg=0.5)
    assert table.n_bins == 360
    # 0.4° / 0.5° = 0.8 → bin 1 (0.5°); 179.6° / 0.5° = 359.2 and 179.7° / 0.5° = 359.4
    # → bin 359; 0° alone stays in bin 0.
    np.testing.assert_allclose(table.lengths_m[0], [2.0])
    np.testing.assert_allclose(table.lengths_m[1], [1.0])
    np.testing.assert_allclose(table.lengths_m[359], sorted([0.5, round(1.2345, 3)]))


def test_orientation_bins_round_to_nearest_and_wrap():
    b = orientation_bins(np.deg2rad([0.0, 0.49, 0.51, 179.49, 179.51, -0.2, 360.2]), DEG, 180)
    np.testing.assert_array_equal(b, [0, 0, 1, 179, 0, 0, 0])


# --- accumulator ------------------------------------------------------------------------------

# Global map: bin 0 holds lengths 1.0 and 3.0 (two horizontal walls), bin 90 holds 2.0,
# bin 30 holds 1.5.
ACC_GLOBAL = np.array(
    [seg(0.0, 1.0, 0, 0), seg(180.0, 3.0, 5, 5), seg(90.0, 2.0, 1, 1), seg(30.0, 1.5, 2, 0)]
)
# Local map: L1 σ = 0° λ = 2.2 (given as 2.2004: λL is rounded to the millimetre too),
# L2 σ = 90° λ = 0.8, L3 σ = 60° λ = 1.0.
ACC_LOCAL = np.array([seg(0.0, 2.2004, 3, 3), seg(90.0, 0.8, -1, 0), seg(60.0, 1.0, 0, -2)])
ACC_HEADINGS_DEG = np.array([0.0, 90.0, -30.0, 10.0, -90.0])

# Per heading, (λL, λG) of each pair that finds a non-empty bin:
#   α = 0°:   L1 → bin 0, closest to 2.2 in [1.0, 3.0] is 3.0 (|0.8| < |1.2|);
#             L2 → bin 90 → 2.0;  L3 → bin 60: empty, no vote.
#   α = 90°:  L1 → bin 90 → 2.0;  L2 → bin 180 = 0, closest to 0.8 in [1.0, 3.0] is 1.0;
#             L3 → bin 150: empty.
#   α = −30°: L1 → bin 150: empty; L2 → bin 60: empty; L3 → bin 30 → 1.5.
#   α = 10°:  bins 10, 100, 70: all empty → 0.
#   α = −90°: same bins as +90° (orientations are undirected).
ACC_PAIRS = [
    [(2.2, 3.0), (0.8, 2.0)],
    [(2.2, 2.0), (0.8, 1.0)],
    [(1.0, 1.5)],
    [],
    [(2.2, 2.0), (0.8, 1.0)],
]


@pytest.mark.parametrize(
    ("scheme", "expected"),
    [
        # product λL·λG: 2.2·3 + 0.8·2 = 8.2 | 2.2·2 + 0.8·1 = 5.2 | 1·1.5 = 1.5 | 0 | 5.2
        ("product", [8.2, 5.2, 1.5, 0.0, 5.2]),
        # count: the number of pairs
        ("count", [2.0, 2.0, 1.0, 0.0, 2.0]),
        # local λL: 2.2 + 0.8 = 3.0 | 3.0 | 1.0 | 0 | 3.0
        ("local", [3.0, 3.0, 1.0, 0.0, 3.0]),
        # sum λL + λG: 5.2 + 2.8 = 8.0 | 4.2 + 1.8 = 6.0 | 2.5 | 0 | 6.0
        ("sum", [8.0, 6.0, 2.5, 0.0, 6.0]),
    ],
)
def test_accumulator_each_vote_scheme_exact(scheme, expected):
    table = RTable.build(ACC_GLOBAL, 1.0)
    votes = accumulate(table, ACC_LOCAL, ACC_HEADINGS_DEG * DEG, scheme)
    np.testing.assert_allclose(votes, expected, rtol=0, atol=1e-12)
    # The same numbers from the pair list above, through the scheme's weight.
    by_pairs = [
        sum(float(vote_weight(scheme, np.array(lam_l), np.array(lam_g))) for lam_l, lam_g in p)
        for p in ACC_PAIRS
    ]
    np.testing.assert_allclose(votes, by_pairs, rtol=0, atol=1e-12)


def test_vote_schemes_are_the_four_of_the_paper():
    assert VOTE_SCHEMES == ("product", "count", "local", "sum")
    with pytest.raises(ValueError, match="unknown vote scheme"):
        vote_weight("max", np.array([1.0]), np.array([1.0]))
    with pytest.raises(ValueError, match="unknown vote scheme"):
        accumulate(RTable.build(ACC_GLOBAL), ACC_LOCAL, np.array([0.0]), "median")


def test_closest_length_is_chosen_among_several_in_a_bin():
    # Bin 0 holds 0.5, 1.0, 2.0, 4.0; bin 90 is empty.
    g = np.array([seg(0, 4.0), seg(0, 0.5, 0, 1), seg(0, 2.0, 0, 2), seg(0, 1.0, 0, 3)])
    table = RTable.build(g, 1.0)
    local = np.array([0.1, 0.7, 0.8, 1.4, 1.6, 2.9, 3.1, 9.0])
    closest = table.closest_at(np.repeat([[0], [90]], local.size, axis=1), local)
    closest = {0: closest[0], 90: closest[1]}
    # 0.1 → 0.5 (below all); 0.7 → 0.5 (0.2 < 0.3); 0.8 → 1.0; 1.4 → 1.0; 1.6 → 2.0;
    # 2.9 → 2.0 (0.9 < 1.1); 3.1 → 4.0; 9.0 → 4.0 (above all).
    np.testing.assert_allclose(closest[0], [0.5, 0.5, 1.0, 1.0, 2.0, 2.0, 4.0, 4.0])
    assert np.all(np.isnan(closest[90]))
    # And through the accumulator: one local segment of 2.9 m at σ = 0 → vote 2.9·2.0.
    votes = accumulate(table, np.array([seg(0.0, 2.9)]), np.array([0.0, 90 * DEG]))
    np.testing.assert_allclose(votes, [2.9 * 2.0, 0.0], atol=1e-12)


def test_accumulator_ignores_positions():
    # Moving local segments around (without turning them) changes no vote.
    table = RTable.build(ACC_GLOBAL, 1.0)
    shifted = ACC_LOCAL + np.array([10.0, -7.0, 10.0, -7.0])
    headings = np.deg2rad(np.arange(-180.0, 180.0, 1.0))
    np.testing.assert_allclose(
        accumulate(table, shifted, headings), accumulate(table, ACC_LOCAL, headings), atol=1e-12
    )


def test_accumulator_empty_local_map_votes_zero():
    table = RTable.build(ACC_GLOBAL, 1.0)
    votes = accumulate(table, np.zeros((0, 4)), np.array([0.0, 1.0]))
    np.testing.assert_array_equal(votes, [0.0, 0.0])


# --- candidate headings -----------------------------------------------------------------------


def test_candidate_headings_window_bounds():
    h = candidate_headings(10 * DEG, 20 * DEG, DEG)
    # 10° ± 20° in 1° steps: −10°, −9°, …, 30° → 41 headings, the prior in the middle.
    assert h.size == 41
    np.testing.assert_allclose(h, np.deg2rad(np.arange(-10.0, 31.0)), atol=1e-12)
    assert h[20] == pytest.approx(10 * DEG, abs=1e-15)
    # A window that is not a whole number of steps stops at the last whole step: ±2°.
    h = candidate_headings(0.0, 2.5 * DEG, DEG)
    np.testing.assert_allclose(h, np.deg2rad([-2.0, -1.0, 0.0, 1.0, 2.0]), atol=1e-12)
    # A zero window scores the prior alone.
    np.testing.assert_allclose(candidate_headings(0.3, 0.0, DEG), [0.3])


def test_candidate_headings_wrap_around_pi():
    h = candidate_headings(179.5 * DEG, 20 * DEG, DEG)
    assert h.size == 41
    assert np.all(h >= -np.pi)
    assert np.all(h < np.pi)
    # 159.5° … 179.5°, then 180.5° → −179.5°, …, 199.5° → −160.5°.
    expected = wrap_angle(np.deg2rad(np.arange(159.5, 200.0, 1.0)))
    np.testing.assert_allclose(h, expected, atol=1e-12)
    assert h[20] == pytest.approx(179.5 * DEG, abs=1e-12)
    assert h[21] == pytest.approx(-179.5 * DEG, abs=1e-12)
    assert h[-1] == pytest.approx(-160.5 * DEG, abs=1e-12)


def test_candidate_headings_whole_circle():
    h = candidate_headings(None, 20 * DEG, DEG)
    assert h.size == 360
    assert np.all(h >= -np.pi)
    assert np.all(h < np.pi)
    # From 0 upwards: 0°, 1°, …, 179°, then −180°, −179°, …, −1°.
    expected = np.deg2rad(np.concatenate([np.arange(0.0, 180.0), np.arange(-180.0, 0.0)]))
    np.testing.assert_allclose(h, expected, atol=1e-12)
    assert candidate_headings(None, 0.0, 5 * DEG).size == 72


# --- align with a prior -----------------------------------------------------------------------

# A non-symmetric map: orientations 0°, 35°, 100°; lengths 4, 2, 1.5.
TRI_MAP = np.array([seg(0.0, 4.0, -2, -1), seg(35.0, 2.0, 1, 0.5), seg(100.0, 1.5, 2, -2)])


def test_align_with_prior_finds_true_heading_in_window():
    true = Pose2.from_deg(1.0, 2.0, 7.0)
    local = as_local(TRI_MAP, true)
    table = RTable.build(TRI_MAP, 1.0)
    result = align(table, local, prior_rad=0.0, window_deg=20.0)
    # Window −20° … 20°, 41 headings; only one peak is returned with a prior.
    assert result.headings_rad.size == 41
    assert result.headings_rad[0] == pytest.approx(-20 * DEG, abs=1e-12)
    assert result.headings_rad[-1] == pytest.approx(20 * DEG, abs=1e-12)
    assert result.peaks_rad.size == 1
    assert result.best_rad == pytest.approx(7 * DEG, abs=1e-12)
    # At 7° every local segment meets its own global one: 4·4 + 2·2 + 1.5·1.5 = 22.25.
    assert result.peak_votes[0] == pytest.approx(22.25, abs=1e-9)
    assert result.votes.max() == pytest.approx(22.25, abs=1e-9)


def test_align_true_heading_outside_window_is_not_found():
    local = as_local(TRI_MAP, Pose2.from_deg(0, 0, 30.0))
    table = RTable.build(TRI_MAP, 1.0)
    result = align(table, local, prior_rad=0.0, window_deg=20.0)
    assert abs(result.best_rad - 30 * DEG) > 9 * DEG
    assert result.peak_votes[0] < 22.25


def test_align_ties_go_to_the_heading_closest_to_prior():
    # Two equal global walls at 0° and 10°; one local wall at σ = 0°: headings 0° and 10°
    # both score 2·2 = 4.
    g = np.array([seg(0.0, 2.0), seg(10.0, 2.0, 0, 3)])
    local = np.array([seg(0.0, 2.0, 1, 1)])
    table = RTable.build(g, 1.0)
    near_ten = align(table, local, prior_rad=6 * DEG, window_deg=20.0)  # |10 − 6| < |0 − 6|
    assert near_ten.best_rad == pytest.approx(10 * DEG, abs=1e-12)
    assert near_ten.peak_votes[0] == pytest.approx(4.0)
    near_zero = align(table, local, prior_rad=4 * DEG, window_deg=20.0)  # |0 − 4| < |10 − 4|
    assert near_zero.best_rad == pytest.approx(0.0, abs=1e-12)
    # The tie is a real one: the accumulator holds two maxima of 4.
    assert np.sum(np.isclose(near_zero.votes, 4.0)) == 2


def test_align_tie_breaking_measures_distance_across_pi():
    # Walls at 0° and 170°; local σ = 0°. Equal maxima at α = 0° and α = 170° (= −10° + 180°,
    # one of its 180° twins). With the prior at −175°, α = 170° is 15° away, α = −180° (the
    # twin of 0°) is 5° away: the twin of 0° must win, measured across ±180°.
    g = np.array([seg(0.0, 2.0), seg(170.0, 2.0, 0, 3)])
    local = np.array([seg(0.0, 2.0)])
    table = RTable.build(g, 1.0)
    result = align(table, local, prior_rad=-175 * DEG, window_deg=20.0)
    assert abs(wrap_angle(result.best_rad - np.pi)) < 1e-9
    assert result.peak_votes[0] == pytest.approx(4.0)


def test_align_prior_near_pi_finds_heading_across_the_seam():
    true = Pose2.from_deg(0.0, 0.0, -179.5)
    map_ = np.array([seg(0.0, 5.0), seg(50.0, 3.0, 1, 1), seg(120.0, 2.0, -1, 2)])
    local = as_local(map_, true)
    # Bins are whole degrees; local orientations are β + 179.5° ≡ β − 0.5°, so only
    # α ≡ −179.5° (mod 180°) puts them back on their bins (5·5 + 3·3 + 2·2 = 38).
    table = RTable.build(map_, 1.0)
    result = align(table, local, prior_rad=179.5 * DEG, window_deg=20.0)
    assert result.best_rad == pytest.approx(-179.5 * DEG, abs=1e-9)
    assert result.peak_votes[0] == pytest.approx(38.0)
    assert np.all(result.headings_rad < np.pi)
    assert np.all(result.headings_rad >= -np.pi)


# --- whole circle -----------------------------------------------------------------------------


def test_align_whole_circle_returns_true_heading_and_its_180_twin():
    true = Pose2.from_deg(0.5, -0.5, 25.0)
    local = as_local(TRI_MAP, true)
    table = RTable.build(TRI_MAP, 1.0)
    result = align(table, local, prior_rad=None)
    assert result.headings_rad.size == 360
    # At 25° and at 205° (= −155°) each local segment meets its own: 16 + 4 + 2.25 = 22.25.
    # Cross-pairings score at most 4·2 = 8 < 0.5·22.25, so these are the only two peaks;
    # equal votes keep accumulator order (25° at index 25 before 205° at index 205).
    np.testing.assert_allclose(result.peaks_rad, np.deg2rad([25.0, -155.0]), atol=1e-9)
    np.testing.assert_allclose(result.peak_votes, [22.25, 22.25], atol=1e-9)
    # The cross-pairings: L(0°→−25°) with the 35° bin at α = 60° (4·2 = 8), with the 100° bin
    # at α = 125° (4·1.5 = 6); L(35°→10°) with the 0° bin at α = −10° (2·4 = 8), with 100° at
    # α = 90° (2·1.5 = 3); L(100°→75°) with 0° at α = 105° (6), with 35° at α = −40° (3).
    degrees = np.rint(np.rad2deg(result.headings_rad)).astype(int)
    votes = dict(zip(degrees, result.votes, strict=True))
    for alpha, v in [(60, 8.0), (125, 6.0), (-10, 8.0), (90, 3.0), (105, 6.0), (-40, 3.0)]:
        twin = (alpha + 360) % 360 - 180  # α + 180°, wrapped to [−180°, 180°)
        assert votes[alpha] == pytest.approx(v)
        assert votes[twin] == pytest.approx(v)
    # Nothing else votes: 2 peak headings + 6 cross-pairing headings and their 6 twins.
    assert np.count_nonzero(result.votes) == 2 + 2 * 6


def test_align_rectilinear_map_gives_peaks_90_degrees_apart():
    # A 6 m × 4 m room: walls at 0° (6 m, twice) and 90° (4 m, twice).
    room = np.array([[0, 0, 6, 0], [6, 0, 6, 4], [6, 4, 0, 4], [0, 4, 0, 0]], dtype=float)
    local = as_local(room, Pose2.from_deg(3.0, 2.0, 30.0))
    table = RTable.build(room, 1.0)
    result = align(table, local, prior_rad=None)
    # α = 30°, 210°: walls meet their own: 2·6·6 + 2·4·4 = 104.
    # α = 120°, 300°: long local walls land on the 90° bin (closest length 4), short ones on
    # the 0° bin (closest 6): 2·6·4 + 2·4·6 = 96 ≥ 0.5·104.
    np.testing.assert_allclose(
        result.peaks_rad, np.deg2rad([30.0, -150.0, 120.0, -60.0]), atol=1e-9
    )
    np.testing.assert_allclose(result.peak_votes, [104.0, 104.0, 96.0, 96.0], atol=1e-9)
    np.testing.assert_allclose(np.diff(np.sort(np.rad2deg(result.peaks_rad))), [90.0] * 3)
    # max_peaks keeps the strongest.
    two = align(table, local, prior_rad=None, max_peaks=2)
    np.testing.assert_allclose(two.peaks_rad, np.deg2rad([30.0, -150.0]), atol=1e-9)
    # A ratio above 96/104 drops the 90° peaks.
    strict = align(table, local, prior_rad=None, peak_ratio=0.95)
    np.testing.assert_allclose(strict.peaks_rad, np.deg2rad([30.0, -150.0]), atol=1e-9)


def test_align_whole_circle_no_match_gives_no_peak():
    table = RTable.build(TRI_MAP, 1.0)
    result = align(table, np.zeros((0, 4)), prior_rad=None)
    assert result.peaks_rad.size == 0
    assert result.peak_votes.size == 0


# --- circular_peaks on hand-made accumulators -------------------------------------------------


def test_circular_peaks_simple_and_ratio():
    votes = np.array([0, 1, 3, 1, 0, 0, 2, 0], dtype=float)
    # Maxima at 2 (3) and 6 (2 ≥ 0.5·3).
    np.testing.assert_array_equal(circular_peaks(votes, 8, 0.5), [2, 6])
    # 2 < 0.7·3 = 2.1: dropped.
    np.testing.assert_array_equal(circular_peaks(votes, 8, 0.7), [2])
    # Exactly at the ratio is kept: 2 ≥ (2/3)·3.
    np.testing.assert_array_equal(circular_peaks(votes, 8, 2.0 / 3.0 - 1e-12), [2, 6])


def test_circular_peaks_plateau_counts_once_at_its_centre():
    # Plateau 1..3 → centre 2; the lone 1 at index 5 reaches 0.5·2.
    np.testing.assert_array_equal(
        circular_peaks(np.array([0, 2, 2, 2, 0, 1, 0], dtype=float), 8, 0.5), [2, 5]
    )
    # Even plateau 1..4: centre 1 + (4 − 1)//2 = 2.
    np.testing.assert_array_equal(
        circular_peaks(np.array([0, 2, 2, 2, 2, 0], dtype=float), 8, 0.5), [2]
    )
    # A plateau across the seam: indices 5, 0, 1 → centre 0.
    np.testing.assert_array_equal(
        circular_peaks(np.array([3, 3, 0, 0, 0, 3], dtype=float), 8, 0.5), [0]
    )
    # Indices 4, 5, 0, 1, 2 → centre 0 again; 4, 5, 0, 1 → centre 5.
    np.testing.assert_array_equal(
        circular_peaks(np.array([3, 3, 3, 0, 3, 3], dtype=float), 8, 0.5), [0]
    )
    np.testing.assert_array_equal(
        circular_peaks(np.array([3, 3, 0, 0, 3, 3], dtype=float), 8, 0.5), [5]
    )


def test_circular_peaks_wrap_around_at_first_and_last_index():
    # Index 0 is a peak: its neighbours are 1 (index 1) and 1 (index 4, across the seam).
    np.testing.assert_array_equal(
        circular_peaks(np.array([5, 1, 0, 0, 1], dtype=float), 8, 0.1), [0]
    )
    # The last index is a peak; index 0 (1) is not, its left neighbour is the 4.
    np.testing.assert_array_equal(
        circular_peaks(np.array([1, 0, 0, 2, 4], dtype=float), 8, 0.1), [4]
    )
    # A slope up to the seam on one side only: index 0 is not a peak when the last index is
    # higher.
    assert 0 not in circular_peaks(np.array([3, 1, 0, 1, 4], dtype=float), 8, 0.1)


def test_circular_peaks_order_and_max_peaks():
    votes = np.array([0, 4, 0, 5, 0, 3, 0, 2, 0], dtype=float)
    np.testing.assert_array_equal(circular_peaks(votes, 8, 0.0), [3, 1, 5, 7])
    np.testing.assert_array_equal(circular_peaks(votes, 2, 0.0), [3, 1])
    np.testing.assert_array_equal(circular_peaks(votes, 1, 0.0), [3])


def test_circular_peaks_degenerate_inputs():
    assert circular_peaks(np.zeros(0), 8, 0.5).size == 0
    assert circular_peaks(np.zeros(10), 8, 0.5).size == 0
    # All equal and positive: one plateau, reported at index 0.
    np.testing.assert_array_equal(circular_peaks(np.full(6, 2.0), 8, 0.5), [0])


def test_votes_of_allowed_segments_are_those_of_their_own_table():
    """A vote restricted to some map segments is the vote of an R-table built from them."""
    rng = np.random.default_rng(5)
    ends = rng.uniform(-10.0, 10.0, (300, 2))
    turns = rng.integers(0, 12, 300) * 15.0 + rng.uniform(-0.4, 0.4, 300)
    lengths = rng.choice([0.5, 1.0, 1.5, 2.0, 3.0], 300)
    world = np.array([seg(t, s, x, y) for (x, y), t, s in zip(ends, turns, lengths, strict=True)])
    allowed = rng.random(300) < 0.3
    local = as_local(world[:20], Pose2(1.0, -2.0, 0.3))
    headings = candidate_headings(0.3, np.deg2rad(20.0), DEG)
    for scheme in VOTE_SCHEMES:
        np.testing.assert_array_equal(
            accumulate(RTable.build(world), local, headings, scheme, allowed),
            accumulate(RTable.build(world[allowed]), local, headings, scheme),
        )


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), scheme=st.sampled_from(VOTE_SCHEMES))
def test_compiled_votes_are_the_numpy_composition_to_the_last_bit(seed, scheme):
    """``accumulate``'s one compiled pass gives what orientation bins, closest lengths and
    vote weights give as numpy array operations, bit for bit, with and without a mask of
    allowed segments, for orientations on bin edges, non-finite ones and lengths past the
    keys' range."""
    rng = np.random.default_rng(seed)
    g = rng.uniform(-20, 20, (int(rng.integers(1, 60)), 4))
    g[: g.shape[0] // 4, 3] = g[: g.shape[0] // 4, 1]  # horizontal: the bin-0/180° edge
    local = rng.uniform(-8, 8, (int(rng.integers(0, 40)), 4))
    if local.shape[0] > 2:
        local[0, 2] = np.nan
        local[1] = [0.0, 0.0, 2e6, 0.0]
    table = RTable.build(g, float(rng.choice([0.5, 1.0, 2.0])))
    headings = np.concatenate([rng.uniform(-4, 4, 30), np.deg2rad([0.25, 0.5, 179.5, -90.0])])
    allowed = rng.random(g.shape[0]) < 0.6 if rng.random() < 0.5 else None
    local_len = np.round(segment_lengths(local), 3)
    sigma = segment_orientations(local)
    bins = orientation_bins(sigma[None, :] + headings[:, None], table.bin_width_rad, table.n_bins)
    global_len = table.closest_at(bins, local_len, allowed)
    weights = vote_weight(scheme, local_len[None, :], np.nan_to_num(global_len))
    expected = np.where(np.isnan(global_len), 0.0, weights).sum(axis=1)
    np.testing.assert_array_equal(accumulate(table, local, headings, scheme, allowed), expected)
