"""Every message segloc writes for Foxglove decodes and validates against Foxglove's published
schemas (the ``foxglove_schemas_protobuf`` package), and the run view shows what the run did.

Protobuf messages (the run view) must name a Foxglove schema whose descriptor in the file is
the published one, parse under the published message class with no unknown fields, and
encode back to the same bytes. JSON messages (logs) must parse strictly under the published
class through protobuf's JSON mapping, Foxglove's ``{sec, nsec}`` times aside.
"""

from __future__ import annotations

import csv
import importlib
import json
import math
import tomllib
from collections import Counter, defaultdict
from datetime import UTC, datetime, timedelta
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from conftest import HALL
from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory
from google.protobuf.unknown_fields import UnknownFieldSet
from mcap.reader import make_reader
from precision import assert_within_precision
from test_cli import run_cli

from segloc_cli.geometry import Pose2, quaternion_to_heading
from segloc_cli.io.maps import read_map
from segloc_cli.io.mcap_log import read_log, write_log
from segloc_cli.io.runview import (
    LASER_FRAME,
    LAYOUT_FILE,
    ROBOT_FRAME,
    TOPICS,
    WORLD_FRAME,
    RunViewWriter,
    foxglove_layout,
)
from segloc_cli.scan import Scan

LOG = HALL / "log.mcap"
MAP = HALL / "map.json"


def published_class(schema_name: str):
    """Foxglove's published protobuf class for a schema name such as ``foxglove.LaserScan``."""
    package, _, name = schema_name.partition(".")
    assert package == "foxglove", f"{schema_name} is not a Foxglove schema"
    module = importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2")
    return getattr(module, name)


def _signature(descriptor, seen: set[str] | None = None) -> tuple:
    """A message descriptor's fields, nested messages and enums included, as plain data."""
    seen = set() if seen is None else seen
    if descriptor.full_name in seen:
        return (descriptor.full_name,)
    seen.add(descriptor.full_name)
    fields = []
    for field in descriptor.fields:
        nested = None
        if field.message_type is not None:
            nested = _signature(field.message_type, seen)
        elif field.enum_type is not None:
            nested = tuple((v.name, v.number) for v in field.enum_type.values)
        fields.append((field.name, field.number, field.type, field.is_repeated, nested))
    return (descriptor.full_name, tuple(fields))


def _descriptor_in_file(schema_name: str, data: bytes):
    """The message descriptor a file's protobuf schema (a FileDescriptorSet) defines."""
    files = descriptor_pb2.FileDescriptorSet.FromString(data)
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    return pool.FindMessageTypeByName(schema_name)


def validate_protobuf(schema_name: str, schema_data: bytes, data: bytes):
    """The message, decoded under the published class, after checking schema and bytes."""
    cls = published_class(schema_name)
    in_file = _descriptor_in_file(schema_name, schema_data)
    assert _signature(in_file) == _signature(cls.DESCRIPTOR), f"{schema_name}: schema differs"
    # Decoding with the file's own schema (as Foxglove does) and with the published class.
    message_factory.GetMessageClass(in_file).FromString(data)
    message = cls.FromString(data)
    assert len(UnknownFieldSet(message)) == 0, f"{schema_name}: fields the schema lacks"
    assert message.SerializeToString() == data, f"{schema_name}: does not encode back the same"
    return message


def _protobuf_json(value, descriptor):
    """Foxglove JSON → protobuf's JSON mapping: times ``{sec, nsec}`` become RFC 3339 text."""
    if descriptor.full_name == "google.protobuf.Timestamp":
        assert set(value) == {"sec", "nsec"}, f"time {value} is not {{sec, nsec}}"
        assert 0 <= value["nsec"] < 1_000_000_000
        time = datetime(1970, 1, 1, tzinfo=UTC) + timedelta(seconds=value["sec"])
        return time.strftime("%Y-%m-%dT%H:%M:%S") + f".{value['nsec']:09d}Z"
    out = {}
    for key, item in value.items():
        field = descriptor.fields_by_name.get(key)
        if field is not None and field.message_type is not None:
            if field.is_repeated:
                item = [_protobuf_json(v, field.message_type) for v in item]
            else:
                item = _protobuf_json(item, field.message_type)
        out[key] = item
    return out


