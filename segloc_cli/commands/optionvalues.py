"""Option values written as text parsed into values, each refused with ``click.BadParameter``
naming the option and saying what it takes: a pose ``X_M,Y_M,THETA_DEG``, a point ``X,Y``,
or text a parser of its own reads (``parsed``)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TypeVar

import click

T = TypeVar("T")


def _numbers(text: str, count: int) -> tuple[float, ...]:
    """The ``count`` comma-separated numbers of ``text``; NaN each where it holds other text,
    or another count."""
    try:
        numbers = tuple(float(v) for v in text.split(","))
    except ValueError:
        numbers = ()
    return numbers if len(numbers) == count else (math.nan,) * count


def parse_planar_pose(value: str, option: str, limit_m: float, example: str) -> tuple[float, ...]:
    """``X_M,Y_M,THETA_DEG`` text as (x m, y m, heading degrees), each finite, x and y within
    ±``limit_m``; else ``click.BadParameter`` naming ``option`` and giving ``example``."""
    x, y, theta_deg = _numbers(value, 3)
    if not (max(abs(x), abs(y)) <= limit_m and math.isfinite(theta_deg)):
        raise click.BadParameter(
            f"{value!r}; use X_M,Y_M,THETA_DEG, finite and within ±{limit_m:g} m (e.g. {example})",
            param_hint=option,
        )
    return x, y, theta_deg


def parse_point(value: str, option: str, example: str) -> tuple[float, float]:
    """``X,Y`` text as (x m, y m), both finite; else ``click.BadParameter`` naming ``option``
    and giving ``example``."""
    x, y = _numbers(value, 2)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise click.BadParameter(
            f"{value!r}; use X,Y in metres (e.g. {example})", param_hint=option
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
