"""The emulator's own parts: fault plans, the scanner's trajectory, its command line."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from conftest import HALL_WORLD, SEGLOC

from segloc_cli.devices import parse_device
from segloc_cli.devices.emulator import Faults, Trajectory


def test_fault_plan_parses_every_kind_and_rejects_unknown_ones():
    plan = Faults.parse("garbage, checksum,stall,hangup", rate=0.3, after_scans=7)
    assert plan.kinds == {"garbage", "checksum", "stall", "hangup"}
    assert (plan.rate, plan.after_scans) == (0.3, 7)
    assert Faults.parse("").kinds == frozenset()
    with pytest.raises(ValueError, match="unknown fault smoke; choose from garbage"):
        Faults.parse("garbage,smoke")


def test_trajectory_interpolates_and_holds_its_ends():
    path = Trajectory(
        np.array([0.0, 2.0]), np.array([[0.0, 0.0, np.pi - 0.1], [2.0, 4.0, -np.pi + 0.1]])
    )
    mid = path.at(1.0)
    assert (mid.x, mid.y) == pytest.approx((1.0, 2.0))
    # The heading turns the short way through ±π, not back through 0.
    assert abs(np.cos(mid.theta) + 1.0) < 1e-12
    assert path.at(-5.0).x == 0.0 and path.at(9.0).y == 4.0


def test_device_names_parse_and_name_the_protocols():
    assert parse_device("scip2:/dev/ttyACM0") == ("scip2", "/dev/ttyACM0")
    with pytest.raises(ValueError, match="expected PROTOCOL:PORT"):
        parse_device("/dev/ttyACM0")
    with pytest.raises(
        ValueError, match="unknown protocol 'urg'; known protocols: explorer, scip2"
    ):
        parse_device("urg:/dev/ttyACM0")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "exactly one of --pose or --path"),
        (["--pose", "1,2"], "X_M,Y_M,THETA_DEG"),
        (["--pose", "1,2,3", "--faults", "fire"], "unknown fault fire"),
        (["--pose", "1,2,3", "--device", "sick"], "'sick' is not one of"),
    ],
)
def test_bad_emulator_arguments_give_one_line(args, message):
    argv = [str(SEGLOC), "emulate", "--world", str(HALL_WORLD)]
    if "--device" not in args:
        argv += ["--device", "scip2"]
    result = subprocess.run(argv + args, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
