"""``segloc sweep``: the spec checked, the same rows on a local cluster, on a scheduler started
from the command line and in-process, resume, interruption and failed tasks."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import HALL, SEGLOC, made_once
from test_cli import Result, assert_one_line_error, run_cli, run_in_process

from segloc_cli.estimates import STATUS_TASK_FAILED
from segloc_cli.io.tables import read_pose_table
from segloc_cli.runs.sweep import ResultStore, Task, connect, run_task, run_tasks, summary
from segloc_cli.runs.sweepspec import read_spec

SPEC = """\
map = "hall/map.json"
logs = ["hall/log.mcap"]
survey = "hall/survey.csv"
init-errors = "uniform:1.5,20"
seeds = [1, 2]

[grid]
iterations = [6, 8]
grid-m = [1.0, 1.5]
"""
"""The issue's example spec, with the hall copied beside it."""
TASKS, SCANS = 8, 10


def _spec(folder: Path, text: str = SPEC) -> Path:
    """``text`` as ``folder/sweep.toml``, the hall's files in ``folder/hall``."""
    hall = folder / "hall"
    if not hall.exists():
        hall.mkdir(parents=True)
        for name in ("map.json", "log.mcap", "survey.csv"):
            shutil.copy(HALL / name, hall / name)
    path = folder / "sweep.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _sweep(*args: object, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(SEGLOC), "sweep", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
        env={**os.environ, "PYTHONIOENCODING": "utf-8"},
    )


def _sweep_here(*args: object) -> Result:
    """``segloc sweep ARGS`` in this process (``run_in_process``); its Dask workers are
    processes of their own all the same."""
    return run_in_process("sweep", *args)


def _without_times(table: pd.DataFrame) -> pd.DataFrame:
    return table.drop(columns="runtime_ms").reset_index(drop=True)


@pytest.fixture(scope="module")
def hall_sweep(tmp_path_factory):
    """The example spec run on a local cluster of 2 workers, once a session, in a copy of
    this worker's own: (spec, results, in-process rows, what the sweep said)."""

    def make(folder: Path) -> None:
        spec = _spec(folder)
        done = _sweep(spec, "--out", folder / "results.parquet", "--jobs", "2")
        assert done.returncode == 0, done.stderr
        (folder / "stdout.txt").write_text(done.stdout, encoding="utf-8")
        (folder / "stderr.txt").write_text(done.stderr, encoding="utf-8")
        tasks = read_spec(spec).tasks
        in_process = pd.concat([run_task(t) for t in tasks], ignore_index=True)
        in_process.to_parquet(folder / "in-process.parquet", index=False)

    folder = tmp_path_factory.mktemp("sweep") / "copy"
    shutil.copytree(made_once(tmp_path_factory, "hall-sweep", make), folder)
    said = [(folder / name).read_text(encoding="utf-8") for name in ("stdout.txt", "stderr.txt")]
    done = subprocess.CompletedProcess([], 0, *said)
    in_process = pd.read_parquet(folder / "in-process.parquet")
    return folder / "sweep.toml", folder / "results.parquet", in_process, done


def test_a_local_cluster_gives_the_rows_of_an_in_process_run(hall_sweep):
    _, out, in_process, done = hall_sweep
    table = pd.read_parquet(out)
    assert len(table) == TASKS * SCANS == 80
    pd.testing.assert_frame_equal(_without_times(table), _without_times(in_process))
    assert (table["runtime_ms"] > 0).all()
    assert "segloc: sweep: 8 tasks; running 8 on a local cluster of 2 workers" in done.stderr
    said = [line for line in done.stderr.splitlines() if line.strip()]
    assert said and all(line.startswith("segloc: ") for line in said), done.stderr
    assert out.with_name("results.run.toml").is_file()
    assert not out.with_name("results.parquet.parts").exists()


