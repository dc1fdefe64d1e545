"""The run view: an MCAP file that shows a localization run (or a map build) in Foxglove.

Written with the Foxglove SDK, so every message is protobuf under Foxglove's own published
schema (the schema travels in the file) and the file is chunked, indexed and compressed
(zstd). Frames: ``world`` (the map), ``base_link`` (the robot, at the estimate) and
``laser`` (the scanner, mounted on the robot). Topics:

- ``/map``: ``foxglove.SceneUpdate``, one entity ``map`` of line segments in ``world``,
  written once at the first scan's time and kept for the whole run.
- ``/tf``: ``foxglove.FrameTransforms`` at each scan with a pose: ``world → base_link`` (the
  estimate, or the surveyed pose of a map build) and ``base_link → laser`` (the mounting).
- ``/scan``: ``foxglove.LaserScan`` in ``laser``, every scan, with or without a pose;
  invalid readings as 0 (Foxglove skips them).
- ``/estimate``, ``/guess``, ``/runner_up``: ``foxglove.PoseInFrame`` in ``world``: the
  answer, the initial guess and the best distinct alternative, each where it exists.
- ``/hypotheses``: ``foxglove.PosesInFrame`` in ``world``: every distinct pose found
  besides the answer (the runner-up first), where the caller lists any.
- ``/local_segments``: ``foxglove.SceneUpdate``, one entity ``local_segments`` in
  ``base_link``: the segments the localizer extracted from the scan, with the status as text
  above the robot. Each scan's entity replaces the last.
- ``/status``: ``foxglove.Log``, one line per scan at the level the caller gives (a run:
  info when the estimate is accepted, warning when ambiguous, error otherwise).
- ``/loops`` (a map built with no survey): ``foxglove.SceneUpdate``, one entity ``loops`` of
  lines in ``world``, each joining two keyframes a loop joined; ``/guess`` there is where the
  odometry alone put each scan.

Every message's log time is its scan's time (ns). Metadata record ``segloc.run`` says what
the file shows (the caller's words: command, logs, map...), and ``segloc.view``, written when
the file is closed, what was drawn: ``map_segments`` and, for each status, ``status.NAME``
the number of scans with it; for a run stopped before its end (``note_stopped``), also
``stopped_by`` (the signal), ``scans_done`` and ``scans_planned``.

The file is streamed in place, like the estimates beside it: the scans added are handed to
the operating system as a chunk at least every ``FLUSH_INTERVAL_S`` (the first at once), so
a run that is killed leaves a view that an MCAP reader reads, without the summary that comes
last, up to the last whole scan of its last chunk. Leaving the writer's block finishes the
file, whatever ended the run. ``read_run_view`` tells a run view from a log and says what
it holds, from its summary or, in a view cut short, from its records; ``layout_path`` is
where the package keeps the Foxglove layout for it (``foxglove_layout``, as a file).
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from segloc_cli.geometry import Pose2, heading_to_quaternion
from segloc_cli.io.files import OutputError, writing_error
from segloc_cli.scan import Scan
from segloc_cli.wording import counted, stopped_after

if TYPE_CHECKING:
    from foxglove.mcap import MCAPWriter

WORLD_FRAME = "world"
ROBOT_FRAME = "base_link"
LASER_FRAME = "laser"
RUN_METADATA_NAME = "segloc.run"
VIEW_METADATA_NAME = "segloc.view"
LAYOUT_FILE = "foxglove-layout.json"
"""The layout (``foxglove_layout``) as the package ships it, beside this package's modules."""

POSE_TOPICS = ("/estimate", "/guess", "/runner_up")
"""The poses of each scan, in ``world``."""
TOPICS = ("/map", "/tf", "/scan", *POSE_TOPICS, "/hypotheses", "/local_segments", "/status")
"""Every topic of a run view, in the order its channels are made."""

