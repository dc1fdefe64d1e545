"""The LaTeX tables (``evaluate`` and ``sweep`` with ``--format latex``) say on their first line
the one package they need, hold only ASCII, and use no command beyond the LaTeX kernel and
booktabs; where pdflatex is installed, they compile in a bare article with that package."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pandas as pd
import pytest
from test_evaluate import mixed_table
from test_relations import hand_summary

from segloc_cli.latex import NEEDS, latex_text
from segloc_cli.runs.sweep import format_summary
from segloc_cli.scoring.evaluate import format_table, summary
from segloc_cli.scoring.gates import Gates
from segloc_cli.scoring.relations import PUBLISHED, format_relations

BOOKTABS = {"toprule", "midrule", "bottomrule"}
KERNEL = {"begin", "end", "multicolumn", "footnotesize", "circ", "theta", "surd", "pm"}
KERNEL |= {"leq", "geq", "times", "infty", "mu", "dots", "textbackslash", "textasciitilde"}
KERNEL |= {"textasciicircum"}
"""Commands the tables may use: booktabs' rules, and the kernel's."""


def sweep_frame() -> pd.DataFrame:
    """A sweep summary with the symbols its columns hold (%, °) and an infinite error."""
    row = {"combination": 1, "method": "two_stage", "grid-m": 1.5, "tasks": 2}
    row |= {"failed tasks": 0, "poses": 10, "within gates %": 90.0, "median cm": 0.12}
    row |= {"p95 cm": np.inf, "median °": 0.01, "p95 °": 0.2, "median ms": 12.3}
    return pd.DataFrame([row])


def tables() -> dict[str, str]:
    table = mixed_table()
    stats = summary(table, gates=Gates(axis_cm=3.5, deg=0.3))
    relations = format_relations(hand_summary(), "latex", PUBLISHED["fr079"], label="a_b & c")
    return {
        "evaluate": format_table(table, stats, "latex"),
        "relations": relations,
        "sweep": format_summary(sweep_frame(), "latex"),
    }


@pytest.mark.parametrize("name", ["evaluate", "relations", "sweep"])
def test_a_latex_table_says_what_it_needs_and_needs_nothing_else(name):
    text = tables()[name]
    assert text.splitlines()[0] == NEEDS == r"% needs \usepackage{booktabs}"
    assert text.isascii(), [ch for ch in text if not ch.isascii()]
    used = set(re.findall(r"\\([A-Za-z]+)", text.partition("\n")[2]))
    assert used <= KERNEL | BOOKTABS, used - KERNEL - BOOKTABS
    # No unescaped % (a comment) after the first line: every row reaches its \\.
    assert not re.search(r"(?<!\\)%", text.partition("\n")[2])
    assert text.rstrip().endswith(r"\end{tabular}")


def test_the_sweep_table_escapes_its_headers():
    header = tables()["sweep"].splitlines()[3]
    assert r"within gates \%" in header and r"median $^\circ$" in header
    assert r"two\_stage" in tables()["sweep"]


def test_symbols_of_the_summary_lines_become_latex():
    assert latex_text("√(X² + Y²) ≤ 3.5 cm ± 0.1 × 2 – ∞ 5 µm…") == (
        r"$\surd$(X$^2$ + Y$^2$) $\leq$ 3.5 cm $\pm$ 0.1 $\times$ 2 -- $\infty$ 5 $\mu$m\dots{}"
    )
    assert latex_text("50 % of a_b & {c} #1 $2 ~^\\") == (
        r"50 \% of a\_b \& \{c\} \#1 \$2 \textasciitilde{}\textasciicircum{}\textbackslash{}"
    )


@pytest.mark.skipif(shutil.which("pdflatex") is None, reason="pdflatex is not installed")
@pytest.mark.parametrize("name", ["evaluate", "relations", "sweep"])
def test_a_latex_table_compiles_in_a_bare_article_with_booktabs(name, tmp_path):
    (tmp_path / "table.tex").write_text(tables()[name], encoding="ascii")
    (tmp_path / "doc.tex").write_text(
        "\\documentclass{article}\n\\usepackage{booktabs}\n\\begin{document}\n"
        "\\input{table}\n\\end{document}\n",
        encoding="ascii",
    )
    done = subprocess.run(
        ["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "doc.tex"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    errors = [line for line in done.stdout.splitlines() if line.startswith("!")]
    assert done.returncode == 0 and not errors, errors
    assert (tmp_path / "doc.pdf").stat().st_size > 0
