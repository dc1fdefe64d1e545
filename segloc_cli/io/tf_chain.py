"""A moving transform chain, composed over time: the pose of one frame in another (say
``base_link`` in ``map``) from the transforms of a bag, at every stamp at which a link of the
chain changes.

The chain is the way up the transform tree from the child frame to the parent frame (each
frame's parent is the one its latest transform names; a static transform's parent wins).
A link given by a static transform (``Link.static``: from ``/tf_static``) is fixed, its
latest value used at every stamp whatever its own stamp. Every other link holds its latest
value until its next stamp, for at most ``MAX_LINK_AGE_S``: no interpolation (tf2 would
interpolate, but a localizer's ``map → odom`` is meant to hold until its next correction).
At each stamp of a moving link the chain is composed once every link is held, so a chain of
``map → odom`` from a localizer and ``odom → base_link`` from odometry gives a pose at each
stamp of either. A moving link's transform that is not finite leaves the link unknown until
its next one: no pose at those stamps, rather than one composed with the value before it.
"""

from __future__ import annotations

from collections import Counter
from itertools import pairwise
from typing import NamedTuple

import numpy as np

from segloc_cli.io.pose_messages import Link
from segloc_cli.io.tf import transform_matrix
from segloc_cli.io.times import NS_PER_S

MAX_LINK_AGE_S = 10.0
"""Longest time (s) a moving link is held after its stamp, tf2's default buffer length: a
chain whose link is older at a stamp is not composed there."""


class ChainError(ValueError):
    """The chain cannot be composed; the message says why in one line."""


class Chain(NamedTuple):
    """``frames`` the chain from the child up to the parent; ``stamps_ns`` (K,) int64 the
    stamps at which it was composed, in increasing order; ``matrices`` (K, 4, 4) the child's
    pose in the parent there (metres); ``dropped`` reason → count of transforms or stamps
    left out."""

    frames: list[str]
    stamps_ns: np.ndarray
    matrices: np.ndarray
    dropped: dict[str, int]


def _span(moving: list[tuple[int, str, np.ndarray | None]], child: str, parent: str) -> str:
    """When the moving link from ``parent`` to ``child`` was given, in words."""
    stamps = [stamp / NS_PER_S for stamp, below, _ in moving if below == child]
    if not stamps:
        return f"{parent} → {child} static"
    if len(stamps) == 1:
        return f"{parent} → {child} once, at {stamps[0]:.3f} s"
    return f"{parent} → {child} {len(stamps)}× from {min(stamps):.3f} to {max(stamps):.3f} s"


def _frames_seen(links: list[Link]) -> list[str]:
    return sorted({link.parent for link in links} | {link.child for link in links})


def chain_frames(links: list[Link], parent: str, child: str) -> list[str]:
    """The frames from ``child`` up to ``parent`` through ``links`` (``child`` first);
    ``ChainError`` when either frame is absent or ``parent`` is not above ``child``."""
    seen = _frames_seen(links)
    for frame in (parent, child):
        if frame not in seen:
            raise ChainError(
                f"frame {frame} is not in the transforms; frames seen: {', '.join(seen)}"
            )
    parent_of: dict[str, str] = {}
    for link in sorted(links, key=lambda k: k.static):  # static ones last: they win
        parent_of[link.child] = link.parent
    frames = [child]
    while frames[-1] != parent:
        above = parent_of.get(frames[-1])
        if above is None or above in frames:
            way = " → ".join(reversed(frames + ([above] if above else [])))
            why = "a loop" if above else "a root"
            raise ChainError(
                f"{parent} is not above {child} in the transforms (the way up from {child} "
                f"ends at {why}: {way}); frames seen: {', '.join(seen)}"
            )
        frames.append(above)
    return frames


