"""Every fenced block of README.md and of the pages in docs/, run as written, in order, as a
reader would.

``PAGES`` lists the blocks of each Markdown page (README.md and every docs/*.md) in the order
they appear, and says how each is checked. Each page runs on its own, top to bottom, in a
temporary copy of the repository's layout (its ``datasets/`` and the files the page shows,
such as ``sweep.toml``), with ``segloc`` on PATH from this test's environment, each block
reading what the blocks before it on that page wrote. A command block runs as ``sh -e`` runs
it (in this process where it holds only ``segloc`` commands that leave no process of their
own behind, run through its entry point, files written by a heredoc and ``mkdir -p``:
``run_block``) and must exit with the status its page
gives (0 unless it says otherwise). A block a page prints as a command's output must be
printed by the block before it; a TOML block must be the file it says it is, or be accepted
by the commands its tables name; a synopsis must name every command, each with options it
has. Blocks that need a serial scanner carry a ``# needs a scanner`` comment and run against
``segloc emulate``'s ptys instead; a ``make`` block runs as written, in a copy that also
holds the Makefile, ``pyproject.toml`` and ``examples/``, with a ``.venv`` that stands for
``make setup``'s (this test's environment); blocks on the public logs
(``../shared/datasets``) run under ``make readme-real``, which runs each page that has them
top to bottom beside those logs. A page, or a block on a page,
without an entry here fails ``test_every_block_is_classified``: every block is either run or
skipped with a reason.
"""

from __future__ import annotations

import functools
import itertools
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import click
import pytest
from conftest import SEGLOC, start_emulator, stop_emulator
from junitparser import JUnitXml
from test_cli import Result, run_in_process

from segloc_cli.cli import cli
from segloc_cli.io.maps import read_world
from segloc_cli.io.mcap_log import read_log

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
DATASETS_VARIABLE = "SEGLOC_README_DATASETS"
"""Set by ``make readme-real`` to the folder of the public logs (intel/, aces/, ...)."""
BLOCK_TIMEOUT_S = 600.0
CONFIG_NAME = "FILE.toml"
"""Where a configuration block is written to be read back (its page calls it FILE.toml)."""

RUN = "run"  # runs as written on the shipped data and what earlier blocks wrote
REAL = "real"  # reads the public logs in ../shared/datasets: make readme-real
HARDWARE = "hardware"  # needs a serial scanner: run against emulators' ptys
MAKE = "make"  # a make target needing no more than make setup: run as written
SKIP = "skip"  # not run, for the reason given
OUTPUT = "output"  # what the command block before it prints
FILE = "file"  # a file the repository ships
CONFIG = "config"  # a configuration file: each of its tables read by its command's --config
SYNOPSIS = "synopsis"  # usage lines: every command named, each with options it has
DIAGRAM = "diagram"  # no command, no file (a layout, a frame's bytes)

SHELL_KINDS = (RUN, REAL, HARDWARE, MAKE)
MAKE_FILES = ("Makefile", "pyproject.toml", "examples")
"""What a MAKE block's copy holds besides the page's files, as a fresh clone has them."""
HARDWARE_MARK = "# needs a scanner"


@dataclass(frozen=True)
class Block:
    """A fenced block of a Markdown page: ``line`` of its opening fence (from 1), its info
    string ``lang`` (``sh``, ``toml``, ``text`` or empty) and its ``text``."""

    line: int
    lang: str
    text: str

    @property
    def title(self) -> str:
        return next((s for s in self.text.splitlines() if s.strip()), "")


@dataclass(frozen=True)
class Expect:
    """How one block is checked: its ``kind`` and a fragment it ``holds`` (to tell it apart).

    ``status`` is the exit status the page gives the block; ``why`` a skip's reason;
    ``shipped`` the repository file a FILE block is; ``setup`` prepares the working folder
    before the block runs; ``check`` looks at what it wrote (working folder, environment);
    ``shorten`` replaces option values that would make a HARDWARE block run for minutes.
    """

    kind: str
    holds: str
    status: int = 0
    why: str = ""
    shipped: str = ""
    setup: Callable[[Path], None] | None = None
    check: Callable[[Path, dict[str, str]], None] | None = None
    shorten: tuple[tuple[str, str], ...] = field(default=())


