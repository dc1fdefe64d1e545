"""Option values written as text parsed into values, each refused with ``click.BadParameter``
naming the option and saying what it takes: a pose ``X_M,Y_M,THETA_DEG``, a point ``X,Y``,
or text a parser of its own reads (``parsed``)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TypeVar

import click

T = TypeVar("T")


def _split_numbers(text: str) -> tuple[float, ...] | None:
    """The comma-separated numbers of ``text``; None where it holds other text."""
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        return None


def _numbers(text: str, count: int) -> tuple[float, ...]:
    """The ``count`` comma-separated numbers of ``text``; NaN each where it holds other text,
    or another count."""
    numbers = _split_numbers(text)
    return numbers if numbers is not None and len(numbers) == count else (math.nan,) * count


def seed_pose(text: str) -> tuple[float, ...] | None:
    """``--initial X_M,Y_M,THETA_DEG``, the first scan's pose, as (x m, y m, heading degrees;
    world frame); None when ``text`` is not three comma-separated numbers (``odom``, a file)."""
    numbers = _split_numbers(text)
    return numbers if numbers is not None and len(numbers) == 3 else None


def numbers_only(text: str) -> bool:
    """Whether ``text`` is comma-separated numbers, more than one (of any count)."""
    numbers = _split_numbers(text)
    return numbers is not None and len(numbers) > 1


def _quoted(value: str, count: int) -> str:
    """``value`` quoted for an error, with how many numbers it holds where that is not
    ``count``: "'0,0' is 2 numbers"."""
    numbers = _split_numbers(value)
    if numbers is None or len(numbers) == count:
        return repr(value)
    return f"{value!r} is {len(numbers)} numbers"


def parse_planar_pose(value: str, option: str, limit_m: float, example: str) -> tuple[float, ...]:
    """``X_M,Y_M,THETA_DEG`` text as (x m, y m, heading degrees), each finite, x and y within
    ±``limit_m``; else ``click.BadParameter`` naming ``option`` and giving ``example``."""
    x, y, theta_deg = _numbers(value, 3)
    # Each number finite first: max() of a NaN and a number can be the number.
    if not (all(map(math.isfinite, (x, y, theta_deg))) and max(abs(x), abs(y)) <= limit_m):
        raise click.BadParameter(
            f"{_quoted(value, 3)}; use X_M,Y_M,THETA_DEG, finite and within ±{limit_m:g} m "
            f"(e.g. {example})",
            param_hint=option,
        )
    return x, y, theta_deg


def parse_point(value: str, option: str, example: str) -> tuple[float, float]:
    """``X,Y`` text as (x m, y m), both finite; else ``click.BadParameter`` naming ``option``
    and giving ``example``."""
    x, y = _numbers(value, 2)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise click.BadParameter(
            f"{_quoted(value, 2)}; use X,Y in metres (e.g. {example})", param_hint=option
        )
    return x, y


def parsed(parse: Callable[[str], T], value: str, option: str) -> T:
    """``parse(value)``, its ``ValueError`` refused as ``click.BadParameter`` naming ``option``
    (the error's text says what is wrong)."""
    try:
        return parse(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint=option) from None


def parse_frame_pair(value: str | None) -> tuple[str, str] | None:
    """``PARENT,CHILD`` (``--frames``) as two different frame names, leading slashes left
    out; None stays None."""
    if value is None:
        return None
    parts = [part.strip().lstrip("/") for part in value.split(",")]
    if len(parts) != 2 or not all(parts) or parts[0] == parts[1]:
        raise click.BadParameter(
            f"{value!r} is not two different frames; write PARENT,CHILD, e.g. map,base_link"
        )
    return parts[0], parts[1]
