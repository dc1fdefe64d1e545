"""Hypothesis search: many candidate poses, scored by how much of the scan lies on the map.

With a handful of local segments (a 180° scan of 180 beams gives 6–9) the
stage-2 overlap is nearly flat across a wide area, and a single descent from
the initial guess often ends on a wrong pose that overlaps just as well. The
search here asks the scan's points instead. For each candidate heading it
sums, over a grid of positions, the raster scores of the rotated and shifted
points (``field.py``): first per coarse block, whose sums bound every shift
inside it, then at the fine resolution only inside the blocks whose bound
can still compete, best first. The result is a ranked list of distinct grid
poses, which the caller polishes by refinement and compares.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from segloc_cli.config import SearchParams
from segloc_cli.field import INDEX_LIMIT, cell_indices, coarse_bound, score_raster
from segloc_cli.geometry import Pose2, rotation, wrap_angle

MAX_BOUND_CELLS = 2**24
"""Most coarse-block bounds held at once (float64, 128 MiB); more headings are done in batches."""


@dataclass(frozen=True)
class Hypothesis:
    """A grid pose (world frame) and the mean score of the scan's points there, in [0, 1]."""

    pose: Pose2
    score: float


@njit(cache=True)
def _shift_sums(raster, ix, iy, nu, nv):
    """Sums (H, nu, nv) over points of raster[ix[h, p] + u, iy[h, p] + v]; 0 outside.

    Points whose base cell lies beyond ``INDEX_LIMIT`` are skipped, so no index
    arithmetic can overflow and every read stays inside ``raster``.
    """
    n_h, n_p = ix.shape
    nx, ny = raster.shape
    out = np.zeros((n_h, nu, nv))
    for h in range(n_h):
        for p in range(n_p):
            bx, by = ix[h, p], iy[h, p]
            if bx < -INDEX_LIMIT or bx > INDEX_LIMIT or by < -INDEX_LIMIT or by > INDEX_LIMIT:
                continue
            u_lo, u_hi = max(0, -bx), min(nu, nx - bx)
            v_lo, v_hi = max(0, -by), min(nv, ny - by)
            for u in range(u_lo, u_hi):
                row = raster[bx + u]
                for v in range(v_lo, v_hi):
                    out[h, u, v] += row[by + v]
    return out


FULL_SORT_CELLS = 2**22
"""Bounds of up to this many blocks are fully sorted; larger sets are first cut down to their
best with a partition (the same blocks, in an order that may differ among equal bounds)."""


def _best_first(values: np.ndarray, count: int) -> np.ndarray:
    """Indices of the ``count`` largest of ``values`` (1-D), largest first; past
    ``FULL_SORT_CELLS`` values, only positive ones (a bound of 0 is never searched)."""
    if values.size <= FULL_SORT_CELLS or count >= values.size:
        return np.argsort(values)[::-1][:count]
    positive = np.flatnonzero(values > 0.0)
    if positive.size > count:
        kept = np.argpartition(values[positive], positive.size - count)[positive.size - count :]
        positive = positive[kept]
    return positive[np.argsort(values[positive])[::-1]]


def distinct(poses: list[Pose2], pose: Pose2, distinct_m: float, distinct_deg: float) -> bool:
    """Whether ``pose`` differs from every pose in ``poses`` by the given margins."""
    for other in poses:
        near = np.hypot(pose.x - other.x, pose.y - other.y) <= distinct_m
        turn = abs(np.rad2deg(wrap_angle(pose.theta - other.theta)))
        if near and turn <= distinct_deg:
            return False
    return True


