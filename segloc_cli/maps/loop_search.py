"""Where segment SLAM's loop searches run: in the mapping process, or beside it in a worker
process that holds the submaps, so that the front end maps on while older submaps are
searched (``LoopSearcher``).

The answers do not depend on which: a keyframe's searches are handed over when it is
searched for, and their answers taken in at the next keyframe searched for (or at the end),
whether they were found at once or in the worker meanwhile. Where the worker has not
finished a keyframe's searches by then, the mapping process takes the last of them itself
while the worker goes on from the first (``_Claims``), each search made by one of the two.
Poses are (x_m, y_m, theta_rad) in a submap's frame, that of its first keyframe.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from segloc_cli.config import LocalizeParams
from segloc_cli.geometry import Pose2

if TYPE_CHECKING:
    from segloc_cli.method.localize import Localizer


@dataclass(frozen=True)
class LoopQuery:
    """A search of a keyframe in submap ``submap`` around ``guess`` (3,), with ``params``
    (its square and heading window)."""

    submap: int
    guess: np.ndarray
    params: LocalizeParams


@dataclass(frozen=True)
class LoopFind:
    """What a search found: the pose (3,; NaN where nothing), the verdict and the share of
    the points on the submap there."""

    pose: np.ndarray
    status: str
    inlier_ratio: float


class _Submaps:
    """The submaps' segments, and a localizer on each, made on its first search."""

    def __init__(self) -> None:
        self.segments: dict[int, np.ndarray] = {}
        self.localizers: dict[int, Localizer] = {}

    def add(self, index: int, segments: np.ndarray) -> None:
        """Submap ``index``'s segments, new or fused again (its search is then made anew)."""
        self.segments[index] = segments
        self.localizers.pop(index, None)

    def search(
        self, local_map: np.ndarray, points: np.ndarray, queries: list[LoopQuery]
    ) -> list[LoopFind]:
        """Each query's find of the keyframe (its local map (N, 4) and points (P, 2), robot
        frame)."""
        return [self.search_one(local_map, points, query) for query in queries]

    def search_one(self, local_map: np.ndarray, points: np.ndarray, query: LoopQuery) -> LoopFind:
        from segloc_cli.method.localize import Localizer

        if query.submap not in self.localizers:
            self.localizers[query.submap] = Localizer.on_map(
                self.segments[query.submap], query.params
            )
        localizer = self.localizers[query.submap].with_params(query.params)
        est = localizer.localize(local_map, Pose2(*query.guess), points)
        return LoopFind(est.pose.as_array(), est.status, float(est.inlier_ratio))


class _Claims:
    """Which of a keyframe's searches are still to be made, shared by the mapping process
    and the worker: the worker takes them from the first on, the mapping process from the
    last back, so that each is made once."""

    def __init__(self, context) -> None:
        self._ends = context.Array("q", 2)  # the first and one past the last left

    def reset(self, count: int) -> None:
        with self._ends.get_lock():
            self._ends[0], self._ends[1] = 0, count

    def first(self) -> int | None:
        with self._ends.get_lock():
            if self._ends[0] >= self._ends[1]:
                return None
            self._ends[0] += 1
            return self._ends[0] - 1

    def last(self) -> int | None:
        with self._ends.get_lock():
            if self._ends[0] >= self._ends[1]:
                return None
            self._ends[1] -= 1
            return self._ends[1]


def _serve(connection, claims: _Claims) -> None:
    """The worker: takes submaps and searches from ``connection`` until told to stop,
    answering each keyframe's searches with the finds of those it claimed (index, find),
    or the error that stopped it. Ctrl-C reaches the mapping process, which stops it: the
    worker itself ignores it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    submaps = _Submaps()
    while True:
        kind, *message = connection.recv()
        if kind == "submap":
            submaps.add(*message)
        elif kind == "search":
            local_map, points, queries = message
            try:
                finds = []
                while (index := claims.first()) is not None:
                    finds.append((index, submaps.search_one(local_map, points, queries[index])))
                connection.send(("finds", finds))
            except Exception as exc:  # handed to the mapping process, which raises it
                connection.send(("error", f"{type(exc).__name__}: {exc}"))
        else:
            return


class LoopSearcher:
    """Runs the searches of one keyframe at a time (``submit``), in a worker process when
    ``parallel`` (this one making those the worker has not begun when ``collect`` wants
    them), else here; ``collect`` gives the finds of the last one submitted."""

    def __init__(self, parallel: bool) -> None:
        self._submaps = _Submaps()
        """The submaps as this process searches them: all searches, or where it helps the
        worker."""
        self._parallel = parallel
        self._asked: tuple[np.ndarray, np.ndarray, list[LoopQuery]] | None = None
        self._finds: list[LoopFind] | None = None
        if not parallel:
            return
        # Forked, before the mapping starts any thread (gtsam's, numba's): a spawned worker
        # would import the caller's main module again, which a script may not allow.
        context = multiprocessing.get_context("fork")
        self._connection, child = context.Pipe()
        self._claims = _Claims(context)
        self._worker = context.Process(target=_serve, args=(child, self._claims), daemon=True)
        # Forked ignoring Ctrl-C, so that none can reach it before ``_serve`` ignores it.
        main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
        try:
            self._worker.start()
        finally:
            if main and previous is not None:
                signal.signal(signal.SIGINT, previous)
        child.close()

    def add_submap(self, index: int, segments: np.ndarray) -> None:
        self._submaps.add(index, segments)
        if self._parallel:
            self._connection.send(("submap", index, segments))

    def submit(self, local_map: np.ndarray, points: np.ndarray, queries: list[LoopQuery]):
        """Start the ``queries`` of a keyframe (its local map and points, robot frame); the
        finds of the one before must have been collected."""
        if not self._parallel:
            self._finds = self._submaps.search(local_map, points, queries)
            return
        self._claims.reset(len(queries))
        self._connection.send(("search", local_map, points, queries))
        self._asked = (local_map, points, queries)

    def collect(self) -> list[LoopFind]:
        """The finds of the searches last submitted, one per query, in their order."""
        if not self._parallel:
            found, self._finds = self._finds or [], None
            return found
        if self._asked is None:
            return []
        local_map, points, queries = self._asked
        self._asked = None
        finds: list[LoopFind | None] = [None] * len(queries)
        while (index := self._claims.last()) is not None:  # those the worker has not begun
            finds[index] = self._submaps.search_one(local_map, points, queries[index])
        kind, answer = self._connection.recv()
        if kind == "error":
            raise RuntimeError(f"a loop search failed: {answer}")
        for index, find in answer:
            finds[index] = find
        return [find for find in finds if find is not None]

    def close(self) -> None:
        """Stop the worker, if there is one."""
        if self._parallel and self._worker.is_alive():
            self._connection.send(("stop",))
            self._worker.join(timeout=5.0)
            if self._worker.is_alive():
                self._worker.terminate()
