"""Ctrl-C, SIGTERM and SIGHUP as requests to stop at the next safe point, not as interruptions."""

from __future__ import annotations

import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)
"""Signals that ask a run to stop: Ctrl-C, a polite kill, the terminal closing."""

RETRY_S = 0.2
"""Seconds after which a stop signal's interrupt is raised again while the command has not
taken it: put off while a module was being imported, or swallowed by library code (numpy
comparing a dtype, a weakref callback) that clears whatever its callbacks raise."""

_pending: list[str] = []
"""The stop signals received whose interrupt the command has not taken yet (by name)."""


def install_interrupts() -> None:
    """Make every stop signal interrupt the command (``KeyboardInterrupt``, as Python makes
    Ctrl-C) where that is safe, and see that the interrupt is not lost: for the entry point,
    before anything heavy is imported. The command takes it with ``interrupt_taken``."""
    for signum in (*STOP_SIGNALS, signal.SIGALRM):
        signal.signal(signum, _interrupt_when_safe)


def interrupt_taken() -> None:
    """The command has the interrupt of the stop signals received so far, or has ended
    without it: raise it no more."""
    if _pending:  # else no timer of ours runs, and one of someone else's stays
        _pending.clear()
        signal.setitimer(signal.ITIMER_REAL, 0)


def _interrupt_when_safe(signum: int, frame: FrameType | None) -> None:
    """Raise ``KeyboardInterrupt`` for a stop signal, again every ``RETRY_S`` (``SIGALRM``)
    until the command takes it, and never in the middle of an import.

    An interrupt raised while an extension module initializes can leave it half made, and
    the interpreter then aborts on its way out instead of exiting 130. A repeat waits while
    an exception is handled: it may be this interrupt's, with cleanup under way."""
    if signum != signal.SIGALRM:
        _pending.append(signal.Signals(signum).name)
    elif not _pending or sys.exc_info()[1] is not None:
        if _pending:
            signal.setitimer(signal.ITIMER_REAL, RETRY_S)
        return
    signal.setitimer(signal.ITIMER_REAL, RETRY_S)
    if not _importing(frame):
        raise KeyboardInterrupt


def _importing(frame: FrameType | None) -> bool:
    """Whether ``frame`` runs, at any depth, inside Python's import machinery."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


@contextmanager
def stop_requests(requests: list[str] | None = None) -> Iterator[list[str]]:
    """While inside, ``STOP_SIGNALS`` are noted (by name, in order) in the list yielded:
    ``requests`` when given, so that code set up earlier can watch the same list.

    A loop that checks the list between steps ends cleanly, e.g. after
    finishing a file, where an exception could strike mid-write. The previous
    handlers are restored on leaving.
    """
    noted = [] if requests is None else requests

    def note(signum, _frame) -> None:
        noted.append(signal.Signals(signum).name)

    previous = {s: signal.signal(s, note) for s in STOP_SIGNALS}
    try:
        yield noted
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
