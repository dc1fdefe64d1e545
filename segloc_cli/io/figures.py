"""Figures to files: PNG and PDF, each written beside its target and renamed into place, so
no figure is ever half drawn."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from segloc_cli.io.files import atomic_path
from segloc_cli.progress import ProgressFactory, silent

if TYPE_CHECKING:
    from matplotlib.figure import Figure

FIGURE_DPI = 150
"""Resolution of the PNG files; the PDF files are vector graphics."""


def save_figure(fig: Figure, out_dir: str | Path, name: str) -> list[Path]:
    """Write ``fig`` as ``out_dir/name.png`` (``FIGURE_DPI``) and ``out_dir/name.pdf``.

    Returns the two paths. The PDF carries no creation date, so the same
    figure gives the same file.
    """
    out_dir = Path(out_dir)
    png, pdf = out_dir / f"{name}.png", out_dir / f"{name}.pdf"
    with atomic_path(png) as partial:
        fig.savefig(partial, format="png", dpi=FIGURE_DPI)
    with atomic_path(pdf) as partial:
        fig.savefig(partial, format="pdf", metadata={"CreationDate": None})
    return [png, pdf]


def write_figures(
    figures: Mapping[str, Callable[[], Figure]],
    out_dir: str | Path,
    progress: ProgressFactory = silent,
) -> list[Path]:
    """Draw each of ``figures`` (name → drawing function) and write it into ``out_dir``
    (which must exist), each a step of ``progress``. Returns the paths, PNG before PDF."""
    written = []
    with progress("drawing figures", len(figures), "figure") as shown:
        for name, draw in figures.items():
            written += save_figure(draw(), out_dir, name)
            shown.advance()
    return written
