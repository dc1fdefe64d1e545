"""One configuration: options made from it, ``--config`` files, run files that repeat a run."""

from __future__ import annotations

import csv
import hashlib
import os
import re
import tomllib
from dataclasses import fields
from pathlib import Path

import click
import pytest
from conftest import HALL
from test_cli import assert_one_line_error, run_cli

from segloc_cli import __version__
from segloc_cli.cli import cli
from segloc_cli.commands.configfile import option_key
from segloc_cli.config import (
    EXTRACT,
    FUSE,
    LOCALIZE_SETTINGS,
    LOCALIZE_TUNING,
    SETTINGS,
    TABLE_BEGIN,
    TABLE_END,
    Config,
    ExtractParams,
    LocalizeParams,
    RefineParams,
    SearchParams,
    TrackParams,
    settings_table,
)

ROOT = Path(__file__).resolve().parents[1]
SETTINGS_PAGE = ROOT / "docs" / "configuration.md"
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _commands(group: click.Group = cli, prefix: tuple[str, ...] = ()):
    for name, command in group.commands.items():
        if isinstance(command, click.Group):
            yield from _commands(command, (*prefix, name))
        else:
            yield (*prefix, name), command


def _option(command: click.Command, key: str) -> click.Option:
    return next(p for p in command.params if isinstance(p, click.Option) and option_key(p) == key)


# --------------------------------------------------------------------------- one source


@pytest.mark.parametrize(
    "path,command", list(_commands()), ids=lambda v: "-".join(v) if isinstance(v, tuple) else ""
)
def test_every_setting_option_has_the_configurations_default(path, command):
    for param in command.params:
        key = option_key(param)
        if path == ("sweep",) and key == "jobs":
            continue  # the local cluster's worker processes, not localize's setting
        if isinstance(param, click.Option) and key in SETTINGS:
            assert param.default == SETTINGS[key].default, f"segloc {' '.join(path)} --{key}"


def test_localize_and_map_build_take_every_setting():
    commands = dict(_commands())
    localize_keys = {option_key(p) for p in commands[("localize",)].params}
    build_keys = {option_key(p) for p in commands[("map", "build")].params}
    assert {s.key for s in LOCALIZE_TUNING} <= localize_keys
    assert {s.key for s in LOCALIZE_SETTINGS} == localize_keys & set(SETTINGS)
    assert {s.key for s in (*EXTRACT, *FUSE)} <= build_keys
    assert set(SETTINGS) <= localize_keys | build_keys


def test_every_field_of_every_stage_is_a_setting():
    """Each field of the parameter classes can be set, except the per-scan prior spreads."""
    paths = {s.path for s in SETTINGS.values()}
    for owner, cls in [
        (("extract",), ExtractParams),
        (("localize",), LocalizeParams),
        (("localize", "refine"), RefineParams),
        (("localize", "search"), SearchParams),
        (("track",), TrackParams),
    ]:
        for f in fields(cls):
            nested = f.name in ("refine", "search", "confidence")
            per_scan = f.name.startswith("prior_sigma")
            if not (nested or per_scan):
                assert (*owner, f.name) in paths, f"{cls.__name__}.{f.name} has no setting"


def test_values_set_nested_fields_and_switches_win_over_their_field():
    config = Config.from_values(
        {"no-prior-heading": True, "window-deg": 30.0, "refine-gate-m": 0.3, "search-cell-m": 0.1}
    )
    assert config.localize.window_deg is None
    assert config.localize.refine.gate_m == 0.3
    assert config.localize.search.cell_m == 0.1
    assert Config.from_values({"no-refine": True, "refine-gate-m": 0.3}).localize.refine is None
    assert Config.from_values({"track-max-jump-m": 1, "jobs": 2}).track.max_jump_m == 1.0
    assert Config.from_values({}) == Config()


