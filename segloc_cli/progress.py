"""Progress of long commands on standard error: a bar on a terminal, plain lines elsewhere.

Work that can take more than ``SHOW_AFTER_S`` seconds (reading and importing logs, building
maps, localizing, drawing figures) reports its steps to a ``Progress``. On a terminal,
tqdm draws a bar with the rate and the time left once the work has run that long; when
standard error is a file or a pipe (a CI log, ``2> run.log``), a plain line with the same
figures is written every ``PLAIN_EVERY_S`` seconds instead, and a last one when it ends.
Work that ends sooner shows nothing. The rate and the time left leave the first step out:
it may include compiling the kernels or reading a map, which the steps after it do not.
The library functions take a ``Progress`` (or a ``ProgressFactory`` for several stretches)
and default to showing nothing, so they print only when a command asks. The bar is erased
when the work ends, or left where it stopped when Ctrl-C stops it, the line after it saying so.

Every line and the bar start with ``segloc:`` (``wording.said``), as all of segloc's lines on
standard error do. Work whose steps end in outcomes worth watching counts them beside the
rate (``tally``: a track's lost and recovered scans).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Mapping, Sequence
from typing import IO

from tqdm import tqdm

from segloc_cli.wording import counted, plural, said

SHOW_AFTER_S = 2.0
"""Work that ends sooner than this (s) shows no progress."""
PLAIN_EVERY_S = 5.0
"""Seconds between the plain lines written when standard error is not a terminal."""
STARTING = "starting"
"""What a line or the bar says in place of the rate and the time left before there is a rate:
until the step after the first has ended."""
_STARTING_BAR = "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}, " + STARTING + "{postfix}]"
_STARTING_COUNT = "{desc}: {n_fmt}{unit} [{elapsed}, " + STARTING + "{postfix}]"
"""The bar's formats (tqdm's own, with ``STARTING`` for the rate and the time left) until
there is a rate, for a known total and for an unknown one."""


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
        self.tallies: dict[str, int] = {}
        """Steps by outcome, of the outcomes ``tally`` named, in its order."""
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
                desc=said(what),
                unit=unit,
                file=self._stream,
                delay=SHOW_AFTER_S,
                bar_format=_STARTING_BAR if total else _STARTING_COUNT,
                leave=False,
                dynamic_ncols=True,
                smoothing=0,  # the average rate since the first step (see advance)
            )

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_exc: object) -> None:
        self.close(stopped=exc_type is not None and issubclass(exc_type, KeyboardInterrupt))

    def tally(self, outcomes: Sequence[str]) -> Progress:
        """Count the steps that end in each of ``outcomes`` (``advance``'s ``outcome``) and
        show the counts, zeros too, beside the rate; returns this progress."""
        self.tallies = dict.fromkeys(outcomes, 0)
        self._show_tallies()
        return self

    def count(self, counts: Mapping[str, int]) -> None:
        """Show ``counts`` (name → how many) beside the rate in place of the outcomes'
        tallies: what a step can make more than one of, or none (keyframes, loops)."""
        self.tallies = dict(counts)
        self._show_tallies()

    def advance(self, steps: int = 1, outcome: str | None = None) -> None:
        """``steps`` more steps are done, ending in ``outcome`` (counted if ``tally`` named
        it)."""
        self.done += steps
        if outcome in self.tallies:
            self.tallies[outcome] += steps
            self._show_tallies()
        now = time.monotonic()
        first = self._first is None
        if self._first is None:
            self._first = (self.done, now)
        if self._bar is not None:
            if self.done > self._first[0]:
                self._bar.bar_format = None  # tqdm's own, with the rate and the time left
            self._bar.update(steps)
            if first:
                self._count_from_here(now)
            return
        if now >= self._next_line:
            self._write_line(now)
            self._next_line = now + PLAIN_EVERY_S

    def _show_tallies(self) -> None:
        if self._bar is not None and self.tallies:
            self._bar.set_postfix_str(tallies_text(self.tallies), refresh=False)

    def _count_from_here(self, now: float) -> None:
        """Have the bar's rate count from the end of the first step: tqdm's average rate is
        (n - initial) / (time since start_t); the bar stays hidden for what is left of
        ``SHOW_AFTER_S``, and is cleared when it closes as any shown bar is."""
        assert self._bar is not None
        self._bar.initial = self._bar.n
        self._bar.start_t = self._bar.last_print_t = time.time()
        self._bar.delay = max(0.0, SHOW_AFTER_S - (now - self._started))

    def close(self, stopped: bool = False) -> None:
        """End the display: the bar is removed, or when ``stopped`` (by Ctrl-C) left as it
        stands on a line of its own, so that the line after it (``segloc: interrupted``)
        follows it; plain lines end with a last one."""
        if self._bar is not None:
            self._bar.leave = stopped
            self._bar.close()
            self._bar = None
        elif self._lines:
            if self.done != self._shown_done:  # not when the last line said it all
                self._write_line(time.monotonic())
            self._lines = 0

    def _write_line(self, now: float) -> None:
        first_done, first_at = self._first or (0, self._started)
        rate = (self.done - first_done) / (now - first_at) if now > first_at else 0.0
        line = plain_line(
            self.what, self.done, self.total, self.unit, now - self._started, rate, self.tallies
        )
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
    tallies: Mapping[str, int] | None = None,
) -> str:
    """``segloc: localizing: 30/100 scans (30%), 2.4 scans/s, 00:28 left``: the line
    written where no bar can be drawn (an unknown total gives the time so far instead);
    ``rate`` in steps per second, by default ``done`` over ``elapsed_s`` (0: not known yet,
    and the line says "starting" instead of a rate and the time left);
    ``tallies``, steps by outcome, follow ("; 2 lost, 1 recovered")."""
    if rate is None:
        rate = done / elapsed_s if elapsed_s > 0 else 0.0
    speed = (
        STARTING
        if rate <= 0
        else f"{rate:.1f} {unit}s/s"
        if rate >= 1
        else f"{1 / rate:.1f} s/{unit}"
    )
    if total:
        left = f", {tqdm.format_interval((total - done) / rate)} left" if rate > 0 else ""
        line = f"{what}: {done}/{total} {plural(total, unit)} ({done / total:.0%}), {speed}{left}"
    else:
        line = f"{what}: {counted(done, unit)}, {speed}, {tqdm.format_interval(elapsed_s)} so far"
    if tallies:
        line += f"; {tallies_text(tallies)}"
    return said(line)


def tallies_text(tallies: Mapping[str, int]) -> str:
    """Steps by outcome in words: "2 lost, 1 recovered"."""
    return ", ".join(f"{n} {outcome}" for outcome, n in tallies.items())


class _Silent(Progress):
    """Progress nobody sees (the default of library functions)."""

    def __init__(self) -> None:
        self.what, self.total, self.unit, self.done = "", None, "", 0
        self.tallies = {}

    def advance(self, steps: int = 1, outcome: str | None = None) -> None:
        pass

    def tally(self, outcomes: Sequence[str]) -> Progress:
        return self

    def count(self, counts: Mapping[str, int]) -> None:
        pass

    def close(self, stopped: bool = False) -> None:
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
