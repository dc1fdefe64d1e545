"""A sweep's spec: the TOML file read and checked, and the tasks it plans.

The spec names a map, the logs, a survey (the true poses each answer is scored against), how
the initial guesses are made and the seeds; any localize setting is fixed at the top level
(``iterations = 8``) or listed in ``[grid]`` (``iterations = [6, 8]``), whose every
combination is run. Keys are ``segloc localize``'s long option names, as in a ``--config``
table, and each value is checked as that option checks its own (``tablevalues``, by
``Setting.checked``). Paths are relative to the spec's folder. A log may be a table,
``{path = "...", map = "...", survey = "..."}``, to give it a map and survey of its own.
"""

from __future__ import annotations

import itertools
import math
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from segloc_cli.config import GUESSES_KEYWORD, LOCALIZE_SETTINGS, Setting
from segloc_cli.errors import InputError
from segloc_cli.runs.sweep import Task, task_key
from segloc_cli.runs.tablevalues import Takes, setting_value, table_value
from segloc_cli.wording import did_you_mean

SPEC_KEYS = {
    "map": "the segment map (MAP.json) of every log that names none",
    "logs": "the logs (MCAP) to localize: paths, or tables {path, map, survey}",
    "survey": "the true poses (survey CSV or TUM) of every log that names none",
    "init-errors": "guesses = survey − errors: 'paper' or 'uniform:XY_M,THETA_DEG', one draw "
    "per seed and log (as the spec names it)",
    "initial": "guesses from a file (CSV or TUM), or 'odom': the log's /odom (the default)",
    "seeds": "the seeds of the guesses' draws (default [0])",
    "fail-above-cm": "the summary's gate on |err_x| and |err_y| (default 10 cm)",
    "fail-above-deg": "the summary's gate on |err_theta| (default 1°)",
}
"""The spec's own keys (besides localize's settings and ``[grid]``), with what they hold."""
DEFAULT_GATES = {"fail-above-cm": 10.0, "fail-above-deg": 1.0}
NOT_SWEPT = {"map", "out", "tum", "mcap", "hypotheses", "initial", "track", "jobs", "region"}
"""Localize options a spec does not take: its outputs, its inputs (given by the spec's own
keys), tracking (whose scans follow one another, not one task's guesses), the worker
count (the sweep's --jobs) and the global search's region."""
SPEC_FLAGS = ("global",)
"""Localize's flags a spec takes besides its settings: a global search, without guesses."""
LOG_TABLE_KEYS = ("path", "map", "survey")
MAX_TASKS = 10_000
"""Most tasks (logs × combinations × seeds) a spec may plan: planning, submitting and
keeping each task's rows cost time and files before any runs (a million take minutes to
plan and hours to submit), and a sweep larger than this is several sweeps."""


@dataclass(frozen=True)
class Plan:
    """What a spec asks: its tasks in order, the grid's keys, the summary's gates, and
    every file it reads (role, path), for the run file."""

    tasks: list[Task]
    grid_keys: tuple[str, ...]
    gates: dict[str, float]
    inputs: list[tuple[str, Path]]


def read_spec(path: Path) -> Plan:
    """The plan of the spec ``path``; a bad key or value is an ``InputError`` naming it."""
    from segloc_cli.runs.runfile import load_toml

    document = load_toml(path, "a sweep spec (TOML)")
    swept = _swept()
    grid = document.pop("grid", {})
    if not isinstance(grid, dict):
        raise InputError("[grid] must be a table of lists: iterations = [6, 8]", path=path)
    for key, value in document.items():
        if isinstance(value, dict):
            raise InputError(f"table [{key}] is no part of a spec; the only table is [grid]", path)
        if key not in SPEC_KEYS and key not in swept:
            raise InputError(_unknown(key, swept), path=path)
    fixed = {
        key: _value(swept[key], key, value, path) for key, value in document.items() if key in swept
    }
    grid_values = _grid(grid, swept, fixed, path)
    logs = _logs(document, path)
    seeds = _seeds(document.get("seeds", [0]), path)
    _check_size(len(logs), [len(v) for v in grid_values.values()], len(seeds), path)
    combinations = [
        dict(zip(grid_values, values, strict=True))
        for values in itertools.product(*grid_values.values())
    ]
    for combination in combinations:
        _check_combination({**fixed, **combination}, path)
    gates = {k: _gate(document.get(k, v), k, path) for k, v in DEFAULT_GATES.items()}
    plan = _planned(document, path, logs, combinations, fixed, seeds, gates, tuple(grid_values))
    _check_distinct(plan.tasks, path)
    return plan


def _swept() -> dict[str, Setting | None]:
    """The localize keys a spec takes: its settings but those ``NOT_SWEPT``, and its
    ``SPEC_FLAGS`` (None: no setting)."""
    settings = {s.key: s for s in LOCALIZE_SETTINGS if s.key not in NOT_SWEPT}
    return settings | dict.fromkeys(SPEC_FLAGS)