def validate_json(schema_name: str, data: bytes):
    """The JSON message parsed strictly (no unknown or mistyped field) under the published
    class."""
    cls = published_class(schema_name)
    value = json.loads(data)
    return json_format.ParseDict(_protobuf_json(value, cls.DESCRIPTOR), cls())


def validated_messages(path: Path) -> dict[str, list]:
    """Every message of an MCAP file, validated and decoded, by topic in log-time order."""
    by_topic: dict[str, list] = defaultdict(list)
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        for schema, channel, record in reader.iter_messages(log_time_order=True):
            assert schema is not None, f"{channel.topic} has no schema"
            if channel.message_encoding == "protobuf":
                assert schema.encoding == "protobuf"
                message = validate_protobuf(schema.name, schema.data, record.data)
            else:
                assert (channel.message_encoding, schema.encoding) == ("json", "jsonschema")
                message = validate_json(schema.name, record.data)
            by_topic[channel.topic].append((record.log_time, message))
    return by_topic


def messages_before_the_cut(path: Path) -> dict[str, list]:
    """Every whole message of an MCAP file that may be cut short (no summary: a killed
    run's view), validated and decoded, by topic in file order, up to the cut."""
    from mcap.reader import NonSeekingReader

    by_topic: dict[str, list] = defaultdict(list)
    with open(path, "rb") as stream:
        messages = NonSeekingReader(stream).iter_messages(log_time_order=False)
        while True:
            try:
                schema, channel, record = next(messages)
            except Exception:  # the end, or the cut: a record that ends early
                break
            message = validate_protobuf(schema.name, schema.data, record.data)
            by_topic[channel.topic].append((record.log_time, message))
    return by_topic


def _pose(message) -> Pose2:
    p, q = message.position, message.orientation
    return Pose2(p.x, p.y, quaternion_to_heading(q.x, q.y, q.z, q.w))


def _transform_pose(transform) -> Pose2:
    t, q = transform.translation, transform.rotation
    return Pose2(t.x, t.y, quaternion_to_heading(q.x, q.y, q.z, q.w))


def _row_pose(row: dict[str, str], prefix: str) -> Pose2:
    """A pose of an estimates row read as text: ``x_m``, ``y_m``, ``theta_deg`` after prefix."""
    x, y, theta = (float(row[prefix + key]) for key in ("x_m", "y_m", "theta_deg"))
    return Pose2.from_deg(x, y, theta)


def _close(a: Pose2, b: Pose2) -> bool:
    return (
        math.isclose(a.x, b.x, abs_tol=1e-9)
        and math.isclose(a.y, b.y, abs_tol=1e-9)
        and (abs(math.remainder(a.theta - b.theta, 2 * math.pi)) < 1e-9)
    )


def _as_written(shown: Pose2, row: Pose2) -> bool:
    """A pose of the view (as made) is the pose of a CSV row (to 1 µm and 1e-6°)."""
    return (
        math.isclose(shown.x, row.x, abs_tol=0.5e-6 * 1.001)
        and math.isclose(shown.y, row.y, abs_tol=0.5e-6 * 1.001)
        and abs(math.remainder(shown.theta - row.theta, 2 * math.pi)) < math.radians(0.5e-6) * 1.01
    )


# --------------------------------------------------------------------------- the run view


