"""Another localizer's trajectory, written in every format with the formats' own writers and
read back as estimates: the same poses, times and covariances from each, the same Table 1,
evo's APE, the transform chain of a bag, and one-line errors on bad input."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from amcl_bags import write_amcl_bag
from test_cli import run_cli
from trajectory_samples import (
    NS,
    ODOMETRY,
    POSE_STAMPED,
    PWCS,
    ROS1_STORE,
    ROS2_STORE,
    SCAN,
    TF,
    empty_scan,
    estimates_frame,
    odometry,
    pose_stamped,
    pose_with_covariance,
    tf_message,
    write_bag,
    write_foxglove_mcap,
    write_json_pose_mcap,
    write_tum,
)

from segloc_cli.errors import InputError
from segloc_cli.estimates import COVARIANCE_COLUMNS, ESTIMATE_COLUMNS, PoseTable
from segloc_cli.geometry import Pose2
from segloc_cli.io.tables import write_estimates, write_pose_table_tum
from segloc_cli.io.trajectories import EST_FORMATS, guess_format, read_trajectory
from segloc_cli.scoring.evaluate import TABLE_COLUMNS, table1

N = 50
EPOCH_NS = 1_700_000_000 * NS  # stamps near today's Unix time, where float seconds are coarse
rng = np.random.default_rng(33)
# 50 poses over 20 s, stamps with nanoseconds of their own.
STAMPS = sorted(EPOCH_NS + round(t * NS) + 7 for t in np.linspace(0.0, 20.0, N))
TIMES_S = np.array([stamp / NS for stamp in STAMPS])
TRUTH = np.column_stack(
    [np.linspace(1.0, 9.0, N), 2.0 + np.sin(np.linspace(0, 3, N)), np.linspace(-3.0, 3.0, N)]
)
ERRORS = np.column_stack(
    [rng.normal(0, 0.03, N), rng.normal(0, 0.03, N), np.radians(rng.normal(0, 1.0, N))]
)
POSES = TRUTH + ERRORS  # the localizer's estimates: a few cm off
_A = rng.normal(0, 0.1, (N, 3, 3))
COVARIANCES = _A @ np.transpose(_A, (0, 2, 1)) + 1e-4 * np.eye(3)
SURVEY = PoseTable(np.arange(1, N + 1, dtype=np.int64), TIMES_S.copy(), TRUTH.copy())


def amcl_messages(store, frame: str = "map") -> list[tuple]:
    return [
        ("/amcl_pose", stamp + 5_000_000, pose_with_covariance(store, stamp, frame, p, c))
        for stamp, p, c in zip(STAMPS, POSES, COVARIANCES, strict=True)
    ]


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> dict[str, tuple[Path, bool]]:
    """Every format of the one trajectory: name → (path, whether it carries covariance)."""
    where = tmp_path_factory.mktemp("formats")
    write_estimates(where / "est.csv", estimates_frame(TIMES_S, POSES))
    for storage in ("sqlite3", "mcap"):
        write_bag(storage, where / storage, {"/amcl_pose": PWCS}, amcl_messages(ROS2_STORE))
    shutil.copy(where / "mcap" / "mcap.mcap", where / "ros2.mcap")
    return {
        "segloc": (where / "est.csv", False),
        "tum": (write_tum(where / "est.tum", STAMPS, POSES), False),
        "ros1": (
            write_bag("ros1", where / "amcl.bag", {"/amcl_pose": PWCS}, amcl_messages(ROS1_STORE)),
            True,
        ),
        "ros2-sqlite3": (where / "sqlite3", True),
        "ros2-mcap": (where / "mcap", True),
        "mcap-ros2": (where / "ros2.mcap", True),
        "mcap-protobuf": (write_foxglove_mcap(where / "fox.mcap", STAMPS, POSES), False),
        "mcap-json": (write_json_pose_mcap(where / "json.mcap", STAMPS, POSES), False),
    }


FORMAT_NAMES = [
    "segloc",
    "tum",
    "ros1",
    "ros2-sqlite3",
    "ros2-mcap",
    "mcap-ros2",
    "mcap-protobuf",
    "mcap-json",
]


def assert_same_poses(frame: pd.DataFrame, poses: np.ndarray, tolerance: float = 1e-9) -> None:
    assert np.abs(frame["x_m"].to_numpy() - poses[:, 0]).max() < tolerance
    assert np.abs(frame["y_m"].to_numpy() - poses[:, 1]).max() < tolerance
    turned = (frame["theta_deg"].to_numpy() - np.degrees(poses[:, 2]) + 180.0) % 360.0 - 180.0
    assert np.abs(turned).max() < tolerance
    assert frame["theta_deg"].between(-180.0, 180.0, inclusive="left").all()


@pytest.mark.parametrize("name", FORMAT_NAMES)
def test_every_format_reads_back_the_poses_times_and_covariance_written(written, name):
    path, has_covariance = written[name]
    frame = read_trajectory(path)
    assert list(frame.columns) == [*ESTIMATE_COLUMNS, *COVARIANCE_COLUMNS]
    assert frame["pose_id"].tolist() == list(range(1, N + 1))
    # The float nearest each nanosecond stamp, the one a bag's stamp gives.
    assert frame["time_s"].tolist() == [stamp / NS for stamp in STAMPS]
    # segloc's CSV keeps positions to the micrometre and headings to 1e-6°.
    assert_same_poses(frame, POSES, 0.5e-6 * 1.001 if name == "segloc" else 1e-9)
    assert (frame["status"] == "ok").all()
    assert frame.attrs["dropped"] == {}
    covariance = frame[list(COVARIANCE_COLUMNS)].to_numpy()
    if has_covariance:
        upper = COVARIANCES[:, [0, 0, 1, 0, 1, 2], [0, 1, 1, 2, 2, 2]]
        np.testing.assert_array_equal(covariance, upper)
    else:
        assert np.isnan(covariance).all()


def test_the_sample_amcl_bag_reads_back_at_its_times_to_the_nanosecond(tmp_path):
    bag = write_amcl_bag(tmp_path / "amcl", TIMES_S, POSES, COVARIANCES)
    frame = read_trajectory(bag)
    assert np.abs(frame["time_s"].to_numpy() - TIMES_S).max() < 1e-6
    assert_same_poses(frame, POSES)
    np.testing.assert_array_equal(frame["cov_xy_m2"], COVARIANCES[:, 0, 1])


def test_the_source_line_says_what_was_read(written):
    ros2 = read_trajectory(written["ros2-sqlite3"][0])
    assert ros2.attrs["source"] == (
        "ROS 2 bag, /amcl_pose (geometry_msgs/msg/PoseWithCovarianceStamped), its only pose "
        f"topic, {N} poses in frame map"
    )
    fox = read_trajectory(written["mcap-protobuf"][0], topic="/pose")
    assert fox.attrs["source"] == (
        f"MCAP file, /pose (foxglove.PoseInFrame, protobuf), {N} poses in frame map"
    )


@pytest.mark.parametrize(
    ("name", "fmt"),
    [
        ("segloc", "segloc"),
        ("tum", "tum"),
        ("ros1", "ros1"),
        ("ros2-mcap", "ros2"),
        ("mcap-ros2", "mcap"),
    ],
)
def test_the_format_is_told_by_extension_and_folder(written, name, fmt):
    assert guess_format(written[name][0]) == fmt


def test_a_file_without_a_known_extension_is_told_by_its_contents(written, tmp_path):
    (tmp_path / "trajectory.txt").write_bytes(written["tum"][0].read_bytes())
    (tmp_path / "poses").write_bytes(written["mcap-json"][0].read_bytes())
    assert guess_format(tmp_path / "trajectory.txt") == "tum"
    assert guess_format(tmp_path / "poses") == "mcap"
    (tmp_path / "notes.txt").write_text("a b c\n")
    with pytest.raises(InputError) as caught:
        guess_format(tmp_path / "notes.txt")
    assert_one_line(caught.value, "--est-format", ", ".join(EST_FORMATS))


def test_table1_is_the_same_from_every_format(written):
    columns = list(TABLE_COLUMNS)  # the covariance beside them differs by format
    expected = table1(read_trajectory(written["segloc"][0]), SURVEY)[columns]
    assert len(expected) == N
    # Errors of a few cm: the comparison below would see a pose mixed up.
    assert 1.0 < np.sqrt(np.mean(expected["err_xy_cm"] ** 2)) < 10.0
    for name in FORMAT_NAMES[1:]:
        table = table1(read_trajectory(written[name][0]), SURVEY)[columns]
        # segloc's CSV (the expected table's) keeps positions to 1 µm (1e-4 cm), headings to
        # 1e-6°.
        pd.testing.assert_frame_equal(table, expected, check_exact=False, rtol=0, atol=1e-4)


def test_the_translation_rms_agrees_with_evo_ape(written, tmp_path):
    from evo.core import metrics, sync  # type: ignore[import-untyped]
    from evo.tools import file_interface  # type: ignore[import-untyped]

    truth_path = tmp_path / "truth.tum"
    write_pose_table_tum(truth_path, SURVEY)
    estimates_path = written["tum"][0]
    reference = file_interface.read_tum_trajectory_file(str(truth_path))
    estimated = file_interface.read_tum_trajectory_file(str(estimates_path))
    reference, estimated = sync.associate_trajectories(reference, estimated, max_diff=0.001)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((reference, estimated))
    evo_rms_m = ape.get_statistic(metrics.StatisticsType.rmse)

    table = table1(read_trajectory(estimates_path), SURVEY)
    rms_m = math.sqrt(np.mean((table["err_xy_cm"].to_numpy() / 100.0) ** 2))
    assert len(table) == N
    assert abs(rms_m - evo_rms_m) < 1e-4


def test_each_pose_message_type_is_read_from_its_topic(tmp_path):
    topics = {"/amcl_pose": PWCS, "/pose": POSE_STAMPED, "/odom": ODOMETRY}
    makers = {"/amcl_pose": pose_with_covariance, "/pose": pose_stamped, "/odom": odometry}
    messages = [
        (topic, stamp, maker(ROS2_STORE, stamp, "odom", p, c))
        for topic, maker in makers.items()
        for stamp, p, c in zip(STAMPS, POSES, COVARIANCES, strict=True)
    ]
    bag = write_bag("sqlite3", tmp_path / "bag", topics, sorted(messages, key=lambda m: m[1]))
    for topic in topics:
        frame = read_trajectory(bag, topic=topic)
        assert frame["time_s"].tolist() == TIMES_S.tolist()
        assert_same_poses(frame, POSES)
        assert topic in frame.attrs["source"] and "in frame odom" in frame.attrs["source"]
        var_x = frame["var_x_m2"].to_numpy()
        if topic == "/pose":
            assert np.isnan(var_x).all()
        else:
            np.testing.assert_array_equal(var_x, COVARIANCES[:, 0, 0])
            np.testing.assert_array_equal(frame["var_theta_rad2"], COVARIANCES[:, 2, 2])


# The chain map → odom → base_link → base_footprint: map → odom from a localizer at 2 Hz,
# its first stamp after odometry's first; odom → base_link from odometry at 10 Hz; the
# footprint below base_link on /tf_static.
ODOM_STAMPS = [EPOCH_NS + j * NS // 10 for j in range(20)]
MAP_ODOM_STAMPS = [EPOCH_NS + NS // 10 + k * NS // 2 for k in range(4)]  # = odom's 1, 6, 11, 16
MAP_ODOM = [(0.5 + 0.1 * k, -0.2 * k, 0.3 - 0.05 * k) for k in range(4)]
ODOM_BASE = [(0.2 * j, 0.05 * j * j, 0.1 * j - 1.0) for j in range(20)]
FOOTPRINT = (0.1, -0.05, 0.2)


def tf_records(store, odom_base=ODOM_BASE, map_odom=MAP_ODOM) -> list[tuple]:
    records = [
        ("/tf_static", EPOCH_NS, tf_message(store, [(0, "base_link", "base_footprint", FOOTPRINT)]))
    ]
    records += [
        ("/tf", stamp, tf_message(store, [(stamp, "odom", "base_link", pose)]))
        for stamp, pose in zip(ODOM_STAMPS, odom_base, strict=True)
    ]
    records += [
        ("/tf", stamp + 1, tf_message(store, [(stamp, "map", "odom", pose)]))
        for stamp, pose in zip(MAP_ODOM_STAMPS, map_odom, strict=True)
    ]
    return sorted(records, key=lambda r: r[1])


def expected_chain(odom_base=ODOM_BASE, map_odom=MAP_ODOM) -> tuple[list[int], np.ndarray]:
    """By the rule: at each odometry stamp from the first map → odom on, the latest
    map → odom ⊕ odom → base_link ⊕ the footprint's mounting; none where either latest
    link is not finite."""
    stamps, poses = [], []
    for stamp, odom_pose in zip(ODOM_STAMPS, odom_base, strict=True):
        latest = [pose for s, pose in zip(MAP_ODOM_STAMPS, map_odom, strict=True) if s <= stamp]
        if latest and np.isfinite([*latest[-1], *odom_pose]).all():
            pose = Pose2(*latest[-1]).compose(Pose2(*odom_pose)).compose(Pose2(*FOOTPRINT))
            stamps.append(stamp)
            poses.append(pose.as_array())
    return stamps, np.array(poses)


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_a_transform_chain_is_composed_at_each_stamp_of_a_moving_link(tmp_path, kind):
    store = ROS1_STORE if kind == "ros1" else ROS2_STORE
    path = tmp_path / ("tf.bag" if kind == "ros1" else "tf")
    bag = write_bag(kind, path, {"/tf": TF, "/tf_static": TF}, tf_records(store))
    frame = read_trajectory(bag, topic="/tf", frames=("map", "base_footprint"))
    stamps, poses = expected_chain()
    assert len(stamps) == 19  # odometry's first stamp comes before any map → odom
    assert frame["time_s"].tolist() == [stamp / NS for stamp in stamps]
    assert_same_poses(frame, poses)
    assert frame.attrs["dropped"] == {
        "stamps at which a link of map → odom → base_link → base_footprint was not yet "
        "given or older than 10 s": 1
    }
    assert "map → odom → base_link → base_footprint" in frame.attrs["source"]
    assert np.isnan(frame[list(COVARIANCE_COLUMNS)].to_numpy()).all()


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_a_link_not_finite_leaves_no_pose_until_it_is_given_again(tmp_path, kind):
    store = ROS1_STORE if kind == "ros1" else ROS2_STORE
    nan = (np.nan, 0.0, 0.0)
    odom_base = [nan if j == 8 else pose for j, pose in enumerate(ODOM_BASE)]
    map_odom = [nan if k == 2 else pose for k, pose in enumerate(MAP_ODOM)]  # odom's 11
    path = tmp_path / ("tf.bag" if kind == "ros1" else "tf")
    records = tf_records(store, odom_base, map_odom)
    bag = write_bag(kind, path, {"/tf": TF, "/tf_static": TF}, records)
    frame = read_trajectory(bag, topic="/tf", frames=("map", "base_footprint"))
    stamps, poses = expected_chain(odom_base, map_odom)
    # Not at odom's stamp 8, nor at 11–15 while map → odom's latest is unknown.
    assert len(stamps) == 13
    assert frame["time_s"].tolist() == [stamp / NS for stamp in stamps]
    assert_same_poses(frame, poses)
    chain = "map → odom → base_link → base_footprint"
    assert frame.attrs["dropped"] == {
        "transforms not finite or with an all-zero quaternion": 2,
        f"stamps at which a link of {chain} was last given by a transform not finite": 6,
        f"stamps at which a link of {chain} was not yet given or older than 10 s": 1,
    }


def test_a_chain_of_static_transforms_alone_is_refused(tmp_path):
    records = [
        ("/tf_static", EPOCH_NS, tf_message(ROS2_STORE, [(0, "map", "odom", (1.0, 0.0, 0.0))])),
        ("/tf_static", EPOCH_NS + 1, tf_message(ROS2_STORE, [(0, "odom", "base_link", FOOTPRINT)])),
    ]
    bag = write_bag("mcap", tmp_path / "bag", {"/tf_static": TF}, records)
    text = read_error(bag, topic="/tf_static", frames=("map", "base_link"))
    assert_one_line(InputError(text), "no link of the chain map → odom → base_link moves")


def test_a_chain_of_foxglove_frame_transforms_is_composed(tmp_path):
    import foxglove
    from foxglove import channels
    from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Timestamp, Vector3

    from segloc_cli.geometry import heading_to_quaternion

    def transform(stamp: int, parent: str, child: str, pose) -> FrameTransform:
        qx, qy, qz, qw = heading_to_quaternion(pose[2]).tolist()
        return FrameTransform(
            timestamp=Timestamp(sec=stamp // NS, nsec=stamp % NS),
            parent_frame_id=parent,
            child_frame_id=child,
            translation=Vector3(x=float(pose[0]), y=float(pose[1]), z=0.0),
            rotation=Quaternion(x=qx, y=qy, z=qz, w=qw),
        )

    context = foxglove.Context()
    writer = foxglove.open_mcap(tmp_path / "tf.mcap", context=context)
    channel = channels.FrameTransformsChannel("/tf", context=context)
    for stamp, pose in zip(STAMPS, POSES, strict=True):
        links = [transform(stamp, "world", "base_link", pose)]
        links += [transform(stamp, "base_link", "laser", FOOTPRINT)]
        channel.log(FrameTransforms(transforms=links), log_time=stamp)
    writer.close()
    frame = read_trajectory(tmp_path / "tf.mcap", frames=("world", "laser"))
    assert frame["time_s"].tolist() == TIMES_S.tolist()
    expected = [Pose2(*pose).compose(Pose2(*FOOTPRINT)).as_array() for pose in POSES]
    assert_same_poses(frame, np.array(expected))


def rolled(yaw_rad: float, roll_rad: float) -> list[float]:
    """The quaternion x y z w of a turn by ``yaw_rad`` about z after ``roll_rad`` about x:
    its x axis seen from above still points at ``yaw_rad``."""
    cz, sz = math.cos(yaw_rad / 2), math.sin(yaw_rad / 2)
    cr, sr = math.cos(roll_rad / 2), math.sin(roll_rad / 2)
    return [cz * sr, sz * sr, cr * sz, cz * cr]


def test_what_is_left_out_is_counted_by_reason(tmp_path):
    messages = amcl_messages(ROS2_STORE)[:10]
    nan_pose = pose_with_covariance(ROS2_STORE, STAMPS[3], "map", (np.nan, 1.0, 0.0))
    messages[3] = ("/amcl_pose", messages[3][1], nan_pose)
    messages[5] = (
        "/amcl_pose",
        messages[5][1],
        pose_with_covariance(ROS2_STORE, STAMPS[5], "odom", POSES[5]),
    )
    repeat = pose_with_covariance(ROS2_STORE, STAMPS[7], "map", (50.0, 50.0, 0.0))
    messages.append(("/amcl_pose", messages[-1][1] + 1, repeat))
    for k, roll_deg in ((8, 10.0), (9, 60.0)):  # kept with a warning; left out
        q = rolled(POSES[k, 2], math.radians(roll_deg))
        message = pose_with_covariance(ROS2_STORE, STAMPS[k], "map", POSES[k], quaternion=q)
        messages[k] = ("/amcl_pose", messages[k][1], message)
    bag = write_bag("mcap", tmp_path / "bag", {"/amcl_pose": PWCS}, messages)
    frame = read_trajectory(bag)
    assert frame.attrs["dropped"] == {
        "not finite (or an all-zero quaternion)": 1,
        "tilted more than 45° from level": 1,
        "in frame odom, not map (the frame most poses are in)": 1,
        "repeating a time (the first kept)": 1,
    }
    kept = [0, 1, 2, 4, 6, 7, 8]
    assert frame["time_s"].tolist() == TIMES_S[kept].tolist()
    assert_same_poses(frame, POSES[kept])  # the first of the repeated stamp, not (50, 50)
    assert frame.attrs["warnings"] == [
        "1 pose tilted more than 3° from level (at most 10.0°); its heading is its x "
        "axis seen from above"
    ]


TILTED = {3: 20.0, 4: 30.0, 6: 4.0}
"""Poses rolled (degrees) in the trajectories below; the others are level."""


def tilted_tum(path: Path) -> Path:
    lines = []
    for k, (stamp, (x, y, theta)) in enumerate(zip(STAMPS, POSES, strict=True)):
        q = rolled(theta, math.radians(TILTED.get(k, 0.0)))
        lines.append(" ".join(repr(float(v)) for v in (stamp / NS, x, y, 0.0, *q)))
    path.write_text("\n".join(lines) + "\n")
    return path


def tilted_bag(path: Path) -> Path:
    messages = [
        ("/amcl_pose", stamp, pose_with_covariance(ROS2_STORE, stamp, "map", p, quaternion=q))
        for k, (stamp, p) in enumerate(zip(STAMPS, POSES, strict=True))
        for q in [rolled(p[2], math.radians(TILTED.get(k, 0.0)))]
    ]
    return write_bag("mcap", path, {"/amcl_pose": PWCS}, messages)


@pytest.mark.parametrize(
    ("make", "warning"),
    [
        (tilted_tum, "3 poses tilted more than 3° from level (at most 30.0°)"),
        (tilted_bag, "3 poses tilted more than 3° from level (at most 30.0°)"),
        (
            lambda path: write_json_pose_mcap(path, STAMPS, POSES, untimed=(2, 5)),
            "2 messages on /pose carry no timestamp; their log times are used",
        ),
    ],
    ids=["tum", "ros2", "mcap-untimed"],
)
def test_evaluate_prints_what_the_reader_noted_once_with_its_count(capsys, tmp_path, make, warning):
    est = make(tmp_path / "est")
    survey = tmp_path / "survey.tum"
    write_pose_table_tum(survey, SURVEY)
    fmt = {"tilted_tum": "tum", "tilted_bag": "ros2"}.get(make.__name__, "mcap")
    result = run_cli(capsys, "evaluate", est, "--est-format", fmt, "--survey", survey)
    assert result.code == 0, result.err
    warnings = [line for line in result.err.splitlines() if line.startswith("segloc: warning:")]
    assert len(warnings) == 1, result.err
    assert warnings[0].startswith(f"segloc: warning: {est}: {warning}")


# --- bad input ------------------------------------------------------------------------


def assert_one_line(error: InputError, *fragments: str) -> str:
    text = str(error)
    assert "\n" not in text
    for fragment in fragments:
        assert fragment in text, f"{fragment!r} not in {text!r}"
    return text


def read_error(*args, **kwargs) -> str:
    with pytest.raises(InputError) as caught:
        read_trajectory(*args, **kwargs)
    return str(caught.value)


@pytest.fixture
def busy_bag(tmp_path) -> Path:
    """A ROS 2 bag with a scan topic, AMCL's poses, odometry and transforms."""
    topics = {"/scan": SCAN, "/amcl_pose": PWCS, "/odom": ODOMETRY, "/tf": TF}
    stamp = STAMPS[0]
    messages = [
        ("/scan", stamp, empty_scan(ROS2_STORE, stamp)),
        ("/amcl_pose", stamp, pose_with_covariance(ROS2_STORE, stamp, "map", POSES[0])),
        ("/odom", stamp, odometry(ROS2_STORE, stamp, "odom", POSES[0])),
        ("/tf", stamp, tf_message(ROS2_STORE, [(stamp, "odom", "base_link", (0, 0, 0))])),
    ]
    return write_bag("sqlite3", tmp_path / "busy", topics, messages)