def test_the_settings_table_is_the_configurations():
    text = SETTINGS_PAGE.read_text(encoding="utf-8")
    assert TABLE_BEGIN in text and TABLE_END in text
    block = text.split(TABLE_BEGIN)[1].split(TABLE_END)[0]
    assert block == settings_table(), "run: python -m segloc_cli.config docs/configuration.md"


def test_option_tables_give_the_configurations_defaults():
    """The hand-written option tables of README and docs/ (with the paper's values beside)
    agree too."""
    rows = [
        (page.name, *row)
        for page in PAGES
        for row in re.findall(r"^\| `--([a-z0-9-]+)` \| ([^|]+) \|", page.read_text(), re.M)
    ]
    checked = 0
    for page, key, shown in rows:
        if key not in SETTINGS:
            continue
        default, shown = SETTINGS[key].default, shown.strip().strip("`")
        if isinstance(default, bool):
            assert shown == "off", f"{page} gives --{key} the default {shown}"
        elif isinstance(default, str):
            assert shown == default, f"{page} gives --{key} the default {shown}"
        else:
            assert float(shown) == default, f"{page} gives --{key} the default {shown}"
        checked += 1
    assert checked >= 10


# --------------------------------------------------------------------------- --config


@pytest.fixture
def hall(tmp_path, monkeypatch):
    """A folder holding the hall's log, map and survey under short relative names."""
    for name in ("log.mcap", "map.json", "survey.csv"):
        (tmp_path / name).write_bytes((HALL / name).read_bytes())
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="", encoding="utf-8") as stream:
        rows = list(csv.DictReader(stream))
    for row in rows:
        row.pop("runtime_ms")
    return rows


def test_config_sets_options_and_flags_win(hall, capsys):
    (hall / "settings.toml").write_text(
        '[localize]\nmap = "map.json"\niterations = 3\nno-refine = true\n', encoding="utf-8"
    )
    config = ["--config", "settings.toml"]
    assert run_cli(capsys, "localize", "log.mcap", *config, "--out", "a.csv").code == 0
    direct = ["--map", "map.json", "--no-refine"]
    assert (
        run_cli(capsys, "localize", "log.mcap", *direct, "--iterations", "3", "--out", "b.csv").code
        == 0
    )
    assert _rows(hall / "a.csv") == _rows(hall / "b.csv")
    flag = ["--iterations", "5", "--out", "c.csv"]
    assert run_cli(capsys, "localize", "log.mcap", *config, *flag).code == 0
    direct5 = [*direct, "--iterations", "5", "--out", "d.csv"]
    assert run_cli(capsys, "localize", "log.mcap", *direct5).code == 0
    assert _rows(hall / "c.csv") == _rows(hall / "d.csv") != _rows(hall / "a.csv")


CONFIG_ERRORS = {
    "unknown key": ("[localize]\ngrid_m = 1.0\n", "unknown key 'grid_m'", "'grid-m'"),
    "bad value": ("[localize]\ngrid-m = -1.0\n", "key 'grid-m'", "-1.0"),
    "nan": ("[localize]\nratio = nan\n", "key 'ratio'"),
    "flag not bool": ("[localize]\nno-refine = 1\n", "key 'no-refine'", "true or false"),
    "unknown table": ("[localise]\ngrid-m = 1.0\n", "[localise]", "names no segloc command"),
    "outside table": ("grid-m = 1.0\n", "key 'grid-m' is outside any table"),
    "not toml": ("[localize\n", "not valid TOML"),
    "list value": ("[localize]\ngrid-m = [1.0]\n", "key 'grid-m'"),
    "tuning out of bounds": ("[localize]\nsearch-cell-m = 0\n", "key 'search-cell-m'"),
    "fraction for a count": ("[localize]\niterations = 6.5\n", "key 'iterations'", "whole"),
    "bool for a number": ("[localize]\ngrid-m = true\n", "key 'grid-m'"),
    "date for a number": ("[localize]\ngrid-m = 2026-12-01\n", "key 'grid-m'"),
}