def test_the_hall_run_view_shows_the_map_every_scan_and_each_estimate(tmp_path, capsys):
    out, view = tmp_path / "est.csv", tmp_path / "run.mcap"
    result = run_cli(capsys, "localize", LOG, "--map", MAP, "--out", out, "--mcap", view)
    assert result.code == 0, result.err
    rows = list(csv.DictReader(out.open(encoding="utf-8")))
    log = read_log(LOG)
    messages = validated_messages(view)
    with open(view, "rb") as stream:  # chunked, indexed and compressed like every log
        summary = make_reader(stream).get_summary()
    assert summary.chunk_indexes and {c.compression for c in summary.chunk_indexes} == {"zstd"}
    runner_ups = [r for r in rows if r["runner_up_x_m"] != ""]
    # Every scan of the hall is unmistakable: no runner-up, so no other hypothesis either.
    alike = set() if runner_ups else {"/runner_up", "/hypotheses"}
    assert set(messages) == set(TOPICS) - alike
    assert len(messages.get("/runner_up", [])) == len(runner_ups)

    # The map: every segment as one line of the map entity, in the world frame.
    [(map_time, update)] = messages["/map"]
    [entity] = update.entities
    assert (entity.id, entity.frame_id) == ("map", WORLD_FRAME)
    points = np.array([(p.x, p.y) for line in entity.lines for p in line.points])
    np.testing.assert_array_equal(points.reshape(-1, 4), read_map(MAP))
    assert map_time <= min(t for t, _ in messages["/scan"])

    # Every scan, in the laser frame, with the readings of the log.
    assert len(messages["/scan"]) == len(rows) == len(log.scans)
    for (time_ns, scan), source in zip(messages["/scan"], log.scans, strict=True):
        assert scan.frame_id == LASER_FRAME
        assert time_ns == round(source.time_s * 1e9)
        np.testing.assert_array_equal(scan.ranges, np.where(source.valid, source.ranges_m, 0))
        assert scan.start_angle == source.angles_rad[0]
        assert scan.end_angle == source.angles_rad[-1]

    # One world → base_link transform per estimate, at the estimate, and the mounting.
    estimates = [
        Pose2.from_deg(float(r["x_m"]), float(r["y_m"]), float(r["theta_deg"])) for r in rows
    ]
    assert len(messages["/tf"]) == len(estimates)
    for (_, transforms), estimate, source_scan in zip(
        messages["/tf"], estimates, log.scans, strict=True
    ):
        robot, laser = transforms.transforms
        assert (robot.parent_frame_id, robot.child_frame_id) == (WORLD_FRAME, ROBOT_FRAME)
        assert (laser.parent_frame_id, laser.child_frame_id) == (ROBOT_FRAME, LASER_FRAME)
        assert _as_written(_transform_pose(robot), estimate)
        assert _close(_transform_pose(laser), source_scan.mount)
    for (_, pose), estimate in zip(messages["/estimate"], estimates, strict=True):
        assert pose.frame_id == WORLD_FRAME and _as_written(_pose(pose.pose), estimate)
    guesses = [_row_pose(row, "init_") for row in rows]
    for (_, pose), guess in zip(messages["/guess"], guesses, strict=True):
        assert _as_written(_pose(pose.pose), guess)

    # The local segments move with the robot; the status is logged and written above it.
    for (_, update), row in zip(messages["/local_segments"], rows, strict=True):
        [entity] = update.entities
        assert entity.frame_id == ROBOT_FRAME
        assert sum(len(line.points) for line in entity.lines) == 2 * int(row["n_local_segments"])
        assert [text.text for text in entity.texts] == [row["status"]]
    statuses = Counter(log_line.message.split(":")[0] for _, log_line in messages["/status"])
    assert statuses == Counter(row["status"] for row in rows)