class HypothesisSearch:
    """Scores candidate poses of scans against one map (M, 4), world frame."""

    def __init__(self, segments_world: np.ndarray, params: SearchParams | None = None):
        self.params = params or SearchParams()
        p = self.params
        self.segments_world = np.asarray(segments_world, dtype=float).reshape(-1, 4)
        self.fine = score_raster(
            self.segments_world, p.cell_m, p.score_radius_m, margin_m=p.score_radius_m
        )
        self._coarse: dict[int, np.ndarray] = {}

    def coarse(self, factor: int) -> np.ndarray:
        if factor not in self._coarse:
            self._coarse[factor] = coarse_bound(self.fine.score, factor)
        return self._coarse[factor]

    def _ranked_blocks(
        self, cx: np.ndarray, cy: np.ndarray, n_coarse: int, count: int, f: int, n_points: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``count`` (heading, block) pairs of highest bound, best first.

        Returns flat indices into (H, n_coarse, n_coarse) and their bounds (share
        of the points). The bounds of all headings at once would take
        H·n_coarse² floats (gigabytes for a global search of a large map), so
        headings are bounded in batches of at most ``MAX_BOUND_CELLS`` blocks and
        only each batch's best ``count`` are kept.
        """
        n_h = cx.shape[0]
        per_heading = n_coarse * n_coarse
        batch = max(1, MAX_BOUND_CELLS // per_heading)
        coarse = self.coarse(f)
        flats, values = [], []
        for h0 in range(0, n_h, batch):
            part = slice(h0, h0 + batch)
            bounds = _shift_sums(coarse, cx[part], cy[part], n_coarse, n_coarse) / n_points
            order = _best_first(bounds.reshape(-1), count)
            flats.append(order + h0 * per_heading)
            values.append(bounds.reshape(-1)[order])
        if len(flats) == 1:
            return flats[0], values[0]
        flat, value = np.concatenate(flats), np.concatenate(values)
        keep = np.argsort(-value, kind="stable")[:count]
        return flat[keep], value[keep]

    def extent(self) -> tuple[np.ndarray, float]:
        """Centre (2,) and half side (m) of a square holding the whole map."""
        ends = self.segments_world.reshape(-1, 2)
        lo, hi = ends.min(axis=0), ends.max(axis=0)
        return (lo + hi) / 2.0, float((hi - lo).max() / 2.0)

    def search(
        self,
        points_robot: np.ndarray,
        headings_rad: np.ndarray,
        centre_xy: np.ndarray,
        half_width_m: float,
        coarse_factor: int,
        max_expansions: int,
    ) -> list[Hypothesis]:
        """Distinct grid poses, best first, within a square around ``centre_xy``.

        Every heading is combined with every position on the fine grid of the
        square (spacing ``cell_m``); only positions in coarse blocks whose
        bound reaches ``keep_fraction`` of the best fine score are scored
        exactly, at most ``max_expansions`` blocks, best bound first.
        """
        p = self.params
        points = np.asarray(points_robot, dtype=float).reshape(-1, 2)
        headings = np.atleast_1d(np.asarray(headings_rad, dtype=float))
        if points.shape[0] == 0 or headings.size == 0 or self.segments_world.shape[0] == 0:
            return []
        if not (np.all(np.isfinite(centre_xy)) and np.isfinite(half_width_m)):
            return []
        cell, f = self.fine.cell_m, int(coarse_factor)
        half_cells = int(np.ceil(half_width_m / cell))
        start = np.asarray(centre_xy, dtype=float) - half_cells * cell
        n_fine = 2 * half_cells + 1
        n_coarse = -(-n_fine // f)
        # Fine cell of every point at every heading, the shift being ``start``.
        rotated = np.einsum("pk,hjk->hpj", points, np.stack([rotation(h) for h in headings]))
        base = cell_indices((rotated + start - self.fine.origin) / cell)
        ix, iy = np.ascontiguousarray(base[..., 0]), np.ascontiguousarray(base[..., 1])
        n_points = float(points.shape[0])
        ranked, ranked_bounds = self._ranked_blocks(
            ix // f, iy // f, n_coarse, max_expansions, f, n_points
        )
        found: list[Hypothesis] = []
        best = 0.0
        for flat, bound in zip(ranked, ranked_bounds, strict=True):
            h, cu, cv = np.unravel_index(flat, (headings.size, n_coarse, n_coarse))
            if bound < p.keep_fraction * best or bound <= 0.0:
                break
            sums = _shift_sums(
                self.fine.score, ix[h : h + 1] + cu * f, iy[h : h + 1] + cv * f, f, f
            )[0]
            u, v = np.unravel_index(np.argmax(sums), sums.shape)
            score = float(sums[u, v] / n_points)
            xy = start + cell * np.array([cu * f + u, cv * f + v])
            found.append(Hypothesis(Pose2(float(xy[0]), float(xy[1]), float(headings[h])), score))
            best = max(best, score)
        found.sort(key=lambda hyp: -hyp.score)
        kept: list[Hypothesis] = []
        for hyp in found:
            if distinct([k.pose for k in kept], hyp.pose, p.distinct_m, p.distinct_deg):
                kept.append(hyp)
                if len(kept) == p.hypotheses:
                    break
        return kept

    def around(
        self, points_robot: np.ndarray, initial: Pose2, window_deg: float, extra_headings=()
    ) -> list[Hypothesis]:
        """Search the square of ``half_width_m`` around the guess, headings within ± window."""
        p = self.params
        steps = np.arange(-window_deg, window_deg + 1e-9, p.heading_step_deg)
        headings = np.concatenate([initial.theta + np.deg2rad(steps), np.asarray(extra_headings)])
        return self.search(
            points_robot,
            wrap_angle(headings),
            np.array([initial.x, initial.y]),
            p.half_width_m,
            p.coarse_factor,
            p.max_expansions,
        )

    def everywhere(self, points_robot: np.ndarray) -> list[Hypothesis]:
        """Search the whole map at every heading (no initial guess).

        Every heading, not only stage 1's peaks: over a whole map the vote's
        strongest peaks often miss the true heading of a 180° scan.
        """
        p = self.params
        headings = np.deg2rad(np.arange(0.0, 360.0, p.heading_step_deg))
        centre, half = self.extent()
        return self.search(
            points_robot, headings, centre, half, p.global_coarse_factor, p.global_max_expansions
        )
