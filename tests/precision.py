"""Numbers read back from the files segloc writes: equal to what was written to the
precision of their unit (``numbers.py``), and written without binary noise."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd

from segloc_cli.numbers import decimals_of, step_of, unit_of

BINARY_NOISE = re.compile(r"\d\.\d{12,}|\d{17,}")
"""A number written with 12 or more decimals, or 17 or more digits: float64 noise such as
``125.00000000000001`` or ``182.19999999999993``."""


def assert_within_precision(read, written, unit: str | None) -> None:
    """``read`` (from a file) equals ``written`` within half a step of ``unit``'s precision
    (and the float64 rounding of the larger values), NaN where it is NaN."""
    read, written = np.asarray(read, dtype=float), np.asarray(written, dtype=float)
    np.testing.assert_array_equal(np.isnan(read), np.isnan(written))
    known = ~np.isnan(written)
    slack = step_of(unit) / 2 + np.spacing(np.abs(written[known]))
    np.testing.assert_array_less(np.abs(read[known] - written[known]), slack * 1.001)


def assert_frame_within_precision(read: pd.DataFrame, written: pd.DataFrame) -> None:
    """``read`` has ``written``'s columns, its float columns within the precision of each
    column's unit, every other column equal."""
    assert list(read.columns) == list(written.columns)
    for column in written.columns:
        if pd.api.types.is_float_dtype(written[column]):
            assert_within_precision(read[column], written[column], unit_of(column))
        else:
            assert read[column].tolist() == written[column].tolist(), column


def decimals(text: str) -> int:
    """The decimals a number's text holds (``1.25`` 2, ``1e-05`` 5, ``12`` 0)."""
    mantissa, _, exponent = text.lower().partition("e")
    places = len(mantissa.partition(".")[2])
    return max(0, places - int(exponent or 0))


def assert_at_precision(text: str, unit: str | None) -> None:
    """A number's ``text`` holds no more decimals than ``unit`` keeps."""
    assert decimals(text) <= decimals_of(unit), f"{text} has more decimals than {unit} keeps"
