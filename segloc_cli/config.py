"""Every setting of a run, with its default: the one place defaults are written.

A run's settings are frozen dataclasses, one per stage, composed in ``Config``:
extraction, map fusion, both stages of the method, the hypothesis search,
refinement, the verdict, tracking, and the matcher, worker count and pairing
tolerance around them. The stage modules import their parameter class from
here.

``SETTINGS`` names each of them for the outside world: the key is the long
option of the command line (``--grid-m``) and the key in a ``--config`` table
(``grid-m = 1.5``); ``path`` says which field of ``Config`` it sets; ``help``
is the option's help text, or None for a tuning setting, which the command
line accepts but does not list (docs/configuration.md's settings table lists them all).
``Setting.checked`` is the one check of a setting's value, whether it comes from the
command line, a ``--config`` table, a run file or a sweep spec; ``run_config`` makes a
localize run's ``Config`` and refuses settings that cannot go together.

This module imports nothing heavier than numpy: the command line reads it at start-up.
"""

from __future__ import annotations

import ast
import functools
import inspect
import itertools
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from segloc_cli.errors import SeglocError
from segloc_cli.limits import MAX_COORDINATE_M

TIME_TOLERANCE_MS = 50.0
"""Default largest time difference when pairing records of two files by time."""

MIN_HOLD_POINTS = 3.0
"""Fewest points' worth that must pin the position along its weakest direction: fewer, and
the position along a corridor or a lone wall rests on one or two readings, or on none."""

MIN_POINT_SPREAD_M = 0.1
"""Smallest spread (m) of a scan's points across their main direction for a trusted pose.
Every scan of the Intel Research Lab log spreads at least 0.2 m; one wall seen alone, or a
fan whose beams all lie on one ray, spreads about the range noise (a centimetre)."""

VOTE_SCHEMES = ("product", "count", "local", "sum")
"""Vote weights of the paper: eq. (1) λL·λG, eq. (2) 1, eq. (3) λL, eq. (4) λL + λG."""

METHODS = ("two-stage", "icp", "correlative")
"""Matchers ``segloc localize --method`` runs: the paper's method and two peers."""

ICP_VARIANTS = ("gicp", "plane")
"""ICP flavours of ``--method icp``: generalized ICP or point-to-plane ICP."""

SEEN_THROUGH_CHOICES = ("drop", "keep")
"""What ``map build`` does with a segment the scans see through (``FuseParams.seen_through``)."""

GUESSES_KEYWORD = "odom"
"""``--initial`` value that takes the guesses from the log itself rather than a file."""


@dataclass(frozen=True)
class ExtractParams:
    """Extraction settings (metres, degrees at the edge)."""

    range_sigma_m: float = 0.012
    """Range noise σ of the scanner; sets the breakpoint slack and the fit tolerance."""
    breakpoint_lambda_deg: float = 10.0
    """Shallowest incidence angle on a surface that is still one surface (Borges & Aldon's λ)."""
    split_m: float = 0.05
    """Largest distance of a point from its segment's line."""
    min_points: int = 4
    """Fewest readings on a segment; four leave two degrees of freedom to judge the fit."""
    min_length_m: float = 0.25
    """Shortest segment kept."""
    max_direction_sigma_deg: float = 3.0
    """Largest standard error of a segment's direction (see ``direction_sigma_rad``).

    Equal to the map fusion's orientation tolerance: a piece whose direction is
    less certain than that could not be told to lie on its wall.
    """


@dataclass(frozen=True)
class FuseParams:
    """When two world-frame segments are one wall (metres, degrees), how the scans' poses
    are polished before their segments are fused, and which fused segments the map keeps."""

    angle_deg: float = 3.0
    """Largest difference of undirected orientation."""
    offset_m: float = 0.06
    """Largest distance of either segment's endpoints from the other's line."""
    gap_m: float = 0.15
    """Largest gap between their extents along the common line (negative = overlap)."""
    polish_rounds: int = 0
    """Rounds of polishing: each scan's pose re-fitted to the map the other half of the scans
    make (``maps.fusion.polish_poses``); 0 keeps the poses as surveyed."""
    polish_max_shift_m: float = 0.2
    """A polished pose farther than this from the surveyed one is not taken (a bad fit)."""
    polish_min_inlier_ratio: float = 0.6
    """A polished pose with a smaller share of the scan's points on the map is not taken."""
    min_observations: int = 1
    """A fused segment is kept only if seen from at least this many surveyed poses (scans
    paired with one survey row count once); 1 keeps every segment."""
    seen_through: str = "keep"
    """What becomes of a fused segment that is free space over most of its length, seen
    through there from more surveyed poses than saw it: "drop" or "keep" (``maps.carving``)."""


