"""What the warm-up (``runs/warmup.py``) says as it runs: when it starts compiling, how many
kernels and about how long (on standard error, at the first kernel compiled, through
``jit.watching_compiles``); the kernels compiled so far, every few seconds (a
``progress.Progress``: a bar on a terminal, plain lines elsewhere); and one closing line on
standard output.

The kernels counted are those this process compiled and those the process compiling ahead
said it compiled (``jit.compiled_ahead``), each once, by name. On an empty cache they are
counted against the number the warm-up compiles; where some were cached already, how many
are left is not known, so the progress gives the count and the rate alone.
"""

from __future__ import annotations

import threading
from types import TracebackType

from segloc_cli.jit import compiled_ahead, kernel_name, loaded_kernels
from segloc_cli.progress import Progress
from segloc_cli.wording import counted

TICK_S = 0.5
"""How often (s) the kernels compiled are counted."""


def compiled_here() -> set[str]:
    """The kernels (``jit.kernel_name``) this process has compiled (not loaded from the
    cache), any of their specializations."""
    return {kernel_name(kernel) for kernel in loaded_kernels() if kernel.stats.cache_misses}


def compiled_by_both() -> set[str]:
    """The kernels this process and the process compiling ahead have compiled."""
    return compiled_here() | compiled_ahead()


class CompileCount:
    """The warm-up's first line and its progress: use as a context manager around the work,
    and hand ``notice`` to ``jit.watching_compiles``. The count is taken every ``TICK_S`` on a
    thread of its own, as the compiling holds the main thread for seconds at a time.

    ``expected`` kernels of ``what`` ("map build and a default localize") take about
    ``about_s`` seconds to compile on an empty cache; ``quiet`` says and shows nothing."""

    def __init__(self, what: str, expected: int, about_s: int, quiet: bool = False):
        self.what, self.expected, self.about_s, self.quiet = what, expected, about_s, quiet
        self.partly = False
        """Whether some kernels were loaded from the cache before the first was compiled."""
        self.said = ""
        """The line said at the first kernel compiled ("" before, or when ``quiet``)."""
        self._progress: Progress | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def notice(self, partly: bool) -> str:
        """The line said at the first kernel compiled (``partly``: some were loaded from the
        cache before it); starts the progress."""
        self.partly = partly
        if self.quiet:
            return ""
        with self._lock:
            total = None if partly else self.expected
            self._progress = Progress("warm-up", total, "kernel")
        if partly:
            self.said = (
                f"warm-up: compiling those of the {self.expected} kernels of {self.what} that "
                "numba's cache does not hold yet"
            )
        else:
            self.said = (
                f"warm-up: compiling the {self.expected} kernels of {self.what}, about "
                f"{self.about_s} s on 2 cores"
            )
        return self.said

    def __enter__(self) -> CompileCount:
        self._thread.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._stop.set()
        self._thread.join()
        self._tick()
        with self._lock:
            if self._progress is not None:
                self._progress.close()

    def _run(self) -> None:
        while not self._stop.wait(TICK_S):
            self._tick()

    def _tick(self) -> None:
        with self._lock:
            progress = self._progress
            if progress is None:
                return
            count = len(compiled_by_both())
            if progress.total is not None:
                count = min(count, progress.total)
            progress.advance(max(0, count - progress.done))


def closing_line(runs: str, took_s: float, partly: bool) -> str:
    """The warm-up's last line: what ran (``runs``), in how long (s), and how many kernels
    were compiled by this process and by the one compiling ahead (``partly``: the others were
    in the cache already)."""
    here = compiled_here()
    ahead = compiled_ahead() - here
    if not here and not ahead:
        done = "all were cached"
    elif ahead:
        done = (
            f"{counted(len(here | ahead), 'numba kernel')} compiled, {len(here)} by this "
            f"process and {len(ahead)} by a second one"
        )
    else:
        done = f"{counted(len(here), 'numba kernel')} compiled"
    if (here or ahead) and partly:
        done += ", the others were in numba's cache"
    return f"segloc warm-up: {runs} run on a simulated room in {took_s:.1f} s; {done}"
