"""Shared fixtures: scanners emulated in their own processes on pseudo-terminals.

``emulator`` runs ``segloc emulate`` (a protocol's device scanning a world);
``device_process`` serves any ``EmulatedDevice`` built in a forked child with
the same loop, for devices a test scripts itself (a silent one, one that
answers in another protocol, one with a clock about to wrap). ``made_once`` makes a
folder once a session for every worker; ``kernel_caches`` (a plugin of this suite) holds
the numba caches compiled from empty that several tests share.
"""

from __future__ import annotations

import fcntl
import multiprocessing
import os
import select
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from segloc_cli.devices.base import Driver, EmulatedDevice

SEGLOC = Path(sys.executable).parent / "segloc"
HALL = Path(__file__).resolve().parents[1] / "datasets" / "hall"
HALL_WORLD = HALL / "world.json"
HALL_POSE = (11.0, 1.6, 90.0)
"""A pose inside the hall (the survey's first): x_m, y_m, theta_deg."""
START_TIMEOUT_S = 20.0

pytest_plugins = ["kernel_caches"]


@pytest.fixture(autouse=True)
def _no_step_summary(monkeypatch: pytest.MonkeyPatch) -> None:
    """Runs of the suite inside a GitHub job keep its step summary out of the tests."""
    monkeypatch.delenv("GITHUB_STEP_SUMMARY", raising=False)


def made_once(
    tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], None]
) -> Path:
    """A folder of this test session named ``name``, filled by ``make`` once: the pytest-xdist
    worker that asks first makes it while the others wait, then all share it (a module's
    fixture is otherwise made on every worker that runs one of its tests). ``make`` gets the
    empty folder; a ``make`` that fails leaves the next asker to try again."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the session's folder, above each worker's own
    folder, made = base / name, base / f"{name}.made"
    with open(base / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not made.exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            make(folder)
            made.touch()
    return folder


@pytest.fixture(scope="session")
def dask_scheduler() -> Iterator[str]:
    """The address of a local Dask cluster of one single-threaded worker process, started
    once a session on each pytest worker. The sweeps that check what becomes of their tasks
    (resumed, failed, kept) run on it with ``--scheduler``, as on a user's cluster, instead
    of each starting and stopping workers of its own (seconds each); the local clusters a
    sweep starts are checked on their own in ``test_sweep.py``."""
    from segloc_cli.runs.sweep import connect

    with connect(None, 1) as client:
        yield client.scheduler.address


class SilentDevice(EmulatedDevice):
    """A device that never says anything."""

    protocol = "silent"

    def __init__(self):
        super().__init__(np.zeros_like)

    def receive(self, data: bytes, now_s: float) -> bytes:
        return b""

    def poll(self, now_s: float) -> list[bytes]:
        return []


class ParrotDevice(SilentDevice):
    """A device that answers whatever the host writes with the same fixed bytes."""

    def __init__(self, answer: bytes):
        super().__init__()
        self.answer = answer

    def receive(self, data: bytes, now_s: float) -> bytes:
        return self.answer


def start_emulator(protocol: str, *args: str) -> tuple[str, subprocess.Popen]:
    """Start ``segloc emulate --device PROTOCOL ARGS`` and wait for its device path.

    Without ``--world`` the hall's world is scanned; without ``--pose`` or
    ``--path`` the scanner stands at ``HALL_POSE``.
    """
    argv = [str(SEGLOC), "emulate", "--device", protocol, *args]
    if "--world" not in args:
        argv += ["--world", str(HALL_WORLD)]
    if "--pose" not in args and "--path" not in args:
        argv += ["--pose", ",".join(map(str, HALL_POSE))]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], START_TIMEOUT_S)
    line = proc.stdout.readline().strip() if ready else ""
    if not line.startswith("/dev/"):
        stop_emulator(proc)
        raise RuntimeError(f"emulator did not start: {line!r} {proc.stderr.read()}")
    return line, proc


def stop_emulator(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    for stream in (proc.stdout, proc.stderr):
        if stream is not None:
            stream.close()


@pytest.fixture
def emulator() -> Iterator[Callable[..., str]]:
    """``port = emulator(protocol, *extra_args)``: an emulator on a pty; stopped at teardown."""
    running: list[subprocess.Popen] = []

    def start(protocol: str, *args: str) -> str:
        port, proc = start_emulator(protocol, *args)
        running.append(proc)
        return port

    yield start
    for proc in running:
        stop_emulator(proc)


def _serve_in_child(make_device: Callable, faults, connection) -> None:
    from segloc_cli.devices.emulator import serve_device

    serve_device(make_device(), faults, announce=connection.send)


@pytest.fixture
def device_process() -> Iterator[Callable[..., str]]:
    """``port = device_process(make_device, faults=Faults())``: ``make_device()`` is called
    in a forked child, whose device is served on a pty; stopped at teardown."""
    from segloc_cli.devices.emulator import Faults

    context = multiprocessing.get_context("fork")
    running = []

    def start(make_device: Callable, faults: Faults | None = None) -> str:
        receiver, sender = context.Pipe(duplex=False)
        child = context.Process(
            target=_serve_in_child, args=(make_device, faults or Faults(), sender), daemon=True
        )
        child.start()
        running.append(child)
        if not receiver.poll(START_TIMEOUT_S):
            raise RuntimeError("the device process did not announce its port")
        return receiver.recv()

    yield start
    for child in running:
        child.terminate()
        child.join(5)
        if child.is_alive():
            child.kill()
            child.join()


@pytest.fixture
def driver_on(device_process) -> Iterator[Callable[..., Driver]]:
    """``driver = driver_on(DriverClass, make_device, timeout_s=1.0)``: a driver opened on
    ``make_device()`` served by another process (see ``device_process``); closed at teardown."""
    opened: list[Driver] = []

    def connect(driver_class: type[Driver], make_device: Callable, timeout_s: float = 1.0):
        driver = driver_class(device_process(make_device), timeout_s=timeout_s)
        driver.open()
        opened.append(driver)
        return driver

    yield connect
    for driver in opened:
        driver.close()