@dataclass(frozen=True)
class RefineParams:
    """Settings of the fit (metres, counts)."""

    gate_m: float = 0.4
    """First round's largest point-to-segment distance for a point to take part."""
    final_gate_m: float = 0.05
    """Last round's gate; also the band within which a point counts as an inlier."""
    steps_per_round: int = 4
    """Gauss-Newton steps per gate; the gate halves between rounds down to ``final_gate_m``."""
    min_points: int = 8
    """Fewer inliers than this and the fit is not attempted (the pose is returned as is)."""
    point_sigma_m: float = 0.02
    """Typical distance of a good point from its wall: weighs the prior against the points."""
    prior_sigma_m: float | None = None
    """Spread of the guess's position (per axis); None fits the points alone. Tracking sets
    it per scan from ``TrackParams``; it is not a setting of a run."""
    prior_sigma_deg: float | None = None
    """Spread of the guess's heading; None leaves the heading to the points (as above)."""


@dataclass(frozen=True)
class SearchParams:
    """Settings of the hypothesis search (metres, degrees, counts)."""

    cell_m: float = 0.05
    """Fine raster cell and fine position step."""
    score_radius_m: float = 0.1
    """A point scores 1 on a segment, falling to 0 at this distance from it."""
    half_width_m: float = 2.0
    """Half side of the square of positions searched around an initial guess."""
    heading_step_deg: float = 1.0
    """Spacing of the headings tried: across the prior window, or the whole circle without one."""
    keep_fraction: float = 0.8
    """Poses scoring under this share of the best are not kept: the search prunes below it."""
    min_score: float = 0.0
    """A search whose best pose scores under this (the mean score of the scan's points, 0 to
    1) finds nothing, and prunes below it from the start (0: the best is always kept)."""
    max_depth: int = 7
    """Levels of the bound pyramid above the fine raster, squares of up to 2^max_depth cells
    (6.4 m at 5 cm), fewer for a smaller region: the branch and bound starts from squares of
    8 cells (0.4 m), or of the finest of the coarser levels where there would be more than
    16 million heading-square pairs."""
    hypotheses: int = 4
    """Distinct grid poses handed on for refinement."""
    distinct_m: float = 0.3
    """Two poses farther apart than this (or ``distinct_deg``) are different answers."""
    distinct_deg: float = 3.0
    """Two poses whose headings differ by more than this are different answers."""
    region: tuple[float, float, float, float] | None = None
    """Global search only: the rectangle (x0, y0, x1, y1; metres, world frame) the robot is
    known to be in, set by ``--region``; None searches wherever the scan could reach the map."""


@dataclass(frozen=True)
class ConfidenceParams:
    """Thresholds of the verdict: on the inlier share (0–1), the confidence (a probability,
    see ``confidence.py``) and the points that fix the position."""

    min_inlier_ratio: float = 0.5
    """Below this share of points on the map the answer is ``lost``."""
    min_confidence: float = 0.9
    """Below this probability of being the right place the answer is ``ambiguous``."""
    min_hold_points: float = MIN_HOLD_POINTS
    """The points on the map must fix the position in every direction by this many points'
    worth (``refine.support``), else ``ambiguous``."""


@dataclass(frozen=True)
class LocalizeParams:
    """Settings of both stages (paper defaults: Table 1 used η0 = 1.5 m and Δα0 = 4°)."""

    window_deg: float | None = 20.0
    """Stage-1 half window around the prior heading; None scores the whole circle."""
    bin_deg: float = 1.0
    """Stage-1 orientation bin width; divides 180."""
    vote: str = "product"
    """Stage-1 vote weights, one of ``VOTE_SCHEMES``."""
    max_peaks: int = 8
    """Most stage-1 headings handed to stage 2, best first."""
    grid_m: float = 1.5
    """Stage-2 initial grid spacing η0, halved every iteration."""
    dtheta_deg: float = 4.0
    """Stage-2 initial heading step Δα0, halved every iteration."""
    iterations: int = 8
    """Halvings K; the paper leaves K to the accuracy wanted (last grid η0 / 2^(K−1))."""
    ratio: float = 0.9
    """Stage-2 candidates within this ratio of the best overlap are averaged."""
    recentres: int = 8
    """Extra same-scale iterations while the estimate still moves (0 = the paper's schedule)."""
    min_segments: int = 3
    """Fewer local segments and the status is ``too_few_segments`` (stage 2 does not run)."""
    min_points: int = 20
    """Fewer valid readings and the status is ``too_few_segments``. The verdict weighs shares
    of the points: below 20, two stray readings would swing them by a tenth, and three segments
    of extraction's 4 readings each leave little to check a fit against."""
    min_spread_m: float = MIN_POINT_SPREAD_M
    """Points spread less than this across their main direction: ``too_few_segments``."""
    refine: RefineParams | None = field(default_factory=RefineParams)
    """Least-squares fit of the scan's points after stage 2; None stops at stage 2 (the paper)."""
    search: SearchParams | None = field(default_factory=SearchParams)
    """With refinement: also refine the best poses of a search of the prior window by the
    scan's points, and keep the fit that puts them closest to the map."""
    confidence: ConfidenceParams = field(default_factory=ConfidenceParams)
    """Thresholds of the verdict (``ok``, ``ambiguous``, ``lost``)."""


