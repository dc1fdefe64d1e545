"""The options the commands share: settings made into options, and the click types and
decorators they are made with.

Every setting of ``config.SETTINGS`` becomes an option here (``setting_option``), its
default and bounds read from the configuration and its values checked by
``Setting.checked``; the options a command lists in ``--help`` are those with a help text.
A command keeps its options in a tuple applied with ``with_options``; ``--config``
(``configfile.config_option``) sets any of them from a file.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from segloc_cli.commands.optionvalues import numbers_only, parse_planar_pose, seed_pose
from segloc_cli.config import (
    GUESSES_KEYWORD,
    SETTINGS,
    Setting,
    SettingError,
    number_within,
)
from segloc_cli.limits import MAX_COORDINATE_M
from segloc_cli.selection import ScanSelection


class _Checked:
    """A click type whose values ``check`` checks (a ``Setting``'s ``checked``, or the bounds
    of a number), its ``SettingError`` the option's error; the click type it is mixed into
    gives the help its metavar and range. A setting's type holds the setting (``setting``),
    by which ``--config`` checks the option's values as well."""

    check: Callable[[Any], Any]

    def convert(self, value, param, ctx):
        try:
            return self.check(value)
        except SettingError as exc:
            self.fail(str(exc), param, ctx)


class FiniteRange(_Checked, click.FloatRange):
    """``click.FloatRange`` that also refuses NaN and the infinities (which pass its bounds)."""

    def check(self, value: Any) -> float:
        return number_within(value, float, self.min, self.max, self.min_open)


class _SettingChoice(_Checked, click.Choice):
    def __init__(self, setting: Setting):
        super().__init__(setting.choices or ())
        self.setting, self.check = setting, setting.checked


class _SettingIntRange(_Checked, click.IntRange):
    def __init__(self, setting: Setting):
        low, high = setting.int_bounds
        super().__init__(min=low, max=high)
        self.setting, self.check = setting, setting.checked


class _SettingFloatRange(_Checked, click.FloatRange):
    def __init__(self, setting: Setting):
        super().__init__(min=setting.low, max=setting.high, min_open=setting.low_open)
        self.setting, self.check = setting, setting.checked


class ModuleChoice(click.Choice):
    """A ``click.Choice`` of the values of a module's constant, imported only when needed
    (help, parsing), so that naming it costs the command line no start-up time."""

    def __init__(self, module: str, name: str):
        self._source = (module, name)
        super().__init__(())

    @property
    def choices(self) -> tuple[str, ...]:
        module, name = self._source
        return tuple(str(value) for value in getattr(importlib.import_module(module), name))

    @choices.setter
    def choices(self, value) -> None:
        pass  # the constant is the only source


class FilePath(click.Path):
    """A file or folder named by an option or argument, as a ``Path``: never empty, which
    ``Path`` would take for the current folder (or fail on as a file name, later)."""

    def __init__(self, **checks: Any):
        super().__init__(path_type=Path, **checks)

    def convert(self, value, param, ctx):
        if isinstance(value, str) and not value:
            self.fail("an empty path; give a file or folder name", param, ctx)
        return super().convert(value, param, ctx)


class GuessSource(click.ParamType):
    """``--initial``: the keyword ``odom``, the first scan's pose ``X_M,Y_M,THETA_DEG`` (three
    numbers; checked here), or a file of poses (a path in a ``--config``)."""

    name = "text"
    holds_path = True

    def convert(self, value, param, ctx):
        if value == "":
            self.fail(
                f"an empty value; give {GUESSES_KEYWORD}, a pose X_M,Y_M,THETA_DEG or a file of "
                "poses",
                param,
                ctx,
            )
        # Numbers of another count than three are a pose mistyped, unless a file has that name.
        if seed_pose(value) is not None or (numbers_only(value) and not Path(value).exists()):
            parse_planar_pose(value, "--initial", MAX_COORDINATE_M, "11,1.6,90")
        return value

    @staticmethod
    def names_file(value: str) -> bool:
        """Whether the value names a file (not ``odom``, nor a pose)."""
        return value != GUESSES_KEYWORD and seed_pose(value) is None


def holds_path(option: click.Parameter) -> bool:
    """Whether the option's value is a file or folder (relative ones are taken relative to a
    ``--config`` file's folder)."""
    return isinstance(option.type, click.Path) or getattr(option.type, "holds_path", False)


def names_file(option: click.Parameter, value: Any) -> bool:
    """Whether ``value``, text given to ``option``, is a path (``--initial odom`` and
    ``--initial X,Y,THETA_DEG`` are not)."""
    if not (holds_path(option) and isinstance(value, str)):
        return False
    return getattr(option.type, "names_file", lambda _: True)(value)


