"""Compiling segloc's kernels: numba's ``njit``, cached on disk wherever numba can write.

Numba keeps a compiled kernel in ``NUMBA_CACHE_DIR`` if set, else beside its module
(``__pycache__``) or in the platform's user cache folder, and refuses to define a
``cache=True`` kernel when it can write to none of them (a system install, a container run
as another user, a read-only checkout and home). There segloc caches its kernels in a
private folder of its own under the temporary directory (``private_cache_dir``), and the
run that makes it says once where. Where even that cannot be had, the kernels are defined
uncached: every run compiles the ones it uses, which costs time but never the result, and
the first one defined says so once on stderr.

A run says once, at the first kernel it compiles, that it is compiling and about how long
it takes (``watching_compiles``): all of a first run's kernels on an empty cache, or, once
the warm-up has cached those of map build and a default localize, the few an option adds
on its first use (``LaterKernels``: ``--global``, ``--seen-through drop``).

A first run with an empty cache compiles on two cores: when the first kernel is compiled,
a second process starts compiling the hypothesis search's and refinement's kernels into
the cache while this one compiles extraction and the two stages; the localizer waits for
it (``await_compiled``) before its first search, then loads them from the cache instead of
compiling them a second time. The second process names each kernel it has compiled
(``reporting_compiles``), so that the warm-up can count them (``compiled_ahead``).

A global search shares its work among numba's threads (``prange``, one per core by
default; ``NUMBA_NUM_THREADS`` sets how many). They run on numba's own ``workqueue`` layer
unless ``NUMBA_THREADING_LAYER`` names another: unlike GNU OpenMP, it keeps working in
processes forked after a parallel kernel ran (``--jobs`` forks its workers, which use one
thread each: ``one_thread``).
"""

from __future__ import annotations

import functools
import os
import stat
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple

import numba
from numba import njit as _numba_njit
from numba import prange  # noqa: F401  (the kernels take it from here, beside njit)
from numba.core import event
from numba.core.dispatcher import Dispatcher

from segloc_cli.wording import said

if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"  # type: ignore[attr-defined]

_said_uncached = False

PRIVATE_CACHE_PREFIX = "segloc-numba-"
"""The private kernel cache's folder under the temporary directory, followed by the user's id."""

FIRST_COMPILE_S = 30
"""About how long (s) a first ``segloc localize`` on an empty cache spends compiling, with
a second process compiling ahead (measured on the shipped hall on two cores: 27–30 s for
the whole run)."""
UNCACHED_COMPILE_S = 55
"""The same where nothing can be cached, so one process compiles everything (the hall's
default localize: 57–59 s for the whole run)."""


class LaterKernels(NamedTuple):
    """The kernels an option compiles on its first use, beyond those of map build and a
    default localize (which the warm-up compiles): the option as typed, and about how long
    (s) they take to compile on two cores."""

    option: str
    about_s: int


GLOBAL_KERNELS = LaterKernels("--global", 8)
"""The global search's: its parallel bounds and the batches after the first (a first
``--global`` on the shipped hall after the warm-up: 11.4 s, 3.3 s once they are cached)."""
SEEN_THROUGH_KERNELS = LaterKernels("--seen-through drop", 4)
"""The free-space carving of ``map build``: each beam against the map's segments (the
shipped hall's map built with it after the warm-up: 5.9 s, 2.1 s once they are cached)."""

AHEAD_ENV = "SEGLOC_COMPILING_AHEAD"
"""Set in the process that compiles ahead, so that it starts no other."""
AHEAD_MODULE = "segloc_cli.runs.warmup"
AHEAD_COMMAND = [sys.executable, "-m", AHEAD_MODULE, "--late-stages"]
"""The second process of a first run: the warm-up of the later stages alone."""
AHEAD_READY = "ready"
"""The line the process compiling ahead writes once the later stages' kernels are cached."""
AHEAD_COMPILED = "compiled"
"""What starts the line the process compiling ahead writes for each kernel it compiled,
followed by the kernel's name (``kernel_name``)."""
AHEAD_WAIT_S = 120.0
"""The longest a run waits for the process compiling ahead before compiling itself."""

