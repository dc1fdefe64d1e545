"""A scanner's range limit, found in its readings and checked against the limits a log states.

Readings are ranges in metres, as a log holds them (any shape); only finite positive
readings below ``segloc_cli.scan.MAX_RANGE_M`` can be returns.

No-return value. A scanner writes a fixed value for a beam that meets nothing (81.83 m,
81.91 m, 50 m), thousands of times, at the top of its readings; a lone corrupt reading
(99999 m) is not one. So the no-return value of a set of readings is the largest positive
value that occurs at least twice and makes up at least 0.5 % of all of them, provided that
at most 0.1 % of the readings lie above it (those then count as no return too). When no
value passes, the readings hold none (inf).

Stated limits. A log may state a limit of its own: a CARMEN ``PARAM *_laser_max`` (a
setting of the robot's navigation, not of the scanner), a ROBOTLASER1 record's
``maximum_range``, a ROS message's ``range_max``. A scanner reports nothing beyond its own
limit but its no-return value, so readings above a stated limit and below the no-return
value are returns the scanner measured beyond it: when there are more of them than stray
readings (``overruled``), that limit is not the scanner's, and applying it would drop
real returns (``dropped_returns`` counts them; ``overruled_text`` says so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from segloc_cli.scan import MAX_RANGE_M
from segloc_cli.wording import counted

SENTINEL_MIN_FRACTION = 0.005
"""Share of all readings the no-return value must make up at least."""
SENTINEL_MIN_COUNT = 2
"""Times the no-return value must occur at least: a lone reading never is one."""
SENTINEL_MAX_ABOVE_FRACTION = 0.001
"""Largest share of the readings that may lie above the no-return value."""


@dataclass(frozen=True)
class NoReturn:
    """The no-return value of some readings: ``value_m`` metres, inf when they hold none;
    ``rule`` says how it was found ("inferred: …") or why there is none ("none: …");
    ``unsure``: there is none although there were positive readings to find it in."""

    value_m: float
    rule: str
    unsure: bool

    @property
    def found(self) -> bool:
        return math.isfinite(self.value_m)

    def limit_text(self) -> str:
        """The limit this value gives, in words, for a message that says which limit is used."""
        if self.found:
            return f"{fmt_m(self.value_m)} m, the no-return value the readings repeat"
        return (
            "none, every positive reading counting as a return: no reading value repeats often "
            "enough at the top of the readings to be a no-return value"
        )


def fmt_m(value_m: float) -> str:
    """A distance in metres as text: up to 10 significant digits, "inf" for no limit."""
    return "inf" if math.isinf(value_m) else f"{value_m:.10g}"


def no_return_value(readings_m: np.ndarray, among: str = "the readings") -> NoReturn:
    """The no-return value of ``readings_m`` (see the module docstring); ``among`` names
    the readings in the rule's text."""
    readings = np.asarray(readings_m, dtype=float).reshape(-1)
    positive = readings[np.isfinite(readings) & (readings > 0.0)]
    if positive.size == 0:
        return NoReturn(math.inf, "none: no positive readings to infer it from", False)
    values, counts = np.unique(positive, return_counts=True)
    total = readings.size
    needed = max(SENTINEL_MIN_COUNT, SENTINEL_MIN_FRACTION * total)
    frequent = np.flatnonzero(counts >= needed)
    if frequent.size:
        i = int(frequent[-1])
        above = int(counts[i + 1 :].sum())
        if above <= SENTINEL_MAX_ABOVE_FRACTION * total:
            share = 100.0 * float(counts[i]) / total
            rule = (
                f"inferred: {fmt_m(float(values[i]))} m, the largest reading that repeats, "
                f"is {share:.3g} % of {among}"
            )
            if above:
                larger = "readings count" if above > 1 else "reading counts"
                rule += f"; the {above} larger {larger} as no return"
            return NoReturn(float(values[i]), rule, False)
    largest = fmt_m(float(values[-1]))
    return NoReturn(
        math.inf,
        f"none: no reading value repeats often enough at the top of {among} to be a "
        f"no-return value (the largest reading is {largest} m)",
        True,
    )


