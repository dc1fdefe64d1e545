"""Opening a user's file: every way it can fail becomes one ``InputError`` naming it."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from segloc_cli.errors import InputError


@contextmanager
def reading(path: Path, expected: str) -> Iterator[None]:
    """Turn OS and decoding errors raised inside the block into ``InputError``.

    ``expected`` names what the file should be ("a JSON map or world", ...).
    """
    try:
        yield
    except FileNotFoundError:
        raise InputError("file not found; check the path", path=path) from None
    except IsADirectoryError:
        raise InputError(f"is a directory, expected {expected}", path=path) from None
    except UnicodeDecodeError:
        raise InputError(f"not a text file; expected {expected}", path=path) from None
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror})", path=path) from None
