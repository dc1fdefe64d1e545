"""GitHub-Markdown pipe tables of text cells, fast enough for a table of every pose of a long
log (tabulate, behind pandas' ``to_markdown``, takes 1.5 s for 16,000 rows; this, 0.1 s).

The layout is tabulate's "pipe" format, which pandas' ``to_markdown`` writes and the tables
segloc printed before this module kept: each column as wide as its widest cell, or as its
header and two spaces; cells padded to that width by the column's alignment, a space on
each side; the separator row marks the alignments with colons.
"""

from __future__ import annotations

from collections.abc import Sequence

ALIGNMENTS = ("left", "right", "center")


def _padded(text: str, width: int, align: str) -> str:
    if align == "right":
        return text.rjust(width)
    if align == "center":
        return f"{text:^{width}}"
    return text.ljust(width)


def _rule(width: int, align: str) -> str:
    """The separator row's cell of a column ``width`` wide (its padding included)."""
    if align == "right":
        return "-" * (width - 1) + ":"
    if align == "center":
        return ":" + "-" * (width - 2) + ":"
    return ":" + "-" * (width - 1)


def cell(text: str) -> str:
    """``text`` as a pipe table's cell: each ``|`` escaped (``\\|``), which would end it."""
    return text.replace("|", "\\|")


def pipe_table(headers: Sequence[str], rows: Sequence[Sequence[str]], aligns: Sequence[str]) -> str:
    """The table of ``headers`` (C,) and ``rows`` (each of C text cells) with the column
    alignments ``aligns`` (C,; each of ``ALIGNMENTS``), without a final newline. A cell is
    written as given: a ``|`` in it must come escaped (``cell``)."""
    if not len(headers) == len(aligns) or any(len(row) != len(headers) for row in rows):
        raise ValueError("every row and the alignments need one entry per header")
    unknown = set(aligns) - set(ALIGNMENTS)
    if unknown:
        raise ValueError(f"unknown alignment {sorted(unknown)[0]!r}; use one of {ALIGNMENTS}")
    widths = [len(header) + 2 for header in headers]
    for row in rows:
        widths = [max(width, len(cell)) for width, cell in zip(widths, row, strict=True)]
    columns = list(zip(widths, aligns, strict=True))

    def line(cells: Sequence[str]) -> str:
        padded = (_padded(cell, w, a) for cell, (w, a) in zip(cells, columns, strict=True))
        return "| " + " | ".join(padded) + " |"

    rule = "|" + "|".join(_rule(w + 2, a) for w, a in columns) + "|"
    return "\n".join([line(headers), rule, *(line(row) for row in rows)])