CHUNK_BYTES = 4 * 2**20
"""Largest uncompressed chunk (bytes) of the run view."""
FLUSH_INTERVAL_S = 0.5
"""Longest time (s) the scans added stay in memory before they go to disk as a chunk: what
a killed run can lose of its view (a chunk per scan would make the file half as large again)."""
LINE_WIDTH_PX = {"map": 2.0, "local_segments": 3.0, "loops": 2.0}
"""Line thickness (screen pixels, so that it stays readable at any zoom)."""
RGBA = {
    "map": (0.85, 0.85, 0.85, 1.0),
    "local_segments": (1.0, 0.55, 0.0, 1.0),
    "loops": (0.2, 0.8, 0.3, 1.0),
}
LOOPS_TOPIC = "/loops"
"""A map built with no survey: its loops, each a line from the keyframe of the submap it was
found in to the keyframe found (``RunViewWriter.add_loops``)."""
TEXT_HEIGHT_M = 0.4
FRAME_ORIGIN = Pose2(0.0, 0.0, 0.0)
"""The pose of a scan or a primitive drawn in its own frame."""
LEVELS = ("info", "warning", "error")
"""Levels of the ``/status`` lines."""


class _Sink:
    """The run view's file, as the Foxglove SDK's writer takes one (``write``, ``seek``,
    ``flush``), keeping the first OS error met, which the SDK's own error leaves out."""

    def __init__(self, path: Path):
        self.error: OSError | None = None
        try:
            self._file: IO[bytes] = open(path, "wb")
        except OSError as exc:
            raise writing_error(path, exc) from None

    def write(self, data: bytes | bytearray) -> int:
        return self._noted(self._file.write, data)

    def seek(self, offset: int, whence: int = 0) -> int:
        return self._noted(self._file.seek, offset, whence)

    def flush(self) -> None:
        self._noted(self._file.flush)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._file.close()

    def _noted(self, call, *args):
        try:
            return call(*args)
        except OSError as exc:
            self.error = self.error or exc
            raise


