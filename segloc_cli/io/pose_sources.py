"""Files of recorded messages opened for their topics: ROS 1 bags and ROS 2 bag folders
through ``rosbags``' ``AnyReader``, MCAP files through the ``mcap`` library (ROS 2 CDR,
ROS 1, protobuf and JSON messages alike).

A ``Source`` lists its topics with their message types and yields the messages of the
topics asked for, each with a ``decode`` that deserializes it when called (so that a message
that cannot be decoded is one skipped message, not a failed file). A file damaged part way
is read up to the damage: a ROS 1 bag without its index record by record
(``ros1_salvage``), an MCAP file without its summary record by record, and any file whose
reading fails in the middle up to there; ``Source.damage`` then says what happened.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import IO, Any, NamedTuple

from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from segloc_cli.errors import InputError
from segloc_cli.io.mcap_log import MCAP_MAGIC
from segloc_cli.io.pose_messages import SUPPORTED_TYPES
from segloc_cli.io.ros1_salvage import salvage_ros1
from segloc_cli.io.rosbag import failure_text, open_bag, ros1_typestore
from segloc_cli.io.trajectories import TOPIC_OPTION

SEVERAL_TYPES = "several types"


class Message(NamedTuple):
    """One recorded message: its topic, its type (``pkg/msg/Name`` for ROS, the schema
    name otherwise), the time it was logged (ns) and ``decode()`` → the decoded message."""

    topic: str
    msgtype: str
    log_time_ns: int
    decode: Callable[[], Any]


class Source:
    """Topics and messages of one file (see the module docstring); a context manager.

    ``kind`` names the file's format ("ROS 2 bag"), ``topics`` maps each topic to its type,
    ``encodings`` each topic to its message encoding where the file says (MCAP), and
    ``damage`` is None until reading met damage (or the file was salvaged), then why.
    """

    def __init__(self, kind: str, topics: dict[str, str], damage: str | None = None):
        self.kind = kind
        self.topics = topics
        self.encodings: dict[str, str] = {}
        self.damage = damage

    def messages(self, topics: list[str]) -> Iterator[Message]:
        """The messages of ``topics`` in file order; reading stops quietly at damage, which
        ``damage`` then names."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the file."""

    def __enter__(self) -> Source:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _topic_types(pairs: list[tuple[str, str]]) -> dict[str, str]:
    """Topic → type from (topic, type) pairs; ``SEVERAL_TYPES`` for a topic given two."""
    types: dict[str, str] = {}
    for topic, msgtype in pairs:
        types[topic] = msgtype if types.get(topic, msgtype) == msgtype else SEVERAL_TYPES
    return types


def ros_type_name(name: str) -> str:
    """A ROS message type as ``pkg/msg/Name`` (ROS 1 writes ``pkg/Name``)."""
    package, _, rest = name.partition("/")
    return name if "/" in rest or not rest else f"{package}/msg/{rest}"


class _BagSource(Source):
    def __init__(self, kind: str, reader: AnyReader):
        topics = {t: info.msgtype or SEVERAL_TYPES for t, info in reader.topics.items()}
        super().__init__(kind, topics)
        self._reader = reader

    def messages(self, topics: list[str]) -> Iterator[Message]:
        connections = [c for t in topics for c in self._reader.topics[t].connections]
        try:
            for connection, log_time_ns, data in self._reader.messages(connections):
                decode = partial(self._reader.deserialize, data, connection.msgtype)
                yield Message(connection.topic, connection.msgtype, log_time_ns, decode)
        except Exception as exc:  # damaged bytes fail the bag library in many ways
            self.damage = f"unreadable past some point ({failure_text(exc)})"

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._reader.close()


class _SalvagedSource(Source):
    def __init__(self, messages: list[tuple[str, str, bytes]], damage: str):
        super().__init__("ROS 1 bag", _topic_types([(t, m) for t, m, _ in messages]), damage)
        self._messages = messages
        self._store = ros1_typestore()

    def messages(self, topics: list[str]) -> Iterator[Message]:
        for topic, msgtype, data in self._messages:
            if topic in topics:
                decode = partial(self._store.deserialize_ros1, data, msgtype)
                yield Message(topic, msgtype, 0, decode)


class _Decoders:
    """Per MCAP channel, the function that decodes its message bytes."""

    def __init__(self) -> None:
        self._cdr: Any = None
        self._ros1: Any = None
        self._protobuf: Any = None
        self._made: dict[int, Callable[[bytes], Any]] = {}

    def __call__(self, channel: Any, schema: Any) -> Callable[[bytes], Any]:
        if channel.id not in self._made:
            self._made[channel.id] = self._make(channel.message_encoding, schema)
        return self._made[channel.id]

    def _make(self, encoding: str, schema: Any) -> Callable[[bytes], Any]:
        name = schema.name if schema is not None else ""
        if encoding == "cdr":
            self._cdr = self._cdr or get_typestore(Stores.LATEST)
            return partial(self._cdr.deserialize_cdr, typename=ros_type_name(name))
        if encoding == "ros1":
            self._ros1 = self._ros1 or ros1_typestore()
            return partial(self._ros1.deserialize_ros1, typename=ros_type_name(name))
        if encoding == "json":
            return json.loads
        if encoding == "protobuf" and schema is not None:
            from mcap_protobuf.decoder import DecoderFactory

            self._protobuf = self._protobuf or DecoderFactory()
            decoder = self._protobuf.decoder_for(encoding, schema)
            if decoder is not None:
                return decoder
        raise ValueError(f"no decoder for {encoding or 'unnamed'} messages")