def test_a_scan_without_a_pose_is_shown_without_a_transform(tmp_path):
    scans = [
        Scan(
            time_s=t,
            angles_rad=np.linspace(-1.0, 1.0, 5),
            ranges_m=np.full(5, 2.0),
            mount=Pose2(0.3, -0.1, 0.5),
        )
        for t in (1.0, 2.0)
    ]
    segments = np.array([[0.0, 0.0, 4.0, 0.0]])
    path = tmp_path / "view.mcap"
    with RunViewWriter(path, segments) as view:
        view.add(scans[0], segments, Pose2(1.0, 2.0, 0.25), guess=Pose2(1.5, 2.0, 0.0))
        view.add(scans[1], np.zeros((0, 4)), None, status="lost", level="error", text="3 points")
    messages = validated_messages(path)
    assert [t for t, _ in messages["/scan"]] == [1_000_000_000, 2_000_000_000]
    assert [t for t, _ in messages["/tf"]] == [1_000_000_000]
    [(_, transforms)] = messages["/tf"]
    assert _close(_transform_pose(transforms.transforms[1]), Pose2(0.3, -0.1, 0.5))
    assert len(messages["/estimate"]) == len(messages["/guess"]) == 1
    levels = [log_line.level for _, log_line in messages["/status"]]
    assert levels == [published_class("foxglove.Log").INFO, published_class("foxglove.Log").ERROR]
    assert messages["/status"][1][1].message == "lost: 3 points"


def test_a_run_view_cut_short_is_finished_with_the_scans_added(tmp_path):
    path = tmp_path / "view.mcap"
    scan = Scan(time_s=1.0, angles_rad=np.linspace(-1.0, 1.0, 5), ranges_m=np.full(5, 2.0))
    with pytest.raises(RuntimeError), RunViewWriter(path, np.zeros((0, 4))) as view:
        view.add(scan, np.zeros((0, 4)), Pose2(1.0, 2.0, 0.25))
        raise RuntimeError("interrupted")
    assert [p.name for p in tmp_path.iterdir()] == ["view.mcap"]
    assert len(validated_messages(path)["/scan"]) == 1


# --------------------------------------------------------------------------- logs


def test_log_messages_validate_against_the_published_schemas(tmp_path):
    scans = [
        Scan(
            time_s=1.5 + i,
            angles_rad=np.linspace(-2.0, 2.0, 7),
            ranges_m=np.array([1.0, 0.0, 2.5, np.inf, 3.0, 0.25, 7.5]),
            range_max_m=8.0,
            intensities=np.arange(7.0),
        )
        for i in range(3)
    ]
    path = tmp_path / "log.mcap"
    write_log(path, scans, [(1.5, Pose2(1.0, -2.0, 3.0))], {"range_max_m": "8"})
    messages = validated_messages(path)
    assert [len(messages["/scan"]), len(messages["/odom"])] == [3, 1]
    first = messages["/scan"][0][1]
    assert list(first.ranges) == [1.0, 0.0, 2.5, 0.0, 3.0, 0.25, 7.5]
    assert _close(_pose(messages["/odom"][0][1].pose), Pose2(1.0, -2.0, 3.0))
    # The shipped log too, message by message.
    shipped = validated_messages(LOG)
    assert len(shipped["/scan"]) == len(read_log(LOG).scans)


def test_map_build_shows_the_built_map_over_the_scans_that_made_it(tmp_path, capsys):
    mapping = HALL / "mapping"
    out, view = tmp_path / "map.json", tmp_path / "build.mcap"
    args = ("map", "build", mapping / "log.mcap", "--survey", mapping / "survey.csv")
    result = run_cli(capsys, *args, "--out", out, "--mcap", view)
    assert result.code == 0, result.err
    messages = validated_messages(view)
    [(_, update)] = messages["/map"]
    points = np.array([(p.x, p.y) for line in update.entities[0].lines for p in line.points])
    assert_within_precision(read_map(out), points.reshape(-1, 4), "m")  # the file to 1 µm
    survey = list(csv.DictReader((mapping / "survey.csv").open(encoding="utf-8")))
    assert len(messages["/scan"]) == len(messages["/tf"]) == len(survey)
    for (_, transforms), row in zip(messages["/tf"], survey, strict=True):
        assert _close(_transform_pose(transforms.transforms[0]), _row_pose(row, ""))
    assert "/guess" not in messages and "/runner_up" not in messages


