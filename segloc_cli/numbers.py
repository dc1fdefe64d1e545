"""How the files segloc writes (CSV, TUM, JSON) give their numbers: each rounded to the
precision of its quantity, then written as the shortest text that reads back to that rounded
float64. A heading of 125° that went through radians is written ``125.0``, not
``125.00000000000001``, and an error of 182.2 cm ``182.2``, not ``182.19999999999993``.

The quantity is read from the name a number is written under, which by the project's
convention ends with its unit (``x_m``, ``theta_deg``, ``time_s``, ``runtime_ms``,
``err_x_cm``, ``trans_pct``, ``rot_deg_per_m``, a setting's ``grid-m``, a table's
``median cm`` or ``p95 °``); a
name without one (a share, score, probability, quaternion component or count) takes
``PLAIN_DECIMALS``. In a JSON document a number takes the unit of the nearest key above it
that names one (``"trans_m": {"mean": …}``).

Each precision lies far below what the method resolves (millimetres, hundredths of a
degree) and within what float64 holds at the largest values the readers accept; a time a log
keeps in whole nanoseconds comes back from its text exactly.
"""

from __future__ import annotations

import functools
import json
import math
import re
from typing import TYPE_CHECKING, Any, SupportsFloat

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

DECIMALS = {
    "m": 6,  # 1 µm
    "cm": 4,  # 1 µm
    "mm": 3,  # 1 µm
    "deg": 6,  # 1e-6 °, 2e-8 rad
    "rad": 8,  # 1e-8 rad, 6e-7 °
    "s": 9,  # 1 ns: what a log keeps of a time
    "ms": 6,  # 1 ns
    "pct": 6,
    "deg_per_m": 6,
    "m2": 10,  # (10 µm)²
    "cm2": 8,
    "deg2": 10,
    "rad2": 12,
}
"""Decimals kept, by the unit a name ends with (its last one to three words, split at ``_``,
``-`` and spaces)."""

PLAIN_DECIMALS = 9
"""Decimals of a number whose name gives no unit: shares and probabilities in [0, 1],
scores, quaternion components, statistics such as a NEES."""

_SYMBOLS = {"°": "deg", "%": "pct"}
"""Units written as symbols in the column names of printed tables (``median °``)."""


@functools.lru_cache(maxsize=1024)  # asked of every cell of every row written, of few names
def unit_of(name: str) -> str | None:
    """The unit ``name`` ends with (a key of ``DECIMALS``), or None: ``err_x_cm`` → cm,
    ``rot_deg_per_m`` → deg_per_m, ``median °`` → deg, ``confidence`` → None."""
    words = [_SYMBOLS.get(word, word) for word in re.split(r"[-_\s]+", name.strip())]
    for size in (3, 2, 1):
        unit = "_".join(words[-size:])
        if len(words) >= size and unit in DECIMALS:
            return unit
    return None


def decimals_of(unit: str | None) -> int:
    """The decimals a number of ``unit`` keeps (``PLAIN_DECIMALS`` for None)."""
    return PLAIN_DECIMALS if unit is None else DECIMALS[unit]


def step_of(unit: str | None) -> float:
    """The precision of ``unit`` as a number (1e-6 for metres): a value read back from a file
    lies within half of it of the value written."""
    return 10.0 ** -decimals_of(unit)


def rounded(value: SupportsFloat, unit: str | None) -> float:
    """``value`` rounded to the precision of ``unit`` (correctly, as decimal text would be; a
    value too large for that many decimals in float64 stays itself); -0.0 becomes 0.0, NaN and
    the infinities stay."""
    return round(float(value), decimals_of(unit)) + 0.0


def number_text(value: SupportsFloat, unit: str | None) -> str:
    """``value`` as a file writes it: rounded to the precision of ``unit``, as the shortest
    text that reads back to the rounded float64 (``repr``); "nan" and "inf" as Python
    writes them (callers write an empty field or null instead)."""
    value = float(value)
    return repr(rounded(value, unit)) if math.isfinite(value) else repr(value)


def rounded_tree(value: Any, unit: str | None = None) -> Any:
    """A JSON-ready document with every float rounded to the unit of the nearest key above it
    that names one (``unit`` at the top); numpy numbers become Python ones, non-finite
    floats stay as they are (``json.dumps(allow_nan=False)`` refuses them)."""
    if isinstance(value, dict):
        return {key: rounded_tree(item, unit_of(str(key)) or unit) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [rounded_tree(item, unit) for item in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return rounded(value, unit)
    return value


def json_text(document: Any, indent: int = 2, ensure_ascii: bool = True) -> str:
    """``document`` as JSON text ending in a newline, every float rounded (``rounded_tree``);
    a non-finite float is refused (``ValueError``), as JSON has none."""
    text = json.dumps(
        rounded_tree(document), indent=indent, allow_nan=False, ensure_ascii=ensure_ascii
    )
    return text + "\n"


def rounded_frame(frame: pd.DataFrame) -> pd.DataFrame:
    """A copy of ``frame`` whose float columns are rounded to the unit of each column's name,
    for pandas to write (NaN and ±inf stay)."""
    import pandas as pd

    out = frame.copy()
    for column in frame.columns:
        if pd.api.types.is_float_dtype(frame[column]):
            unit = unit_of(str(column))
            out[column] = [rounded(v, unit) for v in frame[column].tolist()]
    return out