class RunViewWriter:
    """Writes a run view (see the module docstring); use as a context manager.

    ``map_segments`` (M, 4) ``x1 y1 x2 y2`` metres in ``world``; ``metadata`` str → str,
    stored as ``segloc.run``. Each scan's ``mount`` gives its ``base_link → laser``.
    The file is written in place (truncated first; whether it may be is the caller's
    question), the scans added on disk every ``FLUSH_INTERVAL_S``. Leaving the block
    finishes it with every scan added, an exception or not. An OS error (a full disk)
    raises ``OutputError`` naming ``path`` and why; the file then keeps the scans written
    before it.
    """

    def __init__(
        self,
        path: str | Path,
        map_segments: np.ndarray,
        metadata: dict[str, str] | None = None,
    ):
        import foxglove
        from foxglove import channels
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        self.path = Path(path)
        self._map = np.asarray(map_segments, dtype=float).reshape(-1, 4)
        self._map_written = False
        self._statuses: Counter[str] = Counter()
        self._stopped: dict[str, str] = {}
        self._flushed_at = -math.inf  # time.monotonic() of the last chunk handed on
        self._sink = _Sink(self.path)
        self._context = foxglove.Context()
        options = MCAPWriteOptions(compression=MCAPCompression.Zstd, chunk_size=CHUNK_BYTES)
        self._writer: MCAPWriter | None = None
        with self._failing_writes():
            self._writer = foxglove.open_mcap(
                self._sink, allow_overwrite=True, context=self._context, writer_options=options
            )
            self._writer.write_metadata(RUN_METADATA_NAME, dict(metadata or {}))
        made = {
            "/map": channels.SceneUpdateChannel,
            "/tf": channels.FrameTransformsChannel,
            "/scan": channels.LaserScanChannel,
            **dict.fromkeys(POSE_TOPICS, channels.PoseInFrameChannel),
            "/hypotheses": channels.PosesInFrameChannel,
            "/local_segments": channels.SceneUpdateChannel,
            "/status": channels.LogChannel,
        }
        self._channels: dict[str, Any] = {
            topic: made[topic](topic, context=self._context) for topic in TOPICS
        }

    def __enter__(self) -> RunViewWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
            return
        with contextlib.suppress(OutputError):  # the run's own error is the one to report
            self.close()

    def add(
        self,
        scan: Scan,
        local_segments: np.ndarray,
        pose: Pose2 | None,
        *,
        guess: Pose2 | None = None,
        runner_up: Pose2 | None = None,
        hypotheses: tuple[Pose2, ...] = (),
        status: str = "ok",
        level: str = "info",
        text: str = "",
    ) -> None:
        """One scan: its readings, its local segments (K, 4) metres in the robot frame, its
        pose in ``world`` (None or NaN: none was found), the guess and runner-up where they
        exist, the other distinct poses found (``hypotheses``, best first, the answer not
        among them), its status, and a line of text for the log at ``level`` (one of
        ``LEVELS``). The scans added go to disk, whole, at least every ``FLUSH_INTERVAL_S``."""
        time_ns = _time_ns(scan.time_s)
        if not self._map_written:
            self._write_map(time_ns)
        stamp = _timestamp(time_ns)
        pose, guess, runner_up = (_finite(p) for p in (pose, guess, runner_up))
        if pose is not None:
            self._log("/tf", _transforms(stamp, pose, scan.mount), time_ns)
        self._log("/scan", _laser_scan(stamp, scan), time_ns)
        for topic, shown in zip(POSE_TOPICS, (pose, guess, runner_up), strict=True):
            if shown is not None:
                self._log(topic, _pose_in_frame(stamp, shown), time_ns)
        listed = [p for p in map(_finite, hypotheses) if p is not None]
        if listed:
            self._log("/hypotheses", _poses_in_frame(stamp, listed), time_ns)
        entity = _lines_entity(stamp, "local_segments", ROBOT_FRAME, local_segments, status)
        self._log("/local_segments", _scene_update(entity), time_ns)
        self._log("/status", _log_line(stamp, status, level, text), time_ns)
        self._statuses[status] += 1
        if self._writer is not None and time.monotonic() - self._flushed_at >= FLUSH_INTERVAL_S:
            with self._failing_writes():
                self._writer.flush()  # the chunk of the scans since the last, to the OS
            self._flushed_at = time.monotonic()

    def add_row(
        self, scan: Scan, local_segments: np.ndarray, row: Mapping[str, Any], log_path: Path
    ) -> None:
        """One scan of a localize run with its estimates row (``estimates.EstimateRow``):
        the answer, the guess, the runner-up and the row's other ``hypotheses`` (best
        first, the answer among them) as poses in ``world``, the status at its level
        (``status_level``) and a line on the row (``row_text``) naming the log's file."""
        self.add(
            scan,
            local_segments,
            row_pose(row, ""),
            guess=row_pose(row, "init_"),
            runner_up=row_pose(row, "runner_up_"),
            hypotheses=tuple(row_pose(h, "") for h in row.get("hypotheses", [])[1:]),
            status=row["status"],
            level=status_level(row["status"]),
            text=row_text(log_path, row),
        )

    def add_loops(self, lines: np.ndarray, time_s: float) -> None:
        """The loops of a map built with no survey, as lines (K, 4) ``x1 y1 x2 y2`` metres in
        ``world``, on ``LOOPS_TOPIC`` (a channel of its own, made on the first call) at
        ``time_s``."""
        from foxglove import channels

        if LOOPS_TOPIC not in self._channels:
            self._channels[LOOPS_TOPIC] = channels.SceneUpdateChannel(
                LOOPS_TOPIC, context=self._context
            )
        time_ns = _time_ns(time_s)
        entity = _lines_entity(_timestamp(time_ns), "loops", WORLD_FRAME, lines, None)
        self._log(LOOPS_TOPIC, _scene_update(entity), time_ns)

    def note_stopped(self, by: str, done: int, planned: int) -> None:
        """Record, when the file is finished, that its run was stopped by the signal ``by``
        after ``done`` of the ``planned`` scans: the view shows those alone."""
        self._stopped = {"stopped_by": by, "scans_done": str(done), "scans_planned": str(planned)}

    def close(self) -> None:
        """Finish the file (with the map even if no scan came): what was drawn, the summary.
        Closing again does nothing."""
        if self._writer is None:
            return
        if not self._map_written:
            self._write_map(0)
        drawn = {"map_segments": str(len(self._map))}
        drawn |= {f"status.{name}": str(n) for name, n in sorted(self._statuses.items())}
        drawn |= self._stopped
        with self._failing_writes():
            self._writer.write_metadata(VIEW_METADATA_NAME, drawn)
            self._writer.close()
        self._release()

    @contextlib.contextmanager
    def _failing_writes(self):
        """Turn the SDK's failure to write into ``OutputError`` naming the file and the OS
        error behind it; the writer is let go (it takes no more writes)."""
        try:
            yield
        except (OSError, RuntimeError) as exc:
            self._release()
            reason = self._sink.error or (exc if isinstance(exc, OSError) else OSError(str(exc)))
            raise writing_error(self.path, reason) from None

    def _release(self) -> None:
        """Let the SDK's writer go while Python runs (one that failed, closed once more, so
        that it has nothing to report when it is dropped), and close the file."""
        writer, self._writer = self._writer, None
        if writer is not None:
            with contextlib.suppress(RuntimeError):
                writer.close()
        self._sink.close()

    def _log(self, topic: str, message, time_ns: int) -> None:
        self._channels[topic].log(message, log_time=time_ns)

    def _write_map(self, time_ns: int) -> None:
        entity = _lines_entity(_timestamp(time_ns), "map", WORLD_FRAME, self._map, None)
        self._log("/map", _scene_update(entity), time_ns)
        self._map_written = True


