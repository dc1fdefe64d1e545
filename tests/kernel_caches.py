"""numba caches compiled from empty for the suite, each made once a session (``made_once``).

Compiling segloc's kernels from an empty cache takes about a minute of CPU, so the tests that
need it share three caches made one from the other:

- ``warm_cache``: what ``python -m segloc_cli.runs.warmup --late-stages`` then
  ``python -m segloc_cli.runs.warmup`` compile (a first run's second process, then the
  warm-up ``make setup`` runs);
- ``later_cache``: a copy of it after a first ``localize --global`` and a first
  ``map build --seen-through drop``;
- ``every_kernel_cache``: a copy of that after ``warmup --all``, which holds every kernel.

They are compiled with numba's bounds checks on (``NUMBA_BOUNDSCHECK=1``), each in a folder
of its own that no run outside the suite reads: which kernels a run compiles, and with which
argument types, does not depend on the checks, and the hostile-input test
(``test_kernels_bounds.py``) can then run every kernel with its checks on without compiling
them all once more. numba keys a cached kernel on its signature and source, not on the
checks, so a checked cache must never be the one a normal run loads.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import HALL, SEGLOC, made_once

TIMEOUT_S = 600
WARM_UP = [sys.executable, "-m", "segloc_cli.runs.warmup"]


def checked_env(cache_dir: Path) -> dict[str, str]:
    """This environment, with numba's bounds checks on and its cache in ``cache_dir``."""
    return dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir), NUMBA_BOUNDSCHECK="1")


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
def warm_cache(tmp_path_factory) -> tuple[Path, dict[str, str], dict[str, float], str, str]:
    """The cache after ``--late-stages`` then the warm-up, the environment that points numba
    at it, the compiled files the first wrote with their modification times, and what the
    warm-up wrote on stdout and stderr."""

    def make(folder: Path) -> None:
        env = checked_env(folder / "numba")
        run([*WARM_UP, "--late-stages"], env)
        ahead = {path.name: path.stat().st_mtime for path in folder.rglob("*.nbc")}
        done = run(WARM_UP, env)
        (folder / "ahead.json").write_text(json.dumps(ahead), encoding="utf-8")
        (folder / "stdout.txt").write_text(done.stdout, encoding="utf-8")
        (folder / "stderr.txt").write_text(done.stderr, encoding="utf-8")

    folder = made_once(tmp_path_factory, "warm-cache", make)
    ahead = json.loads((folder / "ahead.json").read_text(encoding="utf-8"))
    said = [(folder / name).read_text(encoding="utf-8") for name in ("stdout.txt", "stderr.txt")]
    return folder / "numba", checked_env(folder / "numba"), ahead, *said


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


@pytest.fixture(scope="session")
def later_cache(warm_cache, demo_map, tmp_path_factory) -> tuple[Path, dict[str, str], str]:
    """A copy of the warm cache after a first ``localize --global`` (one scan) and a first
    ``map build --seen-through drop``, with what they wrote on stderr."""
    cache_dir, *_ = warm_cache

    def make(folder: Path) -> None:
        shutil.copytree(cache_dir, folder / "numba")
        env = checked_env(folder / "numba")
        searched = segloc(
            ["localize", str(HALL / "log.mcap"), "--map", str(demo_map), "--global",
             "--scans", "1", "--out", str(folder / "global.csv")],
            env,
        )  # fmt: skip
        carved = _build_hall_map(folder / "carved.json", env, "--seen-through", "drop")
        (folder / "stderr.txt").write_text(searched.stderr + carved.stderr, encoding="utf-8")

    folder = made_once(tmp_path_factory, "later-cache", make)
    err = (folder / "stderr.txt").read_text(encoding="utf-8")
    return folder / "numba", checked_env(folder / "numba"), err


@pytest.fixture(scope="session")
def every_kernel_cache(later_cache, tmp_path_factory) -> tuple[Path, str]:
    """A copy of the later cache after ``warmup --all``, and what that wrote on stdout."""
    cache_dir, *_ = later_cache

    def make(folder: Path) -> None:
        shutil.copytree(cache_dir, folder / "numba")
        done = run([*WARM_UP, "--all"], checked_env(folder / "numba"))
        (folder / "stdout.txt").write_text(done.stdout, encoding="utf-8")

    folder = made_once(tmp_path_factory, "every-kernel-cache", make)
    return folder / "numba", (folder / "stdout.txt").read_text(encoding="utf-8")
