"""Stage 1, map alignment: the robot heading from a length-weighted Hough vote.

The global map is summarised once in an R-table: every global segment's
undirected orientation, quantised to the bin width, indexes the lengths of the
segments with that orientation. A candidate heading α rotates the local map;
each local segment (robot-frame orientation σ, length λL) then looks up the bin
of σ + α and, if that bin holds global segments, votes with a weight computed
from λL and the global length λG closest to λL. Positions play no part, which
is what decouples heading from position.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from segloc_cli.config import VOTE_SCHEMES
from segloc_cli.geometry import segment_lengths, segment_orientations, wrap_angle
from segloc_cli.jit import njit


def scheme_index(scheme: str) -> int:
    """``scheme``'s place in VOTE_SCHEMES; ``ValueError`` naming them for any other."""
    if scheme not in VOTE_SCHEMES:
        raise ValueError(f"unknown vote scheme {scheme!r}; choose one of {', '.join(VOTE_SCHEMES)}")
    return VOTE_SCHEMES.index(scheme)


def vote_weight(scheme: str, local_len_m: np.ndarray, global_len_m: np.ndarray) -> np.ndarray:
    """The vote of each (local, best global) pair under ``scheme`` (one of VOTE_SCHEMES)."""
    scheme_index(scheme)
    if scheme == "product":
        return local_len_m * global_len_m
    if scheme == "count":
        return np.ones_like(local_len_m)
    if scheme == "local":
        return np.asarray(local_len_m, dtype=float)
    return local_len_m + global_len_m  # "sum"


@dataclass(frozen=True)
class RTable:
    """Global segment lengths indexed by quantised undirected orientation.

    ``bin_width_rad`` divides [0, π) into ``n_bins`` bins; bin b covers the
    orientations that round to b·bin_width. ``sorted_m`` holds the lengths
    (metres, rounded to 1 mm as in the paper) of the global segments, bin by
    bin and sorted within each; ``sizes`` (n_bins,) how many each bin holds;
    ``segment_ids`` which map segment each entry of ``sorted_m`` is, so that a
    vote can be restricted to some of them (``closest_at``'s ``allowed``).
    """

    bin_width_rad: float
    sorted_m: np.ndarray
    sizes: np.ndarray
    segment_ids: np.ndarray

    @property
    def n_bins(self) -> int:
        return int(self.sizes.size)

    @property
    def lengths_m(self) -> tuple[np.ndarray, ...]:
        """The sorted lengths of each bin, one array per bin."""
        return tuple(np.split(self.sorted_m, np.cumsum(self.sizes)[:-1]))

    @classmethod
    def build(cls, segments_world: np.ndarray, bin_width_deg: float = 1.0) -> RTable:
        n_bins = round(180.0 / bin_width_deg)
        if n_bins < 1 or not np.isclose(n_bins * bin_width_deg, 180.0):
            raise ValueError(f"bin width {bin_width_deg}° must divide 180° evenly")
        bin_width_rad = np.deg2rad(bin_width_deg)
        bins = orientation_bins(segment_orientations(segments_world), bin_width_rad, n_bins)
        lengths = np.round(segment_lengths(segments_world), 3)
        order = np.lexsort((lengths, bins))  # by bin, then by length
        sizes = np.bincount(bins, minlength=n_bins)
        return cls(bin_width_rad, lengths[order], sizes, order)

    def closest_at(
        self, bins: np.ndarray, local_len_m: np.ndarray, allowed: np.ndarray | None = None
    ) -> np.ndarray:
        """(H, N): the global length closest to local length n in bin ``bins[h, n]`` (H, N),
        among the map segments ``allowed`` (M,) if given (NaN: none in the bin).

        Ties go to the shorter global length.
        """
        closest_mm = _closest_mm(
            np.ascontiguousarray(bins, dtype=np.int64), _whole_mm(local_len_m), self._sorted_mm,
            self._bin_starts, self.segment_ids, self._every_segment if allowed is None else allowed,
        )  # fmt: skip
        return np.where(closest_mm >= 0, closest_mm / 1000.0, np.nan)

    def votes(
        self,
        headings_rad: np.ndarray,
        sigma_rad: np.ndarray,
        local_len_m: np.ndarray,
        scheme: int,
        allowed: np.ndarray | None = None,
    ) -> np.ndarray:
        """(H, N): the vote of local segment n (orientation ``sigma_rad[n]``, robot frame,
        length ``local_len_m[n]``) at heading h, by ``VOTE_SCHEMES[scheme]`` with the closest
        length in its bin (``closest_at``), 0 where the bin holds no allowed segment."""
        return _votes(
            np.ascontiguousarray(headings_rad, dtype=float),
            np.ascontiguousarray(sigma_rad, dtype=float),
            np.ascontiguousarray(local_len_m, dtype=float),
            _whole_mm(local_len_m),
            self.bin_width_rad,
            self.n_bins,
            self._sorted_mm,
            self._bin_starts,
            self.segment_ids,
            self._every_segment if allowed is None else allowed,
            scheme,
        )

    # Derived once per table, not per vote (a table lives as long as its map's localizer).
    @cached_property
    def _sorted_mm(self) -> np.ndarray:
        return _whole_mm(self.sorted_m)

    @cached_property
    def _bin_starts(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(self.sizes)])

    @cached_property
    def _every_segment(self) -> np.ndarray:
        return np.ones(self.segment_ids.size, dtype=np.bool_)