def test_rows_score_each_estimate_against_its_survey_pose(hall_sweep):
    spec, out, _, _ = hall_sweep
    table = pd.read_parquet(out)
    survey = read_pose_table(spec.parent / "hall" / "survey.csv")
    truth = dict(zip(survey.pose_id, survey.poses, strict=True))
    poses = np.array([truth[i] for i in table["pose_id"]])
    np.testing.assert_allclose(table["err_x_cm"], 100 * (poses[:, 0] - table["x_m"]), atol=1e-9)
    np.testing.assert_allclose(table["err_y_cm"], 100 * (poses[:, 1] - table["y_m"]), atol=1e-9)
    heading = (np.rad2deg(poses[:, 2]) - table["theta_deg"] + 180) % 360 - 180
    np.testing.assert_allclose(table["err_theta_deg"], heading, atol=1e-9)
    # The guesses: the survey less errors within ±1.5 m and ±20°, one draw per seed that
    # every combination shares.
    off = np.abs(poses[:, :2] - table[["init_x_m", "init_y_m"]].to_numpy())
    assert off.max() <= 1.5 and off.max() > 0.5
    turn = np.abs((np.rad2deg(poses[:, 2]) - table["init_theta_deg"] + 180) % 360 - 180)
    assert turn.max() <= 20 and turn.max() > 5
    guesses = table.groupby(["seed", "pose_id"])["init_x_m"].nunique()
    assert (guesses == 1).all()
    by_seed = table[table["combination"] == 0].pivot(
        index="pose_id", columns="seed", values="init_x_m"
    )
    assert (by_seed[1] != by_seed[2]).all()
    assert set(zip(table["iterations"], table["grid-m"], strict=True)) == {
        (6, 1.0), (6, 1.5), (8, 1.0), (8, 1.5)
    }  # fmt: skip


def test_the_summary_has_a_row_per_combination(hall_sweep, tmp_path):
    spec, out, _, done = hall_sweep
    lines = [line for line in done.stdout.splitlines() if line.startswith("| ")]
    assert len(lines) == 1 + 4  # header and one row per combination
    again = _sweep_here(spec, "--out", out, "--format", "json")
    assert again.code == 0, again.err
    assert "nothing to run" in again.err
    rows = json.loads(again.out)
    assert [(r["iterations"], r["grid-m"], r["poses"], r["tasks"]) for r in rows] == [
        (6, 1.0, 20, 2), (6, 1.5, 20, 2), (8, 1.0, 20, 2), (8, 1.5, 20, 2)
    ]  # fmt: skip
    table = pd.read_parquet(out)
    within = (table["err_x_cm"].abs() <= 10) & (table["err_y_cm"].abs() <= 10)
    within &= (table["err_theta_deg"].abs() <= 1) & (table["status"] == "ok")
    expected = within.groupby(table["combination"]).mean() * 100
    assert [r["within gates %"] for r in rows] == pytest.approx(list(expected))


def _scheduler(folder: Path) -> tuple[str, list[subprocess.Popen]]:
    """A Dask scheduler and one `dask worker` command of one worker process, as a user
    starts them; (the scheduler's address, the processes)."""
    dask = SEGLOC.parent / "dask"
    file = folder / "scheduler.json"
    common = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "start_new_session": True}
    scheduler = subprocess.Popen(
        [dask, "scheduler", "--scheduler-file", file, "--port", "0", "--dashboard-address", ":0"],
        **common,
    )
    workers = subprocess.Popen(
        [dask, "worker", "--scheduler-file", file, "--nworkers", "1", "--nthreads", "1",
         "--dashboard-address", ":0"],
        **common,
    )  # fmt: skip
    processes = [workers, scheduler]
    deadline = time.monotonic() + 60
    address = None
    while address is None and time.monotonic() < deadline:
        try:  # the scheduler writes the file in place: it may be there but not whole yet
            address = json.loads(file.read_text())["address"]
        except (FileNotFoundError, json.JSONDecodeError, KeyError):
            time.sleep(0.2)
    assert address is not None, f"no scheduler address in {file} after 60 s"
    from distributed import Client

    with Client(address, timeout="30s") as client:
        client.wait_for_workers(1, timeout=60)
    return address, processes


def test_a_scheduler_started_from_the_command_line_gives_the_same_rows(hall_sweep, tmp_path):
    spec, out, _, _ = hall_sweep
    address, processes = _scheduler(tmp_path)
    try:
        remote = tmp_path / "remote.parquet"
        done = _sweep_here(spec, "--out", remote, "--scheduler", address)
    finally:
        for proc in processes:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=30)
    assert done.code == 0, done.err
    assert f"running 8 on the cluster at {address}" in done.err
    local, cluster = pd.read_parquet(out), pd.read_parquet(remote)
    assert len(cluster) == 80
    pd.testing.assert_frame_equal(_without_times(cluster), _without_times(local))


