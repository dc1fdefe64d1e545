"""The HTML report: pipe tables read into cells, every text escaped, figures inline as PNGs of
their declared size, nothing fetched from elsewhere, and the page as a real browser shows it."""

from __future__ import annotations

import base64
import hashlib
import io
import os
import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from segloc_cli.errors import InputError
from segloc_cli.io.files import sha256 as run_file_sha256
from segloc_cli.io.html_report import (
    PipeTable,
    ReportSection,
    html_report,
    markdown_blocks,
    parse_pipe_table,
    size_text,
    write_html_report,
)
from segloc_cli.scoring.gates import GateOutcome

HOSTILE = "<script>alert('x')</script>"
QUOTED = '" onmouseover="alert(1)'


def _figure(size_in: tuple[float, float]) -> Figure:
    fig = Figure(figsize=size_in)
    FigureCanvasAgg(fig)
    return fig


def line_plot() -> Figure:
    fig = _figure((3.0, 2.0))
    x = np.linspace(0.0, 2.0 * np.pi, 50)
    fig.subplots().plot(x, np.sin(x), color="tab:blue", linewidth=2.0)
    return fig


def bar_chart() -> Figure:
    fig = _figure((2.5, 2.0))
    fig.subplots().bar(["a", "b", "c"], [3.0, 1.0, 2.0], color="tab:orange")
    return fig


def table1_text() -> str:
    """A table and sentences in the shape ``segloc evaluate --format md`` prints."""
    frame = pd.DataFrame(
        {"pose": ["1", "2", "RMS"], "X (cm)": ["1.5", "-2.25", "1.9"], "status": ["ok", "a|b", ""]}
    )
    table = frame.to_markdown(
        index=False, disable_numparse=True, colalign=("left", "right", "center")
    )
    return table + "\n\n3 surveyed poses: ok 2, lost 1.\nErrors are surveyed minus computed.\n"


GATES = (
    GateOutcome("RMS position error", 3.24, 5.0, "cm", True),
    GateOutcome("poses within limits", 80.0, 95.0, "%", False, at_least=True),
)


def page_of(
    tmp_path: Path,
    *,
    sections: tuple[ReportSection, ...] = (),
    gates: tuple[GateOutcome, ...] = GATES,
    figures: dict[str, Callable[[], Figure]] | None = None,
    settings: dict[str, object] | None = None,
    verdict_line: str = "",
    appendix: tuple[ReportSection, ...] = (),
) -> str:
    estimates = tmp_path / "run.csv"
    estimates.write_text("time_s,x_m\n0.0,1.0\n", encoding="utf-8")
    return html_report(
        title="Hall run",
        sections=sections or (ReportSection("Table 1", table1_text(), ["One more line."]),),
        gates=gates,
        figures={"line_plot": line_plot, "bar_chart": bar_chart} if figures is None else figures,
        settings={"method": "segments", "tolerance_ms": 50.0} if settings is None else settings,
        inputs={"estimates": estimates},
        verdict_line=verdict_line,
        appendix=appendix,
        dpi=80,
    )


