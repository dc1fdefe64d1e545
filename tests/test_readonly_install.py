"""An install nobody can write to: the checkout (its venv and package included) and the home
folder mounted read-only in a private mount namespace, where numba can cache no kernel.

A ``localize`` and an ``evaluate`` there give what they give in a writable install; the
first ``localize``, which compiles kernels, says once where it caches them (a private folder
under the temporary directory), and the second loads them from there. Every kernel goes
through the same ``jit.njit``, so those of the run with the fewest, ICP's of one scan (a
dozen, the verdict's: seconds), stand for the others; a default ``localize`` or a ``map
build`` would add up to a minute of compiling and nothing else (that an uncached run starts
no second process is ``test_jit.py``'s). Skipped where the system allows no mount namespace
(``unshare -rm``).
"""

from __future__ import annotations

import os
import shlex
import shutil
import stat
import subprocess
from pathlib import Path

import pandas as pd
import pytest
from conftest import HALL, SEGLOC
from test_cli import run_in_turn

from segloc_cli.estimates import ESTIMATE_COLUMNS
from segloc_cli.jit import AHEAD_ENV, PRIVATE_CACHE_PREFIX

REPO = Path(__file__).resolve().parents[1]


def _namespaced(script: str, home: Path) -> list[str]:
    """A command running ``script`` (bash) with ``REPO`` and ``home`` read-only."""
    mounts = " && ".join(
        f"mount --bind {shlex.quote(str(p))} {shlex.quote(str(p))} && "
        f"mount -o remount,ro,bind {shlex.quote(str(p))}"
        for p in (REPO, home)
    )
    return ["unshare", "-rm", "bash", "-c", f"{mounts} && {script}"]


def _can_unshare() -> bool:
    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "-rm", "true"], capture_output=True, check=False)
    return probe.returncode == 0


def _survey_as_estimates(path: Path) -> Path:
    """The hall's survey written as a run's answers (every other column empty)."""
    survey = pd.read_csv(HALL / "survey.csv")
    answers = survey.reindex(columns=ESTIMATE_COLUMNS).assign(
        status="ok", n_local_segments=9, window_scans=1
    )
    answers.to_csv(path, index=False)
    return path


def _commands(out: Path, estimates: Path) -> str:
    """ICP's localize of the shipped hall's first scan from its surveyed pose, and evaluate of
    ``estimates``, writing into ``out``."""
    segloc, q = shlex.quote(str(SEGLOC)), shlex.quote
    return " && ".join(
        [
            f"{segloc} localize {q(str(HALL / 'log.mcap'))} --map {q(str(HALL / 'map.json'))} "
            f"--method icp --scans 1 --initial {q(str(HALL / 'survey.csv'))} "
            f"--out {q(str(out / 'estimates.csv'))}",
            f"{segloc} evaluate {q(str(estimates))} "
            f"--survey {q(str(HALL / 'survey.csv'))} > {q(str(out / 'table.txt'))}",
        ]
    )


def _answers(path: Path) -> pd.DataFrame:
    """A run's estimates less what differs between any two runs (their time)."""
    return pd.read_csv(path).drop(columns="runtime_ms")


@pytest.mark.skipif(not _can_unshare(), reason="no private mount namespace (unshare -rm)")
def test_a_read_only_install_caches_its_kernels_privately_with_the_same_results(tmp_path):
    home, temp, locked, again, free = (
        tmp_path / name for name in ("home", "temp", "locked", "again", "free")
    )
    for folder in (home, temp, locked, again, free):
        folder.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env |= {"HOME": str(home), "XDG_CACHE_HOME": str(home / ".cache"), "TMPDIR": str(temp)}
    estimates = _survey_as_estimates(tmp_path / "estimates.csv")

    def run_locked(out: Path, **extra: str) -> subprocess.CompletedProcess:
        script = f"cd {shlex.quote(str(REPO))} && {_commands(out, estimates)}"
        return subprocess.run(
            _namespaced(script, home),
            capture_output=True,
            text=True,
            env=env | extra,
            check=False,
        )

    # As if compiling ahead already: ICP needs none of the later stages' kernels.
    first = run_locked(locked, **{AHEAD_ENV: "compiling"})
    assert first.returncode == 0, first.stderr
    (cache,) = temp.iterdir()
    assert cache.name.startswith(PRIVATE_CACHE_PREFIX)
    assert stat.S_IMODE(cache.stat().st_mode) == 0o700
    assert any(cache.rglob("*.nbi"))
    # Said once, by localize (evaluate loads no kernel), naming the folder.
    assert first.stderr.count("segloc caches its compiled kernels in") == 1
    assert first.stderr.count(str(temp)) == 1
    assert "each run compiles" not in first.stderr
    assert not any(home.iterdir())
    second = run_locked(again)
    assert second.returncode == 0, second.stderr
    # Every kernel loaded from there: nothing compiled, nothing said.
    assert "compiling" not in second.stderr
    assert "numba" not in second.stderr
    subprocess.run(["bash", "-c", _commands(free, estimates)], check=True, capture_output=True)
    answers = _answers(locked / "estimates.csv")
    assert answers["status"].tolist() == ["ok"]
    pd.testing.assert_frame_equal(answers, _answers(free / "estimates.csv"))
    pd.testing.assert_frame_equal(_answers(again / "estimates.csv"), answers)
    assert (locked / "table.txt").read_text() == (free / "table.txt").read_text()


def _unloaded_by(package: str, commands: list[list], cwd: Path) -> None:
    """Each of ``commands`` (``segloc`` arguments) runs in turn in one process and exits 0,
    and ``package`` is not imported by the end."""
    said, modules = run_in_turn({" ".join(map(str, c)): c for c in commands}, cwd=cwd)
    for name, result in said.items():
        assert result.code == 0, f"segloc {name}: {result.err}"
    assert package not in modules, sorted(m for m in modules if m.startswith("segloc_cli"))


def test_commands_that_need_no_kernel_load_none(tmp_path):
    """Scoring, inspecting, importing and exporting never import numba, so they start fast
    and cannot meet a kernel cache problem."""
    carmen = tmp_path / "two.clf"
    carmen.write_text(
        "".join(f"FLASER 181 {' '.join(['2.0'] * 181)} 0 0 0 0 0 0 {t} host {t}\n" for t in (1, 2))
    )
    _survey_as_estimates(tmp_path / "estimates.csv")
    commands = [
        ["evaluate", tmp_path / "estimates.csv", "--survey", HALL / "survey.csv"],
        ["info", HALL / "log.mcap"],
        ["import", "carmen", carmen, "--out", tmp_path / "two.mcap"],
        ["map", "export", HALL / "map.json", "--out", tmp_path / "map.yaml"],
    ]
    _unloaded_by("numba", commands, tmp_path)


def test_building_a_map_and_localizing_load_no_pandas(tmp_path):
    """Nor do ``map build`` and ``localize`` import pandas (a third of a second), which only
    reading estimates and scoring need."""
    commands = [
        ["map", "build", HALL / "mapping/log.mcap", "--survey", HALL / "mapping/survey.csv",
         "--out", tmp_path / "map.json", "--end", "20"],
        ["localize", HALL / "log.mcap", "--map", tmp_path / "map.json", "--scans", "2",
         "--initial", HALL / "survey.csv", "--out", tmp_path / "estimates.csv",
         "--tum", tmp_path / "estimates.tum"],
    ]  # fmt: skip
    _unloaded_by("pandas", commands, tmp_path)
