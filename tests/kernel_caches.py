"""numba caches for the warm-up tests, each made once a session (``made_once``).

``warm_cache`` holds the kernels of the warm-up ``make setup`` runs on an empty cache, with
what it said and which process compiled which kernel: ``make setup`` keeps that record of
its own warm-up (``segloc_cli.runs.warmup_record``, in ``.venv/warm-up``), and where the
record no longer holds (a module edited since, or a warm-up that found kernels cached) the
suite makes one the same way, into an empty folder. ``every_path_record`` is the record
``make kernels`` keeps of ``warmup --all`` (or one made here on a copy of ``warm_cache``);
``later_cache`` holds its kernels less one of ``--global``'s and one of ``--seen-through
drop``'s, after a ``localize --global`` and a ``map build --seen-through drop``.

Each lies in a folder of its own (``NUMBA_CACHE_DIR``) that no run outside the suite reads.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import HALL, SEGLOC, made_once
from numba.core.caching import _CacheLocator

from segloc_cli.runs.warmup_record import (
    CACHE_FOLDER,
    PACKAGE,
    RECORD_FILE,
    holding_record,
)

TIMEOUT_S = 600
WARM_UP = [sys.executable, "-m", "segloc_cli.runs.warmup"]
SETUP_RECORD = Path(sys.prefix) / "warm-up"
"""Where ``make setup`` keeps the record of its warm-up (the Makefile's ``--record``)."""
EVERY_PATH_RECORD = Path(sys.prefix) / "warm-up-all"
"""Where ``make kernels`` keeps the record of ``warmup --all``."""


def cache_env(cache_dir: Path) -> dict[str, str]:
    """This environment, with numba's cache in ``cache_dir``."""
    return dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))


def place_recorded_kernels(record: Path, cache_dir: Path) -> None:
    """Copy the kernels a warm-up's record kept into ``cache_dir`` where numba looks for
    them when ``NUMBA_CACHE_DIR`` names that folder (a folder per module folder)."""
    kept = record / CACHE_FOLDER
    for file in kept.rglob("*.nb[ic]"):
        module_file = PACKAGE / file.parent.relative_to(kept) / "module.py"
        into = cache_dir / _CacheLocator.get_suitable_cache_subpath(str(module_file))
        into.mkdir(parents=True, exist_ok=True)
        shutil.copy2(file, into / file.name)


def cached(cache_dir: Path, suffix: str) -> set[str]:
    """Names of numba's cache files under ``cache_dir`` ending in ``suffix``."""
    return {path.name for path in cache_dir.rglob(f"*{suffix}")}


def run(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    """``args`` run to the end; it must exit 0 (its stderr's tail is the failure's message)."""
    done = subprocess.run(args, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stderr[-4000:]
    return done


def segloc(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    return run([str(SEGLOC), *args], env)


def compiling_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("segloc: compiling")]


def _build_hall_map(out: Path, env: dict[str, str], *options: str) -> subprocess.CompletedProcess:
    mapping = HALL / "mapping"
    return segloc(
        ["map", "build", str(mapping / "log.mcap"), "--survey", str(mapping / "survey.csv"),
         *options, "--out", str(out)],
        env,
    )  # fmt: skip


@pytest.fixture(scope="session")
def warm_cache(tmp_path_factory) -> tuple[Path, dict[str, str], dict]:
    """The kernels of a warm-up on an empty cache, the environment that points numba at
    them, and the warm-up's record (``warmup_record.write_record``): ``make setup``'s own
    where it still holds, else one made here."""

    def make(folder: Path) -> None:
        record = SETUP_RECORD
        if holding_record(record) is None:
            record = folder / "record"
            run([*WARM_UP, "--record", str(record)], cache_env(folder / "empty"))
            shutil.rmtree(folder / "empty")
        place_recorded_kernels(record, folder / "numba")
        shutil.copy2(record / RECORD_FILE, folder / RECORD_FILE)

    folder = made_once(tmp_path_factory, "warm-cache", make)
    record = holding_record(folder)
    assert record is not None, "the warm-up's record does not hold for these sources"
    return folder / "numba", cache_env(folder / "numba"), record


@pytest.fixture(scope="session")
def demo_map(warm_cache, tmp_path_factory) -> Path:
    """The demo's map of the hall, built on the warm cache (which it must leave as it is)."""
    cache_dir, env, *_ = warm_cache

    def make(folder: Path) -> None:
        before = cached(cache_dir, ".nbc")
        built = _build_hall_map(folder / "map.json", env)
        assert cached(cache_dir, ".nbc") == before
        assert not compiling_lines(built.stderr), built.stderr

    return made_once(tmp_path_factory, "demo-map", make) / "map.json"


FIRST_OF_LATER = {
    "--global": "search._collect_parallel",
    "--seen-through": "freespace._seen_through",
}
"""A kernel only ``localize --global``, and one only ``map build --seen-through drop``, uses,
each called from Python (a kernel called only by others is compiled into them): ``later_cache``
leaves them out."""


@pytest.fixture(scope="session")
def later_cache(every_path_folder, demo_map, tmp_path_factory) -> tuple[Path, dict[str, str], str]:
    """Every path's kernels but ``FIRST_OF_LATER``, after a ``localize --global`` (one scan)
    and a ``map build --seen-through drop`` on them, with what they wrote on stderr: each
    compiles what it lacks, as a first one after the warm-up compiles all of its own (in a
    third of the time)."""

    def make(folder: Path) -> None:
        place_recorded_kernels(every_path_folder, folder / "numba")
        for kernel in FIRST_OF_LATER.values():
            left_out = list((folder / "numba").rglob(f"{kernel}-*.nb[ic]"))
            assert left_out, f"no cache files of {kernel}: FIRST_OF_LATER names no kernel"
            for file in left_out:
                file.unlink()
        env = cache_env(folder / "numba")
        searched = segloc(
            ["localize", str(HALL / "log.mcap"), "--map", str(demo_map), "--global",
             "--scans", "1", "--out", str(folder / "global.csv")],
            env,
        )  # fmt: skip
        carved = _build_hall_map(folder / "carved.json", env, "--seen-through", "drop")
        (folder / "stderr.txt").write_text(searched.stderr + carved.stderr, encoding="utf-8")

    folder = made_once(tmp_path_factory, "later-cache", make)
    err = (folder / "stderr.txt").read_text(encoding="utf-8")
    return folder / "numba", cache_env(folder / "numba"), err


@pytest.fixture(scope="session")
def every_path_folder(request, tmp_path_factory) -> Path:
    """The folder of the record of ``warmup --all`` (``warmup_record.write_record``):
    ``make kernels``'s where it still holds, else one made here on a copy of the warm cache
    (asked for only then). It found the first run's kernels cached, so it keeps them all."""
    if holding_record(EVERY_PATH_RECORD, from_empty=False) is not None:
        return EVERY_PATH_RECORD
    cache_dir, *_ = request.getfixturevalue("warm_cache")

    def make(folder: Path) -> None:
        shutil.copytree(cache_dir, folder / "numba")
        run([*WARM_UP, "--all", "--record", str(folder / "record")], cache_env(folder / "numba"))

    folder = made_once(tmp_path_factory, "every-path-record", make) / "record"
    assert holding_record(folder, from_empty=False) is not None, (
        "the record of warmup --all does not hold for these sources"
    )
    return folder


@pytest.fixture(scope="session")
def every_path_record(every_path_folder) -> dict:
    """The record of ``warmup --all`` (``every_path_folder``)."""
    record = holding_record(every_path_folder, from_empty=False)
    assert record is not None
    return record
