"""``Setting.checked``: one check of each setting's values, in the words of click's own types.

The command line, ``--config`` files and sweep specs all check a setting's value through
``Setting.checked``; what it accepts and what it says must be what click's ``FloatRange``
(with finiteness), ``IntRange`` and ``Choice`` would, so that no message changes.
"""

from __future__ import annotations

import math

import click
import pytest

from segloc_cli.config import SETTINGS, Setting, SettingError, number_within

VALUES = ["0", "1", "-1", "0.5", "6.5", "1e400", "nan", "inf", "-inf", "abc", "", " 2 ", "1_0",
          "0x10", "200", "100000", 0, 1, -1, 0.0, 2.5, 1e5, math.nan, math.inf, -math.inf, True,
          "product", "sum", "icp", "gicp", "two-stage", "Product"]  # fmt: skip


def _click_type(setting: Setting) -> click.ParamType:
    """The click type the option of ``setting`` had before ``Setting.checked``."""
    if setting.choices is not None:
        return click.Choice(setting.choices)
    if setting.kind is int:
        high = None if setting.high is None else int(setting.high)
        return click.IntRange(min=int(setting.low), max=high)
    return click.FloatRange(min=setting.low, max=setting.high, min_open=setting.low_open)


def _click_says(setting: Setting, value) -> tuple[str, object]:
    kind = _click_type(setting)
    try:
        number = kind.convert(value, None, None)
    except click.BadParameter as exc:
        return "refused", exc.message
    if isinstance(kind, click.FloatRange) and not math.isfinite(number):
        return "refused", f"{value!r} is not a finite number."
    return "taken", number


def _checked_says(setting: Setting, value) -> tuple[str, object]:
    try:
        return "taken", setting.checked(value)
    except SettingError as exc:
        assert exc.key == setting.key
        return "refused", str(exc)


CHECKED = [s for s in SETTINGS.values() if not s.switch and s.parse is None]


@pytest.mark.parametrize("setting", CHECKED, ids=lambda s: s.key)
def test_checked_takes_and_refuses_as_clicks_types_did(setting):
    for value in VALUES:
        if setting.kind is int and isinstance(value, float) and not math.isfinite(value):
            continue  # int(inf) overflows in click too; a file's reader refuses it before
        said = _checked_says(setting, value)
        assert said == _click_says(setting, value), (setting.key, value)


def test_a_bound_is_shown_as_given():
    with pytest.raises(SettingError, match=r"^-1.0 is not in the range x>=0\.$"):
        number_within("-1", float, 0)
    with pytest.raises(SettingError, match=r"^12 is not in the range 0\.0<x<=10\.0\.$"):
        number_within(12, int, 0.0, 10.0, low_open=True)
    assert number_within("3", int, 1) == 3


def test_the_command_line_says_it_after_the_option():
    from click.testing import CliRunner

    from segloc_cli.cli import cli

    args = ["localize", "x.mcap", "--map", "m", "--out", "o", "--grid-m", "-1"]
    result = CliRunner().invoke(cli, args)
    assert "Invalid value for '--grid-m': -1.0 is not in the range 0<x<=50." in result.output
