"""The ``segloc`` command line: the command group, and one contract for every error.

The commands live in ``segloc_cli.commands``, one module per family; each
parses its options, calls ``segloc_cli.runs.pipeline`` and prints.
"""

from __future__ import annotations

import sys
import time
import warnings

import click

from segloc_cli import __version__
from segloc_cli.commands.emulate import emulate
from segloc_cli.commands.evaluate import evaluate
from segloc_cli.commands.imports import import_group
from segloc_cli.commands.info import info_command
from segloc_cli.commands.localize import localize
from segloc_cli.commands.logs import simulate
from segloc_cli.commands.maps import map_group
from segloc_cli.commands.record import record_command
from segloc_cli.commands.sweep import sweep
from segloc_cli.errors import (
    EXIT_BAD_INPUT,
    EXIT_INTERNAL_ERROR,
    EXIT_INTERRUPTED,
    Interrupted,
    SeglocError,
)
from segloc_cli.wording import did_you_mean, said

"""An unexpected error (a bug): one line, and the traceback in a file it names (sysexits'
EX_SOFTWARE)."""

__all__ = ["cli", "main"]


class _SeglocGroup(click.Group):
    """The command group, which hands Ctrl-C to ``main`` as ``Interrupted``: click would print
    an empty line first (to end the line a terminal echoed "^C" on), and under a progress
    bar that leaves a blank line before ``segloc: interrupted``; ``main`` starts that line at
    the start of the terminal's line instead."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt as exc:
            raise Interrupted() from exc


@click.group(
    cls=_SeglocGroup,
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
)
@click.version_option(__version__, prog_name="segloc")
def cli() -> None:
    """Localize a robot in a known map from 2D laser scans, and measure how well it works.

    segloc implements the two-stage method of Reina & Gonzalez (2000): the
    heading comes from a length-weighted Hough vote over segment orientations,
    then the position from a coarse-to-fine search that maximises how much the
    scan's segments overlap the map's.

    \b
    A typical run:
      segloc simulate world.json --poses poses.csv --out sim/
      segloc map build sim/log.mcap --survey sim/survey.csv --out map.json
      segloc localize sim/log.mcap --map map.json --out estimates.csv
      segloc evaluate estimates.csv --survey sim/survey.csv

    Units: metres and degrees in files and options, errors in cm and degrees
    in tables ("surveyed minus computed", as in the paper).
    """


for command in (
    simulate,
    import_group,
    map_group,
    localize,
    evaluate,
    sweep,
    emulate,
    record_command,
):
    cli.add_command(command)
cli.add_command(info_command, "info")


# --------------------------------------------------------------------------- entry point


def _one_line(text: object) -> str:
    """``text`` on one line: the contract of every message segloc prints for an error."""
    return " ".join(str(text).split())


def _interrupted(exc: BaseException) -> bool:
    """Whether ``exc`` came of an interrupt: compiled code that Ctrl-C (or SIGTERM) reaches
    returns with the KeyboardInterrupt set, and Python reports that as a SystemError."""
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return True
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return False


def _report_internal_error(exc: BaseException) -> str:
    """Keep the traceback of an unexpected error in a file; return that file's path."""
    import tempfile
    import traceback

    stamp = time.strftime("%Y%m%d-%H%M%S")
    with tempfile.NamedTemporaryFile(
        "w", prefix=f"segloc-error-{stamp}-", suffix=".txt", delete=False, encoding="utf-8"
    ) as stream:
        stream.write(f"segloc {__version__}\ncommand: {' '.join(sys.argv)}\n\n")
        traceback.print_exception(exc, file=stream)
    return stream.name


def main(argv: list[str] | None = None) -> None:
    """Console entry point: every error is one line on stderr and a non-zero exit, no traceback.

    Exit status: 0 success, 1 a gate failed, 2 bad input or usage, 70 an internal
    error (its traceback kept in a file the line names), 130 interrupted.
    """
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            cli.main(args=argv, prog_name="segloc", standalone_mode=False)
    except BrokenPipeError:
        # The reader of our output went away (e.g. `| head`): nothing left to say.
        sys.stderr.close()
        sys.exit(EXIT_BAD_INPUT)
    except (click.exceptions.Abort, KeyboardInterrupt, Exception) as exc:
        line, code = _error_line(exc)
        # On a terminal, over the "^C" it echoed where the cursor was (a progress bar ends
        # on its own line, see progress.Progress.close).
        start = "\r" if code == EXIT_INTERRUPTED and _is_terminal(sys.stderr) else ""
        click.echo(start + said(line), err=True)
        sys.exit(code)


def _is_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A Python warning raised inside a command (a library's, or numpy's), in one line of
    segloc's own: its kind and text, without the source line Python would show."""
    text = _one_line(str(message))
    click.echo(said(f"warning: {category.__name__}: {text}"), err=True)


def _error_line(exc: BaseException) -> tuple[str, int]:
    """The one line an error prints (after ``segloc:``), and the exit status it gives."""
    # Ctrl-C (and SIGTERM or SIGHUP, which the entry point makes alike): Interrupted from a
    # command, click's Abort while it reads the command line.
    if isinstance(exc, (click.exceptions.Abort, KeyboardInterrupt, Interrupted)):
        return "interrupted", EXIT_INTERRUPTED
    if isinstance(exc, click.exceptions.NoSuchOption):
        return f"error: {_no_such_option(exc)}", EXIT_BAD_INPUT
    if isinstance(exc, click.ClickException):
        no_args = getattr(click.exceptions, "NoArgsIsHelpError", None)  # click >= 8.2
        if no_args is not None and isinstance(exc, no_args):
            message = f"missing command; run '{exc.ctx.command_path} --help' to list them"
        else:
            message = exc.format_message()
        return f"error: {_one_line(message)}", EXIT_BAD_INPUT if exc.exit_code else 0
    if isinstance(exc, SeglocError):
        return f"error: {_one_line(exc)}", EXIT_BAD_INPUT
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if exc.filename else ""
        return f"error: {where}{_one_line(exc.strerror or exc)}", EXIT_BAD_INPUT
    if isinstance(exc, (RecursionError, OverflowError, MemoryError)):
        return (
            f"error: the input is too large or too deeply nested to read "
            f"({type(exc).__name__}); check the files given",
            EXIT_BAD_INPUT,
        )
    if _interrupted(exc):
        return "interrupted", EXIT_INTERRUPTED
    where = _report_internal_error(exc)
    return (
        f"internal error: {type(exc).__name__}: {_one_line(exc)} "
        f"(a bug in segloc; the traceback is in {where}, please report it)",
        EXIT_INTERNAL_ERROR,
    )


def _no_such_option(exc: click.exceptions.NoSuchOption) -> str:
    """ "no such option --ouput; did you mean --out?": the command's long option closest to a
    mistyped one (click names several alike, or none, where one is the closest), else where
    to find them all."""
    ctx = exc.ctx
    if ctx is None:
        return f"no such option {exc.option_name}"
    listed = f"run '{ctx.command_path} --help' to list them"
    known = [
        name
        for param in ctx.command.get_params(ctx)
        for name in (*param.opts, *param.secondary_opts)
        if name.startswith("--")
    ]
    hint = (
        did_you_mean(exc.option_name, known, listed, quoted=False)
        if exc.option_name.startswith("--")
        else listed
    )
    return f"no such option {exc.option_name}; {hint}"