def setting_option(key: str, **help_fields: str) -> Callable:
    """The option of setting ``key``: bounds, choices and default from ``config.SETTINGS``;
    ``help_fields`` fill the placeholders of its help text."""
    setting = SETTINGS[key]
    listed = setting.help is not None
    text = setting.doc if setting.help is None else setting.help.format(**help_fields)
    if setting.switch:
        return click.option(f"--{key}", is_flag=True, default=False, help=text, hidden=not listed)
    return click.option(
        f"--{key}",
        type=_setting_type(setting),
        default=setting.default,
        show_default=listed,
        metavar=setting.metavar,
        help=text,
        hidden=not listed,
    )


def _setting_type(setting: Setting) -> click.ParamType:
    """The click type of a setting's option: ``Setting.checked`` checks its values; text to
    parse is checked when the configuration is made (``config.run_config``)."""
    if setting.parse is not None:
        return click.STRING
    if setting.choices is not None:
        return _SettingChoice(setting)
    if setting.kind is int:
        return _SettingIntRange(setting)
    return _SettingFloatRange(setting)


def tuning_options(settings: tuple[Setting, ...]) -> Callable:
    """The unlisted options of tuning ``settings`` (set in ``--config``, or as flags)."""
    return with_options(*(setting_option(s.key) for s in settings))


def with_options(*decorators: Callable) -> Callable:
    """Apply option decorators in the order listed (the order ``--help`` shows them)."""

    def apply(function: Callable) -> Callable:
        for decorate in reversed(decorators):
            function = decorate(function)
        return function

    return apply


def format_option(module: str, constant: str, help: str) -> Callable:
    """``--format``: one of the formats that ``module``'s ``constant`` lists, md by default."""
    return click.option(
        "--format",
        "fmt",
        type=ModuleChoice(module, constant),
        default="md",
        show_default=True,
        help=help,
    )


force_option = click.option(
    "--force", is_flag=True, help="Overwrite the output file(s) if they exist."
)
"""``--force``: every command that writes a file refuses an existing one without it."""


def path_option(*names: str, required: bool = False, help: str) -> Callable:
    """An option naming a file or folder (``--map``, ``--out``, ...): a ``Path``, or None
    when not given."""
    return click.option(*names, required=required, type=FilePath(), help=help)


def sensor_options(noise_help: str, from_world: bool = False) -> tuple[Callable, Callable]:
    """``--noise-cm`` and ``--seed`` of the simulated scanner (``simulate``, ``emulate``),
    the noise's default that of ``sim.SensorModel``; ``from_world``: None by default, for
    the world file's choice or else the model's default (``noise_help`` says so)."""
    from segloc_cli.sim import MAX_NOISE_CM, SensorModel

    noise = click.option(
        "--noise-cm",
        type=FiniteRange(min=0, max=MAX_NOISE_CM),
        default=None if from_world else SensorModel.noise_cm,
        show_default=not from_world,
        help=noise_help,
    )
    seeds = click.IntRange(min=0)  # numpy's generators take no negative seed
    seed = click.option("--seed", type=seeds, default=0, show_default=True, help="Random seed.")
    return noise, seed


SCAN_SELECTION = (
    click.option(
        "--start",
        type=FiniteRange(min=0),
        metavar="SECONDS",
        help="Only the scans from this many seconds after the log's first scan on (segloc "
        "info shows how long the log is). Selected scans keep their numbers (pose_id).",
    ),
    click.option(
        "--end",
        type=FiniteRange(min=0),
        metavar="SECONDS",
        help="Only the scans up to this many seconds after the log's first scan.",
    ),
    click.option(
        "--every",
        type=click.IntRange(min=1),
        metavar="N",
        help="Only every Nth of those scans, from the first of them.",
    ),
    click.option(
        "--scans", type=click.IntRange(min=1), metavar="N", help="At most the first N of those."
    ),
)
"""The options that select some of a log's scans (``selection.ScanSelection``), alike in
every command that reads a log."""


def scan_selection(options: dict[str, Any]) -> ScanSelection:
    """The ``ScanSelection`` that a command's options (by key) ask for; ``--end`` before
    ``--start`` is refused as a bad ``--end``."""
    selection = ScanSelection.from_options(options)
    if selection.end_s is not None and selection.end_s < selection.start_s:
        raise click.BadParameter(
            f"{selection.end_s:g} is before --start {selection.start_s:g}", param_hint="--end"
        )
    return selection
