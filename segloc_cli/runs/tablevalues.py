"""A value of a TOML table (a ``--config`` file, a run file, a sweep spec) checked for the
kind of value its key takes, before the key's own check; each refusal is an ``InputError``
naming the file and the key.

``table_value`` checks the kind: one value, a flag true or false, a number not text, text not
a number, a whole number for a count, a path in quotes; ``setting_value`` then checks a
setting's value as its option does (``Setting.checked``), without click.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from segloc_cli.config import Setting, SettingError
from segloc_cli.errors import InputError
from segloc_cli.wording import with_article


@dataclass(frozen=True)
class Takes:
    """What a key takes: a flag, a number (a whole one for a count), a path, one of some
    choices (text or numbers, as ``readings = 1024``), or else text."""

    flag: bool = False
    number: bool = False
    whole: bool = False
    path: bool = False
    choice: bool = False


def table_value(key: str, raw: Any, takes: Takes, path: Path) -> Any:
    """``raw``, the value of ``key`` in the file ``path``, if it is of the kind ``takes``
    says (a choice as text); else an ``InputError`` naming the key."""
    if takes.flag and not isinstance(raw, bool):
        raise InputError(f"key {key!r} is a flag: give true or false, not {raw!r}", path=path)
    if not isinstance(raw, (bool, int, float, str)):
        raise InputError(
            f"key {key!r} takes one value, not {with_article(type(raw).__name__)}", path=path
        )
    if not takes.flag and isinstance(raw, bool):
        raise InputError(f"key {key!r} takes a value, not {str(raw).lower()}", path=path)
    _check_kind(key, raw, takes, path)
    if takes.whole and isinstance(raw, float) and not raw.is_integer():
        raise InputError(f"key {key!r} takes a whole number, not {raw!r}", path=path)
    if takes.path and (not isinstance(raw, str) or not raw):
        raise InputError(f"key {key!r} takes a path in quotes, not {raw!r}", path=path)
    return str(raw) if takes.choice else raw


def _check_kind(key: str, raw: Any, takes: Takes, path: Path) -> None:
    """Refuse a value of the wrong kind: text for a number (``"1.5"``), a number for text (a
    layer named 0 is written ``"0"``); a choice takes either, as its values may be numbers
    (``readings = 1024``)."""
    if takes.flag or takes.path or takes.choice:
        return
    if takes.number and isinstance(raw, str):
        raise InputError(f"key {key!r} takes a number, not the text {raw!r}", path=path)
    if not takes.number and not isinstance(raw, str):
        raise InputError(f"key {key!r} takes text in quotes, not {raw!r}", path=path)


def setting_value(setting: Setting, raw: Any, path: Path) -> Any:
    """``raw``, the value of ``setting`` in the file ``path``, as the setting takes it
    (``table_value``, then ``Setting.checked``); else an ``InputError`` naming the key and
    saying why as the command line's option would."""
    numeric = setting.kind in (int, float) and setting.choices is None
    takes = Takes(
        flag=setting.switch,
        number=numeric,
        whole=numeric and setting.kind is int,
        choice=setting.choices is not None,
    )
    value = table_value(setting.key, raw, takes, path)
    try:
        return setting.checked(value)
    except SettingError as exc:
        key = setting.key
        raise InputError(f"key {key!r}: Invalid value for '--{key}': {exc}", path=path) from None
