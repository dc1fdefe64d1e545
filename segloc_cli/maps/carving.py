"""Free-space carving: the segments of a map being built that the scans see through.

A person who walked past the robot is drawn by the scans that caught them, but the scans
taken from elsewhere, before or after, read the wall behind the place they stood: their
beams run on through the segment. A wall is not seen through, however few poses saw it
(the end of a corridor reached once); a pane of glass may be, by the beams it lets pass.
Occupancy mapping weighs the same evidence cell by cell, the beams that end in a cell
against those that pass through it. Here a segment is cut into short pieces, and a piece
is free space when more surveyed poses see through it than saw the segment: each pose
votes once, so a robot standing still does not outvote a moving one. A segment that is
free space over most of its length goes; one seen through only at an end that overshoots
a corner stays.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from segloc_cli.geometry import Pose2, segment_lengths
from segloc_cli.maps.fusion import distinct_viewpoints
from segloc_cli.method.freespace import interior_pieces, seen_through


def free_length(
    segments_world: np.ndarray,
    seen_from: np.ndarray,
    points_robot: Sequence[np.ndarray],
    poses: Sequence[Pose2],
    viewpoints: np.ndarray,
    margin_m: float,
    behind_m: float,
) -> np.ndarray:
    """Metres (M,) of each segment of ``segments_world`` (M, 4) that more viewpoints see
    through than saw the segment (``seen_from`` (M,) viewpoints each).

    The scans' points (robot frame) at ``poses`` (world frame), one ``viewpoints`` label
    (S,) per scan, see through the pieces of a segment's interior (more than ``margin_m``
    from its ends, cut every ``margin_m``) where their beams end more than ``behind_m``
    behind it (``method.freespace.seen_through``).
    """
    segments = np.asarray(segments_world, dtype=float).reshape(-1, 4)
    labels = np.asarray(viewpoints)
    if labels.shape != (len(poses),):
        raise ValueError(f"{labels.size} viewpoints for {len(poses)} scans")
    first, lengths = interior_pieces(segments, margin_m)
    scan, segment, piece = seen_through(segments, points_robot, poses, margin_m, behind_m)
    through = distinct_viewpoints(first[segment] + piece, labels[scan], lengths.size)
    owner = np.repeat(np.arange(segments.shape[0]), np.diff(first))
    free = through > np.asarray(seen_from)[owner]
    return np.bincount(owner[free], lengths[free], minlength=segments.shape[0])


def mostly_free(segments_world: np.ndarray, free_m: np.ndarray, margin_m: float) -> np.ndarray:
    """Mask (M,) of the segments (M, 4) free space over more than half of their interior, the
    stretch more than ``margin_m`` from either end (``free_m`` (M,) metres, from
    ``free_length``): ends that overshoot a corner by a few centimetres do not count."""
    lengths = segment_lengths(np.asarray(segments_world, dtype=float).reshape(-1, 4))
    return np.asarray(free_m) > 0.5 * np.maximum(lengths - 2.0 * margin_m, 0.0)
