"""Localizing independent scans on several processes, with the same rows as on one.

Scans localized from their own initial guesses (or globally) do not depend
on each other, so blocks of them go to worker processes and the rows come
back in scan order. The workers are forked after the localizer's map was
prepared (``prepared.py``: its indexes, R-table and score raster) and its
kernels compiled, so each starts with them rather than building them again.
Every row equals the one a single process gives except ``runtime_ms``, a
measured time.

No more workers are started than there are blocks of scans, nor (``usable_cores``, which
the command warns of) than cores to run them. Where the system lets fewer processes start
than asked (the limit of ``ulimit -u``, a container's), the run goes on with those that
started, and with none on this process alone; a line on stderr says so.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import multiprocessing
import os
import signal
import sys
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from typing import NamedTuple

import numpy as np

from segloc_cli.estimates import EstimateRow
from segloc_cli.geometry import Pose2
from segloc_cli.jit import one_thread
from segloc_cli.method.extract import ExtractParams
from segloc_cli.method.localize import ScanMatcher, localize_scans
from segloc_cli.method.window import Windows
from segloc_cli.scan import Scan
from segloc_cli.wording import said

BLOCK_SCANS = 4
"""Scans per task: small enough to keep both cores busy to the end of a short log."""
POLL_S = 0.25
"""How often (s) the parent, waiting for a block, checks whether it was asked to stop."""
PR_SET_PDEATHSIG = 1
"""Linux prctl option: the signal a process gets when its parent dies."""
START_TIMEOUT_S = 30.0
"""Longest wait (s) for a new pool's first worker to answer: a pool that could not start a
thread of its own never does."""
PROCESS_LIMIT_HINT = "the system's limit on processes (ulimit -u) may be reached"
"""What the warning of a pool (or a sweep's cluster) smaller than asked suggests."""


class _Job(NamedTuple):
    """The work of a run spread over processes: ``localize_scans``'s arguments."""

    scans: list[Scan]
    initial_poses: Sequence[Pose2] | None
    pose_ids: list[int]
    localizer: ScanMatcher
    extract_params: ExtractParams | None
    windows: Windows | None


_job: _Job | None = None
"""The work of the current run, set before the workers are forked (they inherit it)."""


def usable_cores() -> int:
    """How many cores this process may run on (its CPU affinity, where the system tells)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _worker_signals() -> None:
    """A worker leaves stopping to the parent, dies of SIGTERM (as the whole process group
    gets it from a job runner), and dies with the parent even if that is killed outright
    (Linux; elsewhere the pipe's end stops it). The pool takes a dead worker in its stride.
    Its parallel kernels run on one thread: the workers share the cores already."""
    # Ctrl-C and a closing terminal reach every process of the group; the parent handles them.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    with contextlib.suppress(OSError, AttributeError, TypeError):
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() == 1:  # the parent died before the line above took effect
        os._exit(1)
    one_thread()


def _localize_block(bounds: tuple[int, int]) -> list[EstimateRow]:
    if _job is None:
        raise RuntimeError("no job: blocks run on the workers of localize_scans_parallel")
    scans, guesses, pose_ids, localizer, extract_params, windows = _job
    start, stop = bounds
    block_guesses = None if guesses is None else guesses[start:stop]
    block_windows = None if windows is None else windows.block(start, stop)
    rows = localize_scans(
        scans[start:stop],
        block_guesses,
        pose_ids[start:stop],
        localizer,
        extract_params,
        block_windows,
    )
    return list(rows)


_warmed: weakref.WeakSet = weakref.WeakSet()
"""Localizers already run once in this process (their kernels compiled)."""


def warm_localizer(localizer: ScanMatcher, scans: Sequence[Scan], guesses, extract_params) -> None:
    """Run the localizer once on the first scan (globally when ``guesses`` is None), untimed,
    so that no scan's time includes compiling its kernels (and forked workers start with them
    compiled). What it looks the map up in was built with it (``prepared.prepare_map``)."""
    if scans and localizer not in _warmed:
        first = None if guesses is None else guesses[:1]
        list(localize_scans(scans[:1], first, [0], localizer, extract_params))
        _warmed.add(localizer)


def localize_scans_parallel(
    scans: Sequence[Scan],
    initial_poses: Sequence[Pose2] | None,
    pose_ids: Sequence[int] | np.ndarray,
    localizer: ScanMatcher,
    jobs: int,
    extract_params: ExtractParams | None = None,
    stop: Callable[[], bool] = lambda: False,
    windows: Windows | None = None,
) -> Iterator[EstimateRow]:
    """``localize_scans`` spread over ``jobs`` processes; rows are yielded in scan order
    (``windows``: each scan's neighbours, as there).

    With ``jobs`` 1 (or a single scan) this is ``localize_scans`` itself. While
    waiting for a block the parent asks ``stop()`` every ``POLL_S``; when it
    says so (or a worker died of the signal that asked it), no more rows come
    and the workers are killed.
    """
    if jobs <= 1 or len(scans) <= 1:
        yield from localize_scans(
            scans, initial_poses, pose_ids, localizer, extract_params, windows
        )
        return
    global _job
    warm_localizer(localizer, scans, initial_poses, extract_params)
    blocks = [(i, min(i + BLOCK_SCANS, len(scans))) for i in range(0, len(scans), BLOCK_SCANS)]
    _job = _Job(list(scans), initial_poses, list(pose_ids), localizer, extract_params, windows)
    pool, jobs = _started_pool(min(jobs, len(blocks)), stop) if len(blocks) > 1 else (None, 1)
    if pool is None:
        _job = None
        if not stop():
            yield from localize_scans(
                scans, initial_poses, pose_ids, localizer, extract_params, windows
            )
        return
    try:
        # A few blocks ahead per worker keep both busy; the rest are sent as rows come back.
        pending = deque(pool.submit(_localize_block, b) for b in blocks[: 2 * jobs])
        for following in [*blocks[2 * jobs :], *([None] * len(pending))]:
            rows = _result(pending.popleft(), stop)
            if rows is None:
                return
            if following is not None:
                pending.append(pool.submit(_localize_block, following))
            yield from rows
    finally:
        _job = None
        _shut_down(pool)


def _started_pool(jobs: int, stop: Callable[[], bool]) -> tuple[ProcessPoolExecutor | None, int]:
    """A pool of ``jobs`` worker processes, forked now, and its size; where the system lets
    fewer start (``lacks_room``, or a pool that never answered), a pool of as many as did,
    said on stderr, and (None, 0) when not even one starts, or when ``stop()`` asks the run
    to end meanwhile."""
    asked, why = jobs, ""
    while jobs >= 1:
        pool = ProcessPoolExecutor(
            jobs, mp_context=multiprocessing.get_context("fork"), initializer=_worker_signals
        )
        try:
            _start(pool)
        except (OSError, RuntimeError, FutureTimeout) as exc:
            if not (isinstance(exc, FutureTimeout) or lacks_room(exc)):
                _shut_down(pool)
                time.sleep(POLL_S)  # a worker ended by the signal that stops the run
                if stop():
                    return None, 0
                raise
            started = len(getattr(pool, "_processes", {}))
            _shut_down(pool)
            why, jobs = _why(exc), min(jobs - 1, started)
            continue
        if jobs < asked:
            _say(
                f"could start {jobs} of {asked} worker processes ({why}: {PROCESS_LIMIT_HINT}); "
                f"localizing on {jobs}"
            )
        return pool, jobs
    _say(
        f"could start no worker process ({why}: {PROCESS_LIMIT_HINT}); localizing on this one alone"
    )
    return None, 0


def _start(pool: ProcessPoolExecutor) -> None:
    """Fork the pool's workers and start its threads, by running a task that does nothing;
    raise what stopped them, a thread's failure included (which would else be printed and
    leave the task waiting forever), or ``FutureTimeout`` after ``START_TIMEOUT_S``."""
    failed: list[BaseException] = []
    previous = threading.excepthook

    def note(args: threading.ExceptHookArgs) -> None:
        if args.exc_value is not None and lacks_room(args.exc_value):
            failed.append(args.exc_value)
        else:
            previous(args)

    threading.excepthook = note
    try:
        started = pool.submit(_nothing)
        deadline = time.monotonic() + START_TIMEOUT_S
        while not started.done() and not failed and time.monotonic() < deadline:
            time.sleep(0.01)
        if failed:
            raise failed[0]
        started.result(timeout=0)
    finally:
        threading.excepthook = previous


def _nothing() -> None:
    """A task that does nothing: the first one, which starts the pool."""


def lacks_room(exc: BaseException) -> bool:
    """Whether ``exc``, or an error behind it, says the system would start no more processes
    or threads (fork's EAGAIN or ENOMEM, a thread or a Dask nanny that could not start), not
    that something is wrong."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, OSError) and seen.errno in (errno.EAGAIN, errno.ENOMEM):
            return True
        if "can't start new thread" in str(seen) or "Nanny failed to start" in str(seen):
            return True
        seen = seen.__cause__ or seen.__context__
    return False


def _why(exc: BaseException) -> str:
    """What stopped a pool from starting, in a few words."""
    if isinstance(exc, FutureTimeout):
        return f"its first worker did not answer within {START_TIMEOUT_S:g} s"
    return exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)


def _say(message: str) -> None:
    """A warning on stderr, in the command line's words."""
    print(said(f"warning: {message}"), file=sys.stderr)


def _result(future: Future, stop: Callable[[], bool]) -> list[EstimateRow] | None:
    """The rows of a block, or None once ``stop()`` says the run is to end."""
    while True:
        try:
            return future.result(timeout=POLL_S)
        except FutureTimeout:
            if stop():
                return None
        except Exception:
            # A worker ended by the signal that stops the run fails its block; that is the stop.
            time.sleep(POLL_S)  # let the parent's own handler note the signal first
            if stop():
                return None
            raise


def _shut_down(pool: ProcessPoolExecutor) -> None:
    """End the workers at once, busy or not, and let the pool tidy up without waiting."""
    processes = list(getattr(pool, "_processes", {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(OSError, ValueError):
            process.kill()
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AssertionError):
            process.join(timeout=5.0)