@pytest.mark.parametrize("case", CONFIG_ERRORS, ids=str)
def test_bad_config_is_one_line_naming_the_key(case, hall, capsys):
    text, *fragments = CONFIG_ERRORS[case]
    (hall / "bad.toml").write_text(text, encoding="utf-8")
    args = ["localize", "log.mcap", "--map", "map.json", "--out", "e.csv", "--config", "bad.toml"]
    assert_one_line_error(run_cli(capsys, *args), "bad.toml", *fragments)
    assert not (hall / "e.csv").exists()


def test_config_tables_of_other_commands_are_left_alone(hall, capsys):
    (hall / "all.toml").write_text(
        '[map.build]\nsurvey = "survey.csv"\n\n[localize]\nmap = "map.json"\n'
        '[evaluate]\nsurvey = "survey.csv"\n',
        encoding="utf-8",
    )
    result = run_cli(capsys, "map", "build", "log.mcap", "--config", "all.toml", "--out", "m.json")
    assert result.code == 0, result.err
    assert (
        run_cli(capsys, "localize", "log.mcap", "--config", "all.toml", "--out", "e.csv").code == 0
    )


# --------------------------------------------------------------------------- run files


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_run_file_records_settings_version_and_inputs(hall, capsys):
    args = ["localize", "log.mcap", "--map", "map.json", "--out", "est.csv", "--vote", "sum"]
    assert run_cli(capsys, *args).code == 0
    run = tomllib.loads((hall / "est.run.toml").read_text(encoding="utf-8"))
    table = run["localize"]
    assert table["vote"] == "sum" and table["map"] == "map.json"
    assert table["iterations"] == LocalizeParams().iterations
    assert table["search-cell-m"] == SearchParams().cell_m
    assert "out" not in table and "force" not in table
    assert run["run"]["segloc"] == __version__
    inputs = {i["path"]: i["sha256"] for i in run["run"]["inputs"]}
    assert inputs == {
        "log.mcap": _sha256(hall / "log.mcap"),
        "map.json": _sha256(hall / "map.json"),
    }


def test_run_file_repeats_the_run_from_another_folder(hall, capsys):
    (hall / "tuned.toml").write_text(
        "[localize]\nsearch-half-width-m = 1.0\nconfidence-min-confidence = 0.8\nrecentre = 2\n",
        encoding="utf-8",
    )
    (hall / "runs").mkdir()
    first = ["localize", "log.mcap", "--map", "map.json", "--out", "runs/est.csv"]
    assert run_cli(capsys, *first, "--config", "tuned.toml", "--window-deg", "15").code == 0
    elsewhere = hall / "elsewhere"
    elsewhere.mkdir()
    os.chdir(elsewhere)
    again = ["localize", "../log.mcap", "--config", "../runs/est.run.toml", "--out", "other.csv"]
    result = run_cli(capsys, *again)
    assert result.code == 0, result.err
    assert _rows(elsewhere / "other.csv") == _rows(hall / "runs" / "est.csv")
    default = ["localize", "../log.mcap", "--map", "../map.json", "--out", "default.csv"]
    assert run_cli(capsys, *default).code == 0
    assert _rows(elsewhere / "default.csv") != _rows(elsewhere / "other.csv")


def test_map_build_run_file_rebuilds_the_same_map(hall, capsys):
    (hall / "fuse.toml").write_text("[map.build]\nfuse-gap-m = 0.3\n", encoding="utf-8")
    build = ["map", "build", "log.mcap", "--survey", "survey.csv", "--config", "fuse.toml"]
    assert run_cli(capsys, *build, "--out", "a.json").code == 0
    again = ["map", "build", "log.mcap", "--config", "a.run.toml", "--out", "b.json"]
    assert run_cli(capsys, *again).code == 0
    assert (hall / "a.json").read_text() == (hall / "b.json").read_text().replace(
        "b.json", "a.json"
    )
    assert '"gap_m": 0.3' in (hall / "a.json").read_text()


