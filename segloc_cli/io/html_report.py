"""``segloc evaluate --html``: the scores of a run as one self-contained HTML page.

The page opens with the answer: a heading with an overall PASS/FAIL badge, the verdict in
one line and the gates, all on the first screen; then each section's Markdown pipe table as
an HTML table with the sentences under it, every figure as an inline PNG, the appendix
(long tables folded, their failing rows marked), the settings and each input file with its
size and SHA-256. It names no external resource (no
script, font, stylesheet or image from elsewhere), so the file alone is the whole report;
its style is inline and prints well. Every text that goes into the page is escaped by the
template (jinja2 with autoescape).
"""

from __future__ import annotations

import base64
import functools
import io
import itertools
import re
import struct
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import jinja2
import numpy as np

from segloc_cli import __version__
from segloc_cli.io.files import reading, sha256, write_text_atomic
from segloc_cli.wording import counted

if TYPE_CHECKING:
    from matplotlib.figure import Figure


class GateShown(Protocol):
    """What the page shows of a gate (``scoring.gates.GateOutcome`` is one): what it asks,
    what it found, whether it held, and the line that says both."""

    @property
    def passed(self) -> bool: ...

    @property
    def title(self) -> str: ...

    @property
    def result(self) -> str: ...

    @property
    def text(self) -> str: ...


ALIGNMENTS = ("left", "center", "right")
"""Cell alignments a pipe table's separator row can ask for (None: the browser's default)."""


@dataclass(frozen=True)
class ReportSection:
    """A titled block of the page: ``markdown_table`` is a GitHub-Markdown pipe table with
    sentences under it, as ``segloc evaluate`` prints it (None: no table); ``lines`` are more
    sentences, a paragraph each. ``folded``: shown closed, opened by a click;
    ``marked_rows``: the body rows (from 0) of its first table to mark as failing."""

    title: str
    markdown_table: str | None = None
    lines: Sequence[str] = ()
    folded: bool = False
    marked_rows: frozenset[int] = frozenset()


@dataclass(frozen=True)
class PipeTable:
    """A pipe table's text: ``headers`` (C,), ``alignments`` (C,) each one of ``ALIGNMENTS``
    or None, and ``rows``, each of C cells (a short row padded with empty cells)."""

    headers: tuple[str, ...]
    alignments: tuple[str | None, ...]
    rows: tuple[tuple[str, ...], ...]


@dataclass(frozen=True)
class _Figure:
    """A figure drawn for the page: its PNG and that PNG's size in pixels."""

    name: str
    caption: str
    png: bytes
    width_px: int
    height_px: int

    @property
    def data_uri(self) -> str:
        return "data:image/png;base64," + base64.b64encode(self.png).decode("ascii")


@dataclass(frozen=True)
class _Input:
    role: str
    name: str
    size: str
    sha256: str


_SEPARATOR_CELL = re.compile(r"^\s*(:?)-+(:?)\s*$")
_UNESCAPED_PIPE = re.compile(r"(?<!\\)\|")


def parse_pipe_table(text: str) -> PipeTable:
    """The cells of a GitHub-Markdown pipe table (header row, separator row, body rows).

    Accepts the shape ``pandas.DataFrame.to_markdown`` writes, where every row has its pipes
    where the separator row has them (so a cell may hold a ``|``), and hand-written tables
    whose cells escape a pipe as ``\\|``. Cells are stripped of padding; a row with more cells
    than the header loses the extra ones, as on GitHub. Raises ``ValueError`` when ``text``
    is not a pipe table.
    """
    lines = [line.strip() for line in text.strip().splitlines()]
    if len(lines) < 2 or not all(line.startswith("|") for line in lines):
        raise ValueError("a pipe table needs a header row and a separator row, each from '|'")
    separator = lines[1]
    marks = _split_row(separator, None)
    matches = [_SEPARATOR_CELL.match(mark) for mark in marks]
    if not marks or not all(matches):
        raise ValueError(f"not a pipe table's separator row: {separator!r}")
    alignments = tuple(_alignment(match) for match in matches if match)
    pipes = tuple(i for i, ch in enumerate(separator) if ch == "|")
    n_columns = len(alignments)

    def cells(line: str) -> tuple[str, ...]:
        found = _split_row(line, pipes)[:n_columns]
        return tuple(found) + ("",) * (n_columns - len(found))

    return PipeTable(
        headers=cells(lines[0]),
        alignments=alignments,
        rows=tuple(cells(line) for line in lines[2:]),
    )


def _alignment(mark: re.Match[str]) -> str | None:
    left, right = bool(mark.group(1)), bool(mark.group(2))
    if left and right:
        return "center"
    return "left" if left else ("right" if right else None)