def test_the_shipped_layout_shows_every_topic_of_the_run_view():
    shipped = (resources.files("segloc_cli") / LAYOUT_FILE).read_text(encoding="utf-8")
    assert shipped == foxglove_layout(), f"segloc_cli/{LAYOUT_FILE} is not foxglove_layout()"
    layout = json.loads(shipped)
    scene, side = (item["content"] for item in layout["content"]["items"])
    shown = set(scene["config"]["topics"])
    shown |= {panel["content"]["config"].get("topicToRender") for panel in side["items"]}
    assert set(TOPICS) - {"/tf"} <= shown
    assert scene["config"]["followTf"] == WORLD_FRAME


# --------------------------------------------------------------------------- segloc info


def test_info_describes_a_run_view_instead_of_refusing_it(tmp_path, capsys):
    """Three scans simulated in the hall, localized with --mcap: info says what the view
    shows, counted from the file itself and from the run's estimates."""
    poses = tmp_path / "poses.csv"
    lines = (HALL / "poses.csv").read_text(encoding="utf-8").splitlines(keepends=True)
    poses.write_text("".join(lines[:4]), encoding="utf-8")
    sim, est, view = tmp_path / "sim", tmp_path / "est.csv", tmp_path / "run.mcap"
    world = HALL / "world.json"
    made = run_cli(capsys, "simulate", world, "--poses", poses, "--out", sim, "--seed", 7)
    assert made.code == 0, made.err
    args = ("localize", sim / "log.mcap", "--map", world, "--out", est, "--mcap", view)
    assert run_cli(capsys, *args).code == 0
    result = run_cli(capsys, "info", view)
    assert result.code == 0, result.err

    times_s = read_log(sim / "log.mcap").scan_times_s
    rows = list(csv.DictReader(est.open(encoding="utf-8")))
    statuses = Counter(row["status"] for row in rows)
    placed = sum(row["x_m"] != "" for row in rows)
    with open(view, "rb") as stream:
        counts = Counter(channel.topic for _, channel, _ in make_reader(stream).iter_messages())
    assert counts["/scan"] == len(times_s) == 3 and counts["/tf"] == placed
    assert result.out.splitlines() == [
        f"file:      {view}",
        "kind:      run view of segloc localize, to open in Foxglove (not a log)",
        f"/scan:     3 scans, {times_s.min():.3f}–{times_s.max():.3f} s",
        f"/tf:       {placed} scans placed in world, {3 - placed} without a pose",
        f"/map:      {len(read_map(world))} segments",
        "statuses:  " + ", ".join(f"{n} {status}" for status, n in sorted(statuses.items())),
        "messages:  " + ", ".join(f"{topic} {n}" for topic, n in sorted(counts.items())),
        "run.command: localize",
        f"run.logs: {sim / 'log.mcap'}",
        f"run.map: {world}",
        "run.mode: guided",
        f"layout:    {resources.files('segloc_cli') / LAYOUT_FILE} (in Foxglove: Layouts → "
        "Import from file)",
    ]
    # Given where a log belongs, the view is named for what it is.
    again = run_cli(capsys, "localize", view, "--map", world, "--out", tmp_path / "again.csv")
    assert again.code == 2
    assert again.err.strip() == (
        f"segloc: error: {view}: a run view (written by --mcap), not a log: it shows a run's "
        f"answers; `segloc info {view}` names the log it shows"
    )


def test_the_layout_is_package_data_that_info_names(capsys):
    """The layout travels in the package (declared for a non-editable install), is valid
    JSON, and ``segloc info --foxglove-layout`` prints its path, needing no log."""
    layout = resources.files("segloc_cli") / LAYOUT_FILE
    assert layout.is_file()
    assert json.loads(layout.read_text(encoding="utf-8"))["content"]["direction"] == "row"
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    declared = tomllib.loads(pyproject.read_text(encoding="utf-8"))["tool"]["setuptools"]
    assert LAYOUT_FILE in declared["package-data"]["segloc_cli"]
    result = run_cli(capsys, "info", "--foxglove-layout")
    assert result.code == 0 and result.err == ""
    assert result.out == f"{layout}\n"
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    assert f"(segloc_cli/{LAYOUT_FILE})" in readme
