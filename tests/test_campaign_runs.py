"""A bad-input and fault campaign over runs: the run view (``localize --mcap``), sweep specs
and clusters, ROS transforms and CARMEN times that contradict themselves, and ``--jobs``
beyond what the machine gives.

Each case ends in one of three ways a careful tool allows: one ``segloc: error:`` line
naming the file and what to do, exit status 2; a correct success (said in a warning where
segloc chose for the user); or, when interrupted, exit 130 with everything finished kept.
A case fails on a traceback, any other exit status, a hang, a wrong success, lost output or
a silent overwrite. Runs are in-process on a few scans; the few cases that need a process of
their own (signals, a full disk in a private mount, a limit on processes) take seconds.
"""

from __future__ import annotations

import errno
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import HALL, HALL_WORLD, SEGLOC
from test_cli import Result, assert_one_line_error, run_cli, setup_cli
from test_foxglove import messages_before_the_cut, validated_messages
from test_io_rosbag import mounted_bag, quaternion
from test_outputs import write_long_log

from segloc_cli.geometry import Pose2
from segloc_cli.io.mcap_log import read_log

HALL_LOG, HALL_MAP, HALL_SURVEY = HALL / "log.mcap", HALL / "map.json", HALL / "survey.csv"


# --------------------------------------------------------------------------- helpers


def assert_error_last(result: Result, *fragments: str) -> str:
    """Exit status 2, no traceback nor panic, and one ``segloc: error:`` line, the last one
    (lines a run printed before it met the fault, such as warnings, may precede it)."""
    assert "Traceback" not in result.err and "panicked" not in result.err, result.err
    errors = [line for line in result.err.splitlines() if line.startswith("segloc: error:")]
    assert len(errors) == 1, f"expected one error line:\n{result.err}"
    assert result.err.splitlines()[-1] == errors[0], f"the error is not last:\n{result.err}"
    assert result.code == 2, f"exit status {result.code}:\n{result.err}"
    for fragment in fragments:
        assert fragment in errors[0], f"{fragment!r} is not named in {errors[0]!r}"
    return errors[0]


