"""What a command was asked (``Invocation``): its options by key, as resolved from the
command line, ``--config`` and the defaults, the ``Config`` they make, its file arguments,
and the run file it writes beside its output."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from segloc_cli.commands.configfile import RECORDED_INPUTS, command_path, option_key
from segloc_cli.commands.options import names_file
from segloc_cli.commands.printing import warn
from segloc_cli.config import Config

if TYPE_CHECKING:
    from segloc_cli.runs.runfile import Stopped

OUTPUT_KEYS = frozenset(
    {"out", "tum", "mcap", "survey-out", "plots", "config", "force", "junit", "summary-md", "html"}
)
"""Options that name what a run writes (or how), not what it computes: no run file holds
them, and they are no inputs (a run file that named ``--mcap`` would have its repetition
write over the first run's view)."""


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

    def write_run_file(
        self,
        output: Path,
        also_read: Sequence[tuple[str, Path]] = (),
        whole_name: bool = False,
        stopped: Stopped | None = None,
    ) -> Path:
        """Write the run file beside ``output`` (``runfile.run_file_path``, named after its
        whole name with ``whole_name``), its inputs with ``also_read`` (role, path): files the
        inputs led to, such as a grid's image; for a run ``stopped`` before its end, how;
        return its path."""
        from segloc_cli.runs.runfile import run_file_path, write_run_file

        path = run_file_path(output, whole_name)
        inputs = [*self.inputs(), *also_read]
        hashes = write_run_file(path, self.command, self.options, inputs, stopped)
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
    """The value of a file-naming option as a ``Path`` (``--initial odom`` stays a word, and
    ``--initial X,Y,THETA_DEG`` text)."""
    if names_file(option, value):
        return Path(value)
    return value