def _whole_mm(lengths_m: np.ndarray) -> np.ndarray:
    """Lengths (metres) in whole millimetres, clipped to the keys' range: a NaN length
    matches nothing well, it becomes 1,000 km."""
    metres = np.nan_to_num(np.asarray(lengths_m, dtype=float), nan=_MAX_LENGTH_M)
    return np.rint(np.clip(metres, 0.0, _MAX_LENGTH_M) * 1000.0).astype(np.int64)


@njit(cache=True)
def _closest_mm(bins, local_mm, global_mm, starts, segment_ids, allowed):
    """``RTable.closest_at`` in whole millimetres, -1 where the bin holds no allowed segment.

    (difference, length) packs into one integer whose minimum is the closest length,
    shorter on ties.
    """
    n_h, n_local = bins.shape
    out = np.full((n_h, n_local), -1, dtype=np.int64)
    for h in range(n_h):
        for n in range(n_local):
            b, best = bins[h, n], -1
            for k in range(starts[b], starts[b + 1]):
                if allowed[segment_ids[k]]:
                    key = abs(global_mm[k] - local_mm[n]) * _KEY_BASE + global_mm[k]
                    if best < 0 or key < best:
                        best = key
            out[h, n] = best % _KEY_BASE if best >= 0 else -1
    return out


@njit(cache=True)
def _votes(
    headings, sigma, local_len, local_mm, bin_width, n_bins, global_mm, starts, segment_ids,
    allowed, scheme,
):  # fmt: skip
    """``RTable.votes``: what ``orientation_bins``, ``closest_at`` and ``vote_weight`` give,
    compiled (the same arithmetic, so the same votes to the last bit)."""
    n_h, n_local = headings.shape[0], sigma.shape[0]
    bins = np.empty((n_h, n_local), dtype=np.int64)
    for h in range(n_h):
        for n in range(n_local):
            wrapped = (sigma[n] + headings[h]) % np.pi
            if wrapped != wrapped:  # NaN: bin 0
                wrapped = 0.0
            bins[h, n] = np.int64(np.rint(wrapped / bin_width)) % n_bins
    closest_mm = _closest_mm(bins, local_mm, global_mm, starts, segment_ids, allowed)
    out = np.zeros((n_h, n_local))
    for h in range(n_h):
        for n in range(n_local):
            if closest_mm[h, n] < 0:
                continue
            global_len = closest_mm[h, n] / 1000.0
            if scheme == 0:  # VOTE_SCHEMES: product, count, local, sum
                out[h, n] = local_len[n] * global_len
            elif scheme == 1:
                out[h, n] = 1.0
            elif scheme == 2:
                out[h, n] = local_len[n]
            else:
                out[h, n] = local_len[n] + global_len
    return out


_KEY_BASE = 10**9
"""Exceeds any segment length in millimetres (1,000 km)."""

_MAX_LENGTH_M = (_KEY_BASE - 1) / 1000.0
"""Lengths are clipped to this before they are packed into keys, which then cannot overflow."""


def orientation_bins(orientation_rad: np.ndarray, bin_width_rad: float, n_bins: int) -> np.ndarray:
    """Bin of undirected orientations (radians, any value): nearest bin, modulo 180°."""
    wrapped = np.nan_to_num(np.asarray(orientation_rad, dtype=float) % np.pi)  # NaN: bin 0
    return np.rint(wrapped / bin_width_rad).astype(np.int64) % n_bins