def row_pose(row: Mapping[str, Any], prefix: str) -> Pose2:
    """The pose of a row's ``{prefix}x_m``, ``y_m``, ``theta_deg`` columns (metres, degrees,
    world frame): NaN where the row has none, which the run view leaves out."""
    return Pose2.from_deg(row[f"{prefix}x_m"], row[f"{prefix}y_m"], row[f"{prefix}theta_deg"])


def status_level(status: str) -> str:
    """The ``/status`` level of a row's status: info when the estimate is accepted, warning
    when a distinct pose fits nearly as well, error otherwise."""
    from segloc_cli.estimates import ESTIMATED, STATUS_AMBIGUOUS

    return "info" if status in ESTIMATED else "warning" if status == STATUS_AMBIGUOUS else "error"


def row_text(log_path: Path, row: Mapping[str, Any]) -> str:
    """One line on a row for the run view's log."""
    runner_up = (
        f"a distinct pose fits {row['runner_up_ratio']:.0%}"
        if math.isfinite(row["runner_up_x_m"])
        else "no distinct pose fits as well"
    )
    confidence = row["confidence"]
    trust = f"confidence {confidence:.2f}" if math.isfinite(confidence) else "no confidence"
    return (
        f"{log_path.name} pose {row['pose_id']} at {row['time_s']:.3f} s: "
        f"{row['inlier_ratio']:.0%} of the points on the map, overlap {row['overlap_m']:.2f} m, "
        f"{counted(row['n_local_segments'], 'local segment')}; {runner_up}; {trust}"
    )


@dataclass(frozen=True)
class RunViewContents:
    """What a run view holds, from its summary and metadata (or, cut short, its records).

    ``run`` the ``segloc.run`` record (what the file shows, in its writer's words);
    ``drawn`` the ``segloc.view`` record (``map_segments``, ``status.NAME`` counts; empty
    in a view written before it or cut short); ``message_counts`` topic → messages;
    ``span_s`` the first and last message's log time, seconds (None: no message);
    ``finished`` False for a view whose run was killed before it finished the file: it
    holds the whole scans written before that. A view whose run was stopped before its end
    but finished the file says how (``stopped``).
    """

    run: dict[str, str]
    drawn: dict[str, str]
    message_counts: dict[str, int]
    span_s: tuple[float, float] | None
    finished: bool = True

    @property
    def stopped(self) -> str | None:
        """How the run was stopped before its end, in words ("stopped (SIGTERM) after 3 of 10
        scans"); None for a run that ran to its end, or whose view does not say."""
        try:
            done, planned = int(self.drawn["scans_done"]), int(self.drawn["scans_planned"])
            return stopped_after(self.drawn["stopped_by"], done, planned)
        except (KeyError, ValueError):
            return None


def read_run_view(path: str | Path) -> RunViewContents | None:
    """What the run view at ``path`` holds; None when the file is not one (an MCAP file
    with a ``segloc.run`` record) or cannot be read, for the log reader to judge and
    explain (a pipe or device too, which opening could wait on forever)."""
    from mcap.reader import make_reader

    if not Path(path).is_file():
        return None
    try:
        with open(path, "rb") as stream:
            reader = make_reader(stream)
            try:
                summary = reader.get_summary()
            except Exception:  # no footer: a file cut short
                summary = None
            if summary is None:
                return _read_cut_view(stream)
            if not any(index.name == RUN_METADATA_NAME for index in summary.metadata_indexes):
                return None
            records = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    except Exception:  # the mcap parser's many ways to fail on bytes that are not a run view
        return None
    statistics = summary.statistics
    counts = {} if statistics is None else statistics.channel_message_counts
    by_topic: Counter[str] = Counter()
    for channel_id, channel in summary.channels.items():
        by_topic[channel.topic] += counts.get(channel_id, 0)
    span_s = None
    if statistics is not None and statistics.message_count > 0:
        span_s = (statistics.message_start_time / 1e9, statistics.message_end_time / 1e9)
    return RunViewContents(
        records[RUN_METADATA_NAME], records.get(VIEW_METADATA_NAME, {}), dict(by_topic), span_s
    )


