"""Recording: scans from a scanner driver into an MCAP log, safe against every way it can end.

The log is created only once the device has answered and taken its settings,
so a wrong port or protocol leaves no empty file behind. Scans reach the disk in
compressed chunks of at most ``DURABLE_EVERY_S`` of recording (``LogWriter``): a
recorder killed outright loses at most the scans of that last stretch. SIGINT and
SIGTERM end the recording between scans and
the file is finished (summary and footer) as on a normal stop. A device that
goes silent for ``stall_s`` or disappears ends the recording with a
``DeviceError``, after the file has been finished with every scan received.

Scan times are the device clock's, placed on the host's wall clock at the
first scan: the device's spacing between scans is kept exactly.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from segloc_cli.devices.base import DeviceError, DeviceInfo, Driver, ScanFrame
from segloc_cli.io.mcap_log import LogWriter
from segloc_cli.scan import Scan
from segloc_cli.stopping import stop_requests
from segloc_cli.wording import counted, plural

DURABLE_EVERY_S = 0.5
"""Longest a received scan waits in memory before its chunk is written and flushed: a
killed recorder loses at most this much of the recording, plus the scan in flight."""


@dataclass
class RecordingTally:
    """What a recording has done so far (and, at the end, how it ended)."""

    scans: int = 0
    skipped: int = 0
    elapsed_s: float = 0.0
    ended_by: str = ""

    @property
    def rate_hz(self) -> float:
        return self.scans / self.elapsed_s if self.elapsed_s > 0 else 0.0


@dataclass(frozen=True)
class RecordSettings:
    """When to stop and what to ask of the scanner (None: no limit, device default)."""

    scans: int | None = None
    duration_s: float | None = None
    readings: int | None = None
    rev_per_s: float | None = None
    stall_s: float = 3.0


def record(
    driver: Driver,
    out_path: Path,
    settings: RecordSettings,
    on_start: Callable[[DeviceInfo, dict[str, str]], None] = lambda info, sensor: None,
    on_scan: Callable[[RecordingTally], None] = lambda tally: None,
) -> RecordingTally:
    """Record from ``driver`` (not yet opened) into a new log at ``out_path``.

    Returns the final progress; ``ended_by`` is "scans", "duration", "SIGINT"
    or "SIGTERM". Raises ``DeviceError`` for a device that cannot be opened or
    identified (no file written) or that fails mid-run (file finished first).
    """
    with stop_requests() as stop:
        driver.open()
        try:
            info = driver.identify()
            sensor = driver.configure(settings.readings, settings.rev_per_s)
            sensor = {
                **sensor,
                **info.as_metadata(),
                "device.port": driver.port,
                "device.baud": str(driver.baud),
            }
            on_start(info, sensor)
            with LogWriter(out_path, sensor, durable_every_s=DURABLE_EVERY_S) as writer:
                return _stream(driver, writer, settings, stop, on_scan)
        finally:
            driver.stop()
            driver.close()


def _stream(
    driver: Driver,
    writer: LogWriter,
    settings: RecordSettings,
    stop: list[str],
    on_scan: Callable[[RecordingTally], None],
) -> RecordingTally:
    progress = RecordingTally()
    started = time.monotonic()
    last_scan = started
    skipped_at_last_scan = driver.skipped
    anchor: tuple[float, float] | None = None  # (host wall clock, device clock) at scan 1
    driver.start()
    while True:
        now = time.monotonic()
        progress.elapsed_s = now - started
        progress.skipped = driver.skipped
        if stop:
            progress.ended_by = stop[0]
            return progress
        if settings.scans is not None and progress.scans >= settings.scans:
            progress.ended_by = "scans"
            return progress
        if settings.duration_s is not None and progress.elapsed_s >= settings.duration_s:
            progress.ended_by = "duration"
            return progress
        if now - last_scan > settings.stall_s:
            # A device that keeps sending only frames that fail their checks is not
            # silent: say so, since the cure differs (baud rate, protocol, cable).
            spoiled = driver.skipped - skipped_at_last_scan
            why = (
                f"{counted(spoiled, 'frame')} came but {plural(spoiled, 'was', 'were')} damaged "
                f"or inconsistent and {plural(spoiled, 'was', 'were')} skipped"
                if spoiled
                else "device stalled"
            )
            raise DeviceError(
                f"{driver.port}: no scan for {settings.stall_s:g} s ({why}); "
                f"the log keeps the {counted(progress.scans, 'scan')} received"
            )
        writer.make_durable_if_due()
        try:
            frame = driver.read_scan()
        except DeviceError as exc:
            kept = counted(progress.scans, "scan")
            raise DeviceError(f"{exc}; the log keeps the {kept} received") from exc
        if frame is None:
            continue
        if anchor is None:
            anchor = (time.time(), frame.device_time_s)
        writer.add_scan(_scan(frame, anchor))
        last_scan = time.monotonic()
        skipped_at_last_scan = driver.skipped
        progress.scans += 1
        progress.skipped = driver.skipped
        on_scan(progress)


def _scan(frame: ScanFrame, anchor: tuple[float, float]) -> Scan:
    host_s, device_s = anchor
    return Scan(
        time_s=host_s + (frame.device_time_s - device_s),
        angles_rad=frame.angles_rad,
        ranges_m=frame.ranges_m,
        range_max_m=frame.range_max_m,
    )