_announced = False
_compiles = 0
"""How many of segloc's kernels this process has compiled while watching."""
_ahead: _Ahead | None = None
_ahead_started = False


def njit(function: Callable | None = None, **options: Any):
    """``numba.njit(**options)``, as a decorator with or without options; with
    ``cache=True`` where numba finds no folder to cache in, uncached (``_say_uncached``)."""
    if function is None:
        return lambda decorated: njit(decorated, **options)
    try:
        return _numba_njit(**options)(function)
    except RuntimeError as exc:
        if not options.get("cache") or "no locator available" not in str(exc):
            raise
    if _cache_privately():
        return _numba_njit(**options)(function)
    _say_uncached()
    return _numba_njit(**{**options, "cache": False})(function)


def private_cache_dir(temp: Path | None = None) -> tuple[Path | None, bool]:
    """segloc's own kernel cache, for a user none of numba's folders is open to:
    ``PRIVATE_CACHE_PREFIX`` and the user's id under ``temp`` (by default the temporary
    directory), made with mode 0700; and whether this call made it. ``None`` where it cannot
    be made or written, or is not a folder of this user's alone (another's, a link, open to
    the group or others): a kernel loaded from there would run as this user."""
    folder = Path(temp or tempfile.gettempdir()) / f"{PRIVATE_CACHE_PREFIX}{os.getuid()}"
    made = False
    try:
        folder.mkdir(mode=0o700)
        made = True
    except FileExistsError:
        pass
    except OSError:
        return None, False
    try:
        found = os.lstat(folder)
    except OSError:
        return None, False
    alone = (
        stat.S_ISDIR(found.st_mode)
        and found.st_uid == os.getuid()
        and not found.st_mode & (stat.S_IRWXG | stat.S_IRWXO)
    )
    if not alone or not os.access(folder, os.W_OK | os.X_OK):
        return None, False
    return folder, made


@functools.cache
def _cache_privately() -> bool:
    """Point numba's cache at ``private_cache_dir`` (once; saying where, if this run made
    it), and whether it is there. Set in numba's config, not the environment, which numba
    would read again and with it drop segloc's default threading layer; a process this one
    starts is given it as ``NUMBA_CACHE_DIR`` (``start_ahead``)."""
    folder, made = private_cache_dir()
    if folder is None:
        return False
    numba.config.CACHE_DIR = str(folder)  # type: ignore[attr-defined]
    if made:
        _say(
            "numba can write no cache beside the segloc_cli package nor in the "
            f"user's cache folder, so segloc caches its compiled kernels in {folder}; "
            "set NUMBA_CACHE_DIR to a writable folder to keep them elsewhere"
        )
    return True


def _say_uncached() -> None:
    global _said_uncached
    if _said_uncached:
        return
    _said_uncached = True
    _say(
        "numba can write no cache for the compiled kernels here (not beside the "
        "segloc_cli package, nor in the user's cache folder, nor in a private folder under "
        f"{tempfile.gettempdir()}), so each run compiles the ones it uses; set "
        "NUMBA_CACHE_DIR to a writable folder to keep them"
    )


def _say(message: str) -> None:
    print(said(message), file=sys.stderr, flush=True)


def loaded_kernels() -> list[Dispatcher]:
    """Every numba kernel defined in the modules of segloc_cli imported so far."""
    kernels = {}
    for name, module in list(sys.modules.items()):
        if name.startswith("segloc_cli.") and module is not None:
            for value in list(vars(module).values()):
                if isinstance(value, Dispatcher) and value.py_func.__module__ == name:
                    kernels[id(value)] = value
    return list(kernels.values())


def kernel_name(kernel: Dispatcher) -> str:
    """``module.function`` of a kernel: ``segloc_cli.method.search._descend``."""
    return f"{kernel.py_func.__module__}.{kernel.py_func.__qualname__}"


