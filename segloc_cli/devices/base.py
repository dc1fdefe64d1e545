"""What every scanner driver offers, and what every emulated device offers.

Host side, a ``Driver`` talks to one scanner over a serial port:
``open`` → ``identify`` → ``configure`` → ``start`` → ``read_scan`` … →
``stop`` → ``close``. Device side, an ``EmulatedDevice`` answers the same
protocol byte for byte for ``segloc emulate``; it knows nothing of ports or
clocks: the emulator feeds it the host's bytes and the time and writes out
what it returns.

Frames and angles: a scan's beam angles are in radians in the scanner frame
(x forward, counter-clockwise), ranges in metres with 0 for no return. Device
clocks are in seconds and unwrapped by the driver (they start anywhere).
"""

from __future__ import annotations

import errno
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import serial

from segloc_cli.errors import SeglocError

READ_SLICE_S = 0.05
"""Longest single wait on the port: a driver waiting for a reply or a scan checks its
own deadline at least this often, so no wait outlasts ``timeout_s`` by more."""


class DeviceError(SeglocError):
    """A scanner that cannot be opened, does not answer, answers wrongly or goes away."""


class FrameError(ValueError):
    """Bytes that do not form a valid frame or response of the protocol.

    The only exception a protocol's parsers raise on bad bytes; drivers catch
    it, count the frame as skipped and resynchronise.
    """


@dataclass(frozen=True)
class DeviceInfo:
    """Who answered: the identity a scanner reports about itself."""

    protocol: str
    model: str
    serial_number: str
    firmware: str
    extra: dict[str, str] = field(default_factory=dict)

    def as_metadata(self) -> dict[str, str]:
        """Flat str → str entries for the log's sensor metadata record."""
        out = {
            "device.protocol": self.protocol,
            "device.model": self.model,
            "device.serial": self.serial_number,
            "device.firmware": self.firmware,
        }
        out.update({f"device.{k}": str(v) for k, v in self.extra.items()})
        return out


@dataclass(frozen=True)
class ScanFrame:
    """One scan as a device delivered it.

    ``sequence``: the device's own scan counter (it may wrap); ``device_time_s``:
    the device clock at the scan, seconds, unwrapped; ``angles_rad`` (N,) evenly
    spaced, scanner frame; ``ranges_m`` (N,), 0 where there was no return;
    ``range_max_m``: the scanner's largest range.
    """

    sequence: int
    device_time_s: float
    angles_rad: np.ndarray
    ranges_m: np.ndarray
    range_max_m: float


class ClockUnwrapper:
    """A device's wrapping clock (counts modulo ``modulus``) as an unbounded count.

    Each reading is taken as the shorter way round from the previous one, so a
    wrap is undone, and a small step back stays a step back, as long as
    readings come less than half a wrap apart. The first reading is kept as is.
    """

    def __init__(self, modulus: int):
        self.modulus = modulus
        self._last_raw: int | None = None
        self._unwrapped = 0

    def __call__(self, raw: int) -> int:
        """The unwrapped count for the clock reading ``raw`` (same units)."""
        if self._last_raw is None:
            self._unwrapped = raw
        else:
            step = (raw - self._last_raw) % self.modulus
            if step >= self.modulus // 2:
                step -= self.modulus
            self._unwrapped += step
        self._last_raw = raw
        return self._unwrapped


