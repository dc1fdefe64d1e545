"""The pose trajectory of one topic of a ROS bag or an MCAP file: the reader behind
``io/trajectories.read_trajectory`` for the formats ``ros1``, ``ros2`` and ``mcap``
(what comes out is said there)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from segloc_cli.errors import InputError
from segloc_cli.io.pose_messages import (
    LINK_TYPES,
    POSE_READERS,
    SUPPORTED_TYPES,
    Link,
    Pose,
    message_links,
)
from segloc_cli.io.pose_sources import Source, open_source
from segloc_cli.io.tf import TF_STATIC_TOPIC
from segloc_cli.io.tf_chain import ChainError, compose_chain
from segloc_cli.io.times import NS_PER_S
from segloc_cli.io.trajectories import (
    FRAMES_OPTION,
    TOPIC_OPTION,
    PosesRead,
    planar_of_matrices,
    planar_of_quaternions,
    trajectory_frame,
)
from segloc_cli.wording import counted, plural

MAX_LISTED_TOPICS = 12
"""Topics named in a message at most; more are counted."""
_ENCODINGS_SHOWN = ("protobuf", "json")


class _Gathered(NamedTuple):
    """The decoded contents of a topic: its poses or its transforms (with the static ones),
    how many messages it held, those that could not be decoded (with the first error) and
    the poses without a time of their own (given their log time)."""

    poses: list[Pose]
    links: list[Link]
    n_messages: int
    undecodable: int
    first_error: str
    untimed: int


def read_bag_trajectory(
    path: Path, fmt: str, topic: str | None, frames: tuple[str, str] | None
) -> pd.DataFrame:
    """The trajectory of ``topic`` (see ``read_trajectory``) in the bag or MCAP file at
    ``path`` of format ``fmt`` ("ros1", "ros2" or "mcap")."""
    with open_source(path, fmt, topic) as source:
        chosen, picked = _chosen_topic(path, source, topic)
        msgtype = source.topics[chosen]
        if msgtype not in SUPPORTED_TYPES:
            raise InputError(
                f"topic {chosen} holds {msgtype}, not poses; supported types: "
                f"{', '.join(SUPPORTED_TYPES)}; topics found: {_listing(source.topics)}",
                path=path,
            )
        is_tf = msgtype in LINK_TYPES
        if frames is not None and not is_tf:
            raise InputError(
                f"{FRAMES_OPTION} applies to a transform topic ({', '.join(LINK_TYPES)}); "
                f"{chosen} holds {msgtype}: leave {FRAMES_OPTION} out",
                path=path,
            )
        static = source.topics.get(TF_STATIC_TOPIC) in LINK_TYPES and chosen != TF_STATIC_TOPIC
        gathered = _gather(source, chosen, msgtype, [TF_STATIC_TOPIC] if is_tf and static else [])
        damage = source.damage
        encoding = source.encodings.get(chosen, "")
    kind = source.kind
    if gathered.n_messages == 0:
        before = f" before the damage ({damage})" if damage else ""
        raise InputError(
            f"topic {chosen} holds no messages{before}; topics found: {_listing(source.topics)}",
            path=path,
        )
    shown_encoding = f", {encoding}" if encoding in _ENCODINGS_SHOWN else ""
    described = f"{kind}, {chosen} ({msgtype}{shown_encoding})"
    described += ", its only pose topic" if picked else ""
    dropped: Counter[str] = Counter()
    warnings: list[str] = []
    if gathered.undecodable:
        dropped["messages that could not be decoded"] += gathered.undecodable
        warnings.append(
            f"{counted(gathered.undecodable, 'message')} on {chosen} could not be decoded "
            f"(first: {gathered.first_error})"
        )
    if gathered.untimed:
        warnings.append(
            f"{counted(gathered.untimed, 'message')} on {chosen} "
            f"{plural(gathered.untimed, 'carries', 'carry')} no timestamp; their log times are used"
        )
    if is_tf:
        read, chain_text = _chain_poses(path, chosen, gathered.links, frames, dropped)
        described += f", {chain_text}"
    else:
        read = _message_poses(gathered.poses)
    frame = trajectory_frame(path, read, described, dropped, warnings, what=f"topic {chosen}")
    if damage:
        frame.attrs["source"] += " (read up to damage)"
        warnings.append(f"the {kind} is damaged: {damage}; {len(frame)} poses read before it")
    return frame


def _listing(topics: dict[str, str]) -> str:
    """Topics with their types, those of supported types first, at most
    ``MAX_LISTED_TOPICS``."""
    ordered = sorted(topics.items(), key=lambda item: (item[1] not in SUPPORTED_TYPES, item[0]))
    shown = [f"{topic} ({msgtype})" for topic, msgtype in ordered[:MAX_LISTED_TOPICS]]
    more = len(ordered) - len(shown)
    return ", ".join(shown + ([f"{more} more"] if more else [])) or "none"


def _damage_note(source: Source) -> str:
    """What a message about the topics adds when the file was read only up to damage."""
    return f"; the {source.kind} is damaged: {source.damage}" if source.damage else ""


def _chosen_topic(path: Path, source: Source, topic: str | None) -> tuple[str, bool]:
    """The topic to read, and whether it was picked as the file's only pose topic."""
    kind = source.kind
    if not source.topics and source.damage:
        raise InputError(
            f"the {kind} is damaged before its first message: {source.damage}", path=path
        )
    if topic is not None:
        if topic not in source.topics and f"/{topic}" in source.topics:
            return f"/{topic}", False
        if topic not in source.topics:
            raise InputError(
                f"no topic {topic} in the {kind}; topics found: {_listing(source.topics)}"
                f"{_damage_note(source)}",
                path=path,
            )
        return topic, False
    candidates = {
        name: msgtype
        for name, msgtype in source.topics.items()
        if msgtype in SUPPORTED_TYPES and name != TF_STATIC_TOPIC
    }
    if len(candidates) == 1:
        return next(iter(candidates)), True
    if not candidates:
        raise InputError(
            f"the {kind} has no topic of a pose type ({', '.join(SUPPORTED_TYPES)}); topics "
            f"found: {_listing(source.topics)}{_damage_note(source)}",
            path=path,
        )
    raise InputError(
        f"the {kind} has {len(candidates)} pose topics; give {TOPIC_OPTION} with one of: "
        f"{_listing(candidates)}",
        path=path,
    )