def test_existing_run_file_needs_force(hall, capsys):
    (hall / "est.run.toml").write_text("# an earlier run\n", encoding="utf-8")
    args = ["localize", "log.mcap", "--map", "map.json", "--out", "est.csv"]
    assert_one_line_error(run_cli(capsys, *args), "est.run.toml", "--force")
    assert run_cli(capsys, *args, "--force").code == 0
    assert "[localize]" in (hall / "est.run.toml").read_text()


def test_run_file_of_another_version_warns(hall, capsys):
    args = ["localize", "log.mcap", "--map", "map.json", "--out", "est.csv"]
    assert run_cli(capsys, *args).code == 0
    text = (hall / "est.run.toml").read_text().replace(f'"{__version__}"', '"0.0.1"')
    (hall / "old.run.toml").write_text(text)
    result = run_cli(capsys, "localize", "log.mcap", "--config", "old.run.toml", "--out", "o.csv")
    assert result.code == 0
    assert "written by segloc 0.0.1" in result.err
    assert _rows(hall / "o.csv") == _rows(hall / "est.csv")


def test_a_run_file_of_another_command_is_refused(hall, capsys):
    build = ["map", "build", "log.mcap", "--survey", "survey.csv", "--out", "m.json"]
    assert run_cli(capsys, *build).code == 0
    args = ["localize", "log.mcap", "--map", "map.json", "--config", "m.run.toml"]
    result = run_cli(capsys, *args, "--out", "e.csv")
    assert_one_line_error(result, "m.run.toml: is the run file of `segloc map build`")
    assert not (hall / "e.csv").exists()


def test_a_configuration_without_the_commands_table_sets_nothing_and_says_so(hall, capsys):
    (hall / "build.toml").write_text("[map.build]\nfuse-gap-m = 0.2\n", encoding="utf-8")
    args = ["localize", "log.mcap", "--map", "map.json", "--config", "build.toml"]
    result = run_cli(capsys, *args, "--out", "e.csv")
    assert result.code == 0
    assert "build.toml has no [localize] table" in result.err


def test_simulate_run_file_repeats_the_log(hall, capsys):
    from segloc_cli.io.mcap_log import read_log

    (hall / "poses.csv").write_bytes((HALL / "poses.csv").read_bytes())
    first = ["simulate", HALL / "world.json", "--poses", "poses.csv", "--out", "a"]
    assert run_cli(capsys, *first, "--seed", "5", "--init-errors", "uniform:1,10").code == 0
    again = ["simulate", HALL / "world.json", "--config", "a/log.run.toml", "--out", "b"]
    assert run_cli(capsys, *again).code == 0
    assert (hall / "a" / "survey.csv").read_text() == (hall / "b" / "survey.csv").read_text()
    logs = [read_log(hall / folder / "log.mcap") for folder in ("a", "b")]
    assert logs[0].sensor == logs[1].sensor
    for one, other in zip(logs[0].scans, logs[1].scans, strict=True):
        assert one.ranges_m.tobytes() == other.ranges_m.tobytes()
    assert logs[0].odom_poses.tobytes() == logs[1].odom_poses.tobytes()


def _tables(run_file: Path) -> dict:
    """A run file's table of its command (``[simulate]``, ``[map.export]``)."""
    document = tomllib.loads(run_file.read_text(encoding="utf-8"))
    table = document
    for name in document["run"]["command"].split()[1:]:
        table = table[name]
    return table


def _numbers_in_quotes(table: dict) -> dict:
    """The values of a run file's table written as text though they are numbers or flags."""
    quoted = {}
    for key, value in table.items():
        if isinstance(value, str) and value.lower() in ("true", "false"):
            quoted[key] = value
        elif isinstance(value, str):
            try:
                float(value)
            except ValueError:
                continue
            quoted[key] = value
    return quoted


