"""Every relative link of README.md and the pages of docs/ leads somewhere: to a file or folder
of the repository and, after a ``#``, to a heading of the page it names (GitHub's anchors)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(([^)\s]+)\)")
"""An inline link or image, ``[text](target)``; its text may hold brackets one deep."""


def prose(text: str) -> str:
    """A page without its fenced blocks and inline code, where a bracket is no link."""
    text = re.sub(r"^```.*?^```[ \t]*$", "", text, flags=re.M | re.S)
    return re.sub(r"`[^`\n]*`", "", text)


def anchors(text: str) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation but ``-`` and
    ``_`` dropped, spaces made hyphens; a repeated one numbered ``-1``, ``-2``, ..."""
    text = re.sub(r"^```.*?^```[ \t]*$", "", text, flags=re.M | re.S)
    found: set[str] = set()
    for heading in re.findall(r"^#{1,6}[ \t]+(.+?)[ \t]*#*$", text, re.M):
        heading = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link keeps its text
        slug = re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-")
        candidate, n = slug, 0
        while candidate in found:
            n += 1
            candidate = f"{slug}-{n}"
        found.add(candidate)
    return found


def broken(page: Path, text: str | None = None) -> list[str]:
    """The relative links of the page at ``page`` (its ``text`` when given) that lead
    nowhere, each with the reason."""
    text = page.read_text(encoding="utf-8") if text is None else text
    problems = []
    for target in LINK.findall(prose(text)):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # https:, mailto: ...
            continue
        path, _, anchor = target.partition("#")
        goal = Path(os.path.normpath(page.parent / path)) if path else page
        if goal != page and not goal.exists():
            problems.append(f"{target}: no {os.path.relpath(goal, ROOT)}")
        elif ROOT not in goal.parents:
            problems.append(f"{target}: outside the repository")
        elif anchor:
            headings = text if goal == page else goal.read_text(encoding="utf-8")
            if goal.suffix != ".md" or anchor not in anchors(headings):
                problems.append(f"{target}: no heading #{anchor} in {goal.name}")
    return problems


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_leads_somewhere(page):
    assert broken(page) == []


def test_links_to_nowhere_are_found():
    text = (
        "[a](architecture.md) [b](architecture.md#no-such-heading) [c](../README.md#segloc)\n"
        "[d](missing.md) [e](#here) [f](#gone) ![g](../datasets/hall) [h](https://x.org/#y)\n"
        "[i](../../elsewhere.md)\n"
        "## Here\n`[j](nowhere.md)`\n```sh\n[k](nowhere.md)\n# Gone\n```\n"
    )
    assert broken(ROOT / "docs" / "new-page.md", text) == [
        "architecture.md#no-such-heading: no heading #no-such-heading in architecture.md",
        "missing.md: no docs/missing.md",
        "#gone: no heading #gone in new-page.md",
        "../../elsewhere.md: no ../elsewhere.md",
    ]


def test_anchors_are_githubs():
    text = "# `segloc import` — public logs into MCAP\n## What segloc refuses, and why\n"
    text += "## Why\n## Why\n"
    assert anchors(text) == {
        "segloc-import--public-logs-into-mcap",
        "what-segloc-refuses-and-why",
        "why",
        "why-1",
    }