def _gather(source: Source, topic: str, msgtype: str, static_topics: list[str]) -> _Gathered:
    """Decode the messages of ``topic`` (and of ``static_topics``, static transforms)."""
    poses: list[Pose] = []
    links: list[Link] = []
    n_messages = undecodable = untimed = 0
    first_error = ""
    for message in source.messages([topic, *static_topics]):
        ours = message.topic == topic
        n_messages += ours
        try:
            decoded = message.decode()
            if message.msgtype in LINK_TYPES:
                # /tf_static's transforms are fixed links when it is the topic read, too.
                static = message.topic in static_topics or message.topic == TF_STATIC_TOPIC
                links += message_links(message.msgtype, decoded, static, message.log_time_ns)
            else:
                pose = POSE_READERS[msgtype](decoded)
                if pose.stamp_ns is None:
                    untimed += 1
                    pose = pose._replace(stamp_ns=message.log_time_ns)
                poses.append(pose)
        except Exception as exc:  # three libraries' decoders fail in many ways
            undecodable += ours
            first_error = first_error or " ".join(f"{type(exc).__name__}: {exc}".split())[:160]
    return _Gathered(poses, links, n_messages, undecodable, first_error, untimed)


def _seconds(stamps_ns: list[int]) -> np.ndarray:
    # Integer true division rounds once; int64 → float64 first would round twice.
    return np.array([int(stamp) / NS_PER_S for stamp in stamps_ns], dtype=float)


def _message_poses(poses: list[Pose]) -> PosesRead:
    nan6 = (np.nan,) * 6
    return PosesRead(
        time_s=_seconds([int(pose.stamp_ns or 0) for pose in poses]),
        frame_ids=[pose.frame_id for pose in poses],
        planar=planar_of_quaternions(np.array([pose.values for pose in poses], dtype=float)),
        covariance=np.array([pose.covariance or nan6 for pose in poses], dtype=float).reshape(
            -1, 6
        ),
    )


def _chain_poses(
    path: Path,
    topic: str,
    links: list[Link],
    frames: tuple[str, str] | None,
    dropped: Counter[str],
) -> tuple[PosesRead, str]:
    """The poses of a transform chain and the words for it ("map → odom → base_link")."""
    seen = sorted({link.parent for link in links} | {link.child for link in links})
    if frames is None:
        raise InputError(
            f"topic {topic} holds transforms; give {FRAMES_OPTION} PARENT,CHILD (e.g. "
            f"map,base_link) to read the pose of CHILD in PARENT; frames seen: "
            f"{', '.join(seen) or 'none'}",
            path=path,
        )
    parent, child = (frame.lstrip("/") for frame in frames)
    try:
        chain = compose_chain(links, parent, child)
    except ChainError as exc:
        raise InputError(
            f"{exc} ({FRAMES_OPTION} {parent},{child}, topic {topic})", path=path
        ) from None
    dropped.update(chain.dropped)
    n = len(chain.stamps_ns)
    read = PosesRead(
        time_s=_seconds(chain.stamps_ns.tolist()),
        frame_ids=[parent] * n,
        planar=planar_of_matrices(chain.matrices),
        covariance=np.full((n, 6), np.nan),
    )
    return read, " → ".join(reversed(chain.frames))
