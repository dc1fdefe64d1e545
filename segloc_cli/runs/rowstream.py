"""A localize run's rows written as they are made, and how the run went.

``write_rows`` reads the rows of each log's run (``pipeline.LogRun``) in turn and writes
each at once to the estimates CSV, and to the TUM trajectory, the hypotheses table and the
run view where asked (``RowOutputs``), so that a run stopped or killed keeps every finished
row. Ctrl-C, SIGTERM and SIGHUP ask it to stop between scans (``stopping.py``); the
``RunSummary`` it returns says how many scans were planned and done, their statuses and
times, and what stopped it. It prints nothing: progress goes to the ``ProgressFactory`` it
is given, and the command says the rest.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from segloc_cli.config import ExtractParams
from segloc_cli.estimates import STATUS_LOST, STATUS_RECOVERED, EstimateRow
from segloc_cli.io.log import Log
from segloc_cli.progress import Progress, ProgressFactory, silent
from segloc_cli.runs.pipeline import LogRun

if TYPE_CHECKING:
    from segloc_cli.runs.runfile import Stopped

PROGRESS_LABELS = {"guided": "localizing", "global": "global search", "track": "tracking"}
"""What the progress display says a run of each mode (``pipeline.RUN_MODES``) is doing."""
PROGRESS_TALLIES = {"track": (STATUS_LOST, STATUS_RECOVERED)}
"""The statuses whose scans the progress display of a mode counts as it goes: a track's lost
scans, and those it found again."""


class RowWriter(Protocol):
    """A file a run's rows stream into (``io/tables``: estimates, TUM, hypotheses)."""

    def write_row(self, row: Mapping[str, Any]) -> None: ...


@dataclass(frozen=True)
class RowOutputs:
    """Where a run's rows go: the estimates CSV ``out``; the TUM trajectory ``tum``; the
    hypotheses table ``hypotheses`` (its path, and K, the most poses per scan); the run view
    ``view``; each None when not asked for."""

    out: Path
    tum: Path | None = None
    hypotheses: tuple[Path, int] | None = None
    view: Path | None = None

    @classmethod
    def beside(
        cls, out: Path, tum: Path | None, hypotheses: int | None, view: Path | None
    ) -> RowOutputs:
        """The outputs of ``--out``, ``--tum``, ``--mcap`` and, with ``--hypotheses K``, the
        table of K poses per scan beside OUT (est.csv → est.hypotheses.csv)."""
        from segloc_cli.runs.runfile import beside

        listed = None if hypotheses is None else (beside(out, ".hypotheses.csv"), hypotheses)
        return cls(out, tum, listed, view)

    def by_option(self) -> dict[str, Path | None]:
        """Every file the run writes, by the option that names it (as ``io/files.check_outputs``
        takes them), the run file beside OUT among them."""
        from segloc_cli.runs.runfile import RUN_FILE_OUTPUT, run_file_path

        hypotheses = None if self.hypotheses is None else self.hypotheses[0]
        return {
            "--out": self.out,
            "--tum": self.tum,
            "--mcap": self.view,
            "--hypotheses": hypotheses,
            RUN_FILE_OUTPUT: run_file_path(self.out),
        }


@dataclass(frozen=True)
class RunView:
    """What the run view (``RowOutputs.view``) shows besides the rows: the map (M, 4; metres,
    world frame), the run in words (``segloc.run`` metadata), the logs the rows come from (in
    the order of the runs) and the extraction that gives each scan's local segments."""

    segments_world: np.ndarray
    metadata: dict[str, str]
    logs: Sequence[Log]
    extract: ExtractParams


@dataclass(frozen=True)
class RunSummary:
    """How a run went: the scans ``planned``, the ``statuses`` and ``runtimes_ms`` of the rows
    written (in order), the seconds it took, the signal that stopped it (None: it ran to the
    end; "Ctrl-C" for one that came outside the signal handler) and the scans of the logs it
    skipped (no initial guess, or no odometry when tracking)."""

    planned: int
    statuses: tuple[str, ...]
    runtimes_ms: tuple[float, ...]
    elapsed_s: float
    stopped_by: str | None
    skipped: int

    @property
    def done(self) -> int:
        """Scans localized and written."""
        return len(self.statuses)

    @property
    def stopped(self) -> Stopped | None:
        """How the run stopped before its end (None: it ran to the end), for its run file."""
        from segloc_cli.runs.runfile import Stopped

        by = self.stopped_by
        return None if by is None else Stopped(by, self.done, self.planned)

    @property
    def counts(self) -> list[tuple[str, int]]:
        """(status, scans) of the rows written, most frequent first."""
        return Counter(self.statuses).most_common()

    @property
    def median_ms(self) -> float:
        """The median time per scan (ms)."""
        return float(np.median(self.runtimes_ms))


