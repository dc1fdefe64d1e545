"""``rowstream.write_rows``: a run's rows written as they come, and the summary of the run."""

from __future__ import annotations

import csv

from conftest import HALL

from segloc_cli.config import Config
from segloc_cli.io.maps import read_map
from segloc_cli.io.mcap_log import read_log
from segloc_cli.io.runview import read_run_view
from segloc_cli.runs import pipeline
from segloc_cli.runs.rowstream import RowOutputs, RunView, write_rows


def _runs(stops: list[str] | None = None, mode: str = "guided"):
    log = read_log(HALL / "log.mcap")
    segments = read_map(HALL / "map.json")
    localizer = pipeline.localizer_for(segments, Config(), mode)
    stop = (lambda: bool(stops)) if stops is not None else (lambda: False)
    run = pipeline.localize_log(log, HALL / "log.mcap", localizer, mode, None, Config(), stop)
    return [run], log, segments


def test_every_row_goes_to_every_output_and_the_summary_counts_them(tmp_path):
    runs, log, segments = _runs()
    outputs = RowOutputs.beside(tmp_path / "e.csv", tmp_path / "e.tum", 2, tmp_path / "e.mcap")
    assert outputs.hypotheses == (tmp_path / "e.hypotheses.csv", 2)
    assert list(outputs.by_option()) == [
        "--out", "--tum", "--mcap", "--hypotheses", "--out (run file)"
    ]  # fmt: skip
    expected = []
    view = RunView(segments, {"command": "test"}, [log], Config().extract)
    summary = write_rows(
        runs, outputs, [], "guided", expect=lambda *a: expected.append(a), view=view
    )
    rows = list(csv.DictReader((tmp_path / "e.csv").open(encoding="utf-8")))
    assert summary.planned == summary.done == len(rows) == 10
    assert summary.stopped_by is None and summary.skipped == 0
    assert summary.statuses == tuple(row["status"] for row in rows)
    assert summary.counts == [("ok", 10)] and summary.median_ms > 0
    assert len((tmp_path / "e.tum").read_text().splitlines()) == 1 + 10  # a comment line
    assert (tmp_path / "e.hypotheses.csv").is_file()
    shown = read_run_view(tmp_path / "e.mcap")
    assert shown.drawn["status.ok"] == "10" and shown.stopped is None
    assert summary.stopped is None
    assert expected == []  # only a global search says what to expect


def test_a_stop_ends_the_run_after_the_row_being_written(tmp_path):
    stops = ["SIGTERM"]
    runs, log, segments = _runs(stops)
    view = RunView(segments, {"command": "test"}, [log], Config().extract)
    outputs = RowOutputs(tmp_path / "e.csv", view=tmp_path / "e.mcap")
    summary = write_rows(runs, outputs, stops, "guided", view=view)
    assert summary.stopped_by == "SIGTERM"
    assert summary.planned == 10 and 1 <= summary.done < 10
    assert summary.stopped == ("SIGTERM", summary.done, 10)
    assert len((tmp_path / "e.csv").read_text().splitlines()) == summary.done + 1
    # The view is finished, and says its run stopped, after how many scans.
    shown = read_run_view(tmp_path / "e.mcap")
    assert shown.finished
    assert shown.stopped == f"stopped (SIGTERM) after {summary.done} of 10 scans"
    assert sum(int(n) for k, n in shown.drawn.items() if k.startswith("status.")) == summary.done
