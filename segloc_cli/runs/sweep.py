"""Sweeps: many localize runs at once, one task per log × combination of settings × seed.

A task localizes the scans of one log that the survey holds, against one map, from guesses
made for one seed, under one combination of settings, and scores each answer against the
survey (``run_task``). Tasks run on a Dask cluster: a local one over this machine's cores, or
the one a scheduler address names (``connect``). Each finished task's rows are kept at once
in a file of their own (``ResultStore``), so that an interrupted or killed sweep loses
nothing done, and a rerun skips every task whose key it already holds: the key hashes the
log's, map's and survey's bytes, the guesses, the resolved settings and the seed.

The table has one row per log × scan × seed × combination, in the order the spec plans them
whatever the order tasks finished in; only ``runtime_ms`` differs from run to run. Positions
are in metres and headings in degrees (world frame), errors in cm and degrees, surveyed
minus estimate, as ``segloc evaluate`` gives them.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import shutil
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from segloc_cli.errors import InputError
from segloc_cli.estimates import STATUS_NO_GUESS, STATUS_NO_SCAN, STATUS_TASK_FAILED, PoseTable
from segloc_cli.wording import counted

TASK_COLUMNS = ("task", "log", "combination", "seed")
"""The task a row belongs to: its key, the log as the spec names it, the combination's index
in the spec's grid (from 0) and the seed."""
SCAN_COLUMNS = (
    "pose_id",
    "time_s",
    "init_x_m",
    "init_y_m",
    "init_theta_deg",
    "x_m",
    "y_m",
    "theta_deg",
    "status",
    "confidence",
    "inlier_ratio",
    "err_x_cm",
    "err_y_cm",
    "err_xy_cm",
    "err_theta_deg",
    "runtime_ms",
    "error",
)
"""What each scan's row holds after the task and parameter columns; ``error`` is empty but
for the one row of a failed task."""
MISSING_ODOMETRY = "; give init-errors or initial = FILE in the spec"
"""How the error of a task that takes its guesses from a log without /odom ends."""
KEY_DIGITS = 16
"""Hex digits of a task key (64 bits): no two tasks of any sweep share one."""


@dataclass(frozen=True)
class Task:
    """One log × one combination × one seed, with all a worker needs but the log itself,
    which it reads from ``log_path`` (so every worker must see that path).

    ``params`` are the combination's grid values by key, in the grid's order; ``settings``
    every localize setting the spec sets (fixed and grid) by key, as ``Config.from_values``
    takes them, and ``global`` when true. ``guesses`` are the initial poses (world frame,
    paired with the scans by time), None to take the log's /odom or, for a global search,
    none at all. ``survey`` holds the true poses the answers are scored against.
    """

    key: str
    log: str
    log_path: Path
    combination: int
    params: tuple[tuple[str, Any], ...]
    settings: tuple[tuple[str, Any], ...]
    seed: int
    segments_world: np.ndarray
    survey: PoseTable
    survey_path: str
    guesses: PoseTable | None

    @property
    def is_global(self) -> bool:
        return bool(dict(self.settings).get("global", False))


def task_key(identity: dict[str, Any]) -> str:
    """The key of a task from what decides its rows (JSON-able values), ``KEY_DIGITS`` hex."""
    text = json.dumps(identity, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:KEY_DIGITS]


# --------------------------------------------------------------------------- on a worker


@functools.lru_cache(maxsize=4)
def _read_log(path: str, mtime_ns: int, size: int):
    """A log read once per worker while its file is unchanged (the tasks of one log share it)."""
    from segloc_cli.io.mcap_log import read_log

    return read_log(Path(path))


def _log_of(path: Path):
    try:
        stat = path.stat()
    except OSError as exc:
        raise InputError(f"cannot read the log ({exc.strerror})", path=path) from None
    return _read_log(str(path), stat.st_mtime_ns, stat.st_size)