def _value(setting: Setting | None, key: str, raw: Any, path: Path) -> Any:
    """A localize key's value checked as its option checks it (a flag's: true or false)."""
    if setting is None:
        return table_value(key, raw, Takes(flag=True), path)
    return setting_value(setting, raw, path)


def _check_size(n_logs: int, grid_lengths: list[int], n_seeds: int, path: Path) -> None:
    """Refuse, before any combination is made, a spec that plans more than ``MAX_TASKS``
    tasks (logs × combinations × seeds)."""
    n_tasks = n_logs * math.prod(grid_lengths) * n_seeds
    if n_tasks > MAX_TASKS:
        sizes = " × ".join(map(str, [n_logs, *grid_lengths, n_seeds]))
        raise InputError(
            f"plans {n_tasks:,} tasks (logs × [grid] values × seeds: {sizes}), more than the "
            f"{MAX_TASKS:,} a sweep takes; list fewer values, or split it into several specs",
            path=path,
        )


def _check_distinct(tasks: list[Task], path: Path) -> None:
    """Refuse two tasks of one key: the same log (by its bytes) listed twice with the same
    map, survey and guesses, whose rows would be counted twice."""
    first: dict[str, Task] = {}
    for task in tasks:
        twin = first.setdefault(task.key, task)
        if twin is not task:
            raise InputError(
                f"logs {twin.log!r} and {task.log!r} are the same log (the same bytes, map, "
                "survey and guesses): their rows would be counted twice; list it once",
                path=path,
            )


def _unknown(key: str, swept: dict) -> str:
    known = [*SPEC_KEYS, *swept]
    hint = did_you_mean(key, known, "see segloc sweep --help")
    return (
        f"unknown key {key!r}; a spec takes {', '.join(SPEC_KEYS)} and localize's settings; {hint}"
    )


def _grid(grid: dict, swept: dict, fixed: dict, path: Path) -> dict[str, list]:
    """The grid's keys with their checked values, in the spec's order."""
    values: dict[str, list] = {}
    for key, listed in grid.items():
        if key not in swept:
            raise InputError(
                _unknown(key, swept).replace("unknown key", "unknown [grid] key"), path
            )
        if key in fixed:
            raise InputError(f"key {key!r} is both fixed and in [grid]; keep one", path=path)
        if not isinstance(listed, list) or not listed:
            raise InputError(f"[grid] key {key!r} takes a list of values, e.g. [6, 8]", path=path)
        checked = [_value(swept[key], key, v, path) for v in listed]
        if len(set(map(repr, checked))) < len(checked):
            raise InputError(f"[grid] key {key!r} lists a value twice", path=path)
        values[key] = checked
    return values


def _check_combination(settings: dict[str, Any], path: Path) -> None:
    """Refuse settings that cannot go together, as ``segloc localize`` does."""
    from segloc_cli.config import SettingError, run_config

    try:
        run_config(settings, bool(settings.get("global")), track=False)
    except SettingError as exc:
        raise InputError(str(exc), path=path) from None


@dataclass(frozen=True)
class _Log:
    label: str
    path: Path
    map_path: Path
    survey_path: Path


def _logs(document: dict, path: Path) -> list[_Log]:
    """The logs, each with its map and survey (its own, or the spec's)."""
    listed = document.get("logs")
    if not isinstance(listed, list) or not listed:
        raise InputError('key "logs" must list the logs: logs = ["run1.mcap", "run2.mcap"]', path)
    logs = []
    for entry in listed:
        table = {"path": entry} if isinstance(entry, str) else entry
        if not isinstance(table, dict) or not isinstance(table.get("path"), str):
            raise InputError(
                f"a log is a path or a table {{path = ..., map = ..., survey = ...}}, "
                f"not {entry!r}",
                path=path,
            )
        extra = sorted(set(table) - set(LOG_TABLE_KEYS))
        if extra:
            raise InputError(
                f"a log's table takes {', '.join(LOG_TABLE_KEYS)}, not {extra[0]!r}", path
            )
        files = {}
        for key in ("map", "survey"):
            given = table.get(key, document.get(key))
            if not isinstance(given, str) or not given:
                raise InputError(
                    f'log {table["path"]!r} has no {key}: give {key} = "FILE" at the top or '
                    "in the log's table",
                    path=path,
                )
            files[key] = path.parent / given
        log_path = path.parent / table["path"]
        for role, file in (("log", log_path), *files.items()):
            if not file.is_file():
                what = "is a folder, not a file" if file.is_dir() else "does not exist"
                raise InputError(f"the {role} {file} {what} (paths are relative to the spec)", path)
        logs.append(_Log(table["path"], log_path.resolve(), files["map"], files["survey"]))
    return logs


MAX_SEED = 2**63 - 1
"""Largest seed a sweep takes (seeds start at 0, as numpy's generators do): its tables hold
a seed as a 64-bit signed integer."""


def _seeds(value: Any, path: Path) -> list[int]:
    ok = isinstance(value, list) and value and all(type(v) is int for v in value)
    if not ok or len(set(value)) < len(value) or not all(0 <= v <= MAX_SEED for v in value):
        raise InputError(
            f"key 'seeds' takes a list of distinct whole numbers from 0 to {MAX_SEED}, "
            f"not {value!r}",
            path,
        )
    return value