def test_a_missing_topic_lists_the_topics_pose_like_first(busy_bag):
    text = read_error(busy_bag, topic="/nope")
    assert_one_line(
        InputError(text),
        "no topic /nope",
        "/amcl_pose (geometry_msgs/msg/PoseWithCovarianceStamped)",
    )
    assert text.index("/amcl_pose") < text.index("/tf ") < text.index("/scan")


def test_several_pose_topics_and_no_topic_given_names_the_candidates(busy_bag):
    text = read_error(busy_bag)
    assert_one_line(InputError(text), "--topic", "3 pose topics", "/amcl_pose", "/odom", "/tf")
    assert "/scan" not in text


def test_an_unsupported_message_type_names_the_supported_ones(busy_bag):
    text = read_error(busy_bag, topic="/scan")
    assert_one_line(
        InputError(text),
        "/scan holds sensor_msgs/msg/LaserScan",
        "supported types",
        "geometry_msgs/msg/PoseWithCovarianceStamped",
        "foxglove.PoseInFrame",
    )


def test_a_transform_topic_needs_frames_that_are_there(busy_bag):
    assert_one_line(
        InputError(read_error(busy_bag, topic="/tf")),
        "--frames",
        "frames seen: base_link, odom",
    )
    text = read_error(busy_bag, topic="/tf", frames=("map", "base_link"))
    assert_one_line(
        InputError(text), "frame map is not in the transforms", "frames seen: base_link, odom"
    )
    text = read_error(busy_bag, topic="/amcl_pose", frames=("map", "base_link"))
    assert_one_line(InputError(text), "--frames applies to a transform topic")


