"""Progress of long commands on standard error: a bar on a terminal, plain lines elsewhere.

Work that can take more than ``SHOW_AFTER_S`` seconds (reading and importing logs, building
maps, localizing, drawing figures) reports its steps to a ``Progress``. On a terminal,
tqdm draws a bar with the rate and the time left once the work has run that long; when
standard error is a file or a pipe (a CI log, ``2> run.log``), a plain line with the same
figures is written every ``PLAIN_EVERY_S`` seconds instead, and a last one when it ends.
Work that ends sooner shows nothing. The rate and the time left leave the first step out:
it may include compiling the kernels or reading a map, which the steps after it do not.
The library functions take a ``Progress`` (or a ``ProgressFactory`` for several stretches)
and default to showing nothing, so they print only when a command asks.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import IO

from tqdm import tqdm

SHOW_AFTER_S = 2.0
"""Work that ends sooner than this (s) shows no progress."""
PLAIN_EVERY_S = 5.0
"""Seconds between the plain lines written when standard error is not a terminal."""


class Progress:
    """Progress of ``total`` steps (None: unknown) of ``unit`` (singular, e.g. "scan")
    described by ``what`` ("localizing"); use as a context manager, call ``advance``.

    ``stream`` defaults to standard error; ``terminal`` (default: whether it is one)
    chooses the bar or the plain lines.
    """

    def __init__(
        self,
        what: str,
        total: int | None,
        unit: str,
        stream: IO[str] | None = None,
        terminal: bool | None = None,
    ):
        self.what, self.total, self.unit = what, total, unit
        self.done = 0
        self._stream = sys.stderr if stream is None else stream
        self._terminal = _is_terminal(self._stream) if terminal is None else terminal
        self._started = time.monotonic()
        self._first: tuple[int, float] | None = None
        """Steps done and the time when the first step ended: the rate counts from there."""
        self._next_line = self._started + max(SHOW_AFTER_S, PLAIN_EVERY_S)
        self._lines = 0
        self._shown_done = -1
        self._bar: tqdm | None = None
        if self._terminal:
            self._bar = tqdm(
                total=total,
                desc=what,
                unit=unit,
                file=self._stream,
                delay=SHOW_AFTER_S,
                leave=False,
                dynamic_ncols=True,
                smoothing=0,  # the average rate since the first step (see advance)
            )

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def advance(self, steps: int = 1) -> None:
        """``steps`` more steps are done."""
        self.done += steps
        now = time.monotonic()
        first = self._first is None
        if first:
            self._first = (self.done, now)
        if self._bar is not None:
            self._bar.update(steps)
            if first:
                self._count_from_here(now)
            return
        if now >= self._next_line:
            self._write_line(now)
            self._next_line = now + PLAIN_EVERY_S

    def _count_from_here(self, now: float) -> None:
        """Have the bar's rate count from the end of the first step: tqdm's average rate is
        (n - initial) / (time since start_t); the bar stays hidden for what is left of
        ``SHOW_AFTER_S``, and is cleared when it closes as any shown bar is."""
        assert self._bar is not None
        self._bar.initial = self._bar.n
        self._bar.start_t = self._bar.last_print_t = time.time()
        self._bar.delay = max(0.0, SHOW_AFTER_S - (now - self._started))

    def close(self) -> None:
        """End the display: the bar is removed; plain lines end with a last one."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        elif self._lines:
            if self.done != self._shown_done:  # not when the last line said it all
                self._write_line(time.monotonic())
            self._lines = 0

    def _write_line(self, now: float) -> None:
        first_done, first_at = self._first or (0, self._started)
        rate = (self.done - first_done) / (now - first_at) if now > first_at else 0.0
        line = plain_line(self.what, self.done, self.total, self.unit, now - self._started, rate)
        self._stream.write(line + "\n")
        self._stream.flush()
        self._lines += 1
        self._shown_done = self.done


def plain_line(
    what: str,
    done: int,
    total: int | None,
    unit: str,
    elapsed_s: float,
    rate: float | None = None,
) -> str:
    """``segloc: localizing: 30/100 scans (30%), 2.4 scans/s, 00:28 left``: the line
    written where no bar can be drawn (an unknown total gives the time so far instead);
    ``rate`` in steps per second, by default ``done`` over ``elapsed_s`` (0: not known)."""
    if rate is None:
        rate = done / elapsed_s if elapsed_s > 0 else 0.0
    speed = (
        "?" if rate == 0 else f"{rate:.1f} {unit}s/s" if rate >= 1 else f"{1 / rate:.1f} s/{unit}"
    )
    if total:
        left = tqdm.format_interval((total - done) / rate) if rate > 0 else "?"
        return f"segloc: {what}: {done}/{total} {unit}s ({done / total:.0%}), {speed}, {left} left"
    units = unit if done == 1 else f"{unit}s"
    return f"segloc: {what}: {done} {units}, {speed}, {tqdm.format_interval(elapsed_s)} so far"


class _Silent(Progress):
    """Progress nobody sees (the default of library functions)."""

    def __init__(self) -> None:
        self.what, self.total, self.unit, self.done = "", None, "", 0

    def advance(self, steps: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


SILENT: Progress = _Silent()
"""A ``Progress`` that shows nothing."""

ProgressFactory = Callable[[str, int | None, str], Progress]
"""Makes the ``Progress`` of one stretch of work from (what, total, unit): ``Progress``
itself in a command, ``silent`` in library use."""


def silent(what: str, total: int | None, unit: str) -> Progress:
    """The ``ProgressFactory`` that shows nothing."""
    return SILENT


def _is_terminal(stream: IO[str]) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False
