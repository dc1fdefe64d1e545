"""Other tools' logs given where segloc's own is wanted: what each is, and the ``segloc import``
command that converts it, for the one-line errors of the readers.

- a ROS 1 bag (its first bytes ``ROS1_BAG_MAGIC``), a ROS 2 bag folder (it holds
  ``metadata.yaml``), or a file inside one (``inside_ros2_bag``: its ``metadata.yaml`` or
  its ``.db3`` database, which are not the bag): ``segloc import rosbag``;
- a CARMEN log (``is_carmen_log``): ``segloc import carmen``.

The command converts into a log beside the source, named after it (``run.bag`` →
``run.mcap``, ``intel.log.gz`` → ``intel.mcap``; ``run-segloc.mcap`` where that would be the
source's own name).
"""

from __future__ import annotations

import zlib
from pathlib import Path

from segloc_cli.errors import InputError

ROS1_BAG_MAGIC = b"#ROSBAG V"
"""How a ROS 1 bag begins (``#ROSBAG V2.0`` and a newline)."""
ROS2_METADATA = "metadata.yaml"
"""The file that makes a folder a ROS 2 bag."""
ROS2_DATABASE_SUFFIX = ".db3"
"""The suffix of a ROS 2 bag's sqlite3 storage files."""
CARMEN_SUFFIXES = (".log", ".log.gz", ".clf", ".clf.gz")
"""The names CARMEN logs go by."""
CARMEN_RECORDS = frozenset(
    {
        "PARAM", "SYNC", "ODOM", "TRUEPOS", "FLASER", "RLASER", "LASER3", "LASER4",
        "ROBOTLASER1", "ROBOTLASER2", "RAWLASER1", "RAWLASER2", "RAWLASER3", "RAWLASER4",
        "NMEAGGA", "NMEARMC", "NMEAHDT", "IMU", "SONAR", "BUMPER", "SCANMARK",
    }
)  # fmt: skip
"""The record types a CARMEN log's lines begin with (CARMEN's ``logger`` writes them)."""
HEAD_BYTES = 1 << 16
"""How much of a file (after decompressing gzip) ``is_carmen_log`` looks at."""
GZIP_MAGIC = b"\x1f\x8b"


def inside_ros2_bag(path: Path) -> Path | None:
    """The ROS 2 bag folder (the folder holding ``metadata.yaml``) of which ``path`` is the
    ``metadata.yaml`` or a ``.db3`` database, files that are not the bag on their own; None
    for anything else. A folder given as ``.`` is named by its absolute path."""
    path = Path(path)
    folder = path.parent
    if not path.is_file() or not (folder / ROS2_METADATA).is_file():
        return None
    if path.name != ROS2_METADATA and path.suffix.lower() != ROS2_DATABASE_SUFFIX:
        return None
    return folder if str(folder) != "." else path.resolve().parent


def refuse_inside_ros2_bag(path: Path) -> None:
    """Refuse a file inside a ROS 2 bag (``inside_ros2_bag``) where a bag is read: an
    ``InputError`` naming the bag folder to give instead (a ``.db3`` read alone would lose
    the bag's other files). Anything else passes."""
    folder = inside_ros2_bag(path)
    if folder is not None:
        raise InputError(
            f"a file inside a ROS 2 bag; give the bag folder {folder} (the folder holding "
            f"{ROS2_METADATA})",
            path=path,
        )


def is_carmen_log(path: Path, head: bytes) -> bool:
    """Whether the file at ``path``, of which ``head`` are the first bytes (gzip-compressed
    or not), is a CARMEN log: its first line that is neither blank nor a ``#`` comment is a
    CARMEN record (``CARMEN_RECORDS``); where it has none to read (all comments, damaged
    gzip), its name (``CARMEN_SUFFIXES``) decides. An empty file is none."""
    if not head:
        return False
    if head.startswith(GZIP_MAGIC):
        try:
            head = zlib.decompressobj(wbits=31).decompress(head, HEAD_BYTES)
        except zlib.error:
            head = b""
    for line in head.decode("utf-8", errors="replace").splitlines():
        words = line.split()
        if words and not words[0].startswith("#"):
            return words[0] in CARMEN_RECORDS
    return path.name.lower().endswith(CARMEN_SUFFIXES)


def other_log(path: Path, head: bytes) -> str | None:
    """What the file at ``path`` (``head`` its first bytes, ``HEAD_BYTES`` of them or all) is
    when it is another tool's log, and how to convert it, for an error's line ("a CARMEN log,
    not a segloc log; convert it first with `segloc import carmen …`"); None when it is none
    of those."""
    if head.startswith(ROS1_BAG_MAGIC):
        return f"a ROS 1 bag, not a segloc log; {conversion('rosbag', path)}"
    if is_carmen_log(path, head):
        return f"a CARMEN log, not a segloc log; {conversion('carmen', path)}"
    return None


def conversion(importer: str, source: Path, what: str = "it") -> str:
    """ "convert it first with `segloc import IMPORTER SOURCE --out LOG.mcap`", the log beside
    ``source`` and named after it; ``what`` names the thing converted."""
    return (
        f"convert {what} first with `segloc import {importer} {source} "
        f"--out {_log_beside(Path(source))}`"
    )


def _log_beside(source: Path) -> Path:
    """The log a conversion of ``source`` writes: beside it, named after it without its
    suffix (and ``.gz`` before it: ``run.bag``, ``intel.log.gz``, a bag folder ``run``) and
    ``.mcap``, or ``-segloc.mcap`` where that is ``source`` itself."""
    name = source.name
    if name.lower().endswith(".gz"):
        name = name[: -len(".gz")]
    stem = Path(name).stem or source.name
    out = source.with_name(f"{stem}.mcap")
    return out if out != source else source.with_name(f"{stem}-segloc.mcap")
