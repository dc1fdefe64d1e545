"""Localizing independent scans on several processes, with the same rows as on one.

Scans localized from their own initial guesses (or globally) do not depend
on each other, so blocks of them go to worker processes and the rows come
back in scan order. The workers are forked after the localizer has built
what it shares (R-table, score raster) and compiled its kernels, so each
starts with them rather than building them again. Every row equals the one
a single process gives except ``runtime_ms``, a measured time.
"""

from __future__ import annotations

import multiprocessing
import signal
import weakref
from collections.abc import Iterator, Sequence

from segloc_cli.extract import ExtractParams
from segloc_cli.geometry import Pose2
from segloc_cli.localize import Localizer, ScanMatcher, localize_scans
from segloc_cli.scan import Scan

BLOCK_SCANS = 4
"""Scans per task: small enough to keep both cores busy to the end of a short log."""

_job: tuple | None = None
"""The work of the current run, set before the workers are forked (they inherit it)."""


def _ignore_interrupts() -> None:
    # Ctrl-C reaches every process of the terminal's group; the parent alone handles it.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # The parent may turn SIGTERM into a stop request; a worker must still die of it when
    # the pool is closed.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _localize_block(bounds: tuple[int, int]) -> list[dict]:
    scans, guesses, pose_ids, localizer, extract_params = _job
    start, stop = bounds
    block_guesses = None if guesses is None else guesses[start:stop]
    rows = localize_scans(
        scans[start:stop], block_guesses, pose_ids[start:stop], localizer, extract_params
    )
    return list(rows)


_warmed: weakref.WeakSet = weakref.WeakSet()
"""Localizers already run once in this process (their kernels compiled, their parts built)."""


def _warm_up(localizer: ScanMatcher, scans: Sequence[Scan], guesses, extract_params) -> None:
    """Build the localizer's lazy parts in the parent, so that forked workers share them."""
    if isinstance(localizer, Localizer) and localizer.params.refine is not None:
        if localizer.params.search is not None or guesses is None:
            localizer.hypothesis_search  # noqa: B018 (built on first access)
    if scans and localizer not in _warmed:
        first = None if guesses is None else guesses[:1]
        list(localize_scans(scans[:1], first, [0], localizer, extract_params))
        _warmed.add(localizer)


def localize_scans_parallel(
    scans: Sequence[Scan],
    initial_poses: Sequence[Pose2] | None,
    pose_ids: Sequence[int],
    localizer: ScanMatcher,
    jobs: int,
    extract_params: ExtractParams | None = None,
) -> Iterator[dict]:
    """``localize_scans`` spread over ``jobs`` processes; rows are yielded in scan order.

    With ``jobs`` 1 (or a single scan) this is ``localize_scans`` itself.
    """
    if jobs <= 1 or len(scans) <= 1:
        yield from localize_scans(scans, initial_poses, pose_ids, localizer, extract_params)
        return
    global _job
    _warm_up(localizer, scans, initial_poses, extract_params)
    blocks = [(i, min(i + BLOCK_SCANS, len(scans))) for i in range(0, len(scans), BLOCK_SCANS)]
    _job = (list(scans), initial_poses, list(pose_ids), localizer, extract_params)
    try:
        context = multiprocessing.get_context("fork")
        with context.Pool(jobs, initializer=_ignore_interrupts) as pool:
            for rows in pool.imap(_localize_block, blocks):
                yield from rows
    finally:
        _job = None