def _returns(readings_m: np.ndarray) -> np.ndarray:
    """The readings (1-D) that can be returns: finite, positive, below ``MAX_RANGE_M``."""
    readings = np.asarray(readings_m, dtype=float).reshape(-1)
    with np.errstate(invalid="ignore"):
        return readings[np.isfinite(readings) & (readings > 0.0) & (readings < MAX_RANGE_M)]


@dataclass(frozen=True)
class Overruled:
    """A stated limit that the scanner's returns lie beyond: ``beyond`` of them, above it
    and below ``no_return``, the no-return value found among the readings at or above it
    (inf when they hold none)."""

    beyond: int
    no_return: NoReturn


def overruled(readings_m: np.ndarray, stated_m: float) -> Overruled | None:
    """Whether real returns lie beyond a stated limit ``stated_m`` (metres): ``Overruled``
    when they do, None when the readings agree with it.

    The no-return value is looked for among the readings at or above the limit, where a
    scanner's no-return value is all there is when the limit is its own, however rarely
    it met nothing. The returns between the two must be at least ``SENTINEL_MIN_COUNT``
    and more than ``SENTINEL_MAX_ABOVE_FRACTION`` of ``readings_m``: as a few stray
    readings above a no-return value are no returns, so are a few above a stated limit.
    """
    returns = _returns(readings_m)
    at_or_above = returns[returns >= stated_m]
    if at_or_above.size == 0:
        return None
    no_return = no_return_value(at_or_above, f"the readings from {fmt_m(stated_m)} m on")
    beyond = int(np.count_nonzero((at_or_above > stated_m) & (at_or_above < no_return.value_m)))
    total = np.size(readings_m)
    if beyond < SENTINEL_MIN_COUNT or beyond <= SENTINEL_MAX_ABOVE_FRACTION * total:
        return None
    return Overruled(beyond, no_return)


def dropped_returns(readings_m: np.ndarray, stated_m: float, limit_m: float) -> tuple[int, float]:
    """The readings a limit of ``stated_m`` would drop (at or above it) that a limit of
    ``limit_m`` keeps (below it), metres: how many, and the largest of them (nan if none)."""
    returns = _returns(readings_m)
    dropped = returns[(returns >= stated_m) & (returns < limit_m)]
    return int(dropped.size), float(dropped.max()) if dropped.size else math.nan


@dataclass(frozen=True)
class GroupLimit:
    """The range limit used for a group of scans or records that state one of their own
    (``stated_limit``) which returns lie beyond: ``value_m`` metres, the ``warning`` saying
    so and the ``rule`` that gave it (for the sensor setting ``range_max_from``)."""

    value_m: float
    warning: str
    rule: str


def stated_limit(
    readings_m: np.ndarray, stated_m: float, field: str, group: str
) -> GroupLimit | None:
    """The limit of a ``group`` ("3 scans") whose ``field`` ("range_max") states
    ``stated_m`` metres and whose readings are ``readings_m``: None when the readings agree
    with it (``overruled``), else the no-return value found beyond it, with the warning and
    the rule."""
    check = overruled(readings_m, stated_m)
    if check is None:
        return None
    limit = check.no_return
    dropped = dropped_returns(readings_m, stated_m, limit.value_m)
    warning = overruled_text(
        f"the {field} of {group}", stated_m, dropped, np.size(readings_m), limit.limit_text()
    )
    rule = f"for {group} whose {field} ({fmt_m(stated_m)} m) returns lie beyond, {limit.rule}"
    return GroupLimit(limit.value_m, warning, rule)


def overruled_text(
    stated: str, stated_m: float, dropped: tuple[int, float], total: int, used: str
) -> str:
    """The warning that a stated limit is not the scanner's: ``stated`` names it ("PARAM
    robot_front_laser_max", "the range_max of 3 scans"), ``stated_m`` is its value (m),
    ``dropped`` what ``dropped_returns`` found among ``total`` readings, and ``used`` says
    which limit is used instead (``NoReturn.limit_text``)."""
    n, largest_m = dropped
    share = 100.0 * n / total if total else 0.0
    return (
        f"{stated} ({fmt_m(stated_m)} m) is not the scanner's range limit: it would have "
        f"dropped {counted(n, 'reading')} ({share:.3g} % of the readings) that are returns, "
        f"from {fmt_m(stated_m)} m up to {fmt_m(largest_m)} m; the limit used is {used} "
        "(--range-max-m sets one)"
    )
