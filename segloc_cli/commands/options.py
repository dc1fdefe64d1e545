"""Options shared by the commands: settings made into options, ``--config``, run files.

Every setting of ``config.SETTINGS`` becomes an option here, its default and
bounds read from the configuration; the options a command lists in ``--help``
are those with a help text. ``--config FILE.toml`` sets any option of the
command from the file's table for it (flags given on the command line win),
and ``Invocation`` hands a command what it was asked: the resolved options by
key, the ``Config`` they make, and the run file to write beside the output.
"""

from __future__ import annotations

import difflib
import importlib
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click

from segloc_cli.config import GUESSES_KEYWORD, SETTINGS, Config, Setting, number_within
from segloc_cli.errors import InputError

OUTPUT_KEYS = frozenset({"out", "tum", "mcap", "survey-out", "plots", "config", "force"})
"""Options that name what a run writes (or how), not what it computes: no run file holds
them, and they are no inputs (a run file that named ``--mcap`` would have its repetition
write over the first run's view)."""

COMMAND_LINE_ONLY = frozenset({"force"})
"""Options a configuration file may not set: ``--force`` must be seen where it is given, or
a file kept for its settings would overwrite outputs unasked."""


def warn(message: str) -> None:
    """Print a warning line on standard error."""
    click.echo(f"segloc: warning: {message}", err=True)


def within_cores(jobs: int, running: str) -> int:
    """``--jobs`` no more than the cores segloc may use here (more processes would only share
    them), with a warning that ends in ``running`` (its ``{cores}`` filled in) when it asked
    for more."""
    from segloc_cli.parallel import usable_cores

    cores = usable_cores()
    if jobs <= cores:
        return jobs
    running = running.format(cores=cores)
    warn(f"--jobs {jobs} is more than the {cores} core(s) segloc may use here; {running}")
    return cores


def info(message: str) -> None:
    """Print a progress or summary line on standard error."""
    click.echo(message, err=True)


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


def load_log(path: Path):
    """Read a segloc MCAP log, printing its reader's warnings."""
    from segloc_cli.io.mcap_log import read_log

    log = read_log(path)
    for warning in log.warnings:
        warn(warning)
    return log


class _Checked:
    """A click type whose values ``check`` checks (a ``Setting``'s ``checked``, or the bounds
    of a number), its ``SettingError`` the option's error; the click type it is mixed into
    gives the help its metavar and range."""

    check: Callable[[Any], Any]

    def convert(self, value, param, ctx):
        from segloc_cli.config import SettingError

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
        super().__init__(setting.choices)
        self.setting, self.check = setting, setting.checked


class _SettingIntRange(_Checked, click.IntRange):
    def __init__(self, setting: Setting):
        high = None if setting.high is None else int(setting.high)
        super().__init__(min=int(setting.low), max=high)
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


class GuessSource(click.ParamType):
    """``--initial``: the keyword ``odom`` or a file of poses (a path in a ``--config``)."""

    name = "text"
    holds_path = True


def holds_path(option: click.Parameter) -> bool:
    """Whether the option's value is a file or folder (relative ones are taken relative to a
    ``--config`` file's folder)."""
    return isinstance(option.type, click.Path) or getattr(option.type, "holds_path", False)


def setting_option(key: str, **help_fields: str) -> Callable:
    """The option of setting ``key``: bounds, choices and default from ``config.SETTINGS``;
    ``help_fields`` fill the placeholders of its help text."""
    setting = SETTINGS[key]
    listed = setting.help is not None
    text = setting.help.format(**help_fields) if listed else setting.doc
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

config_option = click.option(
    "--config",
    type=click.Path(path_type=Path, dir_okay=False),
    is_eager=True,
    expose_value=False,
    callback=lambda ctx, param, value: _apply_config(ctx, value),
    help="Read options from this TOML file's table for the command (e.g. [localize]; keys "
    "are the long option names); options given here win. A run file (*.run.toml) repeats "
    "its run.",
)
"""``--config FILE.toml`` on every command that does work."""


def option_key(option: click.Parameter) -> str:
    """An option's key in a configuration table: its long name without the dashes."""
    longest = max(option.opts, key=len)
    return longest.lstrip("-")


def options_by_key(command: click.Command) -> dict[str, click.Option]:
    return {
        option_key(p): p
        for p in command.params
        if isinstance(p, click.Option) and option_key(p) not in ("config", "help")
    }


