"""The record a warm-up keeps of itself (``python -m segloc_cli.runs.warmup --record FOLDER``):
what it said, which kernels it and the process compiling ahead compiled, and a copy of every
kernel it left in numba's cache.

``make setup`` has its warm-up, the one a newcomer's first run depends on, keep one in
``.venv/warm-up``, and ``make kernels`` its warm-up of every path in ``.venv/warm-up-all``.
The suite's warm-up tests (``tests/kernel_caches.py``) check those records, and run the demo
on a copy of the first one's kernels, instead of compiling every kernel a second time. A
record speaks for the sources it was made from: it holds only while segloc's modules, Python
and numba are those it names (``sources_digest``), and for the first, only if the warm-up
started from an empty cache (``holding_record``); otherwise the tests make their own.
"""

from __future__ import annotations

import glob
import hashlib
import json
import shutil
import sys
from pathlib import Path
from typing import Any

import numba

from segloc_cli.jit import compiled_ahead, kernel_name, loaded_kernels
from segloc_cli.runs.warmup_lines import compiled_here

PACKAGE = Path(__file__).resolve().parents[1]
RECORD_FILE = "record.json"
CACHE_FOLDER = "cache"
"""Under a record's folder: the kernels' index and data files, in folders named after their
modules' folders within segloc_cli (``method/search._descend-835.py311.nbi``)."""


def sources_digest() -> str:
    """A digest of what a compiled kernel depends on: every module of segloc_cli (its path
    and bytes), Python's version and numba's."""
    digest = hashlib.sha256(f"{sys.version}\n{numba.__version__}\n".encode())
    for path in sorted(PACKAGE.rglob("*.py")):
        digest.update(path.relative_to(PACKAGE).as_posix().encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


def write_record(folder: Path, notice: str, closing: str, partly: bool) -> None:
    """Keep in ``folder`` (replacing what it held) the record of the warm-up that has just
    run in this process: the line it said when it started compiling (``notice``, "" if it
    compiled nothing), its closing line, whether some kernels were cached before it started
    (``partly``), and a copy of the cache files of its kernels. From an empty cache those
    are the kernels it or the process compiling ahead compiled; otherwise every kernel the
    cache holds, as a kernel loaded from the cache does not say which kernels it calls."""
    shutil.rmtree(folder, ignore_errors=True)
    here, ahead = compiled_here(), compiled_ahead()
    from_empty = _from_empty(partly, here | ahead)
    kept = []
    for kernel in loaded_kernels():
        name = kernel_name(kernel)
        # numba has no public name for a kernel's index file
        index = Path(kernel._cache._cache_file._index_path)  # type: ignore[attr-defined]
        if not index.is_file() or (from_empty and not (kernel.overloads or name in ahead)):
            continue  # on an empty cache, a file of a kernel this run did not use is stale
        module_folder = Path(kernel.py_func.__code__.co_filename).resolve().parent
        into = folder / CACHE_FOLDER / module_folder.relative_to(PACKAGE)
        into.mkdir(parents=True, exist_ok=True)
        stem = glob.escape(index.name.removesuffix(".nbi"))
        for file in index.parent.glob(f"{stem}.*"):
            shutil.copy2(file, into / file.name)
        kept.append(name)
    record = {
        "sources": sources_digest(),
        "notice": notice,
        "closing": closing,
        "partly": partly,
        "compiled_here": sorted(here),
        "compiled_ahead": sorted(ahead),
        "kernels": sorted(kept),
    }
    (folder / RECORD_FILE).write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")


def holding_record(folder: Path, from_empty: bool = True) -> dict[str, Any] | None:
    """The record kept in ``folder``, if there is one, made from the sources as they are
    now (with ``from_empty``, by a warm-up that started from an empty cache); None
    otherwise."""
    try:
        record = json.loads((folder / RECORD_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if record.get("sources") != sources_digest():
        return None
    compiled = {*record.get("compiled_here", ()), *record.get("compiled_ahead", ())}
    if from_empty and not _from_empty(record.get("partly", True), compiled):
        return None
    return record


def _from_empty(partly: bool, compiled: set[str]) -> bool:
    """Whether a warm-up started from an empty cache: it found no kernel cached before its
    first compile (``partly``) and compiled some (``compiled``, in either process)."""
    return not partly and bool(compiled)