def _type_of(channel: Any, schema: Any) -> str:
    name = schema.name if schema is not None else ""
    return ros_type_name(name) if channel.message_encoding in ("cdr", "ros1") else name


class _McapSource(Source):
    def __init__(self, path: Path, stream: IO[bytes]):
        from mcap.reader import make_reader

        super().__init__("MCAP file", {})
        self._path = path
        self._stream = stream
        self._decoders = _Decoders()
        self._kept: list[tuple[Any, Any, Any]] | None = None  # a damaged file's messages
        if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise InputError("not an MCAP file (it lacks the MCAP magic bytes)", path=path)
        stream.seek(0)
        self._reader = make_reader(stream)
        why: str | None = None
        try:
            summary = self._reader.get_summary()
        except Exception as exc:  # no footer or summary: a file cut short
            summary, why = None, failure_text(exc)
        if summary is not None:
            self._channels = [
                (c, summary.schemas.get(c.schema_id)) for c in summary.channels.values()
            ]
        else:
            self._channels = self._read_through(why)
        self.topics = _topic_types([(c.topic, _type_of(c, s)) for c, s in self._channels])
        self.encodings = {c.topic: c.message_encoding for c, _ in self._channels}

    def _read_through(self, why: str | None) -> list[tuple[Any, Any]]:
        """Every channel and every message of a supported type of a file without a
        summary, read record by record up to the first damage (``why``: why the summary
        could not be read; None when the file has none)."""
        from mcap.reader import NonSeekingReader

        self._stream.seek(0)
        channels: dict[int, tuple[Any, Any]] = {}
        self._kept = []
        try:
            for schema, channel, message in NonSeekingReader(self._stream).iter_messages(
                log_time_order=False
            ):
                channels[channel.id] = (channel, schema)
                if _type_of(channel, schema) in SUPPORTED_TYPES:
                    self._kept.append((schema, channel, message))
        except Exception as exc:  # the cut: a record that ends early, or bytes gone bad
            self.damage = f"unreadable past some point ({failure_text(exc)})"
        else:
            if why is not None:
                self.damage = f"its summary is unreadable ({why})"
        return list(channels.values())

    def messages(self, topics: list[str]) -> Iterator[Message]:
        records: Any = self._kept
        if records is None:
            records = self._reader.iter_messages(topics=topics, log_time_order=False)
        try:
            for schema, channel, message in records:
                if channel.topic in topics:
                    decode = partial(self._decoders(channel, schema), message.data)
                    yield Message(
                        channel.topic, _type_of(channel, schema), message.log_time, decode
                    )
        except Exception as exc:  # damaged bytes fail the reader in many ways
            self.damage = f"unreadable past some point ({failure_text(exc)})"

    def close(self) -> None:
        self._stream.close()


def open_source(path: Path, fmt: str, topic: str | None) -> Source:
    """Open ``path`` as ``fmt`` ("ros1", "ros2", "mcap"): a ROS 2 bag given as a file is its
    MCAP file. ``InputError`` when it cannot be opened; ``topic`` is needed to read a ROS 1
    bag whose index is damaged (record by record, only the topic and ``/tf_static``)."""
    if fmt == "mcap" or (fmt == "ros2" and path.is_file()):
        return _open_mcap(path)
    kind = "ROS 1 bag" if fmt == "ros1" else "ROS 2 bag"
    try:
        return _BagSource(kind, open_bag(path))
    except InputError as refusal:
        inside = sorted(path.glob("*.mcap")) if path.is_dir() else []
        if fmt == "ros2" and len(inside) == 1:  # a recording cut short: its one file
            source = _open_mcap(inside[0])
            source.kind = "ROS 2 bag"
            source.damage = source.damage or "its metadata is unreadable"
            return source
        if fmt != "ros1" or not path.is_file():
            raise
        return _salvaged(path, topic, refusal)


def _open_mcap(path: Path) -> Source:
    try:
        stream = path.open("rb")
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", path=path) from None
    try:
        return _McapSource(path, stream)
    except InputError:
        stream.close()
        raise
    except Exception as exc:  # what the reader makes of bytes that are not MCAP
        stream.close()
        raise InputError(f"not a readable MCAP file ({failure_text(exc)})", path=path) from None


def _salvaged(path: Path, topic: str | None, refusal: InputError) -> Source:
    """A ROS 1 bag the reader refused (its index is missing: a recording cut short), read
    record by record; ``refusal`` extended when that is not possible."""
    if topic is None:
        raise InputError(f"{refusal}; give {TOPIC_OPTION} to read it record by record") from None
    from segloc_cli.io.tf import TF_STATIC_TOPIC

    try:
        salvage = salvage_ros1(path, {topic, TF_STATIC_TOPIC})
    except (OSError, ValueError):
        raise refusal from None
    if not salvage.messages:
        raise refusal
    where = "" if salvage.stopped is None else f" up to where {salvage.stopped}"
    note = f"its index is missing or damaged; read record by record{where}"
    return _SalvagedSource(salvage.messages, note)
