"""Laser scanners on serial ports: one module per protocol, one registry here.

A device is named on the command line as ``PROTOCOL:PORT`` (``scip2:/dev/ttyACM0``);
``PROTOCOLS`` maps each protocol name to its driver (host side) and its
emulated device (``segloc emulate``), imported only when asked for.
"""

from __future__ import annotations

from importlib import import_module

from segloc_cli.devices.base import Driver, EmulatedDevice

PROTOCOLS = {
    # name: (module, driver class, emulated device class)
    "explorer": ("segloc_cli.devices.explorer", "ExplorerDriver", "ExplorerDevice"),
    "scip2": ("segloc_cli.devices.scip2", "Scip2Driver", "Scip2Device"),
}


def _protocol(name: str) -> tuple[str, str, str]:
    try:
        return PROTOCOLS[name]
    except KeyError:
        known = ", ".join(sorted(PROTOCOLS))
        raise ValueError(f"unknown protocol {name!r}; known protocols: {known}") from None


def driver_class(name: str) -> type[Driver]:
    """The host-side driver of protocol ``name`` (``ValueError`` if unknown)."""
    module, driver, _ = _protocol(name)
    return getattr(import_module(module), driver)


def device_class(name: str) -> type[EmulatedDevice]:
    """The emulated device of protocol ``name`` (``ValueError`` if unknown)."""
    module, _, device = _protocol(name)
    return getattr(import_module(module), device)


def parse_device(text: str) -> tuple[str, str]:
    """``"PROTOCOL:PORT"`` → (protocol, port); ``ValueError`` saying what is expected."""
    protocol, sep, port = text.partition(":")
    if not sep or not port:
        raise ValueError(
            f"expected PROTOCOL:PORT such as scip2:/dev/ttyACM0, got {text!r} "
            f"(protocols: {', '.join(sorted(PROTOCOLS))})"
        )
    _protocol(protocol)
    return protocol, port
