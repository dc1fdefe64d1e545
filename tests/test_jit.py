"""``jit``: a run says once that it compiles, and about how long: all of a first run's
kernels on an empty cache, or those an option adds once the rest are cached; a first run
has a second process compile the later stages ahead, waiting for its word before it needs
them, and hears which kernels it compiled.

The kernels compiled here are tiny functions of this file, named into ``segloc_cli`` (the
watch hears segloc's kernels only); the second process is a stand-in that answers as the
warm-up's ``--late-stages`` does, so nothing here compiles segloc's own kernels.
"""

from __future__ import annotations

import stat
import sys
import threading
import time

import pytest
from numba import njit

from segloc_cli import jit


def fresh_kernel(module: str = "segloc_cli.stand_in"):
    """A kernel not compiled yet (no cache), seen as defined in ``module``."""

    def add_one(x):
        return x + 1

    add_one.__module__ = module
    return njit(add_one)


@pytest.fixture
def first_run(monkeypatch):
    """A process that has said nothing, started no second process yet and loaded nothing
    from the cache (an empty cache)."""
    monkeypatch.setattr(jit, "_announced", False)
    monkeypatch.setattr(jit, "_ahead_started", False)
    monkeypatch.setattr(jit, "_ahead", None)
    monkeypatch.setattr(jit, "_said_uncached", False)
    monkeypatch.setattr(jit, "partly_cached", lambda: False)
    monkeypatch.delenv(jit.AHEAD_ENV, raising=False)


def test_the_first_kernel_compiled_is_said_once(first_run, capsys):
    with jit.watching_compiles():
        fresh_kernel()(1)
        fresh_kernel()(2)
    err = capsys.readouterr().err
    assert err.count("segloc: compiling segloc's kernels once") == 1
    # Outside the block, or for a kernel not segloc's, nothing is said.
    jit._announced = False
    fresh_kernel()(3)
    with jit.watching_compiles():
        fresh_kernel("elsewhere")(4)
    assert capsys.readouterr().err == ""


def test_once_some_kernels_are_cached_a_run_says_what_it_compiles_and_starts_no_other(
    first_run, monkeypatch, capsys
):
    monkeypatch.setattr(jit, "partly_cached", lambda: True)
    monkeypatch.setattr(jit, "AHEAD_COMMAND", [sys.executable, "-c", "print('ready')"])
    with jit.watching_compiles(ahead=True, later=jit.GLOBAL_KERNELS):
        fresh_kernel()(1)
    assert not jit.started_ahead()
    option, about_s = jit.GLOBAL_KERNELS
    assert capsys.readouterr().err == (
        f"segloc: compiling the kernels {option} uses, once, about {about_s} s; later runs "
        "load them from numba's cache\n"
    )
    jit._announced = False
    with jit.watching_compiles():
        fresh_kernel()(2)
    assert "numba's cache does not hold yet, once" in capsys.readouterr().err
    # On an empty cache, the option's kernels add to the first run's.
    jit._announced = False
    monkeypatch.setattr(jit, "partly_cached", lambda: False)
    with jit.watching_compiles(later=jit.SEEN_THROUGH_KERNELS):
        fresh_kernel()(3)
    total_s = jit.FIRST_COMPILE_S + jit.SEEN_THROUGH_KERNELS.about_s
    assert f"compiling segloc's kernels once, about {total_s} s;" in capsys.readouterr().err


def test_a_run_can_say_its_own_line_or_none(first_run, capsys):
    heard = []

    def notice(partly: bool) -> str:
        heard.append(partly)
        return "warm-up: compiling"

    with jit.watching_compiles(notice=notice):
        fresh_kernel()(1)
    assert heard == [False] and capsys.readouterr().err == "segloc: warm-up: compiling\n"
    jit._announced = False
    with jit.watching_compiles(notice=lambda partly: ""):
        fresh_kernel()(2)
    assert capsys.readouterr().err == ""


def test_compiles_are_counted_so_that_timings_can_leave_them_out(first_run):
    before = jit.compiles_heard()
    with jit.watching_compiles(notice=lambda partly: ""):
        fresh_kernel()(1)
        fresh_kernel("elsewhere")(1)  # not segloc's
    assert jit.compiles_heard() == before + 1


