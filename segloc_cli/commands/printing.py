"""What the commands print on standard error besides their errors: progress and summary
lines, warnings, and the work that says something as it goes (a log read, with its reader's
warnings; ``--jobs`` capped at the cores there are). Each line starts with ``segloc:``
(``wording.said``)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from segloc_cli.wording import counted, said

if TYPE_CHECKING:
    import numpy as np

    from segloc_cli.estimates import PoseTable


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


def write_pose_file(
    survey_out: Path, table: PoseTable, original_times_s: np.ndarray, what: str
) -> None:
    """Write ``table`` to ``survey_out``: a TUM trajectory for a name ending in .tum, else a
    survey CSV with the poses' original times (s) in an ``original_time_s`` column; then
    say how many poses (``what``: "reference pose") it holds."""
    from segloc_cli.io.tables import write_pose_table, write_pose_table_tum

    if survey_out.suffix.lower() == ".tum":
        write_pose_table_tum(survey_out, table)  # TUM has no column for original times
    else:
        write_pose_table(survey_out, table, {"original_time_s": original_times_s})
    info(f"{survey_out}: {counted(len(table), what)}")
