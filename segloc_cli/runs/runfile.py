"""Configuration files in, run files out: the TOML that sets a command's options.

A configuration file holds one table per command (``[localize]``,
``[map.build]``, ``[import.carmen]``), its keys the command's long option
names (``grid-m = 1.5``). A run file is such a file written beside a command's
output (``est.csv`` → ``est.run.toml``): every option the run resolved, and in
its ``[run]`` table the segloc version and each input's path and sha256. Given
back as ``--config``, it makes the same output again. Paths in both are taken
relative to the file's own folder.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import tomli_w

from segloc_cli import __version__
from segloc_cli.errors import InputError
from segloc_cli.io.files import reading, sha256, write_text_atomic
from segloc_cli.wording import stopped_after

RUN_TABLE = "run"
"""The table of a run file that records how the file was made; ``--config`` skips it."""

MAX_CONFIG_BYTES = 1 << 20
"""Largest configuration file read (1 MiB): settings, not data."""
STOPPED_KEY = "stopped"
"""The key of a run file's ``[run]`` table that records a run stopped before its end."""


class Stopped(NamedTuple):
    """A run stopped before its end: the signal that stopped it (``by``: "SIGTERM",
    "Ctrl-C"), and how many of the scans it ``planned`` it had ``done``."""

    by: str
    done: int
    planned: int

    def __str__(self) -> str:
        return stopped_after(self.by, self.done, self.planned)


RUN_FILE_OUTPUT = "--out (run file)"
"""The name under which a command checks the run file it writes beside ``--out`` with its
other outputs (``files.check_outputs``)."""


def run_file_path(output: Path, whole_name: bool = False) -> Path:
    """Where the run file of ``output`` goes: beside it, ``est.csv`` → ``est.run.toml``; with
    ``whole_name``, after the whole name, ``map.dxf`` → ``map.dxf.run.toml``, for an output
    made from a file of the same stem (``map.json``) whose own run file it must leave be."""
    return beside(output, f"{output.suffix if whole_name else ''}.run.toml")


def beside(output: Path, ending: str) -> Path:
    """A file beside ``output`` named after it: ``est.csv`` and ".run.toml" → ``est.run.toml``."""
    return output.with_name(f"{output.stem if output.suffix else output.name}{ending}")


def read_table(path: Path, command: Sequence[str], commands: set[tuple[str, ...]]) -> dict:
    """The table of ``command`` (e.g. ("map", "build")) in the TOML file ``path`` ({} if the
    file has none).

    Tables that name no command of ``commands`` (nor ``[run]``) and keys outside any
    table are refused, naming them, so a misspelt table does not pass unnoticed.
    """
    document = load_toml(path)
    for key, value in document.items():
        if not isinstance(value, dict):
            raise InputError(
                f"key {key!r} is outside any table; put it under the table of its command, "
                f"e.g. [{' '.join(command).replace(' ', '.')}]",
                path=path,
            )
    _check_tables(path, document, commands)
    table: Any = document
    for name in command:
        table = table.get(name, {})
    return table


def load_toml(path: Path, what: str = "a TOML configuration") -> dict:
    """The TOML document in ``path``, refused with one line if it is unreadable, over
    ``MAX_CONFIG_BYTES`` or not TOML."""
    with reading(path, what):
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise InputError(f"is over {MAX_CONFIG_BYTES:,} bytes; not a configuration", path=path)
        text = path.read_bytes().decode("utf-8", errors="replace")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"is not valid TOML: {exc}", path=path) from None


def _check_tables(path: Path, document: dict, commands: set[tuple[str, ...]]) -> None:
    """Refuse top-level tables that are neither a command, a command group nor ``[run]``."""
    groups = {c[:1] for c in commands}
    for name, table in document.items():
        if name == RUN_TABLE or (name,) in commands:
            continue
        if (name,) not in groups:
            known = sorted({" ".join(c).replace(" ", ".") for c in commands})
            raise InputError(
                f"table [{name}] names no segloc command; tables are {', '.join(known)}",
                path=path,
            )
        for sub in table:
            if (name, sub) not in commands:
                raise InputError(f"table [{name}.{sub}] names no segloc command", path=path)