def test_the_run_waits_for_the_ready_line_not_for_the_end(first_run, monkeypatch):
    # The stand-in names what it compiled and says it is ready, then works on for a long
    # while, as the warm-up does.
    script = (
        "import time; print('compiled segloc_cli.method.search._descend', flush=True); "
        "print('ready', flush=True); time.sleep(30)"
    )
    monkeypatch.setattr(jit, "AHEAD_COMMAND", [sys.executable, "-c", script])
    with jit.watching_compiles(ahead=True):
        fresh_kernel()(1)
        assert jit._ahead is not None and jit.started_ahead()
        started = jit._ahead.process
        t0 = time.monotonic()
        jit.await_compiled()
        waited_s = time.monotonic() - t0
    try:
        assert started.poll() is None  # still working, not awaited
        assert waited_s < jit.AHEAD_WAIT_S
        assert jit.compiled_ahead() == {"segloc_cli.method.search._descend"}
        t0 = time.monotonic()
        jit.await_compiled()  # waited for once: not again
        # A forked worker (another process than the one listening) does not wait at all.
        monkeypatch.setattr(jit._ahead, "awaited", False)
        monkeypatch.setattr(jit._ahead, "ready", threading.Event())
        monkeypatch.setattr(jit._ahead, "listener_pid", -1)
        jit.await_compiled()
        assert time.monotonic() - t0 < 1.0
    finally:
        started.kill()
        started.wait()
    # Once per process: a second first compile starts no other.
    with jit.watching_compiles(ahead=True):
        jit._announced = False
        fresh_kernel()(2)
    assert jit._ahead.process is started


def test_a_run_can_wait_for_the_second_process_to_end(first_run, monkeypatch):
    script = "import time; print('ready', flush=True); time.sleep(0.5)"
    monkeypatch.setattr(jit, "AHEAD_COMMAND", [sys.executable, "-c", script])
    jit.finish_ahead()  # none started: nothing to wait for
    with jit.watching_compiles(ahead=True):
        fresh_kernel()(1)
    jit.finish_ahead()
    assert jit._ahead is not None and jit._ahead.process.returncode == 0


def test_the_warm_up_can_start_the_second_process_itself_with_its_arguments(first_run, monkeypatch):
    script = "import sys; print('compiled segloc_cli.given' + sys.argv[-1], flush=True)"
    monkeypatch.setattr(jit, "AHEAD_COMMAND", [sys.executable, "-c", script])
    jit.start_ahead("--all")
    jit.start_ahead("--other")  # one a process: started already
    jit.finish_ahead()
    assert jit.compiled_ahead() == {"segloc_cli.given--all"}


def test_no_second_process_where_nothing_can_be_cached_or_in_the_second_process(
    first_run, monkeypatch, capsys
):
    monkeypatch.setattr(jit, "AHEAD_COMMAND", [sys.executable, "-c", "print('ready')"])
    monkeypatch.setattr(jit, "_said_uncached", True)
    with jit.watching_compiles(ahead=True):
        fresh_kernel()(1)
    assert jit._ahead is None and not jit.started_ahead()
    assert f"about {jit.UNCACHED_COMPILE_S} s, in every run" in capsys.readouterr().err
    monkeypatch.setattr(jit, "_said_uncached", False)
    monkeypatch.setattr(jit, "_announced", False)
    monkeypatch.setenv(jit.AHEAD_ENV, "compiling")
    with jit.watching_compiles(ahead=True):
        fresh_kernel()(2)
    assert jit._ahead is None and capsys.readouterr().err == ""
    jit.await_compiled()  # nothing to wait for