def test_run_files_hold_numbers_as_numbers_and_flags_as_booleans(hall, capsys):
    (hall / "poses.csv").write_bytes((HALL / "poses.csv").read_bytes())
    first = ["simulate", HALL / "world.json", "--poses", "poses.csv", "--out", "a"]
    assert run_cli(capsys, *first, "--readings", "256", "--seed", "5").code == 0
    table = _tables(hall / "a" / "log.run.toml")
    assert table["readings"] == 256 and table["seed"] == 5 and table["noise-cm"] == 1.2
    assert "readings = 256\n" in (hall / "a" / "log.run.toml").read_text(encoding="utf-8")
    localize = ["localize", "a/log.mcap", "--map", "map.json", "--out", "e.csv", "--no-refine"]
    assert run_cli(capsys, *localize).code == 0
    assert _tables(hall / "e.run.toml")["no-refine"] is True
    for run_file in (hall / "a" / "log.run.toml", hall / "e.run.toml"):
        assert _numbers_in_quotes(_tables(run_file)) == {}, run_file
    # Given back, the run file sets the same options: its repetition records the same table.
    again = ["simulate", HALL / "world.json", "--config", "a/log.run.toml", "--out", "b"]
    assert run_cli(capsys, *again).code == 0
    assert _tables(hall / "b" / "log.run.toml") == table
    from segloc_cli.io.mcap_log import read_log

    assert read_log(hall / "b" / "log.mcap").sensor["readings"] == "256"


def test_map_export_writes_a_run_file_that_repeats_it(hall, capsys):
    """``map export`` takes ``--config`` and writes its run file beside its output, named after
    the whole of OUT so that the map's own run file (here map.run.toml) stays; given back, it
    writes the same grid."""
    (hall / "map.run.toml").write_text("# the map's own run file\n", encoding="utf-8")
    first = ["map", "export", "map.json", "--out", "map.yaml", "--resolution", "0.1"]
    result = run_cli(capsys, *first)
    assert result.code == 0, result.err
    assert (hall / "map.run.toml").read_text(encoding="utf-8") == "# the map's own run file\n"
    run = tomllib.loads((hall / "map.yaml.run.toml").read_text(encoding="utf-8"))
    assert run["map"]["export"] == {"resolution": 0.1}
    assert run["run"]["command"] == "segloc map export"
    assert [(i["path"], i["sha256"]) for i in run["run"]["inputs"]] == [
        ("map.json", _sha256(hall / "map.json"))
    ]
    again = ["map", "export", "map.json", "--config", "map.yaml.run.toml", "--out", "b.yaml"]
    result = run_cli(capsys, *again)
    assert result.code == 0, result.err
    assert (hall / "b.pgm").read_bytes() == (hall / "map.pgm").read_bytes()
    assert (hall / "b.yaml").read_text() == (hall / "map.yaml").read_text().replace(
        "map.pgm", "b.pgm"
    )
    # Like every output, the run file is not overwritten unasked.
    (hall / "map.yaml").unlink()
    (hall / "map.pgm").unlink()
    assert_one_line_error(run_cli(capsys, *first), "map.yaml.run.toml", "--force")


def test_region_is_a_setting_of_global_runs(hall, capsys):
    """``--region`` from a configuration file or a run file limits a global search as on the
    command line, and goes with ``--global`` there too."""
    (hall / "region.toml").write_text(
        '[localize]\nmap = "map.json"\nglobal = true\nregion = "0,0,20,14"\n', encoding="utf-8"
    )
    args = ["localize", "log.mcap", "--config", "region.toml", "--out", "a.csv"]
    assert run_cli(capsys, *args).code == 0
    table = tomllib.loads((hall / "a.run.toml").read_text(encoding="utf-8"))["localize"]
    assert table["region"] == "0,0,20,14"
    again = ["localize", "log.mcap", "--config", "a.run.toml", "--out", "b.csv"]
    assert run_cli(capsys, *again).code == 0
    assert _rows(hall / "a.csv") == _rows(hall / "b.csv")
    (hall / "guided.toml").write_text('[localize]\nregion = "0,0,20,14"\n', encoding="utf-8")
    guided = ["localize", "log.mcap", "--map", "map.json", "--config", "guided.toml"]
    assert_one_line_error(run_cli(capsys, *guided, "--out", "c.csv"), "--region goes with --global")


