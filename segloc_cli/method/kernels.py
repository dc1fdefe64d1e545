"""Compiled planar geometry shared by the numba kernels of stage 2, refinement and the rasters.

Compiled code can only call compiled functions, so these are the scalar twins
of helpers in ``geometry.py`` (which work on numpy arrays), written once here
and called from the kernels of ``overlap.py``, ``refine.py``, ``score_raster.py``,
``spatial.py`` and ``freespace.py`` (``copy_into`` and ``grown`` are no geometry: an element
copy that spares them numba's slice assignment, slow to compile, and a list's array grown).
Units are metres and radians; a segment is ``x1 y1 x2 y2`` and every argument
of one call is in the same frame unless a docstring says otherwise.

Numba's on-disk cache of a compiled caller is keyed on the caller's own source
file only: after editing this module, delete the ``*.nbi`` / ``*.nbc`` files in
``segloc_cli/__pycache__`` (or touch the calling modules), or the callers keep
running the old code.
"""

from __future__ import annotations

import numpy as np

from segloc_cli.jit import njit


@njit(cache=True)
def wrap(angle: float) -> float:
    """``angle`` (radians) wrapped into [-π, π): the compiled twin of ``geometry.wrap_angle``.

    Both map ±π to -π and multiples of 2π to 0. Computed as
    ``angle − 2π·floor((angle + π) / 2π)`` rather than with a remainder, so the
    two can differ in the last bit, by an amount that grows with ``|angle|``.
    """
    return angle - 2.0 * np.pi * np.floor((angle + np.pi) / (2.0 * np.pi))


@njit(cache=True)
def point_segment_distance(
    px: float, py: float, x1: float, y1: float, x2: float, y2: float
) -> float:
    """Distance (metres) from the point (px, py) to the segment (x1, y1)–(x2, y2).

    The nearest point is the foot of the perpendicular, clamped to the
    segment's ends; a zero-length segment is its single point.
    """
    dx, dy = x2 - x1, y2 - y1
    t = ((px - x1) * dx + (py - y1) * dy) / max(dx * dx + dy * dy, 1e-300)
    t = min(max(t, 0.0), 1.0)
    ex, ey = px - x1 - t * dx, py - y1 - t * dy
    return np.sqrt(ex * ex + ey * ey)


@njit(cache=True)
def list_if_within(px, py, segments, j, radius_m, listed, listed_d, count):
    """Segment ``j`` of ``segments`` (M, 4) and its distance (m) from the point (px, py),
    written at ``count`` into ``listed`` and ``listed_d`` when it lies within ``radius_m``;
    returns how many are listed then."""
    d = point_segment_distance(
        px, py, segments[j, 0], segments[j, 1], segments[j, 2], segments[j, 3]
    )
    if d <= radius_m:  # not ``d > radius_m``: a NaN distance lists nothing
        listed[count] = j
        listed_d[count] = d
        return count + 1
    return count


@njit(cache=True)
def copy_into(dst: np.ndarray, src: np.ndarray) -> None:
    """``dst[: src.size] = src`` for 1-d arrays, element by element: numba's slice assignment
    compiles a shape check whose message formatting costs seconds of compile time."""
    for i in range(src.size):
        dst[i] = src[i]


@njit(cache=True)
def grown(values: np.ndarray, count: int, size: int) -> np.ndarray:
    """The first ``count`` of ``values`` (1-d) copied into a new array of ``size`` (the rest
    unset): room made for a list that outgrew its array."""
    out = np.empty(size, dtype=values.dtype)
    copy_into(out, values[:count])
    return out


@njit(cache=True)
def angular_interval(x1: float, y1: float, x2: float, y2: float) -> tuple[float, float]:
    """Centre (in [-π, π)) and half-width (radians) of the angle the segment subtends at
    the origin of its frame, taking the shorter way round between its ends."""
    a = np.arctan2(y1, x1)
    span = wrap(np.arctan2(y2, x2) - a)
    return wrap(a + 0.5 * span), 0.5 * abs(span)


@njit(cache=True)
def point_into_frame(
    px: float, py: float, x: float, y: float, cos_theta: float, sin_theta: float
) -> tuple[float, float]:
    """The point (px, py) expressed in the frame of pose (x, y, θ), given cos θ and sin θ.

    The pose and the point are in the same outer frame (e.g. world → robot).
    """
    dx, dy = px - x, py - y
    return cos_theta * dx + sin_theta * dy, cos_theta * dy - sin_theta * dx


@njit(cache=True)
def out_of_frame(segments: np.ndarray, x: float, y: float, theta: float) -> np.ndarray:
    """Segments (N, 4) in the frame of pose (x, y, theta), expressed in the frame the pose
    is in (e.g. robot → world): the compiled twin of ``transform_segments``."""
    c, s = np.cos(theta), np.sin(theta)
    out = np.empty_like(segments)
    for i in range(segments.shape[0]):
        for e in (0, 2):
            px, py = segments[i, e], segments[i, e + 1]
            out[i, e] = x + c * px - s * py
            out[i, e + 1] = y + s * px + c * py
    return out


@njit(cache=True)
def wrap_remainder(angle: float) -> float:
    """``angle`` (radians) wrapped into [-π, π) exactly as ``geometry.wrap_angle`` does it,
    with a floating-point remainder, to the last bit.

    For compiled code that repeats a numpy computation step for step; ``wrap``
    is the cheaper choice where the last bit does not matter.
    """
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


@njit(cache=True)
def segment_distance_ends(
    ax1: float, ay1: float, ax2: float, ay2: float, bx1: float, by1: float, bx2: float, by2: float
) -> float:
    """``segment_distance`` of the segments (ax1, ay1)–(ax2, ay2) and (bx1, by1)–(bx2, by2),
    given as scalars: the same arithmetic, to the last bit, for loops that would otherwise
    slice a row out of an array for every pair (each slice costs a reference count)."""

    def side(px, py, x1, y1, x2, y2):
        return (x2 - x1) * (py - y1) - (y2 - y1) * (px - x1)

    if side(ax1, ay1, bx1, by1, bx2, by2) * side(ax2, ay2, bx1, by1, bx2, by2) <= 0.0 and (
        side(bx1, by1, ax1, ay1, ax2, ay2) * side(bx2, by2, ax1, ay1, ax2, ay2) <= 0.0
    ):
        return 0.0
    return min(
        min(
            point_segment_distance(ax1, ay1, bx1, by1, bx2, by2),
            point_segment_distance(ax2, ay2, bx1, by1, bx2, by2),
        ),
        min(
            point_segment_distance(bx1, by1, ax1, ay1, ax2, ay2),
            point_segment_distance(bx2, by2, ax1, ay1, ax2, ay2),
        ),
    )