class _Elements(HTMLParser):
    """Every start tag of a page with its attributes, and its text."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append((tag, dict(attrs)))

    def handle_data(self, data: str) -> None:
        self.text.append(data)


def elements(page: str) -> _Elements:
    parsed = _Elements()
    parsed.feed(page)
    return parsed


# --------------------------------------------------------------------------- pipe tables


def test_a_pandas_table_keeps_its_alignment_and_a_pipe_inside_a_cell() -> None:
    table = parse_pipe_table(table1_text().split("\n\n")[0])
    assert table.headers == ("pose", "X (cm)", "status")
    assert table.alignments == ("left", "right", "center")
    assert table.rows == (("1", "1.5", "ok"), ("2", "-2.25", "a|b"), ("RMS", "1.9", ""))


def test_a_hand_written_table_escapes_pipes_and_evens_its_rows() -> None:
    text = "| a | b | c |\n|---|:--|--:|\n| x \\| y | 2 |\n| 1 | 2 | 3 | 4 |"
    table = parse_pipe_table(text)
    assert table.alignments == (None, "left", "right")
    assert table.rows == (("x | y", "2", ""), ("1", "2", "3"))


def test_text_that_is_no_table_is_refused_by_the_parser_and_kept_as_text() -> None:
    with pytest.raises(ValueError, match="separator"):
        parse_pipe_table("| a | b |\n| c | d |")
    blocks = markdown_blocks("Before.\n| a | b |\n| c | d |\n\n| x |\n|:-:|\n| 1 |\nAfter.\n")
    assert blocks[:3] == ["Before.", "| a | b |", "| c | d |"]
    assert blocks[3] == PipeTable(headers=("x",), alignments=("center",), rows=(("1",),))
    assert blocks[4:] == ["After."]


def test_the_page_shows_cells_with_their_alignment_and_escapes_a_script_in_a_cell(
    tmp_path: Path,
) -> None:
    text = f"| name | value |\n|:---|---:|\n| {HOSTILE} | 1 |\n"
    page = page_of(tmp_path, sections=(ReportSection("Scores", text),), gates=())
    found = elements(page)
    cells = [attrs.get("class") for tag, attrs in found.tags if tag in ("th", "td")]
    assert cells[:4] == ["align-left", "align-right", "align-left", "align-right"]
    assert "script" not in [tag for tag, _ in found.tags]
    assert HOSTILE in "".join(found.text)
    assert "&lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt;" in page


# --------------------------------------------------------------------------- the page


def test_hostile_strings_everywhere_stay_text(tmp_path: Path) -> None:
    estimates = tmp_path / "run.csv"
    estimates.write_text("x\n", encoding="utf-8")
    page = html_report(
        title=HOSTILE,
        sections=(ReportSection(QUOTED, f"| {QUOTED} |\n|---|\n| {HOSTILE} |", [HOSTILE]),),
        gates=(GateOutcome(QUOTED, 1.0, 2.0, "cm", True),),
        figures={},
        settings={HOSTILE: QUOTED},
        inputs={QUOTED: estimates},
    )
    found = elements(page)
    assert [tag for tag, _ in found.tags if tag == "script"] == []
    attributes = [name for _, attrs in found.tags for name in attrs]
    assert not [name for name in attributes if name.startswith("on")]
    text = "".join(found.text)
    assert text.count(HOSTILE) >= 4
    assert text.count(QUOTED) >= 4


def test_the_page_names_no_address_and_loads_nothing_from_elsewhere(tmp_path: Path) -> None:
    page = page_of(tmp_path)
    assert "http" not in page.lower()
    assert "url(" not in page and "@import" not in page
    sources = [attrs.get("src") or "" for tag, attrs in elements(page).tags if tag == "img"]
    assert len(sources) == 2
    assert all(source.startswith("data:image/png;base64,") for source in sources)
    assert not [tag for tag, _ in elements(page).tags if tag in ("script", "link", "iframe")]


def test_figures_are_pngs_of_their_declared_size_with_alt_and_caption(tmp_path: Path) -> None:
    page = page_of(tmp_path)
    images = [attrs for tag, attrs in elements(page).tags if tag == "img"]
    # 3 x 2 and 2.5 x 2 inches at 80 dots per inch.
    expected = {"Figure: Line plot": (240, 160), "Figure: Bar chart": (200, 160)}
    for attrs in images:
        png = base64.b64decode(str(attrs["src"]).split(",", 1)[1], validate=True)
        with Image.open(io.BytesIO(png)) as image:
            assert image.format == "PNG"
            declared = (int(str(attrs["width"])), int(str(attrs["height"])))
            assert image.size == declared == expected[str(attrs["alt"])]
    assert "<figcaption>Line plot" in page and "<figcaption>Bar chart" in page


def test_figures_drawn_through_pyplot_are_closed(tmp_path: Path) -> None:
    import matplotlib.pyplot as plt

    plt.close("all")

    def pyplot_figure() -> Figure:
        fig = plt.figure(figsize=(2.0, 2.0))
        fig.subplots().plot([0, 1], [1, 0])
        return fig

    page_of(tmp_path, figures={"one": pyplot_figure, "two": pyplot_figure})
    assert plt.get_fignums() == []


@pytest.mark.parametrize(
    ("gates", "badge"),
    [
        (GATES[:1], '<span class="badge pass">PASS</span>'),
        (GATES, '<span class="badge fail">FAIL</span>'),
        ((), '<span class="badge none">no gates</span>'),
    ],
)
def test_the_badge_fails_when_any_gate_fails(
    tmp_path: Path, gates: tuple[GateOutcome, ...], badge: str
) -> None:
    page = page_of(tmp_path, gates=gates, figures={})
    assert badge in page
    assert page.count('class="badge') == 1
    assert page.count("✘ FAIL") == sum(not gate.passed for gate in gates)


def test_the_gates_show_the_measure_against_the_limit(tmp_path: Path) -> None:
    page = page_of(tmp_path, figures={})
    assert "<td>3.2 cm ≤ 5 cm</td>" in page
    assert "<td>80.0 % &lt; 95 %</td>" in page


def test_the_answer_comes_first_and_the_long_table_last_folded_with_its_failures_marked(
    tmp_path: Path,
) -> None:
    folded = ReportSection("Every pose", table1_text(), folded=True, marked_rows=frozenset({1}))
    page = page_of(
        tmp_path, verdict_line="FAIL: 1 of 2 gates failed.", appendix=(folded,), figures={}
    )
    order = [page.index(text) for text in ('class="verdict fail"', "<h2>Gates</h2>", "<details>")]
    assert order == sorted(order)
    assert page.index("<h2>Table 1</h2>") < page.index("<details>")
    details = page[page.index("<details>") : page.index("</details>")]
    assert "<summary>Every pose</summary>" in details
    rows = re.findall(r"<tr( class=\"failing\")?>", details.split("<tbody>")[1])
    # Pose 2 (the second body row) is marked; pose 1 and the RMS row are not.
    assert rows == ["", ' class="failing"', ""]


def test_settings_are_shown_as_names_and_values(tmp_path: Path) -> None:
    settings: dict[str, object] = {
        "tolerance_ms": 50.0,
        "track": True,
        "window": None,
        "bins_m": (0.5, 1.0),
    }
    page = page_of(tmp_path, figures={}, settings=settings)
    for name, value in [("tolerance_ms", "50"), ("track", "true"), ("window", "—")]:
        assert f'<th scope="row">{name}</th><td>{value}</td>' in page
    assert '<th scope="row">bins_m</th><td>0.5, 1</td>' in page


def test_inputs_show_size_and_sha256_as_a_run_file_records_them(tmp_path: Path) -> None:
    data = tmp_path / "survey.csv"
    data.write_bytes(b"pose_id,x_m\n" * 200)
    bag = tmp_path / "bag"
    (bag / "inner").mkdir(parents=True)
    (bag / "metadata.yaml").write_text("a: 1\n", encoding="utf-8")
    (bag / "inner" / "data.db3").write_bytes(b"\0" * 10)
    inputs = {"survey": data, "bag": bag}
    page = html_report(title="t", sections=(), gates=(), figures={}, settings={}, inputs=inputs)
    full = hashlib.sha256(data.read_bytes()).hexdigest()
    assert f'<code title="{full}">{full[:16]}…</code>' in page
    assert "2.4 kB (2,400 bytes)" in page
    folder = run_file_sha256(bag)
    assert f'<code title="{folder}">{folder[:16]}…</code>' in page
    assert "15 bytes" in page


def test_a_missing_input_is_one_line_naming_it(tmp_path: Path) -> None:
    missing = tmp_path / "gone.csv"
    with pytest.raises(InputError, match=r"gone\.csv: file not found"):
        html_report(title="t", sections=(), gates=(), figures={}, settings={}, inputs={"": missing})


@pytest.mark.parametrize(
    ("n_bytes", "text"),
    [
        (0, "0 bytes"),
        (1, "1 byte"),
        (999, "999 bytes"),
        (1234, "1.2 kB (1,234 bytes)"),
        (999_960, "1.0 MB (999,960 bytes)"),
        (5 * 10**9, "5.0 GB (5,000,000,000 bytes)"),
    ],
)
def test_sizes_read_for_people(n_bytes: int, text: str) -> None:
    assert size_text(n_bytes) == text


def test_the_page_is_written_whole_and_replaces_an_old_one(tmp_path: Path) -> None:
    target = tmp_path / "report.html"
    target.write_text("old", encoding="utf-8")
    write_html_report(target, "<p>é</p>\n")
    assert target.read_text(encoding="utf-8") == "<p>é</p>\n"
    assert [p.name for p in tmp_path.iterdir()] == ["report.html"]


# --------------------------------------------------------------------------- in a browser


def _chromium() -> str:
    """Debian's chromium; a skip without it, except in CI, which must run this test."""
    path = shutil.which("chromium")
    reason = ""
    if path is None:
        reason = "Debian's chromium is not installed (make test installs it when run as root)"
    else:
        try:
            import playwright.sync_api  # noqa: F401
        except ImportError:
            reason = "playwright is not installed (a dev dependency)"
    if reason and os.environ.get("CI") == "true":
        pytest.fail(reason)
    if reason:
        pytest.skip(reason)
    assert path is not None
    return path


