"""The messages of a ROS 1 bag whose index is missing or cut off, read record by record.

A recorder that is killed, or a bag copied only in part, leaves no index (the
index is written last), and ROS 1 bag readers refuse such a file. Its chunks
are still whole up to the cut, so this reader walks the records from the
start (the ROS bag 2.0 layout: a length-prefixed header of ``name=value``
fields with an ``op`` code, then a length-prefixed body), opens each chunk
(uncompressed, bz2 or lz4), and keeps every message on the wanted topics
that lies wholly before the damage. Connections are learned as they come.

Every length is checked against what is left of the file or chunk, so no
field can make it read or allocate past the data there.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import lz4.frame

MAGIC = b"#ROSBAG V2.0\n"
OP_MESSAGE, OP_CHUNK, OP_CONNECTION = 0x02, 0x05, 0x07
MAX_CHUNK_BYTES = 1 << 30
"""Largest decompressed chunk accepted (bytes); rosbag writes chunks of about 768 KiB."""


@dataclass(frozen=True)
class Salvage:
    """What could be read: ``messages`` as (topic, ROS 2 style type name, raw bytes) in file
    order; ``stopped`` why reading ended before the end of the file (None when it did not)."""

    messages: list[tuple[str, str, bytes]]
    stopped: str | None


class _Damage(Exception):
    """The data ends, or stops making sense, here."""


def _records(data: bytes | memoryview) -> Iterator[tuple[dict[str, bytes], memoryview]]:
    """(header fields, body) of each whole record in ``data``; ``_Damage`` at a bad one."""
    view, at = memoryview(data), 0
    while at < len(view):
        fields, at = _fields(view, at)
        if at + 4 > len(view):
            raise _Damage("a record's body length is cut off")
        (size,) = struct.unpack_from("<I", view, at)
        if at + 4 + size > len(view):
            raise _Damage("a record's body is cut off")
        yield fields, view[at + 4 : at + 4 + size]
        at += 4 + size


def _fields(view: memoryview, at: int) -> tuple[dict[str, bytes], int]:
    if at + 4 > len(view):
        raise _Damage("a record's header length is cut off")
    (size,) = struct.unpack_from("<I", view, at)
    end = at + 4 + size
    if end > len(view):
        raise _Damage("a record's header is cut off")
    fields, at = {}, at + 4
    while at < end:
        if at + 4 > end:
            raise _Damage("a header field's length is cut off")
        (length,) = struct.unpack_from("<I", view, at)
        field = bytes(view[at + 4 : at + 4 + length])
        if at + 4 + length > end or b"=" not in field:
            raise _Damage("a header field is malformed")
        name, _, value = field.partition(b"=")
        fields[name.decode("latin-1")] = value
        at += 4 + length
    if "op" not in fields or len(fields["op"]) != 1:
        raise _Damage("a record has no op code")
    return fields, end


def _chunk_data(fields: dict[str, bytes], body: memoryview) -> bytes:
    compression = fields.get("compression", b"none")
    try:
        size = struct.unpack("<I", fields.get("size", b""))[0]
    except struct.error:
        raise _Damage("a chunk has no size") from None
    if size > MAX_CHUNK_BYTES:
        raise _Damage(f"a chunk claims {size} bytes")
    try:
        if compression == b"none":
            return bytes(body)
        if compression == b"bz2":
            return bz2.decompress(body)
        if compression == b"lz4":
            return lz4.frame.decompress(body)
    except (OSError, EOFError, ValueError, RuntimeError) as exc:
        kind = compression.decode("latin-1")
        raise _Damage(f"a {kind} chunk does not decompress ({exc})") from None
    raise _Damage(f"a chunk uses unknown compression {compression!r}")


def _ros2_type(connection_body: memoryview) -> str:
    """``pkg/msg/Name`` from a connection record's body (a header with ``type=pkg/Name``)."""
    fields: dict[str, bytes] = {}
    view, at = connection_body, 0
    while at + 4 <= len(view):
        (length,) = struct.unpack_from("<I", view, at)
        name, _, value = bytes(view[at + 4 : at + 4 + length]).partition(b"=")
        fields[name.decode("latin-1")] = value
        at += 4 + length
    package, _, message = fields.get("type", b"").decode("latin-1").partition("/")
    return f"{package}/msg/{message}"


def salvage_ros1(path: Path, topics: set[str]) -> Salvage:
    """Every whole message on ``topics`` in the ROS 1 bag at ``path``, read without its index.

    Raises ``ValueError`` when the file is not a ROS bag 2.0 at all.
    """
    data = path.read_bytes()
    if not data.startswith(MAGIC):
        raise ValueError("not a ROS bag 2.0 file")
    connections: dict[bytes, tuple[str, str]] = {}
    messages: list[tuple[str, str, bytes]] = []

    def take(fields: dict[str, bytes], body: memoryview) -> None:
        op = fields["op"][0]
        if op == OP_CONNECTION:
            topic = fields.get("topic", b"").decode("latin-1")
            connections[fields.get("conn", b"")] = (topic, _ros2_type(body))
        elif op == OP_MESSAGE:
            topic, msgtype = connections.get(fields.get("conn", b""), ("", ""))
            if topic in topics:
                messages.append((topic, msgtype, bytes(body)))

    try:
        for fields, body in _records(memoryview(data)[len(MAGIC) :]):
            if fields["op"][0] == OP_CHUNK:
                for inner, inner_body in _records(_chunk_data(fields, body)):
                    take(inner, inner_body)
            else:
                take(fields, body)
    except _Damage as damage:
        return Salvage(messages, str(damage))
    return Salvage(messages, None)
