"""Two ROS 2 bags of AMCL's ``/amcl_pose``, for scoring a localizer in CI: ``main/`` and ``pr/``.

They stand for a localizer's runs on the main branch and on a pull request, simulated over
the surveyed poses of a survey CSV (``pose_id,time_s,x_m,y_m,theta_deg``; by default the
shipped hall's). Each message is a ``geometry_msgs/msg/PoseWithCovarianceStamped`` in frame
``map``, stamped at a surveyed pose's time and recorded 5 ms later, as AMCL publishes: the
surveyed pose plus an error drawn from the covariance the message claims (3 cm per axis,
0.5° in heading), pushed a further 4 cm from the truth in the pull request's run.

    python examples/amcl_bags.py --out out/ci     # what make ci-example runs

On a robot, record the topic instead (``ros2 bag record /amcl_pose``). Needs numpy and
rosbags, which segloc installs.
"""

from __future__ import annotations

import argparse
import csv
import shutil
import sys
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

STORE = get_typestore(Stores.LATEST)
PWCS = "geometry_msgs/msg/PoseWithCovarianceStamped"
NS = 1_000_000_000
RECORD_DELAY_NS = 5_000_000
"""A message is recorded this long after its stamp."""
SIGMA_M, SIGMA_DEG = 0.03, 0.5
"""The covariance AMCL claims (1σ per axis and in heading); the errors are drawn from it."""
WORSE_CM = 4.0
"""How much further from the truth every pose of the pull request's run is."""
SEEDS = {"main": 7, "pr": 8}


def read_survey(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A survey CSV's times (N,) in seconds and poses (N, 3) as x m, y m, θ rad."""
    with path.open(newline="", encoding="utf-8") as stream:
        rows = list(csv.DictReader(stream))
    times_s = np.array([float(row["time_s"]) for row in rows])
    poses = np.array([[float(row[k]) for k in ("x_m", "y_m", "theta_deg")] for row in rows])
    poses[:, 2] = np.deg2rad(poses[:, 2])
    return times_s, poses


def pose_message(stamp_ns: int, pose: np.ndarray, covariance: np.ndarray):
    """A ``PoseWithCovarianceStamped`` in frame ``map`` at ``pose`` (x m, y m, θ rad) with a
    (3, 3) ``covariance`` over (x, y, yaw), placed in ROS's 6×6 over x y z roll pitch yaw."""
    t = STORE.types
    sec, nanosec = divmod(stamp_ns, NS)
    full = np.zeros((6, 6))
    full[np.ix_((0, 1, 5), (0, 1, 5))] = covariance
    half = 0.5 * float(pose[2])
    return t[PWCS](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id="map"
        ),
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
                orientation=t["geometry_msgs/msg/Quaternion"](
                    x=0.0, y=0.0, z=float(np.sin(half)), w=float(np.cos(half))
                ),
            ),
            covariance=full.reshape(36),
        ),
    )


def write_amcl_bag(
    path: Path, times_s: np.ndarray, poses: np.ndarray, covariances: np.ndarray
) -> Path:
    """A ROS 2 bag folder at ``path`` (it must not exist; MCAP storage) holding ``/amcl_pose``:
    a message per pose (``poses`` (N, 3) x m, y m, θ rad; ``covariances`` (N, 3, 3)), stamped
    at ``times_s`` (seconds, kept to the nanosecond). Returns ``path``."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/amcl_pose", PWCS, typestore=STORE)
        for time_s, pose, covariance in zip(times_s, poses, covariances, strict=True):
            stamp_ns = round(float(time_s) * NS)
            data = STORE.serialize_cdr(pose_message(stamp_ns, pose, covariance), PWCS)
            writer.write(connection, stamp_ns + RECORD_DELAY_NS, bytes(data))
    return path


def simulated_run(poses: np.ndarray, seed: int, worse_cm: float = 0.0):
    """Estimates of the true ``poses`` (N, 3): each off by an error drawn from the claimed
    covariance, its position error lengthened by ``worse_cm``. Returns the estimates (N, 3)
    and the covariances (N, 3, 3) their messages carry."""
    covariance = np.diag([SIGMA_M**2, SIGMA_M**2, np.deg2rad(SIGMA_DEG) ** 2])
    errors = np.random.default_rng(seed).multivariate_normal(
        np.zeros(3), covariance, size=len(poses)
    )
    lengths = np.hypot(errors[:, 0], errors[:, 1])
    errors[:, :2] *= ((lengths + worse_cm / 100.0) / lengths)[:, None]
    return poses + errors, np.repeat(covariance[None], len(poses), axis=0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--survey", type=Path, default=Path("datasets/hall/survey.csv"))
    parser.add_argument("--out", type=Path, default=Path("out/ci"), help="folder of the bags")
    parser.add_argument("--force", action="store_true", help="replace bags written before")
    args = parser.parse_args(argv)
    times_s, truth = read_survey(args.survey)
    args.out.mkdir(parents=True, exist_ok=True)
    for name, worse_cm in (("main", 0.0), ("pr", WORSE_CM)):
        bag = args.out / name
        if bag.exists():
            if not (args.force and (bag / "metadata.yaml").is_file()):
                print(f"{bag} exists (--force replaces a bag written before)", file=sys.stderr)
                return 2
            shutil.rmtree(bag)
        poses, covariances = simulated_run(truth, SEEDS[name], worse_cm)
        write_amcl_bag(bag, times_s, poses, covariances)
        worse = f", each {worse_cm:g} cm further off" if worse_cm else ""
        print(f"{bag}/: /amcl_pose, {len(poses)} poses{worse}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
