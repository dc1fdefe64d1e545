"""A scanner emulator on a pseudo-terminal: a simulated world served over a real tty.

``serve_device`` opens a pty pair, announces the slave's path (what a driver opens as
its serial port) and runs an ``EmulatedDevice`` behind the master side: host
bytes go to ``device.receive``, and the scan frames ``device.poll`` says are
due go back out. ``serve`` builds the device of a protocol whose scans are
rendered from a world at the scanner's current pose. The device clock is
seconds since the emulator started.

Faults, for testing what a recorder does when things go wrong:

- ``garbage``: random bytes written between frames now and then;
- ``checksum``: now and then a scan frame with a spoiled checksum;
- ``stall``: after ``after_scans`` scans the device goes silent (port still open);
- ``hangup``: after ``after_scans`` scans the emulator closes the pty and exits,
  as an unplugged USB scanner does.

The emulator keeps its own handle on the slave side open so that a host that
closes the port and opens it again finds the device still there.
"""

from __future__ import annotations

import os
import select
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from segloc_cli.devices import device_class
from segloc_cli.devices.base import EmulatedDevice
from segloc_cli.geometry import Pose2
from segloc_cli.sim import SensorModel, render_ranges
from segloc_cli.stopping import stop_requests
from segloc_cli.world import World

FAULTS = ("garbage", "checksum", "stall", "hangup")
POLL_S = 0.002
MAX_PENDING_BYTES = 1 << 16
"""Output not yet taken by the host beyond which new frames are dropped (a full UART)."""
GARBAGE_BYTES = (1, 48)


@dataclass(frozen=True)
class Faults:
    """Which faults to inject, how often and when (see the module docstring)."""

    kinds: frozenset[str] = frozenset()
    rate: float = 0.2
    """Chance per scan frame of a garbage burst or a spoiled checksum."""
    after_scans: int = 20
    """Scans served before a stall or hangup."""

    @classmethod
    def parse(cls, text: str, rate: float = 0.2, after_scans: int = 20) -> Faults:
        """``"garbage,checksum"`` → Faults; ``ValueError`` naming the unknown ones."""
        kinds = frozenset(k.strip() for k in text.split(",") if k.strip())
        unknown = sorted(kinds - set(FAULTS))
        if unknown:
            raise ValueError(f"unknown fault {', '.join(unknown)}; choose from {', '.join(FAULTS)}")
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"fault rate must be in [0, 1], got {rate}")
        if after_scans < 0:
            raise ValueError(f"scans before a stall or hangup must be >= 0, got {after_scans}")
        return cls(kinds, rate, after_scans)


class Trajectory:
    """The scanner's pose (world frame) at emulator time t seconds.

    ``times_s`` (K,) ascending, relative to the emulator's start; ``poses``
    (K, 3) x_m, y_m, theta_rad. Between rows the pose is interpolated
    linearly (heading along the shorter way); before the first and after the
    last row it holds still.
    """

    def __init__(self, times_s: np.ndarray, poses: np.ndarray):
        self.times_s = np.asarray(times_s, dtype=float).reshape(-1)
        self.poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        if self.times_s.size == 0 or self.times_s.size != self.poses.shape[0]:
            raise ValueError("a trajectory needs at least one pose and one time per pose")
        if np.any(np.diff(self.times_s) < 0):
            raise ValueError("trajectory times must be ascending")

    def at(self, t_s: float) -> Pose2:
        x = np.interp(t_s, self.times_s, self.poses[:, 0])
        y = np.interp(t_s, self.times_s, self.poses[:, 1])
        theta = np.interp(t_s, self.times_s, np.unwrap(self.poses[:, 2]))
        return Pose2(float(x), float(y), float(theta))


def serve(
    protocol: str,
    world: World,
    trajectory: Trajectory,
    faults: Faults = Faults(),
    sensor: SensorModel | None = None,
    seed: int = 0,
    announce: Callable[[str], None] = print,
) -> str:
    """Emulate a ``protocol`` scanner in ``world`` until SIGINT/SIGTERM or a hangup fault.

    Returns why it ended; ``announce`` receives the device path once the pty is ready.
    """
    rng = np.random.default_rng(seed)
    sensor = sensor or SensorModel()
    clock = _Clock()

    def render(angles_rad: np.ndarray) -> np.ndarray:
        return render_ranges(world, trajectory.at(clock.now()), angles_rad, sensor, rng)

    def corrupt() -> bool:
        return "checksum" in faults.kinds and rng.random() < faults.rate

    device = device_class(protocol)(render, corrupt)
    return serve_device(device, faults, rng, announce, clock)


def serve_device(
    device: EmulatedDevice,
    faults: Faults = Faults(),
    rng: np.random.Generator | None = None,
    announce: Callable[[str], None] = print,
    clock: _Clock | None = None,
) -> str:
    """Serve ``device`` on a new pty until SIGINT/SIGTERM or a hangup fault; returns why it ended.

    ``faults`` garbage, stall and hangup are applied here (a spoiled checksum
    is the device's own doing); ``rng`` draws them.
    """
    rng = rng or np.random.default_rng(0)
    clock = clock or _Clock()
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    pending = bytearray()
    served = 0
    try:
        with stop_requests() as stopping:
            announce(os.ttyname(slave))
            while not stopping:
                readable, _, _ = select.select([master], [], [], POLL_S)
                now = clock.now()
                if readable:
                    try:
                        data = os.read(master, 4096)
                    except (BlockingIOError, InterruptedError):
                        data = b""
                    if data:
                        _queue(pending, device.receive(data, now))
                for frame in device.poll(now):
                    served += 1
                    if served > faults.after_scans and "hangup" in faults.kinds:
                        _flush(master, pending)
                        return "hangup"
                    if served > faults.after_scans and "stall" in faults.kinds:
                        continue
                    if "garbage" in faults.kinds and rng.random() < faults.rate:
                        _queue(pending, rng.bytes(int(rng.integers(*GARBAGE_BYTES))))
                    _queue(pending, frame)
                _flush(master, pending)
            return stopping[0]
    finally:
        for fd in (master, slave):
            try:
                os.close(fd)
            except OSError:
                pass


class _Clock:
    def __init__(self) -> None:
        self.start = time.monotonic()

    def now(self) -> float:
        return time.monotonic() - self.start


def _queue(pending: bytearray, data: bytes) -> None:
    """Add output unless the host has left too much unread (then it is lost, as on a UART)."""
    if data and len(pending) + len(data) <= MAX_PENDING_BYTES:
        pending += data


def _flush(master: int, pending: bytearray) -> None:
    while pending:
        try:
            written = os.write(master, pending)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            pending.clear()  # nobody can read the other side; drop
            return
        del pending[:written]
