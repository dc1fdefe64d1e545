"""What the commands print on standard error besides their errors: progress and summary
lines, warnings, and the work that says something as it goes (a log read, with its reader's
warnings; ``--jobs`` capped at the cores there are). Each line starts with ``segloc:``
(``wording.said``)."""

from __future__ import annotations

from pathlib import Path

import click

from segloc_cli.wording import counted, said


def warn(message: str) -> None:
    """Print a warning line on standard error."""
    info(f"warning: {message}")


def info(message: str) -> None:
    """Print a progress or summary line on standard error."""
    click.echo(said(message), err=True)


def within_cores(jobs: int, running: str, noun: str, nouns: str | None = None) -> int:
    """``--jobs`` no more than the cores segloc may use here (more processes would only share
    them), with a warning when it asked for more that ends in ``running`` and the cores
    counted as ``noun`` ("localizing on" 2 "process")."""
    from segloc_cli.runs.parallel import usable_cores

    cores = usable_cores()
    if jobs <= cores:
        return jobs
    warn(
        f"--jobs {jobs} is more than the {counted(cores, 'core')} segloc may use here; "
        f"{running} {counted(cores, noun, nouns)}"
    )
    return cores


def load_log(path: Path):
    """Read a segloc MCAP log, printing its reader's warnings."""
    from segloc_cli.io.mcap_log import read_log

    log = read_log(path)
    for warning in log.warnings:
        warn(warning)
    return log
