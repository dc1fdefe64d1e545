"""How the lines segloc prints are worded: each line on standard error starts with
``segloc:`` (``said``), a count's noun is in the number the count asks for ("1 scan",
"2 scans", "0 scans"), and a word gets the article it sounds like it takes ("an explorer",
"a scip2", "an 8-byte payload").

Every line on standard error carries the prefix, so that in a CI log or beside other tools'
output each can be told apart and found with grep: errors, warnings, summaries, and the
progress lines written where no bar can be drawn. The bar drawn on a terminal carries it
too, though it is rewritten in place and erased when the work ends.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Sequence

PREFIX = "segloc: "
"""What every line on standard error starts with."""

_VOWEL_LETTERS = "AEFHILMNORSX"
"""Capitals whose spoken name starts with a vowel sound (an "L", an "RGBA" image)."""


def said(message: str) -> str:
    """``message`` as a line of segloc's on standard error: after ``PREFIX``."""
    return f"{PREFIX}{message}"


def plural(n: float, noun: str, nouns: str | None = None) -> str:
    """``noun`` where ``n`` is 1 (or -1), else its plural: ``nouns``, by default ``noun``
    and an "s" ("hypothesis" needs ``nouns="hypotheses"``; "1.5 scans", a median, too)."""
    if abs(n) == 1:
        return noun
    return f"{noun}s" if nouns is None else nouns


def counted(n: int, noun: str, nouns: str | None = None) -> str:
    """``n`` and its noun in the right number: "1 scan", "2 scans", "0 scans" (``plural``)."""
    return f"{n} {plural(n, noun, nouns)}"


def stopped_after(by: str, done: int, planned: int) -> str:
    """How a run stopped early is told, in its run file, its run view and ``info``: "stopped
    (SIGTERM) after 3 of 10 scans"."""
    return f"stopped ({by}) after {done} of {counted(planned, 'scan')}"


def article(word: str) -> str:
    """ "a" or "an", as ``word`` sounds when read out: "an explorer", "a scip2", "an RGBA",
    "an 8-byte", "an 11 × 4", "a 1-byte". Lower-case words go by their first letter ("u" as
    in "unit" takes "a"); capitals are read letter by letter; numbers as spoken."""
    if not word:
        return "a"
    digits = re.match(r"\d[\d,]*", word)
    if digits:
        return "an" if _number_starts_with_vowel(digits.group().replace(",", "")) else "a"
    first = word[0]
    if first.isupper() and (len(word) == 1 or not word[1].islower()):
        return "an" if first in _VOWEL_LETTERS else "a"
    return "an" if first.lower() in "aeio" else "a"


def _number_starts_with_vowel(digits: str) -> bool:
    """Whether a whole number read out starts with a vowel: eight…, eleven…, eighteen…
    ("eleven thousand", but "one hundred ten")."""
    if digits.startswith("8"):
        return True
    return digits[:2] in ("11", "18") and len(digits) % 3 == 2


def with_article(word: str) -> str:
    """``word`` after its article (``article``): "an explorer", "a scip2"."""
    return f"{article(word)} {word}"


def did_you_mean(word: str, known: Sequence[str], otherwise: str = "", quoted: bool = True) -> str:
    """ "did you mean 'x'?", x being the one of ``known`` closest to a mistyped ``word``
    (without quotes unless ``quoted``: "did you mean --out?"), or ``otherwise`` where none
    is close."""
    close = difflib.get_close_matches(word, list(known), n=1)
    if not close:
        return otherwise
    return f"did you mean {close[0]!r}?" if quoted else f"did you mean {close[0]}?"