def partly_cached() -> bool:
    """Whether this process has loaded any of segloc's kernels from numba's cache: if so, a
    kernel it compiles is one that was not cached yet, not the first of an empty cache."""
    return any(kernel.stats.cache_hits for kernel in loaded_kernels())


def first_compile_notice(partly: bool, later: LaterKernels | None = None) -> str:
    """What a run says at the first kernel it compiles: where nothing can be cached, that it
    compiles every time; on an empty cache (not ``partly`` cached), that it compiles once,
    about how long; else what ``later`` adds, or the kernels that are not cached yet."""
    extra_s = later.about_s if later is not None else 0
    if _said_uncached:
        return (
            f"compiling segloc's kernels about {UNCACHED_COMPILE_S + extra_s} s, in every run "
            "as none can be cached here"
        )
    if not partly:
        return (
            f"compiling segloc's kernels once, about {FIRST_COMPILE_S + extra_s} s; later runs "
            f"load them from numba's cache (`python -m {AHEAD_MODULE}` compiles them ahead)"
        )
    if later is not None:
        return (
            f"compiling the kernels {later.option} uses, once, about {later.about_s} s; later "
            "runs load them from numba's cache"
        )
    return (
        "compiling the kernels of this run that numba's cache does not hold yet, once; later "
        "runs load them from there"
    )


def _segloc_kernel(ev: event.Event) -> Dispatcher | None:
    """The kernel of a ``numba:compile`` event, if it is one of segloc's."""
    dispatcher = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", "")
    return dispatcher if module.startswith("segloc_cli.") else None


class _FirstCompile(event.Listener):
    """Hears numba compile a kernel (not load one from the cache): the first of segloc's
    says what is happening (``notice``), and may start the process that compiles ahead."""

    def __init__(self, ahead: bool, notice: Callable[[bool], str]):
        self.ahead, self.notice = ahead, notice

    def on_start(self, ev: event.Event) -> None:
        global _announced, _compiles
        if _segloc_kernel(ev) is None:
            return
        _compiles += 1
        if _announced:
            return
        _announced = True
        partly = partly_cached()
        if self.ahead and not partly:
            start_ahead()
        message = self.notice(partly)
        if message:
            _say(message)

    def on_end(self, ev: event.Event) -> None:
        pass


@contextmanager
def watching_compiles(
    ahead: bool = False,
    later: LaterKernels | None = None,
    notice: Callable[[bool], str] | None = None,
) -> Iterator[None]:
    """While in the block, at the first kernel this process compiles: say once what
    ``notice(partly_cached())`` returns (nothing for ""), by default ``first_compile_notice``
    with the kernels ``later`` adds; with ``ahead``, on an empty cache, start a second process
    compiling the later stages' kernels then (where they can be cached, and unless this
    process is that one, or already started one)."""
    if os.environ.get(AHEAD_ENV):
        yield
        return
    if notice is None:

        def notice(partly: bool) -> str:
            return first_compile_notice(partly, later)

    with event.install_listener("numba:compile", _FirstCompile(ahead, notice)):
        yield


