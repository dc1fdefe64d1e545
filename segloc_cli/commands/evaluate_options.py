"""``segloc evaluate``'s options, in the groups ``--help`` lists them: the estimates and how
to read them, the truth, the table, the gates, the comparison with an earlier run, the CI
outputs and the figures."""

from __future__ import annotations

from collections.abc import Callable

import click

from segloc_cli.commands.configfile import config_option
from segloc_cli.commands.options import (
    FilePath,
    FiniteRange,
    ModuleChoice,
    force_option,
    format_option,
    path_option,
    setting_option,
)
from segloc_cli.commands.optionvalues import parse_frame_pair


def _limit(name: str, help: str, maximum: float | None = None) -> Callable:
    return click.option(name, type=FiniteRange(min=0, max=maximum), help=help)


ESTIMATE_OPTIONS = (
    click.option(
        "--est-format",
        type=ModuleChoice("segloc_cli.io.trajectories", "EST_FORMATS"),
        help="How to read EST; by default told by its name: .csv segloc's estimates, .tum TUM "
        "(t x y z qx qy qz qw), .bag a ROS 1 bag, a folder with metadata.yaml a ROS 2 bag, "
        ".mcap an MCAP file.",
    ),
    click.option(
        "--topic",
        help="With a bag or MCAP: the topic of the poses, e.g. /amcl_pose. Read: "
        "PoseWithCovarianceStamped, PoseStamped, Odometry, foxglove.PoseInFrame, and "
        "TFMessage with --frames.",
    ),
    click.option(
        "--frames",
        callback=lambda ctx, param, value: parse_frame_pair(value),
        metavar="PARENT,CHILD",
        help="With a /tf topic: the chain to follow, e.g. map,base_link (map→odom→base_link "
        "composed at each stamp).",
    ),
)

TRUTH_OPTIONS = (
    path_option(
        "--survey",
        "survey_path",
        help="Ground truth poses (survey CSV or TUM): prints the paper's Table 1.",
    ),
    path_option(
        "--relations",
        "relations_path",
        help="Reference relative motions (t1 t2 dx dy dz droll dpitch dyaw): prints the "
        "relation metric of Kümmerle et al. (2009) instead.",
    ),
    click.option(
        "--published",
        type=ModuleChoice("segloc_cli.scoring.relations", "PUBLISHED"),
        help="With --relations: add the published graph-mapping errors for this dataset.",
    ),
    setting_option("tolerance-ms", pairing="pairing estimates with survey rows"),
)

TABLE_OPTIONS = (
    format_option("segloc_cli.scoring.evaluate", "FORMATS", "Table format."),
    path_option(
        "--out",
        "out_path",
        help="Write the table here instead of standard output (an existing file needs --force).",
    ),
    click.option(
        "--only-ok",
        is_flag=True,
        help="Summarise only poses whose status is ok (or recovered), every column alike; with "
        "--relations, use only those poses. By default every pose with an estimate counts.",
    ),
)

GATE_OPTIONS = (
    _limit(
        "--min-paired-pct",
        "Fail when under this share (%) of the surveyed poses (relations) has an estimate "
        "within the tolerance. Default 100 whenever another gate is given: a localizer that "
        "stops answering fails, and every pose without an estimate fails the per-pose gates.",
        maximum=100,
    ),
    _limit(
        "--fail-above-cm",
        "Per pose: fail when |X| or |Y| exceeds this (each axis), or the pose is not ok.",
    ),
    _limit(
        "--fail-above-xy-cm",
        "Per pose: fail when the position error's magnitude |XY| "
        "exceeds this, or the pose is not ok.",
    ),
    _limit("--fail-above-deg", "Per pose: fail when |θ| exceeds this, or the pose is not ok."),
    _limit(
        "--min-within-pct",
        "With a per-pose limit: pass when at least this share (%) of "
        "poses keeps to it (default 100: every pose); --junit still marks each pose beyond.",
        maximum=100,
    ),
    _limit(
        "--fail-rms-above-cm",
        "Fail when the RMS position error (with --relations: translational) exceeds this.",
    ),
    _limit("--fail-rms-above-deg", "Fail when the RMS heading (rotational) error exceeds this."),
    _limit(
        "--fail-mean-above-cm", "Fail when the mean position (translational) error exceeds this."
    ),
    _limit("--fail-mean-above-deg", "Fail when the mean heading (rotational) error exceeds this."),
    _limit(
        "--fail-percentile-above-cm",
        "Fail when the --percentile of the position (translational) error exceeds this.",
    ),
    _limit(
        "--fail-percentile-above-deg",
        "Fail when the --percentile of the heading (rotational) error exceeds this.",
    ),
    click.option(
        "--percentile",
        type=FiniteRange(min=0, max=100),
        default=95.0,
        show_default=True,
        help="The percentile the --fail-percentile-above-* gates bound.",
    ),
)

BASELINE_OPTIONS = (
    path_option(
        "--baseline",
        "baseline_path",
        help="An earlier run's `evaluate --format json` output: print each figure's change "
        "with a paired bootstrap 95 % interval over the poses both runs share.",
    ),
    _limit(
        "--fail-if-worse-cm",
        "With --baseline: fail when a position figure got worse by "
        "more than this beyond doubt (its whole interval above it).",
    ),
    _limit(
        "--fail-if-worse-deg",
        "With --baseline: fail when a heading figure got worse by more than this beyond doubt.",
    ),
    _limit(
        "--fail-if-fewer-pct",
        "With --baseline: fail when the poses compared fall short of those the baseline "
        "scored by more than this share (%). Default 0 with --fail-if-worse-cm or -deg.",
        maximum=100,
    ),
)

CI_OPTIONS = (
    path_option(
        "--junit",
        "junit_path",
        help="Write a JUnit XML file: a test case per surveyed pose (with --relations, per "
        "relation missing an end) and one per gate, named alike in every run. Reports are "
        "replaced on a rerun, without --force.",
    ),
    path_option(
        "--summary-md",
        "summary_md_path",
        help="Write the Markdown summary here, verdict first, under 1 MiB (with "
        "GITHUB_STEP_SUMMARY set, it is also appended there, or a warning says why not). "
        "Replaced on a rerun.",
    ),
    path_option(
        "--html",
        "html_path",
        help="Write one self-contained HTML page: verdict and gates first, then the comparison, "
        "failing poses, figures, the whole table folded, settings. Replaced on a rerun.",
    ),
)

FIGURE_OPTIONS = (
    click.option(
        "--plots",
        "plots_dir",
        type=FilePath(file_okay=False),
        help="Also draw figures (PNG and PDF) into this folder, created if needed "
        "(existing figures need --force).",
    ),
    path_option(
        "--map",
        "map_path",
        help="With --plots or --html: the map of the estimates, for the figures over the map "
        "(and with --log, those of both stages).",
    ),
    path_option(
        "--log",
        "log_path",
        help="With --plots or --html and --survey: the log the estimates were made from, for "
        "the figures of both stages.",
    ),
)

EVALUATE_OPTIONS = (
    *ESTIMATE_OPTIONS,
    *TRUTH_OPTIONS,
    *TABLE_OPTIONS,
    *GATE_OPTIONS,
    *BASELINE_OPTIONS,
    *CI_OPTIONS,
    *FIGURE_OPTIONS,
    config_option,
    force_option,
)
"""Every option of ``segloc evaluate``, in ``--help`` order."""
