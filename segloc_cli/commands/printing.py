"""What the commands print on standard error besides their errors: progress and summary
lines, warnings, and the work that says something as it goes (a log read, with its reader's
warnings; ``--jobs`` capped at the cores there are)."""

from __future__ import annotations

from pathlib import Path

import click


def warn(message: str) -> None:
    """Print a warning line on standard error."""
    click.echo(f"segloc: warning: {message}", err=True)


def info(message: str) -> None:
    """Print a progress or summary line on standard error."""
    click.echo(message, err=True)


def within_cores(jobs: int, running: str) -> int:
    """``--jobs`` no more than the cores segloc may use here (more processes would only share
    them), with a warning that ends in ``running`` (its ``{cores}`` filled in) when it asked
    for more."""
    from segloc_cli.runs.parallel import usable_cores

    cores = usable_cores()
    if jobs <= cores:
        return jobs
    running = running.format(cores=cores)
    warn(f"--jobs {jobs} is more than the {cores} core(s) segloc may use here; {running}")
    return cores


def load_log(path: Path):
    """Read a segloc MCAP log, printing its reader's warnings."""
    from segloc_cli.io.mcap_log import read_log

    log = read_log(path)
    for warning in log.warnings:
        warn(warning)
    return log
