"""Progress of long commands on standard error: a bar on a terminal, plain lines elsewhere.

Work that can take more than ``SHOW_AFTER_S`` seconds (reading and importing logs, building
maps, localizing, drawing figures) reports its steps to a ``Progress``. On a terminal,
tqdm draws a bar with the rate and the time left once the work has run that long; when
standard error is a file or a pipe (a CI log, ``2> run.log``), a plain line with the same
figures is written every ``PLAIN_EVERY_S`` seconds instead, and a last one when it ends.
Work that ends sooner shows nothing. The library functions take a ``Progress`` (or a
``ProgressFactory`` for several stretches) and default to showing nothing, so they print
only when a command asks.
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
            )

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def advance(self, steps: int = 1) -> None:
        """``steps`` more steps are done."""
        self.done += steps
        if self._bar is not None:
            self._bar.update(steps)
            return
        now = time.monotonic()
        if now >= self._next_line:
            self._write_line(now)
            self._next_line = now + PLAIN_EVERY_S

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
        self._stream.write(
            plain_line(self.what, self.done, self.total, self.unit, now - self._started) + "\n"
        )
        self._stream.flush()
        self._lines += 1
        self._shown_done = self.done


def plain_line(what: str, done: int, total: int | None, unit: str, elapsed_s: float) -> str:
    """``segloc: localizing: 30/100 scans (30%), 2.4 scans/s, 00:28 left``: the line
    written where no bar can be drawn (an unknown total gives the time so far instead)."""
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