def _split_row(line: str, pipes: tuple[int, ...] | None) -> list[str]:
    """The stripped cells of one row. A row padded like the separator (``pipes``: where its
    pipes are) is cut at those pipes alone, so a ``|`` inside a cell stays in it."""
    if pipes and len(line) == pipes[-1] + 1 and all(line[i] == "|" for i in pipes):
        return [line[a + 1 : b].strip().replace("\\|", "|") for a, b in itertools.pairwise(pipes)]
    inner = line[1:-1] if line.endswith("|") and not line.endswith("\\|") else line[1:]
    return [cell.strip().replace("\\|", "|") for cell in _UNESCAPED_PIPE.split(inner)]


def markdown_blocks(text: str) -> list[PipeTable | str]:
    """``text`` (a pipe table with sentences around it) as blocks in order: a ``PipeTable`` for
    each run of lines that form a table, a string for each other non-blank line. Lines from
    ``|`` that do not form a table stay text."""
    blocks: list[PipeTable | str] = []
    run: list[str] = []

    def end_run() -> None:
        if not run:
            return
        try:
            blocks.append(parse_pipe_table("\n".join(run)))
        except ValueError:
            blocks.extend(run)
        run.clear()

    for line in text.splitlines():
        if line.strip().startswith("|"):
            run.append(line.strip())
            continue
        end_run()
        if line.strip():
            blocks.append(line.strip())
    end_run()
    return blocks


def humanized(name: str) -> str:
    """A figure's name as a caption: ``success_vs_initial_error`` → ``Success vs initial
    error``."""
    words = re.sub(r"[_\-\s]+", " ", name).strip()
    return words[:1].upper() + words[1:] if words else name


def html_report(
    *,
    title: str,
    sections: Sequence[ReportSection],
    gates: Sequence[GateShown],
    figures: Mapping[str, Callable[[], Figure]],
    settings: Mapping[str, object],
    inputs: Mapping[str, Path],
    verdict_line: str = "",
    appendix: Sequence[ReportSection] = (),
    dpi: int = 100,
) -> str:
    """The whole page as text: the title and badge, ``verdict_line``, the ``gates``, the
    ``sections``, the figures, the ``appendix``, the settings and the inputs.

    ``figures`` maps a name to a function that draws the figure (as
    ``scoring/plots.evaluation_figures`` gives them); each is drawn in turn, kept as a PNG of
    ``dpi`` dots per inch and closed. ``settings`` are shown as name and value; ``inputs``
    map a role (``"estimates"``) to a file or folder, shown with its size and SHA-256 (of a
    folder as a run file records it). The badge says FAIL when any of ``gates`` failed, PASS
    when all passed, "no gates" when there are none. A missing or unreadable input raises
    ``InputError`` naming it.
    """
    if not gates:
        verdict = "none"
    else:
        verdict = "pass" if all(gate.passed for gate in gates) else "fail"
    listed = [_input_of(role, Path(path)) for role, path in inputs.items()]
    drawn = [_draw(name, draw, dpi) for name, draw in figures.items()]
    return _template().render(
        title=title,
        verdict=verdict,
        verdict_line=verdict_line,
        sections=[_section_blocks(section) for section in sections],
        appendix=[_section_blocks(section) for section in appendix],
        gates=[_gate_row(gate) for gate in gates],
        figures=drawn,
        settings=[(str(name), _setting_text(value)) for name, value in settings.items()],
        inputs=listed,
        version=__version__,
    )


def write_html_report(path: Path, text: str) -> None:
    """Write the page ``text`` to ``path`` whole or not at all (``files.write_text_atomic``)."""
    write_text_atomic(path, text)


# --------------------------------------------------------------------------- parts of the page


def _section_blocks(section: ReportSection) -> dict[str, object]:
    blocks: list[PipeTable | str] = []
    if section.markdown_table is not None:
        blocks += markdown_blocks(section.markdown_table)
    blocks += [line for line in section.lines if line.strip()]
    first_table = next((i for i, block in enumerate(blocks) if isinstance(block, PipeTable)), -1)
    return {
        "title": section.title,
        "blocks": blocks,
        "folded": section.folded,
        "marked": {first_table: section.marked_rows},
    }


def _gate_row(gate: GateShown) -> dict[str, object]:
    """A gate as the page's row: what it asks (``RMS position error ≤ 5 cm``), and the
    measure against the bound with its counts (``3.2 cm ≤ 5 cm``)."""
    return {"name": gate.title, "outcome": gate.result, "passed": gate.passed, "text": gate.text}