def test_a_rerun_runs_only_the_tasks_missing(hall_sweep, dask_scheduler, tmp_path):
    spec, out, _, _ = hall_sweep
    full = pd.read_parquet(out)
    partial = tmp_path / "results.parquet"
    keys = list(dict.fromkeys(full["task"]))
    full[~full["task"].isin(keys[2:5])].to_parquet(partial, index=False)
    done = _sweep_here(spec, "--out", partial, "--scheduler", dask_scheduler)
    assert done.code == 0, done.err
    assert "8 tasks, 5 done before; running 3" in done.err
    again = pd.read_parquet(partial)
    pd.testing.assert_frame_equal(_without_times(again), _without_times(full))
    kept = again["task"].isin(set(keys) - set(keys[2:5]))
    assert (again.loc[kept, "runtime_ms"].to_numpy() == full.loc[kept, "runtime_ms"]).all()


def test_results_of_another_spec_are_not_mixed_in(hall_sweep, tmp_path):
    spec, out, _, _ = hall_sweep
    other = _spec(spec.parent, SPEC.replace("seeds = [1, 2]", "seeds = [3]"))
    try:
        done = _sweep_here(other, "--out", out)
    finally:
        _spec(spec.parent)
    assert done.code == 2
    assert "holds 8 tasks this spec does not plan" in done.err
    assert "--force" in done.err


GLOBAL_SPEC = (
    SPEC.replace('init-errors = "uniform:1.5,20"', "global = true")
    .replace(
        "iterations = [6, 8]\ngrid-m = [1.0, 1.5]", "search-heading-step-deg = [1.5, 2.0, 2.5, 3.0]"
    )
    .replace("seeds = [1, 2]", "seeds = [1]")
)
"""Tasks (global searches, a few tenths of a second each) enough that a sweep stopped as its
first is kept has some left, however fast the machine and its 0.5 s between looks at a stop."""
GLOBAL_TASKS = 4