class _Ahead:
    """The process compiling ahead, and what it has said so far: the kernels it compiled,
    and whether the later stages' are ready (or it ended)."""

    def __init__(self, process: subprocess.Popen):
        self.process = process
        self.ready = threading.Event()
        self.compiled: set[str] = set()
        self.awaited = False
        self.listener_pid = os.getpid()
        """The process whose thread listens: a forked worker inherits no thread."""
        self.listener = threading.Thread(target=self._listen, daemon=True)
        self.listener.start()

    def await_ready(self, timeout_s: float) -> None:
        """Wait (at most ``timeout_s``) for the later stages to be ready, or the process to
        end. A forked worker, which has no thread listening (``--jobs`` forks once the
        parent has waited, unless its first scan did not search), does not wait: it loads
        what is cached and compiles the rest."""
        if os.getpid() == self.listener_pid:
            self.ready.wait(timeout_s)

    def _listen(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            word, _, name = line.strip().partition(" ")
            if word == AHEAD_COMPILED:
                self.compiled.add(name)
            elif word == AHEAD_READY:
                self.ready.set()
        self.ready.set()  # it ended: nothing more to wait for


def start_ahead(*arguments: str) -> None:
    """Start the process compiling ahead (``AHEAD_COMMAND``, and ``arguments``), where
    what it compiles can be cached and unless one was started already. The first kernel
    compiled starts it on an empty cache (``watching_compiles``); the warm-up of every path
    starts it itself, whatever the cache holds."""
    global _ahead, _ahead_started
    if _said_uncached or _ahead_started:
        return  # nothing compiled elsewhere could be loaded here, or it runs already
    _ahead_started = True  # forked workers inherit it and start none
    try:
        process = subprocess.Popen(
            [*AHEAD_COMMAND, *arguments],
            env={**os.environ, **_cache_env(), AHEAD_ENV: "compiling"},
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
    except OSError:
        return  # no second process: this one compiles everything, as without it
    _ahead = _Ahead(process)


def _cache_env() -> dict[str, str]:
    """``NUMBA_CACHE_DIR`` for a process this one starts, where this one caches there."""
    folder = numba.config.CACHE_DIR  # type: ignore[attr-defined]
    return {"NUMBA_CACHE_DIR": folder} if folder else {}


def compiles_heard() -> int:
    """How many of segloc's kernels (specializations, those called by others included) this
    process has compiled in ``watching_compiles`` blocks: where it grew, the time of the work
    in between includes compiling."""
    return _compiles


def one_thread() -> None:
    """Run this process's parallel kernels on one thread: for a worker of several processes,
    which share the cores already."""
    numba.set_num_threads(1)


def started_ahead() -> bool:
    """Whether this process started a second one compiling the later stages ahead."""
    return _ahead_started


def compiled_ahead() -> set[str]:
    """The kernels (``kernel_name``) the process compiling ahead has said it compiled."""
    return set() if _ahead is None else set(_ahead.compiled)


def await_compiled() -> None:
    """Wait (at most ``AHEAD_WAIT_S``) for the process compiling the later stages ahead, if
    one runs, to say they are in the cache (its line ``AHEAD_READY``, or its end), so their
    kernels load from there; nothing to do otherwise, or once waited for."""
    if _ahead is None or _ahead.awaited:
        return
    _ahead.awaited = True
    _ahead.await_ready(AHEAD_WAIT_S)  # if it takes longer, this process compiles them itself


def finish_ahead(timeout_s: float = AHEAD_WAIT_S) -> None:
    """Wait (at most ``timeout_s``) for the process compiling ahead, if one was started, to
    end: for a run that should leave nothing compiling behind it (the warm-up)."""
    if _ahead is None or os.getpid() != _ahead.listener_pid:
        return
    try:
        _ahead.process.wait(timeout_s)
    except subprocess.TimeoutExpired:
        _ahead.process.kill()
        _ahead.process.wait()
    _ahead.listener.join(timeout_s)  # the last of what it said, heard


class _Reporter(event.Listener):
    """In the process compiling ahead: names each of segloc's kernels once it is compiled,
    on its own line (``AHEAD_COMPILED``); stops when nobody reads them any more."""

    def __init__(self) -> None:
        self.heard = True

    def on_start(self, ev: event.Event) -> None:
        pass

    def on_end(self, ev: event.Event) -> None:
        dispatcher = _segloc_kernel(ev)
        if not self.heard or dispatcher is None:
            return
        try:
            print(f"{AHEAD_COMPILED} {kernel_name(dispatcher)}", flush=True)
        except OSError:  # the run that started it has ended: it compiles on, silently
            self.heard = False


@contextmanager
def reporting_compiles() -> Iterator[None]:
    """While in the block, in the process compiling ahead: name each kernel compiled on
    standard output, for the run that started it (``compiled_ahead``)."""
    with event.install_listener("numba:compile", _Reporter()):
        yield


def say_ahead_ready() -> None:
    """In the process compiling ahead: tell the run waiting for it that the later stages'
    kernels are in the cache."""
    try:
        print(AHEAD_READY, flush=True)
    except OSError:
        pass