@dataclass(frozen=True)
class TrackParams:
    """How each tracked scan is fitted and when the fit is accepted (metres, degrees)."""

    min_inlier_ratio: float = 0.5
    """Share of the scan's points that must lie on the map (within refinement's final gate)."""
    max_jump_m: float = 0.5
    """Largest correction of the dead-reckoning guess accepted (position)."""
    max_jump_deg: float = 15.0
    """Largest correction of the dead-reckoning guess accepted (heading)."""
    widen: float = 2.0
    """The recovery search multiplies the grid, the heading window and the jump limits by this..."""
    max_widenings: int = 3
    """...once more for every scan lost in a row, up to this many times in all."""
    odom_sigma_m: float = 0.02
    """Spread of the guess per scan when standing still (position, per axis)..."""
    odom_sigma_per_m: float = 0.1
    """...plus this much per metre the odometry moved since the previous scan."""
    odom_sigma_deg: float = 1.0
    """Spread of the guess's heading per scan when not turning..."""
    odom_sigma_per_deg: float = 0.2
    """...plus this much per degree the odometry turned since the previous scan."""

    def prior(self, increment: Any) -> tuple[float, float]:
        """Spread (m, °) of a guess made by moving the previous estimate by ``increment``
        (a ``Pose2``: x, y in metres, heading in radians)."""
        return (
            self.odom_sigma_m + self.odom_sigma_per_m * float(np.hypot(increment.x, increment.y)),
            self.odom_sigma_deg + self.odom_sigma_per_deg * abs(increment.theta_deg),
        )


@dataclass(frozen=True)
class WindowParams:
    """Which neighbours join a scan's local map when the log has odometry (``window.py``;
    metres, degrees, seconds)."""

    travel_m: float = 1.0
    """Scans within this much odometry travel before and after the scan join its local map;
    0 localizes each scan alone."""
    max_time_s: float = 3.0
    """...and within this many seconds of it: odometry drifts with time as well as travel."""
    spacing_m: float = 0.2
    """A neighbour is taken once the odometry moved this far since the last one taken..."""
    spacing_deg: float = 10.0
    """...or turned this far."""
    max_scans: int = 9
    """Most scans in a window, the scan included (half of the rest on each side)."""
    thin_m: float = 0.1
    """A neighbour adds its points only in cells of this size that hold none yet."""
    max_correction_m: float = 0.3
    """A neighbour whose fit to the others moves it farther than this from where the
    odometry put it is left out: over a metre odometry slips less, so the fit slipped."""
    max_correction_deg: float = 5.0
    """...or turns it more than this."""
    min_agreement: float = 0.5
    """A neighbour with fewer than this share of its points on the scans placed before it,
    once fitted, is left out (of the points within ``max_correction_m`` of them: the rest see
    what the window has not): where they overlap, a neighbour a metre away sees the same
    walls, and one the odometry put in the wrong place (wheels slip in a turn) sees them
    elsewhere."""


