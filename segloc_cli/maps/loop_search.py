"""Where segment SLAM's loop searches run: in the mapping process, or beside it in a worker
process that holds the submaps, so that the front end maps on while older submaps are
searched (``LoopSearcher``).

The answers do not depend on which: a keyframe's searches are handed over when it is
searched for, and their answers taken in at the next keyframe searched for (or at the end),
whether they were found at once or in the worker meanwhile. Poses are (x_m, y_m, theta_rad)
in a submap's frame, that of its first keyframe.
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
        self.segments[index] = segments

    def search(
        self, local_map: np.ndarray, points: np.ndarray, queries: list[LoopQuery]
    ) -> list[LoopFind]:
        """Each query's find of the keyframe (its local map (N, 4) and points (P, 2), robot
        frame)."""
        from segloc_cli.method.localize import Localizer

        finds = []
        for query in queries:
            if query.submap not in self.localizers:
                self.localizers[query.submap] = Localizer.on_map(
                    self.segments[query.submap], query.params
                )
            localizer = self.localizers[query.submap].with_params(query.params)
            est = localizer.localize(local_map, Pose2(*query.guess), points)
            finds.append(LoopFind(est.pose.as_array(), est.status, float(est.inlier_ratio)))
        return finds


def _serve(connection) -> None:
    """The worker: takes submaps and searches from ``connection`` until told to stop,
    answering each search with its finds (or the error that stopped it). Ctrl-C reaches
    the mapping process, which stops it: the worker itself ignores it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    submaps = _Submaps()
    while True:
        kind, *message = connection.recv()
        if kind == "submap":
            submaps.add(*message)
        elif kind == "search":
            try:
                connection.send(("finds", submaps.search(*message)))
            except Exception as exc:  # handed to the mapping process, which raises it
                connection.send(("error", f"{type(exc).__name__}: {exc}"))
        else:
            return


class LoopSearcher:
    """Runs the searches of one keyframe at a time (``submit``), in a worker process when
    ``parallel``, else here; ``collect`` gives the finds of the last one submitted."""

    def __init__(self, parallel: bool) -> None:
        self._submaps: _Submaps | None = None
        self._waiting = False
        self._finds: list[LoopFind] | None = None
        if not parallel:
            self._submaps = _Submaps()
            return
        # Forked, before the mapping starts any thread (gtsam's, numba's): a spawned worker
        # would import the caller's main module again, which a script may not allow.
        context = multiprocessing.get_context("fork")
        self._connection, child = context.Pipe()
        self._worker = context.Process(target=_serve, args=(child,), daemon=True)
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
        if self._submaps is not None:
            self._submaps.add(index, segments)
        else:
            self._connection.send(("submap", index, segments))

    def submit(self, local_map: np.ndarray, points: np.ndarray, queries: list[LoopQuery]):
        """Start the ``queries`` of a keyframe (its local map and points, robot frame); the
        finds of the one before must have been collected."""
        if self._submaps is not None:
            self._finds = self._submaps.search(local_map, points, queries)
        else:
            self._connection.send(("search", local_map, points, queries))
            self._waiting = True

    def collect(self) -> list[LoopFind]:
        """The finds of the searches last submitted, one per query, in their order."""
        if self._submaps is not None:
            finds, self._finds = self._finds or [], None
            return finds
        if not self._waiting:
            return []
        self._waiting = False
        kind, answer = self._connection.recv()
        if kind == "error":
            raise RuntimeError(f"a loop search failed: {answer}")
        return answer

    def close(self) -> None:
        """Stop the worker, if there is one."""
        if self._submaps is None and self._worker.is_alive():
            self._connection.send(("stop",))
            self._worker.join(timeout=5.0)
            if self._worker.is_alive():
                self._worker.terminate()