def run_script(*args, cwd: Path | None = None, prefix: tuple = (), timeout: float = 60) -> Result:
    """``segloc ARGS`` in a process of its own (behind ``prefix``, e.g. unshare), its
    numerical libraries on one thread each, so that it starts as many on every machine."""
    one_thread = {name: "1" for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    proc = subprocess.run(
        [*map(str, prefix), str(SEGLOC), *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, "PYTHONIOENCODING": "utf-8", **one_thread},
        check=False,
    )
    return Result(proc.returncode, proc.stdout, proc.stderr)


def estimate_rows(path: Path) -> pd.DataFrame:
    """The whole rows of an estimates CSV (a killed run's last line may be cut)."""
    text = path.read_text(encoding="utf-8")
    assert text.endswith("\n"), "the last row is cut"
    frame = pd.read_csv(path)
    assert frame["status"].notna().all()
    return frame


def without_times(frame: pd.DataFrame) -> pd.DataFrame:
    return frame.drop(columns="runtime_ms").reset_index(drop=True)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    """A folder holding a three-scan simulated log of the hall (``sim/log.mcap``), its
    survey (``sim/survey.csv``) and the hall's world as the map (``map.json``)."""
    root = tmp_path_factory.mktemp("tiny")
    poses = root / "poses.csv"
    poses.write_text("\n".join((HALL / "poses.csv").read_text().splitlines()[:4]) + "\n")
    setup_cli("simulate", HALL_WORLD, "--poses", poses, "--out", root / "sim", "--seed", 7)
    shutil.copy(HALL_WORLD, root / "map.json")
    return root


def snapshot(*paths: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in paths}


# =========================================================================== 1. the run view


def localize_view(capsys, tiny: Path, view: object, *extra: object, out: str = "est") -> Result:
    """``localize`` of the tiny log with ``--mcap VIEW``, its estimates in runs/OUT.csv."""
    (tiny / "runs").mkdir(exist_ok=True)
    return run_cli(
        capsys, "localize", tiny / "sim" / "log.mcap", "--map", tiny / "map.json",
        "--out", tiny / "runs" / f"{out}.csv", "--mcap", view, "--force", *extra,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("where", "why"),
    [("missing/run.mcap", "does not exist"), ("missing/deeper/run.mcap", "does not exist"),
     ("sim/log.mcap/run.mcap", "is a file, not a folder")],
    ids=["missing", "missing-twice", "a-file"],
)  # fmt: skip
def test_a_view_whose_folder_is_missing_is_refused_before_any_work(capsys, tiny, where, why):
    out = "folder-" + where.replace("/", "-")
    result = localize_view(capsys, tiny, tiny / where, out=out)
    assert_one_line_error(result, str(tiny / where), "--mcap", why)
    assert not (tiny / "runs" / f"{out}.csv").exists()


INPUT_SPELLINGS = {
    "the-log": lambda t: t / "sim" / "log.mcap",
    "the-map": lambda t: t / "map.json",
    "dot-slash-log": lambda t: Path(f"{t}/./sim/log.mcap"),
    "dot-dot-map": lambda t: Path(f"{t}/sim/../map.json"),
    "symlink-to-log": lambda t: _link(t / "log-link.mcap", t / "sim" / "log.mcap"),
    "symlink-to-map": lambda t: _link(t / "map-link.mcap", t / "map.json"),
    "hard-link-to-log": lambda t: _link(t / "log-hard.mcap", t / "sim" / "log.mcap", hard=True),
    "relative-log": lambda t: Path(os.path.relpath(t / "sim" / "log.mcap")),
}


def _link(link: Path, target: Path, hard: bool = False) -> Path:
    if not link.exists():
        (link.hardlink_to if hard else link.symlink_to)(target)
    return link


@pytest.mark.parametrize("force", [False, True], ids=["kept", "forced"])
@pytest.mark.parametrize("spelling", INPUT_SPELLINGS)
def test_a_view_that_is_an_input_is_refused_even_with_force(capsys, tiny, spelling, force):
    inputs = snapshot(tiny / "sim" / "log.mcap", tiny / "map.json")
    view = INPUT_SPELLINGS[spelling](tiny)
    out = tiny / "runs" / "est.csv"
    out.parent.mkdir(exist_ok=True)
    args = ["localize", tiny / "sim" / "log.mcap", "--map", tiny / "map.json", "--out", out]
    result = run_cli(capsys, *args, "--mcap", view, *(["--force"] if force else []))
    assert_one_line_error(result, "is an input of this command", "--mcap")
    assert "--force" not in result.err  # no advice that would be refused next
    assert snapshot(*inputs) == inputs


@pytest.mark.parametrize(
    ("option", "name"),
    [("--out", "est.csv"), ("--tum", "est.tum"), ("--hypotheses", "est.hypotheses.csv"),
     ("run file", "est.run.toml")],
)  # fmt: skip
def test_a_view_that_is_another_output_is_refused(capsys, tiny, option, name):
    runs = tiny / "runs"
    runs.mkdir(exist_ok=True)
    extra = {"--tum": ["--tum", runs / "est.tum"], "--hypotheses": ["--hypotheses", "2"]}
    result = localize_view(capsys, tiny, runs / name, *extra.get(option, []))
    assert_one_line_error(result, "name the same file", "--mcap")


def test_an_existing_view_is_kept_without_force_and_replaced_with_it(capsys, tiny):
    view = tiny / "runs" / "kept.mcap"
    view.parent.mkdir(exist_ok=True)
    view.write_bytes(b"precious")
    out = tiny / "runs" / "fresh.csv"
    args = ["localize", tiny / "sim" / "log.mcap", "--map", tiny / "map.json", "--out", out]
    result = run_cli(capsys, *args, "--mcap", view)
    assert_one_line_error(result, str(view), "file exists", "--force")
    assert view.read_bytes() == b"precious" and not out.exists()
    done = run_cli(capsys, *args, "--mcap", view, "--force")
    assert done.code == 0, done.err
    assert len(validated_messages(view)["/scan"]) == 3


@pytest.mark.parametrize("kind", ["folder", "device", "fifo"])
def test_a_view_that_is_no_regular_file_is_refused(capsys, tiny, kind):
    where = {"folder": tiny / "sim", "device": Path("/dev/null"), "fifo": tiny / "pipe.mcap"}
    if kind == "fifo" and not where[kind].exists():
        os.mkfifo(where[kind])
    result = localize_view(capsys, tiny, where[kind])
    assert_one_line_error(result, str(where[kind]), "--mcap")


class _FullSink:
    """Stands in for the view's file: takes ``room`` bytes, then fails as a full disk."""

    def __init__(self, room: int):
        self.room = room

    def __call__(self, real_sink):
        outer = self

        def write(data: bytes) -> int:
            if len(data) > outer.room:
                error = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                real_sink.error = real_sink.error or error
                raise error
            outer.room -= len(data)
            return real_sink._file.write(data)

        real_sink.write = write
        return real_sink


@pytest.mark.parametrize(
    ("room", "rows"), [(0, None), (300, 0), (9_000, 3)], ids=["at-open", "first-scan", "at-close"]
)
def test_a_full_disk_under_the_view_is_one_line_and_keeps_every_row(
    capsys, tiny, monkeypatch, room, rows
):
    """The disk fills (ENOSPC) after ``room`` bytes of the view: opening it, writing its
    first scan's chunk (header and metadata are 259 bytes), or finishing it."""
    from segloc_cli.io import runview

    real = runview._Sink
    monkeypatch.setattr(runview, "_Sink", lambda path: _FullSink(room)(real(path)))
    view = tiny / "runs" / f"full-{room}.mcap"
    result = localize_view(capsys, tiny, view, out=f"full-{room}")
    assert_error_last(result, str(view), "cannot write file", "No space left on device")
    if rows is not None:  # the run had begun: every row it finished is in the estimates
        assert len(estimate_rows(tiny / "runs" / f"full-{room}.csv")) == rows


def _private_tmpfs_works() -> bool:
    probe = subprocess.run(
        ["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=4k tmpfs /mnt"],
        capture_output=True,
        check=False,
    )
    return probe.returncode == 0


needs_tmpfs = pytest.mark.skipif(
    shutil.which("unshare") is None or not _private_tmpfs_works(),
    reason="no private mount namespace (unshare -rm) in which to mount a small tmpfs",
)


@needs_tmpfs
@pytest.mark.parametrize("full", ["view", "estimates"])
def test_a_full_tmpfs_is_one_line_naming_the_file(tiny, tmp_path, full):
    small = tmp_path / "small"
    small.mkdir()
    view = small / "run.mcap" if full == "view" else tmp_path / "run.mcap"
    out = small / "est.csv" if full == "estimates" else tmp_path / "est.csv"
    args = ["localize", tiny / "sim" / "log.mcap", "--map", tiny / "map.json", "--out", out]
    # 12 KiB take the view's first chunk (the map and a scan), not the rest; 4 KiB one file.
    size = "12k" if full == "view" else "4k"
    mount = f'mount -t tmpfs -o size={size} tmpfs {small} && exec "$@"'
    prefix = ("unshare", "-rm", "sh", "-c", mount, "sh")
    result = run_script(*args, "--mcap", view, prefix=prefix)
    named = view if full == "view" else small / "est"
    assert_error_last(result, str(named), "No space left on device")
    if full == "view":
        assert len(estimate_rows(out)) == 3


@pytest.fixture(scope="module")
def long_log(tmp_path_factory) -> Path:
    return write_long_log(tmp_path_factory.mktemp("long") / "long.mcap", copies=40)


@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGINT, signal.SIGKILL],
                         ids=["SIGTERM", "SIGINT", "SIGKILL"])  # fmt: skip