def _not_blank(region: Image.Image) -> tuple[int, float]:
    """Distinct colours of ``region`` and its share of pixels that are not near white."""
    pixels = np.asarray(region.convert("RGB"), dtype=np.int32).reshape(-1, 3)
    n_colours = len(np.unique(pixels @ np.array([1 << 16, 1 << 8, 1])))  # one int a colour
    return n_colours, float(np.mean(pixels.min(axis=1) < 230))


@dataclass(frozen=True)
class Browsed:
    """What headless Chromium saw of a page: console errors and warnings and page errors
    (``complaints``), every URL it requested, each image's natural, declared and shown
    width with its box on the page, the computed alignment of the first table's first
    row, the page's text with its folded parts opened and a full-page screenshot (PNG
    bytes) taken so; as first shown: the box of the first element each selector asked
    for finds (``located``, None where none) and a screenshot of the first screen."""

    complaints: list[str]
    requested: list[str]
    images: list[dict]
    boxes: list[dict]
    aligns: list[str]
    text: str
    shot: bytes
    located: dict[str, dict | None]
    first_screen: bytes


def browse(
    path: Path, viewport: tuple[int, int] = (1000, 700), locate: tuple[str, ...] = ()
) -> Browsed:
    """Open ``path`` in Debian's headless Chromium (skipped without it, but under CI) in a
    window of ``viewport`` pixels, finding the elements of the ``locate`` selectors."""
    executable = _chromium()
    from playwright.sync_api import sync_playwright

    complaints: list[str] = []
    requested: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=executable,
            args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"],
        )
        try:
            page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
            page.on(
                "console",
                lambda m: (
                    complaints.append(f"{m.type}: {m.text}")
                    if m.type in ("error", "warning")
                    else None
                ),
            )
            page.on("pageerror", lambda error: complaints.append(f"page error: {error}"))
            page.on("request", lambda request: requested.append(request.url))
            page.goto(path.as_uri(), wait_until="load")
            images = page.eval_on_selector_all(
                "img",
                "els => els.map(e => ({natural: e.naturalWidth, declared: e.getAttribute('width'),"
                " shown: e.clientWidth}))",
            )
            boxes = [element.bounding_box() for element in page.query_selector_all("img")]
            # The first table after the gates: the first section's.
            aligns = page.eval_on_selector_all(
                "table:not(.gates)",
                "tables => tables.length ? Array.from(tables[0].querySelectorAll("
                "'tbody tr:first-child td'), e => getComputedStyle(e).textAlign) : []",
            )
            located = {}
            for selector in locate:
                element = page.query_selector(selector)
                located[selector] = None if element is None else element.bounding_box()
            first_screen = page.screenshot()
            page.eval_on_selector_all("details", "els => els.forEach(e => { e.open = true; })")
            text = page.inner_text("body")
            shot = page.screenshot(full_page=True)
        finally:
            browser.close()
    return Browsed(complaints, requested, images, boxes, aligns, text, shot, located, first_screen)


