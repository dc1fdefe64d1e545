"""Pipe tables laid out cell for cell as pandas' ``to_markdown`` (tabulate) lays them out."""

from __future__ import annotations

import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from segloc_cli.markdown import ALIGNMENTS, pipe_table

CELL = st.text(alphabet=st.sampled_from(list("ab1.-θ°✘ \\|漢")), max_size=10).map(str.strip)


@st.composite
def tables(draw) -> tuple[list[str], list[list[str]], list[str]]:
    n_columns = draw(st.integers(1, 5))
    headers = draw(st.lists(CELL.filter(bool), min_size=n_columns, max_size=n_columns, unique=True))
    rows = draw(
        st.lists(st.lists(CELL, min_size=n_columns, max_size=n_columns), min_size=1, max_size=6)
    )
    aligns = draw(st.lists(st.sampled_from(ALIGNMENTS), min_size=n_columns, max_size=n_columns))
    return headers, rows, aligns


@settings(max_examples=30, deadline=None)
@given(tables())
def test_the_layout_is_tabulates_pipe_format(table):
    headers, rows, aligns = table
    frame = pd.DataFrame(rows, columns=headers)
    expected = frame.to_markdown(index=False, disable_numparse=True, colalign=aligns)
    assert pipe_table(headers, rows, aligns) == expected


def test_a_hand_made_table():
    text = pipe_table(
        ["pose", "X (cm)", "ok"],
        [["1", "-2.5", "yes"], ["RMS", "2.5", ""]],
        ["left", "right", "center"],
    )
    assert text.splitlines() == [
        "| pose   |   X (cm) |  ok  |",
        "|:-------|---------:|:----:|",
        "| 1      |     -2.5 | yes  |",
        "| RMS    |      2.5 |      |",
    ]


@pytest.mark.parametrize(
    ("headers", "rows", "aligns", "message"),
    [
        (["a"], [["1", "2"]], ["left"], "one entry per header"),
        (["a"], [["1"]], ["middle"], "unknown alignment 'middle'"),
    ],
)
def test_a_ragged_table_or_unknown_alignment_is_refused(headers, rows, aligns, message):
    with pytest.raises(ValueError, match=message):
        pipe_table(headers, rows, aligns)
