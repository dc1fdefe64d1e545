"""`segloc record` against the emulator: a real pty, the emulator in its own process.

Covers the recording's whole life: a clean run through localize and evaluate,
Ctrl-C and SIGTERM (finished file), SIGKILL (every flushed scan kept), a
stalled or unplugged scanner (file finished, one-line error, exit 2), frames
spoiled on the wire, and bad input before any file is written.
"""

from __future__ import annotations

import math
import os
import pty
import re
import select
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import HALL, HALL_POSE, SEGLOC
from test_cli import run_in_process

from segloc_cli.devices.explorer import ExplorerDevice
from segloc_cli.devices.record import DURABLE_EVERY_S
from segloc_cli.devices.scip2 import URG_04LX_PARAMETERS, Scip2Device
from segloc_cli.estimates import PoseTable
from segloc_cli.io.mcap_log import read_log
from segloc_cli.io.tables import write_pose_table

PROGRESS = re.compile(r"recorded (\d+) scans")
WAIT_S = 30.0


def run_segloc(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(SEGLOC), *map(str, args)], capture_output=True, text=True, timeout=timeout
    )


def start_recorder(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [str(SEGLOC), "record", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def wait_for_scans(proc: subprocess.Popen, at_least: int) -> int:
    """Read the recorder's progress lines until it reports ``at_least`` scans; returns the count."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stderr], [], [], 0.5)
        if not ready:
            continue
        line = proc.stderr.readline()
        if not line and proc.poll() is not None:
            break
        match = PROGRESS.search(line)
        if match and int(match.group(1)) >= at_least:
            return int(match.group(1))
    proc.kill()
    raise AssertionError(f"recorder never reported {at_least} scans: {proc.stderr.read()}")


def one_line_error(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) >= 1 and lines[-1].startswith("segloc: error: "), result.stderr
    assert "Traceback" not in result.stderr
    return lines[-1]


@pytest.mark.parametrize("protocol", ["explorer", "scip2"])
def test_recording_localizes_within_the_ci_gates(protocol, emulator, tmp_path):
    """Record from the emulated scanner, localize the scans from a guess 40 cm / 8° off,
    and pass `evaluate --fail-above-cm 2 --fail-above-deg 0.3` against the true pose."""
    port = emulator(protocol, "--seed", "3")
    log = tmp_path / "rec.mcap"
    result = run_segloc("record", "--device", f"{protocol}:{port}", "--scans", "6", "--out", log)
    assert result.returncode == 0, result.stderr
    contents = read_log(log)
    assert contents.finished and len(contents.scans) == 6
    assert contents.sensor["device.protocol"] == protocol

    times = contents.scan_times_s
    truth = np.tile([HALL_POSE[0], HALL_POSE[1], np.deg2rad(HALL_POSE[2])], (len(times), 1))
    ids = np.arange(1, len(times) + 1)
    write_pose_table(tmp_path / "survey.csv", PoseTable(ids, times, truth))
    write_pose_table(
        tmp_path / "initial.csv",
        PoseTable(ids, times, truth + np.array([0.3, -0.25, np.deg2rad(8.0)])),
    )
    est = tmp_path / "est.csv"
    # The recording is the process under test; the runs on its log need no process of their own.
    localized = run_in_process(
        "localize", log, "--map", HALL / "map.json", "--initial", tmp_path / "initial.csv",
        "--out", est,
    )  # fmt: skip
    assert localized.code == 0, localized.err
    gate = run_in_process(
        "evaluate", est, "--survey", tmp_path / "survey.csv",
        "--fail-above-cm", "2", "--fail-above-deg", "0.3",
    )  # fmt: skip
    assert gate.code == 0, gate.out + gate.err


def test_sigkill_loses_at_most_the_last_half_second(emulator, tmp_path):
    port = emulator("explorer")
    log = tmp_path / "killed.mcap"
    proc = start_recorder("--device", f"explorer:{port}", "--rev-per-s", "4", "--out", log)
    reported = wait_for_scans(proc, 8)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    contents = read_log(log)
    assert not contents.finished
    # Scans wait at most DURABLE_EVERY_S in memory: at 4 scans/s, those of the last half
    # second (2) and the one in flight are all a kill can take.
    assert reported - math.ceil(DURABLE_EVERY_S * 4) - 1 <= len(contents.scans) <= reported + 1
    assert contents.sensor["device.protocol"] == "explorer"
    shown = run_in_process("info", log)
    assert shown.code == 0
    assert "finished:  no" in shown.out
    assert f"/scan:     {len(contents.scans)} scans, 1024 readings" in shown.out
    assert "recording was not finished" in shown.err


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_finishes_the_file(signum, emulator, tmp_path):
    port = emulator("scip2")
    log = tmp_path / "stopped.mcap"
    proc = start_recorder("--device", f"scip2:{port}", "--out", log)
    reported = wait_for_scans(proc, 3)
    proc.send_signal(signum)
    assert proc.wait(timeout=10) == 130  # interrupted, with the file finished
    rest = proc.stderr.read()
    assert f"stopped by {signal.Signals(signum).name}" in rest
    contents = read_log(log)
    assert contents.finished and not contents.warnings
    assert len(contents.scans) >= reported


@pytest.mark.parametrize(
    ("fault", "message"),
    [("stall", "no scan for 1 s"), ("hangup", "disconnected")],
)
def test_device_failure_finishes_the_file_with_what_arrived(fault, message, emulator, tmp_path):
    port = emulator("explorer", "--faults", fault, "--fault-after", "3")
    log = tmp_path / "cut.mcap"
    result = run_segloc(
        "record", "--device", f"explorer:{port}", "--stall-timeout", "1", "--out", log
    )
    error = one_line_error(result)
    assert message in error and "keeps the 3 scans" in error
    contents = read_log(log)
    assert contents.finished and len(contents.scans) == 3


def test_a_device_sending_only_spoiled_frames_is_told_apart_from_a_silent_one(
    device_process, tmp_path
):
    port = device_process(lambda: ExplorerDevice(np.ones_like, corrupt=lambda: True))
    log = tmp_path / "spoiled.mcap"
    result = run_segloc(
        "record", "--device", f"explorer:{port}", "--rev-per-s", "4", "--stall-timeout", "1",
        "--out", log,
    )  # fmt: skip
    error = one_line_error(result)
    assert re.search(
        r"no scan for 1 s \((1 frame came but was|\d+ frames came but were) damaged or "
        r"inconsistent and (was|were) skipped\); the log keeps the 0 scans received",
        error,
    ), error
    contents = read_log(log)
    assert contents.finished and len(contents.scans) == 0


def test_spoiled_frames_are_skipped_and_counted(emulator, tmp_path):
    port = emulator("explorer", "--faults", "garbage,checksum", "--fault-rate", "0.5")
    log = tmp_path / "noisy.mcap"
    result = run_segloc(
        "record", "--device", f"explorer:{port}", "--rev-per-s", "4", "--scans", "8", "--out", log
    )
    assert result.returncode == 0, result.stderr
    skipped = int(re.search(r"(\d+) frames skipped \(stopped", result.stderr).group(1))
    assert skipped > 0
    contents = read_log(log)
    assert contents.finished and len(contents.scans) == 8
    assert all(len(scan) == 1024 for scan in contents.scans)


def test_info_shows_the_device_identity(emulator, tmp_path):
    port = emulator("scip2")
    log = tmp_path / "urg.mcap"
    assert (
        run_segloc("record", "--device", f"scip2:{port}", "--scans", "2", "--out", log).returncode
        == 0
    )
    shown = run_in_process("info", log)
    assert shown.code == 0
    assert "finished:  yes" in shown.out
    assert "sensor.device.protocol: scip2" in shown.out
    assert "sensor.range_max_m:" in shown.out


# --- bad input: one line, exit 2, no file ------------------------------------------------


def test_no_such_port(tmp_path):
    log = tmp_path / "none.mcap"
    error = one_line_error(
        run_segloc("record", "--device", "scip2:/dev/segloc-no-such-port", "--out", log)
    )
    assert "no such serial port" in error
    assert not log.exists()


def test_unknown_protocol(tmp_path):
    error = one_line_error(
        run_segloc("record", "--device", "sick:/dev/ttyUSB0", "--out", tmp_path / "x.mcap")
    )
    assert "unknown protocol 'sick'" in error and "scip2" in error


def test_device_that_does_not_answer(tmp_path):
    master, slave = pty.openpty()
    try:
        log = tmp_path / "silent.mcap"
        error = one_line_error(
            run_segloc(
                "record",
                "--device",
                f"scip2:{os.ttyname(slave)}",
                "--timeout",
                "0.5",
                "--out",
                log,
            )
        )
        assert "no answer" in error
        assert not log.exists()
    finally:
        os.close(master)
        os.close(slave)


def _forbidden_port(tmp_path: Path) -> Path:
    """A path this process may not open for writing, as a tty of another user's group."""
    if os.geteuid() != 0:
        port = tmp_path / "ttyFORBIDDEN"
        port.write_bytes(b"")
        port.chmod(0)
        return port
    # Root may open any file; a read-only kernel attribute still refuses writers.
    return Path("/sys/kernel/uevent_seqnum")


def test_permission_denied(tmp_path):
    port = _forbidden_port(tmp_path)
    try:
        port.open("r+b").close()
    except PermissionError:
        pass
    else:
        pytest.skip(f"{port} can be opened for writing here")
    log = tmp_path / "denied.mcap"
    error = one_line_error(run_segloc("record", "--device", f"explorer:{port}", "--out", log))
    assert "permission denied" in error and "dialout" in error
    assert not log.exists()


def test_existing_output_is_not_overwritten(tmp_path):
    log = tmp_path / "keep.mcap"
    log.write_bytes(b"precious")
    error = one_line_error(
        run_segloc("record", "--device", "scip2:/dev/segloc-no-such-port", "--out", log)
    )
    assert "--force" in error
    assert log.read_bytes() == b"precious"


def test_a_device_reporting_an_impossible_geometry_is_refused(device_process, tmp_path):
    bogus = {**URG_04LX_PARAMETERS, "AMAX": "99999999999"}
    port = device_process(lambda: Scip2Device(np.ones_like, parameters=bogus))
    log = tmp_path / "bogus.mcap"
    error = one_line_error(run_segloc("record", "--device", f"scip2:{port}", "--out", log))
    assert error == (
        f"segloc: error: {port}: the device's PP parameter AMAX=99999999999 is out of bounds "
        "(the last step must be 0..1023: below ARES=1024, at most 9999); "
        "refusing a device that reports it"
    )
    assert not log.exists()


def test_wrong_protocol_for_the_device(emulator, tmp_path):
    port = emulator("scip2")
    log = tmp_path / "wrong.mcap"
    error = one_line_error(
        run_segloc("record", "--device", f"explorer:{port}", "--timeout", "0.5", "--out", Path(log))
    )
    assert "explorer" in error or "no answer" in error
    assert not log.exists()