def test_a_chain_whose_links_never_meet_in_time_is_refused(tmp_path):
    late = EPOCH_NS + 60 * NS
    records = [
        ("/tf", EPOCH_NS, tf_message(ROS2_STORE, [(EPOCH_NS, "map", "odom", (0, 0, 0))])),
        ("/tf", late, tf_message(ROS2_STORE, [(late, "odom", "base_link", (1, 0, 0))])),
    ]
    bag = write_bag("mcap", tmp_path / "bag", {"/tf": TF}, records)
    text = read_error(bag, topic="/tf", frames=("map", "base_link"))
    assert_one_line(
        InputError(text), "never complete", "within 10 s", "map → odom once, at 1700000000.000 s"
    )


def test_an_empty_topic_is_refused(tmp_path):
    bag = write_bag("sqlite3", tmp_path / "bag", {"/amcl_pose": PWCS}, [])
    assert_one_line(InputError(read_error(bag)), "topic /amcl_pose holds no messages")


def test_a_bag_cut_short_gives_the_poses_before_the_damage(tmp_path):
    from rosbags.rosbag1 import Writer

    writer = Writer(tmp_path / "whole.bag")
    writer.chunk_threshold = 256  # a few messages a chunk
    with writer:
        connection = writer.add_connection("/amcl_pose", PWCS, typestore=ROS1_STORE)
        for _, record_ns, message in amcl_messages(ROS1_STORE):
            writer.write(connection, record_ns, bytes(ROS1_STORE.serialize_ros1(message, PWCS)))
    data = (tmp_path / "whole.bag").read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    frame = read_trajectory(cut, topic="/amcl_pose")
    assert 10 < len(frame) < N
    assert frame["time_s"].tolist() == TIMES_S[: len(frame)].tolist()
    assert_same_poses(frame, POSES[: len(frame)])
    assert "read up to damage" in frame.attrs["source"]
    assert f"{len(frame)} poses read before it" in frame.attrs["warnings"][-1]
    assert_one_line(InputError(read_error(cut)), "give --topic to read it record by record")
    cut.write_bytes(data[:100])
    assert_one_line(InputError(read_error(cut, topic="/amcl_pose")), "not a readable ROS bag")