@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_stopped_sweep_keeps_every_finished_task(dask_scheduler, tmp_path, how):
    spec = _spec(tmp_path, GLOBAL_SPEC)
    out = tmp_path / "results.parquet"
    parts = tmp_path / "results.parquet.parts"
    proc = subprocess.Popen(
        [str(SEGLOC), "sweep", spec, "--out", out, "--jobs", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 180
        while not list(parts.glob("*.parquet")) and time.monotonic() < deadline:
            time.sleep(0.05)
        if how == signal.SIGKILL:
            os.killpg(proc.pid, how)  # the sweep and its workers, as an OOM killer might
        else:
            proc.send_signal(how)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    if how == signal.SIGTERM:
        assert proc.returncode == 130, err
        assert "Traceback" not in err
        held = pd.read_parquet(out)["task"].nunique()
        assert 1 <= held < GLOBAL_TASKS
        assert f"interrupted (SIGTERM) with {held} of {GLOBAL_TASKS} tasks" in err
        assert not parts.exists()
    else:
        assert proc.returncode == -signal.SIGKILL
        assert not out.exists()
        held = len(list(parts.glob("*.parquet")))
        assert 1 <= held < GLOBAL_TASKS
    done = _sweep_here(spec, "--out", out, "--scheduler", dask_scheduler)
    assert done.code == 0, done.err
    left = GLOBAL_TASKS - held
    assert f"{GLOBAL_TASKS} tasks, {held} done before; running {left}" in done.err
    table = pd.read_parquet(out)
    assert len(table) == GLOBAL_TASKS * SCANS and (table["status"] != STATUS_TASK_FAILED).all()
    assert list(dict.fromkeys(table["task"])) == [t.key for t in read_spec(spec).tasks]


def test_a_failing_task_is_kept_with_its_error_and_the_sweep_goes_on(dask_scheduler, tmp_path):
    text = SPEC.replace('logs = ["hall/log.mcap"]', 'logs = ["hall/log.mcap", "broken.mcap"]')
    spec = _spec(tmp_path, text.replace("grid-m = [1.0, 1.5]\n", ""))  # 2 × 2 tasks a log
    (tmp_path / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\0" * 64)
    out = tmp_path / "results.parquet"
    curves = tmp_path / "curves"
    done = _sweep_here(spec, "--out", out, "--scheduler", dask_scheduler, "--convergence", curves)
    assert done.code == 1, done.err
    assert "Traceback" not in done.err
    # Curves of a sweep with failed tasks would be of part of it: none until the rerun.
    assert "no convergence curves of a sweep with failed tasks" in done.err
    assert not list(tmp_path.glob("curves.*"))
    table = pd.read_parquet(out)
    failed = table[table["status"] == STATUS_TASK_FAILED]
    assert len(failed) == 4 and set(failed["log"]) == {"broken.mcap"}
    assert failed["error"].str.contains("broken.mcap").all()
    assert (table.loc[table["log"] == "hall/log.mcap", "status"] == "ok").sum() == 4 * SCANS
    assert "4 tasks failed" in done.err
    # Mended, only the failed tasks run again.
    shutil.copy(HALL / "log.mcap", tmp_path / "broken.mcap")
    again = _sweep_here(spec, "--out", out, "--scheduler", dask_scheduler, "--convergence", curves)
    assert again.code == 0, again.err
    assert "8 tasks, 4 done before; running 4" in again.err
    assert len(pd.read_parquet(out)) == 8 * SCANS
    assert sorted(p.name for p in tmp_path.glob("curves.*")) == ["curves.md", "curves.pdf",
                                                                 "curves.png"]  # fmt: skip


def test_a_failed_task_is_tried_once_more_then_recorded(dask_scheduler, tmp_path):
    tasks = read_spec(_spec(tmp_path)).tasks[:2]  # seeds 1 and 2 of one combination
    counters = [tmp_path / f"attempts-{t.seed}" for t in tasks]
    runs = [replace(t, log_path=c) for t, c in zip(tasks, counters, strict=True)]
    store = ResultStore(tmp_path / "results.parquet")
    with connect(dask_scheduler, 1) as client:
        work = _flaky(tmp_path / "hall" / "log.mcap")
        run_tasks(client, runs, store, lambda: None, lambda: False, work=work)
    table = store.finish([t.key for t in tasks])
    assert [c.read_text() for c in counters] == ["2", "2"]
    ok = table[table["seed"] == 1]
    assert len(ok) == SCANS and (ok["status"] == "ok").all()
    failed = table[table["seed"] == 2]
    assert len(failed) == 1 and failed["status"].iloc[0] == STATUS_TASK_FAILED
    assert failed["error"].iloc[0] == "RuntimeError: attempt 2 fails on two lines"
    assert ResultStore(tmp_path / "results.parquet").done() == {tasks[0].key}


def _flaky(log: Path):
    """A task runner that fails on each task's first attempt (counted in the file its
    ``log_path`` names) and on every attempt of seed 2, and else runs the task on ``log``."""

    def work(task: Task) -> pd.DataFrame:
        attempts = task.log_path
        count = int(attempts.read_text()) + 1 if attempts.exists() else 1
        attempts.write_text(str(count))
        if count == 1 or task.seed == 2:
            raise RuntimeError(f"attempt {count} fails\non two lines")
        return run_task(replace(task, log_path=log))

    return work


@pytest.mark.parametrize(
    ("change", "fragments"),
    [
        (("iterations = [6, 8]", "iteration = [6, 8]"), ["unknown [grid] key 'iteration'",
                                                       "did you mean 'iterations'?"]),
        (("seeds = [1, 2]", "seeds = [1, 2]\nwindow = 3"), ["unknown key 'window'"]),
        (("iterations = [6, 8]", "iterations = [0, 8]"), ["key 'iterations'", "0"]),
        (("iterations = [6, 8]", "iterations = 6"), ["[grid] key 'iterations' takes a list"]),
        (("iterations = [6, 8]", "iterations = [6, 6]"), ["lists a value twice"]),
        (("seeds = [1, 2]", "seeds = [1, 2]\niterations = 8"), ["both fixed and in [grid]"]),
        (("seeds = [1, 2]", "seeds = [1.5]"), ["key 'seeds' takes a list of distinct whole"]),
        (("seeds = [1, 2]", "seeds = [1, -1]"), ["key 'seeds'", "from 0 to"]),
        (("seeds = [1, 2]", f"seeds = [{2**63}]"), ["key 'seeds'", "from 0 to"]),
        (("seeds = [1, 2]", 'seeds = [1]\ninitial = "guesses.csv"'), ["not both"]),
        (('"uniform:1.5,20"', '"uniform:1.5"'), ["key 'init-errors'", "uniform:XY_M,THETA_DEG"]),
        (("hall/log.mcap", "hall/nowhere.mcap"), ["nowhere.mcap does not exist"]),
        (("seeds = [1, 2]", "seeds = [1]\nmethod = \"icp\"\nglobal = true"),
         ["--method icp cannot be combined with --global"]),
        (("seeds = [1, 2]", "seeds = [1]\ntrack = true"), ["unknown key 'track'"]),
        (("seeds = [1, 2]", "seeds = [1]\n[localize]\nx = 1"), ["table [localize] is no part"]),
        (('logs = ["hall/log.mcap"]', 'logs = [{path = "hall/log.mcap", mapp = "m.json"}]'),
         ["a log's table takes path, map, survey, not 'mapp'"]),
    ],
    ids=["grid-key", "top-key", "bad-value", "not-a-list", "twice", "fixed-and-grid",
         "seeds", "negative-seed", "seed-beyond-int64", "guesses-twice", "init-errors",
         "missing-log", "modes", "track", "other-table", "log-table"],
)  # fmt: skip
def test_a_bad_spec_is_one_line_naming_what_is_wrong(tmp_path, capsys, change, fragments):
    spec = _spec(tmp_path, SPEC.replace(*change))
    result = run_cli(capsys, "sweep", spec, "--out", tmp_path / "results.parquet")
    assert_one_line_error(result, *fragments)
    assert not (tmp_path / "results.parquet").exists()


def test_per_log_maps_and_surveys(tmp_path):
    text = SPEC.replace(
        'logs = ["hall/log.mcap"]',
        'logs = ["hall/log.mcap", {path = "again/log.mcap", map = "again/map.json", '
        'survey = "again/survey.csv"}]',
    )
    spec = _spec(tmp_path, text)
    shutil.copytree(tmp_path / "hall", tmp_path / "again")
    tasks = read_spec(spec).tasks
    assert len(tasks) == 2 * TASKS
    assert [t.log for t in tasks[::TASKS]] == ["hall/log.mcap", "again/log.mcap"]
    assert tasks[TASKS].log_path == (tmp_path / "again" / "log.mcap").resolve()
    # The same bytes, but a draw of its own for the second log: other guesses, other keys.
    assert len({t.key for t in tasks}) == 2 * TASKS
    first, second = tasks[0].guesses.poses, tasks[TASKS].guesses.poses
    assert not np.allclose(first, second)


def test_survey_poses_without_a_scan_or_guess_are_misses(tmp_path):
    guessed = SPEC.replace('init-errors = "uniform:1.5,20"', 'initial = "guesses.csv"')
    spec = _spec(tmp_path, guessed)
    survey = (tmp_path / "hall" / "survey.csv").read_text().splitlines()
    # A pose between two scans (no scan within 50 ms), and a guess file lacking pose 3.
    (tmp_path / "hall" / "survey.csv").write_text(
        "\n".join([*survey, "11,2.5,12.0,8.0,0.0", "12,99.0,12.0,8.0,0.0"]) + "\n"
    )
    (tmp_path / "guesses.csv").write_text(
        "\n".join(line for k, line in enumerate(survey) if k != 3) + "\n"
    )
    table = run_task(read_spec(spec).tasks[0])
    statuses = dict(zip(table["pose_id"], table["status"], strict=True))
    assert statuses[3] == "no guess" and statuses[11] == "no scan"
    assert 12 not in statuses, "a pose after the log's last scan belongs to another log"
    assert list(table["pose_id"]) == list(range(1, 12))  # survey order
    assert table["x_m"][table["status"].isin(["no guess", "no scan"])].isna().all()
    stats = summary(table, ("iterations", "grid-m"), 10.0, 1.0)
    assert stats["poses"].iloc[0] == 11
    assert stats["within gates %"].iloc[0] == pytest.approx(100 * 9 / 11)
    # 2 of 11 without an estimate: the median is finite, the 95th percentile is not.
    assert np.isfinite(stats["median cm"].iloc[0]) and np.isinf(stats["p95 cm"].iloc[0])


def test_an_output_that_is_no_sweep_is_refused_not_overwritten(tmp_path, capsys):
    spec = _spec(tmp_path)
    out = tmp_path / "results.parquet"
    out.write_text("pose_id,x_m\n1,2.0\n")
    result = run_cli(capsys, "sweep", spec, "--out", out)
    assert_one_line_error(result, "results.parquet", "is not a sweep's results", "--force")
    assert out.read_text() == "pose_id,x_m\n1,2.0\n"


def test_jobs_sets_the_local_cluster_only(tmp_path, capsys):
    spec = _spec(tmp_path)
    result = run_cli(capsys, "sweep", spec, "--out", tmp_path / "r.parquet", "--jobs", "2",
                     "--scheduler", "tcp://127.0.0.1:8786")  # fmt: skip
    assert result.code == 2 and "--jobs sets the local cluster" in result.err


@pytest.mark.parametrize(
    ("out", "fragment"),
    [("hall/log.mcap", "is an input of this command"),
     ("sweep.toml", "is an input of this command"),
     ("nowhere/results.parquet", "does not exist")],
    ids=["log", "spec", "missing-folder"],
)  # fmt: skip
def test_an_output_that_cannot_be_written_is_refused_before_any_work(
    tmp_path, capsys, out, fragment
):
    spec = _spec(tmp_path)
    target = tmp_path / out
    before = target.read_bytes() if target.exists() else None
    result = run_cli(capsys, "sweep", spec, "--out", target, "--force")
    assert_one_line_error(result, fragment)
    assert (target.read_bytes() if target.exists() else None) == before


def _md_counts(text: str, combination: str, unit: str) -> list[tuple[int, int]]:
    """(trials, successes) of each bin of one combination and axis in a convergence table."""
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in text.splitlines()]
    return [
        (int(row[2]), int(row[3]))
        for row in cells
        if len(row) == 6 and row[0] == combination and row[1].endswith(unit)
    ]


def test_convergence_curves_count_successes_by_initial_error(hall_sweep, tmp_path, capsys):
    spec, out, _, _ = hall_sweep
    results = tmp_path / "results.parquet"
    shutil.copy(out, results)
    prefix = tmp_path / "curves"
    done = run_cli(capsys, "sweep", spec, "--out", results, "--convergence", prefix)
    assert done.code == 0, done.err
    assert "nothing to run" in done.err and "convergence curves: written to" in done.err
    assert prefix.with_suffix(".png").read_bytes()[:4] == b"\x89PNG"
    assert prefix.with_suffix(".pdf").read_bytes()[:4] == b"%PDF"
    text = prefix.with_suffix(".md").read_text(encoding="utf-8")
    # Counted here from the survey itself, with numpy's histogram (bins hold their lower
    # edge, the last one its upper edge too).
    table = pd.read_parquet(results)
    survey = read_pose_table(spec.parent / "hall" / "survey.csv")
    truth = dict(zip(survey.pose_id, survey.poses, strict=True))
    poses = np.array([truth[i] for i in table["pose_id"]])
    off_m = np.hypot(*(poses[:, :2] - table[["init_x_m", "init_y_m"]].to_numpy()).T)
    turn_deg = np.abs((np.rad2deg(poses[:, 2]) - table["init_theta_deg"] + 180) % 360 - 180)
    right = table["status"].isin(["ok", "recovered"]) & (table["err_xy_cm"] <= 30)
    right = (right & (table["err_theta_deg"].abs() <= 3)).to_numpy()
    grid = zip(table["iterations"], table["grid-m"], strict=True)
    labels = np.array([f"iterations={i}, grid-m={g}" for i, g in grid])
    assert len(set(labels)) == 4
    for label in set(labels):
        mine = labels == label
        for values, edges, unit in (
            (off_m, (0.0, 0.25, 0.5, 1.0, 2.0, 4.0), " m"),
            (turn_deg, (0, 5, 10, 20, 45, 90, 180), "°"),
        ):
            n, _ = np.histogram(values[mine], bins=edges)
            k, _ = np.histogram(values[mine & right], bins=edges)
            assert _md_counts(text, label, unit) == list(zip(n, k, strict=True))
            assert n.sum() == SCANS * 2  # every pose of both seeds has a guess in some bin
    again = run_cli(capsys, "sweep", spec, "--out", results, "--convergence", prefix)
    assert_one_line_error(again, "curves.md", "file exists", "--force")
    assert prefix.with_suffix(".md").read_text(encoding="utf-8") == text