def run_task(task: Task) -> pd.DataFrame:
    """Localize the task's scans and score them: one row per survey pose within the log's
    time span, ``TASK_COLUMNS``, the grid keys, then ``SCAN_COLUMNS``, in survey order. A pose
    without a scan, or without a guess, keeps its row, with status ``STATUS_NO_SCAN`` or
    ``STATUS_NO_GUESS`` and no estimate: a miss. Raises on bad input, which the sweep
    records as the task's failure."""
    from segloc_cli.config import Config
    from segloc_cli.runs import pipeline
    from segloc_cli.runs.parallel import warm_localizer
    from segloc_cli.scoring.evaluate import final_errors

    log = _log_of(task.log_path)
    config = Config.from_values(dict(task.settings))
    rows, guesses, missing = _survey_pairing(task, log, config.tolerance_ms / 1e3)
    if rows.size == 0:
        raise InputError(
            f"no survey row has a scan within {config.tolerance_ms:g} ms"
            + ("" if task.is_global else " and a guess"),
            path=task.log_path,
        )
    mode = "global" if task.is_global else "guided"
    localizer = pipeline.localizer_for(task.segments_world, config, mode)
    scans = [log.scans[i] for i in guesses.index]
    warm_localizer(localizer, scans, None if task.is_global else guesses.poses, config.extract)
    guided = not task.is_global
    made = pipeline.localize_guessed(log, task.log_path, localizer, guesses, config, guided=guided)
    estimates = pd.DataFrame(
        [{k: v for k, v in row.items() if k != "hypotheses"} for row in made.rows]
    )
    final = (estimates[c].to_numpy(float) for c in ("x_m", "y_m", "theta_deg"))
    frame = estimates.assign(**final_errors(task.survey.poses[rows], *final), error=None)
    absent = np.flatnonzero(pd.notna(missing))
    misses = pd.DataFrame({c: np.full(absent.size, np.nan) for c in SCAN_COLUMNS})
    misses = misses.assign(pose_id=task.survey.pose_id[absent], time_s=task.survey.time_s[absent],
                           status=missing[absent], error=None)  # fmt: skip
    order = np.argsort(np.concatenate([rows, absent]), kind="stable")
    table = pd.concat([frame[list(SCAN_COLUMNS)], misses[list(SCAN_COLUMNS)]], ignore_index=True)
    table["status"] = table["status"].astype(str)  # the misses' are objects
    return _framed(task, table.iloc[order])


def _survey_pairing(task: Task, log, tolerance_s: float):
    """(survey rows to localize, ``pipeline.Guesses`` of their scans, misses): the rows whose
    time has a scan of ``log`` (its nearest, within ``tolerance_s``) and a guess (world
    frame; none for a global search), those scans' indices, guesses and the rows' pose ids;
    and for each survey row the status of a row that lies within the log's time span but
    lacks a scan or a guess (None elsewhere)."""
    from segloc_cli.geometry import Pose2
    from segloc_cli.runs import pipeline
    from segloc_cli.timing import pair_by_time

    survey_s = task.survey.time_s
    # Each survey row takes the scan nearest its time: a dense log under a sparse survey
    # must not score two scans against one true pose.
    scan = pair_by_time(survey_s, log.scan_times_s, tolerance_s, query_path=task.survey_path,
                        ref_path=task.log_path, query_label="row", ref_label="scan")  # fmt: skip
    times = log.scan_times_s
    spanned = (survey_s >= times.min() - tolerance_s) & (survey_s <= times.max() + tolerance_s)
    missing = np.full(survey_s.size, None, dtype=object)
    missing[(scan < 0) & spanned] = STATUS_NO_SCAN
    guess_poses = None
    if not task.is_global:
        guess_of_row, guess_poses = _guesses_of_rows(task, log, scan, tolerance_s)
        unguessed = (scan >= 0) & (guess_of_row < 0)
        missing[unguessed] = STATUS_NO_GUESS
        scan[unguessed] = -1
    rows = np.flatnonzero(scan >= 0)
    poses = [] if guess_poses is None else [Pose2(*guess_poses[r]) for r in rows]
    return rows, pipeline.Guesses(scan[rows], poses, task.survey.pose_id[rows]), missing


