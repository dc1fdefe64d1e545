"""Shared settings and checks for the fuzz suites (``tests/test_fuzz_*.py``).

Every reader of user input must end one of two ways on any bytes: a result,
or an ``InputError`` whose message is one line naming the file. ``make test``
runs a small number of cases per reader; ``make fuzz`` sets
``SEGLOC_FUZZ_EXAMPLES`` (10,000 by default there) for the long run.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from hypothesis import HealthCheck, settings

from segloc_cli.errors import InputError

T = TypeVar("T")

FUZZ_EXAMPLES = int(os.environ.get("SEGLOC_FUZZ_EXAMPLES", "40"))
"""Cases per fuzz test: small in ``make test``, large in ``make fuzz``."""

fuzz_settings = settings(
    max_examples=FUZZ_EXAMPLES,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
"""Decorate every fuzz test with this (after ``@given``), and set no ``max_examples`` of its own."""


def outcome(read: Callable[[Path], T], path: Path) -> T | InputError:
    """Run ``read(path)``: its result, or the ``InputError`` it raised, checked to be one line
    that names ``path``. Any other exception fails the test by propagating."""
    try:
        return read(path)
    except InputError as exc:
        message = str(exc)
        assert "\n" not in message, f"error message spans lines: {message!r}"
        assert str(path) in message or path.name in message, (
            f"error message does not name the file: {message!r}"
        )
        return exc
