"""A map prepared for localizing: the lookups every scan asks of it, built once, up front.

The two-stage method, the hypothesis search and the fit each look the map up their own
way: stage 1 through an R-table of segment lengths by orientation, stage 2 and the heading
window through a coarse grid of the segments, refinement and the verdict through a fine
one, the search through a score raster and its bound pyramid. ``prepare_map`` builds them
all before the first scan, so that no scan's time includes them and worker processes
forked afterwards inherit them; ``PreparedMap.for_params`` gives the map for other
settings, building again only what those settings change.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from segloc_cli.config import LocalizeParams, SearchParams
from segloc_cli.method.align import RTable
from segloc_cli.method.search import HypothesisSearch
from segloc_cli.method.spatial import NEAR_CELL_M, SegmentGrid


def search_needed(params: LocalizeParams, global_search: bool = False) -> bool:
    """Whether localizing with ``params`` runs the hypothesis search: a global search always
    does; a guided one (and a track's recovery) when refinement is on and its search is not
    switched off (``params.search`` None)."""
    return global_search or (params.refine is not None and params.search is not None)


@dataclass(frozen=True, eq=False)
class PreparedMap:
    """A global map (``segments_world``, (M, 4), metres, world frame) with its lookups.

    ``index`` files the segments under coarse cells (``spatial.DEFAULT_CELL_M``): stage 1's
    heading window and stage 2. ``near_index`` files them under fine cells (``NEAR_CELL_M``):
    refinement, the points' inlier shares and the beams' wall crossings. ``rtable`` holds the
    segment lengths by orientation bin (stage 1) at one bin width. ``search`` is the score
    raster and bound pyramid of the hypothesis search at one ``SearchParams``, or None when
    the settings the map was prepared for never search (``search_needed``).
    """

    segments_world: np.ndarray
    index: SegmentGrid
    near_index: SegmentGrid
    rtable: RTable
    search: HypothesisSearch | None

    def for_params(self, params: LocalizeParams, *, global_search: bool = False) -> PreparedMap:
        """This map prepared for ``params`` (and a global search, if asked), sharing what
        they leave unchanged: the indexes always, the R-table at the same bin width, the
        search at the same search settings."""
        return _prepared(self.segments_world, params, global_search, self)

    def unsuited_to(self, params: LocalizeParams) -> str | None:
        """Why this map cannot serve a guided localizer with ``params`` (an R-table at another
        bin width, a search at other settings, or none where they search), in words; None
        when it can."""
        if not self._bins_fit(params):
            return f"its R-table's bins are not {params.bin_deg:g}° wide"
        if self.search is None:
            return "it has no hypothesis search" if search_needed(params) else None
        return None if self._search_fits(params) else "its hypothesis search has other settings"

    def _bins_fit(self, params: LocalizeParams) -> bool:
        return self.rtable.bin_width_rad == np.deg2rad(params.bin_deg)

    def _search_fits(self, params: LocalizeParams) -> bool:
        return self.search is not None and self.search.params == (params.search or SearchParams())


def prepare_map(
    segments_world: np.ndarray,
    params: LocalizeParams | None = None,
    *,
    global_search: bool = False,
) -> PreparedMap:
    """The map (M, 4), metres, world frame, prepared for localizing with ``params`` (default
    settings when None): its indexes, its R-table at ``params.bin_deg``, and its hypothesis
    search when those settings, or a global search (``global_search``), run it."""
    segments = np.asarray(segments_world, dtype=float)
    return _prepared(segments, params or LocalizeParams(), global_search, None)


def _prepared(
    segments: np.ndarray,
    params: LocalizeParams,
    global_search: bool,
    shared: PreparedMap | None,
) -> PreparedMap:
    """The map prepared for ``params``, taking from ``shared`` (the same map prepared for other
    settings, or None) whatever those settings leave unchanged."""
    if shared is None:
        index, near_index = SegmentGrid(segments), SegmentGrid(segments, cell_m=NEAR_CELL_M)
    else:
        index, near_index = shared.index, shared.near_index
    if shared is not None and shared._bins_fit(params):
        rtable = shared.rtable
    else:
        rtable = RTable.build(segments, params.bin_deg)
    wanted = params.search or SearchParams()
    if shared is not None and shared._search_fits(params):
        search = shared.search
    elif not search_needed(params, global_search):
        search = None
    elif shared is not None and shared.search is not None and _same_raster(shared.search, wanted):
        search = _with_params(shared.search, wanted)
    else:
        search = HypothesisSearch(segments, params.search)
    return PreparedMap(segments, index, near_index, rtable, search)


RASTER_SETTINGS = ("cell_m", "score_radius_m", "max_depth")
"""The search settings its raster and bound pyramid are built from; the others (the square
around a guess, the headings, the pruning, the floor, the region) only steer a search."""


def _same_raster(search: HypothesisSearch, params: SearchParams) -> bool:
    """Whether a search at ``params`` builds the raster and pyramid ``search`` has."""
    return all(getattr(params, f) == getattr(search.params, f) for f in RASTER_SETTINGS)


def _with_params(search: HypothesisSearch, params: SearchParams) -> HypothesisSearch:
    """``search`` steered by ``params``, sharing its raster and pyramid (building them costs
    far more than a guided search in them)."""
    other = copy.copy(search)
    other.params = params
    return other
