"""Users' files: reading them with errors that name them, writing them so no run leaves half a file.

Reading: every way a read can fail becomes one ``InputError`` naming the file.

Writing: a whole-file output (a map, a table, a trajectory) is written to a
temporary file beside the target and renamed over it once complete, so a full
disk, a crash or a kill leaves either the old file or the new one, never a
fragment. Streamed outputs (the estimates of ``localize``, a recording) are
written in place instead, each record flushed as it is made, so that a killed
run keeps every finished record. ``check_output`` runs before any work: it
refuses an existing file without ``--force`` and a folder that is missing or
not writable, so that minutes of work never end in "No such file or directory".
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from segloc_cli.errors import InputError


@contextmanager
def reading(path: Path, expected: str) -> Iterator[None]:
    """Turn OS and decoding errors raised inside the block into ``InputError``.

    ``expected`` names what the file should be ("a JSON map or world", ...). A pipe,
    socket or device is refused before the block runs: reading one could wait forever.
    """
    path = Path(path)
    if path.exists() and not path.is_file() and not path.is_dir():
        raise InputError(
            f"is not a regular file (a pipe, socket or device); expected {expected}", path=path
        )
    try:
        yield
    except FileNotFoundError:
        raise InputError("file not found; check the path", path=path) from None
    except IsADirectoryError:
        raise InputError(f"is a directory, expected {expected}", path=path) from None
    except UnicodeDecodeError:
        raise InputError(f"not a text file; expected {expected}", path=path) from None
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror or exc})", path=path) from None


class OutputError(InputError):
    """An output that cannot be written: exists without --force, no folder, no room, no rights."""


def check_output(path: str | Path, force: bool, option: str = "--out") -> Path:
    """Refuse ``path`` before any work is done unless it can be written.

    Raises ``OutputError`` naming the file when it exists and ``force`` is
    false, when it is a directory, or when its folder is missing or not
    writable. Returns the path.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"is a directory; {option} takes a file path", path=path)
    if path.exists() and not path.is_file():
        raise OutputError(
            f"is not a regular file (a device, pipe or socket); {option} takes a file path",
            path=path,
        )
    if path.exists() and not force:
        raise OutputError(f"file exists; choose another {option} or pass --force", path=path)
    folder = path.parent if str(path.parent) else Path(".")
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder} is a file, not a folder; choose another {option}", path=path)
    if not folder.is_dir():
        raise OutputError(
            f"folder {folder} does not exist; create it or choose another {option}", path=path
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"folder {folder} is not writable; choose another {option}", path=path)
    return path


def check_outputs(
    outputs: Mapping[str, str | Path | None],
    inputs: Iterable[str | Path | None],
    force: bool,
    replaced: Iterable[str] = (),
) -> None:
    """``check_output`` for every output (option name → path, None when not asked for), and
    refuse an output that is one of the ``inputs`` or another output, which writing would
    destroy: ``--force`` overwrites results, never the data they are made from. The outputs
    of the options in ``replaced`` (reports a rerun refreshes) are replaced without
    ``force``.
    """
    named = {option: Path(path) for option, path in outputs.items() if path is not None}
    # An input first: "pass --force" would be the wrong advice for one.
    by_file = {_identity(path): option for option, path in reversed(named.items())}
    for source in (Path(s) for s in inputs if s is not None):
        option = by_file.get(_identity(source))
        if option is not None:
            raise OutputError(f"is an input of this command; choose another {option}", path=source)
    seen: dict[str, str] = {}
    replaced = set(replaced)
    for option, path in named.items():
        check_output(path, force or option in replaced, option)
        key = _identity(path)
        if key in seen:
            raise OutputError(f"{seen[key]} and {option} name the same file", path=path)
        seen[key] = option


def check_appended(
    path: str | Path,
    option: str,
    outputs: Mapping[str, str | Path | None],
    inputs: Iterable[str | Path | None],
) -> Path:
    """Refuse, before any work, a file a run appends to (named by ``option``): one that is
    one of the ``inputs`` or another of the run's ``outputs`` (as ``check_outputs`` takes
    them), is not a regular file (a pipe could block the run forever, a device take
    nothing), or cannot be written (the file read-only, its folder missing or not writable).
    Raises ``OutputError`` naming the file; returns the path. An existing file is no reason
    to refuse: appending keeps what it holds."""
    path = Path(path)
    key = _identity(path)
    for source in (Path(s) for s in inputs if s is not None):
        if _identity(source) == key:
            raise OutputError(f"is an input of this command; choose another {option}", path=path)
    for other, named in outputs.items():
        if named is not None and _identity(Path(named)) == key:
            raise OutputError(f"{other} and {option} name the same file", path=path)
    check_output(path, force=True, option=option)
    if path.exists() and not os.access(path, os.W_OK):
        raise OutputError(f"is not writable; choose another {option}", path=path)
    return path


def same_file(path: str | Path, other: str | Path) -> bool:
    """Whether ``path`` and ``other`` name one file (through links, hard ones too, ``./``
    or ``..``), whether or not it exists."""
    return _identity(Path(path)) == _identity(Path(other))


def _identity(path: Path) -> str:
    """The file ``path`` names (links, hard ones too, followed), whether or not it exists."""
    try:
        status = path.stat()
    except OSError:
        return str(path.resolve())
    return f"{status.st_dev}:{status.st_ino}"