@dataclass(frozen=True)
class SlamParams:
    """Settings of the segment SLAM (metres, degrees)."""

    keyframe_m: float = 0.25
    """A scan becomes a keyframe once the odometry moved this far since the last one..."""
    keyframe_deg: float = 10.0
    """...or turned this much."""
    local_map_m: float = 4.0
    """The keyframes within this much travel before a scan make the map it is fitted to."""
    min_inlier_ratio: float = 0.3
    """A fit with fewer of the scan's points on the local map is not taken: the odometry
    places the keyframe, with its own spread (``odom_sigma_*``)..."""
    max_correction_m: float = 0.3
    """...nor, in a log with odometry, a fit that moves the scan farther than this from
    where the odometry put it since the scan before (odometry does not err so much in a
    fraction of a second)..."""
    max_correction_deg: float = 10.0
    """...or turns it more than this."""
    point_sigma_m: float = 0.05
    """Spread of a point about its wall in the fit's information (wider than the range
    noise: the points of one scan do not err independently)."""
    edge_floor_m: float = 0.01
    """Added to the spread of every edge's position (per axis): what a fit's own figures
    leave out (segments fused to about a centimetre, points that err together)..."""
    edge_floor_deg: float = 0.2
    """...and to the spread of its heading."""
    odom_jump_m: float = 2.0
    """Odometry that moves this far between two scans, and faster than ``odom_jump_m_per_s``,
    has jumped (a robot carried off, a reset): that scan is placed by the scans alone..."""
    odom_jump_deg: float = 135.0
    """...as is one it turns this much, faster than ``odom_jump_deg_per_s``."""
    odom_jump_m_per_s: float = 3.0
    """Faster than a mobile robot drives: a step longer than ``odom_jump_m`` over a gap
    between scans long enough for the robot to drive it is no jump..."""
    odom_jump_deg_per_s: float = 360.0
    """...nor a turn that a robot turning this fast makes in the gap."""
    odom_sigma_m: float = 0.05
    """Spread of an odometry edge per metre travelled (position, per axis)..."""
    odom_sigma_deg: float = 2.0
    """...and of its heading per metre travelled (plus one tenth of the turn)."""
    submap_m: float = 8.0
    """Travel covered by one submap."""
    submap_bend_m: float = 0.05
    """A submap is fused again once loops have moved one of its keyframes this far relative
    to its anchor since it was fused..."""
    submap_bend_deg: float = 0.5
    """...or turned one this much."""
    loop_min_travel_m: float = 15.0
    """A keyframe is searched for only in submaps ended at least this much travel before it."""
    loop_radius_m: float = 1.0
    """Uncertainty of a keyframe's pose relative to a submap it is searched for in (position),
    where the two are joined by a loop..."""
    loop_radius_per_m: float = 0.05
    """...growing by this much per metre of travel between them along the graph (loops closed
    so far are short cuts), up to ``loop_max_radius_m``."""
    loop_max_radius_m: float = 6.0
    loop_window_deg: float = 20.0
    """Heading uncertainty between a keyframe and a submap joined by a loop (the search's
    window either side)..."""
    loop_window_per_m: float = 0.2
    """...growing by this much (°) per metre of travel between them along the graph, up to
    180°."""
    loop_min_score: float = 0.4
    """A loop search is not followed through where the best pose puts under this share of
    the scan's points on the submap (the search's ``min_score``): a loop this weakly
    supported would not be taken, and the searches of submaps the keyframe does not see end
    early."""
    loop_every: int = 3
    """Every this-many-th keyframe is searched for in older submaps."""
    loop_cauchy: float = 1.0
    """Scale of the Cauchy loss on loop edges, in their standard deviations."""
    loop_drop_chi2: float = 11.34
    """A loop the final solution leaves off by more than this, as the squared Mahalanobis
    distance of its residual under the loop's covariance, is dropped and the graph solved
    again without it (up to three times): 11.34 is the 99th percentile of χ² with three
    degrees of freedom, so a true loop is dropped once in a hundred."""


@dataclass(frozen=True)
class Config:
    """Every setting of a run: the stages' parameters and the choices around them."""

    extract: ExtractParams = field(default_factory=ExtractParams)
    fuse: FuseParams = field(default_factory=FuseParams)
    localize: LocalizeParams = field(default_factory=LocalizeParams)
    """Both stages, with refinement, the hypothesis search and the verdict inside."""
    track: TrackParams = field(default_factory=TrackParams)
    window: WindowParams = field(default_factory=WindowParams)
    """Neighbours placed by odometry into each scan's local map (guided and global runs)."""
    slam: SlamParams = field(default_factory=SlamParams)
    """``map build`` without a survey: keyframes, submaps and loops."""
    method: str = "two-stage"
    """One of ``METHODS``."""
    icp_variant: str = "gicp"
    """With ``method`` icp: one of ``ICP_VARIANTS``."""
    jobs: int = 1
    """Processes localizing independent scans."""
    tolerance_ms: float = TIME_TOLERANCE_MS
    """Largest time difference when pairing records of two files by time."""

    @classmethod
    def from_values(cls, values: dict[str, Any]) -> Config:
        """The configuration with the settings named in ``values`` (keys of ``SETTINGS``,
        as option names) set, and every other at its default. Keys that are no setting
        (a command's inputs and outputs) are ignored."""
        config = cls()
        named = [(SETTINGS[key], value) for key, value in values.items() if key in SETTINGS]
        # Switches last: --no-prior-heading empties the window that --window-deg sets.
        for setting, value in sorted(named, key=lambda item: item[0].switch):
            if value is not None:
                config = setting.applied(config, value)
        return config


class SettingError(SeglocError):
    """A value a setting does not take, or settings that cannot go together, in the command
    line's words. From ``Setting.checked`` (``key`` set), the reason alone: what click prints
    after "Invalid value for '--KEY': "."""

    def __init__(self, message: str, key: str | None = None):
        super().__init__(message)
        self.key = key