def test_an_mcap_file_cut_short_gives_the_poses_before_the_damage(written, tmp_path):
    from mcap.writer import Writer

    whole = tmp_path / "whole.mcap"
    with whole.open("wb") as stream:  # small chunks, as a recorder's
        writer = Writer(stream, chunk_size=512)
        writer.start(profile="ros2")
        schema = writer.register_schema(PWCS, "ros2msg", b"")
        channel = writer.register_channel("/amcl_pose", "cdr", schema)
        for _, record_ns, message in amcl_messages(ROS2_STORE):
            data = bytes(ROS2_STORE.serialize_cdr(message, PWCS))
            writer.add_message(channel, log_time=record_ns, data=data, publish_time=record_ns)
        writer.finish()
    data = whole.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    frame = read_trajectory(cut)
    assert 10 < len(frame) < N
    assert_same_poses(frame, POSES[: len(frame)])
    np.testing.assert_array_equal(frame["var_y_m2"], COVARIANCES[: len(frame), 1, 1])
    assert f"{len(frame)} poses read before it" in frame.attrs["warnings"][-1]
    cut.write_bytes(b"not an mcap file at all")
    assert_one_line(InputError(read_error(cut, fmt="mcap")), "not an MCAP file")
    cut.write_bytes(data[:20])
    assert_one_line(InputError(read_error(cut)), "damaged before its first message")


def test_a_tum_line_of_the_wrong_count_is_named(tmp_path):
    path = tmp_path / "bad.tum"
    path.write_text("# t x y z qx qy qz qw\n1 2 3 0 0 0 0 1\n2 2 3 0 0 0 1\n")
    assert_one_line(InputError(read_error(path)), "line 3 holds 7 values", "8 numbers")
    path.write_text("1 2 3 0 0 0 0 one\n")
    assert_one_line(InputError(read_error(path)), "line 1: 'one' is not a number")


def test_options_that_do_not_apply_and_unknown_formats_are_refused(written):
    tum = written["tum"][0]
    assert_one_line(InputError(read_error(tum, topic="/amcl_pose")), "--topic applies to ROS bags")
    assert_one_line(
        InputError(read_error(tum, fmt="csv")), "unknown trajectory format 'csv'", "--est-format"
    )