def _read_cut_view(stream) -> RunViewContents | None:
    """What a file without a summary holds, read record by record up to the first one cut
    short: a run view killed mid-run (None when it has no ``segloc.run`` record)."""
    from mcap.records import Channel, Message, Metadata
    from mcap.stream_reader import StreamReader

    stream.seek(0)
    records: dict[str, dict[str, str]] = {}
    topics: dict[int, str] = {}
    counts: Counter[str] = Counter()
    span_ns: list[int] = []  # the first and last log time
    with contextlib.suppress(Exception):  # the cut: a record that ends early
        for record in StreamReader(stream, emit_chunks=False).records:
            if isinstance(record, Metadata):
                records[record.name] = dict(record.metadata)
            elif isinstance(record, Channel):
                topics[record.id] = record.topic
            elif isinstance(record, Message):
                counts[topics.get(record.channel_id, "?")] += 1
                times = [*span_ns, record.log_time]
                span_ns = [min(times), max(times)]
    if RUN_METADATA_NAME not in records:
        return None
    span_s = (span_ns[0] / 1e9, span_ns[1] / 1e9) if span_ns else None
    drawn = records.get(VIEW_METADATA_NAME, {})
    return RunViewContents(records[RUN_METADATA_NAME], drawn, dict(counts), span_s, False)


def layout_path() -> Path:
    """The Foxglove layout file (JSON) the installed package holds: the one to import in
    Foxglove (Layouts → Import from file) to see a run view."""
    from importlib.resources import files

    return Path(str(files("segloc_cli") / LAYOUT_FILE))


def _transforms(stamp, robot: Pose2, mount: Pose2):
    """``world → base_link`` at the robot's pose and ``base_link → laser`` by the mounting."""
    from foxglove.messages import FrameTransforms

    return FrameTransforms(
        transforms=[
            _transform(stamp, WORLD_FRAME, ROBOT_FRAME, robot),
            _transform(stamp, ROBOT_FRAME, LASER_FRAME, mount),
        ]
    )


def _time_ns(time_s: float) -> int:
    return max(0, round(time_s * 1e9))


def _finite(pose: Pose2 | None) -> Pose2 | None:
    if pose is None or not np.all(np.isfinite(pose.as_array())):
        return None
    return pose


