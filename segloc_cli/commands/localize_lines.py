"""What ``segloc localize`` says on standard error as it runs: how each log's scans are
localized, the time a global search will take, and how the run ended (a summary, or the
line of an interrupted run and its exit status)."""

from __future__ import annotations

import sys

from segloc_cli.commands.printing import info, warn
from segloc_cli.errors import EXIT_INTERRUPTED
from segloc_cli.wording import counted


def say_how(runs) -> None:
    """Warn of logs that overlap in time, and say how each log's local maps were made."""
    from segloc_cli.runs.pipeline import overlapping_logs

    for message in overlapping_logs(runs):
        warn(message)
    for log_run in runs:
        if log_run.local_maps:
            info(f"{log_run.path}: {log_run.local_maps}")


def expect(first_ms: float, n_scans: int) -> None:
    """Say how long a global run will take, from its first scan."""
    each = first_ms / 1e3
    total_min = each * n_scans / 60.0
    info(
        f"global search: about {each:.1f} s per scan, {counted(n_scans, 'scan')} "
        f"(about {total_min:.1f} min)"
    )


def report(summary, written) -> None:
    """Print how the run went (a ``rowstream.RunSummary``) and where its rows went
    (``written``); exit 130 if it was interrupted."""
    out_path, done = written.out, summary.done
    if summary.stopped_by is not None:
        kept = f"their estimates are in {out_path}" if done else f"{out_path} holds the header only"
        info(
            f"interrupted ({summary.stopped_by}) after {done} of "
            f"{counted(summary.planned, 'scan')}; {kept}"
        )
        sys.exit(EXIT_INTERRUPTED)
    counts = ", ".join(f"{n} {status}" for status, n in summary.counts)
    skipped = summary.skipped
    info(
        f"{out_path}: {counted(done, 'scan')} localized ({counts}) in "
        f"{summary.elapsed_s:.2f} s, median {summary.median_ms:.1f} ms per scan"
        + (
            f"; {counted(skipped, 'scan')} skipped (no initial guess or odometry)"
            if skipped
            else ""
        )
    )
    if written.hypotheses is not None:
        path, limit = written.hypotheses
        info(f"{path}: up to {limit} distinct poses per scan, best first")