def test_compile_times_list_what_this_process_compiled_longest_first():
    from segloc_cli.runs.warmup import compile_times

    quick, slower = fresh_kernel(), fresh_kernel("segloc_cli.slower")
    quick(1)
    slower(1)
    slower(1.5)  # a second specialization, listed on its own
    times = compile_times([quick, slower])
    assert len(times) == 3
    assert [seconds for seconds, _ in times] == sorted((s for s, _ in times), reverse=True)
    assert sorted(name for _, name in times) == [
        "segloc_cli.slower.fresh_kernel.<locals>.add_one",
        "segloc_cli.slower.fresh_kernel.<locals>.add_one",
        "segloc_cli.stand_in.fresh_kernel.<locals>.add_one",
    ]
    assert all(seconds > 0 for seconds, _ in times)


def test_compile_times_leave_out_what_was_loaded_from_the_cache():
    # A kernel numba loaded from its cache has no compile metadata: nothing to list.
    from segloc_cli.runs.warmup import compile_times

    class Loaded:
        signatures = (("float64",),)
        py_func = fresh_kernel().py_func

        @staticmethod
        def get_metadata(signature):
            return None

    assert compile_times([Loaded()]) == []


@pytest.fixture
def no_cache_folder(monkeypatch, tmp_path):
    """A process none of numba's cache folders is open to (a stand-in for numba that refuses
    a cached kernel while its cache folder is unset), the temporary directory in
    ``tmp_path``, nothing said or decided yet."""
    import numba

    def stand_in_njit(**options):
        def define(function):
            if options.get("cache") and not numba.config.CACHE_DIR:
                raise RuntimeError("cannot cache function 'f': no locator available for file")
            return options

        return define

    monkeypatch.setattr(jit, "_numba_njit", stand_in_njit)
    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    monkeypatch.setattr(jit.tempfile, "gettempdir", lambda: str(tmp_path))
    monkeypatch.setattr(jit, "_said_uncached", False)
    jit._cache_privately.cache_clear()
    yield tmp_path
    jit._cache_privately.cache_clear()  # decided for this stand-in, not for numba


def test_kernels_numba_cannot_cache_are_cached_in_a_private_folder_said_once(
    no_cache_folder, capsys
):
    assert jit.njit(lambda x: x, cache=True) == {"cache": True}
    assert jit.njit(lambda x: x, cache=True) == {"cache": True}
    assert jit.njit(lambda x: x) == {}
    (folder,) = no_cache_folder.iterdir()
    err = capsys.readouterr().err
    assert err.count(f"segloc caches its compiled kernels in {folder};") == 1
    assert "each run compiles" not in err
    # The process compiling ahead caches there too.
    assert jit._cache_env() == {"NUMBA_CACHE_DIR": str(folder)}


def test_where_no_private_folder_can_be_had_kernels_are_uncached_said_once(
    no_cache_folder, monkeypatch, capsys
):
    monkeypatch.setattr(jit.tempfile, "gettempdir", lambda: str(no_cache_folder / "a file"))
    (no_cache_folder / "a file").write_text("")
    assert jit.njit(lambda x: x, cache=True) == {"cache": False}
    assert jit.njit(lambda x: x, cache=True) == {"cache": False}
    err = capsys.readouterr().err
    assert err.count("so each run compiles the ones it uses") == 1
    assert "caches its compiled kernels" not in err
    assert jit._cache_env() == {}


def test_the_private_cache_folder_is_made_0700_and_used_only_if_this_users_alone(
    tmp_path, monkeypatch
):
    folder, made = jit.private_cache_dir(tmp_path)
    assert made and folder is not None and folder.parent == tmp_path
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert jit.private_cache_dir(tmp_path) == (folder, False)  # found again, not made
    folder.chmod(0o750)  # open to the group
    assert jit.private_cache_dir(tmp_path) == (None, False)
    folder.chmod(0o700)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    for uid, kind in enumerate(("link", "file", "another's"), start=4242):
        monkeypatch.setattr(jit.os, "getuid", lambda uid=uid: uid)
        found = elsewhere / f"{jit.PRIVATE_CACHE_PREFIX}{jit.os.getuid()}"
        if kind == "link":
            found.symlink_to(folder)
        elif kind == "file":
            found.write_text("")
        else:
            found.mkdir(mode=0o700)  # this user's: not the one of that id
        assert jit.private_cache_dir(elsewhere) == (None, False), kind
