"""The warm-up ``make setup`` runs compiles the kernels of ``make demo`` and of a first default
``localize``, with the types a real run uses; ``--all`` (``make test``) compiles every other.

The warm-up checked is ``make setup``'s own, on the empty cache of a fresh install: it keeps
a record of what it said and compiled and a copy of its kernels (``warmup_record``); where
that record no longer holds for the sources, the suite runs the same warm-up into an empty
folder (``kernel_caches.py``). It says when it starts compiling how many kernels it
compiles, and ends with one line on stdout; the cache then holds that many kernels. The
demo's commands (``map build`` with a survey, a default ``localize``) on a copy of those
kernels, and ``--track``, ``--no-refine`` and a peer, which use no other kernel, must add no
compiled code: had the warm-up called a kernel with other argument types (another dtype,
layout or integer width), or left one out, the first real run would compile it.

A first ``--global`` or ``--seen-through drop`` after it compiles the kernels of its own,
says so in one line and finishes (checked on a cache that lacks one kernel of each).
``--all`` then compiles whatever is left: every ``@njit`` function of segloc_cli must have
its index file in the cache. A new kernel that fails that test sits on a path the warm-up
does not run: run that path in ``segloc_cli.runs.warmup`` (in ``warm_up`` itself when a
default localize or the demo reaches it).

On an empty cache the warm-up has a second process compile the hypothesis search's and
refinement's kernels ahead, and no extraction; the warm-up loads those instead of compiling
them a second time.
"""

from __future__ import annotations

import ast
import json
from pathlib import Path

from conftest import HALL
from kernel_caches import cached, compiling_lines
from test_cli import run_in_turn

from segloc_cli.jit import GLOBAL_KERNELS, SEEN_THROUGH_KERNELS
from segloc_cli.runs.warmup import FIRST_RUN_KERNELS

PACKAGE = Path(__file__).resolve().parents[1] / "segloc_cli"


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


def cached_kernels(cache_dir: Path) -> set[str]:
    """``stem.function`` of every kernel with an index file under ``cache_dir``."""
    return {name.rsplit("-", 1)[0] for name in cached(cache_dir, ".nbi")}


def test_compiling_ahead_takes_the_search_and_refinement_not_extraction(warm_cache):
    _, _, record = warm_cache
    ahead, here = set(record["compiled_ahead"]), set(record["compiled_here"])
    for kernel in ("search._descend", "refine._fit", "refine._gauss_newton"):
        assert f"segloc_cli.method.{kernel}" in ahead, f"{kernel} not compiled ahead"
        # The warm-up loaded what was compiled ahead instead of compiling it again.
        assert f"segloc_cli.method.{kernel}" not in here, f"{kernel} compiled twice"
    assert not any(name.startswith("segloc_cli.method.extract.") for name in ahead), ahead


def test_the_source_holds_kernels():
    assert len(njit_functions()) >= 10


def test_the_warm_up_compiles_the_first_runs_kernels_and_says_how_many(warm_cache):
    cache_dir, _, record = warm_cache
    assert record["closing"].startswith("segloc warm-up: map build and a default localize run")
    assert record["closing"].endswith(f"; {FIRST_RUN_KERNELS} numba kernels compiled, "
                                      f"{len(record['compiled_here'])} by this process and "
                                      f"{FIRST_RUN_KERNELS - len(record['compiled_here'])} by "
                                      "a second one")  # fmt: skip
    kernels = cached_kernels(cache_dir)
    assert len(kernels) == FIRST_RUN_KERNELS, (
        f"the warm-up cached {len(kernels)} kernels; update runs.warmup.FIRST_RUN_KERNELS "
        "(and the README's count) if a default localize or map build now uses another number"
    )
    # Every stage of a default localize, and map build's extraction.
    for kernel in ("extract._extract", "align._votes", "overlap._search_kernel",
                   "search._descend", "refine._fit", "freespace._crossed"):  # fmt: skip
        assert kernel in kernels
    # Not those of the options left to their first use.
    assert not {"search._bound_headings_parallel", "freespace._seen_through"} & kernels
    assert record["notice"].startswith(f"warm-up: compiling the {FIRST_RUN_KERNELS} kernels")


FIRST_RUNS = [[], ["--track"], ["--no-refine"], ["--method", "icp"]]
"""The options of a first ``localize`` that the warm-up must leave nothing to compile for."""


