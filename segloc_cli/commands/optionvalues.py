"""Option values written as text (a pose ``X_M,Y_M,THETA_DEG``, ...) parsed into numbers,
each refused with ``click.BadParameter`` naming the option and the form it takes."""

from __future__ import annotations

import math

import click


def parse_planar_pose(value: str, option: str, limit_m: float, example: str) -> tuple[float, ...]:
    """``X_M,Y_M,THETA_DEG`` text as (x m, y m, heading degrees), each finite, x and y within
    ±``limit_m``; else ``click.BadParameter`` naming ``option`` and giving ``example``."""
    try:
        x, y, theta_deg = (float(v) for v in value.split(","))
    except ValueError:
        x = y = theta_deg = math.nan
    if not (max(abs(x), abs(y)) <= limit_m and math.isfinite(theta_deg)):
        raise click.BadParameter(
            f"{value!r}; use X_M,Y_M,THETA_DEG, finite and within ±{limit_m:g} m (e.g. {example})",
            param_hint=option,
        )
    return x, y, theta_deg