def _gate(value: Any, key: str, path: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
        raise InputError(f"key {key!r} takes a number of at least 0, not {value!r}", path=path)
    return float(value)


def _guesses(
    document: dict, path: Path
) -> tuple[tuple[str, float, float] | None, Path | None, str]:
    """(init errors, guesses file, what identifies them) from ``init-errors`` or ``initial``."""
    from segloc_cli.io.files import sha256
    from segloc_cli.sim import parse_init_errors

    if "init-errors" in document and "initial" in document:
        raise InputError("give init-errors or initial, not both", path=path)
    if "init-errors" in document:
        text = document["init-errors"]
        try:
            return parse_init_errors(str(text)), None, f"init-errors {text}"
        except ValueError as exc:
            raise InputError(f"key 'init-errors': {exc}", path=path) from None
    initial = document.get("initial", GUESSES_KEYWORD)
    if not isinstance(initial, str) or not initial:
        raise InputError(f"key 'initial' takes 'odom' or a path in quotes, not {initial!r}", path)
    if initial == GUESSES_KEYWORD:
        return None, None, GUESSES_KEYWORD
    file = path.parent / initial
    if not file.is_file():
        raise InputError(f"the initial guesses {file} do not exist", path=path)
    return None, file, f"initial {sha256(file)}"


@dataclass(frozen=True)
class _Inputs:
    """The files a spec reads, each read once: their sha256 by path, the maps and surveys by
    path, and every file as (role, path) in the order first named."""

    digests: dict[Path, str]
    maps: dict[Path, np.ndarray]
    surveys: dict[Path, Any]
    listed: list[tuple[str, Path]]


def _read_inputs(logs: list[_Log], guess_file: Path | None) -> _Inputs:
    from segloc_cli.io.files import sha256
    from segloc_cli.io.maps import read_map
    from segloc_cli.io.tables import read_pose_table

    files = _Inputs({}, {}, {}, [] if guess_file is None else [("initial", guess_file)])
    for log in logs:
        for role, file in (("log", log.path), ("map", log.map_path), ("survey", log.survey_path)):
            if file not in files.digests:
                files.digests[file] = sha256(file)
                files.listed.append((role, file))
        files.maps.setdefault(log.map_path, read_map(log.map_path))
        files.surveys.setdefault(log.survey_path, read_pose_table(log.survey_path))
    return files


def _planned(
    document: dict,
    path: Path,
    logs: list[_Log],
    combinations: list[dict],
    fixed: dict,
    seeds: list[int],
    gates: dict[str, float],
    grid_keys: tuple[str, ...],
) -> Plan:
    """The tasks in order: by log, then combination, then seed."""
    from segloc_cli.config import Config
    from segloc_cli.io.tables import read_pose_table

    init_errors, guess_file, guesses_id = _guesses(document, path)
    file_guesses = None if guess_file is None else read_pose_table(guess_file)
    files = _read_inputs(logs, guess_file)
    settings = [{**fixed, **grid_settings} for grid_settings in combinations]
    configs = [repr(Config.from_values(each)) for each in settings]
    tasks = []
    for log in logs:
        survey = files.surveys[log.survey_path]
        # One draw per seed, which every combination shares.
        guesses = {seed: file_guesses for seed in seeds}
        if init_errors is not None:
            guesses = {seed: _drawn(survey, init_errors, seed, log.label) for seed in seeds}
        for combination, grid_settings in enumerate(combinations):
            mode = "global" if settings[combination].get("global") else "guided"
            for seed in seeds:
                identity = {
                    "log": files.digests[log.path],
                    "map": files.digests[log.map_path],
                    "survey": files.digests[log.survey_path],
                    "guesses": None if mode == "global" else guesses_id,
                    "draw": [seed, log.label] if init_errors is not None else None,
                    "config": configs[combination],
                    "mode": mode,
                    "seed": seed,
                }
                tasks.append(
                    Task(
                        key=task_key(identity),
                        log=log.label,
                        log_path=log.path,
                        combination=combination,
                        params=tuple(grid_settings.items()),
                        settings=tuple(settings[combination].items()),
                        seed=seed,
                        segments_world=files.maps[log.map_path],
                        survey=survey,
                        survey_path=str(log.survey_path),
                        guesses=guesses[seed],
                    )
                )
    return Plan(tasks, grid_keys, gates, files.listed)


def _drawn(survey, init_errors: tuple[str, float, float], seed: int, label: str):
    """The guesses of seed ``seed`` for the log named ``label``: the survey's poses less
    errors drawn as ``init_errors`` says. Drawn from the log's name, so that adding or
    reordering logs leaves every other log's guesses (and finished tasks) as they were."""
    from segloc_cli.estimates import PoseTable
    from segloc_cli.sim import initial_errors, initial_guesses

    rng = np.random.default_rng([seed, zlib.crc32(label.encode())])
    poses = initial_guesses(survey.poses, initial_errors(len(survey), init_errors, rng))
    return PoseTable(survey.pose_id, survey.time_s, poses)