def assert_images_drawn(seen: Browsed) -> None:
    """Each image's region of the screenshot holds a drawing: colours and ink, not a blank."""
    with Image.open(io.BytesIO(seen.shot)) as screenshot:
        for box in seen.boxes:
            assert box is not None
            left, top = round(box["x"]), round(box["y"])
            region = screenshot.crop(
                (left, top, left + round(box["width"]), top + round(box["height"]))
            )
            n_colours, inked = _not_blank(region)
            assert n_colours > 8
            assert 0.01 < inked < 0.9


def test_a_browser_shows_the_page_without_complaint(tmp_path: Path) -> None:
    path = tmp_path / "report.html"
    write_html_report(path, page_of(tmp_path))
    seen = browse(path)
    complaints, requested, images = seen.complaints, seen.requested, seen.images
    aligns, text = seen.aligns, seen.text

    assert complaints == []
    assert [url for url in requested if not url.startswith(("file:", "data:"))] == []
    assert len(images) == 2
    for image in images:
        assert image["natural"] > 0
        assert image["natural"] == int(image["declared"]) == image["shown"]
    assert aligns == ["left", "right", "center"]
    for phrase in ("Hall run", "FAIL", "X (cm)", "-2.25", "a|b", "3 surveyed poses: ok 2, lost 1."):
        assert phrase in text
    assert "RMS position error" in text and "80.0 % < 95 %" in text

    assert_images_drawn(seen)