@dataclass(frozen=True)
class Setting:
    """One setting as the outside world names it.

    ``key`` is the long option and ``--config`` key; ``path`` the field of
    ``Config`` it sets (through nested parameter classes); ``low``/``high``
    bound a number (``low_open`` excludes ``low``); ``choices`` list the
    values of a text setting; ``help`` is the option's help text, None for a
    tuning setting that the help does not list. A ``switch`` is a flag that
    sets the field to None (``--no-refine``: no refinement); its ``path`` is
    the field it empties. A setting given as text of several parts (``--region
    X0,Y0,X1,Y1``) has a ``parse`` that checks the text and makes the field's value of it,
    when the configuration is made (``run_config``), as ``metavar`` shows it.
    """

    key: str
    path: tuple[str, ...]
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    choices: tuple[str, ...] | None = None
    help: str | None = None
    switch: bool = False
    metavar: str | None = None
    parse: Callable[[str], Any] | None = None

    @property
    def default(self) -> Any:
        """The default, read from the parameter classes (False for a switch)."""
        if self.switch:
            return False
        value: Any = Config()
        for name in self.path:
            value = getattr(value, name)
        return value

    @property
    def kind(self) -> type:
        """The value's type: bool, int, float or str (text to ``parse``)."""
        if self.switch:
            return bool
        if self.parse is not None:
            return str
        return {"float": float, "int": int, "str": str}[_field_kind(self.path)]

    def checked(self, value: Any) -> Any:
        """``value`` (text from the command line, or a value of a configuration file) as the
        setting takes it: one of its ``choices``; a whole number within its bounds; a finite
        number within them; a switch's bool; text to ``parse`` as it is (``parse`` checks
        it). ``SettingError`` says why not, as click's own types say it."""
        if self.switch:
            return bool(value)
        if self.choices is not None:
            return one_of(value, self.choices, self.key)
        if self.parse is not None:
            return value
        if self.kind is int:
            return number_within(value, int, *self.int_bounds, key=self.key)
        return number_within(value, float, self.low, self.high, self.low_open, self.key)

    @property
    def int_bounds(self) -> tuple[int | None, int | None]:
        """``low`` and ``high`` as whole numbers, None where there is no bound (``int`` kind)."""
        low = None if self.low is None else int(self.low)
        return low, None if self.high is None else int(self.high)

    def applied(self, config: Config, value: Any) -> Config:
        """``config`` with this setting set to ``value`` (a switch: emptied when True; text
        to parse: parsed, which may raise ``SettingError``)."""
        if self.switch:
            return _replaced(config, self.path, None) if value else config
        made = self.kind(value) if self.parse is None else self.parse(value)
        return _replaced(config, self.path, made)

    @property
    def doc(self) -> str:
        """The help text, or for a tuning setting the docstring of its field."""
        return self.help or field_doc(_owner_class(self.path), self.path[-1])


def number_within(
    value: Any,
    kind: type,
    low: float | None,
    high: float | None = None,
    low_open: bool = False,
    key: str | None = None,
) -> float:
    """``value`` as a number of ``kind`` (int, or float: then also finite) from ``low`` (above
    it when ``low_open``) to ``high``, either None for no bound; ``SettingError`` in the words
    of click's ``IntRange`` and ``FloatRange`` (the bounds shown as given)."""
    try:
        number = kind(value)
    except ValueError:
        name = "integer range" if kind is int else "float range"
        raise SettingError(f"{value!r} is not a valid {name}.", key) from None
    below = low is not None and (number <= low if low_open else number < low)
    if below or (high is not None and number > high):
        if low is None:
            bounds = f"x<={high}"
        elif high is None:
            bounds = f"x{'>' if low_open else '>='}{low}"
        else:
            bounds = f"{low}{'<' if low_open else '<='}x<={high}"
        raise SettingError(f"{number} is not in the range {bounds}.", key)
    if kind is float and not math.isfinite(number):
        raise SettingError(f"{value!r} is not a finite number.", key)
    return number


def one_of(value: Any, choices: tuple[str, ...], key: str | None = None) -> str:
    """The choice that ``value`` names (as text); ``SettingError`` in ``click.Choice``'s words."""
    if str(value) in choices:
        return str(value)
    listed = ", ".join(map(repr, choices))
    some = f"one of {listed}" if len(choices) > 1 else listed
    raise SettingError(f"{value!r} is not {some}.", key)


def _owner_class(path: tuple[str, ...]) -> type:
    """The parameter class that holds the last field of ``path``."""
    holder: Any = Config()
    for name in path[:-1]:
        holder = getattr(holder, name)
    return type(holder)


def _field_kind(path: tuple[str, ...]) -> str:
    """The type named by the annotation of the field at ``path``: "float", "int" or "str"
    (an optional field's type without its None)."""
    annotation = {f.name: f.type for f in fields(_owner_class(path))}[path[-1]]
    return str(annotation).split(" |")[0]


def _replaced(holder: Any, path: tuple[str, ...], value: Any) -> Any:
    """``holder`` with the field at ``path`` (through nested dataclasses) set to ``value``.
    A nested class that is None (refinement off) is left None: there is nothing to set."""
    head, rest = path[0], path[1:]
    if not rest:
        return replace(holder, **{head: value})
    inner = getattr(holder, head)
    if inner is None:
        return holder
    return replace(holder, **{head: _replaced(inner, rest, value)})


