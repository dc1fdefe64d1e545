"""Ctrl-C, SIGTERM and SIGHUP as requests to stop at the next safe point, not as interruptions."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager

STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)
"""Signals that ask a run to stop: Ctrl-C, a polite kill, the terminal closing."""


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