def test_run_config_sets_the_region_and_refuses_what_cannot_go_together():
    from segloc_cli.config import SettingError, run_config

    config = run_config({"region": "0,0,20,14"}, global_search=True, track=False)
    assert config.localize.search.region == (0.0, 0.0, 20.0, 14.0)
    for values, global_search, track, said in [
        ({"region": "0,0,20,14"}, False, False, "--region goes with --global"),
        ({"region": "5,0,1,4"}, True, False, "Invalid value for --region: '5,0,1,4'; use X0,Y0"),
        ({"bin-deg": 7.0}, False, False, "Invalid value for --bin-deg: 7 does not divide 180"),
        ({"jobs": 2}, False, True, "--jobs cannot be combined with --track"),
        ({"no-refine": True}, True, False, "--global cannot be combined with --no-refine"),
    ]:
        with pytest.raises(SettingError, match="^" + re.escape(said)):
            run_config(values, global_search, track)


@pytest.mark.parametrize("stop", ["Ctrl-C", "SIGTERM"])
@pytest.mark.parametrize("mode", [[], ["--track"]])
def test_the_run_file_and_view_of_a_stopped_run_say_it_stopped_and_after_how_many_scans(
    hall, capsys, monkeypatch, stop, mode
):
    """Stopped during its second scan of four selected, a localize keeps the rows done, and its
    run file and run view say so, as ``info`` of the view and ``--config`` of the run file do;
    a whole run's say nothing of it."""
    import signal

    from segloc_cli.method.localize import Localizer

    real_localize, calls = Localizer.localize, []

    def stopped_at_the_second(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            if stop == "Ctrl-C":
                raise KeyboardInterrupt
            os.kill(os.getpid(), signal.SIGTERM)
        return real_localize(self, *args, **kwargs)

    monkeypatch.setattr(Localizer, "localize", stopped_at_the_second)
    args = ["localize", "log.mcap", "--map", "map.json", "--scans", "4", "--initial", "survey.csv"]
    result = run_cli(capsys, *args, *mode, "--out", "est.csv", "--mcap", "est.mcap")
    assert result.code == 130, result.err
    done = len(_rows(hall / "est.csv"))
    assert 1 <= done < 4  # SIGTERM ends the run after the scan it came in
    words = f"stopped ({stop}) after {done} of 4 scans"
    text = (hall / "est.run.toml").read_text()
    assert f"# This run was {words}" in text
    assert tomllib.loads(text)["run"]["stopped"] == {"by": stop, "done": done, "planned": 4}
    view = run_cli(capsys, "info", "est.mcap")
    assert f"finished:  no (its run was {words}; it shows those scans)" in view.out
    monkeypatch.setattr(Localizer, "localize", real_localize)
    again = run_cli(capsys, "localize", "log.mcap", "--config", "est.run.toml", "--out", "o.csv",
                    "--mcap", "o.mcap")  # fmt: skip
    assert again.code == 0, again.err
    assert f"est.run.toml records a run {words}" in again.err
    assert len(_rows(hall / "o.csv")) == 4
    assert "stopped" not in tomllib.loads((hall / "o.run.toml").read_text())["run"]
    assert "This run was" not in (hall / "o.run.toml").read_text()
    assert "finished:" not in run_cli(capsys, "info", "o.mcap").out
