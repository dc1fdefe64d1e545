"""Hostile configuration files: any table a stranger writes is read or refused in one line.

Every command that does work is given a ``--config`` file of random keys (real
setting names, near misses, nonsense) and random values (numbers at and past
their bounds, NaN, text, flags, lists, dates, nested tables), or random bytes.
Its log and map do not exist, so a configuration that is read leads to the
one-line error naming the missing file: either way the exit status is 2 and
stderr is one line, never a traceback or an internal error (70).
"""

from __future__ import annotations

import contextlib
import io
import tempfile
from pathlib import Path

import tomli_w
from fuzzing import ODD_TOKENS, fuzz_settings
from hypothesis import given
from hypothesis import strategies as st

from segloc_cli.cli import main
from segloc_cli.config import SETTINGS

COMMANDS = {
    "localize": ["localize", "none.mcap", "--map", "none.json", "--out", "e.csv"],
    "map.build": ["map", "build", "none.mcap", "--survey", "none.csv", "--out", "m.json"],
    "evaluate": ["evaluate", "none.csv", "--survey", "none.csv"],
    "simulate": ["simulate", "none.json", "--poses", "none.csv", "--out", "sim"],
    "import.carmen": ["import", "carmen", "none.log", "--out", "x.mcap"],
}
OTHER_KEYS = ["map", "initial", "survey", "format", "readings", "seed", "laser", "out", "grid_m",
              "Grid-M", "", "run", "iterations.x", "tolerance-ms "]  # fmt: skip

scalars = st.one_of(
    st.booleans(),
    st.integers(-(2**63), 2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(ODD_TOKENS),
    st.text(max_size=20),
)
values = st.one_of(scalars, st.lists(scalars, max_size=3), st.dates(), st.just({"a": 1}))
tables = st.dictionaries(st.sampled_from([*SETTINGS, *OTHER_KEYS]), values, max_size=4)


def _run(argv: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            main(argv)
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
    return code, err.getvalue()


def _check(text: bytes, argv: list[str]) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "config.toml"
        path.write_bytes(text)
        with contextlib.chdir(folder):
            code, err = _run([*argv, "--config", str(path)])
    lines = [line for line in err.splitlines() if not line.startswith("segloc: warning:")]
    assert code == 2, f"exit {code} for {text!r}: {err}"
    assert len(lines) == 1 and lines[0].startswith("segloc: error:"), err


@given(command=st.sampled_from(sorted(COMMANDS)), table=tables)
@fuzz_settings
def test_random_tables_are_read_or_refused_in_one_line(command, table):
    document: dict = {}
    holder = document
    *groups, name = command.split(".")
    for group in groups:
        holder = holder.setdefault(group, {})
    holder[name] = table
    _check(tomli_w.dumps(document).encode(), COMMANDS[command])


@given(command=st.sampled_from(sorted(COMMANDS)), text=st.binary(max_size=200))
@fuzz_settings
def test_random_bytes_as_config_are_refused_in_one_line(command, text):
    _check(text, COMMANDS[command])
