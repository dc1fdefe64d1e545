"""Which scans of a log a command works on: a span of time counted from the log's first
scan, every Nth scan of it, at most so many (``--start``, ``--end``, ``--every``,
``--scans``).

A selection picks scans; it does not cut the log. The scans left out keep their place: a
selected scan keeps its own number (its pose id), its odometry, and the neighbours its
window takes from the whole log, so it gets the row a run of the whole log gives it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.timing import readable_span

SELECTION_KEYS = ("start", "end", "every", "scans")
"""The options that select scans, by the key a configuration file gives them."""


@dataclass(frozen=True)
class ScanSelection:
    """The scans whose time lies from ``start_s`` to ``end_s`` seconds after the log's first
    scan (both included; ``end_s`` None: to the last scan), every ``every``-th of them from the
    first on, and of those the first ``count`` (None: all)."""

    start_s: float = 0.0
    end_s: float | None = None
    every: int = 1
    count: int | None = None

    @classmethod
    def from_options(cls, options: dict) -> ScanSelection:
        """The selection that a command's options (by key, ``SELECTION_KEYS``) ask for."""
        start, end, every, count = (options.get(key) for key in SELECTION_KEYS)
        return cls(0.0 if start is None else float(start), end, every or 1, count)

    @property
    def whole(self) -> bool:
        """Whether every scan is selected."""
        return self == ScanSelection()

    def indices(self, times_s: np.ndarray) -> np.ndarray:
        """Indices (K,) int64, in log order, of the selected scans among scans at ``times_s``
        (S,) seconds; the log's first scan is its earliest."""
        times_s = np.asarray(times_s, dtype=float)
        if times_s.size == 0:
            return np.zeros(0, dtype=np.int64)
        after_s = times_s - times_s.min()
        inside = after_s >= self.start_s
        if self.end_s is not None:
            inside &= after_s <= self.end_s
        chosen = np.flatnonzero(inside)[:: self.every]
        return chosen[: self.count].astype(np.int64)

    def options_text(self) -> str:
        """The options that make this selection, as a command line gives them."""
        given = [("start", self.start_s, 0.0), ("end", self.end_s, None)]
        given += [("every", self.every, 1), ("scans", self.count, None)]
        return " ".join(f"--{key} {value:g}" for key, value, unset in given if value != unset)

    def chosen(self, times_s: np.ndarray, path: object) -> np.ndarray:
        """``indices``, refusing a selection that holds no scan with an ``InputError`` naming
        ``path`` and the seconds the log's scans span."""
        index = self.indices(times_s)
        if index.size == 0:
            length = f"{np.ptp(times_s):.3f} s" if np.size(times_s) else "no scans"
            raise InputError(
                f"{self.options_text()} selects no scan: the log's scans span 0 to {length} "
                "after its first (segloc info shows the span)",
                path=path,
            )
        return index


def span_line(times_s: np.ndarray) -> str:
    """How long a log's scans span, and what ``--start`` and ``--end`` count from; then, where
    the seconds do not say it readily, the span in minutes or hours and the dates of Unix
    times (``timing.readable_span``)."""
    times_s = np.asarray(times_s, dtype=float)
    if times_s.size == 0:
        return "no scans"
    line = (
        f"{np.ptp(times_s):.3f} s from the first scan at {times_s.min():.3f} s "
        "(--start and --end count seconds from it)"
    )
    readable = readable_span(times_s)
    return line if readable is None else f"{line}; {readable}"
