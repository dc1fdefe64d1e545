"""Distinct record times for logs whose records share a time or go back in time.

Some logs store the same time on many records: every record at 0, or absolute
times printed with six significant digits (1.13486e+09), so that hundreds of
records share one value. Pairing scans with poses by time needs every scan to
have its own time, so the importers replace such times by one rule:

**Colliding times.** Walk the records in file order. A record whose time is
greater than the time of the current group starts a new group; a record whose
time is not greater (equal: it collides; smaller: it goes back in time) joins
the current group. A group of k records whose first record has time T is
spread evenly over [T, T_next), T_next being the next group's time: the j-th
record of the group (j = 0 … k−1) gets T + j·(T_next − T)/k. The last group has
no T_next: its records are spaced by the median of (T_next − T)/k over all
earlier groups, but never more than 1 s apart (nor when the log has no other
group: every time equal, e.g. all 0), so a log of few groups far apart does not
spread its last records over hours. The first record of every group keeps its time exactly, so a log
whose times already increase strictly comes back unchanged. Where a gap is too
narrow for its records to get distinct floating-point values (records nanoseconds
apart at absolute times), each time that would not exceed the one before it is
raised to the next representable value.

Times are seconds; the rule does not depend on the time base (relative or
absolute). The original times are kept by the importers beside the new ones.

A log keeps each time in whole nanoseconds, so the importers' times are the ones a log
gives back (``logged_times``): each rounded to the nanosecond as the log writer rounds it,
and later than the one before. A survey or trajectory written with them pairs with the
log's scans exactly, even at a tolerance of 0 ms.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from segloc_cli.errors import InputError

LAST_GROUP_STEP_S = 1.0
"""Largest spacing (s) of the records of the last group (and the spacing when all times
are equal)."""

NS_PER_S = 1_000_000_000
SETTLE_STEPS = 8
"""Most rounds of writing and reading back a time before it is taken as kept."""

MAX_TIME_S = float(2**32)
"""Largest record time (s) an importer accepts, before and after making times distinct:
the end of 32-bit Unix time (the year 2106), well inside a log's nanosecond clock."""


def time_groups(times_s: np.ndarray) -> np.ndarray:
    """Group index (S,) of each record under the rule of the module docstring.

    ``times_s`` (S,) finite seconds in file order. Group 0 starts at the first
    record; a record starts a new group exactly when its time is greater than
    every time before it.
    """
    t = _checked(times_s)
    if t.size == 0:
        return np.zeros(0, dtype=np.int64)
    # A group's time is the largest time so far: records that join it are not greater.
    starts = np.concatenate([[True], t[1:] > np.maximum.accumulate(t)[:-1]])
    return np.cumsum(starts) - 1


def colliding(times_s: np.ndarray) -> np.ndarray:
    """Mask (S,) of the records in a group of more than one record.

    These are the records that share their time with another record or go back
    in time, and the first record of each such group; the count of them is what
    the importers report.
    """
    groups = time_groups(times_s)
    if groups.size == 0:
        return np.zeros(0, dtype=bool)
    return np.bincount(groups)[groups] > 1


def distinct_times(times_s: np.ndarray) -> np.ndarray:
    """Strictly increasing times (S,) in seconds for records in file order.

    ``times_s`` (S,) finite seconds, in file order. The rule is the module
    docstring's; a record alone in its group keeps its exact value, so strictly
    increasing input comes back identical. Raises ``ValueError`` on times that
    are not finite or not one-dimensional.
    """
    t = _checked(times_s)
    if t.size == 0:
        return t.copy()
    groups = time_groups(t)
    first = np.flatnonzero(np.concatenate([[True], np.diff(groups) > 0]))
    start_s = t[first]
    sizes = np.diff(np.append(first, t.size))
    steps = np.diff(start_s) / sizes[:-1]
    last_step = min(float(np.median(steps)), LAST_GROUP_STEP_S) if steps.size else LAST_GROUP_STEP_S
    steps = np.append(steps, last_step)
    rank = np.arange(t.size) - first[groups]
    # rank 0 adds exactly 0.0: the first record of every group keeps its time.
    out = start_s[groups] + rank * steps[groups]
    stalled = np.flatnonzero(out[1:] <= out[:-1])
    if stalled.size:
        for i in range(int(stalled[0]) + 1, t.size):
            if out[i] <= out[i - 1]:
                out[i] = np.nextafter(out[i - 1], np.inf)
    if not np.all(np.isfinite(out)):
        raise ValueError("times too large to be made distinct")
    return out


def logged_times(times_s: np.ndarray) -> np.ndarray:
    """Increasing times (S,) in seconds as a log keeps them: each a whole number of
    nanoseconds that the log writer's rounding (``round(t·10⁹)``) keeps and the reader gives
    back (ns / 10⁹), and each at least a nanosecond after the one before."""
    kept = np.empty(len(times_s))
    last_ns = -1
    for i, time_s in enumerate(np.asarray(times_s, dtype=float).tolist()):
        last_ns = _logged_ns(time_s, last_ns)
        kept[i] = last_ns / NS_PER_S
    return kept


def _logged_ns(time_s: float, after_ns: int) -> int:
    """The nanoseconds a log keeps for ``time_s``, raised past ``after_ns`` where needed."""
    ns, step = max(round(time_s * 1e9), after_ns + 1), 1
    while (kept := _settled_ns(ns)) <= after_ns:
        ns, step = after_ns + 1 + step, 2 * step  # past a float's spacing at large times
    return kept


def _settled_ns(ns: int) -> int:
    """``ns`` as the log ends up keeping it: past 2^53 ns (104 days), the time ns / 10⁹
    can round to other nanoseconds when written again; these settle in a step or two."""
    for _ in range(SETTLE_STEPS):
        again = round(ns / NS_PER_S * 1e9)
        if again == ns:
            break
        ns = again
    return ns


def importer_times(
    original_times_s: np.ndarray, path: Path, records: str, order: str, where: str
) -> tuple[np.ndarray, str | None]:
    """An importer's distinct times (S,) for its records, as a log keeps them
    (``logged_times``), and the warning to give, if any.

    ``original_times_s`` (S,) seconds, in the order ``order`` names ("file order");
    ``records`` names them in messages ("laser records"), ``where`` is how the
    warning names the file. Raises ``InputError`` naming ``path`` when the
    distinct times run past ``MAX_TIME_S``.
    """
    times_s = logged_times(distinct_times(original_times_s))
    if times_s.size and times_s[-1] > MAX_TIME_S:
        raise InputError(
            f"the times of the {records}, made distinct, run past {MAX_TIME_S:.0f} s "
            "(the year 2106); the log's times are not plausible (see README: colliding times)",
            path=path,
        )
    n_colliding = int(np.count_nonzero(colliding(original_times_s)))
    if not n_colliding:
        return times_s, None
    return times_s, (
        f"{where}: {n_colliding} of {times_s.size} {records} share their time with another "
        f"or go back in time; gave them distinct times in {order} (see README: colliding times)"
    )


def _checked(times_s: np.ndarray) -> np.ndarray:
    t = np.asarray(times_s, dtype=float)
    if t.ndim != 1:
        raise ValueError(f"times must be one-dimensional, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("times must be finite")
    return t