def candidate_headings(prior_rad: float | None, window_rad: float, step_rad: float) -> np.ndarray:
    """Headings the accumulator scores (radians, wrapped to [-π, π)).

    With a prior heading: α0 − window … α0 + window in ``step_rad`` steps
    (always including α0 itself). Without: the whole circle from 0.
    """
    if prior_rad is None:
        n = round(2 * np.pi / step_rad)
        return wrap_angle(np.arange(n) * step_rad)
    k = int(np.floor(window_rad / step_rad + 1e-9))
    return wrap_angle(prior_rad + np.arange(-k, k + 1) * step_rad)


def accumulate(
    rtable: RTable,
    segments_robot: np.ndarray,
    headings_rad: np.ndarray,
    scheme: str = "product",
    allowed: np.ndarray | None = None,
) -> np.ndarray:
    """Votes (H,) for each candidate heading (H,) given the local map (N, 4), robot frame;
    only the map segments ``allowed`` (M,) vote, if given."""
    local_len = np.round(segment_lengths(segments_robot), 3)
    votes = rtable.votes(
        np.asarray(headings_rad, dtype=float).reshape(-1),
        segment_orientations(segments_robot),
        local_len,
        scheme_index(scheme),
        allowed,
    )
    return votes.sum(axis=1)


@dataclass(frozen=True)
class Alignment:
    """Result of stage 1: the accumulator and the headings it supports.

    ``peaks_rad`` are candidate headings in decreasing order of votes
    (``peak_votes``); with a prior heading there is one peak, the maximum
    in the window.
    """

    headings_rad: np.ndarray
    votes: np.ndarray
    peaks_rad: np.ndarray
    peak_votes: np.ndarray

    @property
    def best_rad(self) -> float:
        return float(self.peaks_rad[0])


def align(
    rtable: RTable,
    segments_robot: np.ndarray,
    prior_rad: float | None = None,
    window_deg: float = 20.0,
    scheme: str = "product",
    max_peaks: int = 8,
    peak_ratio: float = 0.5,
    allowed: np.ndarray | None = None,
) -> Alignment:
    """Estimate the robot heading (world frame) from the local map (N, 4), robot frame.

    With ``prior_rad`` the accumulator spans ±``window_deg`` around it and the
    single best heading is returned; ties go to the heading closest to the prior.
    Without a prior the whole circle is scored and up to ``max_peaks`` local
    maxima of at least ``peak_ratio`` × the highest are returned, so that the
    180° twin (undirected orientations cannot tell α from α + 180°) and the
    90° peaks of rectilinear buildings all reach stage 2. ``allowed`` (M,) limits the
    vote to those map segments.
    """
    step = rtable.bin_width_rad
    headings = candidate_headings(prior_rad, np.deg2rad(window_deg), step)
    votes = accumulate(rtable, segments_robot, headings, scheme, allowed)
    if prior_rad is not None:
        offset = np.abs(wrap_angle(headings - prior_rad))
        order = np.lexsort((offset, -votes))
        best = order[0]
        return Alignment(headings, votes, headings[[best]], votes[[best]])
    peaks = circular_peaks(votes, max_peaks, peak_ratio)
    return Alignment(headings, votes, headings[peaks], votes[peaks])


def circular_peaks(votes: np.ndarray, max_peaks: int, ratio: float) -> np.ndarray:
    """Indices of the local maxima of a circular accumulator, strongest first.

    A plateau of equal votes counts once, at its centre. Maxima below
    ``ratio`` × the global maximum are dropped.
    """
    votes = np.asarray(votes, dtype=float)
    n = votes.size
    top = votes.max() if n else 0.0
    if n == 0 or top <= 0:
        return np.zeros(0, dtype=np.int64)
    # Compress runs of equal values so plateaus become single points.
    change = votes != np.roll(votes, 1)
    if not change.any():
        return np.array([0])
    starts = np.flatnonzero(change)
    values = votes[starts]
    lengths = np.diff(np.append(starts, starts[0] + n))
    is_peak = (values > np.roll(values, 1)) & (values > np.roll(values, -1))
    peak_runs = np.flatnonzero(is_peak & (values >= ratio * top))
    centres = (starts[peak_runs] + (lengths[peak_runs] - 1) // 2) % n
    order = np.argsort(-votes[centres], kind="stable")
    return centres[order][:max_peaks]