def fenced_blocks(path: Path) -> list[Block]:
    """Every fenced (```) block of the Markdown file at ``path``, in order."""
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks, opened = [], None
    for number, line in enumerate(lines, start=1):
        if opened is None:
            match = re.fullmatch(r"```(\S*)\s*", line)
            if match:
                opened = (number, match.group(1))
        elif re.fullmatch(r"```\s*", line):
            start, lang = opened
            blocks.append(Block(start, lang, "\n".join(lines[start : number - 1]) + "\n"))
            opened = None
    assert opened is None, f"{path.name}: the block opened on line {opened[0]} never closes"
    return blocks


def run_shell(script: str, cwd: Path, env: dict[str, str]) -> Result:
    """``sh -e -c script`` in ``cwd``; every process it leaves behind is ended with it."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(
            ["sh", "-e", "-c", script], cwd=cwd, env=env, stdout=out, stderr=err,
            start_new_session=True,
        )  # fmt: skip
        try:
            code = proc.wait(timeout=BLOCK_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            code = -signal.SIGKILL
        finally:
            try:
                os.killpg(proc.pid, signal.SIGKILL)  # a background process the block left
            except ProcessLookupError:
                pass
            proc.wait()
        out.seek(0)
        err.seek(0)
        return Result(
            code, out.read().decode(errors="replace"), err.read().decode(errors="replace")
        )


IN_PROCESS_COMMANDS = ("localize", "evaluate", "map", "info", "simulate", "import", "sweep")
"""Commands that open no device and leave no process or signal handler of their own behind
once they end (a sweep's local workers end with it): a block of them alone runs through
``segloc``'s entry point in this process (``run_block``)."""
SHELL_SYNTAX = re.compile(r"[|&;<>$`(){}*?~\\\"'=]")
HEREDOC = re.compile(r"cat > ([\w./-]+) <<'(\w+)'")
"""A line that writes the lines after it to a file, as they are (the end word quoted), up to
the end word: ``cat > NAME <<'END'``."""
Step = Callable[[Path, dict[str, str]], Result]
"""A step of a block, run in a folder with an environment."""


def block_steps(script: str) -> list[Step] | None:
    """The steps of a block made of ``IN_PROCESS_COMMANDS`` one a line (with ``\\``
    continuations and ``#`` comments as ``sh`` reads them), files written by ``HEREDOC``
    and folders made by ``mkdir -p``, and no other shell syntax; None for any other block."""
    steps: list[Step] = []
    lines = iter(script.splitlines())
    joined = ""
    for line in lines:
        if not joined and (heredoc := HEREDOC.fullmatch(line.strip())):
            name, end = heredoc.groups()
            text = "".join(f"{body}\n" for body in itertools.takewhile(end.__ne__, lines))
            steps.append(functools.partial(_write, name, text))
            continue
        if line.endswith("\\"):
            joined += line[:-1] + " "
            continue
        words = re.sub(r"(^|\s)#.*", "", joined + line).split()
        joined = ""
        if not words:
            continue
        if any(SHELL_SYNTAX.search(word) for word in words):
            return None
        if words[:2] == ["mkdir", "-p"] and len(words) > 2:
            steps.append(functools.partial(_make_folders, words[2:]))
        elif words[0] == "segloc" and len(words) > 1 and words[1] in IN_PROCESS_COMMANDS:
            steps.append(functools.partial(_in_process, words[1:]))
        else:
            return None
    return steps or None


def _write(name: str, text: str, cwd: Path, env: dict[str, str]) -> Result:
    (cwd / name).write_text(text, encoding="utf-8")
    return Result(0, "", "")


def _make_folders(names: list[str], cwd: Path, env: dict[str, str]) -> Result:
    for name in names:
        (cwd / name).mkdir(parents=True, exist_ok=True)
    return Result(0, "", "")


def _in_process(argv: list[str], cwd: Path, env: dict[str, str]) -> Result:
    return run_in_process(*argv, cwd=cwd, env=env)


def run_block(script: str, cwd: Path, env: dict[str, str]) -> Result:
    """``script`` as ``sh -e`` runs it in ``cwd`` with ``env``: in this process, ``segloc``
    commands through its entry point, where ``block_steps`` can take the block apart (which
    saves each command its start-up), else by ``sh``. Either way the block stops at its
    first step that fails, with that status."""
    steps = block_steps(script)
    if steps is None:
        return run_shell(script, cwd, env)
    said = []
    for step in steps:
        said.append(step(cwd, env))
        if said[-1].code != 0:
            break
    return Result(said[-1].code, "".join(r.out for r in said), "".join(r.err for r in said))


# ------------------------------------------------------------------- what blocks wrote


def ci_reports(repo: Path, env: dict[str, str]) -> None:
    """The JUnit file has a case per surveyed pose and per gate, the baseline's failed; the
    step summary is appended to, the earlier steps' text kept."""
    suite = next(iter(JUnitXml.fromfile(str(repo / "out" / "ci" / "amcl.xml"))))
    names = [case.name for case in suite]
    assert names[:10] == [f"pose {i}" for i in range(1, 11)], names
    failed = [case.name for case in suite if not case.is_passed]
    assert "gate: RMS |XY| worse than the baseline's by ≤ 1 cm" in failed, failed
    assert suite.failures == len(failed) == 8
    summary = Path(env["GITHUB_STEP_SUMMARY"]).read_text(encoding="utf-8")
    assert summary.startswith("earlier steps\n"), summary[:200]
    assert "### segloc evaluate: FAIL" in summary


def office_simulation(repo: Path, env: dict[str, str]) -> None:
    """The world example's log is scanned by its world's sensor: a SICK-like fan of 361
    beams over 180°, glass on, no clutter."""
    assert read_world(repo / "office.json").sensor == {
        "readings": 361, "fov_deg": 180, "clutter": False,
    }  # fmt: skip
    log = read_log(repo / "office-sim" / "log.mcap")
    assert {len(s) for s in log.scans} == {361}
    assert log.sensor["device"] == "simulated scanner" and log.sensor["clutter"] == "off"


def hall_slam(repo: Path, env: dict[str, str]) -> None:
    """The hall mapped from its odometry (its evaluate's gate has held the test scans to
    1 cm and 0.2°): every pose within 2 cm and 0.2° of the survey, every segment within
    2 cm of the map built at the surveyed poses, and every segment of a metre or more
    within 2 cm of the world's wall it stands for (shorter ones are column faces and
    passers-by, as in the map of the surveyed poses)."""
    import numpy as np
    import pandas as pd

    from segloc_cli.geometry import point_segment_distances
    from segloc_cli.io.maps import read_map

    found = pd.read_csv(repo / "slam-poses.csv")
    survey = pd.read_csv(repo / "datasets/hall/mapping/survey.csv")
    assert found.pose_id.tolist() == survey.pose_id.tolist()
    assert np.hypot(found.x_m - survey.x_m, found.y_m - survey.y_m).max() < 0.02
    assert np.abs((found.theta_deg - survey.theta_deg + 180) % 360 - 180).max() < 0.2
    mapped = read_map(repo / "slam-map.json")
    ends = np.vstack([mapped[:, :2], mapped[:, 2:]])
    surveyed = read_map(repo / "datasets/hall/map.json")
    assert point_segment_distances(ends, surveyed).min(axis=1).max() < 0.02
    # The wall a segment stands for is the world's segment nearest its middle, within
    # 0.3 m (datasets/hall/README.md: the one long segment farther off joins the glass
    # doors to a plant box); its ends are measured to that wall's line (a segment may run
    # on past the wall's end).
    long = mapped[np.hypot(*(mapped[:, 2:] - mapped[:, :2]).T) >= 1.0]
    walls = read_world(repo / "datasets/hall/world.json").segments
    to_wall = point_segment_distances((long[:, :2] + long[:, 2:]) / 2, walls)
    standing = to_wall.min(axis=1) < 0.3
    assert standing.sum() >= 20 and (~standing).sum() <= 1
    long, wall = long[standing], walls[to_wall[standing].argmin(axis=1)]
    along = (wall[:, 2:] - wall[:, :2]) / np.hypot(*(wall[:, 2:] - wall[:, :2]).T)[:, None]
    for end in (long[:, :2], long[:, 2:]):
        offset = end - wall[:, :2]
        assert np.abs(offset[:, 0] * along[:, 1] - offset[:, 1] * along[:, 0]).max() < 0.02


# ------------------------------------------------------------------------ the blocks

PAGES: dict[str, list[Expect]] = {
    "README.md": [
        Expect(
            SKIP,
            "make demo",
            why="long: make demo sets up .venv, then maps and localizes "
            "the hall (about a minute); make test is this suite",
        ),
        Expect(MAKE, "make ci-example"),
        Expect(RUN, "segloc evaluate out/ci/main/"),
        Expect(RUN, "segloc evaluate out/ci/pr/", status=1, check=ci_reports),
        Expect(OUTPUT, "Gate: max position error"),
        Expect(REAL, "segloc import rosbag ../shared/datasets/intel/intel.orig.bag"),
        Expect(RUN, "segloc map build datasets/hall/mapping/log.mcap --initial", check=hall_slam),
        Expect(
            HARDWARE,
            "segloc record --device scip2:/dev/ttyACM0",
            shorten=(("--duration 60", "--duration 1"), ("--scans 500", "--scans 4")),
        ),
        Expect(RUN, "segloc emulate"),
        Expect(SYNOPSIS, "segloc simulate WORLD.json"),
    ],
    "docs/accuracy.md": [],
    "docs/architecture.md": [
        Expect(DIAGRAM, "commands/   parse options"),
        Expect(DIAGRAM, "datasets/hall/"),
    ],
    "docs/ci.md": [
        Expect(MAKE, "make ci-example"),
        Expect(RUN, "segloc evaluate out/ci/main/"),
        Expect(RUN, "segloc evaluate out/ci/pr/", status=1, check=ci_reports),
        Expect(OUTPUT, "| pose "),
    ],
    "docs/configuration.md": [
        Expect(CONFIG, "[map.build]"),
        Expect(RUN, "--config estimates.run.toml"),
    ],
    "docs/evaluation.md": [
        Expect(RUN, "segloc evaluate estimates.csv --survey datasets/hall/survey.csv\n"),
        Expect(RUN, "--plots figures"),
    ],
    "docs/explorer-protocol.md": [
        Expect(DIAGRAM, "A5 5A 02 04"),
        Expect(DIAGRAM, "A5 5A 82 06"),
    ],
    "docs/localization.md": [
        Expect(RUN, "--initial guesses.csv"),
        Expect(REAL, "--track --initial 0,0,0"),
        Expect(RUN, "--mcap run.mcap"),
        Expect(RUN, "segloc info --foxglove-layout"),
    ],
    "docs/logs.md": [
        Expect(REAL, "segloc import carmen"),
        Expect(RUN, "segloc info datasets/hall/log.mcap"),
    ],
    "docs/maps.md": [
        Expect(RUN, "segloc map build datasets/hall/mapping/log.mcap"),
        Expect(REAL, "segloc import rosbag ../shared/datasets/fr079/fr079.orig.bag"),
        Expect(RUN, "segloc map export"),
    ],
    "docs/refusals.md": [],
    "docs/setup.md": [],
    "docs/simulation.md": [
        Expect(RUN, "segloc simulate datasets/hall/world.json"),
        Expect(RUN, "cat > office.json", check=office_simulation),
    ],
    "docs/sweeps.md": [
        Expect(FILE, 'logs = ["datasets/hall/log.mcap"]', shipped="sweep.toml"),
        Expect(RUN, "segloc sweep sweep.toml --out out/sweep.parquet"),
        Expect(
            SKIP,
            "dask scheduler",
            why="needs a Dask cluster: `dask scheduler` and `dask "
            "worker` run until stopped, on its machines; tests/test_sweep.py starts both on "
            "this one and sweeps on them",
        ),
    ],
}
"""Each page's blocks in order. A page or a block added needs its entry here."""

LANGS = {RUN: ("sh",), REAL: ("sh",), HARDWARE: ("sh",), MAKE: ("sh",), SKIP: ("sh",),
         OUTPUT: ("text",), FILE: ("toml",), CONFIG: ("toml",), SYNOPSIS: ("text",),
         DIAGRAM: ("", "text")}  # fmt: skip


def markdown_pages() -> list[str]:
    """README.md and every page of docs/, as paths from the repository's top."""
    return ["README.md", *(f"docs/{p.name}" for p in sorted(DOCS.glob("*.md")))]


def classified(page: str, path: Path | None = None) -> list[tuple[Block, Expect]]:
    """A page's blocks beside their entries (the page read from ``path`` when given);
    AssertionError when they no longer match."""
    blocks, expects = fenced_blocks(path or ROOT / page), PAGES[page]
    listing = "\n".join(f"  line {b.line} ({b.lang or 'no language'}): {b.title}" for b in blocks)
    hint = f"{page}'s blocks are now:\n{listing}\nUpdate PAGES[{page!r}] in {Path(__file__).name}."
    assert len(blocks) == len(expects), (
        f"{page} has {len(blocks)} blocks, PAGES {len(expects)}. {hint}"
    )
    for block, expect in zip(blocks, expects, strict=True):
        where = f"{page} line {block.line} ({block.title!r})"
        assert expect.holds in block.text, f"{where} lacks {expect.holds!r}. {hint}"
        assert block.lang in LANGS[expect.kind], (
            f"{where}: a {expect.kind} block is ```{' or ```'.join(LANGS[expect.kind])}"
        )
        if expect.kind == MAKE:
            assert block.title.startswith("make "), f"{where}: a make block starts with make"
        else:
            assert expect.kind == SKIP or "make " not in block.title, (
                f"{where}: make targets run only as MAKE blocks"
            )
        if expect.kind != REAL:
            assert "../shared/datasets" not in block.text, (
                f"{where} reads the public logs: kind REAL"
            )
        if expect.kind == HARDWARE:
            assert HARDWARE_MARK in block.text, f"{where}: says nothing of the scanner it needs"
        if expect.kind == SKIP:
            assert expect.why, f"{where}: a skipped block needs its reason"
    return list(zip(blocks, expects, strict=True))


def pages_with(*kinds: str) -> list[str]:
    return [page for page, expects in PAGES.items() if any(e.kind in kinds for e in expects)]


def device_paths(text: str) -> dict[str, str]:
    """``--device PROTOCOL:PATH`` options of a command block: {path: protocol}."""
    return {path: protocol for protocol, path in re.findall(r"--device (\w+):(\S+)", text)}


def run_on_emulators(block: Block, expect: Expect, cwd: Path, env: dict[str, str]) -> Result:
    """A HARDWARE block with each device path replaced by the pty of an emulator of its
    protocol, and the option values of ``expect.shorten`` replaced."""
    script, running = block.text, []
    try:
        for path, protocol in device_paths(block.text).items():
            port, proc = start_emulator(protocol)
            running.append(proc)
            script = script.replace(f"{protocol}:{path}", f"{protocol}:{port}")
        for long, short in expect.shorten:
            assert long in script, f"line {block.line} no longer says {long!r}"
            script = script.replace(long, short)
        return run_shell(script, cwd, env)
    finally:
        for proc in running:
            stop_emulator(proc)


def stand_in_for_setup(repo: Path) -> None:
    """``repo/.venv`` as ``make setup`` leaves it, made of this test's environment (its
    ``bin`` and ``lib`` linked, its ``pyvenv.cfg`` copied) and stamped after
    ``pyproject.toml``, so that a make target runs in it and sets nothing up."""
    venv, prefix = repo / ".venv", Path(sys.prefix)
    venv.mkdir()
    (venv / "bin").symlink_to(SEGLOC.parent)
    if (prefix / "pyvenv.cfg").is_file():
        shutil.copy2(prefix / "pyvenv.cfg", venv / "pyvenv.cfg")
        (venv / "lib").symlink_to(prefix / "lib")
    # Setup's two stamps: segloc installed with a first run's kernels, then the extras.
    for step, stamp in enumerate((venv / ".installed-base", venv / ".installed")):
        stamp.touch()
        os.utime(stamp, (stamp.stat().st_mtime + step, stamp.stat().st_mtime + step))
    before = stamp.stat().st_mtime - 60
    os.utime(repo / "pyproject.toml", (before, before))
    up_to_date = subprocess.run(["make", "-q", ".venv/.installed"], cwd=repo, check=False)
    assert up_to_date.returncode == 0, "make would set .venv up again: not in a test"


def significant_lines(text: str) -> list[str]:
    """A TOML text's lines that are not blank or comments alone."""
    return [s.rstrip() for s in text.splitlines() if s.strip() and not s.lstrip().startswith("#")]


def command_tables(table: dict, prefix: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    """The commands a configuration file sets: ``[map.build]`` → ("map", "build")."""
    for key, value in table.items():
        if isinstance(value, dict) and all(isinstance(v, dict) for v in value.values()):
            yield from command_tables(value, (*prefix, key))
        elif isinstance(value, dict):
            yield (*prefix, key)


def leaf_commands(group: click.Group = cli, path: tuple[str, ...] = ()) -> set[tuple[str, ...]]:
    """Every command segloc has, as the words that name it: ("map", "build"), ("info",)."""
    found: set[tuple[str, ...]] = set()
    for name, command in group.commands.items():
        if isinstance(command, click.Group):
            found |= leaf_commands(command, (*path, name))
        else:
            found.add((*path, name))
    return found


def synopsis_problems(text: str) -> list[str]:
    """What a synopsis gets wrong: a ``segloc`` line that names no command or gives an option
    its command lacks, and the commands it leaves out."""
    problems, named = [], set()
    for line in text.replace("\\\n", " ").splitlines():
        words = line.split()
        if not words or words[0] != "segloc":
            continue
        command, path = cli, ()
        while isinstance(command, click.Group) and len(words) > len(path) + 1:
            word = words[len(path) + 1]
            if word not in command.commands:
                break
            command, path = command.commands[word], (*path, word)
        if isinstance(command, click.Group):
            problems.append(f"{line.strip()!r} names no command")
            continue
        named.add(path)
        options = {o for p in command.params for o in (*p.opts, *p.secondary_opts)} | {"--help"}
        unknown = sorted(set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", line)) - options)
        if unknown:
            problems.append(f"segloc {' '.join(path)} has no {', '.join(unknown)}")
    left_out = sorted(" ".join(c) for c in leaf_commands() - named)
    if left_out:
        problems.append(f"names no line for: {', '.join(left_out)}")
    return problems


def failure(page: str, block: Block, what: str, result: Result | None = None) -> str:
    told = f"\nstdout:\n{result.out[-1500:]}\nstderr:\n{result.err[-1500:]}" if result else ""
    return f"{page} line {block.line} ({block.title!r}): {what}{told}"


def run_page(page: str, work: Path, datasets: Path | None) -> list[str]:
    """Run a page's blocks in order in a copy of the repository's layout under ``work``
    (the public logs linked at ``work/shared/datasets`` when ``datasets`` is given; without
    them REAL blocks are left out); the failures, one message per block."""
    expects = PAGES[page]
    repo = work / "repo"
    shutil.copytree(ROOT / "datasets", repo / "datasets")
    for name in {e.shipped for e in expects if e.shipped}:
        shutil.copy2(ROOT / name, repo / name)
    if any(e.kind == MAKE for e in expects):
        for name in MAKE_FILES:
            copy = shutil.copytree if (ROOT / name).is_dir() else shutil.copy2
            copy(ROOT / name, repo / name)
        stand_in_for_setup(repo)
    if datasets is not None:
        (work / "shared").mkdir()
        (work / "shared" / "datasets").symlink_to(datasets.resolve())
    summary = work / "step_summary.md"
    summary.write_text("earlier steps\n", encoding="utf-8")
    env = {
        **os.environ,
        "PATH": f"{SEGLOC.parent}{os.pathsep}{os.environ.get('PATH', '')}",
        "GITHUB_STEP_SUMMARY": str(summary),
    }
    failures: list[str] = []
    printed: Result | None = None
    for block, expect in classified(page):
        if expect.kind == SKIP or (expect.kind == REAL and datasets is None):
            continue
        if expect.kind in SHELL_KINDS:
            if expect.setup is not None:
                expect.setup(repo)
            if expect.kind == HARDWARE:
                printed = run_on_emulators(block, expect, repo, env)
            else:
                printed = run_block(block.text, repo, env)
            if printed.code != expect.status:
                failures.append(
                    failure(page, block, f"exit {printed.code}, not {expect.status}", printed)
                )
            elif expect.check is not None:
                try:
                    expect.check(repo, env)
                except AssertionError as exc:
                    failures.append(failure(page, block, f"wrote what it does not say: {exc}"))
        elif expect.kind == OUTPUT:
            lines = (printed.out + printed.err).splitlines() if printed else []
            missing = [s for s in block.text.splitlines() if s.strip() and s not in lines]
            if missing:
                failures.append(failure(page, block, f"the block before prints no {missing}"))
        elif expect.kind == FILE:
            shipped = (ROOT / expect.shipped).read_text(encoding="utf-8")
            if significant_lines(shipped) != significant_lines(block.text):
                failures.append(failure(page, block, f"differs from {expect.shipped}"))
        elif expect.kind == CONFIG:
            (repo / CONFIG_NAME).write_text(block.text, encoding="utf-8")
            for command in command_tables(tomllib.loads(block.text)):
                script = f"segloc {' '.join(command)} --config {CONFIG_NAME} --help"
                result = run_block(script, repo, env)
                if result.code != 0:
                    failures.append(failure(page, block, f"refused by `{script}`", result))
        elif expect.kind == SYNOPSIS:
            failures += [failure(page, block, problem) for problem in synopsis_problems(block.text)]
    return failures


def test_every_page_is_listed():
    assert sorted(PAGES) == sorted(markdown_pages()), "every page of docs/ needs its PAGES entry"


@pytest.mark.parametrize("page", markdown_pages())
def test_every_block_is_classified(page):
    assert len(classified(page)) == len(PAGES[page])


@pytest.mark.parametrize("page", ["README.md", "docs/architecture.md"])
def test_a_block_added_to_a_page_fails_until_it_is_classified(tmp_path, page):
    copy = tmp_path / "page.md"
    text = (ROOT / page).read_text(encoding="utf-8")
    copy.write_text(text + "\n```sh\nsegloc frobnicate\n```\n", encoding="utf-8")
    with pytest.raises(AssertionError, match="segloc frobnicate"):
        classified(page, copy)


def test_a_synopsis_names_every_command_with_options_it_has():
    good = "\n".join(f"segloc {' '.join(c)}" for c in sorted(leaf_commands()))
    assert synopsis_problems(good) == []
    assert synopsis_problems(good + "\nsegloc map frobnicate X") == [
        "'segloc map frobnicate X' names no command"
    ]
    assert synopsis_problems(good + "\nsegloc localize LOG --frobnicate") == [
        "segloc localize has no --frobnicate"
    ]
    assert synopsis_problems(good.replace("segloc sweep", "")) == ["names no line for: sweep"]


@pytest.mark.parametrize(
    ("page", "expect"),
    [(page, e) for page, expects in PAGES.items() for e in expects if e.kind in (SKIP, REAL)],
    ids=lambda v: v if isinstance(v, str) else v.holds[:40],
)
def test_blocks_make_test_leaves_out(page, expect):
    """Listed so that the report names them: skipped ones with their reason, and those on
    the public logs, which ``make readme-real`` runs."""
    if expect.kind == SKIP:
        pytest.skip(expect.why)
    pytest.skip("reads the public logs in ../shared/datasets: make readme-real runs it")


@pytest.mark.parametrize("page", pages_with(*SHELL_KINDS, OUTPUT, FILE, CONFIG, SYNOPSIS))
def test_every_block_runs_as_written_on_the_shipped_data(tmp_path, page):
    failures = run_page(page, tmp_path, datasets=None)
    assert not failures, "\n\n".join(failures)


@pytest.mark.parametrize("page", pages_with(REAL))
def test_the_page_top_to_bottom_beside_the_public_logs(tmp_path, page):
    """``make readme-real``: every block of a page that reads the public logs but the
    skipped ones, those on the logs included, in one folder beside them, as a reader with
    the logs would run them."""
    datasets = os.environ.get(DATASETS_VARIABLE)
    if not datasets:
        pytest.skip(f"make readme-real runs it (sets {DATASETS_VARIABLE})")
    if not Path(datasets).is_dir():
        pytest.skip(f"{datasets} is not a folder: no public logs to run its blocks on")
    failures = run_page(page, tmp_path, datasets=Path(datasets))
    assert not failures, "\n\n".join(failures)