def _guesses_of_rows(task: Task, log, scan: np.ndarray, tolerance_s: float):
    """For each survey row, the row of its guess (−1: none) and that guess (x m, y m, θ rad;
    world frame): the log's /odom at the row's scan, or the task's guess nearest the row's
    time."""
    from segloc_cli.runs import pipeline
    from segloc_cli.timing import pair_by_time

    if task.guesses is None:
        odom = pipeline.odometry_rows(log, task.log_path, tolerance_s, MISSING_ODOMETRY)
        guess_of_row = np.where(scan >= 0, odom[scan], -1)
        return guess_of_row, log.odom_poses[guess_of_row]
    guess_of_row = pair_by_time(task.survey.time_s, task.guesses.time_s, tolerance_s,
                                query_path=task.survey_path, ref_path="the guesses",
                                query_label="row", ref_label="guess")  # fmt: skip
    return guess_of_row, task.guesses.poses[guess_of_row]


def _framed(task: Task, scans: pd.DataFrame) -> pd.DataFrame:
    """``scans`` behind the task's own columns and its grid values."""
    head = {"task": task.key, "log": task.log, "combination": task.combination, "seed": task.seed}
    head |= dict(task.params)
    return pd.concat(
        [
            pd.DataFrame({k: [v] * len(scans) for k, v in head.items()}),
            scans.reset_index(drop=True),
        ],
        axis=1,
    )


def failed_rows(task: Task, error: BaseException) -> pd.DataFrame:
    """The one row a failed task leaves: status ``STATUS_TASK_FAILED``, the error on one line."""
    message = " ".join(f"{type(error).__name__}: {error}".split())
    row: dict[str, Any] = {c: np.nan for c in SCAN_COLUMNS}
    row |= {"pose_id": -1, "status": STATUS_TASK_FAILED, "error": message}
    return _framed(task, pd.DataFrame([row]))


# --------------------------------------------------------------------------- results on disk


class ResultStore:
    """The results of a sweep in ``out`` (Parquet), and the tasks finished since it was last
    written, each in a file of its own in the folder ``out.parts`` beside it.

    A task's file is written whole (renamed into place) as soon as it finishes, so a killed
    sweep keeps every finished task; ``finish`` merges them into ``out`` in plan order and
    removes the folder. A task whose rows are a failure counts as not done: a rerun tries it
    again.
    """

    def __init__(self, out: Path, fresh: bool = False):
        self.out = out
        self.parts = out.with_name(out.name + ".parts")
        self._frames: dict[str, pd.DataFrame] = {}
        if self.parts.exists() and not self.parts.is_dir():
            raise InputError(
                "is not a folder, and segloc sweep keeps each finished task there until it "
                "ends; move it away, or use another --out",
                path=self.parts,
            )
        if fresh:
            shutil.rmtree(self.parts, ignore_errors=True)
            return
        if out.exists():
            self._take(_read_results(out))
        for part in sorted(self.parts.glob("*.parquet")) if self.parts.is_dir() else ():
            with contextlib.suppress(OSError, ValueError):  # a file cut short holds nothing
                self._take(pd.read_parquet(part))

    def _take(self, frame: pd.DataFrame) -> None:
        for key, rows in frame.groupby("task", sort=False):
            self._frames[str(key)] = rows.reset_index(drop=True)

    def done(self) -> set[str]:
        """Keys of the tasks held whose rows are not a failure."""
        return {k for k, rows in self._frames.items() if not _is_failure(rows)}

    def todo(self, tasks: Sequence[Task]) -> list[Task]:
        """The ``tasks`` not done yet, in order; an ``InputError`` when the store holds tasks
        they do not include (another spec's results)."""
        done = self.done()
        foreign = done - {t.key for t in tasks}  # failures of other tasks hold nothing
        if foreign:
            raise InputError(
                f"holds {counted(len(foreign), 'task')} this spec does not plan (another spec's "
                "results?); use another --out, or --force to replace it",
                path=self.out,
            )
        return [t for t in tasks if t.key not in done]

    def add(self, key: str, rows: pd.DataFrame) -> None:
        """Keep a finished task's rows, on disk at once."""
        from segloc_cli.io.files import atomic_path

        self.parts.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.parts / f"{key}.parquet") as partial:
            rows.to_parquet(partial, index=False)
        self._frames[key] = rows

    def finish(self, order: Sequence[str]) -> pd.DataFrame:
        """Write ``out``: the rows of the tasks held, in the order of the keys ``order``;
        return them."""
        from segloc_cli.io.files import atomic_path

        frames = [self._frames[k] for k in order if k in self._frames]
        table = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
        with atomic_path(self.out) as partial:
            table.to_parquet(partial, index=False)
        shutil.rmtree(self.parts, ignore_errors=True)
        return table


