"""Ctrl-C and SIGTERM as requests to stop at the next safe point, not as interruptions."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def stop_requests() -> Iterator[list[str]]:
    """While inside, SIGINT and SIGTERM are noted (by name, in order) in the list yielded.

    A loop that checks the list between steps ends cleanly, e.g. after
    finishing a file, where an exception could strike mid-write. The previous
    handlers are restored on leaving.
    """
    requests: list[str] = []

    def note(signum, _frame) -> None:
        requests.append(signal.Signals(signum).name)

    previous = {s: signal.signal(s, note) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield requests
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