def _draw(name: str, draw: Callable[[], Figure], dpi: int) -> _Figure:
    fig = draw()
    try:
        buffer = io.BytesIO()
        # No "Software" chunk: the same figure gives the same bytes, and no address.
        fig.savefig(buffer, format="png", dpi=dpi, metadata={"Software": None})
    finally:
        _close(fig)
    png = buffer.getvalue()
    width_px, height_px = png_size(png)
    return _Figure(name, humanized(name), png, width_px, height_px)


def _close(fig: Figure) -> None:
    # A figure made through pyplot stays alive in pyplot's registry until closed; one made on
    # its own canvas (as scoring/plots makes them) is not registered. pyplot is only asked
    # when something already imported it, so rendering never loads it.
    pyplot = sys.modules.get("matplotlib.pyplot")
    if pyplot is not None:
        pyplot.close(fig)


def png_size(png: bytes) -> tuple[int, int]:
    """Width and height in pixels of the PNG ``png``, from its header; ``ValueError`` when it
    is not a PNG."""
    if len(png) < 24 or png[:8] != b"\x89PNG\r\n\x1a\n" or png[12:16] != b"IHDR":
        raise ValueError("not a PNG image")
    width, height = struct.unpack(">II", png[16:24])
    return int(width), int(height)


def _setting_text(value: object) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool | np.bool_):
        return "true" if value else "false"
    if isinstance(value, float | np.floating):
        return f"{float(value):g}"
    if isinstance(value, Path):
        return value.as_posix()
    if isinstance(value, list | tuple | np.ndarray):
        return ", ".join(_setting_text(item) for item in value)
    return str(value)


def _input_of(role: str, path: Path) -> _Input:
    with reading(path, "an input of this report"):
        if path.is_dir():
            n_bytes = sum(file.stat().st_size for file in path.rglob("*") if file.is_file())
        else:
            n_bytes = path.stat().st_size
    return _Input(str(role), path.name or str(path), size_text(n_bytes), sha256(path))


def size_text(n_bytes: int) -> str:
    """A size for people: ``512 bytes``, ``1.2 kB (1,234 bytes)``, in powers of 1000."""
    if n_bytes < 1000:
        return counted(n_bytes, "byte")
    scaled = float(n_bytes)
    for unit in ("kB", "MB", "GB", "TB"):
        scaled /= 1000.0
        if scaled < 999.95 or unit == "TB":
            break
    return f"{scaled:.1f} {unit} ({n_bytes:,} bytes)"


# --------------------------------------------------------------------------- the template


