"""``--config FILE.toml``: a command's options set from its table in a file.

Every key of the command's table (``[localize]``, ``[map.build]``) becomes that option's
default, so that the command line still overrides it; an unknown key, a key that may only
be given on the command line, or a value the option would refuse is an ``InputError``
naming the file. A run file is such a file: ``RECORDED_INPUTS`` keeps the inputs it
records, for the run to say when it does not repeat that one.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import click

from segloc_cli.commands.options import FilePath, holds_path, names_file
from segloc_cli.commands.printing import warn
from segloc_cli.errors import InputError
from segloc_cli.wording import did_you_mean

COMMAND_LINE_ONLY = frozenset({"force"})
"""Options a configuration file may not set: ``--force`` must be seen where it is given, or
a file kept for its settings would overwrite outputs unasked."""

RECORDED_INPUTS = "segloc.recorded_inputs"
"""Key of the click context's ``meta`` holding the ``--config`` file and the inputs it
records, (role, sha256) pairs, when it is a run file."""

config_option = click.option(
    "--config",
    type=FilePath(dir_okay=False),
    is_eager=True,
    expose_value=False,
    callback=lambda ctx, param, value: _apply_config(ctx, value),
    help="Read options from this TOML file's table for the command (e.g. [localize]; keys "
    "are the long option names); options given here win. A run file (*.run.toml) repeats "
    "its run.",
)
"""``--config FILE.toml`` on every command that does work."""


def check_command_outputs(
    outputs: Mapping[str, str | Path | None],
    inputs: Iterable[str | Path | None],
    force: bool,
    replaced: Iterable[str] = (),
) -> None:
    """``io.files.check_outputs`` with the ``--config`` file read (if any) among ``inputs``:
    the file a command takes its options from is none of its outputs, ``--force`` or not;
    only a run repeated in place from its run file rewrites that (``runfile.RUN_FILE_OUTPUT``)."""
    from segloc_cli.io.files import check_outputs, same_file
    from segloc_cli.runs.runfile import RUN_FILE_OUTPUT

    ctx = click.get_current_context(silent=True)
    config = None if ctx is None else ctx.meta.get(RECORDED_INPUTS, (None,))[0]
    run_file = outputs.get(RUN_FILE_OUTPUT)
    if config is not None and run_file is not None and same_file(config, run_file):
        config = None
    check_outputs(outputs, [*inputs, config], force, replaced)


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


def _command_paths(
    command: click.Command, prefix: tuple[str, ...] = ()
) -> Iterator[tuple[str, ...]]:
    """The paths of the commands under ``command`` (the root group), e.g. ('map', 'build')."""
    if not isinstance(command, click.Group):
        return
    for name, sub in command.commands.items():
        if isinstance(sub, click.Group):
            yield from _command_paths(sub, (*prefix, name))
        else:
            yield (*prefix, name)


def command_path(ctx: click.Context) -> tuple[str, ...]:
    """The command's names below ``segloc``: ("map", "build")."""
    return tuple(ctx.command_path.split()[1:])


def _apply_config(ctx: click.Context, value: Path | None) -> None:
    """Read ``--config``: every key of the command's table becomes that option's default
    (so the command line still overrides it); an unknown key or bad value is refused."""
    from segloc_cli.runs import runfile

    if value is None or ctx.resilient_parsing:
        return
    command = command_path(ctx)
    table = runfile.read_table(value, command, set(_command_paths(ctx.find_root().command)))
    record = runfile.run_record(value)
    runfile.check_run_command(value, record, command)
    for note in (runfile.version_note(value), runfile.stopped_note(value, record)):
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
    hint = did_you_mean(key, list(options), f"see segloc {' '.join(command)} --help")
    return f"unknown key {key!r} in [{name}]; keys are long option names; {hint}"


def config_value(ctx: click.Context, option: click.Option, key: str, raw: Any, path: Path):
    """A value of a configuration table, checked as the option checks its own: a setting's by
    ``tablevalues.setting_value``, any other's kind by ``tablevalues.table_value`` and its
    value by its click type (a relative path taken relative to the file's folder)."""
    from segloc_cli.runs.tablevalues import Takes, setting_value, table_value

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
    if names_file(option, raw):
        raw = str(path.parent / raw)  # an absolute raw stays itself
    try:
        return option.type_cast_value(ctx, raw)
    except click.BadParameter as exc:
        raise InputError(f"key {key!r}: {exc.format_message()}", path=path) from None