def run_record(path: Path) -> dict:
    """The ``[run]`` table of the TOML file ``path``: {} for a configuration written by hand."""
    record = load_toml(path).get(RUN_TABLE, {})
    return record if isinstance(record, dict) else {}


def check_run_command(path: Path, record: Mapping[str, Any], command: Sequence[str]) -> None:
    """Refuse the run file ``path`` (its ``[run]`` table ``record``) as the configuration of
    ``command`` when another command wrote it: it holds no setting for this one, and running
    on defaults while meaning to repeat a run is the mistake it would hide."""
    made_by = record.get("command")
    this = "segloc " + " ".join(command)
    if isinstance(made_by, str) and made_by != this:
        raise InputError(
            f"is the run file of `{made_by}`, not of `{this}`; give it to `{made_by}`, or give "
            f"--config a file with a [{'.'.join(command)}] table",
            path=path,
        )


def recorded_inputs(record: Mapping[str, Any]) -> set[tuple[str, str]]:
    """The inputs a run file's ``[run]`` table ``record`` lists, as (role, sha256) pairs."""
    inputs = record.get("inputs")
    listed = inputs if isinstance(inputs, list) else []
    return {
        (str(entry.get("role")), str(entry.get("sha256")))
        for entry in listed
        if isinstance(entry, dict)
    }


def version_note(path: Path) -> str | None:
    """A warning when the run file ``path`` was written by another segloc version."""
    try:
        made_by = tomllib.loads(path.read_text(encoding="utf-8"))[RUN_TABLE]["segloc"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if made_by == __version__:
        return None
    return f"{path} was written by segloc {made_by}, this is {__version__}; results may differ"


def stopped_note(path: Path, record: Mapping[str, Any]) -> str | None:
    """A warning when the run file ``path`` (its ``[run]`` table ``record``) is that of a run
    stopped before its end: its outputs hold part of what the settings make."""
    stopped = record.get(STOPPED_KEY)
    if not isinstance(stopped, dict):
        return None
    try:
        words = Stopped(str(stopped["by"]), int(stopped["done"]), int(stopped["planned"]))
    except (KeyError, TypeError, ValueError):
        return None
    return f"{path} records a run {words}: its outputs hold those scans alone"


def portable(value: Any, folder: Path) -> Any:
    """``value`` as TOML writes it: paths relative to ``folder``, other values as they are."""
    if isinstance(value, Path):
        return os.path.relpath(value.absolute(), folder.absolute())
    return value


def write_run_file(
    path: Path,
    command: Sequence[str],
    options: Mapping[str, Any],
    inputs: Sequence[tuple[str, Path]],
    stopped: Stopped | None = None,
) -> list[str]:
    """Write the run file ``path``: ``options`` (key → value; None left out, paths made
    relative to the file's folder) as the table of ``command``, and the ``[run]`` table
    with the version, each input (role, path, sha256) and, for a run ``stopped`` before its
    end, how it stopped (its ``STOPPED_KEY``, also said in the file's header). Returns the
    inputs' sha256s."""
    folder = path.parent
    table = {k: portable(v, folder) for k, v in options.items() if v is not None}
    document: dict[str, Any] = {}
    holder = document
    for name in command[:-1]:
        holder = holder.setdefault(name, {})
    holder[command[-1]] = table
    hashes = [sha256(p) for _, p in inputs]
    document[RUN_TABLE] = {
        "segloc": __version__,
        "command": "segloc " + " ".join(command),
        "inputs": [
            {"role": role, "path": portable(p, folder), "sha256": digest}
            for (role, p), digest in zip(inputs, hashes, strict=True)
        ],
    }
    name = " ".join(command)
    header = f"# segloc run file: the settings and inputs of a `segloc {name}` run.\n"
    if stopped is not None:
        document[RUN_TABLE][STOPPED_KEY] = stopped._asdict()
        header += f"# This run was {stopped}: its outputs hold those scans alone.\n"
    header += f"# Run it again with: segloc {name} ... --config {path.name}\n\n"
    write_text_atomic(path, header + tomli_w.dumps(document))
    return hashes
