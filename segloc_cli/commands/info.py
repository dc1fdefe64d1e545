"""``segloc info``: what a file holds. A log is summarised by ``logs.log_info``; a run
view (``localize --mcap``, ``map build --mcap``) is described here from its summary and
metadata; ``--foxglove-layout`` prints where the installed layout for run views is."""

from __future__ import annotations

from pathlib import Path

import click

from segloc_cli.commands.options import SCAN_SELECTION, FilePath, scan_selection, with_options
from segloc_cli.wording import counted


def _print_layout_path(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    """Print the installed Foxglove layout's path and end the command (an eager flag)."""
    if not value or ctx.resilient_parsing:
        return
    from segloc_cli.io.runview import layout_path

    click.echo(layout_path())
    ctx.exit()


@click.command("info")
@click.argument("log_path", metavar="LOG.mcap", type=FilePath())
@click.option(
    "--foxglove-layout",
    is_flag=True,
    is_eager=True,
    expose_value=False,
    callback=_print_layout_path,
    help="Print the path of the Foxglove layout that shows a run view (import it in Foxglove: "
    "Layouts → Import from file), and exit.",
)
@with_options(*SCAN_SELECTION)
def info_command(log_path: Path, **selection_options) -> None:
    """Summarise a log or a run view.

    A log: channels and message counts, time span and length (--start and
    --end count seconds from its first scan; given here, the scans they
    select; beyond a minute, in minutes or hours too, with the dates, UTC, of
    Unix times), sensor settings, whether the file was finished (a recording cut
    short still shows every complete scan). A run view (localize --mcap, map
    build --mcap): the run it shows, its map, scans and their statuses,
    message counts, and the layout to open it with.
    """
    from segloc_cli.commands.logs import log_info
    from segloc_cli.io.runview import read_run_view

    selection = scan_selection(selection_options)
    view = read_run_view(log_path)
    if view is None:
        log_info(log_path, selection)
        return
    if not selection.whole:
        raise click.UsageError(
            f"{log_path} is a run view, not a log: {selection.options_text()} selects a log's scans"
        )
    for line in run_view_lines(log_path, view):
        click.echo(line)


def run_view_lines(path: Path, view) -> list[str]:
    """The lines ``segloc info`` prints for a run view (a ``RunViewContents``); what the
    writer drew (map segments, statuses) only where the file records it."""
    from segloc_cli.io.runview import layout_path
    from segloc_cli.timing import readable_span, time_range

    counts = view.message_counts
    scans, placed = counts.get("/scan", 0), counts.get("/tf", 0)
    span_s = view.span_s if scans else []
    readable = readable_span(span_s)
    lines = [
        f"file:      {path}",
        f"kind:      run view of segloc {view.run.get('command', '?')}, to open in Foxglove "
        "(not a log)",
        f"/scan:     {counted(scans, 'scan')}, {time_range(span_s)}"
        + ("" if readable is None else f" ({readable})"),
        f"/tf:       {counted(placed, 'scan')} placed in world, {scans - placed} without a pose",
    ]
    if not view.finished:
        lines.insert(2, "finished:  no (its run was killed; it shows the scans written before)")
    elif view.stopped is not None:
        lines.insert(2, f"finished:  no (its run was {view.stopped}; it shows those scans)")
    if "map_segments" in view.drawn:
        lines.append(f"/map:      {counted(int(view.drawn['map_segments']), 'segment')}")
    statuses = [
        f"{n} {key.removeprefix('status.')}"
        for key, n in view.drawn.items()
        if key.startswith("status.")
    ]
    if statuses:
        lines.append(f"statuses:  {', '.join(statuses)}")
    lines.append("messages:  " + ", ".join(f"{t} {n}" for t, n in sorted(counts.items())))
    lines += [f"run.{key}: {value}" for key, value in sorted(view.run.items())]
    lines.append(f"layout:    {layout_path()} (in Foxglove: Layouts → Import from file)")
    return lines