def _is_failure(rows: pd.DataFrame) -> bool:
    return bool((rows["status"] == STATUS_TASK_FAILED).any())


def _read_results(path: Path) -> pd.DataFrame:
    """A sweep's earlier results, refused with one line if they are not."""
    try:
        frame = pd.read_parquet(path)
    except (OSError, ValueError) as exc:
        raise InputError(
            f"is not a sweep's results ({' '.join(str(exc).split())[:120]}); use another --out, "
            "or --force to replace it",
            path=path,
        ) from None
    missing = [c for c in (*TASK_COLUMNS, "status") if c not in frame.columns]
    if missing:
        raise InputError(
            f"is not a sweep's results (no column {missing[0]}); use another --out, or --force "
            "to replace it",
            path=path,
        )
    return frame


# --------------------------------------------------------------------------- on the cluster


SCHEDULER_TIMEOUT_S = 15.0
"""Longest wait (s) for a scheduler to connect and greet: an address where nothing answers,
or something that is not a scheduler, is refused after it, never waited on."""
HOST_PORT_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")
"""Address schemes whose location is HOST:PORT."""


def address_problem(address: str) -> str | None:
    """What is wrong with a scheduler address, in a few words, or None when it can name
    one: a known scheme (tcp when none is given) and, for the network ones, a host and a
    port from 1 to 65535."""
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.comm.registry import backends

    scheme, location = parse_address(address.strip())
    if scheme not in backends:
        return f"unknown scheme {scheme!r} (known: {', '.join(sorted(backends))})"
    if scheme not in HOST_PORT_SCHEMES:
        return None
    try:
        host, port = parse_host_port(location)
    except ValueError:
        host, port = "", 0
    if not host or not 1 <= int(port) <= 65535:
        return f"{location!r} is not HOST:PORT with a port from 1 to 65535"
    return None


@contextlib.contextmanager
def connect(
    scheduler: str | None, workers: int, warn: Callable[[str], None] = lambda _: None
) -> Iterator[Any]:
    """A Dask client: of the scheduler at ``scheduler`` (e.g. tcp://10.0.0.5:8786), which
    must greet within ``SCHEDULER_TIMEOUT_S`` (``InputError`` else), or of a local cluster
    of ``workers`` single-threaded worker processes (fewer where the system lets fewer
    start, said through ``warn``), shut down on leaving."""
    from distributed import Client

    if scheduler is not None:
        _greet(scheduler)
        try:
            client = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s")
        except Exception as exc:  # Dask fails to connect in many ways
            raise _unreachable(scheduler, exc) from None
        with client:
            if not client.scheduler_info().get("workers"):
                warn(
                    f"the cluster at {scheduler} has no worker yet; the tasks wait for one "
                    f"(start one with `dask worker {scheduler}`)"
                )
            yield client
        return
    cluster = _local_cluster(workers, warn)
    with cluster, Client(cluster) as client:
        yield client


def where(client: Any, scheduler: str | None) -> str:
    """Where the tasks of ``client`` (``connect``) run, in words: the cluster at the
    scheduler's address, or the local one and its workers."""
    if scheduler:
        return f"the cluster at {scheduler}"
    n = len(client.scheduler_info().get("workers", {}))
    return f"a local cluster of {counted(n, 'worker')}"


def _greet(address: str) -> None:
    """Connect to the scheduler at ``address`` and exchange greetings, within
    ``SCHEDULER_TIMEOUT_S`` (Dask's own client can wait forever on a server that accepts
    and stays silent); ``InputError`` saying why not."""
    import asyncio

    from distributed.comm import connect as open_comm
    from distributed.security import Security

    problem = address_problem(address)
    if problem is not None:
        raise InputError(f"--scheduler {address!r}: {problem}; e.g. tcp://10.0.0.5:8786")
    arguments = Security().get_connection_args("client")

    async def greet() -> None:
        comm = await open_comm(address, timeout=SCHEDULER_TIMEOUT_S, **arguments)
        await comm.close()

    try:
        asyncio.run(asyncio.wait_for(greet(), SCHEDULER_TIMEOUT_S))
    except (OSError, TimeoutError) as exc:
        raise _unreachable(address, exc) from None
    except Exception as exc:  # bytes that are no greeting fail the parser in many ways
        raise InputError(
            f"what answers at {address} is not a Dask scheduler ({_short(exc)}); give the "
            "address `dask scheduler` prints"
        ) from None