def test_the_demo_and_a_first_localize_after_the_warm_up_compile_nothing(
    warm_cache, demo_map, tmp_path
):
    """Each localize of ``FIRST_RUNS`` in turn, in one fresh process: a kernel that the
    warm-up left out, or compiled for other argument types, would be compiled there (and
    cached) by the first run that calls it."""
    cache_dir, env, *_ = warm_cache
    before = cached(cache_dir, ".nbc")
    runs = {
        " ".join(options) or "default": ["localize", str(HALL / "log.mcap"), "--map",
                                         str(demo_map), *options,
                                         "--out", str(tmp_path / f"estimates-{i}.csv")]
        for i, options in enumerate(FIRST_RUNS)
    }  # fmt: skip
    said, _ = run_in_turn(runs, env=env)
    assert cached(cache_dir, ".nbc") == before
    assert list(said) == list(runs)
    for name, result in said.items():
        assert result.code == 0, f"localize {name}: {result.err}"
        assert not compiling_lines(result.err), f"localize {name}: {result.err}"


def test_a_first_global_or_seen_through_says_it_compiles_its_kernels_once(later_cache):
    _, _, err = later_cache
    said = compiling_lines(err)
    assert said == [
        f"segloc: compiling the kernels {later.option} uses, once, about {later.about_s} s; "
        "later runs load them from numba's cache"
        for later in (GLOBAL_KERNELS, SEEN_THROUGH_KERNELS)
    ], err


def test_every_kernel_is_compiled_by_the_warm_up_of_every_path(every_path_record):
    assert every_path_record["closing"].startswith(
        "segloc warm-up: map build (and --seen-through drop)"
    )
    cached = {".".join(name.split(".")[-2:]) for name in every_path_record["kernels"]}
    missing = [
        f"{stem}.{name}" for stem, name in njit_functions() if f"{stem}.{name}" not in cached
    ]
    assert not missing, f"not compiled by segloc_cli.runs.warmup --all: {missing}"


def test_the_warm_ups_lines_say_what_it_compiles_and_who_compiled_it(monkeypatch):
    from segloc_cli.runs import warmup_lines

    count = warmup_lines.CompileCount("map build", 7, 40)
    assert (
        count.notice(False)
        == "warm-up: compiling the 7 kernels of map build, about 40 s on 2 cores"
    )
    assert count.notice(True).startswith("warm-up: compiling those of the 7 kernels of map build")
    assert warmup_lines.CompileCount("map build", 7, 40, quiet=True).notice(False) == ""
    monkeypatch.setattr(warmup_lines, "compiled_here", lambda: {"a", "b"})
    monkeypatch.setattr(warmup_lines, "compiled_ahead", lambda: {"b", "c"})
    assert warmup_lines.closing_line("it", 1.5, False) == (
        "segloc warm-up: it run on a simulated room in 1.5 s; 3 numba kernels compiled, 2 by this "
        "process and 1 by a second one"
    )
    monkeypatch.setattr(warmup_lines, "compiled_ahead", set)
    assert warmup_lines.closing_line("it", 2.0, True).endswith(
        "2 numba kernels compiled, the others were in numba's cache"
    )
    monkeypatch.setattr(warmup_lines, "compiled_here", set)
    assert warmup_lines.closing_line("it", 2.0, True).endswith("; all were cached")


def test_a_record_holds_only_for_the_sources_it_was_made_from(tmp_path):
    from segloc_cli.runs.warmup_record import RECORD_FILE, holding_record, sources_digest

    def kept(**fields) -> Path:
        folder = tmp_path / str(len(list(tmp_path.iterdir())))
        folder.mkdir()
        record = {"sources": sources_digest(), "partly": False, "compiled_here": ["k"]}
        (folder / RECORD_FILE).write_text(json.dumps(record | fields), encoding="utf-8")
        return folder

    assert holding_record(kept())["compiled_here"] == ["k"]
    assert holding_record(kept(sources="0" * 64)) is None  # a module edited since
    assert holding_record(tmp_path / "none") is None
    # A warm-up that found kernels cached, or compiled none, started from no empty cache.
    assert holding_record(kept(partly=True)) is None
    assert holding_record(kept(compiled_here=[])) is None
    assert holding_record(kept(partly=True), from_empty=False) is not None
