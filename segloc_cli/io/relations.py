"""Reference relations files (``*.relations``), as Kümmerle et al. published them for the
Freiburg and Intel logs: one relation a line, whitespace-separated
``t1 t2 dx dy dz droll dpitch dyaw`` (seconds, metres, radians); ``#`` starts a comment;
blank lines are ignored. The planar metric uses dx, dy and dyaw."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from segloc_cli.errors import InputError
from segloc_cli.estimates import Relations
from segloc_cli.io.files import reading

_RELATION_FIELDS = ("t1", "t2", "dx", "dy", "dz", "droll", "dpitch", "dyaw")


def read_relations(path: str | Path) -> Relations:
    """Read a ``*.relations`` file → ``Relations``.

    Raises ``InputError`` naming the file, and the 1-based line for a line
    without 8 finite numbers; also for an unreadable file or one with no relation.
    """
    path = Path(path)
    with reading(path, "a relations file (t1 t2 dx dy dz droll dpitch dyaw per line)"):
        text = path.read_text(encoding="utf-8-sig")
    rows: list[list[float]] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.split()
        if len(fields) != len(_RELATION_FIELDS):
            raise InputError(
                f"line {number}: expected 8 whitespace-separated values "
                f"'{' '.join(_RELATION_FIELDS)}', got {len(fields)}",
                path=path,
            )
        values = []
        for name, text_value in zip(_RELATION_FIELDS, fields, strict=True):
            try:
                value = float(text_value)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise InputError(
                    f"line {number}: {name} is {text_value!r}; expected a finite number",
                    path=path,
                )
            values.append(value)
        rows.append(values)
    if not rows:
        raise InputError(
            "no relations; expected lines 't1 t2 dx dy dz droll dpitch dyaw'", path=path
        )
    table = np.array(rows, dtype=float)
    return Relations(
        t1_s=table[:, 0].copy(),
        t2_s=table[:, 1].copy(),
        delta=table[:, [2, 3, 7]].copy(),
    )
