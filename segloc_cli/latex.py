"""LaTeX text for the tables segloc writes (``evaluate`` and ``sweep`` with ``--format
latex``): booktabs ``tabular`` environments whose first line says the one package they
need, and whose text is ASCII, so that ``\\documentclass{article}`` with
``\\usepackage{booktabs}`` typesets them under any input encoding."""

from __future__ import annotations

NEEDS = "% needs \\usepackage{booktabs}"
"""The first line of every table: its rules (``\\toprule``, ``\\midrule``, ``\\bottomrule``)
are booktabs'; nothing else beyond the LaTeX kernel is used."""

_ESCAPED = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
}
"""Characters LaTeX reads as commands, as text."""

_SYMBOLS = {
    "°": r"$^\circ$",
    "θ": r"$\theta$",
    "√": r"$\surd$",
    "²": r"$^2$",
    "±": r"$\pm$",
    "×": r"$\times$",
    "≤": r"$\leq$",
    "≥": r"$\geq$",
    "∞": r"$\infty$",
    "−": "-",
    "–": "--",
    "—": "---",
    "µ": r"$\mu$",
    "…": r"\dots{}",
}
"""The symbols segloc's tables hold, in kernel LaTeX."""


def latex_text(text: str) -> str:
    """``text`` as LaTeX text: special characters escaped, symbols (°, θ, √, ², ±, ×, ≤, ∞,
    dashes) written as LaTeX commands."""
    return "".join(_ESCAPED.get(ch) or _SYMBOLS.get(ch) or ch for ch in text)


def with_needs(tabular: str) -> str:
    """A booktabs ``tabular`` (text) with the ``NEEDS`` line above it, ending in a newline."""
    return f"{NEEDS}\n{tabular.rstrip()}\n"