def _unreachable(address: str, exc: BaseException) -> InputError:
    """The error of a scheduler that did not answer (``exc`` says how)."""
    why = _short(exc) if str(exc).strip() else "no answer"
    return InputError(
        f"cannot reach the Dask scheduler at {address} within {SCHEDULER_TIMEOUT_S:g} s "
        f"({why}); start one with `dask scheduler` and workers with `dask worker ADDRESS`"
    )


def _short(exc: BaseException) -> str:
    """An exception as a phrase of one line."""
    return " ".join(str(exc).split())[:200] or type(exc).__name__


CLUSTER_THREADS = 8
"""Threads a local cluster adds to this process (its scheduler, the client, the writers of
the results), which count against the limit on processes as processes do."""
WORKER_THREADS = 12
"""Processes and threads one local worker takes (its process and threads, its nanny's in
this process), with room to spare: a worker short of threads hangs rather than fails."""


def room_for_processes() -> int | None:
    """How many more processes and threads (the kernel counts both) this user may start
    under the limit on processes (``ulimit -u``); None where none holds (no limit, root)."""
    import resource

    limit, _ = resource.getrlimit(resource.RLIMIT_NPROC)
    if limit == resource.RLIM_INFINITY or os.getuid() == 0:
        return None
    used = 0
    for status in Path("/proc").glob("[0-9]*/status"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            fields = dict(line.split(":", 1) for line in status.read_text().splitlines())
            if int(fields["Uid"].split()[0]) == os.getuid():
                used += int(fields["Threads"])
    return limit - used


def _workers_with_room(workers: int, warn: Callable[[str], None]) -> int:
    """``workers``, or as many as the limit on processes leaves room for (said through
    ``warn``); ``InputError`` when it leaves room for none."""
    room = room_for_processes()
    if room is None:
        return workers
    fit = (room - CLUSTER_THREADS) // WORKER_THREADS
    if fit < 1:
        raise InputError(
            f"the system's limit on processes (ulimit -u) leaves room for {max(room, 0)} more "
            f"processes and threads, and a local Dask worker takes about "
            f"{CLUSTER_THREADS + WORKER_THREADS}; raise the limit, or run the tasks on a "
            "cluster with --scheduler"
        )
    if fit < workers:
        warn(
            f"the system's limit on processes (ulimit -u) leaves room for {room} more processes "
            f"and threads: a local cluster of {counted(fit, 'worker')}, not {workers}"
        )
    return min(workers, fit)


def _local_cluster(workers: int, warn: Callable[[str], None]):
    """A local cluster of ``workers`` worker processes, or of as many as the limit on
    processes leaves room for (``_workers_with_room``), or where fewer start still, of half
    as many in turn down to one, said through ``warn``; ``InputError`` when not even one
    starts."""
    import logging

    from distributed import LocalCluster

    from segloc_cli.runs.parallel import PROCESS_LIMIT_HINT, lacks_room

    # Dask's own lines (a worker that failed to start, one reaped at exit) are said better
    # here, and a failed task is kept with its error.
    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    workers = asked = _workers_with_room(workers, warn)
    while True:
        try:
            with _terminal_signals_ignored():  # by the workers, which inherit it
                cluster = LocalCluster(
                    n_workers=workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    scheduler_kwargs={"dashboard_address": ":0"},  # its HTTP server on a free port
                    silence_logs=logging.CRITICAL,
                )
        except (OSError, RuntimeError) as exc:
            if not lacks_room(exc):
                raise
            if workers == 1:
                raise InputError(
                    f"could start no local Dask worker ({_short(exc)}): {PROCESS_LIMIT_HINT}; "
                    "raise it, or run the tasks on a cluster with --scheduler"
                ) from None
            workers, why = workers // 2, _short(exc)
            continue
        if workers < asked:
            warn(
                f"could start {workers} of {asked} local Dask workers ({why}: "
                f"{PROCESS_LIMIT_HINT}); running on {workers}"
            )
        return cluster


@contextlib.contextmanager
def _terminal_signals_ignored() -> Iterator[None]:
    """Ignore Ctrl-C and SIGHUP while inside. A terminal sends them to every process of the
    job, and a worker process started meanwhile keeps ignoring them: the sweep alone decides
    how to stop (``run_tasks``) and shuts its workers down."""
    import signal

    names = [n for n in ("SIGINT", "SIGHUP") if hasattr(signal, n)]
    previous = {n: signal.signal(getattr(signal, n), signal.SIG_IGN) for n in names}
    try:
        yield
    finally:
        for name, handler in previous.items():
            signal.signal(getattr(signal, name), handler)


def run_tasks(
    client: Any,
    tasks: Sequence[Task],
    store: ResultStore,
    advance: Callable[[], None],
    stop: Callable[[], bool],
    work: Callable[[Task], pd.DataFrame] = run_task,
) -> None:
    """Run ``tasks`` on ``client``'s cluster, each finished one kept in ``store`` at once.

    ``work`` runs a task on a worker (``run_task``). A task that raises is run once more and
    then kept as a failure (``failed_rows``); the others go on. Between finished tasks
    ``stop`` is asked; when it says so, the tasks not yet finished are cancelled.
    """
    from distributed import wait

    futures = {}
    for task in tasks:  # thousands take seconds to submit: a stop is heard meanwhile
        if stop():
            break
        key = f"segloc-sweep-{task.key}"
        futures[client.submit(work, task, key=key, retries=1, pure=False)] = task
    pending = set(futures)
    try:
        while pending and not stop():
            with contextlib.suppress(TimeoutError):
                finished, pending = wait(pending, timeout=0.5, return_when="FIRST_COMPLETED")
                for future in finished:
                    task = futures[future]
                    if future.status == "finished":
                        store.add(task.key, future.result())
                    else:
                        store.add(task.key, failed_rows(task, future.exception()))
                    advance()
    finally:
        if pending:
            client.cancel(list(pending))


# --------------------------------------------------------------------------- the summary


SUMMARY_FORMATS = ("md", "csv", "latex", "json")
STAT_DECIMALS = {
    "within gates %": 1,
    "median cm": 1,
    "p95 cm": 1,
    "median °": 2,
    "p95 °": 2,
    "median ms": 1,
}
"""The summary's figures and the decimals Markdown and LaTeX show them with."""


def summary(
    table: pd.DataFrame,
    grid_keys: Sequence[str],
    fail_above_cm: float,
    fail_above_deg: float,
) -> pd.DataFrame:
    """One row per combination: its grid values, tasks (and failed ones), survey poses
    scored, the share of them within the gates (``segloc evaluate``'s: |err_x|, |err_y| ≤
    ``fail_above_cm``, |err_theta| ≤ ``fail_above_deg`` and an accepted status), median and
    95th percentile of the position (cm) and heading (°) errors, a pose without an estimate
    counting as infinitely wrong, and the median time per scan (ms)."""
    from segloc_cli.scoring.gates import Gates, failing_mask

    gates = Gates(axis_cm=fail_above_cm, deg=fail_above_deg)

    rows = []
    for combination, group in table.groupby("combination", sort=True):
        failed = group["status"] == STATUS_TASK_FAILED
        poses = group[~failed]
        failing = failing_mask(poses, gates)
        position = _misses_infinite(poses["err_xy_cm"])
        heading = _misses_infinite(poses["err_theta_deg"].abs())
        row: dict[str, Any] = {k: group[k].iloc[0] for k in grid_keys}
        row |= {
            "tasks": int(group["task"].nunique()),
            "failed tasks": int(failed.sum()),
            "poses": len(poses),
            "within gates %": 100.0 * float(np.mean(~failing)) if len(poses) else np.nan,
            "median cm": _percentile(position, 50),
            "p95 cm": _percentile(position, 95),
            "median °": _percentile(heading, 50),
            "p95 °": _percentile(heading, 95),
            "median ms": _percentile(poses["runtime_ms"].dropna().to_numpy(float), 50),
        }
        rows.append({"combination": int(combination), **row})
    return pd.DataFrame(rows)


def _misses_infinite(errors: pd.Series) -> np.ndarray:
    return np.nan_to_num(errors.to_numpy(float), nan=np.inf)


def _percentile(values: np.ndarray, q: float) -> float:
    """The ``q``-th percentile, by the nearest rank below so that ∞ stays ∞ (NaN if empty)."""
    return float(np.percentile(values, q, method="lower")) if values.size else float("nan")


def format_summary(frame: pd.DataFrame, fmt: str) -> str:
    """The summary as Markdown (1 decimal; 2 for degrees), CSV or JSON (each number rounded to
    its unit's precision, ``numbers.py``), or a LaTeX booktabs ``tabular`` (``latex.py``).
    An infinite error (too many poses without an estimate) is ∞, inf in CSV and null in
    JSON."""
    from segloc_cli.numbers import rounded_frame

    if fmt == "csv":
        return rounded_frame(frame).to_csv(index=False)
    if fmt == "json":
        return rounded_frame(frame).to_json(orient="records", indent=2) + "\n"
    shown = frame.astype(object)
    for column, decimals in STAT_DECIMALS.items():
        shown[column] = [_number(v, decimals) for v in frame[column]]
    if fmt == "md":
        return shown.to_markdown(index=False, disable_numparse=True) + "\n"
    if fmt == "latex":
        from segloc_cli.latex import latex_text, with_needs

        shown = shown.map(lambda v: latex_text(str(v)))
        shown.columns = [latex_text(str(c)) for c in shown.columns]
        return with_needs(shown.style.hide(axis="index").to_latex(hrules=True))
    raise ValueError(f"unknown format {fmt!r}; choose one of {', '.join(SUMMARY_FORMATS)}")


def _number(value: float, decimals: int) -> str:
    if np.isinf(value):
        return "∞"
    return f"{value:.{decimals}f}" if np.isfinite(value) else "–"


# --------------------------------------------------------------------------- convergence curves


CONVERGENCE_SUFFIXES = (".md", ".png", ".pdf")
"""The files of ``--convergence PREFIX``: the table (Markdown), then the figure."""


def convergence_outputs(prefix: Path | None) -> dict[str, Path]:
    """The files ``--convergence PREFIX`` writes, by the name an error gives each: PREFIX.md,
    PREFIX.png and PREFIX.pdf; none without a prefix."""
    if prefix is None:
        return {}
    return {
        f"--convergence ({suffix[1:]})": prefix.with_name(prefix.name + suffix)
        for suffix in CONVERGENCE_SUFFIXES
    }


def survey_truth(tasks: Sequence[Task]) -> pd.DataFrame:
    """The surveyed poses of the tasks' logs, one row per log and pose: ``log``, ``pose_id``,
    ``x_m``, ``y_m``, ``theta_deg`` (m, °; world frame)."""
    frames = {}
    for task in tasks:
        if task.log not in frames:
            poses = task.survey.poses
            frames[task.log] = pd.DataFrame(
                {"log": task.log, "pose_id": task.survey.pose_id, "x_m": poses[:, 0],
                 "y_m": poses[:, 1], "theta_deg": np.rad2deg(poses[:, 2])}
            )  # fmt: skip
    if not frames:
        return pd.DataFrame(columns=["log", "pose_id", "x_m", "y_m", "theta_deg"])
    return pd.concat(frames.values(), ignore_index=True)


def write_convergence(
    table: pd.DataFrame, tasks: Sequence[Task], grid_keys: Sequence[str], prefix: Path
) -> tuple[list[Path], list[str]]:
    """Write the convergence curves of a sweep's rows (``scoring.convergence``), success
    against initial error scored against the tasks' surveys: PREFIX.md, the table, and
    PREFIX.png and PREFIX.pdf, the figure. Returns (the files written, the notes on rows
    that fall in no bin)."""
    from segloc_cli.io.figures import save_figure
    from segloc_cli.io.files import write_text_atomic
    from segloc_cli.scoring.convergence import (
        convergence_table,
        draw_convergence,
        format_convergence_md,
    )

    curves = convergence_table(table, survey_truth(tasks), grid_keys)
    markdown = convergence_outputs(prefix)["--convergence (md)"]
    write_text_atomic(markdown, format_convergence_md(curves))
    figures = save_figure(draw_convergence(curves), prefix.parent, prefix.name)
    return [markdown, *figures], list(curves.attrs["notes"])
