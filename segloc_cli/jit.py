"""Compiling segloc's kernels: numba's ``njit``, cached on disk wherever numba can write.

Numba keeps a compiled kernel beside its module (``__pycache__``) or in the user's cache
folder, and refuses to define a ``cache=True`` kernel when it can write to neither (a
system install, a container run as another user, a read-only checkout). There segloc's
kernels are defined uncached instead: every run compiles the ones it uses, which costs
time but never the result, and the first one defined says so once on stderr.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

from numba import njit as _numba_njit

_said_uncached = False


def njit(function: Callable | None = None, **options: Any):
    """``numba.njit(**options)``, as a decorator with or without options; with
    ``cache=True`` where numba finds no folder to cache in, uncached (``_say_uncached``)."""
    if function is None:
        return lambda decorated: njit(decorated, **options)
    try:
        return _numba_njit(**options)(function)
    except RuntimeError as exc:
        if not options.get("cache") or "no locator available" not in str(exc):
            raise
    _say_uncached()
    return _numba_njit(**{**options, "cache": False})(function)


def _say_uncached() -> None:
    global _said_uncached
    if _said_uncached:
        return
    _said_uncached = True
    print(
        "segloc: numba can write no cache for the compiled kernels here (not beside the "
        "segloc_cli package nor in the user's cache folder), so each run compiles the ones "
        "it uses; set NUMBA_CACHE_DIR to a writable folder to keep them",
        file=sys.stderr,
    )