def writing_error(path: str | Path, exc: OSError) -> OutputError:
    """The one-line error for an OS error met while writing ``path``."""
    return OutputError(f"cannot write file ({exc.strerror or exc})", path=path)


def write_whole(fd: int, data: bytes, size: int) -> None:
    """Write ``data`` to the open file ``fd`` whole (one write may take only part of it), or
    on an ``OSError`` (a full disk) cut the file back to ``size`` bytes, its length before,
    and raise the error: the file never ends in part of ``data``."""
    view = memoryview(data)
    try:
        while view:
            view = view[os.write(fd, view) :]
    except OSError:
        with contextlib.suppress(OSError):
            os.ftruncate(fd, size)
            os.lseek(fd, size, os.SEEK_SET)
        raise


@contextmanager
def writing(path: str | Path) -> Iterator[None]:
    """Turn an ``OSError`` met in the block into the ``OutputError`` naming ``path``: for a
    block writing one of the files of ``atomic_paths``, which cannot tell which one failed."""
    try:
        yield
    except OSError as exc:
        if isinstance(exc, InputError):
            raise
        raise writing_error(path, exc) from None


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path``, renamed to ``path`` when the block ends without error.

    For writers that open files themselves (an MCAP writer, a figure). On any
    error the temporary file is removed and ``path`` is left as it was; an
    ``OSError`` comes out as an ``OutputError`` naming ``path``.
    """
    with atomic_paths(path) as (temporary,):
        yield temporary


@contextmanager
def atomic_paths(*paths: str | Path) -> Iterator[list[Path]]:
    """Temporary paths beside ``paths``, renamed over them together when the block ends
    without error: files that go as a set (an image and the YAML naming it) are replaced
    all or none.

    Every file is complete before any is renamed. A rename that fails puts back the files
    already replaced (the old ones, or none where there was none), so the set is left as
    it was; on any error the temporary files are removed. An ``OSError`` comes out as an
    ``OutputError`` naming the first path, unless the block names the file (``writing``).
    """
    targets = [Path(path) for path in paths]
    temporaries: list[Path] = []
    try:
        for path in targets:
            folder = path.parent if str(path.parent) else Path(".")
            try:
                fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
            except OSError as exc:
                raise writing_error(path, exc) from None
            os.close(fd)
            temporaries.append(Path(name))
        with writing(targets[0]):
            yield temporaries
        _replace_together(targets, temporaries)
    finally:
        for temporary in temporaries:
            with contextlib.suppress(OSError):
                temporary.unlink()


def _replace_together(paths: list[Path], temporaries: list[Path]) -> None:
    """Rename each temporary over its path; when one fails, put back the files replaced
    before it (from a hard link or copy of each old file, made before it is replaced) and
    raise ``OutputError`` naming the one that failed."""
    replaced: list[tuple[Path, Path | None]] = []  # a path replaced, and its old file's copy
    copies: list[Path] = []
    path = paths[0]
    try:
        for i, (path, temporary) in enumerate(zip(paths, temporaries, strict=True)):
            os.chmod(temporary, 0o666 & ~_umask())
            kept = None
            if i < len(paths) - 1 and path.exists():  # nothing follows the last rename
                kept = temporary.with_name(temporary.name + ".old")
                copies.append(kept)
                try:
                    os.link(path, kept)
                except OSError:
                    shutil.copy2(path, kept)
            os.replace(temporary, path)
            replaced.append((path, kept))
    except OSError as exc:
        for done, kept in reversed(replaced):
            with contextlib.suppress(OSError):
                if kept is None:
                    done.unlink()
                else:
                    os.replace(kept, done)
        raise writing_error(path, exc) from None
    finally:
        for kept in copies:
            with contextlib.suppress(OSError):
                kept.unlink()


@contextmanager
def atomic_write(path: str | Path, mode: str = "w") -> Iterator[IO]:
    """Open a temporary file beside ``path`` for writing; rename it to ``path`` on success.

    ``mode`` is "w" (text, UTF-8, line ends as written) or "wb". The data is
    flushed to disk before the rename; see ``atomic_path`` for failures.
    """
    text: dict[str, Any] = {"encoding": "utf-8", "newline": ""} if "b" not in mode else {}
    with atomic_path(path) as temporary, open(temporary, mode, **text) as stream:
        yield stream
        stream.flush()
        os.fsync(stream.fileno())


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` through ``atomic_write``."""
    with atomic_write(path) as stream:
        stream.write(text)


def _umask() -> int:
    # os.umask can only be read by setting it; set it straight back.
    mask = os.umask(0)
    os.umask(mask)
    return mask


def sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes; of a folder (a ROS 2 bag), of each file's path
    relative to it and its bytes, in sorted order, so that a changed, added, removed or
    renamed file changes it."""
    digest = hashlib.sha256()
    if path.is_dir():
        files = sorted(p for p in path.rglob("*") if p.is_file())
        for file in files:
            digest.update(file.relative_to(path).as_posix().encode() + b"\0")
            digest.update(sha256(file).encode())
        return digest.hexdigest()
    with reading(path, "a file to hash"), path.open("rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