def compose_chain(links: list[Link], parent: str, child: str) -> Chain:
    """``child``'s pose in ``parent`` composed from ``links`` (in bag order) at every stamp
    at which a moving link of the chain changes (see the module docstring).

    ``ChainError`` when the frames are absent or not on one chain, when no link of the
    chain moves, or when the chain is never complete.
    """
    dropped: Counter[str] = Counter()
    usable = []
    broken = []
    for link in links:
        try:
            usable.append((link, transform_matrix(link.values[:3], link.values[3:])))
        except ValueError:
            dropped["transforms not finite or with an all-zero quaternion"] += 1
            broken.append(link)
    frames = chain_frames([link for link, _ in usable], parent, child)
    on_chain = dict(pairwise(frames))  # child → parent
    fixed: dict[str, np.ndarray] = {}
    moving: list[tuple[int, str, np.ndarray | None]] = [
        (link.stamp_ns, link.child, None)
        for link in broken
        if not link.static and on_chain.get(link.child) == link.parent
    ]
    for link, matrix in usable:
        if link.child not in on_chain:
            continue
        if link.parent != on_chain[link.child]:
            dropped[
                f"transforms giving {link.child} a parent other than {on_chain[link.child]}"
            ] += 1
        elif link.static:
            fixed[link.child] = matrix
        else:
            moving.append((link.stamp_ns, link.child, matrix))
    shadowed = [m for m in moving if m[1] in fixed and m[2] is not None]
    if shadowed:
        dropped["transforms of a link also given as static (the static one used)"] += len(shadowed)
    moving = [m for m in moving if m[1] not in fixed]
    shown = " → ".join(reversed(frames))
    if not any(m[2] is not None for m in moving):
        raise ChainError(f"no link of the chain {shown} moves: every one is static")
    return _composed(frames, fixed, moving, dropped)


def _composed(
    frames: list[str],
    fixed: dict[str, np.ndarray],
    moving: list[tuple[int, str, np.ndarray | None]],
    dropped: Counter[str],
) -> Chain:
    """The chain composed at each stamp of ``moving`` (stamp ns, child frame, its pose in
    its parent), the ``fixed`` links held throughout and each moving link for at most
    ``MAX_LINK_AGE_S``. A pose of None is a transform that was unusable (not finite): the
    link's value at that stamp is unknown, so it holds no value until its next transform and
    the chain is not composed meanwhile (not with the value before it)."""
    moving.sort(key=lambda m: m[0])  # stable: among equal stamps, bag order
    current: dict[str, tuple[int, np.ndarray | None]] = {
        child: (-1, matrix)
        for child, matrix in fixed.items()  # -1: never stale
    }
    stamps: list[int] = []
    matrices: list[np.ndarray] = []
    given: set[tuple[int, str]] = set()
    incomplete = unknown = 0
    max_age_ns = round(MAX_LINK_AGE_S * NS_PER_S)
    for i, (stamp_ns, child, matrix) in enumerate(moving):
        if (stamp_ns, child) in given:
            dropped["transforms repeating a link's stamp (the first kept)"] += 1
        else:
            given.add((stamp_ns, child))
            current[child] = (stamp_ns, matrix)
        if i + 1 < len(moving) and moving[i + 1][0] == stamp_ns:
            continue  # the stamp's other links first
        held = [
            current[frame][1]
            for frame in frames[:-1]
            if frame in current
            and (current[frame][0] < 0 or stamp_ns - current[frame][0] <= max_age_ns)
        ]
        known = [matrix for matrix in held if matrix is not None]
        if len(known) < len(held):
            unknown += 1
            continue
        if len(held) < len(frames) - 1:
            incomplete += 1
            continue
        pose = np.eye(4)
        for link in known:  # from the child up
            pose = link @ pose
        stamps.append(stamp_ns)
        matrices.append(pose)
    shown = " → ".join(reversed(frames))
    if not stamps:
        spans = "; ".join(
            _span(moving, below, above) for below, above in reversed(list(pairwise(frames)))
        )
        raise ChainError(
            f"the chain {shown} is never complete: at no stamp had each moving link been given "
            f"within {MAX_LINK_AGE_S:g} s ({spans})"
        )
    if unknown:
        dropped[f"stamps at which a link of {shown} was last given by a transform not finite"] += (
            unknown
        )
    if incomplete:
        dropped[
            f"stamps at which a link of {shown} was not yet given or older than "
            f"{MAX_LINK_AGE_S:g} s"
        ] += incomplete
    return Chain(
        frames=frames,
        stamps_ns=np.array(stamps, dtype=np.int64),
        matrices=np.array(matrices, dtype=float).reshape(-1, 4, 4),
        dropped=dict(dropped),
    )