def _timestamp(time_ns: int):
    from foxglove.messages import Timestamp

    return Timestamp(sec=time_ns // 1_000_000_000, nsec=time_ns % 1_000_000_000)


def _position_and_rotation(pose: Pose2):
    """A planar pose as Foxglove's position (``Vector3``, z 0) and rotation about +z."""
    from foxglove.messages import Quaternion, Vector3

    qx, qy, qz, qw = heading_to_quaternion(pose.theta)
    return Vector3(x=pose.x, y=pose.y, z=0.0), Quaternion(x=qx, y=qy, z=qz, w=qw)


def _pose(pose: Pose2):
    from foxglove.messages import Pose

    position, orientation = _position_and_rotation(pose)
    return Pose(position=position, orientation=orientation)


def _transform(stamp, parent: str, child: str, pose: Pose2):
    from foxglove.messages import FrameTransform

    translation, rotation = _position_and_rotation(pose)
    return FrameTransform(
        timestamp=stamp,
        parent_frame_id=parent,
        child_frame_id=child,
        translation=translation,
        rotation=rotation,
    )


def _pose_in_frame(stamp, pose: Pose2):
    from foxglove.messages import PoseInFrame

    return PoseInFrame(timestamp=stamp, frame_id=WORLD_FRAME, pose=_pose(pose))


def _poses_in_frame(stamp, poses: list[Pose2]):
    from foxglove.messages import PosesInFrame

    return PosesInFrame(timestamp=stamp, frame_id=WORLD_FRAME, poses=[_pose(p) for p in poses])


def _laser_scan(stamp, scan: Scan):
    from foxglove.messages import LaserScan

    ranges = np.where(scan.valid, scan.ranges_m, 0.0)
    angles = np.asarray(scan.angles_rad, dtype=float)
    intensities = np.asarray(scan.intensities, dtype=float)
    return LaserScan(
        timestamp=stamp,
        frame_id=LASER_FRAME,
        pose=_pose(FRAME_ORIGIN),
        start_angle=float(angles[0]) if angles.size else 0.0,
        end_angle=float(angles[-1]) if angles.size else 0.0,
        ranges=ranges.tolist(),
        intensities=intensities.tolist() if intensities.size == ranges.size else [],
    )


def _lines_entity(stamp, name: str, frame: str, segments: np.ndarray, status: str | None):
    """A scene entity of the segments (K, 4) metres in ``frame``, with ``status`` as text."""
    from foxglove.messages import (
        Color,
        LinePrimitive,
        LinePrimitiveLineType,
        Point3,
        SceneEntity,
        TextPrimitive,
    )

    ends = np.asarray(segments, dtype=float).reshape(-1, 2)
    line = LinePrimitive(
        type=LinePrimitiveLineType.LineList,
        pose=_pose(FRAME_ORIGIN),
        thickness=LINE_WIDTH_PX[name],
        scale_invariant=True,
        points=[Point3(x=x, y=y, z=0.0) for x, y in ends.tolist()],
        color=Color(**dict(zip("rgba", RGBA[name], strict=True))),
    )
    texts = []
    if status is not None:
        texts.append(
            TextPrimitive(
                pose=_pose(FRAME_ORIGIN),
                billboard=True,
                font_size=TEXT_HEIGHT_M,
                scale_invariant=False,
                color=Color(r=1.0, g=1.0, b=1.0, a=1.0),
                text=status,
            )
        )
    return SceneEntity(
        timestamp=stamp, frame_id=frame, id=name, frame_locked=True, lines=[line], texts=texts
    )


def _scene_update(entity):
    from foxglove.messages import SceneUpdate

    return SceneUpdate(entities=[entity])


def _log_line(stamp, status: str, level: str, text: str):
    from foxglove.messages import Log, LogLevel

    levels = {"info": LogLevel.Info, "warning": LogLevel.Warning, "error": LogLevel.Error}
    message = f"{status}: {text}" if text else status
    return Log(timestamp=stamp, level=levels[level], message=message, name="segloc")


POSE_COLORS = {"/estimate": "#2ca02cff", "/guess": "#1f77b4ff", "/runner_up": "#d62728ff"}
"""Arrow colours of the poses in the layout: answer green, guess blue, runner-up red (the
other hypotheses are small arrows along ``HYPOTHESES_GRADIENT``, red to orange)."""
HYPOTHESES_GRADIENT = ("#d62728ff", "#ff7f0eff")


def foxglove_layout() -> str:
    """The Foxglove layout (JSON) that opens a run view: a top-down 3D panel in ``world``
    with every topic shown (the scans at the estimates, the poses as arrows), the
    status log and the estimates' messages beside it."""
    import foxglove.layouts as fl

    topics: dict[str, Any] = {
        "/map": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
        "/local_segments": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
        "/scan": fl.BaseRendererLaserScanTopicSettings(
            visible=True, point_size=3.0, color_mode="flat", flat_color="#ffd21fff"
        ),
        **{
            topic: fl.BaseRendererPoseTopicSettings(visible=True, type="arrow", color=color)
            for topic, color in POSE_COLORS.items()
        },
        "/hypotheses": fl.BaseRendererPosesTopicSettings(
            visible=True, type="arrow", arrow_scale=(0.6, 0.1, 0.1), gradient=HYPOTHESES_GRADIENT
        ),
    }
    scene = fl.ThreeDeePanel(
        title="run",
        config=fl.ThreeDeeConfig(
            follow_tf=WORLD_FRAME,
            follow_mode="follow-none",
            camera_state=fl.ThreeDeeCameraState(perspective=False, distance=60.0, phi=0.0),
            topics=topics,
        ),
    )
    side = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(
                content=fl.LogPanel(title="status", config=fl.LogConfig(topic_to_render="/status"))
            ),
            fl.SplitItem(
                content=fl.RawMessagesPanel(
                    title="estimate", config=fl.RawMessagesConfig(topic_path="/estimate")
                )
            ),
        ],
    )
    layout = fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[fl.SplitItem(proportion=3, content=scene), fl.SplitItem(content=side)],
        )
    )
    return json.dumps(json.loads(layout.to_json()), indent=2) + "\n"