@functools.cache
def _template() -> jinja2.Template:
    environment = jinja2.Environment(
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    environment.tests["pipe_table"] = lambda block: isinstance(block, PipeTable)
    return environment.from_string(_PAGE)


_STYLE = """
:root { color-scheme: light; }
body { font: 15px/1.45 system-ui, -apple-system, "Segoe UI", sans-serif; color: #1f2328;
  background: #fff; max-width: 1100px; margin: 1.5em auto; padding: 0 1em; }
h1 { font-size: 1.6em; display: flex; align-items: center; gap: .6em; flex-wrap: wrap; }
h2 { font-size: 1.2em; border-bottom: 1px solid #d0d7de; padding-bottom: .2em; margin-top: 1.8em; }
.badge { font-size: .6em; padding: .2em .7em; border-radius: 1em; border: 1px solid;
  letter-spacing: .05em; }
.badge.pass { background: #dafbe1; color: #116329; border-color: #4ac26b; }
.badge.fail { background: #ffebe9; color: #a40e26; border-color: #ff8182; }
.badge.none { background: #f6f8fa; color: #59636e; border-color: #d0d7de; }
table { border-collapse: collapse; margin: .6em 0; font-variant-numeric: tabular-nums; }
th, td { border: 1px solid #d0d7de; padding: .25em .6em; vertical-align: top;
  text-align: left; }
thead th { background: #f6f8fa; }
tbody tr:nth-child(even) { background: #fbfcfd; }
.align-left { text-align: left; } .align-center { text-align: center; }
.align-right { text-align: right; }
table.settings th { text-align: left; font-weight: 600; background: #f6f8fa; }
td.pass { color: #116329; } td.fail { color: #a40e26; font-weight: 600; }
table.gates td:first-child { white-space: nowrap; }
p.verdict { font-size: 1.1em; font-weight: 600; margin: .2em 0 .8em; }
p.verdict.fail { color: #a40e26; } p.verdict.pass { color: #116329; }
tbody tr.failing, tbody tr.failing:nth-child(even) { background: #ffebe9; }
details > summary { cursor: pointer; font-size: 1.2em; font-weight: 600; margin-top: 1.8em;
  border-bottom: 1px solid #d0d7de; padding-bottom: .2em; }
code { font: .9em ui-monospace, "SFMono-Regular", Menlo, Consolas, monospace; }
figure { margin: 1em 0; break-inside: avoid; }
figure img { max-width: 100%; height: auto; border: 1px solid #eaeef2; }
figcaption { color: #59636e; font-size: .9em; }
footer { color: #59636e; font-size: .85em; margin-top: 2.5em; }
@media print {
  body { max-width: none; margin: 0; font-size: 11pt; }
  .badge, thead th, table.settings th { print-color-adjust: exact;
    -webkit-print-color-adjust: exact; }
  h2 { break-after: avoid; } table, figure { break-inside: avoid; }
}
"""

_PAGE = (
    """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{{ title }}</title>
<style>"""
    + _STYLE
    + """</style>
</head>
<body>
{% macro pipe_table(table, marked=()) %}
<table>
<thead><tr>
{% for header in table.headers %}
<th{{ align(table.alignments[loop.index0]) }}>{{ header }}</th>
{% endfor %}
</tr></thead>
<tbody>
{% for row in table.rows %}
<tr{% if loop.index0 in marked %} class="failing"{% endif %}>{% for cell in row %}
<td{{ align(table.alignments[loop.index0]) }}>{{ cell }}</td>
{%- endfor %}</tr>
{% endfor %}
</tbody>
</table>
{% endmacro %}
{% macro blocks(section) %}
{% for block in section.blocks %}
{% if block is pipe_table %}{{ pipe_table(block, section.marked.get(loop.index0, ())) }}
{% else %}<p>{{ block }}</p>
{% endif %}
{% endfor %}
{% endmacro %}
{% macro align(alignment) %}
{% if alignment %} class="align-{{ alignment }}"{% endif %}
{%- endmacro %}
<header>
<h1><span>{{ title }}</span>
{% if verdict == "pass" %}<span class="badge pass">PASS</span>
{% elif verdict == "fail" %}<span class="badge fail">FAIL</span>
{% else %}<span class="badge none">no gates</span>{% endif %}
</h1>
{% if verdict_line %}<p class="verdict {{ verdict }}">{{ verdict_line }}</p>{% endif %}
</header>
<main>
{% if gates %}
<section>
<h2>Gates</h2>
<table class="gates">
<thead><tr><th>result</th><th>gate</th><th>measured</th></tr></thead>
<tbody>
{% for gate in gates %}
<tr title="{{ gate.text }}"><td class="{{ 'pass' if gate.passed else 'fail' }}">
{{- '✔ pass' if gate.passed else '✘ FAIL' }}</td><td>{{ gate.name }}</td>
<td>{{ gate.outcome }}</td></tr>
{% endfor %}
</tbody>
</table>
</section>
{% endif %}
{% for section in sections %}
<section>
<h2>{{ section.title }}</h2>
{{ blocks(section) }}
</section>
{% endfor %}
{% if figures %}
<section>
<h2>Figures</h2>
{% for figure in figures %}
<figure id="figure-{{ figure.name }}">
<img src="{{ figure.data_uri }}" width="{{ figure.width_px }}" height="{{ figure.height_px }}"
 alt="Figure: {{ figure.caption }}">
<figcaption>{{ figure.caption }} (<code>{{ figure.name }}</code>)</figcaption>
</figure>
{% endfor %}
</section>
{% endif %}
{% for section in appendix %}
<section>
{% if section.folded %}
<details>
<summary>{{ section.title }}</summary>
{{ blocks(section) }}
</details>
{% else %}
<h2>{{ section.title }}</h2>
{{ blocks(section) }}
{% endif %}
</section>
{% endfor %}
{% if settings %}
<section>
<h2>Settings</h2>
<table class="settings">
<tbody>
{% for name, value in settings %}
<tr><th scope="row">{{ name }}</th><td>{{ value }}</td></tr>
{% endfor %}
</tbody>
</table>
</section>
{% endif %}
{% if inputs %}
<section>
<h2>Inputs</h2>
<table class="inputs">
<thead><tr><th>role</th><th>file</th><th>size</th><th>SHA-256</th></tr></thead>
<tbody>
{% for input in inputs %}
<tr><td>{{ input.role }}</td><td>{{ input.name }}</td><td class="align-right">{{ input.size }}</td>
<td><code title="{{ input.sha256 }}">{{ input.sha256[:16] }}…</code></td></tr>
{% endfor %}
</tbody>
</table>
</section>
{% endif %}
</main>
<footer>Made by segloc {{ version }}.</footer>
</body>
</html>
"""
)