@functools.cache
def _field_docs(module: str) -> dict[str, dict[str, str]]:
    """Docstrings written under the fields of the classes defined at the top of ``module``, by
    class and field name. Each module's source is parsed once: every command builds its
    tuning options' help from here when it starts (``inspect.getsource`` of each class
    would parse its whole module again)."""
    tree = ast.parse(inspect.getsource(sys.modules[module]))
    docs: dict[str, dict[str, str]] = {}
    for definition in tree.body:
        if not isinstance(definition, ast.ClassDef):
            continue
        fields_docs = docs.setdefault(definition.name, {})
        for node, after in itertools.pairwise(definition.body):
            if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
                continue
            if isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant):
                fields_docs[node.target.id] = inspect.cleandoc(str(after.value.value))
    return docs


def field_doc(cls: type, name: str) -> str:
    """The docstring of field ``name`` of ``cls``, as one paragraph ("" if none)."""
    doc = _field_docs(cls.__module__).get(cls.__qualname__, {}).get(name, "")
    return " ".join(doc.split("\n\n")[0].split())


_TUNING_BOUNDS: dict[str, tuple[float, float, bool]] = {
    "float": (0.0, 1e4, True),
    "int": (1, 1_000_000, False),
    "extract.min_points": (2, 1_000_000, False),
    "extract.breakpoint_lambda_deg": (0.0, 90.0, True),
    "extract.max_direction_sigma_deg": (0.0, 180.0, True),
    "fuse.gap_m": (-1e4, 1e4, False),
    "fuse.polish_min_inlier_ratio": (0.0, 1.0, False),
    "localize.min_spread_m": (0.0, 1e4, False),
    "localize.search.keep_fraction": (0.0, 1.0, True),
    "localize.search.min_score": (0.0, 1.0, False),
    "localize.search.max_depth": (0, 12, False),
    "localize.search.heading_step_deg": (0.0, 360.0, True),
    "localize.search.distinct_m": (0.0, 1e4, False),
    "localize.search.distinct_deg": (0.0, 180.0, False),
    "localize.confidence.min_inlier_ratio": (0.0, 1.0, False),
    "localize.confidence.min_confidence": (0.0, 1.0, False),
    "localize.confidence.min_hold_points": (0.0, 1e6, False),
    "track.min_inlier_ratio": (0.0, 1.0, False),
    "track.widen": (1.0, 100.0, False),
    "track.max_widenings": (0, 30, False),
    "track.odom_sigma_per_m": (0.0, 1e4, False),
    "track.odom_sigma_per_deg": (0.0, 1e4, False),
    "window.max_time_s": (0.0, 3600.0, True),
    "window.spacing_m": (0.0, 100.0, False),
    "window.spacing_deg": (0.0, 360.0, False),
    "window.max_scans": (1, 64, False),
    "window.thin_m": (0.001, 10.0, False),
    "window.min_agreement": (0.0, 1.0, False),
}
"""Bounds (low, high, low excluded) of tuning settings: by field path, else by type (a count
of at least 1, a positive size). They keep a run clear of divisions by zero and of searches
that would never end."""


def _tuning_setting(key: str, path: tuple[str, ...]) -> Setting:
    low, high, low_open = _TUNING_BOUNDS.get(".".join(path), _TUNING_BOUNDS[_field_kind(path)])
    return Setting(key, path, low, high, low_open)


def _tuning(prefix: str, owner: str, *skip: str) -> tuple[Setting, ...]:
    """A tuning setting for every field of the parameter class at ``owner`` (a dotted path),
    keyed ``prefix-field-name``."""
    path = tuple(owner.split("."))
    return tuple(
        _tuning_setting(f"{prefix}{f.name.replace('_', '-')}", (*path, f.name))
        for f in fields(_owner_class((*path, "")))
        if f.name not in skip
    )


STAGES = (
    Setting(
        "window-deg",
        ("localize", "window_deg"),
        0,
        180,
        help="Stage 1 searches headings within ± this of the initial heading.",
    ),
    Setting(
        "no-prior-heading",
        ("localize", "window_deg"),
        switch=True,
        help="Ignore the initial heading: stage 1 votes over the whole circle and stage 2 "
        "chooses among its peaks.",
    ),
    Setting(
        "vote",
        ("localize", "vote"),
        choices=VOTE_SCHEMES,
        help="Stage-1 vote: product λL·λG (paper eq. 1), count (eq. 2), local λL (eq. 3), "
        "sum λL+λG (eq. 4).",
    ),
    Setting(
        "bin-deg",
        ("localize", "bin_deg"),
        0.05,
        45,
        help="Stage-1 orientation bin width (must divide 180).",
    ),
    Setting(
        "grid-m",
        ("localize", "grid_m"),
        0,
        50,
        low_open=True,
        help="Stage-2 initial grid spacing η0 (halved every iteration).",
    ),
    Setting(
        "dtheta-deg",
        ("localize", "dtheta_deg"),
        0,
        90,
        help="Stage-2 initial heading step Δα0 (halved every iteration).",
    ),
    Setting(
        "iterations",
        ("localize", "iterations"),
        1,
        30,
        help="Stage-2 iterations K; the last grid is η0/2^(K-1).",
    ),
    Setting(
        "ratio",
        ("localize", "ratio"),
        0,
        1,
        low_open=True,
        help="Candidates within this ratio of the best overlap are averaged.",
    ),
    Setting(
        "recentre",
        ("localize", "recentres"),
        0,
        100,
        help="Up to this many extra stage-2 iterations, spent re-searching at the same scale "
        "while the estimate still moves by over half a step; 0 keeps the paper's fixed schedule.",
    ),
    Setting(
        "no-refine",
        ("localize", "refine"),
        switch=True,
        help="Stop at the stage-2 pose (the paper's method) instead of fitting the scan's points "
        "to the map segments by robust least squares afterwards.",
    ),
)