class Driver(ABC):
    """A scanner on a serial port, host side.

    ``skipped`` counts frames dropped for a bad checksum, garbage or a broken
    layout; ``read_scan`` skips them and resynchronises on its own. Every
    failure the user can act on is a ``DeviceError`` with a one-line message.
    """

    protocol: ClassVar[str]
    default_baud: ClassVar[int] = 115200

    def __init__(self, port: str, baud: int | None = None, timeout_s: float = 1.0):
        self.port = port
        self.baud = baud or self.default_baud
        self.timeout_s = timeout_s
        self.skipped = 0
        self._serial: serial.Serial | None = None

    # -- the serial port, shared by every protocol --------------------------------
    def open(self) -> None:
        """Open the port (raw, 8N1); ``DeviceError`` for a missing or forbidden port."""
        self._serial = open_serial(self.port, self.baud, min(self.timeout_s, READ_SLICE_S))

    @property
    def link(self) -> serial.Serial:
        if self._serial is None:
            raise DeviceError(f"{self.port}: port is not open")
        return self._serial

    def write(self, data: bytes) -> None:
        """Send bytes; ``DeviceError`` if the device has gone."""
        try:
            self.link.write(data)
            self.link.flush()
        except (serial.SerialException, OSError) as exc:
            raise DeviceError(f"{self.port}: device disconnected ({_reason(exc)})") from exc

    def read(self, size: int) -> bytes:
        """Up to ``size`` bytes, waiting at most ``READ_SLICE_S``; ``DeviceError`` if gone."""
        try:
            return self.link.read(size)
        except (serial.SerialException, OSError) as exc:
            raise DeviceError(f"{self.port}: device disconnected ({_reason(exc)})") from exc

    def read_available(self) -> bytes:
        """What has arrived (at least one byte, or nothing after ``READ_SLICE_S``)."""
        first = self.read(1)
        if not first:
            return b""
        try:
            waiting = self.link.in_waiting
        except (serial.SerialException, OSError) as exc:
            raise DeviceError(f"{self.port}: device disconnected ({_reason(exc)})") from exc
        return first + (self.read(waiting) if waiting else b"")

    def close(self) -> None:
        """Close the port (idempotent, never raises)."""
        if self._serial is not None:
            try:
                self._serial.close()
            except (serial.SerialException, OSError):
                pass
            self._serial = None

    # -- the protocol ----------------------------------------------------------------
    @abstractmethod
    def identify(self) -> DeviceInfo:
        """Ask the device who it is; ``DeviceError`` if it does not answer in time."""

    @abstractmethod
    def configure(self, readings: int | None, rev_per_s: float | None) -> dict[str, str]:
        """Apply the settings the device supports (None: keep its default).

        Returns the settings in effect as str → str for the log's metadata,
        including ``range_max_m``. ``DeviceError`` for a setting the device
        cannot take, naming the values it can.
        """

    @abstractmethod
    def start(self) -> None:
        """Start continuous scanning."""

    @abstractmethod
    def read_scan(self) -> ScanFrame | None:
        """The next complete scan, or None if none arrived within the read timeout."""

    @abstractmethod
    def stop(self) -> None:
        """Stop scanning (best effort: never raises for a device that has gone)."""


class EmulatedDevice(ABC):
    """A scanner's side of a protocol, for the emulator.

    ``render(angles_rad) -> ranges_m`` gives the ranges the simulated scanner
    sees at those beam angles (scanner frame), 0 for no return.
    ``corrupt()`` says, each time a scan frame is built, whether to spoil its
    checksum (fault injection).
    """

    protocol: ClassVar[str]

    def __init__(
        self,
        render: Callable[[np.ndarray], np.ndarray],
        corrupt: Callable[[], bool] = lambda: False,
    ):
        self.render = render
        self.corrupt = corrupt

    @abstractmethod
    def receive(self, data: bytes, now_s: float) -> bytes:
        """Take bytes from the host (possibly a partial command); return the replies due."""

    @abstractmethod
    def poll(self, now_s: float) -> list[bytes]:
        """Scan frames due by ``now_s`` while streaming, one bytes object per scan."""


def open_serial(port: str, baud: int, timeout_s: float) -> serial.Serial:
    """A raw 8N1 serial port; ``DeviceError`` naming the port and what to do."""
    try:
        return serial.Serial(port, baudrate=baud, timeout=timeout_s, exclusive=True)
    except serial.SerialException as exc:
        code = getattr(exc, "errno", None)
        if code == errno.ENOENT:
            raise DeviceError(
                f"{port}: no such serial port; check the cable and the device path"
            ) from exc
        if code in (errno.EACCES, errno.EPERM):
            raise DeviceError(
                f"{port}: permission denied; add your user to the port's group (often 'dialout')"
            ) from exc
        if code == errno.EBUSY or "lock" in str(exc).lower():
            raise DeviceError(f"{port}: port is in use by another program") from exc
        raise DeviceError(f"{port}: cannot open the serial port ({_reason(exc)})") from exc
    except ValueError as exc:
        raise DeviceError(f"{port}: bad serial settings ({exc})") from exc


SHOWN_CHARS = 32
"""Characters of a device-supplied value quoted in a message at most; the rest is cut."""


def printable(text: str | bytes, limit: int | None = None) -> str:
    """Device-supplied text made safe to print on one line and to store as metadata.

    Bytes are read as Latin-1; every character outside printable ASCII becomes its
    Python escape (``\\n``, ``\\x07``), so nothing a device sends can break a line
    or upset a terminal.
    With ``limit``, text longer than that is cut and ends in "...".
    """
    if isinstance(text, bytes):
        text = text.decode("latin-1")
    if limit is not None and len(text) > limit:
        text = text[:limit] + "..."
    return "".join(c if " " <= c <= "~" else c.encode("unicode_escape").decode() for c in text)


def _reason(exc: BaseException) -> str:
    text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return text.splitlines()[0]