def test_a_stopped_run_keeps_its_rows_and_a_readable_view(capsys, tmp_path, long_log, how):
    out, view = tmp_path / "est.csv", tmp_path / "run.mcap"
    args = ["localize", long_log, "--map", HALL_MAP, "--out", out, "--mcap", view]
    proc = subprocess.Popen(
        [str(SEGLOC), *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:
            if out.exists() and out.read_text().count("\n") > 12:
                break
            time.sleep(0.05)
        time.sleep(0.6)  # past a flush of the view
        proc.send_signal(how)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    rows = estimate_rows(out)
    assert 12 <= len(rows) < 400
    if how == signal.SIGKILL:
        assert proc.returncode == -signal.SIGKILL
        shown = messages_before_the_cut(view)  # no summary: read up to the cut
        assert 1 <= len(shown["/scan"]) == len(shown["/status"]) <= len(rows) + 1
        described = run_cli(capsys, "info", view)
        assert described.code == 0 and "finished:  no" in described.out
    else:
        assert proc.returncode == 130, err
        assert f"interrupted ({how.name}) after {len(rows)} of 400 scans" in err
        assert "Traceback" not in err
        shown = validated_messages(view)  # finished, with every row's scan
        assert len(shown["/scan"]) == len(shown["/status"]) == len(rows)
    assert not [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


# =========================================================================== 2. sweep specs

SPEC = """\
map = "map.json"
logs = ["sim/log.mcap"]
survey = "sim/survey.csv"
init-errors = "uniform:0.5,5"
seeds = [1, 2]
"""
"""Two tasks on the tiny log (three scans each)."""


@pytest.fixture
def spec_dir(tiny, tmp_path) -> Path:
    """A folder holding the tiny log, its survey and map, for specs written into it."""
    shutil.copytree(tiny / "sim", tmp_path / "sim")
    shutil.copy(tiny / "map.json", tmp_path / "map.json")
    return tmp_path


def write_spec(folder: Path, text: str = SPEC, name: str = "sweep.toml") -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def sweep(capsys, spec: Path, out: Path, *extra: object, on: str | None = None) -> Result:
    """``segloc sweep SPEC --out OUT EXTRA`` in this process, on one local worker or, where
    the tasks run, on the cluster at the scheduler ``on`` (``dask_scheduler``)."""
    where = ("--jobs", "1") if on is None else ("--scheduler", on)
    return run_cli(capsys, "sweep", spec, "--out", out, *where, *extra)


def test_an_empty_grid_is_one_combination(capsys, spec_dir, dask_scheduler):
    spec = write_spec(spec_dir, SPEC + "\n[grid]\n")
    out = spec_dir / "results.parquet"
    done = sweep(capsys, spec, out, on=dask_scheduler)
    assert done.code == 0, done.err
    table = pd.read_parquet(out)
    assert len(table) == 2 * 3 and set(table["combination"]) == {0}
    assert table["task"].nunique() == 2


@pytest.mark.parametrize(
    ("change", "fragment"),
    [(("seeds = [1, 2]", "seeds = [1, 2]\n[grid]\niterations = []"), "takes a list of values"),
     (("seeds = [1, 2]", "seeds = []"), "key 'seeds' takes a list"),
     (('logs = ["sim/log.mcap"]', "logs = []"), 'key "logs" must list the logs'),
     (("seeds = [1, 2]", "seeds = [1, 2]\ngrid = 5"), "[grid] must be a table")],
    ids=["grid-key-empty", "no-seeds", "no-logs", "grid-not-a-table"],
)  # fmt: skip
def test_a_spec_that_plans_nothing_is_refused(capsys, spec_dir, change, fragment):
    spec = write_spec(spec_dir, SPEC.replace(*change))
    result = sweep(capsys, spec, spec_dir / "results.parquet")
    assert_one_line_error(result, str(spec), fragment)
    assert not (spec_dir / "results.parquet").exists()


ENORMOUS = {
    "grid": "seeds = [1]\n[grid]\niterations = [4, 5, 6, 7, 8, 9, 10, 11, 12, 13]\n"
    + "grid-m = [" + ", ".join(f"{1 + k / 100:g}" for k in range(40)) + "]\n"
    + "ratio = [" + ", ".join(f"{0.5 + k / 100:g}" for k in range(30)) + "]\n",
    "seeds": "seeds = [" + ", ".join(map(str, range(10_001))) + "]\n",
    "both": "seeds = [" + ", ".join(map(str, range(2_000))) + "]\n[grid]\n"
    + "iterations = [6, 7, 8, 9, 10, 11]\n",
}  # fmt: skip


@pytest.mark.parametrize("kind", ENORMOUS)
def test_an_enormous_sweep_is_refused_with_its_limit_before_it_starts(capsys, spec_dir, kind):
    spec = write_spec(spec_dir, SPEC.replace("seeds = [1, 2]\n", ENORMOUS[kind]))
    started = time.monotonic()
    result = sweep(capsys, spec, spec_dir / "results.parquet")
    assert_one_line_error(result, str(spec), "more than the 10,000 a sweep takes", "tasks")
    assert time.monotonic() - started < 5
    assert not (spec_dir / "results.parquet.parts").exists()


def test_a_sweep_at_the_limit_is_planned(spec_dir):
    from segloc_cli.runs.sweepspec import MAX_TASKS, read_spec

    seeds = "seeds = [" + ", ".join(map(str, range(MAX_TASKS // 10))) + "]\n"
    grid = "[grid]\niterations = [" + ", ".join(map(str, range(3, 13))) + "]\n"
    spec = write_spec(spec_dir, SPEC.replace("seeds = [1, 2]\n", seeds + grid))
    assert len(read_spec(spec).tasks) == MAX_TASKS


MISSING = {
    "log": ('logs = ["sim/log.mcap"]', 'logs = ["sim/gone.mcap"]', "gone.mcap does not exist"),
    "map": ('map = "map.json"', 'map = "gone.json"', "gone.json does not exist"),
    "survey": ('survey = "sim/survey.csv"', 'survey = "gone.csv"', "gone.csv does not exist"),
    "guesses": ('init-errors = "uniform:0.5,5"', 'initial = "gone.csv"', "gone.csv do not exist"),
    "log-folder": ('logs = ["sim/log.mcap"]', 'logs = ["sim"]', "sim is a folder, not a file"),
    "table-log": ('logs = ["sim/log.mcap"]', 'logs = [{path = "gone.mcap"}]', "does not exist"),
    "table-map": ('logs = ["sim/log.mcap"]', 'logs = [{path = "sim/log.mcap", map = "no.json"}]',
                  "no.json does not exist"),
}  # fmt: skip


@pytest.mark.parametrize("what", MISSING)
def test_a_missing_input_is_named_before_any_task(capsys, spec_dir, what):
    before, after, fragment = MISSING[what]
    spec = write_spec(spec_dir, SPEC.replace(before, after))
    result = sweep(capsys, spec, spec_dir / "results.parquet")
    assert_one_line_error(result, str(spec), fragment)
    assert not (spec_dir / "results.parquet").exists()


OUT_AS_INPUT = {
    "log": lambda d: d / "sim" / "log.mcap",
    "map": lambda d: d / "map.json",
    "survey": lambda d: d / "sim" / "survey.csv",
    "spec": lambda d: d / "sweep.toml",
    "guesses": lambda d: d / "sim" / "survey.csv",
    "symlink-to-log": lambda d: _link(d / "out-link.parquet", d / "sim" / "log.mcap"),
    "hard-link-to-map": lambda d: _link(d / "out-hard.parquet", d / "map.json", hard=True),
}


@pytest.mark.parametrize("what", OUT_AS_INPUT)
def test_an_out_that_is_an_input_is_refused_even_with_force(capsys, spec_dir, what):
    text = SPEC.replace('init-errors = "uniform:0.5,5"', 'initial = "sim/survey.csv"')
    spec = write_spec(spec_dir, text if what == "guesses" else SPEC)
    inputs = snapshot(spec, spec_dir / "map.json", *(spec_dir / "sim").iterdir())
    result = sweep(capsys, spec, OUT_AS_INPUT[what](spec_dir), "--force")
    assert_one_line_error(result, "is an input of this command", "--out")
    assert snapshot(*inputs) == inputs


@pytest.mark.parametrize(
    "logs", ['["sim/log.mcap", "sim/log.mcap"]', '["sim/log.mcap", "./sim/log.mcap"]',
             '["sim/log.mcap", "copy.mcap"]'],
    ids=["twice", "two-spellings", "a-copy"],
)  # fmt: skip
def test_a_log_listed_twice_is_refused_not_counted_twice(capsys, spec_dir, logs):
    shutil.copy(spec_dir / "sim" / "log.mcap", spec_dir / "copy.mcap")
    text = SPEC.replace('init-errors = "uniform:0.5,5"\n', "")  # guesses from /odom
    spec = write_spec(spec_dir, text.replace('["sim/log.mcap"]', logs))
    result = sweep(capsys, spec, spec_dir / "results.parquet")
    assert_one_line_error(result, str(spec), "the same log", "counted twice", "list it once")


def test_a_copy_of_a_log_with_guesses_of_its_own_is_a_task_of_its_own(spec_dir):
    from segloc_cli.runs.sweepspec import read_spec

    shutil.copy(spec_dir / "sim" / "log.mcap", spec_dir / "copy.mcap")
    spec = write_spec(spec_dir, SPEC.replace('["sim/log.mcap"]', '["sim/log.mcap", "copy.mcap"]'))
    assert len({task.key for task in read_spec(spec).tasks}) == 4


class _Server:
    """A TCP server on localhost that is no Dask scheduler: it greets with HTTP, stays
    silent, or closes each connection at once; or a port nothing listens on (refused)."""

    def __init__(self, mode: str):
        self.mode = mode
        self.socket = socket.socket()
        self.socket.bind(("127.0.0.1", 0))
        self.port = self.socket.getsockname()[1]
        self.held: list[socket.socket] = []
        if mode != "refused":
            self.socket.listen(8)
            threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                peer, _ = self.socket.accept()
            except OSError:
                return
            if self.mode == "http":
                peer.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
            if self.mode in ("http", "close"):
                peer.close()
            else:
                self.held.append(peer)

    def close(self) -> None:
        self.socket.close()
        for peer in self.held:
            peer.close()


@pytest.mark.parametrize(
    ("mode", "fragment"),
    [("refused", "cannot reach the Dask scheduler"), ("silent", "within 1 s (no answer)"),
     ("close", "cannot reach the Dask scheduler"), ("http", "is not a Dask scheduler")],
)  # fmt: skip
def test_a_scheduler_that_does_not_answer_is_refused_in_bounded_time(
    capsys, spec_dir, monkeypatch, mode, fragment
):
    import segloc_cli.runs.sweep

    monkeypatch.setattr(segloc_cli.runs.sweep, "SCHEDULER_TIMEOUT_S", 1.0)
    server = _Server(mode)
    try:
        address = f"tcp://127.0.0.1:{server.port}"
        started = time.monotonic()
        result = run_cli(capsys, "sweep", write_spec(spec_dir), "--out",
                         spec_dir / "results.parquet", "--scheduler", address)  # fmt: skip
        elapsed = time.monotonic() - started
    finally:
        server.close()
    assert_one_line_error(result, address, fragment)
    assert elapsed < 10
    assert not (spec_dir / "results.parquet.parts").exists()


@pytest.mark.parametrize(
    ("address", "fragment"),
    [("", "is not HOST:PORT"), ("somewhere", "is not HOST:PORT"),
     ("tcp://127.0.0.1:99999", "a port from 1 to 65535"), ("foo://bar:1", "unknown scheme 'foo'")],
    ids=["empty", "no-port", "port-out-of-range", "unknown-scheme"],
)  # fmt: skip
def test_a_scheduler_address_that_names_none_is_refused_at_once(
    capsys, spec_dir, address, fragment
):
    spec = write_spec(spec_dir)
    result = run_cli(capsys, "sweep", spec, "--out", spec_dir / "r.parquet", "--scheduler", address)
    assert_one_line_error(result, "--scheduler", fragment, "tcp://10.0.0.5:8786")


def _finished_parts(spec: Path, out: Path, keep: slice) -> tuple[list[str], pd.DataFrame]:
    """Run the spec's tasks in-process, keep those of ``keep`` as a killed sweep leaves
    them (in OUT.parts), with the debris of the one that was being written; (the plan's keys,
    the rows kept)."""
    from segloc_cli.runs.sweep import ResultStore, run_task
    from segloc_cli.runs.sweepspec import read_spec

    tasks = read_spec(spec).tasks
    store = ResultStore(out)
    kept = []
    for task in tasks[keep]:
        rows = run_task(task)
        store.add(task.key, rows)
        kept.append(rows)
    (store.parts / f".{tasks[-1].key}.parquet.x1y2.tmp").write_bytes(b"PAR1 half a file")
    return [t.key for t in tasks], pd.concat(kept, ignore_index=True)


@pytest.mark.parametrize("kept", ["first", "last", "both-of-three"])
def test_a_killed_sweep_resumes_with_no_task_lost_or_run_twice(
    capsys, spec_dir, dask_scheduler, kept
):
    text = SPEC.replace("seeds = [1, 2]", "seeds = [1, 2, 3]")
    spec, out = write_spec(spec_dir, text), spec_dir / "results.parquet"
    keep = {"first": slice(0, 1), "last": slice(2, 3), "both-of-three": slice(0, 2)}[kept]
    keys, before = _finished_parts(spec, out, keep)
    if kept == "both-of-three":  # a part cut short counts as not done
        parts = out.with_name("results.parquet.parts")
        (parts / f"{keys[1]}.parquet").write_bytes(b"PAR1\x00cut")
    done = sweep(capsys, spec, out, on=dask_scheduler)
    assert done.code == 0, done.err
    n_before = before["task"].nunique() - (kept == "both-of-three")
    assert f"3 tasks, {n_before} done before; running {3 - n_before}" in done.err
    table = pd.read_parquet(out)
    assert list(dict.fromkeys(table["task"])) == keys  # every task once, in plan order
    assert len(table) == 3 * 3 and not out.with_name("results.parquet.parts").exists()
    for key in set(before["task"]) & set(keys[:1] if kept == "both-of-three" else keys):
        runtimes = table.loc[table["task"] == key, "runtime_ms"].to_numpy()
        assert (runtimes == before.loc[before["task"] == key, "runtime_ms"].to_numpy()).all()


@pytest.mark.parametrize("held", ["results", "parts", "superset"])
def test_results_of_another_spec_are_refused_not_mixed(capsys, spec_dir, held):
    from segloc_cli.runs.sweep import ResultStore, run_task
    from segloc_cli.runs.sweepspec import read_spec

    other = write_spec(spec_dir, SPEC.replace("seeds = [1, 2]", "seeds = [5, 6]"), "other.toml")
    out = spec_dir / "results.parquet"
    store = ResultStore(out)
    tasks = read_spec(other).tasks
    if held == "superset":  # this spec's tasks and one more: some are another spec's
        tasks = [*read_spec(write_spec(spec_dir)).tasks, tasks[0]]
    for task in tasks:
        store.add(task.key, run_task(task))
    if held != "parts":
        store.finish([t.key for t in tasks])
    kept = {p: p.read_bytes() for p in spec_dir.rglob("results.parquet*") if p.is_file()}
    result = sweep(capsys, write_spec(spec_dir), out)
    assert_one_line_error(result, "this spec does not plan", "--force")
    assert {p: p.read_bytes() for p in kept} == kept


def test_a_parts_path_that_is_a_file_is_refused_before_any_task(capsys, spec_dir):
    spec, out = write_spec(spec_dir), spec_dir / "results.parquet"
    out.with_name("results.parquet.parts").write_text("not a folder")
    result = sweep(capsys, spec, out)
    assert_one_line_error(result, "results.parquet.parts", "is not a folder")


# =========================================================================== 3. ROS and CARMEN

AT_02 = ("base_link", "laser", (0.2, 0.0, 0.3), quaternion())
AT_05 = ("base_link", "laser", (0.5, 0.1, 0.3), quaternion(yaw=0.3))


def import_bag(capsys, where: Path, static: list, moving: list = (), *options) -> Result:
    """``segloc import rosbag`` of a ROS 1 bag of the standard scans, whose transforms are
    ``static`` (on /tf_static) and ``moving`` (each a /tf message), into where/log.mcap."""
    bag = mounted_bag("ros1", where, static, moving)
    return run_cli(capsys, "import", "rosbag", bag, "--out", where / "log.mcap", *options)


def offset_warnings(result: Result) -> list[str]:
    return [line for line in result.err.splitlines() if "laser" in line and "warning" in line]


@pytest.mark.parametrize(
    ("static", "moving", "used", "said"),
    [([AT_02, AT_05], [], (0.5, 0.1), "the latest on /tf_static, as tf2 takes it"),
     ([AT_02], [[AT_05]], (0.2, 0.0), "/tf_static over an unchanging /tf"),
     ([AT_05, AT_02], [], (0.2, 0.0), "the latest on /tf_static"),
     ([AT_02, ("odom", "laser", (1.0, 0.0, 0.0), quaternion())], [], (0.0, 0.0), "in odom at")],
    ids=["static-twice", "static-and-tf", "static-twice-reversed", "two-parents"],
)  # fmt: skip
def test_two_poses_of_the_scanner_take_tf2s_choice_and_say_so(
    capsys, tmp_path, static, moving, used, said
):
    result = import_bag(capsys, tmp_path, static, moving)
    assert result.code == 0, result.err
    log = read_log(tmp_path / "log.mcap")
    assert (log.laser_offset.x, log.laser_offset.y) == pytest.approx(used, abs=1e-12)
    [warning] = [w for w in offset_warnings(result) if "two poses" in w]
    assert "the bag gives laser two poses" in warning and said in warning
    assert "--laser-offset X,Y,THETA_DEG" in warning


@pytest.mark.parametrize(
    "static", [[AT_02, AT_02], [AT_02, ("base_link", "camera", (0, 0, 1.0), quaternion()),
                                ("base_link", "camera", (0, 0, 2.0), quaternion())]],
    ids=["same-twice", "off-the-chain"],
)  # fmt: skip
def test_transforms_that_agree_or_lie_off_the_chain_say_nothing(capsys, tmp_path, static):
    result = import_bag(capsys, tmp_path, static)
    assert result.code == 0, result.err
    assert not [w for w in offset_warnings(result) if "two poses" in w]
    assert read_log(tmp_path / "log.mcap").laser_offset.x == pytest.approx(0.2, abs=1e-12)


LOOPS = {
    "two-frames": [("base_link", "laser", (0.2, 0, 0), quaternion()),
                   ("laser", "base_link", (0.3, 0, 0), quaternion())],
    "three-frames": [("base_link", "mount", (0.2, 0, 0), quaternion()),
                     ("mount", "laser", (0.1, 0, 0), quaternion()),
                     ("laser", "base_link", (0.3, 0, 0), quaternion())],
    "itself": [("laser", "laser", (0.2, 0, 0), quaternion())],
    "above-the-robot": [("base_link", "laser", (0.2, 0, 0), quaternion()),
                        ("odom", "base_link", (0, 0, 0), quaternion()),
                        ("base_link", "odom", (0, 0, 0), quaternion())],
}  # fmt: skip


@pytest.mark.parametrize("loop", LOOPS)
def test_transforms_that_form_a_loop_are_refused_in_one_line(capsys, tmp_path, loop):
    result = import_bag(capsys, tmp_path, LOOPS[loop])
    assert_one_line_error(result, "test.bag", "form a loop", "--laser-offset X,Y,THETA_DEG")
    assert not (tmp_path / "log.mcap").exists()


def test_a_loop_off_the_chain_is_no_matter(capsys, tmp_path):
    loop = [("x", "y", (1, 0, 0), quaternion()), ("y", "x", (1, 0, 0), quaternion())]
    result = import_bag(capsys, tmp_path, [AT_02, *loop])
    assert result.code == 0, result.err
    assert read_log(tmp_path / "log.mcap").laser_offset_source == "tf_static:base_link->laser"


@pytest.mark.parametrize(
    ("static", "given", "said"),
    [([AT_02], "0.1,0,0", "place laser at x 0.2 m, y 0 m, theta 0°"),
     ([AT_05], "0.5,0.1,0", "theta 17.1887°"),
     ([("base_link", "laser", (0.2, 0, 0.3), quaternion(roll=math.pi))], "0.2,0,0",
      "upside down"),
     (LOOPS["two-frames"], "0.1,0,0", None),
     ([AT_02], "0.2,0,0", None),
     ([AT_02], "0.2004,0,0.005", None),
     ([], "0.3,0,0", None)],
    ids=["moved", "turned", "upside-down", "loop", "same", "within-rounding", "no-tf"],
)  # fmt: skip
def test_laser_offset_wins_over_the_bag_and_says_where_the_bag_put_it(
    capsys, tmp_path, static, given, said
):
    result = import_bag(capsys, tmp_path, static, [], "--laser-offset", given)
    assert result.code == 0, result.err
    log = read_log(tmp_path / "log.mcap")
    x, y, theta_deg = (float(v) for v in given.split(","))
    assert (log.laser_offset.x, log.laser_offset.y) == (x, y)
    assert log.laser_offset.theta_deg == pytest.approx(theta_deg, abs=1e-12)
    assert log.laser_offset_source == "--laser-offset"
    overridden = [w for w in offset_warnings(result) if f"--laser-offset {given[:3]}" in w]
    if said is None:
        assert overridden == []
    else:
        [warning] = overridden
        assert "is used; the bag's transforms" in warning and said in warning


def carmen_log(path: Path, times: list[str]) -> Path:
    """A CARMEN log of FLASER records (181 beams over 180°) of the hall along a short path,
    one per time, written as given; the pose and odometry fields hold the true poses."""
    from segloc_cli.io.maps import read_world
    from segloc_cli.sim import SensorModel, render_ranges

    world, rng = read_world(HALL_WORLD), np.random.default_rng(3)
    angles = -math.pi / 2 + np.arange(181) * math.pi / 180
    lines = ["PARAM robot_front_laser_max 30.0 nohost 0"]
    for k, time_s in enumerate(times):
        pose = Pose2(6.0 + 0.25 * k, 4.0 + 0.1 * k, math.radians(10 + 3 * k))
        ranges = render_ranges(world, pose, angles, SensorModel(noise_cm=0.5), rng)
        values = [*np.where(ranges > 0, ranges, 30.0), *pose.as_array(), *pose.as_array()]
        numbers = " ".join(f"{v:.6f}" for v in values)
        lines.append(f"FLASER 181 {numbers} {time_s} host {time_s}")
    path.write_text("\n".join(lines) + "\n")
    return path


BACKWARD = {
    "back-mid": ["10.0", "10.2", "10.4", "5.0", "5.2", "10.6"],
    "back-far": ["1000.0", "1000.2", "10.0", "10.2", "1000.4", "1000.6"],
    "first-is-latest": ["500", "1", "2", "3", "4", "5"],
    "sawtooth": ["1", "2", "1", "2", "1", "3"],
    "epoch": ["1.13486e+09", "1.13487e+09", "1.12e+09", "1.13486e+09", "1.13488e+09",
              "1.13489e+09"],
    "squeezed": ["5.1", "5.1", "5.1", "5.1000003", "4.0", "5.2"],
}  # fmt: skip


@pytest.mark.parametrize("times", BACKWARD)
def test_carmen_times_that_jump_back_pair_exactly_at_zero_tolerance(capsys, tmp_path, times):
    source = carmen_log(tmp_path / "back.log", BACKWARD[times])
    log, survey = tmp_path / "back.mcap", tmp_path / "survey.csv"
    done = run_cli(capsys, "import", "carmen", source, "--out", log, "--survey-out", survey)
    assert done.code == 0, done.err
    assert "go back in time; gave them distinct times" in done.err
    out = tmp_path / "est.csv"
    exact = ("--tolerance-ms", "0")
    located = run_cli(capsys, "localize", log, "--map", HALL_WORLD, "--out", out, *exact)
    assert located.code == 0, located.err
    rows = estimate_rows(out)
    reference = pd.read_csv(survey)
    assert len(rows) == len(reference) == 6
    assert (rows["time_s"].to_numpy() == reference["time_s"].to_numpy()).all()
    assert (rows["status"] == "ok").all()
    scored = run_cli(capsys, "evaluate", out, "--survey", survey, *exact, "--format", "json")
    assert scored.code == 0, scored.err
    assert '"no_estimate"' not in scored.out and "no estimate" not in scored.err
    built = run_cli(capsys, "map", "build", log, "--survey", survey, "--out",
                    tmp_path / "map.json", *exact)  # fmt: skip
    assert built.code == 0 and "(0 scans had no survey row)" in built.err, built.err


def test_carmen_times_that_run_past_2106_once_made_distinct_are_refused(capsys, tmp_path):
    source = carmen_log(tmp_path / "far.log", ["4294967295", "7", "8", "9"])
    result = run_cli(capsys, "import", "carmen", source, "--out", tmp_path / "far.mcap")
    assert_one_line_error(result, str(source), "run past 4294967296 s")
    assert not (tmp_path / "far.mcap").exists()


# =========================================================================== 4. --jobs and limits


@pytest.fixture(scope="module")
def one_job(tmp_path_factory) -> pd.DataFrame:
    """The hall's ten scans localized on one process: the rows every --jobs must give."""
    out = tmp_path_factory.mktemp("one") / "est.csv"
    setup_cli("localize", HALL_LOG, "--map", HALL_MAP, "--out", out, "--window-m", "0")
    return without_times(pd.read_csv(out))


def localize_jobs(capsys, tmp_path: Path, jobs: object) -> tuple[Result, Path]:
    out = tmp_path / "est.csv"
    args = ["localize", HALL_LOG, "--map", HALL_MAP, "--out", out, "--window-m", "0"]
    return run_cli(capsys, *args, "--jobs", jobs), out


@pytest.mark.parametrize("jobs", [3, 64, 400, 10**6])
def test_more_jobs_than_cores_run_on_the_cores_and_say_so(capsys, tmp_path, one_job, jobs):
    from segloc_cli.runs.parallel import usable_cores

    result, out = localize_jobs(capsys, tmp_path, jobs)
    assert result.code == 0, result.err
    cores = usable_cores()
    said = f"--jobs {jobs} is more than the {cores} core{'s' if cores > 1 else ''} segloc may use"
    assert (said in result.err) == (jobs > cores)
    pd.testing.assert_frame_equal(without_times(pd.read_csv(out)), one_job)


@pytest.mark.parametrize("jobs", ["0", "-3", "two"])
def test_jobs_that_are_no_count_are_refused(capsys, tmp_path, jobs):
    result, out = localize_jobs(capsys, tmp_path, jobs)
    assert_one_line_error(result, "--jobs")
    assert not out.exists()


def test_many_jobs_with_track_are_refused_before_any_work(capsys, tmp_path):
    out = tmp_path / "est.csv"
    args = ["localize", HALL_LOG, "--map", HALL_MAP, "--out", out, "--track", "--jobs", "400"]
    assert_one_line_error(run_cli(capsys, *args), "--jobs", "--track")
    assert not out.exists()


def _forks_failing_after(monkeypatch, allowed: int, code: int) -> None:
    """Let this process have ``allowed`` children alive at once, and fail a fork past them
    as the kernel does (``code``)."""
    real, children = os.fork, []

    def fork() -> int:
        alive = [pid for pid in children if Path(f"/proc/{pid}").exists()]
        if len(alive) >= allowed:
            raise OSError(code, os.strerror(code))
        pid = real()
        children.append(pid)
        return pid

    monkeypatch.setattr(os, "fork", fork)


@pytest.mark.parametrize(
    ("allowed", "code", "said"),
    [(1, errno.EAGAIN, "could start 1 of 2 worker processes (Resource temporarily unavailable"),
     (0, errno.EAGAIN, "could start no worker process (Resource temporarily unavailable"),
     (0, errno.ENOMEM, "could start no worker process (Cannot allocate memory")],
    ids=["one-of-two", "none-eagain", "none-enomem"],
)  # fmt: skip
def test_workers_the_system_will_not_start_are_done_without(
    capsys, tmp_path, monkeypatch, one_job, allowed, code, said
):
    _forks_failing_after(monkeypatch, allowed, code)
    result, out = localize_jobs(capsys, tmp_path, 2)
    assert result.code == 0, result.err
    assert said in result.err and "ulimit -u" in result.err
    assert "Resource temporarily unavailable" not in result.err.splitlines()[-1]
    pd.testing.assert_frame_equal(without_times(pd.read_csv(out)), one_job)


@pytest.mark.parametrize("where", ["manager", "feeder"])
def test_a_pool_that_cannot_start_its_threads_is_done_without(
    capsys, tmp_path, monkeypatch, one_job, where
):
    """No thread to run the pool (``ulimit -u`` counts threads): started in this process
    (the manager) or in the pool's own thread (the queue's feeder), where it would else be
    printed as a traceback and leave the run waiting."""
    import concurrent.futures.process
    import multiprocessing.queues

    def refuse(*_args, **_kwargs):
        raise RuntimeError("can't start new thread")

    if where == "manager":
        monkeypatch.setattr(concurrent.futures.process._ExecutorManagerThread, "start", refuse)
    else:
        monkeypatch.setattr(multiprocessing.queues.Queue, "_start_thread", refuse)
    started = time.monotonic()
    result, out = localize_jobs(capsys, tmp_path, 2)
    assert result.code == 0, result.err
    assert "Traceback" not in result.err
    assert "could start no worker process (can't start new thread" in result.err
    assert time.monotonic() - started < 20
    pd.testing.assert_frame_equal(without_times(pd.read_csv(out)), one_job)


def test_a_sweep_with_more_jobs_than_cores_runs_on_the_cores(capsys, spec_dir):
    from segloc_cli.runs.parallel import usable_cores

    out = spec_dir / "results.parquet"
    done = run_cli(capsys, "sweep", write_spec(spec_dir), "--out", out, "--jobs", "400")
    assert done.code == 0, done.err
    cores = usable_cores()
    said = f"--jobs 400 is more than the {cores} core{'s' if cores > 1 else ''} segloc may use here"
    assert said in done.err
    n = min(cores, 2)
    assert f"running 2 on a local cluster of {n} worker{'s' if n > 1 else ''}" in done.err
    assert len(pd.read_parquet(out)) == 2 * 3


def _process_limit(nproc: int) -> tuple[str, ...] | None:
    """A prefix that runs a command under a limit of ``nproc`` processes (and threads), as
    an unprivileged user (root is not held to the limit), or None where none can be set."""
    if shutil.which("prlimit") is None:
        return None
    if os.getuid() != 0:
        return ("prlimit", f"--nproc={nproc}")
    if shutil.which("setpriv") is None:
        return None
    # nobody, keeping the right to read and write the files here but not to pass the limit.
    caps = "+dac_override,+dac_read_search"
    user = ("setpriv", "--reuid=65534", "--regid=65534", "--clear-groups")
    prefix = (*user, f"--inh-caps={caps}", f"--ambient-caps={caps}", "prlimit", f"--nproc={nproc}")
    probe = subprocess.run([*prefix, sys.executable, "-c", "pass"], capture_output=True)
    return prefix if probe.returncode == 0 else None


@pytest.fixture
def open_dir(spec_dir):
    """``spec_dir``'s files in a folder anyone may write in (the unprivileged user of
    ``_process_limit`` must pass segloc's check that it may write its outputs)."""
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix="segloc-limit-", dir="/tmp"))
    try:
        shutil.copytree(spec_dir, folder, dirs_exist_ok=True)
        folder.chmod(0o777)  # after the copy, which gives it spec_dir's mode
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@pytest.mark.parametrize(
    ("command", "nproc", "outcome"),
    [("localize", 6, "; localizing on "),
     ("sweep", 12, "leaves room for"),
     ("sweep", 26, "a local cluster of 1 worker, not 2")],
    ids=["localize-6", "sweep-12", "sweep-26"],
)  # fmt: skip
def test_under_a_process_limit_runs_with_what_starts_or_says_why_not(
    open_dir, command, nproc, outcome
):
    from segloc_cli.runs.parallel import usable_cores

    prefix = _process_limit(nproc)
    if prefix is None:
        pytest.skip("no way here to run a command under a limit on processes (prlimit)")
    if usable_cores() < 2:
        pytest.skip("one core: --jobs 2 asks for no more than it gives")
    spec_dir = open_dir
    if command == "localize":
        # Copies: the unprivileged user may not reach the repository's own (a clone in a
        # folder only its owner may enter), and segloc checks that it may read its inputs.
        log, segment_map = (Path(shutil.copy(f, spec_dir)) for f in (HALL_LOG, HALL_MAP))
        out = spec_dir / "est.csv"
        argv = ["localize", log, "--map", segment_map, "--out", out, "--jobs", "400"]
    else:
        out = spec_dir / "results.parquet"
        text = SPEC.replace("seeds = [1, 2]", "seeds = [1, 2, 3]")
        argv = ["sweep", write_spec(spec_dir, text), "--out", out, "--jobs", "2"]
    result = run_script(*argv, prefix=prefix, timeout=90)
    assert "Resource temporarily unavailable" not in result.err.splitlines()[-1]
    assert outcome in result.err
    if nproc == 12:
        assert_error_last(result, "ulimit -u", "--scheduler")
        assert not out.exists()
    else:
        assert result.code == 0, result.err
        assert "Traceback" not in result.err
        assert out.exists()