def _command_paths(group: click.Group, prefix: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    for name, command in group.commands.items():
        if isinstance(command, click.Group):
            yield from _command_paths(command, (*prefix, name))
        else:
            yield (*prefix, name)


def command_path(ctx: click.Context) -> tuple[str, ...]:
    """The command's names below ``segloc``: ("map", "build")."""
    return tuple(ctx.command_path.split()[1:])


def _apply_config(ctx: click.Context, value: Path | None) -> None:
    """Read ``--config``: every key of the command's table becomes that option's default
    (so the command line still overrides it); an unknown key or bad value is refused."""
    from segloc_cli import runfile

    if value is None or ctx.resilient_parsing:
        return
    command = command_path(ctx)
    table = runfile.read_table(value, command, set(_command_paths(ctx.find_root().command)))
    record = runfile.run_record(value)
    runfile.check_run_command(value, record, command)
    note = runfile.version_note(value)
    if note is not None:
        warn(note)
    if not table:
        warn(f"{value} has no [{'.'.join(command)}] table; nothing was set from it")
    options = options_by_key(ctx.command)
    defaults = {}
    for key, raw in table.items():
        option = options.get(key)
        if option is None:
            raise InputError(_unknown_key(key, command, options), path=value)
        if key in COMMAND_LINE_ONLY:
            raise InputError(
                f"key {key!r} is not read from a file; give --{key} on the command line",
                path=value,
            )
        defaults[option.name] = config_value(ctx, option, key, raw, value)
    ctx.default_map = {**(ctx.default_map or {}), **defaults}
    ctx.meta[RECORDED_INPUTS] = (value, runfile.recorded_inputs(record))


def _unknown_key(key: str, command: tuple[str, ...], options: dict) -> str:
    name = ".".join(command)
    close = difflib.get_close_matches(key, list(options), n=1)
    hint = f"did you mean {close[0]!r}?" if close else f"see segloc {' '.join(command)} --help"
    return f"unknown key {key!r} in [{name}]; keys are long option names; {hint}"


def config_value(ctx: click.Context, option: click.Option, key: str, raw: Any, path: Path):
    """A value of a configuration table, checked as the option checks its own: a setting's by
    ``tablevalues.setting_value``, any other's kind by ``tablevalues.table_value`` and its
    value by its click type (a relative path taken relative to the file's folder)."""
    from segloc_cli.tablevalues import Takes, setting_value, table_value

    setting = getattr(option.type, "setting", None)
    if setting is not None:
        return setting_value(setting, raw, path)
    numeric = click.types.IntParamType | click.types.FloatParamType
    takes = Takes(
        flag=option.is_flag,
        number=isinstance(option.type, numeric),
        whole=isinstance(option.type, click.types.IntParamType),
        path=holds_path(option),
        choice=isinstance(option.type, click.Choice),
    )
    raw = table_value(key, raw, takes, path)
    if holds_path(option) and raw != GUESSES_KEYWORD:
        raw = str(path.parent / raw)  # an absolute raw stays itself
    try:
        return option.type_cast_value(ctx, raw)
    except click.BadParameter as exc:
        raise InputError(f"key {key!r}: {exc.format_message()}", path=path) from None


RECORDED_INPUTS = "segloc.recorded_inputs"
"""Key of the click context's ``meta`` holding the ``--config`` file and the inputs it
records, (role, sha256) pairs, when it is a run file."""


@dataclass(frozen=True)
class Invocation:
    """What a command was asked: its names, its options by key (as resolved from the
    command line, ``--config`` and the defaults), its file arguments, and the force flag."""

    command: tuple[str, ...]
    options: dict[str, Any]
    arguments: list[tuple[str, Path]]
    force: bool

    @classmethod
    def current(cls) -> Invocation:
        """The invocation of the command running now."""
        ctx = click.get_current_context()
        options, arguments = {}, []
        for param in ctx.command.params:
            value = ctx.params.get(param.name)
            if isinstance(param, click.Argument):
                values = value if isinstance(value, tuple) else (value,)
                role = param.human_readable_name.rstrip(".")
                arguments += [(role, v) for v in values if isinstance(v, Path)]
            elif option_key(param) not in OUTPUT_KEYS:
                options[option_key(param)] = _as_path(param, value)
        return cls(command_path(ctx), options, arguments, bool(ctx.params.get("force")))

    @property
    def config(self) -> Config:
        """The settings the options make, every other at its default."""
        return Config.from_values(self.options)

    def inputs(self) -> list[tuple[str, Path]]:
        """Every file the run read: its arguments and its options that name a file."""
        named = [(k, v) for k, v in self.options.items() if isinstance(v, Path) and v.is_file()]
        return [*self.arguments, *named]

    def write_run_file(self, output: Path, also_read: list[tuple[str, Path]] = ()) -> Path:
        """Write the run file beside ``output``, its inputs with ``also_read`` (role, path):
        files the inputs led to, such as a grid's image; return its path."""
        from segloc_cli.runfile import run_file_path, write_run_file

        path = run_file_path(output)
        inputs = [*self.inputs(), *also_read]
        hashes = write_run_file(path, self.command, self.options, inputs)
        _warn_unrepeated(inputs, hashes)
        return path


def _warn_unrepeated(inputs: list[tuple[str, Path]], hashes: list[str]) -> None:
    """Warn for each input (role, path) whose sha256 (``hashes``, in order) is not among those
    the ``--config`` run file records for that role: the run does not repeat the recorded one."""
    config, recorded = click.get_current_context().meta.get(RECORDED_INPUTS, (None, set()))
    for (role, source), digest in zip(inputs, hashes, strict=True):
        if recorded and (role, digest) not in recorded:
            warn(
                f"{source} is not the {role} that {config} records (its sha256 differs): "
                "this run does not repeat that one"
            )


def _as_path(option: click.Parameter, value: Any) -> Any:
    """The value of a file-naming option as a ``Path`` (``--initial odom`` stays a word)."""
    if holds_path(option) and isinstance(value, str) and value != GUESSES_KEYWORD:
        return Path(value)
    return value


def path_option(*names: str, required: bool = False, help: str) -> Callable:
    """An option naming a file or folder (``--map``, ``--out``, ...): a ``Path``, or None
    when not given."""
    return click.option(*names, required=required, type=click.Path(path_type=Path), help=help)


def sensor_options(noise_help: str) -> tuple[Callable, Callable]:
    """``--noise-cm`` and ``--seed`` of the simulated scanner (``simulate``, ``emulate``),
    the noise's default that of ``sim.SensorModel``."""
    from segloc_cli.sim import SensorModel

    noise = click.option(
        "--noise-cm",
        type=FiniteRange(min=0, max=100),
        default=SensorModel.noise_cm,
        show_default=True,
        help=noise_help,
    )
    seed = click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
    return noise, seed
