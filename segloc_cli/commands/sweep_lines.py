"""What ``segloc sweep`` prints when its tasks are done: the summary per combination, the
convergence curves it was asked for, and how the sweep ended (its exit status)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from segloc_cli.commands.printing import info, warn
from segloc_cli.errors import EXIT_INTERRUPTED, EXIT_TASKS_FAILED
from segloc_cli.wording import counted


def report(plan, table, out_path: Path, fmt: str, stops: list[str], convergence) -> None:
    """Print the summary, write the convergence curves of a sweep that ended without failed
    tasks, then say how it ended; exit 130 if stopped, 1 if tasks failed."""
    from segloc_cli.estimates import STATUS_TASK_FAILED
    from segloc_cli.runs.sweep import format_summary, summary, write_convergence

    if len(table):
        stats = summary(table, plan.grid_keys, *plan.gates.values())
        click.echo(format_summary(stats, fmt), nl=False)
    held = table["task"].nunique() if len(table) else 0
    if stops and held < len(plan.tasks):  # a stop that came after the last task changes nothing
        info(
            f"interrupted ({stops[0]}) with {held} of {counted(len(plan.tasks), 'task')} in "
            f"{out_path}; run the same command again to finish"
        )
        sys.exit(EXIT_INTERRUPTED)
    info(f"{out_path}: {counted(len(table), 'row')} from {counted(held, 'task')}")
    failures = table[table["status"] == STATUS_TASK_FAILED] if len(table) else table
    if convergence is not None and not len(failures):
        written, notes = write_convergence(table, plan.tasks, plan.grid_keys, convergence)
        for line in [*notes, f"written to {', '.join(map(str, written))}"]:
            info(f"convergence curves: {line}")
    if len(failures):
        first = failures.iloc[0]
        warn(
            f"{counted(len(failures), 'task')} failed, kept as rows with status "
            f"{STATUS_TASK_FAILED!r}; "
            f"the first ({first['log']}, combination {first['combination']}, seed "
            f"{first['seed']}): {first['error']}"
        )
        if convergence is not None:
            warn("no convergence curves of a sweep with failed tasks; run it again to finish")
        sys.exit(EXIT_TASKS_FAILED)
