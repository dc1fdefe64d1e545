"""Pairing records of two sources by time: the scans of a log with the rows of a survey,
a guesses table or an odometry stream. A pairing that could go more than one way is
refused, naming the rows, rather than decided silently."""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.wording import with_article


def nearest_by_time(query_times_s, ref_times_s, tolerance_s: float) -> np.ndarray:
    """Index into ``ref_times_s`` of the nearest reference time for each query.

    ``query_times_s`` (Q,) and ``ref_times_s`` (R,) seconds; ``ref`` need not be
    sorted. Returns (Q,) int64 indices, −1 where no reference time lies within
    ``tolerance_s`` (inclusive) or the query is NaN. On a tie the earlier
    reference time wins; among equal reference times, the first in ``ref``.
    """
    query = np.asarray(query_times_s, dtype=float).reshape(-1)
    ref = np.asarray(ref_times_s, dtype=float).reshape(-1)
    result = np.full(query.shape, -1, dtype=np.int64)
    finite_ref = np.flatnonzero(np.isfinite(ref))
    if finite_ref.size == 0 or query.size == 0:
        return result
    order = finite_ref[np.argsort(ref[finite_ref], kind="stable")]
    sorted_ref = ref[order]
    n = len(sorted_ref)

    right = np.searchsorted(sorted_ref, query, side="left")
    left = right - 1
    right_c = np.clip(right, 0, n - 1)
    left_c = np.clip(left, 0, n - 1)
    with np.errstate(invalid="ignore"):
        dist_right = np.where(right < n, sorted_ref[right_c] - query, np.inf)
        dist_left = np.where(left >= 0, query - sorted_ref[left_c], np.inf)
    # The left neighbour may be the last of a run of equal times: step back to its first.
    left_first = np.searchsorted(sorted_ref, sorted_ref[left_c], side="left")
    take_left = dist_left <= dist_right
    best_pos = np.where(take_left, left_first, right_c)
    best_dist = np.where(take_left, dist_left, dist_right)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(query) & (best_dist <= tolerance_s)
    result[ok] = order[best_pos[ok]]
    return result


def _numbered(label: str, indices: np.ndarray, shown: int = 3) -> str:
    """'rows 4 and 5', 'rows 4, 5 and 9', 'rows 4, 5, 9 and 12 more' from 0-based indices."""
    numbers = [str(int(i) + 1) for i in indices]
    if len(numbers) > shown:
        return f"{label}s {', '.join(numbers[:shown])} and {len(numbers) - shown} more"
    return f"{label}s {', '.join(numbers[:-1])} and {numbers[-1]}"


def _located_error(path: object, where: str, message: str) -> InputError:
    """An InputError reading ``path, where: message`` (``where`` names several rows)."""
    error = InputError(f"{path}, {where}: {message}")
    error.path = path
    return error