MATCHER = (
    Setting(
        "method",
        ("method",),
        choices=METHODS,
        help="two-stage: this tool's method. For comparison: icp registers the scan's points to "
        "points sampled along the map (small-gicp), correlative searches ±2.1 m and ±20° around "
        "the guess against virtual scans of the map (Karto's matcher); both need "
        "pip install 'segloc[peers]' and an initial guess per scan.",
    ),
    Setting(
        "icp-variant",
        ("icp_variant",),
        choices=ICP_VARIANTS,
        help="With --method icp: generalized ICP or point-to-plane ICP.",
    ),
    Setting(
        "jobs",
        ("jobs",),
        1,
        help="Localize scans on this many processes (not with --track, whose scans depend on "
        "each other); the estimates are the same as with 1.",
    ),
)

WINDOW = Setting(
    "window-m",
    ("window", "travel_m"),
    0,
    100,
    help="Localize each scan with the scans within this much odometry travel before and after "
    "it, placed by the log's /odom and fitted to each other, as one local map: a rival place "
    "that explains the scan but not its neighbours falls behind. Used when the log has "
    "odometry (not --track, not the peers' methods); 0 localizes each scan alone.",
)


def _rectangle(text: str) -> tuple[float, float, float, float]:
    """``X0,Y0,X1,Y1`` text → (x0, y0, x1, y1) metres, finite, within ±``MAX_COORDINATE_M``
    and with x0 < x1, y0 < y1; else ``SettingError``."""
    try:
        corners = tuple(float(v) for v in text.split(","))
    except ValueError:
        corners = ()
    if not (
        len(corners) == 4
        and all(abs(c) <= MAX_COORDINATE_M for c in corners)
        and corners[0] < corners[2]
        and corners[1] < corners[3]
    ):
        raise SettingError(
            f"{text!r}; use X0,Y0,X1,Y1 in metres with X0 < X1 and Y0 < Y1, finite and "
            f"within ±{MAX_COORDINATE_M:g} m (e.g. 0,0,40,25)",
            "region",
        )
    return corners


REGION = Setting(
    "region",
    ("localize", "search", "region"),
    help="With --global: search only this rectangle (metres, world frame) instead of "
    "wherever the scan could reach the map.",
    metavar="X0,Y0,X1,Y1",
    parse=_rectangle,
)
"""The global search's rectangle; it goes with ``--global`` (``run_config``)."""

TOLERANCE = Setting(
    "tolerance-ms",
    ("tolerance_ms",),
    0,
    60_000,
    help="Largest time difference when {pairing}.",
)
"""Pairing by time, in every command that pairs; its help names what is paired."""

EXTRACT = _tuning("extract-", "extract")
FUSE = _tuning("fuse-", "fuse", "polish_rounds", "min_observations", "seen_through")
POLISH = Setting(
    "polish",
    ("fuse", "polish_rounds"),
    0,
    10,
    help="Polish the surveyed poses this many rounds before fusing: each scan is fitted to "
    "the map the other half of the scans make, which sharpens walls blurred by pose errors "
    "(0: use the poses as given).",
)
MIN_OBSERVATIONS = Setting(
    "min-observations",
    ("fuse", "min_observations"),
    1,
    1000,
    metavar="N",
    help="Keep only segments seen from at least N surveyed poses (scans paired with one survey "
    "row count once): a passer-by is seen from one pose, a wall from several. The default, 1, "
    "keeps every segment: on real logs 2 also drops walls seen from one spot or left unfused "
    "by pose errors, and tracking suffered.",
)
SEEN_THROUGH = Setting(
    "seen-through",
    ("fuse", "seen_through"),
    choices=SEEN_THROUGH_CHOICES,
    help="drop: leave out each segment that, over most of its length, more surveyed poses "
    "see through than see (their beams run on to ranges ending over 0.3 m behind it), as a "
    "person walking by is. The default keeps every segment: on the shared real logs, drop "
    "also took out clutter that stood through much of the run, and tracking suffered.",
)
LOCALIZE_TUNING = (
    *(
        _tuning_setting(key, ("localize", name))
        for key, name in (
            ("max-peaks", "max_peaks"),
            ("min-segments", "min_segments"),
            ("min-points", "min_points"),
            ("min-spread-m", "min_spread_m"),
        )
    ),
    *_tuning("refine-", "localize.refine", "prior_sigma_m", "prior_sigma_deg"),
    *_tuning("search-", "localize.search", "region"),
    *_tuning("confidence-", "localize.confidence"),
    *_tuning("track-", "track"),
    *_tuning("window-", "window", "travel_m"),
)
"""Localization's tuning settings: config-file keys (and unlisted options)."""

