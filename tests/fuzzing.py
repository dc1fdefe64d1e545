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
from hypothesis import strategies as st

from segloc_cli.errors import InputError

T = TypeVar("T")

FUZZ_EXAMPLES = int(os.environ.get("SEGLOC_FUZZ_EXAMPLES", "40"))
"""Cases per fuzz test: small in ``make test``, large in ``make fuzz``."""

ODD_TOKENS = [
    "nan",
    "NaN",
    "inf",
    "-inf",
    "-0",
    "-0.0",
    "0",
    "-1",
    "1e10",
    "1e308",
    "1.7976931348623157e308",
    "4.9e-324",
    "1e400",
    "-1e400",
    "1e-400",
    "1" + "0" * 400,  # 10**400
    "999999999999",
    "4294967296",
    str(2**63),
    str(-(2**63) - 1),
    str(2**64 + 1),
    "9" * 5000,  # beyond the digits int() accepts
    "0x10",
    "1_000",
    "+.5",
    "",
    " ",
    "\x00",
    "\xff\xfe",
    "\ufeff",
    "é",
    '"',
    '"1,2"',
    "#",
    "ok",
    "FLASER",
]
"""Numbers and non-numbers that have broken, or might break, a parser of numbers and counts."""

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


def byte_mutations(
    where: st.SearchStrategy[float] | None = None, length_fields: bool = False
) -> st.SearchStrategy[tuple]:
    """One damage to a byte string, for ``mutate``: a bit pattern flipped, bytes inserted or
    deleted, the end cut off, or (with ``length_fields``) an absurd little-endian length
    written where a length field might be. ``where`` draws the place as a fraction of the
    length (uniform by default)."""
    at = st.floats(0.0, 1.0) if where is None else where
    kinds = [
        st.tuples(st.just("flip"), at, st.integers(1, 255)),
        st.tuples(st.just("insert"), at, st.binary(min_size=1, max_size=40)),
        st.tuples(st.just("delete"), at, st.integers(1, 40)),
        st.tuples(st.just("truncate"), at, st.just(0)),
    ]
    if length_fields:
        lengths = st.sampled_from([2**32 - 1, 2**63, 10**7])
        kinds.append(st.tuples(st.just("length"), at, lengths))
    return st.one_of(kinds)


def mutate(data: bytes, mutations: list[tuple]) -> bytes:
    """``data`` with each ``byte_mutations`` damage done to it in turn."""
    buffer = bytearray(data)
    for kind, where, arg in mutations:
        at = min(int(where * len(buffer)), len(buffer))
        if kind == "flip" and at < len(buffer):
            buffer[at] ^= arg
        elif kind == "insert":
            buffer[at:at] = arg
        elif kind == "delete":
            del buffer[at : at + arg]
        elif kind == "truncate":
            del buffer[at:]
        elif kind == "length":
            buffer[at : at + 8] = arg.to_bytes(8, "little")
    return bytes(buffer)