def pair_by_time(
    query_times_s,
    ref_times_s,
    tolerance_s: float,
    *,
    query_path: object,
    ref_path: object,
    query_label: str = "record",
    ref_label: str = "row",
    distinct_queries: bool = True,
) -> np.ndarray:
    """``nearest_by_time``, refusing every pairing that is not unambiguous.

    ``query_times_s`` (Q,) and ``ref_times_s`` (R,) are seconds; each query is
    paired with the reference nearest in time within ``tolerance_s``
    (inclusive). Returns (Q,) int64 indices into ``ref_times_s``, −1 where no
    reference is close enough or the query is NaN.

    The rule: a pairing is refused (``InputError``, exit status 2) when

    - the reference time nearest a query is held by two or more reference rows
      (equal times, e.g. all 0 or absolute times printed with too few digits):
      the query could be paired with either, and the message names
      ``ref_path`` and those rows;
    - two distinct reference times are exactly as near a query, one on either
      side (a query halfway between two rows): the message names ``ref_path``
      and those two rows; or
    - ``distinct_queries`` is true and two or more queries that found a
      reference have the same time: they would all take the same reference
      row, and the message names ``query_path`` and those queries.

    Nothing else is refused. Other references that lie within the tolerance
    but farther than the nearest one do not matter: scans 25 ms apart at
    40 Hz pair one-to-one with a table written at the same times, whatever
    the tolerance. Distinct query times may share a reference row (a
    sparse survey under a dense log). Rows are numbered from 1, in the
    order given; labels are singular nouns ("scan", "row") made plural with an "s".
    """
    query = np.asarray(query_times_s, dtype=float).reshape(-1)
    ref = np.asarray(ref_times_s, dtype=float).reshape(-1)
    match = nearest_by_time(query, ref, tolerance_s)
    hit = np.flatnonzero(match >= 0)
    if hit.size == 0:
        return match

    matched_ref_s = ref[match[hit]]
    sorted_ref = np.sort(ref[np.isfinite(ref)])
    holders = np.searchsorted(sorted_ref, matched_ref_s, side="right") - np.searchsorted(
        sorted_ref, matched_ref_s, side="left"
    )
    shared = np.flatnonzero(holders > 1)
    if shared.size:
        q = int(hit[shared[0]])
        t_ref = float(ref[match[q]])
        rows = np.flatnonzero(ref == t_ref)
        verb = "both have" if rows.size == 2 else "all have"
        hint = "" if query[q] == t_ref else " (or lower --tolerance-ms)"
        raise _located_error(
            ref_path,
            _numbered(ref_label, rows),
            f"{verb} time {t_ref:.3f} s, so {with_article(query_label)} at {query[q]:.3f} s "
            "matches more "
            f"than one {ref_label}; give every {ref_label} a distinct time{hint}",
        )

    halfway = _halfway(query[hit], sorted_ref)
    if halfway is not None:
        at, below, above = halfway
        q = int(hit[at])
        raise _located_error(
            ref_path,
            _numbered(ref_label, np.flatnonzero((ref == below) | (ref == above))),
            f"their times {below:.3f} and {above:.3f} s are equally near "
            f"{with_article(query_label)} at {query[q]:.3f} s, so it matches either; give times "
            f"that are not halfway between two {ref_label}s (or lower --tolerance-ms)",
        )

    if distinct_queries and hit.size > 1:
        matched_query_s = query[hit]
        _, inverse, counts = np.unique(matched_query_s, return_inverse=True, return_counts=True)
        repeated = counts[inverse.reshape(-1)] > 1
        if repeated.any():
            q = int(hit[np.argmax(repeated)])
            same = hit[matched_query_s == query[q]]
            both = "both" if same.size == 2 else "all"
            raise _located_error(
                query_path,
                _numbered(query_label, same),
                f"{both} have time {query[q]:.3f} s, so {both} would be paired with {ref_label} "
                f"{int(match[q]) + 1} of {ref_path}; give every {query_label} a distinct time",
            )
    return match


def _halfway(query: np.ndarray, sorted_ref: np.ndarray) -> tuple[int, float, float] | None:
    """The first of the queries (finite, each with a reference within reach) that lies exactly
    halfway between two neighbouring times of ``sorted_ref``: its index, and the reference
    times before and after it; None when no query does."""
    right = np.searchsorted(sorted_ref, query, side="left")  # the first time not earlier
    left = right - 1  # the last earlier time
    inside = np.flatnonzero((left >= 0) & (right < len(sorted_ref)))
    q, later, earlier = query[inside], sorted_ref[right[inside]], sorted_ref[left[inside]]
    tied = np.flatnonzero((later != q) & (later - q == q - earlier))
    if tied.size == 0:
        return None
    first = int(tied[0])
    return int(inside[first]), float(earlier[first]), float(later[first])


def time_range(times_s) -> str:
    """``first–last s`` of some times, or ``none``."""
    times_s = np.asarray(times_s, dtype=float)
    if times_s.size == 0:
        return "none"
    return f"{times_s.min():.3f}–{times_s.max():.3f} s"


UNIX_TIMES_FROM_S = 1e8
"""Times from this on (1973-03-03 UTC) are taken for Unix times and also shown as dates;
smaller ones count from some start (a simulated log, a corrected log's relative times)."""


def duration_text(seconds: float) -> str:
    """A length of time for people: ``9.0 s``, ``29 min 43 s``, ``2 h 05 min``."""
    if seconds < 60.0:
        return f"{seconds:.1f} s"
    whole = round(seconds)
    if whole < 3600:
        return f"{whole // 60} min {whole % 60:02d} s"
    return f"{whole // 3600} h {whole % 3600 // 60:02d} min"


def readable_span(times_s) -> str | None:
    """How long some times span, first to last, where their seconds alone do not say it
    readily: in minutes or hours from a minute on (``29 min 43 s``), with the dates of Unix
    times in UTC (``2005-12-19 10:12:40 to 10:42:23 UTC``); None for a short span of times
    counted from some start, or for no times."""
    times_s = np.asarray(times_s, dtype=float)
    times_s = times_s[np.isfinite(times_s)]
    if times_s.size == 0:
        return None
    first, last = float(times_s.min()), float(times_s.max())
    parts = [duration_text(last - first)] if last - first >= 60.0 else []
    if first >= UNIX_TIMES_FROM_S:
        start, end = (datetime.fromtimestamp(t, UTC) for t in (first, last))
        same_day = end.date() == start.date()
        shown_end = end.strftime("%H:%M:%S" if same_day else "%Y-%m-%d %H:%M:%S")
        parts.append(f"{start:%Y-%m-%d %H:%M:%S} to {shown_end} UTC")
    return ", ".join(parts) or None
