"""The warm-up ``make setup`` runs compiles every kernel, with the types a real run uses.

One subprocess runs ``python -m segloc_cli.runs.warmup`` into an empty numba cache (a
temporary folder, so the normal cache is left alone); every ``@njit`` function of
segloc_cli must then have its index file there. Localizing the hall on that
cache (guided, tracked, with a peer) must add no compiled code: had the warm-up
called a kernel with other argument types (another dtype, layout or integer
width), the first real run would compile it again.

A new kernel that fails the first test sits on a path the warm-up does not
run: run that path in ``segloc_cli.runs.warmup``.

Before the warm-up, the same cache gets what a first run's second process compiles
ahead (``--late-stages``): the hypothesis search's and refinement's kernels, and no
extraction; the warm-up after it must load those, not compile them again.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import HALL, SEGLOC

PACKAGE = Path(__file__).resolve().parents[1] / "segloc_cli"
TIMEOUT_S = 600


def njit_functions() -> list[tuple[str, str]]:
    """(module file stem, function name) of every ``@njit`` function in segloc_cli."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.FunctionDef) and any(_is_njit(d) for d in node.decorator_list):
                found.append((path.stem, node.name))
    return found


def _is_njit(decorator: ast.expr) -> bool:
    target = decorator.func if isinstance(decorator, ast.Call) else decorator
    name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
    return name in ("njit", "jit")


def cached(cache_dir: Path, suffix: str) -> set[str]:
    """Names of numba's cache files under ``cache_dir`` ending in ``suffix``."""
    return {path.name for path in cache_dir.rglob(f"*{suffix}")}


def _run(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    done = subprocess.run(args, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stderr[-4000:]
    return done


@pytest.fixture(scope="module")
def warm_cache(tmp_path_factory) -> tuple[Path, dict[str, str], dict[str, float]]:
    """An empty numba cache after ``python -m segloc_cli.runs.warmup --late-stages`` then
    ``python -m segloc_cli.runs.warmup``, the environment that points numba at it, and the
    compiled files the first of them wrote with their modification times."""
    cache_dir = tmp_path_factory.mktemp("numba")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    _run([sys.executable, "-m", "segloc_cli.runs.warmup", "--late-stages"], env)
    ahead = {path.name: path.stat().st_mtime for path in cache_dir.rglob("*.nbc")}
    done = _run([sys.executable, "-m", "segloc_cli.runs.warmup"], env)
    assert len(done.stdout.splitlines()) == 1, done.stdout
    return cache_dir, env, ahead


def test_compiling_ahead_takes_the_search_and_refinement_not_extraction(warm_cache):
    cache_dir, _, ahead = warm_cache
    for kernel in ("search._descend-", "refine._fit-", "refine._gauss_newton-"):
        assert any(name.startswith(kernel) for name in ahead), f"{kernel} not compiled ahead"
    assert not any(name.startswith("extract.") for name in ahead), sorted(ahead)
    # The warm-up after it loaded what was compiled ahead instead of compiling it again.
    now = {path.name: path.stat().st_mtime for path in cache_dir.rglob("*.nbc")}
    assert {name: now[name] for name in ahead} == ahead


def test_the_source_holds_kernels():
    assert len(njit_functions()) >= 10


def test_every_kernel_is_compiled_by_the_warm_up(warm_cache):
    cache_dir, _, _ = warm_cache
    indexed = cached(cache_dir, ".nbi")
    missing = [
        f"{stem}.{name}"
        for stem, name in njit_functions()
        if not any(index.startswith(f"{stem}.{name}-") for index in indexed)
    ]
    assert not missing, f"not compiled by segloc_cli.runs.warmup: {missing}"


@pytest.mark.parametrize("options", [[], ["--track"], ["--method", "icp"]], ids=" ".join)
def test_a_first_localize_after_the_warm_up_compiles_nothing(warm_cache, tmp_path, options):
    cache_dir, env, _ = warm_cache
    before = cached(cache_dir, ".nbc")
    argv = [str(SEGLOC), "localize", str(HALL / "log.mcap"), "--map", str(HALL / "map.json")]
    done = subprocess.run(
        [*argv, *options, "--out", str(tmp_path / "estimates.csv")],
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    assert cached(cache_dir, ".nbc") == before
    assert "compiling segloc's kernels" not in done.stderr