LOCALIZE_SETTINGS = (*STAGES, *MATCHER, WINDOW, REGION, TOLERANCE, *LOCALIZE_TUNING)
"""The settings ``segloc localize`` takes."""

SETTINGS: dict[str, Setting] = {
    s.key: s
    for s in (
        *STAGES,
        WINDOW,
        REGION,
        *MATCHER,
        TOLERANCE,
        *EXTRACT,
        POLISH,
        MIN_OBSERVATIONS,
        SEEN_THROUGH,
        *FUSE,
        *LOCALIZE_TUNING,
    )
}
"""Every setting by key."""


def run_config(values: dict[str, Any], global_search: bool, track: bool) -> Config:
    """The configuration of a localize run from its settings by key (as ``Config.from_values``
    takes them), refusing as ``SettingError`` a ``--region`` without ``--global``, a region
    that is no rectangle, and settings that cannot go together."""
    if values.get(REGION.key) is not None and not global_search:
        raise SettingError("--region goes with --global")
    try:
        config = Config.from_values(values)
    except SettingError as exc:  # text parsed as the configuration is made (--region)
        raise SettingError(f"Invalid value for --{exc.key}: {exc}") from None
    _check_together(config, global_search, track)
    return config


def _check_together(config: Config, global_search: bool, track: bool) -> None:
    """Refuse settings that cannot go together (``--track``, ``--global``: the modes)."""
    bin_deg = config.localize.bin_deg
    if not np.isclose(180.0 / bin_deg, round(180.0 / bin_deg)):
        raise SettingError(f"Invalid value for --bin-deg: {bin_deg:g} does not divide 180")
    if config.method != "two-stage" and (global_search or track):
        other = "--global" if global_search else "--track"
        raise SettingError(
            f"--method {config.method} cannot be combined with {other}: it matches each scan "
            "from its own initial guess"
        )
    if track and config.jobs > 1:
        raise SettingError(
            "--jobs cannot be combined with --track: each tracked scan starts from the "
            "previous one's estimate"
        )
    if global_search and (track or config.localize.refine is None):
        other = "--track" if track else "--no-refine"
        raise SettingError(
            f"--global cannot be combined with {other}: it searches every scan afresh and "
            "ranks its candidates by refining them"
        )


def _shown(value: Any) -> str:
    return "off" if value is False else "none" if value is None else str(value)


def settings_table() -> str:
    """Every setting as a Markdown table: key, default and meaning, by the stage it tunes."""
    sections = [
        ("Both stages (`localize`)", STAGES),
        ("Matcher, window and pairing (`localize`; `tolerance-ms` also `map build`, "
         "`evaluate`)", (*MATCHER, WINDOW, TOLERANCE)),
        ("Extraction (`localize`, `map build`)", EXTRACT),
        ("Fusion (`map build`)", (POLISH, MIN_OBSERVATIONS, SEEN_THROUGH, *FUSE)),
        ("Checks, search, refinement, verdict and tracking (`localize`)",
         (REGION, *LOCALIZE_TUNING)),
    ]  # fmt: skip
    lines = ["| key | default | meaning |", "|---|---|---|"]
    for title, settings in sections:
        lines.append(f"| **{title}** | | |")
        for s in settings:
            meaning = s.doc.format(pairing="pairing records of two files by time")
            lines.append(f"| `{s.key}` | `{_shown(s.default)}` | {meaning.replace('|', '/')} |")
    return "\n".join(lines) + "\n"


TABLE_BEGIN = "<!-- settings table: python -m segloc_cli.config docs/configuration.md -->\n"
TABLE_END = "<!-- end of settings table -->\n"


def _rewrite_table(path: str) -> None:
    """Replace the settings table of a Markdown file (between its markers) with the current one."""
    with open(path, encoding="utf-8") as stream:
        text = stream.read()
    head, rest = text.split(TABLE_BEGIN)
    _, tail = rest.split(TABLE_END)
    with open(path, "w", encoding="utf-8") as stream:
        stream.write(head + TABLE_BEGIN + settings_table() + TABLE_END + tail)


if __name__ == "__main__":
    import sys

    _rewrite_table(sys.argv[1])