def write_rows(
    runs: Sequence[LogRun],
    outputs: RowOutputs,
    stops: list[str],
    mode: str,
    progress: ProgressFactory = silent,
    expect: Callable[[float, int], None] | None = None,
    view: RunView | None = None,
) -> RunSummary:
    """Write the rows of ``runs`` (of one ``mode``) to ``outputs`` as they come (to the run
    view with ``view``, what it shows), showing ``progress``. A global search, whose scans
    take long, calls ``expect(runtime_ms, planned)`` once its first row is written whose time
    includes no compiling of kernels (``jit.compiles_heard``): the time to expect per scan.
    The stop signals are noted in ``stops`` (which the runs' ``stop`` reads) and end the run
    between scans, every finished row kept; the run view then says so."""
    from segloc_cli.io.runview import RunViewWriter

    planned = sum(run.times_s.size for run in runs)
    with ExitStack() as stack:
        rows: Iterator[EstimateRow] = (row for run in runs for row in run.rows)
        writer = None
        if outputs.view is not None and view is not None:
            writer = stack.enter_context(
                RunViewWriter(outputs.view, view.segments_world, view.metadata)
            )
            rows = _shown(writer, runs, view)
        t0 = time.perf_counter()
        tallied = PROGRESS_TALLIES.get(mode, ())

        def shown() -> Progress:
            return progress(PROGRESS_LABELS[mode], planned, "scan").tally(tallied)

        timed = expect if mode == "global" else None
        statuses, runtimes_ms = _written(rows, outputs, stops, shown, timed, planned)
        elapsed_s = time.perf_counter() - t0
        if writer is not None and stops:
            writer.note_stopped(stops[0], len(statuses), planned)
    skipped = sum(run.skipped for run in runs)
    stopped_by = stops[0] if stops else None
    return RunSummary(planned, statuses, runtimes_ms, elapsed_s, stopped_by, skipped)


def _written(
    rows: Iterator[EstimateRow],
    outputs: RowOutputs,
    stops: list[str],
    progress: Callable[[], Progress],
    timed: Callable[[float, int], None] | None,
    planned: int,
) -> tuple[tuple[str, ...], tuple[float, ...]]:
    """Write ``rows`` until they end or a stop is noted in ``stops``, showing the
    ``progress()`` made once the files are open, and calling ``timed(runtime_ms, planned)``
    at the first row whose time includes no compiling; (statuses, runtimes in ms) of those
    written."""
    from segloc_cli.stopping import interrupt_taken, stop_requests

    statuses: list[str] = []
    runtimes_ms: list[float] = []
    compiles = _compiles_heard() if timed is not None else 0
    with ExitStack() as stack:
        stack.enter_context(stop_requests(stops))
        writers = _writers(stack, outputs)
        shown = stack.enter_context(progress())
        try:
            for row in rows:
                shown.advance(outcome=row["status"])
                for writer in writers:
                    writer.write_row(row)
                statuses.append(row["status"])
                runtimes_ms.append(row["runtime_ms"])
                if timed is not None:
                    compiles, before = _compiles_heard(), compiles
                    if compiles == before:  # a time with no compiling in it
                        timed(row["runtime_ms"], planned)
                        timed = None
                if stops:
                    break
        except KeyboardInterrupt:  # Ctrl-C that arrived outside the stop handler
            interrupt_taken()
            stops.append("Ctrl-C")
    return tuple(statuses), tuple(runtimes_ms)


def _compiles_heard() -> int:
    from segloc_cli.jit import compiles_heard

    return compiles_heard()


def _writers(stack: ExitStack, outputs: RowOutputs) -> list[RowWriter]:
    """The writers of the estimates, TUM and hypotheses files asked for, open in ``stack``."""
    from segloc_cli.io.tables import EstimatesWriter, HypothesesWriter, TumWriter

    writers: list[RowWriter] = [stack.enter_context(EstimatesWriter(outputs.out))]
    if outputs.tum is not None:
        writers.append(stack.enter_context(TumWriter(outputs.tum)))
    if outputs.hypotheses is not None:
        writers.append(stack.enter_context(HypothesesWriter(*outputs.hypotheses)))
    return writers


def _shown(view, runs: Sequence, shown: RunView) -> Iterator[EstimateRow]:
    """The rows of ``runs``, each also added to the run ``view`` with its scan and the scan's
    local segments."""
    from segloc_cli.method.extract import extract_segments

    for run, log in zip(runs, shown.logs, strict=True):
        scans = {scan.time_s: scan for scan in log.scans}
        for row in run.rows:
            scan = scans[row["time_s"]]
            view.add_row(scan, extract_segments(scan, shown.extract), row, run.path)
            yield row
